/*
 * selfx.h - does a triangle mesh intersect itself?  The support-slimming
 * deformation may fold a thin part onto itself; a result that does is
 * never returned (slim.c falls back to an earlier iterate).
 *
 * Thread-safe: each call builds its own Embree scene.
 */
#ifndef SF_GEOM_SELFX_H
#define SF_GEOM_SELFX_H

#include <stdbool.h>
#include <stdint.h>

#include "../base/err.h"
#include "../mesh/mesh.h"

/*
 * Count the mesh edges that pierce a triangle not touching them (0 for a
 * mesh that does not intersect itself; two crossing triangles give at
 * least one).  Returns the count (>= 0) or a negative sf_status.
 */
int selfx_count(const struct mesh *m, struct sf_err *err);

/*
 * The new ones only: edges of m that pierce a triangle they were more than
 * tol mm from in ref (the same connectivity, another shape: the input of a
 * deformation), except between two shells that already cross in ref, and
 * within two rings of a crossing ref has (a deformation slides the crossing
 * curve over its neighbours).  Crossings and contacts the input already had
 * (overlapping shells, a soup's T-junctions and coincident faces) are not
 * counted, so a deformation of a defective part is judged by what it adds.  Returns the
 * count or a negative sf_status (SF_EINVAL: connectivity differs, tol < 0).
 */
int selfx_count_new(const struct mesh *ref, const struct mesh *m, double tol, struct sf_err *err);

#endif
