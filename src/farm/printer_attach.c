/*
 * printer_attach.c - a network printer that comes back offered the job the
 * store holds as interrupted on it (printer_int.h: printer_attach_offer).
 *
 * Why its own module: the offer reads the store (the interrupted job, its
 * G-code's path, which on PostgreSQL may fetch the whole file from the
 * database), and the loop must not wait for that (issue 32).  The read runs
 * on the store's thread (storeq_read, after every request queued before it,
 * so after the job's CRASHED); the printer waits offline meanwhile, and the
 * answer comes back to a ticket that outlives the printer (printer_free).
 *
 * Thread: the loop thread (attach_read: the store's).
 */
#include "printer_int.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/log.h"
#include "../base/mem.h"

/* attach() answers "not yet" taken on one connection before the job stays interrupted
   (backoff 0.5, 1, 2, ... s: about two minutes in all) */
#define PRINTER_ATTACH_WAITS 10

/* An offer's read on the store's thread: for p (NULL once p is freed), p's name copied. */
struct attach_ticket {
    struct printer *p; /* NULL: freed meanwhile */
    char name[sizeof(((struct farmcfg_printer *)0)->name)];
    struct job_row row; /* the interrupted job (found) */
    bool found;         /* a job is interrupted on p and its G-code is at path */
    char path[1024];
};

/* On the store's thread: the job interrupted on t->name and its G-code's path. */
static int
attach_read(struct store *s, void *arg, struct sf_err *err)
{
    struct attach_ticket *t = arg;
    t->found = false;
    int rc = store_job_interrupted(s, t->name, &t->row, err);
    if (rc == SF_ENOTFOUND || (rc == SF_OK && !t->row.gcode_sha[0]))
        return SF_OK;
    if (rc == SF_OK)
        rc = store_file_path(s, t->row.gcode_sha, t->path, sizeof(t->path), err);
    if (rc == SF_OK)
        t->found = true;
    else if (rc == SF_ENOTFOUND || rc == SF_EINVAL)
        return SF_OK; /* its file is not to be had here: the job stays interrupted */
    return rc;
}

/*
 * Offer the driver job j, its G-code at path: SF_OK when the job was re-attached; SF_EAGAIN
 * when the driver cannot tell yet (its first poll, PrusaLink's job details still on the way:
 * ask again); SF_ENOTFOUND otherwise (the printer does not know it).  If the printer still
 * prints that file (or finished it meanwhile) the job is printing again and ends as the
 * printer says; otherwise it stays interrupted, as it would on Marlin.
 */
static int
attach_job(struct printer *p, const struct job_row *j, const char *path)
{
    struct sf_err err;
    struct drv_job_scan scan = { .lines_total = (uint64_t)j->gcode_lines };
    int rc = p->drv->ops->attach(p->drv, path, j->gcode_lines > 0 ? &scan : NULL, &err);
    if (rc == SF_OK) {
        /* the driver runs it for this host now: the host holds the job (its fencing token, on
           the store's thread: the loop waits neither for the queue nor for the statement),
           then p takes it back, or records its end if the driver saw that first
           (printer_op.c) */
        p->est_s = printer_estimate_s(j, path);
        p->away_id = j->id;
        printer_away_hold(p);
        return SF_OK;
    }
    if (rc == SF_EAGAIN && p->attach_waits < PRINTER_ATTACH_WAITS) {
        log_printer(LOG_INFO, p->cfg.name, "job %lld: re-attach waits: %s", (long long)j->id,
                    err.msg);
        snprintf(p->message, sizeof(p->message), "re-attaching job %lld: %s", (long long)j->id,
                 err.msg);
        return SF_EAGAIN;
    }
    log_printer(LOG_INFO, p->cfg.name, "job %lld stays interrupted: %s", (long long)j->id, err.msg);
    return SF_ENOTFOUND;
}

/* The driver answered "not yet" to attach: offer the job again with its status now. */
static void
on_attach_retry(struct loop *l, void *ud)
{
    (void)l;
    struct printer *p = ud;
    p->attach_retry = 0;
    printer_attach_again(p);
}

static void
schedule_attach_retry(struct printer *p)
{
    if (!p->attach_retry)
        p->attach_retry =
            loop_timer_add(p->env.l, drv_backoff_ms(p->attach_waits++), on_attach_retry, p);
}

bool
printer_attach_later(struct printer *p)
{
    if (p->attach_waits >= PRINTER_ATTACH_WAITS)
        return false;
    schedule_attach_retry(p);
    return true;
}

/* Whether p still waits for its offer: offline, not offered yet, its driver able to answer. */
static bool
attach_wanted(const struct printer *p)
{
    enum drv_state ds = p->drv ? p->drv->status.state : DRV_OFFLINE;
    return !p->deaf && p->state == PRINTER_OFFLINE && p->drv && p->drv->ops->attach &&
           !p->attach_tried && (ds == DRV_IDLE || ds == DRV_PRINTING || ds == DRV_PAUSED);
}

/* The read came back: offer the job (if any) to the driver, or let p connect without it. */
static void
on_attach_read(void *ud, const struct storeq_result *r)
{
    struct attach_ticket *t = ud;
    struct printer *p = t->p;
    if (!p) {
        free(t);
        return;
    }
    p->aticket = NULL;
    if (!attach_wanted(p)) {
        /* the link dropped (the next connection offers it again) or the daemon stops */
        free(t);
        return;
    }
    int rc = SF_ENOTFOUND;
    if (r->rc)
        log_printer(LOG_WARN, p->cfg.name, "its interrupted job is not known: %s", r->err->msg);
    else if (t->found && t->row.id != p->orphan.id && t->row.id != p->away_id)
        rc = attach_job(p, &t->row, t->path); /* (those two are printer_op.c's to settle) */
    free(t);
    if (rc == SF_EAGAIN) {
        schedule_attach_retry(p);
    } else {
        p->attach_tried = true;
        if (rc != SF_OK) /* no job to take back: p connects as its driver says */
            printer_apply_status(p);
    }
    printer_changed(p);
}

/* May p's host drive a print now (env.hold)?  If not, p says why and waits offline. */
static bool
attach_held(struct printer *p)
{
    struct sf_err err;
    int64_t fence;
    if (!p->env.hold || p->env.hold(p->env.ud, 0, &fence, &err) != SF_EAGAIN)
        return false;
    if (strcmp(p->message, err.msg) != 0)
        log_printer(LOG_INFO, p->cfg.name, "waits to re-attach its job: %s", err.msg);
    snprintf(p->message, sizeof(p->message), "%s", err.msg);
    return true;
}

bool
printer_attach_offer(struct printer *p)
{
    /* a host without its lease yet (a restart waits out its predecessor's, whose reap at the
       join interrupts the job) attaches nothing: p waits offline and is offered the job once
       the host joined (printer_attach_again) */
    if (attach_held(p))
        return true;
    /* a read on its way: it acts on the driver's status then; the orphan's first
       (printer_settle_orphan), whose end the offer's read must see */
    if (p->aticket || p->oticket)
        return true;
    /* a job the driver runs on for this host, not held now: held and taken back, or its end
       recorded (printer_op.c), not offered to the driver again (it has it) */
    if (p->away_id || p->hticket) {
        if (!p->attach_retry)
            printer_settle_orphan(p); /* (one read and one hold at a time) */
        return true;
    }
    if (p->bed_full) {
        p->attach_tried = true;
        return false;
    }
    struct attach_ticket *t = mem_calloc(1, sizeof(*t));
    if (!t) {
        log_printer(LOG_ERROR, p->cfg.name, "out of memory: its interrupted job stays so");
        p->attach_tried = true;
        return false;
    }
    t->p = p;
    snprintf(t->name, sizeof(t->name), "%s", p->cfg.name);
    /* after every request queued before it: the job's CRASHED, if still queued, included */
    if (storeq_read(p->env.q, attach_read, t, on_attach_read, t)) {
        free(t);
        p->attach_tried = true;
        return false;
    }
    p->aticket = t;
    return true;
}

void
printer_attach_release(struct printer *p)
{
    if (p->aticket)
        p->aticket->p = NULL; /* its read comes back to no one */
    p->aticket = NULL;
}

void
printer_attach_again(struct printer *p)
{
    p->hold_join = false; /* the host joined (or the offer's timer): the hold may be asked */
    printer_settle_orphan(p);
    printer_attach_wake(p);
}

void
printer_attach_wake(struct printer *p)
{
    enum drv_state ds = p->drv ? p->drv->status.state : DRV_OFFLINE;
    if (!p->deaf && p->state == PRINTER_OFFLINE && !p->attach_tried &&
        (ds == DRV_IDLE || ds == DRV_PRINTING || ds == DRV_PAUSED))
        printer_apply_status(p);
}
