/*
 * mesh_int.h - internal to the mesh module (mesh.c, mesh_repair.c), not a
 * contract for anyone else: the weld that loading uses.
 *
 * Single-threaded per mesh, as mesh.h.
 */
#ifndef SF_MESH_MESH_INT_H
#define SF_MESH_MESH_INT_H

#include <stdbool.h>

#include "../base/err.h"
#include "mesh.h"

/* mesh_weld; distinct says no two vertices are bit-identical already (the
   binary STL parser merged them), so the exact pass is skipped. */
int mesh_weld_distinct(struct mesh *m, double tol, bool distinct, struct sf_err *err);

#endif
