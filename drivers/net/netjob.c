/*
 * netjob.c - the remote-state table of netjob.h.
 *
 * Why one table: Moonraker and PrusaLink name the same few situations
 * differently (print_stats "complete" vs PrusaLink "FINISHED", klippy
 * "shutdown" vs "ERROR"), and the farm must react the same way to each:
 * a job is never left on a printer that no longer runs it, a job the
 * printer still runs is never failed, and a cancel nobody here asked for
 * is a failure the operator sees, not a silent success.
 *
 * Thread: any; pure.
 */
#include "netjob.h"

#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>

#include "../../src/base/log.h"

static const char *
said(const struct netjob_obs *o, const char *fallback)
{
    return o->message && o->message[0] ? o->message : fallback;
}

/* Copy the first line of the printer's words (Klipper's shutdown text runs
   to nine lines; the first says what happened). */
static void
put(struct netjob_verdict *v, const char *text)
{
    size_t k = 0;
    for (; text[k] && text[k] != '\n' && text[k] != '\r' && k + 1 < sizeof(v->message); k++)
        v->message[k] = text[k];
    v->message[k] = '\0';
}

static const char *
file_of(const struct netjob_obs *o)
{
    return o->file && o->file[0] ? o->file : "?";
}

static void
end(struct netjob_verdict *v, enum drv_state st, enum drv_event ev)
{
    v->state = st;
    v->ends = true;
    v->ev = ev;
}

/* The printer is in a state that does not depend on whose job it has. */
static bool
judge_host(const struct netjob_obs *o, struct netjob_verdict *v)
{
    if (o->remote == NETJOB_R_HALTED) {
        v->state = DRV_ERROR;
        put(v, said(o, "printer halted"));
        return true;
    }
    if (o->remote == NETJOB_R_STARTING) {
        v->state = DRV_CONNECTING;
        put(v, said(o, "printer host starting"));
        return true;
    }
    return false;
}

static void
judge_none(const struct netjob_obs *o, struct netjob_verdict *v)
{
    if (judge_host(o, v))
        return;
    switch (o->remote) {
    case NETJOB_R_PRINTING:
    case NETJOB_R_PAUSED:
        v->state = o->remote == NETJOB_R_PRINTING ? DRV_PRINTING : DRV_PAUSED;
        snprintf(v->message, sizeof(v->message), "%s '%s', a job the farm did not send",
                 o->remote == NETJOB_R_PRINTING ? "printing" : "paused in", file_of(o));
        return;
    case NETJOB_R_BUSY:
        v->state = DRV_PRINTING;
        snprintf(v->message, sizeof(v->message), "busy: %s", said(o, "the printer is working"));
        return;
    default:
        v->state = DRV_IDLE;
        return;
    }
}

static void
judge_running(const struct netjob_obs *o, struct netjob_verdict *v)
{
    switch (o->remote) {
    case NETJOB_R_HALTED:
        judge_host(o, v);
        end(v, DRV_ERROR, DRV_EV_JOB_FAILED);
        return;
    case NETJOB_R_STARTING:
        /* a host that restarts has lost the print (Klipper keeps no job
           across a restart) */
        judge_host(o, v);
        end(v, DRV_CONNECTING, DRV_EV_JOB_FAILED);
        snprintf(v->message, sizeof(v->message), "the printer restarted during the job (%s)",
                 said(o, "starting"));
        return;
    case NETJOB_R_BUSY:
        v->state = DRV_PRINTING;
        return;
    case NETJOB_R_PRINTING:
    case NETJOB_R_PAUSED:
        if (o->ours) {
            v->state = o->remote == NETJOB_R_PRINTING ? DRV_PRINTING : DRV_PAUSED;
            if (o->remote == NETJOB_R_PAUSED && o->message && o->message[0])
                put(v, o->message);
            return;
        }
        end(v, o->remote == NETJOB_R_PRINTING ? DRV_PRINTING : DRV_PAUSED, DRV_EV_JOB_FAILED);
        snprintf(v->message, sizeof(v->message), "the printer runs '%s', not this job", file_of(o));
        return;
    case NETJOB_R_DONE:
        if (o->ours) {
            end(v, DRV_IDLE, DRV_EV_JOB_DONE);
            return;
        }
        break;
    case NETJOB_R_CANCELLED:
        if (o->ours) {
            end(v, DRV_IDLE, DRV_EV_JOB_FAILED);
            snprintf(v->message, sizeof(v->message), "cancelled at the printer");
            return;
        }
        break;
    case NETJOB_R_FAILED:
        if (o->ours) {
            end(v, DRV_IDLE, DRV_EV_JOB_FAILED);
            put(v, said(o, "the print failed"));
            return;
        }
        break;
    case NETJOB_R_IDLE:
        break;
    }
    end(v, DRV_IDLE, DRV_EV_JOB_FAILED);
    snprintf(v->message, sizeof(v->message), "the printer no longer has this job");
}

static void
judge_cancelling(const struct netjob_obs *o, struct netjob_verdict *v)
{
    if (judge_host(o, v)) {
        end(v, v->state, DRV_EV_JOB_CANCELLED);
        return;
    }
    if ((o->remote == NETJOB_R_PRINTING || o->remote == NETJOB_R_PAUSED ||
         o->remote == NETJOB_R_BUSY) &&
        (o->ours || o->remote == NETJOB_R_BUSY)) {
        v->state = DRV_PRINTING; /* the cancel is still under way */
        return;
    }
    end(v, DRV_IDLE, DRV_EV_JOB_CANCELLED);
}

void
netjob_judge(enum netjob_phase phase, const struct netjob_obs *o, struct netjob_verdict *v)
{
    memset(v, 0, sizeof(*v));
    switch (phase) {
    case NETJOB_NONE:
        judge_none(o, v);
        return;
    case NETJOB_RUNNING:
        judge_running(o, v);
        return;
    case NETJOB_CANCELLING:
        judge_cancelling(o, v);
        return;
    }
    judge_none(o, v);
}

const char *
netjob_remote_name(enum netjob_remote r)
{
    static const char *const names[] = { "idle",      "busy",   "printing", "paused", "done",
                                         "cancelled", "failed", "starting", "halted" };
    return (unsigned)r < sizeof(names) / sizeof(names[0]) ? names[r] : "?";
}

int
netjob_prepare(struct netjob *j, const char *gcode_path, const struct drv_job_scan *scan,
               char *path, size_t n, struct sf_err *err)
{
    memset(j, 0, sizeof(*j));
    struct stat sb;
    if (stat(gcode_path, &sb) != 0)
        return sf_err_sys(err, "job file '%s'", gcode_path);
    if ((size_t)snprintf(path, n, "%s", gcode_path) >= n)
        return sf_err_set(err, SF_EINVAL, "job file '%s': path too long", gcode_path);
    struct drv_job_scan own;
    if (!scan) {
        int rc = drv_job_scan(gcode_path, &own, err);
        if (rc)
            return rc;
        scan = &own;
    }
    j->phase = NETJOB_RUNNING;
    drv_remote_name(gcode_path, j->name, sizeof(j->name));
    j->size = (int64_t)sb.st_size;
    j->lines_total = scan->lines_total;
    return SF_OK;
}

static void
emit(struct drv *d, enum drv_event ev)
{
    if (d->on_event)
        d->on_event(d, ev, d->ud);
}

void
netjob_state(struct drv *d, enum drv_state s, const char *fmt, ...)
{
    if (fmt) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(d->status.message, sizeof(d->status.message), fmt, ap);
        va_end(ap);
    }
    if (d->status.state == s)
        return;
    log_printer(LOG_INFO, d->name, "%s -> %s%s%s", drv_state_name(d->status.state),
                drv_state_name(s), d->status.message[0] ? ": " : "", d->status.message);
    d->status.state = s;
    emit(d, DRV_EV_STATE);
}

void
netjob_report(struct drv *d, struct netjob *j, const struct netjob_verdict *v, double progress)
{
    struct drv_status *st = &d->status;
    enum drv_state was = st->state;
    if (progress < 0)
        progress = 0;
    if (progress > 1)
        progress = 1;
    if (j->phase != NETJOB_NONE) {
        if (v->ends && v->ev == DRV_EV_JOB_DONE)
            progress = 1;
        uint64_t lines = v->has_lines && !(v->ends && v->ev == DRV_EV_JOB_DONE)
                             ? v->lines
                             : (uint64_t)(progress * (double)j->lines_total + 0.5);
        if (lines > j->lines_total)
            lines = j->lines_total;
        st->progress = progress;
        st->lines_total = j->lines_total;
        if (lines != st->lines_acked) {
            st->lines_acked = lines;
            emit(d, DRV_EV_PROGRESS);
        }
    }
    snprintf(st->message, sizeof(st->message), "%s", v->message);
    st->state = v->state;
    /* the state first: the farm takes a printer's error (and its message)
       from DRV_EV_STATE, and a job's end then finds it already moved */
    if (st->state != was) {
        log_printer(LOG_INFO, d->name, "%s -> %s%s%s", drv_state_name(was),
                    drv_state_name(st->state), st->message[0] ? ": " : "", st->message);
        emit(d, DRV_EV_STATE);
    }
    if (v->ends) {
        log_printer(v->ev == DRV_EV_JOB_FAILED ? LOG_WARN : LOG_INFO, d->name, "job '%s': %s%s%s",
                    j->name,
                    v->ev == DRV_EV_JOB_DONE        ? "done"
                    : v->ev == DRV_EV_JOB_CANCELLED ? "cancelled"
                                                    : "failed",
                    v->message[0] ? ": " : "", v->message);
        j->phase = NETJOB_NONE;
        st->has_time_left = false;
        emit(d, v->ev);
    }
}

void
netjob_temps(struct drv *d, double nozzle_c, double nozzle_target_c, double bed_c,
             double bed_target_c)
{
    struct drv_status *st = &d->status;
    if (st->nozzle_c == nozzle_c && st->nozzle_target_c == nozzle_target_c && st->bed_c == bed_c &&
        st->bed_target_c == bed_target_c)
        return;
    st->nozzle_c = nozzle_c;
    st->nozzle_target_c = nozzle_target_c;
    st->bed_c = bed_c;
    st->bed_target_c = bed_target_c;
    emit(d, DRV_EV_TEMPS);
}
