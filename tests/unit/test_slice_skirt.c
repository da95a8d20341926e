/*
 * test_slice_skirt.c - skirt and brim on generated parts, read back from
 * the G-code: the skirt's loops lie skirt_distance outside the part, the
 * brim hugs it brim_width wide, the automatic brim picks tall parts on
 * small footprints, and neither touches a support (the tee's columns
 * stand right beside its stem).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../slicer/estimate.h"
#include "../../slicer/slice.h"
#include "../../src/base/buf.h"
#include "../../src/base/mem.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"
#include "slice_run.h"

struct seg {
    double x0, y0, x1, y1;
};

struct segs {
    struct seg *s;
    size_t n, cap;
};

/* Extrusion segments of layer 0 (and of later layers under skirt) by kind. */
struct first_layer {
    struct segs skirt, support, part;
    uint32_t skirt_layers_above; /* skirt moves on layers > 0 */
    double x, y;
};

static int
push(struct segs *v, double x0, double y0, double x1, double y1)
{
    if (!mem_grow((void **)&v->s, &v->cap, v->n + 1, sizeof(*v->s)))
        return SF_ENOMEM;
    v->s[v->n++] = (struct seg){ x0, y0, x1, y1 };
    return SF_OK;
}

static int
on_move(void *ud, const struct est_move *mv)
{
    struct first_layer *f = ud;
    bool skirt = mv->type && mv->type_len == 10 && memcmp(mv->type, "Skirt/Brim", 10) == 0;
    int rc = SF_OK;
    if (mv->de > 0 && (mv->x != f->x || mv->y != f->y)) {
        if (mv->layer > 0)
            f->skirt_layers_above += skirt;
        else if (skirt)
            rc = push(&f->skirt, f->x, f->y, mv->x, mv->y);
        else if (mv->support)
            rc = push(&f->support, f->x, f->y, mv->x, mv->y);
        else
            rc = push(&f->part, f->x, f->y, mv->x, mv->y);
    }
    f->x = mv->x;
    f->y = mv->y;
    return rc;
}

static void
first_layer_release(struct first_layer *f)
{
    free(f->skirt.s);
    free(f->support.s);
    free(f->part.s);
}

static int
slice_first_layer(const struct mesh *m, const struct slice_profile *p, const char *name,
                  struct slice_result *r, struct first_layer *f, struct sf_err *err)
{
    memset(f, 0, sizeof(*f));
    return ts_slice_walk(m, p, name, r, on_move, f, err);
}

/* Distance from (x, y) to the axis-aligned rectangle [x0,x1] x [y0,y1] (0 inside). */
static double
rect_dist(double x, double y, double x0, double y0, double x1, double y1)
{
    double dx = fmax(fmax(x0 - x, 0), x - x1), dy = fmax(fmax(y0 - y, 0), y - y1);
    return hypot(dx, dy);
}

static double
pt_seg(double px, double py, const struct seg *s)
{
    double dx = s->x1 - s->x0, dy = s->y1 - s->y0, l2 = dx * dx + dy * dy;
    double t = l2 > 0 ? ((px - s->x0) * dx + (py - s->y0) * dy) / l2 : 0;
    t = t < 0 ? 0 : t > 1 ? 1 : t;
    return hypot(s->x0 + t * dx - px, s->y0 + t * dy - py);
}

static double
orient(double ax, double ay, double bx, double by, double cx, double cy)
{
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax);
}

/* Distance between two segments (0 when they cross). */
static double
seg_seg(const struct seg *a, const struct seg *b)
{
    double d1 = orient(a->x0, a->y0, a->x1, a->y1, b->x0, b->y0),
           d2 = orient(a->x0, a->y0, a->x1, a->y1, b->x1, b->y1),
           d3 = orient(b->x0, b->y0, b->x1, b->y1, a->x0, a->y0),
           d4 = orient(b->x0, b->y0, b->x1, b->y1, a->x1, a->y1);
    if (((d1 > 0) != (d2 > 0)) && ((d3 > 0) != (d4 > 0)))
        return 0;
    return fmin(fmin(pt_seg(a->x0, a->y0, b), pt_seg(a->x1, a->y1, b)),
                fmin(pt_seg(b->x0, b->y0, a), pt_seg(b->x1, b->y1, a)));
}

T_CASE(skirt_loops_at_the_distance)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_box(&m, v3(0, 0, 0), v3(10, 10, 5), &err), &err);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    p.support = false;
    p.skirts = 2;
    p.skirt_distance_mm = 3;
    p.brim_auto = false;
    p.arc_fitting = false; /* measured along the moves' end points */
    struct slice_result r;
    struct first_layer f;
    T_OK(slice_first_layer(&m, &p, "skirt", &r, &f, &err), &err);
    /* the cube sits centred on the bed: 120..130 x 100..110 */
    double sp = p.width_mm - 0.2 * (1 - M_PI / 4), lo = 1e9, hi = 0, len = 0;
    for (size_t i = 0; i < f.skirt.n; i++) {
        const struct seg *s = &f.skirt.s[i];
        double d = rect_dist(s->x1, s->y1, 120, 100, 130, 110);
        lo = fmin(lo, d);
        hi = fmax(hi, d);
        len += hypot(s->x1 - s->x0, s->y1 - s->y0);
    }
    /* line centres at 3 + w/2 and one spacing further out */
    if (fabs(lo - (3 + p.width_mm / 2)) > 0.02 || fabs(hi - (3 + p.width_mm / 2 + sp)) > 0.02)
        t_fail(__FILE__, __LINE__, "skirt %.3f..%.3f mm from the cube", lo, hi);
    double want = 2 * 40 + 2 * M_PI * (2 * (3 + p.width_mm / 2) + sp); /* two rounded squares */
    if (fabs(len - want) > 0.02 * want)
        t_fail(__FILE__, __LINE__, "skirt %.1f mm long, want %.1f", len, want);
    T_EQ_INT(f.skirt_layers_above, 0);
    T_EQ_DBL(r.brim_mm, 0, 0);
    first_layer_release(&f);
    /* skirts = 0: none */
    p.skirts = 0;
    T_OK(slice_first_layer(&m, &p, "noskirt", &r, &f, &err), &err);
    T_EQ_INT(f.skirt.n, 0);
    first_layer_release(&f);
    /* skirt_height = 3: three layers of it */
    p.skirts = 1;
    p.skirt_height = 3;
    T_OK(slice_first_layer(&m, &p, "skirt3", &r, &f, &err), &err);
    T_TRUE(f.skirt.n > 0 && f.skirt_layers_above >= 2 * 4);
    first_layer_release(&f);
    slice_profile_release(&p);
    mesh_release(&m);
}

T_CASE(brim_hugs_the_part_and_auto_brim_picks_tall_parts)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_box(&m, v3(0, 0, 0), v3(10, 10, 5), &err), &err);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    p.support = false;
    p.skirts = 0;
    p.brim_width_mm = 4;
    p.arc_fitting = false;
    struct slice_result r;
    struct first_layer f;
    T_OK(slice_first_layer(&m, &p, "brim", &r, &f, &err), &err);
    T_EQ_DBL(r.brim_mm, 4, 0);
    double sp = p.width_mm - 0.2 * (1 - M_PI / 4), lo = 1e9, hi = 0;
    for (size_t i = 0; i < f.skirt.n; i++) {
        double d = rect_dist(f.skirt.s[i].x1, f.skirt.s[i].y1, 120, 100, 130, 110);
        lo = fmin(lo, d);
        hi = fmax(hi, d);
    }
    int loops = (int)floor(4 / sp);
    if (fabs(lo - sp / 2) > 0.02 || fabs(hi - (sp / 2 + (loops - 1) * sp)) > 0.02 || hi > 4)
        t_fail(__FILE__, __LINE__, "brim %.3f..%.3f mm out, want %.3f..%.3f", lo, hi, sp / 2,
               sp / 2 + (loops - 1) * sp);
    first_layer_release(&f);

    /* automatic: a 10 x 10 x 5 block stands on its own, a 6 x 6 x 30
       tower (30 > 3 x 6) gets brim_auto_width */
    p.brim_width_mm = 0;
    p.brim_auto = true;
    T_OK(slice_first_layer(&m, &p, "noautobrim", &r, &f, &err), &err);
    T_EQ_INT(f.skirt.n, 0);
    T_EQ_DBL(r.brim_mm, 0, 0);
    first_layer_release(&f);
    mesh_release(&m);
    mesh_init(&m);
    T_OK(shape_box(&m, v3(0, 0, 0), v3(6, 6, 30), &err), &err);
    T_OK(slice_first_layer(&m, &p, "autobrim", &r, &f, &err), &err);
    T_EQ_DBL(r.brim_mm, p.brim_auto_width_mm, 0);
    T_TRUE(f.skirt.n > 0);
    hi = 0;
    for (size_t i = 0; i < f.skirt.n; i++)
        hi = fmax(hi, rect_dist(f.skirt.s[i].x1, f.skirt.s[i].y1, 122, 102, 128, 108));
    T_TRUE(hi > p.brim_auto_width_mm - sp && hi <= p.brim_auto_width_mm);
    first_layer_release(&f);
    /* a 6 x 6 x 17 one does not (17 < 18) */
    mesh_release(&m);
    mesh_init(&m);
    T_OK(shape_box(&m, v3(0, 0, 0), v3(6, 6, 17), &err), &err);
    T_OK(slice_first_layer(&m, &p, "autobrim17", &r, &f, &err), &err);
    T_EQ_DBL(r.brim_mm, 0, 0);
    first_layer_release(&f);
    slice_profile_release(&p);
    mesh_release(&m);
}

T_CASE(skirt_and_brim_keep_clear_of_supports)
{
    /* the tee: its stem (x -5..5) stands on the bed, the arms' support
       columns stand 0.3 mm beside it, inside a 5 mm brim's reach */
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    p.brim_width_mm = 5;
    p.skirts = 1;
    p.arc_fitting = false;
    p.skirt_distance_mm = 2;
    struct slice_result r;
    struct first_layer f;
    T_OK(slice_first_layer(&m, &p, "tee_brim", &r, &f, &err), &err);
    T_TRUE(f.support.n > 0 && f.skirt.n > 0);
    /* no brim or skirt line within a line width of a support line, centre to centre */
    double closest = 1e9;
    for (size_t i = 0; i < f.skirt.n; i++)
        for (size_t j = 0; j < f.support.n; j++)
            closest = fmin(closest, seg_seg(&f.skirt.s[i], &f.support.s[j]));
    if (closest < p.width_mm - 1e-3)
        t_fail(__FILE__, __LINE__, "a brim or skirt line passes %.3f mm from support", closest);
    /* the brim is there where the support is not: along the stem's y sides */
    size_t n_brim = 0;
    double sx0 = 1e9, sx1 = -1e9, kx0 = 1e9, kx1 = -1e9;
    for (size_t i = 0; i < f.skirt.n; i++) {
        const struct seg *s = &f.skirt.s[i];
        n_brim += rect_dist(s->x1, s->y1, 120, 95, 130, 115) < 5;
        kx0 = fmin(kx0, s->x1);
        kx1 = fmax(kx1, s->x1);
    }
    T_TRUE(n_brim > 10);
    /* the skirt goes around the support too */
    for (size_t j = 0; j < f.support.n; j++) {
        sx0 = fmin(sx0, fmin(f.support.s[j].x0, f.support.s[j].x1));
        sx1 = fmax(sx1, fmax(f.support.s[j].x0, f.support.s[j].x1));
    }
    if (!(kx0 < sx0 - 2 && kx1 > sx1 + 2))
        t_fail(__FILE__, __LINE__, "skirt x %.2f..%.2f, support x %.2f..%.2f", kx0, kx1, sx0, sx1);
    first_layer_release(&f);
    slice_profile_release(&p);
    mesh_release(&m);
}
