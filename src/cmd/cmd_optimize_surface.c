/*
 * cmd_optimize_surface.c - `slimfarm optimize PART -o OUT --method surface`:
 * orientation-fused surface shape optimization (Jayakody et al., see
 * src/geom/surfopt.h).  cmd_optimize.c hands `--method surface` here; the
 * report has the support metrics as given, after the orientation step
 * alone and after the shape step, the deviation and the risky faces per
 * iteration.  With --search-direction K the shape step runs inside the
 * direction search (dirsearch.h), weighed by print time and support grams
 * (printtime.h: --gram-seconds, --material-first); the JSON's "search"
 * object has both figures as given and as returned and the seconds of each
 * stage.
 */
#include <getopt.h>
#include <jansson.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../geom/dirsearch.h"
#include "../geom/surfopt.h"
#include "cmd.h"
#include "cmdmesh.h"
#include "cmdreport.h"

static void
progress(void *ud, const struct surfopt_progress *pr)
{
    (void)ud;
    cmd_progress("surface", (double)pr->round * pr->max_iters + pr->iter,
                 (double)pr->n_rounds * pr->max_iters);
}

static int
report_json(const char *in, const char *out, const struct surfopt_params *p,
            const struct surfopt_result *r, json_t *search)
{
    json_t *o = json_pack(
        "{s:s, s:s, s:s, s:f, s:o, s:o, s:o, s:o, s:{s:f, s:f, s:f, s:f}, s:b, s:i, s:i, s:i, "
        "s:{s:i, s:i}, s:{s:f, s:f, s:f, s:f, s:f, s:f, s:f, s:f}, s:{s:f, s:f}}",
        "file", in, "output", out, "method", "surface", "angle_deg", p->angle_deg, "input",
        cmd_metrics_json(&r->input), "oriented", cmd_metrics_json(&r->oriented), "after",
        cmd_metrics_json(&r->after), "risky_per_iteration", cmd_curve_json(r->curve, r->n_curve),
        "deviation", "mndr", r->dev.mndr, "andr", r->dev.andr, "max_mm", r->dev.max_mm, "mean_mm",
        r->dev.mean_mm, "shape_changed", r->shape_changed, "rounds", (json_int_t)r->n_rounds,
        "iterations", (json_int_t)r->n_iters, "rejected", (json_int_t)r->n_rejected,
        "self_intersections", "input", (json_int_t)r->selfx_input, "output",
        (json_int_t)r->selfx_out, "seconds", "saliency", r->saliency_s, "orient", r->orient_s,
        "factor", r->factor_s, "iterate", r->iterate_s, "check", r->check_s, "total", r->total_s,
        "self_intersection", r->selfx_s, "support_model", r->model_s, "model_support_g", "oriented",
        r->model_oriented_g, "after", r->model_after_g);
    if (o && r->unchanged_why)
        json_object_set_new(o, "unchanged_why", json_string(r->unchanged_why));
    if (o && search)
        json_object_set_new(o, "search", search);
    else
        json_decref(search);
    return cmd_put_json("optimize", o);
}

static void
report_text(const char *in, const char *out, const struct surfopt_result *r)
{
    printf("%s -> %s: surface optimization, %d round%s, %d iterations, %.2f s (saliency %.2f, "
           "orientation %.2f, factor %.2f, iterations %.2f, checks %.2f; self-intersection "
           "%.2f, support model %.2f)\n",
           in, out, r->n_rounds, r->n_rounds == 1 ? "" : "s", r->n_iters, r->total_s, r->saliency_s,
           r->orient_s, r->factor_s, r->iterate_s, r->check_s, r->selfx_s, r->model_s);
    cmd_print_metrics("as given", &r->input);
    cmd_print_metrics("oriented", &r->oriented);
    cmd_print_metrics("after", &r->after);
    if (r->shape_changed)
        printf("  deviation MNDR %.2f %% ANDR %.2f %% (max %.2f mm, mean %.2f mm)\n",
               100 * r->dev.mndr, 100 * r->dev.andr, r->dev.max_mm, r->dev.mean_mm);
    else
        printf("  shape kept: %s\n", r->unchanged_why ? r->unchanged_why : "?");
    printf("  rejected %u; self-intersecting edges %d -> %d\n", r->n_rejected, r->selfx_input,
           r->selfx_out);
    cmd_print_curve(r->curve, r->n_curve);
}

/* The direction search's options. */
struct search_opts {
    int k;         /* > 0: shape inside the direction search */
    double gram_s; /* --gram-seconds */
    bool material_first;
    double min_gain; /* --min-gain as a share, < 0 when not given */
};

/* The options into p, out, json and so: 0, or 2 (a usage error, message printed). */
static int
parse_opts(int argc, char **argv, struct surfopt_params *p, const char **out, bool *json,
           struct search_opts *so)
{
    static const struct option opts[] = { { "output", required_argument, NULL, 'o' },
                                          { "method", required_argument, NULL, 'm' },
                                          { "angle", required_argument, NULL, 'a' },
                                          { "margin", required_argument, NULL, 'g' },
                                          { "max-mndr", required_argument, NULL, 'M' },
                                          { "max-andr", required_argument, NULL, 'A' },
                                          { "fix-bottom", required_argument, NULL, 'f' },
                                          { "iterations", required_argument, NULL, 'i' },
                                          { "rounds", required_argument, NULL, 'r' },
                                          { "saliency", required_argument, NULL, 's' },
                                          { "detail", required_argument, NULL, 'd' },
                                          { "min-gain", required_argument, NULL, 'G' },
                                          { "no-orient", no_argument, NULL, 'n' },
                                          { "search-direction", required_argument, NULL, 'S' },
                                          { "gram-seconds", required_argument, NULL, 'W' },
                                          { "material-first", no_argument, NULL, 'F' },
                                          { "json", no_argument, NULL, 'j' },
                                          { NULL, 0, NULL, 0 } };
    const struct cmd_num nums[] = {
        { 'a', "angle", 0, 89, "degrees in [0, 89]", &p->angle_deg, NULL, 0 },
        { 'g', "margin", 0, 45, "degrees in [0, 45]", &p->margin_deg, NULL, 0 },
        { 'M', "max-mndr", 0.01, 100, "a percentage", &p->max_mndr, NULL, 100 },
        { 'A', "max-andr", 0.01, 100, "a percentage", &p->max_andr, NULL, 100 },
        { 'f', "fix-bottom", 0, 1e4, "mm", &p->fix_bottom_mm, NULL, 0 },
        { 'i', "iterations", 1, SURFOPT_CURVE_MAX - 2, "a count", NULL, &p->max_iters, 0 },
        { 'r', "rounds", 1, 16, "a count in [1, 16]", NULL, &p->rounds, 0 },
        { 's', "saliency", 0, 1, "a share in [0, 1]", &p->saliency, NULL, 0 },
        { 'd', "detail", 0, 1e3, "a weight in [0, 1000]", &p->beta, NULL, 0 },
        { 'G', "min-gain", 0, 99, "a percentage in [0, 99]", &so->min_gain, NULL, 100 },
        { 'S', "search-direction", 1, DIRSEARCH_K_MAX, "a count of directions in [1, 5]", NULL,
          &so->k, 0 },
        { 'W', "gram-seconds", 0, 1e6, "seconds in [0, 1000000]", &so->gram_s, NULL, 0 },
    };
    int c;
    optind = 1;
    while ((c = cmd_getopt("optimize", argc, argv, "o:", opts, nums,
                           (int)(sizeof(nums) / sizeof(nums[0])))) != -1) {
        switch (c) {
        case 'o':
            *out = optarg;
            break;
        case 'm':
            break; /* "surface": how we got here */
        case 'n':
            p->orient = false;
            break;
        case 'j':
            *json = true;
            break;
        case 'F':
            so->material_first = true;
            break;
        default:
            return cmd_opt_error(c, CMD_OPTIMIZE_SURFACE_USAGE);
        }
    }
    if (optind != argc - 1 || !*out)
        return cmd_usage(CMD_OPTIMIZE_SURFACE_USAGE);
    if (so->min_gain >= 0)
        p->min_gain = so->min_gain;
    return 0;
}

/* The direction search's figures and stage seconds, for the JSON report. */
static json_t *
search_json(const struct dirsearch_result *ds)
{
    json_t *shape = json_array(), *dirs = json_array();
    for (int i = 0; i < ds->n_tried + ds->n_axes; i++) {
        if (i < ds->n_tried)
            json_array_append_new(shape, json_real(ds->shape_s[i]));
        const struct dirsearch_step *st = &ds->steps[i];
        json_t *d =
            json_pack("{s:[f, f, f], s:f, s:f, s:b, s:f, s:i, s:i, s:i, s:i, s:i}", "up",
                      ds->ups[i].x, ds->ups[i].y, ds->ups[i].z, "model_support_g", ds->model_g[i],
                      "print_s", ds->print_s[i], "shape_changed", ds->shape_changed[i],
                      "start_model_g", st->start_g, "iterations", (json_int_t)st->iters, "rejected",
                      (json_int_t)st->rejected, "folded", (json_int_t)st->folded, "halved",
                      (json_int_t)st->halved, "frozen", (json_int_t)st->frozen);
        if (st->unchanged_why)
            json_object_set_new(d, "unchanged_why", json_string(st->unchanged_why));
        json_object_set_new(d, "axis", json_boolean(i >= ds->n_tried));
        json_array_append_new(dirs, d);
    }
    const struct dirsearch_stages *st = &ds->stages;
    json_t *stages =
        json_pack("{s:f, s:f, s:f, s:f, s:f, s:f, s:f}", "orientation", st->orient_s, "saliency",
                  st->saliency_s, "surface", st->surface_s, "self_intersection", st->selfx_s,
                  "support_model", st->model_s, "print_time", st->print_s, "other", st->other_s);
    return json_pack("{s:o, s:i, s:b, s:{s:f, s:f}, s:{s:f, s:f}, s:{s:f, s:f, s:f, s:o, s:f, s:f, "
                     "s:o}}",
                     "directions", dirs, "axes_left_out_cura", (json_int_t)ds->n_axes_cura,
                     "kept_input", ds->kept_input, "input", "model_support_g",
                     ds->input_cost.support_g, "print_s", ds->input_cost.print_s, "result",
                     "model_support_g", ds->cost.support_g, "print_s", ds->cost.print_s, "seconds",
                     "total", ds->seconds, "orient", ds->orient_s, "input", ds->input_s, "shape",
                     shape, "axes", ds->axes_s, "check", ds->check_s, "stages", stages);
}

/* The direction search's lines of the text report. */
static void
print_search(const struct dirsearch_result *ds, const struct surfopt_result *r)
{
    const struct dirsearch_stages *st = &ds->stages;
    printf("direction search: %d directions reshaped, %d axes weighed, model grams as given "
           "%.2f, best %.2f, estimated print time %.0f -> %.0f s%s\n",
           ds->n_tried, ds->n_axes, ds->model_input_g, r->model_after_g, ds->input_cost.print_s,
           ds->cost.print_s, ds->kept_input ? " (input kept)" : "");
    printf("  %.2f s; by stage, summed over the directions: orientation %.2f, saliency %.2f, "
           "surface steps %.2f, self-intersection %.2f, support model %.2f, print time %.2f, "
           "other %.2f\n",
           ds->seconds, st->orient_s, st->saliency_s, st->surface_s, st->selfx_s, st->model_s,
           st->print_s, st->other_s);
}

int
cmd_optimize_surface(int argc, char **argv)
{
    struct surfopt_params p;
    surfopt_params_default(&p);
    const char *out = NULL;
    bool json = false;
    struct dirsearch_params dp;
    dirsearch_params_default(&dp);
    struct search_opts so = { .gram_s = dp.policy.gram_s, .min_gain = -1 };
    int rc = parse_opts(argc, argv, &p, &out, &json, &so);
    if (rc)
        return rc;
    if (p.margin_deg > p.angle_deg)
        p.margin_deg = p.angle_deg;
    p.progress = progress;
    struct mesh m;
    struct sf_err err;
    struct surfopt_result r;
    mesh_init(&m);
    if (!cmd_load_part("optimize", argv[optind], &m, NULL))
        return 1;
    struct dirsearch_result ds;
    json_t *sj = NULL;
    if (so.k > 0) {
        dp.k = so.k;
        dp.sp = p;
        dp.policy.gram_s = so.gram_s;
        dp.policy.material_first = so.material_first;
        if (so.min_gain >= 0)
            dp.policy.min_gain = so.min_gain; /* one threshold for the shape and the direction */
        rc = dirsearch_surface(&m, &dp, &ds, &err);
        if (rc == SF_OK) {
            r = ds.best; /* taken over: released with r */
            if (json)
                sj = search_json(&ds);
            else
                print_search(&ds, &r);
        }
    } else {
        rc = surfopt_optimize(&m, &p, &r, &err);
    }
    mesh_release(&m);
    if (rc != SF_OK) {
        fprintf(stderr, "slimfarm optimize: %s: %s\n", argv[optind], err.msg);
        return 1;
    }
    if (!cmd_save_part("optimize", &r.out, out)) {
        surfopt_result_release(&r);
        json_decref(sj);
        return 1;
    }
    int status = 0;
    if (json)
        status = report_json(argv[optind], out, &p, &r, sj);
    else
        report_text(argv[optind], out, &r);
    surfopt_result_release(&r);
    return status;
}
