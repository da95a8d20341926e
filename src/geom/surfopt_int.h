/*
 * surfopt_int.h - internal to the surface optimizer (surfopt*.c), not a
 * contract for anyone else: the kept iterates and the choice among them
 * (surfopt_kept.c).
 *
 * Pure functions on the caller's data: thread-safe.
 */
#ifndef SF_GEOM_SURFOPT_INT_H
#define SF_GEOM_SURFOPT_INT_H

#include <stdbool.h>

#include "../base/err.h"
#include "../mesh/mesh.h"
#include "measure.h"
#include "selfx.h"
#include "surfopt.h"

/* An improving iterate kept as a fallback for the final checks. */
struct snapshot {
    struct vec3 *v;
    double proxy;
    bool checked; /* found to add no self-intersection where it stands (not moved since) */
};

/* Ray-cast support metrics of m with +z up. */
int surfopt_ray_metrics(const struct mesh *m, double angle_deg, struct support_metrics *out,
                        struct sf_err *err);

/*
 * The result: of the kept shapes that add no self-intersection, the one the
 * layer-based support model (supmodel.h, PrusaSlicer's rules) gives the
 * fewest grams, if that saves min_gain of what the orientation alone needs
 * and min_gain_g more;
 * else the orientation alone.  The ray-cast volume steered the iterations;
 * the model, which follows what a slicer prints, decides: the oriented
 * part's model grams are res->model_oriented_g (the caller's), its
 * seconds oriented_s.  cur (scratch, n positions) ends as the chosen shape
 * with its metrics in *sm when res->shape_changed.
 */
int surfopt_choose_kept(const struct mesh *m, struct mesh *cur, double oriented_s,
                        const struct snapshot *keep, int n_keep, struct selfx_ref *sxr,
                        const struct surfopt_params *p, struct surfopt_result *res,
                        struct support_metrics *sm, struct sf_err *err);

/* SF_OK when p's values are in range, else SF_EINVAL naming the field (surfopt_params.c). */
int surfopt_check_params(const struct surfopt_params *p, struct sf_err *err);

#endif
