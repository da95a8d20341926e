/*
 * test_slice_bridge.c - bridges run across the short span: a slab on two
 * posts 10 mm apart is bridged post to post, whichever way the gap runs
 * (before, bridge lines ran at the solid infill's 45 / 135 degrees).
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "../../slicer/estimate.h"
#include "../../slicer/layers.h"
#include "../../slicer/slice.h"
#include "../../slicer/toolpath.h"
#include "../../src/base/buf.h"
#include "../../src/base/mem.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"
#include "slice_run.h"
#include "slice_shapes.h"

struct dir {
    double along_x, along_y; /* bridge extrusion length by main direction */
    double px, py;
};

static int
on_move(void *ud, const struct est_move *mv)
{
    struct dir *d = ud;
    if (mv->de > 0 && mv->type && mv->type_len == 13 &&
        memcmp(mv->type, "Bridge infill", 13) == 0) {
        double dx = fabs(mv->x - d->px), dy = fabs(mv->y - d->py);
        if (dx > dy)
            d->along_x += hypot(dx, dy);
        else
            d->along_y += hypot(dx, dy);
    }
    d->px = mv->x;
    d->py = mv->y;
    return SF_OK;
}

/* Posts 5 x 5 (gap along x) or turned (gap along y), slab on top. */
static int
bridge_dir(bool turn, struct dir *d, struct sf_err *err)
{
    struct mesh m, b;
    mesh_init(&m);
    mesh_init(&b);
    double L = 20, W = 12; /* the slab: 20 along the gap, 12 across */
    int rc = turn ? shape_box(&m, v3(0, 0, 0), v3(W, 5, 6), err)
                  : shape_box(&m, v3(0, 0, 0), v3(5, W, 6), err);
    if (rc == SF_OK)
        rc = turn ? shape_box(&b, v3(0, L - 5, 0), v3(W, L, 6), err)
                  : shape_box(&b, v3(L - 5, 0, 0), v3(L, W, 6), err);
    if (rc == SF_OK)
        rc = ts_merge(&m, &b);
    mesh_release(&b);
    mesh_init(&b);
    if (rc == SF_OK)
        /* 1.4 mm: 3 bottom and 4 top layers, all solid, so no internal
           bridge (over sparse infill, in the solid's direction) mixes in */
        rc = turn ? shape_box(&b, v3(0, 0, 6), v3(W, L, 7.4), err)
                  : shape_box(&b, v3(0, 0, 6), v3(L, W, 7.4), err);
    if (rc == SF_OK)
        rc = ts_merge(&m, &b);
    struct slice_profile p;
    if (rc == SF_OK && (rc = slice_profile_default(&p)) == SF_OK) {
        p.support = false;
        p.skirts = 0;
        p.brim_auto = false;
        memset(d, 0, sizeof(*d));
        rc = ts_slice_walk(&m, &p, turn ? "bridge1" : "bridge0", NULL, on_move, d, err);
        slice_profile_release(&p);
    }
    mesh_release(&m);
    mesh_release(&b);
    return rc;
}

T_CASE(bridge_lines_span_the_gap)
{
    struct sf_err err;
    struct dir d;
    /* the gap runs along x (posts at x 0..5 and 15..20): lines along x */
    T_OK(bridge_dir(false, &d, &err), &err);
    if (!(d.along_x > 0 && d.along_x > 9 * d.along_y))
        t_fail(__FILE__, __LINE__, "gap along x: bridge %.0f mm along x, %.0f along y", d.along_x,
               d.along_y);
    T_OK(bridge_dir(true, &d, &err), &err);
    if (!(d.along_y > 0 && d.along_y > 9 * d.along_x))
        t_fail(__FILE__, __LINE__, "gap along y: bridge %.0f mm along x, %.0f along y", d.along_x,
               d.along_y);
}

/* Bridge line length and the layer's solid infill length on layer k. */
static void
roles_of(const struct layer_paths *lp, double *bridge_mm, double *solid_mm, float *bridge_w)
{
    *bridge_mm = *solid_mm = 0;
    for (uint32_t i = 0; i < lp->p.n; i++) {
        double l = paths_length_k(&lp->p, i, lp->info[i].closed);
        if (lp->info[i].role == ROLE_BRIDGE) {
            *bridge_mm += l;
            *bridge_w = lp->info[i].width_mm;
        } else if (lp->info[i].role == ROLE_SOLID || lp->info[i].role == ROLE_TOP) {
            *solid_mm += l;
        }
    }
}

T_CASE(solid_over_sparse_infill_is_an_internal_bridge)
{
    /* a 30 mm box 10 mm tall: its first solid layer under the top (layer
       46, over layer 45's sparse grid) is bridged with nozzle-wide lines,
       as PrusaSlicer's bridge_over_infill does; the layers over solid are
       not.  Before, layer 46 was ordinary solid infill. */
    struct mesh m = { 0 };
    struct sf_err err;
    T_TRUE(ts_box(&m, 0, 0, 0, 30, 30, 10) == 0);
    struct layer_stack s;
    T_OK(layers_slice(&m, 0.2, 0.2, 0, 0, &s, &err), &err);
    T_EQ_INT(s.n, 50);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    for (uint32_t k = 0; k < s.n; k++)
        T_OK(toolpath_areas(&s, k, &p), NULL);
    double inner = 30 - 2 * (p.width_mm / 2 + 1.5 * tp_spacing(p.width_mm, 0.2));
    for (int stored = 0; stored < 2; stored++) {
        /* with the regions kept (slice_mesh) and without (computed) */
        for (uint32_t k = 0; stored && k < s.n; k++)
            T_OK(toolpath_store_regions(&s, k, &p), NULL);
        for (uint32_t k = 45; k < 48; k++) {
            struct layer_paths lp;
            layer_paths_init(&lp);
            T_OK(toolpath_layer(&s, k, &p, NULL, &lp), NULL);
            double br, so;
            float w = 0;
            roles_of(&lp, &br, &so, &w);
            if (k == 46) {
                /* lines nz + 0.05 apart over the whole inner area */
                T_EQ_DBL(br, inner * inner / (p.nozzle_mm + 0.05), 0.05 * inner * inner / 0.45);
                T_EQ_DBL(w, p.nozzle_mm, 1e-6);
                T_EQ_DBL(so, 0, 1e-9);
            } else {
                T_EQ_DBL(br, 0, 1e-9);
                if (k == 47)
                    T_TRUE(so > 1000);
            }
            layer_paths_release(&lp);
        }
    }
    slice_profile_release(&p);
    layer_stack_release(&s);
    ts_free(&m);
}
