/*
 * storeq.c - the store's own thread (storeq.h).
 *
 * Why: every store call used to run on the loop, so a write that waited
 * (another process holding SQLite's write lock: 5 s a write, then an
 * error) stopped every printer's stream with it; on PostgreSQL each call
 * is a network round trip.  The writes made while printers print
 * (progress, printer states, bed, notes, the end of a print) come here
 * instead and the loop goes on.
 *
 * Design: one mutex guards the FIFO of pending requests, the list of
 * finished ones and the counters the thread touches.  The thread takes the
 * head, runs it on its own connection without the lock, puts it on the
 * finished list and writes an eventfd the loop watches; the loop's
 * callback takes the whole list and delivers it in order.  An fd, not
 * loop_post: storeq_free must withdraw what is undelivered (loop_del_fd),
 * and a posted callback cannot be withdrawn.  storeq_sync waits on a
 * condition signalled when the queue empties.  A request that fails with
 * nothing applied (busy, the connection away: sqldb.h's SF_EBUSY and
 * SF_EUNREACH) waits (on the same condition, so a stop cuts the wait short;
 * a post does not) and runs again: a store transaction that failed left
 * nothing behind.  One whose COMMIT's answer was lost (SF_EINDOUBT) is read
 * back first (settle).  Anything else is reported at once: a constraint or
 * an invalid byte fails the same way every time, and must not hold the
 * queue for STOREQ_RETRY_MS.
 *
 * Thread: storeq.h's functions on the loop thread; run() and what it calls
 * on the queue's thread.
 */
#include "storeq.h"

#include <errno.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <time.h>
#include <unistd.h>

#include "../base/clock.h"
#include "../base/log.h"
#include "../base/mem.h"

enum op {
    OP_PROGRESS,    /* store_jobs_progress */
    OP_REASON,      /* store_job_set_reason */
    OP_PRINTER_SET, /* store_printer_set */
    OP_NOTE,        /* store_printer_note */
    OP_BED_SET,     /* store_printer_bed_set */
    OP_EVENT,       /* store_job_event */
    OP_CALL,        /* a caller's function (storeq_call), or nothing (storeq_barrier) */
};

/* A job event's argument strings, copied (job_event_args points into them on the thread). */
struct event_strs {
    char printer[64];
    char gcode_sha[STORE_SHA_HEX];
    char prep_key[192];
    char mesh_sha[STORE_SHA_HEX];
    char reason[512];
    char note[512];
};

struct req {
    struct req *next;            /* in pending or finished */
    enum op op;                  /* what */
    int64_t id;                  /* the job (OP_REASON, OP_EVENT) */
    struct store_progress *prog; /* OP_PROGRESS: n_prog entries, owned */
    size_t n_prog;
    char name[64];     /* the printer (OP_PRINTER_SET, OP_NOTE, OP_BED_SET), or who (OP_EVENT) */
    char kind[24];     /* OP_NOTE's kind */
    char text[512];    /* OP_REASON's reason, OP_NOTE's detail */
    int value;         /* OP_PRINTER_SET's state, OP_BED_SET's full, OP_CALL: 1 a read */
    enum job_event ev; /* OP_EVENT */
    struct job_event_args a; /* OP_EVENT, its strings pointing into s */
    bool has_a;              /* OP_EVENT had args */
    struct event_strs *s;    /* OP_EVENT's strings, owned */
    storeq_event_fn done;    /* OP_EVENT's and OP_CALL's callback, may be NULL */
    storeq_call_fn call;     /* OP_CALL's function, NULL for a barrier */
    void *arg;               /* its argument */
    void *ud;                /* its argument */
    bool started;            /* the thread took it: progress is no longer folded into it */
    int64_t posted_ms;       /* clock_mono_ms at post */
    int64_t ended_ms;        /* when it ran for the last time */
    int rc;                  /* result */
    enum job_state to;       /* OP_EVENT's new state */
    struct sf_err err;       /* why it failed */
};

struct storeq {
    struct loop *l;     /* delivers results */
    struct store *conn; /* the queue's own connection (the thread's alone) */
    int evfd;           /* written by the thread when a request ended */
    pthread_t thread;
    pthread_mutex_t mu;              /* guards everything below down to stats */
    pthread_cond_t cond;             /* work posted, the queue emptied, or a stop */
    struct req *head, *tail;         /* pending, in order (the head may be running) */
    struct req *fin_head, *fin_tail; /* ended, not yet delivered */
    size_t depth;                    /* pending, counting the running one */
    bool stop;                       /* storeq_free: end once the queue is empty */
    bool refused;                    /* a storeq_sync gave up: call commit once the queue empties */
    int64_t stop_ms;                 /* when stop was asked */
    bool gave_up;                    /* a request ran out of retries during a stop: the rest
                                        fail at once instead of each waiting its turn */
    uint64_t retries;                /* stats.retries */
    int64_t retry_ms;                /* how long a failing request is tried: STOREQ_RETRY_MS */
    /* loop thread only */
    storeq_commit_fn commit; /* the wake after events were logged */
    void *commit_ud;
    struct storeq_stats st; /* posted, done, failed, depth_max, wait_max_ms */
};

/* ---- the queue's thread ---- */

/* Run r once on the thread's connection. */
static int
run_once(struct storeq *q, struct req *r)
{
    struct store *s = q->conn;
    struct sf_err *err = &r->err;
    switch (r->op) {
    case OP_PROGRESS: {
        int rc = store_jobs_progress(s, r->prog, r->n_prog, err);
        return rc < 0 ? rc : SF_OK;
    }
    case OP_REASON:
        return store_job_set_reason(s, r->id, r->text, err);
    case OP_PRINTER_SET:
        return store_printer_set(s, r->name, (enum printer_state)r->value, err);
    case OP_NOTE:
        return store_printer_note(s, r->name, r->kind, r->text, err);
    case OP_BED_SET:
        return store_printer_bed_set(s, r->name, r->value != 0, err);
    case OP_EVENT:
        return store_job_event(s, r->id, r->ev, r->has_a ? &r->a : NULL, &r->to, err);
    case OP_CALL:
        return r->call ? r->call(s, r->arg, err) : SF_OK;
    }
    return sf_err_set(err, SF_EBUG, "storeq: unknown request %d", (int)r->op);
}

/* Wait ms on the condition, or less if a stop comes; with q->mu held. */
static void
nap(struct storeq *q, int64_t ms)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    ts.tv_sec += ms / 1000;
    ts.tv_nsec += (ms % 1000) * 1000000L;
    if (ts.tv_nsec >= 1000000000L) {
        ts.tv_sec++;
        ts.tv_nsec -= 1000000000L;
    }
    pthread_cond_timedwait(&q->cond, &q->mu, &ts);
}

/* Whether a failure left nothing applied and a later try may pass: busy, or the connection
   lost or not back yet (sqldb.h).  Anything else (a constraint, invalid input, a refused
   event) would fail the same way again: it is reported at once. */
static bool
transient(int rc)
{
    return rc == SF_EBUSY || rc == SF_EUNREACH;
}

/* The end of r's retries (started at t0), with q->mu held: STOREQ_RETRY_MS, or less once a
   stop is asked. */
static int64_t
retry_end(const struct storeq *q, int64_t t0)
{
    int64_t end = t0 + q->retry_ms;
    if (q->stop && q->stop_ms + STOREQ_STOP_MS < end)
        end = q->stop_ms + STOREQ_STOP_MS;
    return end;
}

/* Wait ms before a retry unless the end (or a stop) comes first, with q->mu held; false
   when there is no time left.  A post wakes the condition too: the wait goes on after it. */
static bool
back_off(struct storeq *q, int64_t t0, int64_t ms)
{
    int64_t now = clock_mono_ms(), until = now + ms;
    if (until >= retry_end(q, t0))
        return false;
    for (bool stop = q->stop; q->stop == stop && now < until; now = clock_mono_ms())
        nap(q, until - now);
    return true;
}

/* r failed with SF_EINDOUBT (its COMMIT's answer was lost): read back whether it committed,
   asking again while the server cannot tell, until r's retries run out.  SF_OK when it did
   (its result stands), SF_EBUSY when it did not (run it again), SF_EINDOUBT when nobody can
   tell in time (reported: running it again could apply it twice).  A write that sets values
   (progress, a reason, a printer's state or bed) and a read are simply run again: twice is
   once; a caller's write (storeq_call: a PREPARED with its files) is read back as an event. */
static int
settle(struct storeq *q, struct req *r, int64_t t0)
{
    bool call_write = r->op == OP_CALL && r->call && !r->value;
    if (r->op != OP_EVENT && r->op != OP_NOTE && !call_write)
        return SF_EBUSY;
    for (int64_t backoff = 50;; backoff = backoff * 2 > 1000 ? 1000 : backoff * 2) {
        struct sf_err e = { 0 };
        int o = store_commit_outcome(q->conn, &e);
        if (o >= 0)
            return o == 1 ? SF_OK : SF_EBUSY;
        pthread_mutex_lock(&q->mu);
        bool again = back_off(q, t0, backoff);
        if (again)
            q->retries++;
        pthread_mutex_unlock(&q->mu);
        if (!again) {
            sf_err_prefix(&r->err, "%s; still unknown", e.msg);
            return SF_EINDOUBT;
        }
    }
}

/* Run r, again while it fails with nothing applied and time is left; q->mu not held. */
static void
run_req(struct storeq *q, struct req *r)
{
    int64_t t0 = clock_mono_ms(), backoff = 50;
    pthread_mutex_lock(&q->mu);
    bool late = q->gave_up && q->stop; /* shutdown's window is spent: no more waits */
    pthread_mutex_unlock(&q->mu);
    if (late) {
        r->rc = sf_err_set(&r->err, SF_EUNREACH,
                           "store: not written: the database stayed busy or unreachable through "
                           "shutdown's %d s",
                           STOREQ_STOP_MS / 1000);
        r->ended_ms = clock_mono_ms();
        return;
    }
    for (;;) {
        r->err = (struct sf_err){ 0 };
        r->rc = run_once(q, r);
        if (r->rc == SF_EINDOUBT) {
            int rc = settle(q, r, t0);
            if (rc == SF_OK)
                r->err = (struct sf_err){ 0 };
            r->rc = rc;
        }
        if (!transient(r->rc))
            break;
        pthread_mutex_lock(&q->mu);
        bool again = back_off(q, t0, backoff);
        if (again)
            q->retries++;
        else if (q->stop)
            q->gave_up = true;
        pthread_mutex_unlock(&q->mu);
        if (!again)
            break;
        backoff = backoff * 2 > 1000 ? 1000 : backoff * 2;
    }
    r->ended_ms = clock_mono_ms();
}

static void *
run(void *ud)
{
    struct storeq *q = ud;
    pthread_mutex_lock(&q->mu);
    for (;;) {
        while (!q->head && !q->stop)
            pthread_cond_wait(&q->cond, &q->mu);
        if (!q->head)
            break; /* stopped, and nothing left */
        struct req *r = q->head;
        r->started = true;
        pthread_mutex_unlock(&q->mu);
        run_req(q, r);
        pthread_mutex_lock(&q->mu);
        q->head = r->next;
        if (!q->head)
            q->tail = NULL;
        r->next = NULL;
        if (q->fin_tail)
            q->fin_tail->next = r;
        else
            q->fin_head = r;
        q->fin_tail = r;
        q->depth--;
        if (!q->depth)
            pthread_cond_broadcast(&q->cond); /* storeq_sync */
        uint64_t one = 1;
        /* a full counter means a wake-up is pending anyway */
        if (write(q->evfd, &one, sizeof(one)) < 0) {
        }
    }
    pthread_mutex_unlock(&q->mu);
    return NULL;
}

/* ---- the loop's side ---- */

static void
req_free(struct req *r)
{
    free(r->prog);
    free(r->s);
    free(r);
}

/* Hand back what ended, in order. */
static void
deliver(struct storeq *q)
{
    pthread_mutex_lock(&q->mu);
    struct req *r = q->fin_head;
    q->fin_head = q->fin_tail = NULL;
    /* a caller told "busy" acts once the queue has emptied */
    bool logged = q->refused && !q->depth;
    if (logged)
        q->refused = false;
    pthread_mutex_unlock(&q->mu);
    while (r) {
        struct req *next = r->next;
        q->st.done++;
        if (r->ended_ms - r->posted_ms > q->st.wait_max_ms)
            q->st.wait_max_ms = r->ended_ms - r->posted_ms;
        if (r->rc)
            q->st.failed++;
        if ((r->op == OP_EVENT || r->op == OP_CALL) && r->done)
            r->done(r->ud, &(struct storeq_result){ r->id, r->ev, r->rc, r->to, &r->err });
        else if (r->rc && r->name[0])
            log_printer(LOG_ERROR, r->name, "store: %s", r->err.msg);
        else if (r->rc)
            log_error("store", "%s", r->err.msg);
        logged |= r->rc == SF_OK && r->op != OP_PROGRESS && r->op != OP_REASON &&
                  (r->op != OP_CALL || (r->call && !r->value));
        req_free(r);
        r = next;
    }
    if (logged && q->commit)
        q->commit(q->commit_ud);
}

static void
on_ended(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)l;
    (void)events;
    uint64_t n;
    if (read(fd, &n, sizeof(n)) < 0) { /* EAGAIN: delivered already */
    }
    deliver(ud);
}

/* A new request of kind op, or NULL (counted as failed). */
static struct req *
req_new(struct storeq *q, enum op op)
{
    struct req *r = mem_calloc(1, sizeof(*r));
    if (!r) {
        q->st.failed++;
        log_error("store", "out of memory: a store write is lost");
        return NULL;
    }
    r->op = op;
    r->posted_ms = clock_mono_ms();
    return r;
}

static int
post(struct storeq *q, struct req *r)
{
    pthread_mutex_lock(&q->mu);
    if (q->tail)
        q->tail->next = r;
    else
        q->head = r;
    q->tail = r;
    size_t depth = ++q->depth;
    pthread_cond_broadcast(&q->cond);
    pthread_mutex_unlock(&q->mu);
    q->st.posted++;
    if (depth > q->st.depth_max)
        q->st.depth_max = depth;
    return SF_OK;
}

struct storeq *
storeq_new(struct loop *l, const struct store *s, struct sf_err *err)
{
    struct storeq *q = mem_calloc(1, sizeof(*q));
    if (!q) {
        sf_err_set(err, SF_ENOMEM, "storeq: out of memory");
        return NULL;
    }
    q->l = l;
    q->evfd = -1;
    q->retry_ms = STOREQ_RETRY_MS;
    pthread_mutex_init(&q->mu, NULL);
    pthread_condattr_t ca;
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC); /* nap()'s deadlines */
    pthread_cond_init(&q->cond, &ca);
    pthread_condattr_destroy(&ca);
    if (!(q->conn = store_open_writer(s, err)))
        goto fail;
    if ((q->evfd = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC)) < 0) {
        sf_err_set(err, SF_EIO, "storeq: eventfd: %s", strerror(errno));
        goto fail;
    }
    if (loop_add_fd(l, q->evfd, LOOP_READ, on_ended, q, err))
        goto fail;
    /* Started with every signal blocked, as the pool's workers are: a SIGTERM or SIGHUP
       must reach the loop's signalfd, not kill the process through this thread. */
    sigset_t all, old;
    sigfillset(&all);
    pthread_sigmask(SIG_SETMASK, &all, &old);
    int rc = pthread_create(&q->thread, NULL, run, q);
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    if (rc) {
        loop_del_fd(l, q->evfd);
        sf_err_set(err, SF_EIO, "storeq: cannot start its thread");
        goto fail;
    }
    return q;
fail:
    if (q->evfd >= 0)
        close(q->evfd);
    store_close(q->conn);
    pthread_cond_destroy(&q->cond);
    pthread_mutex_destroy(&q->mu);
    free(q);
    return NULL;
}

void
storeq_free(struct storeq *q)
{
    if (!q)
        return;
    pthread_mutex_lock(&q->mu);
    q->stop = true;
    q->stop_ms = clock_mono_ms();
    pthread_cond_broadcast(&q->cond);
    pthread_mutex_unlock(&q->mu);
    pthread_join(q->thread, NULL);
    deliver(q); /* every request ran: hand back the rest here */
    loop_del_fd(q->l, q->evfd);
    close(q->evfd);
    store_close(q->conn);
    pthread_cond_destroy(&q->cond);
    pthread_mutex_destroy(&q->mu);
    free(q);
}

void
storeq_set_retry_ms(struct storeq *q, int64_t ms)
{
    pthread_mutex_lock(&q->mu);
    q->retry_ms = ms;
    pthread_mutex_unlock(&q->mu);
}

void
storeq_set_commit(struct storeq *q, storeq_commit_fn fn, void *ud)
{
    q->commit = fn;
    q->commit_ud = ud;
}

/* Fold p into a pending progress of the same job not started yet; true if all of it was. */
static bool
fold(struct storeq *q, const struct store_progress *p, size_t n)
{
    size_t folded = 0;
    pthread_mutex_lock(&q->mu);
    for (size_t i = 0; i < n; i++) {
        struct store_progress *hit = NULL;
        /* the last pending request on this job, if it is a progress: folding into an earlier
           one would move the count before an event on the job posted since */
        for (struct req *r = q->head; r; r = r->next) {
            if (r->op == OP_EVENT && r->id == p[i].job_id)
                hit = NULL;
            for (size_t k = 0; r->op == OP_PROGRESS && k < r->n_prog; k++)
                if (r->prog[k].job_id == p[i].job_id)
                    hit = r->started ? NULL : &r->prog[k];
        }
        if (!hit)
            break;
        hit->lines_acked = p[i].lines_acked;
        folded++;
    }
    pthread_mutex_unlock(&q->mu);
    return folded == n;
}

int
storeq_jobs_progress(struct storeq *q, const struct store_progress *p, size_t n)
{
    if (!n || fold(q, p, n))
        return SF_OK;
    struct req *r = req_new(q, OP_PROGRESS);
    if (!r || !(r->prog = mem_array(n, sizeof(*p)))) {
        free(r);
        return SF_ENOMEM;
    }
    memcpy(r->prog, p, n * sizeof(*p));
    r->n_prog = n;
    return post(q, r);
}

int
storeq_job_set_reason(struct storeq *q, int64_t id, const char *reason)
{
    struct req *r = req_new(q, OP_REASON);
    if (!r)
        return SF_ENOMEM;
    r->id = id;
    snprintf(r->text, sizeof(r->text), "%s", reason);
    return post(q, r);
}

int
storeq_printer_set(struct storeq *q, const char *name, enum printer_state st)
{
    struct req *r = req_new(q, OP_PRINTER_SET);
    if (!r)
        return SF_ENOMEM;
    snprintf(r->name, sizeof(r->name), "%s", name);
    r->value = (int)st;
    return post(q, r);
}

int
storeq_printer_note(struct storeq *q, const char *name, const char *kind, const char *detail)
{
    struct req *r = req_new(q, OP_NOTE);
    if (!r)
        return SF_ENOMEM;
    snprintf(r->name, sizeof(r->name), "%s", name);
    snprintf(r->kind, sizeof(r->kind), "%s", kind);
    snprintf(r->text, sizeof(r->text), "%s", detail);
    return post(q, r);
}

int
storeq_printer_bed_set(struct storeq *q, const char *name, bool full)
{
    struct req *r = req_new(q, OP_BED_SET);
    if (!r)
        return SF_ENOMEM;
    snprintf(r->name, sizeof(r->name), "%s", name);
    r->value = full;
    return post(q, r);
}

/* Copy src into dst (cap bytes); NULL stays NULL (as a marker for run()). */
static const char *
copy(char *dst, size_t cap, const char *src)
{
    if (!src)
        return NULL;
    snprintf(dst, cap, "%s", src);
    return dst;
}

int
storeq_job_event(struct storeq *q, int64_t id, enum job_event ev, const struct job_event_args *a,
                 const char *who, storeq_event_fn done, void *ud)
{
    struct req *r = req_new(q, OP_EVENT);
    if (!r)
        return SF_ENOMEM;
    if (a && !(r->s = mem_calloc(1, sizeof(*r->s)))) {
        q->st.failed++;
        free(r);
        return SF_ENOMEM;
    }
    r->id = id;
    r->ev = ev;
    r->done = done;
    r->ud = ud;
    if (who)
        snprintf(r->name, sizeof(r->name), "%s", who);
    if (a) {
        struct event_strs *s = r->s;
        r->has_a = true;
        r->a = *a;
        r->a.printer = copy(s->printer, sizeof(s->printer), a->printer);
        r->a.gcode_sha = copy(s->gcode_sha, sizeof(s->gcode_sha), a->gcode_sha);
        r->a.prep_key = copy(s->prep_key, sizeof(s->prep_key), a->prep_key);
        r->a.mesh_sha = copy(s->mesh_sha, sizeof(s->mesh_sha), a->mesh_sha);
        r->a.reason = copy(s->reason, sizeof(s->reason), a->reason);
        r->a.note = copy(s->note, sizeof(s->note), a->note);
    }
    return post(q, r);
}

int
storeq_sync(struct storeq *q, int64_t max_ms, struct sf_err *err)
{
    int64_t end = clock_mono_ms() + max_ms;
    pthread_mutex_lock(&q->mu);
    while (q->depth && (max_ms < 0 || clock_mono_ms() < end)) {
        if (max_ms < 0)
            pthread_cond_wait(&q->cond, &q->mu);
        else
            nap(q, end - clock_mono_ms());
    }
    size_t left = q->depth;
    if (left)
        q->refused = true;
    pthread_mutex_unlock(&q->mu);
    if (left)
        return sf_err_set(err, SF_EBUSY, "the store is busy: %zu writes wait for the database",
                          left);
    return SF_OK;
}

size_t
storeq_depth(struct storeq *q)
{
    pthread_mutex_lock(&q->mu);
    size_t n = q->depth;
    pthread_mutex_unlock(&q->mu);
    return n;
}

void
storeq_stats(struct storeq *q, struct storeq_stats *out)
{
    *out = q->st;
    pthread_mutex_lock(&q->mu);
    out->retries = q->retries;
    out->depth = q->depth;
    pthread_mutex_unlock(&q->mu);
}

/* A new OP_CALL request: fn(arg) on the store thread, then done(ud); NULL if out of memory. */
static struct req *
call_new(struct storeq *q, storeq_call_fn fn, void *arg, storeq_event_fn done, void *ud)
{
    struct req *r = req_new(q, OP_CALL);
    if (!r)
        return NULL;
    r->call = fn;
    r->arg = arg;
    r->done = done;
    r->ud = ud;
    r->ev = (enum job_event) - 1;
    return r;
}

int
storeq_call(struct storeq *q, storeq_call_fn fn, void *arg, const char *who, storeq_event_fn done,
            void *ud)
{
    struct req *r = call_new(q, fn, arg, done, ud);
    if (!r)
        return SF_ENOMEM;
    if (who)
        snprintf(r->name, sizeof(r->name), "%s", who);
    return post(q, r);
}

int
storeq_barrier(struct storeq *q, storeq_event_fn done, void *ud)
{
    return storeq_call(q, NULL, NULL, NULL, done, ud);
}

int
storeq_read(struct storeq *q, storeq_call_fn fn, void *arg, storeq_event_fn done, void *ud)
{
    struct req *r = call_new(q, fn, arg, done, ud);
    if (!r)
        return SF_ENOMEM;
    r->value = 1; /* wakes no one */
    return post(q, r);
}
