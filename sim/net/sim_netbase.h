/*
 * sim_netbase.h - the body the HTTP printer simulators share (Moonraker,
 * PrusaLink): a machine (sim_netprinter.h), the HTTP server in front of it
 * (sim_http.h) keeping its uploads in the machine's folder, and a watch
 * timer on which the simulator fires its line-triggered faults; and the
 * reading of those faults' "name=N" specs.
 *
 * A simulator embeds struct sim_netbase as its first member (as a driver
 * embeds struct drv), so one pointer is both: sim_netbase_free() frees any
 * of them, and sim_netbase_main() serves any of them on the command line
 * (sim_netcli.h).  What differs stays with each simulator: its routes and
 * words, its auth, its own faults and what the watch does.
 *
 * Why: sim_moonraker.c and sim_prusalink.c each had their own copy of
 * creation, port, status, teardown, fault counts and the command-line face
 * (the `duplicates` tool's largest pair in sim/).
 *
 * Thread: the loop thread (sim_netbase_main: the main thread, which runs
 * that loop).  Owns the machine, the server and the timer.
 */
#ifndef SF_SIM_NET_SIM_NETBASE_H
#define SF_SIM_NET_SIM_NETBASE_H

#include <stddef.h>
#include <stdint.h>

#include "../../src/base/err.h"
#include "../../src/base/loop.h"
#include "sim_http.h"
#include "sim_netcli.h"
#include "sim_netprinter.h"
#include "sim_ws.h"

/* Called on each watch tick with the server's ud (the simulator). */
typedef void (*sim_netbase_watch_fn)(void *ud);

struct sim_netbase {
    struct loop *l;                /* the loop everything runs on */
    struct sim_netprinter *np;     /* the machine, NULL until made */
    struct sim_http *http;         /* its HTTP API, NULL until made */
    uint64_t watch;                /* watch timer, 0 if none */
    int watch_ms;                  /* its period */
    sim_netbase_watch_fn on_watch; /* what it calls */
    void *ud;                      /* with what (hc->ud) */
    struct sim_ws_hub *hub;        /* push sockets the face opened (NULL: none); freed first */
};

/* A zeroed simulator of size bytes (its struct, sim_netbase first), or NULL with err set
   ("KIND sim: out of memory").  Free with sim_netbase_free(). */
void *sim_netbase_alloc(size_t size, const char *kind, struct sf_err *err);

/*
 * Start, on loop l, the machine of config machine, then the HTTP server of
 * hc (its upload_dir set to the machine's folder), then a timer that calls
 * on_watch(hc->ud) every watch_ms.  On failure returns the error with err
 * set, b holding what was made: sim_netbase_release() frees it either way.
 */
int sim_netbase_init(struct sim_netbase *b, struct loop *l,
                     const struct sim_netprinter_config *machine, struct sim_http_config *hc,
                     int watch_ms, sim_netbase_watch_fn on_watch, struct sf_err *err);
/* Stop the timer, close the push sockets, free the server and the machine (flushing its log);
   zeroed b is fine. */
void sim_netbase_release(struct sim_netbase *b);
/* Release a simulator from sim_netbase_alloc() and free it.  NULL is fine. */
void sim_netbase_free(void *sim);

/* The port the server listens on. */
int sim_netbase_port(const struct sim_netbase *b);

/* The machine's status. */
void sim_netbase_status(const struct sim_netbase *b, struct sim_np_status *out);

/*
 * `slimfarm-sim KIND ...` for a simulator built on sim_netbase: parse argv
 * (sim_net_parse, usage plus extra), then serve the printers create makes,
 * each freed with sim_netbase_free, addressed and counted through their
 * server and machine (sim_net_serve).  The process exit status.
 */
int sim_netbase_main(int argc, char **argv, const char *extra,
                     void *(*create)(struct loop *l, const struct sim_net_opts *o, int index,
                                     struct sf_err *err));

/*
 * The value of a fault spec "name=value" whose name is name ("" for a bare
 * "name"), or NULL if spec names another fault.
 */
const char *sim_netbase_fault_arg(const char *spec, const char *name);
/* Parse v, the value of spec, as a whole number from 1 into *out.  SF_EINVAL naming spec. */
int sim_netbase_fault_count(const char *spec, const char *v, long *out, struct sf_err *err);

#endif
