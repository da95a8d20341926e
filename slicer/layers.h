/*
 * layers.h - cut a mesh into per-layer cross-sections.
 *
 * The part is placed on the bed first: its lowest point goes to z = 0 and
 * its bounding box is centred at (cx, cy).  Layer 0 is first_mm thick,
 * the rest layer_mm; each layer is cut by the plane through its middle
 * (as PrusaSlicer does), so a 20 mm cube at 0.2 mm gives 100 layers.
 * The cross-section is a polygon set with holes in tree order (poly.h).
 *
 * Robustness: a vertex on a cutting plane (within 0.1 um: float
 * coordinates, double planes) counts as above it (symbolic perturbation),
 * so a top face modelled at a plane's height keeps that layer, as in
 * PrusaSlicer, and every cut triangle has exactly two crossing
 * edges and every crossing point is computed from its edge alone, the same
 * way for both triangles that share it.  Segments are chained through the
 * edges they cross (topology, no epsilon), then, for unwelded or open
 * meshes, through exactly equal points, then across cracks of up to 2 mm
 * from a chain's end to the nearest chain start (PrusaSlicer's gap
 * closing); what stays open is closed straight and the loops are united
 * with the nonzero rule.
 *
 * Thread: layers_slice may run concurrently on different outputs.
 */
#ifndef SF_SLICER_LAYERS_H
#define SF_SLICER_LAYERS_H

#include <stdbool.h>
#include <stdint.h>

#include "../src/base/err.h"
#include "../src/mesh/mesh.h"
#include "poly.h"

/* At most this many extra perimeters on an island (extra_perimeters). */
#define LAYER_MORE_MAX 4

struct layer {
    double z_mm;         /* top of the layer above the bed */
    double h_mm;         /* its thickness */
    struct paths region; /* part cross-section at z_mm - h_mm / 2 */
    struct paths inner;  /* inside the perimeters: filled by toolpath_areas() */
    /* the islands of region that get more than the profile's perimeters
       (extra_perimeters): more[e] those with at least e + 1 more; n_more
       how many sets are not empty (toolpath_areas()) */
    struct paths more[LAYER_MORE_MAX];
    uint32_t n_more;
    struct paths skin;        /* the surface open to the air above, and its part in inner
                                 grown skin_margin: toolpath_areas() */
    struct paths skin_bottom; /* the same for the surface open below */
    struct paths top_in;      /* the surface open to the air above (opened) inside inner:
                                 toolpath_areas() */
    struct paths small;       /* pieces of inner away from this layer's own top and bottom
                                 surfaces no larger than solid_infill_below_area: solid
                                 (toolpath_areas()) */
    /* the infill area split by toolpath_store_regions(): solid, top solid
       and sparse (the layer above bridges over this sparse) */
    struct paths solid, top, sparse;
    bool has_regions;
};

struct layer_stack {
    struct layer *l;
    uint32_t n;
    double dx, dy, dz;   /* translation applied to the mesh to place it */
    double cx_mm, cy_mm; /* where its bounding box's centre went (the fills' grid runs through) */
    uint32_t n_open;     /* open chains closed straight (holes over 2 mm) */
};

/*
 * Slice m.  out is filled (layer_stack_release frees it).  SF_EINVAL for
 * an empty or non-finite mesh or one taller than SF_SLICE_LAYERS_MAX
 * layers; SF_ENOMEM.
 */
int layers_slice(const struct mesh *m, double first_mm, double layer_mm, double cx, double cy,
                 struct layer_stack *out, struct sf_err *err);

void layer_stack_release(struct layer_stack *s);

#endif
