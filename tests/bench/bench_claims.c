/*
 * bench_claims.c DATA_DIR N CLAIMERS [POSTGRESQL_URL] - job claims per
 * second (store_job_claim) with CLAIMERS hosts claiming at once from N
 * queued jobs until none is left: each claimer a thread with its own
 * connection and host name (on PostgreSQL a store_open_host of its own, on
 * SQLite a store_open_peer of the one process the data dir's flock allows).
 * The jobs are inserted in one statement (the claims are what is timed),
 * then every claimer starts at once.  Every claim commits durably on both
 * engines (SQLite synchronous=FULL, PostgreSQL's default
 * synchronous_commit).  Prints the claims per second over the whole drain
 * and each claim's latency (p50, p99; a claim that timed out on SQLite's
 * writer lock and was tried again counts from its last try, and the count of
 * such time-outs is printed); tests/bench/bench_store.sh puts the
 * engines and claimer counts side by side.  Wall times on a shared machine:
 * give the load next to them.
 */
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../../src/base/log.h"
#include "../../src/farm/sqldb.h"
#include "../../src/farm/store_host.h"

#define MAX_CLAIMERS 64

static double
now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

/* One claimer thread. */
struct claimer {
    struct store *s;
    char host[16];
    int64_t token;
    double *lat_ms; /* each claim's latency, n of them */
    long n, cap;
    long busy; /* claims that timed out waiting for SQLite's writer lock, and were tried again */
    int rc;
    struct sf_err err;
};

static pthread_barrier_t start;

static void *
claim_all(void *arg)
{
    struct claimer *c = arg;
    pthread_barrier_wait(&start);
    for (;;) {
        struct job_row j;
        double t = now_ms();
        int rc = store_job_claim(c->s, c->host, c->token, NULL, &j, NULL, &c->err);
        if (rc == SF_ENOTFOUND)
            return NULL;
        if (rc == SF_EIO && strstr(c->err.msg, "database is locked")) {
            c->busy++; /* SQLite: waited past its busy timeout (5 s) for the one writer */
            continue;
        }
        if (rc || c->n == c->cap) {
            c->rc = rc ? rc : SF_EBUG;
            return NULL;
        }
        c->lat_ms[c->n++] = now_ms() - t;
    }
}

static int
cmp_dbl(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* n queued jobs of the part sha, in one statement. */
static int
fill(const char *target, long n, const char *sha)
{
    struct sf_err err;
    struct sqldb *db = sqldb_open(target, 0, &err);
    if (!db) {
        fprintf(stderr, "bench_claims: %s\n", err.msg);
        return 1;
    }
    struct sqldb_stmt *st;
    int rc = sqldb_prepare(
        db,
        "WITH RECURSIVE n(i) AS (SELECT 1 UNION ALL SELECT i + 1 FROM n WHERE i < ?1)"
        " INSERT INTO jobs(name, file_sha, state, method, deviation_mm, overhang_deg, copies,"
        " max_retries, material, target_printer, target_group, priority, created_ms, updated_ms,"
        " queue_pos) SELECT 'bench.stl', ?2, 'queued', 'orient', 0, 0, 1, 1, '', '', '', 0, 0, 0,"
        " i FROM n",
        &st);
    if (rc == SF_OK) {
        sqldb_bind_int64(st, 1, n);
        sqldb_bind_text(st, 2, sha);
        rc = sqldb_step(st) == SQLDB_DONE ? SF_OK : SF_EIO;
        sqldb_finalize(st);
    }
    if (rc)
        fprintf(stderr, "bench_claims: fill: %s\n", sqldb_errmsg(db));
    sqldb_close(db);
    return rc ? 1 : 0;
}

/* Open the k claimers' stores and join them as hosts h0 .. */
static int
open_claimers(struct store *s, const char *dir, const char *url, struct claimer *c, int k, long n)
{
    struct sf_err err;
    for (int i = 0; i < k; i++) {
        char d[600];
        snprintf(d, sizeof(d), "%s/h%d", dir, i);
        c[i].s = url ? store_open_host(d, url, NULL, &err) : store_open_peer(s, &err);
        snprintf(c[i].host, sizeof(c[i].host), "h%d", i);
        c[i].cap = n;
        c[i].lat_ms = malloc((size_t)n * sizeof(double));
        if (!c[i].s || !c[i].lat_ms ||
            store_host_join(c[i].s, c[i].host, 3600 * 1000, &c[i].token, &err)) {
            fprintf(stderr, "bench_claims: claimer %d: %s\n", i, err.msg);
            return 1;
        }
    }
    return 0;
}

int
main(int argc, char **argv)
{
    if (argc < 4) {
        fprintf(stderr, "usage: bench_claims DATA_DIR N CLAIMERS [POSTGRESQL_URL]\n");
        return 2;
    }
    long n = strtol(argv[2], NULL, 10);
    int k = (int)strtol(argv[3], NULL, 10);
    const char *url = argc > 4 ? argv[4] : NULL;
    struct sf_err err;
    log_set_level(LOG_WARN);
    struct store *s = store_open_host(argv[1], url, NULL, &err);
    char sha[STORE_SHA_HEX], path[600];
    if (!s || n < 1 || k < 1 || k > MAX_CLAIMERS ||
        store_file_put(s, "solid bench\nendsolid\n", 21, sha, &err)) {
        fprintf(stderr, "bench_claims: open: %s\n", s ? err.msg : "bad arguments");
        return 1;
    }
    snprintf(path, sizeof(path), "%s/slimfarm.db", argv[1]);
    static struct claimer c[MAX_CLAIMERS];
    if (fill(url ? url : path, n, sha) || open_claimers(s, argv[1], url, c, k, n))
        return 1;
    pthread_t th[MAX_CLAIMERS];
    pthread_barrier_init(&start, NULL, (unsigned)k + 1);
    for (int i = 0; i < k; i++)
        pthread_create(&th[i], NULL, claim_all, &c[i]);
    pthread_barrier_wait(&start);
    double t0 = now_ms();
    for (int i = 0; i < k; i++)
        pthread_join(th[i], NULL);
    double elapsed = now_ms() - t0;
    double *all = malloc((size_t)n * sizeof(double));
    long got = 0, busy = 0;
    for (int i = 0; i < k; i++) {
        if (c[i].rc) {
            fprintf(stderr, "bench_claims: claimer %d: %s\n", i, c[i].err.msg);
            return 1;
        }
        memcpy(all + got, c[i].lat_ms, (size_t)c[i].n * sizeof(double));
        got += c[i].n;
        busy += c[i].busy;
        free(c[i].lat_ms);
        store_close(c[i].s);
    }
    if (got == 0) {
        fprintf(stderr, "bench_claims: no job was claimed\n");
        return 1;
    }
    qsort(all, (size_t)got, sizeof(double), cmp_dbl);
    printf("%-10s %2d claimer%s: %6ld claims in %7.0f ms = %6.0f claims/s; a claim p50 %.2f ms, "
           "p99 %.2f ms",
           url ? "PostgreSQL" : "SQLite", k, k == 1 ? " " : "s", got, elapsed,
           got / (elapsed / 1000), all[got / 2], all[(long)(got * 0.99)]);
    if (busy)
        printf("; %ld timed out on the writer lock (5 s) and were tried again", busy);
    printf("\n");
    free(all);
    store_close(s);
    return got == n ? 0 : 1;
}
