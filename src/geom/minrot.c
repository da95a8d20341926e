/*
 * minrot.c - closed-form minimal rotation on the Gauss sphere (see
 * minrot.h; Hu, Jin & Wang 2015, sec. 4.2).
 *
 * The feasible set on the unit sphere is the complement of one or two
 * open "forbidden" caps {x : n_i . x < -tau}, each smaller than a
 * hemisphere.  The point of it nearest to d lies on the boundary of the
 * union of the caps: on an arc of one circle, where the nearest point of
 * the whole circle (the projection) is the only local minimum, or at a
 * corner where the circles cross.  So the candidates are d, the two
 * projections and the two corners; the nearest feasible one is the exact
 * answer.  This replaces the paper's region tests by the same candidates
 * checked directly, which is what makes the region boundaries continuous.
 *
 * Pure; thread-safe.
 */
#include "minrot.h"

#include <math.h>

/* Slack on n . x >= -tau, so projections that land on a circle count as safe. */
#define FEAS_EPS 1e-9

static struct vec3
any_perpendicular(struct vec3 u)
{
    struct vec3 p = fabs(u.x) < 0.6 ? v3(1, 0, 0) : fabs(u.y) < 0.6 ? v3(0, 1, 0) : v3(0, 0, 1);
    return v3_normalize(v3_sub(p, v3_scale(u, v3_dot(p, u))));
}

/* Nearest point to d on the circle {x on the sphere : n . x = -tau} (Hu 2015, eq. 9). */
static struct vec3
project_circle(struct vec3 n, struct vec3 d, double tau, struct vec3 hint)
{
    struct vec3 t = v3_sub(d, v3_scale(n, v3_dot(d, n)));
    double tl = v3_len(t);
    if (tl < MINROT_HINT_WEIGHT) { /* fades out: exact once d is 14 degrees off -n */
        struct vec3 h = v3_sub(hint, v3_scale(n, v3_dot(hint, n)));
        double f = 1 - tl / MINROT_HINT_WEIGHT;
        t = v3_add(t, v3_scale(v3_normalize(h), MINROT_HINT_WEIGHT * f * f));
    }
    double len = v3_len(t);
    t = len > 1e-12 ? v3_scale(t, 1 / len) : any_perpendicular(n); /* d = -n: any way out */
    return v3_add(v3_scale(n, -tau), v3_scale(t, sqrt(1 - tau * tau)));
}

/* Points on both circles: x = a n1 + b n2 + c (n1 x n2) with n_i . x = -tau. */
static int
corners(struct vec3 n1, struct vec3 n2, double tau, struct vec3 out[2])
{
    double g = v3_dot(n1, n2);
    double den = 1 - g * g;
    if (den < 1e-14)
        return 0;
    double a = -tau * (1 - g) / den; /* symmetric: a = b */
    struct vec3 m = v3_scale(v3_add(n1, n2), a);
    double rest = 1 - v3_dot(m, m);
    if (rest < 0)
        return 0; /* the circles do not meet */
    struct vec3 c = v3_cross(n1, n2);
    double h = sqrt(rest / den); /* |n1 x n2|^2 = den */
    out[0] = v3_add(m, v3_scale(c, h));
    out[1] = v3_sub(m, v3_scale(c, h));
    return 2;
}

static int
feasible(const struct vec3 *n, int k, struct vec3 x, double tau)
{
    for (int i = 0; i < k; i++)
        if (v3_dot(n[i], x) < -tau - FEAS_EPS)
            return 0;
    return 1;
}

static double
arc(struct vec3 a, struct vec3 b)
{
    return atan2(v3_len(v3_cross(a, b)), v3_dot(a, b));
}

void
minrot_solve(const struct vec3 *n, int k, struct vec3 d, double tau, struct vec3 hint,
             struct minrot *out)
{
    out->axis = v3(0, 0, 1);
    out->angle = 0;
    out->dprime = d;
    out->config = MINROT_SAFE;
    if (feasible(n, k, d, tau))
        return;
    struct vec3 best = d;
    double best_arc = INFINITY;
    enum minrot_config cfg = MINROT_SAFE;
    if (k == 2 && v3_dot(n[0], n[1]) > 1 - 1e-12)
        k = 1, cfg = MINROT_PARALLEL;
    for (int i = 0; i < k; i++) {
        struct vec3 p = project_circle(n[i], d, tau, hint);
        double a = arc(d, p);
        if (feasible(n, k, p, tau) && a < best_arc) {
            best = p, best_arc = a;
            cfg = cfg == MINROT_PARALLEL ? cfg : (i ? MINROT_FACE2 : MINROT_FACE1);
        }
    }
    struct vec3 cs[2];
    int nc = k == 2 ? corners(n[0], n[1], tau, cs) : 0;
    for (int i = 0; i < nc; i++) {
        double a = arc(d, cs[i]);
        if (a < best_arc)
            best = cs[i], best_arc = a, cfg = MINROT_CORNER;
    }
    if (!(best_arc < INFINITY))
        return; /* unreachable: a projection or a corner is always feasible */
    struct vec3 axis = v3_cross(best, d); /* Q takes d' onto d */
    double s = v3_len(axis);
    out->axis = s > 1e-15 ? v3_scale(axis, 1 / s) : any_perpendicular(d);
    out->angle = best_arc;
    out->dprime = best;
    out->config = cfg;
}

struct mat3
minrot_matrix(const struct minrot *r, double beta_rad)
{
    double a = r->angle - beta_rad;
    return a > 0 ? m3_axis_angle(r->axis, a) : m3_identity();
}
