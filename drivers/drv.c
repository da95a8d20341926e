/*
 * drv.c - the driver factory of drv.h: the registry of driver kinds.
 *
 * Why: the daemon names a printer kind in its config and gets a struct drv
 * back; only this file knows which kinds exist (the registry below, which
 * the config parser asks too), which link options each takes (their
 * tables, drv_link.h), its own rules over them, and which G-code rules its
 * jobs pass (gcheck.h).  Nothing else lives here, on purpose: a program
 * that links this file links every driver (and their libraries, libcurl
 * and jansson for the network ones), so the helpers every driver shares
 * sit in drv_util.c, and a Marlin-only tool (slimfarm send) calls
 * drv_marlin_new without the registry.  Thread: loop thread (the tables:
 * any).
 */
#include "drv.h"

#include <stddef.h>
#include <stdio.h>
#include <string.h>

#include "bambu/drv_bambu.h"
#include "drv_link.h"
#include "marlin/drv_marlin.h"
#include "net/drv_moonraker.h"
#include "net/drv_octoprint.h"
#include "net/drv_prusalink.h"

#define CFG(field) offsetof(struct drv_config, field)

/*
 * The link options, one table per group of kinds that take them (kinds
 * list the tables they take).  Sizes, ranges and defaults are the config's
 * (config/farm.ini documents each option).  No option is DRV_OPT_LIVE:
 * every driver reads its config once, at creation, so a change reconnects.
 */
static const struct drv_option serial_options[] = {
    { "port", DRV_OPT_STR, CFG(port), 256, 0, 0, 0, NULL, DRV_OPT_REQUIRED },
    { "baud", DRV_OPT_INT, CFG(baud), 0, 1200, 4000000, 115200, NULL, 0 },
    { "buffer_lines", DRV_OPT_INT, CFG(buffer_lines), 0, 1, 32, 4, NULL, 0 },
    { "rx_buffer", DRV_OPT_INT, CFG(rx_buffer), 0, 64, 65536, 128, NULL, 0 },
    { NULL },
};

/* Every network kind: where, and the key. */
static const struct drv_option net_options[] = {
    { "url", DRV_OPT_URL, CFG(url), 256, 0, 0, 0, NULL, DRV_OPT_REQUIRED },
    { "api_key", DRV_OPT_STR, CFG(api_key), 128, 0, 0, 0, NULL, DRV_OPT_SECRET },
    { NULL },
};

/* HTTP kinds that poll the printer's status: fast while it works, slow while it waits. */
static const struct drv_option poll_options[] = {
    { "poll_ms", DRV_OPT_INT, CFG(poll_ms), 0, 200, 60000, 1000, NULL, 0 },
    { "poll_idle_ms", DRV_OPT_INT, CFG(poll_idle_ms), 0, 200, 600000, 5000, NULL, 0 },
    { NULL },
};

/* HTTP kinds with a push socket: it replaces the polls unless turned off. */
static const struct drv_option push_options[] = {
    { "poll_only", DRV_OPT_BOOL, CFG(poll_only), 0, 0, 0, 0, NULL, 0 },
    { NULL },
};

/* HTTP Digest instead of a key. */
static const struct drv_option digest_options[] = {
    { "user", DRV_OPT_STR, CFG(user), 64, 0, 0, 0, NULL, 0 },
    { "password", DRV_OPT_STR, CFG(password), 128, 0, 0, 0, NULL, DRV_OPT_SECRET },
    { NULL },
};

/* Bambu Lab in LAN mode: MQTT over TLS and FTPS. */
static const struct drv_option bambu_options[] = {
    /* the printer's IP: url is mqtts://HOST unless url is given */
    { "host", DRV_OPT_STR, CFG(url), 128, 0, 0, 0, "mqtts://", DRV_OPT_FALLBACK },
    /* the LAN access code, api_key by its Bambu name */
    { "access_code", DRV_OPT_STR, CFG(api_key), 128, 0, 0, 0, NULL, DRV_OPT_SECRET },
    { "serial", DRV_OPT_IDENT, CFG(serial), 48, 0, 0, 0, NULL, 0 },
    { "ca_file", DRV_OPT_PATH, CFG(ca_file), 256, 0, 0, 0, NULL, 0 },
    { "tls_insecure", DRV_OPT_BOOL, CFG(tls_insecure), 0, 0, 0, 0, NULL, 0 },
    /* 0 (not given): the driver's 990 */
    { "ftps_port", DRV_OPT_INT, CFG(ftps_port), 0, 1, 65535, 0, NULL, 0 },
    { NULL },
};

/* Bambu's own rules: the serial names the device and its certificate; trust needs a CA. */
static int
bambu_check(const struct drv_config *cfg, char *why, size_t n)
{
    if (!cfg->serial[0] || !cfg->api_key[0]) {
        snprintf(why, n, "options 'serial' and 'access_code' are required by driver bambu");
        return -1;
    }
    if (!cfg->ca_file[0] && !cfg->tls_insecure) {
        snprintf(why, n,
                 "option 'ca_file' is required by driver bambu (or tls_insecure: true, which "
                 "checks no certificate)");
        return -1;
    }
    return 0;
}

/* Every kind this build has; a new driver is one row here (and its options, if new). */
static const struct drv_kind kinds[] = {
    { .name = "marlin",
      .create = drv_marlin_new,
      .options = { serial_options },
      .gcode = GCHECK_MARLIN },
    { .name = "octoprint",
      .url = true,
      .auth = DRV_AUTH_KEY,
      .schemes = "http https",
      .create = drv_octoprint_new,
      .options = { net_options, poll_options, push_options },
      .gcode = GCHECK_MARLIN },
    { .name = "moonraker",
      .url = true,
      .auth = DRV_AUTH_KEY_OPTIONAL,
      .schemes = "http https",
      .create = drv_moonraker_new,
      .options = { net_options, poll_options, push_options },
      .gcode = GCHECK_MARLIN },
    { .name = "prusalink",
      .url = true,
      .auth = DRV_AUTH_KEY_OR_DIGEST,
      .schemes = "http https",
      .create = drv_prusalink_new,
      .options = { net_options, poll_options, digest_options },
      .gcode = GCHECK_MARLIN },
    { .name = "bambu",
      .url = true,
      .auth = DRV_AUTH_NONE,
      .schemes = "mqtts",
      .create = drv_bambu_new,
      .options = { net_options, bambu_options },
      .check = bambu_check,
      .gcode = GCHECK_MARLIN },
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
