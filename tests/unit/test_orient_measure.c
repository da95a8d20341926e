/*
 * test_orient_measure.c - the measuring shortcuts the orientation search
 * takes: several angles from one cast, grid extents from the hull's
 * vertices, and the event-driven growth simulation's island search.
 */
#include <math.h>
#include <stdlib.h>

#include "../../src/geom/growth.h"
#include "../../src/geom/hull.h"
#include "../../src/geom/measure.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"

/* a and b in one mesh (two shells) */
static int
join(struct mesh *out, const struct mesh *a, const struct mesh *b, struct sf_err *err)
{
    int r = mesh_alloc(out, a->n_verts + b->n_verts, a->n_tris + b->n_tris, err);
    if (r)
        return r;
    memcpy(out->v, a->v, a->n_verts * sizeof(*a->v));
    memcpy(out->v + a->n_verts, b->v, b->n_verts * sizeof(*b->v));
    memcpy(out->t, a->t, a->n_tris * sizeof(*a->t));
    for (uint32_t i = 0; i < b->n_tris; i++)
        for (int k = 0; k < 3; k++)
            out->t[a->n_tris + i][k] = b->t[i][k] + a->n_verts;
    return SF_OK;
}

static int
metrics_at(const struct mesh *m, struct vec3 up, double angle, struct support_metrics *out,
           struct sf_err *err)
{
    struct raycast *rc = raycast_new(m, err);
    if (!rc)
        return err->code;
    struct support_params p;
    support_params_default(&p);
    p.angle_deg = angle;
    int r = measure_support(m, rc, up, &p, out, err);
    raycast_free(rc);
    return r;
}

T_CASE(two_angles_from_one_cast_match_two_casts)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_arch(&m, &err), &err);
    struct raycast *rc = raycast_new(&m, &err);
    T_TRUE(rc != NULL);
    struct proxy_cache pc;
    T_OK(proxy_cache_init(&pc, &m, NULL, 0, &err), &err);
    struct vec3 up = v3_normalize(v3(0.3, -0.2, 1));
    struct support_params p[2];
    support_params_default(&p[0]);
    p[0].angle_deg = 40;
    p[1] = p[0];
    p[1].angle_deg = 45;
    struct support_metrics both[2], one;
    T_OK(measure_support_angles(&m, rc, &pc, up, p, 2, both, &err), &err);
    for (int i = 0; i < 2; i++) {
        T_OK(measure_support_cached(&m, rc, &pc, up, &p[i], &one, &err), &err);
        T_EQ_DBL(both[i].volume_mm3, one.volume_mm3, 1e-9);
        T_EQ_DBL(both[i].contact_area_mm2, one.contact_area_mm2, 1e-9);
        T_EQ_DBL(both[i].risky_area_mm2, one.risky_area_mm2, 1e-9);
        T_EQ_INT(both[i].n_anchors, one.n_anchors);
        T_EQ_INT(both[i].n_islands, one.n_islands);
        T_EQ_INT(both[i].n_rays, one.n_rays);
        T_EQ_DBL(both[i].base_margin_mm, one.base_margin_mm, 1e-9);
    }
    /* the angles differ, so the figures must too: each p[i] was used */
    T_TRUE(both[0].risky_area_mm2 > both[1].risky_area_mm2);
    /* one pitch for all */
    p[1].pitch_mm = 2;
    T_ERR(measure_support_angles(&m, rc, &pc, up, p, 2, both, &err), SF_EINVAL, &err, "pitch");
    proxy_cache_release(&pc);
    raycast_free(rc);
    mesh_release(&m);
}

T_CASE(hull_vertices_give_the_same_grid)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_sphere_on_stem(&m, &err), &err);
    struct vec3 com;
    mesh_volume(&m, &com);
    struct hull_base *bases;
    uint32_t n_bases, *verts, n_verts;
    T_OK(hull_bases(&m, com, &bases, &n_bases, &verts, &n_verts, &err), &err);
    T_TRUE(n_verts < m.n_verts);
    struct raycast *all = raycast_new(&m, &err), *hull = raycast_new(&m, &err);
    T_TRUE(all && hull);
    T_OK(raycast_set_extreme(hull, verts, n_verts, &err), &err);
    struct vec3 dirs[] = { v3(0, 0, 1), v3(1, 2, -0.5), v3(-0.3, 0.1, -1) };
    for (int d = 0; d < 3; d++) {
        struct ray_grid a, b;
        T_OK(raycast_grid(all, v3_normalize(dirs[d]), 1, &a, &err), &err);
        T_OK(raycast_grid(hull, v3_normalize(dirs[d]), 1, &b, &err), &err);
        T_EQ_INT(a.nu, b.nu);
        T_EQ_INT(a.nw, b.nw);
        T_EQ_DBL(a.base, b.base, 1e-9);
        T_EQ_INT(a.n_hits, b.n_hits);
        T_TRUE(memcmp(a.hits, b.hits, a.n_hits * sizeof(*a.hits)) == 0);
        ray_grid_release(&a);
        ray_grid_release(&b);
    }
    uint32_t bad = m.n_verts;
    T_ERR(raycast_set_extreme(hull, &bad, 1, &err), SF_EINVAL, &err, "extreme vertex");
    raycast_free(all);
    raycast_free(hull);
    free(bases);
    free(verts);
    mesh_release(&m);
}

T_CASE(a_slab_held_by_a_middle_pier_is_no_island)
{
    /* at 90 degrees nothing is risky, so no column holds anything: an 80 mm
       slab 10 mm up is held only through its pier.  Its first layer is all
       new voxels on both sides of the pier; every search from them must end
       held, directly or through a search that stopped held before it */
    double x[] = { -3, 3, 3, 40, 40, -40, -40, -3 };
    double z[] = { 0, 0, 10, 10, 14, 14, 10, 10 };
    struct mesh m;
    struct sf_err err;
    struct support_metrics s;
    mesh_init(&m);
    T_OK(shape_extrude_xz(&m, x, z, 8, 20, &err), &err);
    T_OK(metrics_at(&m, v3(0, 0, 1), 90, &s, &err), &err);
    T_EQ_INT(s.n_columns, 0);
    T_EQ_INT(s.n_islands, 0);
    mesh_release(&m);
}

T_CASE(a_slab_beside_its_pier_is_one_island)
{
    /* the same slab, 1 mm clear of a pier standing beside it: one island, its
       first layer (80 x 20 cells) about 10 mm above the bed */
    double xs[] = { -40, 40, 40, -40 }, zs[] = { 10, 10, 14, 14 };
    double xp[] = { 41, 47, 47, 41 }, zp[] = { 0, 0, 14, 14 };
    struct mesh slab, pier, both;
    struct sf_err err;
    struct support_metrics s;
    mesh_init(&slab);
    mesh_init(&pier);
    mesh_init(&both);
    T_OK(shape_extrude_xz(&slab, xs, zs, 4, 20, &err), &err);
    T_OK(shape_extrude_xz(&pier, xp, zp, 4, 20, &err), &err);
    struct vec3 lo, hi;
    mesh_bbox(&slab, &lo, &hi);
    mesh_translate(&slab, v3(0, 0, 10 - lo.z)); /* the shape may come placed on the bed */
    mesh_bbox(&pier, &lo, &hi);
    mesh_translate(&pier, v3(0, 0, -lo.z));
    T_OK(join(&both, &slab, &pier, &err), &err);
    T_OK(metrics_at(&both, v3(0, 0, 1), 90, &s, &err), &err);
    T_EQ_INT(s.n_islands, 1);
    T_TRUE(s.island_volume_mm3 > 0.8 * 80 * 20 * 10 && s.island_volume_mm3 < 1.2 * 80 * 20 * 10);
    mesh_release(&slab);
    mesh_release(&pier);
    mesh_release(&both);
}
