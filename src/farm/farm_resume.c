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
#include <string.h>

#include "../../drivers/gpolicy.h"
#include "../base/log.h"
#include "../base/mem.h"
#include "farm_host.h"

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

/* What a resume reads from the store (resume_read): on the loop, or on the store's thread. */
struct resume_ask {
    struct farm *f;
    int64_t id, line;
    struct job_row j;
    char path[1200];
    struct drv_job_scan scan;
    storeq_event_fn done; /* the answer (farm_job_resume_then) */
    void *ud;
    bool held;               /* one of several hosts: the job is held, under fence */
    int64_t fence;           /* (farm_host_hold_ask, on the store's thread) */
    struct resume_ask *next; /* in f->resuming while its hold is on its way */
};

/* Job a->id and, when it is interrupted, its G-code's path and line count. */
static int
resume_read(struct store *s, void *arg, struct sf_err *err)
{
    struct resume_ask *a = arg;
    int rc = store_job_get(s, a->id, &a->j, err);
    if (rc || a->j.state != JOB_INTERRUPTED)
        return rc; /* refused by resume_go */
    /* G-code prepared before its count was kept (gcode_lines 0) is scanned here */
    a->scan = (struct drv_job_scan){ .lines_total = (uint64_t)a->j.gcode_lines };
    if ((rc = store_file_path(s, a->j.gcode_sha, a->path, sizeof(a->path), err)) ||
        (a->j.gcode_lines == 0 && (rc = drv_job_scan(a->path, &a->scan, err))))
        return rc;
    return SF_OK;
}

/* May a's job, read (resume_read), resume now?  Its printer in *pp, its line in *linep. */
static int
resume_check(struct farm *f, struct resume_ask *a, struct printer **pp, int64_t *linep,
             struct sf_err *err)
{
    struct job_row *jr = &a->j;
    int64_t id = a->id, line = a->line;
    if (jr->state != JOB_INTERRUPTED)
        return sf_err_set(err, SF_EINVAL, "job %lld is %s: only an interrupted job can be resumed",
                          (long long)id, job_state_name(jr->state));
    struct printer *p = farm_find(f, jr->printer);
    if (!p || printer_removed(p))
        return sf_err_set(err, SF_EINVAL,
                          "job %lld: its part is on printer '%s', which is no longer configured",
                          (long long)id, jr->printer);
    if (printer_state(p) != PRINTER_IDLE || !printer_connected(p) || printer_job(p))
        return sf_err_set(err, SF_EINVAL, "job %lld: printer %s is %s; resume when it is idle",
                          (long long)id, jr->printer, printer_state_name(printer_state(p)));
    if (line < 0)
        line = jr->lines_acked;
    uint64_t total = a->scan.lines_total;
    /* Line 0 would run the job's own start: its G28 homes Z into the part. */
    if (line < 1 || (uint64_t)line >= total)
        return sf_err_set(err, SF_EINVAL,
                          "job %lld: line %lld is out of range: resume from 1..%llu (the job has "
                          "%llu command lines; to print from line 0, clear the bed and restart)",
                          (long long)id, (long long)line,
                          (unsigned long long)(total > 1 ? total - 1 : 1),
                          (unsigned long long)total);
    *pp = p;
    *linep = line;
    return SF_OK;
}

/* The resume of a's job, read (resume_read): its checks, the commit, the read up to the line. */
static int
resume_go(struct farm *f, struct resume_ask *a, struct sf_err *err)
{
    struct job_row *jr = &a->j;
    int64_t id = a->id, line = 0;
    struct printer *p = NULL;
    int rc = resume_check(f, a, &p, &line, err);
    if (rc)
        return rc;
    uint64_t total = a->scan.lines_total;
    struct resume *r = mem_calloc(1, sizeof(*r));
    if (!r)
        return sf_err_set(err, SF_ENOMEM, "job %lld: out of memory", (long long)id);
    if ((rc = a->held ? printer_resume_fenced(p, id, line, a->fence, err)
                      : printer_resume_commit(p, id, line, err))) {
        free(r);
        return rc;
    }
    /* The machine state at `line` comes from reading the file up to it
       (0.5 s for 2/3 of a 112 MB job): on the io thread, so the other
       printers' streams do not wait; the driver starts when it is read. */
    log_printer(LOG_INFO, jr->printer, "job %lld: resumed at line %lld of %llu", (long long)id,
                (long long)line, (unsigned long long)total);
    double est_s = printer_estimate_s(jr, a->path);
    struct sf_err perr;
    *r = (struct resume){
        .f = f, .job_id = id, .line = (uint64_t)line, .scan = a->scan, .est_s = est_s
    };
    snprintf(r->printer, sizeof(r->printer), "%s", jr->printer);
    snprintf(r->path, sizeof(r->path), "%s", a->path);
    snprintf(r->name, sizeof(r->name), "%s", jr->opts.name);
    farmcfg_policy(printer_cfg(p), &r->policy);
    if (!pool_submit(f->io, resume_work, resume_done, r, &perr))
        resume_done(f->l, r, resume_work(r, NULL)); /* no worker: judged and read here */
    farm_kick(f);
    return SF_OK;
}

int
farm_job_resume(struct farm *f, int64_t id, int64_t line, struct sf_err *err)
{
    struct resume_ask *a = mem_calloc(1, sizeof(*a));
    if (!a)
        return sf_err_set(err, SF_ENOMEM, "job %lld: out of memory", (long long)id);
    a->id = id;
    a->line = line;
    int rc = resume_read(f->s, a, err);
    if (rc == SF_OK)
        rc = resume_go(f, a, err);
    free(a);
    return rc;
}

/* Answer a's resume (rc, err): a refusal now; once its RESUME (queued) committed otherwise. */
static void
resume_answer(struct resume_ask *a, int rc, struct sf_err *errp)
{
    struct farm *f = a->f;
    struct sf_err err = *errp;
    /* its RESUME is queued: the answer follows it */
    if (rc || storeq_barrier(f->q, a->done, a->ud)) {
        if (!rc)
            rc = sf_err_set(&err, SF_ENOMEM, "job %lld: out of memory: resumed, its answer is lost",
                            (long long)a->id);
        struct storeq_result res = { .id = a->id, .rc = rc, .err = &err };
        a->done(a->ud, &res);
    }
    free(a);
}

/* The hold of a's job came back (rc, fence): resume it, its state checked again (the printer
   may have moved meanwhile), and answer. */
static void
on_resume_held(void *ud, int rc, int64_t fence, const struct sf_err *herr)
{
    struct resume_ask *a = ud;
    struct farm *f = a->f;
    for (struct resume_ask **pp = &f->resuming; *pp; pp = &(*pp)->next)
        if (*pp == a) {
            *pp = a->next;
            break;
        }
    struct sf_err err = { 0 };
    if (rc)
        err = herr ? *herr : err;
    else if (f->stopping)
        rc = sf_err_set(&err, SF_ECANCELED, "job %lld: the daemon stops: not resumed",
                        (long long)a->id);
    else {
        a->held = true;
        a->fence = fence;
        rc = resume_go(f, a, &err);
    }
    resume_answer(a, rc, &err);
}

/* One of several hosts: hold a's job on the store's thread (farm_host_hold_ask) before the
   resume (on_resume_held); one resume per job and per printer at a time.  SF_OK with *posted
   false: nothing to hold (one host). */
static int
resume_hold(struct farm *f, struct resume_ask *a, bool *posted, struct sf_err *err)
{
    *posted = false;
    if (!f->host)
        return SF_OK;
    for (const struct resume_ask *o = f->resuming; o; o = o->next)
        if (o->id == a->id || !strcmp(o->j.printer, a->j.printer))
            return sf_err_set(err, SF_EINVAL,
                              "job %lld: printer %s has a resume on its way; try again once it "
                              "is answered",
                              (long long)a->id, a->j.printer);
    int rc = farm_host_hold_ask(f, a->id, a->j.printer, posted, on_resume_held, a, err);
    if (rc == SF_OK && *posted) {
        a->next = f->resuming;
        f->resuming = a;
    }
    return rc;
}

/* The job came back from the store's thread: resume it (held first on the store's thread by
   one of several hosts); answered once its RESUME committed. */
static void
on_resume_read(void *ud, const struct storeq_result *r)
{
    struct resume_ask *a = ud;
    struct farm *f = a->f;
    struct sf_err err = { 0 };
    int rc = r->rc;
    bool posted = false;
    struct printer *p = NULL;
    int64_t line = 0;
    if (rc)
        err = *r->err;
    else if (f->stopping)
        rc = sf_err_set(&err, SF_ECANCELED, "job %lld: the daemon stops: not resumed",
                        (long long)a->id);
    else if ((rc = resume_check(f, a, &p, &line, &err)) == SF_OK &&
             (rc = resume_hold(f, a, &posted, &err)) == SF_OK && !posted)
        rc = resume_go(f, a, &err);
    if (!posted)
        resume_answer(a, rc, &err);
}

int
farm_job_resume_then(struct farm *f, int64_t id, int64_t line, storeq_event_fn done, void *ud,
                     struct sf_err *err)
{
    struct resume_ask *a = mem_calloc(1, sizeof(*a));
    if (!a)
        return sf_err_set(err, SF_ENOMEM, "job %lld: out of memory", (long long)id);
    *a = (struct resume_ask){ .f = f, .id = id, .line = line, .done = done, .ud = ud };
    if (storeq_read(f->q, resume_read, a, on_resume_read, a)) {
        free(a);
        return sf_err_set(err, SF_ENOMEM, "job %lld: out of memory", (long long)id);
    }
    return SF_OK;
}
