/*
 * drv_marlin.h - the Marlin USB-serial driver (behind drv.h).
 *
 * Most callers use drv_new() with kind "marlin"; this header adds the
 * constructor drv.c calls and counters for tests and benchmarks.
 *
 * Thread: loop thread, except drv_marlin_scan (any thread).
 */
#ifndef SF_DRIVERS_MARLIN_DRV_MARLIN_H
#define SF_DRIVERS_MARLIN_DRV_MARLIN_H

#include <stdint.h>

#include "../drv.h"

struct drv_marlin_stats {
    uint64_t lines_sent; /* numbered lines written, resends included */
    uint64_t bytes_sent; /* bytes written */
    uint64_t rewinds;    /* Resend requests acted on */
    uint64_t probes;     /* numbered M105 probes (after a garbled reply or a silence) */
    uint64_t deadlines;  /* silences longer than what was in flight could take */
    int64_t lost_ms;     /* time spent waiting out those silences */
    uint64_t host_lines; /* numbered lines the driver added (park, resume, end, M400, M105) */
    uint64_t renumbers;  /* M110s that skipped line numbers near M108/M112/M410 */
    int window;          /* lines in flight now allowed */
};

struct drv *drv_marlin_new(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event,
                           void *ud, struct sf_err *err);

/*
 * drv_job_scan() for Marlin: count the command lines of the job file at
 * path and check each fits a numbered, checksummed Marlin line.  SF_EINVAL
 * naming 'path':line, SF_EIO.  Pure, any thread.
 */
int drv_marlin_scan(const char *path, struct drv_job_scan *out, struct sf_err *err);
/* drv_job_scan_to() for Marlin.  Pure, any thread. */
int drv_marlin_scan_to(const char *path, uint64_t first_line, struct drv_job_scan *scan,
                       struct sf_err *err);

/* Counters; false if d is not a Marlin driver. */
bool drv_marlin_stats(const struct drv *d, struct drv_marlin_stats *out);

#endif
