/*
 * slice.h - the built-in slicer's public entry point: a mesh and a profile
 * in, a Marlin G-code file and its figures out.  This is the only header
 * the daemon and the CLI need (with profile.h for the settings).
 *
 *     struct slice_profile p;
 *     if (slice_profile_load("config/printers/mk3.cfg", "config/materials/pla.cfg", &p, &err) < 0)
 * ... struct slice_result r; if (slice_mesh(&mesh, &p, "part.gcode", &r, NULL, NULL, &err) < 0) ...
 *     printf("%u layers, %.1f g, %.0f s\n", r.n_layers, r.filament_g, r.time_s);
 *     slice_profile_release(&p);
 *
 * The part is placed on the bed as given (lowest point on z = 0, bounding
 * box centred on the bed); orient and slim it before.  Pipeline: layers
 * (layers.h), column supports (support.h support_columns, src/geom's
 * support model), toolpaths (toolpath.h), G-code body (gcwrite.h), time
 * and filament (estimate.h), then the file: header comments with the
 * estimates, start G-code, body with M73 progress, end G-code.
 *
 * Thread: slice_mesh may run on a worker thread, several at once on
 * different meshes; its per-layer stages run on par_for (base/par.h).
 * progress is called on the calling thread.
 */
#ifndef SF_SLICER_SLICE_H
#define SF_SLICER_SLICE_H

#include <stdbool.h>
#include <stdint.h>

#include "../src/base/err.h"
#include "../src/mesh/mesh.h"
#include "profile.h"

struct slice_result {
    uint32_t n_layers;
    double height_mm;   /* part height */
    double filament_mm; /* all extrusion, mm of filament */
    double filament_g;
    double support_mm; /* of which support and interface */
    double support_g;
    double time_s;             /* estimated print time */
    double support_volume_mm3; /* volume of the support regions printed (before infill density) */
    double ray_volume_mm3;     /* the metrics module's column volume on the same grid */
    uint32_t n_columns;        /* ray-grid columns */
    uint32_t n_island_columns; /* extra columns under islands */
    uint32_t n_open_loops;     /* open slice chains closed by force (open mesh) */
    double brim_mm;            /* brim printed, mm wide (brim_width or automatic) */
    double wall_s;             /* slicing wall time */
};

/*
 * Called between stages ("layers", "supports", "toolpaths", "gcode",
 * "estimate", "write", "done") and between toolpath layers, with the
 * stage's fraction done (0..1).  Return 0 to go on, non-zero to cancel:
 * slice_mesh then stops at once with SF_ECANCELED (a daemon cancelling a
 * job), writing no file.
 */
typedef int (*slice_progress_fn)(void *ud, const char *stage, double done);

/*
 * Slice m with p and write the G-code to gcode_path.  res (may be NULL)
 * receives the figures.  Errors: SF_EINVAL (the part does not fit the bed,
 * a bad profile or placeholder), SF_EIO (writing the file; a partial file
 * is removed), SF_ECANCELED (progress asked to stop), SF_ENOMEM, SF_EBUG.
 */
int slice_mesh(const struct mesh *m, const struct slice_profile *p, const char *gcode_path,
               struct slice_result *res, slice_progress_fn progress, void *ud, struct sf_err *err);

/*
 * Expand {placeholders} of G-code template t ("start_gcode" for messages)
 * into out: bed_temp, nozzle_temp, first_layer_bed_temp,
 * first_layer_nozzle_temp, bed_x, bed_y, max_z, layer_height,
 * first_layer_height, filament_diameter, nozzle_diameter, printer,
 * material.  SF_EINVAL naming an unknown placeholder.
 */
struct buf;
int slice_expand(const struct slice_profile *p, const char *what, const char *t, struct buf *out,
                 struct sf_err *err);

/* The estimator's machine limits from a profile. */
struct est_limits;
void slice_limits(const struct slice_profile *p, struct est_limits *lim);

#endif
