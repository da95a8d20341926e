/*
 * farm_ask.c - the scheduling pass's claims and takes (one of several
 * hosts) on the store thread: the pass posts them and goes on, and the
 * answer, on the loop, starts the preparation or the print.
 *
 * A claim or take on its way (an ask) is in f->asks until its answer is
 * handled: a pass meanwhile sees its job as the store will have it
 * (claimed: preparing; taken: printing) and the printer it was taken for
 * as busy, so it neither asks for the job again nor gives that printer
 * another one.  A claim counts in f->preparing from its post (the pool's
 * places include claims on their way), as a reslice's take does.
 *
 * The printer may have changed before the answer comes (removed, disabled,
 * another host's, its key changed; for a print, busy with an operator's
 * job or gone offline): a job taken for it is given back (farm_host_release; the ask
 * stays in f->asks until that is answered, so no pass takes the job again
 * under the token being given back), and a job claimed for it goes back to
 * the queue (DEFER), rather than a print started on a changed printer.  At
 * the stop (storeq_free delivers what is in flight) nothing is started: the
 * leave (farm_host_stop) gives this host's claims back.
 *
 * Thread: the loop thread.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/log.h"
#include "../base/mem.h"
#include "farm_host.h"
#include "farm_int.h"
#include "printer.h"
#include "sched.h"
#include "store_host.h"
#include "storeq.h"

struct farm_ask {
    struct farm_ask *next; /* in f->asks */
    struct farm *f;
    bool take;                     /* a take (else a claim) */
    bool reslice;                  /* a take to prepare the job again for the printer */
    struct job_row job;            /* as the pass read it (a claim's: as claimed) */
    char printer[64];              /* what for */
    char key[SCHED_KEY_MAX];       /* the printer's key then */
    struct farmcfg_printer *spare; /* a claim for another host's printer: its settings */
};

static void
unlink_ask(struct farm *f, struct farm_ask *a)
{
    for (struct farm_ask **pp = &f->asks; *pp; pp = &(*pp)->next)
        if (*pp == a) {
            *pp = a->next;
            break;
        }
    free(a->spare);
    free(a);
}

static struct farm_ask *
ask_new(struct farm *f, const struct job_row *j, const struct printer *p, bool take, bool reslice)
{
    struct farm_ask *a = mem_calloc(1, sizeof(*a));
    if (!a)
        return NULL;
    struct sched_printer v;
    farm_printer_view(p, &v);
    *a = (struct farm_ask){ .f = f, .take = take, .reslice = reslice, .job = *j };
    snprintf(a->printer, sizeof(a->printer), "%s", v.name);
    sched_key(&v, j->opts.overhang_deg, a->key);
    return a;
}

/* The printer a was for, if it is still what it was (else NULL and why it is not); one a job
   was taken for to print must still be idle (a job is prepared for any printer, busy or not). */
static struct printer *
ask_printer(struct farm *f, const struct farm_ask *a, char *why, size_t cap)
{
    struct printer *p = farm_find(f, a->printer);
    struct sched_printer v;
    char key[SCHED_KEY_MAX];
    if (p)
        farm_printer_view(p, &v);
    if (!p || printer_removed(p))
        snprintf(why, cap, "printer %s was removed meanwhile", a->printer);
    else if (!v.enabled)
        snprintf(why, cap, "printer %s was disabled meanwhile", a->printer);
    else if (!farm_host_owns(f, a->printer))
        snprintf(why, cap, "printer %s is another host's now", a->printer);
    else if (sched_key(&v, a->job.opts.overhang_deg, key), strcmp(key, a->key) != 0)
        snprintf(why, cap, "printer %s changed meanwhile (%s, was %s)", a->printer, key, a->key);
    else if (a->take && !a->reslice && (v.state != PRINTER_IDLE || printer_job(p)))
        snprintf(why, cap, "printer %s is %s now", a->printer,
                 printer_job(p) ? "busy with another job" : printer_state_name(v.state));
    else
        return p;
    return NULL;
}

/* A take's give-back came back (logged there): the job is askable again. */
static void
on_released(void *ud, int rc, int64_t fence, const struct job_row *job)
{
    (void)rc, (void)fence, (void)job;
    struct farm_ask *a = ud;
    struct farm *f = a->f;
    unlink_ask(f, a);
    farm_kick(f);
}

static void
on_taken(void *ud, int rc, int64_t fence, const struct job_row *job)
{
    (void)job;
    struct farm_ask *a = ud;
    struct farm *f = a->f;
    if (a->reslice)
        f->preparing--;            /* counted while on its way; prepare counts it again */
    if (f->stopping || !f->pool) { /* the stop: the leave gives it back */
        unlink_ask(f, a);
        return;
    }
    if (rc) {
        /* another host's now, or no longer ready: the printer may have another job; the
           database away or busy (or the take in doubt): taken again by a later pass */
        if (rc == SF_ENOTFOUND)
            farm_kick(f);
        else
            farm_retry_later(f);
        unlink_ask(f, a);
        return;
    }
    char why[160];
    struct printer *p = ask_printer(f, a, why, sizeof(why));
    if (!p) {
        log_info("farm", "job %lld: not started: %s", (long long)a->job.id, why);
        if (farm_host_release(f, a->job.id, fence, why, on_released, a) == SF_OK)
            return;       /* a stays in f->asks until the store answered */
        unlink_ask(f, a); /* out of memory: it stays this host's, taken again by a pass */
        farm_kick(f);
        return;
    }
    if (a->reslice) {
        farm_prepare(f, &a->job, printer_cfg(p), true, fence, false);
    } else {
        printer_set_fence(p, a->job.id, fence);
        farm_start(f, &a->job, p);
    }
    unlink_ask(f, a);
}

static void
on_claimed(void *ud, int rc, int64_t fence, const struct job_row *job)
{
    struct farm_ask *a = ud;
    struct farm *f = a->f;
    f->preparing--;                /* counted while on its way; prepare counts it again */
    if (f->stopping || !f->pool) { /* the stop: the leave gives it back to the queue */
        unlink_ask(f, a);
        return;
    }
    if (rc) {
        /* a database that was away or busy: a later pass tries again (a claim in doubt is
           read back first, and wakes the farm when settled); another host's: its place in
           the pool is free for another job */
        if (rc == SF_EBUSY)
            farm_retry_soon(f);
        else if (rc == SF_EUNREACH)
            farm_retry_later(f);
        else if (rc == SF_ENOTFOUND)
            farm_kick(f);
        unlink_ask(f, a);
        return;
    }
    a->job = *job;
    char why[160];
    struct printer *p = a->spare ? NULL : ask_printer(f, a, why, sizeof(why));
    if (a->spare) { /* another host's printer, as published: its owner takes the job ready */
        farm_prepare(f, &a->job, a->spare, false, fence, true);
    } else if (p) {
        farm_prepare(f, &a->job, printer_cfg(p), false, fence, false);
    } else {
        log_info("farm", "job %lld goes back to the queue: %s", (long long)a->job.id, why);
        struct job_event_args e = { .reason = why, .fence = fence };
        farm_prep_end(f, a->job.id, JOB_EV_DEFER, &e); /* written until the store takes it */
        farm_kick(f);
    }
    unlink_ask(f, a);
}

/* The queued jobs the pass would prepare for printer best as it would jobs[i] (not waiting for
   a reason, files not cooling, the same overhang: the printer's key is the ask's), jobs[i]
   first, then those after it in the pass's order, into ids (STORE_CLAIM_IDS_MAX); how many.
   Hosts whose passes read the same queue choose the same first job: the claim takes the
   first of these still free, so all but one do not come back empty for a pass again (each a
   read of the whole live queue: bench_hosts, 10 hosts, 5 passes a claim). */
static size_t
claim_choices(struct farm *f, const struct job_row *jobs, const struct sched_job *sj, size_t n,
              size_t i, const struct sched_printer *sp, size_t best, char (*why)[SCHED_REASON_MAX],
              int64_t *ids)
{
    size_t m = 0, seen = 0;
    ids[m++] = jobs[i].id;
    /* a few more queued jobs looked at than taken: each look is a walk of the live jobs */
    for (size_t k = i + 1; k < n && m < STORE_CLAIM_IDS_MAX && seen < 4 * STORE_CLAIM_IDS_MAX;
         k++) {
        if (jobs[k].state != JOB_QUEUED)
            continue;
        seen++;
        if (!why[k][0] && jobs[k].opts.overhang_deg == jobs[i].opts.overhang_deg &&
            !farm_cooling(f, jobs[k].id) && sched_prepare_for(sj, n, k, sp, f->n_printers) == best)
            ids[m++] = jobs[k].id;
    }
    return m;
}

void
farm_ask_claim(struct farm *f, const struct job_row *jobs, const struct sched_job *sj, size_t n,
               size_t i, const struct sched_printer *sp, size_t best, char (*why)[SCHED_REASON_MAX])
{
    int64_t ids[STORE_CLAIM_IDS_MAX];
    size_t n_ids = claim_choices(f, jobs, sj, n, i, sp, best, why, ids);
    struct farm_ask *a = ask_new(f, &jobs[i], f->printers[best], false, false);
    if (!a)
        return; /* the next kick tries again */
    if (farm_host_claim(f, ids, n_ids, on_claimed, a)) {
        free(a); /* its last claim in doubt still (settled, it kicks), or out of memory */
        return;
    }
    f->preparing++;
    a->next = f->asks;
    f->asks = a;
}

void
farm_ask_spare(struct farm *f, const struct job_row *j, const struct farmcfg_printer *c)
{
    struct farm_ask *a = mem_calloc(1, sizeof(*a));
    if (!a || !(a->spare = mem_calloc(1, sizeof(*a->spare)))) {
        free(a);
        return; /* the next kick tries again */
    }
    struct sched_printer v;
    *a->spare = *c;
    farm_cfg_view(a->spare, &v);
    a->f = f;
    a->job = *j;
    snprintf(a->printer, sizeof(a->printer), "%s", c->name);
    sched_key(&v, j->opts.overhang_deg, a->key);
    if (farm_host_claim(f, &j->id, 1, on_claimed, a)) {
        free(a->spare);
        free(a);
        return;
    }
    f->preparing++;
    a->next = f->asks;
    f->asks = a;
}

void
farm_ask_take(struct farm *f, const struct job_row *j, struct printer *p, bool reslice)
{
    if (!farm_host_on(f)) { /* a single host: nothing to take */
        if (reslice) {
            farm_prepare(f, j, printer_cfg(p), true, 0, false);
        } else {
            printer_set_fence(p, j->id, 0);
            farm_start(f, j, p);
        }
        return;
    }
    struct farm_ask *a = ask_new(f, j, p, true, reslice);
    if (!a)
        return;
    if (farm_host_take(f, j->id, on_taken, a)) {
        free(a); /* given back lately (the other hosts first), or out of memory */
        return;
    }
    if (reslice)
        f->preparing++;
    a->next = f->asks;
    f->asks = a;
}

void
farm_ask_mark(const struct farm *f, struct job_row *jobs, size_t n, struct sched_printer *sp)
{
    for (const struct farm_ask *a = f->asks; a; a = a->next) {
        for (size_t i = 0; i < n; i++) {
            if (jobs[i].id != a->job.id)
                continue;
            if (!a->take && jobs[i].state == JOB_QUEUED)
                jobs[i].state = JOB_PREPARING;
            else if (a->take && jobs[i].state == JOB_READY)
                jobs[i].state = JOB_PRINTING;
        }
        for (size_t i = 0; a->take && !a->reslice && i < f->n_printers; i++)
            if (strcmp(sp[i].name, a->printer) == 0 && sp[i].state == PRINTER_IDLE)
                sp[i].state = PRINTER_PRINTING;
    }
}
