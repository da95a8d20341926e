/*
 * test_metrics.c - the /metrics text (metrics.h) from a real store in a
 * scratch dir: every print outcome the store records shows up under its
 * own label of slimfarm_prints_total, and none is counted as another.
 * The HTTP side (keys, content type, the figures after real jobs) is
 * tests/integ/farmd_upload.sh's.
 */
#include <stdlib.h>

#include "../../src/api/metrics.h"
#include "../../src/farm/store.h"
#include "../t.h"
#include "../tstore.h"

/* Add a job of copies for some part bytes and make it ready with some G-code; 0 on failure. */
static int64_t
ready_job(struct store *s, const char *part, int copies, struct sf_err *err)
{
    char sha[STORE_SHA_HEX];
    int64_t id = 0;
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "part.stl");
    o.copies = copies;
    if (store_file_put(s, part, strlen(part), sha, err) || store_job_add(s, &o, sha, &id, err) ||
        store_job_event(s, id, JOB_EV_PREPARE, NULL, NULL, err) ||
        store_file_put(s, "G28\nG1 X1\n", 10, sha, err))
        return 0;
    struct job_event_args a = { .gcode_sha = sha, .size_mm = { 20, 30, 40 } };
    return store_job_event(s, id, JOB_EV_PREPARED, &a, NULL, err) ? 0 : id;
}

/* Start job id on printer and end that print with ev. */
static int
print_once(struct store *s, int64_t id, const char *printer, enum job_event ev, struct sf_err *err)
{
    struct job_event_args start = { .printer = printer };
    int rc = store_job_event(s, id, JOB_EV_START, &start, NULL, err);
    return rc ? rc : store_job_event(s, id, ev, NULL, NULL, err);
}

/* The value of the series line that starts with name (labels and all), or -1 if absent. */
static long long
value_of(const char *text, const char *name)
{
    size_t n = strlen(name);
    for (const char *p = text; p && *p; p = strchr(p, '\n'), p = p ? p + 1 : NULL)
        if (strncmp(p, name, n) == 0 && p[n] == ' ')
            return strtoll(p + n + 1, NULL, 10);
    return -1;
}

/*
 * One printer's prints, one of each outcome: refused (the printer would not
 * start it, printer.c's PRINTER_REFUSED_MSG), failed, done, cancelled, and
 * interrupted (the daemon stopped mid-print).  A refused start is counted as
 * refused, not as interrupted.
 */
T_CASE(metrics_count_each_print_outcome)
{
    struct sf_err err;
    char dir[512];
    snprintf(dir, sizeof(dir), "%s/outcomes", t_tmpdir());
    struct store *s = t_store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    int64_t a = ready_job(s, "a", 2, &err), b = ready_job(s, "b", 1, &err);
    T_TRUE(a && b);
    T_OK(print_once(s, a, "mk3", JOB_EV_REFUSED, &err), &err);
    T_OK(print_once(s, a, "mk3", JOB_EV_PRINT_FAILED, &err), &err); /* one retry left */
    T_OK(print_once(s, a, "mk3", JOB_EV_PRINT_DONE, &err), &err);
    T_OK(print_once(s, a, "mk3", JOB_EV_CANCEL, &err), &err);
    T_OK(print_once(s, b, "mk3", JOB_EV_CRASHED, &err), &err);
    char *text = metrics_render(s, NULL, 0, NULL, &err);
    T_TRUE(text != NULL);
    long long refused =
                  value_of(text, "slimfarm_prints_total{printer=\"mk3\",outcome=\"refused\"}"),
              interrupted =
                  value_of(text, "slimfarm_prints_total{printer=\"mk3\",outcome=\"interrupted\"}"),
              done = value_of(text, "slimfarm_prints_total{printer=\"mk3\",outcome=\"done\"}"),
              failed = value_of(text, "slimfarm_prints_total{printer=\"mk3\",outcome=\"failed\"}"),
              cancelled =
                  value_of(text, "slimfarm_prints_total{printer=\"mk3\",outcome=\"cancelled\"}");
    free(text);
    store_close(s);
    T_EQ_INT(refused, 1);
    T_EQ_INT(interrupted, 1);
    T_EQ_INT(done, 1);
    T_EQ_INT(failed, 1);
    T_EQ_INT(cancelled, 1);
}

/* One of several hosts: the beat's own store queue's counters beside the farm queue's; one
   host alone has no beat and shows none. */
T_CASE(metrics_show_the_beat_queue_of_a_host)
{
    struct sf_err err;
    char dir[512];
    snprintf(dir, sizeof(dir), "%s/beat", t_tmpdir());
    struct store *s = t_store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    struct farm_health h = { .store = { .posted = 9, .done = 7, .depth = 2, .depth_max = 3 },
                             .has_beat = true,
                             .beat = { .posted = 12,
                                       .done = 11,
                                       .failed = 1,
                                       .retries = 4,
                                       .depth = 1,
                                       .depth_max = 5,
                                       .wait_max_ms = 2500 } };
    char *text = metrics_render(s, NULL, 0, &h, &err);
    T_TRUE(text != NULL);
    T_EQ_INT(value_of(text, "slimfarm_store_queue_depth"), 2); /* the farm queue's, as before */
    T_EQ_INT(value_of(text, "slimfarm_store_writes_total"), 7);
    T_EQ_INT(value_of(text, "slimfarm_store_beat_queue_depth"), 1);
    T_EQ_INT(value_of(text, "slimfarm_store_beat_queue_depth_max"), 5);
    T_TRUE(strstr(text, "\nslimfarm_store_beat_queue_wait_max_seconds 2.500\n") != NULL);
    T_EQ_INT(value_of(text, "slimfarm_store_beat_requests_total"), 11);
    T_EQ_INT(value_of(text, "slimfarm_store_beat_failures_total"), 1);
    T_EQ_INT(value_of(text, "slimfarm_store_beat_retries_total"), 4);
    T_TRUE(strstr(text, "# TYPE slimfarm_store_beat_requests_total counter") != NULL);
    free(text);
    h.has_beat = false;
    text = metrics_render(s, NULL, 0, &h, &err);
    T_TRUE(text != NULL);
    T_EQ_INT(value_of(text, "slimfarm_store_queue_depth"), 2);
    T_TRUE(strstr(text, "slimfarm_store_beat") == NULL);
    free(text);
    store_close(s);
}
