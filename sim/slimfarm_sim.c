/*
 * slimfarm_sim.c - `slimfarm-sim marlin [options]`: run a simulated Marlin
 * printer for tests, benchmarks and demos.
 *
 * Prints where to connect on its first line of output (the pty path or
 * tcp://127.0.0.1:PORT), then serves until SIGINT/SIGTERM, when it flushes
 * its log and prints one "stats:" line on stderr (executed commands,
 * resends, planner starvation, bytes), which the benchmarks read.
 *
 * Thread: main thread, one event loop.
 */
#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../src/base/loop.h"
#include "sim_marlin.h"

static const char usage_text[] =
    "usage: slimfarm-sim marlin [--tcp PORT] [--link PATH] [--baud N] [--speed X]\n"
    "                           [--bufsize N] [--planner N] [--rx-size N] [--advanced-ok]\n"
    "                           [--log FILE] [--fault SPEC]...\n"
    "faults: corrupt=RATE corrupt-rx=RATE corrupt-tx=RATE drop-ok=RATE garbage=RATE\n"
    "        slow=MS reset=N disconnect=N runaway=N seed=N\n";

static void
on_signal(struct loop *l, int signo, void *ud)
{
    (void)signo;
    (void)ud;
    loop_stop(l);
}

static int
parse_long(const char *opt, const char *v, long lo, long hi, long *out)
{
    char *end;
    errno = 0;
    long n = v ? strtol(v, &end, 10) : 0;
    if (!v || errno || end == v || *end || n < lo || n > hi) {
        fprintf(stderr, "slimfarm-sim: %s expects a whole number from %ld to %ld\n", opt, lo, hi);
        return -1;
    }
    *out = n;
    return 0;
}

int
main(int argc, char **argv)
{
    if (argc < 2 || strcmp(argv[1], "marlin") != 0) {
        fputs(usage_text, stderr);
        return 2;
    }
    struct sim_marlin_config c;
    sim_marlin_config_init(&c);
    struct sf_err err;
    for (int i = 2; i < argc; i++) {
        const char *o = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        long n;
        if (strcmp(o, "--advanced-ok") == 0) {
            c.advanced_ok = true;
            continue;
        }
        if (strcmp(o, "-h") == 0 || strcmp(o, "--help") == 0) {
            fputs(usage_text, stdout);
            return 0;
        }
        if (!v) {
            fprintf(stderr, "slimfarm-sim: %s needs a value\n%s", o, usage_text);
            return 2;
        }
        i++;
        if (strcmp(o, "--tcp") == 0) {
            if (parse_long(o, v, 0, 65535, &n) < 0)
                return 2;
            c.tcp_port = (int)n;
        } else if (strcmp(o, "--baud") == 0) {
            if (parse_long(o, v, 300, 4000000, &n) < 0)
                return 2;
            c.baud = (int)n;
        } else if (strcmp(o, "--bufsize") == 0) {
            if (parse_long(o, v, 1, 64, &n) < 0)
                return 2;
            c.bufsize = (int)n;
        } else if (strcmp(o, "--planner") == 0) {
            if (parse_long(o, v, 1, 256, &n) < 0)
                return 2;
            c.planner_blocks = (int)n;
        } else if (strcmp(o, "--rx-size") == 0) {
            if (parse_long(o, v, 96, 65536, &n) < 0)
                return 2;
            c.rx_size = (int)n;
        } else if (strcmp(o, "--speed") == 0) {
            char *end;
            errno = 0;
            c.speed = strtod(v, &end);
            if (errno || end == v || *end || !(c.speed > 0) || c.speed > 1e6) {
                fprintf(stderr, "slimfarm-sim: --speed expects a factor above 0, up to 1e6\n");
                return 2;
            }
        } else if (strcmp(o, "--log") == 0) {
            c.log_path = v;
        } else if (strcmp(o, "--link") == 0) {
            c.link = v;
        } else if (strcmp(o, "--fault") == 0) {
            if (faults_parse(&c.faults, v, &err) < 0) {
                fprintf(stderr, "slimfarm-sim: %s\n", err.msg);
                return 2;
            }
        } else {
            fprintf(stderr, "slimfarm-sim: unknown option '%s'\n%s", o, usage_text);
            return 2;
        }
    }
    struct loop *l = loop_new(&err);
    if (!l) {
        fprintf(stderr, "slimfarm-sim: %s\n", err.msg);
        return 1;
    }
    if (loop_add_signal(l, SIGINT, on_signal, NULL, &err) < 0 ||
        loop_add_signal(l, SIGTERM, on_signal, NULL, &err) < 0) {
        fprintf(stderr, "slimfarm-sim: %s\n", err.msg);
        loop_free(l);
        return 1;
    }
    signal(SIGPIPE, SIG_IGN);
    struct sim_marlin *s = sim_marlin_new(l, &c, &err);
    if (!s) {
        fprintf(stderr, "slimfarm-sim: %s\n", err.msg);
        loop_free(l);
        return 1;
    }
    printf("%s\n", sim_marlin_path(s));
    fflush(stdout);
    int rc = loop_run(l);
    struct sim_marlin_stats st;
    sim_marlin_stats(s, &st);
    fprintf(stderr,
            "stats: executed=%llu resends=%llu starved=%llu starved_s=%.3f rx_bytes=%llu "
            "tx_bytes=%llu connects=%llu halted=%d x=%.3f y=%.3f z=%.3f e=%.5f\n",
            (unsigned long long)st.executed, (unsigned long long)st.resends,
            (unsigned long long)st.starved, st.starved_s, (unsigned long long)st.rx_bytes,
            (unsigned long long)st.tx_bytes, (unsigned long long)st.connects, st.halted, st.x, st.y,
            st.z, st.e);
    sim_marlin_free(s);
    loop_free(l);
    return rc < 0 ? 1 : 0;
}
