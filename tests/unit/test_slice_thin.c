/*
 * test_slice_thin.c - thin walls and gap fill: walls narrower than two
 * lines print (a 0.4 mm wall printed nothing before, a 0.6 mm one a loop
 * around a sliver, 1.3 x its volume), every one lays down its own volume
 * (the 2-3 mm ones 6-13 % more before, zig-zag links in narrow infill)
 * within a few percent, plus PrusaSlicer's infill overlap where a strip
 * inside the loops is wide enough to be infill, and a 0.6 mm wall is one
 * line along its middle.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "../../slicer/estimate.h"
#include "../../slicer/slice.h"
#include "../../src/base/buf.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"
#include "slice_run.h"

struct gaps {
    double gap_mm;  /* filament of gap fill */
    double x0, x1;  /* x range of gap fill moves */
    uint32_t n_gap; /* gap fill moves */
    double px, py;
};

static int
on_move(void *ud, const struct est_move *mv)
{
    struct gaps *g = ud;
    if (mv->de > 0 && mv->type && mv->type_len == 8 && memcmp(mv->type, "Gap fill", 8) == 0 &&
        (mv->x != g->px || mv->y != g->py)) {
        g->gap_mm += mv->de;
        g->x0 = fmin(g->x0, mv->x);
        g->x1 = fmax(g->x1, mv->x);
        g->n_gap++;
    }
    g->px = mv->x;
    g->py = mv->y;
    return SF_OK;
}

static int
slice_wall(double wall_mm, bool gap_fill, struct slice_result *r, struct gaps *g,
           struct sf_err *err)
{
    struct mesh m;
    mesh_init(&m);
    int rc = shape_box(&m, v3(0, 0, 0), v3(wall_mm, 20, 10), err);
    struct slice_profile p;
    if (rc == SF_OK && (rc = slice_profile_default(&p)) == SF_OK) {
        p.support = false;
        p.skirts = 0;
        p.brim_auto = false;
        p.gap_fill = gap_fill;
        char name[64];
        snprintf(name, sizeof(name), "wall%g%s", wall_mm, gap_fill ? "" : "-");
        memset(g, 0, sizeof(*g));
        g->x0 = INFINITY;
        g->x1 = -INFINITY;
        rc = ts_slice_walk(&m, &p, name, r, on_move, g, err);
        slice_profile_release(&p);
    }
    mesh_release(&m);
    return rc;
}

T_CASE(thin_walls_print_their_volume)
{
    struct sf_err err;
    struct slice_result r;
    struct gaps g;
    double fil = M_PI * 1.75 * 1.75 / 4;
    /* without gap fill neither prints: no loop fits (the old generator
       printed nothing for 0.4 mm and a loop around a sliver, 1.3 x the
       volume, for 0.6; the loop below fails on it) */
    T_OK(slice_wall(0.4, false, &r, &g, &err), &err);
    T_EQ_DBL(r.filament_mm, 0, 1e-9);
    T_OK(slice_wall(0.6, false, &r, &g, &err), &err);
    T_EQ_DBL(r.filament_mm, 0, 1e-9);
    const double walls[] = { 0.4, 0.6, 1.0, 1.2, 1.5, 2.0, 2.5, 3.0 };
    for (size_t i = 0; i < sizeof(walls) / sizeof(walls[0]); i++) {
        T_OK(slice_wall(walls[i], true, &r, &g, &err), &err);
        double v = r.filament_mm * fil, want = walls[i] * 20 * 10;
        /* a strip inside the loops at least min_bead_width (0.34 mm) wide
           is infill, grown infill_overlap (25 % of the 0.407 mm loop
           spacing) into the loops on every side, as PrusaSlicer lays it
           (2.5 / 3 mm walls: 527.6 / 628.6 mm3 in PrusaSlicer 2.5);
           narrower leftovers print their own area */
        double sp = 0.45 - 0.2 * (1 - M_PI / 4), d = 0.45 / 2 + 1.5 * sp;
        double sw = walls[i] - 2 * d, sl = 20 - 2 * d;
        if (sw >= 0.85 * 0.4)
            want += 0.25 * sp * 2 * (sw + sl) * 10;
        /* the perimeter flow model leaves w - spacing (0.04 mm) at the edges */
        if (fabs(v - want) > 0.05 * want)
            t_fail(__FILE__, __LINE__, "%.1f mm wall: %.1f mm3 extruded, want %.1f", walls[i], v,
                   want);
    }
    /* a 0.6 mm wall (x 124.7..125.3 on the bed) is one line along its middle, each layer */
    T_OK(slice_wall(0.6, true, &r, &g, &err), &err);
    T_TRUE(g.gap_mm > 0.95 * r.filament_mm);
    T_TRUE(g.x0 > 124.95 && g.x1 < 125.05);
    T_TRUE(g.n_gap >= 50 && g.n_gap < 50 * 4);
}

T_CASE(thin_disk_on_edge_prints_its_volume)
{
    /* a 40 mm disc 2.5 mm thick standing on its edge: every layer a strip
       too narrow for infill lines beside the perimeters */
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    double x[64], z[64];
    for (int i = 0; i < 64; i++) {
        x[i] = 20 * cos(2 * M_PI * i / 64);
        z[i] = 20 + 20 * sin(2 * M_PI * i / 64);
    }
    T_OK(shape_extrude_xz(&m, x, z, 64, 2.5, &err), &err);
    double area = 0;
    for (int i = 0; i < 64; i++)
        area += x[i] * z[(i + 1) % 64] - x[(i + 1) % 64] * z[i];
    double want = fabs(area) / 2 * 2.5;
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    p.support = false;
    p.skirts = 0;
    p.brim_auto = false;
    char path[512];
    snprintf(path, sizeof(path), "%s/disk.gcode", t_tmpdir());
    struct slice_result r;
    /* without the infill overlap: the disc's own volume */
    p.infill_overlap = 0;
    T_OK(slice_mesh(&m, &p, path, &r, NULL, NULL, &err), &err);
    double v = r.filament_mm * M_PI * 1.75 * 1.75 / 4;
    if (fabs(v - want) > 0.04 * want)
        t_fail(__FILE__, __LINE__, "disk: %.0f mm3 extruded, its volume is %.0f", v, want);
    /* with it (PrusaSlicer's 25 %), the volume and the band the strip
       inside the loops grows into them on every layer: PrusaSlicer 2.5
       lays 5-6 % more than the volume on such discs (2.5 and 3 mm; our
       -7 % / -6 % there came from leaving that band out) */
    p.infill_overlap = 0.25;
    T_OK(slice_mesh(&m, &p, path, &r, NULL, NULL, &err), &err);
    double sp = 0.45 - 0.2 * (1 - M_PI / 4), d = 0.45 / 2 + 1.5 * sp, band = 0;
    for (int k = 0; k < 200; k++) {
        double zc = 0.2 * k + 0.1 - 20, chord = 2 * sqrt(fmax(0, 400 - zc * zc));
        if (chord > 2 * d && 2.5 - 2 * d >= 0.85 * 0.4)
            band += 0.25 * sp * 2 * (chord - 2 * d + 2.5 - 2 * d) * 0.2;
    }
    v = r.filament_mm * M_PI * 1.75 * 1.75 / 4;
    if (fabs(v - (want + band)) > 0.04 * (want + band))
        t_fail(__FILE__, __LINE__, "disk: %.0f mm3 extruded, want %.0f + %.0f (overlap)", v, want,
               band);
    T_TRUE(v > 1.03 * want);
    /* without gap fill the strips' zig-zag links overfill it */
    p.gap_fill = false;
    T_OK(slice_mesh(&m, &p, path, &r, NULL, NULL, &err), &err);
    T_TRUE(r.filament_mm * M_PI * 1.75 * 1.75 / 4 > 1.05 * want);
    slice_profile_release(&p);
    mesh_release(&m);
}
