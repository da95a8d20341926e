/*
 * hull.h - the convex hull of a part (qhull) as a list of planar bases:
 * the faces the part can rest on.  Coplanar hull triangles are merged into
 * one convex polygon, as qhull's default facet merging does.
 *
 * Thread-safe: qhull's reentrant library, one qhT per call.
 */
#ifndef SF_GEOM_HULL_H
#define SF_GEOM_HULL_H

#include <stdint.h>

#include "../base/err.h"
#include "../mesh/mesh.h"

struct hull_base {
    struct vec3 normal; /* outward unit normal of the hull facet; the part rests on it with
                           up = -normal */
    double area_mm2;    /* facet area */
    double margin_mm;   /* distance from the centre of mass's projection to the facet's
                           nearest edge; negative when it falls outside (tips over) */
};

/*
 * All hull facets of m, largest first.  com is the part's centre of mass.
 * *bases is allocated (free()).  If verts is not NULL, *verts receives the
 * indices of the hull's vertices (allocated, free()) and *n_verts their
 * count: the only vertices that can be a part's lowest or highest point.
 */
int hull_bases(const struct mesh *m, struct vec3 com, struct hull_base **bases, uint32_t *n,
               uint32_t **verts, uint32_t *n_verts, struct sf_err *err);

#endif
