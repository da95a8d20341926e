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
#include "farm_remote.h"
#include "store_host.h"

struct farm_host {
    struct farm *f;
    struct store *ls; /* the listener's connection */
    char name[STORE_HOST_NAME_MAX];
    int64_t token;     /* this process's, once joined */
    bool joined;       /* the lease is ours */
    bool waiting;      /* a join was refused: say so once, retry at each beat */
    int64_t lease_ms;  /* host_lease_s */
    uint64_t timer;    /* the beat */
    int fd;            /* the listener's socket on the loop, -1 if none */
    int64_t fd_gen;    /* the listener's reconnects (store_host_reconnects) when fd was added */
    uint64_t relisten; /* the listener is lost: timer of its next try, 0 if none */
    bool listen_lost;  /* said so (once until it is back) */
    /* printers of f's config that another live host owns (store_host_own): the scheduler
       leaves them alone; tried again at each beat, taken once that host is gone */
    char (*foreign)[STORE_HOST_NAME_MAX];
    size_t n_foreign;
    /* claims whose COMMIT's answer was lost (SF_EINDOUBT): not claimed again until their
       read-back (store_job_claim_settle, on the store thread) settled them */
    struct doubt *doubts;
    uint64_t resettle; /* a read-back failed: timer of the next round, 0 if none */
    int peers;         /* other live hosts at the last join or beat; -1 if not known */
    /* the reap's grace (on_beat): when this host's current run of renewals began (monotonic
       ms; 0: not renewing, as after a failed beat), its last renewal, and the store
       connection's reconnects then */
    int64_t renewing_since, renewed_at, renew_gen;
    bool doubted; /* a claim, take or hold found the lease not current: the beat decides */
    /* ready jobs this host gave back (farm_host_give_back): not taken here again until
       their time (monotonic ms), so the other hosts have them first */
    struct given {
        int64_t id, until;
    } * given;
    size_t n_given, cap_given;
    uint64_t given_timer; /* a kick when the first of them may be taken here again */
};

/* A claim in doubt, on its way to the store thread's read-back or waiting for another. */
struct doubt {
    struct farm_host *h;
    struct doubt *next;             /* in h->doubts */
    char host[STORE_HOST_NAME_MAX]; /* h's name, for the store thread */
    int64_t id;                     /* the job */
    bool posted;                    /* its read-back is on the store thread */
    bool released;                  /* the claim had committed and was given back */
};

static bool listen_arm(struct farm_host *h);
static void listen_retry(struct farm_host *h);

/* A lost listener is tried again this often: each try advances its connect without waiting
   (store_open_listener), so a few tries bring it back once the server answers. */
#define FARM_HOST_RELISTEN_MS 200

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

/* Was printer p another live host's at the last own()? */
static bool
was_foreign(const struct farm_host *h, const char *p)
{
    for (size_t i = 0; i < h->n_foreign; i++)
        if (strcmp(h->foreign[i], p) == 0)
            return true;
    return false;
}

/* Own f's printers (replacing what the host owned before); those another live host owns are
   left to it, and its scheduler leaves them alone (said once, when it finds one). */
static void
own(struct farm_host *h)
{
    struct farm *f = h->f;
    size_t n = f->n_printers ? f->n_printers : 1;
    const char **names = mem_array(n, sizeof(*names));
    struct store_host_owned *out = mem_array(n, sizeof(*out));
    char(*foreign)[STORE_HOST_NAME_MAX] = mem_array(n, sizeof(*foreign));
    struct sf_err err;
    if (!names || !out || !foreign)
        goto out;
    for (size_t i = 0; i < f->n_printers; i++)
        names[i] = printer_cfg(f->printers[i])->name;
    if (store_host_own(f->s, h->name, h->token, names, f->n_printers, out, &err)) {
        log_error("host", "%s: %s", h->name, err.msg);
        goto out;
    }
    size_t n_foreign = 0;
    for (size_t i = 0; i < f->n_printers; i++) {
        if (out[i].owned) {
            if (was_foreign(h, names[i]))
                log_info("host", "%s: printer '%s' is its own now: scheduling on it", h->name,
                         names[i]);
            continue;
        }
        if (!was_foreign(h, names[i]))
            log_warn("host",
                     "%s: printer '%s' belongs to live host '%s': not scheduling on it here (a "
                     "printer is in one host's config; trying again at each beat)",
                     h->name, names[i], out[i].other);
        snprintf(foreign[n_foreign++], STORE_HOST_NAME_MAX, "%s", names[i]);
    }
    free(h->foreign);
    h->foreign = foreign;
    h->n_foreign = n_foreign;
    foreign = NULL;
out:
    free(names);
    free(out);
    free(foreign);
}

/*
 * The reap's grace.  A host whose lease ran out is reaped by the first
 * other host to notice, but after an outage of the database (a restart,
 * the network to it cut) longer than the lease every lease ran out at
 * once, though no host died: the first host back would reap all the
 * others and end every USB print in the farm.  So a host reaps others only
 * once it has itself renewed its lease without a break for a whole lease
 * (FARM_HOST_BEATS_PER_LEASE beats): every live peer had as long to come
 * back and renew as this host had, and one that did not is dead or cut
 * off.  The run breaks at a failed beat, at a reconnect of the store's
 * connection, and at a gap between two renewals of more than half a lease
 * (a loop stall, or a beat that hung on the network); a new run starts at
 * the join and at the next renewal.  Hosts judge leases by their own wall
 * clocks (store_host.h: NTP); the grace is this host's monotonic clock.
 */
static void
renewed(struct farm_host *h)
{
    int64_t now = clock_mono_ms(), gen = store_host_reconnects(h->f->s);
    if (!h->renewing_since || gen != h->renew_gen || now - h->renewed_at > h->lease_ms / 2)
        h->renewing_since = now;
    h->renewed_at = now;
    h->renew_gen = gen;
}

/* May this host reap the others now (the grace above)? */
static bool
may_reap(const struct farm_host *h)
{
    return h->joined && h->renewing_since && clock_mono_ms() - h->renewing_since >= h->lease_ms;
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
    renewed(h);
    own(h);
    count_peers(h);
    log_info("host", "%s joined (token %lld, lease %.1f s, %zu printers)", h->name,
             (long long)h->token, (double)h->lease_ms / 1000, h->f->n_printers);
    farm_host_wake(h->f); /* the others see the printers; this one schedules */
    farm_kick(h->f);
    for (size_t i = 0; i < h->f->n_printers; i++) /* what waited for the lease (a restart) */
        printer_attach_again(h->f->printers[i]);
}

/* This host's lease is lost (reaped, or its name taken): the reap bumped the fencing token
   of every job it held, so each printer lets its fenced job go at once rather than at its
   next write. */
static void
let_go(struct farm_host *h)
{
    for (size_t i = 0; i < h->f->n_printers; i++) {
        struct printer *p = h->f->printers[i];
        int64_t id = printer_job(p);
        if (id && printer_fence(p, id))
            printer_fenced_out(p, id);
    }
}

static void
on_beat(struct loop *l, void *ud)
{
    struct farm_host *h = ud;
    struct sf_err err;
    h->timer = 0;
    bool doubted = h->doubted;
    h->doubted = false;
    if (!h->joined) {
        join(h);
    } else if (store_host_beat(h->f->s, h->name, h->token, h->lease_ms, &err)) {
        log_error("host", "%s: %s", h->name, err.msg);
        h->renewing_since = 0;       /* the grace starts again at the next renewal */
        if (err.code == SF_ESTALE) { /* reaped: its jobs moved on; join as a new process */
            h->joined = false;
            let_go(h);
            join(h);
        }
    } else {
        renewed(h);
        if (doubted) { /* the lease had only run out, and is renewed: carry on */
            log_info("host", "%s: its lease is renewed (it had run out, nobody reaped it)",
                     h->name);
            farm_kick(h->f);
            for (size_t i = 0; i < h->f->n_printers; i++)
                printer_attach_again(h->f->printers[i]);
        }
        if (h->n_foreign) { /* their owner may be gone: own them again */
            own(h);
            if (!h->n_foreign)
                farm_kick(h->f);
        }
    }
    struct store_recovery moved;
    int n = may_reap(h) ? store_host_reap(h->f->s, clock_wall_ms(), &moved, &err) : 0;
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
    h->timer = loop_timer_add(l, h->lease_ms / FARM_HOST_BEATS_PER_LEASE, on_beat, h);
}

/* A claim, take or hold found this host's lease not current (SF_ESTALE).  That is not yet a
   reap: a lease that only ran out (the database away longer than the lease, a stalled loop)
   and that nobody reaped is renewed by the beat, and the host carries on, its prints
   untouched; only a beat that finds the lease lost (reaped: its token moved on, or the name
   another process's) lets go of them and joins again.  So beat now, and let it decide. */
static void
lease_doubted(struct farm_host *h)
{
    if (!h->joined || h->doubted)
        return;
    h->doubted = true;
    if (h->timer)
        loop_timer_cancel(h->f->l, h->timer);
    h->timer = loop_timer_add(h->f->l, 0, on_beat, h);
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
    if (n >= 0 && store_host_reconnects(h->ls) == h->fd_gen &&
        store_host_notify_fd(h->ls) == h->fd) {
        if (n > 0)
            farm_kick(h->f);
        return;
    }
    /* lost, or back already on a new session whose socket is a new one (perhaps under the
       old number, which epoll dropped when the old socket closed): watch it again, or try
       again shortly.  Dropped at once: the number is still this registration's. */
    listen_drop(h);
    if (!listen_arm(h))
        listen_retry(h);
}

static void
on_relisten(struct loop *l, void *ud)
{
    (void)l;
    struct farm_host *h = ud;
    h->relisten = 0;
    if (!listen_arm(h))
        listen_retry(h);
}

/* Try the lost listener again in FARM_HOST_RELISTEN_MS (saying so once). */
static void
listen_retry(struct farm_host *h)
{
    if (!h->listen_lost)
        log_warn("host", "%s: the wake-up connection is lost; trying again every %d ms", h->name,
                 FARM_HOST_RELISTEN_MS);
    h->listen_lost = true;
    if (!h->relisten)
        h->relisten = loop_timer_add(h->f->l, FARM_HOST_RELISTEN_MS, on_relisten, h);
}

/* Watch the listener's socket (again): drain first, which advances the reconnect of a lost
   connection (never waiting).  False while it is not back. */
static bool
listen_arm(struct farm_host *h)
{
    struct sf_err err;
    if (store_host_drain(h->ls) < 0)
        return false;
    int fd = store_host_notify_fd(h->ls);
    if (fd < 0)
        return false;
    if (loop_add_fd(h->f->l, fd, LOOP_READ, on_note, h, &err)) {
        log_warn("host", "%s: %s", h->name, err.msg);
        return false;
    }
    h->fd = fd;
    h->fd_gen = store_host_reconnects(h->ls);
    if (h->listen_lost)
        log_info("host", "%s: the wake-up connection is back", h->name);
    h->listen_lost = false;
    farm_kick(h->f); /* what arrived while it was away */
    return true;
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
    if (!(h->ls = store_open_listener(f->s, err)) || store_host_listen(h->ls, err)) {
        sf_err_prefix(err, "host %s: wake-up connection", h->name);
        return err->code;
    }
    if (!listen_arm(h))
        listen_retry(h);
    join(h);
    h->timer = loop_timer_add(f->l, h->lease_ms / FARM_HOST_BEATS_PER_LEASE, on_beat, h);
    return farm_remote_start(f, err); /* actions on printers other hosts own */
}

void
farm_host_stop(struct farm *f)
{
    struct farm_host *h = f ? f->host : NULL;
    if (!h)
        return;
    if (h->timer)
        loop_timer_cancel(f->l, h->timer);
    if (h->relisten)
        loop_timer_cancel(f->l, h->relisten);
    if (h->resettle)
        loop_timer_cancel(f->l, h->resettle);
    if (h->given_timer)
        loop_timer_cancel(f->l, h->given_timer);
    /* a claim still in doubt: the store thread's queue ran (farm_free), so none is posted;
       the leave below reaps this host, which gives such a job back */
    for (struct doubt *d = h->doubts, *next; d; d = next) {
        next = d->next;
        log_warn("host", "%s: job %lld: its claim is still in doubt at the stop", h->name,
                 (long long)d->id);
        free(d);
    }
    listen_drop(h);
    struct sf_err err;
    if (h->joined) {
        /* leave: the lease ends now and this host reaps itself (itself only: the others'
           leases are the reap's, after its grace), so its waiting work moves on at once (its
           prints are interrupted already: farm_free) */
        struct store_recovery moved;
        if (store_host_leave(f->s, h->name, h->token, &moved, &err))
            log_warn("host", "%s: leave: %s", h->name, err.msg);
        else
            log_info("host", "%s left: %d jobs back in the queue", h->name, moved.requeued);
        farm_host_wake(f);
    }
    store_close(h->ls);
    free(h->foreign);
    free(h->given);
    free(h);
    f->host = NULL;
}

const char *
farm_host_name(const struct farm *f)
{
    return f && f->host ? f->host->name : "";
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

int64_t
farm_host_token(const struct farm *f)
{
    return f->host && f->host->joined ? f->host->token : 0;
}

static void settle(struct farm_host *h);

static int
settle_call(struct store *s, void *arg, struct sf_err *err)
{
    struct doubt *d = arg;
    return store_job_claim_settle(s, d->host, d->id, &d->released, err);
}

static void
on_resettle(struct loop *l, void *ud)
{
    (void)l;
    struct farm_host *h = ud;
    h->resettle = 0;
    settle(h);
}

/* A read-back came back: the job is settled (claimable again), or asked again later. */
static void
on_settled(void *ud, const struct storeq_result *r)
{
    struct doubt *d = ud;
    struct farm_host *h = d->h;
    d->posted = false;
    if (r->rc) {
        log_warn("host", "%s: job %lld: reading back its claim: %s (trying again)", h->name,
                 (long long)d->id, r->err->msg);
        if (!h->resettle)
            h->resettle = loop_timer_add(h->f->l, FARM_RETRY_MS, on_resettle, h);
        return;
    }
    log_info("host", "%s: job %lld: its claim in doubt %s", h->name, (long long)d->id,
             d->released ? "had committed: given back to the queue" : "did not commit");
    for (struct doubt **pp = &h->doubts; *pp; pp = &(*pp)->next)
        if (*pp == d) {
            *pp = d->next;
            break;
        }
    free(d);
    farm_kick(h->f); /* claimable again, by this host too */
}

/* Post the read-back of every claim in doubt not on its way yet. */
static void
settle(struct farm_host *h)
{
    for (struct doubt *d = h->doubts; d; d = d->next) {
        if (d->posted)
            continue;
        if (storeq_call(h->f->q, settle_call, d, NULL, on_settled, d)) {
            if (!h->resettle) /* out of memory: later */
                h->resettle = loop_timer_add(h->f->l, FARM_RETRY_MS, on_resettle, h);
            return;
        }
        d->posted = true;
    }
}

/* Is the claim of job id in doubt (its read-back not back yet)? */
static bool
in_doubt(const struct farm_host *h, int64_t id)
{
    for (const struct doubt *d = h->doubts; d; d = d->next)
        if (d->id == id)
            return true;
    return false;
}

/* A claim, take or give-back on its way to the store thread (farm_host_claim, farm_host_take,
   give_back): what the thread needs, copied; what it answers; whom to tell. */
struct hask {
    struct farm_host *h;
    enum { ASK_CLAIM, ASK_TAKE, ASK_GIVE } op;
    char host[STORE_HOST_NAME_MAX]; /* h's name and token when posted */
    int64_t token, id, fence;       /* the job; a give-back's token, a claim's or take's answer */
    bool bar;                       /* a give-back: not taken here again for a lease */
    bool ran;                       /* a claim or take ran: rc and err are its answer */
    int rc;
    struct sf_err err;
    char why[256];      /* a give-back's */
    struct job_row job; /* a claim's: the job as claimed */
    farm_host_answer_fn done;
    void *ud;
};

/* On the store thread.  A claim or take that failed in passing (busy, unreachable) or whose
   commit is in doubt is answered as it is, not tried again or read back here: the loop does
   what it did with the synchronous call's answer (a claim in doubt is settled, a take in
   doubt taken again by a later pass, whose new token it needs; busy: a later pass).  A
   give-back is an ordinary write: retried, and read back when in doubt. */
static int
ask_call(struct store *s, void *arg, struct sf_err *err)
{
    struct hask *a = arg;
    a->err = (struct sf_err){ 0 };
    if (a->op == ASK_GIVE)
        return store_job_give_back(s, a->host, a->id, a->fence, a->why, err);
    a->rc = a->op == ASK_CLAIM
                ? store_job_claim_id(s, a->host, a->token, a->id, &a->job, &a->fence, &a->err)
                : store_job_take(s, a->host, a->token, a->id, &a->fence, &a->err);
    a->ran = true;
    *err = a->err;
    if (a->rc == SF_EBUSY || a->rc == SF_EUNREACH || a->rc == SF_EINDOUBT)
        return sf_err_set(err, SF_EAGAIN, "%s", a->err.msg); /* the loop's to handle */
    return a->rc;
}

static void settle(struct farm_host *h);

/* Drop job id from the ones given back (a give-back that failed: it is still this host's). */
static void
given_drop(struct farm_host *h, int64_t id)
{
    for (size_t i = 0; i < h->n_given; i++)
        if (h->given[i].id == id) {
            h->given[i] = h->given[--h->n_given];
            return;
        }
}

/* A claim of a's came back: logged; one in doubt is read back (settle); a lost lease makes the
   host beat.  Not at the stop: the leave reaps this host, giving such a job back. */
static void
claim_answered(struct farm_host *h, struct hask *a, int rc, const char *msg)
{
    if (rc == SF_OK)
        log_info("host", "%s claimed job %lld", h->name, (long long)a->id);
    else if (rc != SF_ENOTFOUND)
        log_warn("host", "%s: claim job %lld: %s", h->name, (long long)a->id, msg);
    if (h->f->stopping)
        return;
    struct doubt *d = rc == SF_EINDOUBT ? mem_calloc(1, sizeof(*d)) : NULL;
    if (d) {
        /* it may have committed: the job would be this host's, preparing, and prepared by
           no one.  Read back on the store thread, and give it back if so. */
        *d = (struct doubt){ .h = h, .next = h->doubts, .id = a->id };
        snprintf(d->host, sizeof(d->host), "%s", h->name);
        h->doubts = d;
        settle(h);
    }
    if (rc == SF_ESTALE)
        lease_doubted(h); /* the beat renews it, or joins again if it was reaped */
}

static void
on_asked(void *ud, const struct storeq_result *r)
{
    struct hask *a = ud;
    struct farm_host *h = a->h;
    /* a claim's or take's own answer, unless it never ran (the stop's window spent) */
    int rc = a->ran ? a->rc : r->rc;
    const char *msg = a->ran ? a->err.msg : r->rc ? r->err->msg : "";
    if (rc)
        a->fence = 0;
    if (a->op == ASK_CLAIM) {
        claim_answered(h, a, rc, msg);
    } else if (a->op == ASK_TAKE) {
        if (rc && rc != SF_ENOTFOUND)
            log_warn("host", "%s: take job %lld: %s", h->name, (long long)a->id, msg);
        if (rc == SF_ESTALE && !h->f->stopping)
            lease_doubted(h);
    } else if (rc) {
        log_warn("host", "%s: job %lld: %s", h->name, (long long)a->id, msg);
        if (a->bar)
            given_drop(h, a->id); /* still this host's: taken here again, as before */
        if (rc == SF_ESTALE && !h->f->stopping)
            lease_doubted(h);
    } else if (a->bar) {
        log_warn("host",
                 "%s gave job %lld back for the other hosts (it cannot start it here: %s); taken "
                 "here again in %.1f s at the earliest",
                 h->name, (long long)a->id, a->why, (double)h->lease_ms / 1000);
    } else {
        log_warn("host", "%s gave job %lld back (not started: %s)", h->name, (long long)a->id,
                 a->why);
    }
    if (a->done)
        a->done(a->ud, rc, a->fence, a->op == ASK_CLAIM && rc == SF_OK ? &a->job : NULL);
    free(a);
}

/* Post a (its op, id and fence set) with h's name and token; SF_OK, or SF_ENOMEM (a freed). */
static int
ask_post(struct farm_host *h, struct hask *a, farm_host_answer_fn done, void *ud)
{
    a->h = h;
    snprintf(a->host, sizeof(a->host), "%s", h->name);
    a->token = h->token;
    a->done = done;
    a->ud = ud;
    int rc = storeq_call(h->f->q, ask_call, a, NULL, on_asked, a);
    if (rc)
        free(a);
    return rc;
}

int
farm_host_claim(struct farm *f, int64_t id, farm_host_answer_fn done, void *ud)
{
    struct farm_host *h = f->host;
    if (in_doubt(h, id))
        return SF_ENOTFOUND; /* not again until its last claim is settled */
    struct hask *a = mem_calloc(1, sizeof(*a));
    if (!a)
        return SF_ENOMEM;
    /* on the store thread after what the farm queued before it (its events) */
    a->op = ASK_CLAIM;
    a->id = id;
    return ask_post(h, a, done, ud);
}

/* Did this host give job id back lately (forgetting those whose time passed)? */
static bool
given_back(struct farm_host *h, int64_t id)
{
    int64_t now = clock_mono_ms();
    bool found = false;
    for (size_t i = 0; i < h->n_given;) {
        if (h->given[i].until <= now) {
            h->given[i] = h->given[--h->n_given];
            continue;
        }
        found |= h->given[i].id == id;
        i++;
    }
    return found;
}

static void
on_given_timer(struct loop *l, void *ud)
{
    struct farm_host *h = ud;
    h->given_timer = 0;
    farm_kick(h->f); /* what it gave back may be taken here again, if no other host took it */
    /* and again when the next of those still barred may be: one given back after the first
       would otherwise wait for some other kick, perhaps forever */
    (void)given_back(h, 0); /* forgets those whose time passed */
    int64_t next = 0;
    for (size_t i = 0; i < h->n_given; i++)
        if (!next || h->given[i].until < next)
            next = h->given[i].until;
    if (next) {
        int64_t wait = next - clock_mono_ms();
        h->given_timer = loop_timer_add(l, wait > 0 ? wait : 0, on_given_timer, h);
    }
}

/* Give back job id (taken under fence) on the store thread; bar: f does not take it again for
   a lease (from now: a pass meanwhile must not take it again; dropped if it fails). */
static int
give_back(struct farm *f, int64_t id, int64_t fence, const char *why, bool bar,
          farm_host_answer_fn done, void *ud)
{
    struct farm_host *h = f->host;
    struct hask *a = mem_calloc(1, sizeof(*a));
    if (!a)
        return SF_ENOMEM;
    a->op = ASK_GIVE;
    a->id = id;
    a->fence = fence;
    a->bar = bar;
    snprintf(a->why, sizeof(a->why), "%s", why ? why : "");
    int rc = ask_post(h, a, done, ud);
    if (rc || !bar)
        return rc;
    if (mem_grow((void **)&h->given, &h->cap_given, h->n_given + 1, sizeof(*h->given)))
        h->given[h->n_given++] = (struct given){ id, clock_mono_ms() + h->lease_ms };
    if (!h->given_timer)
        h->given_timer = loop_timer_add(f->l, h->lease_ms, on_given_timer, h);
    return SF_OK;
}

void
farm_host_give_back(struct farm *f, int64_t id, int64_t fence, const char *why)
{
    if (f && f->host && give_back(f, id, fence, why, true, NULL, NULL))
        log_warn("host", "%s: job %lld: not given back: out of memory", f->host->name,
                 (long long)id);
}

int
farm_host_release(struct farm *f, int64_t id, int64_t fence, const char *why,
                  farm_host_answer_fn done, void *ud)
{
    return give_back(f, id, fence, why, false, done, ud);
}

int
farm_host_take(struct farm *f, int64_t id, farm_host_answer_fn done, void *ud)
{
    struct farm_host *h = f->host;
    if (given_back(h, id))
        return SF_ENOTFOUND; /* the other hosts first; on_given_timer kicks the farm */
    struct hask *a = mem_calloc(1, sizeof(*a));
    if (!a)
        return SF_ENOMEM;
    a->op = ASK_TAKE;
    a->id = id;
    return ask_post(h, a, done, ud);
}

void
farm_host_wake(struct farm *f)
{
    struct sf_err err;
    if (f && f->host && store_host_wake(f->s, &err))
        log_warn("host", "%s: wake the other hosts: %s", f->host->name, err.msg);
}

void
farm_host_own(struct farm *f)
{
    if (f && f->host && f->host->joined)
        own(f->host);
}

bool
farm_host_owns(const struct farm *f, const char *printer)
{
    const struct farm_host *h = f ? f->host : NULL;
    return !h || !was_foreign(h, printer);
}

int
farm_host_hold(void *ud, int64_t id, int64_t *fence, struct sf_err *err)
{
    struct farm *f = ud;
    struct farm_host *h = f->host;
    *fence = 0;
    if (!h)
        return SF_OK;
    if (!h->joined)
        return sf_err_set(err, SF_EAGAIN, "host %s has no lease yet", h->name);
    if (id <= 0)
        return SF_OK;
    /* after what the farm queued for the store (the job's CRASHED, say) */
    int rc = farm_sync(f, STOREQ_SYNC_MS, err);
    if (rc == SF_OK)
        rc = store_job_attach(f->s, h->name, h->token, id, fence, err);
    if (rc == SF_OK)
        log_info("host", "%s holds job %lld (fencing token %lld)", h->name, (long long)id,
                 (long long)*fence);
    else
        sf_err_prefix(err, "host %s: hold job %lld", h->name, (long long)id);
    if (rc == SF_ESTALE)
        lease_doubted(h);
    return rc;
}
