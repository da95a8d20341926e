/*
 * farm_prepend.c - a preparation's end that the store must hear (farm_int.h
 * farm_prep_end).
 *
 * A job whose preparation ended without a G-code is PREPARING in the store
 * until its DEFER (back to the queue) or PREPARE_FAILED is written.  Posted
 * as any event, one the store thread gave up on after STOREQ_RETRY_MS (the
 * database locked or away that long) was lost, and the job stayed preparing
 * until a restart's recovery: with the G-code's upload meeting the lock
 * first, a PostgreSQL farm's DEFER was lost whenever a PREPARED would have
 * been.  Here a write that failed with nothing known to be applied (busy,
 * unreachable, in doubt) is posted again at once (the queue's own back-off
 * paces it), until it is written or refused (a refusal means the job moved
 * on: cancelled, or another host's by a newer fencing token), or the farm
 * stops (the next start's recovery, or a reap, requeues the job).
 *
 * Thread: the loop thread.
 */
#include <stdio.h>
#include <stdlib.h>

#include "../base/log.h"
#include "../base/mem.h"
#include "farm_int.h"
#include "storeq.h"

/* An end on its way: the event and its arguments, owned. */
struct prep_end {
    struct farm *f;
    int64_t id;
    enum job_event ev;
    int64_t fence;
    char reason[512];
};

static void on_end(void *ud, const struct storeq_result *r);

static int
post(struct prep_end *e)
{
    struct job_event_args a = { .reason = e->reason, .fence = e->fence };
    return storeq_job_event(e->f->q, e->id, e->ev, &a, NULL, on_end, e);
}

static void
on_end(void *ud, const struct storeq_result *r)
{
    struct prep_end *e = ud;
    struct farm *f = e->f;
    bool passing = r->rc == SF_EBUSY || r->rc == SF_EUNREACH || r->rc == SF_EINDOUBT;
    if (passing && f->pool && !f->stopping) {
        log_warn("farm", "job %lld: its %s is not written yet, trying again: %s", (long long)e->id,
                 job_event_name(e->ev), r->err->msg);
        if (post(e) == SF_OK)
            return;
    } else if (r->rc && r->rc != SF_EINVAL && r->rc != SF_ESTALE && r->rc != SF_ENOTFOUND) {
        log_error("farm", "job %lld: %s not written: %s", (long long)e->id, job_event_name(e->ev),
                  r->err->msg);
    }
    free(e);
}

void
farm_prep_end(struct farm *f, int64_t id, enum job_event ev, const struct job_event_args *a)
{
    struct prep_end *e = mem_calloc(1, sizeof(*e));
    if (!e) { /* as any event: posted, and lost only if the store gives up on it */
        storeq_job_event(f->q, id, ev, a, NULL, NULL, NULL);
        return;
    }
    *e = (struct prep_end){ .f = f, .id = id, .ev = ev, .fence = a ? a->fence : 0 };
    snprintf(e->reason, sizeof(e->reason), "%s", a && a->reason ? a->reason : "");
    if (post(e)) {
        log_error("farm", "job %lld: %s not posted: out of memory", (long long)id,
                  job_event_name(ev));
        free(e);
    }
}
