/*
 * farm_host.c - the farm as one of several hosts on one store (farm_host.h):
 * the join, the beat and the reap on a loop timer, the claims the
 * scheduling pass makes, and the LISTEN connection on the loop's epoll.
 *
 * Why the beat and the reap share one timer on the loop's connection: both
 * are one short statement each a few seconds, and the reap is idempotent,
 * so every host running it is harmless (the first one in moves the work).
 * The listener has a connection of its own (sqldb.h: a notification that
 * arrives while another call runs on a connection does not wake its fd).
 *
 * Thread: the loop thread.
 */
#include "farm_host.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "../base/clock.h"
#include "../base/log.h"
#include "../base/mem.h"
#include "farm_int.h"
#include "store_host.h"

struct farm_host {
    struct farm *f;
    struct store *ls; /* the listener's connection */
    char name[STORE_HOST_NAME_MAX];
    int64_t token;    /* this process's, once joined */
    bool joined;      /* the lease is ours */
    bool waiting;     /* a join was refused: say so once, retry at each beat */
    int64_t lease_ms; /* host_lease_s */
    uint64_t timer;   /* the beat */
    int fd;           /* the listener's socket on the loop, -1 if none */
    int peers;        /* other live hosts at the last join or beat; -1 if not known */
};

static void listen_arm(struct farm_host *h);

bool
farm_host_on(const struct farm *f)
{
    return f && f->host;
}

bool
farm_host_alone(const struct farm *f)
{
    return !farm_host_on(f) || (f->host->joined && f->host->peers == 0);
}

/* Count the other live hosts (farm_host_alone). */
static void
count_peers(struct farm_host *h)
{
    struct sf_err err;
    if (store_host_peers(h->f->s, h->name, clock_wall_ms(), &h->peers, &err)) {
        log_warn("host", "%s: %s", h->name, err.msg);
        h->peers = -1;
    }
}

/* The machine's hostname as a host name: letters, digits, '.', '-', '_' (others as '-'). */
static void
default_name(char *out, size_t n)
{
    char hn[256] = "";
    if (gethostname(hn, sizeof(hn) - 1) != 0 || !hn[0])
        snprintf(hn, sizeof(hn), "host");
    snprintf(out, n, "%s", hn);
    for (char *p = out; *p; p++)
        if (!((*p >= 'a' && *p <= 'z') || (*p >= 'A' && *p <= 'Z') || (*p >= '0' && *p <= '9') ||
              *p == '.' || *p == '-' || *p == '_'))
            *p = '-';
}

/* Own f's printers (replacing what the host owned before). */
static void
own(struct farm_host *h)
{
    struct farm *f = h->f;
    const char **names = mem_array(f->n_printers ? f->n_printers : 1, sizeof(*names));
    struct sf_err err;
    if (!names)
        return;
    for (size_t i = 0; i < f->n_printers; i++)
        names[i] = printer_cfg(f->printers[i])->name;
    if (store_host_own(f->s, h->name, h->token, names, f->n_printers, &err))
        log_error("host", "%s: %s", h->name, err.msg);
    free(names);
}

/* Join (again): the lease, the printers.  Logs why not. */
static void
join(struct farm_host *h)
{
    struct sf_err err;
    int rc = store_host_join(h->f->s, h->name, h->lease_ms, &h->token, &err);
    if (rc) {
        if (!h->waiting || rc != SF_EAGAIN)
            log_warn("host", "%s: cannot join yet: %s (trying again every %lld ms)", h->name,
                     err.msg, (long long)(h->lease_ms / FARM_HOST_BEATS_PER_LEASE));
        h->waiting = true;
        return;
    }
    h->joined = true;
    h->waiting = false;
    own(h);
    count_peers(h);
    log_info("host", "%s joined (token %lld, lease %.1f s, %zu printers)", h->name,
             (long long)h->token, (double)h->lease_ms / 1000, h->f->n_printers);
    farm_host_wake(h->f); /* the others see the printers; this one schedules */
    farm_kick(h->f);
    for (size_t i = 0; i < h->f->n_printers; i++) /* what waited for the lease (a restart) */
        printer_attach_again(h->f->printers[i]);
}

static void
on_beat(struct loop *l, void *ud)
{
    struct farm_host *h = ud;
    struct sf_err err;
    h->timer = 0;
    if (!h->joined) {
        join(h);
    } else if (store_host_beat(h->f->s, h->name, h->token, h->lease_ms, &err)) {
        log_error("host", "%s: %s", h->name, err.msg);
        if (err.code == SF_ESTALE) { /* reaped: its jobs moved on; join as a new process */
            h->joined = false;
            join(h);
        }
    }
    struct store_recovery moved;
    int n = store_host_reap(h->f->s, clock_wall_ms(), &moved, &err);
    if (n < 0) {
        log_warn("host", "reap: %s", err.msg);
    } else if (n > 0) {
        log_warn("host",
                 "reaped %d hosts whose lease ran out: %d jobs back in the queue, %d "
                 "interrupted",
                 n, moved.requeued, moved.interrupted);
        farm_host_wake(h->f);
        farm_kick(h->f);
    }
    if (h->joined)
        count_peers(h);
    if (h->fd < 0)
        listen_arm(h);
    h->timer = loop_timer_add(l, h->lease_ms / FARM_HOST_BEATS_PER_LEASE, on_beat, h);
}

static void
listen_drop(struct farm_host *h)
{
    if (h->fd >= 0)
        loop_del_fd(h->f->l, h->fd);
    h->fd = -1;
}

static void
on_note(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)l, (void)fd, (void)events;
    struct farm_host *h = ud;
    int n = store_host_drain(h->ls);
    if (n < 0) { /* lost: the beat tries again */
        log_warn("host", "%s: the wake-up connection was lost; retrying at each beat", h->name);
        listen_drop(h);
        return;
    }
    if (store_host_notify_fd(h->ls) != h->fd) { /* it reconnected */
        listen_drop(h);
        listen_arm(h);
    }
    if (n > 0)
        farm_kick(h->f);
}

/* Watch the listener's socket (again): drain first, which reconnects a lost connection. */
static void
listen_arm(struct farm_host *h)
{
    struct sf_err err;
    if (store_host_drain(h->ls) < 0)
        return;
    int fd = store_host_notify_fd(h->ls);
    if (fd < 0)
        return;
    if (loop_add_fd(h->f->l, fd, LOOP_READ, on_note, h, &err)) {
        log_warn("host", "%s: %s", h->name, err.msg);
        return;
    }
    h->fd = fd;
    farm_kick(h->f); /* what arrived while it was away */
}

int
farm_host_start(struct farm *f, const struct farmcfg *cfg, struct sf_err *err)
{
    if (!cfg->store[0])
        return SF_OK;
    struct farm_host *h = mem_calloc(1, sizeof(*h));
    if (!h)
        return sf_err_set(err, SF_ENOMEM, "host: out of memory");
    h->f = f;
    h->fd = -1;
    h->peers = -1;
    h->lease_ms = (int64_t)(cfg->host_lease_s * 1000);
    if (cfg->host[0])
        snprintf(h->name, sizeof(h->name), "%s", cfg->host);
    else
        default_name(h->name, sizeof(h->name));
    f->host = h;
    if (!(h->ls = store_open_peer(f->s, err)) || store_host_listen(h->ls, err)) {
        sf_err_prefix(err, "host %s: wake-up connection", h->name);
        return err->code;
    }
    listen_arm(h);
    join(h);
    h->timer = loop_timer_add(f->l, h->lease_ms / FARM_HOST_BEATS_PER_LEASE, on_beat, h);
    return SF_OK;
}

void
farm_host_stop(struct farm *f)
{
    struct farm_host *h = f ? f->host : NULL;
    if (!h)
        return;
    if (h->timer)
        loop_timer_cancel(f->l, h->timer);
    listen_drop(h);
    struct sf_err err;
    if (h->joined) {
        /* leave: the lease ends now and this host reaps itself, so its waiting work moves on
           at once (its prints are interrupted already: farm_free) */
        struct store_recovery moved;
        int64_t now = clock_wall_ms();
        if (store_host_beat(f->s, h->name, h->token, 1, &err) ||
            store_host_reap(f->s, now + 2, &moved, &err) < 0)
            log_warn("host", "%s: leave: %s", h->name, err.msg);
        else
            log_info("host", "%s left: %d jobs back in the queue", h->name, moved.requeued);
        farm_host_wake(f);
    }
    store_close(h->ls);
    free(h);
    f->host = NULL;
}

bool
farm_host_reader(const struct farm *f, char *name, size_t size)
{
    const struct farm_host *h = f->host;
    name[0] = '\0';
    if (!h)
        return true;
    if (!h->joined)
        return false;
    snprintf(name, size, "%s", h->name);
    return true;
}

int
farm_host_claim(struct farm *f, int64_t id, int64_t *fence)
{
    struct farm_host *h = f->host;
    struct sf_err err;
    struct job_row j;
    /* after what the farm queued for the store, as job_event's PREPARE */
    int rc = farm_sync(f, STOREQ_SYNC_MS, &err);
    if (rc == SF_OK)
        rc = store_job_claim_id(f->s, h->name, h->token, id, &j, fence, &err);
    if (rc == SF_OK)
        log_info("host", "%s claimed job %lld", h->name, (long long)id);
    else if (rc != SF_ENOTFOUND)
        log_warn("host", "%s: claim job %lld: %s", h->name, (long long)id, err.msg);
    if (rc == SF_ESTALE)
        h->joined = false; /* the next beat joins again */
    return rc;
}

bool
farm_host_take(struct farm *f, int64_t id)
{
    struct farm_host *h = f->host;
    if (!h)
        return true;
    struct sf_err err;
    int rc = store_job_take(f->s, h->name, h->token, id, NULL, &err);
    if (rc && rc != SF_ENOTFOUND)
        log_warn("host", "%s: take job %lld: %s", h->name, (long long)id, err.msg);
    if (rc == SF_ESTALE)
        h->joined = false;
    return rc == SF_OK;
}

void
farm_host_wake(struct farm *f)
{
    struct sf_err err;
    if (f && f->host && store_host_wake(f->s, &err))
        log_warn("host", "%s: wake the other hosts: %s", f->host->name, err.msg);
}

int
farm_host_hold(struct farm *f, int64_t id, struct sf_err *err)
{
    struct farm_host *h = f->host;
    if (!h)
        return SF_OK;
    if (!h->joined)
        return sf_err_set(err, SF_EAGAIN, "host %s has no lease yet", h->name);
    if (id <= 0)
        return SF_OK;
    int rc = store_job_attach(f->s, h->name, h->token, id, NULL, err);
    if (rc == SF_ESTALE)
        h->joined = false; /* the next beat joins again */
    return rc;
}

void
farm_host_own(struct farm *f)
{
    if (f && f->host && f->host->joined)
        own(f->host);
}
