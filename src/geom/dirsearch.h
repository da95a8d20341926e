/*
 * dirsearch.h - shape inside the direction search (Hu 2015's print-direction
 * search, Jayakody 2025's alternation of orientation and shape): the
 * orientation search's best K distinct directions are each turned up and
 * surface-optimized (surfopt.h, one geometry round, no re-orientation),
 * and the layer-based support model (supmodel.h) picks the winner.  The
 * input is returned unchanged unless the winner's model grams are at least
 * min_gain below the input's.  A part the orientation search finds is no
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
#include "surfopt.h"

#define DIRSEARCH_K_MAX 5

struct dirsearch_params {
    int k;                    /* directions reshaped (4; at most DIRSEARCH_K_MAX) */
    double min_gain;          /* keep the input unless the model saves this share (0.05) */
    struct orient_params op;  /* the direction search (angle taken from sp.angle_deg) */
    struct surfopt_params sp; /* the shape step (its own orientation step is turned off) */
};

void dirsearch_params_default(struct dirsearch_params *p);

struct dirsearch_result {
    struct surfopt_result best; /* the winner (best.out on z = 0); the input when kept */
    struct vec3 up;             /* its up-direction in the input frame */
    bool kept_input;            /* no direction saved min_gain by the model */
    double model_input_g;       /* the model's grams for the input as given */
    int n_tried;
    struct vec3 ups[DIRSEARCH_K_MAX];
    double model_g[DIRSEARCH_K_MAX]; /* each direction's result, by the model */
    bool shape_changed[DIRSEARCH_K_MAX];
    double seconds;
};

/*
 * Search m (not modified).  res is filled (release with
 * dirsearch_result_release).  Errors: those of orient_find and
 * surfopt_optimize (SF_EINVAL, SF_ENOMEM, SF_ECANCELED).
 */
int dirsearch_surface(const struct mesh *m, const struct dirsearch_params *p,
                      struct dirsearch_result *res, struct sf_err *err);
void dirsearch_result_release(struct dirsearch_result *res);

#endif
