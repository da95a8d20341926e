/*
 * test_slice_preview.c - PNG pictures of a part and of a G-code layer, and
 * the errors a person would hit (a layer the file does not have).
 */
#include <cairo.h>
#include <math.h>
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

T_CASE(preview_shows_the_seam)
{
    /* a cylinder with its seam at the rear: the layer picture has a white
       dot there (above the centre, as y points up in the picture) */
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    double r[4] = { 0, 10, 10, 0 }, z[4] = { 0, 0, 10, 10 };
    T_OK(shape_revolve(&m, r, z, 4, 90, &err), &err);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    p.support = false;
    p.skirts = 0;
    p.brim_auto = false;
    T_OK(slice_profile_set(&p, "seam_position=rear", &err), &err);
    char gc[512], png[512];
    snprintf(gc, sizeof(gc), "%s/cyl.gcode", t_tmpdir());
    snprintf(png, sizeof(png), "%s/cyl.png", t_tmpdir());
    T_OK(slice_mesh(&m, &p, gc, NULL, NULL, NULL, &err), &err);
    struct buf b;
    buf_init(&b, 0);
    T_OK(buf_read_file(&b, gc, &err), &err);
    struct preview_opts o;
    preview_opts_default(&o);
    o.layer = 20;
    T_OK(preview_gcode(b.data, b.len, gc, &o, png, &err), &err);
    cairo_surface_t *s = cairo_image_surface_create_from_png(png);
    T_TRUE(cairo_surface_status(s) == CAIRO_STATUS_SUCCESS);
    int w = cairo_image_surface_get_width(s), h = cairo_image_surface_get_height(s);
    int stride = cairo_image_surface_get_stride(s);
    const unsigned char *px = cairo_image_surface_get_data(s);
    /* the layer spans about 20 mm (external perimeter centres 19.55 mm
       apart) over 0.9 of the smaller side; the seam is at its top */
    double sc = 0.9 * fmin(w, h) / 19.55;
    int cx = w / 2, cy = (int)lround(h / 2.0 - sc * 9.775);
    int white = 0, span = (int)(0.6 * sc); /* the rear vertex may be one facet (0.35 mm) aside */
    for (int dy = -2; dy <= 2; dy++)
        for (int dx = -span; dx <= span; dx++) {
            const unsigned char *q = px + (cy + dy) * stride + 4 * (cx + dx);
            white += q[0] > 240 && q[1] > 240 && q[2] > 240;
        }
    T_TRUE(white >= 5);
    cairo_surface_destroy(s);
    buf_release(&b);
    slice_profile_release(&p);
    mesh_release(&m);
}
