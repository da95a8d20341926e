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
