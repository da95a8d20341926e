/*
 * slim.h - support slimming by volumetric as-rigid-as-possible
 * deformation (Hu, Jin & Wang, "Support slimming for single material based
 * additive manufacturing", CAD 2015; DESIGN.md method 2).
 *
 * The part is embedded in a coarse enclosing tet mesh (tetmesh.h); a
 * local/global ARAP loop (arap.h) rotates the tets whose surface faces
 * overhang toward safe orientations by the minimal rotation, keeping the
 * bottom fixed; the part follows through barycentric coordinates.  The
 * iterate the layer-based support model (supmodel.h) gives the fewest
 * grams is kept; if the deviation limits (MNDR, ANDR) fail, the penalty
 * angle beta is raised and the loop runs again.  Optionally, print
 * directions on a grid of rotations about x and y are each optimized (in
 * parallel) and the one the model gives the fewest grams wins (the
 * paper's extension).  A result never has inverted tets
 * or new self-intersections: it falls back to the best clean iterate, and
 * at worst to the input.
 *
 * Volume: the deformation shrinks the part (arap.h, "Volume"), and a
 * smaller part needs less support for that reason alone.  So by default
 * (keep_volume) each kept iterate is scaled uniformly about its bed contact
 * back to the input's volume before it is weighed and checked (deviation
 * limits, self-intersections, min_gain of the model's grams): a uniform
 * scale turns no face, so the risky faces stay as they were, and the part
 * keeps resting on the bed.  The fixed bottom then scales with the part
 * (it stays on the bed; its outline grows by the scale, 1-7 % on the
 * shared meshes); fix_boxes turn the rescale off, as they promise their
 * region stays exactly.
 *
 * Thread-safety: slim_optimize may run on any thread; it starts its own
 * workers for the direction search.  The progress callback may be called
 * from those workers (serialized: never two at once).
 */
#ifndef SF_GEOM_SLIM_H
#define SF_GEOM_SLIM_H

#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>

#include "../base/err.h"
#include "../mesh/mesh.h"
#include "measure.h"
#include "tetmesh.h"

/* An axis-aligned box of the input frame whose part stays where it is. */
struct slim_box {
    struct vec3 lo, hi; /* mm */
};

/* What the progress callback sees after each iteration. */
struct slim_progress {
    int dir, n_dirs;     /* direction being optimized (search), 0 and 1 otherwise */
    int run;             /* beta round, from 0 */
    double beta_deg;     /* penalty angle of this round */
    int iter, max_iters; /* iteration just done, from 1 */
    uint32_t n_risky;    /* risky faces of the part now */
    double mndr, andr;   /* deviation now */
    double model_g;      /* the support model's grams of this iterate (supmodel.h, PrusaSlicer's
                            rules; rescaled with keep_volume), which ranks it; NAN when it is
                            past the limits and not weighed */
};

struct slim_params {
    double angle_deg;     /* alpha: self-supporting angle from vertical (45) */
    double margin_deg;    /* the minimal rotation aims this far past the steepest face the
                             support model leaves unsupported (alpha less PrusaSlicer's
                             inclusive degree; 5): the global
                             step realises only part of each target, so aiming at the
                             threshold itself stalls just short of it */
    double beta_deg;      /* starting penalty angle (0) */
    double beta_step_deg; /* raise per round when the deviation limits fail (5) */
    double beta_max_deg;  /* give up raising past this (45) */
    double max_mndr;      /* limit on max displacement / bbox diagonal (0.05) */
    double max_andr;      /* limit on mean displacement / bbox diagonal (0.015) */
    double fix_bottom_mm; /* everything this close to the bed stays fixed (2) */
    const struct slim_box *fix_boxes; /* more fixed regions (may be NULL) */
    int n_fix_boxes;
    int max_iters;             /* per round (100) */
    int patience;              /* stop when the risky count has not dropped for this many (5) */
    struct tetmesh_params tet; /* enclosing tet mesh */
    bool search_direction;     /* also try rotations about x and y (false) */
    double search_step_deg;    /* grid step of the search (15) */
    double search_max_deg;     /* largest tilt about each axis (30) */
    int threads;               /* threads for the search, at most (0: par.h's budget) */
    double min_gain;           /* keep the input unless the result needs at least this fraction
                                  less support by the model (0.05): a part's shape is not changed
                                  for a saving the slicers' own rules blur (orient.h keeps its
                                  input orientation by the same rule) */
    bool keep_volume;          /* scale the result uniformly about its bed contact so its volume
                                  is the input's (true); skipped when fix_boxes are given, which
                                  must stay exactly where they are (see "Volume" above) */
    void (*progress)(void *ud, const struct slim_progress *pr); /* optional */
    void *progress_ud;
    const atomic_bool *cancel; /* optional: set to stop with SF_ECANCELED */
};

void slim_params_default(struct slim_params *p);

#define SLIM_CURVE_MAX 1024 /* risky-face counts kept per result */

struct slim_result {
    struct mesh out;      /* the slimmed part in the print orientation (mesh_release) */
    struct mat3 rotation; /* applied to the input first (identity unless searched) */
    struct support_metrics before, after; /* ray-cast metrics, the input as given vs output */
    /* the layer-based support model (supmodel.h, PrusaSlicer's rules), grams of the input as
       given and of out: it picks the iterate and the direction, and a result (slimmed, turned
       or both) must save min_gain of the input's */
    double model_before_g, model_after_g;
    struct deviation dev; /* MNDR / ANDR of out against the rotated input */
    /* enclosed volume of the rotated input and of out (mesh_volume): equal up to rounding with
       keep_volume.  Without it the deformation does not keep it (arap.h, "Volume": disagreeing
       target rotations compress the tets) and MNDR / ANDR do not see a spread-out squash.  A
       part with few vertices follows only them: the tee's 16 vertices give +20 % while its tet
       mesh loses 4 % */
    double part_volume_in_mm3, part_volume_out_mm3;
    double volume_scale;            /* the uniform scale keep_volume applied (1: none) */
    uint32_t curve[SLIM_CURVE_MAX]; /* risky faces per iteration of the chosen round; [0] = input */
    int n_curve;
    int best_iter;              /* iteration returned (0: the input itself) */
    int n_runs;                 /* beta rounds run for the chosen direction */
    double beta_deg;            /* penalty angle of the returned iterate */
    int n_dirs;                 /* directions optimized */
    uint32_t n_inverted;        /* inverted tets in the returned result (0 by construction) */
    int selfx_input, selfx_out; /* self-intersecting edges before and after */
    uint32_t n_rejected;        /* better iterates rejected: inverted tets, new
                                   self-intersections, more support volume or,
                                   once rescaled, deviation past the limits */
    /* tet mesh and timing */
    uint32_t tet_verts, tet_tets, tet_surface, tet_outside;
    double setup_s, total_s; /* tet mesh and face hosts; everything */
    struct slim_timing {
        int iterations;      /* local/global iterations run, all rounds and directions */
        uint64_t rotated;    /* minimal rotations applied, summed over iterations */
        uint64_t slow_polar; /* nearest rotations that took the scalar path */
        double factor_s;     /* assembling and factorizing L (once per direction) */
        double local_s;      /* deformation gradients and nearest rotations */
        double minrot_s;     /* minimal rotations */
        double rhs_s;        /* right-hand sides */
        double solve_s;      /* back-substitutions */
        double part_s;       /* mapping the part, measuring it, finding the drives */
        double score_s;      /* weighing each iterate within the limits by the support model */
        double choose_s;     /* checking the kept iterates (self-intersection, ray cast) */
    } timing;
};

/*
 * Slim part m.  res is filled (release with slim_result_release).  Errors:
 * SF_EINVAL (bad parameters or a part TetGen cannot enclose), SF_ENOMEM,
 * SF_ECANCELED.
 */
int slim_optimize(const struct mesh *m, const struct slim_params *p, struct slim_result *res,
                  struct sf_err *err);
void slim_result_release(struct slim_result *res);

#endif
