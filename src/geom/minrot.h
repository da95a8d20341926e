/*
 * minrot.h - the minimal rotation that makes a tetrahedron's surface faces
 * self-supporting (Hu, Jin & Wang 2015, sec. 4.2, "minimal rotation on the
 * Gauss sphere").
 *
 * A face with outward unit normal n is safe for print direction d when
 * n . d >= -tau, tau = sin(alpha) (measure.h's convention).  Rotating the
 * tet by Q turns n into Q n, and (Q n) . d = n . (Q^T d): so the smallest Q
 * that makes faces n_1..n_k safe is the shortest arc from d to the point d'
 * nearest to d on the Gauss sphere inside every half-space n_i . x >= -tau,
 * and Q rotates d' onto d.
 *   case I  (one face): d' is d projected onto the boundary circle
 *           n . x = -tau (Hu 2015, eq. 9);
 *   case II (two faces): the nearest feasible point is d itself, the
 *           projection onto circle 1 if it satisfies face 2 (config I),
 *           onto circle 2 if it satisfies face 1 (config II), or a corner
 *           where both circles meet (config III), whichever is nearest;
 *           config IV is two coincident faces, solved as case I.
 * Tets with three or more surface faces are split before (slim.c).
 *
 * Pure; thread-safe.
 */
#ifndef SF_GEOM_MINROT_H
#define SF_GEOM_MINROT_H

#include "../mesh/vec.h"

enum minrot_config {
    MINROT_SAFE = 0, /* d already satisfies every face: no rotation */
    MINROT_FACE1,    /* case I, or case II config I: projection onto face 1's circle */
    MINROT_FACE2,    /* case II config II: projection onto face 2's circle */
    MINROT_CORNER,   /* case II config III: a point on both circles */
    MINROT_PARALLEL, /* case II config IV: the two normals coincide, solved as case I */
};

struct minrot {
    struct vec3 axis;          /* unit rotation axis (world frame), +z when angle is 0 */
    double angle;              /* radians, >= 0 */
    struct vec3 dprime;        /* the safe direction d' (Q d' = d) */
    enum minrot_config config; /* which configuration gave the answer */
};

/*
 * The minimal rotation for k = 1 or 2 unit normals n (current, rotated
 * frame), unit print direction d and tau = sin(alpha) in [0, 1).
 *
 * hint (any length, or zero for none) settles the one degenerate case:
 * a face pointing straight down (n = -d) can turn any way, and the exact
 * answer then depends on noise.  Its part perpendicular to n is added to
 * the direction in which d' leaves d, with a weight fading from
 * MINROT_HINT_WEIGHT at n = -d to 0 when d is asin(MINROT_HINT_WEIGHT)
 * (14 degrees) off -n, so near-flat downward faces turn toward the hint
 * (arap.c passes "away from the fixed base": overhangs rise) and every
 * other face gets the exact minimal rotation.
 */
#define MINROT_HINT_WEIGHT 0.25
void minrot_solve(const struct vec3 *n, int k, struct vec3 d, double tau, struct vec3 hint,
                  struct minrot *out);

/* The rotation matrix of out with its angle reduced by beta (Hu 2015:
   theta' = max(theta - beta, 0)). */
struct mat3 minrot_matrix(const struct minrot *r, double beta_rad);

#endif
