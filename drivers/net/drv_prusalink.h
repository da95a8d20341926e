/*
 * drv_prusalink.h - the Prusa driver, through PrusaLink's v1 HTTP API
 * (behind drv.h): MK4/MK3.9/MK3.5, MINI, XL and CORE One on Buddy
 * firmware, and the MK3 behind the PrusaLink host.  Also the parsers of
 * PrusaLink's replies it is built on.
 *
 * Most callers use drv_new() with kind "prusalink"; this header adds the
 * constructor drv.c calls, and the pure functions that read PrusaLink's
 * JSON, checked against bodies that follow the OpenAPI specification field
 * by field (tests/replay/prusalink/; prusa3d/Prusa-Link-Web spec/openapi.yaml
 * "1.0.0-draft" at commit 337fabbd, 2025-01-13).
 *
 * Thread: loop thread for the driver; the parsers are pure (any thread).
 */
#ifndef SF_DRIVERS_NET_DRV_PRUSALINK_H
#define SF_DRIVERS_NET_DRV_PRUSALINK_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../drv.h"
#include "netjob.h"

/* What GET /api/v1/status says (StatusPrinter, StatusJob, StatusStorage). */
struct prusalink_status {
    char state[16];    /* printer.state: IDLE BUSY PRINTING PAUSED FINISHED STOPPED ERROR
                          ATTENTION READY */
    char message[160]; /* printer.status_printer.message when .ok is false, else "" */
    double nozzle_c, nozzle_target_c; /* printer.temp_nozzle, .target_nozzle */
    double bed_c, bed_target_c;       /* printer.temp_bed, .target_bed */
    bool has_job;                     /* a job object came */
    int64_t job_id;                   /* job.id */
    double progress;                  /* job.progress / 100 */
    int64_t time_remaining_s;         /* job.time_remaining, -1 if not given */
    char storage[32]; /* storage.path without slashes ("usb", "local"); "" if absent */
    bool read_only;   /* storage.read_only */
};

/* What GET /api/v1/job says (Job with JobFilePrint). */
struct prusalink_job {
    int64_t id;      /* id */
    char state[16];  /* state: PRINTING PAUSED FINISHED STOPPED ERROR */
    char name[256];  /* file.display_name (long name), else file.name; "" for a serial print */
    int64_t size;    /* file.size, bytes (0 if not given) */
    double progress; /* progress / 100 */
};

/* Parse /api/v1/status.  SF_EINVAL naming the field when not the documented shape. */
int drv_prusalink_parse_status(const char *body, size_t len, struct prusalink_status *st,
                               struct sf_err *err);

/* Parse /api/v1/job (a 200 body; 204 means no job).  SF_EINVAL. */
int drv_prusalink_parse_job(const char *body, size_t len, struct prusalink_job *job,
                            struct sf_err *err);

/*
 * The printer's words in an error reply: the Error object's "text" (with
 * "title: " before it when both are there), else the plain-text body's
 * first line, else "".  At most n - 1 bytes.  Never fails.
 */
void drv_prusalink_error_text(const char *body, size_t len, char *out, size_t n);

/*
 * Name st in netjob's words; the job is ours when it carries job_id (> 0),
 * or when the printer reports a finished or stopped job without an id.
 */
void drv_prusalink_observe(const struct prusalink_status *st, int64_t job_id, struct netjob_obs *o);

/* The constructor drv.c calls for kind "prusalink". */
struct drv *drv_prusalink_new(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event,
                              void *ud, struct sf_err *err);

#endif
