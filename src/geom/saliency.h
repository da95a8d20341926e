/*
 * saliency.h - mesh saliency (Lee, Varshney & Jacobs, "Mesh saliency",
 * SIGGRAPH 2005): how much a vertex's mean curvature stands out from its
 * surroundings, over several scales.  The surface shape optimizer
 * (surfopt.h) lets salient features move less.
 *
 * Per vertex: mean curvature H from the cotangent Laplacian; Gaussian-
 * weighted averages G(H, s) over the vertices within 2s; at each scale
 * s_i in {2, 3, 4, 5, 6} * eps (eps = 0.3 % of the bbox diagonal) the map
 * |G(H, s_i) - G(H, 2 s_i)|, normalized to [0, 1] and weighted by
 * (1 - mean of its other local maxima)^2 so maps with one clear peak count
 * more than maps with many; the sum is normalized to [0, 1].
 *
 * Thread-safe on distinct outputs.
 */
#ifndef SF_GEOM_SALIENCY_H
#define SF_GEOM_SALIENCY_H

#include "../base/err.h"
#include "../mesh/mesh.h"

/* out[n_verts] receives each vertex's saliency in [0, 1]. */
int mesh_saliency(const struct mesh *m, double *out, struct sf_err *err);

#endif
