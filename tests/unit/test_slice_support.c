/*
 * test_slice_support.c - the printed support as PrusaSlicer 2.5 prints it
 * (issue 33): its lines are the nozzle's width (support_line_width 0.4,
 * PrusaSlicer's automatic support width; before, the solid infill's 0.45),
 * and its columns fill cells of the grid PrusaSlicer snaps support to,
 * whose lines lie at whole multiples of the cell from the part's centre
 * (before, from the raster's corner: a narrow ledge got a cell more or
 * less than PrusaSlicer gives it, by where the part's edge fell), out
 * past the part's outline where a contact's cell reaches beyond it
 * (before, the raster of the part's shadow stopped them at its edge).
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "../../slicer/estimate.h"
#include "../../slicer/slice.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"
#include "slice_run.h"

/* PrusaSlicer's support cell: support_material_spacing 2.5 + the support
   flow's spacing 0.336 (../shared/SUPPORT-DETECTION.md) */
#define SNAP_MM 2.836

struct sup_walk {
    double ext_lo, ext_hi; /* x range of the external perimeters */
    double sup_lo, sup_hi; /* x range of the support lines' ends */
    double sup_mm, sup_e;  /* support path length and filament above the bed layer */
    double px, py;         /* the previous move's end */
};

static int
on_move(void *ud, const struct est_move *mv)
{
    struct sup_walk *w = ud;
    double len = hypot(mv->x - w->px, mv->y - w->py);
    bool ext = mv->de > 0 && len > 0;
    w->px = mv->x;
    w->py = mv->y;
    if (ext && ts_is_type(mv, "External perimeter")) {
        w->ext_lo = fmin(w->ext_lo, mv->x);
        w->ext_hi = fmax(w->ext_hi, mv->x);
    }
    if (ext &&
        (ts_is_type(mv, "Support material") || ts_is_type(mv, "Support material interface"))) {
        w->sup_lo = fmin(w->sup_lo, mv->x);
        w->sup_hi = fmax(w->sup_hi, mv->x);
        if (mv->layer > 1 && len > 1) { /* above the bed layer */
            w->sup_mm += len;
            w->sup_e += mv->de;
        }
    }
    return SF_OK;
}

/* A wall 3 mm thick, 20 tall and 30 long with a 0.8 mm ledge along its
   top 5 mm (a snap bead under a box's rim), sliced with supports on: on a
   10 mm foot, 2 mm thick (the ledge inside the part's shadow), or without
   (the ledge at its edge). */
static void
slice_ledge(bool foot, struct sup_walk *w)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    double x[8] = { 0, 10, 10, 3, 3, 3.8, 3.8, 0 }, z[8] = { 0, 0, 2, 2, 15, 15, 20, 20 };
    double xs[6] = { 0, 3, 3, 3.8, 3.8, 0 }, zs[6] = { 0, 0, 15, 15, 20, 20 };
    T_OK(foot ? shape_extrude_xz(&m, x, z, 8, 30, &err) : shape_extrude_xz(&m, xs, zs, 6, 30, &err),
         &err);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    p.skirts = 0;
    p.brim_auto = false;
    *w = (struct sup_walk){ INFINITY, -INFINITY, INFINITY, -INFINITY, 0, 0, 0, 0 };
    T_OK(ts_slice_walk(&m, &p, foot ? "ledge_foot" : "ledge", NULL, on_move, w, &err), &err);
    slice_profile_release(&p);
    mesh_release(&m);
}

T_CASE(support_lines_are_the_nozzles_width)
{
    struct sup_walk w;
    slice_ledge(true, &w);
    T_TRUE(w.sup_mm > 100);
    /* filament a mm of support line at 0.2 mm layers: spacing
       0.4 - 0.2 (1 - pi / 4) times 0.2 over the 1.75 mm filament's
       section; 0.45 mm lines lay 14 % more */
    double want = (0.4 - 0.2 * (1 - M_PI / 4)) * 0.2 / (M_PI * 0.875 * 0.875);
    double got = w.sup_e / w.sup_mm;
    if (fabs(got / want - 1) > 0.03)
        t_fail(__FILE__, __LINE__, "support: %.5f mm of filament a mm, want %.5f", got, want);
}

T_CASE(support_snaps_to_the_grid_through_the_parts_centre)
{
    struct sup_walk w;
    slice_ledge(true, &w);
    T_TRUE(w.sup_hi > w.sup_lo);
    /* the part is 10 mm wide, its centre 5 mm from the wall's back; the
       ledge (3 to 3.8 mm) lies in PrusaSlicer's grid cell from one cell
       (2.836 mm) short of the centre to the centre, so its support reaches
       the centre, its lines half a line short of it (at most half a
       raster cell, 0.12 mm, off where the raster has an odd number of
       cells).  Snapped from the raster's corner, the cell ran 5.08 mm
       from the centre (21.5 raster cells) and the support 0.39 mm past
       the centre */
    double cx = (w.ext_lo + w.ext_hi) / 2, want = -0.2;
    if (!(fabs(w.sup_hi - cx - want) < 0.15 && w.sup_lo < cx - 1.2))
        t_fail(__FILE__, __LINE__,
               "support %.3f..%.3f, part %.3f..%.3f: %.3f mm from the centre, want %.3f", w.sup_lo,
               w.sup_hi, w.ext_lo, w.ext_hi, w.sup_hi - cx, want);
}

T_CASE(support_reaches_past_the_parts_outline)
{
    /* the ledge is the part's widest point: PrusaSlicer fills the grid
       cell it touches beyond it (an enclosure's ears: 1.3 mm past their
       ends).  Here that cell's side lies 2.72 mm out from the centre
       (11.5 raster cells of 0.236 mm), the ledge's edge 1.9 mm: support
       lines to 2.52 mm.  Before, the raster of the part's shadow ended at
       the ledge's edge, and the support with it (lines to 1.81 mm) */
    struct sup_walk w;
    slice_ledge(false, &w);
    double cx = (w.ext_lo + w.ext_hi) / 2;
    if (!(w.sup_hi - cx > 2.3 && w.sup_hi - cx < 2.836))
        t_fail(__FILE__, __LINE__, "support %.3f..%.3f, part %.3f..%.3f: %.3f mm from the centre",
               w.sup_lo, w.sup_hi, w.ext_lo, w.ext_hi, w.sup_hi - cx);
}
