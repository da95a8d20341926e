/*
 * notify.c - the event log turned into webhooks and mails (notify.h).
 *
 * Design: a cursor over the store's event log (last_id), read on a
 * zero-delay timer after each kick and on a slow poll; each event the
 * operator cares about becomes one delivery per target that asked for it.
 * A delivery owns everything its request needs (url, headers, body,
 * recipients), so a SIGHUP that drops or changes its target never leaves
 * it pointing at freed config.  Requests go through the loop's shared
 * libcurl multi client (httpc.h) rather than a thread of our own: it
 * already runs every printer's HTTP on the loop without blocking, libcurl
 * speaks smtp:// and smtps:// as well, and a thread would need a queue
 * and a lock for what the loop does for free.  Retries wait on loop
 * timers with doubling delays.
 *
 * Which events: a job's move to done or failed (the event's detail is
 * "FROM -> TO[: why]"), a printer's state moving to awaiting-clear, error
 * or offline (offline only when it was seen online: every printer starts
 * offline), and the queue running empty (after a job starts or ends, no
 * job is queued, being prepared or ready; told once until a job waits
 * again).  Bodies are built by notify_body.c.
 *
 * Where the log is read: on the farm's store thread (notify_set_queue,
 * storeq_read), one read at a time so events are told in order: a batch
 * of events with what telling each needs (its teller, its job, the queue's
 * counts), so the loop's own connection sends nothing for them (issue 32:
 * each was a round trip every printer waited for on PostgreSQL).  The
 * first read is of the newest event's id only (where telling starts), so
 * notify_new sends nothing on the loop's connection either.  Without a
 * queue the same reads run on the loop's store.
 *
 * Thread: the loop thread; log_read on the store's thread.
 */
#include "notify.h"

#include <curl/curl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../drivers/net/httpc.h"
#include "../base/clock.h"
#include "../base/log.h"
#include "../base/mem.h"
#include "notify_int.h"
#include "store_host.h"
#include "storeq.h"

#define PRINTERS_TRACKED 1000 /* printers whose last state is remembered (farmcfg's cap) */

/* A printer's last state seen in the log, to tell a change from a repeat. */
struct seen_printer {
    char name[64];
    char state[24];
};

/* What telling of one event needs, read with it on the store's thread (log_read). */
struct ev_more {
    bool teller_read; /* the event's teller was asked (one of several hosts) */
    int teller_rc;    /* its answer: SF_OK (who) or the failure */
    struct sf_err teller_err;
    char who[STORE_HOST_NAME_MAX];
    bool have_job; /* the event's job, read because this host tells of it */
    struct job_row job;
    char last_printer[64]; /* the printer of the job's last print, "" if none */
    bool queue_read;       /* the queue's counts were read (a job started or ended) */
    bool q_teller_read;    /* the queue's teller was asked */
    int q_teller_rc;
    struct sf_err q_teller_err;
    char q_who[STORE_HOST_NAME_MAX];
    int counts_rc;
    struct sf_err counts_err;
    uint64_t by_state[JOB_STATE_COUNT];
};

/* One read of the log, on the store's thread: its batch and what telling each needs. */
struct log_read {
    struct notify *n; /* NULL once notify_free left it (the answer comes later) */
    /* the loop's, copied at the post */
    bool newest;                    /* the newest event's id only, into after (the first read) */
    int64_t after;                  /* the newest event read before */
    char host[STORE_HOST_NAME_MAX]; /* notify_set_host's */
    unsigned events;                /* what any target asks for */
    /* the thread's */
    int rc; /* store_events' failure (warned, read again at the next poll) */
    struct sf_err err;
    struct event_row *ev;
    size_t k;
    struct ev_more *more;
};

struct notify {
    struct loop *l;            /* the loop */
    struct store *s;           /* the event log */
    struct httpc *h;           /* the loop's shared curl client */
    struct notifycfg *targets; /* n_targets, copied */
    size_t n_targets;          /* their count */
    int64_t last_id;           /* newest event read */
    bool known;                /* last_id was read (the first read: the log's newest) */
    uint64_t kick;             /* pending zero-delay read, 0 if none */
    uint64_t poll;             /* the slow poll timer */
    bool queue_armed;          /* a job waited since the last queue-empty */
    bool log_failed;           /* the last log read failed (warned once) */
    struct seen_printer *seen; /* n_seen printers' last states */
    size_t n_seen, cap_seen;   /* count and room */
    struct delivery *pending;  /* deliveries waiting or in flight (doubly linked) */
    size_t n_pending;          /* their count */
    /* one of several hosts (notify_set_host), "" if alone; the last store_host_teller
       failed (warned once) */
    char host[STORE_HOST_NAME_MAX];
    bool teller_failed;
    struct storeq *q;         /* where the log is read (notify_set_queue); NULL: on s */
    struct log_read *reading; /* the read in flight, NULL if none */
    bool reread;              /* kicked while it ran: read again after it */
};

/* ---- deliveries ---- */

static void attempt(struct delivery *d);

static void
unlink_free(struct delivery *d)
{
    struct notify *n = d->n;
    if (d->prev)
        d->prev->next = d->next;
    else
        n->pending = d->next;
    if (d->next)
        d->next->prev = d->prev;
    n->n_pending--;
    notify_delivery_free(d);
}

static void
on_retry(struct loop *l, void *ud)
{
    (void)l;
    struct delivery *d = ud;
    d->timer = 0;
    attempt(d);
}

/* The attempt failed (why): try again later, or give up. */
static void
failed(struct delivery *d, const char *why)
{
    if (d->attempt > d->retries) {
        log_warn("notify", "%s: %s: not sent after %d attempts (%s)", d->target, d->what,
                 d->attempt, why);
        unlink_free(d);
        return;
    }
    int64_t wait = NOTIFY_BACKOFF_MS;
    for (int i = 1; i < d->attempt && wait < NOTIFY_BACKOFF_MAX; i++)
        wait *= 2;
    if (wait > NOTIFY_BACKOFF_MAX)
        wait = NOTIFY_BACKOFF_MAX;
    log_info("notify", "%s: %s: attempt %d failed (%s); again in %lld ms", d->target, d->what,
             d->attempt, why, (long long)wait);
    d->timer = loop_timer_add(d->n->l, wait, on_retry, d);
    if (!d->timer)
        unlink_free(d);
}

static void
on_done(struct httpc_req *r, const struct httpc_result *res, void *ud)
{
    (void)r;
    struct delivery *d = ud;
    d->req = NULL;
    char why[160];
    if (res->code != SF_OK) {
        /* libcurl's words without the url, which may hold a key */
        snprintf(why, sizeof(why), "%s", res->detail[0] ? res->detail : "no answer");
        failed(d, why);
        return;
    }
    if (!d->mail && (res->status < 200 || res->status > 299)) {
        snprintf(why, sizeof(why), "status %ld", res->status);
        failed(d, why);
        return;
    }
    log_info("notify", "%s: %s: sent", d->target, d->what);
    unlink_free(d);
}

static CURLcode
mail_opts(CURL *easy, void *ud)
{
    struct delivery *d = ud;
    CURLcode cc = curl_easy_setopt(easy, CURLOPT_MAIL_FROM, d->from);
    if (cc == CURLE_OK)
        cc = curl_easy_setopt(easy, CURLOPT_MAIL_RCPT, d->rcpt);
    if (cc == CURLE_OK && d->starttls)
        cc = curl_easy_setopt(easy, CURLOPT_USE_SSL, (long)CURLUSESSL_ALL);
    return cc;
}

static void
attempt(struct delivery *d)
{
    d->attempt++;
    struct httpc_opts o = { .url = d->url,
                            .method = d->mail ? "PUT" : "POST", /* PUT: curl's upload */
                            .body = d->body,
                            .body_len = d->body_len,
                            .headers = d->mail ? NULL : d->headers,
                            .max_body = 64 << 10,
                            .timeout_ms = d->timeout_s * 1000,
                            .user = d->user[0] ? d->user : NULL,
                            .password = d->password,
                            .done = on_done,
                            .ud = d,
                            .setopt = d->mail ? mail_opts : NULL,
                            .setopt_ud = d };
    struct sf_err err;
    d->req = httpc_start(d->n->h, &o, &err);
    if (!d->req)
        failed(d, err.code == SF_ENOMEM ? "out of memory" : "bad request options");
}

/* Queue one delivery of event e, told as text, to target t. */
static void
deliver(struct notify *n, const struct notifycfg *t, const struct notify_msg *m)
{
    if (n->n_pending >= NOTIFY_PENDING_MAX) {
        log_warn("notify", "%s: %s: dropped, %d deliveries already pending", t->name, m->event,
                 NOTIFY_PENDING_MAX);
        return;
    }
    struct delivery *d = notify_delivery_new(t, m);
    if (!d) {
        log_warn("notify", "%s: %s: dropped, out of memory", t->name, m->event);
        return;
    }
    d->n = n;
    d->next = n->pending;
    if (n->pending)
        n->pending->prev = d;
    n->pending = d;
    n->n_pending++;
    attempt(d);
}

/* ---- events ---- */

/* The printer's previous state ("" if never seen), and remember state. */
static const char *
printer_moved(struct notify *n, const char *name, const char *state, char prev[24])
{
    prev[0] = '\0';
    for (size_t i = 0; i < n->n_seen; i++)
        if (strcmp(n->seen[i].name, name) == 0) {
            snprintf(prev, 24, "%s", n->seen[i].state);
            snprintf(n->seen[i].state, sizeof(n->seen[i].state), "%s", state);
            return prev;
        }
    if (n->n_seen < PRINTERS_TRACKED &&
        mem_grow((void **)&n->seen, &n->cap_seen, n->n_seen + 1, sizeof(*n->seen))) {
        struct seen_printer *p = &n->seen[n->n_seen++];
        snprintf(p->name, sizeof(p->name), "%s", name);
        snprintf(p->state, sizeof(p->state), "%s", state);
    }
    return prev;
}

/* A job's event: the state it moved to ("X -> TO[: why]"), into to. */
static void
job_moved_to(const char *detail, char to[24])
{
    to[0] = '\0';
    const char *arrow = strstr(detail, " -> ");
    if (arrow)
        snprintf(to, 24, "%.*s", (int)strcspn(arrow + 4, ":"), arrow + 4);
}

/* Does this host tell of an event, the teller read (read) with rc into who?  Alone, yes; one of
   several hosts reads the whole farm's log, and each event is told by one of them
   (store_host_teller): the job's holder, the printer's owner, else the first live host.  When
   that cannot be read, yes (told twice rather than not at all). */
static bool
tells(struct notify *n, bool read, int rc, const struct sf_err *err, const char *who)
{
    if (!n->host[0] || !read)
        return true;
    if (rc) {
        if (!n->teller_failed)
            log_warn("notify", "which host tells: %s", err->msg);
        n->teller_failed = true;
        return true;
    }
    n->teller_failed = false;
    return !who[0] || strcmp(who, n->host) == 0;
}

/* After a job started or ended: tell once that no job waits any more (only if a target asks,
   and on one host of several: the first live one, the teller of (0, "")), from the counts m
   read with the event. */
static void
check_queue(struct notify *n, const struct event_row *e, const struct ev_more *m)
{
    bool asked = false;
    for (size_t i = 0; i < n->n_targets; i++)
        asked |= (n->targets[i].events & NOTIFY_QUEUE_EMPTY) != 0;
    if (!asked || !m->queue_read ||
        !tells(n, m->q_teller_read, m->q_teller_rc, &m->q_teller_err, m->q_who))
        return;
    if (m->counts_rc) { /* counted by the database: no rows read */
        log_warn("notify", "queue: %s", m->counts_err.msg);
        return;
    }
    const uint64_t *by_state = m->by_state;
    uint64_t waiting = by_state[JOB_QUEUED] + by_state[JOB_PREPARING] + by_state[JOB_READY];
    if (waiting) {
        n->queue_armed = true;
        return;
    }
    if (!n->queue_armed)
        return;
    n->queue_armed = false;
    struct notify_msg msg = { .ev = NOTIFY_QUEUE_EMPTY, .e = e };
    notify_msg_text(&msg, NULL);
    for (size_t i = 0; i < n->n_targets; i++)
        if (n->targets[i].events & NOTIFY_QUEUE_EMPTY)
            deliver(n, &n->targets[i], &msg);
}

/* A job's move e (job-*, not job-add): done or failed, 0 for another; whether it asks for
   the queue's counts (a job left the queue or ended). */
static enum notify_event
job_event(const struct event_row *e, bool *queue_check)
{
    char to[24];
    job_moved_to(e->detail, to);
    *queue_check = strcmp(to, "printing") == 0 || strcmp(to, "done") == 0 ||
                   strcmp(to, "failed") == 0 || strcmp(to, "cancelled") == 0;
    return strcmp(to, "done") == 0     ? NOTIFY_JOB_DONE
           : strcmp(to, "failed") == 0 ? NOTIFY_JOB_FAILED
                                       : 0;
}

/* Which notify_event e is, 0 for none. */
static enum notify_event
classify(struct notify *n, const struct event_row *e, bool *queue_check)
{
    *queue_check = false;
    if (strcmp(e->kind, "job-add") == 0) {
        n->queue_armed = true;
        return 0;
    }
    if (strncmp(e->kind, "job-", 4) == 0)
        return job_event(e, queue_check);
    if (strcmp(e->kind, "printer-state") != 0 || !e->printer[0])
        return 0;
    char prev[24];
    printer_moved(n, e->printer, e->detail, prev);
    if (strcmp(prev, e->detail) == 0)
        return 0; /* a repeat */
    if (strcmp(e->detail, "awaiting-clear") == 0)
        return NOTIFY_BED_CLEAR;
    if (strcmp(e->detail, "error") == 0)
        return NOTIFY_PRINTER_ERROR;
    if (strcmp(e->detail, "offline") == 0 && prev[0])
        return NOTIFY_PRINTER_OFFLINE;
    return 0;
}

static void
handle(struct notify *n, const struct event_row *e, const struct ev_more *more)
{
    bool queue_check;
    enum notify_event ev = classify(n, e, &queue_check);
    bool wanted = false;
    for (size_t i = 0; i < n->n_targets; i++)
        wanted |= (n->targets[i].events & ev) != 0;
    if (ev && wanted &&
        tells(n, more->teller_read, more->teller_rc, &more->teller_err, more->who)) {
        struct notify_msg m = { .ev = ev, .e = e };
        /* a job that ended is on no printer: say the one its last print ran on */
        snprintf(m.printer, sizeof(m.printer), "%s",
                 e->printer[0] ? e->printer : more->last_printer);
        notify_msg_text(&m, more->have_job ? &more->job : NULL);
        for (size_t i = 0; i < n->n_targets; i++)
            if (n->targets[i].events & ev)
                deliver(n, &n->targets[i], &m);
    }
    if (queue_check)
        check_queue(n, e, more);
}

/* Which notify_event e may be from itself alone (classify's, without what the loop
   remembers), and whether it asks for the queue's counts; 0 for none. */
static enum notify_event
may_be(const struct event_row *e, bool *queue_check)
{
    *queue_check = false;
    if (strncmp(e->kind, "job-", 4) == 0 && strcmp(e->kind, "job-add") != 0)
        return job_event(e, queue_check);
    if (strcmp(e->kind, "printer-state") != 0 || !e->printer[0])
        return 0;
    return strcmp(e->detail, "awaiting-clear") == 0 ? NOTIFY_BED_CLEAR
           : strcmp(e->detail, "error") == 0        ? NOTIFY_PRINTER_ERROR
           : strcmp(e->detail, "offline") == 0      ? NOTIFY_PRINTER_OFFLINE
                                                    : 0;
}

/* On the store's thread: the teller of (job_id, printer) for r's host into who, rc into *rc;
   whether this host tells (yes when alone, or when it cannot be read). */
static bool
read_teller(struct store *s, const struct log_read *r, int64_t job_id, const char *printer,
            bool *read, int *rc, struct sf_err *err, char *who, size_t cap)
{
    if (!r->host[0])
        return true;
    *read = true;
    *rc = store_host_teller(s, job_id, printer, clock_wall_ms(), who, cap, err);
    return *rc || !who[0] || strcmp(who, r->host) == 0;
}

/* On the store's thread: what telling of event e needs, into m. */
static void
read_more(struct store *s, const struct log_read *r, const struct event_row *e, struct ev_more *m)
{
    bool queue_check;
    enum notify_event ev = may_be(e, &queue_check);
    if ((ev & r->events) && read_teller(s, r, e->job_id, e->printer, &m->teller_read, &m->teller_rc,
                                        &m->teller_err, m->who, sizeof(m->who))) {
        m->have_job = e->job_id > 0 && store_job_get(s, e->job_id, &m->job, NULL) == SF_OK;
        struct print_row *prints;
        size_t k;
        if (m->have_job && !e->printer[0] &&
            store_prints(s, e->job_id, &prints, &k, NULL) == SF_OK) {
            if (k)
                snprintf(m->last_printer, sizeof(m->last_printer), "%s", prints[k - 1].printer);
            free(prints);
        }
    }
    if (!queue_check || !(r->events & NOTIFY_QUEUE_EMPTY))
        return;
    m->queue_read = true;
    if (read_teller(s, r, 0, "", &m->q_teller_read, &m->q_teller_rc, &m->q_teller_err, m->q_who,
                    sizeof(m->q_who)))
        m->counts_rc = store_job_counts(s, m->by_state, &m->counts_err);
}

/* On the store's thread: the newest event's id into r->after, where telling starts.  A
   failure is the request's (the queue tries it again): store_event_last says 0 for one, so
   a 0 is checked against the log, lest all of it be told. */
static int
read_newest(struct store *s, struct log_read *r, struct sf_err *err)
{
    if ((r->after = store_event_last(s)))
        return SF_OK;
    struct event_row *ev = NULL;
    size_t k = 0;
    int rc = store_events(s, 0, 1, &ev, &k, err);
    free(ev);
    if (rc == SF_OK && k)
        rc = sf_err_set(err, SF_EBUSY, "the event log's newest id could not be read");
    return rc;
}

/* On the store's thread: a batch of events after r->after, and what telling each needs.  A
   failure is kept in r (warned on the loop, read again at the next poll), not retried. */
static int
log_read(struct store *s, void *arg, struct sf_err *err)
{
    struct log_read *r = arg;
    if (r->newest)
        return read_newest(s, r, err);
    if ((r->rc = store_events(s, r->after, NOTIFY_BATCH, &r->ev, &r->k, &r->err)))
        return SF_OK;
    if (r->k && !(r->more = mem_calloc(r->k, sizeof(*r->more)))) {
        free(r->ev);
        r->ev = NULL;
        r->k = 0;
        r->rc = sf_err_set(&r->err, SF_ENOMEM, "out of memory");
        return SF_OK;
    }
    for (size_t i = 0; i < r->k; i++)
        read_more(s, r, &r->ev[i], &r->more[i]);
    return SF_OK;
}

static void
log_read_free(struct log_read *r)
{
    free(r->ev);
    free(r->more);
    free(r);
}

/* The read came back (on the loop): tell of its events, in order. */
static void
on_read(void *ud, const struct storeq_result *res)
{
    struct log_read *r = ud;
    struct notify *n = r->n;
    if (!n) { /* notify_free came first */
        log_read_free(r);
        return;
    }
    n->reading = NULL;
    if (r->newest && res->rc) { /* nothing told until it is read: tried at the next poll */
        if (!n->log_failed)
            log_warn("notify", "reading the event log's newest id: %s",
                     res->err ? res->err->msg : "failed");
        n->log_failed = true;
    } else if (r->newest) {
        n->log_failed = false;
        n->last_id = r->after;
        n->known = true;
    } else if (r->rc) {
        if (!n->log_failed)
            log_warn("notify", "reading the event log: %s", r->err.msg);
        n->log_failed = true;
    } else {
        n->log_failed = false;
        for (size_t i = 0; i < r->k; i++) {
            n->last_id = r->ev[i].id;
            handle(n, &r->ev[i], &r->more[i]);
        }
    }
    if (n->reread || (!r->rc && r->k == NOTIFY_BATCH))
        notify_kick(n); /* kicked meanwhile, or more than a batch: the rest on the next turn */
    n->reread = false;
    log_read_free(r);
}

static void
read_log(struct loop *l, void *ud)
{
    (void)l;
    struct notify *n = ud;
    n->kick = 0;
    if (n->reading) { /* one read at a time: the events in order */
        n->reread = true;
        return;
    }
    struct log_read *r = mem_calloc(1, sizeof(*r));
    if (!r)
        return; /* read at the next poll */
    r->n = n;
    r->newest = !n->known;
    r->after = n->last_id;
    snprintf(r->host, sizeof(r->host), "%s", n->host);
    for (size_t i = 0; i < n->n_targets; i++)
        r->events |= n->targets[i].events;
    n->reading = r;
    if (n->q && storeq_read(n->q, log_read, r, on_read, r) == SF_OK)
        return;
    /* no queue (or no memory for its request): on the loop's store */
    struct sf_err err = { 0 };
    struct storeq_result res = { .rc = log_read(n->s, r, &err), .err = &err };
    on_read(r, &res);
}

static void
on_poll(struct loop *l, void *ud)
{
    struct notify *n = ud;
    n->poll = loop_timer_add(l, NOTIFY_POLL_MS, on_poll, n);
    read_log(l, n);
}

/* ---- lifecycle ---- */

void
notify_kick(struct notify *n)
{
    if (n && !n->kick)
        n->kick = loop_timer_add(n->l, 0, read_log, n);
}

void
notify_set_queue(struct notify *n, struct storeq *q)
{
    if (n)
        n->q = q;
}

void
notify_set_host(struct notify *n, const char *host)
{
    if (n)
        snprintf(n->host, sizeof(n->host), "%s", host ? host : "");
}

size_t
notify_pending(const struct notify *n)
{
    return n ? n->n_pending : 0;
}

int
notify_reload(struct notify *n, const struct notifycfg *targets, size_t n_targets,
              struct sf_err *err)
{
    struct notifycfg *copy = NULL;
    if (n_targets) {
        copy = mem_array(n_targets, sizeof(*copy));
        if (!copy)
            return sf_err_set(err, SF_ENOMEM, "notify: out of memory");
        memcpy(copy, targets, n_targets * sizeof(*copy));
    }
    free(n->targets);
    n->targets = copy;
    n->n_targets = n_targets;
    return SF_OK;
}

struct notify *
notify_new(struct loop *l, struct store *s, struct storeq *q, const struct notifycfg *targets,
           size_t n_targets, struct sf_err *err)
{
    struct notify *n = mem_calloc(1, sizeof(*n));
    if (!n) {
        sf_err_set(err, SF_ENOMEM, "notify: out of memory");
        return NULL;
    }
    n->l = l;
    n->s = s;
    n->queue_armed = true;
    n->q = q;
    if (notify_reload(n, targets, n_targets, err) || !(n->h = httpc_get(l, err)) ||
        !(n->poll = loop_timer_add(l, NOTIFY_POLL_MS, on_poll, n))) {
        if (!n->poll && n->h)
            sf_err_set(err, SF_ENOMEM, "notify: out of memory");
        notify_free(n);
        return NULL;
    }
    read_log(l, n); /* the newest event: from now on (see notify.h on restarts) */
    return n;
}

void
notify_free(struct notify *n)
{
    if (!n)
        return;
    while (n->pending) {
        struct delivery *d = n->pending;
        if (d->req)
            httpc_cancel(d->req);
        if (d->timer)
            loop_timer_cancel(n->l, d->timer);
        unlink_free(d);
    }
    if (n->reading)
        n->reading->n = NULL; /* its answer comes later: freed then */
    if (n->kick)
        loop_timer_cancel(n->l, n->kick);
    if (n->poll)
        loop_timer_cancel(n->l, n->poll);
    httpc_put(n->h);
    free(n->targets);
    free(n->seen);
    free(n);
}
