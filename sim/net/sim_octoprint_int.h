/*
 * sim_octoprint_int.h - internal to the OctoPrint simulator: the state
 * sim_octoprint.c (the REST API, the faults) and sim_octoprint_push.c (the
 * SockJS push socket) share, and the status shapes both send.  Not for
 * other modules.
 *
 * Thread: the loop thread.
 */
#ifndef SF_SIM_NET_SIM_OCTOPRINT_INT_H
#define SF_SIM_NET_SIM_OCTOPRINT_INT_H

#include <jansson.h>
#include <stdbool.h>
#include <stdint.h>

#include "../../src/base/loop.h"
#include "sim_http.h"
#include "sim_netprinter.h"
#include "sim_ws.h"

/* The one user: the API key's, and the session /api/login hands out (the socket's auth). */
#define SIM_OCTO_USER    "slimfarm"
#define SIM_OCTO_SESSION "0123456789abcdef"

struct octo_sim {
    struct sim_netprinter *np;
    struct sim_http *http;
    struct sim_ws_hub *hub; /* the push sockets */
    struct loop *l;
    char address[64];
    long error_at;  /* fault: fail after this many job lines (0: never) */
    long cancel_at; /* fault: cancel at the printer after this many job lines */
    bool busy;      /* fault: the printer says it is busy */
    bool fired;     /* cancel-at done for this job */
    bool err_fired; /* error-at done (once per run: the printer is fixed after) */
    uint64_t tick;  /* fault watch timer */
    uint64_t uploads, jobs;
    const char *api_key; /* the key (the sim's options own it), NULL: none */
    bool was_running;    /* the job ran on the last watch turn */
    int finishing;       /* watch turns left in Finishing */
    double bed_offset_c; /* /api/printer/bed offset */
    /* what the push sockets were last told (sim_octoprint_push.c) */
    enum sim_np_state push_state;
    const char *push_text; /* the state text */
    char push_file[SIM_NP_NAME_MAX + 1];
    uint64_t push_size;
};

/* Watch turns (10 ms each) a completed job shows Finishing. */
#define FINISH_TICKS 30
/* Most files a file list shows. */
#define FILES_MAX 256

/* The state as OctoPrint names it (Operational, Printing, Finishing, ...). */
const char *sim_octoprint_state_text(const struct octo_sim *o, const struct sim_np_status *st);
/* A job is under way (printing, pausing, paused, cancelling). */
bool sim_octoprint_active(const struct sim_np_status *st);
/* /api/printer's state.flags. */
json_t *sim_octoprint_flags(const struct octo_sim *o, const struct sim_np_status *st);
/* /api/job's answer: job, progress, state (and error). */
json_t *sim_octoprint_job(const struct octo_sim *o, const struct sim_np_status *st);

/* sim_octoprint_push.c: the hub (NULL if out of memory), the routes' handlers, and the watch's
   turn (events on state changes, current every 500 ms). */
struct sim_ws_hub *sim_octoprint_push_hub(struct octo_sim *o);
void sim_octoprint_on_sockjs(struct sim_http_req *r, void *ud);
void sim_octoprint_on_sockjs_info(struct sim_http_req *r, void *ud);
void sim_octoprint_push_watch(struct octo_sim *o, const struct sim_np_status *st);

#endif
