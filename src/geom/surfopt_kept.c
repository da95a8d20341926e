/*
 * surfopt_kept.c - the surface optimizer's result among its kept iterates
 * (see surfopt_int.h).
 */
#include <string.h>

#include "../base/clock.h"
#include "supmodel.h"
#include "surfopt_int.h"

/* Why the result is the orientation alone (choose_kept). */
static const char *
unchanged_why(const struct surfopt_result *res, int n_keep, int n_selfx, int n_peer_rise,
              bool small_gain)
{
    return n_keep == 0 && res->n_folded > 0
               ? "every iterate that lowered the risky faces within the "
                 "deviation limits folded the surface onto itself (new "
                 "self-intersections)"
           : n_keep == 0       ? "no iterate lowered the risky faces within the deviation "
                                 "limits"
           : n_selfx == n_keep ? "every kept shape adds self-intersections"
           : n_peer_rise > 0   ? "the kept shapes of this open shell need more support than "
                                 "the part as given in PrusaSlicer or CuraEngine, which drop "
                                 "what its open rims leave open"
           : res->model_oriented_g <= 0 ? "the oriented part needs no support by the model"
           : small_gain                 ? "no kept shape saves min_gain of the oriented "
                                          "part's model grams"
                        : "no kept shape needs fewer model grams than the oriented part";
}

int
surfopt_choose_kept(const struct mesh *m, struct mesh *cur, double oriented_s,
                    const struct snapshot *keep, int n_keep, struct selfx_ref *sxr,
                    const struct surfopt_params *p, struct surfopt_result *res,
                    struct support_metrics *sm, struct sf_err *err)
{
    uint32_t n = cur->n_verts;
    int rc;
    struct supmodel_params mp;
    supmodel_params_steer(&mp, p->angle_deg);
    struct supmodel_result mr;
    int best_k = -1, n_selfx = 0, n_peer_rise = 0;
    double best_g = res->model_oriented_g, best_s = oriented_s;
    for (int k = n_keep - 1; k >= 0; k--) {
        memcpy(cur->v, keep[k].v, (size_t)n * sizeof(struct vec3));
        /* a check of the same positions says the same: only the iterates an
           orientation step moved since (float casts) are checked again */
        double t0 = clock_mono_s();
        rc = keep[k].checked ? 0 : selfx_ref_count(sxr, cur, NULL, err);
        res->selfx_s += clock_mono_s() - t0;
        if (rc < 0)
            return rc;
        if (rc > 0) {
            res->n_rejected++;
            n_selfx++;
            continue;
        }
        t0 = clock_mono_s();
        rc = supmodel_of_mesh(cur, v3(0, 0, 1), &mp, &mr, err);
        /* nor may it cost the part as given more in a slicer that drops what
           open rims leave open (supmodel_peers_rise; closed parts: no) */
        bool rises = false;
        if (rc >= 0 && mr.grams < best_g)
            rc = supmodel_peers_rise(m, cur, p->angle_deg, &rises, NULL, err);
        res->model_s += clock_mono_s() - t0;
        if (rc < 0)
            return rc;
        if (mr.grams < best_g && !rises) {
            best_g = mr.grams;
            best_s = mr.time_s;
            best_k = k;
        } else {
            res->n_rejected++;
            n_peer_rise += rises;
        }
    }
    bool small_gain =
        best_k >= 0 && !(best_g <= (1 - p->min_gain) * res->model_oriented_g - p->min_gain_g);
    if (small_gain)
        best_k = -1;
    if (best_k >= 0) {
        memcpy(cur->v, keep[best_k].v, (size_t)n * sizeof(struct vec3));
        double t0 = clock_mono_s();
        rc = selfx_count(cur, err);
        res->selfx_s += clock_mono_s() - t0;
        if (rc < 0)
            return rc;
        res->selfx_out = rc;
        if ((rc = surfopt_ray_metrics(cur, p->angle_deg, sm, err)) < 0)
            return rc;
        res->shape_changed = true;
        res->model_after_g = best_g;
        res->model_after_s = best_s;
    } else {
        res->model_after_g = res->model_oriented_g;
        res->model_after_s = oriented_s;
        res->unchanged_why = unchanged_why(res, n_keep, n_selfx, n_peer_rise, small_gain);
    }
    return SF_OK;
}
