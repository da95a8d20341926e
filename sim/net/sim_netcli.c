/*
 * sim_netcli.c - the shared command line and serve loop of the network
 * printer simulators (sim_netcli.h).
 *
 * Thread: main thread.
 */
#include "sim_netcli.h"

#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/base/mem.h"
#include "sim_http.h"
#include "sim_netprinter.h"
#include "sim_ws.h"

static void
usage(FILE *f, const char *kind, const char *extra)
{
    fprintf(f,
            "usage: slimfarm-sim %s [--port N] [--api-key K] [--user U --password P]\n"
            "                  [--speed X] [--log FILE] [--uploads DIR] [--fault SPEC]...\n"
            "                  [--count N]\n"
            "  prints http://127.0.0.1:PORT per printer, serves until SIGINT/SIGTERM\n"
            "http faults: 5xx=N[@K] slow=MS slow-upload=MS[@N] drop-upload=N drop=N\n"
            "firmware faults: as slimfarm-sim marlin (corrupt=RATE reset=N runaway=N ...)\n"
            "%s",
            kind, extra ? extra : "");
}

static int
num(const char *opt, const char *v, double lo, double hi, double *out)
{
    char *end;
    errno = 0;
    double d = v ? strtod(v, &end) : 0;
    if (!v || errno || end == v || *end || !(d >= lo) || d > hi) {
        fprintf(stderr, "slimfarm-sim: %s expects a number from %g to %g\n", opt, lo, hi);
        return -1;
    }
    *out = d;
    return 0;
}

int
sim_net_parse(int argc, char **argv, struct sim_net_opts *o, const char *extra)
{
    memset(o, 0, sizeof(*o));
    o->kind = argv[1];
    o->speed = 1;
    o->count = 1;
    for (int i = 2; i < argc; i++) {
        const char *a = argv[i];
        if (strcmp(a, "-h") == 0 || strcmp(a, "--help") == 0) {
            usage(stdout, o->kind, extra);
            return 0;
        }
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!v) {
            fprintf(stderr, "slimfarm-sim: %s needs a value\n", a);
            return 2;
        }
        i++;
        double d;
        if (strcmp(a, "--port") == 0) {
            if (num(a, v, 0, 65535, &d) < 0 || d != (int)d)
                return 2;
            o->port = (int)d;
        } else if (strcmp(a, "--count") == 0) {
            if (num(a, v, 1, SIM_NET_COUNT_MAX, &d) < 0 || d != (int)d)
                return 2;
            o->count = (int)d;
        } else if (strcmp(a, "--speed") == 0) {
            if (num(a, v, 1e-3, 1e6, &d) < 0)
                return 2;
            o->speed = d;
        } else if (strcmp(a, "--api-key") == 0) {
            o->api_key = v;
        } else if (strcmp(a, "--user") == 0) {
            o->user = v;
        } else if (strcmp(a, "--password") == 0) {
            o->password = v;
        } else if (strcmp(a, "--log") == 0) {
            o->log_path = v;
        } else if (strcmp(a, "--uploads") == 0) {
            o->uploads_dir = v;
        } else if (strcmp(a, "--fault") == 0) {
            if (o->n_faults == SIM_NET_FAULTS_MAX) {
                fprintf(stderr, "slimfarm-sim: at most %d --fault options\n", SIM_NET_FAULTS_MAX);
                return 2;
            }
            o->faults[o->n_faults++] = v;
        } else {
            fprintf(stderr, "slimfarm-sim: unknown option '%s'\n", a);
            usage(stderr, o->kind, extra);
            return 2;
        }
    }
    if (o->port && o->port + o->count - 1 > 65535) {
        fprintf(stderr, "slimfarm-sim: --port %d + %d printers passes port 65535\n", o->port,
                o->count);
        return 2;
    }
    return -1;
}

static void
on_stop(struct loop *l, int signo, void *ud)
{
    (void)signo, (void)ud;
    loop_stop(l);
}

void
sim_net_machine(const struct sim_net_opts *o, struct sim_netprinter_config *m)
{
    m->speed = o->speed;
    m->log_path = o->log_path;
    m->uploads_dir = o->uploads_dir;
}

/* The stats line of a face without its own: the machine's state and the requests served. */
static void
default_stats(const struct sim_net_face *face, void *sim, char *out, size_t n)
{
    struct sim_np_status st;
    sim_netprinter_status(face->machine(sim), &st);
    struct sim_ws_hub *hub = face->hub ? face->hub(sim) : NULL;
    snprintf(out, n, "state=%s file=%s lines_done=%llu requests=%llu pushed=%llu",
             sim_np_state_name(st.state), st.file, (unsigned long long)st.lines_done,
             (unsigned long long)sim_http_served(face->http(sim)),
             (unsigned long long)(hub ? sim_ws_hub_sent(hub) : 0));
}

struct serving {
    const struct sim_net_opts *o;
    const struct sim_net_face *face;
    void **sims;
};

/* One stats line per printer on stderr (at exit, and on SIGUSR1: a running count). */
static void
print_stats(const struct serving *sv)
{
    for (int i = 0; i < sv->o->count; i++) {
        char line[512];
        if (!sv->sims[i])
            continue;
        if (sv->face->stats)
            sv->face->stats(sv->sims[i], line, sizeof(line));
        else
            default_stats(sv->face, sv->sims[i], line, sizeof(line));
        if (sv->o->count > 1)
            fprintf(stderr, "stats: printer=%d %s\n", i, line);
        else
            fprintf(stderr, "stats: %s\n", line);
    }
    fflush(stderr);
}

static void
on_usr1(struct loop *l, int signo, void *ud)
{
    (void)l, (void)signo;
    print_stats(ud);
}

int
sim_net_serve(const struct sim_net_opts *o, const struct sim_net_face *face)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    if (!l) {
        fprintf(stderr, "slimfarm-sim: %s\n", err.msg);
        return 1;
    }
    void **sims = mem_calloc((size_t)o->count, sizeof(*sims));
    struct serving sv = { o, face, sims };
    int rc = 1;
    if (!sims || loop_add_signal(l, SIGINT, on_stop, NULL, &err) < 0 ||
        loop_add_signal(l, SIGTERM, on_stop, NULL, &err) < 0 ||
        loop_add_signal(l, SIGUSR1, on_usr1, &sv, &err) < 0) {
        fprintf(stderr, "slimfarm-sim: %s\n", sims ? err.msg : "out of memory");
        goto out;
    }
    signal(SIGPIPE, SIG_IGN);
    for (int i = 0; i < o->count; i++) {
        struct sim_net_opts c = *o;
        char log_path[512], uploads[512];
        if (o->count > 1 && o->log_path) {
            snprintf(log_path, sizeof(log_path), "%s.%d", o->log_path, i);
            c.log_path = log_path;
        }
        if (o->count > 1 && o->uploads_dir) {
            snprintf(uploads, sizeof(uploads), "%s.%d", o->uploads_dir, i);
            c.uploads_dir = uploads;
        }
        if (o->port)
            c.port = o->port + i;
        sims[i] = face->create(l, &c, i, &err);
        if (!sims[i]) {
            fprintf(stderr, "slimfarm-sim: %s printer %d: %s\n", o->kind, i, err.msg);
            goto out;
        }
        if (face->address)
            printf("%s\n", face->address(sims[i]));
        else
            printf("http://127.0.0.1:%d\n", sim_http_port(face->http(sims[i])));
    }
    fflush(stdout);
    rc = loop_run(l) < 0 ? 1 : 0;
    print_stats(&sv);
out:
    for (int i = 0; sims && i < o->count; i++)
        if (sims[i])
            face->destroy(sims[i]);
    free(sims);
    loop_free(l);
    return rc;
}
