/*
 * test_slice_preview.c - PNG pictures of a part and of a G-code layer, and
 * the errors a person would hit (a layer the file does not have).
 */
#include <stdio.h>
#include <string.h>

#include "../../slicer/preview.h"
#include "../../slicer/slice.h"
#include "../../src/base/buf.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"

static int
is_png(const char *path, size_t *len)
{
    struct buf b;
    buf_init(&b, 0);
    int ok = buf_read_file(&b, path, NULL) == SF_OK && b.len > 1000 &&
             memcmp(b.data, "\x89PNG\r\n\x1a\n", 8) == 0;
    *len = b.len;
    buf_release(&b);
    return ok;
}

T_CASE(preview_part_and_layer)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    struct preview_opts o;
    preview_opts_default(&o);
    char png[512], gc[512];
    size_t n;
    snprintf(png, sizeof(png), "%s/tee.png", t_tmpdir());
    T_OK(preview_part(&m, &o, png, &err), &err);
    T_TRUE(is_png(png, &n));
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    snprintf(gc, sizeof(gc), "%s/tee.gcode", t_tmpdir());
    T_OK(slice_mesh(&m, &p, gc, NULL, NULL, NULL, &err), &err);
    struct buf b;
    buf_init(&b, 0);
    T_OK(buf_read_file(&b, gc, &err), &err);
    o.layer = 10;
    snprintf(png, sizeof(png), "%s/layer.png", t_tmpdir());
    T_OK(preview_gcode(b.data, b.len, gc, &o, png, &err), &err);
    T_TRUE(is_png(png, &n));
    o.layer = 175;
    T_ERR(preview_gcode(b.data, b.len, "tee.gcode", &o, png, &err), SF_EINVAL, &err,
          "tee.gcode: layer 175 asked, the file has 175");
    T_ERR(preview_gcode("G1 X1\n", 6, "x.gcode", &o, png, &err), SF_EINVAL, &err,
          "no ;LAYER_CHANGE");
    buf_release(&b);
    slice_profile_release(&p);
    mesh_release(&m);
}
