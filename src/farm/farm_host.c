/*
 * farm_host.c - the farm as one of several hosts on one store (farm_host.h):
 * the join, the beat and the reap on a loop timer, and the LISTEN
 * connection on the loop's epoll (the claims the scheduling pass makes:
 * farm_host_ask.c; the state both share: farm_host_int.h).
 *
 * Why the beat and the reap share one timer: both are one short statement
 * each a few seconds, and the reap is idempotent, so every host running it
 * is harmless (the first one in moves the work).  They run, with the join
 * and the printers' own, on a store thread and connection of the beat's
 * own (h->bq, a storeq of its own), never on the loop's: the loop must not
 * wait on the network, and the farm's store thread is no place for them
 * either, since a request there that fails with nothing applied holds its
 * queue for up to STOREQ_RETRY_MS (60 s, two leases) and a silent partition
 * holds each request for the connection's tcp_user_timeout (10 s): a beat
 * behind a queue of progress writes could miss its lease and have this host
 * reaped by the others.  The join locks the host's name to the connection
 * it runs on (store_host_join), so the beat's connection is also the one
 * that holds the name.  One beat is in flight at a time; what it found is
 * applied on the loop when it comes back (on_beat_done).
 * The listener has a connection of its own (sqldb.h: a notification that
 * arrives while another call runs on a connection does not wake its fd).
 *
 * Thread: the loop thread (beat_call on the beat's store thread).
 */
#include "farm_host.h"
#include "farm_host_int.h"

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
farm_host_beat_stats(const struct farm *f, struct storeq_stats *out)
{
    if (!farm_host_on(f) || !f->host->bq)
        return false;
    storeq_stats(f->host->bq, out);
    return true;
}

bool
farm_host_alone(const struct farm *f)
{
    return !farm_host_on(f) || (f->host->joined && f->host->peers == 0);
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

/* Is printer p one of the n names (a list the last own() left: foreign or mine)? */
static bool
listed(char (*names)[STORE_HOST_NAME_MAX], size_t n, const char *p)
{
    for (size_t i = 0; i < n; i++)
        if (strcmp(names[i], p) == 0)
            return true;
    return false;
}

/* Was printer p another live host's at the last own()? */
static bool
was_foreign(const struct farm_host *h, const char *p)
{
    return listed(h->foreign, h->n_foreign, p);
}

/* One beat on the beat's store thread: what it needs, copied (nothing points into the loop's
   state), and what it found, applied on the loop by on_beat_done. */
struct beat {
    struct farm_host *h;
    /* in */
    char name[STORE_HOST_NAME_MAX];
    int64_t lease_ms;
    bool doubted;                       /* h->doubted when it was posted */
    bool own;                           /* own the printers (names), after a renewal too */
    bool publish;                       /* publish preps (after an own that came back too) */
    char (*names)[STORE_HOST_NAME_MAX]; /* f's printers when it was posted */
    const char **ptrs;                  /* into names, for store_host_own */
    struct store_printer_prep *preps;   /* n: what preparing for them needs, published */
    size_t n;
    /* in and out: the lease, and the reap's grace (renewed) */
    int64_t token;
    bool joined;
    int64_t since, at, gen;
    /* out */
    bool beat, lost, join; /* renewed (or tried to), found the lease lost, joined (or tried) */
    int beat_rc, join_rc, own_rc, publish_rc, reaped, wake_rc, peers_rc, peers;
    struct sf_err beat_err, join_err, own_err, publish_err, reap_err, wake_err, peers_err;
    struct store_host_owned *out; /* n: what own found */
    struct store_recovery moved;
};

static void
beat_free(struct beat *b)
{
    if (!b)
        return;
    free(b->names);
    free(b->ptrs);
    free(b->preps);
    free(b->out);
    free(b);
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
 * off.  The run breaks at a failed beat, at a reconnect of the beat's
 * connection, and at a gap between two renewals of more than half a lease
 * (a loop stall, or a beat that hung on the network); a new run starts at
 * the join and at the next renewal.  Hosts judge leases by their own wall
 * clocks (store_host.h: NTP); the grace is this host's monotonic clock.
 * Kept in the beat (b) on the beat's thread: it is the thread's renewal that
 * starts or continues a run, and its reap that the grace allows.
 */
static void
renewed(struct beat *b, int64_t gen)
{
    int64_t now = clock_mono_ms();
    if (!b->since || gen != b->gen || now - b->at > b->lease_ms / 2)
        b->since = now;
    b->at = now;
    b->gen = gen;
}

/* May this host reap the others now (the grace above)? */
static bool
may_reap(const struct beat *b)
{
    return b->joined && b->since && clock_mono_ms() - b->since >= b->lease_ms;
}

/* The beat, on the beat's thread with its connection s: renew the lease (join if there is none,
   or it was lost), own the printers if asked (always after a join), reap once the grace
   allows, wake the other hosts if that moved anything, count them.  Each step's outcome goes
   into b for the loop; the call itself always succeeds (nothing is retried: the next beat
   is the retry). */
static int
beat_call(struct store *s, void *arg, struct sf_err *err)
{
    (void)err;
    struct beat *b = arg;
    if (b->joined) {
        b->beat = true;
        b->beat_rc = store_host_beat(s, b->name, b->token, b->lease_ms, &b->beat_err);
        if (b->beat_rc == SF_OK) {
            renewed(b, store_host_reconnects(s));
        } else {
            b->since = 0;                /* the grace starts again at the next renewal */
            if (b->beat_rc == SF_ESTALE) /* reaped: its jobs moved on; join as a new process */
                b->lost = true, b->joined = false;
        }
    }
    if (!b->joined) {
        b->join = true;
        b->join_rc = store_host_join(s, b->name, b->lease_ms, &b->token, &b->join_err);
        if (b->join_rc == SF_OK) {
            b->joined = true;
            b->own = true;
            renewed(b, store_host_reconnects(s));
        }
    }
    if (b->joined && b->own)
        b->own_rc = store_host_own(s, b->name, b->token, b->ptrs, b->n, b->out, &b->own_err);
    /* and publish what preparing for them needs, for the hosts with spare cores (its own
       outcome: a failed publish is tried again, and never undoes the own) */
    b->publish = b->joined && (b->own || b->publish) && b->own_rc == SF_OK;
    if (b->publish)
        b->publish_rc = store_host_publish(s, b->name, b->token, b->preps, b->n, &b->publish_err);
    b->reaped = may_reap(b) ? store_host_reap(s, clock_wall_ms(), &b->moved, &b->reap_err) : 0;
    /* the others see the printers of a join, and the jobs a reap moved */
    if ((b->join && b->join_rc == SF_OK) || b->reaped > 0)
        b->wake_rc = store_host_wake(s, &b->wake_err);
    if (b->joined)
        b->peers_rc = store_host_peers(s, b->name, clock_wall_ms(), &b->peers, &b->peers_err);
    return SF_OK;
}

/* Is printer p one this host owned at the last own that came back? */
static bool
is_mine(const struct farm_host *h, const char *p)
{
    return listed(h->mine, h->n_mine, p);
}

/* What b's own found: the printers another live host owns are left to it, and the scheduler
   leaves them alone (said once, when it finds one). */
static void
owned(struct farm_host *h, struct beat *b)
{
    if (b->own_rc) {
        log_error("host", "%s: %s", h->name, b->own_err.msg);
        h->reown = true; /* the next beat tries again */
        return;
    }
    size_t n = b->n ? b->n : 1;
    char(*foreign)[STORE_HOST_NAME_MAX] = mem_array(n, sizeof(*foreign));
    char(*mine)[STORE_HOST_NAME_MAX] = mem_array(n, sizeof(*mine));
    if (!foreign || !mine) {
        free(foreign);
        free(mine);
        h->reown = true;
        return;
    }
    size_t n_foreign = 0, n_mine = 0;
    for (size_t i = 0; i < b->n; i++) {
        const char *name = b->names[i];
        if (b->out[i].owned) {
            if (was_foreign(h, name))
                log_info("host", "%s: printer '%s' is its own now: scheduling on it", h->name,
                         name);
            snprintf(mine[n_mine++], STORE_HOST_NAME_MAX, "%s", name);
            continue;
        }
        if (!was_foreign(h, name))
            log_warn("host",
                     "%s: printer '%s' belongs to live host '%s': not scheduling on it here (a "
                     "printer is in one host's config; trying again at each beat)",
                     h->name, name, b->out[i].other);
        snprintf(foreign[n_foreign++], STORE_HOST_NAME_MAX, "%s", name);
    }
    bool freed = h->n_foreign && !n_foreign;
    free(h->foreign);
    h->foreign = foreign;
    h->n_foreign = n_foreign;
    free(h->mine);
    h->mine = mine;
    h->n_mine = n_mine;
    if (!h->reown)
        h->owning = false; /* no reload since: its printers are known */
    if (freed)
        farm_kick(h->f);
}

static void on_beat(struct loop *l, void *ud);

/* Beat again now (or as soon as the beat in flight is back). */
static void
beat_now(struct farm_host *h)
{
    if (h->beating) {
        h->beat_due = true;
        return;
    }
    if (h->timer)
        loop_timer_cancel(h->f->l, h->timer);
    h->timer = loop_timer_add(h->f->l, 0, on_beat, h);
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

/* After a join, or a doubted lease renewed: offer each printer its job again (what waited
   for the lease; a print that ended while this host was away is recorded).  The offers read
   and hold on the farm's store thread (printer_attach.c, printer_op.c), never on the loop's
   connection, which after an outage reconnects only as it is used: nothing here waits for
   it. */
static void
reoffer(struct farm_host *h)
{
    if (!h->joined)
        return; /* lost again: the next join offers them */
    for (size_t i = 0; i < h->f->n_printers; i++)
        printer_attach_again(h->f->printers[i]);
}

/* b came back: the loop's view of the lease follows what the beat's thread found. */
static void
on_beat_done(void *ud, const struct storeq_result *r)
{
    (void)r; /* beat_call always succeeds: each step's outcome is in b */
    struct beat *b = ud;
    struct farm_host *h = b->h;
    h->beating = false;
    h->joined = b->joined;
    h->token = b->token;
    h->renewing_since = b->since;
    h->renewed_at = b->at;
    h->renew_gen = b->gen;
    if (h->stopping) { /* farm_host_stop: the leave needs the lease, nothing else */
        beat_free(b);
        return;
    }
    if (b->beat && b->beat_rc)
        log_error("host", "%s: %s", h->name, b->beat_err.msg);
    if (b->lost)
        let_go(h);
    if (b->join && b->join_rc) {
        if (!h->waiting || b->join_rc != SF_EAGAIN)
            log_warn("host", "%s: cannot join yet: %s (trying again every %lld ms)", h->name,
                     b->join_err.msg, (long long)(h->lease_ms / FARM_HOST_BEATS_PER_LEASE));
        h->waiting = true;
    }
    if (b->joined && b->own)
        owned(h, b);
    if (b->publish && b->publish_rc) {
        log_warn("host", "%s: %s (publishing again at the next beat)", h->name, b->publish_err.msg);
        h->republish = true;
    }
    if (b->join && b->join_rc == SF_OK) {
        h->waiting = false;
        log_info("host", "%s joined (token %lld, lease %.1f s, %zu printers)", h->name,
                 (long long)h->token, (double)h->lease_ms / 1000, h->f->n_printers);
    } else if (b->doubted && b->beat && b->beat_rc == SF_OK) {
        /* the lease had only run out, and is renewed: carry on */
        log_info("host", "%s: its lease is renewed (it had run out, nobody reaped it)", h->name);
    }
    if ((b->join && b->join_rc == SF_OK) || (b->doubted && b->beat && b->beat_rc == SF_OK)) {
        farm_kick(h->f); /* this one schedules */
        reoffer(h);      /* what waited for the lease */
    }
    if (b->reaped < 0) {
        log_warn("host", "reap: %s", b->reap_err.msg);
    } else if (b->reaped > 0) {
        log_warn("host",
                 "reaped %d hosts whose lease ran out: %d jobs back in the queue, %d "
                 "interrupted",
                 b->reaped, b->moved.requeued, b->moved.interrupted);
        farm_kick(h->f);
    }
    if (b->wake_rc)
        log_warn("host", "%s: wake the other hosts: %s", h->name, b->wake_err.msg);
    if (b->joined && b->peers_rc)
        log_warn("host", "%s: %s", h->name, b->peers_err.msg);
    if (b->joined)
        h->peers = b->peers_rc ? -1 : b->peers;
    beat_free(b);
    if (h->beat_due) {
        h->beat_due = false;
        beat_now(h);
    }
}

/* Post a beat of h (its lease, printers and grace copied) to the beat's thread. */
static int
beat_post(struct farm_host *h)
{
    struct farm *f = h->f;
    struct beat *b = mem_calloc(1, sizeof(*b));
    size_t n = f->n_printers ? f->n_printers : 1;
    if (!b || !(b->names = mem_array(n, sizeof(*b->names))) ||
        !(b->ptrs = mem_array(n, sizeof(*b->ptrs))) || !(b->out = mem_array(n, sizeof(*b->out))) ||
        !(b->preps = mem_array(n, sizeof(*b->preps))))
        goto fail;
    b->h = h;
    b->lease_ms = h->lease_ms;
    b->doubted = h->doubted;
    b->own = h->reown || h->n_foreign; /* a reload; or their owner may be gone */
    b->publish = h->republish;         /* the last publish failed */
    b->n = f->n_printers;
    b->token = h->token;
    b->joined = h->joined;
    b->since = h->renewing_since;
    b->at = h->renewed_at;
    b->gen = h->renew_gen;
    snprintf(b->name, sizeof(b->name), "%s", h->name);
    for (size_t i = 0; i < f->n_printers; i++) {
        snprintf(b->names[i], STORE_HOST_NAME_MAX, "%s", printer_cfg(f->printers[i])->name);
        b->ptrs[i] = b->names[i];
        farm_spare_publish(printer_cfg(f->printers[i]), &b->preps[i]);
    }
    if (storeq_read(h->bq, beat_call, b, on_beat_done, b))
        goto fail;
    h->beating = true;
    h->doubted = false;
    h->reown = false;
    h->republish = false;
    return SF_OK;
fail:
    beat_free(b);
    log_error("host", "%s: out of memory: beating again later", h->name);
    return SF_ENOMEM;
}

/* The beat's timer: a beat every third of the lease, one at a time (one still in flight, a
   call that hangs on the network, is followed by the next at once when it comes back). */
static void
on_beat(struct loop *l, void *ud)
{
    struct farm_host *h = ud;
    h->timer = 0;
    if (h->beating)
        h->beat_due = true;
    else
        beat_post(h);
    h->timer = loop_timer_add(l, h->lease_ms / FARM_HOST_BEATS_PER_LEASE, on_beat, h);
}

/* A claim, take or hold found this host's lease not current (SF_ESTALE).  That is not yet a
   reap: a lease that only ran out (the database away longer than the lease, a stalled loop)
   and that nobody reaped is renewed by the beat, and the host carries on, its prints
   untouched; only a beat that finds the lease lost (reaped: its token moved on, or the name
   another process's) lets go of them and joins again.  So beat now, and let it decide. */
void
farm_host_lease_doubted(struct farm_host *h)
{
    if (!h->joined || h->doubted)
        return;
    h->doubted = true;
    beat_now(h);
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
    if (!(h->bq = storeq_new(f->l, f->s, err))) {
        sf_err_prefix(err, "host %s: the beat's connection", h->name);
        return err->code;
    }
    on_beat(f->l, h); /* the join, on the beat's thread; the loop goes on meanwhile */
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
    /* a beat still in flight comes back here (on_beat_done records the lease only), and the
       beat's connection closes: the name's lock goes with it, while its lease still runs */
    h->stopping = true;
    storeq_free(h->bq);
    h->bq = NULL;
    if (h->relisten)
        loop_timer_cancel(f->l, h->relisten);
    farm_host_ask_stop(h); /* its timers, and the claims still in doubt */
    listen_drop(h);
    struct sf_err err;
    if (h->joined) {
        /* leave: the lease ends now and this host reaps itself (itself only: the others'
           leases are the reap's, after its grace), so its waiting work moves on at once (its
           prints are interrupted already: farm_free).  On the loop's connection, waiting:
           at the stop the printers are stopped and the store thread's queue has run, so
           nothing waits behind it. */
        struct store_recovery moved;
        if (store_host_leave(f->s, h->name, h->token, &moved, &err))
            log_warn("host", "%s: leave: %s", h->name, err.msg);
        else
            log_info("host", "%s left: %d jobs back in the queue", h->name, moved.requeued);
        farm_host_wake(f);
    }
    store_close(h->ls);
    free(h->foreign);
    free(h->mine);
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
    struct farm_host *h = f ? f->host : NULL;
    if (!h)
        return;
    /* on the beat's thread (a join owns them anyway); a printer new to this host is not
       scheduled on until the answer says it is its own */
    h->reown = true;
    h->owning = true;
    if (h->joined)
        beat_now(h);
}

bool
farm_host_owns(const struct farm *f, const char *printer)
{
    const struct farm_host *h = f ? f->host : NULL;
    return !h || (!was_foreign(h, printer) && (!h->owning || is_mine(h, printer)));
}

/* Whether a hold must go to the store (*go): not on one host (nothing to hold against) nor for
   no job; SF_EAGAIN before this host has a lease. */
static int
hold_gate(const struct farm_host *h, int64_t id, bool *go, struct sf_err *err)
{
    *go = false;
    if (!h)
        return SF_OK;
    if (!h->joined)
        return sf_err_set(err, SF_EAGAIN, "host %s has no lease yet", h->name);
    *go = id > 0;
    return SF_OK;
}

int
farm_host_hold(void *ud, int64_t id, int64_t *fence, struct sf_err *err)
{
    struct farm *f = ud;
    struct farm_host *h = f->host;
    *fence = 0;
    bool go;
    int rc = hold_gate(h, id, &go, err);
    if (rc || !go)
        return rc;
    /* after what the farm queued for the store (the job's CRASHED, say) */
    rc = farm_sync(f, STOREQ_SYNC_MS, err);
    if (rc == SF_OK)
        rc = store_job_attach(f->s, h->name, h->token, id, fence, err);
    if (rc == SF_OK)
        log_info("host", "%s holds job %lld (fencing token %lld)", h->name, (long long)id,
                 (long long)*fence);
    else
        sf_err_prefix(err, "host %s: hold job %lld", h->name, (long long)id);
    if (rc == SF_ESTALE)
        farm_host_lease_doubted(h);
    return rc;
}

/* A hold on the farm's store thread (farm_host_hold_ask): what it needs, copied. */
struct hold_ask {
    struct farm *f;
    char name[STORE_HOST_NAME_MAX];
    char printer[64];
    int64_t token, id, fence;
    void (*done)(void *ud, int rc, int64_t fence, const struct sf_err *err);
    void *ud;
};

static int
hold_call(struct store *s, void *arg, struct sf_err *err)
{
    struct hold_ask *a = arg;
    return store_job_reattach(s, a->name, a->token, a->id, a->printer, &a->fence, err);
}

static void
on_held(void *ud, const struct storeq_result *r)
{
    struct hold_ask *a = ud;
    struct farm_host *h = a->f->host; /* alive: the farm's queue is freed before the host */
    struct sf_err err = { 0 };
    if (r->rc && r->err)
        err = *r->err;
    if (r->rc == SF_OK) {
        log_info("host", "%s holds job %lld (fencing token %lld)", a->name, (long long)a->id,
                 (long long)a->fence);
    } else {
        sf_err_prefix(&err, "host %s: hold job %lld", a->name, (long long)a->id);
        /* a lease this host held when it asked (not one it lost and joined again since) */
        if (r->rc == SF_ESTALE && h && h->joined && h->token == a->token)
            farm_host_lease_doubted(h);
    }
    a->done(a->ud, r->rc, r->rc ? 0 : a->fence, &err);
    free(a);
}

int
farm_host_hold_ask(void *ud, int64_t id, const char *printer, bool *posted,
                   void (*done)(void *ud, int rc, int64_t fence, const struct sf_err *err),
                   void *dud, struct sf_err *err)
{
    struct farm *f = ud;
    struct farm_host *h = f->host;
    *posted = false;
    bool go;
    int rc = hold_gate(h, id, &go, err);
    if (rc || !go)
        return rc;
    struct hold_ask *a = mem_calloc(1, sizeof(*a));
    if (!a)
        return sf_err_set(err, SF_ENOMEM, "host %s: hold job %lld: out of memory", h->name,
                          (long long)id);
    *a = (struct hold_ask){ .f = f, .token = h->token, .id = id, .done = done, .ud = dud };
    snprintf(a->name, sizeof(a->name), "%s", h->name);
    snprintf(a->printer, sizeof(a->printer), "%s", printer);
    if (storeq_call(f->q, hold_call, a, h->name, on_held, a)) {
        free(a);
        return sf_err_set(err, SF_ENOMEM, "host %s: hold job %lld: out of memory", h->name,
                          (long long)id);
    }
    *posted = true;
    return SF_OK;
}
