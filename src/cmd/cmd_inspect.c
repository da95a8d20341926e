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

static const char usage_line[] = "inspect PART [--up x,y,z] [--angle DEG] [--grid MM] [--json]";

static int
run(int argc, char **argv)
{
    static const struct option opts[] = { { "up", required_argument, NULL, 'u' },
                                          { "angle", required_argument, NULL, 'a' },
                                          { "grid", required_argument, NULL, 'g' },
                                          { "json", no_argument, NULL, 'j' },
                                          { NULL, 0, NULL, 0 } };
    struct vec3 up = v3(0, 0, 1);
    struct support_params sp;
    support_params_default(&sp);
    bool json = false;
    int c;
    optind = 1;
    while ((c = getopt_long(argc, argv, "", opts, NULL)) != -1) {
        switch (c) {
        case 'u': {
            double v[3];
            if (!cmd_parse_vec3("inspect", "up", optarg, v))
                return 2;
            up = v3(v[0], v[1], v[2]);
            break;
        }
        case 'a':
            if (!cmd_parse_num("inspect", "angle", optarg, 0, 89.9, "degrees in [0, 90)",
                               &sp.angle_deg))
                return 2;
            break;
        case 'g':
            if (!cmd_parse_num("inspect", "grid", optarg, 0.05, 50, "mm in [0.05, 50]",
                               &sp.pitch_mm))
                return 2;
            break;
        case 'j':
            json = true;
            break;
        default:
            fprintf(stderr, "usage: slimfarm %s\n", usage_line);
            return 2;
        }
    }
    if (optind != argc - 1) {
        fprintf(stderr, "usage: slimfarm %s\n", usage_line);
        return 2;
    }
    const char *path = argv[optind];
    up = v3_normalize(up);

    struct mesh m;
    struct mesh_load_info info;
    struct mesh_topo topo;
    struct support_metrics sm;
    struct sf_err err;
    int rc = 1;
    mesh_init(&m);
    memset(&topo, 0, sizeof(topo));
    if (mesh_load(path, &m, &info, &err) != SF_OK) {
        fprintf(stderr, "slimfarm inspect: %s\n", err.msg);
        return 1;
    }
    struct raycast *ray = NULL;
    if (mesh_topo_build(&m, &topo, &err) != SF_OK || !(ray = raycast_new(&m, &err)) ||
        measure_support(&m, ray, up, &sp, &sm, &err) != SF_OK) {
        fprintf(stderr, "slimfarm inspect: %s: %s\n", path, err.msg);
        goto out;
    }
    /* the layer-based support model, imitating each peer slicer (supmodel.h) */
    struct supmodel_result mod[2];
    for (int k = 0; k < 2; k++) {
        struct supmodel_params mp;
        supmodel_params_default(&mp, k ? SUPMODEL_CURA : SUPMODEL_PRUSA);
        mp.angle_deg = sp.angle_deg;
        if (supmodel_eval(ray, up, &mp, &mod[k], &err) != SF_OK) {
            fprintf(stderr, "slimfarm inspect: %s: %s\n", path, err.msg);
            goto out;
        }
    }
    struct vec3 lo, hi, com;
    mesh_bbox(&m, &lo, &hi);
    double vol = mesh_volume(&m, &com);
    bool closed = mesh_topo_closed(&topo);
    if (json) {
        json_t *o = json_pack(
            "{s:s, s:s, s:{s:i, s:i, s:i, s:i, s:i}, s:[fff], s:[fff], s:f, s:f, s:b,"
            " s:{s:i, s:i, s:i, s:i, s:i}}",
            "file", path, "format", mesh_format_name(info.format), "mesh", "triangles",
            (json_int_t)m.n_tris, "vertices", (json_int_t)m.n_verts, "merged",
            (json_int_t)info.n_merged, "degenerate", (json_int_t)info.n_degenerate, "flipped",
            (json_int_t)info.n_flipped, "bbox_min", lo.x, lo.y, lo.z, "bbox_max", hi.x, hi.y, hi.z,
            "volume_mm3", closed ? vol : 0.0, "area_mm2", mesh_area(&m), "closed", closed,
            "topology", "components", (json_int_t)topo.n_comps, "edges", (json_int_t)topo.n_edges,
            "boundary_edges", (json_int_t)topo.n_boundary, "nonmanifold_edges",
            (json_int_t)topo.n_nonmanifold, "misoriented_edges", (json_int_t)topo.n_misoriented);
        json_t *s = json_pack(
            "{s:[fff], s:f, s:f, s:i, s:f, s:f, s:f, s:f, s:i, s:i, s:f, s:f}", "up", up.x, up.y,
            up.z, "angle_deg", sp.angle_deg, "grid_mm", sp.pitch_mm, "risky_faces",
            (json_int_t)sm.n_risky, "risky_area_mm2", sm.risky_area_mm2, "proxy_mm3", sm.proxy_mm3,
            "support_volume_mm3", sm.volume_mm3, "contact_area_mm2", sm.contact_area_mm2, "columns",
            (json_int_t)sm.n_columns, "anchors", (json_int_t)sm.n_anchors, "com_height_mm",
            sm.com_height_mm, "build_height_mm", sm.build_height_mm);
        if (s)
            json_object_update_new(s,
                                   json_pack("{s:i, s:f, s:f}", "islands", (json_int_t)sm.n_islands,
                                             "island_volume_mm3", sm.island_volume_mm3,
                                             "base_margin_mm", sm.base_margin_mm));
        if (s)
            json_object_set_new(s, "model",
                                json_pack("{s:{s:f, s:f, s:f}, s:{s:f, s:f, s:f}}", "prusaslicer",
                                          "support_g", mod[0].grams, "support_s", mod[0].time_s,
                                          "contact_area_mm2", mod[0].contact_area_mm2, "curaengine",
                                          "support_g", mod[1].grams, "support_s", mod[1].time_s,
                                          "contact_area_mm2", mod[1].contact_area_mm2));
        if (!o || !s || json_object_set_new(o, "support", s) != 0) {
            fprintf(stderr, "slimfarm inspect: out of memory\n");
            json_decref(o);
            goto out;
        }
        char *text = json_dumps(o, JSON_INDENT(2) | JSON_REAL_PRECISION(10));
        json_decref(o);
        if (!text)
            goto out;
        puts(text);
        free(text);
    } else {
        printf("%s: %s, %u triangles, %u vertices\n", path, mesh_format_name(info.format), m.n_tris,
               m.n_verts);
        printf("  repaired:   %u vertices merged, %u degenerate triangles dropped, %u flipped\n",
               info.n_merged, info.n_degenerate, info.n_flipped);
        printf("  size:       %.2f x %.2f x %.2f mm (min %.2f, %.2f, %.2f)\n", hi.x - lo.x,
               hi.y - lo.y, hi.z - lo.z, lo.x, lo.y, lo.z);
        printf("  topology:   %s, %u component%s, %u edges, %u boundary, %u non-manifold\n",
               closed ? "closed" : "open", topo.n_comps, topo.n_comps == 1 ? "" : "s", topo.n_edges,
               topo.n_boundary, topo.n_nonmanifold);
        if (closed)
            printf("  volume:     %.1f mm3, area %.1f mm2\n", vol, mesh_area(&m));
        else
            printf("  volume:     (open mesh), area %.1f mm2\n", mesh_area(&m));
        printf("support for up (%.3f, %.3f, %.3f), %.0f deg from vertical, %.2f mm grid:\n", up.x,
               up.y, up.z, sp.angle_deg, sp.pitch_mm);
        printf("  risky faces %u, area %.1f mm2, proxy %.0f mm3\n", sm.n_risky, sm.risky_area_mm2,
               sm.proxy_mm3);
        printf("  support volume %.0f mm3 in %u columns, contact %.0f mm2, %u anchors\n",
               sm.volume_mm3, sm.n_columns, sm.contact_area_mm2, sm.n_anchors);
        printf("  height %.1f mm, centre of mass at %.1f mm\n", sm.build_height_mm,
               sm.com_height_mm);
        printf("  support model: PrusaSlicer %.2f g (%.0f min), CuraEngine %.2f g (%.0f min)\n",
               mod[0].grams, mod[0].time_s / 60, mod[1].grams, mod[1].time_s / 60);
        printf("  growth: %u island%s needing %.0f mm3 (included above), centre of mass %.1f mm "
               "%s the base\n",
               sm.n_islands, sm.n_islands == 1 ? "" : "s", sm.island_volume_mm3,
               fabs(sm.base_margin_mm), sm.base_margin_mm >= 0 ? "inside" : "OUTSIDE");
        if (sm.n_rays_open)
            printf("  warning: %u of %u rays meet surfaces that do not pair up (not a closed "
                   "solid): the support figures are estimates\n",
                   sm.n_rays_open, sm.n_rays);
    }
    rc = 0;
out:
    raycast_free(ray);
    mesh_topo_release(&topo);
    mesh_release(&m);
    return rc;
}

CMD_REGISTER(inspect, "inspect", usage_line, "mesh report and support metrics of a part", run)
