/*
 * printer_heat.c - a printer's heaters after an interruption (hold_heat_min,
 * printer_int.h): connected, hot and with no print on it for that long, it
 * has its heaters turned off, said in its message, the log and the event log.
 *
 * Thread: the loop thread.
 */
#include "printer_int.h"

#include <stdio.h>

#include "../base/log.h"

/* Connected, no print on it, and a heater set: what hold_heat_min bounds. */
bool
printer_hot_idle(const struct printer *p)
{
    if (!p->drv || p->job_id || p->state == PRINTER_OFFLINE || p->state == PRINTER_PRINTING ||
        p->state == PRINTER_PAUSED)
        return false;
    const struct drv_status *st = &p->drv->status;
    return st->state == DRV_IDLE && (st->nozzle_target_c > 0 || st->bed_target_c > 0);
}

/*
 * hold_heat_min is over: the print is not coming back (no resume, no job),
 * so the heaters go off (M104 S0 and M140 S0: Marlin's, and what Klipper
 * and OctoPrint take as console G-code), said in p's message and the log.
 */
static void
on_heat_off(struct loop *l, void *ud)
{
    (void)l;
    struct printer *p = ud;
    p->heat_timer = 0;
    if (!printer_hot_idle(p))
        return;
    struct sf_err err;
    char what[160];
    const struct drv_status *st = &p->drv->status;
    int rc = !p->drv->ops->command ? sf_err_set(&err, SF_EUNSUPP, "its %s driver sends no commands",
                                                p->drv->ops->kind)
                                   : p->drv->ops->command(p->drv, "M104 S0", &err);
    if (rc == SF_OK)
        rc = p->drv->ops->command(p->drv, "M140 S0", &err);
    if (rc == SF_OK)
        snprintf(what, sizeof(what),
                 "heaters off (were %.0f/%.0f C): no print for %g min (hold_heat_min)",
                 st->nozzle_target_c, st->bed_target_c, p->cfg.hold_heat_min);
    else
        snprintf(what, sizeof(what), "hot with no print for %g min, heaters not turned off: %s",
                 p->cfg.hold_heat_min, err.msg);
    log_printer(rc ? LOG_ERROR : LOG_WARN, p->cfg.name, "%s", what);
    snprintf(p->message, sizeof(p->message), "%s", what);
    storeq_printer_note(p->env.q, p->cfg.name, "printer-heat", what);
    printer_changed(p);
}

void
printer_heat_watch(struct printer *p)
{
    bool hot = printer_hot_idle(p);
    if (hot && !p->heat_timer)
        p->heat_timer =
            loop_timer_add(p->env.l, (int64_t)(p->cfg.hold_heat_min * 60000.0), on_heat_off, p);
    else if (!hot && p->heat_timer) {
        loop_timer_cancel(p->env.l, p->heat_timer);
        p->heat_timer = 0;
    }
}
