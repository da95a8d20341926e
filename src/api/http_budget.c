/*
 * http_budget.c - the HTTP server's connection budgets: one list per
 * class, oldest first, so a class's count, its oldest member and the
 * members of one address are a walk of at most its cap.
 *
 * Why classes rather than one limit: the server cannot tell a keyed client
 * from a keyless one until its request head is in, and one shared pool is
 * then filled by whoever asks most (issue 30: 256 keyless keep-alive
 * connections locked out every key).  So a connection waits as "pending"
 * (capped, oldest dropped, with a deadline), and its request head moves it
 * into the class it asked as, whose cap no other class can use.
 *
 * Dropping is shutdown(2): the server's library sees the end of the stream
 * and closes the connection in its own time, so nothing here frees.
 *
 * Thread: whichever thread calls http_run().
 */
#include "http_budget.h"

#include <stddef.h>
#include <sys/resource.h>
#include <sys/socket.h>

#include "../base/log.h"
#include "http.h"

static void
unlink_slot(struct http_budget *b, struct http_slot *s)
{
    if (s->cls == HTTP_CLASS_N)
        return;
    if (s->prev)
        s->prev->next = s->next;
    else
        b->head[s->cls] = s->next;
    if (s->next)
        s->next->prev = s->prev;
    else
        b->tail[s->cls] = s->prev;
    s->prev = s->next = NULL;
    b->n[s->cls]--;
    s->cls = HTTP_CLASS_N;
}

static void
link_slot(struct http_budget *b, struct http_slot *s, enum http_class cls)
{
    s->cls = cls;
    s->next = NULL;
    s->prev = b->tail[cls];
    if (b->tail[cls])
        b->tail[cls]->next = s;
    else
        b->head[cls] = s;
    b->tail[cls] = s;
    b->n[cls]++;
}

static unsigned
count_addr(const struct http_budget *b, enum http_class cls, uint32_t addr)
{
    unsigned n = 0;
    for (const struct http_slot *s = b->head[cls]; s; s = s->next)
        n += s->addr == addr;
    return n;
}

static void
drop(struct http_budget *b, struct http_slot *s, const char *why)
{
    log_info("http", "closing a connection that sent no complete request head: %s", why);
    shutdown(s->fd, SHUT_RDWR);
    unlink_slot(b, s);
}

unsigned long
http_budget_size(struct http_budget_caps *caps)
{
    static const unsigned max[HTTP_CLASS_N] = { HTTP_PREAUTH_MAX, HTTP_KEYLESS_MAX, HTTP_READ_MAX,
                                                HTTP_WRITE_MAX };
    unsigned long need = HTTP_CONNECTIONS_MAX + HTTP_FD_RESERVE;
    struct rlimit rl;
    unsigned long soft = need;
    if (getrlimit(RLIMIT_NOFILE, &rl) == 0) {
        if (rl.rlim_cur != RLIM_INFINITY && rl.rlim_cur < need) {
            struct rlimit up = rl;
            up.rlim_cur = rl.rlim_max == RLIM_INFINITY || rl.rlim_max > need ? need : rl.rlim_max;
            if (setrlimit(RLIMIT_NOFILE, &up) == 0)
                rl = up;
        }
        if (rl.rlim_cur != RLIM_INFINITY && rl.rlim_cur < need)
            soft = rl.rlim_cur;
    }
    /* What the file descriptors left after the reserve allow, in proportion. */
    unsigned long avail = soft > HTTP_FD_RESERVE + 16 ? soft - HTTP_FD_RESERVE : 16;
    unsigned long want = HTTP_CONNECTIONS_MAX;
    caps->total = 0;
    for (int c = 0; c < HTTP_CLASS_N; c++) {
        unsigned long m = avail >= want ? max[c] : max[c] * avail / want;
        caps->max[c] = m ? (unsigned)m : 1;
        caps->total += caps->max[c];
    }
    caps->total +=
        avail >= want ? HTTP_CONNECTIONS_SPARE : (unsigned)(HTTP_CONNECTIONS_SPARE * avail / want);
    caps->pending_per_addr = HTTP_PREAUTH_PER_IP_MAX;
    caps->keyless_per_addr = HTTP_KEYLESS_PER_IP_MAX;
    if (avail < want)
        log_warn("http",
                 "only %lu file descriptors (RLIMIT_NOFILE): connection caps cut to %u "
                 "(pending %u, keyless %u, read %u, write %u); raise the limit to %lu",
                 soft, caps->total, caps->max[0], caps->max[1], caps->max[2], caps->max[3], need);
    return soft;
}

void
http_budget_init(struct http_budget *b, const struct http_budget_caps *caps)
{
    *b = (struct http_budget){ .caps = *caps };
}

void
http_budget_accept(struct http_budget *b, struct http_slot *s)
{
    s->cls = HTTP_CLASS_N;
    link_slot(b, s, HTTP_CLASS_PENDING);
    if (count_addr(b, HTTP_CLASS_PENDING, s->addr) > b->caps.pending_per_addr) {
        struct http_slot *o = b->head[HTTP_CLASS_PENDING];
        while (o->addr != s->addr)
            o = o->next;
        drop(b, o, "too many from its address waiting for theirs");
    } else if (b->n[HTTP_CLASS_PENDING] > b->caps.max[HTTP_CLASS_PENDING]) {
        drop(b, b->head[HTTP_CLASS_PENDING], "too many connections waiting for theirs");
    }
}

bool
http_budget_enter(struct http_budget *b, struct http_slot *s, enum http_class cls)
{
    if (s->cls == cls)
        return true;
    unlink_slot(b, s);
    if (b->n[cls] >= b->caps.max[cls])
        return false;
    if (cls == HTTP_CLASS_KEYLESS && count_addr(b, cls, s->addr) >= b->caps.keyless_per_addr)
        return false;
    link_slot(b, s, cls);
    return true;
}

void
http_budget_close(struct http_budget *b, struct http_slot *s)
{
    unlink_slot(b, s);
}

void
http_budget_expire(struct http_budget *b, int64_t now_ms)
{
    while (b->head[HTTP_CLASS_PENDING] && b->head[HTTP_CLASS_PENDING]->deadline_ms <= now_ms)
        drop(b, b->head[HTTP_CLASS_PENDING], "header deadline passed");
}

int64_t
http_budget_next_ms(const struct http_budget *b)
{
    return b->head[HTTP_CLASS_PENDING] ? b->head[HTTP_CLASS_PENDING]->deadline_ms : -1;
}
