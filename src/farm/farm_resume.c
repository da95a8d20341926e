/*
 * farm_resume.c - an interrupted job resumed at a line (farm_job_resume,
 * farm.h): its checks, the commit, and on the farm's io thread the file
 * judged by its printer's G-code policy as it is now (as every start is,
 * farm_gcheck.c: a reload may have made the printer stricter) and read up
 * to that line, before the driver starts.
 *
 * Thread: the loop thread; the read runs on the io thread with a copy.
 */
#include "farm_int.h"

#include <stdio.h>

#include "../../drivers/gpolicy.h"
#include "../base/log.h"
#include "../base/mem.h"

/* A resume waiting for its read (drv_job_scan_to) on the io thread. */
struct resume {
    struct farm *f;
    int64_t job_id;
    char printer[64];
    char path[1200];
    uint64_t line;
    struct drv_job_scan scan;
    double est_s;            /* the job's print time estimate (printer_estimate_s) */
    char name[JOB_NAME_MAX]; /* the job's name, for the policy's messages */
    struct gpolicy policy;   /* the printer's, now */
    struct sf_err err;
    char msg[1024]; /* the refused lines, as a start's check gives them */
};

static int
resume_work(void *ud, const atomic_bool *cancel)
{
    (void)cancel;
    struct resume *r = ud;
    int rc =
        gpolicy_check_file(&r->policy, r->path, r->name, r->msg, sizeof(r->msg), NULL, &r->err);
    return rc ? rc : drv_job_scan_to(r->path, r->line, &r->scan, &r->err);
}

static void
resume_done(struct loop *l, void *ud, int rc)
{
    (void)l;
    struct resume *r = ud;
    /* Shutting down (SF_ECANCELED) leaves it for printer_stop. */
    struct printer *p = rc == SF_ECANCELED ? NULL : farm_find(r->f, r->printer);
    if (p)
        printer_resume_go(p, r->job_id, r->path, r->line, &r->scan, r->est_s, rc,
                          r->msg[0] ? r->msg : r->err.msg);
    free(r);
}

int
farm_job_resume(struct farm *f, int64_t id, int64_t line, struct sf_err *err)
{
    struct job_row j;
    int rc = store_job_get(f->s, id, &j, err);
    if (rc)
        return rc;
    if (j.state != JOB_INTERRUPTED)
        return sf_err_set(err, SF_EINVAL, "job %lld is %s: only an interrupted job can be resumed",
                          (long long)id, job_state_name(j.state));
    struct printer *p = farm_find(f, j.printer);
    if (!p || printer_removed(p))
        return sf_err_set(err, SF_EINVAL,
                          "job %lld: its part is on printer '%s', which is no longer configured",
                          (long long)id, j.printer);
    if (printer_state(p) != PRINTER_IDLE || !printer_connected(p) || printer_job(p))
        return sf_err_set(err, SF_EINVAL, "job %lld: printer %s is %s; resume when it is idle",
                          (long long)id, j.printer, printer_state_name(printer_state(p)));
    if (line < 0)
        line = j.lines_acked;
    char path[1200];
    /* G-code prepared before its count was kept (gcode_lines 0) is scanned here */
    struct drv_job_scan scan = { .lines_total = (uint64_t)j.gcode_lines };
    if ((rc = store_file_path(f->s, j.gcode_sha, path, sizeof(path), err)) ||
        (j.gcode_lines == 0 && (rc = drv_job_scan(path, &scan, err))))
        return rc;
    uint64_t total = scan.lines_total;
    /* Line 0 would run the job's own start: its G28 homes Z into the part. */
    if (line < 1 || (uint64_t)line >= total)
        return sf_err_set(err, SF_EINVAL,
                          "job %lld: line %lld is out of range: resume from 1..%llu (the job has "
                          "%llu command lines; to print from line 0, clear the bed and restart)",
                          (long long)id, (long long)line,
                          (unsigned long long)(total > 1 ? total - 1 : 1),
                          (unsigned long long)total);
    struct resume *r = mem_calloc(1, sizeof(*r));
    if (!r)
        return sf_err_set(err, SF_ENOMEM, "job %lld: out of memory", (long long)id);
    if ((rc = printer_resume_commit(p, id, line, err))) {
        free(r);
        return rc;
    }
    /* The machine state at `line` comes from reading the file up to it
       (0.5 s for 2/3 of a 112 MB job): on the io thread, so the other
       printers' streams do not wait; the driver starts when it is read. */
    log_printer(LOG_INFO, j.printer, "job %lld: resumed at line %lld of %llu", (long long)id,
                (long long)line, (unsigned long long)total);
    double est_s = printer_estimate_s(&j, path);
    struct sf_err perr;
    *r = (struct resume){
        .f = f, .job_id = id, .line = (uint64_t)line, .scan = scan, .est_s = est_s
    };
    snprintf(r->printer, sizeof(r->printer), "%s", j.printer);
    snprintf(r->path, sizeof(r->path), "%s", path);
    snprintf(r->name, sizeof(r->name), "%s", j.opts.name);
    farmcfg_policy(printer_cfg(p), &r->policy);
    if (!pool_submit(f->io, resume_work, resume_done, r, &perr))
        resume_done(f->l, r, resume_work(r, NULL)); /* no worker: judged and read here */
    farm_kick(f);
    return SF_OK;
}
