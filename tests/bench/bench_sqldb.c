/*
 * bench_sqldb.c URL N PGCTL - sqldb's PostgreSQL connection: how soon a
 * NOTIFY reaches a listener's callback, and how soon a connection is back
 * after the server restarts (sqldb.h's reconnect).
 *
 * Notify latency: N times, one connection runs sqldb_notify (pg_notify,
 * autocommit) and the clock runs until another, listening, has the payload
 * in its callback (poll on sqldb_notify_fd, then sqldb_notifications):
 * median, p99 and max, beside the notifying call's own time.
 * Reconnect: PGCTL (a command taking "stop -m fast" / "start", from
 * tests/bench/bench_sqldb.sh) stops the server; a caller either calls every
 * 10 ms through the outage (its back-off grows, 0.2 s doubling to 5 s) or
 * stays idle; then the server starts, and the time from pg_ctl's return
 * (the server accepts connections) to the caller's first successful call
 * is reported, and how long that call took (the reconnect's own cost).
 */
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../../src/base/clock.h"
#include "../../src/farm/sqldb.h"

struct want {
    const char *payload;
    bool got;
};

static void
on_note(void *arg, const char *channel, const char *payload)
{
    struct want *w = arg;
    (void)channel;
    w->got |= strcmp(payload, w->payload) == 0;
}

static int
cmp_dbl(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static void
nap_ms(int ms)
{
    nanosleep(&(struct timespec){ .tv_sec = ms / 1000, .tv_nsec = (ms % 1000) * 1000000L }, NULL);
}

static int
notify_latency(const char *url, int n)
{
    struct sf_err err;
    struct sqldb *l = sqldb_open(url, 0, &err), *s = l ? sqldb_open(url, 0, &err) : NULL;
    if (!s || sqldb_listen(l, "bench")) {
        fprintf(stderr, "bench_sqldb: %s\n", s ? sqldb_errmsg(l) : err.msg);
        return 1;
    }
    double *e2e = calloc((size_t)n, sizeof(*e2e)), *call = calloc((size_t)n, sizeof(*call));
    for (int i = 0; i < n; i++) {
        char payload[32];
        snprintf(payload, sizeof(payload), "%d", i);
        struct want w = { payload, false };
        double t0 = clock_mono_s();
        if (sqldb_notify(s, "bench", payload)) {
            fprintf(stderr, "bench_sqldb: notify: %s\n", sqldb_errmsg(s));
            return 1;
        }
        call[i] = (clock_mono_s() - t0) * 1e3;
        while (!w.got) {
            struct pollfd pfd = { .fd = sqldb_notify_fd(l), .events = POLLIN };
            if (poll(&pfd, 1, 10000) != 1 || sqldb_notifications(l, on_note, &w) < 0) {
                fprintf(stderr, "bench_sqldb: notification %d did not come\n", i);
                return 1;
            }
        }
        e2e[i] = (clock_mono_s() - t0) * 1e3;
    }
    qsort(e2e, (size_t)n, sizeof(*e2e), cmp_dbl);
    qsort(call, (size_t)n, sizeof(*call), cmp_dbl);
    printf("notify -> listener's callback, %d over a Unix socket: median %.3f ms, p99 %.3f ms, "
           "max %.3f ms (the notifying call alone: median %.3f ms, p99 %.3f ms)\n",
           n, e2e[n / 2], e2e[n * 99 / 100], e2e[n - 1], call[n / 2], call[n * 99 / 100]);
    free(e2e);
    free(call);
    sqldb_close(l);
    sqldb_close(s);
    return 0;
}

static int
pgctl(const char *ctl, const char *args)
{
    char cmd[1024];
    snprintf(cmd, sizeof(cmd), "%s %s > /dev/null", ctl, args);
    return system(cmd);
}

/* One outage of outage_ms; busy: call every 10 ms through it. */
static int
reconnect_after(const char *url, const char *ctl, int outage_ms, bool busy)
{
    struct sf_err err;
    struct sqldb *db = sqldb_open(url, 0, &err);
    if (!db || sqldb_exec(db, "SELECT 1") || pgctl(ctl, "stop -m fast"))
        return 1;
    double t_stop = clock_mono_s();
    while ((clock_mono_s() - t_stop) * 1e3 < outage_ms) {
        if (busy)
            sqldb_exec(db, "SELECT 1");
        nap_ms(10);
    }
    if (pgctl(ctl, "start"))
        return 1;
    double t_up = clock_mono_s(), t_call = t_up;
    while (sqldb_exec(db, "SELECT 1") != SF_OK) {
        if (clock_mono_s() - t_up > 60) {
            fprintf(stderr, "bench_sqldb: no reconnect in 60 s: %s\n", sqldb_errmsg(db));
            return 1;
        }
        nap_ms(10);
        t_call = clock_mono_s();
    }
    double t_ok = clock_mono_s();
    printf("server away %5.1f s, caller %s: first success %7.1f ms after the server was back "
           "(that call took %.1f ms)\n",
           outage_ms / 1e3, busy ? "calling every 10 ms" : "idle             ", (t_ok - t_up) * 1e3,
           (t_ok - t_call) * 1e3);
    sqldb_close(db);
    return 0;
}

int
main(int argc, char **argv)
{
    int n = argc == 4 ? (int)strtol(argv[2], NULL, 10) : 0;
    if (n < 1)
        fprintf(stderr, "usage: bench_sqldb URL N PGCTL (N >= 1)\n");
    if (n < 1 || notify_latency(argv[1], n))
        return 1;
    const int outages_ms[] = { 1000, 3000, 10000 };
    for (int i = 0; i < 3; i++)
        for (int busy = 0; busy < 2; busy++)
            if (reconnect_after(argv[1], argv[3], outages_ms[i], busy))
                return 1;
    return 0;
}
