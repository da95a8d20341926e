/*
 * drv_moonraker_int.h - internal to the Moonraker driver: its state, which
 * drv_moonraker.c (the HTTP side) and drv_moonraker_ws.c (the push socket)
 * share.  Not for other modules.
 *
 * How it talks: netdrv.h's core (one request at a time, polls on a timer
 * that actions pre-empt, a short outage ridden out with a job on the
 * printer, a longer one offline with the job left to attach()), over
 * Moonraker: GET /server/info until Klippy is ready (every 2 s while it
 * starts, as the docs ask), then GET /printer/objects/query every
 * MR_POLL_MS (the rate Moonraker's docs give simple polling clients: "1
 * to 2 seconds"); the upload is POST /server/files/upload with print=true
 * (multipart, the file streamed from disk), /printer/print/start by name
 * if the printer stored it without starting; pause, resume and cancel are
 * POST /printer/print/...; manual commands POST /printer/gcode/script.
 *
 * Once a poll has answered, the driver opens Moonraker's websocket
 * (drv_moonraker_ws.c) and subscribes to the same objects; while that
 * subscription stands, its updates take the polls' place (the timer
 * stops; a poll is still made at once after each action, to confirm it,
 * as before).  An update that comes while a request holds the slot waits
 * for the slot to free, so no update is judged in the middle of an
 * upload or an action.  When the socket closes, goes silent, or the
 * printer's Klippy restarts, polling takes over at once and the socket is
 * tried again later (netpush.h: the lifecycle the OctoPrint driver shares).
 * Deltas are not missed: they come in order over one TCP stream, and a
 * new socket starts from the subscription's full snapshot.
 *
 * Thread: the loop thread.
 */
#ifndef SF_DRIVERS_NET_DRV_MOONRAKER_INT_H
#define SF_DRIVERS_NET_DRV_MOONRAKER_INT_H

#include <jansson.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "drv_moonraker.h"
#include "netdrv.h"
#include "netpush.h"

#define MR_POLL_MS    1000 /* drv_config.poll_ms 0 */
#define MR_STARTUP_MS 2000 /* docs: ask /server/info again after 2 s while Klippy starts */
#define MR_SCRIPT_MAX 4096 /* manual commands waiting to be sent */

enum { RQ_START = NETDRV_RQ_OWN, RQ_GCODE, RQ_META, RQ_HISTORY, RQ_ESTOP };

/* attach()'s look-up, in Moonraker's job history, of a job print_stats no longer shows */
enum hist_state { H_NONE, H_ASKING, H_ANSWERED };

struct moonraker {
    struct netdrv n;
    const char *json_hdrs[3];     /* the key (if any), Content-Type: application/json, NULL */
    const char *hdrs[2];          /* the key (if any), NULL */
    bool ready;                   /* Klippy answered /server/info: poll the objects */
    struct moonraker_status last; /* the last poll's answer (attach reads it) */
    char script[MR_SCRIPT_MAX];   /* manual commands waiting, '\n'-separated */
    size_t script_len;
    bool want_estop; /* an emergency stop waits for the slot (before all else) */
    /* the job file's metadata (its slicer's time estimate; its upload time) */
    char meta_name[160]; /* the file asked about ("" none) */
    bool meta_known;     /* answered (meta_found: the printer has the file) */
    bool meta_found;
    bool want_meta;             /* ask when the slot frees */
    struct moonraker_meta meta; /* the answer */
    enum hist_state hist_state; /* the history look-up of hist_name */
    char hist_name[160];
    struct moonraker_hist hist; /* its answer (H_ANSWERED) */
    char hist_why[200];         /* why the look-up could not tell, "" if it could */
    /* the push socket (drv_moonraker_ws.c) */
    struct netpush push;
    json_t *ws_status; /* the objects as the socket told them */
    bool ws_held;      /* the socket waits for Klippy to be ready again (hold) */
};

/* The status st seen (by a poll, or pushed by the socket): judge and report it. */
void drv_moonraker_seen(struct moonraker *m, const struct moonraker_status *st, bool pushed);

/* Open the push socket, to ip (the address the poll reached; NULL: the URL's host), if there is
   none and its backoff has passed. */
void drv_moonraker_ws_open(struct moonraker *m, const char *ip);
/* Close it (why: logged, then polling takes over at once; NULL: quietly, the caller polls). */
void drv_moonraker_ws_close(struct moonraker *m, const char *why);
/* Judge what the socket said last, if it is new and the slot is free. */
void drv_moonraker_ws_apply(struct moonraker *m);
/* The polls saw Klippy ready: a socket still held subscribes again (it missed
   notify_klippy_ready). */
void drv_moonraker_ws_klippy_ready(struct moonraker *m);

#endif
