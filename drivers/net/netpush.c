/*
 * netpush.c - a network driver's push socket lifecycle (netpush.h).
 *
 * Thread: the loop thread.
 */
#include "netpush.h"

#include <stdio.h>

#include "../../src/base/log.h"

bool
netpush_may_open(const struct netpush *p, const struct netdrv *n)
{
    return !p->ws && !p->never && !n->poll_only && n->open &&
           loop_now_ms(n->base.loop) >= p->retry_ms;
}

bool
netpush_open(struct netpush *p, struct netdrv *n, const char *ip, const char *path,
             const struct wsc_ops *ops, void *ud)
{
    if (!netpush_may_open(p, n))
        return false;
    char hdrs[sizeof(n->key_hdr) + 4] = "";
    if (n->key_hdr[0])
        snprintf(hdrs, sizeof(hdrs), "%s\r\n", n->key_hdr);
    struct sf_err err;
    p->ws = wsc_new(n->base.loop, n->url, ip, path, hdrs, ops, ud, &err);
    if (p->ws)
        return true;
    if (err.code == SF_EUNSUPP) {
        p->never = true;
        log_printer(LOG_INFO, n->base.name, "no push socket (%s): polling", err.msg);
        return false;
    }
    netpush_close(p, n, err.msg);
    return false;
}

void
netpush_live(struct netpush *p, struct netdrv *n)
{
    p->live = true;
    p->dirty = true;
    p->backoff_ms = 1000;
    log_printer(LOG_INFO, n->base.name, "push socket standing: its updates replace the polls");
}

bool
netpush_standing(const struct netpush *p, const struct netdrv *n)
{
    return p->live && !n->poll_now;
}

/* The polls take over at once from a socket that stood. */
static void
polls_again(struct netdrv *n)
{
    if (n->open && !n->req)
        netdrv_schedule(n, 0);
    else if (n->open && !n->timer)
        netdrv_schedule(n, netdrv_period(n));
}

void
netpush_hold(struct netpush *p, struct netdrv *n, const char *why)
{
    bool was_live = p->live;
    p->live = p->dirty = false;
    log_printer(LOG_INFO, n->base.name, "%s; polling%s while the socket waits", why,
                was_live ? " again" : "");
    if (was_live)
        polls_again(n);
}

bool
netpush_close(struct netpush *p, struct netdrv *n, const char *why)
{
    bool was_live = p->live;
    wsc_free(p->ws);
    p->ws = NULL;
    p->live = p->dirty = false;
    if (!why)
        return was_live;
    if (p->backoff_ms < 1000)
        p->backoff_ms = 1000;
    p->retry_ms = loop_now_ms(n->base.loop) + p->backoff_ms;
    log_printer(LOG_INFO, n->base.name, "%s; polling%s, socket again in %d ms", why,
                was_live ? " again" : "", p->backoff_ms);
    p->backoff_ms =
        p->backoff_ms * 2 > NETPUSH_BACKOFF_MAX_MS ? NETPUSH_BACKOFF_MAX_MS : p->backoff_ms * 2;
    if (was_live)
        polls_again(n);
    return was_live;
}

bool
netpush_due(struct netpush *p, const struct netdrv *n)
{
    if (!p->live || !p->dirty || n->req || !n->open || (n->timer && n->poll_now))
        return false;
    p->dirty = false;
    return true;
}
