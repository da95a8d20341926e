/*
 * marlin_exec.h - follow the machine state G-code commands leave, and bound
 * how long each takes to run, for the Marlin driver's pause, resume and
 * deadlines.
 *
 * Pure, thread-safe; owns nothing.
 */
#ifndef SF_DRIVERS_MARLIN_MARLIN_EXEC_H
#define SF_DRIVERS_MARLIN_MARLIN_EXEC_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../drv.h"

/* Follow the state a job line leaves behind, so resume can restore it. */
void marlin_exec_track(struct drv_machine *mo, const char *cmd, size_t len);

/*
 * An upper bound on how long the printer takes to run cmd, ms, from the
 * machine state before it (advanced past it).  Moves: the trapezoid the
 * estimator's planner uses for a block (slicer/estimate.c), started and
 * ended at rest, at a low acceleration, so never less than the firmware
 * needs.  Commands that block (homing, probing, heating, dwell) get their
 * own allowances; heating and homing keep the host informed with busy and
 * temperature lines, which count as replies (see expect_ms).
 */
int32_t marlin_exec_ms(struct drv_machine *mo, const char *cmd);

/* A move (G0-G3): planned, acknowledged, then run. */
bool marlin_exec_is_move(const char *cmd);

/* A heat-up wait: Marlin reports temperatures while it runs. */
bool marlin_exec_heats(const char *cmd);

#endif
