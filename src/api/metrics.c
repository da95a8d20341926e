/*
 * metrics.c - Prometheus text format from the store (see metrics.h).
 *
 * Why from the store at each scrape rather than counters in memory: the
 * store already holds every print and job with its times and estimates,
 * so a restart loses nothing and the numbers agree with /api/jobs.  A
 * scrape asks SQLite for counts, sums and histogram buckets (store.h's
 * aggregates) rather than loading every row, and runs on the API's
 * reader thread (api_read.h), not on the loop that feeds the printers.
 *
 * Thread: see metrics.h.
 */
#include "metrics.h"

#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include <jansson.h>

#include "../base/buf.h"
#include "../base/mem.h"
#include "../farm/farm_host.h"
#include "../farm/farm_view.h"

#define METRICS_TEXT_MAX (16 << 20) /* 1000 printers x 6 series fit many times over */

/* Bucket bounds (seconds) shared by every histogram: a slice of a second
   up to a day-long print or wait. */
static const double bounds[] = {
    1, 5, 10, 30, 60, 300, 600, 1800, 3600, 7200, 14400, 43200, 86400
};
#define N_BOUNDS (sizeof(bounds) / sizeof(bounds[0]))

/* The text, and whether any append failed (then the scrape fails). */
struct out {
    struct buf b;
    int rc;
};

static void put(struct out *o, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

static void
put(struct out *o, const char *fmt, ...)
{
    char line[512];
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(line, sizeof(line), fmt, ap);
    va_end(ap);
    if (n < 0 || (size_t)n >= sizeof(line) || buf_append(&o->b, line, (size_t)n))
        o->rc = SF_ENOMEM;
}

struct hist {
    unsigned long long n[N_BOUNDS]; /* observations <= bounds[i] (cumulative at output) */
    unsigned long long count;
    double sum;
};

/* A label value as the text format wants it: \ " and newline escaped. */
static void
label(struct out *b, const char *v)
{
    for (const char *p = v; *p; p++) {
        if (*p == '\\')
            put(b, "\\\\");
        else if (*p == '"')
            put(b, "\\\"");
        else if (*p == '\n')
            put(b, "\\n");
        else
            put(b, "%c", *p);
    }
}

static void
family(struct out *b, const char *name, const char *type, const char *help)
{
    put(b, "# HELP %s %s\n# TYPE %s %s\n", name, help, name, type);
}

static void
hist_out(struct out *b, const char *name, const char *lname, const char *lval, const struct hist *h)
{
    for (size_t i = 0; i < N_BOUNDS; i++) {
        put(b, "%s_bucket{", name);
        if (lname) {
            put(b, "%s=\"", lname);
            label(b, lval);
            put(b, "\",");
        }
        put(b, "le=\"%g\"} %llu\n", bounds[i], h->n[i]);
    }
    put(b, "%s_bucket{", name);
    if (lname) {
        put(b, "%s=\"", lname);
        label(b, lval);
        put(b, "\",");
    }
    put(b, "le=\"+Inf\"} %llu\n", h->count);
    const char *kinds[] = { "sum", "count" };
    for (int k = 0; k < 2; k++) {
        put(b, "%s_%s", name, kinds[k]);
        if (lname) {
            put(b, "{%s=\"", lname);
            label(b, lval);
            put(b, "\"}");
        }
        if (k == 0)
            put(b, " %.3f\n", h->sum);
        else
            put(b, " %llu\n", h->count);
    }
}

/* Per printer: counts by outcome, grams. */
struct per {
    char name[64];
    unsigned long long done, failed, cancelled, refused, interrupted;
    double filament_g, saved_g;
};

static struct per *
per_find(struct per **arr, size_t *n, size_t *cap, const char *name)
{
    for (size_t i = 0; i < *n; i++)
        if (strcmp((*arr)[i].name, name) == 0)
            return &(*arr)[i];
    if (!mem_grow((void **)arr, cap, *n + 1, sizeof(**arr)))
        return NULL;
    struct per *p = &(*arr)[(*n)++];
    memset(p, 0, sizeof(*p));
    snprintf(p->name, sizeof(p->name), "%s", name);
    return p;
}

/* Another host's printer r as a scrape reports it: offline while its host is down. */
static void
remote_printer(const struct store_command_printer *r, struct metrics_printer *o)
{
    snprintf(o->name, sizeof(o->name), "%s", r->name);
    snprintf(o->host, sizeof(o->host), "%s", r->host);
    if (!r->live || !printer_state_parse(r->state, &o->state))
        o->state = PRINTER_OFFLINE;
    json_t *v = r->live && r->view[0] ? json_loads(r->view, 0, NULL) : NULL;
    json_t *t = json_object_get(v, "temps");
    o->temps = o->state != PRINTER_OFFLINE && json_is_object(t);
    o->nozzle_c = json_number_value(json_object_get(t, "nozzle_c"));
    o->bed_c = json_number_value(json_object_get(t, "bed_c"));
    json_decref(v);
}

/* Is name among the other hosts' printers rem (n)?  A printer two hosts' configs list is
   the owner's: the other's copy (never scheduled, farm_host.h) would count it twice. */
static bool
remote_named(const struct store_command_printer *rem, size_t n, const char *name)
{
    for (size_t i = 0; i < n; i++)
        if (strcmp(rem[i].name, name) == 0)
            return true;
    return false;
}

int
metrics_printers(struct farm *f, struct metrics_printer **out, size_t *n)
{
    size_t own = f ? farm_printer_count(f) : 0;
    const struct store_command_printer *rem = NULL;
    size_t n_rem = farm_view_printers(f, &rem);
    /* this host's name, joined or not yet (a restart waits out its predecessor's lease): a
       series keeps its labels when the host joins */
    char me[STORE_HOST_NAME_MAX];
    snprintf(me, sizeof(me), "%s", farm_host_name(f));
    *out = mem_calloc(own + n_rem ? own + n_rem : 1, sizeof(**out));
    if (!*out)
        return SF_ENOMEM;
    *n = 0;
    for (size_t i = 0; i < own; i++) {
        struct printer_info pi;
        farm_printer_info(f, i, &pi);
        if (remote_named(rem, n_rem, pi.cfg->name))
            continue; /* in this host's config too, but another live host owns it: its row */
        struct metrics_printer *o = &(*out)[(*n)++];
        snprintf(o->name, sizeof(o->name), "%s", pi.cfg->name);
        snprintf(o->host, sizeof(o->host), "%s", me);
        o->state = pi.state;
        o->temps = pi.state != PRINTER_OFFLINE;
        o->nozzle_c = pi.nozzle_c;
        o->bed_c = pi.bed_c;
    }
    for (size_t i = 0; i < n_rem; i++)
        remote_printer(&rem[i], &(*out)[(*n)++]);
    return SF_OK;
}

/* A per-printer series' labels: printer="NAME" and, on one of several hosts, host="HOST". */
static void
printer_labels(struct out *b, const char *name, const char *host)
{
    put(b, "printer=\"");
    label(b, name);
    put(b, "\"");
    if (host && host[0]) {
        put(b, ",host=\"");
        label(b, host);
        put(b, "\"");
    }
}

/* The host of printer name among pr (n_pr), "" if none. */
static const char *
host_of(const struct metrics_printer *pr, size_t n_pr, const char *name)
{
    for (size_t i = 0; i < n_pr; i++)
        if (strcmp(pr[i].name, name) == 0)
            return pr[i].host;
    return "";
}

/* Each printer's state (1 for the one it is in) and temperatures. */
static void
printer_series(struct out *b, const struct metrics_printer *pr, size_t n_pr)
{
    family(b, "slimfarm_printer_state", "gauge", "Each printer of the farm, 1 in its state.");
    for (size_t i = 0; i < n_pr; i++) {
        put(b, "slimfarm_printer_state{");
        printer_labels(b, pr[i].name, pr[i].host);
        put(b, ",state=\"%s\"} 1\n", printer_state_name(pr[i].state));
    }
    family(b, "slimfarm_printer_temperature_celsius", "gauge",
           "Each printer's nozzle and bed temperature, when not offline.");
    for (size_t i = 0; i < n_pr; i++) {
        if (!pr[i].temps)
            continue;
        const char *sensor[] = { "nozzle", "bed" };
        const double v[] = { pr[i].nozzle_c, pr[i].bed_c };
        for (size_t k = 0; k < 2; k++) {
            put(b, "slimfarm_printer_temperature_celsius{");
            printer_labels(b, pr[i].name, pr[i].host);
            put(b, ",sensor=\"%s\"} %.1f\n", sensor[k], v[k]);
        }
    }
}

/* The printers' counters: every configured printer, then every other that printed. */
static int
tally(struct store *s, const struct metrics_printer *pr, size_t n_pr, struct per **per,
      size_t *n_per, struct sf_err *err)
{
    struct print_tally *t = NULL;
    size_t n_t = 0, cap = 0;
    int rc = store_print_tally(s, &t, &n_t, err);
    for (size_t i = 0; rc == SF_OK && i < n_pr; i++)
        if (!per_find(per, n_per, &cap, pr[i].name))
            rc = SF_ENOMEM;
    for (size_t i = 0; rc == SF_OK && i < n_t; i++) {
        struct per *q = per_find(per, n_per, &cap, t[i].printer);
        if (!q) {
            rc = SF_ENOMEM;
            break;
        }
        if (strcmp(t[i].outcome, "done") == 0) {
            q->done += t[i].n;
            q->filament_g += t[i].filament_g;
            q->saved_g += t[i].saved_g;
        } else if (strcmp(t[i].outcome, "failed") == 0)
            q->failed += t[i].n;
        else if (strcmp(t[i].outcome, "cancelled") == 0)
            q->cancelled += t[i].n;
        else if (strcmp(t[i].outcome, "refused") == 0)
            q->refused += t[i].n; /* the printer would not start it: nothing printed */
        else
            q->interrupted += t[i].n;
    }
    free(t);
    if (rc == SF_ENOMEM)
        sf_err_set(err, SF_ENOMEM, "metrics: out of memory");
    return rc;
}

/* Histogram which from the store into h. */
static int
hist_read(struct store *s, enum store_hist which, struct hist *h, struct sf_err *err)
{
    struct store_hist_out o;
    int rc = store_hist(s, which, bounds, N_BOUNDS, &o, err);
    for (size_t i = 0; rc == SF_OK && i < N_BOUNDS; i++)
        h->n[i] = o.le[i];
    h->count = o.count;
    h->sum = o.sum_s;
    return rc;
}

/* The loop's longest turn and the store thread's counters. */
static void
health_out(struct out *b, const struct farm_health *h)
{
    const struct storeq_stats *q = &h->store;
    family(b, "slimfarm_loop_turn_max_seconds", "gauge",
           "Longest turn of the event loop since the start: every printer waited that long.");
    put(b, "slimfarm_loop_turn_max_seconds %.3f\n", h->loop_turn_max_ms / 1000.0);
    family(b, "slimfarm_store_loop_round_trips_total", "counter",
           "Statements the event loop sent to a PostgreSQL store and waited for (0 on SQLite).");
    put(b, "slimfarm_store_loop_round_trips_total %lld\n", (long long)h->loop_round_trips);
    family(b, "slimfarm_store_queue_depth", "gauge", "Store writes queued on the store thread.");
    put(b, "slimfarm_store_queue_depth %zu\n", q->depth);
    family(b, "slimfarm_store_queue_depth_max", "gauge", "The most store writes queued at once.");
    put(b, "slimfarm_store_queue_depth_max %zu\n", q->depth_max);
    family(b, "slimfarm_store_queue_wait_max_seconds", "gauge",
           "Longest a queued store write took from its post to its end.");
    put(b, "slimfarm_store_queue_wait_max_seconds %.3f\n", q->wait_max_ms / 1000.0);
    family(b, "slimfarm_store_writes_total", "counter", "Queued store writes run to their end.");
    put(b, "slimfarm_store_writes_total %llu\n", (unsigned long long)q->done);
    family(b, "slimfarm_store_write_failures_total", "counter",
           "Queued store writes that failed after their retries (logged).");
    put(b, "slimfarm_store_write_failures_total %llu\n", (unsigned long long)q->failed);
    family(b, "slimfarm_store_write_retries_total", "counter",
           "Queued store writes tried again (the store was busy or unreachable).");
    put(b, "slimfarm_store_write_retries_total %llu\n", (unsigned long long)q->retries);
    if (!h->has_beat)
        return;
    /* one of several hosts: the beat's own store thread (its lease, the peers, the claims and
       takes), whose wait is the lease's risk */
    q = &h->beat;
    family(b, "slimfarm_store_beat_queue_depth", "gauge",
           "Requests queued on the host beat's store thread.");
    put(b, "slimfarm_store_beat_queue_depth %zu\n", q->depth);
    family(b, "slimfarm_store_beat_queue_depth_max", "gauge",
           "The most requests queued at once on the host beat's store thread.");
    put(b, "slimfarm_store_beat_queue_depth_max %zu\n", q->depth_max);
    family(b, "slimfarm_store_beat_queue_wait_max_seconds", "gauge",
           "Longest a request on the host beat's store thread took from its post to its end.");
    put(b, "slimfarm_store_beat_queue_wait_max_seconds %.3f\n", q->wait_max_ms / 1000.0);
    family(b, "slimfarm_store_beat_requests_total", "counter",
           "Requests on the host beat's store thread run to their end.");
    put(b, "slimfarm_store_beat_requests_total %llu\n", (unsigned long long)q->done);
    family(b, "slimfarm_store_beat_failures_total", "counter",
           "Requests on the host beat's store thread that failed after their retries.");
    put(b, "slimfarm_store_beat_failures_total %llu\n", (unsigned long long)q->failed);
    family(b, "slimfarm_store_beat_retries_total", "counter",
           "Requests on the host beat's store thread tried again (busy or unreachable).");
    put(b, "slimfarm_store_beat_retries_total %llu\n", (unsigned long long)q->retries);
}

char *
metrics_render(struct store *s, const struct metrics_printer *pr, size_t n_pr,
               const struct farm_health *h, struct sf_err *err)
{
    struct per *per = NULL;
    size_t n_per = 0;
    struct out b = { .rc = SF_OK };
    buf_init(&b.b, METRICS_TEXT_MAX);
    char *out = NULL;
    uint64_t by_state[JOB_STATE_COUNT];
    struct hist prep = { 0 }, slice = { 0 }, print = { 0 }, wait = { 0 };
    if (store_job_counts(s, by_state, err) || hist_read(s, STORE_HIST_PREPARE, &prep, err) ||
        hist_read(s, STORE_HIST_SLICE, &slice, err) ||
        hist_read(s, STORE_HIST_PRINT, &print, err) || hist_read(s, STORE_HIST_WAIT, &wait, err) ||
        tally(s, pr, n_pr, &per, &n_per, err))
        goto done;
    family(&b, "slimfarm_jobs", "gauge", "Jobs in the store by state.");
    for (int st = 0; st < JOB_STATE_COUNT; st++)
        put(&b, "slimfarm_jobs{state=\"%s\"} %llu\n", job_state_name((enum job_state)st),
            (unsigned long long)by_state[st]);

    unsigned long long pstate[PRINTER_STATE_COUNT] = { 0 };
    for (size_t i = 0; i < n_pr; i++)
        if ((unsigned)pr[i].state < PRINTER_STATE_COUNT)
            pstate[pr[i].state]++;
    family(&b, "slimfarm_printers", "gauge",
           "Configured printers by state (on one of several hosts: every host's).");
    for (int st = 0; st < PRINTER_STATE_COUNT; st++)
        put(&b, "slimfarm_printers{state=\"%s\"} %llu\n",
            printer_state_name((enum printer_state)st), pstate[st]);
    printer_series(&b, pr, n_pr);

    family(&b, "slimfarm_prints_total", "counter", "Prints ended, by printer and outcome.");
    for (size_t i = 0; i < n_per; i++) {
        const char *oc[] = { "done", "failed", "cancelled", "refused", "interrupted" };
        unsigned long long v[] = { per[i].done, per[i].failed, per[i].cancelled, per[i].refused,
                                   per[i].interrupted };
        for (size_t k = 0; k < sizeof(oc) / sizeof(oc[0]); k++) {
            put(&b, "slimfarm_prints_total{");
            printer_labels(&b, per[i].name, host_of(pr, n_pr, per[i].name));
            put(&b, ",outcome=\"%s\"} %llu\n", oc[k], v[k]);
        }
    }
    family(&b, "slimfarm_filament_used_grams_total", "counter",
           "Filament of the prints done, grams, from their G-code's estimate.");
    for (size_t i = 0; i < n_per; i++) {
        put(&b, "slimfarm_filament_used_grams_total{");
        printer_labels(&b, per[i].name, host_of(pr, n_pr, per[i].name));
        put(&b, "} %.3f\n", per[i].filament_g);
    }
    family(&b, "slimfarm_support_saved_grams_total", "counter",
           "Support material the optimization saved on the prints done, grams, as estimated.");
    for (size_t i = 0; i < n_per; i++) {
        put(&b, "slimfarm_support_saved_grams_total{");
        printer_labels(&b, per[i].name, host_of(pr, n_pr, per[i].name));
        put(&b, "} %.3f\n", per[i].saved_g);
    }
    family(
        &b, "slimfarm_stage_duration_seconds", "histogram",
        "Wall time of a stage: prepare (orient to slice, each job's last), slice, print (done).");
    hist_out(&b, "slimfarm_stage_duration_seconds", "stage", "prepare", &prep);
    hist_out(&b, "slimfarm_stage_duration_seconds", "stage", "slice", &slice);
    hist_out(&b, "slimfarm_stage_duration_seconds", "stage", "print", &print);
    family(&b, "slimfarm_queue_wait_seconds", "histogram",
           "Wait of a print from its job becoming ready to its start on a printer.");
    hist_out(&b, "slimfarm_queue_wait_seconds", NULL, NULL, &wait);
    if (h)
        health_out(&b, h);
    if (b.rc || !(out = buf_take(&b.b, NULL)))
        goto oom;
    goto done;
oom:
    sf_err_set(err, SF_ENOMEM, "metrics: out of memory");
done:
    buf_release(&b.b);
    free(per);
    return out;
}
