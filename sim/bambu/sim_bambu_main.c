/*
 * sim_bambu_main.c - `slimfarm-sim bambu`: run one simulated Bambu printer
 * (sim_bambu.h) against a broker the caller started.
 *
 * Thread: main thread, one event loop (plus the FTPS server's own).
 */
#include <stdio.h>
#include <string.h>

#include "../../src/base/loop.h"
#include "../simopt.h"
#include "sim_bambu.h"

static const char usage_text[] =
    "usage: slimfarm-sim bambu --serial S --access-code C --ca DIR\n"
    "                          (--mqtt HOST:PORT | --mqtt-port N) [--ftps-port N]\n"
    "                          [--model x1|p1] [--speed X] [--log FILE] [--storage DIR]\n"
    "                          [--report-ms N] [--fault SPEC]...\n"
    "  --ca DIR  holds ca.pem, printer.pem and printer.key (CN = serial)\n"
    "faults: unsigned storage-full ftps-drop=BYTES no-reuse-check pasv-early\n"
    "        ftps-slow=MS hms=HEX16@PCT stop-at=PCT mqtt-drop=N ftps-wrong-cert\n";

#define PROG "slimfarm-sim bambu"

int
sim_bambu_main(int argc, char **argv)
{
    struct sim_bambu_config c;
    sim_bambu_config_init(&c);
    char host[64] = "127.0.0.1";
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
            c.serial = v;
        } else if (strcmp(o, "--access-code") == 0) {
            c.access_code = v;
        } else if (strcmp(o, "--ca") == 0) {
            c.ca_dir = v;
        } else if (strcmp(o, "--mqtt") == 0) {
            const char *colon = strrchr(v, ':');
            if (!colon || colon == v || (size_t)(colon - v) >= sizeof(host) ||
                simopt_num(PROG, o, colon + 1, 1, 65535, true, &d) < 0) {
                fprintf(stderr, PROG ": --mqtt expects HOST:PORT\n");
                return 2;
            }
            memcpy(host, v, (size_t)(colon - v));
            host[colon - v] = '\0';
            c.mqtt_port = (int)d;
        } else if (strcmp(o, "--mqtt-port") == 0) {
            if (simopt_num(PROG, o, v, 1, 65535, true, &d) < 0)
                return 2;
            c.mqtt_port = (int)d;
        } else if (strcmp(o, "--ftps-port") == 0) {
            if (simopt_num(PROG, o, v, 0, 65535, true, &d) < 0)
                return 2;
            c.ftps_port = (int)d;
        } else if (strcmp(o, "--model") == 0) {
            if (strcmp(v, "x1") != 0 && strcmp(v, "p1") != 0) {
                fprintf(stderr, PROG ": --model is x1 or p1\n");
                return 2;
            }
            c.p1 = strcmp(v, "p1") == 0;
        } else if (strcmp(o, "--speed") == 0) {
            if (simopt_num(PROG, o, v, 1e-3, 1e6, false, &c.speed) < 0)
                return 2;
        } else if (strcmp(o, "--report-ms") == 0) {
            if (simopt_num(PROG, o, v, 10, 600000, true, &d) < 0)
                return 2;
            c.report_ms = (int)d;
        } else if (strcmp(o, "--log") == 0) {
            c.log_path = v;
        } else if (strcmp(o, "--storage") == 0) {
            c.storage_dir = v;
        } else if (strcmp(o, "--fault") == 0) {
            if (sim_bambu_fault_parse(&c.faults, v, &err) < 0) {
                fprintf(stderr, PROG ": %s\n", err.msg);
                return 2;
            }
        } else {
            fprintf(stderr, PROG ": unknown option '%s'\n%s", o, usage_text);
            return 2;
        }
    }
    c.mqtt_host = host;
    struct loop *l = simopt_loop(PROG);
    if (!l)
        return 1;
    struct sim_bambu *s = sim_bambu_new(l, &c, &err);
    if (!s) {
        fprintf(stderr, PROG ": %s\n", err.msg);
        loop_free(l);
        return 1;
    }
    printf("ftps://127.0.0.1:%d\nmqtts://127.0.0.1:%d\n", sim_bambu_ftps_port(s),
           sim_bambu_mqtt_port(s));
    fflush(stdout);
    int rc = loop_run(l) < 0 ? 1 : 0;
    struct sim_bambu_stats st;
    sim_bambu_stats(s, &st);
    fprintf(stderr,
            "stats: reports=%llu requests=%llu refused=%llu jobs_started=%llu "
            "jobs_finished=%llu mqtt_connects=%llu uploads=%llu refused_reuse=%llu "
            "executed=%llu gcode_state=%s\n",
            (unsigned long long)st.reports, (unsigned long long)st.requests,
            (unsigned long long)st.refused, (unsigned long long)st.jobs_started,
            (unsigned long long)st.jobs_finished, (unsigned long long)st.mqtt_connects,
            (unsigned long long)st.uploads, (unsigned long long)st.refused_reuse,
            (unsigned long long)st.executed, st.gcode_state);
    sim_bambu_free(s);
    loop_free(l);
    return rc;
}
