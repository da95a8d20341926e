/*
 * sim_bambu_main.c - `slimfarm-sim bambu`: run simulated Bambu printers
 * (sim_bambu.h) against brokers the caller started.
 *
 * --count N serves N printers from this one process on one loop, for farm
 * benchmarks (as `slimfarm-sim marlin --count`): printer i has the serial
 * SERIAL followed by i in decimal, its certificates in DIR.i (--ca DIR;
 * CN = its serial), its broker on --mqtt port + i (one broker listener a
 * printer, each showing that printer's certificate), --ftps-port + i when
 * one is given, and --log, --storage with a ".i" suffix.  Output: two
 * address lines a printer, in order; "stats: printer=I ..." lines.
 * SIGUSR1 prints the stats lines without stopping.
 *
 * Thread: main thread, one event loop (plus each FTPS server's own).
 */
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/base/loop.h"
#include "../../src/base/mem.h"
#include "../simopt.h"
#include "sim_bambu.h"

static const char usage_text[] =
    "usage: slimfarm-sim bambu --serial S --access-code C --ca DIR\n"
    "                          (--mqtt HOST:PORT | --mqtt-port N) [--ftps-port N]\n"
    "                          [--model x1|p1] [--speed X] [--log FILE] [--storage DIR]\n"
    "                          [--report-ms N] [--fault SPEC]... [--count N]\n"
    "  --ca DIR  holds ca.pem, printer.pem and printer.key (CN = serial)\n"
    "  --count N N printers: serial SERIAL<i>, --ca DIR.<i>, broker port + i, --ftps-port + i,\n"
    "            --log and --storage .<i>; SIGUSR1 prints the stats lines\n"
    "faults: unsigned storage-full ftps-drop=BYTES no-reuse-check pasv-early\n"
    "        ftps-slow=MS hms=HEX16@PCT stop-at=PCT mqtt-drop=N ftps-wrong-cert\n";

#define PROG "slimfarm-sim bambu"
/* Printers one process may serve (each holds an FTPS thread, sockets and a log). */
#define BAMBU_COUNT_MAX 256

/* Parse argv into c (host: the broker's address) and *count; 0 for --help, 2 on a usage
   error, -1 to go on. */
static int
parse(int argc, char **argv, struct sim_bambu_config *c, char *host, size_t host_n, int *count)
{
    struct sf_err err;
    for (int i = 2; i < argc; i++) {
        const char *o = argv[i];
        if (strcmp(o, "-h") == 0 || strcmp(o, "--help") == 0) {
            fputs(usage_text, stdout);
            return 0;
        }
        const char *v = i + 1 < argc ? argv[++i] : NULL;
        double d;
        if (!v) {
            fprintf(stderr, PROG ": %s needs a value\n%s", o, usage_text);
            return 2;
        }
        if (strcmp(o, "--serial") == 0) {
            c->serial = v;
        } else if (strcmp(o, "--access-code") == 0) {
            c->access_code = v;
        } else if (strcmp(o, "--ca") == 0) {
            c->ca_dir = v;
        } else if (strcmp(o, "--mqtt") == 0) {
            const char *colon = strrchr(v, ':');
            if (!colon || colon == v || (size_t)(colon - v) >= host_n ||
                simopt_num(PROG, o, colon + 1, 1, 65535, true, &d) < 0) {
                fprintf(stderr, PROG ": --mqtt expects HOST:PORT\n");
                return 2;
            }
            memcpy(host, v, (size_t)(colon - v));
            host[colon - v] = '\0';
            c->mqtt_port = (int)d;
        } else if (strcmp(o, "--mqtt-port") == 0) {
            if (simopt_num(PROG, o, v, 1, 65535, true, &d) < 0)
                return 2;
            c->mqtt_port = (int)d;
        } else if (strcmp(o, "--ftps-port") == 0) {
            if (simopt_num(PROG, o, v, 0, 65535, true, &d) < 0)
                return 2;
            c->ftps_port = (int)d;
        } else if (strcmp(o, "--model") == 0) {
            if (strcmp(v, "x1") != 0 && strcmp(v, "p1") != 0) {
                fprintf(stderr, PROG ": --model is x1 or p1\n");
                return 2;
            }
            c->p1 = strcmp(v, "p1") == 0;
        } else if (strcmp(o, "--speed") == 0) {
            if (simopt_num(PROG, o, v, 1e-3, 1e6, false, &c->speed) < 0)
                return 2;
        } else if (strcmp(o, "--report-ms") == 0) {
            if (simopt_num(PROG, o, v, 10, 600000, true, &d) < 0)
                return 2;
            c->report_ms = (int)d;
        } else if (strcmp(o, "--log") == 0) {
            c->log_path = v;
        } else if (strcmp(o, "--storage") == 0) {
            c->storage_dir = v;
        } else if (strcmp(o, "--count") == 0) {
            if (simopt_num(PROG, o, v, 1, BAMBU_COUNT_MAX, true, &d) < 0)
                return 2;
            *count = (int)d;
        } else if (strcmp(o, "--fault") == 0) {
            if (sim_bambu_fault_parse(&c->faults, v, &err) < 0) {
                fprintf(stderr, PROG ": %s\n", err.msg);
                return 2;
            }
        } else {
            fprintf(stderr, PROG ": unknown option '%s'\n%s", o, usage_text);
            return 2;
        }
    }
    return -1;
}

struct bambu_farm {
    struct sim_bambu **sims; /* count printers, NULL where none was made */
    int count;
};

/* One stats line per printer on stderr (at exit, and on SIGUSR1: a running count). */
static void
print_stats(const struct bambu_farm *f)
{
    for (int i = 0; i < f->count; i++) {
        if (!f->sims[i])
            continue;
        struct sim_bambu_stats st;
        sim_bambu_stats(f->sims[i], &st);
        fprintf(stderr,
                "%sreports=%llu requests=%llu refused=%llu jobs_started=%llu "
                "jobs_finished=%llu mqtt_connects=%llu uploads=%llu refused_reuse=%llu "
                "executed=%llu gcode_state=%s\n",
                simopt_stats_head(i, f->count), (unsigned long long)st.reports,
                (unsigned long long)st.requests, (unsigned long long)st.refused,
                (unsigned long long)st.jobs_started, (unsigned long long)st.jobs_finished,
                (unsigned long long)st.mqtt_connects, (unsigned long long)st.uploads,
                (unsigned long long)st.refused_reuse, (unsigned long long)st.executed,
                st.gcode_state);
    }
    fflush(stderr);
}

static void
on_usr1(struct loop *l, int signo, void *ud)
{
    (void)l, (void)signo;
    print_stats(ud);
}

/* Printer i of base's count: its serial, certificates, ports and paths suffixed. */
static struct sim_bambu *
start_one(struct loop *l, const struct sim_bambu_config *base, int i, int count, struct sf_err *err)
{
    struct sim_bambu_config c = *base;
    char serial[64], ca[512], log_path[512], storage[512];
    if (count > 1) {
        snprintf(serial, sizeof(serial), "%s%d", base->serial ? base->serial : "", i);
        snprintf(ca, sizeof(ca), "%s.%d", base->ca_dir ? base->ca_dir : "", i);
        c.serial = serial;
        c.ca_dir = ca;
        c.mqtt_port = base->mqtt_port + i;
        if (base->ftps_port)
            c.ftps_port = base->ftps_port + i;
        if (base->log_path) {
            snprintf(log_path, sizeof(log_path), "%s.%d", base->log_path, i);
            c.log_path = log_path;
        }
        if (base->storage_dir) {
            snprintf(storage, sizeof(storage), "%s.%d", base->storage_dir, i);
            c.storage_dir = storage;
        }
    }
    return sim_bambu_new(l, &c, err);
}

int
sim_bambu_main(int argc, char **argv)
{
    struct sim_bambu_config c;
    sim_bambu_config_init(&c);
    char host[64] = "127.0.0.1";
    int count = 1;
    int rc = parse(argc, argv, &c, host, sizeof(host), &count);
    if (rc >= 0)
        return rc;
    if (c.mqtt_port + count - 1 > 65535 || (c.ftps_port && c.ftps_port + count - 1 > 65535)) {
        fprintf(stderr, PROG ": a port + %d printers passes port 65535\n", count);
        return 2;
    }
    c.mqtt_host = host;
    struct loop *l = simopt_loop(PROG);
    if (!l)
        return 1;
    struct bambu_farm farm = { mem_calloc((size_t)count, sizeof(struct sim_bambu *)), count };
    struct sf_err err;
    rc = 1;
    if (!farm.sims || loop_add_signal(l, SIGUSR1, on_usr1, &farm, &err) < 0) {
        fprintf(stderr, PROG ": %s\n", farm.sims ? err.msg : "out of memory");
        goto out;
    }
    for (int i = 0; i < count; i++) {
        farm.sims[i] = start_one(l, &c, i, count, &err);
        if (!farm.sims[i]) {
            fprintf(stderr, PROG ": printer %d: %s\n", i, err.msg);
            goto out;
        }
        printf("ftps://127.0.0.1:%d\nmqtts://127.0.0.1:%d\n", sim_bambu_ftps_port(farm.sims[i]),
               sim_bambu_mqtt_port(farm.sims[i]));
    }
    fflush(stdout);
    rc = loop_run(l) < 0 ? 1 : 0;
    print_stats(&farm);
out:
    for (int i = 0; farm.sims && i < count; i++)
        sim_bambu_free(farm.sims[i]);
    free(farm.sims);
    loop_free(l);
    return rc;
}
