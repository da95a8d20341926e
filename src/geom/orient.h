/*
 * orient.h - choose the up-direction that needs the least support.
 *
 * Candidates (Allen & Dutta; Jayakody et al.): the stable planar bases of
 * the convex hull, N Fibonacci-sphere directions, and the input
 * orientation; a cheap proxy prunes them, the exact ray-cast metrics score
 * the survivors in parallel, and a finer cap of samples refines around the
 * best few.  Cost = support volume + w_contact * contact area + w_stability
 * * centre-of-mass height, support volume including what the growth
 * simulation's islands need; a direction on which the part would stand on a
 * point with nothing holding it, or would tip over while it grows, is dropped.
 *
 * Thread-safe: each call is independent; it runs on par_for (base/par.h),
 * within the process's thread budget.
 */
#ifndef SF_GEOM_ORIENT_H
#define SF_GEOM_ORIENT_H

#include <stdatomic.h>
#include <stdint.h>

#include "../base/err.h"
#include "../mesh/mesh.h"
#include "measure.h"

struct orient_params {
    double angle_deg;       /* self-supporting angle from vertical (45) */
    double margin_deg;      /* score as if the angle were this much smaller (5): slicers work
                               in layers and count faces at the limit as overhangs, so a face
                               left exactly at the limit gets support after all */
    double pitch_mm;        /* ray grid pitch for scoring (1) */
    int samples;            /* Fibonacci-sphere directions (1000) */
    int exact_top;          /* sphere samples kept after the proxy for exact scoring (24) */
    int exact_hull;         /* stable hull bases kept after the proxy for exact scoring, the
                               best by proxy (12): a part with many stable faces (couplingdown:
                               82) cast every one, twice the work of other parts; keeping
                               only 6 left every pick on the 12 shared meshes unchanged */
    double w_contact_mm;    /* cost per mm2 of contact area, in mm3 (1: one interface layer) */
    double w_stability_mm2; /* cost per mm of centre-of-mass height, in mm3 (0.5) */
    double min_gain;        /* keep the input orientation unless the best costs at least this
                               fraction less (0.05): operators do not want parts turned for
                               nothing, and the peers' layer rules blur small differences */
    double max_open_rays;   /* if more than this fraction of the input's rays meet unpaired
                               surfaces (0.01), the part is no closed solid, its support
                               figures are guesses, and the input orientation is kept */
    double min_base_mm2;    /* smallest hull face the part may rest on (25) */
    double min_margin_mm;   /* centre of mass must project this far inside a base (1) */
    int threads;            /* at most this many threads (0: par.h's budget) */
    void (*progress)(void *ud, double done, double total); /* optional, any thread */
    void *progress_ud;
    const atomic_bool *cancel; /* optional: checked before each direction is scored;
                                  set, orient_find returns SF_ECANCELED */
};

void orient_params_default(struct orient_params *p);

enum orient_source { ORIENT_INPUT, ORIENT_HULL, ORIENT_SPHERE, ORIENT_REFINE };

struct orient_candidate {
    struct vec3 up;            /* unit up-direction in the input frame */
    enum orient_source source; /* where it came from */
    struct support_metrics m;  /* exact metrics at angle_deg (what the operator asked) */
    double cost;               /* ray-cast cost, scored at angle_deg - margin_deg */
    double support_g;          /* finalists: the layer-based model's grams (supmodel.h,
                                  PrusaSlicer's rules at angle_deg), which ranks them */
};

struct orient_result {
    struct orient_candidate best;
    struct orient_candidate input;      /* the input orientation, for comparison */
    struct orient_candidate runners[4]; /* next best, distinct directions */
    int n_runners;
    bool not_solid;        /* input kept: the part is not a closed solid (max_open_rays) */
    uint32_t n_candidates; /* directions considered */
    uint32_t n_exact;      /* scored with the ray cast */
    double seconds;        /* wall time in total */
    double seconds_setup;  /* hull, proxy cache, Embree scene */
    double seconds_proxy;  /* proxy over every candidate */
    double seconds_exact;  /* ray-cast scoring, refinement included */
};

/* Find the best up-direction for m.  res->best.up is what to rotate onto +z. */
int orient_find(const struct mesh *m, const struct orient_params *p, struct orient_result *res,
                struct sf_err *err);

/* Rotate m so up becomes +z, rest it on z = 0 centred at (cx, cy). */
void orient_apply(struct mesh *m, struct vec3 up, double cx, double cy);

const char *orient_source_name(enum orient_source s);

#endif
