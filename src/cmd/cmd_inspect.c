/*
 * cmd_inspect.c - `slimfarm inspect PART`: what the loader found and
 * repaired, the part's topology, and the support metrics for one
 * up-direction, as text or JSON.
 */
#include <getopt.h>
#include <jansson.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../geom/measure.h"
#include "../geom/supmodel.h"
#include "../mesh/mesh.h"
#include "cmd.h"
#include "cmdmesh.h"

static const char usage_line[] = "inspect PART [--up x,y,z] [--angle DEG] [--grid MM] [--json]";

/* What inspect found, for the reports. */
struct facts {
    const char *path;              /* the part as named */
    struct mesh_load_info info;    /* what loading repaired */
    struct mesh_topo topo;         /* its topology */
    struct support_metrics sm;     /* support for up */
    struct supmodel_result mod[2]; /* the support model: PrusaSlicer's, CuraEngine's */
    struct vec3 up, lo, hi;        /* up-direction; bounding box */
    struct support_params sp;      /* angle and grid measured with */
    double vol;                    /* enclosed volume (meaningful when closed) */
    bool closed;                   /* a closed shell */
};

static int
report_json(const struct facts *f, const struct mesh *m)
{
    json_t *o = json_pack(
        "{s:s, s:s, s:{s:i, s:i, s:i, s:i, s:i}, s:[fff], s:[fff], s:f, s:f, s:b,"
        " s:{s:i, s:i, s:i, s:i, s:i}}",
        "file", f->path, "format", mesh_format_name(f->info.format), "mesh", "triangles",
        (json_int_t)m->n_tris, "vertices", (json_int_t)m->n_verts, "merged",
        (json_int_t)f->info.n_merged, "degenerate", (json_int_t)f->info.n_degenerate, "flipped",
        (json_int_t)f->info.n_flipped, "bbox_min", f->lo.x, f->lo.y, f->lo.z, "bbox_max", f->hi.x,
        f->hi.y, f->hi.z, "volume_mm3", f->closed ? f->vol : 0.0, "area_mm2", mesh_area(m),
        "closed", f->closed, "topology", "components", (json_int_t)f->topo.n_comps, "edges",
        (json_int_t)f->topo.n_edges, "boundary_edges", (json_int_t)f->topo.n_boundary,
        "nonmanifold_edges", (json_int_t)f->topo.n_nonmanifold, "misoriented_edges",
        (json_int_t)f->topo.n_misoriented);
    json_t *s =
        json_pack("{s:[fff], s:f, s:f, s:i, s:f, s:f, s:f, s:f, s:i, s:i, s:f, s:f}", "up", f->up.x,
                  f->up.y, f->up.z, "angle_deg", f->sp.angle_deg, "grid_mm", f->sp.pitch_mm,
                  "risky_faces", (json_int_t)f->sm.n_risky, "risky_area_mm2", f->sm.risky_area_mm2,
                  "proxy_mm3", f->sm.proxy_mm3, "support_volume_mm3", f->sm.volume_mm3,
                  "contact_area_mm2", f->sm.contact_area_mm2, "columns",
                  (json_int_t)f->sm.n_columns, "anchors", (json_int_t)f->sm.n_anchors,
                  "com_height_mm", f->sm.com_height_mm, "build_height_mm", f->sm.build_height_mm);
    if (s)
        json_object_update_new(s,
                               json_pack("{s:i, s:f, s:f}", "islands", (json_int_t)f->sm.n_islands,
                                         "island_volume_mm3", f->sm.island_volume_mm3,
                                         "base_margin_mm", f->sm.base_margin_mm));
    if (s)
        json_object_set_new(s, "model",
                            json_pack("{s:{s:f, s:f, s:f}, s:{s:f, s:f, s:f}}", "prusaslicer",
                                      "support_g", f->mod[0].grams, "support_s", f->mod[0].time_s,
                                      "contact_area_mm2", f->mod[0].contact_area_mm2, "curaengine",
                                      "support_g", f->mod[1].grams, "support_s", f->mod[1].time_s,
                                      "contact_area_mm2", f->mod[1].contact_area_mm2));
    if (!o || !s || json_object_set_new(o, "support", s) != 0) {
        fprintf(stderr, "slimfarm inspect: out of memory\n");
        json_decref(o);
        return 1;
    }
    char *text = json_dumps(o, JSON_INDENT(2) | JSON_REAL_PRECISION(10));
    json_decref(o);
    if (!text)
        return 1;
    puts(text);
    free(text);
    return 0;
}

static void
report_text(const struct facts *f, const struct mesh *m)
{
    printf("%s: %s, %u triangles, %u vertices\n", f->path, mesh_format_name(f->info.format),
           m->n_tris, m->n_verts);
    printf("  repaired:   %u vertices merged, %u degenerate triangles dropped, %u flipped\n",
           f->info.n_merged, f->info.n_degenerate, f->info.n_flipped);
    printf("  size:       %.2f x %.2f x %.2f mm (min %.2f, %.2f, %.2f)\n", f->hi.x - f->lo.x,
           f->hi.y - f->lo.y, f->hi.z - f->lo.z, f->lo.x, f->lo.y, f->lo.z);
    printf("  topology:   %s, %u component%s, %u edges, %u boundary, %u non-manifold\n",
           f->closed ? "closed" : "open", f->topo.n_comps, f->topo.n_comps == 1 ? "" : "s",
           f->topo.n_edges, f->topo.n_boundary, f->topo.n_nonmanifold);
    if (f->closed)
        printf("  volume:     %.1f mm3, area %.1f mm2\n", f->vol, mesh_area(m));
    else
        printf("  volume:     (open mesh), area %.1f mm2\n", mesh_area(m));
    printf("support for up (%.3f, %.3f, %.3f), %.0f deg from vertical, %.2f mm grid:\n", f->up.x,
           f->up.y, f->up.z, f->sp.angle_deg, f->sp.pitch_mm);
    printf("  risky faces %u, area %.1f mm2, proxy %.0f mm3\n", f->sm.n_risky, f->sm.risky_area_mm2,
           f->sm.proxy_mm3);
    printf("  support volume %.0f mm3 in %u columns, contact %.0f mm2, %u anchors\n",
           f->sm.volume_mm3, f->sm.n_columns, f->sm.contact_area_mm2, f->sm.n_anchors);
    printf("  height %.1f mm, centre of mass at %.1f mm\n", f->sm.build_height_mm,
           f->sm.com_height_mm);
    printf("  support model: PrusaSlicer %.2f g (%.0f min), CuraEngine %.2f g (%.0f min)\n",
           f->mod[0].grams, f->mod[0].time_s / 60, f->mod[1].grams, f->mod[1].time_s / 60);
    printf("  growth: %u island%s needing %.0f mm3 (included above), centre of mass %.1f mm "
           "%s the base\n",
           f->sm.n_islands, f->sm.n_islands == 1 ? "" : "s", f->sm.island_volume_mm3,
           fabs(f->sm.base_margin_mm), f->sm.base_margin_mm >= 0 ? "inside" : "OUTSIDE");
    if (f->sm.n_rays_open)
        printf("  warning: %u of %u rays meet surfaces that do not pair up (not a closed "
               "solid): the support figures are estimates\n",
               f->sm.n_rays_open, f->sm.n_rays);
}

/* The options into up (normalized), sp and json: 0, or 2 (a usage error, message printed). */
static int
parse_opts(int argc, char **argv, struct vec3 *up, struct support_params *sp, bool *json)
{
    static const struct option opts[] = { { "up", required_argument, NULL, 'u' },
                                          { "angle", required_argument, NULL, 'a' },
                                          { "grid", required_argument, NULL, 'g' },
                                          { "json", no_argument, NULL, 'j' },
                                          { NULL, 0, NULL, 0 } };
    const struct cmd_num nums[] = {
        { 'a', "angle", 0, 89.9, "degrees in [0, 90)", &sp->angle_deg, NULL, 0 },
        { 'g', "grid", 0.05, 50, "mm in [0.05, 50]", &sp->pitch_mm, NULL, 0 },
    };
    int c;
    optind = 1;
    while ((c = cmd_getopt("inspect", argc, argv, "", opts, nums, 2)) != -1) {
        switch (c) {
        case 'u': {
            double v[3];
            if (!cmd_parse_vec3("inspect", "up", optarg, v))
                return 2;
            *up = v3(v[0], v[1], v[2]);
            break;
        }
        case 'j':
            *json = true;
            break;
        default:
            return cmd_opt_error(c, usage_line);
        }
    }
    if (optind != argc - 1)
        return cmd_usage(usage_line);
    *up = v3_normalize(*up);
    return 0;
}

static int
run(int argc, char **argv)
{
    struct facts f;
    memset(&f, 0, sizeof(f));
    f.up = v3(0, 0, 1);
    support_params_default(&f.sp);
    bool json = false;
    int rc = parse_opts(argc, argv, &f.up, &f.sp, &json);
    if (rc)
        return rc;
    f.path = argv[optind];

    struct mesh m;
    struct sf_err err;
    rc = 1;
    mesh_init(&m);
    if (!cmd_load_part("inspect", f.path, &m, &f.info))
        return 1;
    struct raycast *ray = NULL;
    if (mesh_topo_build(&m, &f.topo, &err) != SF_OK || !(ray = raycast_new(&m, &err)) ||
        measure_support(&m, ray, f.up, &f.sp, &f.sm, &err) != SF_OK) {
        fprintf(stderr, "slimfarm inspect: %s: %s\n", f.path, err.msg);
        goto out;
    }
    /* the layer-based support model, imitating each peer slicer (supmodel.h) */
    for (int k = 0; k < 2; k++) {
        struct supmodel_params mp;
        supmodel_params_default(&mp, k ? SUPMODEL_CURA : SUPMODEL_PRUSA);
        mp.angle_deg = f.sp.angle_deg;
        if (supmodel_eval(ray, f.up, &mp, &f.mod[k], &err) != SF_OK) {
            fprintf(stderr, "slimfarm inspect: %s: %s\n", f.path, err.msg);
            goto out;
        }
    }
    struct vec3 com;
    mesh_bbox(&m, &f.lo, &f.hi);
    f.vol = mesh_volume(&m, &com);
    f.closed = mesh_topo_closed(&f.topo);
    rc = json ? report_json(&f, &m) : (report_text(&f, &m), 0);
out:
    raycast_free(ray);
    mesh_topo_release(&f.topo);
    mesh_release(&m);
    return rc;
}

CMD_REGISTER(inspect, "inspect", usage_line, "mesh report and support metrics of a part", run)
