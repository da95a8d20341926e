/*
 * test_slice.c - the slicer end to end on generated parts: extruded volume
 * of a cube, supports of a T-shape (under the arms, nowhere else, the
 * same volume as the metrics module's ray cast), G-code read back into
 * the writer's moves, placeholders, and the shared meshes when present.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "../../slicer/estimate.h"
#include "../../slicer/gcwrite.h"
#include "../../slicer/slice.h"
#include "../../slicer/toolpath.h"
#include "../../src/base/buf.h"
#include "../../src/base/mem.h"
#include "../../src/geom/measure.h"
#include "../../src/geom/supmodel.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"
#include "slice_run.h"
#include "slice_shapes.h"

static double
fil_area(const struct slice_profile *p)
{
    return M_PI * p->filament_mm * p->filament_mm / 4;
}

T_CASE(slice_cube_extrudes_its_volume)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_box(&m, v3(0, 0, 0), v3(20, 20, 20), &err), &err);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    p.skirts = 0; /* the cube's volume alone */
    char path[512];
    struct slice_result r;
    /* solid: every mm^3 of the cube is extruded */
    p.infill_density = 1;
    T_TRUE(slice_profile_set(&p, "infill_pattern=rectilinear", &err) == SF_OK);
    T_OK(ts_slice(&m, &p, "cube_solid", &r, path, sizeof(path), &err), &err);
    T_EQ_INT(r.n_layers, 100);
    double v = r.filament_mm * fil_area(&p);
    T_TRUE(fabs(v - 8000) < 0.03 * 8000);
    /* 15 % grid: shell solid, the sparse core at 15 % (anchors off: they
       are extra material by design, tested in test_slice_layers) */
    p.infill_density = 0.15;
    p.infill_anchor_mm = 0;
    p.infill_anchor_max_mm = 0;
    T_TRUE(slice_profile_set(&p, "infill_pattern=grid", &err) == SF_OK);
    T_OK(ts_slice(&m, &p, "cube_grid", &r, path, sizeof(path), &err), &err);
    double sp = tp_spacing(p.width_mm, 0.2);
    double a = 20 - 2 * (p.width_mm / 2 + (p.perimeters - 1) * sp + sp / 2);
    int sparse_layers = 100 - p.top_layers - p.bottom_layers;
    double want = 8000 - sparse_layers * 0.2 * a * a * (1 - p.infill_density);
    v = r.filament_mm * fil_area(&p);
    if (fabs(v - want) > 0.03 * want)
        t_fail(__FILE__, __LINE__, "extruded %.1f mm3, want %.1f", v, want);
    T_EQ_DBL(r.support_g, 0, 1e-9);
    T_TRUE(r.time_s > 600 && r.time_s < 1500);
    slice_profile_release(&p);
    mesh_release(&m);
}

struct tee_check {
    uint32_t n_support, n_bad;
    double left, right; /* support extrusion on each side, mm */
    double zmax;
    double last[3];
};

static int
on_tee_move(void *ud, const struct est_move *mv)
{
    struct tee_check *c = ud;
    if (mv->support && mv->de > 0) {
        double dx = mv->x - 125;
        c->n_support++;
        double dy = fabs(mv->y - 105);
        /* under the arms (5.25 to 25 mm out, 10 mm either side), or at
           most a snap cell past their outline, clear of the post, as
           PrusaSlicer's (its lines reach 25.7 and 11.6 mm out, and run
           past the post's sides); the bed layer 3 mm further, a flange
           as PrusaSlicer's (raft_first_layer_expansion) */
        double out = 2.84 + (mv->z < 0.2 + 1e-6 ? 3 : 0);
        if ((fabs(dx) < 5.25 && dy < 10.25) || fabs(dx) > 25 + out || dy > 10 + out ||
            mv->z > 29.8 + 1e-6)
            c->n_bad++;
        if (dx < 0)
            c->left += mv->de;
        else
            c->right += mv->de;
        if (mv->z > c->zmax)
            c->zmax = mv->z;
    }
    return SF_OK;
}

T_CASE(slice_tee_supports_arms_only)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    char path[512];
    struct slice_result r;
    T_OK(ts_slice(&m, &p, "tee", &r, path, sizeof(path), &err), &err);
    T_TRUE(r.n_columns > 0);
    T_EQ_INT(r.n_island_columns, 0);
    /* the regions printed agree with the metrics module's ray-cast volume */
    if (fabs(r.support_volume_mm3 - r.ray_volume_mm3) > 0.04 * r.ray_volume_mm3)
        t_fail(__FILE__, __LINE__, "support regions %.0f mm3, ray cast %.0f mm3",
               r.support_volume_mm3, r.ray_volume_mm3);
    struct support_params sp;
    support_params_default(&sp);
    struct raycast *rc = raycast_new(&m, &err);
    T_TRUE(rc != NULL);
    struct support_metrics sm;
    T_OK(measure_support(&m, rc, v3(0, 0, 1), &sp, &sm, &err), &err);
    raycast_free(rc);
    /* the columns come from the layer-based support model (supmodel.h),
       snapped to PrusaSlicer's 3 mm grid cells, with its bridge exemption:
       part of the arms' shadow as the ray cast sees it, over the arms'
       whole extent (PrusaSlicer 2.5 prints 6.17 g of support under this
       tee; ours 6.06 g, 6.92 g before its lines ran one way 2.857 mm
       apart, 5.56 g before the columns reached past the arms' outline in
       0.4 mm lines, and 7.48 g when the slicer stood every column) */
    if (!(r.ray_volume_mm3 > 0.3 * sm.volume_mm3 && r.ray_volume_mm3 < 0.8 * sm.volume_mm3))
        t_fail(__FILE__, __LINE__, "columns %.0f mm3, the arms' shadow %.0f mm3", r.ray_volume_mm3,
               sm.volume_mm3);
    /* read the file back: support only under the arms, below the bar */
    struct buf b;
    buf_init(&b, 0);
    T_OK(buf_read_file(&b, path, &err), &err);
    struct est_limits lim;
    slice_limits(&p, &lim);
    struct tee_check c = { 0 };
    struct estimate e;
    T_OK(estimate_gcode(b.data, b.len, path, &lim, on_tee_move, &c, &e, &err), &err);
    buf_release(&b);
    T_TRUE(c.n_support > 100);
    T_EQ_INT(c.n_bad, 0);
    T_TRUE(c.left > 0.4 * (c.left + c.right) && c.right > 0.4 * (c.left + c.right));
    T_EQ_DBL(c.zmax, 29.8, 1e-6);
    T_EQ_DBL(e.support_mm, r.support_mm, 1e-6);
    T_EQ_DBL(e.time_s, r.time_s, 0.02 * r.time_s); /* header estimate: body only */
    estimate_release(&e);
    /* without support, no support at all */
    p.support = false;
    T_OK(ts_slice(&m, &p, "tee_off", &r, path, sizeof(path), &err), &err);
    T_EQ_DBL(r.support_mm, 0, 1e-12);
    slice_profile_release(&p);
    mesh_release(&m);
}

T_CASE(slice_island_gets_support)
{
    /* an octahedron hanging tip-down 5 mm above a plate: its faces lean
       19.5 deg from vertical, so no ray column; the tip is an island */
    struct mesh m, b;
    struct sf_err err;
    mesh_init(&m);
    mesh_init(&b);
    T_OK(shape_box(&m, v3(-15, -15, 0), v3(15, 15, 2), &err), &err);
    double r[3] = { 0, 5, 0 }, z[3] = { 0, 10, 20 };
    T_OK(shape_revolve(&b, r, z, 3, 4, &err), &err);
    mesh_translate(&b, v3(0, 0, 7));
    T_OK(ts_merge(&m, &b), NULL);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    char path[512];
    struct slice_result res;
    T_OK(ts_slice(&m, &p, "island", &res, path, sizeof(path), &err), &err);
    /* the support model's layer rule finds the tip itself (no neighbouring
       column is solid below it); its columns fill the snap cells (of the
       model's raster cells) the tip's rays fall in, at most four */
    struct supmodel_params mp;
    supmodel_params_default(&mp, SUPMODEL_PRUSA);
    mp.pitch_mm = p.support_pitch_mm;
    double k = round(mp.snap_mm / supmodel_raster_pitch(&mp)); /* raster cells a side */
    if (res.n_columns + res.n_island_columns < 1 ||
        res.n_columns + res.n_island_columns > 4 * k * k + 4)
        t_fail(__FILE__, __LINE__, "%u columns, %u island columns", res.n_columns,
               res.n_island_columns);
    /* from the plate (+0.2 gap) to 0.2 under the tip (4.6 mm), in the cells
       beside the tip up to the cone's underside, which rises 2.8 mm a mm:
       at least one cell, at most four snap cells 10 mm tall */
    if (!(res.support_volume_mm3 > 0.6 * 4.6 && res.support_volume_mm3 < 4 * 9 * 10))
        t_fail(__FILE__, __LINE__, "support volume %.2f mm3", res.support_volume_mm3);
    T_TRUE(res.support_g > 0);
    /* with supports off nothing */
    p.support = false;
    T_OK(ts_slice(&m, &p, "island_off", &res, path, sizeof(path), &err), &err);
    T_EQ_DBL(res.support_volume_mm3, 0, 1e-12);
    slice_profile_release(&p);
    mesh_release(&m);
    mesh_release(&b);
}

struct written {
    double (*mv)[4]; /* x y z e of every move the writer wrote */
    size_t n, cap;
};

static void
on_write(void *ud, double x, double y, double z, double e)
{
    struct written *w = ud;
    if (mem_grow((void **)&w->mv, &w->cap, w->n + 1, sizeof(*w->mv))) {
        w->mv[w->n][0] = x;
        w->mv[w->n][1] = y;
        w->mv[w->n][2] = z;
        w->mv[w->n][3] = e;
        w->n++;
    }
}

struct readback {
    uint32_t n, n_differ;
    const struct written *w;
    double zmin, zmax;
};

static int
on_move(void *ud, const struct est_move *mv)
{
    struct readback *rb = ud;
    /* the same move the writer meant: positions to the 3 decimals written,
       E (absolute sense) to the 5 decimals written */
    if (rb->n < rb->w->n) {
        const double *m = rb->w->mv[rb->n];
        if (fabs(m[0] - mv->x) > 1e-9 || fabs(m[1] - mv->y) > 1e-9 || fabs(m[2] - mv->z) > 1e-9 ||
            fabs(m[3] - mv->e) > 6e-6)
            rb->n_differ++;
    }
    rb->n++;
    if (mv->de <= 0)
        return SF_OK;
    if (mv->z < rb->zmin)
        rb->zmin = mv->z;
    if (mv->z > rb->zmax)
        rb->zmax = mv->z;
    return SF_OK;
}

T_CASE(gcode_reads_back_into_the_same_moves)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_frame(&m, &err), &err);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    struct layer_stack s;
    T_OK(layers_slice(&m, 0.2, 0.2, 50, 50, &s, &err), &err);
    struct layer_paths *lp = mem_calloc(s.n, sizeof(*lp));
    T_TRUE(lp != NULL);
    for (uint32_t k = 0; k < s.n; k++)
        T_OK(toolpath_areas(&s, k, &p), NULL);
    for (uint32_t k = 0; k < s.n; k++)
        T_OK(toolpath_layer(&s, k, &p, NULL, &lp[k]), NULL);
    for (int rel = 0; rel < 2; rel++) {
        p.e_relative = rel;
        struct buf b;
        buf_init(&b, 0);
        struct gcw_stats st;
        struct written wr = { 0 };
        T_OK(gcw_body(&s, lp, &p, &b, &st, on_write, &wr, &err), &err);
        struct est_limits lim;
        slice_limits(&p, &lim);
        struct readback rb = { .w = &wr, .zmin = 1e9, .zmax = -1e9 };
        struct estimate e;
        T_OK(estimate_gcode(b.data, b.len, "body", &lim, on_move, &rb, &e, &err), &err);
        T_EQ_INT(rb.n, st.n_moves);
        T_EQ_INT(wr.n, st.n_moves);
        T_EQ_INT(rb.n_differ, 0);
        gcw_stats_release(&st);
        free(wr.mv);
        double sum = 0;
        for (int r = 0; r < ROLE_N; r++)
            sum += st.e_mm[r];
        T_EQ_DBL(e.filament_mm, sum, 1e-5 * st.n_moves);
        T_EQ_INT(e.n_layers, s.n);
        T_EQ_DBL(rb.zmin, 0.2, 1e-9);
        T_EQ_DBL(rb.zmax, 10.0, 1e-9);
        estimate_release(&e);
        buf_release(&b);
    }
    for (uint32_t k = 0; k < s.n; k++)
        layer_paths_release(&lp[k]);
    free(lp);
    layer_stack_release(&s);
    slice_profile_release(&p);
    mesh_release(&m);
}

T_CASE(slice_placeholders_and_bad_placeholder)
{
    struct slice_profile p;
    struct sf_err err;
    T_OK(slice_profile_default(&p), NULL);
    struct buf b;
    buf_init(&b, 0);
    T_OK(slice_expand(&p, "start_gcode", "M190 S{bed_temp}\nM109 S{nozzle_temp} ; {printer}", &b,
                      &err),
         &err);
    T_EQ_STR(b.data, "M190 S60\nM109 S210 ; generic-marlin\n");
    buf_reset(&b);
    T_ERR(slice_expand(&p, "end_gcode", "M104 S{hot}", &b, &err), SF_EINVAL, &err,
          "end_gcode: unknown placeholder '{hot}'");
    buf_release(&b);
    slice_profile_release(&p);
}

T_CASE(slice_rejects_part_larger_than_bed)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_box(&m, v3(0, 0, 0), v3(300, 20, 20), &err), &err);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    char path[512];
    T_ERR(ts_slice(&m, &p, "big", NULL, path, sizeof(path), &err), SF_EINVAL, &err, "does not fit");
    slice_profile_release(&p);
    mesh_release(&m);
}

struct bed_check {
    double bx, by;
    uint32_t out;
};

static int
on_bed_move(void *ud, const struct est_move *mv)
{
    struct bed_check *c = ud;
    if (mv->x < 0 || mv->y < 0 || mv->x > c->bx || mv->y > c->by)
        c->out++;
    return SF_OK;
}

T_CASE(slice_shared_mesh_stays_on_bed)
{
    const char *path = t_shared_mesh("anchor.stl");
    T_SKIP_UNLESS(path, "../shared/meshes not present");
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(mesh_load(path, &m, NULL, &err), &err);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    char out[512];
    struct slice_result r;
    T_OK(ts_slice(&m, &p, "anchor", &r, out, sizeof(out), &err), &err);
    T_TRUE(r.n_layers > 100 && r.support_g > 0 && r.filament_g > r.support_g);
    struct buf b;
    buf_init(&b, 0);
    T_OK(buf_read_file(&b, out, &err), &err);
    struct est_limits lim;
    slice_limits(&p, &lim);
    struct bed_check c = { p.bed_x_mm, p.bed_y_mm, 0 };
    struct estimate e;
    T_OK(estimate_gcode(b.data, b.len, out, &lim, on_bed_move, &c, &e, &err), &err);
    T_EQ_INT(c.out, 0);
    estimate_release(&e);
    buf_release(&b);
    slice_profile_release(&p);
    mesh_release(&m);
}

static int
cancel_at_toolpaths(void *ud, const char *stage, double done)
{
    int *calls = ud;
    (*calls)++;
    return strcmp(stage, "toolpaths") == 0 && done > 0.2;
}

T_CASE(slice_progress_and_cancel)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    char path[512];
    snprintf(path, sizeof(path), "%s/cancel.gcode", t_tmpdir());
    int calls = 0;
    T_ERR(slice_mesh(&m, &p, path, NULL, cancel_at_toolpaths, &calls, &err), SF_ECANCELED, &err,
          "cancel");
    T_TRUE(calls > 3);
    FILE *f = fopen(path, "r");
    T_TRUE(f == NULL); /* no file written */
    slice_profile_release(&p);
    mesh_release(&m);
}

T_CASE(slice_m73_progress_is_monotone)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_arch(&m, &err), &err);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    char path[512];
    struct slice_result r;
    T_OK(ts_slice(&m, &p, "arch", &r, path, sizeof(path), &err), &err);
    FILE *f = fopen(path, "r");
    T_TRUE(f != NULL);
    char line[512];
    long last_p = -1, last_r = 1L << 30, n = 0, layers = 0;
    bool ok = true;
    while (fgets(line, sizeof(line), f)) {
        long pp, rr;
        if (sscanf(line, "M73 P%ld R%ld", &pp, &rr) == 2) {
            ok = ok && pp >= last_p && rr <= last_r && pp <= 100;
            last_p = pp;
            last_r = rr;
            n++;
        }
        layers += strncmp(line, ";LAYER_CHANGE", 13) == 0;
    }
    fclose(f);
    T_TRUE(ok);
    T_EQ_INT(last_p, 100);
    T_EQ_INT(last_r, 0);
    T_EQ_INT(n, layers + 2);
    T_EQ_INT(layers, r.n_layers);
    slice_profile_release(&p);
    mesh_release(&m);
}

T_CASE(slice_prints_island_by_island)
{
    /* two separate posts: each layer prints one post completely (its
       perimeters and infill), then the other */
    struct mesh m, b;
    struct sf_err err;
    mesh_init(&m);
    mesh_init(&b);
    T_OK(shape_box(&m, v3(0, 0, 0), v3(10, 10, 5), &err), &err);
    T_OK(shape_box(&b, v3(30, 0, 0), v3(40, 10, 5), &err), &err);
    T_OK(ts_merge(&m, &b), NULL);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    char path[512];
    struct slice_result r;
    T_OK(ts_slice(&m, &p, "posts", &r, path, sizeof(path), &err), &err);
    FILE *f = fopen(path, "r");
    T_TRUE(f != NULL);
    char line[512];
    int layer = -1, ext = 0, switches = 0, side = -1;
    while (fgets(line, sizeof(line), f)) {
        if (strncmp(line, ";LAYER_CHANGE", 13) == 0) {
            layer++;
            side = -1;
        }
        if (layer == 12 && strncmp(line, ";TYPE:External perimeter", 24) == 0)
            ext++;
        double x;
        if (layer == 12 && sscanf(line, "G1 X%lf", &x) == 1 && strstr(line, " E")) {
            int s = x > 125;
            if (side >= 0 && s != side)
                switches++;
            side = s;
        }
    }
    fclose(f);
    T_EQ_INT(ext, 2);
    T_EQ_INT(switches, 1); /* extrusion moves change posts once per layer */
    slice_profile_release(&p);
    mesh_release(&m);
    mesh_release(&b);
}

/* x extents, over the layers above the bed layer, of the external
   perimeters and of the solid infill (solid and top solid) */
struct solid_span {
    double ext_lo, solid_lo;
};

static int
on_solid_move(void *ud, const struct est_move *mv)
{
    struct solid_span *w = ud;
    if (!(mv->de > 0) || mv->layer < 2)
        return SF_OK;
    if (ts_is_type(mv, "External perimeter"))
        w->ext_lo = fmin(w->ext_lo, mv->x);
    if (ts_is_type(mv, "Solid infill") || ts_is_type(mv, "Top solid infill"))
        w->solid_lo = fmin(w->solid_lo, mv->x);
    return SF_OK;
}

T_CASE(slice_solid_lines_stop_where_prusaslicers_do)
{
    /* a 20 x 20 x 2 mm plate is solid through: PrusaSlicer 2.5 zig-zags
       its solid lines along the inner area grown infill_overlap (0.1 mm)
       and shrunk half a solid spacing (0.204): 0.10 mm inside the inner
       perimeter's inner edge, 0.713 mm in from the external perimeter's
       centre line (0.2035 + 0.407 + 0.102).  Ours ran to the inner edge
       (0.611), 5.9 % more solid infill across the hook's 4 mm arm of the
       mech set */
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    p.skirts = 0;
    p.brim_auto = false;
    struct solid_span w = { INFINITY, INFINITY };
    struct sf_err err;
    struct mesh m;
    mesh_init(&m);
    T_OK(shape_box(&m, v3(0, 0, 0), v3(20, 20, 2), &err), &err);
    T_OK(ts_slice_walk(&m, &p, "plate2", NULL, on_solid_move, &w, &err), &err);
    double sp = 0.45 - 0.2 * (1 - M_PI / 4), want = sp / 2 + sp + (0.5 - 0.25) * sp;
    if (fabs(w.solid_lo - w.ext_lo - want) > 0.03)
        t_fail(__FILE__, __LINE__, "solid lines from %.3f mm in, want %.3f", w.solid_lo - w.ext_lo,
               want);
    slice_profile_release(&p);
    mesh_release(&m);
}
