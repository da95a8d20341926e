/*
 * sim_netcli.h - the command line every network printer simulator shares:
 * `slimfarm-sim KIND --port N [--api-key K] [--user U --password P]
 * [--speed X] [--log FILE] [--uploads DIR] [--fault SPEC]... [--count N]`.
 *
 * A simulator's main (sim_octoprint_main, ...) parses with
 * sim_net_parse() and hands a face (new/address/free) to sim_net_serve(),
 * which starts --count printers on one loop, prints one address line per
 * printer ("http://127.0.0.1:PORT"), serves until SIGINT/SIGTERM and
 * prints one "stats:" line each on stderr (so does SIGUSR1, running on).  With --count N > 1,
 * --port P becomes P+i, --log FILE and --uploads DIR get a ".i" suffix.
 *
 * Fault specs are kept as given: each face applies them (its own faults,
 * then sim_http_fault_parse, then faults_parse for the firmware) and
 * refuses an unknown one.
 *
 * Thread: main thread.
 */
#ifndef SF_SIM_NET_SIM_NETCLI_H
#define SF_SIM_NET_SIM_NETCLI_H

#include <stdbool.h>
#include <stddef.h>

#include "../../src/base/err.h"
#include "../../src/base/loop.h"

#define SIM_NET_FAULTS_MAX 32
/* Printers one process may serve (the 50-printer bench and some room). */
#define SIM_NET_COUNT_MAX 256

struct sim_ws_hub;

struct sim_net_opts {
    const char *kind;                       /* "octoprint", ... (argv[1]) */
    int port;                               /* --port (0: any free port) */
    const char *api_key;                    /* --api-key, or NULL */
    const char *user;                       /* --user (digest), or NULL */
    const char *password;                   /* --password */
    double speed;                           /* --speed (default 1) */
    const char *log_path;                   /* --log, or NULL */
    const char *uploads_dir;                /* --uploads, or NULL (a temporary directory) */
    int count;                              /* --count (default 1) */
    const char *faults[SIM_NET_FAULTS_MAX]; /* --fault specs, in order */
    int n_faults;
};

struct sim_netprinter;
struct sim_netprinter_config;
struct sim_http;

/* One printer of the instance i: paths and port already suffixed. */
struct sim_net_face {
    void *(*create)(struct loop *l, const struct sim_net_opts *o, int index, struct sf_err *err);
    const char *(*address)(void *sim);             /* "http://127.0.0.1:PORT"; NULL: from http */
    void (*stats)(void *sim, char *out, size_t n); /* one line, without "stats: "; NULL: the
                                                      machine's state, file, lines, requests */
    void (*destroy)(void *sim);
    /* For address and stats left NULL: the sim's machine and HTTP side. */
    struct sim_netprinter *(*machine)(void *sim);
    struct sim_http *(*http)(void *sim);
    struct sim_ws_hub *(*hub)(void *sim); /* its push sockets (stats: pushed=); NULL: none */
};

/* The machine options every face takes from o: speed, --log, --uploads. */
void sim_net_machine(const struct sim_net_opts *o, struct sim_netprinter_config *m);

/*
 * Parse argv[2..] into o.  Prints usage (extra: the face's own lines) and
 * returns 0 for --help, 2 on a usage error, -1 to go on.
 */
int sim_net_parse(int argc, char **argv, struct sim_net_opts *o, const char *extra);

/* Serve o->count printers of face until a signal; the process exit status. */
int sim_net_serve(const struct sim_net_opts *o, const struct sim_net_face *face);

#endif
