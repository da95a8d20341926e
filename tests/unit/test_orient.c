/*
 * test_orient.c - the hull bases and the orientation search on generated
 * parts with known best orientations.
 */
#include <fcntl.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "../../src/geom/hull.h"
#include "../../src/geom/orient.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"

static int
find_w(const struct mesh *m, double w_stability, struct orient_result *r, struct sf_err *err)
{
    struct orient_params p;
    orient_params_default(&p);
    if (w_stability >= 0)
        p.w_stability_mm2 = w_stability;
    p.samples = 300; /* keeps the sanitizer build quick; bench uses 1000 */
    p.pitch_mm = 1;
    return orient_find(m, &p, r, err);
}

static int
find(const struct mesh *m, struct orient_result *r, struct sf_err *err)
{
    return find_w(m, -1, r, err);
}

static double
angle_deg(struct vec3 a, struct vec3 b)
{
    return acos(fmax(-1, fmin(1, v3_dot(v3_normalize(a), v3_normalize(b))))) * 180 / M_PI;
}

T_CASE(hull_bases_of_a_box)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_box(&m, v3(0, 0, 0), v3(10, 20, 30), &err), &err);
    struct hull_base *b;
    uint32_t n;
    struct vec3 com;
    mesh_volume(&m, &com);
    uint32_t *hv, n_hv;
    T_OK(hull_bases(&m, com, &b, &n, &hv, &n_hv, &err), &err);
    T_EQ_INT(n_hv, 8);
    free(hv);
    T_EQ_INT(n, 6); /* coplanar triangles merged into faces */
    T_EQ_DBL(b[0].area_mm2, 600, 1e-6);
    T_EQ_DBL(b[0].margin_mm, 10, 1e-6); /* com 10 mm from the long edges of the 20 x 30 face */
    T_EQ_DBL(b[5].area_mm2, 200, 1e-6);
    free(b);
    mesh_release(&m);
}

T_CASE(tee_upside_down_and_tilted_comes_back)
{
    struct mesh m;
    struct sf_err err;
    struct orient_result r;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    /* upside down, then tilted 20 degrees about x */
    struct mat3 rot =
        m3_mul(m3_axis_angle(v3(1, 0, 0), 20 * M_PI / 180), m3_axis_angle(v3(0, 1, 0), M_PI));
    mesh_transform(&m, rot, v3(0, 0, 0));
    T_OK(find(&m, &r, &err), &err);
    /* Two orientations need no support: on the bar's top (stem up) and lying
       on the T's profile face (up = the extrusion axis, y).  The profile is
       lower (20 vs 35 mm) and its centre of mass lower (10 vs 12 mm): best. */
    struct vec3 extrusion = m3_mul_v(rot, v3(0, 1, 0));
    T_TRUE(fabs(v3_dot(r.best.up, extrusion)) > cos(1 * M_PI / 180));
    T_EQ_DBL(r.best.m.com_height_mm, 10, 1e-6);
    bool stem_up_scored = false;
    for (int i = 0; i < r.n_runners; i++)
        if (angle_deg(r.runners[i].up, m3_mul_v(rot, v3(0, 0, -1))) < 1 &&
            r.runners[i].m.volume_mm3 == 0)
            stem_up_scored = true;
    T_TRUE(stem_up_scored);
    T_EQ_DBL(r.best.m.volume_mm3, 0, 1e-9);
    T_TRUE(r.input.m.volume_mm3 > 1000);
    mesh_release(&m);
}

T_CASE(cube_stays_on_a_face)
{
    struct mesh m;
    struct sf_err err;
    struct orient_result r;
    mesh_init(&m);
    T_OK(shape_box(&m, v3(0, 0, 0), v3(20, 20, 20), &err), &err);
    T_OK(find(&m, &r, &err), &err);
    double ax = fmax(fabs(r.best.up.x), fmax(fabs(r.best.up.y), fabs(r.best.up.z)));
    T_EQ_DBL(ax, 1, 1e-9);
    T_EQ_DBL(r.best.m.volume_mm3, 0, 1e-9);
    mesh_release(&m);
}

T_CASE(lbracket_lies_on_its_large_face)
{
    struct mesh m;
    struct sf_err err;
    struct orient_result r;
    mesh_init(&m);
    T_OK(shape_lbracket(&m, &err), &err);
    /* stand it on the wall's end: the plate then overhangs */
    struct mat3 rot = m3_axis_angle(v3(0, 1, 0), -M_PI / 2);
    mesh_transform(&m, rot, v3(0, 0, 0));
    T_OK(find(&m, &r, &err), &err);
    /* the large face is the plate's underside, 40 x 60: up is its inward normal */
    struct vec3 plate_up = m3_mul_v(rot, v3(0, 0, 1));
    T_TRUE(angle_deg(r.best.up, plate_up) < 1);
    T_EQ_DBL(r.best.m.volume_mm3, 0, 1e-9);
    mesh_release(&m);
}

T_CASE(tiny_hull_face_is_not_a_base)
{
    /* a frustum: 40 x 40 base, 1 x 1 top, sides lean 18 degrees: supportless
       either way up, but it must not be balanced on the 1 mm2 top */
    struct mesh m;
    struct sf_err err;
    struct orient_result r;
    mesh_init(&m);
    double x[4] = { -20, 20, 0.5, -0.5 }, z[4] = { 0, 0, 60, 60 };
    T_OK(shape_extrude_xz(&m, x, z, 4, 40, &err), &err); /* a wedge in x; now taper y */
    for (uint32_t i = 0; i < m.n_verts; i++) {
        double f = 1 - m.v[i].z / 60 * (39.0 / 40);
        m.v[i].y = 20 + (m.v[i].y - 20) * f;
    }
    mesh_transform(&m, m3_axis_angle(v3(1, 0, 0), M_PI), v3(0, 0, 0)); /* on its tip */
    /* no stability weight: only the standing rule keeps it off the tip, where
       it needs no support either (and the input orientation comes first) */
    T_OK(find_w(&m, 0, &r, &err), &err);
    orient_apply(&m, r.best.up, 0, 0);
    /* what touches the bed spans at least 40 mm (a real face, not the tip) */
    struct vec3 lo = v3(INFINITY, INFINITY, 0), hi = v3(-INFINITY, -INFINITY, 0);
    for (uint32_t i = 0; i < m.n_verts; i++)
        if (m.v[i].z < 1e-6) {
            lo = v3_min(lo, m.v[i]);
            hi = v3_max(hi, m.v[i]);
        }
    T_TRUE(fmax(hi.x - lo.x, hi.y - lo.y) >= 40 - 1e-6);
    T_EQ_DBL(r.best.m.volume_mm3, 0, 1e-9);
    mesh_release(&m);
}

T_CASE(leaning_tower_is_not_left_to_tip_over)
{
    /* leaning 40 degrees on a 10 mm foot: no support needed, but it would
       topple while printing; the search must stand it on a real base */
    double off = 60 * tan(40 * M_PI / 180);
    double x[] = { 0, 10, 10 + off, off }, z[] = { 0, 0, 60, 60 };
    struct mesh m;
    struct sf_err err;
    struct orient_result r;
    mesh_init(&m);
    T_OK(shape_extrude_xz(&m, x, z, 4, 20, &err), &err);
    /* no stability weight: the input, first and supportless, would win a tie */
    T_OK(find_w(&m, 0, &r, &err), &err);
    T_TRUE(r.input.m.base_margin_mm < 0);
    T_TRUE(r.best.m.base_margin_mm > 0);
    T_TRUE(angle_deg(r.best.up, v3(0, 0, 1)) > 10);
    mesh_release(&m);
}

T_CASE(an_open_shell_is_left_as_it_is)
{
    /* a tee with its whole top face missing: rays cannot tell inside from
       outside, so no support figure can be trusted and nothing is turned */
    struct mesh m;
    struct sf_err err;
    struct orient_result r;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    uint32_t kept = 0;
    for (uint32_t i = 0; i < m.n_tris; i++) {
        struct vec3 n = mesh_tri_normal(&m, i), c = mesh_tri_centroid(&m, i);
        if (!(n.z > 0.99 && c.z > 34.9))
            memcpy(m.t[kept++], m.t[i], sizeof(m.t[0]));
    }
    T_EQ_INT(m.n_tris - kept, 2);
    m.n_tris = kept;
    T_OK(find(&m, &r, &err), &err);
    T_TRUE(r.not_solid);
    T_TRUE(r.input.m.n_rays_open > 0);
    T_EQ_DBL(r.best.up.z, 1, 1e-12);
    mesh_release(&m);
}

/* A 40-sided prism has 42 stable hull bases (40 sides of 94 mm2, the centre
   of mass 1.2 mm inside each, and two caps); only the exact_hull best by
   proxy are ray-cast, and the search still stands it on a cap. */
T_CASE(many_hull_bases_are_pruned_by_the_proxy)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    double r[4] = { 0, 15, 15, 0 }, z[4] = { 0, 0, 40, 40 };
    T_OK(shape_revolve(&m, r, z, 4, 40, &err), &err);
    /* tilted, so the input is not already the answer */
    mesh_transform(&m, m3_rotate_onto(v3(0, 0, 1), v3_normalize(v3(1, 0.2, 0.3))), v3(0, 0, 0));
    struct orient_result pruned, all;
    struct orient_params p;
    orient_params_default(&p);
    p.samples = 200;
    T_OK(orient_find(&m, &p, &pruned, &err), &err);
    uint32_t kept = (uint32_t)p.exact_hull;
    p.exact_hull = 1000;
    T_OK(orient_find(&m, &p, &all, &err), &err);
    /* at most 21 casts past the first stage: 16 refinement samples and 5 finalists */
    T_TRUE(pruned.n_exact <= (uint32_t)p.exact_top + kept + 1 + 21);
    T_TRUE(all.n_exact >= pruned.n_exact + 42 - kept);
    for (int i = 0; i < 2; i++) {
        const struct orient_result *res = i ? &all : &pruned;
        struct vec3 axis = v3_normalize(v3(1, 0.2, 0.3)); /* the caps' normals, turned */
        T_TRUE(fmin(angle_deg(res->best.up, axis), angle_deg(res->best.up, v3_scale(axis, -1))) <
               1e-6);
        T_EQ_DBL(res->best.m.volume_mm3, 0, 1e-9);
    }
    mesh_release(&m);
}

/* The helper threads (one builds the scene while the caller runs the proxy
   stage) change who scores what, never the answer: 1, 2 and 5 threads agree
   to the bit.  A part with no hull fails cleanly with the helpers started. */
T_CASE(same_answer_on_any_thread_count)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    mesh_transform(&m, m3_rotate_onto(v3(0, 0, 1), v3_normalize(v3(0.3, -0.2, -1))), v3(0, 0, 0));
    struct orient_result r[3];
    int threads[3] = { 1, 2, 5 };
    for (int i = 0; i < 3; i++) {
        struct orient_params p;
        orient_params_default(&p);
        p.samples = 200;
        p.threads = threads[i];
        T_OK(orient_find(&m, &p, &r[i], &err), &err);
    }
    for (int i = 1; i < 3; i++) {
        T_TRUE(memcmp(&r[i].best.up, &r[0].best.up, sizeof(r[0].best.up)) == 0);
        T_TRUE(r[i].best.cost == r[0].best.cost);
        T_TRUE(r[i].best.m.volume_mm3 == r[0].best.m.volume_mm3);
        T_TRUE(r[i].input.cost == r[0].input.cost);
        T_EQ_INT(r[i].n_exact, r[0].n_exact);
        T_EQ_INT(r[i].n_runners, r[0].n_runners);
        for (int k = 0; k < r[0].n_runners; k++)
            T_TRUE(r[i].runners[k].cost == r[0].runners[k].cost);
    }
    mesh_release(&m);

    /* flat: qhull refuses it */
    T_OK(shape_box(&m, v3(0, 0, 0), v3(10, 10, 10), &err), &err);
    for (uint32_t i = 0; i < m.n_verts; i++)
        m.v[i].z = 0;
    struct orient_params p;
    orient_params_default(&p);
    p.threads = 2;
    /* ... saying why in the error, with nothing of qhull's page-long report on stderr */
    char errpath[512];
    snprintf(errpath, sizeof(errpath), "%s/flat-stderr", t_tmpdir());
    fflush(stderr);
    int saved = dup(2), fd = open(errpath, O_WRONLY | O_CREAT | O_TRUNC, 0600);
    T_TRUE(saved >= 0 && fd >= 0);
    dup2(fd, 2);
    close(fd);
    int rc = orient_find(&m, &p, &r[0], &err);
    fflush(stderr);
    dup2(saved, 2);
    close(saved);
    T_ERR(rc, SF_EINVAL, &err, "convex hull failed: flat or degenerate part (QH");
    struct stat st;
    T_TRUE(stat(errpath, &st) == 0);
    T_EQ_INT(st.st_size, 0);
    mesh_release(&m);
}
