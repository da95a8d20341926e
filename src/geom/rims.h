/*
 * rims.h - the open rims of a part (edges only one triangle uses) and the
 * layers where an outside slicer leaves a cross-section open and drops it.
 *
 * PrusaSlicer 2.5 and CuraEngine 4.13 slice a layer into segments, chain
 * them into loops and keep only loops that close: an open polyline's ends
 * are joined to other ends within max_gap (PrusaSlicer's make_loops ->
 * chain_open_polylines_close_gaps, 2 mm; CuraEngine's SlicerLayer::stitch,
 * max_stitch1 = 10 mm) and whatever stays open is dropped, with the area it
 * bounded.  A layer plane that cuts an open rim ends a polyline at each
 * crossing.  The rule here: a layer of a component is dropped when one of
 * its rim crossings has no other crossing within max_gap.  That takes the
 * component's whole layer for the one loop the rim cuts (a component with
 * two islands in that layer loses both).  On mech-holes-shark, whose four
 * open holes cut most layers in most directions, it lifts the model's rank
 * correlation with PrusaSlicer over 64 directions from 0.39 to 0.85; a
 * finer rule (per loop, the area each bounds, the holes closed by straight
 * lines) ranked worse (-0.06) and cost 5x: an open loop's area is not well
 * defined.  Our own slicer closes such sections by winding and prints the
 * part.
 *
 * Built once per part; rims_open_layers is pure and thread-safe.
 */
#ifndef SF_GEOM_RIMS_H
#define SF_GEOM_RIMS_H

#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"
#include "../mesh/mesh.h"

struct rims {
    uint32_t n_edges;
    uint32_t (*edge)[2]; /* vertex pairs of the boundary edges */
    uint32_t *edge_comp; /* component of each edge's triangle */
    uint32_t *tri_comp;  /* component of every triangle (edge-connected) */
    uint32_t n_comps;
};

/* The rims of m (none for a closed mesh); r is valid while m is unchanged. */
int rims_build(const struct mesh *m, struct rims *r, struct sf_err *err);
void rims_release(struct rims *r);

/* A layer (plane at (k + 0.5) * layer_mm above base along up) of a component
   whose cross-section stays open. */
struct open_layer {
    uint32_t comp;
    int32_t k;
};

/*
 * The open layers of m turned to up, sorted by (comp, k), each once: *out is
 * malloc'd (NULL when there are none; free it).  base is the part's lowest
 * point along up.  SF_ENOMEM, SF_EINVAL for a non-positive layer or a
 * negative gap.
 */
int rims_open_layers(const struct rims *r, const struct mesh *m, struct vec3 up, double base,
                     double layer_mm, double max_gap_mm, struct open_layer **out, size_t *n,
                     struct sf_err *err);

#endif
