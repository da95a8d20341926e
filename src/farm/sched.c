/*
 * sched.c - greedy matching of ready jobs to idle printers (rules in
 * sched.h).
 *
 * Why greedy: jobs must start in priority/FIFO order, which is what an
 * operator expects and can predict; the only freedom left is which of the
 * qualifying printers a job takes, and best fit by bed area is the classic
 * answer that keeps large printers for large parts.  Design: sort job
 * indices once (priority, order, id), then walk them, each taking the best free
 * printer; O(jobs log jobs + jobs x printers), trivial for a farm of
 * hundreds.  Reasons are built only for jobs left waiting.
 *
 * Pure functions, no state: any thread.
 */
#include "sched.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "../base/mem.h"
#include "gcjob.h"

static bool
empty(const char *s)
{
    return !s || !s[0];
}

bool
sched_fits_bed(const double s[3], const double b[3])
{
    if (s[2] > b[2])
        return false;
    return (s[0] <= b[0] && s[1] <= b[1]) || (s[1] <= b[0] && s[0] <= b[1]);
}

static void say(char *why, size_t cap, const char *fmt, ...) __attribute__((format(printf, 3, 4)));

static void
say(char *why, size_t cap, const char *fmt, ...)
{
    if (!why || !cap)
        return;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(why, cap, fmt, ap);
    va_end(ap);
}

bool
sched_compatible(const struct sched_job *j, const struct sched_printer *p, char *why,
                 size_t why_cap)
{
    if (!p->enabled) {
        say(why, why_cap, "disabled");
        return false;
    }
    if (!empty(j->printer) && strcmp(j->printer, p->name) != 0) {
        say(why, why_cap, "not the target printer %s", j->printer);
        return false;
    }
    if (!empty(j->group) && (empty(p->group) || strcmp(j->group, p->group) != 0)) {
        say(why, why_cap, "not in group %s", j->group);
        return false;
    }
    if (!empty(j->material) && strcmp(j->material, p->material ? p->material : "") != 0) {
        say(why, why_cap, "material %s not loaded (has %s)", j->material,
            empty(p->material) ? "none" : p->material);
        return false;
    }
    if (gcjob_key_is(j->key) &&
        !gcjob_runs_on(j->key, p->gcode_models, p->nozzle_mm, why, why ? why_cap : 0))
        return false;
    if (!sched_fits_bed(j->size_mm, p->bed_mm)) {
        say(why, why_cap, "part %gx%gx%g mm does not fit bed %gx%gx%g mm", j->size_mm[0],
            j->size_mm[1], j->size_mm[2], p->bed_mm[0], p->bed_mm[1], p->bed_mm[2]);
        return false;
    }
    return true;
}

void
sched_key(const struct sched_printer *p, double angle_deg, char key[SCHED_KEY_MAX])
{
    /* %g prints config decimals exactly enough: 0.4 and 0.40 are one key */
    snprintf(key, SCHED_KEY_MAX, "%s/%s/n%g/bed%gx%gx%g/a%g", p->profile ? p->profile : "",
             p->material ? p->material : "", p->nozzle_mm, p->bed_mm[0], p->bed_mm[1], p->bed_mm[2],
             angle_deg > 0 ? angle_deg : p->overhang_deg);
}

bool
sched_runs_on(const struct sched_job *j, const struct sched_printer *p)
{
    if (empty(j->key))
        return false;
    if (gcjob_key_is(j->key)) /* printed as is: sched_compatible checked its printer */
        return true;
    char key[SCHED_KEY_MAX];
    sched_key(p, j->overhang_deg, key);
    return strcmp(key, j->key) == 0;
}

static void
explain(const struct sched_job *j, const struct sched_printer *printers, size_t n_printers,
        const bool *taken, char *r)
{
    r[0] = '\0';
    bool any = false;
    for (size_t p = 0; p < n_printers && !any; p++)
        any = sched_compatible(j, &printers[p], NULL, 0);
    if (!any) {
        snprintf(r, SCHED_REASON_MAX, "fits no printer%s",
                 n_printers ? ": " : " (none configured)");
        for (size_t p = 0; p < n_printers; p++) {
            char why[160];
            sched_compatible(j, &printers[p], why, sizeof(why));
            size_t len = strlen(r);
            snprintf(r + len, SCHED_REASON_MAX - len, "%s%s: %s", p ? "; " : "", printers[p].name,
                     why);
            if (strlen(r) + 1 >= SCHED_REASON_MAX)
                memcpy(r + SCHED_REASON_MAX - 4, "...", 4);
        }
        return;
    }
    if (j->state != JOB_READY) {
        /* compatible with some printer; it just is not ready yet */
        return;
    }
    snprintf(r, SCHED_REASON_MAX, "waits for a printer: ");
    bool first = true;
    for (size_t p = 0; p < n_printers; p++) {
        if (!sched_compatible(j, &printers[p], NULL, 0))
            continue;
        char what[96];
        if (taken[p] && printers[p].state == PRINTER_IDLE)
            snprintf(what, sizeof(what), "taken by a job before it");
        else
            snprintf(what, sizeof(what), "%s", printer_state_name(printers[p].state));
        size_t len = strlen(r);
        snprintf(r + len, SCHED_REASON_MAX - len, "%s%s is %s", first ? "" : "; ", printers[p].name,
                 what);
        first = false;
        if (strlen(r) + 1 >= SCHED_REASON_MAX)
            memcpy(r + SCHED_REASON_MAX - 4, "...", 4);
    }
}

/* Job order for the greedy walk; the array is sorted by index through qsort_r. */
static int
cmp_jobs(const void *a, const void *b, void *ud)
{
    const struct sched_job *jobs = ud;
    const struct sched_job *x = &jobs[*(const size_t *)a], *y = &jobs[*(const size_t *)b];
    if (x->priority != y->priority)
        return x->priority > y->priority ? -1 : 1;
    if (x->order != y->order)
        return x->order < y->order ? -1 : 1;
    return (x->id > y->id) - (x->id < y->id);
}

/* A job still waiting for a printer: queued, being prepared or ready. */
static bool
waiting(const struct sched_job *j)
{
    return j->state == JOB_QUEUED || j->state == JOB_PREPARING || j->state == JOB_READY;
}

/*
 * Is printer p needed by a waiting job other than jobs[self] that names a
 * material?  A job that names none should leave such a printer free: a
 * material-less job once took the farm's only PETG printer while the PETG
 * job waited (issue 31).
 */
static bool
needed(const struct sched_job *jobs, size_t n_jobs, size_t self, const bool *placed,
       const struct sched_printer *p)
{
    if (!empty(jobs[self].material))
        return false;
    for (size_t k = 0; k < n_jobs; k++)
        if (k != self && !(placed && placed[k]) && waiting(&jobs[k]) && !empty(jobs[k].material) &&
            sched_compatible(&jobs[k], p, NULL, 0))
            return true;
    return false;
}

/* The walk's state: printers taken (or held), jobs placed. */
struct walk {
    const struct sched_job *jobs;
    size_t n_jobs;
    const struct sched_printer *printers;
    size_t n_printers;
    bool *taken;  /* n_printers: assigned, or held for a job not ready yet */
    size_t *held; /* n_printers: 1 + the walk rank of the job holding it, 0: none */
    bool *placed; /* n_jobs: assigned this round */
};

/* Is printer p free for the job of walk rank `rank`?  A printer held for a
   later job not ready yet is (pass 1 runs after every hold is made). */
static bool
is_free(const struct walk *w, size_t p, size_t rank)
{
    return !w->taken[p] || (w->held[p] && w->held[p] - 1 > rank);
}

/*
 * The best free idle printer for jobs[i] (n_printers if none): not the
 * printer it failed on, then one no other waiting job needs, then the
 * smallest bed.  key_only: only printers its G-code runs on.  *avoided and
 * *is_needed say what the best one is.
 */
static size_t
pick(const struct walk *w, size_t i, size_t rank, bool key_only, bool *avoided, bool *is_needed)
{
    const struct sched_job *j = &w->jobs[i];
    size_t best = w->n_printers;
    bool best_avoided = false, best_needed = false;
    for (size_t p = 0; p < w->n_printers; p++) {
        const struct sched_printer *pr = &w->printers[p];
        if (!is_free(w, p, rank) || pr->state != PRINTER_IDLE ||
            !sched_compatible(j, pr, NULL, 0) || (key_only && !sched_runs_on(j, pr)))
            continue;
        bool av = !empty(j->avoid) && strcmp(j->avoid, pr->name) == 0;
        bool nd = needed(w->jobs, w->n_jobs, i, w->placed, pr);
        double area = pr->bed_mm[0] * pr->bed_mm[1];
        bool better = best == w->n_printers || (best_avoided && !av) ||
                      (av == best_avoided && best_needed && !nd) ||
                      (av == best_avoided && nd == best_needed &&
                       area < w->printers[best].bed_mm[0] * w->printers[best].bed_mm[1]);
        if (better) {
            best = p;
            best_avoided = av;
            best_needed = nd;
        }
    }
    *avoided = best_avoided;
    *is_needed = best_needed;
    return best;
}

/*
 * Place jobs[order[k]] in this pass; false if it stays waiting.  A job not
 * ready yet (queued, preparing) holds the printer it would take, so a later
 * job that prepared faster does not start before it (first come, first
 * served within a priority: issue 31).
 */
static bool
place(struct walk *w, size_t i, size_t rank, int pass, struct sched_assign *out)
{
    const struct sched_job *j = &w->jobs[i];
    bool ready = j->state == JOB_READY;
    if (pass == 1 && gcjob_key_is(j->key))
        return false; /* uploaded G-code is never prepared again */
    bool avoided, is_needed;
    size_t best = pick(w, i, rank, ready && pass == 0, &avoided, &is_needed);
    if (best == w->n_printers)
        return false;
    /* The avoided printer is used only if no other qualifying printer
       exists at all (busy ones count: better to wait for them). */
    if (avoided)
        for (size_t p = 0; p < w->n_printers; p++)
            if (p != best && sched_compatible(j, &w->printers[p], NULL, 0))
                return false;
    if (!ready) {
        if (!j->stalled) {
            w->taken[best] = true;
            w->held[best] = rank + 1;
        }
        return false;
    }
    /* Its G-code runs on a printer another job needs while a free one no
       job needs could take it: slice it again for that one (pass 1), if it
       can be now (else it would stall beside an idle printer). */
    if (pass == 0 && is_needed && !j->stalled && !gcjob_key_is(j->key)) {
        bool a, n;
        if (pick(w, i, rank, false, &a, &n) < w->n_printers && !n)
            return false;
    }
    w->taken[best] = true;
    w->held[best] = 0;
    w->placed[i] = true;
    *out = (struct sched_assign){ .job = i,
                                  .printer = best,
                                  .reslice = !sched_runs_on(j, &w->printers[best]) };
    return true;
}

size_t
sched_plan(const struct sched_job *jobs, size_t n_jobs, const struct sched_printer *printers,
           size_t n_printers, struct sched_assign *out, char (*reasons)[SCHED_REASON_MAX])
{
    size_t *order = mem_array(n_jobs ? n_jobs : 1, sizeof(*order));
    bool *taken = mem_calloc(n_printers ? n_printers : 1, sizeof(*taken));
    bool *placed = mem_calloc(n_jobs ? n_jobs : 1, sizeof(*placed));
    size_t *held = mem_calloc(n_printers ? n_printers : 1, sizeof(*held));
    size_t n_out = 0;
    if (!order || !taken || !placed || !held) {
        /* Nothing placed this round; the next call tries again. */
        for (size_t i = 0; reasons && i < n_jobs; i++)
            snprintf(reasons[i], SCHED_REASON_MAX, "scheduler out of memory");
        goto out;
    }
    size_t n_wait = 0;
    for (size_t i = 0; i < n_jobs; i++)
        if (waiting(&jobs[i]))
            order[n_wait++] = i;
    qsort_r(order, n_wait, sizeof(*order), cmp_jobs, (void *)jobs);
    struct walk w = { jobs, n_jobs, printers, n_printers, taken, held, placed };
    /* Pass 0 starts jobs on printers of their key (and lets the jobs not
       ready hold theirs); pass 1 gives each ready job still waiting an idle
       printer left over, to be prepared again for. */
    for (int pass = 0; pass < 2; pass++)
        for (size_t k = 0; k < n_wait; k++) {
            size_t i = order[k];
            if (placed[i] || (pass == 1 && jobs[i].state != JOB_READY))
                continue;
            if (place(&w, i, k, pass, &out[n_out]))
                n_out++;
        }
    for (size_t i = 0; reasons && i < n_jobs; i++) {
        reasons[i][0] = '\0';
        if (!placed[i] && (jobs[i].state == JOB_READY || jobs[i].state == JOB_QUEUED))
            explain(&jobs[i], printers, n_printers, taken, reasons[i]);
    }
out:
    free(order);
    free(taken);
    free(placed);
    free(held);
    return n_out;
}

size_t
sched_prepare_for(const struct sched_job *jobs, size_t n_jobs, size_t job,
                  const struct sched_printer *printers, size_t n_printers)
{
    size_t best = n_printers;
    bool best_idle = false, best_needed = false;
    for (size_t p = 0; p < n_printers; p++) {
        if (!sched_compatible(&jobs[job], &printers[p], NULL, 0))
            continue;
        bool idle = printers[p].state == PRINTER_IDLE;
        bool nd = needed(jobs, n_jobs, job, NULL, &printers[p]);
        if (best == n_printers || (idle && !best_idle) ||
            (idle == best_idle && best_needed && !nd)) {
            best = p;
            best_idle = idle;
            best_needed = nd;
        }
    }
    return best;
}
