/*
 * selfx.h - does a triangle mesh intersect itself?  The support-slimming
 * deformation may fold a thin part onto itself; a result that does is
 * never returned (slim.c falls back to an earlier iterate).
 *
 * Thread-safe: each call builds its own Embree scene.
 */
#ifndef SF_GEOM_SELFX_H
#define SF_GEOM_SELFX_H

#include <stdint.h>

#include "../base/err.h"
#include "../mesh/mesh.h"

/*
 * Count the mesh edges that pierce a triangle not touching them (0 for a
 * mesh that does not intersect itself; two crossing triangles give at
 * least one).  Returns the count (>= 0) or a negative sf_status.
 */
int selfx_count(const struct mesh *m, struct sf_err *err);

#endif
