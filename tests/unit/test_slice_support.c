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
 * Its lines run one way, 2.5 mm apart plus a line, joined along the
 * boundary; its interface is as deep as PrusaSlicer's three 0.3 mm support
 * layers, and only under the contacts it prints dense; its bed layer is a
 * 3 mm flange.  The optimizers' support model scores the columns so too
 * (the grid through the centre, a snap cell of margin).
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "../../slicer/estimate.h"
#include "../../slicer/slice.h"
#include "../../src/geom/raycast.h"
#include "../../src/geom/supmodel.h"
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
    if (ext && mv->layer > 0 && /* the columns: the bed layer is a flange, wider */
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

T_CASE(support_takes_the_grid_cell_an_overhang_reaches_a_hair_into)
{
    /* a wall 3 mm thick with a ledge 2.772 mm long out of its top 5 mm:
       the part is 5.772 mm wide, 25 raster cells (an odd count: the cells'
       centres lie on PrusaSlicer's grid lines, the first one at the ledge's
       far end, 0.05 mm in), so the ledge reaches 0.05 mm into the grid cell
       past that line.  PrusaSlicer's grid takes every cell the contact
       area overlaps (anti-aliased: any coverage fills the cell), and
       prints a column there, its lines to about 2.7 mm past the ledge's
       end (the mech set's boss_block: its horizontal boss ends 0.044 mm
       past a line, PrusaSlicer's support a row longer than ours, 1.02 g
       against 0.80).  Before, the contact on the line counted only in the
       cell on its own side: the support stopped 0.07 mm past the end */
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    double l = 2 * (SNAP_MM + 0.05) - 3;
    double x[6] = { l, l + 3, l + 3, 0, 0, l }, z[6] = { 0, 0, 20, 20, 15, 15 };
    T_OK(shape_extrude_xz(&m, x, z, 6, 30, &err), &err);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    p.skirts = 0;
    p.brim_auto = false;
    struct sup_walk w = { INFINITY, -INFINITY, INFINITY, -INFINITY, 0, 0, 0, 0 };
    T_OK(ts_slice_walk(&m, &p, "ledge_line", NULL, on_move, &w, &err), &err);
    slice_profile_release(&p);
    mesh_release(&m);
    T_TRUE(w.sup_hi > w.sup_lo);
    if (!(w.ext_lo - w.sup_lo > 2.0 && w.ext_lo - w.sup_lo < 3.0))
        t_fail(__FILE__, __LINE__, "support %.3f..%.3f, part %.3f..%.3f: %.3f mm past its end",
               w.sup_lo, w.sup_hi, w.ext_lo, w.ext_hi, w.ext_lo - w.sup_lo);
}

/* Support moves of a part (the tee: stem 10 x 20 x 30 under a 50 x 20 x 5
   bar), layer by layer (the walk's: 0 is the bed layer): body segments
   along x and along y, the y of the body's x-parallel segments over 1.5 mm
   on one layer (probe), the interface laid, the body's x range. */
#define TEE_LAYERS 200
#define TEE_YS     64
struct layer_walk {
    double x_mm[TEE_LAYERS], y_mm[TEE_LAYERS], iface_mm[TEE_LAYERS];
    double lo[TEE_LAYERS], hi[TEE_LAYERS];
    double ys[TEE_YS];
    double ext_lo, ext_hi; /* y range of the external perimeters */
    int n_ys, probe;
    double px, py;
};

static int
on_layer_move(void *ud, const struct est_move *mv)
{
    struct layer_walk *w = ud;
    double dx = mv->x - w->px, dy = mv->y - w->py, len = hypot(dx, dy);
    double y0 = w->py;
    w->px = mv->x;
    w->py = mv->y;
    if (!(mv->de > 0 && len > 0) || mv->layer >= TEE_LAYERS)
        return SF_OK;
    int k = (int)mv->layer;
    if (ts_is_type(mv, "External perimeter")) {
        w->ext_lo = fmin(w->ext_lo, mv->y);
        w->ext_hi = fmax(w->ext_hi, mv->y);
    }
    if (ts_is_type(mv, "Support material interface"))
        w->iface_mm[k] += len;
    if (!ts_is_type(mv, "Support material"))
        return SF_OK;
    w->lo[k] = fmin(w->lo[k], fmin(mv->x, mv->x - dx));
    w->hi[k] = fmax(w->hi[k], fmax(mv->x, mv->x - dx));
    if (fabs(dy) < 1e-3) {
        w->x_mm[k] += len;
        if (k == w->probe && len > 1.5 && w->n_ys < TEE_YS)
            w->ys[w->n_ys++] = y0;
    } else if (fabs(dx) < 1e-3) {
        w->y_mm[k] += len;
    }
    return SF_OK;
}

/* Walk the support moves of m sliced with the defaults (no skirt, no brim). */
static void
walk_part(const struct mesh *m, const char *name, struct layer_walk *w)
{
    struct slice_profile p;
    struct sf_err err;
    T_OK(slice_profile_default(&p), NULL);
    p.skirts = 0;
    p.brim_auto = false;
    memset(w, 0, sizeof(*w));
    for (int k = 0; k < TEE_LAYERS; k++)
        w->lo[k] = INFINITY, w->hi[k] = -INFINITY;
    w->ext_lo = INFINITY;
    w->ext_hi = -INFINITY;
    w->probe = 50;
    T_OK(ts_slice_walk(m, &p, name, NULL, on_layer_move, w, &err), &err);
    slice_profile_release(&p);
}

static void
slice_tee(const char *name, struct layer_walk *w)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    walk_part(&m, name, w);
    mesh_release(&m);
}

T_CASE(support_lines_run_one_way_a_gap_and_a_line_apart)
{
    /* PrusaSlicer 2.5 (grid style, rectilinear) lays every body layer's
       lines one way (support_material_angle 0: along x), its
       support_material_spacing (2.5) plus a line's spacing apart (0.357 at
       0.2 mm): 2.857 mm.  Before, they turned 90 degrees every layer and
       lay 2.5 mm apart: 14 % more filament, and a narrow column's strip
       got a line along it every other layer where PrusaSlicer's miss it */
    struct layer_walk w;
    slice_tee("tee_lines", &w);
    for (int k = 10; k < 120; k++)
        if (!(w.x_mm[k] > 1.5 * w.y_mm[k]))
            t_fail(__FILE__, __LINE__, "layer %d: support %.1f mm along x, %.1f along y", k,
                   w.x_mm[k], w.y_mm[k]);
    /* the lines lie on that grid through the part's centre (the sheath's
       sides, on the support cells' edges, mostly off it): at least five
       neighbouring grid lines hold one */
    double want = 2.5 + (0.4 - 0.2 * (1 - M_PI / 4)), cy = (w.ext_lo + w.ext_hi) / 2;
    bool on[64] = { false };
    for (int i = 0; i < w.n_ys; i++) {
        double q = (w.ys[i] - cy) / want;
        long g = lround(q);
        if (fabs(q - (double)g) * want < 0.01 && g > -32 && g < 32)
            on[g + 32] = true;
    }
    int run = 0, best = 0;
    for (int g = 0; g < 64; g++)
        run = on[g] ? run + 1 : 0, best = run > best ? run : best;
    if (best < 5)
        t_fail(__FILE__, __LINE__, "%d neighbouring support lines on a %.3f mm grid through y %.3f",
               best, want, cy);
}

T_CASE(support_interface_as_deep_as_prusaslicers)
{
    /* PrusaSlicer's 3 interface layers are support layers of up to 0.75
       nozzle (0.3 mm): 0.9 mm dense under the bar, 5 of our 0.2 mm
       layers (before, 3: 0.6 mm, two thirds of its interface) */
    struct layer_walk w;
    slice_tee("tee_iface", &w);
    int n = 0;
    for (int k = 0; k < TEE_LAYERS; k++)
        n += w.iface_mm[k] > 20;
    T_EQ_INT(n, 5);
}

T_CASE(support_bed_layer_is_a_flange)
{
    /* the bed layer's support reaches 3 mm past the columns
       (raft_first_layer_expansion), outside the part: the bar's overhang
       ends at x = 50 from the tee's left, its column's bed layer 3 mm
       further (before, level with the column) */
    struct layer_walk w;
    slice_tee("tee_flange", &w);
    T_TRUE(w.hi[10] > w.lo[10]);
    double d = w.hi[0] - w.hi[10], e = w.lo[10] - w.lo[0];
    if (!(d > 2.5 && d < 3.5 && e > 2.5 && e < 3.5))
        t_fail(__FILE__, __LINE__, "bed layer's support %.2f..%.2f, the column's %.2f..%.2f",
               w.lo[0], w.hi[0], w.lo[10], w.hi[10]);
}

T_CASE(support_gentle_slope_gets_no_interface)
{
    /* a face 50 degrees from vertical steps 0.24 mm a layer: past
       PrusaSlicer's 45-degree threshold (0.19 mm), short of the 0.27 mm
       its dense contacts need (0.6 perimeter widths), so it prints its
       support sparse to the top; before, every column's top three
       layers printed dense (3042 mm of interface, 17648 of support) */
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_wedge(&m, 50, &err), &err);
    struct layer_walk w;
    walk_part(&m, "wedge50", &w);
    mesh_release(&m);
    double body = 0, iface = 0;
    for (int k = 1; k < TEE_LAYERS; k++)
        body += w.x_mm[k] + w.y_mm[k], iface += w.iface_mm[k];
    if (!(body > 100 && iface < 0.05 * body))
        t_fail(__FILE__, __LINE__, "wedge at 50 degrees: support %.1f mm, interface %.1f", body,
               iface);
}

/* *mm3: the support model's volume (PrusaSlicer's rules, as the optimizers
   steer by) of the ledge on its foot, or of its mirror image (x -> 10 - x). */
static void
model_ledge_mm3(bool mirror, double *mm3)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    double x[8] = { 0, 10, 10, 3, 3, 3.8, 3.8, 0 }, z[8] = { 0, 0, 2, 2, 15, 15, 20, 20 };
    if (mirror)
        for (int i = 0; i < 8; i++)
            x[i] = 10 - x[i];
    T_OK(shape_extrude_xz(&m, x, z, 8, 30, &err), &err);
    struct supmodel_params mp;
    supmodel_params_steer(&mp, 45);
    struct supmodel_result mr;
    T_OK(supmodel_of_mesh(&m, v3(0, 0, 1), &mp, &mr, &err), &err);
    mesh_release(&m);
    *mm3 = mr.base_mm3 + mr.interface_mm3 + mr.outline_mm3;
}

T_CASE(support_model_snaps_through_the_parts_centre)
{
    /* the model snaps its cells as the slicer does, from the part's
       centre: a part and its mirror image get the same support (within a
       raster cell's worth: 488 and 507 mm3).  Snapped from the raster's
       corner, 492 and 399 mm3 */
    double a, b;
    model_ledge_mm3(false, &a);
    model_ledge_mm3(true, &b);
    T_TRUE(a > 1);
    if (fabs(a / b - 1) > 0.1)
        t_fail(__FILE__, __LINE__, "model: ledge %.2f mm3, its mirror image %.2f", a, b);
}

T_CASE(support_model_reaches_past_the_parts_outline)
{
    /* the ledge at the part's widest point: the slicer fills the snap cell
       past the outline, and the model scores that cell too (supmodel_eval
       pads its raster by a snap cell); on the raster of the part's shadow
       alone (supmodel_eval_grid, unpadded) the column stops at the edge:
       112 mm3 of base against 52 (before, 52 both ways) */
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    double xs[6] = { 0, 3, 3, 3.8, 3.8, 0 }, zs[6] = { 0, 0, 15, 15, 20, 20 };
    T_OK(shape_extrude_xz(&m, xs, zs, 6, 30, &err), &err);
    struct supmodel_params mp;
    supmodel_params_steer(&mp, 45);
    struct supmodel_result padded, bare;
    T_OK(supmodel_of_mesh(&m, v3(0, 0, 1), &mp, &padded, &err), &err);
    struct raycast *rc = raycast_new(&m, &err);
    T_TRUE(rc != NULL);
    struct ray_grid g;
    T_OK(raycast_grid(rc, v3(0, 0, 1), supmodel_raster_pitch(&mp), &g, &err), &err);
    T_OK(supmodel_eval_grid(&g, &mp, &bare, &err), &err);
    ray_grid_release(&g);
    raycast_free(rc);
    mesh_release(&m);
    if (!(padded.base_mm3 > 1.3 * bare.base_mm3))
        t_fail(__FILE__, __LINE__, "model: %.2f mm3 of base padded, %.2f on the shadow's raster",
               padded.base_mm3, bare.base_mm3);
}
