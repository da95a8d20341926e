/*
 * http_budget.h - who may hold the HTTP server's connections: every
 * connection in one class (pending, keyless, read, write; http.h says why
 * each has its cap), counted from accept to close, with the caps sized to
 * the process's file descriptor limit.
 *
 * Kept apart from http.c because it is plain accounting: no MHD, so its
 * rules read (and are tested) on their own.  http.c keeps one struct
 * http_slot per connection (MHD's socket context) and reports each
 * connection's accept, request head and close here.
 *
 * Thread: whichever thread calls http_run(); the functions keep no global
 * state apart from http_budget_size(), which sets the process's soft
 * RLIMIT_NOFILE.
 */
#ifndef SF_API_HTTP_BUDGET_H
#define SF_API_HTTP_BUDGET_H

#include <stdbool.h>
#include <stdint.h>

enum http_class {
    HTTP_CLASS_PENDING, /* no complete request head yet */
    HTTP_CLASS_KEYLESS, /* its latest request came without a key */
    HTTP_CLASS_READ,    /* ... with a read-only or metrics key */
    HTTP_CLASS_WRITE,   /* ... with a read-write key */
    HTTP_CLASS_N,       /* none: refused, closing; counted nowhere */
};

struct http_budget_caps {
    unsigned max[HTTP_CLASS_N]; /* connections per class */
    unsigned pending_per_addr;  /* pending connections per client address */
    unsigned keyless_per_addr;  /* keyless connections per client address */
    unsigned total;             /* MHD's connection limit: the sum plus a spare */
};

/* One connection; the caller owns it (allocated at accept, freed at close). */
struct http_slot {
    int fd;                 /* its socket, shut down to drop it */
    uint32_t addr;          /* client IPv4 address, network order (0: unknown) */
    enum http_class cls;    /* where it is counted */
    int64_t deadline_ms;    /* pending: monotonic time its head must be in by */
    struct http_slot *prev; /* in its class's list, oldest first */
    struct http_slot *next;
};

struct http_budget {
    struct http_budget_caps caps;
    struct http_slot *head[HTTP_CLASS_N]; /* each class, oldest first */
    struct http_slot *tail[HTTP_CLASS_N];
    unsigned n[HTTP_CLASS_N]; /* their counts */
};

/*
 * The caps of http.h, for a process whose soft RLIMIT_NOFILE is raised (up
 * to its hard limit) to cover them plus HTTP_FD_RESERVE; when it cannot
 * be, every class shrinks in proportion (at least 1 each).  Returns the
 * soft limit now in force.
 */
unsigned long http_budget_size(struct http_budget_caps *caps);

void http_budget_init(struct http_budget *b, const struct http_budget_caps *caps);

/*
 * A new connection, counted as pending with deadline_ms set by the caller.
 * When that puts its address or all pending ones over their cap, the
 * oldest pending of that address (else the oldest of all) is dropped: its
 * socket shut down (the server then closes it) and counted nowhere.
 */
void http_budget_accept(struct http_budget *b, struct http_slot *s);

/*
 * s sent a request head of class cls.  True if counted there (moved from
 * its old class); false when cls, or for keyless its address, is full:
 * then s is counted nowhere and the caller answers 503 and closes it.
 */
bool http_budget_enter(struct http_budget *b, struct http_slot *s, enum http_class cls);

/* s is closed: count it nowhere (the caller frees it). */
void http_budget_close(struct http_budget *b, struct http_slot *s);

/* Drop the pending connections whose deadline is at or before now_ms. */
void http_budget_expire(struct http_budget *b, int64_t now_ms);
/* The earliest pending deadline, or -1 if none. */
int64_t http_budget_next_ms(const struct http_budget *b);

#endif
