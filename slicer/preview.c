/*
 * preview.c - PNG pictures of parts and layers with cairo (see preview.h).
 *
 * The part: every triangle projected once, sorted by depth with qsort,
 * filled back to front; shade = 0.35 + 0.65 |n . light|.  Columns come
 * from support_columns() on the profile the slicer gets, so the picture
 * shows exactly what will be supported (less the columns the slicer adds
 * under islands it finds in the layers).  The layer: moves are
 * collected through the estimator's move callback (one G-code reader for
 * everything), then stroked with the role's colour and line width.
 *
 * Thread: reentrant.
 */
#include "preview.h"

#include <cairo.h>
#include <math.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>

#include "../src/base/mem.h"
#include "estimate.h"
#include "support.h"

void
preview_opts_default(struct preview_opts *o)
{
    o->width_px = 800;
    o->height_px = 600;
    o->angle_deg = 45;
    o->profile = NULL;
    o->pitch_mm = 0;
    o->layer = -1;
}

/* View frame: azimuth -35 deg, elevation 25 deg, looking at the part from the front-right. */
struct view {
    struct vec3 right, up, fwd;
    double scale, ox, oy; /* screen = (p . right, -(p . up)) * scale + (ox, oy) */
};

static void
view_init(struct view *v, struct vec3 lo, struct vec3 hi, int w, int h)
{
    double az = -35 * M_PI / 180, el = 25 * M_PI / 180;
    v->right = v3(cos(az), sin(az), 0);
    v->fwd = v3(-sin(az) * cos(el), cos(az) * cos(el), -sin(el));
    v->up = v3_cross(v->right, v->fwd);
    double x0 = INFINITY, x1 = -INFINITY, y0 = INFINITY, y1 = -INFINITY;
    for (int i = 0; i < 8; i++) {
        struct vec3 p = v3(i & 1 ? hi.x : lo.x, i & 2 ? hi.y : lo.y, i & 4 ? hi.z : lo.z);
        double sx = v3_dot(p, v->right), sy = -v3_dot(p, v->up);
        x0 = fmin(x0, sx);
        x1 = fmax(x1, sx);
        y0 = fmin(y0, sy);
        y1 = fmax(y1, sy);
    }
    v->scale = 0.9 * fmin(w / fmax(x1 - x0, 1e-9), h / fmax(y1 - y0, 1e-9));
    v->ox = w / 2.0 - v->scale * (x0 + x1) / 2;
    v->oy = h / 2.0 - v->scale * (y0 + y1) / 2;
}

static void
project(const struct view *v, struct vec3 p, double *x, double *y)
{
    *x = v3_dot(p, v->right) * v->scale + v->ox;
    *y = -v3_dot(p, v->up) * v->scale + v->oy;
}

struct tri_key {
    float depth;
    uint32_t tri;
};

static int
cmp_depth(const void *a, const void *b)
{
    float x = ((const struct tri_key *)a)->depth, y = ((const struct tri_key *)b)->depth;
    return x > y ? -1 : x < y; /* far (large depth along fwd) first */
}

static int
finish(cairo_surface_t *s, cairo_t *cr, const char *png_path, struct sf_err *err)
{
    cairo_destroy(cr);
    cairo_status_t st = cairo_surface_write_to_png(s, png_path);
    cairo_surface_destroy(s);
    if (st != CAIRO_STATUS_SUCCESS)
        return sf_err_set(err, SF_EIO, "preview '%s': %s", png_path, cairo_status_to_string(st));
    return SF_OK;
}

int
preview_columns(const struct mesh *m, const struct preview_opts *o, struct support_grid *g,
                struct support_column **cols, size_t *n, size_t *n_body, struct sf_err *err)
{
    struct slice_profile def;
    const struct slice_profile *p = o->profile;
    size_t cap;
    if (!p) {
        int rc = slice_profile_default(&def);
        if (rc < 0)
            return sf_err_set(err, rc, "preview: out of memory");
        def.max_overhang_deg = def.support_angle_deg = o->angle_deg;
        if (o->pitch_mm > 0)
            def.support_pitch_mm = o->pitch_mm;
        p = &def;
    }
    int rc = support_columns(m, p, g, cols, n, &cap, n_body, err);
    if (p == &def)
        slice_profile_release(&def);
    return rc;
}

int
preview_part(const struct mesh *m, const struct preview_opts *o, const char *png_path,
             struct sf_err *err)
{
    if (!m->n_tris)
        return sf_err_set(err, SF_EINVAL, "preview: the part has no triangles");
    struct vec3 lo, hi;
    mesh_bbox(m, &lo, &hi);
    struct view v;
    view_init(&v, lo, hi, o->width_px, o->height_px);
    struct tri_key *keys = mem_array(m->n_tris, sizeof(*keys));
    if (!keys)
        return sf_err_set(err, SF_ENOMEM, "preview: out of memory");
    for (uint32_t i = 0; i < m->n_tris; i++) {
        keys[i].tri = i;
        keys[i].depth = (float)v3_dot(mesh_tri_centroid(m, i), v.fwd);
    }
    qsort(keys, m->n_tris, sizeof(*keys), cmp_depth);

    cairo_surface_t *s = cairo_image_surface_create(CAIRO_FORMAT_ARGB32, o->width_px, o->height_px);
    cairo_t *cr = cairo_create(s);
    cairo_set_source_rgb(cr, 1, 1, 1);
    cairo_paint(cr);
    double angle = o->profile ? slice_profile_angle(o->profile) : o->angle_deg;
    double tau = sin(angle * M_PI / 180);
    struct vec3 light = v3_normalize(v3(0.3, -0.5, 0.8));
    cairo_set_line_width(cr, 0.3);
    for (uint32_t k = 0; k < m->n_tris; k++) {
        uint32_t i = keys[k].tri;
        struct vec3 n = mesh_tri_normal(m, i);
        if (v3_dot(n, v.fwd) > 0.2) /* facing away: hidden behind the front faces */
            continue;
        double shade = 0.35 + 0.65 * fabs(v3_dot(n, light));
        bool risky = n.z < -tau && mesh_tri_centroid(m, i).z - lo.z > 0.05;
        if (risky)
            cairo_set_source_rgb(cr, 0.95 * shade, 0.15 * shade, 0.1 * shade);
        else
            cairo_set_source_rgb(cr, 0.55 * shade, 0.6 * shade, 0.68 * shade);
        for (int c = 0; c < 3; c++) {
            double x, y;
            project(&v, m->v[m->t[i][c]], &x, &y);
            if (c == 0)
                cairo_move_to(cr, x, y);
            else
                cairo_line_to(cr, x, y);
        }
        cairo_close_path(cr);
        cairo_fill_preserve(cr);
        cairo_stroke(cr);
    }
    free(keys);

    /* the printed support columns, translucent over the part */
    struct support_grid g;
    struct support_column *cols = NULL;
    size_t n_cols = 0, n_body = 0;
    int st = preview_columns(m, o, &g, &cols, &n_cols, &n_body, err);
    if (st == SF_OK) {
        cairo_set_source_rgba(cr, 0.1, 0.35, 0.95, 0.12);
        cairo_set_line_width(cr, fmax(1, 0.3 * g.pitch * v.scale));
        for (size_t c = 0; c < n_body; c++) {
            uint32_t i = cols[c].cell % g.nu, j = cols[c].cell / g.nu;
            double x = g.x0 + i * g.pitch, y = g.y0 + j * g.pitch, sx, sy, tx, ty;
            project(&v, v3(x, y, g.base + cols[c].lo), &sx, &sy);
            project(&v, v3(x, y, g.base + cols[c].hi), &tx, &ty);
            cairo_move_to(cr, sx, sy);
            cairo_line_to(cr, tx, ty);
            cairo_stroke(cr);
        }
    }
    free(cols);
    if (st < 0) {
        cairo_destroy(cr);
        cairo_surface_destroy(s);
        return st;
    }
    return finish(s, cr, png_path, err);
}

struct seg {
    float x0, y0, x1, y1, w;
    uint8_t role; /* index into role_colours, 0 = travel */
};

/* What preview_gcode collects of a G-code file: the shown layer's moves, every layer's seams. */
struct layer_moves {
    int layer;
    struct seg *segs;
    size_t n, cap;
    double x, y;
    bool have;
    bool in_ext;       /* the last move extruded an external perimeter */
    float (*seams)[3]; /* where external perimeters start: x, y, 1 on the layer shown */
    size_t n_seams, cap_seams;
};

static const struct {
    const char *name;
    double r, g, b;
} role_colours[] = {
    { "travel", 0.7, 0.7, 0.7 },           { "External perimeter", 1.0, 0.49, 0.22 },
    { "Perimeter", 1.0, 0.9, 0.3 },        { "Internal infill", 0.69, 0.19, 0.16 },
    { "Solid infill", 0.59, 0.33, 0.8 },   { "Top solid infill", 0.94, 0.25, 0.25 },
    { "Bridge infill", 0.3, 0.5, 0.73 },   { "Support material interface", 0.0, 0.5, 0.25 },
    { "Support material", 0.0, 1.0, 0.0 }, { "Skirt/Brim", 0.0, 0.53, 0.53 },
    { "Gap fill", 1.0, 1.0, 1.0 },         { "Overhang perimeter", 0.0, 0.0, 1.0 },
};

static uint8_t
role_of(const struct est_move *mv)
{
    for (uint8_t i = 1; i < sizeof(role_colours) / sizeof(role_colours[0]); i++)
        if (mv->type && mv->type_len == strlen(role_colours[i].name) &&
            memcmp(mv->type, role_colours[i].name, mv->type_len) == 0)
            return i;
    return 2;
}

static int
on_move(void *ud, const struct est_move *mv)
{
    struct layer_moves *c = ud;
    bool ext = mv->type && mv->type_len == 18 && memcmp(mv->type, "External perimeter", 18) == 0 &&
               mv->de > 0 && c->have && (mv->x != c->x || mv->y != c->y);
    if (ext && !c->in_ext) {
        if (!mem_grow((void **)&c->seams, &c->cap_seams, c->n_seams + 1, sizeof(*c->seams)))
            return SF_ENOMEM;
        c->seams[c->n_seams][0] = (float)c->x;
        c->seams[c->n_seams][1] = (float)c->y;
        c->seams[c->n_seams++][2] = (int)mv->layer == c->layer;
    }
    /* an overhang run inside an external loop does not start a new seam */
    if (!(mv->type && mv->type_len == 18 && memcmp(mv->type, "Overhang perimeter", 18) == 0))
        c->in_ext = ext;
    if ((int)mv->layer == c->layer && c->have && (mv->x != c->x || mv->y != c->y)) {
        if (!mem_grow((void **)&c->segs, &c->cap, c->n + 1, sizeof(*c->segs)))
            return SF_ENOMEM;
        struct seg *s = &c->segs[c->n++];
        s->x0 = (float)c->x;
        s->y0 = (float)c->y;
        s->x1 = (float)mv->x;
        s->y1 = (float)mv->y;
        s->role = mv->de > 0 ? role_of(mv) : 0;
        s->w = 0.45f;
    }
    c->x = mv->x;
    c->y = mv->y;
    c->have = true;
    return SF_OK;
}

int
preview_gcode(const char *text, size_t len, const char *name, const struct preview_opts *o,
              const char *png_path, struct sf_err *err)
{
    struct est_limits lim;
    memset(&lim, 0, sizeof(lim));
    lim.accel_extrude_mm_s2 = lim.accel_travel_mm_s2 = lim.accel_retract_mm_s2 = 1000;
    struct estimate e;
    int rc = estimate_gcode(text, len, name, &lim, NULL, NULL, &e, err);
    if (rc < 0)
        return rc;
    uint32_t n_layers = e.n_layers;
    estimate_release(&e);
    if (!n_layers)
        return sf_err_set(err, SF_EINVAL, "%s: no ;LAYER_CHANGE comments", name);
    int layer = o->layer < 0 ? (int)n_layers / 2 : o->layer;
    if (layer >= (int)n_layers)
        return sf_err_set(err, SF_EINVAL, "%s: layer %d asked, the file has %u", name, layer,
                          n_layers);
    struct layer_moves c = { .layer = layer };
    rc = estimate_gcode(text, len, name, &lim, on_move, &c, &e, err);
    estimate_release(&e);
    if (rc < 0) {
        free(c.segs);
        free(c.seams);
        return rc == SF_ENOMEM ? sf_err_set(err, rc, "preview: out of memory") : rc;
    }
    double x0 = INFINITY, x1 = -INFINITY, y0 = INFINITY, y1 = -INFINITY;
    for (size_t i = 0; i < c.n; i++) {
        if (!c.segs[i].role)
            continue;
        x0 = fmin(x0, fmin(c.segs[i].x0, c.segs[i].x1));
        x1 = fmax(x1, fmax(c.segs[i].x0, c.segs[i].x1));
        y0 = fmin(y0, fmin(c.segs[i].y0, c.segs[i].y1));
        y1 = fmax(y1, fmax(c.segs[i].y0, c.segs[i].y1));
    }
    if (!isfinite(x0)) {
        x0 = y0 = 0;
        x1 = y1 = 1;
    }
    double sc = 0.9 * fmin(o->width_px / fmax(x1 - x0, 1), o->height_px / fmax(y1 - y0, 1));
    double ox = o->width_px / 2.0 - sc * (x0 + x1) / 2,
           oy = o->height_px / 2.0 + sc * (y0 + y1) / 2;
    cairo_surface_t *s = cairo_image_surface_create(CAIRO_FORMAT_ARGB32, o->width_px, o->height_px);
    cairo_t *cr = cairo_create(s);
    cairo_set_source_rgb(cr, 0.12, 0.12, 0.14);
    cairo_paint(cr);
    cairo_set_line_cap(cr, CAIRO_LINE_CAP_ROUND);
    for (int pass = 0; pass < 2; pass++) {
        for (size_t i = 0; i < c.n; i++) {
            const struct seg *g = &c.segs[i];
            if ((pass == 0) != (g->role == 0))
                continue;
            cairo_set_source_rgb(cr, role_colours[g->role].r, role_colours[g->role].g,
                                 role_colours[g->role].b);
            cairo_set_line_width(cr, g->role ? fmax(1, g->w * sc) : 0.5);
            cairo_move_to(cr, g->x0 * sc + ox, oy - g->y0 * sc);
            cairo_line_to(cr, g->x1 * sc + ox, oy - g->y1 * sc);
            cairo_stroke(cr);
        }
    }
    /* seams: every layer's as small grey dots (aligned seams make one line
       of them up the part, seen from above a dot), this layer's white */
    for (int pass = 0; pass < 2; pass++)
        for (size_t i = 0; i < c.n_seams; i++) {
            if ((c.seams[i][2] != 0) != (pass == 1))
                continue;
            double g = pass ? 1.0 : 0.55;
            cairo_set_source_rgb(cr, g, g, g);
            cairo_arc(cr, c.seams[i][0] * sc + ox, oy - c.seams[i][1] * sc, pass ? 3.5 : 1.5, 0,
                      2 * M_PI);
            cairo_fill(cr);
        }
    free(c.segs);
    free(c.seams);
    /* no text: cairo's toy font API pulls in fontconfig, whose caches
       live for the whole process (LeakSanitizer reports them) */
    return finish(s, cr, png_path, err);
}
