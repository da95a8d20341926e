/*
 * support.h - the support columns the slicer prints, and their per-layer
 * support regions.
 *
 * Columns come from the support model (src/geom supmodel_columns: the
 * outside slicer's overhang rules the optimizers steer by, on a ray grid of
 * vertical cells), built by support_columns from the slicer profile through
 * support_model_params: the one generator the slicer and the part picture
 * (preview.h) both call, so the picture shows the columns the print gets.
 * The column and grid types are src/geom's (measure.h: support_column,
 * support_grid).  Islands - a piece of a layer that touches nothing in the
 * layer below (a local minimum, a part starting in mid-air) - add columns
 * of their own even where no face is steep enough to count as risky.
 *
 * Each layer's support is the union of the cells whose column spans the
 * whole layer, stopping support_z_gap below the part (and above it, when
 * the column stands on the part), minus the part's cross-section grown by
 * support_xy_gap.  The top support_interface_count layers of each column
 * (and the bottom ones where it stands on the part) are the interface
 * (printed dense).  Cells in a row are merged into
 * rectangles before the union, so a layer costs one Clipper call.
 *
 * Thread: reentrant.
 */
#ifndef SF_SLICER_SUPPORT_H
#define SF_SLICER_SUPPORT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../src/geom/measure.h"
#include "../src/geom/supmodel.h"
#include "../src/mesh/mesh.h"
#include "layers.h"
#include "profile.h"
#include "toolpath.h"

/* The tri of the columns support_islands adds (no risky triangle): their
   tops print dense, where the model's columns take the dense interface
   from its bands. */
#define SUPPORT_ISLAND_TRI UINT32_MAX

/* The support model's parameters for profile p: PrusaSlicer's rules at the
   profile's overhang angle, layer height, column pitch, gaps and interface
   layers, with its bridge exemption (dont_support_bridges: a bottom its
   bridge detector anchors gets no columns; our bridge infill spans it in
   the anchored direction), so the print, the part picture and the
   optimizers' model hold up the same bottoms. */
void support_model_params(const struct slice_profile *p, struct supmodel_params *mp);

/* How many of our layers the dense interface of a column takes: PrusaSlicer
   2.5 prints support_interface_layers of its support layers, and those are
   as thick as its max_layer_height allows (0.75 of the nozzle by default,
   Slicing.cpp), not the part's layers: 3 at a 0.4 mm nozzle are 0.9 mm
   dense (hook of the mech set: 0.3 + 0.3 + 0.3 mm under each contact), 5
   of our 0.2 mm layers (rounded up; its partial contact layer on top
   makes up the difference). */
int support_interface_count(const struct slice_profile *p);

/*
 * The columns the slicer prints for m as it lies (+z up, m's coordinates)
 * under profile p: *g the grid (x0, y0 cell (0, 0)'s centre, base m's
 * lowest z), *cols (allocated, capacity *cap; free()) *n columns: the
 * *n_body columns first, then their dense-interface bands (iface set).
 * SF_ENOMEM, or what the ray cast reports.
 */
int support_columns(const struct mesh *m, const struct slice_profile *p, struct support_grid *g,
                    struct support_column **cols, size_t *n, size_t *cap, size_t *n_body,
                    struct sf_err *err);

/*
 * Append a column under every island of s (layers 1 and up) whose cells
 * have no column ending near the island's bottom.  *cols (capacity *cap,
 * grown with mem_grow) holds *n columns.  SF_ENOMEM / SF_EBUG.
 */
int support_islands(const struct layer_stack *s, const struct support_grid *g,
                    struct support_column **cols, size_t *n, size_t *cap);

/*
 * Fill out[k] (s->n entries, initialised here; release each with
 * support_layer_release) with the support of layer k.  cols is sorted in
 * place.  SF_ENOMEM / SF_EBUG.
 */
int support_layers(const struct layer_stack *s, const struct support_grid *g,
                   struct support_column *cols, size_t n, const struct slice_profile *p,
                   struct support_layer *out, struct sf_err *err);

void support_layer_release(struct support_layer *l);

/* Volume of the support regions (body and interface), mm^3. */
double support_volume(const struct layer_stack *s, const struct support_layer *sup);

#endif
