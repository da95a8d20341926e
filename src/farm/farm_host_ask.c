/*
 * farm_host_ask.c - the scheduling pass's claims, takes and give-backs of one
 * of several hosts (farm_host.h), on the farm's store thread: the pass posts
 * them and goes on; each answer acts on the loop (farm_ask.c keeps what is
 * in flight).  A claim whose commit's answer was lost is read back
 * (settle) before the job is claimed again.
 *
 * Thread: the loop thread (the *_call functions on the store's).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/clock.h"
#include "../base/log.h"
#include "../base/mem.h"
#include "farm_host_int.h"
#include "farm_int.h"
#include "storeq.h"

static void settle(struct farm_host *h);

static int
settle_call(struct store *s, void *arg, struct sf_err *err)
{
    struct doubt *d = arg;
    return store_job_claim_settle(s, d->host, d->id, &d->released, err);
}

static void
on_resettle(struct loop *l, void *ud)
{
    (void)l;
    struct farm_host *h = ud;
    h->resettle = 0;
    settle(h);
}

/* A read-back came back: the job is settled (claimable again), or asked again later. */
static void
on_settled(void *ud, const struct storeq_result *r)
{
    struct doubt *d = ud;
    struct farm_host *h = d->h;
    d->posted = false;
    if (r->rc) {
        log_warn("host", "%s: job %lld: reading back its claim: %s (trying again)", h->name,
                 (long long)d->id, r->err->msg);
        if (!h->resettle)
            h->resettle = loop_timer_add(h->f->l, FARM_RETRY_MS, on_resettle, h);
        return;
    }
    log_info("host", "%s: job %lld: its claim in doubt %s", h->name, (long long)d->id,
             d->released ? "had committed: given back to the queue" : "did not commit");
    for (struct doubt **pp = &h->doubts; *pp; pp = &(*pp)->next)
        if (*pp == d) {
            *pp = d->next;
            break;
        }
    free(d);
    farm_kick(h->f); /* claimable again, by this host too */
}

/* Post the read-back of every claim in doubt not on its way yet. */
static void
settle(struct farm_host *h)
{
    for (struct doubt *d = h->doubts; d; d = d->next) {
        if (d->posted)
            continue;
        if (storeq_call(h->f->q, settle_call, d, NULL, on_settled, d)) {
            if (!h->resettle) /* out of memory: later */
                h->resettle = loop_timer_add(h->f->l, FARM_RETRY_MS, on_resettle, h);
            return;
        }
        d->posted = true;
    }
}

/* Is the claim of job id in doubt (its read-back not back yet)? */
static bool
in_doubt(const struct farm_host *h, int64_t id)
{
    for (const struct doubt *d = h->doubts; d; d = d->next)
        if (d->id == id)
            return true;
    return false;
}

/* A claim, take or give-back on its way to the store thread (farm_host_claim, farm_host_take,
   give_back): what the thread needs, copied; what it answers; whom to tell. */
struct hask {
    struct farm_host *h;
    enum { ASK_CLAIM, ASK_TAKE, ASK_GIVE } op;
    char host[STORE_HOST_NAME_MAX];   /* h's name and token when posted */
    int64_t token, id, fence;         /* the job; a give-back's token, a claim's or take's answer */
    int64_t ids[STORE_CLAIM_IDS_MAX]; /* a claim's: the jobs it chooses from (id: the one tried) */
    size_t n_ids;
    bool bar; /* a give-back: not taken here again for a lease */
    bool ran; /* a claim or take ran: rc and err are its answer */
    int rc;
    struct sf_err err;
    char why[256];      /* a give-back's */
    struct job_row job; /* a claim's: the job as claimed */
    farm_host_answer_fn done;
    void *ud;
};

/* On the store thread.  A claim or take that failed in passing (busy, unreachable) or whose
   commit is in doubt is answered as it is, not tried again or read back here: the loop does
   what it did with the synchronous call's answer (a claim in doubt is settled, a take in
   doubt taken again by a later pass, whose new token it needs; busy: a later pass).  A
   give-back is an ordinary write: retried, and read back when in doubt. */
static int
ask_call(struct store *s, void *arg, struct sf_err *err)
{
    struct hask *a = arg;
    a->err = (struct sf_err){ 0 };
    if (a->op == ASK_GIVE)
        return store_job_give_back(s, a->host, a->id, a->fence, a->why, err);
    if (a->op == ASK_CLAIM) {
        int64_t tried = 0;
        a->rc = store_job_claim_first(s, a->host, a->token, a->ids, a->n_ids, &tried, &a->job,
                                      &a->fence, &a->err);
        if (tried)
            a->id = tried; /* the job claimed, or the one to read back */
        else if (a->rc == SF_EINDOUBT)
            a->rc = SF_EUNREACH; /* no claim was made: nothing to read back */
    } else {
        a->rc = store_job_take(s, a->host, a->token, a->id, &a->fence, &a->err);
    }
    a->ran = true;
    *err = a->err;
    if (a->rc == SF_EBUSY || a->rc == SF_EUNREACH || a->rc == SF_EINDOUBT)
        return sf_err_set(err, SF_EAGAIN, "%s", a->err.msg); /* the loop's to handle */
    return a->rc;
}

static void settle(struct farm_host *h);

/* Drop job id from the ones given back (a give-back that failed: it is still this host's). */
static void
given_drop(struct farm_host *h, int64_t id)
{
    for (size_t i = 0; i < h->n_given; i++)
        if (h->given[i].id == id) {
            h->given[i] = h->given[--h->n_given];
            return;
        }
}

/* A claim of a's came back: logged; one in doubt is read back (settle); a lost lease makes the
   host beat.  Not at the stop: the leave reaps this host, giving such a job back. */
static void
claim_answered(struct farm_host *h, struct hask *a, int rc, const char *msg)
{
    if (rc == SF_OK)
        log_info("host", "%s claimed job %lld", h->name, (long long)a->id);
    else if (rc == SF_EBUSY) /* its row held, as by another host's claim: a later pass */
        log_info("host", "%s: claim job %lld: %s; trying again", h->name, (long long)a->id, msg);
    else if (rc != SF_ENOTFOUND)
        log_warn("host", "%s: claim job %lld: %s", h->name, (long long)a->id, msg);
    if (h->f->stopping)
        return;
    struct doubt *d = rc == SF_EINDOUBT ? mem_calloc(1, sizeof(*d)) : NULL;
    if (d) {
        /* it may have committed: the job would be this host's, preparing, and prepared by
           no one.  Read back on the store thread, and give it back if so. */
        *d = (struct doubt){ .h = h, .next = h->doubts, .id = a->id };
        snprintf(d->host, sizeof(d->host), "%s", h->name);
        h->doubts = d;
        settle(h);
    }
    if (rc == SF_ESTALE)
        farm_host_lease_doubted(h); /* the beat renews it, or joins again if it was reaped */
}

static void
on_asked(void *ud, const struct storeq_result *r)
{
    struct hask *a = ud;
    struct farm_host *h = a->h;
    /* a claim's or take's own answer, unless it never ran (the stop's window spent) */
    int rc = a->ran ? a->rc : r->rc;
    const char *msg = a->ran ? a->err.msg : r->rc ? r->err->msg : "";
    if (rc)
        a->fence = 0;
    if (a->op == ASK_CLAIM) {
        claim_answered(h, a, rc, msg);
    } else if (a->op == ASK_TAKE) {
        if (rc && rc != SF_ENOTFOUND)
            log_warn("host", "%s: take job %lld: %s", h->name, (long long)a->id, msg);
        if (rc == SF_ESTALE && !h->f->stopping)
            farm_host_lease_doubted(h);
    } else if (rc) {
        log_warn("host", "%s: job %lld: %s", h->name, (long long)a->id, msg);
        if (a->bar)
            given_drop(h, a->id); /* still this host's: taken here again, as before */
        if (rc == SF_ESTALE && !h->f->stopping)
            farm_host_lease_doubted(h);
    } else if (a->bar) {
        log_warn("host",
                 "%s gave job %lld back for the other hosts (it cannot start it here: %s); taken "
                 "here again in %.1f s at the earliest",
                 h->name, (long long)a->id, a->why, (double)h->lease_ms / 1000);
    } else {
        log_warn("host", "%s gave job %lld back (not started: %s)", h->name, (long long)a->id,
                 a->why);
    }
    if (a->done)
        a->done(a->ud, rc, a->fence, a->op == ASK_CLAIM && rc == SF_OK ? &a->job : NULL);
    free(a);
}

/* Post a (its op, id and fence set) with h's name and token; SF_OK, or SF_ENOMEM (a freed). */
static int
ask_post(struct farm_host *h, struct hask *a, farm_host_answer_fn done, void *ud)
{
    a->h = h;
    snprintf(a->host, sizeof(a->host), "%s", h->name);
    a->token = h->token;
    a->done = done;
    a->ud = ud;
    /* a claim or take wakes nobody at its commit (storeq_read): its answer acts (prepares,
       starts, or kicks a pass when refused), and a pass per commit re-read every live job
       for nothing (bench_hosts, 10 hosts on 10,000 jobs: one claim per five 0.25 s reads) */
    int rc = a->op == ASK_GIVE ? storeq_call(h->f->q, ask_call, a, NULL, on_asked, a)
                               : storeq_read(h->f->q, ask_call, a, on_asked, a);
    if (rc)
        free(a);
    return rc;
}

int
farm_host_claim(struct farm *f, const int64_t *ids, size_t n, farm_host_answer_fn done, void *ud)
{
    struct farm_host *h = f->host;
    struct hask *a = mem_calloc(1, sizeof(*a));
    if (!a)
        return SF_ENOMEM;
    for (size_t k = 0; k < n && a->n_ids < STORE_CLAIM_IDS_MAX; k++)
        if (!in_doubt(h, ids[k])) /* not again until its last claim is settled */
            a->ids[a->n_ids++] = ids[k];
    if (!a->n_ids) {
        free(a);
        return SF_ENOTFOUND;
    }
    /* on the store thread after what the farm queued before it (its events) */
    a->op = ASK_CLAIM;
    a->id = a->ids[0];
    return ask_post(h, a, done, ud);
}

/* Did this host give job id back lately (forgetting those whose time passed)? */
static bool
given_back(struct farm_host *h, int64_t id)
{
    int64_t now = clock_mono_ms();
    bool found = false;
    for (size_t i = 0; i < h->n_given;) {
        if (h->given[i].until <= now) {
            h->given[i] = h->given[--h->n_given];
            continue;
        }
        found |= h->given[i].id == id;
        i++;
    }
    return found;
}

static void
on_given_timer(struct loop *l, void *ud)
{
    struct farm_host *h = ud;
    h->given_timer = 0;
    farm_kick(h->f); /* what it gave back may be taken here again, if no other host took it */
    /* and again when the next of those still barred may be: one given back after the first
       would otherwise wait for some other kick, perhaps forever */
    (void)given_back(h, 0); /* forgets those whose time passed */
    int64_t next = 0;
    for (size_t i = 0; i < h->n_given; i++)
        if (!next || h->given[i].until < next)
            next = h->given[i].until;
    if (next) {
        int64_t wait = next - clock_mono_ms();
        h->given_timer = loop_timer_add(l, wait > 0 ? wait : 0, on_given_timer, h);
    }
}

/* Give back job id (taken under fence) on the store thread; bar: f does not take it again for
   a lease (from now: a pass meanwhile must not take it again; dropped if it fails). */
static int
give_back(struct farm *f, int64_t id, int64_t fence, const char *why, bool bar,
          farm_host_answer_fn done, void *ud)
{
    struct farm_host *h = f->host;
    struct hask *a = mem_calloc(1, sizeof(*a));
    if (!a)
        return SF_ENOMEM;
    a->op = ASK_GIVE;
    a->id = id;
    a->fence = fence;
    a->bar = bar;
    snprintf(a->why, sizeof(a->why), "%s", why ? why : "");
    int rc = ask_post(h, a, done, ud);
    if (rc || !bar)
        return rc;
    if (mem_grow((void **)&h->given, &h->cap_given, h->n_given + 1, sizeof(*h->given)))
        h->given[h->n_given++] = (struct given){ id, clock_mono_ms() + h->lease_ms };
    if (!h->given_timer)
        h->given_timer = loop_timer_add(f->l, h->lease_ms, on_given_timer, h);
    return SF_OK;
}

void
farm_host_give_back(struct farm *f, int64_t id, int64_t fence, const char *why)
{
    if (f && f->host && give_back(f, id, fence, why, true, NULL, NULL))
        log_warn("host", "%s: job %lld: not given back: out of memory", f->host->name,
                 (long long)id);
}

int
farm_host_release(struct farm *f, int64_t id, int64_t fence, const char *why,
                  farm_host_answer_fn done, void *ud)
{
    return give_back(f, id, fence, why, false, done, ud);
}

int
farm_host_take(struct farm *f, int64_t id, farm_host_answer_fn done, void *ud)
{
    struct farm_host *h = f->host;
    if (given_back(h, id))
        return SF_ENOTFOUND; /* the other hosts first; on_given_timer kicks the farm */
    struct hask *a = mem_calloc(1, sizeof(*a));
    if (!a)
        return SF_ENOMEM;
    a->op = ASK_TAKE;
    a->id = id;
    return ask_post(h, a, done, ud);
}

void
farm_host_ask_stop(struct farm_host *h)
{
    if (h->resettle)
        loop_timer_cancel(h->f->l, h->resettle);
    if (h->given_timer)
        loop_timer_cancel(h->f->l, h->given_timer);
    /* a claim still in doubt: the store thread's queue ran (farm_free), so none is posted;
       the leave below reaps this host, which gives such a job back */
    for (struct doubt *d = h->doubts, *next; d; d = next) {
        next = d->next;
        log_warn("host", "%s: job %lld: its claim is still in doubt at the stop", h->name,
                 (long long)d->id);
        free(d);
    }
}
