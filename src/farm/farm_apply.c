/*
 * farm_apply.c - the farm's printers changed while it runs: a reload
 * (SIGHUP, an API change to the run-time printers) applied printer by
 * printer (farm_apply, farm_sweep, farm_reload), and the operator's
 * actions, manual commands and emergency stop on a printer by name.
 *
 * Thread: the loop thread.
 */
#include "farm.h"
#include "farm_int.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../drivers/gpolicy.h"
#include "../base/log.h"
#include "farm_host.h"

bool
farm_link_change(const struct farmcfg_printer *a, const struct farmcfg_printer *b, char *why,
                 size_t n)
{
    /* a new disable reason too: the printer's message says it (printer_new) */
    if (strcmp(a->driver, b->driver) != 0 || a->enabled != b->enabled ||
        strcmp(a->disabled, b->disabled) != 0) {
        snprintf(why, n, "option '%s' changed", a->enabled != b->enabled ? "enabled" : "driver");
        return true;
    }
    const struct drv_kind *k = drv_kind_find(a->driver);
    const struct drv_option *o = drv_link_diff(k, &a->link, &b->link);
    if (!o)
        return false;
    char was[80], now[80];
    drv_link_show(&a->link, k, o, was, sizeof(was));
    drv_link_show(&b->link, k, o, now, sizeof(now));
    snprintf(why, n, "option '%s' changed from '%s' to '%s'", o->name, was, now);
    return true;
}

int
farm_apply(struct farm *f, const struct farmcfg_printer *c, struct sf_err *err)
{
    struct printer *p = farm_find(f, c->name);
    if (!p)
        return farm_add_printer(f, c, err);
    printer_set_removed(p, false);
    const struct farmcfg_printer *old = printer_cfg(p);
    char why[200];
    bool change = farm_link_change(old, c, why, sizeof(why));
    if (!change || printer_job(p) || printer_hot_idle(p)) {
        /* Same link, or busy (printing, or holding its heat: closing its driver would leave
           the heaters on, printer.h): change what the scheduler reads only. */
        struct farmcfg_printer next = *c;
        if (change) {
            log_printer(LOG_WARN, c->name, "link change waits for the print to end%s",
                        printer_job(p) ? "" : " (its heaters are on)");
            memcpy(next.driver, old->driver, sizeof(next.driver));
            next.link = old->link;
            next.enabled = old->enabled;
            memcpy(next.disabled, old->disabled, sizeof(next.disabled));
        }
        printer_set_cfg(p, &next);
        return SF_OK;
    }
    log_printer(LOG_INFO, c->name, "%s: reconnecting", why);
    /* New link and idle: replace the printer. */
    struct printer *fresh = farm_printer_new(f, c, p);
    if (!fresh)
        return sf_err_set(err, SF_ENOMEM, "farm: out of memory");
    for (size_t k = 0; k < f->n_printers; k++)
        if (f->printers[k] == p)
            f->printers[k] = fresh;
    printer_free(p);
    return SF_OK;
}

void
farm_sweep(struct farm *f)
{
    size_t w = 0;
    for (size_t i = 0; i < f->n_printers; i++) {
        struct printer *p = f->printers[i];
        if (printer_removed(p) && !printer_job(p) && !printer_hot_idle(p)) {
            printer_free(p);
            continue;
        }
        f->printers[w++] = p;
    }
    f->n_printers = w;
}

int
farm_reload(struct farm *f, const struct farmcfg *cfg, struct sf_err *err)
{
    /* farm.ini's printers, with the store's run-time rows over them (farm_printers.c) */
    struct farmcfg_printer *list = NULL;
    size_t n = 0;
    int rc = farm_seed(f, cfg->printers, cfg->n_printers, err);
    if (rc || (rc = farm_merged(f, &list, &n, err)))
        return rc;
    /* Printers that left the config: free when not printing, else after. */
    for (size_t i = 0; i < f->n_printers; i++) {
        struct printer *p = f->printers[i];
        bool kept = false;
        for (size_t k = 0; k < n && !kept; k++)
            kept = strcmp(list[k].name, printer_cfg(p)->name) == 0;
        printer_set_removed(p, !kept);
    }
    for (size_t i = 0; i < n && rc == SF_OK; i++)
        rc = farm_apply(f, &list[i], err);
    free(list);
    if (rc)
        return rc;
    farm_sweep(f);
    f->n_no = 0; /* a reload may have mended a profile */
    snprintf(f->profiles_dir, sizeof(f->profiles_dir), "%s", cfg->profiles_dir);
    f->gram_s = cfg->gram_s;
    f->material_first = cfg->material_first;
    farm_host_own(f);
    farm_kick(f);
    return SF_OK;
}

size_t
farm_printer_count(const struct farm *f)
{
    return f->n_printers;
}

void
farm_printer_info(const struct farm *f, size_t i, struct printer_info *out)
{
    printer_info(f->printers[i], out);
}

int
farm_printer_action(struct farm *f, const char *name, enum printer_action act, struct sf_err *err)
{
    struct printer *p = farm_find(f, name);
    if (!p)
        return sf_err_set(err, SF_ENOTFOUND, "no printer '%.64s'", name);
    return printer_action(p, act, err);
}

struct storeq *
farm_storeq(struct farm *f)
{
    return f ? f->q : NULL;
}

int
farm_printer_action_then(struct farm *f, const char *name, enum printer_action act,
                         storeq_event_fn done, void *ud, struct sf_err *err)
{
    struct printer *p = farm_find(f, name);
    if (!p)
        return sf_err_set(err, SF_ENOTFOUND, "no printer '%.64s'", name);
    return printer_action_then(p, act, done, ud, err);
}

/* printer_command (done NULL) or printer_command_then for the line name's G-code policy lets
   through. */
static int
command(struct farm *f, const char *name, const char *line, const char *who, storeq_event_fn done,
        void *ud, struct sf_err *err)
{
    struct printer *p = farm_find(f, name);
    if (!p)
        return sf_err_set(err, SF_ENOTFOUND, "no printer '%.64s'", name);
    /* The printer's G-code policy judges the line as a manual command
       (gpolicy.h): the host's protocol commands, control bytes and what the
       printer's config does not allow are refused; a rewrite is sent instead. */
    struct gpolicy pol;
    struct gpolicy_verdict v;
    farmcfg_policy(printer_cfg(p), &pol);
    switch (gpolicy_check_line(&pol, GPOLICY_MANUAL, line, strlen(line), &v)) {
    case GPOLICY_REFUSE:
        return sf_err_set(err, SF_EINVAL, "manual command on '%.64s': %s refused: %s", name, v.cmd,
                          v.why);
    case GPOLICY_REWRITE:
        log_printer_each(LOG_INFO, name, "manual command '%.80s' from %s sent as '%.80s' (%s)",
                         line, who && who[0] ? who : "?", v.line, v.why);
        return done ? printer_command_then(p, v.line, who, done, ud, err)
                    : printer_command(p, v.line, who, err);
    case GPOLICY_PASS:
        break;
    }
    return done ? printer_command_then(p, line, who, done, ud, err)
                : printer_command(p, line, who, err);
}

int
farm_printer_command(struct farm *f, const char *name, const char *line, const char *who,
                     struct sf_err *err)
{
    return command(f, name, line, who, NULL, NULL, err);
}

int
farm_printer_command_then(struct farm *f, const char *name, const char *line, const char *who,
                          storeq_event_fn done, void *ud, struct sf_err *err)
{
    return command(f, name, line, who, done, ud, err);
}

int
farm_printer_estop(struct farm *f, const char *name, const char *who, struct sf_err *err)
{
    struct printer *p = farm_find(f, name);
    if (!p)
        return sf_err_set(err, SF_ENOTFOUND, "no printer '%.64s'", name);
    return printer_estop(p, who, err);
}
