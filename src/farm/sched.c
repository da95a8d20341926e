/*
 * sched.c - greedy matching of ready jobs to idle printers (rules in
 * sched.h).
 *
 * Why greedy: jobs must start in priority/FIFO order, which is what an
 * operator expects and can predict; the only freedom left is which of the
 * qualifying printers a job takes, and best fit by bed area is the classic
 * answer that keeps large printers for large parts.  Design: sort job
 * indices once (priority, id), then walk them, each taking the best free
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
    return (x->id > y->id) - (x->id < y->id);
}

size_t
sched_plan(const struct sched_job *jobs, size_t n_jobs, const struct sched_printer *printers,
           size_t n_printers, struct sched_assign *out, char (*reasons)[SCHED_REASON_MAX])
{
    size_t *order = mem_array(n_jobs ? n_jobs : 1, sizeof(*order));
    bool *taken = mem_calloc(n_printers ? n_printers : 1, sizeof(*taken));
    bool *placed = mem_calloc(n_jobs ? n_jobs : 1, sizeof(*placed));
    size_t n_out = 0;
    if (!order || !taken || !placed) {
        /* Nothing placed this round; the next call tries again. */
        for (size_t i = 0; reasons && i < n_jobs; i++)
            snprintf(reasons[i], SCHED_REASON_MAX, "scheduler out of memory");
        goto out;
    }
    size_t n_ready = 0;
    for (size_t i = 0; i < n_jobs; i++)
        if (jobs[i].state == JOB_READY)
            order[n_ready++] = i;
    qsort_r(order, n_ready, sizeof(*order), cmp_jobs, (void *)jobs);
    /* Pass 0 starts jobs on printers of their key; pass 1 gives each job
       still waiting an idle printer left over, to be prepared again for. */
    for (int pass = 0; pass < 2; pass++)
        for (size_t k = 0; k < n_ready; k++) {
            const struct sched_job *j = &jobs[order[k]];
            if (placed[order[k]] || (pass == 1 && gcjob_key_is(j->key)))
                continue; /* uploaded G-code is never prepared again */
            size_t best = n_printers;
            bool best_avoided = false;
            for (size_t p = 0; p < n_printers; p++) {
                const struct sched_printer *pr = &printers[p];
                if (taken[p] || pr->state != PRINTER_IDLE || !sched_compatible(j, pr, NULL, 0) ||
                    (pass == 0 && !sched_runs_on(j, pr)))
                    continue;
                bool avoided = !empty(j->avoid) && strcmp(j->avoid, pr->name) == 0;
                double area = pr->bed_mm[0] * pr->bed_mm[1];
                if (best == n_printers || (best_avoided && !avoided) ||
                    (avoided == best_avoided &&
                     area < printers[best].bed_mm[0] * printers[best].bed_mm[1])) {
                    best = p;
                    best_avoided = avoided;
                }
            }
            if (best == n_printers)
                continue;
            /* The avoided printer is used only if no other qualifying printer
               exists at all (busy ones count: better to wait for them). */
            if (best_avoided) {
                bool other = false;
                for (size_t p = 0; p < n_printers && !other; p++)
                    other = p != best && sched_compatible(j, &printers[p], NULL, 0);
                if (other)
                    continue;
            }
            taken[best] = true;
            placed[order[k]] = true;
            out[n_out].job = order[k];
            out[n_out].printer = best;
            out[n_out].reslice = pass == 1;
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
    return n_out;
}
