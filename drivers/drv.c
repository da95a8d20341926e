/*
 * drv.c - the driver factory of drv.h: the registry of driver kinds.
 *
 * Why: the daemon names a printer kind in its config and gets a struct drv
 * back; only this file knows which kinds exist (the registry below, which
 * the config parser asks too).  Nothing else lives here, on purpose: a
 * program that links this file links every driver (and their libraries,
 * libcurl and jansson for the network ones), so the helpers every driver
 * shares sit in drv_util.c, and a Marlin-only tool (slimfarm send) calls
 * drv_marlin_new without the registry.  Thread: loop thread.
 */
#include "drv.h"

#include <stdio.h>
#include <string.h>

#include "bambu/drv_bambu.h"
#include "marlin/drv_marlin.h"
#include "net/drv_moonraker.h"
#include "net/drv_octoprint.h"
#include "net/drv_prusalink.h"

/* Every kind this build has; a new driver is one row here. */
static const struct drv_kind kinds[] = {
    { "marlin", false, DRV_AUTH_NONE, NULL, drv_marlin_new },
    { "octoprint", true, DRV_AUTH_KEY, "http https", drv_octoprint_new },
    { "moonraker", true, DRV_AUTH_KEY_OPTIONAL, "http https", drv_moonraker_new },
    { "prusalink", true, DRV_AUTH_KEY_OR_DIGEST, "http https", drv_prusalink_new },
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
