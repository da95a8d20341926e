/*
 * test_slice_bridge.c - bridges run across the short span: a slab on two
 * posts 10 mm apart is bridged post to post, whichever way the gap runs
 * (before, bridge lines ran at the solid infill's 45 / 135 degrees).
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "../../slicer/estimate.h"
#include "../../slicer/slice.h"
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
        rc = turn ? shape_box(&b, v3(0, 0, 6), v3(W, L, 8), err)
                  : shape_box(&b, v3(0, 0, 6), v3(L, W, 8), err);
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
