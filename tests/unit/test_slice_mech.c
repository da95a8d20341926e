/*
 * test_slice_mech.c - mechanical parts as PrusaSlicer 2.5 prints them
 * (issue 33).  The strip inside a 2.4 mm wall is anchored sparse infill,
 * not gap fill, with as many wall loops as PrusaSlicer's (before, narrow
 * sparse pieces were gap-filled solid: +16 % filament on this box).
 * Bridges that PrusaSlicer's dont_support_bridges leaves unsupported (a
 * slot's roof, a lid modelled lip-down, a gusset bridged along its
 * hypotenuse) get no columns in the print, the
 * part picture or the optimizers' model, while a cantilever still does
 * (before, the slicer held every bridge up).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../slicer/estimate.h"
#include "../../slicer/preview.h"
#include "../../slicer/slice.h"
#include "../../slicer/support.h"
#include "../../src/geom/supmodel.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"
#include "slice_run.h"
#include "slice_shapes.h"

/* The box: 60 x 40 x 20, 2.4 mm walls, 2 mm floor. */
#define BOX_H     20.0
#define BOX_FLOOR 2.0

struct walls {
    double gap_mm, infill_mm, total_mm; /* filament, the wall's middle layers */
    double all_mm;                      /* filament, every layer */
    uint32_t layers;                    /* middle layers seen */
    uint32_t loops_min;                 /* fewest perimeter runs on a middle layer */
    uint32_t loops, layer;              /* perimeter runs on the current layer */
    bool was_perim;                     /* the previous move extruded a perimeter */
    double px, py;                      /* the previous move's end */
};

static void
end_layer(struct walls *w)
{
    if (w->loops && w->loops < w->loops_min)
        w->loops_min = w->loops;
    w->loops = 0;
}

static int
on_move(void *ud, const struct est_move *mv)
{
    struct walls *w = ud;
    if (mv->layer != w->layer) {
        end_layer(w);
        w->layer = mv->layer;
    }
    /* extrusion with XY motion, as the peers count it (no primes) */
    bool ext = mv->de > 0 && (mv->x != w->px || mv->y != w->py);
    w->px = mv->x;
    w->py = mv->y;
    bool perim = ext && (ts_is_type(mv, "Perimeter") || ts_is_type(mv, "External perimeter"));
    if (ext)
        w->all_mm += mv->de;
    /* the wall's middle: clear of the floor's and the rim's solid layers */
    bool middle = mv->z > BOX_FLOOR + 1.5 && mv->z < BOX_H - 1.5;
    if (middle && ext) {
        w->total_mm += mv->de;
        if (ts_is_type(mv, "Gap fill"))
            w->gap_mm += mv->de;
        if (ts_is_type(mv, "Internal infill"))
            w->infill_mm += mv->de;
        if (perim && !w->was_perim)
            w->loops++;
    }
    w->was_perim = perim;
    return SF_OK;
}

/* The default profile without skirt or brim (as the peers slice), with or
   without supports. */
static void
bare_profile(struct slice_profile *p, bool support)
{
    T_OK(slice_profile_default(p), NULL);
    p->support = support;
    p->skirts = 0;
    p->brim_auto = false;
}

/* Slice the 60 x 40 x 20 box with wall_mm walls (no support, skirt or brim)
   and walk its G-code into w. */
static void
slice_box(double wall_mm, const char *name, struct walls *w)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_tray(&m, 60, 40, BOX_H, wall_mm, BOX_FLOOR, false, &err), &err);
    struct slice_profile p;
    bare_profile(&p, false);
    memset(w, 0, sizeof(*w));
    w->loops_min = UINT32_MAX;
    T_OK(ts_slice_walk(&m, &p, name, NULL, on_move, w, &err), &err);
    end_layer(w);
    slice_profile_release(&p);
    mesh_release(&m);
}

T_CASE(thin_walled_box_fills_its_walls_sparse)
{
    struct walls w;
    slice_box(2.4, "box24", &w);
    /* PrusaSlicer 2.5 (the peers' settings) prints this box with 0 mm of
       gap fill: two loops a side, sparse infill in the 0.6 mm between
       them, 658.7 mm of it in all, and 4553.6 mm of filament */
    if (!(w.total_mm > 0 && w.gap_mm < 0.01 * w.total_mm && w.infill_mm > 0.1 * w.total_mm))
        t_fail(__FILE__, __LINE__, "wall middle: %.1f mm gap fill, %.1f mm sparse of %.1f",
               w.gap_mm, w.infill_mm, w.total_mm);
    T_TRUE(w.loops_min >= 4); /* outer and inner face: an external and an inner loop each */
    if (!(w.all_mm < 1.03 * 4553.6))
        t_fail(__FILE__, __LINE__, "%.1f mm of filament, PrusaSlicer 4553.6", w.all_mm);
}

T_CASE(box_walls_too_thin_for_two_loops_print_four_wall_lines)
{
    /* 1.6 mm walls: no second loop fits a side; PrusaSlicer 2.5's Arachne
       prints four perimeter beads (615 mm external, 567 mm inner on a
       10 mm tray).  Ours: the ring between the external loops is two
       wall lines of their own width, printed as perimeters (before:
       gap fill, two wall loops a layer by role) */
    struct walls w;
    slice_box(1.6, "box16", &w);
    if (!(w.total_mm > 0 && w.gap_mm < 0.01 * w.total_mm && w.loops_min >= 4))
        t_fail(__FILE__, __LINE__, "wall middle: %.1f mm gap fill of %.1f, %u wall loops", w.gap_mm,
               w.total_mm, w.loops_min);
}

/* Support filament of m sliced with supports on, and the picture's and the
   optimizers' model's view of it: columns drawn, contacts scored. */
static void
supports_of(const struct mesh *m, const char *name, double *support_mm, size_t *drawn,
            uint32_t *contacts)
{
    struct sf_err err;
    struct slice_profile p;
    bare_profile(&p, true);
    char path[512];
    struct slice_result r;
    T_OK(ts_slice(m, &p, name, &r, path, sizeof(path), &err), &err);
    *support_mm = r.support_mm;
    struct preview_opts o;
    preview_opts_default(&o);
    o.profile = &p;
    struct support_grid g;
    struct support_column *cols = NULL;
    size_t n;
    T_OK(preview_columns(m, &o, &g, &cols, &n, drawn, &err), &err);
    free(cols);
    struct supmodel_params mp;
    supmodel_params_steer(&mp, slice_profile_angle(&p));
    struct supmodel_result mr;
    T_OK(supmodel_of_mesh(m, v3(0, 0, 1), &mp, &mr, &err), &err);
    *contacts = mr.n_contacts;
    slice_profile_release(&p);
}

T_CASE(bridges_are_not_supported_overhangs_are)
{
    struct sf_err err;
    double sup;
    size_t drawn;
    uint32_t contacts;
    /* a 40 x 20 x 15 block with a 10 mm slot, 10 tall, from below along y:
       its roof is bridged wall to wall (PrusaSlicer: no support) */
    struct mesh m;
    mesh_init(&m);
    double x[8] = { 0, 15, 15, 25, 25, 40, 40, 0 }, z[8] = { 0, 0, 10, 10, 0, 0, 15, 15 };
    T_OK(shape_extrude_xz(&m, x, z, 8, 20, &err), &err);
    supports_of(&m, "slot", &sup, &drawn, &contacts);
    if (sup != 0 || drawn != 0 || contacts != 0)
        t_fail(__FILE__, __LINE__, "slot: %.1f mm of support, %zu columns drawn, %u contacts", sup,
               drawn, contacts);
    mesh_release(&m);

    /* a 60 x 40 lid, 8 tall, modelled lip-down: its plate spans 35 mm
       between the lip's walls (PrusaSlicer: no support) */
    mesh_init(&m);
    T_OK(shape_tray(&m, 60, 40, 8, 2.4, 2, true, &err), &err);
    supports_of(&m, "lid", &sup, &drawn, &contacts);
    if (sup != 0 || drawn != 0 || contacts != 0)
        t_fail(__FILE__, __LINE__, "lid: %.1f mm of support, %zu columns drawn, %u contacts", sup,
               drawn, contacts);
    mesh_release(&m);

    /* the tee's 20 mm arms hang free at their ends: held up, in all three */
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    supports_of(&m, "tee", &sup, &drawn, &contacts);
    if (!(sup > 100 && drawn > 10 && contacts > 0))
        t_fail(__FILE__, __LINE__, "tee: %.1f mm of support, %zu columns drawn, %u contacts", sup,
               drawn, contacts);
    mesh_release(&m);
}

T_CASE(ceiling_on_a_plane_is_a_bridge)
{
    /* boxes uploaded upside down, their ceilings (the floor, 1.1-1.9 mm)
       at heights on the layers' cutting planes (8.9 to 26.3 mm): the ray
       hits straddle the plane by float steps, and the model split the
       ceiling between two layers, whose halves it found unanchored and
       held up (mech box_upside: 3.03 g where PrusaSlicer prints 1.11) */
    for (int i = 0; i < 12; i++) {
        struct mesh m;
        struct sf_err err;
        mesh_init(&m);
        double fl = 1.1 + 0.2 * (i % 5), h = 10 + 1.6 * i;
        T_OK(shape_tray(&m, 50.8, 47.1, h, 2.1, fl, true, &err), &err);
        struct supmodel_params mp;
        supmodel_params_steer(&mp, 45);
        struct supmodel_result mr;
        T_OK(supmodel_of_mesh(&m, v3(0, 0, 1), &mp, &mr, &err), &err);
        if (mr.n_contacts != 0)
            t_fail(__FILE__, __LINE__, "%.1f mm box, %.1f mm ceiling: %u contacts, %.2f g", h, fl,
                   mr.n_contacts, mr.grams);
        mesh_release(&m);
    }
}

struct skin {
    double gap_mm, solid_mm, top_mm; /* filament on the steps' skin layers */
    double px, py;
};

static int
on_skin_move(void *ud, const struct est_move *mv)
{
    struct skin *s = ud;
    bool ext = mv->de > 0 && (mv->x != s->px || mv->y != s->py);
    s->px = mv->x;
    s->py = mv->y;
    /* the three layers under each step's top (3 and 6 mm) */
    double dz = fmod(mv->z + 1e-6, 3.0);
    if (!ext || mv->z > 6.1 || !(dz < 0.05 || dz > 2.3))
        return SF_OK;
    if (ts_is_type(mv, "Gap fill"))
        s->gap_mm += mv->de;
    else if (ts_is_type(mv, "Solid infill"))
        s->solid_mm += mv->de;
    else if (ts_is_type(mv, "Top solid infill"))
        s->top_mm += mv->de;
    return SF_OK;
}

T_CASE(narrow_top_strips_are_top_solid_infill)
{
    /* a prism stepped 2 mm in at 3 and 6 mm on both sides: each step's top
       is a strip about 1.1 mm wide inside the loops.  PrusaSlicer prints
       such strips as top solid infill (its gap fill stays between the
       loops); ours laid them as gap fill, so the part had no top skin by
       role, was printed at gap fill's speed instead of the top's, and the
       bench flagged the shared cow WEAKER (top 0.20 vs 0.60 mm) */
    static const double x[] = { 0, 30, 30, 28, 28, 26, 26, 4, 4, 2, 2, 0 };
    static const double z[] = { 0, 0, 3, 3, 6, 6, 9, 9, 6, 6, 3, 3 };
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_extrude_xz(&m, x, z, 12, 20, &err), &err);
    struct slice_profile p;
    bare_profile(&p, false);
    struct skin s = { 0 };
    T_OK(ts_slice_walk(&m, &p, "steps", NULL, on_skin_move, &s, &err), &err);
    if (!(s.top_mm > 5 && s.gap_mm < 0.05 * (s.gap_mm + s.solid_mm + s.top_mm)))
        t_fail(__FILE__, __LINE__, "steps' skin: %.1f mm top solid, %.1f solid, %.1f gap fill",
               s.top_mm, s.solid_mm, s.gap_mm);
    slice_profile_release(&p);
    mesh_release(&m);
}

/* Triangular prism from z0 to z1 over the right triangle with its right
   angle at (x, y) and legs a along x and b along y. */
static int
gusset_prism(struct mesh *m, double x, double y, double a, double b, double z0, double z1)
{
    struct vec3 v[6] = { v3(x, y, z0), v3(x + a, y, z0), v3(x, y + b, z0),
                         v3(x, y, z1), v3(x + a, y, z1), v3(x, y + b, z1) };
    static const uint32_t t[8][3] = { { 0, 2, 1 }, { 3, 4, 5 }, { 0, 1, 4 }, { 0, 4, 3 },
                                      { 1, 2, 5 }, { 1, 5, 4 }, { 2, 0, 3 }, { 2, 3, 5 } };
    return ts_add(m, v, 6, t, 8) < 0 ? SF_ENOMEM : SF_OK;
}

T_CASE(gusset_is_bridged_along_its_hypotenuse)
{
    /* An L bracket on its side (mech bracket_side without its holes): two
       3.9 mm walls 24.4 tall, and in their corner a 3.9 mm gusset plate
       10 mm up, its legs 17.8 and 20.4 mm.  Lines parallel to the
       hypotenuse (49 degrees) run leg to leg, so PrusaSlicer's bridge
       detector, which tries the bridge's own edge directions, bridges it
       whole and prints no support under it.  The model tried 8 lattice
       directions only: at 45 degrees the lines near the hypotenuse end in
       the air, so a band along it was held up (bracket_side: 1.53 g of
       support where PrusaSlicer prints 1.00, filament 1.06 x its) */
    struct mesh m;
    mesh_init(&m);
    T_OK(ts_box(&m, 0, 0, 0, 33.6, 3.9, 24.4) < 0 ? SF_ENOMEM : SF_OK, NULL);
    T_OK(ts_box(&m, 0, 0, 0, 3.9, 37.9, 24.4) < 0 ? SF_ENOMEM : SF_OK, NULL);
    T_OK(gusset_prism(&m, 3.8, 3.8, 17.9, 20.5, 10.25, 14.15), NULL);
    double sup;
    size_t drawn;
    uint32_t contacts;
    supports_of(&m, "gusset", &sup, &drawn, &contacts);
    if (sup != 0 || drawn != 0 || contacts != 0)
        t_fail(__FILE__, __LINE__, "gusset: %.1f mm of support, %zu columns drawn, %u contacts",
               sup, drawn, contacts);
    mesh_release(&m);
}

T_CASE(support_spilling_across_a_wall_stays_on_its_side)
{
    /* mech box_upside without its rounded corners: a 50.8 x 47.1 x 25.2
       box with 2.1 mm walls printed upside down, the outer half of its wall
       cut back 3 mm at the rim, so a 1.05 mm ledge hangs outside the inner
       half.  The ledge's 2.84 mm snap cells reach across the inner half
       into the box; PrusaSlicer keeps of each layer's snapped support only
       the islands the contacts' projection reaches (extract_support), so it
       prints none inside.  Ours printed a ring inside the box too (1.42 g
       of support where PrusaSlicer prints 1.11). */
    struct mesh m, lip;
    struct sf_err err;
    mesh_init(&m);
    mesh_init(&lip);
    T_OK(shape_tray(&m, 50.8, 47.1, 22.2, 2.1, 1.3, true, &err), &err);
    for (uint32_t v = 0; v < m.n_verts; v++)
        m.v[v].z += 3;
    /* the inner half of the wall below the ledge, into the box above */
    double a = 1.05, b = 2.1, x1 = 50.8 - a, y1 = 47.1 - a;
    T_TRUE(ts_box(&lip, a, a, 0, x1, b, 3.1) == 0 && ts_box(&lip, a, y1 - a, 0, x1, y1, 3.1) == 0 &&
           ts_box(&lip, a, a, 0, b, y1, 3.1) == 0 && ts_box(&lip, x1 - a, a, 0, x1, y1, 3.1) == 0);
    T_OK(ts_merge(&m, &lip), NULL);
    struct slice_profile p;
    bare_profile(&p, true);
    struct support_grid g;
    struct support_column *cols;
    size_t n, cap, n_body, inside = 0, outside = 0;
    T_OK(support_columns(&m, &p, &g, &cols, &n, &cap, &n_body, &err), &err);
    for (size_t k = 0; k < n_body; k++) {
        double x = g.x0 + (double)(cols[k].cell % g.nu) * g.pitch;
        double y = g.y0 + (double)(cols[k].cell / g.nu) * g.pitch;
        if (x > b + 0.2 && x < 50.8 - b - 0.2 && y > b + 0.2 && y < 47.1 - b - 0.2)
            inside++;
        else
            outside++;
    }
    if (inside || !outside)
        t_fail(__FILE__, __LINE__, "%zu columns inside the box, %zu outside", inside, outside);
    free(cols);
    slice_profile_release(&p);
    mesh_release(&lip);
    mesh_release(&m);
}

struct by_z {
    double perim_mm[2]; /* inner perimeters: the plate's last layer, the one under it */
    double px, py;
};

static int
on_plate_move(void *ud, const struct est_move *mv)
{
    struct by_z *b = ud;
    bool ext = mv->de > 0 && (mv->x != b->px || mv->y != b->py);
    b->px = mv->x;
    b->py = mv->y;
    if (ext && ts_is_type(mv, "Perimeter")) {
        if (fabs(mv->z - 1.2) < 0.01)
            b->perim_mm[0] += mv->de;
        else if (fabs(mv->z - 1.0) < 0.01)
            b->perim_mm[1] += mv->de;
    }
    return SF_OK;
}

T_CASE(plate_under_a_lip_gets_extra_perimeters)
{
    /* mech lid_up: a 1.2 mm plate with a 1.6 mm lip standing 1.35 mm in
       from its edge.  PrusaSlicer 2.5 (extra_perimeters, on by default and
       in the peers' runs) adds loops to the plate's last layer while over
       30 % of the lip's outline lies in the 1.5 spacings just inside them:
       four loops there, so the lip's walls stand on perimeters.  Ours laid
       two, and the bench flagged lid_up WEAKER (2.00 loops a contour, its
       2.06).  Off, the layer keeps its two. */
    struct mesh m;
    mesh_init(&m);
    double e = 1.35, lw = 1.6, x1 = 60 - e, y1 = 40 - e, z1 = 4.2;
    T_TRUE(ts_box(&m, 0, 0, 0, 60, 40, 1.2) == 0 && ts_box(&m, e, e, 1.1, x1, e + lw, z1) == 0 &&
           ts_box(&m, e, y1 - lw, 1.1, x1, y1, z1) == 0 &&
           ts_box(&m, e, e, 1.1, e + lw, y1, z1) == 0 &&
           ts_box(&m, x1 - lw, e, 1.1, x1, y1, z1) == 0);
    for (int on = 0; on < 2; on++) {
        struct slice_profile p;
        struct sf_err err;
        bare_profile(&p, false);
        p.extra_perimeters = on;
        struct by_z b = { { 0, 0 }, 0, 0 };
        T_OK(ts_slice_walk(&m, &p, on ? "plate_extra" : "plate", NULL, on_plate_move, &b, &err),
             &err);
        /* one inner loop under the plate's last layer; three on it (on) */
        double r = b.perim_mm[0] / b.perim_mm[1];
        if (on ? !(r > 2.7 && r < 3.1) : !(r > 0.95 && r < 1.05))
            t_fail(__FILE__, __LINE__,
                   "extra_perimeters %s: last layer's inner perimeters %.1f mm, "
                   "the layer under it %.1f mm",
                   on ? "on" : "off", b.perim_mm[0], b.perim_mm[1]);
        slice_profile_release(&p);
    }
    mesh_release(&m);
}
