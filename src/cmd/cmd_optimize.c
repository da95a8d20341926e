/*
 * cmd_optimize.c - `slimfarm optimize PART -o OUT --method volumetric`
 * (`--method surface` is cmd_optimize_surface.c):
 * slim a part's support by volumetric ARAP deformation (Hu 2015, see
 * src/geom/slim.h), write the result and report the risky faces per
 * iteration, the deviation (MNDR, ANDR) and the support metrics before and
 * after.  Progress goes to stderr when it is a terminal.
 */
#include <getopt.h>
#include <jansson.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"
#include "../geom/slim.h"
#include "cmd.h"
#include "cmdmesh.h"
#include "cmdreport.h"

static const char usage_line[] =
    "optimize PART -o OUT --method volumetric [--angle DEG] [--beta DEG] [--max-mndr P] "
    "[--max-andr P] [--fix-bottom MM] [--fix-box X0,Y0,Z0,X1,Y1,Z1] [--max-tet-verts N] "
    "[--iterations N] [--search-direction] [--no-keep-volume] [--min-gain P] [--json]\n"
    "       slimfarm " CMD_OPTIMIZE_SURFACE_USAGE;

#define MAX_BOXES 16

static void
progress(void *ud, const struct slim_progress *pr)
{
    (void)ud;
    double done = (double)pr->dir * pr->max_iters + pr->iter;
    cmd_progress(pr->n_dirs > 1 ? "slim (directions)" : "slim", done,
                 (double)pr->n_dirs * pr->max_iters);
}

/* Parse a double in [lo, hi]; false with a message otherwise. */
static bool
parse_num(const char *opt, const char *arg, double lo, double hi, double *out)
{
    char *end;
    double v = strtod(arg, &end);
    if (*end == '%')
        end++;
    if (end == arg || *end || !(v >= lo && v <= hi)) {
        fprintf(stderr, "slimfarm optimize: %s wants a number in [%g, %g], got '%s'\n", opt, lo, hi,
                arg);
        return false;
    }
    *out = v;
    return true;
}

static int
report_json(const char *in, const char *out, const struct slim_params *p,
            const struct slim_result *r)
{
    json_t *rot = json_pack("[[fff][fff][fff]]", r->rotation.m[0][0], r->rotation.m[0][1],
                            r->rotation.m[0][2], r->rotation.m[1][0], r->rotation.m[1][1],
                            r->rotation.m[1][2], r->rotation.m[2][0], r->rotation.m[2][1],
                            r->rotation.m[2][2]);
    json_t *o = json_pack(
        "{s:s, s:s, s:s, s:f, s:o, s:o, s:o, s:{s:f, s:f, s:f, s:f}, s:{s:f, s:f}, s:f, s:i, s:i, "
        "s:f, "
        "s:i, s:o, "
        "s:{s:i, s:i, s:i}, s:{s:i, s:i, s:i}, s:f, s:f, s:{s:f, s:f}}",
        "file", in, "output", out, "method", "volumetric", "angle_deg", p->angle_deg, "before",
        cmd_metrics_json(&r->before), "after", cmd_metrics_json(&r->after), "risky_per_iteration",
        cmd_curve_json(r->curve, r->n_curve), "deviation", "mndr", r->dev.mndr, "andr", r->dev.andr,
        "max_mm", r->dev.max_mm, "mean_mm", r->dev.mean_mm, "part_volume_mm3", "before",
        r->part_volume_in_mm3, "after", r->part_volume_out_mm3, "volume_scale", r->volume_scale,
        "best_iteration", (json_int_t)r->best_iter, "beta_rounds", (json_int_t)r->n_runs,
        "beta_deg", r->beta_deg, "directions", (json_int_t)r->n_dirs, "rotation", rot, "tet_mesh",
        "vertices", (json_int_t)r->tet_verts, "tets", (json_int_t)r->tet_tets,
        "part_vertices_outside", (json_int_t)r->tet_outside, "checks", "inverted_tets",
        (json_int_t)r->n_inverted, "self_intersections_input", (json_int_t)r->selfx_input,
        "self_intersections_output", (json_int_t)r->selfx_out, "setup_s", r->setup_s, "seconds",
        r->total_s, "model_support_g", "before", r->model_before_g, "after", r->model_after_g);
    return cmd_put_json("optimize", o);
}

static void
report_text(const char *in, const char *out, const struct slim_result *r)
{
    printf("%s -> %s: volumetric slimming, %u tet vertices / %u tets, %d direction%s, %.2f s "
           "(setup %.2f s)\n",
           in, out, r->tet_verts, r->tet_tets, r->n_dirs, r->n_dirs == 1 ? "" : "s", r->total_s,
           r->setup_s);
    cmd_print_metrics("before", &r->before);
    cmd_print_metrics("after", &r->after);
    printf("  deviation MNDR %.2f %% ANDR %.2f %% (max %.2f mm, mean %.2f mm)\n", 100 * r->dev.mndr,
           100 * r->dev.andr, r->dev.max_mm, r->dev.mean_mm);
    printf("  part volume %.0f -> %.0f mm3 (%+.1f %%; uniform scale %.4f)\n", r->part_volume_in_mm3,
           r->part_volume_out_mm3,
           r->part_volume_in_mm3 > 0 ? 100 * (r->part_volume_out_mm3 / r->part_volume_in_mm3 - 1)
                                     : 0.0,
           r->volume_scale);
    printf("  kept iteration %d (beta %.0f deg, %d round%s); rejected %u; inverted tets %u; "
           "self-intersecting edges %d -> %d\n",
           r->best_iter, r->beta_deg, r->n_runs, r->n_runs == 1 ? "" : "s", r->n_rejected,
           r->n_inverted, r->selfx_input, r->selfx_out);
    cmd_print_curve(r->curve, r->n_curve);
    if (r->n_dirs > 1)
        printf("  rotation [%.3f %.3f %.3f; %.3f %.3f %.3f; %.3f %.3f %.3f]\n", r->rotation.m[0][0],
               r->rotation.m[0][1], r->rotation.m[0][2], r->rotation.m[1][0], r->rotation.m[1][1],
               r->rotation.m[1][2], r->rotation.m[2][0], r->rotation.m[2][1], r->rotation.m[2][2]);
}

/* One --fix-box X0,Y0,Z0,X1,Y1,Z1 into boxes[*n_boxes]; false with a message if it is not one
   or there are MAX_BOXES already. */
static bool
parse_box(const char *arg, struct slim_box *boxes, int *n_boxes)
{
    struct slim_box *b = &boxes[*n_boxes];
    int used = 0;
    if (*n_boxes == MAX_BOXES ||
        sscanf(arg, "%lf,%lf,%lf,%lf,%lf,%lf%n", &b->lo.x, &b->lo.y, &b->lo.z, &b->hi.x, &b->hi.y,
               &b->hi.z, &used) != 6 ||
        arg[used] || !v3_isfinite(b->lo) || !v3_isfinite(b->hi) || b->lo.x > b->hi.x ||
        b->lo.y > b->hi.y || b->lo.z > b->hi.z) {
        fprintf(stderr,
                "slimfarm optimize: --fix-box wants X0,Y0,Z0,X1,Y1,Z1 in mm with X0 <= X1 "
                "(at most %d boxes), got '%s'\n",
                MAX_BOXES, arg);
        return false;
    }
    (*n_boxes)++;
    return true;
}

/* The volumetric options into p, boxes, out and json: 0, or 2 (a usage error, message
   printed). */
static int
parse_opts(int argc, char **argv, struct slim_params *p, struct slim_box *boxes, int *n_boxes,
           const char **out, bool *json)
{
    static const struct option opts[] = { { "output", required_argument, NULL, 'o' },
                                          { "method", required_argument, NULL, 'm' },
                                          { "angle", required_argument, NULL, 'a' },
                                          { "beta", required_argument, NULL, 'b' },
                                          { "max-mndr", required_argument, NULL, 'M' },
                                          { "max-andr", required_argument, NULL, 'A' },
                                          { "fix-bottom", required_argument, NULL, 'f' },
                                          { "fix-box", required_argument, NULL, 'x' },
                                          { "max-tet-verts", required_argument, NULL, 'v' },
                                          { "iterations", required_argument, NULL, 'i' },
                                          { "search-direction", no_argument, NULL, 's' },
                                          { "no-keep-volume", no_argument, NULL, 'k' },
                                          { "min-gain", required_argument, NULL, 'g' },
                                          { "json", no_argument, NULL, 'j' },
                                          { NULL, 0, NULL, 0 } };
    const char *method = NULL;
    double v;
    int c;
    optind = 1;
    while ((c = getopt_long(argc, argv, "o:", opts, NULL)) != -1) {
        switch (c) {
        case 'o':
            *out = optarg;
            break;
        case 'm':
            method = optarg;
            break;
        case 'a':
            if (!parse_num("--angle", optarg, 0, 89, &p->angle_deg))
                return 2;
            p->margin_deg = fmin(p->margin_deg, p->angle_deg);
            break;
        case 'b':
            if (!parse_num("--beta", optarg, 0, 90, &p->beta_deg))
                return 2;
            break;
        case 'M':
            if (!parse_num("--max-mndr", optarg, 0.01, 100, &v))
                return 2;
            p->max_mndr = v / 100;
            break;
        case 'A':
            if (!parse_num("--max-andr", optarg, 0.01, 100, &v))
                return 2;
            p->max_andr = v / 100;
            break;
        case 'f':
            if (!parse_num("--fix-bottom", optarg, 0, 1e4, &p->fix_bottom_mm))
                return 2;
            break;
        case 'x':
            if (!parse_box(optarg, boxes, n_boxes))
                return 2;
            break;
        case 'v':
            if (!parse_num("--max-tet-verts", optarg, 100, 1e6, &v))
                return 2;
            p->tet.max_verts = (uint32_t)v;
            break;
        case 'i':
            if (!parse_num("--iterations", optarg, 1, SLIM_CURVE_MAX - 1, &v))
                return 2;
            p->max_iters = (int)v;
            break;
        case 's':
            p->search_direction = true;
            break;
        case 'k':
            p->keep_volume = false;
            break;
        case 'g':
            if (!parse_num("--min-gain", optarg, 0, 99, &v))
                return 2;
            p->min_gain = v / 100;
            break;
        case 'j':
            *json = true;
            break;
        default:
            return cmd_usage(usage_line);
        }
    }
    if (optind != argc - 1 || !*out || !method)
        return cmd_usage(usage_line);
    if (strcmp(method, "volumetric") != 0) {
        fprintf(stderr, "slimfarm optimize: method '%s' is not supported (volumetric, surface)\n",
                method);
        return 2;
    }
    return 0;
}

static int
run(int argc, char **argv)
{
    for (int i = 1; i < argc; i++) {
        if ((strcmp(argv[i], "--method") == 0 && i + 1 < argc &&
             strcmp(argv[i + 1], "surface") == 0) ||
            strcmp(argv[i], "--method=surface") == 0)
            return cmd_optimize_surface(argc, argv); /* its own options */
    }
    struct slim_params p;
    slim_params_default(&p);
    struct slim_box boxes[MAX_BOXES];
    int n_boxes = 0;
    const char *out = NULL;
    bool json = false;
    int rc = parse_opts(argc, argv, &p, boxes, &n_boxes, &out, &json);
    if (rc)
        return rc;
    p.fix_boxes = n_boxes ? boxes : NULL;
    p.n_fix_boxes = n_boxes;
    p.progress = progress;
    /* A short-lived process (mem.h): mushroom 5,400 -> 1,100-1,400 page faults,
       0.27 -> 0.22 s.  Not in `slice`, whose threads allocate polygons all the
       time: on one shared heap they queue on its lock (torus 0.42 -> 1.0 s). */
    mem_batch_mode(64);
    struct mesh m;
    struct sf_err err;
    struct slim_result r;
    mesh_init(&m);
    if (!cmd_load_part("optimize", argv[optind], &m, NULL))
        return 1;
    rc = slim_optimize(&m, &p, &r, &err);
    mesh_release(&m);
    if (rc != SF_OK) {
        fprintf(stderr, "slimfarm optimize: %s: %s\n", argv[optind], err.msg);
        return 1;
    }
    if (!cmd_save_part("optimize", &r.out, out)) {
        slim_result_release(&r);
        return 1;
    }
    int status = 0;
    if (json)
        status = report_json(argv[optind], out, &p, &r);
    else
        report_text(argv[optind], out, &r);
    slim_result_release(&r);
    return status;
}

CMD_REGISTER(optimize, "optimize", usage_line, "slim a part's support by deforming it", run)
