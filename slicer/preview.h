/*
 * preview.h - pictures a person can check by eye, as PNG (cairo): a part
 * with its risky faces coloured and its support columns, or one layer of
 * a G-code file with its extrusion roles in PrusaSlicer's colours.
 *
 * The part view is an orthographic three-quarter view from the front,
 * flat-shaded, faces sorted back to front (painter's algorithm); faces
 * that need support at the profile's angle are red, and the support
 * columns the slicer prints for it (support.h support_columns, the same
 * function on the same parameters) blue and translucent.  The layer view is from the top, scaled to
 * the layer's extent, with travel moves as thin grey lines.
 *
 * Thread: reentrant (each call has its own cairo surface).
 */
#ifndef SF_SLICER_PREVIEW_H
#define SF_SLICER_PREVIEW_H

#include <stddef.h>

#include "../src/base/err.h"
#include "../src/geom/measure.h"
#include "../src/mesh/mesh.h"
#include "profile.h"

struct preview_opts {
    int width_px, height_px;             /* image size (default 800 x 600) */
    const struct slice_profile *profile; /* the part's columns as this profile slices
                                            them; NULL (default): the default profile
                                            at angle_deg and pitch_mm */
    double angle_deg;                    /* overhang angle from vertical (default 45) */
    double pitch_mm;                     /* column pitch, 0 (default): the profile's */
    int layer;                           /* G-code layer to draw, -1: the middle one */
};

void preview_opts_default(struct preview_opts *o);

/*
 * The support columns preview_part draws for m: support_columns (support.h)
 * under o's profile, *n_body columns then their interface bands, *cols
 * allocated (free()).  SF_ENOMEM, or what the ray cast reports.
 */
int preview_columns(const struct mesh *m, const struct preview_opts *o, struct support_grid *g,
                    struct support_column **cols, size_t *n, size_t *n_body, struct sf_err *err);

/* Draw m and its support columns into png_path.  SF_EIO, SF_ENOMEM. */
int preview_part(const struct mesh *m, const struct preview_opts *o, const char *png_path,
                 struct sf_err *err);

/*
 * Draw one layer of the G-code text (name for messages) into png_path:
 * extrusions in PrusaSlicer's role colours (skirt and brim teal, gap fill
 * white), travel thin grey, and the seams: where this layer's external
 * perimeters start as white dots, every layer's as small grey ones (an
 * aligned seam's line up the part, seen from above).  SF_EINVAL for a
 * malformed file or a layer it does not have.
 */
int preview_gcode(const char *text, size_t len, const char *name, const struct preview_opts *o,
                  const char *png_path, struct sf_err *err);

#endif
