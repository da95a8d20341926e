/*
 * farm_view.c - publish this host's printers, cache the other hosts'
 * (farm_view.h).
 *
 * Both run on the farm's store thread (storeq_read: neither wakes the
 * scheduler, and a publish, an upsert of one row, is safe to run twice).
 * At most one publish and one read are in flight; what comes meanwhile
 * waits for them (the newest text; one more read).  The state outlives
 * farm_view_stop while a request is in flight, as farm_remote's does.
 *
 * Thread: the loop thread (the requests' work: the store thread).
 */
#include "farm_view.h"

#include <stdlib.h>
#include <string.h>

#include "../base/clock.h"
#include "../base/log.h"
#include "../base/loop.h"
#include "../base/mem.h"
#include "farm_host.h"
#include "farm_int.h"
#include "storeq.h"

struct farm_view {
    struct farm *f;
    /* publishing */
    char *last;         /* the text last written, NULL if none */
    int64_t last_token; /* the host's token it was written under */
    char *next;         /* the newest text not written yet, NULL if none */
    int64_t last_ms;    /* loop time of the last publish's post */
    uint64_t pub_timer; /* the publish held back by FARM_VIEW_MIN_MS, 0 if none */
    bool posting;       /* a publish is on the store thread */
    bool pub_failing;   /* the last publish failed: said so (once until one is written) */
    /* reading */
    struct store_command_printer *rows; /* the cache, n_rows */
    size_t n_rows;
    bool reading;   /* a read is on the store thread */
    bool reread;    /* woken meanwhile: read again once it is back */
    bool used;      /* read by the API since the last read: keep it fresh */
    bool have;      /* read once */
    uint64_t timer; /* the refresh */
    int inflight;   /* requests on the store thread */
    bool stopped;   /* farm_view_stop ran: free once inflight is 0 */
};

/* A publish, the store thread's while in flight. */
struct pub {
    struct farm_view *v;
    char host[STORE_HOST_NAME_MAX];
    int64_t token;
    char *text;
};

/* A read of the other hosts' printers. */
struct rd {
    struct farm_view *v;
    char me[STORE_HOST_NAME_MAX];
    struct store_command_printer *rows;
    size_t n;
};

static void
release(struct farm_view *v)
{
    if (!v->stopped || v->inflight > 0)
        return;
    free(v->last);
    free(v->next);
    free(v->rows);
    free(v);
}

/* ---- publishing ---- */

static void pump(struct farm_view *v);

static int
publish_fn(struct store *s, void *arg, struct sf_err *err)
{
    const struct pub *p = arg;
    return store_view_publish(s, p->host, p->token, p->text, err);
}

static void
on_published(void *ud, const struct storeq_result *res)
{
    struct pub *p = ud;
    struct farm_view *v = p->v;
    v->inflight--;
    v->posting = false;
    if (res->rc == SF_OK && !v->stopped) {
        free(v->last);
        v->last = p->text;
        v->last_token = p->token;
        p->text = NULL;
        if (v->pub_failing)
            log_info("view", "this host's printers are published again");
        v->pub_failing = false;
    } else if (res->rc && !v->stopped && !v->pub_failing) { /* tried again at the next look */
        log_warn("view", "this host's printers not published: %s", res->err->msg);
        v->pub_failing = true;
    }
    free(p->text);
    free(p);
    if (v->stopped)
        release(v);
    else
        pump(v);
}

static void
on_pub_timer(struct loop *l, void *ud)
{
    (void)l;
    struct farm_view *v = ud;
    v->pub_timer = 0;
    pump(v);
}

/* Post the waiting text, unless one is in flight or the last went out too recently. */
static void
pump(struct farm_view *v)
{
    if (v->stopped || v->posting || !v->next || v->pub_timer)
        return;
    int64_t token = farm_host_token(v->f);
    char me[STORE_HOST_NAME_MAX];
    if (!token || !farm_host_reader(v->f, me, sizeof(me)) || !me[0])
        return; /* not joined: published at the next look once it is */
    if (v->last && v->last_token == token && strcmp(v->last, v->next) == 0) {
        free(v->next); /* back to what was written: nothing to do */
        v->next = NULL;
        return;
    }
    int64_t now = loop_now_ms(v->f->l), wait = v->last_ms + FARM_VIEW_MIN_MS - now;
    if (v->last && wait > 0) {
        v->pub_timer = loop_timer_add(v->f->l, wait, on_pub_timer, v);
        return;
    }
    struct pub *p = mem_calloc(1, sizeof(*p));
    if (!p)
        return;
    p->v = v;
    snprintf(p->host, sizeof(p->host), "%s", me);
    p->token = token;
    p->text = v->next;
    if (storeq_read(v->f->q, publish_fn, p, on_published, p)) {
        free(p); /* v->next stays: tried at the next look */
        return;
    }
    v->next = NULL;
    v->posting = true;
    v->inflight++;
    v->last_ms = now;
}

void
farm_view_publish(struct farm *f, const char *text)
{
    struct farm_view *v = f ? f->view : NULL;
    if (!v || v->stopped)
        return;
    if ((v->next && strcmp(v->next, text) == 0) ||
        (!v->next && v->last && strcmp(v->last, text) == 0 && v->last_token == farm_host_token(f)))
        return; /* nothing new */
    char *copy = strdup(text);
    if (!copy)
        return;
    free(v->next);
    v->next = copy;
    pump(v);
}

/* ---- reading ---- */

static void read_again(struct farm_view *v);

static int
read_fn(struct store *s, void *arg, struct sf_err *err)
{
    struct rd *r = arg;
    return store_command_printers(s, r->me, clock_wall_ms(), &r->rows, &r->n, err);
}

static void
on_read(void *ud, const struct storeq_result *res)
{
    struct rd *r = ud;
    struct farm_view *v = r->v;
    v->inflight--;
    v->reading = false;
    if (res->rc == SF_OK && !v->stopped) {
        free(v->rows);
        v->rows = r->rows;
        v->n_rows = r->n;
        r->rows = NULL;
        v->have = true;
    } else if (res->rc && !v->stopped) {
        log_warn("view", "the other hosts' printers: %s", res->err->msg);
    }
    free(r->rows);
    free(r);
    if (v->stopped) {
        release(v);
        return;
    }
    if (v->reread) {
        v->reread = false;
        read_again(v);
    }
}

static void
read_again(struct farm_view *v)
{
    char me[STORE_HOST_NAME_MAX];
    if (v->stopped || !farm_host_reader(v->f, me, sizeof(me)) || !me[0])
        return; /* not joined yet: the refresh tries again */
    if (v->reading) {
        v->reread = true;
        return;
    }
    struct rd *r = mem_calloc(1, sizeof(*r));
    if (!r)
        return;
    r->v = v;
    snprintf(r->me, sizeof(r->me), "%s", me);
    if (storeq_read(v->f->q, read_fn, r, on_read, r)) {
        free(r);
        return;
    }
    v->used = false;
    v->reading = true;
    v->inflight++;
}

static void
on_refresh(struct loop *l, void *ud)
{
    struct farm_view *v = ud;
    v->timer = loop_timer_add(l, FARM_VIEW_REFRESH_MS, on_refresh, v);
    if (v->used || !v->have)
        read_again(v);
    pump(v); /* a text held back before the join */
}

void
farm_view_heard(struct farm *f)
{
    if (f && f->view)
        read_again(f->view);
}

size_t
farm_view_printers(struct farm *f, const struct store_command_printer **rows)
{
    struct farm_view *v = f ? f->view : NULL;
    *rows = v ? v->rows : NULL;
    if (!v)
        return 0;
    v->used = true;
    return v->n_rows;
}

int
farm_view_start(struct farm *f, struct sf_err *err)
{
    struct farm_view *v = mem_calloc(1, sizeof(*v));
    if (!v)
        return sf_err_set(err, SF_ENOMEM, "the farm's view: out of memory");
    v->f = f;
    f->view = v;
    v->timer = loop_timer_add(f->l, FARM_VIEW_REFRESH_MS, on_refresh, v);
    return SF_OK;
}

void
farm_view_stop(struct farm *f)
{
    struct farm_view *v = f ? f->view : NULL;
    if (!v)
        return;
    if (v->timer)
        loop_timer_cancel(f->l, v->timer);
    if (v->pub_timer)
        loop_timer_cancel(f->l, v->pub_timer);
    v->stopped = true;
    f->view = NULL;
    release(v);
}
