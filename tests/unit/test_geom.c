/*
 * test_geom.c - the ray grid and the shared support metrics against closed
 * forms on generated parts.
 */
#include <math.h>
#include <stdlib.h>

#include "../../src/geom/measure.h"
#include "../../src/geom/proxy.h"
#include "../../src/geom/raycast.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"

static int
metrics(const struct mesh *m, struct vec3 up, double angle, double pitch,
        struct support_metrics *out, struct sf_err *err)
{
    struct support_params p;
    support_params_default(&p);
    p.angle_deg = angle;
    p.pitch_mm = pitch;
    struct raycast *rc = raycast_new(m, err);
    if (!rc)
        return err->code;
    int r = measure_support(m, rc, up, &p, out, err);
    raycast_free(rc);
    return r;
}

T_CASE(tee_overhang_area_and_column_volume)
{
    struct mesh m;
    struct sf_err err;
    struct support_metrics s;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    T_OK(metrics(&m, v3(0, 0, 1), 45, 1, &s, &err), &err);
    /* two 20 x 20 mm arms, 30 mm above the bed */
    T_EQ_DBL(s.risky_area_mm2, 800, 1e-9);
    T_EQ_DBL(s.proxy_mm3, 800 * 30, 1e-6);
    T_EQ_DBL(s.volume_mm3, 24000, 24000 * 0.02);
    T_EQ_DBL(s.contact_area_mm2, 800, 800 * 0.02);
    T_EQ_INT(s.n_anchors, 2);
    T_EQ_DBL(s.build_height_mm, 35, 1e-9);
    /* finer grid converges on the exact figure */
    T_OK(metrics(&m, v3(0, 0, 1), 45, 0.25, &s, &err), &err);
    T_EQ_DBL(s.volume_mm3, 24000, 24000 * 0.005);
    mesh_release(&m);
}

T_CASE(tee_upside_down_needs_nothing)
{
    struct mesh m;
    struct sf_err err;
    struct support_metrics s;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    T_OK(metrics(&m, v3(0, 0, -1), 45, 1, &s, &err), &err);
    T_EQ_INT(s.n_risky, 0);
    T_EQ_DBL(s.volume_mm3, 0, 1e-12);
    T_EQ_INT(s.n_columns, 0);
    /* lying on its side (y up), the arms' ends and the stem's bottom face sideways */
    T_OK(metrics(&m, v3(0, 1, 0), 45, 1, &s, &err), &err);
    T_EQ_DBL(s.volume_mm3, 0, 1e-12);
    mesh_release(&m);
}

T_CASE(cube_on_face_needs_no_support)
{
    struct mesh m;
    struct sf_err err;
    struct support_metrics s;
    mesh_init(&m);
    T_OK(shape_box(&m, v3(0, 0, 0), v3(20, 20, 20), &err), &err);
    struct vec3 dirs[] = { { 0, 0, 1 }, { 0, 0, -1 }, { 1, 0, 0 }, { 0, -1, 0 } };
    for (int i = 0; i < 4; i++) {
        T_OK(metrics(&m, dirs[i], 45, 1, &s, &err), &err);
        T_EQ_INT(s.n_risky, 0);
        T_EQ_DBL(s.volume_mm3, 0, 1e-12);
        T_EQ_DBL(s.com_height_mm, 10, 1e-9);
    }
    /* balanced on an edge, both lower faces lean 45 degrees: exactly at the limit */
    T_OK(metrics(&m, v3(1 / M_SQRT2, 0, 1 / M_SQRT2), 44, 1, &s, &err), &err);
    T_EQ_INT(s.n_risky, 4); /* two faces, two triangles each */
    mesh_release(&m);
}

T_CASE(sphere_risky_area_matches_spherical_cap)
{
    struct mesh m;
    struct sf_err err;
    struct support_metrics s;
    mesh_init(&m);
    const double R = 20;
    T_OK(shape_sphere(&m, R, 180, &err), &err); /* 1 degree bands */
    double angles[] = { 45, 30, 60 };
    for (int i = 0; i < 3; i++) {
        T_OK(metrics(&m, v3(0, 0, 1), angles[i], 1, &s, &err), &err);
        /* faces with n.z < -sin(a): the cap within 90 - a of the bottom pole */
        double cap = 2 * M_PI * R * R * (1 - cos((90 - angles[i]) * M_PI / 180));
        T_EQ_DBL(s.risky_area_mm2 / cap, 1, 0.02);
    }
    T_EQ_DBL(s.com_height_mm, R, 0.01);
    mesh_release(&m);
}

T_CASE(rotating_the_part_and_the_direction_together_changes_nothing)
{
    struct mesh m;
    struct sf_err err;
    struct support_metrics a, b;
    mesh_init(&m);
    T_OK(shape_arch(&m, &err), &err);
    T_OK(metrics(&m, v3(0, 0, 1), 45, 0.5, &a, &err), &err);
    struct mat3 r = m3_axis_angle(v3_normalize(v3(1, 2, 3)), 1.1);
    mesh_transform(&m, r, v3(5, -7, 11));
    T_OK(metrics(&m, m3_mul_v(r, v3(0, 0, 1)), 45, 0.5, &b, &err), &err);
    T_TRUE(a.volume_mm3 > 1000);
    T_EQ_DBL(b.volume_mm3 / a.volume_mm3, 1, 0.03);
    T_EQ_DBL(b.risky_area_mm2, a.risky_area_mm2, 1e-6);
    T_EQ_INT(b.n_risky, a.n_risky);
    mesh_release(&m);
}

T_CASE(columns_start_on_the_part_below)
{
    /* an arch: the columns under the opening's crown stand on the bed, and the
       grid's hits along each ray alternate enter/exit */
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_arch(&m, &err), &err);
    struct raycast *rc = raycast_new(&m, &err);
    T_TRUE(rc != NULL);
    struct ray_grid g;
    T_OK(raycast_grid(rc, v3(0, 0, 1), 1, &g, &err), &err);
    for (uint32_t c = 0; c < g.nu * g.nw; c++) {
        uint32_t n = g.first[c + 1] - g.first[c];
        T_TRUE(n % 2 == 0);
        for (uint32_t k = g.first[c]; k < g.first[c + 1]; k++)
            T_TRUE((g.hits[k].cos_up < 0) == ((k - g.first[c]) % 2 == 0));
    }
    struct support_params p;
    support_params_default(&p);
    struct support_column *cols;
    size_t n;
    T_OK(measure_columns(&g, &p, &cols, &n, &err), &err);
    T_TRUE(n > 0);
    for (size_t i = 0; i < n; i++) {
        T_EQ_DBL(cols[i].lo, 0, 1e-6);
        /* only the crown leans more than 45 degrees: above 20 sin 45 */
        T_TRUE(cols[i].hi > 20 * sin(M_PI / 4) - 0.5);
    }
    free(cols);
    ray_grid_release(&g);
    raycast_free(rc);
    mesh_release(&m);
}

T_CASE(deviation_and_hausdorff)
{
    struct mesh a, b;
    struct sf_err err;
    mesh_init(&a);
    mesh_init(&b);
    T_OK(shape_box(&a, v3(0, 0, 0), v3(10, 10, 10), &err), &err);
    T_OK(mesh_copy(&b, &a, &err), &err);
    mesh_translate(&b, v3(3, 4, 0));
    struct deviation d;
    T_OK(measure_deviation(&a, &b, &d, &err), &err);
    T_EQ_DBL(d.max_mm, 5, 1e-12);
    T_EQ_DBL(d.mean_mm, 5, 1e-12);
    T_EQ_DBL(d.mndr, 5 / sqrt(300), 1e-12);
    double one, sym;
    mesh_translate(&b, v3(-3, -4, 2));
    T_OK(measure_hausdorff(&a, &b, &one, &sym, &err), &err);
    T_EQ_DBL(one, 2, 1e-5);
    T_EQ_DBL(sym, 2, 1e-5);
    /* concentric spheres of radius 10 and 11 */
    T_OK(shape_sphere(&a, 10, 40, &err), &err);
    T_OK(shape_sphere(&b, 11, 40, &err), &err);
    mesh_translate(&b, v3(0, 0, -1));
    T_OK(measure_hausdorff(&a, &b, &one, &sym, &err), &err);
    T_EQ_DBL(sym, 1, 0.05);
    mesh_release(&b);
    T_OK(shape_sphere(&b, 10, 8, &err), &err);
    T_ERR(measure_deviation(&a, &b, &d, &err), SF_EINVAL, &err, "same connectivity");
    mesh_release(&a);
    mesh_release(&b);
}

T_CASE(binned_proxy_agrees_with_the_face_by_face_one)
{
    int (*makers[])(struct mesh *, struct sf_err *) = { shape_sphere_on_stem, shape_tee,
                                                        shape_arch };
    for (int s = 0; s < 4; s++) {
        struct mesh m;
        struct sf_err err;
        mesh_init(&m);
        if (s < 3)
            T_OK(makers[s](&m, &err), &err);
        else
            T_OK(shape_torus(&m, 30, 10, 120, 60, &err), &err);
        struct proxy_cache pc;
        T_OK(proxy_cache_init(&pc, &m, NULL, 0, &err), &err);
        struct support_params p;
        support_params_default(&p);
        /* the axes (faces exactly on the bed) and 300 scattered directions */
        for (int i = 0; i < 306; i++) {
            struct vec3 axes[6] = { { 0, 0, 1 },  { 0, 0, -1 }, { 1, 0, 0 },
                                    { -1, 0, 0 }, { 0, 1, 0 },  { 0, -1, 0 } };
            struct vec3 up =
                i < 6 ? axes[i] : v3_normalize(v3(sin(i * 1.3), cos(i * 0.7), sin(i * 0.4 + 1)));
            p.angle_deg = 30 + (i % 4) * 10;
            struct support_metrics a, b;
            measure_proxy(&m, up, &p, &a);
            proxy_eval(&pc, up, &p, &b);
            /* float vs double rounding may flip a face that sits on the limit */
            T_TRUE(abs((int)a.n_risky - (int)b.n_risky) <= 2);
            T_EQ_DBL(b.risky_area_mm2, a.risky_area_mm2, 0.002 * a.risky_area_mm2 + 1e-3);
            T_EQ_DBL(b.proxy_mm3, a.proxy_mm3, 0.002 * a.proxy_mm3 + 1e-2);
            T_EQ_DBL(b.build_height_mm, a.build_height_mm, 1e-3);
        }
        proxy_cache_release(&pc);
        mesh_release(&m);
    }
}

T_CASE(growth_finds_an_island_no_face_marks)
{
    /* a bridge on two piers whose underside has a steep downward V ridge:
       its faces lean 30 degrees, not risky at 45, yet the ridge starts in
       mid-air at z = 10 and must be held */
    double t30 = tan(30 * M_PI / 180);
    double x[] = { -30, -20, -20, -10 * t30, 0, 10 * t30, 20, 20, 30, 30, -30 };
    double z[] = { 0, 0, 20, 20, 10, 20, 20, 0, 0, 30, 30 };
    struct mesh m;
    struct sf_err err;
    struct support_metrics s;
    mesh_init(&m);
    T_OK(shape_extrude_xz(&m, x, z, 11, 20, &err), &err);
    T_OK(metrics(&m, v3(0, 0, 1), 45, 1, &s, &err), &err);
    T_EQ_INT(s.n_islands, 1);
    /* about a 1-2 mm wide strip, 20 mm long, 10-12 mm above the bed */
    T_TRUE(s.island_volume_mm3 > 100 && s.island_volume_mm3 < 600);
    T_TRUE(s.base_margin_mm > 0);
    /* the same bridge without the ridge has no island */
    double x2[] = { -30, -20, -20, 20, 20, 30, 30, -30 };
    double z2[] = { 0, 0, 20, 20, 0, 0, 30, 30 };
    T_OK(shape_extrude_xz(&m, x2, z2, 8, 20, &err), &err);
    T_OK(metrics(&m, v3(0, 0, 1), 45, 1, &s, &err), &err);
    T_EQ_INT(s.n_islands, 0);
    mesh_release(&m);
}

T_CASE(growth_sees_a_leaning_tower_tip_over)
{
    /* a 60 mm prism leaning 40 degrees on a 10 mm foot: no face is risky,
       but its centre of mass ends up 20 mm beyond the foot */
    double off = 60 * tan(40 * M_PI / 180);
    double x[] = { 0, 10, 10 + off, off }, z[] = { 0, 0, 60, 60 };
    struct mesh m;
    struct sf_err err;
    struct support_metrics s;
    mesh_init(&m);
    T_OK(shape_extrude_xz(&m, x, z, 4, 20, &err), &err);
    T_OK(metrics(&m, v3(0, 0, 1), 45, 1, &s, &err), &err);
    T_EQ_INT(s.n_risky, 0);
    T_TRUE(s.base_margin_mm < -10);
    /* upright it stands */
    double xs[] = { 0, 10, 10, 0 };
    T_OK(shape_extrude_xz(&m, xs, z, 4, 20, &err), &err);
    T_OK(metrics(&m, v3(0, 0, 1), 45, 1, &s, &err), &err);
    T_TRUE(s.base_margin_mm > 4);
    mesh_release(&m);
}
