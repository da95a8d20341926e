/*
 * http_loop.c - the http server on the event loop.
 *
 * MHD in external epoll mode exposes one epoll fd that becomes readable
 * when any of its sockets has work, plus a timeout (idle connections,
 * resumed streams).  So: one fd watch, one timer re-armed after every run.
 * Nothing here blocks: MHD_run only does what is ready.  A connection
 * resumed between runs (a deferred answer, a woken stream) asks, through
 * http_set_wake, for a run on the next turn.
 *
 * Thread: the loop thread.
 */
#include "http_loop.h"

#include <stdint.h>

#include "../base/mem.h"

struct http_loop {
    struct loop *l; /* the loop */
    struct http *h; /* the server */
    int fd;         /* MHD's epoll fd, watched for reading */
    uint64_t timer; /* pending timeout timer, 0 if none */
    uint64_t soon;  /* pending run after a resume, 0 if none */
};

static void on_timer(struct loop *l, void *ud);

static void
rearm(struct http_loop *hl)
{
    if (hl->timer)
        loop_timer_cancel(hl->l, hl->timer);
    hl->timer = 0;
    int64_t ms = http_timeout_ms(hl->h);
    if (ms >= 0)
        hl->timer = loop_timer_add(hl->l, ms, on_timer, hl);
}

void
http_loop_kick(struct http_loop *hl)
{
    http_run(hl->h);
    rearm(hl);
}

static void
on_timer(struct loop *l, void *ud)
{
    (void)l;
    struct http_loop *hl = ud;
    hl->timer = 0;
    http_loop_kick(hl);
}

static void
on_soon(struct loop *l, void *ud)
{
    (void)l;
    struct http_loop *hl = ud;
    hl->soon = 0;
    http_loop_kick(hl);
}

/* http_set_wake's hook: run on the next turn, never inside the caller. */
static void
on_wake(void *ud)
{
    struct http_loop *hl = ud;
    if (!hl->soon)
        hl->soon = loop_timer_add(hl->l, 0, on_soon, hl);
}

static void
on_fd(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)l, (void)fd, (void)events;
    http_loop_kick(ud);
}

struct http_loop *
http_loop_attach(struct loop *l, struct http *h, struct sf_err *err)
{
    struct http_loop *hl = mem_calloc(1, sizeof(*hl));
    if (!hl) {
        sf_err_set(err, SF_ENOMEM, "http: out of memory");
        return NULL;
    }
    *hl = (struct http_loop){ l, h, http_fd(h), 0, 0 };
    if (hl->fd < 0) {
        sf_err_set(err, SF_EBUG, "http: server has no epoll fd");
        free(hl);
        return NULL;
    }
    if (loop_add_fd(l, hl->fd, LOOP_READ, on_fd, hl, err)) {
        free(hl);
        return NULL;
    }
    http_set_wake(h, on_wake, hl);
    rearm(hl);
    return hl;
}

void
http_loop_detach(struct http_loop *hl)
{
    if (!hl)
        return;
    if (hl->timer)
        loop_timer_cancel(hl->l, hl->timer);
    if (hl->soon)
        loop_timer_cancel(hl->l, hl->soon);
    http_set_wake(hl->h, NULL, NULL);
    loop_del_fd(hl->l, hl->fd);
    free(hl);
}
