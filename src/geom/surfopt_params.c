/*
 * surfopt_params.c - the surface optimizer's defaults and the check of its
 * parameters (surfopt.h), apart from the method itself (surfopt.c).
 */
#include <math.h>

#include "surfopt.h"
#include "surfopt_int.h"

void
surfopt_params_default(struct surfopt_params *p)
{
    memset(p, 0, sizeof(*p));
    p->angle_deg = 45;
    p->margin_deg = 5;
    p->gamma = 1;
    p->beta = 0;
    p->saliency = 0.8;
    p->max_mndr = 0.05;
    p->max_andr = 0.015;
    p->fix_bottom_mm = 2;
    p->max_iters = 100;
    p->patience = 5;
    p->rounds = 2;
    p->min_gain = 0.02;
    p->min_gain_g = 0.05;
    p->refine_tris = 10000;
    p->orient = true;
    p->anchor = 0.01;
    orient_params_default(&p->op);
}

void
surfopt_result_release(struct surfopt_result *res)
{
    mesh_release(&res->out);
}

int
surfopt_check_params(const struct surfopt_params *p, struct sf_err *err)
{
    if (!(p->angle_deg >= 0 && p->angle_deg < 90))
        return sf_err_set(err, SF_EINVAL, "angle %g: want degrees in [0, 90)", p->angle_deg);
    if (!(p->margin_deg >= 0 && p->margin_deg <= p->angle_deg))
        return sf_err_set(err, SF_EINVAL, "margin %g: want degrees in [0, angle]", p->margin_deg);
    if (!(p->gamma > 0 && p->beta >= 0 && isfinite(p->gamma) && isfinite(p->beta)))
        return sf_err_set(err, SF_EINVAL, "weights gamma %g, beta %g: want gamma > 0, beta >= 0",
                          p->gamma, p->beta);
    if (!(p->anchor >= 0 && isfinite(p->anchor)))
        return sf_err_set(err, SF_EINVAL, "anchor weight %g: want >= 0", p->anchor);
    if (!(p->saliency >= 0 && p->saliency <= 1))
        return sf_err_set(err, SF_EINVAL, "saliency %g: want a share in [0, 1]", p->saliency);
    if (!(p->max_mndr > 0 && p->max_andr > 0))
        return sf_err_set(err, SF_EINVAL, "deviation limits must be positive");
    if (!(p->min_gain >= 0 && p->min_gain < 1))
        return sf_err_set(err, SF_EINVAL, "min-gain %g: want a share in [0, 1)", p->min_gain);
    if (!(p->min_gain_g >= 0 && p->min_gain_g <= 1000))
        return sf_err_set(err, SF_EINVAL, "min_gain_g %g: want grams in [0, 1000]", p->min_gain_g);
    if (!(p->fix_bottom_mm >= 0))
        return sf_err_set(err, SF_EINVAL, "fix-bottom %g: want mm >= 0", p->fix_bottom_mm);
    if (p->max_iters < 1 || p->max_iters >= SURFOPT_CURVE_MAX || p->patience < 1 || p->rounds < 1 ||
        p->rounds > 16)
        return sf_err_set(err, SF_EINVAL, "iterations %d, patience %d, rounds %d out of range",
                          p->max_iters, p->patience, p->rounds);
    return SF_OK;
}
