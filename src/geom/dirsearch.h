/*
 * dirsearch.h - shape inside the direction search (Hu 2015's print-direction
 * search, Jayakody 2025's alternation of orientation and shape): the
 * orientation search's best K distinct directions are each turned up and
 * surface-optimized (surfopt.h, one geometry round, no re-orientation),
 * and weighed beside the axis directions of the input's frame turned up
 * unreshaped (CAD parts come axis-aligned: the orientation search, ranking
 * by support alone, left out axis poses as good by value), and the winner
 * is the one of least value in seconds (printtime.h: the
 * estimated print time, part and the support model's support, plus
 * gram_s per gram of support by the model, supmodel.h).  The input is
 * returned unchanged unless printtime_worth says the winner is worth it:
 * no more support, no slower (unless material_first), and a saving that
 * grows with the input's support (issue 36: a flat 5 % of the grams let
 * a part stand up taller and print longer, and weighed a 2 g part's
 * saving as a 25 g part's).  A part the orientation search finds is no
 * closed solid (orient_result.not_solid) keeps its up: only its shape step
 * runs.
 *
 * Thread-safety: each call is independent (the orientation search starts
 * its own threads).
 */
#ifndef SF_GEOM_DIRSEARCH_H
#define SF_GEOM_DIRSEARCH_H

#include "../base/err.h"
#include "../mesh/mesh.h"
#include "orient.h"
#include "printtime.h"
#include "surfopt.h"

#define DIRSEARCH_K_MAX 5
/* the axis directions of the input's frame weighed beside them, unreshaped
   (+x, -x, +y, -y, -z; +z is the input as given, weighed by the keep rule) */
#define DIRSEARCH_AXES     5
#define DIRSEARCH_DIRS_MAX (DIRSEARCH_K_MAX + DIRSEARCH_AXES)

struct dirsearch_params {
    int k;                          /* directions reshaped (4; at most DIRSEARCH_K_MAX) */
    struct printtime_policy policy; /* what a result is worth and when it beats the input
                                       (printtime_policy_default) */
    struct printtime_params pt;     /* the print-time estimate (printtime_params_default) */
    struct orient_params op;        /* the direction search (angle taken from sp.angle_deg) */
    struct surfopt_params sp;       /* the shape step (its own orientation step is turned off) */
};

void dirsearch_params_default(struct dirsearch_params *p);

/*
 * Where a search's time went, by what ran (issue 36), in wall seconds
 * summed over the directions, which run on two threads at once (so the
 * sum is up to twice the search's own wall time): the orientation
 * candidates (the search's orient_find and each direction's orientation
 * step), the saliency, the surface steps (factorizing and iterating), the
 * self-intersection checks, the support model's evaluations and the
 * print-time estimates; other_s is the rest (loading copies, the ray
 * metrics, choosing).
 */
struct dirsearch_stages {
    double orient_s, saliency_s, surface_s, selfx_s, model_s, print_s, other_s;
};

struct dirsearch_result {
    struct surfopt_result best;       /* the winner (best.out on z = 0); the input when kept */
    struct vec3 up;                   /* its up-direction in the input frame */
    bool kept_input;                  /* no direction's result is worth it (printtime_worth) */
    double model_input_g;             /* the model's grams for the input as given */
    struct printtime_cost input_cost; /* the input as given: model grams, print seconds */
    struct printtime_cost cost;       /* the result handed back (the input's when kept) */
    int n_tried;                      /* directions reshaped: [0, n_tried) */
    /* the axis directions weighed unreshaped, [n_tried, n_tried + n_axes) in
       the arrays below (issue 36: the orientation search ranks by support
       alone and left out axis poses as good by value: scad example008 -y,
       mech shelf +x); those within a few degrees of a reshaped one are left
       out */
    int n_axes;
    int n_axes_cura; /* axes left out: CuraEngine's rules give more support than given */
    struct vec3 ups[DIRSEARCH_DIRS_MAX];
    double model_g[DIRSEARCH_DIRS_MAX]; /* each direction's result, by the model */
    double print_s[DIRSEARCH_DIRS_MAX]; /* and its estimated print seconds */
    bool shape_changed[DIRSEARCH_DIRS_MAX];
    /* each direction's shape step, for the reports: the model's grams of the
       direction before its reshape, why its shape was kept (NULL: changed),
       its iterations and the iterates refused (surfopt_result) */
    struct dirsearch_step {
        double start_g;
        const char *unchanged_why;
        int iters;
        uint32_t rejected, folded, halved, frozen;
    } steps[DIRSEARCH_DIRS_MAX]; /* an axis's: start_g its grams, iters 0 */
    /* wall seconds: in all, the orientation search, the input's model and
       time, each direction's shape step and cost, the axes' costs, the
       peers' check */
    double seconds, orient_s, input_s, shape_s[DIRSEARCH_K_MAX], axes_s, check_s;
    struct dirsearch_stages stages;
};

/*
 * Search m (not modified).  res is filled (release with
 * dirsearch_result_release).  Errors: those of orient_find,
 * surfopt_optimize and printtime_eval (SF_EINVAL, SF_ENOMEM, SF_ECANCELED),
 * SF_EINVAL naming the field for a bad policy.
 */
int dirsearch_surface(const struct mesh *m, const struct dirsearch_params *p,
                      struct dirsearch_result *res, struct sf_err *err);
void dirsearch_result_release(struct dirsearch_result *res);

/*
 * The search's choice among n results c (reshaped[i]: shape changed):
 * the least printtime_value_s among those that may replace the input in
 * (no more support, no slower unless pol->material_first), else the least
 * value (*ok says which); between results whose print seconds are within
 * pol->min_gain of each other (the estimate's noise) the one with less
 * support.  A reshaped winner gives way to the best result
 * of unchanged shape unless it is worth it against that (printtime_worth),
 * as a reshape must be worth it against its own orientation (surfopt.h), or
 * faster beyond min_gain with support within the noise of that one's: a
 * flat lid bent into a shallow roof saved the model 0.01 g over the lid
 * turned over and printed 33 % slower in PrusaSlicer (mech lid_down).
 * Returns the index (n >= 1).
 */
int dirsearch_pick(const struct printtime_policy *pol, const struct printtime_cost *in,
                   const struct printtime_cost *c, const bool *reshaped, int n, bool *ok);

#endif
