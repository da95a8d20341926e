/*
 * drv.c - the driver factory and shared helpers of drv.h.
 *
 * Why: the daemon names a printer kind in its config and gets a struct drv
 * back; only this file knows which kinds exist.  Thread: loop thread,
 * except drv_job_scan and drv_job_scan_to (any thread).
 */
#include "drv.h"

#include <string.h>

#include "drv_marlin.h"

struct drv *
drv_new(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event, void *ud,
        struct sf_err *err)
{
    if (!cfg || !cfg->kind) {
        sf_err_set(err, SF_EINVAL, "printer '%s': no kind given",
                   cfg && cfg->name ? cfg->name : "?");
        return NULL;
    }
    if (strcmp(cfg->kind, "marlin") == 0)
        return drv_marlin_new(l, cfg, on_event, ud, err);
    sf_err_set(err, SF_EUNSUPP, "printer '%s': kind '%s' is not supported (known: marlin)",
               cfg->name ? cfg->name : "?", cfg->kind);
    return NULL;
}

void
drv_free(struct drv *d)
{
    if (!d)
        return;
    d->ops->close(d);
    d->ops->destroy(d);
}

const char *
drv_state_name(enum drv_state s)
{
    switch (s) {
    case DRV_OFFLINE:
        return "offline";
    case DRV_CONNECTING:
        return "connecting";
    case DRV_IDLE:
        return "idle";
    case DRV_PRINTING:
        return "printing";
    case DRV_PAUSED:
        return "paused";
    case DRV_ERROR:
        return "error";
    }
    return "?";
}

int
drv_job_scan(const char *path, struct drv_job_scan *scan, struct sf_err *err)
{
    /* Marlin is the only kind today, and its limits are the tightest a
       driver will have (a numbered, checksummed line in a 96-byte buffer). */
    return drv_marlin_scan(path, scan, err);
}

int
drv_job_scan_to(const char *path, uint64_t first_line, struct drv_job_scan *scan,
                struct sf_err *err)
{
    return drv_marlin_scan_to(path, first_line, scan, err);
}

int
drv_backoff_ms(int attempt)
{
    if (attempt < 0)
        attempt = 0;
    if (attempt > 6)
        return 30000;
    int ms = 500 << attempt;
    return ms > 30000 ? 30000 : ms;
}
