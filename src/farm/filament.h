/*
 * filament.h - how much filament a G-code job has used by a given command
 * line: the net E it extrudes (absolute or relative E, G92 resets), read
 * once from the file when a print starts (on the farm's io thread, beside
 * the start's policy check), so the print's end records its filament
 * (prints.filament_mm: all of the file's for a done print, up to the last
 * acknowledged line for a failed or cancelled one) without reading the
 * file on the loop.
 *
 * Command lines are counted as the drivers count lines_acked (gcode_strip:
 * comments and blank lines are not commands).  The net E is kept at most
 * FILAMENT_MARKS + 1 evenly spaced lines; between two marks a line's share
 * is by lines.
 *
 * Thread: any (pure functions over caller memory and a file).
 */
#ifndef SF_FARM_FILAMENT_H
#define SF_FARM_FILAMENT_H

#include <stdint.h>

#include "../base/err.h"

/* Marks of net E a print keeps: 8 KiB, a mark every 1/1024 of the file
   (a 5 m print's share between two marks is off by at most ~5 mm). */
#define FILAMENT_MARKS 1024

struct filament {
    int64_t job_id;                     /* whose file (0: none read) */
    int64_t lines;                      /* its command lines */
    int64_t step;                       /* command lines between two marks (>= 1) */
    int n_marks;                        /* marks kept (mark 0 is the start) */
    double total_mm;                    /* net E of the whole file */
    double mark_mm[FILAMENT_MARKS + 1]; /* net E after k * step command lines */
};

/*
 * Read the G-code file at path into *out (job_id left 0: the caller sets
 * it).  A line that does not parse counts as a command without E, as a
 * driver would send it.  SF_EIO (err set) when it cannot be read.
 */
int filament_scan(const char *path, struct filament *out, struct sf_err *err);

/* Net E in mm after the first `lines` command lines (all of it from
   f->lines on), never below 0. */
double filament_at(const struct filament *f, int64_t lines);

#endif
