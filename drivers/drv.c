/*
 * drv.c - the driver factory and shared helpers of drv.h.
 *
 * Why: the daemon names a printer kind in its config and gets a struct drv
 * back; only this file knows which kinds exist (the registry below, which
 * the config parser asks too).  Thread: loop thread,
 * except drv_job_scan and drv_job_scan_to (any thread).
 */
#include "drv.h"

#include <stdio.h>
#include <string.h>

#include "drv_bambu.h"
#include "drv_marlin.h"
#include "drv_octoprint.h"

/* Every kind this build has; a new driver is one row here. */
static const struct drv_kind kinds[] = {
    { "marlin", false, DRV_AUTH_NONE, NULL, drv_marlin_new },
    { "octoprint", true, DRV_AUTH_KEY, "http https", drv_octoprint_new },
    { "bambu", true, DRV_AUTH_NONE, "mqtts", drv_bambu_new },
};
#define N_KINDS (sizeof(kinds) / sizeof(kinds[0]))

const struct drv_kind *
drv_kind_find(const char *name)
{
    for (size_t i = 0; name && i < N_KINDS; i++)
        if (strcmp(kinds[i].name, name) == 0)
            return &kinds[i];
    return NULL;
}

const struct drv_kind *
drv_kind_at(size_t i)
{
    return i < N_KINDS ? &kinds[i] : NULL;
}

struct drv *
drv_new(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event, void *ud,
        struct sf_err *err)
{
    if (!cfg || !cfg->kind) {
        sf_err_set(err, SF_EINVAL, "printer '%s': no kind given",
                   cfg && cfg->name ? cfg->name : "?");
        return NULL;
    }
    const struct drv_kind *k = drv_kind_find(cfg->kind);
    if (k)
        return k->create(l, cfg, on_event, ud, err);
    char known[128] = "";
    for (size_t i = 0, n = 0; i < N_KINDS; i++)
        n += (size_t)snprintf(known + n, n < sizeof(known) ? sizeof(known) - n : 0, "%s%s",
                              i ? ", " : "", kinds[i].name);
    sf_err_set(err, SF_EUNSUPP, "printer '%s': kind '%s' is not supported (known: %s)",
               cfg->name ? cfg->name : "?", cfg->kind, known);
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
