/*
 * dirsearch.c - surface optimization inside the direction search (see
 * dirsearch.h).
 */
#include "dirsearch.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../base/clock.h"
#include "../base/mem.h"
#include "../base/par.h"
#include "printtime.h"
#include "supmodel.h"

void
dirsearch_params_default(struct dirsearch_params *p)
{
    memset(p, 0, sizeof(*p));
    p->k = 4;
    printtime_policy_default(&p->policy);
    printtime_params_default(&p->pt);
    orient_params_default(&p->op);
    surfopt_params_default(&p->sp);
}

void
dirsearch_result_release(struct dirsearch_result *res)
{
    surfopt_result_release(&res->best);
}

/* The input as given (+z up): the model's grams, its print seconds (part and
   support) in *c, the support's own seconds in *support_s. */
static int
input_cost(const struct mesh *m, const struct dirsearch_params *p, struct printtime_cost *c,
           double *support_s, struct dirsearch_stages *st, struct sf_err *err)
{
    struct supmodel_params mp;
    supmodel_params_steer(&mp, p->sp.angle_deg);
    struct supmodel_result mr;
    double t0 = clock_mono_s();
    int rc = supmodel_of_mesh(m, v3(0, 0, 1), &mp, &mr, err);
    double t1 = clock_mono_s();
    st->model_s += t1 - t0;
    if (rc < 0)
        return rc;
    struct printtime_result pr;
    rc = printtime_eval(m, v3(0, 0, 1), &p->pt, &pr, err);
    st->print_s += clock_mono_s() - t1;
    if (rc < 0)
        return rc;
    c->support_g = mr.grams;
    c->print_s = printtime_total_s(&p->pt, &pr, mr.time_s);
    *support_s = mr.time_s;
    return SF_OK;
}

/* A direction's result (on z = 0, +z up): its model grams and print seconds. */
static int
result_cost(const struct surfopt_result *r, const struct dirsearch_params *p,
            struct printtime_cost *c, struct sf_err *err)
{
    struct printtime_result pr;
    int rc = printtime_eval(&r->out, v3(0, 0, 1), &p->pt, &pr, err);
    if (rc < 0)
        return rc;
    c->support_g = r->model_after_g;
    c->print_s = printtime_total_s(&p->pt, &pr, r->model_after_s);
    return SF_OK;
}

/* The shape step on m turned to up; the first (best) direction is the
   orientation-fused run itself (its first orientation step finds this
   direction on the refined part), the others keep their start (sp). */
static int
shape_one(const struct mesh *m, const struct dirsearch_params *p, const struct surfopt_params *sp,
          struct vec3 up, bool first, struct surfopt_result *r, struct sf_err *err)
{
    struct mesh turned;
    mesh_init(&turned);
    int rc = mesh_copy(&turned, m, err);
    if (rc < 0)
        return rc;
    if (!first)
        orient_apply(&turned, up, 0, 0);
    rc = surfopt_optimize(&turned, first ? &p->sp : sp, r, err);
    mesh_release(&turned);
    return rc;
}

/* The directions' shape steps, one per par_for index (each writes its own
   slots; the caller picks in index order, so the answer does not depend on
   which thread ran which direction). */
struct shapes {
    const struct mesh *m;
    const struct dirsearch_params *p;
    const struct surfopt_params *sp; /* the runners-up's settings */
    const struct vec3 *ups;
    struct surfopt_result r[DIRSEARCH_K_MAX];
    struct printtime_cost c[DIRSEARCH_K_MAX];
    double seconds[DIRSEARCH_K_MAX];
    double print_s[DIRSEARCH_K_MAX]; /* of seconds: the print-time estimate */
    bool done[DIRSEARCH_K_MAX];      /* r[i] holds a result to release */
    struct sf_err err[DIRSEARCH_K_MAX];
};

static int
shape_task(void *ud, uint32_t begin, uint32_t end, int worker)
{
    struct shapes *s = ud;
    (void)worker;
    for (uint32_t i = begin; i < end; i++) {
        double t0 = clock_mono_s();
        int rc = shape_one(s->m, s->p, s->sp, s->ups[i], i == 0, &s->r[i], &s->err[i]);
        if (rc < 0)
            return rc;
        s->done[i] = true;
        double t1 = clock_mono_s();
        if ((rc = result_cost(&s->r[i], s->p, &s->c[i], &s->err[i])) < 0)
            return rc;
        s->seconds[i] = clock_mono_s() - t0;
        s->print_s[i] = clock_mono_s() - t1;
    }
    return SF_OK;
}

/* Run the shape steps of res->ups on par_for's threads (the directions are
   independent: on two cores the search takes about half the wall time).
   On failure every result is released and err says the lowest failing
   direction's error. */
static int
shape_all(const struct mesh *m, const struct dirsearch_params *p, const struct surfopt_params *sp,
          struct dirsearch_result *res, struct shapes *s, struct sf_err *err)
{
    memset(s, 0, sizeof(*s));
    *s = (struct shapes){ .m = m, .p = p, .sp = sp, .ups = res->ups };
    int rc = par_for((uint32_t)res->n_tried, 1, 0, shape_task, s);
    if (rc >= 0)
        return rc;
    for (int i = 0; i < res->n_tried; i++) {
        if (s->err[i].code < 0 && err) {
            *err = s->err[i];
            break;
        }
    }
    for (int i = 0; i < res->n_tried; i++)
        if (s->done[i])
            surfopt_result_release(&s->r[i]);
    return rc;
}

/* Add direction i's stages to st (the search's own are there already). */
static void
stages_add(struct dirsearch_stages *st, const struct shapes *s, int i)
{
    const struct surfopt_result *r = &s->r[i];
    double known = r->orient_s + r->saliency_s + r->factor_s + r->iterate_s + r->selfx_s +
                   r->model_s + s->print_s[i];
    st->orient_s += r->orient_s;
    st->saliency_s += r->saliency_s;
    st->surface_s += r->factor_s + r->iterate_s;
    st->selfx_s += r->selfx_s;
    st->model_s += r->model_s;
    st->print_s += s->print_s[i];
    st->other_s += fmax(0, s->seconds[i] - known);
}

/* May c replace the input: no more support, no slower unless asked. */
static bool
may_replace(const struct printtime_policy *pol, const struct printtime_cost *in,
            const struct printtime_cost *c)
{
    return c->support_g <= in->support_g && (pol->material_first || c->print_s <= in->print_s);
}

/* Is a better than b?  Print times within min_gain of each other are the
   estimate's noise: there the one with less support is; else the lesser
   value.  (shared elephant: two directions 11 s apart of 3740, the value
   took the one with 0.07 g more by the model, 0.15 g more in PrusaSlicer
   and no faster there.) */
static bool
better(const struct printtime_policy *pol, const struct printtime_cost *a,
       const struct printtime_cost *b)
{
    if (fabs(a->print_s - b->print_s) <= pol->min_gain * fmax(a->print_s, b->print_s))
        return a->support_g < b->support_g;
    return printtime_value_s(pol, a) < printtime_value_s(pol, b);
}

/* Does the reshaped r beat the unchanged-shape u by more than the noise:
   worth it against u (printtime_worth), or faster beyond min_gain (the
   estimate's noise between results, as better() takes it) with support
   within the peers' noise of u's (min_gain of it plus min_gain_g)?  mech
   box_upside: turned over it printed 3.4 % slower in PrusaSlicer than as
   given, tilted 5 degrees and reshaped 3.7 % faster for 0.03 g of support;
   the estimate put the tilt 3.6 % ahead of the turn, but its 12 mg of
   support by the model, more than the turn's none, gave the turn the win. */
static bool
reshape_pays(const struct printtime_policy *pol, const struct printtime_cost *u,
             const struct printtime_cost *r)
{
    if (printtime_worth(pol, u, r))
        return true;
    return r->print_s < (1 - pol->min_gain) * u->print_s &&
           r->support_g <= u->support_g * (1 + pol->min_gain) + pol->min_gain_g;
}

int
dirsearch_pick(const struct printtime_policy *pol, const struct printtime_cost *in,
               const struct printtime_cost *c, const bool *reshaped, int n, bool *ok)
{
    int best = -1, plain = -1;
    *ok = false;
    for (int i = 0; i < n; i++) {
        bool may = may_replace(pol, in, &c[i]);
        if (best < 0 || (may && !*ok) || (may == *ok && better(pol, &c[i], &c[best]))) {
            best = i;
            *ok = may;
        }
        if (may && !reshaped[i] && (plain < 0 || better(pol, &c[i], &c[plain])))
            plain = i;
    }
    if (*ok && plain >= 0 && reshaped[best] && !reshape_pays(pol, &c[plain], &c[best]))
        best = plain;
    return best;
}

/* The axis directions of the input's frame weighed unreshaped (issue 36:
   CAD parts come axis-aligned, and a designed face is often a good base;
   the orientation search ranks its K by support alone and left out scad
   example008 -y, 12.0 g / 3.01 h in PrusaSlicer against the search's
   17.9 g / 3.55 h, and mech shelf +x, 0.72 g against 8.75 g).  +z is the
   input as given, which the keep rule weighs already.  An axis CuraEngine's
   rules give more support than the input is left out: the orientation
   search's ray measure counts every ceiling, as CuraEngine supports
   bridges, and the axes skip it (mech enclosure turned over: PrusaSlicer
   3.85 -> 3.84 g, CuraEngine 1.41 -> 30.8 g, its cavity's ceiling). */
static const struct vec3 axis_dirs[DIRSEARCH_AXES] = {
    { 1, 0, 0 }, { -1, 0, 0 }, { 0, 1, 0 }, { 0, -1, 0 }, { 0, 0, -1 },
};

/* An axis within about 5 degrees of a reshaped direction is that direction. */
#define AXIS_SAME_COS 0.996

/* The axes' costs, one per par_for index (each writes its own slots). */
struct axes {
    const struct mesh *m;
    const struct dirsearch_params *p;
    int n;
    struct vec3 up[DIRSEARCH_AXES];
    struct printtime_cost c[DIRSEARCH_AXES];
    double support_s[DIRSEARCH_AXES];  /* the model's support seconds */
    double cura_g[DIRSEARCH_AXES + 1]; /* CuraEngine's rules; [n]: the input's */
    double seconds[DIRSEARCH_AXES + 1], model_s[DIRSEARCH_AXES + 1], print_s[DIRSEARCH_AXES + 1];
    struct sf_err err[DIRSEARCH_AXES + 1];
};

static int
axis_task(void *ud, uint32_t begin, uint32_t end, int worker)
{
    struct axes *a = ud;
    (void)worker;
    struct supmodel_params mp, cp;
    supmodel_params_steer(&mp, a->p->sp.angle_deg);
    supmodel_params_default(&cp, SUPMODEL_CURA);
    cp.angle_deg = a->p->sp.angle_deg;
    for (uint32_t i = begin; i < end; i++) {
        double t0 = clock_mono_s();
        struct vec3 up = (int)i < a->n ? a->up[i] : v3(0, 0, 1);
        struct supmodel_result mr;
        int rc = supmodel_of_mesh(a->m, up, &cp, &mr, &a->err[i]);
        a->cura_g[i] = mr.grams;
        if (rc < 0 || (int)i == a->n) {
            a->model_s[i] = a->seconds[i] = clock_mono_s() - t0;
            if (rc < 0)
                return rc;
            continue;
        }
        rc = supmodel_of_mesh(a->m, up, &mp, &mr, &a->err[i]);
        double t1 = clock_mono_s();
        if (rc < 0)
            return rc;
        struct printtime_result pr;
        if ((rc = printtime_eval(a->m, a->up[i], &a->p->pt, &pr, &a->err[i])) < 0)
            return rc;
        double t2 = clock_mono_s();
        a->c[i].support_g = mr.grams;
        a->c[i].print_s = printtime_total_s(&a->p->pt, &pr, mr.time_s);
        a->support_s[i] = mr.time_s;
        a->model_s[i] = t1 - t0;
        a->print_s[i] = t2 - t1;
        a->seconds[i] = t2 - t0;
    }
    return SF_OK;
}

/* Cost the axes not within AXIS_SAME_COS of res's reshaped directions (the
   model's grams and the print-time estimate, as the reshaped results are
   costed) and list those CuraEngine's rules give no more support than the
   input after those in res (n_axes, ups, model_g, print_s, steps; the
   others in n_axes_cura; axes_s, stages); a holds the listed ones.  A part
   that is no closed solid (!solid) keeps its up, as its reshaped ones do. */
static int
axes_cost(const struct mesh *m, const struct dirsearch_params *p, bool solid,
          struct dirsearch_result *res, struct axes *a, struct sf_err *err)
{
    memset(a, 0, sizeof(*a));
    a->m = m;
    a->p = p;
    for (int j = 0; solid && j < DIRSEARCH_AXES; j++) {
        bool same = false;
        for (int i = 0; i < res->n_tried; i++)
            same = same || v3_dot(axis_dirs[j], v3_normalize(res->ups[i])) > AXIS_SAME_COS;
        if (!same)
            a->up[a->n++] = axis_dirs[j];
    }
    int rc = a->n ? par_for((uint32_t)a->n + 1, 1, 0, axis_task, a) : SF_OK;
    if (rc < 0) {
        for (int i = 0; i <= a->n; i++) {
            if (a->err[i].code < 0 && err) {
                *err = a->err[i];
                break;
            }
        }
        return rc;
    }
    for (int i = 0; i <= a->n; i++) {
        res->axes_s += a->seconds[i];
        res->stages.model_s += a->model_s[i];
        res->stages.print_s += a->print_s[i];
        res->stages.other_s += fmax(0, a->seconds[i] - a->model_s[i] - a->print_s[i]);
    }
    int n = 0;
    for (int i = 0; i < a->n; i++) {
        if (a->cura_g[i] > a->cura_g[a->n]) {
            res->n_axes_cura++;
            continue;
        }
        a->up[n] = a->up[i];
        a->c[n] = a->c[i];
        a->support_s[n] = a->support_s[i];
        int k = res->n_tried + n++;
        res->ups[k] = a->up[i];
        res->model_g[k] = a->c[i].support_g;
        res->print_s[k] = a->c[i].print_s;
        res->shape_changed[k] = false;
        res->steps[k] = (struct dirsearch_step){ .start_g = a->c[i].support_g,
                                                 .unchanged_why = "an axis direction of the "
                                                                  "input's frame, not reshaped" };
    }
    res->n_axes = a->n = n;
    return SF_OK;
}

/* The axis a->up[i] won: m turned to it, unreshaped, in res->best. */
static int
axis_take(const struct mesh *m, const struct axes *a, int i, struct dirsearch_result *res,
          struct sf_err *err)
{
    double t0 = clock_mono_s();
    memset(&res->best, 0, sizeof(res->best));
    mesh_init(&res->best.out);
    int rc = mesh_copy(&res->best.out, m, err);
    if (rc < 0)
        return rc;
    orient_apply(&res->best.out, a->up[i], 0, 0);
    res->best.model_oriented_g = res->best.model_after_g = a->c[i].support_g;
    res->best.model_after_s = a->support_s[i];
    res->best.unchanged_why = "an axis direction of the input's frame, turned up unreshaped, is "
                              "worth more than every reshaped direction";
    double dt = clock_mono_s() - t0;
    res->axes_s += dt;
    res->stages.other_s += dt;
    return SF_OK;
}

int
dirsearch_surface(const struct mesh *m, const struct dirsearch_params *p,
                  struct dirsearch_result *res, struct sf_err *err)
{
    memset(res, 0, sizeof(*res));
    mesh_init(&res->best.out);
    if (p->k < 1 || p->k > DIRSEARCH_K_MAX)
        return sf_err_set(err, SF_EINVAL, "direction search: k %d outside [1, %d]", p->k,
                          DIRSEARCH_K_MAX);
    int rc = printtime_policy_check(&p->policy, err);
    if (rc < 0)
        return rc;
    double t0 = clock_mono_s(), t1;
    struct orient_params op = p->op;
    op.angle_deg = p->sp.angle_deg;
    struct orient_result found;
    if ((rc = orient_find(m, &op, &found, err)) < 0)
        return rc;
    res->orient_s = (t1 = clock_mono_s()) - t0;
    res->stages.orient_s = res->orient_s;
    double in_support_s;
    if ((rc = input_cost(m, p, &res->input_cost, &in_support_s, &res->stages, err)) < 0)
        return rc;
    res->model_input_g = res->input_cost.support_g;
    res->input_s = clock_mono_s() - t1;
    /* the best direction, then the runners-up (distinct by construction);
       a part that is no closed solid keeps its up (orient.h: its ray counts
       are guesses; mech-holes-shark turned by the model's 14.4 -> 8.7 g
       took PrusaSlicer 3.1 -> 41.6 g) */
    res->ups[res->n_tried++] = found.best.up;
    for (int i = 0; !found.not_solid && i < found.n_runners && res->n_tried < p->k; i++)
        res->ups[res->n_tried++] = found.runners[i].up;
    struct surfopt_params sp = p->sp;
    sp.keep_start_up = true; /* each start keeps its direction for its first round */
    struct shapes *sh = mem_alloc(sizeof(*sh));
    if (!sh)
        return sf_err_set(err, SF_ENOMEM, "direction search: out of memory");
    if ((rc = shape_all(m, p, &sp, res, sh, err)) < 0) {
        free(sh);
        return rc;
    }
    for (int i = 0; i < res->n_tried; i++) {
        res->model_g[i] = sh->c[i].support_g;
        res->print_s[i] = sh->c[i].print_s;
        res->shape_changed[i] = sh->r[i].shape_changed;
        const struct surfopt_result *r = &sh->r[i];
        res->steps[i] = (struct dirsearch_step){ r->model_oriented_g, r->unchanged_why, r->n_iters,
                                                 r->n_rejected,       r->n_folded,      r->n_halved,
                                                 r->n_frozen };
        res->shape_s[i] = sh->seconds[i];
        stages_add(&res->stages, sh, i);
    }
    struct axes *ax = mem_alloc(sizeof(*ax));
    if (!ax || (rc = axes_cost(m, p, !found.not_solid, res, ax, err)) < 0) {
        if (!ax)
            rc = sf_err_set(err, SF_ENOMEM, "direction search: out of memory");
        for (int i = 0; i < res->n_tried; i++)
            surfopt_result_release(&sh->r[i]);
        free(ax);
        free(sh);
        return rc;
    }
    struct printtime_cost all[DIRSEARCH_DIRS_MAX];
    for (int i = 0; i < res->n_tried + res->n_axes; i++)
        all[i] = i < res->n_tried ? sh->c[i] : ax->c[i - res->n_tried];
    bool best_ok;
    int best = dirsearch_pick(&p->policy, &res->input_cost, all, res->shape_changed,
                              res->n_tried + res->n_axes, &best_ok);
    for (int i = 0; i < res->n_tried; i++)
        if (i != best)
            surfopt_result_release(&sh->r[i]);
    if (best < res->n_tried)
        res->best = sh->r[best];
    else
        rc = axis_take(m, ax, best - res->n_tried, res, err);
    res->cost = all[best];
    free(ax);
    free(sh);
    if (rc < 0) {
        dirsearch_result_release(res);
        return rc;
    }
    res->up = res->ups[best];
    t1 = clock_mono_s();
    bool gain = printtime_worth(&p->policy, &res->input_cost, &res->cost), rises = false;
    if (gain &&
        (rc = supmodel_peers_rise(m, &res->best.out, p->sp.angle_deg, &rises, NULL, err)) < 0) {
        dirsearch_result_release(res);
        return rc;
    }
    res->check_s = clock_mono_s() - t1;
    res->stages.model_s += res->check_s;
    if (!gain || rises) {
        /* not worth it: the input as given, resting on z = 0 */
        surfopt_result_release(&res->best);
        memset(&res->best, 0, sizeof(res->best));
        mesh_init(&res->best.out);
        if ((rc = mesh_copy(&res->best.out, m, err)) < 0)
            return rc;
        orient_apply(&res->best.out, v3(0, 0, 1), 0, 0);
        res->best.model_oriented_g = res->best.model_after_g = res->model_input_g;
        res->best.model_after_s = in_support_s;
        res->best.unchanged_why =
            rises ? "the best direction's result of this open shell needs more support than "
                    "the part as given in PrusaSlicer or CuraEngine, which drop what its open "
                    "rims leave open"
            : !best_ok
                ? "every direction's result needs more support or prints slower than the part "
                  "as given"
                : "no direction's result saves min_gain of the input's support grams (plus "
                  "min_gain_g) or of its print seconds";
        res->up = v3(0, 0, 1);
        res->kept_input = true;
        res->cost = res->input_cost;
    }
    res->seconds = clock_mono_s() - t0;
    return SF_OK;
}
