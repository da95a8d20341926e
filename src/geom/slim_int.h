/*
 * slim_int.h - internal to support slimming (slim*.c), not a contract for
 * anyone else: which part faces lie in which tet (slim_hosts.c), the map
 * the direction workers drive the solver by.
 *
 * Pure functions; the result is read-only shared by the workers.
 */
#ifndef SF_GEOM_SLIM_INT_H
#define SF_GEOM_SLIM_INT_H

#include <stdint.h>

#include "../base/err.h"
#include "../mesh/mesh.h"
#include "tetmesh.h"

/*
 * Which part faces lie in which tet: a face is sampled at its vertices, its
 * centroid and a barycentric grid finer than half the lattice pitch, and
 * belongs to every tet a sample falls in.  CSR over the tets that hold any.
 */
struct face_hosts {
    uint32_t n;      /* tets holding part faces */
    uint32_t *tet;   /* n tet indices */
    uint32_t *start; /* n + 1 offsets into face */
    uint32_t *face;  /* part triangle indices */
};

/* Build fh for part m in tet mesh tm (tm->host holds m's vertices' tets);
   SF_ENOMEM, or tetmesh_locate's errors.  Free with slim_face_hosts_release. */
int slim_face_hosts_build(const struct mesh *m, const struct tetmesh *tm, struct face_hosts *fh,
                          struct sf_err *err);
void slim_face_hosts_release(struct face_hosts *fh);

#endif
