/*
 * polar.c - nearest rotation of 3x3 matrices (see polar.h).
 *
 * Fast path (polar_block): Newton's iteration for the orthogonal polar
 * factor, X <- (g X + X^-T / g) / 2 with Higham's scaling
 * g = sqrt(|X^-1|_F / |X|_F) (Higham, "Computing the polar decomposition
 * - with applications", 1986), written with X^-T = cof(X) / det(X) so each
 * step is straight-line code over POLAR_W lanes (the first two steps scaled,
 * the rest plain: by then the singular values are near 1).  It converges
 * quadratically to the polar factor, which is the nearest rotation when
 * det(A) > 0.  The loop stops when every lane has settled (ARAP matrices
 * are near rotations after the first iterations, so 2-4 steps is typical).
 *
 * Robust path (polar_rotation): cyclic Jacobi on A^T A = V S^2 V^T, then
 * u1 = A v1 / |A v1|, u2 = the part of A v2 orthogonal to u1, and
 * R = u1 v1^T + u2 v2^T + (u1 x u2)(v1 x v2)^T.  Building the third
 * columns by cross products makes det R = +1 and puts the sign flip on the
 * smallest singular value, which is exactly the signed polar factor; it
 * needs only the two largest singular directions, so rank-2 matrices are
 * handled too.
 *
 * Pure; thread-safe.
 */
#include "polar.h"

#include <float.h>
#include <math.h>
#include <stdbool.h>

/* Eigen-decomposition of symmetric s by cyclic Jacobi: s becomes diagonal,
   v's columns are the eigenvectors. */
static void
jacobi3(double s[3][3], double v[3][3])
{
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            v[i][j] = i == j;
    for (int sweep = 0; sweep < 32; sweep++) {
        double off = s[0][1] * s[0][1] + s[0][2] * s[0][2] + s[1][2] * s[1][2];
        double diag = s[0][0] * s[0][0] + s[1][1] * s[1][1] + s[2][2] * s[2][2];
        if (off <= 1e-34 * diag || off == 0)
            return;
        for (int p = 0; p < 2; p++) {
            for (int q = p + 1; q < 3; q++) {
                if (s[p][q] == 0)
                    continue;
                double theta = (s[q][q] - s[p][p]) / (2 * s[p][q]);
                double t = (theta >= 0 ? 1 : -1) / (fabs(theta) + sqrt(theta * theta + 1));
                double c = 1 / sqrt(t * t + 1), sn = t * c;
                for (int k = 0; k < 3; k++) { /* s <- J^T s J */
                    double a = s[k][p], b = s[k][q];
                    s[k][p] = c * a - sn * b;
                    s[k][q] = sn * a + c * b;
                }
                for (int k = 0; k < 3; k++) {
                    double a = s[p][k], b = s[q][k];
                    s[p][k] = c * a - sn * b;
                    s[q][k] = sn * a + c * b;
                }
                for (int k = 0; k < 3; k++) {
                    double a = v[k][p], b = v[k][q];
                    v[k][p] = c * a - sn * b;
                    v[k][q] = sn * a + c * b;
                }
            }
        }
    }
}

/* Some unit vector perpendicular to unit u. */
static struct vec3
perpendicular(struct vec3 u)
{
    struct vec3 p = fabs(u.x) < 0.6 ? v3(1, 0, 0) : fabs(u.y) < 0.6 ? v3(0, 1, 0) : v3(0, 0, 1);
    return v3_normalize(v3_sub(p, v3_scale(u, v3_dot(p, u))));
}

struct mat3
polar_rotation(struct mat3 a)
{
    double s[3][3], v[3][3];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            s[i][j] = a.m[0][i] * a.m[0][j] + a.m[1][i] * a.m[1][j] + a.m[2][i] * a.m[2][j];
    jacobi3(s, v);
    int o[3] = { 0, 1, 2 }; /* eigenvalues in decreasing order */
    for (int i = 0; i < 3; i++)
        for (int j = i + 1; j < 3; j++)
            if (s[o[j]][o[j]] > s[o[i]][o[i]]) {
                int t = o[i];
                o[i] = o[j];
                o[j] = t;
            }
    struct vec3 v1 = v3(v[0][o[0]], v[1][o[0]], v[2][o[0]]);
    struct vec3 v2 = v3(v[0][o[1]], v[1][o[1]], v[2][o[1]]);
    v2 = v3_normalize(v3_sub(v2, v3_scale(v1, v3_dot(v1, v2))));
    struct vec3 av1 = m3_mul_v(a, v1), av2 = m3_mul_v(a, v2);
    double n1 = v3_len(av1);
    if (!(n1 > 0))
        return m3_identity();
    struct vec3 u1 = v3_scale(av1, 1 / n1);
    struct vec3 w = v3_sub(av2, v3_scale(u1, v3_dot(u1, av2)));
    double n2 = v3_len(w);
    struct vec3 u2 = n2 > 1e-14 * n1 ? v3_scale(w, 1 / n2) : perpendicular(u1);
    struct vec3 u3 = v3_cross(u1, u2), v3c = v3_cross(v1, v2);
    struct vec3 uu[3] = { u1, u2, u3 }, vv[3] = { v1, v2, v3c };
    struct mat3 r;
    for (int i = 0; i < 3; i++) {
        double ui[3] = { uu[i].x, uu[i].y, uu[i].z }, vi[3] = { vv[i].x, vv[i].y, vv[i].z };
        for (int p = 0; p < 3; p++)
            for (int q = 0; q < 3; q++)
                r.m[p][q] = (i ? r.m[p][q] : 0) + ui[p] * vi[q];
    }
    return r;
}

#define W             POLAR_W
#define POLAR_SETTLED 1e-10 /* squared Frobenius change of a settled lane */

/* One Newton step on every lane; scaled or plain, and measuring each lane's
   change (squared) into delta or not (the flags are constants at each call,
   so each inlined copy is branch-free and vectorizes). */
static inline __attribute__((always_inline)) void
newton_step(double x[9][W], double delta[W], const bool scaled, const bool track)
{
    for (int l = 0; l < W; l++) {
        double c0 = x[4][l] * x[8][l] - x[5][l] * x[7][l];
        double c1 = x[5][l] * x[6][l] - x[3][l] * x[8][l];
        double c2 = x[3][l] * x[7][l] - x[4][l] * x[6][l];
        double c3 = x[2][l] * x[7][l] - x[1][l] * x[8][l];
        double c4 = x[0][l] * x[8][l] - x[2][l] * x[6][l];
        double c5 = x[1][l] * x[6][l] - x[0][l] * x[7][l];
        double c6 = x[1][l] * x[5][l] - x[2][l] * x[4][l];
        double c7 = x[2][l] * x[3][l] - x[0][l] * x[5][l];
        double c8 = x[0][l] * x[4][l] - x[1][l] * x[3][l];
        double det = x[0][l] * c0 + x[1][l] * c1 + x[2][l] * c2;
        double g = 1;
        if (scaled) { /* scaled steps; near convergence g -> 1 and is dropped */
            double fx = 0, fc = c0 * c0 + c1 * c1 + c2 * c2 + c3 * c3 + c4 * c4 + c5 * c5 +
                                c6 * c6 + c7 * c7 + c8 * c8;
            for (int c = 0; c < 9; c++)
                fx += x[c][l] * x[c][l];
            /* |X^-1|_F = |cof X|_F / |det X|.  No branches, so every copy
               vectorizes: + DBL_MIN keeps a singular lane finite here, and a
               lane whose det is or turns non-positive is redone below */
            double adet = fabs(det) + DBL_MIN;
            g = sqrt(sqrt(fc / (fx * adet * adet)));
        }
        double ga = 0.5 * g, gb = 0.5 / (g * det);
        double cof[9] = { c0, c1, c2, c3, c4, c5, c6, c7, c8 };
        double d = 0;
        for (int c = 0; c < 9; c++) {
            double nx = ga * x[c][l] + gb * cof[c];
            if (track)
                d += (nx - x[c][l]) * (nx - x[c][l]);
            x[c][l] = nx;
        }
        if (track)
            delta[l] = d;
    }
}

POLAR_CLONES int
polar_block(const double a[9][W], double r[9][W])
{
    double x[9][W], det0[W], scale[W];
    for (int l = 0; l < W; l++) {
        double f = 0;
        for (int c = 0; c < 9; c++)
            f += a[c][l] * a[c][l];
        /* normalise by the Frobenius norm so the tolerances below are relative */
        scale[l] = 1 / sqrt(f / 3 + DBL_MIN); /* a zero lane stays zero (and goes scalar) */
        for (int c = 0; c < 9; c++)
            x[c][l] = a[c][l] * scale[l];
        det0[l] = x[0][l] * (x[4][l] * x[8][l] - x[5][l] * x[7][l]) -
                  x[1][l] * (x[3][l] * x[8][l] - x[5][l] * x[6][l]) +
                  x[2][l] * (x[3][l] * x[7][l] - x[4][l] * x[6][l]);
    }
    /*
     * A fixed start: two scaled steps and a plain one, untested (the ARAP
     * matrices never settle in fewer; bench_slim: 99 % of blocks took 4 or
     * more).  Then plain steps until every lane's last change is below
     * 1e-5: near the polar factor U, X = U (I + E) becomes U (I + E^2 / 2 +
     * O(E^3)), so a step's change is the error before it and the error left
     * is about change^2 / 2 < 1e-10.
     */
    double delta[W];
    newton_step(x, delta, true, false);
    newton_step(x, delta, true, false);
    newton_step(x, delta, false, false);
    for (int it = 0; it < 8; it++) {
        newton_step(x, delta, false, true);
        double worst = 0;
        for (int l = 0; l < W; l++)
            worst = worst > delta[l] ? worst : delta[l];
        if (worst < POLAR_SETTLED)
            break;
    }
    int slow = 0;
    for (int l = 0; l < W; l++) {
        if (det0[l] > 1e-6 && delta[l] < POLAR_SETTLED && isfinite(delta[l])) {
            for (int c = 0; c < 9; c++)
                r[c][l] = x[c][l];
            continue;
        }
        struct mat3 m, q;
        for (int c = 0; c < 9; c++)
            m.m[c / 3][c % 3] = a[c][l];
        q = polar_rotation(m);
        for (int c = 0; c < 9; c++)
            r[c][l] = q.m[c / 3][c % 3];
        slow++;
    }
    return slow;
}
