/*
 * printer_op.c - what an operator does to a printer (printer.h): pause,
 * resume, cancel and clear its job or bed, send it a manual command, stop
 * it in an emergency; each recorded in the log and the event log.  And the
 * fencing of one of several hosts: the token p holds its job by, carried
 * by what p writes for it, and letting the job go once it is refused.
 *
 * Thread: the loop thread.
 */
#include "printer_int.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/log.h"
#include "../base/mem.h"

static const char *const action_names[PRINTER_ACTION_COUNT] = { "pause", "resume", "cancel",
                                                                "cleared", "cancel-copy" };

const char *
printer_action_name(enum printer_action a)
{
    return (unsigned)a < PRINTER_ACTION_COUNT ? action_names[a] : "?";
}

bool
printer_action_parse(const char *s, enum printer_action *out)
{
    for (int i = 0; i < PRINTER_ACTION_COUNT; i++)
        if (strcmp(s, action_names[i]) == 0) {
            *out = (enum printer_action)i;
            return true;
        }
    return false;
}

/* The job the store holds as interrupted on p (its part may be on the bed) in *id, 0 if none:
   SF_OK, or the store's error in err (SF_EBUSY while a CRASHED may still be queued). */
static int
interrupted_here(struct printer *p, int64_t *id, struct sf_err *err)
{
    struct job_row j;
    *id = 0;
    int rc = storeq_sync(p->env.q, STOREQ_SYNC_MS, err);
    if (rc == SF_OK)
        rc = store_job_interrupted(p->env.s, p->cfg.name, &j, err);
    if (rc == SF_OK)
        *id = j.id;
    return rc == SF_ENOTFOUND ? SF_OK : rc;
}

/* Record what an operator did to p in the log and the event log. */
static void
note(struct printer *p, const char *kind, const char *fmt, const char *a, const char *b)
{
    char what[192];
    snprintf(what, sizeof(what), fmt, a, b);
    if (strcmp(kind, "printer-command") == 0) /* each one, never folded as a repeat */
        log_printer_each(LOG_INFO, p->cfg.name, "%s", what);
    else
        log_printer(LOG_INFO, p->cfg.name, "%s", what);
    storeq_printer_note(p->env.q, p->cfg.name, kind, what);
}

/* Whether p takes a manual command now, as far as the loop knows (printer_command). */
static int
command_checks(struct printer *p, const char *line, struct sf_err *err)
{
    if (!line[0] || strpbrk(line, "\r\n"))
        return sf_err_set(err, SF_EINVAL, "printer %s: a command is one non-empty line",
                          p->cfg.name);
    if (!p->drv)
        return sf_err_set(err, SF_EAGAIN, "printer %s is not connected%s%s", p->cfg.name,
                          p->message[0] ? ": " : "", p->message);
    if (!p->drv->ops->command)
        return sf_err_set(err, SF_EUNSUPP, "printer %s: its %s driver sends no manual commands",
                          p->cfg.name, p->drv->ops->kind);
    if (p->state == PRINTER_OFFLINE)
        return sf_err_set(err, SF_EAGAIN, "printer %s is offline%s%s", p->cfg.name,
                          p->message[0] ? ": " : "", p->message);
    if (p->job_id || p->state == PRINTER_PRINTING)
        return sf_err_set(err, SF_EAGAIN,
                          "printer %s is %s job %lld: manual commands wait until it ends",
                          p->cfg.name, printer_state_name(p->state), (long long)p->job_id);
    /* Only an idle printer with a clear bed: a move on a part (or into it,
       before a resume's G92 Z) is the operator's to make at the printer. */
    if (p->state != PRINTER_IDLE || p->bed_full)
        return sf_err_set(err, SF_EAGAIN,
                          "printer %s is %s%s: manual commands only on an idle printer with a "
                          "clear bed (clear it first)",
                          p->cfg.name, printer_state_name(p->state),
                          p->bed_full && p->state == PRINTER_IDLE ? " with a part on its bed" : "");
    return SF_OK;
}

/* Send the command once the store said whether p holds an interrupted job (held; rc its
   read's code: unknown is not "none", the store's code, busy or unreachable, says when). */
static int
command_send(struct printer *p, const char *line, const char *who, int64_t held, int rc,
             struct sf_err *err)
{
    if (rc) {
        sf_err_prefix(err, "printer %s: whether it holds an interrupted job is not known",
                      p->cfg.name);
        return rc;
    }
    if (held)
        return sf_err_set(err, SF_EAGAIN,
                          "printer %s holds interrupted job %lld: resume, restart or cancel it "
                          "before manual commands",
                          p->cfg.name, (long long)held);
    rc = p->drv->ops->command(p->drv, line, err);
    if (rc == SF_OK)
        note(p, "printer-command", "manual command from %s: %s", who && who[0] ? who : "?", line);
    return rc;
}

int
printer_command(struct printer *p, const char *line, const char *who, struct sf_err *err)
{
    int rc = command_checks(p, line, err);
    if (rc)
        return rc;
    int64_t held;
    rc = interrupted_here(p, &held, err);
    return command_send(p, line, who, held, rc, err);
}

/* How long a manual command waits for the store's answer before it is answered "the store is
   busy" (the API's 503) and not sent: an operator at the console should not wait a minute. */
#define PRINTER_COMMAND_WAIT_MS 2000

/* A manual command waiting for the store's answer (printer_command_then). */
struct cmd_ticket {
    struct printer *p;       /* NULL: freed meanwhile */
    struct cmd_ticket *next; /* in p->cmds */
    struct loop *l;          /* p's */
    uint64_t timer;          /* PRINTER_COMMAND_WAIT_MS, 0 once fired or cancelled */
    bool answered;           /* the timer answered it: the read's answer is dropped */
    char name[sizeof(((struct farmcfg_printer *)0)->name)];
    int64_t held; /* the interrupted job the store holds on it, 0 if none (the thread's) */
    storeq_event_fn done;
    void *ud;
    char *line, *who;
};

/* On the store's thread: the job interrupted on t->name, if any. */
static int
held_read(struct store *s, void *arg, struct sf_err *err)
{
    struct cmd_ticket *t = arg;
    struct job_row j;
    t->held = 0;
    int rc = store_job_interrupted(s, t->name, &j, err);
    if (rc == SF_OK)
        t->held = j.id;
    return rc == SF_ENOTFOUND ? SF_OK : rc;
}

/* The store answered: send the command if p still takes it, and answer. */
static void
on_held_read(void *ud, const struct storeq_result *r)
{
    struct cmd_ticket *t = ud;
    struct printer *p = t->p;
    for (struct cmd_ticket **pp = p ? &p->cmds : NULL; pp && *pp; pp = &(*pp)->next)
        if (*pp == t) {
            *pp = t->next;
            break;
        }
    if (t->timer)
        loop_timer_cancel(t->l, t->timer);
    if (t->answered) { /* too late: answered busy, not sent */
        free(t->line);
        free(t->who);
        free(t);
        return;
    }
    struct sf_err err = { 0 };
    int rc;
    if (!p || p->deaf) {
        rc = sf_err_set(&err, SF_EAGAIN, "printer %s went away: the command was not sent", t->name);
    } else if (r->rc) {
        err = *r->err;
        rc = command_send(p, t->line, t->who, 0, r->rc, &err);
    } else if (!(rc = command_checks(p, t->line, &err))) { /* as p is now */
        rc = command_send(p, t->line, t->who, t->held, SF_OK, &err);
    }
    struct storeq_result res = { .rc = rc, .err = &err };
    t->done(t->ud, &res);
    free(t->line);
    free(t->who);
    free(t);
}

/* The store did not answer in time: answer "busy", and send nothing when it does. */
static void
on_command_wait(struct loop *l, void *ud)
{
    (void)l;
    struct cmd_ticket *t = ud;
    t->timer = 0;
    t->answered = true;
    struct sf_err err = { 0 };
    int rc = sf_err_set(&err, SF_EBUSY,
                        "printer %s: whether it holds an interrupted job is not known: the store "
                        "is busy (its queue waits for the database): the command was not sent",
                        t->name);
    struct storeq_result res = { .rc = rc, .err = &err };
    t->done(t->ud, &res);
}

int
printer_command_then(struct printer *p, const char *line, const char *who, storeq_event_fn done,
                     void *ud, struct sf_err *err)
{
    int rc = command_checks(p, line, err);
    if (rc)
        return rc;
    struct cmd_ticket *t = mem_calloc(1, sizeof(*t));
    if (t) {
        *t = (struct cmd_ticket){ .p = p, .done = done, .ud = ud };
        snprintf(t->name, sizeof(t->name), "%s", p->cfg.name);
        t->line = mem_strdup(line);
        t->who = mem_strdup(who ? who : "");
    }
    /* after what p queued before it: a CRASHED still queued is seen */
    if (!t || !t->line || !t->who || storeq_read(p->env.q, held_read, t, on_held_read, t)) {
        if (t) {
            free(t->line);
            free(t->who);
        }
        free(t);
        return sf_err_set(err, SF_ENOMEM, "printer %s: out of memory", p->cfg.name);
    }
    t->next = p->cmds;
    p->cmds = t;
    t->l = p->env.l;
    t->timer = loop_timer_add(t->l, PRINTER_COMMAND_WAIT_MS, on_command_wait, t);
    return SF_OK;
}

int
printer_estop(struct printer *p, const char *who, struct sf_err *err)
{
    if (!p->drv || p->state == PRINTER_OFFLINE)
        return sf_err_set(err, SF_EUNREACH, "printer %s is offline: no emergency stop reaches it",
                          p->cfg.name);
    int rc = p->drv->ops->version >= 3 && p->drv->ops->estop ? p->drv->ops->estop(p->drv, err)
             : p->job_id                                     ? p->drv->ops->cancel(p->drv, err)
                         : SF_OK; /* nothing it could stop: the farm holds it in error */
    if (rc)
        return rc;
    char why[160];
    snprintf(why, sizeof(why), "emergency stop by an operator (%s)", who && who[0] ? who : "?");
    note(p, "printer-estop", "%s%s", why, p->job_id ? ": the job on it fails, not retried" : "");
    printer_set_bed(p, true); /* whatever it printed stays until an operator clears it */
    if (p->job_id) {
        struct job_event_args a = { .lines_acked = p->lines_acked,
                                    .reason = why,
                                    .no_retry = true };
        int64_t id = p->job_id;
        p->job_id = 0;
        printer_job_event(p, id, JOB_EV_PRINT_FAILED, &a);
    }
    snprintf(p->message, sizeof(p->message), "%s", why);
    if (p->state != PRINTER_ERROR)
        printer_move(p, PRINTER_EV_FAULT);
    return SF_OK;
}

/* Why a job (JOB_EV_CANCEL) or a copy of it (JOB_EV_CANCEL_COPY) ended. */
static const char *
cancel_reason(enum job_event jev)
{
    return jev == JOB_EV_CANCEL_COPY ? "copy cancelled by an operator: it prints again"
                                     : "cancelled by an operator";
}

/* Cancel the job (or copy, jev) p was starting while its file is judged: nothing was sent.
   The CANCEL follows its START in the store's queue; done(ud) once it committed. */
static int
cancel_judged(struct printer *p, enum job_event jev, storeq_event_fn done, void *ud,
              struct sf_err *err)
{
    struct job_event_args a = { .reason = cancel_reason(jev),
                                .fence = printer_fence(p, p->job_id) };
    if (storeq_job_event(p->env.q, p->job_id, jev, &a, p->cfg.name, done, ud))
        return sf_err_set(err, SF_ENOMEM, "printer %s: out of memory", p->cfg.name);
    p->job_id = p->judging = 0;
    printer_move(p, PRINTER_EV_REFUSED); /* idle again, the bed as it was */
    return SF_OK;
}

/* done(ud) once what an action queued (its printer's state, its bed) has committed. */
static int
answer_after(struct printer *p, storeq_event_fn done, void *ud, struct sf_err *err)
{
    if (done && storeq_barrier(p->env.q, done, ud))
        return sf_err_set(err, SF_ENOMEM,
                          "printer %s: out of memory: the action was taken, its answer is lost",
                          p->cfg.name);
    return SF_OK;
}

int
printer_action(struct printer *p, enum printer_action act, struct sf_err *err)
{
    return printer_action_then(p, act, NULL, NULL, err);
}

int
printer_action_then(struct printer *p, enum printer_action act, storeq_event_fn done, void *ud,
                    struct sf_err *err)
{
    static const enum printer_event evs[PRINTER_ACTION_COUNT] = {
        PRINTER_EV_PAUSE, PRINTER_EV_RESUME, PRINTER_EV_FINISHED, PRINTER_EV_CLEARED,
        PRINTER_EV_FINISHED
    };
    if ((unsigned)act >= PRINTER_ACTION_COUNT)
        return sf_err_set(err, SF_EINVAL, "printer %s: no action %d", p->cfg.name, (int)act);
    enum printer_event ev = evs[act];
    enum printer_state to;
    int rc = printer_next(p->state, ev, p->cfg.auto_eject, &to, err);
    if (rc)
        return sf_err_prefix(err, "printer %s", p->cfg.name);
    if (act == PRINTER_ACT_CLEARED) {
        if (p->state == PRINTER_ERROR && p->drv && p->drv->status.state != DRV_IDLE) {
            /* The driver has not seen the printer recover (its next poll
               may): take the operator's word for the bed now and leave the
               error when the driver reports idle, so no job goes to a
               printer that would refuse it. */
            printer_set_bed(p, false);
            p->error_cleared = true;
            snprintf(p->message, sizeof(p->message),
                     "cleared: waits for the printer to report ready");
            printer_changed(p);
            return answer_after(p, done, ud, err);
        }
        printer_move(p, ev);
        return answer_after(p, done, ud, err);
    }
    if (!p->drv || !p->job_id)
        return sf_err_set(err, SF_EINVAL, "printer %s has no job to %s", p->cfg.name,
                          action_names[act]);
    if (p->judging) /* the driver has nothing yet: a cancel is the store's alone */
        return act == PRINTER_ACT_CANCEL ? cancel_judged(p, JOB_EV_CANCEL, done, ud, err)
               : act == PRINTER_ACT_CANCEL_COPY
                   ? cancel_judged(p, JOB_EV_CANCEL_COPY, done, ud, err)
                   : sf_err_set(err, SF_EAGAIN,
                                "printer %s is starting its job: %s it once "
                                "it prints",
                                p->cfg.name, action_names[act]);
    /* The driver's own report of this comes on a later loop turn and finds
       the printer moved already. */
    rc = act == PRINTER_ACT_PAUSE    ? p->drv->ops->pause(p->drv, err)
         : act == PRINTER_ACT_RESUME ? p->drv->ops->resume(p->drv, err)
                                     : p->drv->ops->cancel(p->drv, err);
    if (rc)
        return rc;
    enum job_event jev = act == PRINTER_ACT_PAUSE         ? JOB_EV_PAUSE
                         : act == PRINTER_ACT_RESUME      ? JOB_EV_RESUME
                         : act == PRINTER_ACT_CANCEL_COPY ? JOB_EV_CANCEL_COPY
                                                          : JOB_EV_CANCEL;
    bool ends = jev == JOB_EV_CANCEL || jev == JOB_EV_CANCEL_COPY;
    struct job_event_args a = { .lines_acked = p->lines_acked,
                                .reason = cancel_reason(jev),
                                .filament_mm =
                                    printer_filament_mm(p, p->job_id, jev, p->lines_acked),
                                .fence = printer_fence(p, p->job_id) };
    if (ends && !p->cfg.auto_eject)
        printer_set_bed(p, true); /* the cancelled part stays on the bed */
    /* Queued: the loop does not wait for the store (a busy database held every printer's
       stream); the store's verdict goes to done, or is logged. */
    if (storeq_job_event(p->env.q, p->job_id, jev, &a, p->cfg.name, done, ud))
        return sf_err_set(err, SF_ENOMEM, "printer %s: out of memory", p->cfg.name);
    if (ends) {
        p->job_id = 0;
        if (p->drv->status.state == DRV_PRINTING) {
            /* still running the end sequence: printing with no job until
               DRV_EV_JOB_CANCELLED */
            printer_changed(p);
            return SF_OK;
        }
    }
    printer_move(p, ev);
    return SF_OK;
}

/* ---- fencing (one of several hosts) ---- */

/* A fenced job event on its way to the store: p, unless p was freed meanwhile. */
struct fence_watch {
    struct printer *p;
    struct fence_watch *next; /* in p->watches */
    int64_t id;               /* the job */
    enum job_event ev;        /* the event */
    int64_t lines_acked;      /* its lines */
};

void
printer_set_fence(struct printer *p, int64_t id, int64_t fence)
{
    p->fence_job = fence > 0 ? id : 0;
    p->fence = fence > 0 ? fence : 0;
}

int64_t
printer_fence(const struct printer *p, int64_t id)
{
    return id && p->fence_job == id ? p->fence : 0;
}

static void
on_fenced_event(void *ud, const struct storeq_result *r)
{
    struct fence_watch *w = ud;
    struct printer *p = w->p;
    for (struct fence_watch **pp = p ? &p->watches : NULL; pp && *pp; pp = &(*pp)->next)
        if (*pp == w) {
            *pp = w->next;
            break;
        }
    if (r->rc)
        log_msg(LOG_ERROR, "printer", "%s%s%s", p ? p->cfg.name : "", p ? ": " : "", r->err->msg);
    if (r->rc == SF_ESTALE && p) {
        if (w->ev == JOB_EV_PRINT_DONE) { /* whole here: said once the host holds it again */
            p->orphan.id = w->id;
            p->orphan.lines_acked = w->lines_acked;
            p->orphan.ev = JOB_EV_PRINT_DONE;
            p->orphan.why[0] = '\0';
        }
        printer_fenced_out(p, w->id);
        printer_settle_orphan(p);
    }
    free(w);
}

int
printer_fenced_event(struct printer *p, int64_t id, enum job_event ev,
                     const struct job_event_args *a)
{
    struct fence_watch *w = mem_calloc(1, sizeof(*w));
    if (!w)
        return SF_ENOMEM;
    *w = (struct fence_watch){
        .p = p, .next = p->watches, .id = id, .ev = ev, .lines_acked = a ? a->lines_acked : 0
    };
    if (storeq_job_event(p->env.q, id, ev, a, p->cfg.name, on_fenced_event, w)) {
        free(w);
        return SF_ENOMEM;
    }
    p->watches = w;
    return SF_OK;
}

void
printer_fenced_out(struct printer *p, int64_t id)
{
    if (p->fence_job == id)
        printer_set_fence(p, 0, 0);
    if (p->job_id != id)
        return; /* it ended here already: nothing more is written for it */
    log_printer(LOG_WARN, p->cfg.name,
                "job %lld: another host holds it now (its fencing token here is stale): "
                "this host lets it go",
                (long long)id);
    p->job_id = 0;
    p->judging = 0;
    struct sf_err err;
    if (!p->drv || p->drv->ops->attach) {
        /* a network printer prints on: for the host that holds the job now, or, when it is
           interrupted (this host was reaped), for this one again once it holds it
           (printer_settle_orphan: now, or at the next join); its end, if the driver sees it
           first, is recorded then */
        snprintf(p->message, sizeof(p->message), "printing job %lld, which another host holds",
                 (long long)id);
        if (p->drv) {
            p->away_id = id;
            p->attach_waits = 0;
        }
        printer_move(p, PRINTER_EV_DISCONNECTED);
    } else if (p->drv->ops->cancel(p->drv, &err)) { /* streamed from here: stop streaming */
        log_printer(LOG_ERROR, p->cfg.name, "job %lld: stop: %s", (long long)id, err.msg);
    }
    printer_changed(p);
}

/* The orphan's (or the away job's) read on the store's thread: for p (NULL once p is freed),
   of job id. */
struct orphan_ticket {
    struct printer *p; /* NULL: freed meanwhile */
    int64_t id;
    struct job_row j; /* the job as the store holds it */
};

/* The hold of the orphan's or the away job on the store's thread (env.hold_ask). */
struct hold_ticket {
    struct printer *p; /* NULL: freed meanwhile */
    int64_t id;
};

static int
orphan_read(struct store *s, void *arg, struct sf_err *err)
{
    struct orphan_ticket *t = arg;
    return store_job_get(s, t->id, &t->j, err);
}

/* The away job is not this printer's to take back: p connects as its driver says.  A driver
   that still prints it ends it with no job to record it on: its part stays on the bed. */
static void
away_drop(struct printer *p)
{
    enum drv_state ds = p->drv ? p->drv->status.state : DRV_OFFLINE;
    if (!p->cfg.auto_eject && (ds == DRV_PRINTING || ds == DRV_PAUSED))
        printer_set_bed(p, true);
    p->away_id = 0;
    p->attach_tried = true;
    if (p->drv)
        printer_apply_status(p);
}

/* Record the orphan's end: the host holds the job under fence (0: one host). */
static void
record(struct printer *p, int64_t id, int64_t fence)
{
    bool done = p->orphan.ev != JOB_EV_PRINT_FAILED;
    p->orphan.id = 0;
    if (done)
        log_printer(LOG_INFO, p->cfg.name,
                    "job %lld re-attached: its print ended whole while this host did not hold "
                    "it: recorded done",
                    (long long)id);
    else
        log_printer(LOG_INFO, p->cfg.name,
                    "job %lld re-attached: its print failed while this host did not hold it "
                    "(%s): recorded failed",
                    (long long)id, p->orphan.why);
    struct job_event_args a = { .printer = p->cfg.name,
                                .lines_acked = p->orphan.lines_acked,
                                .reason = done ? NULL : p->orphan.why,
                                .fence = fence };
    storeq_job_event(p->env.q, id, JOB_EV_RESUME, &a, p->cfg.name, NULL, NULL);
    printer_job_event(p, id, done ? JOB_EV_PRINT_DONE : JOB_EV_PRINT_FAILED, &a);
}

/* The away job is held under fence: p takes it back, printing as its driver says.  A driver
   that no longer prints it has its end on the way (the orphan's then) or lost the printer
   (the job stays interrupted: the next connection offers it). */
static void
take(struct printer *p, int64_t id, int64_t fence)
{
    enum drv_state ds = p->drv ? p->drv->status.state : DRV_OFFLINE;
    bool ended = false;
    for (size_t i = 0; i < p->n_queue; i++)
        ended = ended || p->queue[i].ev == DRV_EV_JOB_DONE || p->queue[i].ev == DRV_EV_JOB_FAILED;
    p->attach_tried = true;
    if (p->state != PRINTER_OFFLINE || ended || (ds != DRV_PRINTING && ds != DRV_PAUSED)) {
        if (!ended)
            away_drop(p);
        return;
    }
    p->away_id = 0;
    p->attempts = 0;
    p->attach_waits = 0;
    p->message[0] = '\0';
    printer_move(p, PRINTER_EV_CONNECTED);
    int64_t line = (int64_t)p->drv->status.lines_acked;
    struct sf_err err;
    if (printer_resume_fenced(p, id, line > 0 ? line : 0, fence, &err) == SF_OK)
        log_printer(LOG_INFO, p->cfg.name, "job %lld re-attached: the printer still has it",
                    (long long)id);
    else
        log_printer(LOG_ERROR, p->cfg.name, "job %lld: %s", (long long)id, err.msg);
}

/* The hold of job id came back (rc, fence): record the orphan's end, or take the away job
   back; a refusal that may pass (the store busy or away, the lease in doubt, the job's
   printer another live host's for now) asks again later, a few times. */
static void
held(struct printer *p, int64_t id, int rc, int64_t fence, const struct sf_err *err)
{
    bool orphan = p->orphan.id == id, away = !orphan && p->away_id == id && !p->job_id;
    if (!orphan && !away)
        return; /* p took another course meanwhile */
    if (rc == SF_OK) {
        if (orphan)
            record(p, id, fence);
        else
            take(p, id, fence);
        return;
    }
    const char *why = err && err->msg[0] ? err->msg : "the store refused";
    bool passing = rc == SF_EBUSY || rc == SF_EUNREACH || rc == SF_EAGAIN || rc == SF_ESTALE ||
                   rc == SF_EINDOUBT || rc == SF_ENOMEM;
    if (passing && printer_attach_later(p)) {
        log_printer(LOG_INFO, p->cfg.name, "job %lld: the hold waits: %s (asking again)",
                    (long long)id, why);
        snprintf(p->message, sizeof(p->message), "re-attaching job %lld: %s", (long long)id, why);
        return;
    }
    if (orphan) { /* kept when it may pass: the next join asks again */
        log_printer(LOG_WARN, p->cfg.name, "job %lld: its end is not recorded: %s", (long long)id,
                    why);
        if (!passing)
            p->orphan.id = 0;
        return;
    }
    log_printer(LOG_INFO, p->cfg.name, "job %lld stays interrupted: %s", (long long)id, why);
    away_drop(p);
}

static void
on_held(void *ud, int rc, int64_t fence, const struct sf_err *err)
{
    struct hold_ticket *t = ud;
    struct printer *p = t->p;
    int64_t id = t->id;
    free(t);
    if (!p)
        return;
    p->hticket = NULL;
    if (!p->deaf) {
        held(p, id, rc, fence, err);
        printer_attach_wake(p); /* an offer waited for this hold */
    }
    printer_changed(p);
}

/* Hold job id for p on the store's thread (env.hold_ask); held() acts on the answer.  One hold
   at a time: the one on its way answers for the orphan or the away job, whichever p has then. */
static void
hold(struct printer *p, int64_t id)
{
    if (p->hticket)
        return;
    struct sf_err err = { 0 };
    int64_t fence = 0;
    bool posted = false;
    struct hold_ticket *t = mem_calloc(1, sizeof(*t));
    int rc = !t ? sf_err_set(&err, SF_ENOMEM, "out of memory")
             : p->env.hold_ask
                 ? p->env.hold_ask(p->env.ud, id, p->cfg.name, &posted, on_held, t, &err)
             : p->env.hold ? p->env.hold(p->env.ud, id, &fence, &err)
                           : SF_OK;
    if (posted) {
        *t = (struct hold_ticket){ .p = p, .id = id };
        p->hticket = t;
        return;
    }
    free(t);
    if (rc == SF_EAGAIN && p->env.hold_ask) { /* no lease yet: the join asks again */
        p->hold_join = true;                  /* (no read till then: printer_settle_orphan) */
        if (p->away_id == id)
            snprintf(p->message, sizeof(p->message), "%s", err.msg);
        return;
    }
    held(p, id, rc, fence, &err);
}

void
printer_away_hold(struct printer *p)
{
    if (!p->away_id)
        return;
    snprintf(p->message, sizeof(p->message), "re-attaching job %lld: holding it",
             (long long)p->away_id);
    hold(p, p->away_id);
}

void
printer_away_ended(struct printer *p, enum job_event ev, int64_t lines, const char *why)
{
    int64_t id = p->away_id;
    p->away_id = 0;
    p->orphan.id = id;
    p->orphan.lines_acked = lines;
    p->orphan.ev = ev;
    snprintf(p->orphan.why, sizeof(p->orphan.why), "%s", why ? why : "");
    if (!p->cfg.auto_eject)
        printer_set_bed(p, true); /* its part is on the bed */
    log_printer(LOG_INFO, p->cfg.name,
                "job %lld: the printer ended it (%s) while this host did not hold it: recorded "
                "once it does",
                (long long)id, ev == JOB_EV_PRINT_FAILED ? "failed" : "done");
    printer_settle_orphan(p);
    if (p->drv) /* it waited offline for the job (printer.c apply): it connects now, as its
                   driver says (its bed full first) */
        printer_apply_status(p);
    printer_changed(p);
}

/* The orphan's (or away job's) job came back: hold it if it is still interrupted on p. */
static void
on_orphan_read(void *ud, const struct storeq_result *r)
{
    struct orphan_ticket *t = ud;
    struct printer *p = t->p;
    int64_t id = t->id;
    struct job_row j = t->j;
    free(t);
    if (!p)
        return;
    p->oticket = NULL;
    bool orphan = p->orphan.id == id, away = !orphan && p->away_id == id && !p->job_id;
    /* only while nobody took it on since: interrupted, on this printer */
    bool mine = !r->rc && j.state == JOB_INTERRUPTED && strcmp(j.printer, p->cfg.name) == 0;
    if (p->deaf || (!orphan && !away)) {
        /* p took another course meanwhile */
    } else if (r->rc) { /* the store away: an orphan at the next join; the away job later */
        if (away && !printer_attach_later(p)) {
            log_printer(LOG_INFO, p->cfg.name, "job %lld stays interrupted: %s", (long long)id,
                        r->err ? r->err->msg : "the store did not answer");
            away_drop(p);
        }
    } else if (!mine) {
        if (away)
            log_printer(LOG_INFO, p->cfg.name,
                        "job %lld is %s (on printer '%s'): not taken back here", (long long)id,
                        job_state_name(j.state), j.printer);
        if (orphan)
            p->orphan.id = 0;
        else
            away_drop(p);
    } else {
        hold(p, id); /* and record its end, or take it back, once held */
    }
    if (!p->deaf)
        printer_attach_wake(p); /* an offer waited for this read (printer_attach_offer) */
}

void
printer_settle_orphan(struct printer *p)
{
    int64_t id = p->orphan.id ? p->orphan.id : p->away_id;
    /* the job is read on the store's thread (after what p queued before), then held; one
       read and one hold at a time: the one on its way settles it, or the next join or attach
       asks again */
    if (!id || !p->env.hold || p->oticket || p->hticket || p->hold_join)
        return;
    struct orphan_ticket *t = mem_calloc(1, sizeof(*t));
    if (!t)
        return; /* at the next join or attach */
    *t = (struct orphan_ticket){ .p = p, .id = id };
    if (storeq_read(p->env.q, orphan_read, t, on_orphan_read, t)) {
        free(t);
        return;
    }
    p->oticket = t;
}

void
printer_fence_release(struct printer *p)
{
    for (struct fence_watch *w = p->watches; w; w = w->next)
        w->p = NULL;
    p->watches = NULL;
    if (p->oticket)
        p->oticket->p = NULL; /* its orphan's read too */
    p->oticket = NULL;
    if (p->hticket)
        p->hticket->p = NULL; /* and its hold */
    p->hticket = NULL;
    for (struct cmd_ticket *t = p->cmds; t; t = t->next)
        t->p = NULL; /* and its commands' */
    p->cmds = NULL;
}
