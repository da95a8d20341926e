/*
 * bench_store.c DATA_DIR N [POSTGRESQL_URL] - the store's cost per call on
 * one engine: SQLite in DATA_DIR, or the PostgreSQL database at the URL
 * (its files still in DATA_DIR).  N jobs are added (store_job_add: one
 * transaction with its event each), each moved once (store_job_event
 * PREPARE: read, job_next, update, event, commit), then the reads the loop
 * and the API make are timed: the live jobs, a page of 500, 1,000 events.
 * Every commit is durable on both (SQLite synchronous=FULL, PostgreSQL's
 * default synchronous_commit); tests/bench/bench_store.sh puts the two
 * side by side.  Wall times on a shared machine: give the load next to them.
 */
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "../../src/base/log.h"
#include "../../src/farm/store.h"

static double
now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

static int
fail(const char *what, const struct sf_err *err)
{
    fprintf(stderr, "bench_store: %s: %s\n", what, err->msg);
    return 1;
}

int
main(int argc, char **argv)
{
    if (argc < 3) {
        fprintf(stderr, "usage: bench_store DATA_DIR N [POSTGRESQL_URL]\n");
        return 2;
    }
    long n = strtol(argv[2], NULL, 10);
    const char *url = argc > 3 ? argv[3] : NULL;
    struct sf_err err;
    log_set_level(LOG_WARN);
    struct store *s = store_open_db(argv[1], url, NULL, &err);
    if (!s || n < 1)
        return fail("open", &err);
    char sha[STORE_SHA_HEX];
    if (store_file_put(s, "solid bench\nendsolid\n", 21, sha, &err))
        return fail("file", &err);
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "bench.stl");
    int64_t *ids = malloc((size_t)n * sizeof(*ids));
    double t0 = now_ms();
    for (long i = 0; i < n; i++)
        if (store_job_add(s, &o, sha, &ids[i], &err))
            return fail("add", &err);
    double t1 = now_ms();
    for (long i = 0; i < n; i++)
        if (store_job_event(s, ids[i], JOB_EV_PREPARE, NULL, NULL, &err))
            return fail("event", &err);
    double t2 = now_ms();
    struct job_row *rows;
    size_t got;
    if (store_job_live(s, &rows, &got, &err))
        return fail("live", &err);
    free(rows);
    double t3 = now_ms();
    struct store_job_filter f = { .newest_first = true };
    if (store_job_page(s, &f, 500, &rows, &got, NULL, &err))
        return fail("page", &err);
    free(rows);
    double t4 = now_ms();
    struct event_row *ev;
    if (store_events(s, 0, 1000, &ev, &got, &err))
        return fail("events", &err);
    free(ev);
    double t5 = now_ms();
    printf("%-10s add %7.0f us/job (%5.0f/s)  event %7.0f us (%5.0f/s)  live(%ld) %6.1f ms  "
           "page(500) %5.1f ms  events(1000) %5.1f ms\n",
           url ? "postgresql" : "sqlite", (t1 - t0) * 1e3 / n, n / (t1 - t0) * 1e3,
           (t2 - t1) * 1e3 / n, n / (t2 - t1) * 1e3, n, t3 - t2, t4 - t3, t5 - t4);
    free(ids);
    store_close(s);
    return 0;
}
