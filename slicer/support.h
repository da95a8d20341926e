/*
 * support.h - column supports sliced into per-layer support regions.
 *
 * Columns come from the rays structure (src/geom measure_columns: a
 * vertical ray per cell of an x-y grid, a column from the bed or the
 * part's last exit below up to each risky hit), converted to bed
 * coordinates.  Islands - a piece of a layer that touches nothing in the
 * layer below (a local minimum, a part starting in mid-air) - add columns
 * of their own even where no face is steep enough to count as risky.
 *
 * Each layer's support is the union of the cells whose column spans the
 * whole layer, stopping support_z_gap below the part (and above it, when
 * the column stands on the part), minus the part's cross-section grown by
 * support_xy_gap.  The top support_interface_layers of each column are
 * the interface (printed dense).  Cells in a row are merged into
 * rectangles before the union, so a layer costs one Clipper call.
 *
 * Thread: reentrant.
 */
#ifndef SF_SLICER_SUPPORT_H
#define SF_SLICER_SUPPORT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "layers.h"
#include "profile.h"
#include "toolpath.h"

/* The column grid in bed coordinates: cell (i, j) is centred at
   (x0 + i pitch, y0 + j pitch). */
struct sup_grid {
    double x0, y0, pitch;
    uint32_t nu, nw;
};

/* A column: cell (i, j) from z lo to z hi (mm above the bed).  With iface
   set, not a column but a dense-interface band of one: the layers of cell
   (i, j) wholly inside lo..hi print dense (gaps already applied). */
struct sup_col {
    uint32_t i, j;
    float lo, hi;
    bool iface;
};

/*
 * Append a column under every island of s (layers 1 and up) whose cells
 * have no column ending near the island's bottom.  *cols (capacity *cap,
 * grown with mem_grow) holds *n columns.  SF_ENOMEM / SF_EBUG.
 */
int support_islands(const struct layer_stack *s, const struct sup_grid *g, struct sup_col **cols,
                    size_t *n, size_t *cap);

/*
 * Fill out[k] (s->n entries, initialised here; release each with
 * support_layer_release) with the support of layer k.  cols is sorted in
 * place.  SF_ENOMEM / SF_EBUG.
 */
int support_layers(const struct layer_stack *s, const struct sup_grid *g, struct sup_col *cols,
                   size_t n, const struct slice_profile *p, struct support_layer *out,
                   struct sf_err *err);

void support_layer_release(struct support_layer *l);

/* Volume of the support regions (body and interface), mm^3. */
double support_volume(const struct layer_stack *s, const struct support_layer *sup);

#endif
