/*
 * sim_prusalink.h - a simulated Prusa printer (MK4 on Buddy firmware)
 * behind PrusaLink: the v1 HTTP API of the OpenAPI specification
 * (prusa3d/Prusa-Link-Web spec/openapi.yaml, 1.0.0-draft) over the machine
 * of sim_netprinter.h.
 *
 * What it speaks: GET /api/version, GET /api/v1/info, GET /api/v1/status
 * (printer, job, storage), GET /api/v1/job (204 without a job), PUT
 * /api/v1/files/usb/{name} (the raw body; Print-After-Upload and Overwrite
 * as RFC 8941 booleans "?1"/"?0"; 201, or 409 when the file exists and may
 * not be overwritten, is being printed, or the printer is busy), HEAD and
 * POST (print) and DELETE of /api/v1/files/usb/{name}, PUT
 * /api/v1/job/{id}/pause|resume and DELETE /api/v1/job/{id} (204, 404 for
 * an old id, 409 when the state does not allow it).  Errors are the spec's
 * Error object when the client sends Accept: application/json, else
 * text/plain.  Authentication: X-Api-Key (401 when wrong), or HTTP Digest
 * (user and password, realm "Printer API") as current firmware does.
 *
 * Faults of its own (sim_prusalink_fault_parse), besides sim_http's and
 * the firmware's:
 *   busy=N        the next N uploads meet a busy printer: 409 "Printer is busy"
 *   error=L       the printer goes to ERROR at line L of a job
 *   cancel=L      the job is stopped at the printer at line L (STOPPED)
 *   dismiss=1     an ended job's screen is dismissed at once: the printer is
 *                 IDLE with no job as soon as a print ends (FINISHED and
 *                 STOPPED are never shown; v1 keeps no record of the job)
 *
 * Thread: the loop thread.  Owns its HTTP server and machine.
 */
#ifndef SF_SIM_NET_SIM_PRUSALINK_H
#define SF_SIM_NET_SIM_PRUSALINK_H

#include <stdbool.h>
#include <stdint.h>

#include "../../src/base/err.h"
#include "../../src/base/loop.h"
#include "sim_http.h"
#include "sim_netprinter.h"

struct sim_prusalink_config {
    int port;                             /* 0: any free loopback port */
    const char *api_key;                  /* X-Api-Key, or NULL */
    const char *user;                     /* HTTP Digest user (with password), or NULL */
    const char *password;                 /* its password */
    struct sim_netprinter_config machine; /* speed, log, firmware faults */
    struct sim_http_faults http;          /* 5xx, slow, drops */
    long busy_uploads;                    /* busy=N */
    long error_at;                        /* error=L (0: never) */
    long cancel_at;                       /* cancel=L (0: never) */
    long dismiss;                         /* dismiss=1 */
};

/* Defaults: any port, no auth, sim_netprinter_config_init, no faults. */
void sim_prusalink_config_init(struct sim_prusalink_config *c);

/* Apply one --fault spec (HTTP, the printer's above, or firmware).  SF_EINVAL naming it. */
int sim_prusalink_fault_parse(struct sim_prusalink_config *c, const char *spec, struct sf_err *err);

struct sim_prusalink;

/* Start on loop l.  NULL with err set. */
struct sim_prusalink *sim_prusalink_new(struct loop *l, const struct sim_prusalink_config *c,
                                        struct sf_err *err);
int sim_prusalink_port(const struct sim_prusalink *s);
void sim_prusalink_status(const struct sim_prusalink *s, struct sim_np_status *out);
/* Stop, flush the log, free.  NULL is fine. */
void sim_prusalink_free(struct sim_prusalink *s);

/* `slimfarm-sim prusalink ...` (argv[1] is "prusalink"; sim_netcli.h's options): serve until a
 * signal. */
int sim_prusalink_main(int argc, char **argv);

#endif
