/*
 * drv_util.c - the helpers of drv.h that every driver shares: drv_free,
 * state names, the job file scan (gcheck.h by the rules every kind names),
 * remote file names, the reconnect policy.
 *
 * Apart from the registry (drv.c) so that a driver, or a tool using one
 * driver, links these without linking every other driver.  Thread: loop
 * thread, except drv_job_scan, drv_job_scan_to and drv_remote_name (any
 * thread).
 */
#include "drv.h"

#include <stdio.h>
#include <string.h>

#include "gcheck.h"

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
    return gcheck_scan(DRV_JOB_RULES, path, scan, err);
}

int
drv_job_scan_to(const char *path, uint64_t first_line, struct drv_job_scan *scan,
                struct sf_err *err)
{
    return gcheck_scan_to(DRV_JOB_RULES, path, first_line, scan, err);
}

void
drv_remote_name(const char *gcode_path, char *out, size_t n)
{
    const char *base = strrchr(gcode_path, '/');
    base = base ? base + 1 : gcode_path;
    size_t len = strlen(base);
    if (len > 6 && strcmp(base + len - 6, ".gcode") == 0)
        len -= 6;
    char clean[65];
    size_t k = 0;
    for (size_t i = 0; i < len && k < 64; i++) {
        char c = base[i];
        bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                  c == '-' || c == '_' || (c == '.' && k > 0);
        clean[k++] = ok ? c : '_';
    }
    clean[k] = 0;
    snprintf(out, n, "sf-%s.gcode", k ? clean : "job");
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
