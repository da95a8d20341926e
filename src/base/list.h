/*
 * list.h - intrusive doubly linked list (the Linux kernel's shape).
 *
 * Embed a struct list in the element, keep a struct list head, and get back
 * to the element with list_entry().  No allocation, O(1) removal.
 * Not thread-safe: the owner serializes access.
 */
#ifndef SF_BASE_LIST_H
#define SF_BASE_LIST_H

#include <stdbool.h>
#include <stddef.h>

struct list {
    struct list *prev, *next;
};

static inline void
list_init(struct list *head)
{
    head->prev = head->next = head;
}

static inline bool
list_empty(const struct list *head)
{
    return head->next == head;
}

static inline void
list_insert_after(struct list *pos, struct list *node)
{
    node->prev = pos;
    node->next = pos->next;
    pos->next->prev = node;
    pos->next = node;
}

/* Append node at the tail of head. */
static inline void
list_push_back(struct list *head, struct list *node)
{
    list_insert_after(head->prev, node);
}

static inline void
list_remove(struct list *node)
{
    node->prev->next = node->next;
    node->next->prev = node->prev;
    node->prev = node->next = node;
}

#define list_entry(ptr, type, member) ((type *)((char *)(ptr)-offsetof(type, member)))

/* Iterate safely against removal of the current node. */
#define list_for_each_safe(it, tmp, head)                                                          \
    for ((it) = (head)->next, (tmp) = (it)->next; (it) != (head); (it) = (tmp), (tmp) = (it)->next)

#endif
