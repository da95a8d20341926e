/*
 * farm_remote.c - actions on printers other hosts own, through command
 * rows (farm_remote.h, store_command.h).
 *
 * Every database call runs on the farm's store thread (storeq_call,
 * storeq_read): the loop only posts and is called back.  An ask is one
 * struct that the store thread fills while it is busy (one request at a
 * time); what arrives meanwhile (a NOTIFY, its deadline) is noted and
 * handled when the request is back.  The listener is a connection of its
 * own, as farm_host.c's (a notification that arrives during another call
 * does not wake the fd), drained on the loop: reading a socket, never
 * waiting; a lost one reconnects a step at a time (store_open_listener's
 * SQLDB_NOWAIT), never with a blocking PQreset on the loop.
 *
 * Stopping: the store queue is freed after this (farm_free), and delivers
 * what is in flight then; so the state outlives farm_remote_stop until
 * the last request in flight is back (inflight), and answers nothing more.
 * Nothing is left running that nobody runs: a take still queued at the stop
 * takes nothing (stopping), and a row taken, or an action that ran, whose
 * answer comes back only while the queue closes (its thread gone) has its
 * result written on the loop's own connection (finish_now).
 *
 * Thread: the loop thread; the *_fn functions on the store's.
 */
#include "farm_remote.h"

#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/clock.h"
#include "../base/log.h"
#include "../base/mem.h"
#include "farm_host.h"
#include "farm_int.h"
#include "farm_view.h"
#include "jobctl.h"
#include "store_command.h"
#include "storeq.h"

/* A lost listener is tried again this often: each try advances its connect without waiting
   (store_open_listener), so a few tries bring it back once the server answers. */
#define RELISTEN_MS 200

struct farm_remote {
    struct farm *f;
    struct store *ls;     /* the listener's connection */
    int fd;               /* its socket on the loop, -1 if none */
    int64_t fd_gen;       /* the listener's reconnects (store_host_reconnects) when fd was added */
    uint64_t retry;       /* timer: listen again */
    bool lost;            /* the listener is lost: said so (once until it is back) */
    int inflight;         /* requests on the store queue that point here */
    bool stopped;         /* farm_remote_stop ran: free once inflight is 0 */
    atomic_bool stopping; /* the same, for the store thread: a take queued then takes nothing */
    bool taking;          /* a take is on its way */
    bool retake;          /* woken meanwhile: take again once it is back */
    struct ask *asks;     /* this host's commands waiting for their answer */
};

enum ask_op { ASK_ADD, ASK_READ, ASK_EXPIRE };

/* A command this host asked for, until answered. */
struct ask {
    struct farm_remote *r;
    struct ask *next;
    /* the store thread's while busy */
    struct store_command c; /* in: printer, from, kind, line, who; out: the row */
    int64_t now_ms;         /* the wall clock at the ask: judges the owner's lease */
    enum ask_op op;
    /* the loop's */
    char printer[64]; /* c.printer's copy: the answer at a stop reads it while c may change */
    bool busy;        /* a request is on its way */
    bool answered;    /* done was called: freed once no request is on its way */
    bool heard;       /* a NOTIFY came while busy: read again */
    bool late;        /* the deadline passed while busy: withdraw next */
    bool no_timer;    /* its deadline's timer could not be added: withdrawn at once */
    uint64_t timer;   /* the deadline */
    int64_t end_ms;   /* its monotonic time (the row's deadline is the database's clock) */
    farm_remote_fn done;
    void *ud;
};

/* Free r once stopped with nothing in flight. */
static void
release(struct farm_remote *r)
{
    if (r->stopped && r->inflight == 0)
        free(r);
}

/* ---- the asker ---- */

static void
unlink_ask(struct farm_remote *r, struct ask *a)
{
    for (struct ask **pp = &r->asks; *pp; pp = &(*pp)->next)
        if (*pp == a) {
            *pp = a->next;
            break;
        }
}

/* Answer a (rc, msg) and forget it (freed now, or once its request is back). */
static void
answer(struct ask *a, int rc, const char *msg)
{
    struct sf_err err = { .code = rc };
    snprintf(err.msg, sizeof(err.msg), "%s", msg ? msg : "");
    struct farm_remote_result res = { .rc = rc,
                                      .err = &err,
                                      .printer = a->printer,
                                      .host = a->busy ? "" : a->c.host,
                                      .state = a->busy ? "" : a->c.printer_state };
    if (!a->answered) {
        unlink_ask(a->r, a);
        if (a->timer)
            loop_timer_cancel(a->r->f->l, a->timer);
        a->timer = 0;
        a->answered = true;
        a->done(a->ud, &res);
    }
    if (!a->busy)
        free(a);
}

/* The owner's answer in a's row, as the caller's result. */
static void
answer_row(struct ask *a)
{
    struct store_command *c = &a->c;
    char msg[sizeof(c->message) + 128];
    if (c->rc == SF_OK)
        snprintf(msg, sizeof(msg), "%s", c->message);
    else
        snprintf(msg, sizeof(msg), "%s (on host %s)", c->message[0] ? c->message : "refused",
                 c->host);
    answer(a, c->rc, msg);
}

static int
add_fn(struct store *s, void *arg, struct sf_err *err)
{
    struct ask *a = arg;
    return store_command_add(s, a->c.from, a->c.printer, a->c.kind, a->c.line, a->c.who, a->now_ms,
                             FARM_REMOTE_WAIT_MS, &a->c, err);
}

static int
read_fn(struct store *s, void *arg, struct sf_err *err)
{
    struct ask *a = arg;
    return store_command_get(s, a->c.id, &a->c, err);
}

static int
expire_fn(struct store *s, void *arg, struct sf_err *err)
{
    struct ask *a = arg;
    return store_command_expire(s, a->c.id, &a->c, err);
}

static void on_ask(void *ud, const struct storeq_result *res);

/* Post a's next request (op: a read or a withdrawal); false when out of memory (a is
   answered). */
static bool
post(struct ask *a, enum ask_op op)
{
    struct storeq *q = a->r->f->q;
    a->op = op;
    int rc = op == ASK_READ ? storeq_read(q, read_fn, a, on_ask, a)
                            : storeq_call(q, expire_fn, a, "remote", on_ask, a);
    if (rc) {
        answer(a, SF_ENOMEM, "remote command: out of memory");
        return false;
    }
    a->busy = true;
    a->r->inflight++;
    return true;
}

/* The row's deadline passed: withdraw it (or read what the owner did). */
static void
on_deadline(struct loop *l, void *ud)
{
    (void)l;
    struct ask *a = ud;
    a->timer = 0;
    if (a->busy)
        a->late = true;
    else
        post(a, ASK_EXPIRE);
}

/* The withdrawal's outcome: the row as it is now. */
static void
withdrawn(struct ask *a)
{
    char msg[256];
    if (a->c.state != STORE_CMD_DONE && a->no_timer) {
        snprintf(msg, sizeof(msg), "printer %s: out of memory for the %s's deadline: %s",
                 a->c.printer, a->c.kind,
                 a->c.state == STORE_CMD_RUNNING ? "host took it and may still act (see the "
                                                   "printer's state)"
                                                 : "withdrawn, it will not run");
        log_error("remote", "%s", msg);
        answer(a, SF_ENOMEM, msg);
        return;
    }
    switch (a->c.state) {
    case STORE_CMD_DONE:
        answer_row(a);
        return;
    case STORE_CMD_RUNNING:
        snprintf(msg, sizeof(msg),
                 "printer %s: host %s took the %s but did not answer within %d s: it may still "
                 "act (see the printer's state)",
                 a->c.printer, a->c.host, a->c.kind, FARM_REMOTE_WAIT_MS / 1000);
        break;
    default:
        snprintf(msg, sizeof(msg),
                 "printer %s: host %s did not answer within %d s: the %s was withdrawn and "
                 "will not run",
                 a->c.printer, a->c.host, FARM_REMOTE_WAIT_MS / 1000, a->c.kind);
        break;
    }
    log_warn("remote", "%s", msg);
    answer(a, SF_ETIMEDOUT, msg);
}

static void
on_ask(void *ud, const struct storeq_result *res)
{
    struct ask *a = ud;
    struct farm_remote *r = a->r;
    a->busy = false;
    r->inflight--;
    if (a->answered) { /* at a stop */
        free(a);
        release(r);
        return;
    }
    if (res->rc) {
        if (a->op == ASK_ADD) { /* the owner's lease ran out: its printer is offline */
            answer(a, res->rc == SF_ESTALE ? SF_EUNREACH : res->rc, res->err->msg);
            return;
        }
        /* a read or withdrawal failed (the store's queue retried it): the deadline decides */
        log_warn("remote", "printer %s: command %lld: %s", a->c.printer, (long long)a->c.id,
                 res->err->msg);
        if (a->op == ASK_EXPIRE) {
            char msg[sizeof(res->err->msg) + 160];
            snprintf(msg, sizeof(msg),
                     "printer %s: no answer within %d s, and its withdrawal failed (%s): its "
                     "owner does not run it after its deadline",
                     a->printer, FARM_REMOTE_WAIT_MS / 1000, res->err->msg);
            answer(a, SF_ETIMEDOUT, msg);
            return;
        }
    } else if (a->op == ASK_EXPIRE) {
        withdrawn(a);
        return;
    } else if (a->c.state == STORE_CMD_DONE) {
        answer_row(a);
        return;
    }
    if (a->op == ASK_ADD) {
        int64_t left = a->end_ms - clock_mono_ms();
        a->timer = loop_timer_add(r->f->l, left > 0 ? left : 0, on_deadline, a);
        a->heard = true; /* the answer may have come before the row's id was known */
        if (!a->timer) { /* no deadline would answer it: withdraw it now, SF_ENOMEM */
            a->no_timer = a->late = true;
        }
    }
    if (a->late) {
        a->late = false;
        post(a, ASK_EXPIRE);
    } else if (a->heard) {
        a->heard = false;
        post(a, ASK_READ);
    }
}

/* SF_EINVAL naming printer's field and its limit when v (may be NULL) is longer than cap - 1. */
static int
fits(const char *printer, const char *field, const char *v, size_t cap, struct sf_err *err)
{
    if (v && strlen(v) >= cap)
        return sf_err_set(err, SF_EINVAL, "printer %.64s: %s is longer than %zu bytes", printer,
                          field, cap - 1);
    return SF_OK;
}

int
farm_remote_send(struct farm *f, const char *name, const char *kind, const char *line,
                 const char *who, farm_remote_fn done, void *ud, struct sf_err *err)
{
    struct farm_remote *r = f ? f->remote : NULL;
    char me[STORE_HOST_NAME_MAX];
    if (!r || !f->q)
        return sf_err_set(err, SF_ENOTFOUND, "no printer '%.64s'", name);
    if (!farm_host_reader(f, me, sizeof(me)) || !me[0])
        return sf_err_set(err, SF_EAGAIN,
                          "printer %.64s: this host has not joined the farm yet: try again", name);
    struct ask *a = mem_calloc(1, sizeof(*a));
    if (!a)
        return sf_err_set(err, SF_ENOMEM, "remote command: out of memory");
    int rc;
    if ((rc = fits(name, "printer", name, sizeof(a->c.printer), err)) ||
        (rc = fits(name, "kind", kind, sizeof(a->c.kind), err)) ||
        (rc = fits(name, "command", line, sizeof(a->c.line), err)) ||
        (rc = fits(name, "who", who, sizeof(a->c.who), err))) {
        free(a);
        return rc;
    }
    snprintf(a->c.printer, sizeof(a->c.printer), "%s", name);
    snprintf(a->printer, sizeof(a->printer), "%s", name);
    snprintf(a->c.from, sizeof(a->c.from), "%s", me);
    snprintf(a->c.kind, sizeof(a->c.kind), "%s", kind);
    snprintf(a->c.line, sizeof(a->c.line), "%s", line ? line : "");
    snprintf(a->c.who, sizeof(a->c.who), "%s", who ? who : "");
    a->now_ms = clock_wall_ms();
    a->end_ms = clock_mono_ms() + FARM_REMOTE_WAIT_MS;
    a->r = r;
    a->done = done;
    a->ud = ud;
    a->next = r->asks;
    r->asks = a;
    if (storeq_call(f->q, add_fn, a, "remote", on_ask, a)) {
        r->asks = a->next;
        free(a);
        return sf_err_set(err, SF_ENOMEM, "remote command: out of memory");
    }
    a->op = ASK_ADD;
    a->busy = true;
    r->inflight++;
    return SF_OK;
}

/* ---- the owner ---- */

/* A take of this host's pending commands, or one command's result. */
struct run {
    struct farm_remote *r;
    char host[STORE_HOST_NAME_MAX];
    int64_t taken_ms;           /* the monotonic clock once taken: with each row's left_ms, */
    struct store_command *rows; /* the take's */
    size_t n;
    /* one command's */
    int64_t id;
    char printer[64], kind[24], from[STORE_HOST_NAME_MAX];
    int rc;
    char message[256], state[16];
};

static int
take_fn(struct store *s, void *arg, struct sf_err *err)
{
    struct run *t = arg;
    free(t->rows); /* a retry's */
    t->rows = NULL;
    t->n = 0;
    if (atomic_load(&t->r->stopping))
        return SF_OK; /* nobody would run what it takes: left pending, for its deadline */
    int rc = store_command_take(s, t->host, &t->rows, &t->n, err);
    t->taken_ms = clock_mono_ms();
    return rc;
}

static int
finish_fn(struct store *s, void *arg, struct sf_err *err)
{
    struct run *x = arg;
    return store_command_finish(s, x->id, x->rc, x->message, x->state, err);
}

static void
on_finished(void *ud, const struct storeq_result *res)
{
    struct run *x = ud;
    struct farm_remote *r = x->r;
    if (res->rc)
        log_warn("remote", "printer %s: the result of host %s's %s: %s", x->printer, x->from,
                 x->kind, res->err->msg);
    free(x);
    r->inflight--;
    release(r);
}

/* Write x's result (rc, msg) with its printer's state now; x is freed. */
static void
finish(struct run *x, int rc, const char *msg)
{
    struct farm_remote *r = x->r;
    x->rc = rc;
    snprintf(x->message, sizeof(x->message), "%s", msg ? msg : "");
    struct printer *p = farm_find(r->f, x->printer);
    snprintf(x->state, sizeof(x->state), "%s", p ? printer_state_name(printer_state(p)) : "");
    if (rc)
        log_warn("remote", "printer %s: %s from host %s refused: %s", x->printer, x->kind, x->from,
                 x->message);
    else
        log_info("remote", "printer %s: %s from host %s done (%s)", x->printer, x->kind, x->from,
                 x->state);
    if (storeq_call(r->f->q, finish_fn, x, "remote", on_finished, x)) {
        log_error("remote", "printer %s: out of memory for the result", x->printer);
        free(x);
        return;
    }
    r->inflight++;
}

/* Write command id's result (rc, msg) now on the loop's connection, at a stop: the store
   queue's thread is gone, and the row must not stay running. */
static void
finish_now(struct farm_remote *r, int64_t id, const char *printer, int rc, const char *msg)
{
    struct sf_err err;
    struct printer *p = farm_find(r->f, printer);
    if (store_command_finish(r->f->s, id, rc, msg, p ? printer_state_name(printer_state(p)) : "",
                             &err))
        log_warn("remote", "printer %s: command %lld's result at the stop: %s", printer,
                 (long long)id, err.msg);
}

/* An action's write is back (jobctl_printer_action_then), or a command sent
   (jobctl_printer_command_then): its result. */
static void
on_acted(void *ud, const struct storeq_result *res)
{
    struct run *x = ud;
    struct farm_remote *r = x->r;
    r->inflight--;
    if (r->stopped) { /* it ran: its result, written before the queue's connection closes */
        finish_now(r, x->id, x->printer, res->rc, res->rc ? res->err->msg : "");
        free(x);
        release(r);
        return;
    }
    finish(x, res->rc, res->rc ? res->err->msg : "");
}

/* Run command c, taken at taken_ms (monotonic), through this host's own action path. */
static void
run_one(struct farm_remote *r, const struct store_command *c, int64_t taken_ms)
{
    struct run *x = mem_calloc(1, sizeof(*x));
    struct sf_err err = { 0 };
    enum printer_action act;
    if (!x) {
        log_error("remote", "printer %s: out of memory for command %lld", c->printer,
                  (long long)c->id);
        return;
    }
    x->r = r;
    x->id = c->id;
    snprintf(x->printer, sizeof(x->printer), "%s", c->printer);
    snprintf(x->kind, sizeof(x->kind), "%s", c->kind);
    snprintf(x->from, sizeof(x->from), "%s", c->from);
    char who[96];
    snprintf(who, sizeof(who), "%s@%s", c->who[0] ? c->who : "?", c->from);
    int rc;
    if (clock_mono_ms() - taken_ms >= c->left_ms) { /* the loop came late to it */
        rc = sf_err_set(&err, SF_ETIMEDOUT, "came after its deadline: not run");
    } else if (printer_action_parse(c->kind, &act)) {
        rc = jobctl_printer_action_then(r->f, c->printer, act, on_acted, x, &err);
        if (rc == SF_OK) {
            r->inflight++;
            return;
        }
    } else if (strcmp(c->kind, FARM_REMOTE_CANCEL_JOB) == 0) {
        char *end = NULL;
        long long id = strtoll(c->line, &end, 10);
        if (!c->line[0] || *end || id <= 0) {
            rc = sf_err_set(&err, SF_EINVAL, "cancel-job: job id '%.32s' is not a job id", c->line);
        } else {
            rc = jobctl_cancel_job_on(r->f, c->printer, id, on_acted, x, &err);
            if (rc == SF_OK) {
                r->inflight++;
                return;
            }
        }
    } else if (strcmp(c->kind, "command") == 0) {
        rc = jobctl_printer_command_then(r->f, c->printer, c->line, who, on_acted, x, &err);
        if (rc == SF_OK) {
            r->inflight++;
            return;
        }
    } else if (strcmp(c->kind, "emergency-stop") == 0) {
        rc = jobctl_printer_estop(r->f, c->printer, who, &err);
    } else {
        rc = sf_err_set(&err, SF_EINVAL, "no printer command '%.24s'", c->kind);
    }
    finish(x, rc, rc ? err.msg : "");
}

static void take(struct farm_remote *r);

static void
on_taken(void *ud, const struct storeq_result *res)
{
    struct run *t = ud;
    struct farm_remote *r = t->r;
    r->inflight--;
    if (!r->stopped) {
        r->taking = false;
        if (res->rc)
            log_warn("remote", "%s: take the commands for this host: %s", t->host, res->err->msg);
        for (size_t i = 0; res->rc == SF_OK && i < t->n; i++)
            run_one(r, &t->rows[i], t->taken_ms);
        if (r->retake) {
            r->retake = false;
            take(r);
        }
    } else {
        for (size_t i = 0; res->rc == SF_OK && i < t->n; i++) /* taken, and nobody runs it */
            finish_now(r, t->rows[i].id, t->rows[i].printer, SF_ECANCELED,
                       "its host stopped before it ran: not run");
    }
    free(t->rows);
    free(t);
    release(r);
}

/* Take this host's pending commands (once its last take is back). */
static void
take(struct farm_remote *r)
{
    if (r->taking) {
        r->retake = true;
        return;
    }
    struct run *t = mem_calloc(1, sizeof(*t));
    if (!t || !farm_host_reader(r->f, t->host, sizeof(t->host)) || !t->host[0]) {
        free(t);
        return;
    }
    t->r = r;
    if (storeq_call(r->f->q, take_fn, t, "remote", on_taken, t)) {
        free(t);
        return;
    }
    r->taking = true;
    r->inflight++;
}

/* ---- the listener ---- */

/* Take this host's commands, and read the answers to the ones it asked again. */
static void
wake(struct farm_remote *r)
{
    take(r);                                            /* a command for this host's printers, */
    for (struct ask *a = r->asks, *next; a; a = next) { /* or an answer to one it asked */
        next = a->next;
        if (a->busy)
            a->heard = true;
        else if (a->c.id)
            post(a, ASK_READ);
    }
}

/* A notification: a command or answer for this host, another host's view (farm_view.h), or
   an event logged (by any host: this host's event streams look). */
static void
on_payload(void *ud, const char *channel, const char *payload)
{
    struct farm_remote *r = ud;
    char me[STORE_HOST_NAME_MAX];
    if (strcmp(channel, STORE_VIEW_CHANNEL) == 0) {
        if (!farm_host_reader(r->f, me, sizeof(me)) || strcmp(payload, me) != 0)
            farm_view_heard(r->f);
    } else if (strcmp(channel, STORE_EVENT_CHANNEL) == 0) {
        farm_notify(r->f);
    } else if (farm_host_reader(r->f, me, sizeof(me)) && strcmp(payload, me) == 0) {
        wake(r);
    }
}

static bool arm(struct farm_remote *r);
static void retry(struct farm_remote *r);

static void
drop(struct farm_remote *r)
{
    if (r->fd >= 0)
        loop_del_fd(r->f->l, r->fd);
    r->fd = -1;
}

static void
on_relisten(struct loop *l, void *ud)
{
    (void)l;
    struct farm_remote *r = ud;
    r->retry = 0;
    if (!arm(r))
        retry(r);
}

/* Try the lost listener again in RELISTEN_MS (saying so once). */
static void
retry(struct farm_remote *r)
{
    if (!r->lost)
        log_warn("remote", "the commands' wake-up connection is lost; trying again every %d ms",
                 RELISTEN_MS);
    r->lost = true;
    if (!r->retry)
        r->retry = loop_timer_add(r->f->l, RELISTEN_MS, on_relisten, r);
}

static void
on_readable(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)l, (void)fd, (void)events;
    struct farm_remote *r = ud;
    int n = store_command_drain(r->ls, on_payload, r);
    if (n >= 0 && store_host_reconnects(r->ls) == r->fd_gen &&
        store_command_notify_fd(r->ls) == r->fd)
        return;
    /* lost, or back already on a new session whose socket is a new one (perhaps under the old
       number, which epoll dropped when the old socket closed): watch it again, or retry */
    drop(r);
    if (!arm(r))
        retry(r);
}

/* Watch the listener (again): drain first, which advances the reconnect of a lost connection
   without waiting (store_open_listener: the loop never blocks on the database).  False while
   it is not back. */
static bool
arm(struct farm_remote *r)
{
    struct sf_err err;
    if (store_command_drain(r->ls, on_payload, r) < 0)
        return false;
    int fd = store_command_notify_fd(r->ls);
    if (fd < 0)
        return false;
    if (loop_add_fd(r->f->l, fd, LOOP_READ, on_readable, r, &err)) {
        log_warn("remote", "%s", err.msg);
        return false;
    }
    r->fd = fd;
    r->fd_gen = store_host_reconnects(r->ls);
    if (r->lost)
        log_info("remote", "the commands' wake-up connection is back");
    r->lost = false;
    wake(r); /* what was asked, or answered, while it was away (its NOTIFY lost) */
    farm_view_heard(r->f);
    return true;
}

int
farm_remote_start(struct farm *f, struct sf_err *err)
{
    struct farm_remote *r = mem_calloc(1, sizeof(*r));
    if (!r)
        return sf_err_set(err, SF_ENOMEM, "remote commands: out of memory");
    r->f = f;
    r->fd = -1;
    atomic_init(&r->stopping, false);
    f->remote = r;
    if (farm_view_start(f, err))
        return err->code;
    if (!(r->ls = store_open_listener(f->s, err)) || store_command_listen(r->ls, err)) {
        sf_err_prefix(err, "remote commands: wake-up connection");
        return err->code;
    }
    if (!arm(r))
        retry(r);
    return SF_OK;
}

void
farm_remote_stop(struct farm *f)
{
    struct farm_remote *r = f ? f->remote : NULL;
    if (!r)
        return;
    atomic_store(&r->stopping, true);
    farm_view_stop(f);
    drop(r);
    if (r->retry)
        loop_timer_cancel(f->l, r->retry);
    store_close(r->ls);
    while (r->asks)
        answer(r->asks, SF_ECANCELED, "this host is stopping: the command's answer is not known");
    r->stopped = true;
    f->remote = NULL;
    release(r);
}

bool
farm_remote_is(const struct farm *f, const char *name)
{
    /* a printer of f's config that a live host owns (both configs list it) is that host's
       too: its owner acts on it, not a copy of it here (farm_host_owns) */
    return f && f->remote && (!farm_find(f, name) || !farm_host_owns(f, name));
}
