/*
 * printtime_loops.h - the part's outlines layer by layer, for the two rules
 * of PrusaSlicer 2.5 the face sums of printtime.c cannot see, because they
 * depend on which faces form one loop:
 *   small perimeters   a loop no longer than 2 pi 6.5 mm (its
 *                      SMALL_PERIMETER_LENGTH) prints every perimeter at
 *                      small_perimeter_speed (15 mm/s, not 30 / 60);
 *   small infill       an island whose infill region (inside its
 *                      perimeters) is under solid_infill_below_area (70 mm2)
 *                      is filled solid, not at 15 %.
 * scad example008 turned on its side is cut into small letter-bits: there
 * PrusaSlicer prints 38 of its 62 m of inner perimeters at 15 mm/s (12 of 53
 * as given) and 24 m more solid infill, and its part time rose 42 % where
 * the face sums said 2 %.
 *
 * Each layer is cut at its middle (as the slicers cut), the crossing
 * segments chained into loops across the mesh's shared edges; a chain that
 * does not close (an open or non-manifold mesh) counts as neither small nor
 * an island.  A hole belongs to the smallest outer loop whose bounding box
 * holds its own.
 *
 * Pure function: thread-safe.
 */
#ifndef SF_GEOM_PRINTTIME_LOOPS_H
#define SF_GEOM_PRINTTIME_LOOPS_H

#include <stdint.h>

#include "../base/err.h"
#include "../mesh/mesh.h"

struct printtime_loops_params {
    double layer_mm;        /* layer height */
    double small_loop_mm;   /* a loop this long or shorter is small (40.84) */
    double perimeter_mm;    /* width of an island's perimeters (2 x 0.45) */
    double solid_below_mm2; /* an infill region under this is solid (70) */
};

/*
 * For the n layers of m along up (unit) from zmin, add to small_mm[k] the
 * length of layer k's small closed loops and to small_fill_mm2[k] the infill
 * area of its islands whose infill region is under solid_below_mm2 (both
 * arrays n long, the caller's).  Errors: SF_ENOMEM.
 */
int printtime_loops_eval(const struct mesh *m, struct vec3 up, double zmin, uint32_t n,
                         const struct printtime_loops_params *p, double *small_mm,
                         double *small_fill_mm2, struct sf_err *err);

#endif
