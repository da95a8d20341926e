/*
 * bench_soak.c - the Marlin driver against a noisy simulated Marlin, many
 * prints in a row, on simulated time (`make soak`, tests/bench/soak.sh).
 *
 * Each print: a fresh simulated printer (stock Marlin 2: plain ok, BUFSIZE
 * 4, a 128-byte RX ring on a UART that drops what overflows) joined to the
 * real driver by a socketpair on one loop whose clock jumps to the next
 * timer whenever nothing is ready (loop_set_virtual), so a print of a
 * minute takes a fraction of a second of CPU and every time-out meets the
 * execution times it is computed for.  The faults (--corrupt RATE: that
 * share of bytes garbled in each direction, at most one a line; --drop-ok
 * RATE) are seeded per print.  The judge is the printer's executed log:
 * every command of the file once, in order; a command missing or run twice
 * is counted, and so is a job that does not end done.  Recovery time is
 * the print's simulated time minus the same print's on a clean link.
 *
 * usage: bench_soak [--prints N] [--lines N] [--corrupt RATE] [--drop-ok RATE]
 *                   [--baud N] [--advanced-ok] [--seed N] [--from N]
 *                   [--speed N] [--window N] [--latency MS] [--link]
 * (--link: only the clean print, reporting the link's use: bytes the host
 * wrote over the print's simulated time against baud / 10; with --speed
 * 1000 the printer's motion never sets the pace, the link does.  --window
 * sets the driver's buffer_lines: 2 is the window it kept before issue 17,
 * 1 ping-pong, printcore's scheme; --latency MS delays each reply line by
 * MS, a USB-serial adapter's and the firmware's turnaround.)
 * (--from N starts at print N's seed: a failure reproduces alone.)
 * Prints one line per 100 prints and a summary; exit 1 if any print failed
 * or lost or repeated a line.
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include "../../drivers/drv.h"
#include "../../drivers/marlin/drv_marlin.h"
#include "../../sim/marlin/sim_marlin.h"
#include "../../sim/simlog.h"
#include "../../src/base/buf.h"
#include "../../src/base/gcode.h"
#include "../../src/base/log.h"

struct print_result {
    bool done;           /* the job ended done */
    long lost, repeated; /* file commands missing from / run twice in the log */
    long fragments;      /* log lines that are no file command (cut lines the printer ran) */
    double secs;         /* simulated seconds from start_job to the end */
    uint64_t rewinds, probes, deadlines, resends;
    uint64_t renumbers;  /* the driver's M110s past numbers near M108/M112/M410 */
    uint64_t bytes_sent; /* bytes the host wrote */
    uint64_t ep_near;    /* stream lines one garbled byte from the emergency parser acting */
    uint64_t ep_acted;   /* lines it acted on (a garbled byte made one of them) */
};

static void
on_event(struct drv *d, enum drv_event ev, void *ud)
{
    (void)d;
    int *state = ud;
    if (ev == DRV_EV_JOB_DONE)
        *state = 1;
    else if (ev == DRV_EV_JOB_FAILED || ev == DRV_EV_JOB_CANCELLED)
        *state = 2;
}

/* Judge the log: each file command once, in order.  Job lines all start "G1 X" and differ. */
static void
judge(const char *gcode, const char *log, struct print_result *res)
{
    size_t n_want, n_got;
    char **want = simlog_commands(gcode, &n_want);
    char **got = simlog_commands(log, &n_got);
    long w = 0;
    for (size_t i = 0; i < n_got; i++) {
        if (w < (long)n_want && strcmp(got[i], want[w]) == 0) {
            w++;
            continue;
        }
        if (simlog_host_line(got[i]))
            continue;
        bool earlier = false;
        for (long k = w - 1; k >= 0 && k >= w - 64 && !earlier; k--)
            earlier = strcmp(got[i], want[k]) == 0;
        if (earlier)
            res->repeated++;
        else
            res->fragments++;
    }
    res->lost = (long)n_want - w;
    simlog_free(want, n_want);
    simlog_free(got, n_got);
}

static int window_lines; /* --window: the driver's buffer_lines (0: its default) */

static int
one_print(const char *gcode, const char *log, const struct sim_marlin_config *base, bool faults_on,
          struct print_result *res)
{
    memset(res, 0, sizeof(*res));
    struct sf_err err;
    struct loop *l = loop_new(&err);
    if (!l)
        return -1;
    loop_set_virtual(l);
    int sv[2];
    if (socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, sv) < 0) {
        loop_free(l);
        return -1;
    }
    struct sim_marlin_config sc = *base;
    if (!faults_on) {
        uint64_t seed = sc.faults.rng;
        int slow = sc.faults.slow_ms; /* the link's latency is no fault */
        faults_init(&sc.faults);
        sc.faults.rng = seed;
        sc.faults.slow_ms = slow;
    }
    sc.fd = sv[0];
    sc.virtual_time = true;
    sc.log_path = log;
    struct sim_marlin *sim = sim_marlin_new(l, &sc, &err);
    char port[32];
    snprintf(port, sizeof(port), "fd:%d", sv[1]);
    int state = 0;
    struct drv_config dc = { .name = "soak",
                             .kind = "marlin",
                             .port = port,
                             .baud = sc.baud,
                             .buffer_lines = window_lines };
    struct drv *d = sim ? drv_new(l, &dc, on_event, &state, &err) : NULL;
    int rc = d ? d->ops->open(d, &err) : -1;
    close(sv[1]);
    if (rc < 0) {
        fprintf(stderr, "soak: %s\n", err.msg);
        drv_free(d);
        sim_marlin_free(sim);
        loop_free(l);
        return -1;
    }
    int64_t end = loop_now_ms(l) + 60000;
    while (d->status.state != DRV_IDLE && loop_now_ms(l) < end)
        loop_run_once(l, 50);
    int64_t t0 = loop_now_ms(l);
    if (d->ops->start_job(d, gcode, 0, NULL, &err) < 0) {
        fprintf(stderr, "soak: %s\n", err.msg);
    } else {
        end = t0 + 24 * 3600 * 1000LL;
        while (state == 0 && loop_now_ms(l) < end)
            loop_run_once(l, 50);
    }
    res->secs = (double)(loop_now_ms(l) - t0) / 1000.0;
    res->done = state == 1;
    struct drv_marlin_stats ds;
    drv_marlin_stats(d, &ds);
    struct sim_marlin_stats st;
    sim_marlin_stats(sim, &st);
    res->rewinds = ds.rewinds;
    res->probes = ds.probes;
    res->deadlines = ds.deadlines;
    res->resends = st.resends;
    res->renumbers = ds.renumbers;
    res->bytes_sent = ds.bytes_sent;
    res->ep_near = st.ep_near;
    res->ep_acted = st.ep_acted;
    if (!res->done)
        fprintf(stderr, "soak: job not done: %s\n", d->status.message);
    drv_free(d);
    sim_marlin_free(sim);
    loop_free(l);
    judge(gcode, log, res);
    return 0;
}

static int
arg_long(const char *o, const char *v, long lo, long hi, long *out)
{
    char *end;
    errno = 0;
    long n = v ? strtol(v, &end, 10) : 0;
    if (!v || errno || end == v || *end || n < lo || n > hi) {
        fprintf(stderr, "bench_soak: %s expects %ld-%ld\n", o, lo, hi);
        return -1;
    }
    *out = n;
    return 0;
}

static int
arg_rate(const char *o, const char *v, double *out)
{
    char *end;
    errno = 0;
    double x = v ? strtod(v, &end) : 0;
    if (!v || errno || end == v || *end || !(x >= 0 && x <= 1)) {
        fprintf(stderr, "bench_soak: %s expects a rate 0-1\n", o);
        return -1;
    }
    *out = x;
    return 0;
}

int
main(int argc, char **argv)
{
    long prints = 1000, lines = 3000, baud = 115200, seed = 1, from = 0, speed = 1, win = 0,
         latency = 0;
    double corrupt = 0.01, drop_ok = 0.01;
    bool advanced = false, link = false;
    for (int i = 1; i < argc; i++) {
        const char *o = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        int rc = 0;
        if (strcmp(o, "--advanced-ok") == 0) {
            advanced = true;
            continue;
        }
        if (strcmp(o, "--link") == 0) {
            link = true;
            continue;
        }
        if (strcmp(o, "--prints") == 0)
            rc = arg_long(o, v, 1, 1000000, &prints);
        else if (strcmp(o, "--lines") == 0)
            rc = arg_long(o, v, 1, 10000000, &lines);
        else if (strcmp(o, "--baud") == 0)
            rc = arg_long(o, v, 300, 4000000, &baud);
        else if (strcmp(o, "--seed") == 0)
            rc = arg_long(o, v, 0, 1L << 40, &seed);
        else if (strcmp(o, "--from") == 0)
            rc = arg_long(o, v, 0, 1000000, &from);
        else if (strcmp(o, "--corrupt") == 0)
            rc = arg_rate(o, v, &corrupt);
        else if (strcmp(o, "--drop-ok") == 0)
            rc = arg_rate(o, v, &drop_ok);
        else if (strcmp(o, "--latency") == 0)
            rc = arg_long(o, v, 0, 1000, &latency);
        else if (strcmp(o, "--speed") == 0)
            rc = arg_long(o, v, 1, 100000, &speed);
        else if (strcmp(o, "--window") == 0) {
            rc = arg_long(o, v, 0, 32, &win);
            window_lines = (int)win;
        } else {
            fprintf(stderr, "usage: bench_soak [--prints N] [--lines N] [--corrupt RATE] "
                            "[--drop-ok RATE] [--baud N] [--advanced-ok] [--seed N] [--from N] "
                            "[--speed N] [--window N] [--latency MS] [--link]\n");
            return 2;
        }
        if (rc < 0)
            return 2;
        i++;
    }
    if (!getenv("SLIMFARM_LOG"))
        log_set_level(LOG_ERROR);
    char dir[] = "/tmp/soak.XXXXXX";
    if (!mkdtemp(dir)) {
        perror("mkdtemp");
        return 1;
    }
    char gcode[64], log[64];
    snprintf(gcode, sizeof(gcode), "%s/job.gcode", dir);
    snprintf(log, sizeof(log), "%s/sim.log", dir);
    /* A dense curved part: 1 mm chords at 80 mm/s, the link rather than the
       printer setting the pace (the case that stresses the window most). */
    FILE *f = fopen(gcode, "w");
    fprintf(f, "G90\nM82\nG92 E0\n");
    double e = 0;
    for (long i = 0; i < lines - 3; i++) {
        double a = (double)i * 0.05, r = 20 + 15 * sin((double)i * 0.001);
        e += 0.0331;
        fprintf(f, "G1 X%.3f Y%.3f E%.5f F4800\n", 100 + r * cos(a), 100 + r * sin(a), e);
    }
    fclose(f);

    struct sim_marlin_config base;
    sim_marlin_config_init(&base);
    base.baud = (int)baud;
    base.speed = (double)speed;
    base.faults.slow_ms = (int)latency;
    base.uart = true;
    base.advanced_ok = advanced;
    struct print_result clean;
    if (one_print(gcode, log, &base, false, &clean) < 0 || !clean.done || clean.lost ||
        clean.repeated) {
        fprintf(stderr, "bench_soak: the clean print failed\n");
        return 1;
    }
    if (link) {
        /* Link use: the bytes the host wrote over the clean print's time,
           against the link's byte rate (baud / 10, 8N1). */
        double bps = (double)clean.bytes_sent / clean.secs;
        printf(
            "link use: %ld lines, stock Marlin (%s, BUFSIZE 4, RX 128 UART), printer speed x%ld, "
            "%ld baud, window %d, reply latency %ld ms: %.1f s, %.0f bytes/s, %.1f %% of the "
            "link\n",
            lines, advanced ? "ADVANCED_OK" : "plain ok", speed, baud, window_lines, latency,
            clean.secs, bps, 100.0 * bps / ((double)baud / 10.0));
        unlink(gcode);
        unlink(log);
        rmdir(dir);
        return 0;
    }
    printf("soak: %ld prints of %ld lines, stock Marlin (%s, BUFSIZE 4, RX 128 UART) at %ld baud, "
           "%.2f %% of bytes garbled each way, %.2f %% of oks lost; clean print %.1f s\n",
           prints, lines, advanced ? "ADVANCED_OK" : "plain ok", baud, corrupt * 100, drop_ok * 100,
           clean.secs);
    long failed = 0, lost = 0, repeated = 0, fragments = 0;
    double lost_s = 0, worst_s = 0;
    uint64_t rewinds = 0, deadlines = 0, probes = 0, renumbers = 0, ep_near = 0, ep_acted = 0;
    for (long p = 0; p < prints; p++) {
        struct sim_marlin_config sc = base;
        char spec[64];
        snprintf(spec, sizeof(spec), "seed=%ld", seed * 1000003 + from + p);
        faults_parse(&sc.faults, spec, NULL);
        sc.faults.corrupt_rx = sc.faults.corrupt_tx = corrupt;
        sc.faults.drop_ok = drop_ok;
        struct print_result r;
        if (one_print(gcode, log, &sc, true, &r) < 0)
            return 1;
        failed += !r.done;
        lost += r.lost;
        repeated += r.repeated;
        fragments += r.fragments;
        double extra = r.secs - clean.secs;
        lost_s += extra;
        if (extra > worst_s)
            worst_s = extra;
        rewinds += r.rewinds;
        deadlines += r.deadlines;
        probes += r.probes;
        renumbers += r.renumbers;
        ep_near += r.ep_near;
        ep_acted += r.ep_acted;
        if (!r.done || r.lost || r.repeated)
            printf("  print %ld: %s, %ld lost, %ld repeated (seed %s)\n", p,
                   r.done ? "done" : "FAILED", r.lost, r.repeated, spec);
        if ((p + 1) % 100 == 0 || p + 1 == prints) {
            printf("  %ld prints: %ld failed, %ld lines lost, %ld repeated, %ld cut lines run; "
                   "recovery %.1f s a print (worst %.1f s), %.1f rewinds, %.1f probes, "
                   "%.2f time-outs a print; emergency parser: %llu lines one byte from "
                   "acting, %llu acted on, %.1f renumberings a print\n",
                   p + 1, failed, lost, repeated, fragments, lost_s / (double)(p + 1), worst_s,
                   (double)rewinds / (double)(p + 1), (double)probes / (double)(p + 1),
                   (double)deadlines / (double)(p + 1), (unsigned long long)ep_near,
                   (unsigned long long)ep_acted, (double)renumbers / (double)(p + 1));
            fflush(stdout);
        }
    }
    unlink(gcode);
    unlink(log);
    rmdir(dir);
    return failed || lost || repeated ? 1 : 0;
}
