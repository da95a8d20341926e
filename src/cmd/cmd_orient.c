/*
 * cmd_orient.c - `slimfarm orient PART -o OUT`: find the up-direction that
 * needs the least support, write the part rotated onto it (resting on
 * z = 0, centred on the bed), and report it against the input orientation
 * and the runners-up.
 */
#include <getopt.h>
#include <jansson.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "../base/mem.h"
#include "../geom/orient.h"
#include "cmd.h"
#include "cmdmesh.h"
#include "cmdreport.h"

static const char usage_line[] = "orient PART -o OUT [--angle DEG] [--margin DEG] [--samples N] "
                                 "[--grid MM] [--bed X,Y] [--json]";

static void
progress(void *ud, double done, double total)
{
    (void)ud;
    cmd_progress("orient", done, total);
}

static json_t *
cand_json(const struct orient_candidate *c)
{
    return json_pack(
        "{s:[fff], s:s, s:f, s:f, s:f, s:i, s:i, s:f, s:f, s:f, s:f, s:f}", "up", c->up.x, c->up.y,
        c->up.z, "source", orient_source_name(c->source), "support_volume_mm3", c->m.volume_mm3,
        "contact_area_mm2", c->m.contact_area_mm2, "risky_area_mm2", c->m.risky_area_mm2, "anchors",
        (json_int_t)c->m.n_anchors, "islands", (json_int_t)c->m.n_islands, "base_margin_mm",
        c->m.base_margin_mm, "com_height_mm", c->m.com_height_mm, "build_height_mm",
        c->m.build_height_mm, "cost", c->cost, "model_support_g", c->support_g);
}

static void
print_cand(const char *label, const struct orient_candidate *c)
{
    printf("  %-9s up (%6.3f, %6.3f, %6.3f) %-13s support %9.0f mm3, contact %6.0f mm2, "
           "height %5.1f mm, com %5.1f mm\n",
           label, c->up.x, c->up.y, c->up.z, orient_source_name(c->source), c->m.volume_mm3,
           c->m.contact_area_mm2, c->m.build_height_mm, c->m.com_height_mm);
}

static int
run(int argc, char **argv)
{
    static const struct option opts[] = {
        { "output", required_argument, NULL, 'o' },  { "angle", required_argument, NULL, 'a' },
        { "samples", required_argument, NULL, 's' }, { "grid", required_argument, NULL, 'g' },
        { "bed", required_argument, NULL, 'b' },     { "json", no_argument, NULL, 'j' },
        { "margin", required_argument, NULL, 'm' },  { NULL, 0, NULL, 0 }
    };
    struct orient_params p;
    orient_params_default(&p);
    const char *out = NULL;
    double bed_x = 125, bed_y = 105;
    bool json = false;
    const struct cmd_num nums[] = {
        { 'a', "angle", 0, 89.9, "degrees in [0, 90)", &p.angle_deg, NULL, 0 },
        { 'm', "margin", 0, 44.9, "degrees in [0, 45)", &p.margin_deg, NULL, 0 },
        { 'g', "grid", 0.05, 50, "mm in [0.05, 50]", &p.pitch_mm, NULL, 0 },
    };
    int c;
    char *end;
    optind = 1;
    while ((c = cmd_getopt("orient", argc, argv, "o:", opts, nums, 3)) != -1) {
        switch (c) {
        case 'o':
            out = optarg;
            break;
        case 's': {
            long n = strtol(optarg, &end, 10);
            if (*end || n < 0 || n > 1000000) {
                fprintf(stderr, "slimfarm orient: --samples wants 0..1000000, got '%s'\n", optarg);
                return 2;
            }
            p.samples = (int)n;
            break;
        }
        case 'b':
            if (sscanf(optarg, "%lf,%lf", &bed_x, &bed_y) != 2 || !isfinite(bed_x) ||
                !isfinite(bed_y)) {
                fprintf(stderr, "slimfarm orient: --bed wants the bed centre X,Y in mm\n");
                return 2;
            }
            break;
        case 'j':
            json = true;
            break;
        default:
            return cmd_opt_error(c, usage_line);
        }
    }
    if (optind != argc - 1 || !out)
        return cmd_usage(usage_line);
    /* A short-lived process: reuse freed memory, back the heap with huge pages
       (each 4 KB first touch is a page fault of 14-24 us on the farm's VMs) */
    mem_batch_mode(64);
    struct mesh m;
    struct sf_err err;
    struct orient_result r;
    mesh_init(&m);
    if (!cmd_load_part("orient", argv[optind], &m, NULL))
        return 1;
    p.progress = progress;
    if (orient_find(&m, &p, &r, &err) != SF_OK) {
        fprintf(stderr, "slimfarm orient: %s: %s\n", argv[optind], err.msg);
        mesh_release(&m);
        return 1;
    }
    if (r.not_solid)
        fprintf(stderr,
                "slimfarm orient: %s: warning: not a closed solid (%u of %u rays meet unpaired "
                "surfaces), so its support figures are guesses; orientation kept. Repair the "
                "mesh to orient it.\n",
                argv[optind], r.input.m.n_rays_open, r.input.m.n_rays);
    orient_apply(&m, r.best.up, bed_x, bed_y);
    bool saved = cmd_save_part("orient", &m, out);
    mesh_release(&m);
    if (!saved)
        return 1;
    if (json) {
        json_t *o =
            json_pack("{s:s, s:s, s:o, s:o, s:[], s:i, s:i, s:f}", "file", argv[optind], "output",
                      out, "best", cand_json(&r.best), "input", cand_json(&r.input), "runners_up",
                      "candidates", (json_int_t)r.n_candidates, "scored_exactly",
                      (json_int_t)r.n_exact, "seconds", r.seconds);
        for (int i = 0; o && i < r.n_runners; i++)
            json_array_append_new(json_object_get(o, "runners_up"), cand_json(&r.runners[i]));
        return cmd_put_json("orient", o);
    }
    printf("%s -> %s: %u directions, %u ray-cast, %.3f s (setup %.3f, proxy %.3f, ray cast "
           "%.3f)\n",
           argv[optind], out, r.n_candidates, r.n_exact, r.seconds, r.seconds_setup,
           r.seconds_proxy, r.seconds_exact);
    print_cand("best", &r.best);
    print_cand("input", &r.input);
    for (int i = 0; i < r.n_runners; i++)
        print_cand(i == 0 ? "runners" : "", &r.runners[i]);
    return 0;
}

CMD_REGISTER(orient, "orient", usage_line, "turn a part so it needs the least support", run)
