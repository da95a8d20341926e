/*
 * drv_octoprint.h - the OctoPrint driver: a printer behind OctoPrint's REST
 * API (docs.octoprint.org, API as of 1.10/1.11), over httpc.h.
 *
 * What it does: connects with GET /api/version (the reply must carry
 * "api", and a "text" starting with "OctoPrint") and a first poll; polls
 * GET /api/job, then GET /api/printer, every poll_ms (netdrv.h's core: one
 * request at a time, actions pre-empt a poll); uploads the job's
 * G-code streamed from disk as multipart POST /api/files/local with
 * print=true under drv_remote_name() (and, when OctoPrint does not start
 * it, POST /api/files/local/NAME select+print); pauses, resumes and
 * cancels with POST /api/job; sends manual commands with POST
 * /api/printer/command; re-attaches (drv.h attach) to a print that went on
 * while the daemon was down.  Where it can, it logs in passively (POST
 * /api/login) and reads OctoPrint's push socket (/sockjs/websocket) in
 * place of the status polls while that stands (drv_octoprint_int.h).
 *
 * Remote states: Operational -> DRV_IDLE; Printing, Cancelling, Starting,
 * Resuming, Finishing -> DRV_PRINTING; Pausing, Paused -> DRV_PAUSED;
 * Error, Offline after error -> DRV_ERROR; Offline, Closed, Connecting ->
 * DRV_OFFLINE (OctoPrint answers, its printer does not).  Our job ends
 * DONE when OctoPrint is Operational again at 100 %, FAILED when it stopped
 * short (cancelled at the printer, an error, the printer lost, the file
 * gone), CANCELLED when we cancelled it.  HTTP 401/403 -> "authentication
 * failed (check api_key)"; 409 -> OctoPrint's reason; 5xx, timeouts and
 * refused connections -> DRV_OFFLINE (the farm reconnects with
 * drv_backoff_ms; a job on the printer is re-attached on reconnect).
 * lines_acked is estimated from OctoPrint's file position (OctoPrint counts
 * bytes, not lines).  Resuming mid-file (start_job first_line > 0) is not
 * supported: SF_EUNSUPP.
 *
 * The reply parsers are exposed for the replay tests and the fuzz target.
 *
 * Thread: the loop thread (drv.h).
 */
#ifndef SF_DRIVERS_NET_DRV_OCTOPRINT_H
#define SF_DRIVERS_NET_DRV_OCTOPRINT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../../src/base/err.h"
#include "../drv.h"

/* drv_kind create function for "octoprint" (drv.c's registry). */
struct drv *drv_octoprint_new(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event,
                              void *ud, struct sf_err *err);

/* What OctoPrint's state text says, in our words. */
enum octo_remote {
    OCTO_R_UNKNOWN = 0, /* a text we do not know: treated as busy */
    OCTO_R_IDLE,        /* Operational */
    OCTO_R_PRINTING,    /* Printing, Starting, Resuming, Finishing, Sending file to SD */
    OCTO_R_PAUSED,      /* Paused, Pausing (the pause taking effect) */
    OCTO_R_CANCELLING,  /* Cancelling */
    OCTO_R_ERROR,       /* Error, Offline after error */
    OCTO_R_OFFLINE,     /* Offline, Closed, Opening serial connection, Connecting, Detecting */
};
enum octo_remote octo_classify(const char *state_text);

/* GET /api/job, as far as we read it.  Absent or null numbers are -1. */
struct octo_job {
    char state[64];      /* "state" */
    char file[256];      /* job.file.name ("" when null) */
    int64_t size;        /* job.file.size */
    double completion;   /* progress.completion, percent */
    int64_t filepos;     /* progress.filepos, bytes */
    double print_time_s; /* progress.printTime */
    double time_left_s;  /* progress.printTimeLeft */
    char error[160];     /* "error", "" if none */
};
int octo_parse_job(const char *body, size_t len, struct octo_job *out, struct sf_err *err);

/* GET /api/printer, as far as we read it.  Absent temperatures are -1. */
struct octo_printer {
    char state[64];                                             /* state.text */
    bool operational, printing, paused, error, closed_or_error; /* state.flags */
    double tool_c, tool_target_c, bed_c, bed_target_c;          /* temperature */
};
int octo_parse_printer(const char *body, size_t len, struct octo_printer *out, struct sf_err *err);

/* GET /api/version: OctoPrint's "text" into text; SF_EINVAL if this is no OctoPrint. */
int octo_parse_version(const char *body, size_t len, char *text, size_t n, struct sf_err *err);

/* The 201 of POST /api/files/local: effectivePrint and the stored name. */
int octo_parse_upload(const char *body, size_t len, bool *effective_print, char *name, size_t n,
                      struct sf_err *err);

/* An error reply's reason: {"error": ...}, else the body's first line; "" if none. */
void octo_reason(const char *body, size_t len, char *out, size_t n);

#endif
