/*
 * growth.h - the layer-by-layer growth simulation of the orientation paper
 * (Allen & Dutta, section 4.2.1) on the rays structure.
 *
 * The ray grid's solid intervals give a voxel model (grid cell x layer).
 * Layer by layer, each 4-connected region that touches nothing built below
 * it and no support column is an island that starts in mid-air: it needs
 * support at its lowest points even where no face is steep enough to count
 * as risky (a downward point or edge).  And as the part grows, the centre
 * of mass of what is built so far must stay over the extended base: the
 * convex hull of the first layer and of the support columns standing on the
 * bed.
 *
 * Pure function of its inputs; thread-safe.
 */
#ifndef SF_GEOM_GROWTH_H
#define SF_GEOM_GROWTH_H

#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"
#include "raycast.h"

struct support_column; /* measure.h */

struct growth_report {
    uint32_t n_islands;       /* regions that start in mid-air with no column under them */
    double island_volume_mm3; /* columns needed from the bed or the part below up to them */
    double min_margin_mm;     /* least distance of the partial centre of mass inside the
                                 extended base over all layers; negative: it tips */
    int unstable_layer;       /* first layer where the margin is negative, or -1 */
    uint32_t n_layers;
};

/*
 * Simulate growth in layers of layer_mm (use the grid pitch or the print's
 * layer height).  cols are the ray-structure support columns (measure.h).
 */
int growth_simulate(const struct ray_grid *g, const struct support_column *cols, size_t n_cols,
                    double layer_mm, struct growth_report *out, struct sf_err *err);

#endif
