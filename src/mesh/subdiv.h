/*
 * subdiv.h - midpoint subdivision: every triangle split into four through
 * its edge midpoints.  The surface is unchanged (flat pieces stay flat), a
 * closed mesh stays closed and consistently oriented, and a coarse CAD
 * part gains the vertices a surface deformation needs to bend.
 */
#ifndef SF_MESH_SUBDIV_H
#define SF_MESH_SUBDIV_H

#include "mesh.h"

/* Split every triangle of m into four (in place).  SF_ENOMEM leaves m as it was. */
int mesh_subdivide(struct mesh *m, struct sf_err *err);

/*
 * Subdivide until m has at least min_tris triangles or its longest edge is
 * at most max_edge_mm; never past max_tris.  Returns the rounds done (>= 0).
 */
int mesh_refine(struct mesh *m, uint32_t min_tris, double max_edge_mm, uint32_t max_tris,
                struct sf_err *err);

#endif
