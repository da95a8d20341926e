/*
 * drv_marlin_job.c - the Marlin driver's job stream (drv_marlin_int.h).
 *
 * What: checks a job file before it runs (drv_marlin_scan, _scan_to),
 * starts it or resumes it mid-file (restoring the state the earlier lines
 * left), reads it a command at a time as the window opens, pauses (park),
 * resumes and cancels (end sequence), and ends it (done, failed,
 * cancelled) with its progress.
 *
 * Thread: loop thread; scan_job and drv_marlin_scan(_to): any thread.
 */
#include "drv_marlin.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/base/gcode.h"
#include "../../src/base/limits.h"
#include "../../src/base/log.h"
#include "drv_marlin_int.h"
#include "marlin_exec.h"

#define PROGRESS_MS     250 /* progress events at most this often, */
#define PROGRESS_LINES  16  /* or once this many more lines are acknowledged */
#define PARK_X_MM       0.0 /* where a paused head waits */
#define PARK_Y_MM       0.0
#define PARK_LIFT_MM    10.0
#define RETRACT_MM      2.0
#define RESUME_LIFT_MM  2.0 /* Marlin's POWER_LOSS_ZRAISE: off the part before homing X/Y */
#define RESUME_PRIME_MM 2.0 /* refill what the nozzle oozed while it cooled and reheated */

void
marlin_job_close(struct marlin *m)
{
    if (m->job)
        fclose(m->job);
    m->job = NULL;
    m->mode = J_NONE;
    m->inj_len = 0;
}

/* End the job with ev (DONE, FAILED, CANCELLED); the state is the caller's. */
static void
job_end(struct marlin *m, enum drv_event ev)
{
    if (m->mode == J_NONE)
        return;
    marlin_job_close(m);
    m->base.status.progress = m->base.status.lines_total ? (double)m->base.status.lines_acked /
                                                               (double)m->base.status.lines_total
                                                         : 1.0;
    marlin_emit_event(m, ev);
}

void
marlin_job_fail(struct marlin *m, enum drv_state next, const char *why)
{
    marlin_message(m, "%s at line %llu of %llu", why,
                   (unsigned long long)m->base.status.lines_acked,
                   (unsigned long long)m->base.status.lines_total);
    log_printer(LOG_WARN, m->base.name, "job failed: %s", m->base.status.message);
    if (m->mode != J_NONE) {
        marlin_set_state(m, next);
        job_end(m, DRV_EV_JOB_FAILED);
    } else {
        marlin_set_state(m, next);
    }
}

/*
 * Read the next command of the job file into out.  1: got one, 0: end of
 * file, <0: a bad line (message set).
 */
int
marlin_next_job_command(struct marlin *m, char *out, size_t cap)
{
    char raw[SF_GCODE_LINE_MAX + 2];
    while (fgets(raw, sizeof(raw), m->job)) {
        size_t len = strlen(raw);
        if (len == sizeof(raw) - 1 && raw[len - 1] != '\n') {
            marlin_message(m, "job '%s': a line is longer than %d bytes", m->job_path,
                           SF_GCODE_LINE_MAX);
            return SF_EINVAL;
        }
        bool too_long;
        size_t n = gcode_strip(raw, len, out, cap, &too_long);
        if (too_long) {
            marlin_message(m, "job '%s': command %ld is too long for Marlin", m->job_path,
                           m->job_index + 1);
            return SF_EINVAL;
        }
        if (n > 0)
            return 1;
    }
    if (ferror(m->job)) {
        marlin_message(m, "job '%s': read error", m->job_path);
        return SF_EIO;
    }
    return 0;
}

void
marlin_check_job_progress(struct marlin *m)
{
    struct drv_status *st = &m->base.status;
    if (st->lines_total)
        st->progress = (double)st->lines_acked / (double)st->lines_total;
    int64_t now = loop_now_ms(m->base.loop);
    if (m->mode != J_NONE && (now - m->progress_ev_ms >= PROGRESS_MS ||
                              st->lines_acked >= m->progress_ev_lines + PROGRESS_LINES ||
                              st->lines_acked < m->progress_ev_lines)) {
        m->progress_ev_ms = now;
        m->progress_ev_lines = st->lines_acked;
        marlin_emit_event(m, DRV_EV_PROGRESS);
    }
    if (marlin_stall_check(m, now) || m->inj_len > 0 || !linewin_idle(&m->win))
        return;
    if (m->mode == J_RUN && m->job_eof && m->final_pushed) {
        st->lines_acked = st->lines_total;
        marlin_message(m, "done: %llu lines", (unsigned long long)st->lines_total);
        marlin_set_state(m, DRV_IDLE);
        job_end(m, DRV_EV_JOB_DONE);
    } else if (m->mode == J_CANCELLING) {
        marlin_message(m, "cancelled at line %llu of %llu", (unsigned long long)st->lines_acked,
                       (unsigned long long)st->lines_total);
        marlin_set_state(m, DRV_IDLE);
        job_end(m, DRV_EV_JOB_CANCELLED);
    }
}

/*
 * Bring a printer that lost the job back to where the job's lines before
 * first_line left it, then stream on from first_line.  Modelled on Marlin
 * 2.1's power-loss recovery (powerloss.cpp, PrintJobRecovery::resume):
 * the printer was reset (a USB Marlin resets when the port is reopened),
 * so heaters are off and no axis is homed, but the nozzle still stands
 * where the last executed move left it, on or just above the part.
 *   1. start bed and nozzle heating; wait for the bed (a cold nozzle sits
 *      on the part: heating it there would melt a mark into the top layer);
 *   2. G92 Z = the Z the job's earlier lines commanded (trust the nozzle
 *      stayed put, as powerloss.cpp's G92.9 does), lift RESUME_LIFT_MM off
 *      the part, home X and Y only: homing Z would drive the nozzle down
 *      into the part;
 *   3. wait for the nozzle, prime what the cooling nozzle oozed, travel
 *      back over the point where line first_line starts, lower to Z;
 *   4. restore E mode and position, positioning mode, feedrate and fan;
 *   5. continue with line first_line: its move starts where line
 *      first_line - 1 ended, which is exactly where step 3 put the head,
 *      so the line runs whole, as sliced.
 * Why first_line is the first line *not acknowledged*: Marlin acknowledges
 * a line once it is parsed and planned, so every acknowledged line was
 * printed (the planner drains on its own); an unacknowledged line may or
 * may not have run, and running it twice costs a blob at worst, where
 * skipping it leaves a gap.  The owner may hold an older count than the
 * printer reached (progress is persisted periodically): the lines in
 * between are printed again over themselves, within the same layer when
 * the period is short.
 */
static void
inject_resume(struct marlin *m, const struct drv_machine *s)
{
    if (s->bed_c > 0)
        marlin_inject(m, "M140 S%.0f", s->bed_c);
    if (s->noz_c > 0)
        marlin_inject(m, "M104 S%.0f", s->noz_c);
    if (s->bed_c > 0)
        marlin_inject(m, "M190 S%.0f", s->bed_c);
    marlin_inject(m, "G92 Z%.3f", s->pos[2]);
    marlin_inject(m, "G91");
    marlin_inject(m, "G1 Z%.2f F600", RESUME_LIFT_MM);
    marlin_inject(m, "G90");
    marlin_inject(m, "G28 X Y");
    if (s->noz_c > 0)
        marlin_inject(m, "M109 S%.0f", s->noz_c);
    marlin_inject(m, "M83");
    marlin_inject(m, "G1 E%.2f F300", RESUME_PRIME_MM);
    marlin_inject(m, "G1 X%.3f Y%.3f F6000", s->pos[0], s->pos[1]);
    marlin_inject(m, "G1 Z%.3f F600", s->pos[2]);
    if (!s->rel_e) {
        marlin_inject(m, "M82");
        marlin_inject(m, "G92 E%.5f", s->pos[3]);
    }
    if (s->rel_xyz)
        marlin_inject(m, "G91");
    marlin_inject(m, "G1 F%.0f", s->feed_mm_min);
    if (s->fan > 0)
        marlin_inject(m, "M106 S%.0f", s->fan);
    else
        marlin_inject(m, "M107");
}

/*
 * Read f from its start: count the commands (lines_total) and refuse a bad
 * line (a job must not fail half-way on one).  For first_line > 0 also
 * follow the machine state up to first_line and, if the file has that
 * command, set its resume point (resume_line = first_line, resume_at,
 * machine); with stop_at_first (the count is already known) reading ends
 * there, and lines_total counts only the commands before it.  Pure:
 * touches only f and out, so it may run on any thread.
 */
static int
scan_job(FILE *f, const char *path, uint64_t first_line, bool stop_at_first,
         struct drv_job_scan *out, struct sf_err *err)
{
    char raw[SF_GCODE_LINE_MAX + 2], cmd[LINEWIN_LINE_MAX];
    uint64_t total = 0;
    long lineno = 0, offset = 0;
    *out = (struct drv_job_scan){ .machine = { .feed_mm_min = 1500 } };
    while (fgets(raw, sizeof(raw), f)) {
        size_t len = strlen(raw);
        long at = offset;
        offset += (long)len;
        lineno++;
        bool too_long;
        if (len == sizeof(raw) - 1 && raw[len - 1] != '\n')
            return sf_err_set(err, SF_EINVAL, "job '%s':%ld: line longer than %d bytes", path,
                              lineno, SF_GCODE_LINE_MAX);
        size_t n = gcode_strip(raw, len, cmd, LINEWIN_LINE_MAX - 18, &too_long);
        if (too_long)
            return sf_err_set(err, SF_EINVAL,
                              "job '%s':%ld: command too long for Marlin (%d bytes)", path, lineno,
                              LINEWIN_LINE_MAX - 19);
        if (n == 0)
            continue;
        if (first_line > 0 && total == first_line) {
            out->resume_line = first_line;
            out->resume_at = at;
            if (stop_at_first)
                break;
        }
        if (total < first_line)
            marlin_exec_track(&out->machine, cmd, n);
        total++;
    }
    if (ferror(f))
        return sf_err_sys(err, "job '%s': read", path);
    out->lines_total = total;
    return SF_OK;
}

int
drv_marlin_scan(const char *path, struct drv_job_scan *out, struct sf_err *err)
{
    FILE *f = fopen(path, "r");
    if (!f)
        return sf_err_sys(err, "job '%s'", path);
    struct drv_job_scan sc;
    int rc = scan_job(f, path, 0, false, &sc, err);
    fclose(f);
    if (rc == SF_OK)
        *out = sc;
    return rc;
}

int
drv_marlin_scan_to(const char *path, uint64_t first_line, struct drv_job_scan *scan,
                   struct sf_err *err)
{
    if (first_line == 0)
        return sf_err_set(err, SF_EINVAL, "job '%s': a resume starts at line 1 or later", path);
    FILE *f = fopen(path, "r");
    if (!f)
        return sf_err_sys(err, "job '%s'", path);
    struct drv_job_scan sc;
    int rc = scan_job(f, path, first_line, true, &sc, err);
    fclose(f);
    if (rc)
        return rc;
    if (sc.resume_line != first_line)
        return sf_err_set(err, SF_EINVAL, "job '%s': no command line %llu to resume from", path,
                          (unsigned long long)first_line);
    scan->resume_line = sc.resume_line;
    scan->resume_at = sc.resume_at;
    scan->machine = sc.machine;
    return SF_OK;
}

int
marlin_start_job(struct drv *d, const char *path, uint64_t first_line,
                 const struct drv_job_scan *scan, struct sf_err *err)
{
    struct marlin *m = marlin_of(d);
    if (d->status.state != DRV_IDLE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is %s, not idle", d->name,
                          drv_state_name(d->status.state));
    FILE *f = fopen(path, "r");
    if (!f)
        return sf_err_sys(err, "job '%s'", path);
    /* With the owner's scan a start reads nothing here and a resume reads
       only up to first_line (nothing if the scan has its resume point);
       without one, the whole file is read now. */
    struct drv_job_scan sc = { .machine = { .feed_mm_min = 1500 } };
    uint64_t total = scan ? scan->lines_total : 0;
    bool resume_ok = !scan || first_line < total;
    if (resume_ok && scan && first_line > 0 && scan->resume_line == first_line) {
        sc = *scan;
    } else if (resume_ok && (!scan || first_line > 0)) {
        int rc = scan_job(f, path, first_line, scan != NULL, &sc, err);
        if (rc) {
            fclose(f);
            return rc;
        }
        if (!scan)
            total = sc.lines_total;
        /* no such command: past the end, or a file shorter than its scan said */
        resume_ok = first_line == 0 || sc.resume_line == first_line;
    }
    if (first_line > 0 && !resume_ok) {
        fclose(f);
        return sf_err_set(err, SF_EINVAL,
                          "job '%s': cannot resume from line %llu: the job has %llu command "
                          "lines (0..%llu)",
                          path, (unsigned long long)first_line, (unsigned long long)total,
                          (unsigned long long)(total ? total - 1 : 0));
    }
    if (fseek(f, (long)sc.resume_at, SEEK_SET) != 0) {
        fclose(f);
        return sf_err_sys(err, "job '%s': seek", path);
    }
    m->job = f;
    snprintf(m->job_path, sizeof(m->job_path), "%s", path);
    m->job_index = (long)first_line;
    m->job_eof = false;
    m->final_pushed = false;
    m->mo = sc.machine;
    d->status.lines_total = total;
    d->status.lines_acked = first_line;
    m->unconfirmed_to = 0; /* a silence before this job says nothing of its lines */
    d->status.progress = total ? (double)first_line / (double)total : 0;
    d->status.job_started_ms = loop_now_ms(d->loop);
    m->stall_acked = first_line; /* the stall clock starts with the job */
    m->stall_ms = d->status.job_started_ms;
    if (first_line > 0) {
        inject_resume(m, &sc.machine);
        marlin_message(m, "resuming '%s' at line %llu of %llu", path,
                       (unsigned long long)first_line, (unsigned long long)total);
    } else {
        marlin_message(m, "printing '%s'", path);
    }
    m->mode = J_RUN;
    marlin_set_state(m, DRV_PRINTING);
    marlin_pump(m);
    return SF_OK;
}

void
marlin_do_pause(struct marlin *m)
{
    m->saved = m->mo;
    m->mode = J_PAUSED;
    marlin_inject(m, "M400");
    marlin_inject(m, "M83");
    marlin_inject(m, "G1 E-%.2f F2400", RETRACT_MM);
    marlin_inject(m, "G91");
    marlin_inject(m, "G1 Z%.2f F600", PARK_LIFT_MM);
    marlin_inject(m, "G90");
    marlin_inject(m, "G1 X%.2f Y%.2f F6000", PARK_X_MM, PARK_Y_MM);
    marlin_message(m, "paused at line %llu", (unsigned long long)m->base.status.lines_acked);
    marlin_set_state(m, DRV_PAUSED);
    marlin_pump(m);
}

void
marlin_do_resume(struct marlin *m)
{
    const struct drv_machine *s = &m->saved;
    if (s->bed_c > 0)
        marlin_inject(m, "M190 S%.0f", s->bed_c);
    if (s->noz_c > 0)
        marlin_inject(m, "M109 S%.0f", s->noz_c);
    marlin_inject(m, "G90");
    marlin_inject(m, "G1 X%.3f Y%.3f F6000", s->pos[0], s->pos[1]);
    marlin_inject(m, "G1 Z%.3f F600", s->pos[2]);
    marlin_inject(m, "M83");
    marlin_inject(m, "G1 E%.2f F2400", RETRACT_MM);
    marlin_inject(m, "%s", s->rel_e ? "M83" : "M82");
    if (!s->rel_e)
        marlin_inject(m, "G92 E%.5f", s->pos[3]);
    marlin_inject(m, "%s", s->rel_xyz ? "G91" : "G90");
    marlin_inject(m, "G1 F%.0f", s->feed_mm_min);
    if (s->fan > 0)
        marlin_inject(m, "M106 S%.0f", s->fan);
    m->mo = m->saved;
    m->mode = J_RUN;
    marlin_message(m, "resumed");
    marlin_set_state(m, DRV_PRINTING);
    marlin_pump(m);
}

void
marlin_do_cancel(struct marlin *m)
{
    bool was_paused = m->mode == J_PAUSED;
    m->mode = J_CANCELLING;
    m->inj_len = 0;
    marlin_send_raw(m, "M108\n"); /* break an M109/M190 wait at once (emergency parser) */
    marlin_inject(m, "M104 S0");
    marlin_inject(m, "M140 S0");
    marlin_inject(m, "M107");
    if (!was_paused) {
        marlin_inject(m, "M83");
        marlin_inject(m, "G1 E-%.2f F2400", RETRACT_MM);
        marlin_inject(m, "G91");
        marlin_inject(m, "G1 Z%.2f F600", PARK_LIFT_MM);
        marlin_inject(m, "G90");
    }
    marlin_inject(m, "M84");
    marlin_set_state(m, DRV_PRINTING); /* until the end sequence is acknowledged */
    marlin_pump(m);
}

int
marlin_pause(struct drv *d, struct sf_err *err)
{
    struct marlin *m = marlin_of(d);
    if (d->status.state != DRV_PRINTING || m->mode != J_RUN)
        return sf_err_set(err, SF_EINVAL, "printer '%s' is %s: nothing to pause", d->name,
                          drv_state_name(d->status.state));
    marlin_do_pause(m);
    return SF_OK;
}

int
marlin_resume(struct drv *d, struct sf_err *err)
{
    struct marlin *m = marlin_of(d);
    if (d->status.state != DRV_PAUSED || m->mode != J_PAUSED)
        return sf_err_set(err, SF_EINVAL, "printer '%s' is %s: nothing to resume", d->name,
                          drv_state_name(d->status.state));
    marlin_do_resume(m);
    return SF_OK;
}

int
marlin_cancel(struct drv *d, struct sf_err *err)
{
    struct marlin *m = marlin_of(d);
    if (m->mode != J_RUN && m->mode != J_PAUSED)
        return sf_err_set(err, SF_EINVAL, "printer '%s': no job to cancel", d->name);
    marlin_do_cancel(m);
    return SF_OK;
}
