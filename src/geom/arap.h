/*
 * arap.h - the local/global as-rigid-as-possible solver on a tet mesh, with
 * the support-slimming local step (Hu, Jin & Wang 2015, sec. 4).
 *
 * Energy (Hu 2015, eq. 5, the volume-weighted ARAP energy):
 *     E(x) = sum_T V_T |J_T(x) - R_T|_F^2,   J_T = [x_i - x_0] D_T^-1,
 * D_T the rest edge matrix.  Local step: R_T = the rotation nearest J_T
 * (polar.h), then for tets with surface faces R_T <- Q_T R_T with Q_T the
 * minimal rotation that makes the faces safe (minrot.h, angle reduced by
 * the penalty beta).  Which tets and which normals is the caller's choice
 * (slim.c drives the tets that hold the part's overhanging faces).  Global step: dE/dx = 0 is L x =
 * b(R) with L_ij = sum_T V_T g_i . g_j (g_i the gradients of the barycentric coordinates), the same
 * matrix every iteration: factorized once (sparse.h), back-substituted for x, y and z each
 * iteration.  Fixed vertices are Dirichlet conditions: they keep the positions given.
 *
 * Volume: nothing in E keeps it.  With R_T = polar(J_T) alone the rest shape is the minimiser
 * (test_slim: a rigid motion is reproduced exactly), but the minimal rotations give neighbouring
 * tets targets no deformation meets at once - driven tets against undriven ones and the fixed
 * base, up to 90 degrees apart at alpha = 0 - and the least-squares fit of disagreeing rotations
 * is a compression (the mean of two rotations theta apart about one axis has determinant
 * cos^2(theta / 2)).  L is a Laplacian per coordinate, with no volumetric stiffness, so a squash
 * is not paid back by a bulge elsewhere, and the drives re-impose the targets every iteration.
 * Measured on cow at alpha = 0 (slimfarm optimize defaults, 12,278 tets, 709 driven, 449 of them
 * asked for 50-90 degrees): the tet mesh's summed volume falls 17 % in the first iteration from
 * rest and 26 % after 20 (beta 0); the returned iterate (beta 25) has det J 0.010-4.2, median
 * 0.84 in the tets holding the part's surface, 4,997 tets below 0.9.  The loss is in the tets:
 * the part follows them (part -19 %, its host tets -19.5 %, no vertex outside), the fixed
 * region keeps det J = 1, the split envelope tets lose 0.7 of the 12.5 points.  Tried and not
 * kept: equal instead of volume weights (cow 0: part -6.6 %, support -9.9 % instead of -22 %), a
 * per-iteration cap on the minimal rotation (10/20/30 degrees: -4.4/-10/-17 %; at 10 the
 * generated torus at 45 degrees, which loses 1.2 %, saves 6.6 % of its support, not 21 %), targets
 * scaled by det(J)^(-1/3) (-12.9 %), a fixed or no tie-break hint (-19/-16 %).
 * Tried next (cow / elephant at 0 degrees, part volume): a projective-dynamics volume term
 * (Bouaziz 2014) - each tet's target (1 - w) R + w J det(J)^(-1/3), the isochoric part of J,
 * which keeps L - gives -14.3/-13.4/-14.6/-14.9 % on cow at w = 0.25/0.5/0.75/0.9 and nothing on
 * elephant, whose kept iterate is the first: from rest J = I, so that target is R and the first
 * step's squash (-16.6 %) is already done; an isotropic squash is invisible to it too.  A per-tet
 * integral feedback (target scale s_T *= det(J_T)^(-1/3) every iteration, clamped) keeps the
 * parts within 1 % (cow 0: -6.8 %) and the fixed regions exact, but stiffens the deformation: at
 * equal volume it saves less ray-cast support than the plain result scaled back up (bunny00 45:
 * -18.8 % against -28.7 %, armadillo 45 -4.9 against -7.6, dino 45 -15.7 against -16.7; cow 45
 * -9.4 against -7.2 the exception).  So slim.c keeps this energy and scales each candidate
 * uniformly back to the input's volume (slim.h, keep_volume); support per part volume is the
 * figure that energy change had to beat.
 *
 * Thread-safety: one struct arap per thread.
 */
#ifndef SF_GEOM_ARAP_H
#define SF_GEOM_ARAP_H

#include <stdbool.h>
#include <stdint.h>

#include "../base/err.h"
#include "../mesh/vec.h"
#include "tetmesh.h"

struct arap;

/* Seconds spent in each phase, accumulated over calls. */
struct arap_timing {
    double local_s;  /* one pass: deformation gradients, nearest rotations, right-hand side */
    double minrot_s; /* minimal rotations of the surface tets */
    double rhs_s;    /* Dirichlet terms of the right-hand side */
    double solve_s;  /* back-substitution */
};

/* What the last local step did. */
struct arap_local_stats {
    uint32_t n_rotated;    /* surface tets given a non-zero minimal rotation */
    uint32_t n_slow_polar; /* tets that needed the scalar polar path */
};

/*
 * Precompute per-tet gradients and volumes from the rest positions of tm,
 * assemble L over the free vertices (fixed[v] != 0 marks fixed ones) and
 * factorize it.  NULL with err set: SF_EINVAL when nothing is fixed or a
 * tet is degenerate, SF_ENOMEM.
 */
struct arap *arap_new(const struct tetmesh *tm, const uint8_t *fixed, struct sf_err *err);
void arap_free(struct arap *a);

/* A tet whose surface must turn safe, as the local step sees it. */
struct arap_drive {
    uint32_t tet;     /* tet index */
    int k;            /* 1 or 2 normals (minimal rotation case I or II) */
    struct vec3 n[2]; /* current unit outward normals of its surface */
    struct vec3 hint; /* tie-break direction for straight-down faces (minrot.h) */
};

/*
 * Local step for the current positions x (n_verts): the nearest rotation
 * of every tet's deformation gradient, then for each listed tet R <- Q R
 * with Q the minimal rotation making its normals safe for print direction
 * d (unit), tau = sin(alpha), angle reduced by the penalty beta_rad.  The
 * same pass assembles the right-hand side for the next arap_global.
 */
void arap_local(struct arap *a, const struct vec3 *x, struct vec3 d, double tau, double beta_rad,
                const struct arap_drive *drv, uint32_t n_drv, struct arap_local_stats *stats);

/* Set every tet's target rotation to r (for tests and rigid motions). */
void arap_set_rotation(struct arap *a, struct mat3 r);

/* Global step: x's free vertices become the minimiser for the current
   target rotations; fixed vertices keep their values in x. */
int arap_global(struct arap *a, struct vec3 *x, struct sf_err *err);

/* Accumulated timings and the factor's size. */
const struct arap_timing *arap_timing(const struct arap *a);
size_t arap_factor_nnz(const struct arap *a);
uint32_t arap_n_free(const struct arap *a);

#endif
