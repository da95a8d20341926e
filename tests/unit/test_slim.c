/*
 * test_slim.c - support slimming on generated parts: the tet mesh and its
 * embedding, the ARAP global step, self-intersection, and the behaviour
 * of the whole loop (Hu 2015): a tee's arms rise, a cube stays, fixed
 * vertices stay, limits hold.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/base/mem.h"
#include "../../src/geom/arap.h"
#include "../../src/geom/selfx.h"
#include "../../src/geom/slim.h"
#include "../../src/geom/tetmesh.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"

/* Coarser than the defaults so the sanitizer build stays quick. */
static void
quick_params(struct slim_params *p)
{
    slim_params_default(p);
    p->tet.cells = 12;
    p->threads = 1;
}

/* The tee's left arm (shape_tee), held by the cases that fix it. */
static const struct slim_box tee_left_arm = { { -30, -1, 28 }, { -6, 21, 36 } };

/*
 * The tee cases' preamble: shape_tee in m (initialised here; mesh_release
 * it) and quick parameters at alpha 75 degrees, where its flat arms are
 * safe once tilted 16 (PrusaSlicer's threshold 15, + 1 inclusive), with a
 * deviation budget its 20 mm arms can turn in (0.5 / 0.5; they cannot in
 * the default 5 % / 1.5 %).  With hold_left the left arm is fixed by a box
 * and the bottom by 3 mm.
 */
static int
tee_at_75(struct mesh *m, struct slim_params *p, bool hold_left, struct sf_err *err)
{
    mesh_init(m);
    quick_params(p);
    p->angle_deg = 75;
    p->max_mndr = 0.5;
    p->max_andr = 0.5;
    if (hold_left) {
        p->fix_boxes = &tee_left_arm;
        p->n_fix_boxes = 1;
        p->fix_bottom_mm = 3;
    }
    return shape_tee(m, err);
}

/* a and b side by side (b moved by off) as one mesh */
static int
concat(struct mesh *out, const struct mesh *a, const struct mesh *b, struct vec3 off,
       struct sf_err *err)
{
    int rc = mesh_alloc(out, a->n_verts + b->n_verts, a->n_tris + b->n_tris, err);
    if (rc)
        return rc;
    memcpy(out->v, a->v, sizeof(*a->v) * a->n_verts);
    for (uint32_t i = 0; i < b->n_verts; i++)
        out->v[a->n_verts + i] = v3_add(b->v[i], off);
    memcpy(out->t, a->t, sizeof(*a->t) * a->n_tris);
    for (uint32_t i = 0; i < b->n_tris; i++)
        for (int k = 0; k < 3; k++)
            out->t[a->n_tris + i][k] = b->t[i][k] + a->n_verts;
    return SF_OK;
}

static int
check_embedding(const struct mesh *m, struct sf_err *err)
{
    struct tetmesh_params tp;
    struct tetmesh tm;
    tetmesh_params_default(&tp);
    tp.cells = 12;
    int rc = tetmesh_build(m, &tp, &tm, err);
    if (rc)
        return rc;
    int ok = tm.n_outside == 0 && tm.n_part == m->n_verts;
    for (uint32_t t = 0; t < tm.n_tets; t++) {
        ok &= tetmesh_volume(&tm, tm.x, t) > 0;
        int ns = 0;
        for (int f = 0; f < 4; f++)
            ns += tm.surf[t] >> f & 1;
        ok &= ns <= 2; /* 3+ were split */
    }
    struct vec3 *back = mem_array(m->n_verts, sizeof(*back));
    tetmesh_map(&tm, tm.x, back);
    for (uint32_t v = 0; back && v < m->n_verts; v++) {
        ok &= v3_len(v3_sub(back[v], m->v[v])) < 1e-9;
        for (int k = 0; k < 4; k++)
            ok &= tm.bary[v][k] >= -1e-9;
    }
    if (!ok)
        fprintf(stderr, "  embedding: %u outside, %u verts, %u tets\n", tm.n_outside, tm.n_verts,
                tm.n_tets);
    free(back);
    tetmesh_release(&tm);
    return ok ? SF_OK : SF_EBUG;
}

T_CASE(tetmesh_encloses_any_genus_and_several_shells)
{
    struct mesh torus, box, two, sos;
    struct sf_err err;
    mesh_init(&torus);
    mesh_init(&box);
    mesh_init(&two);
    mesh_init(&sos);
    T_OK(shape_torus(&torus, 20, 6, 32, 16, &err), &err);
    T_OK(check_embedding(&torus, &err), &err); /* genus 1 */
    T_OK(shape_box(&box, v3(0, 0, 0), v3(10, 10, 10), &err), &err);
    T_OK(concat(&two, &box, &box, v3(25, 0, 0), &err), &err);
    T_OK(check_embedding(&two, &err), &err); /* two shells */
    T_OK(shape_sphere_on_stem(&sos, &err), &err);
    T_OK(check_embedding(&sos, &err), &err);
    mesh_release(&torus);
    mesh_release(&box);
    mesh_release(&two);
    mesh_release(&sos);
}

/*
 * An open shell (a box without its top, as mech-holes-shark's 431 rays of
 * 5981 meet unpaired surfaces): the rays entering through its bottom never
 * leave, and the envelope, which took everything above such an entry for
 * inside, ran off its lattice open; TetGen then kept no tetrahedra.
 */
T_CASE(tetmesh_encloses_an_open_shell)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_box(&m, v3(0, 0, 0), v3(20, 20, 10), &err), &err);
    uint32_t n = 0;
    for (uint32_t i = 0; i < m.n_tris; i++)
        if (!(mesh_tri_normal(&m, i).z > 0.5))
            memcpy(m.t[n++], m.t[i], sizeof(*m.t));
    T_EQ_INT(n, m.n_tris - 2);
    m.n_tris = n;
    T_OK(check_embedding(&m, &err), &err);
    /* and it slims: its bottom rests on the bed, nothing to do, the input back */
    struct slim_params p;
    struct slim_result r;
    quick_params(&p);
    T_OK(slim_optimize(&m, &p, &r, &err), &err);
    T_EQ_INT(r.best_iter, 0);
    slim_result_release(&r);
    mesh_release(&m);
}

T_CASE(tetmesh_respects_the_vertex_target)
{
    struct mesh m;
    struct sf_err err;
    struct tetmesh_params tp;
    struct tetmesh tm;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    tetmesh_params_default(&tp);
    tp.cells = 16;
    tp.max_verts = 800;
    T_OK(tetmesh_build(&m, &tp, &tm, &err), &err);
    T_TRUE(tm.n_verts <= 800);
    T_EQ_INT(tm.n_outside, 0);
    tetmesh_release(&tm);
    mesh_release(&m);
}

T_CASE(global_step_reproduces_a_rigid_motion)
{
    struct mesh m;
    struct sf_err err;
    struct tetmesh_params tp;
    struct tetmesh tm;
    mesh_init(&m);
    T_OK(shape_sphere_on_stem(&m, &err), &err);
    tetmesh_params_default(&tp);
    tp.cells = 10;
    T_OK(tetmesh_build(&m, &tp, &tm, &err), &err);
    uint8_t *fixed = mem_calloc(tm.n_verts, 1);
    struct vec3 *x = mem_array(tm.n_verts, sizeof(*x));
    T_TRUE(fixed && x);
    struct mat3 r = m3_axis_angle(v3_normalize(v3(1, 2, 3)), 0.7);
    struct vec3 t = v3(5, -3, 11);
    for (uint32_t v = 0; v < tm.n_verts; v++) {
        fixed[v] = tm.x[v].z < 3;
        /* fixed vertices carry the motion; free ones start anywhere */
        x[v] = fixed[v] ? v3_add(m3_mul_v(r, tm.x[v]), t) : v3(0, 0, 0);
    }
    struct arap *a = arap_new(&tm, fixed, &err);
    T_TRUE(a != NULL);
    arap_set_rotation(a, r);
    T_OK(arap_global(a, x, &err), &err);
    double worst = 0;
    for (uint32_t v = 0; v < tm.n_verts; v++)
        worst = fmax(worst, v3_len(v3_sub(x[v], v3_add(m3_mul_v(r, tm.x[v]), t))));
    T_EQ_DBL(worst, 0, 1e-9);
    /* and the local step finds the same rotation everywhere */
    arap_local(a, x, v3(0, 0, 1), 0.7, 0, NULL, 0, NULL);
    T_OK(arap_global(a, x, &err), &err);
    worst = 0;
    for (uint32_t v = 0; v < tm.n_verts; v++)
        worst = fmax(worst, v3_len(v3_sub(x[v], v3_add(m3_mul_v(r, tm.x[v]), t))));
    T_EQ_DBL(worst, 0, 1e-9);
    /* rotations set after a local step win over the right-hand side that
       step assembled in its pass (arap.c keeps b only while it is current) */
    for (uint32_t v = 0; v < tm.n_verts; v++)
        if (fixed[v])
            x[v] = tm.x[v];
    arap_set_rotation(a, m3_identity());
    T_OK(arap_global(a, x, &err), &err);
    worst = 0;
    for (uint32_t v = 0; v < tm.n_verts; v++)
        worst = fmax(worst, v3_len(v3_sub(x[v], tm.x[v])));
    T_EQ_DBL(worst, 0, 1e-9);
    arap_free(a);
    /* nothing fixed: no unique solution, a clear error */
    memset(fixed, 0, tm.n_verts);
    T_TRUE(arap_new(&tm, fixed, &err) == NULL);
    T_ERR(err.code, SF_EINVAL, &err, "no fixed vertex");
    free(fixed);
    free(x);
    tetmesh_release(&tm);
    mesh_release(&m);
}

T_CASE(selfx_sees_crossing_shells_only)
{
    struct mesh a, two, apart;
    struct sf_err err;
    mesh_init(&a);
    mesh_init(&two);
    mesh_init(&apart);
    T_OK(shape_box(&a, v3(0, 0, 0), v3(10, 10, 10), &err), &err);
    T_EQ_INT(selfx_count(&a, &err), 0);
    T_OK(concat(&two, &a, &a, v3(5, 3, 2), &err), &err);
    T_TRUE(selfx_count(&two, &err) > 0);
    T_OK(concat(&apart, &a, &a, v3(12, 0, 0), &err), &err);
    T_EQ_INT(selfx_count(&apart, &err), 0);
    mesh_release(&a);
    mesh_release(&two);
    mesh_release(&apart);
}

T_CASE(cube_is_unchanged)
{
    struct mesh m;
    struct sf_err err;
    struct slim_params p;
    struct slim_result r;
    mesh_init(&m);
    T_OK(shape_box(&m, v3(0, 0, 0), v3(20, 20, 20), &err), &err);
    quick_params(&p);
    p.tet.cells = 8;
    T_OK(slim_optimize(&m, &p, &r, &err), &err);
    T_EQ_INT(r.best_iter, 0);
    T_EQ_INT(r.out.n_verts, m.n_verts);
    T_TRUE(memcmp(r.out.v, m.v, sizeof(*m.v) * m.n_verts) == 0);
    T_EQ_INT(r.after.n_risky, 0);
    T_EQ_DBL(r.dev.mndr, 0, 0);
    T_EQ_DBL(r.part_volume_in_mm3, 8000, 1e-6);
    T_EQ_DBL(r.part_volume_out_mm3, 8000, 1e-6);
    slim_result_release(&r);
    mesh_release(&m);
}

/* Lowest z of the tee's arm-tip vertices (|x| = 25 in the input) per side. */
static void
tip_heights(const struct mesh *in, const struct mesh *out, double *left, double *right)
{
    *left = *right = INFINITY;
    for (uint32_t v = 0; v < in->n_verts; v++) {
        if (in->v[v].x < -24.9)
            *left = fmin(*left, out->v[v].z);
        if (in->v[v].x > 24.9)
            *right = fmin(*right, out->v[v].z);
    }
}

T_CASE(tee_arms_rise_until_safe)
{
    struct mesh m;
    struct sf_err err;
    struct slim_params p;
    struct slim_result r;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    slim_params_default(&p);
    /* the tee's arms are flat: at alpha = 75 they are safe once tilted 15 degrees
       by the ray cast and 16 by PrusaSlicer (threshold 15, + 1 inclusive): arms
       planar at 15.5 degrees need 8.18 g in PrusaSlicer 2.5 at --angle 75 (the
       flat tee 6.17 g), at 16.5 none.  A deformation past the default deviation
       limits, aimed 10 degrees past alpha: at the default 5 the arms stall in
       that one-degree band, which the support model rightly refuses. */
    p.angle_deg = 75;
    p.margin_deg = 10;
    p.max_mndr = 0.5;
    p.max_andr = 0.5;
    T_OK(slim_optimize(&m, &p, &r, &err), &err);
    T_EQ_INT(r.before.n_risky, 4);
    T_EQ_INT(r.after.n_risky, 0);
    T_EQ_DBL(r.after.volume_mm3, 0, 1e-9);
    T_TRUE(r.before.volume_mm3 > 1000);
    /* PrusaSlicer prints no support under this result (0.00 g at --angle 75) */
    T_TRUE(r.model_before_g > 4);
    T_EQ_DBL(r.model_after_g, 0, 1e-12);
    double left, right;
    tip_heights(&m, &r.out, &left, &right);
    T_TRUE(left > 31 && right > 31); /* both rose from z = 30 */
    T_EQ_INT(r.n_inverted, 0);
    T_TRUE(r.curve[r.n_curve - 1] <= r.curve[0]);
    slim_result_release(&r);
    mesh_release(&m);
}

T_CASE(tee_at_45_degrees_keeps_the_input)
{
    /* At 45 degrees a budget that lets the arms turn (0.15 / 0.05) tilts them
       partway, which lowers the ray-cast volume but costs more support in
       PrusaSlicer 2.5 (--angle 45: flat 6.17 g, arms planar at 10 degrees
       7.82 g, at 20 8.58 g: the flat arms are partly bridged, sloped ones are
       not, and their columns are taller).  The model sees no gain: the input
       stays. */
    struct mesh m;
    struct sf_err err;
    struct slim_params p;
    struct slim_result r;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    quick_params(&p);
    p.beta_step_deg = 15;
    p.max_mndr = 0.15;
    p.max_andr = 0.05;
    p.min_gain = 0;
    T_OK(slim_optimize(&m, &p, &r, &err), &err);
    T_TRUE(r.model_before_g > 4);
    T_EQ_INT(r.best_iter, 0);
    T_EQ_DBL(r.model_after_g, r.model_before_g, 1e-12);
    T_EQ_INT(r.out.n_verts, m.n_verts);
    T_TRUE(memcmp(r.out.v, m.v, sizeof(*m.v) * m.n_verts) == 0);
    slim_result_release(&r);
    mesh_release(&m);
}

T_CASE(tee_at_75_degrees_stays_within_the_limits)
{
    struct mesh m;
    struct sf_err err;
    struct slim_params p;
    struct slim_result r;
    T_OK(tee_at_75(&m, &p, false, &err), &err);
    p.beta_step_deg = 15; /* fewer rounds: the sanitizer build is slow */
    /* a tighter budget, still one the arms can turn in, to see the limits and
       the volume kept; aimed 10 degrees past the model's 16, they turn far
       enough for PrusaSlicer to drop their support (0.00 g at --angle 75, the
       input 6.17 g) */
    p.margin_deg = 10;
    p.max_mndr = 0.15;
    p.max_andr = 0.05;
    T_OK(slim_optimize(&m, &p, &r, &err), &err);
    T_TRUE(r.model_after_g < r.model_before_g);
    T_TRUE(r.dev.mndr <= p.max_mndr && r.dev.andr <= p.max_andr);
    T_TRUE(r.after.volume_mm3 <= r.before.volume_mm3);
    T_TRUE(r.after.n_risky <= r.before.n_risky);
    double left, right;
    tip_heights(&m, &r.out, &left, &right);
    T_TRUE(left >= 30 - 1e-9 && right >= 30 - 1e-9); /* nothing sagged */
    T_TRUE(r.selfx_out <= r.selfx_input);
    /* the volumes reported are the input's and the result's, equal by the rescale (the
       tee's 16 vertices follow the tets' squash into +20 % without it) */
    T_TRUE(r.best_iter > 0);
    T_EQ_DBL(r.part_volume_in_mm3, mesh_volume(&m, NULL), 1e-6);
    T_EQ_DBL(r.part_volume_out_mm3, mesh_volume(&r.out, NULL), 1e-6);
    T_EQ_DBL(r.part_volume_out_mm3, r.part_volume_in_mm3, 1e-9 * r.part_volume_in_mm3);
    T_TRUE(fabs(r.volume_scale - 1) > 1e-3);
    slim_result_release(&r);
    mesh_release(&m);
}

/* A result must save at least min_gain of the input's modelled support; else the input is kept. */
T_CASE(a_small_saving_keeps_the_input)
{
    /* The tee at 75 degrees with its left arm held: the free arm rises past
       PrusaSlicer's 16 degrees, about half the support goes (PrusaSlicer 2.5
       at --angle 75: 6.17 g -> 3.46 g on this result) */
    struct mesh m;
    struct sf_err err;
    struct slim_params p;
    struct slim_result any, dflt, none;
    T_OK(tee_at_75(&m, &p, true, &err), &err);
    p.min_gain = 0;
    T_OK(slim_optimize(&m, &p, &any, &err), &err);
    T_TRUE(any.best_iter > 0 && any.model_after_g < any.model_before_g);
    T_TRUE(any.model_after_g > 0.3 * any.model_before_g); /* the held arm keeps its support */
    p.min_gain = 0.05;                                    /* the default */
    T_OK(slim_optimize(&m, &p, &dflt, &err), &err);
    T_TRUE(dflt.best_iter > 0 && dflt.model_after_g <= 0.95 * dflt.model_before_g);
    /* nothing saves 99 %: the input comes back as it was */
    p.min_gain = 0.99;
    T_OK(slim_optimize(&m, &p, &none, &err), &err);
    T_EQ_INT(none.best_iter, 0);
    T_EQ_INT(none.out.n_verts, m.n_verts);
    T_TRUE(memcmp(none.out.v, m.v, sizeof(*m.v) * m.n_verts) == 0);
    p.min_gain = 1;
    struct slim_result bad;
    T_ERR(slim_optimize(&m, &p, &bad, &err), SF_EINVAL, &err, "min_gain");
    slim_result_release(&any);
    slim_result_release(&dflt);
    slim_result_release(&none);
    mesh_release(&m);
}

static double
lowest_z(const struct mesh *m)
{
    double z = INFINITY;
    for (uint32_t v = 0; v < m->n_verts; v++)
        z = fmin(z, m->v[v].z);
    return z;
}

/* A torus lying on the bed: the lower half of its tube overhangs everywhere. */
T_CASE(result_keeps_the_part_volume)
{
    struct mesh m;
    struct sf_err err;
    struct slim_params p;
    struct slim_result kept, shrunk;
    mesh_init(&m);
    T_OK(shape_torus(&m, 30, 10, 48, 24, &err), &err);
    mesh_translate(&m, v3(0, 0, 10));
    quick_params(&p);
    p.angle_deg = 0; /* every downward face: the most shrink (5 % at this tet mesh) */
    p.margin_deg = 0;
    p.max_iters = 30;
    /* what this case checks is the volume: the support model's saving on the
       rescaled torus is small (8.80 -> 8.47 g, under the default 5 %), so any
       saving is taken */
    p.min_gain = 0;
    p.keep_volume = false;
    T_OK(slim_optimize(&m, &p, &shrunk, &err), &err);
    p.keep_volume = true;
    T_OK(slim_optimize(&m, &p, &kept, &err), &err);
    double vol = mesh_volume(&m, NULL);
    /* the deformation alone shrinks the part (arap.h, "Volume") */
    T_TRUE(shrunk.best_iter > 0);
    T_TRUE(shrunk.part_volume_out_mm3 < 0.97 * vol);
    T_EQ_DBL(shrunk.volume_scale, 1, 0);
    /* the default result has the input's volume, within rounding */
    T_TRUE(kept.best_iter > 0);
    T_EQ_DBL(kept.part_volume_in_mm3, vol, 1e-9 * vol);
    T_EQ_DBL(mesh_volume(&kept.out, NULL), vol, 1e-9 * vol);
    T_TRUE(kept.volume_scale > 1);
    /* a uniform scale turns no face: still fewer risky faces, less support, within the limits,
       resting on the bed where the input did */
    T_TRUE(kept.after.n_risky < kept.before.n_risky);
    T_TRUE(kept.after.volume_mm3 < kept.before.volume_mm3);
    T_TRUE(kept.dev.mndr <= p.max_mndr && kept.dev.andr <= p.max_andr);
    T_EQ_DBL(lowest_z(&kept.out), lowest_z(&m), 1e-9);
    T_EQ_INT(kept.n_inverted, 0);
    T_TRUE(kept.selfx_out <= kept.selfx_input);
    slim_result_release(&kept);
    slim_result_release(&shrunk);
    mesh_release(&m);
}

T_CASE(fixed_vertices_never_move)
{
    struct mesh m;
    struct sf_err err;
    struct slim_params p;
    struct slim_result r;
    T_OK(tee_at_75(&m, &p, true, &err), &err);
    const struct slim_box box = tee_left_arm;
    T_OK(slim_optimize(&m, &p, &r, &err), &err);
    T_TRUE(r.best_iter > 0); /* it did deform */
    int n_fixed = 0, n_moved = 0;
    for (uint32_t v = 0; v < m.n_verts; v++) {
        struct vec3 a = m.v[v];
        bool in_box = a.x >= box.lo.x && a.x <= box.hi.x && a.z >= box.lo.z && a.z <= box.hi.z;
        if (a.z <= 3 || in_box) {
            n_fixed++;
            n_moved += memcmp(&r.out.v[v], &a, sizeof(a)) != 0;
        }
    }
    T_TRUE(n_fixed >= 8);
    T_EQ_INT(n_moved, 0);
    double left, right;
    tip_heights(&m, &r.out, &left, &right);
    T_EQ_DBL(left, 30, 0);
    T_TRUE(right > 31); /* the free arm still rose */
    slim_result_release(&r);
    mesh_release(&m);
}

T_CASE(bad_parameters_are_rejected)
{
    struct mesh m;
    struct sf_err err;
    struct slim_params p;
    struct slim_result r;
    mesh_init(&m);
    T_OK(shape_box(&m, v3(0, 0, 0), v3(10, 10, 10), &err), &err);
    quick_params(&p);
    p.angle_deg = 95;
    T_ERR(slim_optimize(&m, &p, &r, &err), SF_EINVAL, &err, "angle 95");
    quick_params(&p);
    p.max_mndr = 0;
    T_ERR(slim_optimize(&m, &p, &r, &err), SF_EINVAL, &err, "deviation limits");
    quick_params(&p);
    p.max_iters = 0;
    T_ERR(slim_optimize(&m, &p, &r, &err), SF_EINVAL, &err, "iterations");
    struct mesh empty;
    mesh_init(&empty);
    quick_params(&p);
    T_ERR(slim_optimize(&empty, &p, &r, &err), SF_EINVAL, &err, "no triangles");
    mesh_release(&m);
}

static void
cancel_at_third(void *ud, const struct slim_progress *pr)
{
    if (pr->iter == 3)
        atomic_store((atomic_bool *)ud, true);
}

T_CASE(cancel_stops_with_ecanceled)
{
    struct mesh m;
    struct sf_err err;
    struct slim_params p;
    struct slim_result r;
    atomic_bool cancel = false;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    quick_params(&p);
    p.cancel = &cancel;
    p.progress = cancel_at_third;
    p.progress_ud = &cancel;
    T_ERR(slim_optimize(&m, &p, &r, &err), SF_ECANCELED, &err, "cancel");
    slim_result_release(&r);
    mesh_release(&m);
}

T_CASE(direction_search_tries_the_grid)
{
    struct mesh m;
    struct sf_err err;
    struct slim_params p;
    struct slim_result r, plain;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    quick_params(&p);
    p.tet.cells = 8;
    p.max_iters = 10;
    T_OK(slim_optimize(&m, &p, &plain, &err), &err);
    p.search_direction = true;
    p.search_step_deg = 30;
    p.search_max_deg = 30;
    p.threads = 2;
    T_OK(slim_optimize(&m, &p, &r, &err), &err);
    T_EQ_INT(r.n_dirs, 9);
    T_EQ_DBL(m3_det(r.rotation), 1, 1e-12);
    /* the untilted direction is on the grid, so the search is never worse */
    T_TRUE(r.after.volume_mm3 <= plain.after.volume_mm3 + 1e-6);
    slim_result_release(&r);
    slim_result_release(&plain);
    mesh_release(&m);
}

/*
 * A real part whose support slimming does reduce (bunny00: about 28 % with
 * these parameters).  Falling back to the input is a failure here: the
 * result must be a deformed iterate that saves at least min_gain of the
 * support volume within the deviation limits.  anchor.stl, the part this
 * test used before, comes back unchanged (its risky faces rise from the
 * first iteration), so the test passed on the fallback alone.
 */
T_CASE(shared_mesh_support_drops_within_limits)
{
    const char *path = t_shared_mesh("bunny00.stl");
    T_SKIP_UNLESS(path, "../shared/meshes is absent");
    struct mesh m;
    struct sf_err err;
    struct slim_params p;
    struct slim_result r;
    mesh_init(&m);
    T_OK(mesh_load(path, &m, NULL, &err), &err);
    quick_params(&p);
    T_OK(slim_optimize(&m, &p, &r, &err), &err);
    printf("    best_iter %d, support %.0f -> %.0f mm3, risky %u -> %u, mndr %.3f andr %.3f\n",
           r.best_iter, r.before.volume_mm3, r.after.volume_mm3, r.before.n_risky, r.after.n_risky,
           r.dev.mndr, r.dev.andr);
    T_TRUE(r.best_iter > 0); /* not the input handed back */
    T_TRUE(r.after.volume_mm3 <= (1 - p.min_gain) * r.before.volume_mm3);
    T_TRUE(r.after.n_risky < r.before.n_risky);
    T_TRUE(r.dev.mndr > 0 && r.dev.mndr <= p.max_mndr && r.dev.andr <= p.max_andr);
    T_TRUE(r.selfx_out <= r.selfx_input);
    slim_result_release(&r);
    mesh_release(&m);
}

T_CASE(faces_in_prusaslicers_inclusive_degree_are_turned)
{
    /* The tee at 75 degrees with its left arm held, at the default margin:
       PrusaSlicer (threshold 15, + 1 inclusive) supports faces flatter than
       16 degrees, so the free arm must rise past 16, not stall between 15
       and 16, where the support model still prices it (PrusaSlicer 2.5 at
       --angle 75: arms planar at 15.5 degrees 8.18 g, the flat tee 6.17 g)
       and the input came back. */
    struct mesh m;
    struct sf_err err;
    struct slim_params p;
    struct slim_result r;
    T_OK(tee_at_75(&m, &p, true, &err), &err);
    T_OK(slim_optimize(&m, &p, &r, &err), &err);
    T_TRUE(r.model_before_g > 4); /* PrusaSlicer: 6.17 g */
    T_TRUE(r.best_iter > 0);
    T_TRUE(r.model_after_g <= (1 - p.min_gain) * r.model_before_g);
    double left, right;
    tip_heights(&m, &r.out, &left, &right);
    T_EQ_DBL(left, 30, 0);
    T_TRUE(right > 31);
    slim_result_release(&r);
    mesh_release(&m);
}

/* The fewest grams the support model gave any iterate within the limits (slim_progress). */
struct model_low {
    double g; /* lowest model_g seen */
    int n;    /* iterates weighed */
};

static void
note_model(void *ud, const struct slim_progress *pr)
{
    struct model_low *lo = ud;
    if (!isnan(pr->model_g)) {
        lo->g = fmin(lo->g, pr->model_g);
        lo->n++;
    }
}

T_CASE(the_support_model_chooses_the_iterate)
{
    /* Every iterate within the limits is weighed by the model, and the one it
       gives the fewest grams is the result (it has no new self-intersection
       here): not one of those with the fewest risky faces. */
    struct mesh m;
    struct sf_err err;
    struct slim_params p;
    struct slim_result r;
    struct model_low lo = { INFINITY, 0 };
    mesh_init(&m);
    T_OK(shape_torus(&m, 30, 10, 48, 24, &err), &err);
    mesh_translate(&m, v3(0, 0, 10));
    quick_params(&p);
    p.angle_deg = 0;
    p.margin_deg = 0;
    p.max_iters = 30;
    p.patience = p.max_iters; /* all 30, all within the limits: more than the list holds */
    p.max_mndr = 0.5;
    p.max_andr = 0.5;
    p.beta_step_deg = 0;
    p.min_gain = 0;
    p.progress = note_model;
    p.progress_ud = &lo;
    T_OK(slim_optimize(&m, &p, &r, &err), &err);
    printf("    %d iterates weighed, fewest %.3f g, result %.3f g (iteration %d)\n", lo.n, lo.g,
           r.model_after_g, r.best_iter);
    T_TRUE(lo.n > 10);
    T_TRUE(r.best_iter > 0);
    T_EQ_DBL(r.model_after_g, lo.g, 1e-9 * lo.g);
    slim_result_release(&r);
    mesh_release(&m);
}

T_CASE(a_turned_direction_must_save_against_the_part_as_given)
{
    /* A slab tilted 20 degrees about x: the search's direction turned -15
       degrees tilts it 5, which needs far less support, but not 99 % less.
       With min_gain 0.99 nothing saves enough against the part as given, so
       it comes back as given: a turned direction is measured against it, not
       against its own turned input (kept as that direction's result). */
    struct mesh m;
    struct sf_err err;
    struct slim_params p;
    struct slim_result r;
    mesh_init(&m);
    T_OK(shape_box(&m, v3(-15, -15, 0), v3(15, 15, 5), &err), &err);
    mesh_transform(&m, m3_axis_angle(v3(1, 0, 0), 20 * M_PI / 180), v3(0, 0, 0));
    mesh_translate(&m, v3(0, 0, -lowest_z(&m)));
    quick_params(&p);
    p.tet.cells = 8;
    p.max_iters = 10;
    p.search_direction = true;
    p.search_step_deg = 15;
    p.search_max_deg = 15;
    p.min_gain = 0.99;
    T_OK(slim_optimize(&m, &p, &r, &err), &err);
    T_EQ_INT(r.n_dirs, 9);
    T_EQ_INT(r.best_iter, 0);
    T_TRUE(memcmp(&r.rotation, &(struct mat3){ { { 1, 0, 0 }, { 0, 1, 0 }, { 0, 0, 1 } } },
                  sizeof(r.rotation)) == 0);
    T_EQ_INT(r.out.n_verts, m.n_verts);
    T_TRUE(memcmp(r.out.v, m.v, sizeof(*m.v) * m.n_verts) == 0);
    /* with the default min_gain the turned direction wins; its saving is reported
       against the part as given */
    slim_result_release(&r);
    p.min_gain = 0.05;
    T_OK(slim_optimize(&m, &p, &r, &err), &err);
    T_TRUE(r.model_after_g <= 0.95 * r.model_before_g);
    T_TRUE(fabs(r.rotation.m[2][2] - 1) > 1e-3);
    slim_result_release(&r);
    mesh_release(&m);
}
