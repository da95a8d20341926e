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
 * Thread: the loop thread.
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

#define PRINTERS_TRACKED 1000 /* printers whose last state is remembered (farmcfg's cap) */

/* A printer's last state seen in the log, to tell a change from a repeat. */
struct seen_printer {
    char name[64];
    char state[24];
};

struct notify {
    struct loop *l;            /* the loop */
    struct store *s;           /* the event log */
    struct httpc *h;           /* the loop's shared curl client */
    struct notifycfg *targets; /* n_targets, copied */
    size_t n_targets;          /* their count */
    int64_t last_id;           /* newest event read */
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

/* Does this host tell of an event about job job_id and printer?  Alone, yes; one of several
   hosts reads the whole farm's log, and each event is told by one of them
   (store_host_teller): the job's holder, the printer's owner, else the first live host.
   When that cannot be read, yes (told twice rather than not at all). */
static bool
tells(struct notify *n, int64_t job_id, const char *printer)
{
    if (!n->host[0])
        return true;
    char who[STORE_HOST_NAME_MAX];
    struct sf_err err;
    if (store_host_teller(n->s, job_id, printer, clock_wall_ms(), who, sizeof(who), &err)) {
        if (!n->teller_failed)
            log_warn("notify", "which host tells: %s", err.msg);
        n->teller_failed = true;
        return true;
    }
    n->teller_failed = false;
    return !who[0] || strcmp(who, n->host) == 0;
}

/* After a job started or ended: tell once that no job waits any more (only if a target asks,
   and on one host of several: the first live one, tells(0, "")). */
static void
check_queue(struct notify *n, const struct event_row *e)
{
    bool asked = false;
    for (size_t i = 0; i < n->n_targets; i++)
        asked |= (n->targets[i].events & NOTIFY_QUEUE_EMPTY) != 0;
    if (!asked || !tells(n, 0, ""))
        return;
    uint64_t by_state[JOB_STATE_COUNT];
    struct sf_err err;
    if (store_job_counts(n->s, by_state, &err)) { /* counted by the database: no rows read */
        log_warn("notify", "queue: %s", err.msg);
        return;
    }
    uint64_t waiting = by_state[JOB_QUEUED] + by_state[JOB_PREPARING] + by_state[JOB_READY];
    if (waiting) {
        n->queue_armed = true;
        return;
    }
    if (!n->queue_armed)
        return;
    n->queue_armed = false;
    struct notify_msg m = { .ev = NOTIFY_QUEUE_EMPTY, .e = e };
    notify_msg_text(&m, NULL);
    for (size_t i = 0; i < n->n_targets; i++)
        if (n->targets[i].events & NOTIFY_QUEUE_EMPTY)
            deliver(n, &n->targets[i], &m);
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
    if (strncmp(e->kind, "job-", 4) == 0) {
        char to[24];
        job_moved_to(e->detail, to);
        *queue_check = strcmp(to, "printing") == 0 || strcmp(to, "done") == 0 ||
                       strcmp(to, "failed") == 0 || strcmp(to, "cancelled") == 0;
        return strcmp(to, "done") == 0     ? NOTIFY_JOB_DONE
               : strcmp(to, "failed") == 0 ? NOTIFY_JOB_FAILED
                                           : 0;
    }
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
handle(struct notify *n, const struct event_row *e)
{
    bool queue_check;
    enum notify_event ev = classify(n, e, &queue_check);
    bool wanted = false;
    for (size_t i = 0; i < n->n_targets; i++)
        wanted |= (n->targets[i].events & ev) != 0;
    if (ev && wanted && tells(n, e->job_id, e->printer)) {
        struct job_row job;
        bool have_job = e->job_id > 0 && store_job_get(n->s, e->job_id, &job, NULL) == SF_OK;
        struct notify_msg m = { .ev = ev, .e = e };
        snprintf(m.printer, sizeof(m.printer), "%s", e->printer);
        struct print_row *prints;
        size_t k;
        /* a job that ended is on no printer: say the one its last print ran on */
        if (have_job && !m.printer[0] &&
            store_prints(n->s, e->job_id, &prints, &k, NULL) == SF_OK) {
            if (k)
                snprintf(m.printer, sizeof(m.printer), "%s", prints[k - 1].printer);
            free(prints);
        }
        notify_msg_text(&m, have_job ? &job : NULL);
        for (size_t i = 0; i < n->n_targets; i++)
            if (n->targets[i].events & ev)
                deliver(n, &n->targets[i], &m);
    }
    if (queue_check)
        check_queue(n, e);
}

static void
read_log(struct loop *l, void *ud)
{
    (void)l;
    struct notify *n = ud;
    n->kick = 0;
    for (int round = 0; round < 4; round++) {
        struct event_row *ev;
        size_t k;
        struct sf_err err;
        if (store_events(n->s, n->last_id, NOTIFY_BATCH, &ev, &k, &err)) {
            if (!n->log_failed)
                log_warn("notify", "reading the event log: %s", err.msg);
            n->log_failed = true;
            return;
        }
        n->log_failed = false;
        for (size_t i = 0; i < k; i++) {
            n->last_id = ev[i].id;
            handle(n, &ev[i]);
        }
        free(ev);
        if (k < NOTIFY_BATCH)
            return;
    }
    notify_kick(n); /* more than a turn's worth: the rest on the next turn */
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
notify_new(struct loop *l, struct store *s, const struct notifycfg *targets, size_t n_targets,
           struct sf_err *err)
{
    struct notify *n = mem_calloc(1, sizeof(*n));
    if (!n) {
        sf_err_set(err, SF_ENOMEM, "notify: out of memory");
        return NULL;
    }
    n->l = l;
    n->s = s;
    n->queue_armed = true;
    n->last_id = store_event_last(s); /* from now on: see notify.h on restarts */
    if (notify_reload(n, targets, n_targets, err) || !(n->h = httpc_get(l, err)) ||
        !(n->poll = loop_timer_add(l, NOTIFY_POLL_MS, on_poll, n))) {
        if (!n->poll && n->h)
            sf_err_set(err, SF_ENOMEM, "notify: out of memory");
        notify_free(n);
        return NULL;
    }
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
    if (n->kick)
        loop_timer_cancel(n->l, n->kick);
    if (n->poll)
        loop_timer_cancel(n->l, n->poll);
    httpc_put(n->h);
    free(n->targets);
    free(n->seen);
    free(n);
}
