/*
 * sim_moonraker.h - a simulated Klipper printer behind Moonraker: the HTTP
 * API of Moonraker (docs/external_api/ server, printer and file_manager
 * pages, v0.10) over the machine of sim_netprinter.h.
 *
 * What it speaks, as Moonraker does: GET /server/info (klippy_state),
 * GET /printer/info, GET or POST /printer/objects/query (webhooks,
 * print_stats, virtual_sdcard, extruder, heater_bed, display_status;
 * a GET with a query string returns every one of them, the POST body's
 * "objects" picks), POST /server/files/upload (multipart: file, root,
 * path, print; 201 with item, print_started, print_queued, action and a
 * Location header; 403 "File is loaded, upload not permitted" over the
 * file being printed), GET /server/files/metadata, POST
 * /printer/print/start|pause|resume|cancel, POST /printer/gcode/script,
 * POST /printer/emergency_stop and /printer/firmware_restart.  Replies
 * are {"result": ...} (the upload's bare), errors {"error": {"code",
 * "message"}}, a wrong X-Api-Key 401 {"error": {"code": 401, "message":
 * "Unauthorized"}}.
 *
 * Faults of its own (sim_moonraker_fault_parse), besides sim_http's (5xx,
 * slow, drop, drop-upload) and the firmware's (faults.h):
 *   shutdown=L    Klippy shuts down when a job has L lines done
 *                 ("MCU 'mcu' shutdown: Timer too close"); firmware_restart clears it
 *   error=L       the job ends in print_stats "error" at line L (Klippy stays ready)
 *   cancel=L      the job is cancelled at the printer at line L
 *   startup=MS    Klippy is in "startup" for its first MS milliseconds
 *   miss-ready=N  the sockets are not told the first N times Klippy is ready
 *                 again (notify_klippy_ready lost: a client must see it
 *                 some other way, /server/info)
 *
 * Thread: the loop thread.  Owns its HTTP server and machine.
 */
#ifndef SF_SIM_NET_SIM_MOONRAKER_H
#define SF_SIM_NET_SIM_MOONRAKER_H

#include <stdbool.h>
#include <stdint.h>

#include "../../src/base/err.h"
#include "../../src/base/loop.h"
#include "sim_http.h"
#include "sim_netprinter.h"

struct sim_moonraker_config {
    int port;                             /* 0: any free loopback port */
    const char *api_key;                  /* NULL: trusted client, no key asked */
    struct sim_netprinter_config machine; /* speed, log, firmware faults */
    struct sim_http_faults http;          /* 5xx, slow, drops */
    long shutdown_at;                     /* shutdown=L (0: never) */
    long error_at;                        /* error=L (0: never) */
    long cancel_at;                       /* cancel=L (0: never) */
    int startup_ms;                       /* startup=MS */
    long miss_ready;                      /* miss-ready=N (0: none) */
};

/* Defaults: any port, no key, sim_netprinter_config_init, no faults. */
void sim_moonraker_config_init(struct sim_moonraker_config *c);

/*
 * Apply one --fault spec: an HTTP fault (sim_http_fault_parse), one of the
 * printer's above, or a firmware fault (faults_parse).  SF_EINVAL naming it.
 */
int sim_moonraker_fault_parse(struct sim_moonraker_config *c, const char *spec, struct sf_err *err);

struct sim_moonraker;

/* Start on loop l.  NULL with err set. */
struct sim_moonraker *sim_moonraker_new(struct loop *l, const struct sim_moonraker_config *c,
                                        struct sf_err *err);
/* The port it listens on. */
int sim_moonraker_port(const struct sim_moonraker *s);
/* The machine's status (tests). */
void sim_moonraker_status(const struct sim_moonraker *s, struct sim_np_status *out);
/* Status queries answered over HTTP, and websockets holding a subscription (tests). */
uint64_t sim_moonraker_queries(const struct sim_moonraker *s);
int sim_moonraker_subscribed(struct sim_moonraker *s);
/* Websocket connections opened so far (tests). */
int sim_moonraker_ws_opened(const struct sim_moonraker *s);
/* A firmware restart, as POST /printer/firmware_restart does it (tests). */
void sim_moonraker_firmware_restart(struct sim_moonraker *s);
/* Close every websocket (a network blip; tests). */
void sim_moonraker_drop_sockets(struct sim_moonraker *s);
/* Stop, flush the log, free.  NULL is fine. */
void sim_moonraker_free(struct sim_moonraker *s);

/* `slimfarm-sim moonraker ...` (argv[1] is "moonraker"; sim_netcli.h's options): serve until a
 * signal. */
int sim_moonraker_main(int argc, char **argv);

#endif
