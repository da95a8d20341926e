/*
 * test_slice_layers.c - cross-sections of analytic shapes: exact areas per
 * layer, holes, vertices lying exactly on a cutting plane, sliver
 * triangles, an open mesh.
 */
#include <math.h>

#include "../../slicer/clip_shim.h"
#include "../../slicer/layers.h"
#include "../../slicer/toolpath.h"
#include "../t.h"
#include "slice_shapes.h"

T_CASE(slice_cube_layers_and_area)
{
    struct mesh m = { 0 };
    struct sf_err err;
    T_TRUE(ts_box(&m, 0, 0, 0, 20, 20, 20) == 0);
    struct layer_stack s;
    T_OK(layers_slice(&m, 0.2, 0.2, 100, 100, &s, &err), &err);
    T_EQ_INT(s.n, 100);
    for (uint32_t k = 0; k < s.n; k++) {
        T_EQ_DBL(paths_area(&s.l[k].region), 400.0, 1e-6);
        T_EQ_INT(s.l[k].region.n, 1);
    }
    T_EQ_DBL(s.l[99].z_mm, 20.0, 1e-9);
    struct ipt lo, hi;
    T_TRUE(paths_bbox(&s.l[0].region, &lo, &hi));
    T_EQ_DBL(poly_mm(lo.x), 90, 1e-9);
    T_EQ_DBL(poly_mm(hi.y), 110, 1e-9);
    layer_stack_release(&s);
    ts_free(&m);
}

T_CASE(slice_any_height_with_a_flat_top)
{
    /* a flat top just above the last layer's plane gave its triangles a
       reversed layer range, which asked for terabytes (a 12.5 mm plate on
       standoffs: "slice: out of memory"); every height from 5 to 15 mm in
       0.05 mm steps slices */
    for (int i = 100; i <= 300; i++) {
        struct mesh m = { 0 };
        struct sf_err err;
        double h = i * 0.05;
        T_TRUE(ts_box(&m, 0, 0, 0, 20, 20, (float)h) == 0);
        struct layer_stack s;
        int rc = layers_slice(&m, 0.2, 0.2, 100, 100, &s, &err);
        if (rc != SF_OK)
            t_fail(__FILE__, __LINE__, "height %.2f: %s", h, err.msg);
        else if (fabs(s.l[s.n - 1].z_mm - h) > 0.2)
            t_fail(__FILE__, __LINE__, "height %.2f: top layer at %.2f", h, s.l[s.n - 1].z_mm);
        if (rc == SF_OK)
            layer_stack_release(&s);
        ts_free(&m);
    }
}

T_CASE(slice_top_on_a_plane_as_read_from_an_stl)
{
    /* a 1.3 mm plate under a 5 mm post, its top as an STL stores it (the
       float 1.29999995, a few float steps under layer 6's plane at 1.3):
       layer 6 holds the plate, as PrusaSlicer (cutting in floats) prints
       it; before, it held the post alone and the plate was 1.2 mm thick */
    struct mesh m = { 0 };
    struct sf_err err;
    T_TRUE(ts_box(&m, 0, 0, 0, 20, 20, (float)1.3) == 0);
    T_TRUE(ts_box(&m, 5, 5, 0, 10, 10, 5) == 0);
    struct layer_stack s;
    T_OK(layers_slice(&m, 0.2, 0.2, 100, 100, &s, &err), &err);
    T_EQ_INT(s.n, 25);
    T_EQ_DBL(paths_area(&s.l[6].region), 400, 1e-3);
    T_EQ_DBL(paths_area(&s.l[7].region), 25, 1e-3);
    layer_stack_release(&s);
    ts_free(&m);
}

T_CASE(slice_pyramid_area_follows_formula)
{
    struct mesh m = { 0 };
    struct sf_err err;
    T_TRUE(ts_pyramid(&m, 30, 15) == 0);
    struct layer_stack s;
    T_OK(layers_slice(&m, 0.3, 0.2, 0, 0, &s, &err), &err);
    for (uint32_t k = 0; k < s.n; k++) {
        double z = s.l[k].z_mm - s.l[k].h_mm / 2;
        double side = 30 * (1 - z / 15);
        T_EQ_DBL(paths_area(&s.l[k].region), side * side, 1e-3);
    }
    T_EQ_INT(s.n, 74); /* planes 0.15, then 0.4 ... 14.8 */
    layer_stack_release(&s);
    ts_free(&m);
}

T_CASE(slice_vertices_on_plane)
{
    /* equator at z = 10.1: exactly the plane of layer 50 (0.2 mm layers) */
    struct mesh m = { 0 };
    struct sf_err err;
    T_TRUE(ts_octahedron(&m, 10, 10.1) == 0);
    struct layer_stack s;
    T_OK(layers_slice(&m, 0.2, 0.2, 0, 0, &s, &err), &err);
    T_EQ_INT(s.n, 101);
    for (uint32_t k = 0; k < s.n; k++) {
        double z = s.l[k].z_mm - s.l[k].h_mm / 2;
        double r = 10 * (1 - fabs(z - 10.1) / 10.1);
        T_EQ_DBL(paths_area(&s.l[k].region), 2 * r * r, 1e-3);
        T_EQ_INT(s.l[k].region.n, 1);
    }
    T_EQ_INT(s.n_open, 0);
    layer_stack_release(&s);
    ts_free(&m);
}

T_CASE(slice_box_with_hole)
{
    /* a 30 mm frame with a 10 mm square hole: four boxes sharing faces */
    struct mesh m = { 0 };
    struct sf_err err;
    T_TRUE(ts_box(&m, 0, 0, 0, 30, 10, 5) == 0);
    T_TRUE(ts_box(&m, 0, 20, 0, 30, 30, 5) == 0);
    T_TRUE(ts_box(&m, 0, 10, 0, 10, 20, 5) == 0);
    T_TRUE(ts_box(&m, 20, 10, 0, 30, 20, 5) == 0);
    struct layer_stack s;
    T_OK(layers_slice(&m, 0.2, 0.2, 15, 15, &s, &err), &err);
    T_EQ_INT(s.n, 25);
    T_EQ_DBL(paths_area(&s.l[3].region), 800, 1e-6);
    T_EQ_INT(s.l[3].region.n, 2); /* outer + hole */
    T_TRUE(paths_area_k(&s.l[3].region, 0) > 0);
    T_TRUE(paths_area_k(&s.l[3].region, 1) < 0);
    T_TRUE(!paths_contains(&s.l[3].region, (struct ipt){ poly_i(15), poly_i(15) }));
    T_TRUE(paths_contains(&s.l[3].region, (struct ipt){ poly_i(5), poly_i(15) }));
    layer_stack_release(&s);
    ts_free(&m);
}

T_CASE(slice_sliver_triangles)
{
    /* a cube whose front face is split through a point 1e-9 off its diagonal */
    struct mesh m = { 0 };
    struct sf_err err;
    T_TRUE(ts_box(&m, 0, 0, 0, 10, 10, 10) == 0);
    /* replace front face (tris 4,5: y = 0) by four triangles around p */
    struct vec3 p = v3(5 + 1e-9, 0, 5);
    struct vec3 *nv = mem_realloc_array(m.v, 9, sizeof(*nv));
    T_TRUE(nv != NULL);
    m.v = nv;
    m.v[8] = p;
    m.n_verts = 9;
    uint32_t(*nt)[3] = mem_realloc_array(m.t, 14, sizeof(*nt));
    T_TRUE(nt != NULL);
    m.t = nt;
    /* front face corners 0 (0,0,0) 1 (10,0,0) 5 (10,0,10) 4 (0,0,10) */
    uint32_t f[4][3] = { { 0, 1, 8 }, { 1, 5, 8 }, { 5, 4, 8 }, { 4, 0, 8 } };
    for (int c = 0; c < 3; c++) {
        m.t[4][c] = f[0][c];
        m.t[5][c] = f[1][c];
        m.t[12][c] = f[2][c];
        m.t[13][c] = f[3][c];
    }
    m.n_tris = 14;
    struct layer_stack s;
    T_OK(layers_slice(&m, 0.2, 0.2, 5, 5, &s, &err), &err);
    for (uint32_t k = 0; k < s.n; k++)
        T_EQ_DBL(paths_area(&s.l[k].region), 100, 1e-6);
    T_EQ_INT(s.n_open, 0);
    layer_stack_release(&s);
    ts_free(&m);
}

T_CASE(slice_open_mesh_still_closes)
{
    struct mesh m = { 0 };
    struct sf_err err;
    T_TRUE(ts_box(&m, 0, 0, 0, 10, 10, 10) == 0);
    m.t[4][0] = m.t[11][0]; /* drop the front face: overwrite two triangles */
    m.t[4][1] = m.t[11][1];
    m.t[4][2] = m.t[11][2];
    m.t[5][0] = m.t[10][0];
    m.t[5][1] = m.t[10][1];
    m.t[5][2] = m.t[10][2];
    m.n_tris = 10;
    struct layer_stack s;
    T_OK(layers_slice(&m, 0.2, 0.2, 5, 5, &s, &err), &err);
    T_TRUE(s.n_open > 0);
    T_EQ_DBL(paths_area(&s.l[10].region), 100, 1e-6);
    layer_stack_release(&s);
    ts_free(&m);
}

/*
 * The side of a 48-gon prism (radius 10, 5 tall) in three unwelded
 * patches, each moved a few micrometres from its neighbours (cracks like
 * the shared pig's), patch 1 with its facets turned inside out.
 */
static int
cracked_prism(struct mesh *m)
{
    enum { N = 48, PATCH = N / 3 };
    for (int pa = 0; pa < 3; pa++) {
        struct vec3 v[2 * (PATCH + 1)];
        uint32_t t[2 * PATCH][3];
        for (int i = 0; i <= PATCH; i++) {
            double a = 2 * M_PI * (pa * PATCH + i) / N;
            double x = 10 * cos(a) + 0.013 * pa, y = 10 * sin(a) - 0.007 * pa;
            v[2 * i] = v3(x, y, 0);
            v[2 * i + 1] = v3(x, y, 5);
        }
        for (uint32_t i = 0; i < PATCH; i++) {
            uint32_t b0 = 2 * i, t0 = b0 + 1, b1 = b0 + 2, t1 = b0 + 3;
            uint32_t f[2][3] = { { b0, b1, t1 }, { b0, t1, t0 } };
            for (int q = 0; q < 2; q++) {
                t[2 * i + q][0] = f[q][0];
                t[2 * i + q][1] = pa == 1 ? f[q][2] : f[q][1];
                t[2 * i + q][2] = pa == 1 ? f[q][1] : f[q][2];
            }
        }
        if (ts_add(m, v, 2 * (PATCH + 1), t, 2 * PATCH))
            return -1;
    }
    return 0;
}

T_CASE(slice_closes_cracks_between_patches)
{
    /* closing each patch's chain straight would cut the inscribed
       triangle of the three crack points (130 mm2) out of every layer */
    struct mesh m = { 0 };
    struct sf_err err;
    T_TRUE(cracked_prism(&m) == 0);
    struct layer_stack s;
    T_OK(layers_slice(&m, 0.2, 0.2, 0, 0, &s, &err), &err);
    T_EQ_INT(s.n, 25);
    T_EQ_INT(s.n_open, 0);
    double ngon = 0.5 * 48 * 100 * sin(2 * M_PI / 48);
    for (uint32_t k = 0; k < s.n; k++) {
        T_EQ_DBL(paths_area(&s.l[k].region), ngon, 0.002 * ngon);
        T_EQ_INT(s.l[k].region.n, 1);
    }
    layer_stack_release(&s);
    ts_free(&m);
}

/* Solid (with top) and sparse area of layer k. */
static int
region_areas(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
             double *solid_mm2, double *sparse_mm2)
{
    struct paths solid, top, sparse;
    paths_init(&solid);
    paths_init(&top);
    paths_init(&sparse);
    int rc = toolpath_regions(s, k, p, &solid, &top, &sparse);
    *solid_mm2 = paths_area(&solid) + paths_area(&top);
    *sparse_mm2 = paths_area(&sparse);
    paths_release(&solid);
    paths_release(&top);
    paths_release(&sparse);
    return rc;
}

/* Layer k of a square pyramid: its infill area is the inner square (side
   inner), and the solid of it a ring band wide inside the inner edge. */
static void
expect_solid_band(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
                  double inner, double band)
{
    double want = inner * inner - (inner - 2 * band) * (inner - 2 * band);
    double solid, sparse;
    T_OK(region_areas(s, k, p, &solid, &sparse), NULL);
    T_EQ_DBL(solid + sparse, inner * inner, 0.01 * inner * inner);
    T_EQ_DBL(solid, want, 0.03 * want);
}

/* m sliced at 0.2 mm into s, with every layer's areas for profile p. */
static int
slice_areas(const struct mesh *m, const struct slice_profile *p, struct layer_stack *s,
            struct sf_err *err)
{
    int rc = layers_slice(m, 0.2, 0.2, 0, 0, s, err);
    for (uint32_t k = 0; rc == SF_OK && k < s->n; k++) {
        if ((rc = toolpath_areas(s, k, p)) < 0) {
            layer_stack_release(s);
            return sf_err_set(err, rc, "toolpath_areas: layer %u", k);
        }
    }
    return rc;
}

T_CASE(surfaces_thicken_only_their_own_side)
{
    /* a 12 mm post under a 30 mm slab (z 10-12), and a 30 mm block under
       a 12 mm post (z 0-10, then 10-20).  The slab's underside is a
       bottom surface: it thickens the 3 layers from it up, never the post
       below it; the block's top is a top surface: it thickens the 4 layers
       from it down, never the post above (PrusaSlicer's
       discover_horizontal_shells).  Before, one skin for both put solid
       in the first post's 3 layers under the slab and in the second
       post's 2 layers over the block. */
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    double inset = p.width_mm / 2 + 1.5 * tp_spacing(p.width_mm, 0.2);
    double post = (12 - 2 * inset) * (12 - 2 * inset), wide = (30 - 2 * inset) * (30 - 2 * inset);
    for (int part = 0; part < 2; part++) {
        struct mesh m = { 0 };
        struct sf_err err;
        if (part == 0) {
            T_TRUE(ts_box(&m, 0, 0, 0, 12, 12, 10) == 0);
            T_TRUE(ts_box(&m, -9, -9, 10, 21, 21, 12) == 0);
        } else {
            T_TRUE(ts_box(&m, -9, -9, 0, 21, 21, 10) == 0);
            T_TRUE(ts_box(&m, 0, 0, 10, 12, 12, 20) == 0);
        }
        struct layer_stack s;
        T_OK(slice_areas(&m, &p, &s, &err), &err);
        double solid, sparse;
        if (part == 0) {
            /* z 9.2-10: the post under the slab is sparse */
            for (uint32_t k = 46; k < 50; k++) {
                T_OK(region_areas(&s, k, &p, &solid, &sparse), NULL);
                T_EQ_DBL(solid, 0, 1e-9);
                T_EQ_DBL(sparse, post, 0.01 * post);
            }
            /* the slab's first 3 layers are solid but over the post's middle */
            for (uint32_t k = 50; k < 53; k++) {
                T_OK(region_areas(&s, k, &p, &solid, &sparse), NULL);
                T_EQ_DBL(solid + sparse, wide, 0.01 * wide);
                T_TRUE(sparse < post / 2);
            }
        } else {
            /* z 9.2-10: the block's top 4 layers are solid but for the
               middle of the post's footprint, out of the top surface's
               reach (skin_margin): sparse, as in PrusaSlicer, whose
               solid_infill_below_area sees the whole internal area (it
               runs before the skins are projected) */
            double mid = (12 - 2 * p.skin_margin_mm) * (12 - 2 * p.skin_margin_mm);
            for (uint32_t k = 46; k < 50; k++) {
                T_OK(region_areas(&s, k, &p, &solid, &sparse), NULL);
                T_EQ_DBL(solid + sparse, wide, 0.01 * wide);
                T_EQ_DBL(sparse, mid, 0.02 * mid);
            }
            /* z 10-10.6: the post over it is sparse */
            for (uint32_t k = 50; k < 53; k++) {
                T_OK(region_areas(&s, k, &p, &solid, &sparse), NULL);
                T_EQ_DBL(solid, 0, 1e-9);
                T_EQ_DBL(sparse, post, 0.01 * post);
            }
        }
        layer_stack_release(&s);
        ts_free(&m);
    }
    slice_profile_release(&p);
}

T_CASE(slope_gets_projected_top_surfaces)
{
    /* a pyramid 50 wide, 10 tall: its faces move 0.5 mm in per 0.2 mm
       layer.  The top surfaces of this layer and the 3 above (each a
       0.5 mm band at its own outline) land 0..2 mm inside this layer's
       outline; past the 0.84 mm of perimeters that is a band too narrow
       for 3 solid lines, so it grows 3 lines (PrusaSlicer's
       discover_horizontal_shells, the peers' setting).  The vertical-shell
       rule this replaces gave 2.1 mm. */
    struct mesh m = { 0 };
    struct sf_err err;
    T_TRUE(ts_pyramid(&m, 50, 10) == 0);
    struct layer_stack s;
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    T_OK(slice_areas(&m, &p, &s, &err), &err);
    uint32_t k = 25; /* plane at z 5.1: side 24.5 */
    double inset = p.width_mm / 2 + 1.5 * tp_spacing(p.width_mm, 0.2);
    double inner = 24.5 - 2 * inset;
    expect_solid_band(&s, k, &p, inner, p.top_layers * 0.5 - inset + 3 * p.solid_width_mm);
    slice_profile_release(&p);
    layer_stack_release(&s);
    ts_free(&m);
}

T_CASE(steep_slope_gets_a_band_of_solid)
{
    /* a 45 degree pyramid (40 wide, 20 tall) recedes 0.2 mm a layer, so
       the top surfaces of the 3 layers above stay in this layer's
       perimeter zone (0.2..0.8 mm in) and never reach its inner area
       (0.84 mm in).  PrusaSlicer's infill areas reach infill_overlap
       further out (0.73 mm in): the farthest surface leaves a sliver
       there, too narrow, which grows 3 solid lines: a band of solid from
       the inner edge to 0.8 + 3 x 0.45 mm in, all round (none before) */
    struct mesh m = { 0 };
    struct sf_err err;
    T_TRUE(ts_pyramid(&m, 40, 20) == 0);
    struct layer_stack s;
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    T_OK(slice_areas(&m, &p, &s, &err), &err);
    double sp = tp_spacing(p.width_mm, 0.2);
    double inset = p.width_mm / 2 + 1.5 * sp;
    T_TRUE(p.infill_overlap * sp > inset - p.top_layers * 0.2); /* the sliver exists */
    for (uint32_t k = 30; k < 60; k += 10) {
        double side = 40 - 2 * (k * 0.2 + 0.1), inner = side - 2 * inset;
        expect_solid_band(&s, k, &p, inner, p.top_layers * 0.2 + 3 * p.solid_width_mm - inset);
    }
    slice_profile_release(&p);
    layer_stack_release(&s);
    ts_free(&m);
}

/* An octahedron whose faces move w in (above its equator, z 5) or out
   (below) per 0.2 mm layer: each layer's top or bottom surface is a band
   w wide at its outline.  Layers 12 (z 2.5) and 37 (z 7.5) are squares of
   side 25 w (turned 45 degrees).  Their solid (PrusaSlicer 2.5's
   discover_horizontal_shells): the layer's own surface, grown skin_margin
   into the infill (w + 3 mm in), and each of the n - 1 other layers' within
   reach (n the bottom or top layers) projected onto the infill beyond it,
   a band out to (d + 1) w + 3 mm for the layer d away; bands narrower than
   3 solid lines grow 3 lines.  So the solid reaches n w + 3 mm in, 3 lines
   more if the farthest band is narrower than 3 lines.  top: layer 37 too
   (faces receding faster than 0.9 mm a layer get an extra loop there). */
static void
expect_slope_skins(double w, bool top)
{
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    double inset = p.width_mm / 2 + 1.5 * tp_spacing(p.width_mm, 0.2);
    struct mesh m = { 0 };
    struct sf_err err;
    T_TRUE(ts_octahedron(&m, 5 * w / 0.2 * sqrt(2), 5) == 0);
    struct layer_stack s;
    T_OK(slice_areas(&m, &p, &s, &err), &err);
    double inner = 25 * w - 2 * inset; /* 12.5 layers from the tips */
    for (int side = 0; side < 2; side++) {
        int n = side ? p.top_layers : p.bottom_layers;
        double reach = n * w + p.skin_margin_mm;
        if ((n - 1) * w < 2 * 3 * p.solid_width_mm)
            reach += 3 * p.solid_width_mm;
        if (side == 0 || top)
            expect_solid_band(&s, side ? 37 : 12, &p, inner, reach - inset);
    }
    slice_profile_release(&p);
    layer_stack_release(&s);
    ts_free(&m);
}

T_CASE(slanted_skin_wide_enough_is_not_widened)
{
    /* faces moving 1.5 mm a layer under the equator: the bottom surfaces
       reach the inner area, and the 2 layers' above project 3 mm wide
       bands past this layer's own skin, wider than the 3 solid lines
       (1.35 mm) that "too narrow" asks for.  Along slanted edges the
       opening's rounding left hairlines, each taken for a band too
       narrow: the skin grew 3 lines wider all round (PrusaSlicer's
       opening regrows ClipperSafetyOffset more, as ours now does) */
    expect_slope_skins(1.5, false);
}

T_CASE(gentle_slope_skin_reaches_in_from_the_overlap)
{
    /* faces moving 0.8 mm a layer: each top or bottom surface stops short
       of the inner area (0.84 mm in) but reaches PrusaSlicer's infill
       area, which reaches infill_overlap into the loops (its
       fill_expolygons, 0.73 mm in).  PrusaSlicer grows that sliver 3 mm
       (process_external_surfaces) and projects it layer by layer, each
       band narrower than 3 lines growing 3 lines: solid to n x 0.8 + 3 mm
       + 3 lines in.  Ours grew only what reached the inner area (n x 0.8
       mm, widened 3 lines), then regularized the union of the projections
       (a wide band: n x 0.8 + 3 mm), a skin a layer or two thinner along
       gentle slopes than PrusaSlicer's (shared dino's belly 0.80 mm
       against its 1.00) */
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    double sp = tp_spacing(p.width_mm, 0.2), inset = p.width_mm / 2 + 1.5 * sp;
    T_TRUE(0.8 <= inset && 0.8 > inset - p.infill_overlap * sp); /* the sliver exists */
    slice_profile_release(&p);
    expect_slope_skins(0.8, true);
}

T_CASE(skins_leave_small_pieces_of_big_islands_sparse)
{
    /* a 30 mm block under a 14 mm post: the block's top surface, grown
       3 mm (skin_margin) into the post's footprint, leaves its middle
       (8 x 8 = 64 mm2, under solid_infill_below_area) uncovered in the
       block's top 4 layers.  PrusaSlicer turns only internal areas under
       70 mm2 solid before it projects the skins, so that middle stays
       sparse; it was solid (the rule ran on what the skins left) */
    struct mesh m = { 0 };
    struct sf_err err;
    T_TRUE(ts_box(&m, -15, -15, 0, 15, 15, 10) == 0);
    T_TRUE(ts_box(&m, -7, -7, 10, 7, 7, 20) == 0);
    struct layer_stack s;
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    T_OK(slice_areas(&m, &p, &s, &err), &err);
    double mid = (14 - 2 * p.skin_margin_mm) * (14 - 2 * p.skin_margin_mm);
    T_TRUE(mid < p.solid_below_mm2);
    for (uint32_t k = 46; k < 50; k++) {
        double solid, sparse;
        T_OK(region_areas(&s, k, &p, &solid, &sparse), NULL);
        T_EQ_DBL(sparse, mid, 0.02 * mid);
    }
    slice_profile_release(&p);
    layer_stack_release(&s);
    ts_free(&m);
}

T_CASE(small_island_area_counts_the_infill_overlap)
{
    /* PrusaSlicer's infill areas reach infill_overlap (0.1 mm) into the
       loops, and solid_infill_below_area tests those: a tower whose inner
       area is 67 mm2 (under 70) has a 70.5 mm2 infill area, so it stays
       sparse */
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    double sp = tp_spacing(p.width_mm, 0.2), inset = p.width_mm / 2 + 1.5 * sp;
    double ai = 8.2, ov = p.infill_overlap * sp, a = ai + 2 * inset;
    T_TRUE(ai * ai < p.solid_below_mm2 && ai * ai + 4 * ai * ov > p.solid_below_mm2);
    struct mesh m = { 0 };
    struct sf_err err;
    T_TRUE(ts_box(&m, 0, 0, 0, a, a, 10) == 0);
    struct layer_stack s;
    T_OK(slice_areas(&m, &p, &s, &err), &err);
    double solid, sparse;
    T_OK(region_areas(&s, 25, &p, &solid, &sparse), NULL);
    T_EQ_DBL(solid, 0, 1e-9);
    T_EQ_DBL(sparse, ai * ai, 0.01 * ai * ai);
    slice_profile_release(&p);
    layer_stack_release(&s);
    ts_free(&m);
}

T_CASE(small_islands_print_solid)
{
    /* PrusaSlicer's solid_infill_below_area: a 7 mm tower's infill
       (about 28 mm2) is solid, a 20 mm tower's (335 mm2) sparse */
    struct mesh m = { 0 };
    struct sf_err err;
    T_TRUE(ts_box(&m, 0, 0, 0, 7, 7, 10) == 0);
    T_TRUE(ts_box(&m, 20, 0, 0, 40, 20, 10) == 0);
    struct layer_stack s;
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    T_OK(slice_areas(&m, &p, &s, &err), &err);
    double inset = p.width_mm / 2 + 1.5 * tp_spacing(p.width_mm, 0.2);
    double small = (7 - 2 * inset) * (7 - 2 * inset), big = (20 - 2 * inset) * (20 - 2 * inset);
    double solid, sparse;
    T_OK(region_areas(&s, 25, &p, &solid, &sparse), NULL);
    T_EQ_DBL(solid, small, 0.01 * small);
    T_EQ_DBL(sparse, big, 0.01 * big);
    p.solid_below_mm2 = 0;
    T_OK(region_areas(&s, 25, &p, &solid, &sparse), NULL);
    T_EQ_DBL(solid, 0, 1e-9);
    T_EQ_DBL(sparse, small + big, 0.01 * big);
    slice_profile_release(&p);
    layer_stack_release(&s);
    ts_free(&m);
}

T_CASE(clip_offset_and_difference)
{
    struct paths a, b, c;
    paths_init(&a);
    paths_init(&b);
    paths_init(&c);
    struct ipt sq[4] = {
        { 0, 0 }, { poly_i(10), 0 }, { poly_i(10), poly_i(10) }, { 0, poly_i(10) }
    };
    T_TRUE(paths_add(&a, sq, 4));
    T_OK(clip_offset(&a, -1, CLIP_JOIN_MITER, &b), NULL);
    T_EQ_DBL(paths_area(&b), 64, 1e-6);
    T_OK(clip_bool(CLIP_DIFFERENCE, &a, &b, CLIP_NONZERO, &c), NULL);
    T_EQ_DBL(paths_area(&c), 36, 1e-6);
    T_EQ_INT(c.n, 2);
    paths_release(&a);
    paths_release(&b);
    paths_release(&c);
}

/* Squares centred at (cx, cy), side 2 r, counter-clockwise. */
static void
sq_at(struct paths *p, double cx, double cy, double r)
{
    struct ipt q[4] = { { poly_i(cx - r), poly_i(cy - r) },
                        { poly_i(cx + r), poly_i(cy - r) },
                        { poly_i(cx + r), poly_i(cy + r) },
                        { poly_i(cx - r), poly_i(cy + r) } };
    paths_add(p, q, 4);
}

T_CASE(clip_results_in_tree_order)
{
    /* two separate nests, given in reverse: rings of squares 20, 14, 8, 2
       wide (even-odd: outer, hole, island, its hole), a square next to
       them and, inside the second nest's hole, two islands.  Out of every
       Boolean and offset come: an outer, its holes, then each island in
       those holes with its own holes, recursively (the toolpaths walk
       pieces as "a positive ring and the negative ones after it") */
    struct paths a, b, c;
    paths_init(&a);
    paths_init(&b);
    paths_init(&c);
    sq_at(&a, 60, 0, 10);
    sq_at(&a, 60, 0, 7);
    sq_at(&a, 57, 0, 2);
    sq_at(&a, 63, 0, 2);
    sq_at(&a, 30, 0, 3);
    sq_at(&a, 0, 0, 10);
    sq_at(&a, 0, 0, 7);
    sq_at(&a, 0, 0, 4);
    sq_at(&a, 0, 0, 1);
    T_OK(clip_bool(CLIP_UNION, &a, NULL, CLIP_EVENODD, &b), NULL);
    T_EQ_INT(b.n, 9);
    for (int pass = 0; pass < 2; pass++) {
        const struct paths *r = pass ? &c : &b;
        /* every negative ring lies inside the positive ring before it,
           every positive ring after the first of a nest inside a
           negative ring somewhere before it */
        int outers = 0;
        for (uint32_t i = 0; i < r->n; i++) {
            double ar = paths_area_k(r, i);
            struct ipt q = r->pts[r->start[i]];
            if (ar < 0) {
                uint32_t j = i;
                while (j > 0 && paths_area_k(r, j) < 0)
                    j--;
                struct paths one;
                paths_init(&one);
                T_TRUE(paths_add(&one, r->pts + r->start[j], paths_len(r, j)));
                T_TRUE(paths_contains(&one, q));
                T_TRUE(paths_area_k(r, j) > -ar);
                paths_release(&one);
            } else {
                outers++;
            }
        }
        T_EQ_INT(outers, 6);
        /* the first nest: ring 20/14, then the island 8/2 in its hole
           (grown 0.5 mm: 21/13, 9/1) */
        double want[4] = { 400, -196, 64, -4 }, grown[4] = { 441, -169, 81, -1 };
        const double *w = pass ? grown : want;
        uint32_t m = 0;
        while (m < r->n && fabs(paths_area_k(r, m) - w[2]) > 1e-6)
            m++;
        T_TRUE(m >= 2 && m + 1 < r->n);
        for (int i = 0; i < 4 && m >= 2 && m + 1 < r->n; i++)
            T_EQ_DBL(paths_area_k(r, m - 2 + (uint32_t)i), w[i], 1e-6);
        if (!pass) {
            T_OK(clip_offset(&b, 0.5, CLIP_JOIN_MITER, &c), NULL);
            T_EQ_INT(c.n, 9);
        }
    }
    paths_release(&a);
    paths_release(&b);
    paths_release(&c);
}

T_CASE(poly_simplify_and_index)
{
    /* a 1000-gon circle of radius 10: 10 um tolerance keeps its area */
    struct paths c;
    paths_init(&c);
    T_TRUE(paths_begin(&c));
    for (int i = 0; i < 1000; i++) {
        double a = 2 * M_PI * i / 1000;
        T_TRUE(paths_push(&c, (struct ipt){ poly_i(10 * cos(a)), poly_i(10 * sin(a)) }));
    }
    struct ipt sq[4] = { { poly_i(-2), poly_i(-2) },
                         { poly_i(-2), poly_i(2) },
                         { poly_i(2), poly_i(2) },
                         { poly_i(2), poly_i(-2) } }; /* a hole, CW */
    T_TRUE(paths_add(&c, sq, 4));
    double area = paths_area(&c);
    T_TRUE(paths_simplify(&c, 0.01));
    T_EQ_INT(c.n, 2);
    T_TRUE(paths_len(&c, 0) < 300 && paths_len(&c, 0) > 50);
    T_EQ_DBL(paths_area(&c), area, 0.001 * area);
    /* the banded index answers as the plain winding test */
    struct paths_index ix;
    T_TRUE(paths_index_init(&ix, &c));
    for (int i = 0; i < 400; i++) {
        struct ipt q = { poly_i(-12 + 0.06 * i), poly_i(-11 + 0.055 * i) };
        T_EQ_INT(paths_index_contains(&ix, q), paths_contains(&c, q));
    }
    T_TRUE(!paths_index_contains(&ix, (struct ipt){ 0, 0 }));
    T_TRUE(paths_index_contains(&ix, (struct ipt){ poly_i(5), 0 }));
    paths_index_release(&ix);
    paths_release(&c);
}

T_CASE(poly_index_crossing)
{
    struct paths c;
    paths_init(&c);
    struct ipt sq[4] = {
        { 0, 0 }, { poly_i(10), 0 }, { poly_i(10), poly_i(10) }, { 0, poly_i(10) }
    };
    T_TRUE(paths_add(&c, sq, 4));
    struct paths_index ix;
    T_TRUE(paths_index_init(&ix, &c));
    struct ipt in1 = { poly_i(1), poly_i(1) }, in2 = { poly_i(9), poly_i(8) };
    struct ipt out = { poly_i(12), poly_i(5) };
    T_TRUE(!paths_index_crosses(&ix, in1, in2));
    T_TRUE(paths_index_crosses(&ix, in1, out));
    T_TRUE(paths_index_crosses(&ix, (struct ipt){ poly_i(-1), poly_i(-1) },
                               (struct ipt){ poly_i(11), poly_i(11) }));
    paths_index_release(&ix);
    paths_release(&c);
}

T_CASE(fill_lines_cut_by_the_region)
{
    /* a 10 mm square with a 4 mm hole, off the 1 mm grid by 0.25: lines
       at y = 1..10 (10 x 10 mm), 4 of them cut by the hole (4 mm each),
       in 14 pieces */
    struct paths r, lines;
    paths_init(&r);
    paths_init(&lines);
    double o = 0.25;
    struct ipt sq[4] = { { poly_i(o), poly_i(o) },
                         { poly_i(10 + o), poly_i(o) },
                         { poly_i(10 + o), poly_i(10 + o) },
                         { poly_i(o), poly_i(10 + o) } };
    struct ipt hole[4] = { { poly_i(3 + o), poly_i(3 + o) },
                           { poly_i(3 + o), poly_i(7 + o) },
                           { poly_i(7 + o), poly_i(7 + o) },
                           { poly_i(7 + o), poly_i(3 + o) } };
    T_TRUE(paths_add(&r, sq, 4));
    T_TRUE(paths_add(&r, hole, 4));
    T_OK(tp_fill_lines(&r, 0, 1, 0, 0, &lines), NULL);
    T_EQ_INT(lines.n, 14);
    double total = 0;
    for (uint32_t k = 0; k < lines.n; k++)
        total += paths_length_k(&lines, k, false);
    T_EQ_DBL(total, 100 - 16, 1e-4);
    /* at 45 degrees: the area over the spacing, within a line or two */
    paths_reset(&lines);
    T_OK(tp_fill_lines(&r, 45, 0.5, 0, 0, &lines), NULL);
    total = 0;
    for (uint32_t k = 0; k < lines.n; k++)
        total += paths_length_k(&lines, k, false);
    T_EQ_DBL(total, 84 / 0.5, 2 * 10 * M_SQRT2);
    /* the grid runs through the origin given (a part's centre, as
       PrusaSlicer aligns its fills): lines at y = 0.6 + k */
    paths_reset(&lines);
    T_OK(tp_fill_lines(&r, 0, 1, 5, 0.6, &lines), NULL);
    T_EQ_INT(lines.n, 14);
    for (uint32_t k = 0; k < lines.n; k++) {
        double y = poly_mm(lines.pts[lines.start[k]].y);
        T_EQ_DBL(y - floor(y), 0.6, 1e-4);
    }
    paths_release(&r);
    paths_release(&lines);
}

T_CASE(infill_anchors_follow_the_boundary)
{
    /* two vertical lines across a 10 x 10 square, 4 mm apart, as
       PrusaSlicer's connect_infill joins them: the shortest arc between
       neighbouring ends (bottom, 3 -> 7, 4 mm) joins the two lines; the
       top arc (4 mm) would close a loop, so each of its ends gets a stub
       of 2.7 mm the other way, toward the 16 mm of free boundary */
    struct paths sq, lines;
    paths_init(&sq);
    paths_init(&lines);
    struct ipt s[4] = {
        { 0, 0 }, { poly_i(10), 0 }, { poly_i(10), poly_i(10) }, { 0, poly_i(10) }
    };
    T_TRUE(paths_add(&sq, s, 4));
    struct ipt l1[2] = { { poly_i(3), 0 }, { poly_i(3), poly_i(10) } };
    struct ipt l2[2] = { { poly_i(7), poly_i(10) }, { poly_i(7), 0 } };
    T_TRUE(paths_add(&lines, l1, 2));
    T_TRUE(paths_add(&lines, l2, 2));
    T_OK(tp_anchor(&lines, &sq, 2.7, 50, 0.2), NULL);
    T_EQ_INT(lines.n, 1);
    T_EQ_DBL(paths_length_k(&lines, 0, false), 20 + 4 + 2 * 2.7, 1e-3);
    /* joins only under 3 mm: none; the ends of each 4 mm arc get stubs
       toward each other, the first 2.7 mm, the second the 1.3 left */
    paths_reset(&lines);
    T_TRUE(paths_add(&lines, l1, 2));
    T_TRUE(paths_add(&lines, l2, 2));
    T_OK(tp_anchor(&lines, &sq, 2.7, 3, 0.2), NULL);
    T_EQ_INT(lines.n, 2);
    double total = paths_length_k(&lines, 0, false) + paths_length_k(&lines, 1, false);
    T_EQ_DBL(total, 20 + 2 * (2.7 + 1.3), 1e-3);
    paths_release(&sq);
    paths_release(&lines);
}
