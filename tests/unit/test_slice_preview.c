/*
 * test_slice_preview.c - PNG pictures of a part and of a G-code layer, and
 * the errors a person would hit (a layer the file does not have).
 */
#include <cairo.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
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

/* The picture draws the columns the slicer prints: the same set, from the
   same function on the same parameters, for a part with overhangs; and the
   farm's picture (no profile, the job's angle) is the default profile's. */
T_CASE(preview_columns_are_the_sliced_columns)
{
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    p.support_angle_deg = 40; /* not the default's, so the picture must take it */
    char gc[512];
    snprintf(gc, sizeof(gc), "%s/cols.gcode", t_tmpdir());
    struct mesh m;
    struct sf_err err;
    struct slice_result r;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    T_OK(slice_mesh(&m, &p, gc, &r, NULL, NULL, &err), &err);
    T_TRUE(r.n_columns > 10);

    struct preview_opts o;
    preview_opts_default(&o);
    o.profile = &p;
    struct support_grid g, g2;
    struct support_column *cols = NULL, *cols2 = NULL;
    size_t n, n_body, n2, n_body2;
    T_OK(preview_columns(&m, &o, &g, &cols, &n, &n_body, &err), &err);
    T_EQ_INT(n_body, r.n_columns);
    double vol = 0;
    for (size_t i = 0; i < n_body; i++) {
        T_TRUE(!cols[i].iface);
        vol += (double)(cols[i].hi - cols[i].lo) * g.pitch * g.pitch;
    }
    T_TRUE(vol == r.ray_volume_mm3);
    T_TRUE(n > n_body); /* the interface bands travel with them */

    /* the farm's picture: no profile, the job's angle */
    o.profile = NULL;
    o.angle_deg = 40;
    T_OK(preview_columns(&m, &o, &g2, &cols2, &n2, &n_body2, &err), &err);
    T_EQ_INT(n2, n);
    T_EQ_INT(n_body2, n_body);
    T_TRUE(memcmp(&g, &g2, sizeof(g)) == 0);
    for (size_t i = 0; i < n; i++)
        T_TRUE(cols[i].cell == cols2[i].cell && cols[i].lo == cols2[i].lo &&
               cols[i].hi == cols2[i].hi && cols[i].iface == cols2[i].iface);
    free(cols);
    free(cols2);
    slice_profile_release(&p);
    mesh_release(&m);
}
