/*
 * jobctl.c - an operator's requests to the farm's jobs and printers, with
 * their refusals as precise status codes (see jobctl.h).
 *
 * Why here and not in the API: what a cancel means depends on where the
 * job is (on a printer: stop the printer, whose registry records it;
 * elsewhere: the store alone), which is the farm's knowledge; the HTTP
 * side only turns the code into a status.  The job and printer rules say
 * SF_EINVAL when an event is not legal from a state; to an operator that
 * is "not now" (SF_EAGAIN), not bad input.
 *
 * Thread: the loop thread.
 */
#include "jobctl.h"

#include <stdio.h>
#include <string.h>

/* A refusal of the job or printer rules (SF_EINVAL) is "not now". */
static int
not_now(int rc, struct sf_err *err)
{
    if (rc != SF_EINVAL)
        return rc;
    if (err)
        err->code = SF_EAGAIN;
    return SF_EAGAIN;
}

/* SF_ENOTFOUND for an unknown printer, SF_EUNREACH for an offline one. */
static int
reachable(struct farm *f, const char *name, struct sf_err *err)
{
    size_t n = f ? farm_printer_count(f) : 0;
    for (size_t i = 0; i < n; i++) {
        struct printer_info p;
        farm_printer_info(f, i, &p);
        if (strcmp(p.cfg->name, name) != 0)
            continue;
        if (p.state == PRINTER_OFFLINE)
            return sf_err_set(err, SF_EUNREACH, "printer %s is offline%s%s", name,
                              p.message && p.message[0] ? ": " : "", p.message ? p.message : "");
        return SF_OK;
    }
    return sf_err_set(err, SF_ENOTFOUND, "no printer '%.64s'", name);
}

int
jobctl_printer_action(struct farm *f, const char *name, enum printer_action act, struct sf_err *err)
{
    int rc = reachable(f, name, err);
    return rc ? rc : not_now(farm_printer_action(f, name, act, err), err);
}

int
jobctl_printer_action_then(struct farm *f, const char *name, enum printer_action act,
                           storeq_event_fn done, void *ud, struct sf_err *err)
{
    int rc = reachable(f, name, err);
    return rc ? rc : not_now(farm_printer_action_then(f, name, act, done, ud, err), err);
}

int
jobctl_printer_command(struct farm *f, const char *name, const char *line, const char *who,
                       struct sf_err *err)
{
    int rc = reachable(f, name, err);
    return rc ? rc : farm_printer_command(f, name, line, who, err);
}

int
jobctl_printer_command_then(struct farm *f, const char *name, const char *line, const char *who,
                            storeq_event_fn done, void *ud, struct sf_err *err)
{
    int rc = reachable(f, name, err);
    return rc ? rc : farm_printer_command_then(f, name, line, who, done, ud, err);
}

int
jobctl_printer_estop(struct farm *f, const char *name, const char *who, struct sf_err *err)
{
    int rc = reachable(f, name, err);
    return rc ? rc : farm_printer_estop(f, name, who, err);
}

int
jobctl_cancel(struct farm *f, struct store *s, int64_t id, struct sf_err *err)
{
    /* A job on a printer (the loop knows it): stop the printer, whose registry records the
       cancel, without waiting for the store. */
    const char *on = jobctl_printer_of(f, id);
    if (on)
        return jobctl_printer_action(f, on, PRINTER_ACT_CANCEL, err);
    struct job_row j;
    /* the job's end may still be queued, or a reason that a cancel overrides */
    int rc = farm_sync(f, STOREQ_SYNC_MS, err);
    if (rc || (rc = store_job_get(s, id, &j, err)))
        return rc;
    if (job_state_on_printer(j.state))
        /* The printer must stop first; its registry records the cancel. */
        return f ? jobctl_printer_action(f, j.printer, PRINTER_ACT_CANCEL, err)
                 : sf_err_set(err, SF_EAGAIN, "job %lld: no farm to stop its printer",
                              (long long)id);
    struct job_event_args args = { .reason = "cancelled by an operator" };
    return not_now(store_job_event(s, id, JOB_EV_CANCEL, &args, NULL, err), err);
}

int
jobctl_cancel_stored(struct store *s, int64_t id, struct sf_err *err)
{
    return jobctl_cancel_stored_on(s, id, NULL, 0, err);
}

int
jobctl_cancel_stored_on(struct store *s, int64_t id, char *printer, size_t n, struct sf_err *err)
{
    struct job_row j;
    int rc = store_job_get(s, id, &j, err);
    if (rc)
        return rc;
    if (job_state_on_printer(j.state)) { /* its printer must stop it: it took it meanwhile */
        if (printer && n)
            snprintf(printer, n, "%s", j.printer);
        return sf_err_set(err, SF_EAGAIN, "job %lld is %s on printer %s: cancel it again",
                          (long long)id, job_state_name(j.state), j.printer);
    }
    struct job_event_args args = { .reason = "cancelled by an operator" };
    return not_now(store_job_event(s, id, JOB_EV_CANCEL, &args, NULL, err), err);
}

int
jobctl_cancel_job_on(struct farm *f, const char *name, int64_t id, storeq_event_fn done, void *ud,
                     struct sf_err *err)
{
    int rc = reachable(f, name, err);
    if (rc)
        return rc;
    int64_t now = 0;
    for (size_t i = 0; i < farm_printer_count(f); i++) {
        struct printer_info p;
        farm_printer_info(f, i, &p);
        if (strcmp(p.cfg->name, name) == 0)
            now = p.job_id;
    }
    if (now != id && now)
        return sf_err_set(err, SF_EAGAIN,
                          "job %lld is not on printer %s now (job %lld is): not cancelled",
                          (long long)id, name, (long long)now);
    if (now != id)
        return sf_err_set(err, SF_EAGAIN, "job %lld is not on printer %s now: not cancelled",
                          (long long)id, name);
    return not_now(farm_printer_action_then(f, name, PRINTER_ACT_CANCEL, done, ud, err), err);
}

const char *
jobctl_printer_of(struct farm *f, int64_t id)
{
    size_t n = f ? farm_printer_count(f) : 0;
    for (size_t i = 0; i < n; i++) {
        struct printer_info p;
        farm_printer_info(f, i, &p);
        if (p.job_id == id)
            return p.cfg->name;
    }
    return NULL;
}

int
jobctl_restart(struct store *s, int64_t id, struct sf_err *err)
{
    return not_now(store_job_event(s, id, JOB_EV_RESTART, NULL, NULL, err), err);
}

int
jobctl_again(struct store *s, int64_t id, int64_t *new_id, struct sf_err *err)
{
    struct job_row j;
    int rc = store_job_get(s, id, &j, err);
    if (rc)
        return rc;
    if (strcmp(j.opts.method, "gcode") != 0)
        return store_job_add(s, &j.opts, j.file_sha, new_id, err);
    /* G-code as uploaded: what the upload's check found about it, kept with the job */
    struct job_event_args g = { .prep_key = j.prep_key,
                                .nozzle_mm = j.nozzle_mm,
                                .gcode_lines = j.gcode_lines,
                                .filament_g = j.filament_g,
                                .support_g = j.support_g,
                                .est_known = j.est_known,
                                .est_s = j.est_s };
    return store_job_add_gcode(s, &j.opts, j.gcode_sha, &g, new_id, err);
}

int
jobctl_resume(struct farm *f, int64_t id, int64_t line, struct sf_err *err)
{
    if (!f)
        return sf_err_set(err, SF_EAGAIN, "resuming jobs is not available here");
    return not_now(farm_job_resume(f, id, line, err), err);
}

int
jobctl_resume_then(struct farm *f, int64_t id, int64_t line, storeq_event_fn done, void *ud,
                   struct sf_err *err)
{
    if (!f)
        return sf_err_set(err, SF_EAGAIN, "resuming jobs is not available here");
    return farm_job_resume_then(f, id, line, done, ud, err);
}
