/*
 * printer.c - one printer: its state machine, its driver, the job on it and
 * its bed gate (printer.h).
 *
 * Why its own module: the printer's state used to live in three places (the
 * driver's status, the farm's struct printer, a shadow "cancelling" flag)
 * and driver events came back as calls into whoever had just called the
 * driver, so the farm carried guards against applying a move twice.  Here
 * the printer state is job.h's machine alone, fed by one queue of driver
 * events, and every other module sees the printer only through printer.h.
 *
 * Design: the driver callback copies (event, status) into p->queue and arms
 * a zero-delay timer; the timer applies the queue in order.  A timer, not
 * loop_post(): a posted callback cannot be withdrawn, and a printer freed
 * on reload with events queued must take them with it.  A cancel whose end
 * sequence still runs is a printing printer with no job, freed by
 * DRV_EV_JOB_CANCELLED.
 *
 * Files: this one holds the state machine, the link, the driver events and
 * the jobs' start and resume; printer_attach.c the offer of an interrupted
 * job to a network printer that comes back; printer_heat.c the heaters' hold after an
 * interruption (hold_heat_min), printer_op.c the operator's actions (pause,
 * resume, cancel, clear, manual command, emergency stop); printer_int.h
 * what they share (struct printer), internal to these files.
 *
 * Thread: the loop thread.
 */
#include "printer.h"
#include "printer_int.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../drivers/drv_link.h"
#include "../base/log.h"
#include "../base/mem.h"
#include "gcjob.h"

#define PRINTER_SAVE_LINES 16 /* progress this far ahead of the store is saved at once */

/*
 * A START on its way to the store: the printer it is for (NULL once that
 * printer is freed: printer_free) and which start it was.  The store
 * thread's callback gets the ticket, not the printer, which a reload may
 * free in between.
 */
struct start_ticket {
    struct printer *p; /* NULL: freed meanwhile */
    int64_t job_id;
    uint64_t token; /* p->judging of that start */
};

/* A resume's read that came before its RESUME committed (printer_resume_go's arguments). */
struct resume_go {
    char path[1200];
    uint64_t line;
    struct drv_job_scan scan;
    double est_s;
    int rc;
    char why[1024];
};

/* A start's verdict that came before its START committed (printer_start_go's arguments). */
struct start_go {
    char path[1200];
    struct drv_job_scan scan;
    bool has_scan;
    struct filament fil;
    bool has_fil;
    int rc;
    char why[1024];
};

void
printer_changed(struct printer *p)
{
    if (p->env.changed)
        p->env.changed(p->env.ud);
}

/* Record whether p's bed holds a part; a crash after this keeps the bed gate. */
void
printer_set_bed(struct printer *p, bool full)
{
    if (p->bed_full == full)
        return;
    p->bed_full = full;
    storeq_printer_bed_set(p->env.q, p->cfg.name, full); /* a failure is logged there */
}

/*
 * Move p by ev; log refusals (they mean a driver said something odd).  The
 * bed is recorded here, before the caller records the job: a printer whose
 * bed holds a part comes back from any restart or reconnect awaiting clear.
 */
bool
printer_move(struct printer *p, enum printer_event ev)
{
    struct sf_err err;
    enum printer_state to;
    if (printer_next(p->state, ev, p->cfg.auto_eject, &to, &err)) {
        log_printer(LOG_WARN, p->cfg.name, "%s", err.msg);
        return false;
    }
    if (ev == PRINTER_EV_CONNECTED && to == PRINTER_IDLE && p->bed_full)
        to = PRINTER_AWAITING_CLEAR;
    if (to == PRINTER_AWAITING_CLEAR)
        printer_set_bed(p, true);
    else if (ev == PRINTER_EV_CLEARED)
        printer_set_bed(p, false);
    if (to != PRINTER_ERROR)
        p->error_cleared = false;
    if (to != p->state) {
        p->state = to;
        storeq_printer_set(p->env.q, p->cfg.name, to);
    }
    printer_changed(p);
    return true;
}

/* Apply a job event in the store, logging failures (the job fails alone). */
double
printer_filament_mm(const struct printer *p, int64_t id, enum job_event ev, int64_t lines)
{
    if (!id || p->fil.job_id != id)
        return 0;
    return ev == JOB_EV_PRINT_DONE ? filament_at(&p->fil, p->fil.lines)
                                   : filament_at(&p->fil, lines);
}

int
printer_job_event(struct printer *p, int64_t id, enum job_event ev, const struct job_event_args *a)
{
    struct job_event_args with = a ? *a : (struct job_event_args){ 0 };
    if (ev == JOB_EV_PRINT_DONE || ev == JOB_EV_PRINT_FAILED || ev == JOB_EV_CANCEL ||
        ev == JOB_EV_CANCEL_COPY)
        with.filament_mm = printer_filament_mm(p, id, ev, with.lines_acked);
    if (!with.fence)
        with.fence = printer_fence(p, id);
    /* a failure is logged when it comes back; its commit wakes the farm (farm.c) */
    int rc = with.fence
                 ? printer_fenced_event(p, id, ev, &with)
                 : storeq_job_event(p->env.q, id, ev, a ? &with : NULL, p->cfg.name, NULL, NULL);
    printer_changed(p);
    return rc;
}

/* The job on p ended badly (drop, fault): fail it, keep the retry policy. */
static void
fail_job(struct printer *p, const char *why)
{
    if (!p->job_id)
        return;
    struct job_event_args a = { .lines_acked = p->lines_acked, .reason = why };
    int64_t id = p->job_id;
    p->job_id = 0;
    printer_job_event(p, id, JOB_EV_PRINT_FAILED, &a);
}

/*
 * A network printer went unreachable with a job on it: the printer prints
 * on without us, so the job is interrupted (as by a daemon crash), not
 * failed, and re-attached when the printer answers again.
 */
static void
interrupt_job(struct printer *p, const char *why)
{
    char reason[200];
    snprintf(reason, sizeof(reason), "printer unreachable while printing: %s", why);
    struct job_event_args a = { .reason = reason };
    int64_t id = p->job_id;
    p->job_id = 0;
    struct store_progress sp = { id, p->lines_acked, false, printer_fence(p, id) };
    storeq_jobs_progress(p->env.q, &sp, 1);
    log_printer(LOG_WARN, p->cfg.name, "job %lld interrupted: %s", (long long)id, reason);
    printer_job_event(p, id, JOB_EV_CRASHED, &a);
}

/* ---- link ---- */

static void connect_printer(struct printer *p);

static void
on_reconnect(struct loop *l, void *ud)
{
    (void)l;
    struct printer *p = ud;
    p->reconnect = 0;
    connect_printer(p);
}

static void
schedule_reconnect(struct printer *p)
{
    if (p->reconnect || !p->drv || !p->cfg.enabled)
        return;
    p->reconnect = loop_timer_add(p->env.l, drv_backoff_ms(p->attempts++), on_reconnect, p);
}

static void
connect_printer(struct printer *p)
{
    struct sf_err err;
    if (p->drv->ops->open(p->drv, &err)) {
        snprintf(p->message, sizeof(p->message), "%s", err.msg);
        log_printer(LOG_WARN, p->cfg.name, "connect: %s", err.msg);
        schedule_reconnect(p);
    }
}

/* ---- driver events, applied on a later loop turn ---- */

static void apply(struct printer *p, enum drv_event ev, const struct drv_status *st);

void
printer_apply_status(struct printer *p)
{
    apply(p, DRV_EV_STATE, &p->drv->status);
}

static void
apply(struct printer *p, enum drv_event ev, const struct drv_status *st)
{
    switch (ev) {
    case DRV_EV_STATE:
        if (p->state == PRINTER_OFFLINE && p->drv->ops->attach &&
            (!p->attach_tried || p->away_id) &&
            (st->state == DRV_IDLE || st->state == DRV_PRINTING || st->state == DRV_PAUSED)) {
            /* tried only once the driver could answer: p waits offline for the store's
               answer, and "not yet" (SF_EAGAIN) asks again, so the job is not left
               interrupted until the next reconnect (printer_attach.c); a print it runs for
               this host, not held now (away_id), keeps it offline until held or ended */
            if (printer_attach_offer(p))
                break;
        }
        if (st->state == DRV_IDLE && p->state == PRINTER_OFFLINE) {
            p->attempts = 0;
            p->message[0] = '\0';
            printer_move(p, PRINTER_EV_CONNECTED);
        } else if (st->state == DRV_OFFLINE && p->state != PRINTER_OFFLINE) {
            if (p->job_id && p->drv->ops->attach)
                interrupt_job(p, st->message);
            else
                fail_job(p, "printer went offline");
            p->attach_tried = false;
            p->attach_waits = 0;
            snprintf(p->message, sizeof(p->message), "%s", st->message);
            if (p->state == PRINTER_ERROR && !p->error_cleared)
                printer_set_bed(p, true); /* the error's look is owed: it comes back awaiting
                                             clear, never idle (a wedged Marlin's new link) */
            printer_move(p, PRINTER_EV_DISCONNECTED);
            schedule_reconnect(p);
        } else if (st->state == DRV_ERROR && p->state != PRINTER_ERROR) {
            fail_job(p, st->message[0] ? st->message : "printer reported an error");
            snprintf(p->message, sizeof(p->message), "%s", st->message);
            printer_move(p, PRINTER_EV_FAULT);
        } else if (st->state == DRV_IDLE && p->state == PRINTER_ERROR && p->error_cleared) {
            p->message[0] = '\0'; /* the printer recovered after the operator's clear */
            printer_move(p, PRINTER_EV_CLEARED);
        } else if (p->state == PRINTER_IDLE && !p->job_id &&
                   (st->state == DRV_PRINTING || st->state == DRV_PAUSED) &&
                   (p->drv->status.state == DRV_PRINTING || p->drv->status.state == DRV_PAUSED)) {
            /* someone started a print at the printer (the driver still says
               so: not a report from before a cancel): it is not ours to use
               until the driver sees it idle again */
            snprintf(p->message, sizeof(p->message), "%s",
                     st->message[0] ? st->message : "busy with a print the farm did not start");
            printer_move(p, PRINTER_EV_DISCONNECTED);
        } else if (st->state == DRV_OFFLINE && p->drv->ops->attach) {
            /* a network printer still offline (its connect failed): say why, try later */
            p->attach_tried = false;
            p->attach_waits = 0;
            if (st->message[0])
                snprintf(p->message, sizeof(p->message), "%s", st->message);
            schedule_reconnect(p);
        } else if (p->state == PRINTER_OFFLINE &&
                   (st->state == DRV_PRINTING || st->state == DRV_PAUSED) && st->message[0]) {
            snprintf(p->message, sizeof(p->message), "%s", st->message); /* busy, not ours */
        } else if (st->state == DRV_PAUSED && p->state == PRINTER_PRINTING && p->job_id) {
            /* paused by the printer itself (filament runout, M600) */
            struct job_event_args a = { .lines_acked = p->lines_acked };
            printer_job_event(p, p->job_id, JOB_EV_PAUSE, &a);
            printer_move(p, PRINTER_EV_PAUSE);
        } else if (st->state == DRV_PRINTING && p->state == PRINTER_PAUSED && p->job_id) {
            printer_job_event(p, p->job_id, JOB_EV_RESUME, NULL);
            printer_move(p, PRINTER_EV_RESUME);
        }
        break;
    case DRV_EV_PROGRESS:
        p->lines_acked = (int64_t)st->lines_acked;
        if (p->job_id && p->lines_acked >= p->lines_saved + PRINTER_SAVE_LINES) {
            /* Saved at once, not on the farm's timer: a resume after a crash
               re-runs at most these lines plus what the driver had not yet
               reported (drivers report every 16 lines or 250 ms). */
            struct store_progress sp = { p->job_id, p->lines_acked, false,
                                         printer_fence(p, p->job_id) };
            if (storeq_jobs_progress(p->env.q, &sp, 1) == SF_OK)
                p->lines_saved = p->lines_acked;
        }
        break;
    case DRV_EV_TEMPS:
        break; /* read from the driver's status when asked */
    case DRV_EV_JOB_DONE: {
        if (!p->job_id && p->away_id) { /* a print this host does not hold now */
            printer_away_ended(p, JOB_EV_PRINT_DONE, (int64_t)st->lines_acked, NULL);
            break;
        }
        /* the bed first: a crash between the two leaves the job interrupted */
        struct job_event_args a = { .lines_acked = (int64_t)st->lines_acked };
        int64_t id = p->job_id;
        p->job_id = 0;
        printer_move(p, PRINTER_EV_FINISHED);
        if (id)
            printer_job_event(p, id, JOB_EV_PRINT_DONE, &a);
        break;
    }
    case DRV_EV_JOB_CANCELLED:
        /* The cancel was recorded when it was asked; a printer still
           printing with no job ran the end sequence, and is free now. */
        if (p->state == PRINTER_PRINTING && !p->job_id)
            printer_move(p, PRINTER_EV_FINISHED);
        break;
    case DRV_EV_JOB_FAILED:
        if (!p->job_id && p->away_id) {
            printer_away_ended(p, JOB_EV_PRINT_FAILED, (int64_t)st->lines_acked,
                               st->message[0] ? st->message : "the print stopped");
            break;
        }
        p->lines_acked = (int64_t)st->lines_acked;
        if (st->state == DRV_ERROR && st->message[0] && p->state != PRINTER_ERROR)
            snprintf(p->message, sizeof(p->message), "%s", st->message); /* why it halted */
        fail_job(p, st->message[0] ? st->message : "the print stopped");
        if (p->state == PRINTER_PRINTING || p->state == PRINTER_PAUSED)
            printer_move(p, st->state == DRV_ERROR ? PRINTER_EV_FAULT : PRINTER_EV_FINISHED);
        break;
    }
}

static void
deliver(struct loop *l, void *ud)
{
    (void)l;
    struct printer *p = ud;
    p->deliver = 0;
    if (p->bticket)
        return; /* its bed is not known yet: the events wait for it (printer_bed_read) */
    /* apply() never calls the driver back into this queue synchronously,
       but a reconnect's open() may queue more: those wait for the next timer */
    size_t n = p->n_queue;
    struct queued *q = p->queue;
    p->queue = NULL;
    p->n_queue = p->cap_queue = 0;
    for (size_t i = 0; i < n && !p->deaf; i++)
        apply(p, q[i].ev, &q[i].st);
    free(q);
    if (!p->deaf)
        printer_heat_watch(p);
}

static void
on_drv_event(struct drv *d, enum drv_event ev, void *ud)
{
    struct printer *p = ud;
    if (p->deaf)
        return;
    if (!mem_grow((void **)&p->queue, &p->cap_queue, p->n_queue + 1, sizeof(*p->queue))) {
        log_printer(LOG_ERROR, p->cfg.name, "out of memory: driver event %d lost", (int)ev);
        return;
    }
    p->queue[p->n_queue++] = (struct queued){ ev, d->status };
    if (!p->deliver)
        p->deliver = loop_timer_add(p->env.l, 0, deliver, p);
}

/* ---- lifecycle ---- */

/* A new printer's bed on its way from the store's thread (printer_bed_read). */
struct bed_ticket {
    struct printer *p; /* NULL: freed meanwhile */
    char name[sizeof(((struct farmcfg_printer *)0)->name)];
    bool full;
};

static int
bed_read(struct store *s, void *arg, struct sf_err *err)
{
    struct bed_ticket *t = arg;
    return store_printer_bed_get(s, t->name, &t->full, err);
}

/* The bed came back: the gate is known, and the driver's events that waited are applied. */
static void
on_bed_read(void *ud, const struct storeq_result *r)
{
    struct bed_ticket *t = ud;
    struct printer *p = t->p;
    bool full = t->full;
    free(t);
    if (!p)
        return;
    p->bticket = NULL;
    /* a bed it cannot read is taken as holding a part: nothing starts on it until cleared */
    if (r->rc)
        log_printer(LOG_ERROR, p->cfg.name, "%s: its bed is taken as holding a part", r->err->msg);
    p->bed_full = r->rc ? true : full;
    if (p->bed_full)
        log_printer(LOG_INFO, p->cfg.name, "its bed holds a part: clear it before the next job");
    if (p->n_queue && !p->deliver && !p->deaf)
        p->deliver = loop_timer_add(p->env.l, 0, deliver, p);
    printer_changed(p);
}

/* Read p's bed on the store's thread, after what was queued before (a bed set by the printer
   p replaces); until it comes back p takes its bed as full and its driver's events wait. */
static void
printer_bed_read(struct printer *p)
{
    p->bed_full = true;
    struct bed_ticket *t = mem_calloc(1, sizeof(*t));
    if (t) {
        t->p = p;
        snprintf(t->name, sizeof(t->name), "%s", p->cfg.name);
    }
    if (!t || storeq_read(p->env.q, bed_read, t, on_bed_read, t)) {
        free(t);
        log_printer(LOG_ERROR, p->cfg.name, "out of memory: its bed is taken as holding a part");
        return;
    }
    p->bticket = t;
}

static void
printer_bed_release(struct printer *p)
{
    if (p->bticket)
        p->bticket->p = NULL;
    p->bticket = NULL;
}

struct printer *
printer_new(const struct printer_env *env, const struct farmcfg_printer *cfg)
{
    struct printer *p = mem_calloc(1, sizeof(*p));
    if (!p)
        return NULL;
    p->est_s = -1;
    p->env = *env;
    p->cfg = *cfg;
    p->state = PRINTER_OFFLINE;
    struct sf_err err;
    storeq_printer_set(env->q, cfg->name, PRINTER_OFFLINE);
    /* The bed a printer of this name just had (farm_apply replaces printers), read on the
       store's thread after what was queued (printer_bed_read): until it is known the bed
       is taken as holding a part and the driver's events wait, so nothing starts on it. */
    if (env->bed_known) { /* the printer it replaces knew it (a reload): nothing to read */
        p->bed_full = env->bed_full;
        if (p->bed_full)
            log_printer(LOG_INFO, cfg->name, "its bed holds a part: clear it before the next job");
    } else {
        printer_bed_read(p);
    }
    if (!cfg->enabled) {
        if (cfg->disabled[0]) /* by an operator, at run time (farm.h) */
            snprintf(p->message, sizeof(p->message), "disabled: %s", cfg->disabled);
        else
            snprintf(p->message, sizeof(p->message), "disabled in the config");
        return p;
    }
    if (!env->driver) {
        snprintf(p->message, sizeof(p->message), "not connected: the farm runs without drivers");
        return p;
    }
    struct drv_config dc = { .name = p->cfg.name, .kind = p->cfg.driver };
    drv_link_config(&p->cfg.link, drv_kind_find(p->cfg.driver), &dc);
    p->drv = env->driver(env->l, &dc, on_drv_event, p, &err);
    if (!p->drv) {
        snprintf(p->message, sizeof(p->message), "%s", err.msg);
        log_printer(LOG_ERROR, cfg->name, "%s", err.msg);
        return p;
    }
    connect_printer(p);
    return p;
}

void
printer_stop(struct printer *p)
{
    struct job_event_args a = { .reason = "the daemon stopped while this job was printing" };
    p->deaf = true;
    if (!p->job_id)
        return;
    /* queued: the farm drains the queue before the store closes (storeq_free) */
    struct store_progress sp = { p->job_id, p->lines_acked, false, printer_fence(p, p->job_id) };
    a.fence = sp.fence;
    storeq_jobs_progress(p->env.q, &sp, 1);
    storeq_job_event(p->env.q, p->job_id, JOB_EV_CRASHED, &a, p->cfg.name, NULL, NULL);
}

void
printer_free(struct printer *p)
{
    if (!p)
        return;
    p->deaf = true; /* close() reports OFFLINE at once */
    if (p->reconnect)
        loop_timer_cancel(p->env.l, p->reconnect);
    if (p->deliver)
        loop_timer_cancel(p->env.l, p->deliver);
    if (p->hold)
        loop_timer_cancel(p->env.l, p->hold);
    if (p->attach_retry)
        loop_timer_cancel(p->env.l, p->attach_retry);
    if (p->heat_timer)
        loop_timer_cancel(p->env.l, p->heat_timer);
    if (p->drv) {
        /* drv_free() lives with the drivers; the vtable is all we rely on. */
        p->drv->ops->close(p->drv);
        p->drv->ops->destroy(p->drv);
    }
    printer_fence_release(p);
    if (p->ticket)
        p->ticket->p = NULL; /* its START comes back to no one */
    if (p->rticket)
        p->rticket->p = NULL;  /* its RESUME too */
    printer_attach_release(p); /* its interrupted job's read too */
    printer_bed_release(p);    /* and its bed's */
    free(p->go);
    free(p->rgo);
    free(p->queue);
    free(p);
}

/* ---- queries ---- */

const struct farmcfg_printer *
printer_cfg(const struct printer *p)
{
    return &p->cfg;
}

void
printer_set_cfg(struct printer *p, const struct farmcfg_printer *cfg)
{
    p->cfg = *cfg;
}

enum printer_state
printer_state(const struct printer *p)
{
    return p->state;
}

int64_t
printer_job(const struct printer *p)
{
    return p->job_id;
}

bool
printer_connected(const struct printer *p)
{
    return p->drv && p->drv->status.state == DRV_IDLE && !p->hold;
}

void
printer_set_removed(struct printer *p, bool removed)
{
    p->removed = removed;
}

bool
printer_removed(const struct printer *p)
{
    return p->removed;
}

bool
printer_bed_full(const struct printer *p)
{
    return p->bed_full;
}

bool
printer_bed_known(const struct printer *p)
{
    return !p->bticket;
}

void
printer_info(const struct printer *p, struct printer_info *out)
{
    memset(out, 0, sizeof(*out));
    out->cfg = &p->cfg;
    out->state = p->state;
    out->job_id = p->job_id;
    out->message = p->message;
    out->time_left_s = -1;
    out->time_left_from = "";
    if (p->drv) {
        const struct drv_status *st = &p->drv->status;
        if (p->job_id && st->has_time_left) {
            out->time_left_s = st->time_left_s; /* the printer's own */
            out->time_left_from = "printer";
        } else if (p->job_id && p->est_s >= 0) {
            /* the farm's: the G-code's estimate, what the progress leaves of it */
            double left = p->est_s * (1 - (st->progress < 0   ? 0
                                           : st->progress > 1 ? 1
                                                              : st->progress));
            out->time_left_s = (int64_t)(left + 0.5);
            out->time_left_from = "farm";
        }
        out->progress = st->progress;
        out->nozzle_c = st->nozzle_c;
        out->nozzle_target_c = st->nozzle_target_c;
        out->bed_c = st->bed_c;
        out->bed_target_c = st->bed_target_c;
    }
}

bool
printer_progress(const struct printer *p, int64_t *job_id, int64_t *lines)
{
    if (!p->job_id || p->lines_acked == p->lines_saved)
        return false;
    *job_id = p->job_id;
    *lines = p->lines_acked;
    return true;
}

void
printer_progress_saved(struct printer *p, int64_t lines)
{
    p->lines_saved = lines;
}

/* ---- jobs ---- */

/* How drive() words a refused start; the hold's end clears only that message. */
#define PRINTER_REFUSED_MSG "refused a start"

static void
on_hold_end(struct loop *l, void *ud)
{
    (void)l;
    struct printer *p = ud;
    p->hold = 0;
    if (strncmp(p->message, PRINTER_REFUSED_MSG, sizeof(PRINTER_REFUSED_MSG) - 1) == 0)
        p->message[0] = '\0';
    printer_changed(p); /* the scheduler may use p again */
}

/*
 * Hand the job to the driver.  "Not now" (SF_EAGAIN: the printer is not
 * idle, an action is on its way) sends the job back to ready without
 * spending a retry, and p takes no job for drv_backoff_ms(refusals) (0.5 s
 * doubling to 30 s), so a printer that always refuses cannot spin; any
 * other refusal (a bad file, a bad resume line) fails the print.
 */
static void
drive(struct printer *p, const char *path, uint64_t line, const struct drv_job_scan *scan)
{
    struct sf_err err;
    int rc = p->drv->ops->start_job(p->drv, path, line, scan, &err);
    if (rc == SF_OK) {
        p->refusals = 0;
        return;
    }
    log_printer(LOG_WARN, p->cfg.name, "job %lld: %s", (long long)p->job_id, err.msg);
    if (rc != SF_EAGAIN) {
        fail_job(p, err.msg);
        printer_move(p, PRINTER_EV_FINISHED);
        return;
    }
    int64_t id = p->job_id, wait_ms = drv_backoff_ms(p->refusals++);
    struct job_event_args a = { .reason = err.msg };
    p->job_id = 0;
    if (p->hold)
        loop_timer_cancel(p->env.l, p->hold);
    p->hold = loop_timer_add(p->env.l, wait_ms, on_hold_end, p);
    snprintf(p->message, sizeof(p->message), PRINTER_REFUSED_MSG " (%s): takes no job for %lld ms",
             err.msg, (long long)wait_ms);
    printer_move(p, PRINTER_EV_REFUSED);
    printer_job_event(p, id, JOB_EV_REFUSED, &a);
}

static void go(struct printer *p, int64_t id, const char *path, const struct drv_job_scan *scan,
               const struct filament *fil, int rc, const char *why);

/* The START came back: the driver may have the job now (if judged), or p lets it go. */
static void
on_start(void *ud, const struct storeq_result *r)
{
    struct start_ticket *t = ud;
    struct printer *p = t->p;
    int64_t id = r->id;
    /* deaf: the daemon stops (printer_stop queued the job's CRASHED behind it): send nothing */
    bool current = p && !p->deaf && p->job_id == id && p->judging && p->judging == t->token;
    free(t);
    if (!p)
        return;
    p->ticket = NULL;
    struct start_go *g = p->go;
    p->go = NULL;
    if (r->rc) {
        log_printer(LOG_WARN, p->cfg.name, "%s", r->err->msg);
        if (current) { /* nothing was sent: idle again, the bed as it was */
            p->job_id = p->judging = 0;
            printer_move(p, PRINTER_EV_REFUSED);
        }
    } else if (current && g) {
        go(p, id, g->path, g->has_scan ? &g->scan : NULL, g->has_fil ? &g->fil : NULL, g->rc,
           g->why);
    }
    free(g);
    printer_changed(p);
}

int
printer_start(struct printer *p, const struct job_row *j, const char *path)
{
    /* Queued, and the driver gets nothing before it commits (on_start): a crash from then
       on leaves the job interrupted, one before it leaves the job ready. */
    struct start_ticket *t = mem_calloc(1, sizeof(*t));
    if (!t)
        return SF_ENOMEM;
    *t = (struct start_ticket){ p, j->id, ++p->starts };
    struct job_event_args a = { .printer = p->cfg.name, .fence = printer_fence(p, j->id) };
    if (storeq_job_event(p->env.q, j->id, JOB_EV_START, &a, p->cfg.name, on_start, t)) {
        free(t);
        return SF_ENOMEM;
    }
    if (p->ticket)
        p->ticket->p = NULL; /* an earlier start's, cancelled meanwhile: stale */
    free(p->go);
    p->go = NULL;
    p->ticket = t;
    p->job_id = j->id;
    p->lines_acked = p->lines_saved = 0;
    p->est_s = printer_estimate_s(j, path);
    p->judging = t->token;
    printer_move(p, PRINTER_EV_START);
    return SF_OK;
}

uint64_t
printer_start_token(const struct printer *p)
{
    return p->judging;
}

void
printer_start_go(struct printer *p, int64_t id, uint64_t token, const char *path,
                 const struct drv_job_scan *scan, const struct filament *fil, int rc,
                 const char *why)
{
    /* Cancelled, or its printer lost (and the job perhaps resumed since, or, a copy cancelled,
       started again), while the file was judged: this check is stale. */
    if (p->job_id != id || !p->judging || p->judging != token)
        return;
    if (p->ticket) { /* its START is still on its way: keep the verdict for on_start */
        struct start_go *g = mem_calloc(1, sizeof(*g));
        if (!g) {
            log_printer(LOG_ERROR, p->cfg.name, "job %lld: out of memory", (long long)id);
            return; /* p keeps the job until an operator cancels it */
        }
        snprintf(g->path, sizeof(g->path), "%s", path);
        if ((g->has_scan = scan != NULL))
            g->scan = *scan;
        if ((g->has_fil = fil != NULL))
            g->fil = *fil;
        g->rc = rc;
        snprintf(g->why, sizeof(g->why), "%s", why ? why : "");
        free(p->go);
        p->go = g;
        return;
    }
    go(p, id, path, scan, fil, rc, why);
}

/* Hand the judged start to the driver, or fail it with why (its START committed). */
static void
go(struct printer *p, int64_t id, const char *path, const struct drv_job_scan *scan,
   const struct filament *fil, int rc, const char *why)
{
    p->judging = 0;
    p->fil.job_id = 0;
    if (fil && fil->job_id == id)
        p->fil = *fil;
    if (rc == SF_OK) {
        drive(p, path, 0, scan);
        return;
    }
    /* A retry would judge the same file the same way. */
    log_printer(LOG_WARN, p->cfg.name, "job %lld refused at its start: %s", (long long)id, why);
    struct job_event_args a = { .reason = why, .no_retry = true };
    p->job_id = 0;
    printer_move(p, PRINTER_EV_REFUSED);
    printer_job_event(p, id, JOB_EV_PRINT_FAILED, &a);
}

static void resume_go(struct printer *p, int64_t id, const char *path, uint64_t line,
                      const struct drv_job_scan *scan, double est_s, int rc, const char *why);

/* The RESUME came back: the driver may have the job now (if read), or p lets it go. */
static void
on_resume(void *ud, const struct storeq_result *r)
{
    struct start_ticket *t = ud;
    struct printer *p = t->p;
    int64_t id = r->id;
    bool mine = p && p->rticket == t; /* not a later resume's */
    bool current = mine && !p->deaf && p->job_id == id;
    free(t);
    if (!p)
        return;
    if (mine)
        p->rticket = NULL;
    struct resume_go *g = current ? p->rgo : NULL;
    if (current)
        p->rgo = NULL;
    if (r->rc) {
        log_printer(LOG_WARN, p->cfg.name, "job %lld: %s", (long long)id, r->err->msg);
        if (current) { /* the store did not take it: nothing was sent, idle again */
            p->job_id = 0;
            printer_move(p, PRINTER_EV_REFUSED);
        }
    } else if (g) {
        resume_go(p, id, g->path, g->line, &g->scan, g->est_s, g->rc, g->why);
    }
    free(g);
    printer_changed(p);
}

int
printer_resume_commit(struct printer *p, int64_t id, int64_t line, struct sf_err *err)
{
    /* Queued (the loop does not wait for the store): p takes the job at once and the driver
       gets it only once the RESUME has committed (on_resume), so a crash before that leaves
       it interrupted, with nothing sent. */
    int64_t fence = 0;
    /* one of several hosts: the job is this host's (attached) before it resumes here */
    if (p->env.hold) {
        int rc = p->env.hold(p->env.ud, id, &fence, err);
        if (rc)
            return rc;
    }
    return printer_resume_fenced(p, id, line, fence, err);
}

int
printer_resume_fenced(struct printer *p, int64_t id, int64_t line, int64_t fence,
                      struct sf_err *err)
{
    struct start_ticket *t = mem_calloc(1, sizeof(*t));
    if (!t)
        return sf_err_set(err, SF_ENOMEM, "job %lld: out of memory", (long long)id);
    if (p->env.hold)
        printer_set_fence(p, id, fence);
    *t = (struct start_ticket){ p, id, 0 };
    struct job_event_args a = { .printer = p->cfg.name, .lines_acked = line, .fence = fence };
    if (storeq_job_event(p->env.q, id, JOB_EV_RESUME, &a, p->cfg.name, on_resume, t)) {
        free(t);
        return sf_err_set(err, SF_ENOMEM, "job %lld: out of memory", (long long)id);
    }
    if (p->rticket)
        p->rticket->p = NULL; /* an earlier resume's, stale */
    free(p->rgo);
    p->rgo = NULL;
    p->rticket = t;
    p->job_id = id;
    p->judging = 0; /* a start's check still on the io thread is stale now */
    p->lines_acked = p->lines_saved = line;
    p->fil.job_id = 0; /* a print from mid-file: its filament is not counted */
    printer_move(p, PRINTER_EV_START);
    return SF_OK;
}

double
printer_estimate_s(const struct job_row *j, const char *path)
{
    return j->est_known ? j->est_s : gcjob_estimate_s(path);
}

void
printer_resume_go(struct printer *p, int64_t id, const char *path, uint64_t line,
                  const struct drv_job_scan *scan, double est_s, int rc, const char *why)
{
    /* Meanwhile the job may have been cancelled or its printer lost (the
       job moved on with it). */
    if (p->job_id != id)
        return;
    if (p->rticket) { /* its RESUME is still on its way: keep the read for on_resume */
        struct resume_go *g = mem_calloc(1, sizeof(*g));
        if (!g) {
            log_printer(LOG_ERROR, p->cfg.name, "job %lld: out of memory", (long long)id);
            return; /* p keeps the job until an operator cancels it */
        }
        snprintf(g->path, sizeof(g->path), "%s", path);
        g->line = line;
        if (scan)
            g->scan = *scan;
        g->est_s = est_s;
        g->rc = rc;
        snprintf(g->why, sizeof(g->why), "%s", why ? why : "");
        free(p->rgo);
        p->rgo = g;
        return;
    }
    resume_go(p, id, path, line, scan, est_s, rc, why);
}

/* Hand the read resume to the driver, or fail it with why (its RESUME committed). */
static void
resume_go(struct printer *p, int64_t id, const char *path, uint64_t line,
          const struct drv_job_scan *scan, double est_s, int rc, const char *why)
{
    char msg[SF_ERR_MSG_MAX];
    if (rc == SF_OK && (p->state != PRINTER_PRINTING || !printer_connected(p))) {
        rc = SF_EAGAIN;
        snprintf(msg, sizeof(msg), "printer %s is %s: the resume cannot start", p->cfg.name,
                 printer_state_name(p->state));
        why = msg;
    }
    if (rc) {
        log_printer(LOG_WARN, p->cfg.name, "job %lld: %s", (long long)id, why);
        fail_job(p, why);
        printer_move(p, PRINTER_EV_FINISHED);
        return;
    }
    p->est_s = est_s;
    drive(p, path, line, scan);
}
