/*
 * test_slim_rot.c - the two kernels of the slimming local step: nearest
 * rotation (polar.c) and minimal rotation on the Gauss sphere (minrot.c),
 * checked against constructions with known answers and brute force.
 */
#include <math.h>
#include <stdlib.h>

#include "../../src/geom/minrot.h"
#include "../../src/geom/polar.h"
#include "../t.h"

/* Deterministic xorshift, so a failure reproduces. */
static unsigned long long rng_state = 88172645463325252ull;
static double
urand(void)
{
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 7;
    rng_state ^= rng_state << 17;
    return (double)(rng_state >> 11) / 9007199254740992.0;
}

static struct vec3
rand_unit(void)
{
    double z = 2 * urand() - 1, phi = 2 * M_PI * urand(), r = sqrt(1 - z * z);
    return v3(r * cos(phi), r * sin(phi), z);
}

static struct mat3
rand_rotation(void)
{
    return m3_axis_angle(rand_unit(), M_PI * urand());
}

static double
m3_dist(struct mat3 a, struct mat3 b)
{
    double s = 0;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            s += (a.m[i][j] - b.m[i][j]) * (a.m[i][j] - b.m[i][j]);
    return sqrt(s);
}

/* A = Q0 diag(s) Q1^T: the nearest rotation is Q0 Q1^T whenever s is sorted
   by magnitude and only the smallest may be negative. */
static struct mat3
compose(struct mat3 q0, const double s[3], struct mat3 q1)
{
    struct mat3 d = { { { s[0], 0, 0 }, { 0, s[1], 0 }, { 0, 0, s[2] } } };
    return m3_mul(m3_mul(q0, d), m3_transpose(q1));
}

/* Both paths on one matrix: the scalar one and lane 3 of a block. */
static int
check_polar(struct mat3 a, struct mat3 want, double tol)
{
    struct mat3 r1 = polar_rotation(a);
    double blk[9][POLAR_W], out[9][POLAR_W];
    for (int l = 0; l < POLAR_W; l++) {
        struct mat3 other = l == 3 ? a : rand_rotation();
        for (int c = 0; c < 9; c++)
            blk[c][l] = other.m[c / 3][c % 3];
    }
    polar_block(blk, out);
    struct mat3 r2;
    for (int c = 0; c < 9; c++)
        r2.m[c / 3][c % 3] = out[c][3];
    if (m3_dist(r1, want) > tol || m3_dist(r2, want) > tol) {
        fprintf(stderr, "  polar: scalar off by %g, block off by %g (tol %g)\n", m3_dist(r1, want),
                m3_dist(r2, want), tol);
        return 0;
    }
    return fabs(m3_det(r1) - 1) < 1e-9 && fabs(m3_det(r2) - 1) < 1e-9;
}

T_CASE(polar_random_matrices)
{
    for (int i = 0; i < 2000; i++) {
        struct mat3 q0 = rand_rotation(), q1 = rand_rotation();
        double s[3] = { 0.2 + 3 * urand(), 0, 0 };
        s[1] = s[0] * (0.1 + 0.9 * urand());
        s[2] = s[1] * (0.1 + 0.9 * urand());
        T_TRUE(check_polar(compose(q0, s, q1), m3_mul(q0, m3_transpose(q1)), 1e-9));
    }
}

T_CASE(polar_near_singular_matrices)
{
    for (int i = 0; i < 1000; i++) {
        struct mat3 q0 = rand_rotation(), q1 = rand_rotation();
        double s[3] = { 1 + urand(), 0.5 + 0.5 * urand(), pow(10, -4 - 8 * urand()) };
        T_TRUE(check_polar(compose(q0, s, q1), m3_mul(q0, m3_transpose(q1)), 1e-7));
    }
}

T_CASE(polar_reflected_matrices)
{
    for (int i = 0; i < 1000; i++) {
        struct mat3 q0 = rand_rotation(), q1 = rand_rotation();
        double s[3] = { 1 + urand(), 0.6 + 0.4 * urand(), -(0.05 + 0.5 * urand()) };
        /* det < 0: the nearest rotation flips the smallest singular value */
        T_TRUE(check_polar(compose(q0, s, q1), m3_mul(q0, m3_transpose(q1)), 1e-8));
    }
}

T_CASE(polar_rotation_is_a_fixed_point_and_zero_gives_identity)
{
    struct mat3 q = rand_rotation();
    T_TRUE(check_polar(q, q, 1e-12));
    struct mat3 z = { { { 0 } } };
    T_EQ_DBL(m3_dist(polar_rotation(z), m3_identity()), 0, 0);
}

/* ---- minimal rotation ---------------------------------------------------- */

static const struct vec3 up = { 0, 0, 1 };

static int
all_safe(const struct vec3 *n, int k, struct mat3 q, double tau)
{
    for (int i = 0; i < k; i++)
        if (v3_dot(m3_mul_v(q, n[i]), up) < -tau - 1e-9)
            return 0;
    return 1;
}

/* Random surface normals of a random tet: faces of a random tetrahedron. */
static void
rand_tet_normals(struct vec3 nrm[4])
{
    struct vec3 p[4];
    double vol;
    do {
        for (int i = 0; i < 4; i++)
            p[i] = v3(urand(), urand(), urand());
        vol = v3_dot(v3_sub(p[1], p[0]), v3_cross(v3_sub(p[2], p[0]), v3_sub(p[3], p[0])));
    } while (fabs(vol) < 1e-3);
    static const int f[4][3] = { { 1, 2, 3 }, { 0, 3, 2 }, { 0, 1, 3 }, { 0, 2, 1 } };
    for (int i = 0; i < 4; i++) {
        struct vec3 c = v3_cross(v3_sub(p[f[i][1]], p[f[i][0]]), v3_sub(p[f[i][2]], p[f[i][0]]));
        nrm[i] = v3_normalize(vol > 0 ? c : v3_scale(c, -1));
    }
}

T_CASE(minrot_makes_every_face_safe)
{
    for (int i = 0; i < 5000; i++) {
        struct vec3 nrm[4];
        rand_tet_normals(nrm);
        double tau = sin(urand() * 80 * M_PI / 180);
        int k = 1 + (i & 1);
        struct minrot r;
        minrot_solve(nrm, k, up, tau, v3(0, 0, 0), &r);
        T_TRUE(all_safe(nrm, k, minrot_matrix(&r, 0), tau));
        T_TRUE(r.angle >= 0 && r.angle <= M_PI);
        T_EQ_DBL(v3_len(r.axis), 1, 1e-12);
    }
}

/* The smallest arc from up to any sampled safe direction (Fibonacci sphere
   plus a local refinement around the best sample). */
static double
brute_min_angle(const struct vec3 *n, int k, double tau)
{
    int ns = 40000;
    double best = INFINITY;
    struct vec3 bx = up;
    for (int i = 0; i < ns; i++) {
        double z = 1 - (2 * i + 1.0) / ns, r = sqrt(1 - z * z), phi = i * 2.399963229728653;
        struct vec3 x = v3(r * cos(phi), r * sin(phi), z);
        int ok = 1;
        for (int j = 0; j < k; j++)
            ok &= v3_dot(n[j], x) >= -tau;
        double a = acos(fmin(1, z));
        if (ok && a < best)
            best = a, bx = x;
    }
    /* refine: a 41 x 41 grid on the tangent plane around the best sample,
       shrinking 1.5x per round */
    for (double half = 0.03; half > 1e-8; half /= 1.5) {
        struct vec3 e1 = v3_normalize(v3_cross(bx, fabs(bx.x) < 0.6 ? v3(1, 0, 0) : v3(0, 1, 0)));
        struct vec3 e2 = v3_cross(bx, e1), c = bx;
        for (int a = -20; a <= 20; a++)
            for (int b = -20; b <= 20; b++) {
                struct vec3 x = v3_normalize(
                    v3_add(c, v3_add(v3_scale(e1, half * a / 20), v3_scale(e2, half * b / 20))));
                int ok = 1;
                for (int j = 0; j < k; j++)
                    ok &= v3_dot(n[j], x) >= -tau;
                double ang = acos(fmin(1, x.z));
                if (ok && ang < best)
                    best = ang, bx = x;
            }
    }
    /* the optimum of a thin feasible sliver lies on a boundary circle, where a
       grid rarely lands: also sample each circle n . x = -tau, then refine
       along it */
    for (int j = 0; j < k; j++) {
        struct vec3 e1 =
            v3_normalize(v3_cross(n[j], fabs(n[j].x) < 0.6 ? v3(1, 0, 0) : v3(0, 1, 0)));
        struct vec3 e2 = v3_cross(n[j], e1), c = v3_scale(n[j], -tau);
        double rad = sqrt(1 - tau * tau), bt = 0, bt_best = INFINITY;
        for (int i = 0; i < 4096; i++) {
            double t = 2 * M_PI * i / 4096;
            struct vec3 x =
                v3_add(c, v3_add(v3_scale(e1, rad * cos(t)), v3_scale(e2, rad * sin(t))));
            int ok = 1;
            for (int q = 0; q < k; q++)
                ok &= q == j || v3_dot(n[q], x) >= -tau;
            double ang = acos(fmax(-1, fmin(1, x.z)));
            if (ok && ang < bt_best)
                bt_best = ang, bt = t;
        }
        for (double half = 2 * M_PI / 4096; half > 1e-12 && bt_best < INFINITY; half /= 2) {
            for (int i = -20; i <= 20; i++) {
                double t = bt + half * i / 20;
                struct vec3 x =
                    v3_add(c, v3_add(v3_scale(e1, rad * cos(t)), v3_scale(e2, rad * sin(t))));
                int ok = 1;
                for (int q = 0; q < k; q++)
                    ok &= q == j || v3_dot(n[q], x) >= -tau;
                double ang = acos(fmax(-1, fmin(1, x.z)));
                if (ok && ang < bt_best)
                    bt_best = ang, bt = t;
            }
        }
        best = fmin(best, bt_best);
    }
    return best;
}

T_CASE(minrot_no_smaller_safe_rotation_by_brute_force)
{
    int counts[5] = { 0 };
    for (int i = 0; i < 300; i++) {
        struct vec3 nrm[4];
        rand_tet_normals(nrm);
        /* bias toward risky faces so every configuration shows up */
        if (i % 3 == 0)
            nrm[0] = v3_normalize(v3(0.3 * (urand() - 0.5), 0.3 * (urand() - 0.5), -1));
        double tau = sin(urand() * 70 * M_PI / 180);
        int k = 1 + (i % 2);
        struct minrot r;
        minrot_solve(nrm, k, up, tau, v3(0, 0, 0), &r);
        counts[r.config]++;
        double brute = brute_min_angle(nrm, k, tau);
        if (r.angle > brute + 1e-6 || brute > r.angle + 1e-3)
            fprintf(stderr, "  case %d: minrot %.9f brute %.9f config %d\n", i, r.angle, brute,
                    r.config);
        T_TRUE(all_safe(nrm, k, minrot_matrix(&r, 0), tau));
        T_TRUE(r.angle <= brute + 1e-6); /* brute force finds no smaller safe rotation */
        T_TRUE(brute <= r.angle + 1e-3); /* and the sampled optimum approaches ours */
    }
    T_TRUE(counts[MINROT_SAFE] > 0 && counts[MINROT_FACE1] > 0 && counts[MINROT_FACE2] > 0 &&
           counts[MINROT_CORNER] > 0);
}

/* Case II region boundaries: the minimal angle is the distance from d to a
   set, so it is 1-Lipschitz in d; walking d across the regions must never
   jump, and a corner answer lies on both circles. */
T_CASE(minrot_case2_regions_are_continuous)
{
    double tau = sin(30 * M_PI / 180);
    struct vec3 n[2] = { v3_normalize(v3(0.5, 0, -1)), v3_normalize(v3(-0.5, 0.2, -1)) };
    int seen[5] = { 0 };
    for (int path = 0; path < 40; path++) {
        struct vec3 a = rand_unit(), b = rand_unit();
        struct minrot prev;
        struct vec3 dprev = a;
        for (int s = 0; s <= 400; s++) {
            struct vec3 d =
                v3_normalize(v3_add(v3_scale(a, 1 - s / 400.0), v3_scale(b, s / 400.0)));
            /* express d as the print direction: rotate the normals instead */
            struct mat3 q = m3_rotate_onto(d, up);
            struct vec3 nn[2] = { m3_mul_v(q, n[0]), m3_mul_v(q, n[1]) };
            struct minrot r;
            minrot_solve(nn, 2, up, tau, v3(0, 0, 0), &r);
            seen[r.config]++;
            if (r.config == MINROT_CORNER) {
                T_EQ_DBL(v3_dot(nn[0], r.dprime), -tau, 1e-9);
                T_EQ_DBL(v3_dot(nn[1], r.dprime), -tau, 1e-9);
            }
            if (s > 0) {
                double step = acos(fmin(1, v3_dot(d, dprev)));
                T_TRUE(fabs(r.angle - prev.angle) <= step + 1e-9);
            }
            prev = r;
            dprev = d;
        }
    }
    T_TRUE(seen[MINROT_SAFE] && seen[MINROT_FACE1] && seen[MINROT_FACE2] && seen[MINROT_CORNER]);
}

T_CASE(minrot_case1_is_the_projection_and_beta_reduces_it)
{
    /* a face tilted 60 degrees past horizontal-down: n . z = -cos(30deg) */
    struct vec3 n = v3(sin(M_PI / 6), 0, -cos(M_PI / 6));
    double tau = sin(M_PI / 4);
    struct minrot r;
    minrot_solve(&n, 1, up, tau, v3(0, 0, 0), &r);
    T_EQ_INT(r.config, MINROT_FACE1);
    /* the normal is 150 deg from up; safe at 135 deg: 15 degrees to go */
    T_EQ_DBL(r.angle, M_PI / 12, 1e-12);
    struct vec3 turned = m3_mul_v(minrot_matrix(&r, 0), n);
    T_EQ_DBL(turned.z, -tau, 1e-12);
    struct vec3 part = m3_mul_v(minrot_matrix(&r, 5 * M_PI / 180), n);
    T_EQ_DBL(acos(-part.z) * 180 / M_PI, 40, 1e-9); /* 10 of the 15 degrees */
    T_EQ_DBL(m3_dist(minrot_matrix(&r, 1), m3_identity()), 0, 0);
    /* coincident faces: config IV */
    struct vec3 two[2] = { n, n };
    minrot_solve(two, 2, up, tau, v3(0, 0, 0), &r);
    T_EQ_INT(r.config, MINROT_PARALLEL);
    T_EQ_DBL(r.angle, M_PI / 12, 1e-12);
}
