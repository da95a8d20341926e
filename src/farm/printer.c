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
 * Thread: the loop thread.
 */
#include "printer.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../drivers/drv_link.h"
#include "../base/log.h"
#include "../base/mem.h"
#include "gcjob.h"

#define PRINTER_SAVE_LINES 16 /* progress this far ahead of the store is saved at once */
/* attach() answers "not yet" taken on one connection before the job stays interrupted
   (backoff 0.5, 1, 2, ... s: about two minutes in all) */
#define PRINTER_ATTACH_WAITS 10

/* One driver event as it happened. */
struct queued {
    enum drv_event ev;    /* what */
    struct drv_status st; /* the driver's status at that moment */
};

struct printer {
    struct printer_env env;     /* owner, store, loop */
    struct farmcfg_printer cfg; /* its config section */
    enum printer_state state;   /* job.h printer state: the one truth */
    struct drv *drv;            /* its driver; NULL without one */
    int64_t job_id;             /* job on it, 0 if none */
    int64_t lines_acked;        /* latest from the driver */
    int64_t lines_saved;        /* last value written to the store */
    char message[160];          /* why offline / error */
    uint64_t reconnect;         /* reconnect timer id, 0 if none */
    int attempts;               /* reconnects since the link was last up (drv_backoff_ms) */
    bool removed;               /* dropped from the config */
    bool bed_full;              /* the bed holds a part (store_printer_bed_get) */
    bool deaf;                  /* printer_stop: driver events are dropped */
    bool attach_tried;          /* this connection offered the driver its interrupted job */
    bool error_cleared;         /* an operator cleared the error before the driver saw the
                                   printer recover: leave it when the driver reports idle */
    struct queued *queue;       /* driver events not applied yet, n_queue of cap_queue */
    size_t n_queue, cap_queue;
    uint64_t deliver;      /* timer applying the queue, 0 if none */
    uint64_t hold;         /* after a refused start: timer until p takes jobs again, 0 if none */
    int refusals;          /* starts refused in a row (drive) */
    uint64_t attach_retry; /* timer offering the interrupted job again, 0 if none */
    int attach_waits;      /* attach() answers "not yet" on this connection */
    double est_s;          /* the job's print time estimate (printer_estimate_s), s; -1 unknown */
    uint64_t heat_timer;   /* hot with no print: timer turning the heaters off, 0 if none */
    int64_t judging; /* job started whose file is judged before the driver has it, 0 if none */
};

static const char *const action_names[PRINTER_ACTION_COUNT] = { "pause", "resume", "cancel",
                                                                "cleared" };

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

static void
changed(struct printer *p)
{
    if (p->env.changed)
        p->env.changed(p->env.ud);
}

/* Record whether p's bed holds a part; a crash after this keeps the bed gate. */
static void
set_bed(struct printer *p, bool full)
{
    struct sf_err err;
    if (p->bed_full == full)
        return;
    p->bed_full = full;
    if (store_printer_bed_set(p->env.s, p->cfg.name, full, &err))
        log_printer(LOG_ERROR, p->cfg.name, "%s", err.msg);
}

/*
 * Move p by ev; log refusals (they mean a driver said something odd).  The
 * bed is recorded here, before the caller records the job: a printer whose
 * bed holds a part comes back from any restart or reconnect awaiting clear.
 */
static bool
move(struct printer *p, enum printer_event ev)
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
        set_bed(p, true);
    else if (ev == PRINTER_EV_CLEARED)
        set_bed(p, false);
    if (to != PRINTER_ERROR)
        p->error_cleared = false;
    if (to != p->state) {
        p->state = to;
        if (store_printer_set(p->env.s, p->cfg.name, to, &err))
            log_printer(LOG_ERROR, p->cfg.name, "%s", err.msg);
    }
    changed(p);
    return true;
}

/* Apply a job event in the store, logging failures (the job fails alone). */
static int
job_event(struct printer *p, int64_t id, enum job_event ev, const struct job_event_args *a)
{
    struct sf_err err;
    int rc = store_job_event(p->env.s, id, ev, a, NULL, &err);
    if (rc)
        log_printer(LOG_WARN, p->cfg.name, "%s", err.msg);
    changed(p);
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
    job_event(p, id, JOB_EV_PRINT_FAILED, &a);
}

/*
 * A network printer went unreachable with a job on it: the printer prints
 * on without us, so the job is interrupted (as by a daemon crash), not
 * failed, and re-attached when the printer answers again.
 */
static void
interrupt_job(struct printer *p, const char *why)
{
    struct sf_err err;
    char reason[200];
    snprintf(reason, sizeof(reason), "printer unreachable while printing: %s", why);
    struct job_event_args a = { .reason = reason };
    int64_t id = p->job_id;
    p->job_id = 0;
    if (store_job_progress(p->env.s, id, p->lines_acked, &err) ||
        store_job_event(p->env.s, id, JOB_EV_CRASHED, &a, NULL, &err))
        log_printer(LOG_ERROR, p->cfg.name, "%s", err.msg);
    else
        log_printer(LOG_WARN, p->cfg.name, "job %lld interrupted: %s", (long long)id, reason);
    changed(p);
}

/*
 * The driver of a network printer just connected: offer it the job the
 * store holds as interrupted on this printer (a daemon restart, or the
 * printer unreachable for a while).  If the printer still prints that
 * file (or finished it meanwhile) the job is printing again and ends as
 * the printer says; otherwise it stays interrupted, as it would on Marlin.
 * SF_OK when the job was re-attached; SF_EAGAIN when the driver cannot tell
 * yet (its first poll, PrusaLink's job details still on the way: ask again);
 * SF_ENOTFOUND otherwise (no such job, or the printer does not know it).
 */
static int
try_attach(struct printer *p)
{
    struct sf_err err;
    struct job_row row;
    if (p->bed_full || store_job_interrupted(p->env.s, p->cfg.name, &row, &err))
        return SF_ENOTFOUND;
    const struct job_row *j = row.gcode_sha[0] ? &row : NULL;
    int ok = SF_ENOTFOUND;
    char path[1024];
    if (j && store_file_path(p->env.s, j->gcode_sha, path, sizeof(path), &err) == SF_OK) {
        struct drv_job_scan scan = { .lines_total = (uint64_t)j->gcode_lines };
        int rc = p->drv->ops->attach(p->drv, path, j->gcode_lines > 0 ? &scan : NULL, &err);
        if (rc == SF_OK) {
            p->est_s = printer_estimate_s(j, path);
            p->attempts = 0;
            p->message[0] = '\0';
            move(p, PRINTER_EV_CONNECTED);
            int64_t line = (int64_t)p->drv->status.lines_acked;
            if (printer_resume_commit(p, j->id, line > 0 ? line : 0, &err) == SF_OK) {
                log_printer(LOG_INFO, p->cfg.name, "job %lld re-attached: the printer still has it",
                            (long long)j->id);
                ok = SF_OK;
            } else {
                log_printer(LOG_ERROR, p->cfg.name, "job %lld: %s", (long long)j->id, err.msg);
            }
        } else if (rc == SF_EAGAIN && p->attach_waits < PRINTER_ATTACH_WAITS) {
            log_printer(LOG_INFO, p->cfg.name, "job %lld: re-attach waits: %s", (long long)j->id,
                        err.msg);
            snprintf(p->message, sizeof(p->message), "re-attaching job %lld: %s", (long long)j->id,
                     err.msg);
            ok = SF_EAGAIN;
        } else {
            log_printer(LOG_INFO, p->cfg.name, "job %lld stays interrupted: %s", (long long)j->id,
                        err.msg);
        }
    }
    return ok;
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

/* The driver answered "not yet" to attach: offer the job again with its status now. */
static void
on_attach_retry(struct loop *l, void *ud)
{
    (void)l;
    struct printer *p = ud;
    p->attach_retry = 0;
    enum drv_state ds = p->drv->status.state;
    if (!p->deaf && p->state == PRINTER_OFFLINE && !p->attach_tried &&
        (ds == DRV_IDLE || ds == DRV_PRINTING || ds == DRV_PAUSED))
        apply(p, DRV_EV_STATE, &p->drv->status);
}

static void
schedule_attach_retry(struct printer *p)
{
    if (!p->attach_retry)
        p->attach_retry =
            loop_timer_add(p->env.l, drv_backoff_ms(p->attach_waits++), on_attach_retry, p);
}

static void
apply(struct printer *p, enum drv_event ev, const struct drv_status *st)
{
    switch (ev) {
    case DRV_EV_STATE:
        if (p->state == PRINTER_OFFLINE && p->drv->ops->attach && !p->attach_tried &&
            (st->state == DRV_IDLE || st->state == DRV_PRINTING || st->state == DRV_PAUSED)) {
            /* tried only once the driver could answer: "not yet" (SF_EAGAIN)
               keeps p offline and asks again, so the job is not left
               interrupted until the next reconnect */
            int rc = try_attach(p);
            if (rc == SF_EAGAIN) {
                schedule_attach_retry(p);
                break;
            }
            p->attach_tried = true;
            if (rc == SF_OK)
                break;
        }
        if (st->state == DRV_IDLE && p->state == PRINTER_OFFLINE) {
            p->attempts = 0;
            p->message[0] = '\0';
            move(p, PRINTER_EV_CONNECTED);
        } else if (st->state == DRV_OFFLINE && p->state != PRINTER_OFFLINE) {
            if (p->job_id && p->drv->ops->attach)
                interrupt_job(p, st->message);
            else
                fail_job(p, "printer went offline");
            p->attach_tried = false;
            p->attach_waits = 0;
            snprintf(p->message, sizeof(p->message), "%s", st->message);
            move(p, PRINTER_EV_DISCONNECTED);
            schedule_reconnect(p);
        } else if (st->state == DRV_ERROR && p->state != PRINTER_ERROR) {
            fail_job(p, st->message[0] ? st->message : "printer reported an error");
            snprintf(p->message, sizeof(p->message), "%s", st->message);
            move(p, PRINTER_EV_FAULT);
        } else if (st->state == DRV_IDLE && p->state == PRINTER_ERROR && p->error_cleared) {
            p->message[0] = '\0'; /* the printer recovered after the operator's clear */
            move(p, PRINTER_EV_CLEARED);
        } else if (p->state == PRINTER_IDLE && !p->job_id &&
                   (st->state == DRV_PRINTING || st->state == DRV_PAUSED) &&
                   (p->drv->status.state == DRV_PRINTING || p->drv->status.state == DRV_PAUSED)) {
            /* someone started a print at the printer (the driver still says
               so: not a report from before a cancel): it is not ours to use
               until the driver sees it idle again */
            snprintf(p->message, sizeof(p->message), "%s",
                     st->message[0] ? st->message : "busy with a print the farm did not start");
            move(p, PRINTER_EV_DISCONNECTED);
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
            job_event(p, p->job_id, JOB_EV_PAUSE, &a);
            move(p, PRINTER_EV_PAUSE);
        } else if (st->state == DRV_PRINTING && p->state == PRINTER_PAUSED && p->job_id) {
            job_event(p, p->job_id, JOB_EV_RESUME, NULL);
            move(p, PRINTER_EV_RESUME);
        }
        break;
    case DRV_EV_PROGRESS:
        p->lines_acked = (int64_t)st->lines_acked;
        if (p->job_id && p->lines_acked >= p->lines_saved + PRINTER_SAVE_LINES) {
            /* Saved at once, not on the farm's timer: a resume after a crash
               re-runs at most these lines plus what the driver had not yet
               reported (drivers report every 16 lines or 250 ms). */
            struct store_progress sp = { p->job_id, p->lines_acked, false };
            if (store_jobs_progress(p->env.s, &sp, 1, NULL) > 0)
                p->lines_saved = p->lines_acked;
        }
        break;
    case DRV_EV_TEMPS:
        break; /* read from the driver's status when asked */
    case DRV_EV_JOB_DONE: {
        /* the bed first: a crash between the two leaves the job interrupted */
        struct job_event_args a = { .lines_acked = (int64_t)st->lines_acked };
        int64_t id = p->job_id;
        p->job_id = 0;
        move(p, PRINTER_EV_FINISHED);
        if (id)
            job_event(p, id, JOB_EV_PRINT_DONE, &a);
        break;
    }
    case DRV_EV_JOB_CANCELLED:
        /* The cancel was recorded when it was asked; a printer still
           printing with no job ran the end sequence, and is free now. */
        if (p->state == PRINTER_PRINTING && !p->job_id)
            move(p, PRINTER_EV_FINISHED);
        break;
    case DRV_EV_JOB_FAILED:
        p->lines_acked = (int64_t)st->lines_acked;
        if (st->state == DRV_ERROR && st->message[0] && p->state != PRINTER_ERROR)
            snprintf(p->message, sizeof(p->message), "%s", st->message); /* why it halted */
        fail_job(p, st->message[0] ? st->message : "the print stopped");
        if (p->state == PRINTER_PRINTING || p->state == PRINTER_PAUSED)
            move(p, st->state == DRV_ERROR ? PRINTER_EV_FAULT : PRINTER_EV_FINISHED);
        break;
    }
}

/* ---- heaters after an interruption ---- */

/* Connected, no print on it, and a heater set: what hold_heat_min bounds. */
static bool
hot_idle(const struct printer *p)
{
    if (!p->drv || p->job_id || p->state == PRINTER_OFFLINE || p->state == PRINTER_PRINTING ||
        p->state == PRINTER_PAUSED)
        return false;
    const struct drv_status *st = &p->drv->status;
    return st->state == DRV_IDLE && (st->nozzle_target_c > 0 || st->bed_target_c > 0);
}

/*
 * hold_heat_min is over: the print is not coming back (no resume, no job),
 * so the heaters go off (M104 S0 and M140 S0: Marlin's, and what Klipper
 * and OctoPrint take as console G-code), said in p's message and the log.
 */
static void
on_heat_off(struct loop *l, void *ud)
{
    (void)l;
    struct printer *p = ud;
    p->heat_timer = 0;
    if (!hot_idle(p))
        return;
    struct sf_err err;
    char what[160];
    const struct drv_status *st = &p->drv->status;
    int rc = !p->drv->ops->command ? sf_err_set(&err, SF_EUNSUPP, "its %s driver sends no commands",
                                                p->drv->ops->kind)
                                   : p->drv->ops->command(p->drv, "M104 S0", &err);
    if (rc == SF_OK)
        rc = p->drv->ops->command(p->drv, "M140 S0", &err);
    if (rc == SF_OK)
        snprintf(what, sizeof(what),
                 "heaters off (were %.0f/%.0f C): no print for %g min (hold_heat_min)",
                 st->nozzle_target_c, st->bed_target_c, p->cfg.hold_heat_min);
    else
        snprintf(what, sizeof(what), "hot with no print for %g min, heaters not turned off: %s",
                 p->cfg.hold_heat_min, err.msg);
    log_printer(rc ? LOG_ERROR : LOG_WARN, p->cfg.name, "%s", what);
    snprintf(p->message, sizeof(p->message), "%s", what);
    if (store_printer_note(p->env.s, p->cfg.name, "printer-heat", what, &err))
        log_printer(LOG_ERROR, p->cfg.name, "%s", err.msg);
    changed(p);
}

/* Arm the heaters' timer when p is hot with no print, disarm it when not. */
static void
heat_watch(struct printer *p)
{
    bool hot = hot_idle(p);
    if (hot && !p->heat_timer)
        p->heat_timer =
            loop_timer_add(p->env.l, (int64_t)(p->cfg.hold_heat_min * 60000.0), on_heat_off, p);
    else if (!hot && p->heat_timer) {
        loop_timer_cancel(p->env.l, p->heat_timer);
        p->heat_timer = 0;
    }
}

static void
deliver(struct loop *l, void *ud)
{
    (void)l;
    struct printer *p = ud;
    p->deliver = 0;
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
        heat_watch(p);
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
    if (store_printer_set(env->s, cfg->name, PRINTER_OFFLINE, &err) ||
        store_printer_bed_get(env->s, cfg->name, &p->bed_full, &err))
        log_printer(LOG_ERROR, cfg->name, "%s", err.msg);
    if (p->bed_full)
        log_printer(LOG_INFO, cfg->name, "its bed holds a part: clear it before the next job");
    if (!cfg->enabled) {
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
    struct sf_err err;
    struct job_event_args a = { .reason = "the daemon stopped while this job was printing" };
    p->deaf = true;
    if (p->job_id && (store_job_progress(p->env.s, p->job_id, p->lines_acked, &err) ||
                      store_job_event(p->env.s, p->job_id, JOB_EV_CRASHED, &a, NULL, &err)))
        log_printer(LOG_ERROR, p->cfg.name, "%s", err.msg);
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
    changed(p); /* the scheduler may use p again */
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
        move(p, PRINTER_EV_FINISHED);
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
    move(p, PRINTER_EV_REFUSED);
    job_event(p, id, JOB_EV_REFUSED, &a);
}

int
printer_start(struct printer *p, const struct job_row *j, const char *path)
{
    struct job_event_args a = { .printer = p->cfg.name };
    /* Commit first: a crash from here on leaves the job interrupted. */
    int rc = job_event(p, j->id, JOB_EV_START, &a);
    if (rc)
        return rc;
    p->job_id = j->id;
    p->lines_acked = p->lines_saved = 0;
    p->est_s = printer_estimate_s(j, path);
    p->judging = j->id;
    move(p, PRINTER_EV_START);
    return SF_OK;
}

void
printer_start_go(struct printer *p, int64_t id, const char *path, const struct drv_job_scan *scan,
                 int rc, const char *why)
{
    if (p->job_id != id) /* cancelled, or its printer lost, while the file was judged */
        return;
    p->judging = 0;
    if (rc == SF_OK) {
        drive(p, path, 0, scan);
        return;
    }
    /* A retry would judge the same file the same way. */
    log_printer(LOG_WARN, p->cfg.name, "job %lld refused at its start: %s", (long long)id, why);
    struct job_event_args a = { .reason = why, .no_retry = true };
    p->job_id = 0;
    move(p, PRINTER_EV_REFUSED);
    job_event(p, id, JOB_EV_PRINT_FAILED, &a);
}

int
printer_resume_commit(struct printer *p, int64_t id, int64_t line, struct sf_err *err)
{
    /* Commit first (the farm's rule): a crash from here on leaves it interrupted again. */
    struct job_event_args a = { .printer = p->cfg.name, .lines_acked = line };
    int rc = store_job_event(p->env.s, id, JOB_EV_RESUME, &a, NULL, err);
    if (rc)
        return rc;
    p->job_id = id;
    p->lines_acked = p->lines_saved = line;
    move(p, PRINTER_EV_START);
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
        move(p, PRINTER_EV_FINISHED);
        return;
    }
    p->est_s = est_s;
    drive(p, path, line, scan);
}

/* The job the store holds as interrupted on p (its part may be on the bed), or 0. */
static int64_t
interrupted_here(struct printer *p)
{
    struct sf_err err;
    struct job_row j;
    int rc = store_job_interrupted(p->env.s, p->cfg.name, &j, &err);
    if (rc == SF_ENOTFOUND)
        return 0;
    return rc ? -1 : j.id; /* unknown: treated as held */
}

/* Record what an operator did to p in the log and the event log. */
static void
note(struct printer *p, const char *kind, const char *fmt, const char *a, const char *b)
{
    struct sf_err err;
    char what[192];
    snprintf(what, sizeof(what), fmt, a, b);
    if (strcmp(kind, "printer-command") == 0) /* each one, never folded as a repeat */
        log_printer_each(LOG_INFO, p->cfg.name, "%s", what);
    else
        log_printer(LOG_INFO, p->cfg.name, "%s", what);
    if (store_printer_note(p->env.s, p->cfg.name, kind, what, &err))
        log_printer(LOG_ERROR, p->cfg.name, "%s", err.msg);
}

int
printer_command(struct printer *p, const char *line, const char *who, struct sf_err *err)
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
    int64_t held = interrupted_here(p);
    if (held)
        return sf_err_set(err, SF_EAGAIN,
                          "printer %s holds interrupted job %lld: resume, restart or cancel it "
                          "before manual commands",
                          p->cfg.name, (long long)held);
    int rc = p->drv->ops->command(p->drv, line, err);
    if (rc == SF_OK)
        note(p, "printer-command", "manual command from %s: %s", who && who[0] ? who : "?", line);
    return rc;
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
    set_bed(p, true); /* whatever it printed stays until an operator clears it */
    if (p->job_id) {
        struct job_event_args a = { .lines_acked = p->lines_acked,
                                    .reason = why,
                                    .no_retry = true };
        int64_t id = p->job_id;
        p->job_id = 0;
        job_event(p, id, JOB_EV_PRINT_FAILED, &a);
    }
    snprintf(p->message, sizeof(p->message), "%s", why);
    if (p->state != PRINTER_ERROR)
        move(p, PRINTER_EV_FAULT);
    return SF_OK;
}

/* Cancel the job p was starting while its file is judged: nothing was sent. */
static int
cancel_judged(struct printer *p, struct sf_err *err)
{
    struct job_event_args a = { .reason = "cancelled by an operator" };
    int rc = store_job_event(p->env.s, p->job_id, JOB_EV_CANCEL, &a, NULL, err);
    if (rc)
        return rc;
    p->job_id = p->judging = 0;
    move(p, PRINTER_EV_REFUSED); /* idle again, the bed as it was */
    return SF_OK;
}

int
printer_action(struct printer *p, enum printer_action act, struct sf_err *err)
{
    static const enum printer_event evs[PRINTER_ACTION_COUNT] = {
        PRINTER_EV_PAUSE, PRINTER_EV_RESUME, PRINTER_EV_FINISHED, PRINTER_EV_CLEARED
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
            set_bed(p, false);
            p->error_cleared = true;
            snprintf(p->message, sizeof(p->message),
                     "cleared: waits for the printer to report ready");
            changed(p);
            return SF_OK;
        }
        move(p, ev);
        return SF_OK;
    }
    if (!p->drv || !p->job_id)
        return sf_err_set(err, SF_EINVAL, "printer %s has no job to %s", p->cfg.name,
                          action_names[act]);
    if (p->judging == p->job_id) /* the driver has nothing yet: a cancel is the store's alone */
        return act == PRINTER_ACT_CANCEL ? cancel_judged(p, err)
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
    struct job_event_args a = { .lines_acked = p->lines_acked,
                                .reason = "cancelled by an operator" };
    enum job_event jev = act == PRINTER_ACT_PAUSE    ? JOB_EV_PAUSE
                         : act == PRINTER_ACT_RESUME ? JOB_EV_RESUME
                                                     : JOB_EV_CANCEL;
    if (jev == JOB_EV_CANCEL && !p->cfg.auto_eject)
        set_bed(p, true); /* the cancelled part stays on the bed */
    if ((rc = store_job_event(p->env.s, p->job_id, jev, &a, NULL, err)))
        return rc;
    if (jev == JOB_EV_CANCEL) {
        p->job_id = 0;
        if (p->drv->status.state == DRV_PRINTING) {
            /* still running the end sequence: printing with no job until
               DRV_EV_JOB_CANCELLED */
            changed(p);
            return SF_OK;
        }
    }
    move(p, ev);
    return SF_OK;
}
