/*
 * gcheck.h - the check every job file goes through before it reaches a
 * printer: read the whole file once, count its command lines (the unit of
 * progress and resume), and refuse a line no printer of the kind could be
 * sent, so a job never fails half-way on a bad line.  Which rules apply is
 * the printer kind's choice: its registry row names them (drv_kind.gcode,
 * drv.h).
 *
 * Today there is one set of rules, Marlin's (a numbered, checksummed line
 * in a 96-byte buffer), and every kind's row names it: OctoPrint, PrusaLink
 * and Moonraker feed Marlin-family firmware, Bambu's firmware is
 * Marlin-derived.  Where kinds should come to differ (Klipper's extended
 * commands, e.g. "SET_HEATER_TEMPERATURE HEATER=extruder TARGET=200",
 * are longer than Marlin allows and need no line numbers), a new
 * enum gcheck_rules value and its case in gcheck.c are the whole change.
 * Which commands a job may hold (the farm's safety policy, the same for
 * every kind) is gpolicy.h's: the upload check runs it before this scan.
 *
 * Thread: any (pure: reads the file, touches only its arguments).
 */
#ifndef SF_DRIVERS_GCHECK_H
#define SF_DRIVERS_GCHECK_H

#include <stdint.h>

#include "../src/base/err.h"

struct drv_job_scan; /* drv.h */

/* A set of rules a job file must pass. */
enum gcheck_rules {
    GCHECK_MARLIN = 0, /* Marlin's: each command fits a numbered, checksummed 96-byte line */
};

/* The rules' name for messages ("marlin"); "?" for an unknown value. */
const char *gcheck_rules_name(enum gcheck_rules r);

/*
 * Read and check the whole file at path by rules r: count its command lines
 * (comments and blank lines not counted) into scan->lines_total, and refuse
 * a line longer than SF_GCODE_LINE_MAX or a command the rules forbid
 * (SF_EINVAL, the message naming 'path':line).  SF_EIO when the file cannot
 * be read.  scan is set only on success.
 */
int gcheck_scan(enum gcheck_rules r, const char *path, struct drv_job_scan *scan,
                struct sf_err *err);

/*
 * Add to scan (whose lines_total the caller knows) the resume point of
 * command first_line (1 .. lines_total - 1) by rules r: where it starts and
 * the machine state the commands before it leave, reading the file only up
 * to it.  SF_EINVAL if the file holds no such command, SF_EIO.
 */
int gcheck_scan_to(enum gcheck_rules r, const char *path, uint64_t first_line,
                   struct drv_job_scan *scan, struct sf_err *err);

#endif
