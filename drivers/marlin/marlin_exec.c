/*
 * marlin_exec.c - machine state and execution time of G-code commands, for
 * the Marlin driver (marlin_exec.h).
 *
 * Why its own module: pause, resume and a resume mid-file need the state
 * the job's lines leave (position, modes, temperatures, fan), and the
 * deadlines need an upper bound on how long what is in flight may take;
 * both follow each command the same way, and neither needs the driver.
 *
 * Thread: any (no state).
 */
#include "marlin_exec.h"

#include <math.h>
#include <string.h>

#include "../../src/base/gcode.h"

#define ACCEL_MM_S2 1500.0 /* execution time bounds: below most printers' print accel */

/* Follow the state a job line leaves behind, so resume can restore it. */
void
marlin_exec_track(struct drv_machine *mo, const char *cmd, size_t len)
{
    struct gcode_line g;
    if (gcode_parse(cmd, len, &g, NULL) < 0)
        return;
    static const char axes[4] = { 'X', 'Y', 'Z', 'E' };
    double v;
    if (g.letter == 'G' && g.code <= 3) {
        for (int a = 0; a < 4; a++)
            if (gcode_get(&g, axes[a], &v) && !isnan(v))
                mo->pos[a] = (a < 3 ? mo->rel_xyz : mo->rel_e) ? mo->pos[a] + v : v;
        if (gcode_get(&g, 'F', &v) && v > 0)
            mo->feed_mm_min = v;
    } else if (gcode_is(&g, 'G', 90) || gcode_is(&g, 'G', 91)) {
        mo->rel_xyz = mo->rel_e = g.code == 91;
    } else if (gcode_is(&g, 'M', 82) || gcode_is(&g, 'M', 83)) {
        mo->rel_e = g.code == 83;
    } else if (gcode_is(&g, 'G', 92)) {
        for (int a = 0; a < 4; a++)
            if (gcode_get(&g, axes[a], &v))
                mo->pos[a] = isnan(v) ? 0 : v;
    } else if (gcode_is(&g, 'G', 28)) {
        bool any = false;
        for (int a = 0; a < 3; a++)
            any |= gcode_get(&g, axes[a], NULL);
        for (int a = 0; a < 3; a++)
            if (!any || gcode_get(&g, axes[a], NULL))
                mo->pos[a] = 0;
    } else if ((gcode_is(&g, 'M', 104) || gcode_is(&g, 'M', 109)) && gcode_get(&g, 'S', &v) &&
               !isnan(v)) {
        mo->noz_c = v;
    } else if ((gcode_is(&g, 'M', 140) || gcode_is(&g, 'M', 190)) && gcode_get(&g, 'S', &v) &&
               !isnan(v)) {
        mo->bed_c = v;
    } else if (gcode_is(&g, 'M', 106)) {
        mo->fan = gcode_get(&g, 'S', &v) && !isnan(v) ? v : 255;
    } else if (gcode_is(&g, 'M', 107)) {
        mo->fan = 0;
    }
}

/*
 * An upper bound on how long the printer takes to run cmd, ms, from the
 * machine state before it (advanced past it).  Moves: the trapezoid the
 * estimator's planner uses for a block (slicer/estimate.c), started and
 * ended at rest, at a low acceleration, so never less than the firmware
 * needs.  Commands that block (homing, probing, heating, dwell) get their
 * own allowances; heating and homing keep the host informed with busy and
 * temperature lines, which count as replies (see expect_ms).
 */
int32_t
marlin_exec_ms(struct drv_machine *mo, const char *cmd)
{
    struct gcode_line g;
    if (gcode_parse(cmd, strlen(cmd), &g, NULL) < 0)
        return 0;
    double v;
    if (g.letter == 'G' && g.code <= 3) {
        static const char axes[4] = { 'X', 'Y', 'Z', 'E' };
        double d2 = 0, de = 0;
        for (int a = 0; a < 4; a++) {
            if (!gcode_get(&g, axes[a], &v) || isnan(v))
                continue;
            double to = (a < 3 ? mo->rel_xyz : mo->rel_e) ? mo->pos[a] + v : v;
            double dd = to - mo->pos[a];
            if (a < 3)
                d2 += dd * dd;
            else
                de = fabs(dd);
        }
        double d = d2 > 0 ? sqrt(d2) : de;
        if (g.code >= 2 && d > 0)
            d *= 3.2; /* an arc may sweep up to a full turn around its chord */
        double f = mo->feed_mm_min;
        if (gcode_get(&g, 'F', &v) && v > 0)
            f = v;
        marlin_exec_track(mo, cmd, strlen(cmd));
        double vs = f / 60.0 < 0.5 ? 0.5 : f / 60.0;
        double t =
            d >= vs * vs / ACCEL_MM_S2 ? d / vs + vs / ACCEL_MM_S2 : 2 * sqrt(d / ACCEL_MM_S2);
        return t * 1000 > 600000 ? 600000 : (int32_t)(t * 1000) + 1;
    }
    marlin_exec_track(mo, cmd, strlen(cmd));
    if (gcode_is(&g, 'G', 4)) {
        double ms = 0;
        if (gcode_get(&g, 'P', &v) && !isnan(v))
            ms = v;
        else if (gcode_get(&g, 'S', &v) && !isnan(v))
            ms = v * 1000;
        return ms < 0 ? 0 : ms > 3600000 ? 3600000 : (int32_t)ms;
    }
    if (gcode_is(&g, 'G', 28))
        return 60000;
    if (gcode_is(&g, 'G', 29) || gcode_is(&g, 'G', 34) || gcode_is(&g, 'M', 48))
        return 600000;
    if (gcode_is(&g, 'M', 109) || gcode_is(&g, 'M', 190) || gcode_is(&g, 'M', 191) ||
        gcode_is(&g, 'M', 303) || gcode_is(&g, 'M', 0) || gcode_is(&g, 'M', 1) ||
        gcode_is(&g, 'M', 600))
        return 1800000;
    return 0;
}

/* A move (G0-G3): planned, acknowledged, then run. */
bool
marlin_exec_is_move(const char *cmd)
{
    struct gcode_line g;
    return gcode_parse(cmd, strlen(cmd), &g, NULL) == 0 && g.letter == 'G' && g.code <= 3;
}

/* A heat-up wait: Marlin reports temperatures while it runs. */
bool
marlin_exec_heats(const char *cmd)
{
    struct gcode_line g;
    return gcode_parse(cmd, strlen(cmd), &g, NULL) == 0 &&
           (gcode_is(&g, 'M', 109) || gcode_is(&g, 'M', 190) || gcode_is(&g, 'M', 191));
}
