/*
 * prepare.h - the boundary between the farm and the part pipeline: turn a
 * stored part into G-code for one target printer (orient, then shape
 * optimization, then slice).
 *
 * The farm runs a prepare function on the worker pool (pool.h) with plain
 * data copied in struct prepare_req, so it touches nothing shared.  The
 * stages live in src/mesh (load), src/geom (orient, slimming, surface
 * optimization) and slicer/ (slice).  The optimized part is saved
 * (mesh_out) so that a job prepared again for a printer of another
 * profile with the same overhang angle is only sliced again (mesh_in).
 *
 * Thread: a pool worker; must check *cancel between stages.
 */
#ifndef SF_FARM_PREPARE_H
#define SF_FARM_PREPARE_H

#include <stdatomic.h>
#include <stdbool.h>

#include "../base/err.h"
#include "farmcfg.h"
#include "job.h"

#define PREPARE_PATH_MAX 1100 /* data dir paths (store.c caps the dir at 1024) */

/* Everything a preparation needs, copied for the worker. */
struct prepare_req {
    int64_t job_id;                      /* for messages */
    char part_path[PREPARE_PATH_MAX];    /* stored part file (read only) */
    char part_name[JOB_NAME_MAX];        /* the uploaded name; its extension tells the format */
    struct job_opts opts;                /* method, deviation budget, overhang angle ... */
    double gram_s;                       /* surface: a gram of support is worth this many
                                            print seconds (farmcfg gram_seconds) */
    bool material_first;                 /* surface: may print slower to save support */
    struct farmcfg_printer printer;      /* target printer: profile, nozzle, bed, overhang */
    char profiles_dir[PREPARE_PATH_MAX]; /* printers/PROFILE.cfg, materials/MATERIAL.cfg */
    char out_path[PREPARE_PATH_MAX];     /* write the G-code here */
    char mesh_in[PREPARE_PATH_MAX];      /* "" or the part already oriented and shaped for
                                            this overhang angle (a mesh_out of an earlier
                                            prepare): slice it, skipping the optimization */
    char mesh_out[PREPARE_PATH_MAX];     /* "" or where to save the part as it prints (binary
                                            STL), when a method turned or shaped it */
};

/* What a successful preparation reports. */
struct prepare_out {
    double size_mm[3]; /* bounding box of the part as it will print */
    double nozzle_mm;  /* nozzle the G-code was sliced for */
    bool mesh_saved;   /* the part as it prints was written to req->mesh_out */
    double filament_g; /* the slicer's estimates for the G-code written (grams) */
    double support_g;
    double support_saved_g; /* support the optimization saved, grams: the slicer's own
                               figures where it sliced both shapes (slim), else the
                               support model's (orient: input vs chosen direction;
                               surface: before vs after); 0 for method none */
    int64_t slice_ms;       /* slicing's wall time */
    /* the shape deviation of the part as it prints from the part as uploaded (turned
       the same way), measure.h's struct deviation: max / mean vertex displacement over
       the bounding-box diagonal.  Measured by the shape methods (slim, surface) only;
       0 with shape_changed false when the reshaped part was not kept */
    bool dev_measured;  /* mndr, andr are set: method slim or surface ran */
    bool shape_changed; /* the part prints reshaped, not only turned */
    double mndr, andr;
    /* "" or what shape step failed, why and how the part prints instead, e.g.
       "slimming failed (tetgen: no tetrahedra produced): printed as oriented,
       unchanged", or a surface optimization's "... printed as given, unchanged"
       (shape_changed false, mndr = andr = 0 with dev_measured) */
    char shape_failed[SF_ERR_MSG_MAX];
};

typedef int (*prepare_fn)(const struct prepare_req *req, struct prepare_out *out,
                          const atomic_bool *cancel, struct sf_err *err);

/*
 * The pipeline: load the part (or req->mesh_in, then straight to slicing),
 * orient it (methods orient, slim, surface)
 * for the job's overhang angle or else the printer's, reshape it (slim,
 * surface; a slimmed shape only if it prints with less support, see
 * prepare_slice_better), slice it with the
 * printer's profile and the job's material, the farm config's nozzle, bed
 * and angle overriding the profile's.  SF_EINVAL for a bad part or
 * profile (the message names the file), SF_ECANCELED if cancelled.  A
 * slimming or surface optimization that fails other than by cancel or
 * SF_ENOMEM does not fail the job: the part as oriented (surface: as given)
 * is sliced and out->shape_failed says why.
 */
int prepare_part(const struct prepare_req *req, struct prepare_out *out, const atomic_bool *cancel,
                 struct sf_err *err);

/* Which of two slicings prepare_slice_better kept. */
struct prepare_choice {
    bool took_shaped;        /* the reshaped part needs less support: its G-code was kept */
    double support_g_shaped; /* support grams of each, as this slicer prints them */
    double support_g_start;
    double filament_g; /* all filament of the G-code kept */
};

/*
 * Slice a shape optimizer's result (shaped) and the part it started from
 * (start, the same part oriented) with prof, and leave at out_path the
 * G-code of the one needing fewer support grams; a tie goes to start, the
 * unchanged shape.  Why: slimming steers by the ray-cast column volume,
 * which the printed support follows only roughly: the slicer leaves a gap
 * around the part and merges columns (tests/bench/bench_slim.sh, armadillo
 * at 45 degrees: ray-cast -7.6 %, this slicer's grams +3.3 %), so what the
 * farm prints is judged by the slicer that prints it.  Errors as
 * slice_mesh's; no file is left at out_path on an error.
 */
struct mesh;
struct slice_profile;
int prepare_slice_better(const struct mesh *start, const struct mesh *shaped,
                         const struct slice_profile *prof, const char *out_path,
                         const atomic_bool *cancel, struct prepare_choice *ch, struct sf_err *err);

#endif
