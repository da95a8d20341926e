/*
 * farm_gcheck.c - the farm's G-code checks on its io thread (farm_int.h,
 * farm.h): an uploaded G-code file judged before it becomes a job (the
 * G-code policy of every printer that may take it, its line count, the
 * slicer's comments, some printer that could run it), and every start's
 * file judged again by the policy of the printer it starts on.
 *
 * Thread: the loop thread; the reads run on the farm's io thread with
 * copies (never queued behind slicing).
 */
#include "farm_int.h"

#include <stdio.h>
#include <string.h>

#include "../../drivers/gpolicy.h"
#include "../base/log.h"
#include "../base/mem.h"
#include "farm_host.h"

/*
 * A start judged again by the G-code policy of the printer it starts on.
 * The upload (or prepare) judged the file by the policy of its day; a
 * reload since may have made the printer stricter (attended turned off,
 * an allow_gcode entry gone).  Every start reads the whole file once more,
 * on the io thread (as the upload check does), rather than keeping with
 * the job the policy it passed and judging again only when the printer's
 * is stricter: that would be a column in the store for one saved read of
 * a file the driver is about to read anyway, and a job that passed on one
 * printer of its key would need the same care when it starts on another.
 */
struct startcheck {
    struct farm *f;
    int64_t job_id;
    char printer[64];
    char name[JOB_NAME_MAX]; /* the job's name, for the policy's messages */
    char path[1200];
    struct drv_job_scan scan;
    bool counted;          /* scan holds the job's line count (else the driver counts) */
    uint64_t token;        /* the start it judges (printer_start_token) */
    struct gpolicy policy; /* the printer's, now */
    struct filament fil;   /* the file's net E by line, for the print's filament */
    struct sf_err err;
    char msg[1024]; /* the refused lines, "G-code 'NAME': line 12: M600: ..." */
};

static int
startcheck_work(void *ud, const atomic_bool *cancel)
{
    (void)cancel;
    struct startcheck *t = ud;
    int rc =
        gpolicy_check_file(&t->policy, t->path, t->name, t->msg, sizeof(t->msg), NULL, &t->err);
    /* a file it cannot read again only leaves the print's filament unknown (0) */
    if (rc == SF_OK && filament_scan(t->path, &t->fil, NULL) == SF_OK)
        t->fil.job_id = t->job_id;
    return rc;
}

static void
startcheck_done(struct loop *l, void *ud, int rc)
{
    (void)l;
    struct startcheck *t = ud;
    struct printer *p;
    /* Shutting down (SF_ECANCELED) leaves it for printer_stop. */
    if (rc != SF_ECANCELED && (p = farm_find(t->f, t->printer)) != NULL)
        printer_start_go(p, t->job_id, t->token, t->path, t->counted ? &t->scan : NULL, &t->fil, rc,
                         t->msg[0] ? t->msg : t->err.msg);
    free(t);
}

/* What a start does with G-code store_file_path could not give (err): */
enum fetch_verdict {
    FETCH_RETRY,     /* a passing error (busy, unreachable, in doubt, memory): here, later */
    FETCH_GIVE_BACK, /* this host cannot have it, another may: the host that stored it
                        before files were shared, one whose disk did not fail */
    FETCH_FAIL,      /* no host can: the file is gone from the store, or its bytes there are
                        damaged (a missing or short chunk, the wrong SHA-256) */
};

/* On the io thread: what a start does with G-code the store could not give (err), r a reader. */
static enum fetch_verdict
fetch_verdict(struct store *r, const char *sha, const struct sf_err *err)
{
    struct sf_err e;
    switch (err->code) {
    case SF_ENOTFOUND: { /* gone, or its bytes only in another host's data dir */
        int known = store_file_known(r, sha, &e);
        return known < 0 ? FETCH_RETRY : known ? FETCH_GIVE_BACK : FETCH_FAIL;
    }
    case SF_EIO: /* this host's file system (errno), else the store's bytes */
        return err->sys_errno ? FETCH_GIVE_BACK : FETCH_FAIL;
    case SF_EINVAL:
        return FETCH_FAIL;
    default:
        return FETCH_RETRY;
    }
}

/*
 * A start whose G-code is looked up on the io thread: on a shared store a
 * file this host's cache lacks is fetched from the database first (a
 * 100 MB job: 1-2 s), which the loop must not wait for.  Until the answer
 * is back the job and its printer are in f->looking: no pass starts
 * either again (farm_start_looking).
 */
struct startlook {
    struct farm *f;
    struct startlook *next;    /* in f->looking */
    const struct store *store; /* for the io thread's reader (store_open_reader) */
    struct job_row j;          /* the job as the pass read it */
    char printer[64];          /* the printer it starts on */
    int64_t fence;             /* the take's fencing token (0: one host) */
    char path[1200];           /* the G-code, local once found */
    enum fetch_verdict v;      /* when it was not */
    struct sf_err err;
};

static int
startlook_work(void *ud, const atomic_bool *cancel)
{
    (void)cancel;
    struct startlook *t = ud;
    struct store *r = store_open_reader(t->store, &t->err);
    int rc =
        r ? store_file_path(r, t->j.gcode_sha, t->path, sizeof(t->path), &t->err) : t->err.code;
    if (rc)
        t->v = r ? fetch_verdict(r, t->j.gcode_sha, &t->err) : FETCH_RETRY;
    store_close(r);
    return rc;
}

bool
farm_start_looking(const struct farm *f, int64_t job_id, const char *printer)
{
    for (const struct startlook *t = f->looking; t; t = t->next)
        if ((job_id && t->j.id == job_id) || (printer && strcmp(t->printer, printer) == 0))
            return true;
    return false;
}

/* Start t's job on p, its G-code looked up: rc (t->err, t->v) when it was not found. */
static void
start_on(struct farm *f, struct startlook *l, struct printer *p, int rc)
{
    const struct job_row *j = &l->j;
    struct sf_err err;
    struct startcheck *t = mem_calloc(1, sizeof(*t));
    if (!t) {
        farm_retry_later(f); /* the job stays this host's take, taken again then */
        return;
    }
    t->f = f;
    t->job_id = j->id;
    snprintf(t->printer, sizeof(t->printer), "%s", printer_cfg(p)->name);
    snprintf(t->name, sizeof(t->name), "%s", j->opts.name);
    snprintf(t->path, sizeof(t->path), "%s", l->path);
    /* The scan prepare made; G-code prepared before the count was stored
       (gcode_lines 0) is read by the driver itself, once. */
    t->scan = (struct drv_job_scan){ .lines_total = (uint64_t)j->gcode_lines };
    t->counted = j->gcode_lines > 0;
    farmcfg_policy(printer_cfg(p), &t->policy);
    if (rc)
        t->path[0] = '\0'; /* no file to estimate from */
    /* p is printing j from here: the scheduler picks neither again */
    if (printer_start(p, j, t->path)) {
        free(t);
        return;
    }
    t->token = printer_start_token(p);
    if (rc) { /* no host can have its G-code: the start fails the job, naming the file */
        sf_err_set(&t->err, rc, "its G-code (file %s) cannot be had from the store: %s",
                   j->gcode_sha, l->err.msg);
        startcheck_done(f->l, t, rc);
        return;
    }
    if (!pool_submit(f->io, startcheck_work, startcheck_done, t, &err))
        startcheck_done(f->l, t, startcheck_work(t, NULL)); /* no worker: judged here */
}

/*
 * The loop: t's G-code lookup is back (rc).  The printer may have gone,
 * been replaced, or taken something else meanwhile (an operator's resume):
 * then the job stays ready, this host's take, and is taken again later.
 */
static void
startlook_done(struct loop *l, void *ud, int rc)
{
    (void)l;
    struct startlook *t = ud;
    struct farm *f = t->f;
    for (struct startlook **pp = &f->looking; *pp; pp = &(*pp)->next)
        if (*pp == t) {
            *pp = t->next;
            break;
        }
    bool stop = rc == SF_ECANCELED || !f->pool;
    struct printer *p = stop ? NULL : farm_find(f, t->printer);
    int64_t id = t->j.id;
    if (stop) { /* shutting down: the job stays ready */
    } else if (rc && t->v != FETCH_FAIL) {
        log_warn("farm", "job %lld: %s", (long long)id, t->err.msg);
        if (p && printer_fence(p, id))
            printer_set_fence(p, 0, 0);
        if (t->v == FETCH_RETRY)
            farm_retry_later(f); /* the job stays this host's take, taken again then */
        else if (t->fence)
            farm_host_give_back(f, id, t->fence, t->err.msg);
    } else if (!p || printer_removed(p) || printer_state(p) != PRINTER_IDLE ||
               !printer_connected(p) || printer_job(p) || printer_fence(p, id) != t->fence) {
        log_info("farm", "job %lld: printer %s changed while its G-code was looked up: later",
                 (long long)id, t->printer);
        if (p && printer_fence(p, id))
            printer_set_fence(p, 0, 0);
        farm_retry_later(f);
    } else {
        start_on(f, t, p, rc);
    }
    free(t);
    farm_kick(f);
}

void
farm_start(struct farm *f, const struct job_row *j, struct printer *p)
{
    struct sf_err err;
    if (!f->files) /* stopping */
        return;
    if (farm_start_looking(f, j->id, printer_cfg(p)->name))
        return; /* its lookup's answer starts it (the pass should not have picked it) */
    struct startlook *t = mem_calloc(1, sizeof(*t));
    if (!t)
        return; /* the next kick tries again */
    t->f = f;
    t->store = f->s;
    t->j = *j;
    snprintf(t->printer, sizeof(t->printer), "%s", printer_cfg(p)->name);
    t->fence = printer_fence(p, j->id);
    if (!pool_submit(f->files, startlook_work, startlook_done, t, &err)) {
        free(t);
        farm_retry_later(f);
        return;
    }
    t->next = f->looking;
    f->looking = t;
}

/* An uploaded G-code file being checked on the io thread. */
struct gcheck {
    struct farm *f;
    char path[1200];
    struct job_opts o;
    struct farm_gcode g;
    struct gpolicy policy; /* what every printer that may take it passes (gpolicy_meet) */
    struct sf_err err;
    char msg[4096]; /* the policy's findings, every refused line (up to 20) */
    farm_gcode_fn done;
    void *ud;
};

/* The io thread: every line, and the slicer's comments (pure reads). */
static int
gcheck_work(void *ud, const atomic_bool *cancel)
{
    (void)cancel;
    struct gcheck *t = ud;
    struct drv_job_scan scan;
    int rc =
        gpolicy_check_file(&t->policy, t->path, t->o.name, t->msg, sizeof(t->msg), NULL, &t->err);
    if (rc)
        return rc;
    if ((rc = drv_job_scan(t->path, &scan, &t->err)) ||
        (rc = gcjob_read(t->path, &t->g.info, &t->err))) {
        /* the message names the temporary path: name the upload instead */
        const char *at = strstr(t->err.msg, t->path);
        if (at) {
            char rest[SF_ERR_MSG_MAX];
            size_t n = strlen(t->path);
            snprintf(rest, sizeof(rest), "%s", at + n + (at[n] == '\''));
            sf_err_set(&t->err, rc, "G-code '%s'%s", t->o.name, rest);
        }
        return rc;
    }
    if (scan.lines_total == 0)
        return sf_err_set(&t->err, SF_EINVAL, "G-code '%s' holds no command", t->o.name);
    t->g.lines = (int64_t)scan.lines_total;
    t->g.est_s = gcjob_estimate_s(t->path);
    gcjob_key(&t->g.info, t->g.key, sizeof(t->g.key));
    return SF_OK;
}

/* The loop thread: could some printer of the farm run it? */
static void
gcheck_done(struct loop *l, void *ud, int rc)
{
    (void)l;
    struct gcheck *t = ud;
    struct farm *f = t->f;
    if (rc == SF_ECANCELED) {
        sf_err_set(&t->err, rc, "the farm is stopping");
    } else if (rc == SF_OK) {
        /* Refuse now what no printer of the farm could ever run: a slicer
           user hears it at once, not from a job that waits forever.
           Material is not asked: an operator loads another spool, not
           another printer. */
        struct sched_job vj = { .state = JOB_READY,
                                .printer = t->o.printer,
                                .group = t->o.group,
                                .material = "",
                                .key = t->g.key };
        char why[SCHED_REASON_MAX] = "", one[160];
        bool any = false;
        for (size_t i = 0; i < f->n_printers && !any; i++) {
            struct sched_printer sp;
            farm_printer_view(f->printers[i], &sp);
            any = sched_compatible(&vj, &sp, one, sizeof(one));
            size_t len = strlen(why);
            if (!any)
                snprintf(why + len, sizeof(why) - len, "%s%s: %s", i ? "; " : "", sp.name, one);
        }
        const struct gcjob_info *g = &t->g.info;
        if (!any)
            rc = sf_err_set(&t->err, SF_EINVAL,
                            "G-code '%s' (%s%s%s, nozzle %g mm): no printer could run it: %s",
                            t->o.name,
                            g->model[0] ? "for printer model '" : "names no printer model",
                            g->model, g->model[0] ? "'" : "", g->nozzle_mm,
                            f->n_printers ? why : "no printers configured");
    }
    t->done(t->ud, rc, rc ? NULL : &t->g, t->msg[0] ? t->msg : t->err.msg);
    free(t);
}

int
farm_gcode_check(struct farm *f, const char *path, const struct job_opts *o, farm_gcode_fn done,
                 void *ud, struct sf_err *err)
{
    struct gcheck *t = mem_calloc(1, sizeof(*t));
    if (!t)
        return sf_err_set(err, SF_ENOMEM, "farm: out of memory");
    if (snprintf(t->path, sizeof(t->path), "%s", path) >= (int)sizeof(t->path)) {
        free(t);
        return sf_err_set(err, SF_EINVAL, "farm: path too long: '%.80s...'", path);
    }
    t->f = f;
    t->o = *o;
    /* a file passes the policy of every printer that may take it */
    gpolicy_all(&t->policy);
    for (size_t i = 0; i < f->n_printers; i++) {
        const struct farmcfg_printer *c = printer_cfg(f->printers[i]);
        struct gpolicy one;
        if ((o->printer[0] && strcmp(o->printer, c->name) != 0) ||
            (o->group[0] && strcmp(o->group, c->group) != 0))
            continue;
        farmcfg_policy(c, &one);
        gpolicy_meet(&t->policy, &one);
    }
    t->done = done;
    t->ud = ud;
    /* on the io thread, beside resume reads: never queued behind slicing */
    if (!pool_submit(f->io, gcheck_work, gcheck_done, t, err)) {
        free(t);
        return err ? err->code : SF_ENOMEM;
    }
    return SF_OK;
}

/* On the store's thread: a's upload adopted, recorded, its job added and read back. */
static int
add_write(struct store *s, void *ud, struct sf_err *err)
{
    struct farm_add *a = ud;
    if (!a->adopted) { /* the file system's half: not tried again (its temporary is moved) */
        a->adopted = true;
        a->adopt_rc = store_file_adopt(a->store, a->tmp, a->sha, &a->size, &a->adopt_err);
    }
    if (a->adopt_rc) { /* reported at once: a code the queue does not retry */
        *err = a->adopt_err;
        return SF_ECANCELED;
    }
    int rc = store_file_record(s, a->sha, a->size, err);
    if (rc == SF_OK && !a->added) {
        struct job_event_args g = { .prep_key = a->g.key,
                                    .nozzle_mm = a->g.info.nozzle_mm,
                                    .gcode_lines = a->g.lines,
                                    .filament_g = a->g.info.filament_g,
                                    .support_g = a->g.info.support_g,
                                    .est_known = true,
                                    .est_s = a->g.est_s };
        rc = a->gcode ? store_job_add_gcode(s, &a->o, a->sha, &g, &a->id, err)
                      : store_job_add(s, &a->o, a->sha, &a->id, err);
        if (rc == SF_OK) {
            a->added = true; /* a retry after this adds nothing twice */
            if (a->gcode)
                log_info("farm", "job %lld: G-code '%s' queued as is (%lld lines, %s)",
                         (long long)a->id, a->o.name, (long long)a->g.lines, a->g.key);
        }
    }
    return rc ? rc : store_job_get(s, a->id, &a->j, err);
}

int
farm_add_post(struct farm *f, struct farm_add *a, storeq_event_fn done, void *ud,
              struct sf_err *err)
{
    a->store = f->s;
    if (storeq_call(f->q, add_write, a, NULL, done, ud))
        return sf_err_set(err, SF_ENOMEM, "farm: out of memory");
    return SF_OK; /* its commit wakes the farm (on_store_commit) */
}

int
farm_gcode_add(struct farm *f, struct farm_add *a, const struct farm_gcode *g, storeq_event_fn done,
               void *ud, struct sf_err *err)
{
    if (!a->o.material[0] && g->info.material[0])
        snprintf(a->o.material, sizeof(a->o.material), "%s", g->info.material);
    a->gcode = true;
    a->g = *g;
    return farm_add_post(f, a, done, ud, err);
}
