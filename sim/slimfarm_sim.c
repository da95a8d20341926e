/*
 * slimfarm_sim.c - `slimfarm-sim KIND [options]`: run simulated printers
 * for tests, benchmarks and demos.  KIND is a row of the table at the end
 * (marlin here; each network simulator's main lives in its own file and
 * shares sim_netcli.h's options).  What follows is `slimfarm-sim marlin`.
 *
 * Prints where to connect on its first line of output (the pty path or
 * tcp://127.0.0.1:PORT), then serves until SIGINT/SIGTERM, when it flushes
 * its log and prints one "stats:" line on stderr (executed commands,
 * resends, planner starvation, bytes; and where the host's last bytes sit:
 * the last line number taken, the queue, the RX ring, the wire), which the
 * benchmarks and a failing scenario's report (tests/integ/lib/farm.sh) read.
 *
 * --count N runs N printers in this one process, for farm benchmarks where
 * 50 simulator processes would cost more CPU (and scheduler noise) than the
 * daemon they measure.  Each is a full sim_marlin of its own (own pty or
 * port, queue, planner, pacing, faults, log); they only share the loop.
 * Output is then one address line per printer, in order, and one
 * "stats: printer=I ..." line each; --log FILE and --link PATH get a ".I"
 * suffix, and a fixed --tcp PORT becomes PORT+I.  SIGUSR1 prints the
 * stats lines without stopping, so a benchmark can take the difference
 * over a window.
 *
 * Thread: main thread, one event loop.
 */
#include <errno.h>
#include <signal.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../src/base/loop.h"
#include "../src/base/mem.h"
#include "bambu/sim_bambu.h"
#include "marlin/sim_marlin.h"
#include "net/sim_moonraker.h"
#include "net/sim_octoprint.h"
#include "net/sim_prusalink.h"
#include "simopt.h"

static const char usage_text[] =
    "usage: slimfarm-sim marlin [--tcp PORT] [--link PATH] [--baud N] [--speed X]\n"
    "                           [--bufsize N] [--planner N] [--rx-size N] [--advanced-ok]\n"
    "                           [--uart] [--log FILE] [--fault SPEC]... [--count N]\n"
    "       slimfarm-sim octoprint|moonraker|prusalink|bambu ARGS   (each: --help)\n"
    "       slimfarm-sim -h|--help\n"
    "  --uart  bytes reaching a full RX buffer are lost (else the host waits, as on USB)\n"
    "faults: corrupt=RATE corrupt-rx=RATE corrupt-tx=RATE drop-ok=RATE garbage=RATE\n"
    "        drop-oks=LINE:N dup=RATE merge=RATE bad-line=N hit=KIND:LINE:POS:BYTE\n"
    "        slow=MS reset=N disconnect=N runaway=N stuck=N hold=PATH okt=plain seed=N\n"
    "        (hit KIND: ok okn okt resend error busy temp; see sim/marlin/faults.h)\n";

/* Printers one process may serve: each holds a pty or socket and a log file. */
#define SIM_COUNT_MAX 256

static void
print_stats(const struct sim_marlin *s, int index, int count)
{
    struct sim_marlin_stats st;
    sim_marlin_stats(s, &st);
    fprintf(stderr,
            "%sexecuted=%llu resends=%llu starved=%llu starved_s=%.3f rx_bytes=%llu "
            "tx_bytes=%llu rx_dropped=%llu connects=%llu halted=%d x=%.3f y=%.3f z=%.3f "
            "e=%.5f last_n=%ld queued=%d rx=%d stage=%d\n",
            simopt_stats_head(index, count), (unsigned long long)st.executed,
            (unsigned long long)st.resends, (unsigned long long)st.starved, st.starved_s,
            (unsigned long long)st.rx_bytes, (unsigned long long)st.tx_bytes,
            (unsigned long long)st.rx_dropped, (unsigned long long)st.connects, st.halted, st.x,
            st.y, st.z, st.e, st.last_n, st.queued, st.rx_len, st.stage_len);
}

struct farm_of_sims {
    struct sim_marlin **sims; /* count printers */
    int count;
};

static void
on_usr1(struct loop *l, int signo, void *ud)
{
    (void)l;
    (void)signo;
    struct farm_of_sims *f = ud;
    for (int i = 0; i < f->count; i++)
        print_stats(f->sims[i], i, f->count);
    fflush(stderr);
}

/* Start count printers on l, print their addresses, run until a signal, print stats. */
static int
serve(struct loop *l, const struct sim_marlin_config *base, int count)
{
    struct sim_marlin **sims = mem_calloc((size_t)count, sizeof(*sims));
    if (!sims) {
        fprintf(stderr, "slimfarm-sim: out of memory\n");
        return 1;
    }
    int rc = 1;
    struct farm_of_sims farm = { sims, count };
    struct sf_err serr;
    if (loop_add_signal(l, SIGUSR1, on_usr1, &farm, &serr) < 0) {
        fprintf(stderr, "slimfarm-sim: %s\n", serr.msg);
        goto out;
    }
    for (int i = 0; i < count; i++) {
        struct sim_marlin_config c = *base;
        char log_path[512], link[512];
        if (count > 1 && base->log_path) {
            snprintf(log_path, sizeof(log_path), "%s.%d", base->log_path, i);
            c.log_path = log_path;
        }
        if (count > 1 && base->link) {
            snprintf(link, sizeof(link), "%s.%d", base->link, i);
            c.link = link;
        }
        if (base->tcp_port > 0 && base->tcp_port + i > 65535) {
            fprintf(stderr, "slimfarm-sim: --tcp %d + %d printers passes port 65535\n",
                    base->tcp_port, count);
            goto out;
        }
        if (base->tcp_port > 0)
            c.tcp_port = base->tcp_port + i;
        struct sf_err err;
        sims[i] = sim_marlin_new(l, &c, &err);
        if (!sims[i]) {
            fprintf(stderr, "slimfarm-sim: printer %d: %s\n", i, err.msg);
            goto out;
        }
        printf("%s\n", sim_marlin_path(sims[i]));
    }
    fflush(stdout);
    rc = loop_run(l) < 0 ? 1 : 0;
    for (int i = 0; i < count; i++)
        print_stats(sims[i], i, count);
out:
    for (int i = 0; i < count; i++)
        sim_marlin_free(sims[i]);
    free(sims);
    return rc;
}

static int
marlin_main(int argc, char **argv)
{
    struct sim_marlin_config c;
    sim_marlin_config_init(&c);
    struct sf_err err;
    long count = 1;
    for (int i = 2; i < argc; i++) {
        const char *o = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        double n;
        if (strcmp(o, "--advanced-ok") == 0) {
            c.advanced_ok = true;
            continue;
        }
        if (strcmp(o, "--uart") == 0) {
            c.uart = true;
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
        if (strcmp(o, "--count") == 0) {
            if (simopt_num("slimfarm-sim", o, v, 1, SIM_COUNT_MAX, true, &n) < 0)
                return 2;
            count = (long)n;
        } else if (strcmp(o, "--tcp") == 0) {
            if (simopt_num("slimfarm-sim", o, v, 0, 65535, true, &n) < 0)
                return 2;
            c.tcp_port = (int)n;
        } else if (strcmp(o, "--baud") == 0) {
            if (simopt_num("slimfarm-sim", o, v, 300, 4000000, true, &n) < 0)
                return 2;
            c.baud = (int)n;
        } else if (strcmp(o, "--bufsize") == 0) {
            if (simopt_num("slimfarm-sim", o, v, 1, 64, true, &n) < 0)
                return 2;
            c.bufsize = (int)n;
        } else if (strcmp(o, "--planner") == 0) {
            if (simopt_num("slimfarm-sim", o, v, 1, 256, true, &n) < 0)
                return 2;
            c.planner_blocks = (int)n;
        } else if (strcmp(o, "--rx-size") == 0) {
            if (simopt_num("slimfarm-sim", o, v, 96, 65536, true, &n) < 0)
                return 2;
            c.rx_size = (int)n;
        } else if (strcmp(o, "--speed") == 0) {
            if (simopt_num("slimfarm-sim", o, v, 1e-6, 1e6, false, &c.speed) < 0)
                return 2;
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
    struct loop *l = simopt_loop("slimfarm-sim");
    if (!l)
        return 1;
    int rc = serve(l, &c, (int)count);
    loop_free(l);
    return rc;
}

/* Every simulator this program runs: a new one is one row. */
static const struct {
    const char *kind;
    int (*main)(int argc, char **argv); /* argv[1] is the kind */
} sims[] = {
    { "marlin", marlin_main },           { "octoprint", sim_octoprint_main },
    { "moonraker", sim_moonraker_main }, { "prusalink", sim_prusalink_main },
    { "bambu", sim_bambu_main },
};

int
main(int argc, char **argv)
{
    if (argc >= 2 && (strcmp(argv[1], "-h") == 0 || strcmp(argv[1], "--help") == 0)) {
        fputs(usage_text, stdout);
        return 0;
    }
    for (size_t i = 0; argc >= 2 && i < sizeof(sims) / sizeof(sims[0]); i++)
        if (strcmp(argv[1], sims[i].kind) == 0)
            return sims[i].main(argc, argv);
    fputs(usage_text, stderr);
    return 2;
}
