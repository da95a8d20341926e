/*
 * tet_shim.h - TetGen 1.5 behind a C interface: tetrahedralize the inside
 * of a closed triangle surface.
 *
 * TetGen is C++ and reports failure by throwing; this is the only file
 * pair that sees it.  The output arrays are allocated here with mem.h and
 * freed by tet_shim_release().
 *
 * Thread-safe: TetGen keeps no global state between calls.
 */
#ifndef SF_GEOM_TET_SHIM_H
#define SF_GEOM_TET_SHIM_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

struct sf_err;

/* A tetrahedral mesh as TetGen returns it. */
struct tet_shim_out {
    double *xyz;    /* 3 * n_points coordinates: the input points first, then Steiner points */
    uint32_t *tets; /* 4 * n_tets vertex indices, positively oriented */
    uint32_t n_points;
    uint32_t n_tets;
};

/*
 * Tetrahedralize the region bounded by the closed surface (xyz, n_points;
 * tris, n_tris; any orientation).  switches are TetGen's, without 'z' and
 * 'Q', which are always added ("pq1.4/15Y" is a good start: a piecewise
 * linear complex, radius-edge bound 1.4, dihedral angles >= 15 degrees,
 * boundary kept).  Returns SF_OK, SF_EINVAL when TetGen rejects the
 * surface (self-intersecting, not closed), SF_ENOMEM.
 */
int tet_shim_tetrahedralize(const double *xyz, uint32_t n_points, const uint32_t *tris,
                            uint32_t n_tris, const char *switches, struct tet_shim_out *out,
                            struct sf_err *err);

void tet_shim_release(struct tet_shim_out *out);

#ifdef __cplusplus
}
#endif

#endif
