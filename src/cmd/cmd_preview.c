/*
 * cmd_preview.c - `slimfarm preview PART|GCODE -o OUT.png`: a picture to
 * check by eye.  A part (STL/OBJ/3MF) is drawn with its risky faces red
 * and its support columns blue; a G-code file (.gcode, .gco, .g) as one
 * layer seen from the top, coloured by extrusion role.
 */
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "../../slicer/preview.h"
#include "../base/buf.h"
#include "../mesh/mesh.h"
#include "cmd.h"

static const char usage_line[] =
    "preview PART|GCODE -o OUT.png [--layer N] [--angle DEG] [--grid MM] [--size WxH]";

static bool
is_gcode(const char *path)
{
    const char *dot = strrchr(path, '.');
    return dot && (strcasecmp(dot, ".gcode") == 0 || strcasecmp(dot, ".gco") == 0 ||
                   strcasecmp(dot, ".g") == 0);
}

static int
run(int argc, char **argv)
{
    static const struct option opts[] = {
        { "output", required_argument, NULL, 'o' }, { "layer", required_argument, NULL, 'l' },
        { "angle", required_argument, NULL, 'a' },  { "grid", required_argument, NULL, 'g' },
        { "size", required_argument, NULL, 's' },   { NULL, 0, NULL, 0 }
    };
    struct preview_opts po;
    preview_opts_default(&po);
    const char *out = NULL;
    const struct cmd_num nums[] = {
        { 'l', "layer", 0, 1e6, "a layer number", NULL, &po.layer, 0 },
        { 'a', "angle", 0, 89.9, "degrees in [0, 90)", &po.angle_deg, NULL, 0 },
        { 'g', "grid", 0.1, 20, "mm in [0.1, 20]", &po.pitch_mm, NULL, 0 },
    };
    int c, w, h;
    optind = 1;
    while ((c = cmd_getopt("preview", argc, argv, "o:", opts, nums, 3)) != -1) {
        switch (c) {
        case 'o':
            out = optarg;
            break;
        case 's':
            if (sscanf(optarg, "%dx%d", &w, &h) != 2 || w < 16 || h < 16 || w > 8192 || h > 8192) {
                fprintf(stderr, "slimfarm preview: --size wants WxH in 16..8192, got '%s'\n",
                        optarg);
                return 2;
            }
            po.width_px = w;
            po.height_px = h;
            break;
        default:
            return cmd_opt_error(c, usage_line);
        }
    }
    if (optind != argc - 1 || !out)
        return cmd_usage(usage_line);
    const char *in = argv[optind];
    struct sf_err err;
    int rc;
    if (is_gcode(in)) {
        struct buf b;
        buf_init(&b, (size_t)1 << 31);
        rc = buf_read_file(&b, in, &err);
        if (rc == SF_OK)
            rc = preview_gcode(b.data ? b.data : "", b.len, in, &po, out, &err);
        buf_release(&b);
    } else {
        struct mesh m;
        mesh_init(&m);
        rc = mesh_load(in, &m, NULL, &err);
        if (rc == SF_OK)
            rc = preview_part(&m, &po, out, &err);
        mesh_release(&m);
    }
    if (rc < 0) {
        fprintf(stderr, "slimfarm preview: %s\n", err.msg);
        return 1;
    }
    return 0;
}

CMD_REGISTER(preview, "preview", usage_line,
             "draw a part (risky faces, support columns) or a G-code layer as PNG", run)
