/*
 * farm.c - printers, the prepare stage and the scheduler, tied together
 * on the event loop over the job store (see farm.h).
 *
 * Why one module: each piece below is pure or thin (job.h rules, sched.h
 * matching, store.h transactions, drv.h drivers, pool.h workers); what is
 * left is the glue that reacts to events, and glue reads best in one place.
 * Design: every reaction is "apply the rule, commit to the store, then act
 * on the device", so a crash between the two leaves the store ahead of the
 * printer, which recovery turns into "interrupted" for the operator, never
 * into a silently repeated print.  Work is triggered by a zero-delay timer
 * (farm_kick), so bursts of events coalesce into one scheduling pass.
 * Printers are heap-allocated so drivers can keep a stable pointer.
 *
 * Thread: the loop thread; prepare work runs on pool workers with copies,
 * resume reads on the farm's own io thread.
 */
#include "farm.h"

#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "../base/log.h"
#include "../base/mem.h"
#include "sched.h"

struct printer {
    struct farm *f;             /* owner */
    struct farmcfg_printer cfg; /* its config section */
    enum printer_state state;   /* job.h printer state */
    struct drv *drv;            /* its driver; NULL if none in this build */
    int64_t job_id;             /* job on it, 0 if none */
    int64_t lines_acked;        /* latest from the driver */
    int64_t lines_saved;        /* last value written to the store */
    char message[160];          /* why offline / error */
    uint64_t reconnect;         /* reconnect timer id, 0 if none */
    int64_t backoff_ms;         /* next reconnect delay */
    bool removed;               /* dropped from the config; freed when idle */
    bool cancelling;            /* job cancelled; the driver is still running its end
                                   sequence, so the printer is not free yet */
};

struct farm {
    struct loop *l;            /* the loop */
    struct store *s;           /* the job store */
    struct pool *pool;         /* prepare workers */
    struct pool *io;           /* one thread for resume reads: not queued behind slicing */
    struct farm_hooks hooks;   /* drivers, prepare, notify */
    char profiles_dir[512];    /* slicing profiles (farmcfg profiles_dir) */
    struct printer **printers; /* n_printers, config order */
    size_t n_printers;
    uint64_t kick;     /* pending run() timer, 0 if none */
    uint64_t progress; /* progress timer */
    int preparing;     /* prepare tasks in flight */
    int64_t *deferred; /* jobs whose prepare hit a missing stage: not retried */
    size_t n_deferred; /* until reload or restart */
    size_t cap_deferred;
};

/* A prepare task: plain data copied for the worker. */
struct prep {
    struct farm *f;                /* owner (used only on the loop thread) */
    struct prepare_req req;        /* input */
    struct prepare_out out;        /* output */
    struct drv_job_scan scan;      /* the G-code's scan, made on the worker too */
    const struct store *store;     /* for store_file_adopt on the worker */
    char gcode_sha[STORE_SHA_HEX]; /* the G-code, adopted into the store by the worker */
    int64_t gcode_size;
    struct sf_err err; /* why it failed */
};

static void run(struct loop *l, void *ud);

static void
notify(struct farm *f)
{
    if (f->hooks.notify)
        f->hooks.notify(f->hooks.notify_ud);
}

void
farm_kick(struct farm *f)
{
    if (!f->kick)
        f->kick = loop_timer_add(f->l, 0, run, f);
}

static struct printer *
find(const struct farm *f, const char *name)
{
    for (size_t i = 0; i < f->n_printers; i++)
        if (strcmp(f->printers[i]->cfg.name, name) == 0)
            return f->printers[i];
    return NULL;
}

/* Move printer p by ev; log refusals (they mean a driver said something odd). */
static bool
move(struct printer *p, enum printer_event ev)
{
    struct sf_err err;
    enum printer_state to;
    if (printer_next(p->state, ev, p->cfg.auto_eject, &to, &err)) {
        log_printer(LOG_WARN, p->cfg.name, "%s", err.msg);
        return false;
    }
    if (to != p->state) {
        p->state = to;
        if (store_printer_set(p->f->s, p->cfg.name, to, &err))
            log_printer(LOG_ERROR, p->cfg.name, "%s", err.msg);
        notify(p->f);
    }
    return true;
}

/* Apply a job event in the store, logging failures (the job fails alone). */
static int
job_event(struct farm *f, int64_t id, enum job_event ev, const struct job_event_args *a)
{
    struct sf_err err;
    int rc = store_job_event(f->s, id, ev, a, NULL, &err);
    if (rc)
        log_warn("farm", "%s", err.msg);
    notify(f);
    return rc;
}

/* ---- drivers ---- */

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
    p->reconnect = loop_timer_add(p->f->l, p->backoff_ms, on_reconnect, p);
    p->backoff_ms =
        p->backoff_ms * 2 > FARM_BACKOFF_MAX_MS ? FARM_BACKOFF_MAX_MS : p->backoff_ms * 2;
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

/* The job on p ended badly (drop, fault): fail it, keep the retry policy. */
static void
fail_job(struct printer *p, const char *why)
{
    if (!p->job_id)
        return;
    struct job_event_args a = { .lines_acked = p->lines_acked, .reason = why };
    job_event(p->f, p->job_id, JOB_EV_PRINT_FAILED, &a);
    p->job_id = 0;
}

static void
on_drv_event(struct drv *d, enum drv_event ev, void *ud)
{
    struct printer *p = ud;
    struct farm *f = p->f;
    const struct drv_status *st = &d->status;
    switch (ev) {
    case DRV_EV_STATE:
        if (st->state == DRV_IDLE && p->state == PRINTER_OFFLINE) {
            p->backoff_ms = FARM_BACKOFF_MIN_MS;
            p->message[0] = '\0';
            move(p, PRINTER_EV_CONNECTED);
        } else if (st->state == DRV_OFFLINE && p->state != PRINTER_OFFLINE) {
            p->cancelling = false;
            fail_job(p, "printer went offline");
            snprintf(p->message, sizeof(p->message), "%s", st->message);
            move(p, PRINTER_EV_DISCONNECTED);
            schedule_reconnect(p);
        } else if (st->state == DRV_ERROR && p->state != PRINTER_ERROR) {
            fail_job(p, st->message[0] ? st->message : "printer reported an error");
            snprintf(p->message, sizeof(p->message), "%s", st->message);
            move(p, PRINTER_EV_FAULT);
        } else if (st->state == DRV_PAUSED && p->state == PRINTER_PRINTING) {
            /* paused by the printer itself (filament runout, M600) */
            struct job_event_args a = { .lines_acked = p->lines_acked };
            job_event(f, p->job_id, JOB_EV_PAUSE, &a);
            move(p, PRINTER_EV_PAUSE);
        } else if (st->state == DRV_PRINTING && p->state == PRINTER_PAUSED) {
            job_event(f, p->job_id, JOB_EV_RESUME, NULL);
            move(p, PRINTER_EV_RESUME);
        }
        break;
    case DRV_EV_PROGRESS:
        p->lines_acked = (int64_t)st->lines_acked;
        break;
    case DRV_EV_TEMPS:
        break; /* read from d->status when asked */
    case DRV_EV_JOB_DONE: {
        struct job_event_args a = { .lines_acked = (int64_t)st->lines_acked };
        if (p->job_id)
            job_event(f, p->job_id, JOB_EV_PRINT_DONE, &a);
        p->job_id = 0;
        move(p, PRINTER_EV_FINISHED);
        break;
    }
    case DRV_EV_JOB_CANCELLED:
        /* The farm recorded the cancel when it asked; the printer is free
           only now that the end sequence has run. */
        if (p->cancelling) {
            p->cancelling = false;
            move(p, PRINTER_EV_FINISHED);
        }
        break;
    case DRV_EV_JOB_FAILED:
        p->cancelling = false;
        p->lines_acked = (int64_t)st->lines_acked;
        fail_job(p, st->message[0] ? st->message : "the print stopped");
        move(p, st->state == DRV_ERROR ? PRINTER_EV_FAULT : PRINTER_EV_FINISHED);
        break;
    }
    farm_kick(f);
}

static void
printer_free(struct printer *p)
{
    if (!p)
        return;
    if (p->reconnect)
        loop_timer_cancel(p->f->l, p->reconnect);
    if (p->drv) {
        /* drv_free() lives with the drivers; the vtable is all we rely on. */
        p->drv->ops->close(p->drv);
        p->drv->ops->destroy(p->drv);
    }
    free(p);
}

static struct printer *
printer_new(struct farm *f, const struct farmcfg_printer *cfg)
{
    struct printer *p = mem_calloc(1, sizeof(*p));
    if (!p)
        return NULL;
    p->f = f;
    p->cfg = *cfg;
    p->state = PRINTER_OFFLINE;
    p->backoff_ms = FARM_BACKOFF_MIN_MS;
    struct sf_err err;
    if (store_printer_set(f->s, cfg->name, PRINTER_OFFLINE, &err))
        log_printer(LOG_ERROR, cfg->name, "%s", err.msg);
    if (!cfg->enabled) {
        snprintf(p->message, sizeof(p->message), "disabled in the config");
        return p;
    }
    if (!f->hooks.driver) {
        snprintf(p->message, sizeof(p->message),
                 "no '%s' driver in this build (drivers/ not merged yet)", cfg->driver);
        log_printer(LOG_WARN, cfg->name, "%s", p->message);
        return p;
    }
    struct drv_config dc = { .name = cfg->name,
                             .kind = cfg->driver,
                             .port = cfg->port,
                             .baud = cfg->baud,
                             .buffer_lines = cfg->buffer_lines,
                             .rx_buffer = cfg->rx_buffer,
                             .url = cfg->url,
                             .api_key = cfg->api_key };
    p->drv = f->hooks.driver(f->l, &dc, on_drv_event, p, &err);
    if (!p->drv) {
        snprintf(p->message, sizeof(p->message), "%s", err.msg);
        log_printer(LOG_ERROR, cfg->name, "%s", err.msg);
        return p;
    }
    connect_printer(p);
    return p;
}

/* ---- prepare ---- */

static int
prep_work(void *ud, const atomic_bool *cancel)
{
    struct prep *t = ud;
    int rc = t->f->hooks.prepare(&t->req, &t->out, cancel, &t->err);
    /* Count and check the G-code here, off the loop: a bad line fails the
       job now, not half-way through a print, and start_job need not read
       the file on the loop thread (a 150 MB job stalled every printer's
       stream ~2.5 s).  Hashing it into the store is the other long read. */
    if (rc == SF_OK &&
        ((rc = drv_job_scan(t->req.out_path, &t->scan, &t->err)) ||
         (rc = store_file_adopt(t->store, t->req.out_path, t->gcode_sha, &t->gcode_size, &t->err))))
        sf_err_prefix(&t->err, "job %lld", (long long)t->req.job_id);
    return rc;
}

static void
prep_done(struct loop *l, void *ud, int rc)
{
    (void)l;
    struct prep *t = ud;
    struct farm *f = t->f;
    int64_t id = t->req.job_id;
    f->preparing--;
    if (rc == SF_OK) {
        struct sf_err err;
        if (store_file_record(f->s, t->gcode_sha, t->gcode_size, &err) == SF_OK) {
            struct job_event_args a = { .gcode_sha = t->gcode_sha,
                                        .nozzle_mm = t->out.nozzle_mm,
                                        .gcode_lines = (int64_t)t->scan.lines_total };
            memcpy(a.size_mm, t->out.size_mm, sizeof(a.size_mm));
            job_event(f, id, JOB_EV_PREPARED, &a);
        } else {
            struct job_event_args a = { .reason = err.msg };
            job_event(f, id, JOB_EV_PREPARE_FAILED, &a);
        }
    } else if (rc == SF_EUNSUPP) {
        /* A missing stage is the build's fault, not the job's: keep it. */
        struct job_event_args a = { .reason = t->err.msg };
        job_event(f, id, JOB_EV_DEFER, &a);
        if (f->n_deferred == 0)
            log_warn("farm", "%s; such jobs stay queued", t->err.msg);
        if (mem_grow((void **)&f->deferred, &f->cap_deferred, f->n_deferred + 1,
                     sizeof(*f->deferred)))
            f->deferred[f->n_deferred++] = id;
    } else if (rc != SF_ECANCELED) {
        struct job_event_args a = { .reason = t->err.msg[0] ? t->err.msg : sf_status_name(rc) };
        job_event(f, id, JOB_EV_PREPARE_FAILED, &a);
    }
    unlink(t->req.out_path); /* gone when adopted */
    free(t);
    farm_kick(f);
}

/* Start preparing job j for printer p. */
static void
prepare(struct farm *f, const struct job_row *j, const struct printer *p)
{
    struct sf_err err;
    struct prep *t = mem_calloc(1, sizeof(*t));
    if (!t)
        return; /* retried on the next kick */
    t->f = f;
    t->store = f->s;
    t->req.job_id = j->id;
    t->req.opts = j->opts;
    t->req.printer = p->cfg;
    snprintf(t->req.profiles_dir, sizeof(t->req.profiles_dir), "%s", f->profiles_dir);
    snprintf(t->req.part_name, sizeof(t->req.part_name), "%s", j->opts.name);
    if (store_file_path(f->s, j->file_sha, t->req.part_path, sizeof(t->req.part_path), &err) ||
        store_file_path(f->s, j->file_sha, t->req.out_path, sizeof(t->req.out_path) - 16, &err)) {
        struct job_event_args a = { .reason = err.msg };
        job_event(f, j->id, JOB_EV_PREPARE, NULL);
        job_event(f, j->id, JOB_EV_PREPARE_FAILED, &a);
        free(t);
        return;
    }
    /* out: beside the stored files, named for the job */
    char *slash = strrchr(t->req.out_path, '/');
    snprintf(slash + 1, 32, "job-%lld.gcode", (long long)j->id);
    if (job_event(f, j->id, JOB_EV_PREPARE, NULL)) {
        free(t);
        return;
    }
    if (!pool_submit(f->pool, prep_work, prep_done, t, &err)) {
        struct job_event_args a = { .reason = err.msg };
        job_event(f, j->id, JOB_EV_DEFER, &a);
        free(t);
        return;
    }
    f->preparing++;
}

/* ---- scheduling ---- */

static void
sched_view(const struct job_row *j, struct sched_job *out)
{
    *out = (struct sched_job){ .id = j->id,
                               .state = j->state,
                               .priority = j->opts.priority,
                               .material = j->opts.material,
                               .printer = j->opts.printer,
                               .group = j->opts.group,
                               .nozzle_mm = j->nozzle_mm };
    memcpy(out->size_mm, j->size_mm, sizeof(out->size_mm));
}

static void
start(struct farm *f, const struct job_row *j, struct printer *p)
{
    struct sf_err err;
    char path[1200];
    struct job_event_args a = { .printer = p->cfg.name };
    if (store_file_path(f->s, j->gcode_sha, path, sizeof(path), &err)) {
        log_warn("farm", "job %lld: %s", (long long)j->id, err.msg);
        return;
    }
    /* Commit first: a crash from here on leaves the job interrupted. */
    if (job_event(f, j->id, JOB_EV_START, &a))
        return;
    p->job_id = j->id;
    p->lines_acked = p->lines_saved = 0;
    move(p, PRINTER_EV_START);
    /* The scan prepare made; G-code prepared before the count was stored
       (gcode_lines 0) is read by the driver itself, once. */
    struct drv_job_scan scan = { .lines_total = (uint64_t)j->gcode_lines };
    if (p->drv->ops->start_job(p->drv, path, 0, j->gcode_lines > 0 ? &scan : NULL, &err)) {
        log_printer(LOG_WARN, p->cfg.name, "job %lld: %s", (long long)j->id, err.msg);
        fail_job(p, err.msg);
        move(p, PRINTER_EV_FINISHED);
    }
}

static bool
deferred(const struct farm *f, int64_t id)
{
    for (size_t i = 0; i < f->n_deferred; i++)
        if (f->deferred[i] == id)
            return true;
    return false;
}

static void
run(struct loop *l, void *ud)
{
    (void)l;
    struct farm *f = ud;
    f->kick = 0;
    struct sf_err err;
    struct job_row *jobs;
    size_t n;
    if (store_job_list(f->s, &jobs, &n, &err)) {
        log_error("farm", "%s", err.msg);
        return;
    }
    struct sched_job *sj = mem_array(n ? n : 1, sizeof(*sj));
    struct sched_printer *sp = mem_array(f->n_printers ? f->n_printers : 1, sizeof(*sp));
    char(*why)[SCHED_REASON_MAX] = mem_array(n ? n : 1, sizeof(*why));
    struct sched_assign *out = mem_array(n ? n : 1, sizeof(*out));
    if (!sj || !sp || !why || !out)
        goto out; /* the next kick tries again */
    for (size_t i = 0; i < f->n_printers; i++) {
        const struct printer *p = f->printers[i];
        sp[i] = (struct sched_printer){ .name = p->cfg.name,
                                        .state = p->state,
                                        .enabled = p->cfg.enabled && !p->removed,
                                        .material = p->cfg.material,
                                        .nozzle_mm = p->cfg.nozzle_mm,
                                        .group = p->cfg.group };
        memcpy(sp[i].bed_mm, p->cfg.bed_mm, sizeof(sp[i].bed_mm));
        /* An interrupted part is still on this bed, waiting to be resumed:
           nothing else may start on top of it. */
        for (size_t k = 0; k < n; k++)
            if (jobs[k].state == JOB_INTERRUPTED && strcmp(jobs[k].printer, p->cfg.name) == 0 &&
                sp[i].state == PRINTER_IDLE)
                sp[i].state = PRINTER_AWAITING_CLEAR;
    }
    for (size_t i = 0; i < n; i++)
        sched_view(&jobs[i], &sj[i]);
    size_t n_out = sched_plan(sj, n, sp, f->n_printers, out, why);
    for (size_t k = 0; k < n_out; k++)
        start(f, &jobs[out[k].job], f->printers[out[k].printer]);
    /* Prepare queued jobs for the first printer that could take them. */
    for (size_t i = 0; i < n; i++) {
        if (jobs[i].state != JOB_QUEUED)
            continue;
        const char *reason = why[i];
        if (!reason[0] && deferred(f, jobs[i].id))
            continue; /* keeps the reason its prepare gave */
        if (!reason[0] && f->preparing < pool_size(f->pool)) {
            for (size_t p = 0; p < f->n_printers; p++)
                if (sched_compatible(&sj[i], &sp[p], NULL, 0)) {
                    prepare(f, &jobs[i], f->printers[p]);
                    break;
                }
            continue;
        }
        store_job_set_reason(f->s, jobs[i].id, reason, NULL);
    }
    for (size_t i = 0; i < n; i++)
        if (jobs[i].state == JOB_READY && why[i][0])
            store_job_set_reason(f->s, jobs[i].id, why[i], NULL);
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
    /* One transaction for every printer: one fsync a tick on the loop thread, not one per
       printer (50 printers stalled the loop ~0.2 s every tick, bench_farm50). */
    struct store_progress *batch = f->n_printers ? mem_array(f->n_printers, sizeof(*batch)) : NULL;
    size_t n = 0;
    for (size_t i = 0; batch && i < f->n_printers; i++) {
        struct printer *p = f->printers[i];
        if (p->job_id && p->lines_acked != p->lines_saved)
            batch[n++] = (struct store_progress){ p->job_id, p->lines_acked, false };
    }
    if (n && store_jobs_progress(f->s, batch, n, NULL) > 0) {
        for (size_t i = 0, k = 0; i < f->n_printers && k < n; i++) {
            struct printer *p = f->printers[i];
            if (p->job_id && p->lines_acked != p->lines_saved && batch[k++].saved)
                p->lines_saved = p->lines_acked;
        }
    }
    free(batch);
    f->progress = loop_timer_add(l, f->hooks.progress_ms, on_progress, f);
}

/* ---- lifecycle ---- */

static int
add_printer(struct farm *f, const struct farmcfg_printer *cfg, struct sf_err *err)
{
    size_t cap = f->n_printers;
    if (!mem_grow((void **)&f->printers, &cap, f->n_printers + 1, sizeof(*f->printers)))
        return sf_err_set(err, SF_ENOMEM, "farm: out of memory");
    struct printer *p = printer_new(f, cfg);
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
    if (!(f->io = pool_new(l, 1, err))) {
        farm_free(f);
        return NULL;
    }
    for (size_t i = 0; i < cfg->n_printers; i++)
        if (add_printer(f, &cfg->printers[i], err)) {
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
    if (f->io) {
        pool_free(f->io);
        loop_run_once(f->l, 0); /* deliver a resume read cut short (pool.h) */
    }
    if (f->kick)
        loop_timer_cancel(f->l, f->kick);
    if (f->progress)
        loop_timer_cancel(f->l, f->progress);
    for (size_t i = 0; i < f->n_printers; i++)
        printer_free(f->printers[i]);
    free(f->printers);
    free(f->deferred);
    free(f);
}

static bool
same_link(const struct farmcfg_printer *a, const struct farmcfg_printer *b)
{
    return strcmp(a->driver, b->driver) == 0 && strcmp(a->port, b->port) == 0 &&
           a->baud == b->baud && strcmp(a->url, b->url) == 0 &&
           strcmp(a->api_key, b->api_key) == 0 && a->enabled == b->enabled;
}

int
farm_reload(struct farm *f, const struct farmcfg *cfg, struct sf_err *err)
{
    /* Printers that left the config: free when not printing, else after. */
    for (size_t i = 0; i < f->n_printers; i++) {
        struct printer *p = f->printers[i];
        p->removed = !farmcfg_printer(cfg, p->cfg.name);
    }
    for (size_t i = 0; i < cfg->n_printers; i++) {
        const struct farmcfg_printer *c = &cfg->printers[i];
        struct printer *p = find(f, c->name);
        if (!p) {
            if (add_printer(f, c, err))
                return err ? err->code : SF_ENOMEM;
            continue;
        }
        if (same_link(&p->cfg, c) || p->job_id) {
            /* Same link, or busy: change what the scheduler reads only. */
            if (!same_link(&p->cfg, c))
                log_printer(LOG_WARN, c->name, "link change waits for the print to end");
            struct farmcfg_printer keep = p->cfg;
            p->cfg = *c;
            if (!same_link(&keep, c)) {
                memcpy(p->cfg.driver, keep.driver, sizeof(keep.driver));
                memcpy(p->cfg.port, keep.port, sizeof(keep.port));
                memcpy(p->cfg.url, keep.url, sizeof(keep.url));
                memcpy(p->cfg.api_key, keep.api_key, sizeof(keep.api_key));
                p->cfg.baud = keep.baud;
                p->cfg.enabled = keep.enabled;
            }
            continue;
        }
        /* New link and idle: replace the printer. */
        struct printer *fresh = printer_new(f, c);
        if (!fresh)
            return sf_err_set(err, SF_ENOMEM, "farm: out of memory");
        for (size_t k = 0; k < f->n_printers; k++)
            if (f->printers[k] == p)
                f->printers[k] = fresh;
        printer_free(p);
    }
    size_t w = 0;
    for (size_t i = 0; i < f->n_printers; i++) {
        struct printer *p = f->printers[i];
        if (p->removed && !p->job_id) {
            printer_free(p);
            continue;
        }
        f->printers[w++] = p;
    }
    f->n_printers = w;
    f->n_deferred = 0; /* a reload may bring what was missing */
    snprintf(f->profiles_dir, sizeof(f->profiles_dir), "%s", cfg->profiles_dir);
    farm_kick(f);
    return SF_OK;
}

size_t
farm_printer_count(const struct farm *f)
{
    return f->n_printers;
}

void
farm_printer_info(const struct farm *f, size_t i, struct farm_printer_info *out)
{
    const struct printer *p = f->printers[i];
    memset(out, 0, sizeof(*out));
    out->cfg = &p->cfg;
    out->state = p->state;
    out->job_id = p->job_id;
    out->message = p->message;
    if (p->drv) {
        const struct drv_status *st = &p->drv->status;
        out->progress = st->progress;
        out->nozzle_c = st->nozzle_c;
        out->nozzle_target_c = st->nozzle_target_c;
        out->bed_c = st->bed_c;
        out->bed_target_c = st->bed_target_c;
    }
}

int
farm_printer_action(struct farm *f, const char *name, const char *action, struct sf_err *err)
{
    struct printer *p = find(f, name);
    if (!p)
        return sf_err_set(err, SF_ENOTFOUND, "no printer '%.64s'", name);
    enum printer_event ev;
    if (strcmp(action, "pause") == 0)
        ev = PRINTER_EV_PAUSE;
    else if (strcmp(action, "resume") == 0)
        ev = PRINTER_EV_RESUME;
    else if (strcmp(action, "cancel") == 0)
        ev = PRINTER_EV_FINISHED;
    else if (strcmp(action, "cleared") == 0)
        ev = PRINTER_EV_CLEARED;
    else
        return sf_err_set(err, SF_EUNSUPP, "no printer action '%.32s'", action);
    enum printer_state to;
    int rc = printer_next(p->state, ev, p->cfg.auto_eject, &to, err);
    if (rc)
        return sf_err_prefix(err, "printer %s", name);
    if (ev != PRINTER_EV_CLEARED && (!p->drv || !p->job_id))
        return sf_err_set(err, SF_EINVAL, "printer %s has no job to %s", name, action);
    if (ev == PRINTER_EV_PAUSE)
        rc = p->drv->ops->pause(p->drv, err);
    else if (ev == PRINTER_EV_RESUME)
        rc = p->drv->ops->resume(p->drv, err);
    else if (ev == PRINTER_EV_FINISHED)
        rc = p->drv->ops->cancel(p->drv, err);
    if (rc)
        return rc;
    /* A driver that reports its new state at once (Marlin's pause and
       resume do) has already moved the job and printer through
       on_drv_event: do not apply the move twice. */
    if (ev != PRINTER_EV_FINISHED && ev != PRINTER_EV_CLEARED && p->state == to) {
        farm_kick(f);
        return SF_OK;
    }
    if (p->job_id) {
        struct job_event_args a = { .lines_acked = p->lines_acked,
                                    .reason = "cancelled by an operator" };
        enum job_event jev = ev == PRINTER_EV_PAUSE    ? JOB_EV_PAUSE
                             : ev == PRINTER_EV_RESUME ? JOB_EV_RESUME
                                                       : JOB_EV_CANCEL;
        if ((rc = store_job_event(f->s, p->job_id, jev, &a, NULL, err)))
            return rc;
        if (jev == JOB_EV_CANCEL) {
            p->job_id = 0;
            if (p->drv->status.state == DRV_PRINTING) {
                /* still running the end sequence: free on DRV_EV_JOB_CANCELLED */
                p->cancelling = true;
                notify(f);
                return SF_OK;
            }
        }
    }
    move(p, ev);
    farm_kick(f);
    return SF_OK;
}

/* A resume waiting for its read (drv_job_scan_to) on the io thread. */
struct resume {
    struct farm *f;
    int64_t job_id;
    char printer[64];
    char path[1200];
    uint64_t line;
    struct drv_job_scan scan;
    struct sf_err err;
};

static int
resume_work(void *ud, const atomic_bool *cancel)
{
    (void)cancel;
    struct resume *r = ud;
    return drv_job_scan_to(r->path, r->line, &r->scan, &r->err);
}

/* Start the job on its printer, or fail it; the printer is already printing it in the store. */
static void
resume_start(struct printer *p, const char *path, uint64_t line, const struct drv_job_scan *scan)
{
    struct sf_err err;
    if (p->drv->ops->start_job(p->drv, path, line, scan, &err)) {
        log_printer(LOG_WARN, p->cfg.name, "job %lld: %s", (long long)p->job_id, err.msg);
        fail_job(p, err.msg);
        move(p, PRINTER_EV_FINISHED);
    }
}

static void
resume_done(struct loop *l, void *ud, int rc)
{
    (void)l;
    struct resume *r = ud;
    struct printer *p = rc == SF_ECANCELED ? NULL : find(r->f, r->printer);
    /* Meanwhile the job may have been cancelled or its printer lost (the
       job moved on with it); shutting down leaves it printing in the store,
       which the next start's recovery makes interrupted. */
    if (p && p->job_id == r->job_id) {
        if (rc == SF_OK &&
            (p->state != PRINTER_PRINTING || !p->drv || p->drv->status.state != DRV_IDLE))
            rc = sf_err_set(&r->err, SF_EAGAIN, "printer %s is %s: the resume cannot start",
                            p->cfg.name, printer_state_name(p->state));
        if (rc) {
            log_printer(LOG_WARN, p->cfg.name, "job %lld: %s", (long long)r->job_id, r->err.msg);
            fail_job(p, r->err.msg);
            move(p, PRINTER_EV_FINISHED);
        } else {
            resume_start(p, r->path, r->line, &r->scan);
        }
        farm_kick(r->f);
    }
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
    struct printer *p = find(f, j.printer);
    if (!p || p->removed)
        return sf_err_set(err, SF_EINVAL,
                          "job %lld: its part is on printer '%s', which is no longer configured",
                          (long long)id, j.printer);
    if (p->state != PRINTER_IDLE || !p->drv || p->job_id)
        return sf_err_set(err, SF_EINVAL, "job %lld: printer %s is %s; resume when it is idle",
                          (long long)id, p->cfg.name, printer_state_name(p->state));
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
    /* Commit first (farm.c's rule): a crash from here on leaves it interrupted again. */
    struct job_event_args a = { .printer = p->cfg.name, .lines_acked = line };
    if ((rc = store_job_event(f->s, id, JOB_EV_RESUME, &a, NULL, err)))
        return rc;
    notify(f);
    p->job_id = id;
    p->lines_acked = p->lines_saved = line;
    move(p, PRINTER_EV_START);
    /* The machine state at `line` comes from reading the file up to it
       (0.5 s for 2/3 of a 112 MB job): on the io thread, so the other
       printers' streams do not wait; the driver starts when it is read. */
    log_printer(LOG_INFO, p->cfg.name, "job %lld: resumed at line %lld of %llu", (long long)id,
                (long long)line, (unsigned long long)total);
    struct resume *r = mem_calloc(1, sizeof(*r));
    struct sf_err perr;
    if (r) {
        *r = (struct resume){ .f = f, .job_id = id, .line = (uint64_t)line, .scan = scan };
        snprintf(r->printer, sizeof(r->printer), "%s", p->cfg.name);
        snprintf(r->path, sizeof(r->path), "%s", path);
    }
    if (!r || !pool_submit(f->io, resume_work, resume_done, r, &perr)) {
        free(r);
        resume_start(p, path, (uint64_t)line, &scan); /* reads on this thread */
    }
    farm_kick(f);
    return SF_OK;
}
