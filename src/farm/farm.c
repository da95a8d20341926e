/*
 * farm.c - the printers (printer.h), the prepare stage and the scheduler,
 * tied together on the event loop over the job store (see farm.h).
 *
 * Why one module: each piece is pure or owns its own state (job.h rules,
 * sched.h matching, store.h transactions, printer.h printers, pool.h
 * workers); what is left is the glue that decides what to prepare, for
 * which printer, and what to start where.  Design: every reaction is
 * "commit to the store, then act on the device", so a crash between the
 * two leaves the store ahead of the printer, which recovery turns into
 * "interrupted" for the operator, never into a silently repeated print.
 * Work is triggered by a zero-delay timer (farm_kick), so bursts of
 * printer and job events coalesce into one scheduling pass.
 *
 * Files: this one holds the prepare stage, the scheduling pass, the
 * printers' lifecycle and reload; farm_gcheck.c the G-code checks on the io
 * thread (an upload's, and every start's by its printer's policy),
 * farm_resume.c an interrupted job's resume; farm_int.h what they share
 * (struct farm), internal to these files.
 *
 * Thread: the loop thread; prepare work runs on pool workers with copies,
 * resume reads and G-code checks on the farm's own io thread.
 */
#include "farm.h"
#include "farm_int.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "../../drivers/gpolicy.h"
#include "../base/clock.h"
#include "../base/log.h"
#include "../base/mem.h"
#include "farm_host.h"
#include "farm_remote.h"
#include "gcjob.h"
#include "sched.h"
#include "store_host.h"

/* A job that could not be prepared for a printer's key (its profile is broken). */
struct noreslice {
    int64_t job_id;
    char key[SCHED_KEY_MAX];
};

/* A prepare task: plain data copied for the worker. */
struct prep {
    struct farm *f;                /* owner (used only on the loop thread) */
    struct prep *next;             /* in f->reslices (re-slices), f->posted (its PREPARE) */
    bool reslice;                  /* the job is ready and stays so: this is another printer's */
    char key[SCHED_KEY_MAX];       /* sched_key of the printer it is prepared for */
    double angle_deg;              /* the overhang angle it is prepared with */
    struct prepare_req req;        /* input */
    struct prepare_out out;        /* output */
    struct drv_job_scan scan;      /* the G-code's scan, made on the worker too */
    double est_s;                  /* and its print time estimate (gcjob_estimate_s) */
    const struct store *store;     /* for store_file_adopt, farm_prep_files on the worker */
    char part_sha[STORE_SHA_HEX];  /* the part, and the optimized one reused ("" if none): */
    char reuse_sha[STORE_SHA_HEX]; /* their paths looked up by the worker (farm_prep_files) */
    bool files_failed;             /* ... which failed (err says why) */
    char gcode_sha[STORE_SHA_HEX]; /* the G-code, adopted into the store by the worker */
    int64_t gcode_size;
    char mesh_sha[STORE_SHA_HEX]; /* the optimized part, adopted by the worker; "" if none */
    int64_t mesh_size;
    int64_t prepare_ms; /* the prepare function's wall time */
    int64_t fence;      /* the claim's fencing token (farm_host.h); 0 on a single host */
    bool hand_over;     /* for another host's printer: its PREPARED gives the claim up */
    struct sf_err err;  /* why it failed */
    struct job_event_args prepared; /* its PREPARED, written on the store thread */
    enum job_state to;              /* the job's state after it */
};

static void run(struct loop *l, void *ud);

void
farm_notify(struct farm *f)
{
    if (f->hooks.notify)
        f->hooks.notify(f->hooks.notify_ud);
}

void
farm_drop_pool(struct farm *f)
{
    if (!f)
        return;
    f->pool = NULL;
    if (f->kick)
        loop_timer_cancel(f->l, f->kick);
    f->kick = 0;
}

void
farm_kick(struct farm *f)
{
    if (!f->pool)
        return; /* shutting down: nothing starts any more */
    if (!f->kick)
        f->kick = loop_timer_add(f->l, 0, run, f);
}

struct printer *
farm_find(const struct farm *f, const char *name)
{
    for (size_t i = 0; i < f->n_printers; i++)
        if (strcmp(printer_cfg(f->printers[i])->name, name) == 0)
            return f->printers[i];
    return NULL;
}

/* A printer moved or a job on it did: wake event streams, schedule. */
static void
on_printer_changed(void *ud)
{
    struct farm *f = ud;
    farm_notify(f);
    farm_kick(f);
}

/* A printer for cfg; old (NULL: none) the one it replaces, whose bed it keeps. */
struct printer *
farm_printer_new(struct farm *f, const struct farmcfg_printer *cfg, const struct printer *old)
{
    struct printer_env env = {
        .bed_known = old && printer_bed_known(old), /* not while its read is on its way */
        .bed_full = old && printer_bed_full(old),
        .l = f->l,
        .s = f->s,
        .q = f->q,
        .driver = f->hooks.driver,
        .changed = on_printer_changed,
        .ud = f,
        .hold = farm_host_hold,
        .hold_ask = farm_host_hold_ask,
    };
    return printer_new(&env, cfg);
}

/* Queued writes committed (storeq.h): event streams read them, the scheduler sees them. */
static void
on_store_commit(void *ud)
{
    struct farm *f = ud;
    farm_notify(f);
    farm_kick(f);
}

int
farm_sync(struct farm *f, int64_t max_ms, struct sf_err *err)
{
    return f ? storeq_sync(f->q, max_ms, err) : SF_OK;
}

void
farm_health(struct farm *f, struct farm_health *out)
{
    out->loop_turn_max_ms = loop_turn_max_ms(f->l);
    out->loop_round_trips = store_round_trips(f->s);
    storeq_stats(f->q, &out->store);
    out->has_beat = farm_host_beat_stats(f, &out->beat);
}

/* ---- prepare ---- */

static int
prep_work(void *ud, const atomic_bool *cancel)
{
    struct prep *t = ud;
    int rc = farm_prep_files(t->store, &t->req, t->part_sha, t->reuse_sha, t->reslice, &t->err);
    if (rc) {
        t->files_failed = true;
        return rc;
    }
    int64_t t0 = clock_mono_ms();
    rc = t->f->hooks.prepare(&t->req, &t->out, cancel, &t->err);
    t->prepare_ms = clock_mono_ms() - t0;
    if (rc == SF_OK) /* kept with the job: a start reads it from there, not the file */
        t->est_s = gcjob_estimate_s(t->req.out_path);
    /* Count and check the G-code here, off the loop: a bad line fails the
       job now, not half-way through a print, and start_job need not read
       the file on the loop thread (a 150 MB job stalled every printer's
       stream ~2.5 s).  Hashing it into the store is the other long read. */
    /* The policy too (gpolicy.h): the farm's own slicer never breaks it, a
       profile's custom G-code could (an M600 for an unattended printer). */
    struct gpolicy pol;
    char why[1024];
    farmcfg_policy(&t->req.printer, &pol);
    if (rc == SF_OK &&
        ((rc = gpolicy_check_file(&pol, t->req.out_path, t->req.part_name, why, sizeof(why), NULL,
                                  &t->err)) ||
         (rc = drv_job_scan(t->req.out_path, &t->scan, &t->err)) ||
         (rc =
              store_file_adopt(t->store, t->req.out_path, t->gcode_sha, &t->gcode_size, &t->err)) ||
         (t->out.mesh_saved &&
          (rc = store_file_adopt(t->store, t->req.mesh_out, t->mesh_sha, &t->mesh_size, &t->err)))))
        sf_err_prefix(&t->err, "job %lld", (long long)t->req.job_id);
    return rc;
}

static void
unlink_reslice(struct farm *f, struct prep *t)
{
    for (struct prep **pp = &f->reslices; *pp; pp = &(*pp)->next)
        if (*pp == t) {
            *pp = t->next;
            return;
        }
}

static bool
reslicing(const struct farm *f, int64_t id)
{
    for (const struct prep *t = f->reslices; t; t = t->next)
        if (t->req.job_id == id)
            return true;
    return false;
}

static bool
reslice_failed(const struct farm *f, int64_t id, const char *key)
{
    for (size_t i = 0; i < f->n_no; i++)
        if (f->no[i].job_id == id && strcmp(f->no[i].key, key) == 0)
            return true;
    return false;
}

/* Did slicing job id again fail for any printer? */
static bool
reslice_failed_any(const struct farm *f, int64_t id)
{
    for (size_t i = 0; i < f->n_no; i++)
        if (f->no[i].job_id == id)
            return true;
    return false;
}

/* On the store thread: record the files task ud made, then its PREPARED (store_file_record
   is idempotent: a retry after a failure half-way records nothing twice).  Read back first:
   a PREPARED written again after a commit nobody could settle (SF_EINDOUBT) finds itself
   there (the job holds this G-code for this key, out of preparing) and is not applied
   twice. */
static int
prepared_write(struct store *s, void *ud, struct sf_err *err)
{
    struct prep *t = ud;
    struct job_row j;
    int rc = store_job_get(s, t->req.job_id, &j, err);
    if (rc == SF_OK && strcmp(j.gcode_sha, t->gcode_sha) == 0 && strcmp(j.prep_key, t->key) == 0 &&
        (t->reslice || j.state != JOB_PREPARING)) {
        t->to = j.state;
        return SF_OK;
    }
    if (rc == SF_OK)
        rc = store_file_record(s, t->gcode_sha, t->gcode_size, err);
    if (rc == SF_OK && t->mesh_sha[0])
        rc = store_file_record(s, t->mesh_sha, t->mesh_size, err);
    if (rc == SF_OK)
        rc = t->hand_over
                 ? store_job_prepared_release(s, t->req.job_id, &t->prepared, &t->to, err)
                 : store_job_event(s, t->req.job_id, JOB_EV_PREPARED, &t->prepared, &t->to, err);
    if (rc)
        sf_err_prefix(err, "job %lld", (long long)t->req.job_id);
    return rc;
}

/*
 * Task t's PREPARED came back from the store thread (its commit wakes the
 * farm: on_store_commit).  A re-slice stays in f->reslices until now, so
 * no scheduling pass in between, still reading the old G-code's key,
 * slices the job once more.  Every answer has its course:
 *   SF_OK: the job is ready.
 *   SF_EBUSY, SF_EUNREACH: nothing written though the store thread tried
 *     for STOREQ_RETRY_MS; SF_EINDOUBT: whether it was, nobody could tell.
 *     Written again (prepared_write reads back first): the job stays
 *     preparing meanwhile, not stuck (a DEFER would meet the same store).
 *   SF_EINVAL, SF_EAGAIN, SF_ENOTFOUND, SF_ESTALE: the store refused the
 *     event: the job moved on meanwhile (cancelled, removed, another host's).
 *   Anything else (SF_EIO: a constraint, a trigger, a damaged file): the
 *     same every time, so the job fails, once, saying why.  It was sent
 *     back to the queue (DEFER), prepared, refused again, for ever.
 * At shutdown nothing is written again: the next start's recovery requeues
 * a job left preparing.
 */
static void
on_prepared(void *ud, const struct storeq_result *r)
{
    struct prep *t = ud;
    struct farm *f = t->f;
    int64_t id = t->req.job_id;
    const char *msg = r->rc ? r->err->msg : "";
    switch (r->rc) {
    case SF_OK:
        log_info("farm", "job %lld: %s for %s", (long long)id,
                 t->reslice ? "prepared again" : "prepared", t->key);
        break;
    case SF_EBUSY:
    case SF_EUNREACH:
    case SF_EINDOUBT:
        if (f->pool && !f->stopping &&
            storeq_call(f->q, prepared_write, t, NULL, on_prepared, t) == SF_OK) {
            log_warn("farm", "job %lld: its G-code is not recorded yet, trying again: %s",
                     (long long)id, msg);
            return; /* t waits again */
        }
        log_warn("farm", "job %lld: not recorded as prepared: %s", (long long)id, msg);
        break;
    case SF_EINVAL:
    case SF_EAGAIN:
    case SF_ENOTFOUND:
    case SF_ESTALE:
        log_info("farm", "job %lld: %s", (long long)id, msg);
        break;
    default:
        log_warn("farm", "job %lld: the store refused its prepared G-code: %s", (long long)id, msg);
        if (t->reslice) { /* the job keeps its G-code; this key is not tried again */
            if (mem_grow((void **)&f->no, &f->cap_no, f->n_no + 1, sizeof(*f->no))) {
                f->no[f->n_no].job_id = id;
                snprintf(f->no[f->n_no++].key, SCHED_KEY_MAX, "%s", t->key);
            }
        } else {
            char why[SF_ERR_MSG_MAX + 64];
            snprintf(why, sizeof(why), "the store refused its prepared G-code: %s", msg);
            struct job_event_args a = { .reason = why, .fence = t->fence };
            farm_prep_end(f, id, JOB_EV_PREPARE_FAILED, &a);
        }
        break;
    }
    if (t->reslice)
        unlink_reslice(f, t);
    farm_kick(f);
    free(t);
}

/* Whether a worker's failure was the store's database not answering now (busy, unreachable,
   an upload's commit in doubt: sqldb.h), a failure of the moment, not of the job. */
static bool
db_passing(int rc)
{
    return rc == SF_EBUSY || rc == SF_EUNREACH || rc == SF_EINDOUBT;
}

static bool passing(int rc);

/* Task t's part (or the optimized one it reuses) could not be had (rc): only a file that is
   not there, or not valid, fails the job; a database that does not answer now (another host's
   upload not fetched yet) may later: the job goes back to the queue (farm_cool).  A re-slice
   leaves its job ready: a file gone is not tried again for this key, a passing error is. */
static void
files_failed(struct farm *f, struct prep *t, int rc)
{
    int64_t id = t->req.job_id;
    const char *why = t->err.msg;
    if (passing(rc))
        farm_cool(f, id);
    if (t->reslice) {
        log_warn("farm", "job %lld: %s", (long long)id, why);
        if (!passing(rc) && mem_grow((void **)&f->no, &f->cap_no, f->n_no + 1, sizeof(*f->no))) {
            f->no[f->n_no].job_id = id;
            snprintf(f->no[f->n_no++].key, SCHED_KEY_MAX, "%s", t->key);
        }
        return;
    }
    struct job_event_args a = { .reason = why, .fence = t->fence };
    if (passing(rc)) {
        log_warn("farm", "job %lld goes back to the queue: %s", (long long)id, why);
        farm_prep_end(f, id, JOB_EV_DEFER, &a);
    } else {
        farm_prep_end(f, id, JOB_EV_PREPARE_FAILED, &a);
    }
}

static void
prep_done(struct loop *l, void *ud, int rc)
{
    (void)l;
    struct prep *t = ud;
    struct farm *f = t->f;
    int64_t id = t->req.job_id;
    bool queued = false; /* t waits for its PREPARED (on_prepared frees it) */
    f->preparing--;
    if (rc == SF_OK) {
        struct job_event_args a = { .gcode_sha = t->gcode_sha,
                                    .nozzle_mm = t->out.nozzle_mm,
                                    .gcode_lines = (int64_t)t->scan.lines_total,
                                    .prep_key = t->key,
                                    .mesh_sha = t->mesh_sha,
                                    .mesh_angle_deg = t->angle_deg,
                                    .filament_g = t->out.filament_g,
                                    .support_g = t->out.support_g,
                                    .saved_g = t->out.support_saved_g,
                                    .prepare_ms = t->prepare_ms,
                                    .slice_ms = t->out.slice_ms,
                                    .dev_measured = t->out.dev_measured,
                                    .shape_changed = t->out.shape_changed,
                                    .mndr = t->out.mndr,
                                    .andr = t->out.andr,
                                    .est_known = true,
                                    .est_s = t->est_s,
                                    .note = t->out.shape_failed,
                                    .fence = t->fence };
        memcpy(a.size_mm, t->out.size_mm, sizeof(a.size_mm));
        /* A re-slice whose job started meanwhile on a printer of its old key
           (or was cancelled) is refused there and dropped: nothing changed.
           Queued: a prepare ending while the store is busy holds up no print.
           Out of memory, the job stays preparing until the next start's recovery. */
        t->prepared = a; /* its strings are t's: t waits, untouched, until on_prepared */
        queued = storeq_call(f->q, prepared_write, t, NULL, on_prepared, t) == SF_OK;
    } else if (rc != SF_ECANCELED && t->files_failed) {
        files_failed(f, t, rc);
    } else if (rc != SF_ECANCELED) {
        const char *why = t->err.msg;
        if (t->reslice) {
            /* The job keeps the G-code it has; this printer's key is not tried again. */
            log_warn("farm", "job %lld: cannot prepare it for %s: %s", (long long)id, t->key, why);
            if (mem_grow((void **)&f->no, &f->cap_no, f->n_no + 1, sizeof(*f->no))) {
                f->no[f->n_no].job_id = id;
                snprintf(f->no[f->n_no++].key, SCHED_KEY_MAX, "%s", t->key);
            }
        } else if (db_passing(rc)) {
            /* The store's database, not the job: its G-code could not be adopted (PostgreSQL
               down a moment).  Back to the queue, prepared again, not failed for a blip. */
            log_warn("farm", "job %lld goes back to the queue: %s", (long long)id, why);
            struct job_event_args a = { .reason = why, .fence = t->fence };
            farm_prep_end(f, id, JOB_EV_DEFER, &a);
        } else {
            struct job_event_args a = { .reason = why, .fence = t->fence };
            farm_prep_end(f, id, JOB_EV_PREPARE_FAILED, &a);
        }
    }
    if (t->req.out_path[0])
        unlink(t->req.out_path); /* gone when adopted */
    if (t->req.mesh_out[0])
        unlink(t->req.mesh_out);
    if (!queued) {
        if (t->reslice)
            unlink_reslice(f, t);
        free(t);
    }
    farm_kick(f);
}

/* Run the scheduler again later: a passing store failure left a job queued. */
static void
on_retry(struct loop *l, void *ud)
{
    (void)l;
    struct farm *f = ud;
    f->retry = 0;
    farm_kick(f);
}

static void
retry_later(struct farm *f)
{
    if (!f->retry && f->pool)
        f->retry = loop_timer_add(f->l, FARM_RETRY_MS, on_retry, f);
}

void
farm_retry_later(struct farm *f)
{
    retry_later(f);
}

void
farm_retry_soon(struct farm *f)
{
    if (!f->pool)
        return;
    if (f->retry)
        loop_timer_cancel(f->l, f->retry);
    int64_t jitter = (clock_mono_ms() * 7919) % FARM_BUSY_RETRY_MS; /* hosts apart */
    f->retry = loop_timer_add(f->l, FARM_BUSY_RETRY_MS + jitter, on_retry, f);
}

/* Is a store error one that a later try may not have (busy, unreachable), not a verdict? */
static bool
passing(int rc)
{
    return rc != SF_ENOTFOUND && rc != SF_EINVAL;
}

/* Hand task t (a queued job's, its PREPARE committed) to a prepare worker; one it cannot
   take goes back to the queue (DEFER). */
static void
submit(struct farm *f, struct prep *t)
{
    struct sf_err err;
    if (!pool_submit(f->pool, prep_work, prep_done, t, &err)) {
        f->preparing--;
        struct job_event_args a = { .reason = err.msg, .fence = t->fence };
        farm_prep_end(f, t->req.job_id, JOB_EV_DEFER, &a);
        free(t);
    }
}

/*
 * Task t's PREPARE came back from the store thread: the job is preparing
 * (a worker takes it), or the store refused (the job left the queue
 * meanwhile: cancelled, moved) or stayed unreachable through the queue's
 * retries (the job stays queued; the farm tries again later).
 */
static void
on_prepare(void *ud, const struct storeq_result *r)
{
    struct prep *t = ud;
    struct farm *f = t->f;
    for (struct prep **pp = &f->posted; *pp; pp = &(*pp)->next)
        if (*pp == t) {
            *pp = t->next;
            break;
        }
    t->next = NULL;
    if (r->rc == SF_OK && f->pool) {
        submit(f, t);
        return;
    }
    f->preparing--;
    if (r->rc && passing(r->rc)) {
        log_warn("farm", "job %lld stays queued: %s", (long long)r->id, r->err->msg);
        retry_later(f);
    } else if (r->rc) {
        log_info("farm", "job %lld is not prepared: %s", (long long)r->id, r->err->msg);
    }
    free(t);
    farm_kick(f);
}

/*
 * Start preparing job j for printer p.  A queued job goes to preparing; a
 * ready one (reslice) stays ready with the G-code it has until the new one
 * is stored.  The part as optimized for this angle is reused when the job
 * has one: only the slicing is repeated.  A queued job's PREPARE goes
 * through the store's queue and the worker gets the task once it committed
 * (on_prepare): the loop does not wait for the store.  False when the
 * store failed in passing (the job stays queued and is tried again later;
 * the pass stops there).
 */
static bool
prepare(struct farm *f, const struct job_row *j, const struct farmcfg_printer *c, bool reslice,
        int64_t fence, bool hand_over)
{
    struct sf_err err;
    struct prep *t = NULL;
    /* cooling: its files could not be had a moment ago; no memory: the next kick */
    if (farm_cooling(f, j->id) || !(t = mem_calloc(1, sizeof(*t)))) {
        if (fence && !reslice) { /* claimed for it (several hosts): back to the queue */
            struct job_event_args d = { .reason = "not prepared now: tried again shortly",
                                        .fence = fence };
            farm_prep_end(f, j->id, JOB_EV_DEFER, &d);
        }
        retry_later(f);
        return true;
    }
    struct sched_printer view;
    farm_cfg_view(c, &view);
    t->f = f;
    t->store = f->s;
    t->reslice = reslice;
    t->fence = fence; /* a reslice's: its take's (one of several hosts) */
    t->hand_over = hand_over;
    t->angle_deg = j->opts.overhang_deg > 0 ? j->opts.overhang_deg : c->overhang_deg;
    sched_key(&view, j->opts.overhang_deg, t->key);
    t->req.job_id = j->id;
    t->req.opts = j->opts;
    t->req.printer = *c;
    snprintf(t->req.profiles_dir, sizeof(t->req.profiles_dir), "%s", f->profiles_dir);
    t->req.gram_s = f->gram_s;
    t->req.material_first = f->material_first;
    snprintf(t->req.part_name, sizeof(t->req.part_name), "%s", j->opts.name);
    bool reuse = j->mesh_sha[0] && j->mesh_angle_deg == t->angle_deg;
    /* the files' paths: on the worker (farm_prep_files), which may fetch them from the database */
    snprintf(t->part_sha, sizeof(t->part_sha), "%s", j->file_sha);
    if (reuse)
        snprintf(t->reuse_sha, sizeof(t->reuse_sha), "%s", j->mesh_sha);
    if (reslice) { /* the job stays ready: nothing to write before the worker has it */
        if (!pool_submit(f->pool, prep_work, prep_done, t, &err)) {
            free(t);
            return true;
        }
        log_info("farm", "job %lld: preparing it again for %s (%s)%s", (long long)j->id, c->name,
                 t->key, reuse ? ", reusing the optimized part" : "");
        t->next = f->reslices;
        f->reslices = t;
        f->preparing++;
        return true;
    }
    if (farm_host_on(f)) {
        /* One of several hosts: the job is claimed (its PREPARE, one statement that no two
           hosts both win) under fence already, on the store thread (farm_ask_claim). */
        f->preparing++;
        submit(f, t);
        return true;
    }
    f->preparing++; /* counted from now: the pool's places include PREPAREs on their way */
    if (storeq_job_event(f->q, j->id, JOB_EV_PREPARE, NULL, NULL, on_prepare, t)) {
        f->preparing--;
        free(t);
        return true; /* out of memory: the next kick tries again */
    }
    t->next = f->posted;
    f->posted = t;
    return true;
}

bool
farm_prepare(struct farm *f, const struct job_row *j, const struct farmcfg_printer *c, bool reslice,
             int64_t fence, bool hand_over)
{
    return prepare(f, j, c, reslice, fence, hand_over);
}

/* ---- scheduling ---- */

static void
sched_view(const struct job_row *j, struct sched_job *out)
{
    *out = (struct sched_job){ .id = j->id,
                               .state = j->state,
                               .priority = j->opts.priority,
                               .order = j->queue_pos,
                               .material = j->opts.material,
                               .printer = j->opts.printer,
                               .group = j->opts.group,
                               .key = j->prep_key,
                               .overhang_deg = j->opts.overhang_deg };
    memcpy(out->size_mm, j->size_mm, sizeof(out->size_mm));
}

static int
cmp_id(const void *a, const void *b)
{
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

/*
 * A job a printer took reads ready in the store until its START, queued
 * (printer_start), commits, or, before that, while its G-code is looked up
 * (farm_start): mark it printing in jobs so no pass starts it again
 * elsewhere meanwhile.  SF_ENOMEM.
 */
static int
mark_taken(const struct farm *f, struct job_row *jobs, size_t n)
{
    int64_t *held = mem_array(f->n_printers ? f->n_printers : 1, sizeof(*held));
    if (!held)
        return SF_ENOMEM;
    size_t n_held = 0;
    for (size_t i = 0; i < f->n_printers; i++)
        if (printer_job(f->printers[i]))
            held[n_held++] = printer_job(f->printers[i]);
    qsort(held, n_held, sizeof(*held), cmp_id);
    for (size_t i = 0; n_held && i < n; i++)
        if (jobs[i].state == JOB_READY && bsearch(&jobs[i].id, held, n_held, sizeof(*held), cmp_id))
            jobs[i].state = JOB_PRINTING;
    for (size_t i = 0; f->looking && i < n; i++) /* its start's G-code is being looked up */
        if (jobs[i].state == JOB_READY && farm_start_looking(f, jobs[i].id, NULL))
            jobs[i].state = JOB_PRINTING;
    free(held);
    return SF_OK;
}

/* A job whose PREPARE is on its way to the store reads queued until it commits: mark it
   preparing so no pass prepares it twice. */
static void
mark_posted(const struct farm *f, struct job_row *jobs, size_t n)
{
    for (const struct prep *t = f->posted; t; t = t->next)
        for (size_t i = 0; i < n; i++)
            if (jobs[i].id == t->req.job_id && jobs[i].state == JOB_QUEUED)
                jobs[i].state = JOB_PREPARING;
}

/* The live jobs, read on the store's thread for a scheduling pass (on_live). */
struct live {
    struct farm *f;
    struct job_row *jobs;
    size_t n;
    char host[STORE_HOST_NAME_MAX]; /* one of several hosts: its name (farm_host_reader) */
};

static int
live_read(struct store *s, void *ud, struct sf_err *err)
{
    struct live *lv = ud;
    free(lv->jobs); /* a retry's */
    lv->jobs = NULL;
    lv->n = 0;
    return lv->host[0] ? store_job_live_host(s, lv->host, &lv->jobs, &lv->n, err)
                       : store_job_live(s, &lv->jobs, &lv->n, err);
}

static void schedule(struct farm *f, struct job_row *jobs, size_t n);

static void
on_live(void *ud, const struct storeq_result *r)
{
    struct live *lv = ud;
    struct farm *f = lv->f;
    f->reading = false;
    if (r->rc) {
        log_error("farm", "%s", r->err->msg);
        retry_later(f);
    }
    if (r->rc == SF_OK && f->pool) /* not shutting down */
        schedule(f, lv->jobs, lv->n);
    else
        free(lv->jobs);
    free(lv);
    if (f->reread) { /* kicked while it read: what changed may not be in what it read */
        f->reread = false;
        farm_kick(f);
    }
}

/*
 * A scheduling pass: the live jobs (the scheduler never reads history,
 * store.h) are read on the store's thread, after the writes queued before
 * (the loop does not wait for the store; on PostgreSQL a read is a round
 * trip), then planned on the loop (schedule).  One read at a time: a kick
 * meanwhile runs another pass after it.
 */
static void
run(struct loop *l, void *ud)
{
    (void)l;
    struct farm *f = ud;
    f->kick = 0;
    /* a printer dropped while it printed or held its heat goes once it is done (a change
       of it kicked this run) */
    farm_sweep(f);
    if (f->reading) {
        f->reread = true;
        return;
    }
    struct live *lv = mem_calloc(1, sizeof(*lv));
    if (!lv)
        return; /* the next kick tries again */
    lv->f = f;
    if (!farm_host_reader(f, lv->host, sizeof(lv->host))) {
        free(lv); /* one of several hosts, not joined now: nothing of the queue is its own */
        return;
    }
    if (storeq_read(f->q, live_read, lv, on_live, lv)) {
        free(lv);
        return;
    }
    f->reading = true;
}

/*
 * Say why job j waits, once: the scheduler runs at every change, and a
 * write per waiting job per pass (a statement each through the store
 * thread, even unchanged) was most of what 10,000 queued jobs cost a host.
 * A long reason the row cut ("...") is written again; rare.  On a shared
 * store with other live hosts a queued job's reason is this host's only for
 * a printer of its own (another host's printer may take any other job).
 */
static void
post_reason(struct farm *f, const struct job_row *j, const char *why)
{
    if (strcmp(j->reason, why) == 0)
        return;
    if (!farm_host_alone(f) && j->state == JOB_QUEUED &&
        !(j->opts.printer[0] && farm_find(f, j->opts.printer)))
        return;
    storeq_job_set_reason(f->q, j->id, why);
}

/* Plan and act on jobs (n, the live ones as read; freed here). */
static void
schedule(struct farm *f, struct job_row *jobs, size_t n)
{
    struct sched_job *sj = mem_array(n ? n : 1, sizeof(*sj));
    struct sched_printer *sp = mem_array(f->n_printers ? f->n_printers : 1, sizeof(*sp));
    char(*why)[SCHED_REASON_MAX] = mem_array(n ? n : 1, sizeof(*why));
    struct sched_assign *out = mem_array(n ? n : 1, sizeof(*out));
    if (!sj || !sp || !why || !out || mark_taken(f, jobs, n))
        goto out; /* the next kick tries again */
    mark_posted(f, jobs, n);
    for (size_t i = 0; i < f->n_printers; i++) {
        const struct printer *p = f->printers[i];
        farm_printer_view(p, &sp[i]);
        if (!farm_host_owns(f, sp[i].name)) /* another live host's: its jobs are that host's */
            sp[i].enabled = false;
        if (sp[i].state == PRINTER_IDLE && farm_start_looking(f, 0, sp[i].name))
            sp[i].state = PRINTER_PRINTING; /* a start's G-code is being looked up for it */
        /* An interrupted part is still on this bed, waiting to be resumed:
           nothing else may start on top of it. */
        for (size_t k = 0; k < n; k++)
            if (jobs[k].state == JOB_INTERRUPTED && strcmp(jobs[k].printer, sp[i].name) == 0 &&
                sp[i].state == PRINTER_IDLE)
                sp[i].state = PRINTER_AWAITING_CLEAR;
    }
    farm_ask_mark(f, jobs, n, sp); /* claims and takes on their way */
    bool pool_full = f->preparing >= pool_size(f->pool);
    for (size_t i = 0; i < n; i++) {
        sched_view(&jobs[i], &sj[i]);
        /* a job being prepared is not stalled: it is what fills the pool */
        if (jobs[i].state == JOB_QUEUED)
            sj[i].stalled = pool_full;
        else if (jobs[i].state == JOB_READY)
            sj[i].stalled =
                pool_full || reslicing(f, jobs[i].id) || reslice_failed_any(f, jobs[i].id);
    }
    size_t n_out = sched_plan(sj, n, sp, f->n_printers, out, why);
    for (size_t k = 0; k < n_out; k++) {
        const struct job_row *j = &jobs[out[k].job];
        struct printer *p = f->printers[out[k].printer];
        if (!out[k].reslice) {
            /* another host's printer may have taken it; p writes for it with the take's
               fencing token (farm_ask.c: the take on the store thread, the start once it
               is back; one the database did not answer is tried again) */
            farm_ask_take(f, j, p, false);
            continue;
        }
        /* Waiting for a busy printer of its key while p idles: slice it for p. */
        char key[SCHED_KEY_MAX];
        sched_key(&sp[out[k].printer], j->opts.overhang_deg, key);
        if (reslicing(f, j->id) || reslice_failed(f, j->id, key) ||
            f->preparing >= pool_size(f->pool))
            continue;
        farm_ask_take(f, j, p, true);
    }
    /* Prepare queued jobs for a printer that could take them, an idle one first. */
    for (size_t i = 0; i < n; i++) {
        if (jobs[i].state != JOB_QUEUED)
            continue;
        if (why[i][0] || f->preparing >= pool_size(f->pool)) {
            post_reason(f, &jobs[i], why[i]);
            if (why[i][0] && f->preparing < pool_size(f->pool)) /* spare cores: another host's */
                farm_spare_claim(f, sj, n, i, &jobs[i]);
            continue;
        }
        size_t best = sched_prepare_for(sj, n, i, sp, f->n_printers);
        if (best < f->n_printers && farm_host_on(f) && farm_cooling(f, jobs[i].id))
            retry_later(f); /* not claimed while its files cool (prepare would decline) */
        else if (best < f->n_printers && farm_host_on(f)) /* claimed first, on the store thread */
            farm_ask_claim(f, jobs, sj, n, i, sp, best, why);
        else if (best < f->n_printers &&
                 !prepare(f, &jobs[i], printer_cfg(f->printers[best]), false, 0, false))
            break; /* the store is busy: its commit wakes the farm for the rest */
    }
    for (size_t i = 0; i < n; i++)
        if (jobs[i].state == JOB_READY && why[i][0])
            post_reason(f, &jobs[i], why[i]);
out:
    free(sj);
    free(sp);
    free(why);
    free(out);
    free(jobs);
}

static void
on_progress(struct loop *l, void *ud)
{
    struct farm *f = ud;
    /* One transaction for every printer, not one per printer (50 printers stalled the loop
       ~0.2 s every tick, bench_farm50), on the store thread: the loop goes on meanwhile.  A
       job that stopped printing meanwhile is skipped there; marking it saved here is
       harmless, it has no more progress to save. */
    struct store_progress *batch = f->n_printers ? mem_array(f->n_printers, sizeof(*batch)) : NULL;
    size_t n = 0;
    for (size_t i = 0; batch && i < f->n_printers; i++) {
        int64_t id, lines;
        if (printer_progress(f->printers[i], &id, &lines))
            batch[n++] =
                (struct store_progress){ id, lines, false, printer_fence(f->printers[i], id) };
    }
    if (n && storeq_jobs_progress(f->q, batch, n) == SF_OK) {
        for (size_t i = 0; i < f->n_printers; i++) {
            int64_t id, lines;
            if (printer_progress(f->printers[i], &id, &lines))
                printer_progress_saved(f->printers[i], lines);
        }
    }
    free(batch);
    f->progress = loop_timer_add(l, f->hooks.progress_ms, on_progress, f);
}

/* ---- lifecycle ---- */

int
farm_add_printer(struct farm *f, const struct farmcfg_printer *cfg, struct sf_err *err)
{
    size_t cap = f->n_printers;
    if (!mem_grow((void **)&f->printers, &cap, f->n_printers + 1, sizeof(*f->printers)))
        return sf_err_set(err, SF_ENOMEM, "farm: out of memory");
    struct printer *p = farm_printer_new(f, cfg, NULL);
    if (!p)
        return sf_err_set(err, SF_ENOMEM, "farm: out of memory");
    f->printers[f->n_printers++] = p;
    return SF_OK;
}

struct farm *
farm_new(struct loop *l, struct store *s, struct pool *pool, const struct farmcfg *cfg,
         const struct farm_hooks *hooks, struct sf_err *err)
{
    struct farm *f = mem_calloc(1, sizeof(*f));
    if (!f) {
        sf_err_set(err, SF_ENOMEM, "farm: out of memory");
        return NULL;
    }
    *f = (struct farm){ .l = l, .s = s, .pool = pool, .hooks = *hooks };
    snprintf(f->profiles_dir, sizeof(f->profiles_dir), "%s", cfg->profiles_dir);
    f->gram_s = cfg->gram_s;
    f->material_first = cfg->material_first;
    if (!(f->io = pool_new(l, 1, err)) || !(f->files = pool_new(l, 1, err)) ||
        !(f->q = storeq_new(l, s, err))) {
        farm_free(f);
        return NULL;
    }
    storeq_set_commit(f->q, on_store_commit, f);
    struct farmcfg_printer *list = NULL;
    size_t n = 0;
    int rc = farm_seed(f, cfg->printers, cfg->n_printers, err);
    if (rc == SF_OK)
        rc = farm_merged(f, &list, &n, err);
    for (size_t i = 0; rc == SF_OK && i < n; i++)
        rc = farm_add_printer(f, &list[i], err);
    free(list);
    if (rc) {
        farm_free(f);
        return NULL;
    }
    if (farm_host_start(f, cfg, err)) {
        farm_free(f);
        return NULL;
    }
    if (f->hooks.progress_ms <= 0)
        f->hooks.progress_ms = FARM_PROGRESS_MS;
    f->progress = loop_timer_add(l, f->hooks.progress_ms, on_progress, f);
    farm_kick(f);
    return f;
}

void
farm_free(struct farm *f)
{
    if (!f)
        return;
    if (f->files) { /* first: a lookup's answer may still hand its start to io */
        pool_free(f->files);
        f->files = NULL;        /* farm_start starts nothing from here */
        loop_run_once(f->l, 0); /* deliver a start's lookup cut short */
    }
    if (f->io) {
        pool_free(f->io);
        loop_run_once(f->l, 0); /* deliver a resume read cut short (pool.h) */
    }
    if (f->kick)
        loop_timer_cancel(f->l, f->kick);
    if (f->retry)
        loop_timer_cancel(f->l, f->retry);
    if (f->progress)
        loop_timer_cancel(f->l, f->progress);
    /* A stop leaves each print interrupted at its last acknowledged line,
       as a crash does (the operator resumes or restarts it): no retry spent,
       nothing requeued from line 0.  The drivers' goodbyes are not heard. */
    f->stopping = true;
    for (size_t i = 0; i < f->n_printers; i++)
        printer_stop(f->printers[i]);
    farm_remote_stop(f); /* its waiting asks answered; its requests in flight come back below */
    /* Nothing lost on a stop: what is queued (those CRASHED with it) is written now. */
    if (f->q) {
        storeq_set_commit(f->q, NULL, NULL);
        storeq_free(f->q);
    }
    farm_spare_free(f);
    farm_host_stop(f); /* leave, once the store holds what the stop wrote */
    for (size_t i = 0; i < f->n_printers; i++)
        printer_free(f->printers[i]);
    free(f->printers);
    free(f->seed);
    free(f->no);
    free(f->cool);
    free(f);
}
