/*
 * toolpath.c - perimeters, skins and infill of one layer (see toolpath.h).
 *
 * Everything is Clipper offsets and booleans on the layer's region and its
 * neighbours' (read-only), so layers can be built in any order and on any
 * thread.  Infill lines come from tp_fill_lines: a family of parallel
 * lines over the region's bounding box, clipped as open paths.
 *
 * Thread: reentrant; no state outside the arguments.
 */
#include "toolpath.h"

#include <math.h>
#include <string.h>

#include "../src/base/err.h"
#include "../src/base/mem.h"
#include "clip_shim.h"

const char *
tp_role_name(enum tp_role r)
{
    static const char *const names[ROLE_N] = {
        "Support material", "Support material interface", "Perimeter", "External perimeter",
        "Solid infill",     "Top solid infill",           "Internal infill",
    };
    return (unsigned)r < ROLE_N ? names[r] : "Custom";
}

void
layer_paths_init(struct layer_paths *lp)
{
    paths_init(&lp->p);
    lp->info = NULL;
    lp->cap_info = 0;
}

void
layer_paths_release(struct layer_paths *lp)
{
    paths_release(&lp->p);
    free(lp->info);
    layer_paths_init(lp);
}

double
tp_spacing(double w_mm, double h_mm)
{
    return w_mm - h_mm * (1 - M_PI / 4);
}

/* Append every path of src with the same role. */
static int
add(struct layer_paths *lp, const struct paths *src, enum tp_role role, bool closed, double w)
{
    for (uint32_t k = 0; k < src->n; k++) {
        uint32_t n = paths_len(src, k);
        if (n < (closed ? 3u : 2u))
            continue;
        if (lp->p.n + 1 > lp->cap_info) {
            size_t cap = lp->cap_info;
            if (!mem_grow((void **)&lp->info, &cap, lp->p.n + 1, sizeof(*lp->info)))
                return SF_ENOMEM;
            lp->cap_info = (uint32_t)cap;
        }
        if (!paths_add(&lp->p, src->pts + src->start[k], n))
            return SF_ENOMEM;
        struct tp_info *i = &lp->info[lp->p.n - 1];
        i->role = (uint8_t)role;
        i->closed = closed;
        i->width_mm = (float)w;
    }
    return SF_OK;
}

int
tp_fill_lines(const struct paths *region, double angle_deg, double spacing_mm, struct paths *out)
{
    struct ipt lo, hi;
    if (!paths_bbox(region, &lo, &hi) || spacing_mm <= 0)
        return SF_OK;
    double a = angle_deg * M_PI / 180, dx = cos(a), dy = sin(a);
    double nx = -dy, ny = dx; /* line normal */
    double x[2] = { poly_mm(lo.x), poly_mm(hi.x) }, y[2] = { poly_mm(lo.y), poly_mm(hi.y) };
    double t0 = INFINITY, t1 = -INFINITY, o0 = INFINITY, o1 = -INFINITY;
    for (int i = 0; i < 4; i++) {
        double px = x[i & 1], py = y[i >> 1];
        double t = px * dx + py * dy, o = px * nx + py * ny;
        t0 = fmin(t0, t);
        t1 = fmax(t1, t);
        o0 = fmin(o0, o);
        o1 = fmax(o1, o);
    }
    t0 -= 1;
    t1 += 1;
    struct paths lines;
    paths_init(&lines);
    int rc = SF_ENOMEM;
    for (double o = ceil(o0 / spacing_mm) * spacing_mm; o <= o1; o += spacing_mm) {
        struct ipt seg[2] = { { poly_i(o * nx + t0 * dx), poly_i(o * ny + t0 * dy) },
                              { poly_i(o * nx + t1 * dx), poly_i(o * ny + t1 * dy) } };
        if (!paths_add(&lines, seg, 2))
            goto out;
    }
    struct paths clipped;
    paths_init(&clipped);
    rc = clip_lines(&lines, region, &clipped);
    if (rc == SF_OK && !paths_append(out, &clipped))
        rc = SF_ENOMEM;
    paths_release(&clipped);
out:
    paths_release(&lines);
    return rc;
}

/* out = intersection of the inner areas of layers [a, b); empty if the
   range leaves the stack (a surface is within reach). */
static int
intersect_range(const struct layer_stack *s, long a, long b, struct paths *out)
{
    paths_reset(out);
    if (a < 0 || b > (long)s->n)
        return SF_OK;
    struct paths tmp;
    paths_init(&tmp);
    if (!paths_append(out, &s->l[a].inner)) {
        paths_release(&tmp);
        return SF_ENOMEM;
    }
    int rc = SF_OK;
    for (long j = a + 1; j < b && rc == SF_OK && out->n; j++) {
        rc = clip_bool(CLIP_INTERSECTION, out, &s->l[j].inner, CLIP_NONZERO, &tmp);
        paths_move(out, &tmp);
    }
    paths_release(&tmp);
    return rc;
}

int
toolpath_areas(struct layer_stack *s, uint32_t k, const struct slice_profile *p)
{
    struct layer *L = &s->l[k];
    double sp = tp_spacing(p->width_mm, L->h_mm);
    paths_reset(&L->inner);
    paths_reset(&L->skin);
    int rc;
    if (p->perimeters > 0)
        rc = clip_offset(&L->region, -(p->width_mm / 2 + (p->perimeters - 1) * sp + sp / 2),
                         CLIP_JOIN_MITER, &L->inner);
    else
        rc = paths_append(&L->inner, &L->region) ? SF_OK : SF_ENOMEM;
    if (rc < 0 || !L->inner.n || p->skin_margin_mm <= 0)
        return rc;
    /* the seed of the skins: inner area open to the air above or below */
    struct paths a, b, c;
    paths_init(&a);
    paths_init(&b);
    paths_init(&c);
    if (k + 1 < s->n)
        rc = clip_bool(CLIP_DIFFERENCE, &L->inner, &s->l[k + 1].region, CLIP_NONZERO, &a);
    else if (!paths_append(&a, &L->inner))
        rc = SF_ENOMEM;
    if (rc == SF_OK && k > 0)
        rc = clip_bool(CLIP_DIFFERENCE, &L->inner, &s->l[k - 1].region, CLIP_NONZERO, &b);
    else if (rc == SF_OK && !paths_append(&b, &L->inner))
        rc = SF_ENOMEM;
    if (rc == SF_OK && !paths_append(&a, &b))
        rc = SF_ENOMEM;
    /* slivers thinner than a line are the shell's business, not a surface */
    if (rc == SF_OK)
        rc = clip_offset(&a, -p->solid_width_mm / 2, CLIP_JOIN_MITER, &b);
    if (rc == SF_OK && b.n)
        rc = clip_offset(&b, p->solid_width_mm / 2 + p->skin_margin_mm, CLIP_JOIN_SQUARE, &c);
    if (rc == SF_OK && c.n)
        rc = clip_bool(CLIP_INTERSECTION, &c, &L->inner, CLIP_NONZERO, &L->skin);
    paths_release(&a);
    paths_release(&b);
    paths_release(&c);
    return rc;
}

enum { T_AREA, T_TMP, T_TOPI, T_BOTI, T_KEEP, T_SOLID, T_TOP, T_SPARSE, T_LINES, T_N };

int
toolpath_layer(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
               const struct support_layer *sup, struct layer_paths *out)
{
    const struct layer *L = &s->l[k];
    double h = L->h_mm, w = p->width_mm, sw = p->solid_width_mm;
    double sp = tp_spacing(w, h), ssp = tp_spacing(sw, h);
    struct paths t[T_N];
    for (int i = 0; i < T_N; i++)
        paths_init(&t[i]);
    int rc = SF_OK;
#define TRY(x)                                                                                \
    do {                                                                                      \
        if ((rc = (x)) < 0)                                                                   \
            goto out;                                                                         \
    } while (0)

    /* support first: it is printed before the part it holds */
    if (sup && sup->body.n) {
        TRY(clip_offset(&sup->body, -sw / 2, CLIP_JOIN_MITER, &t[T_TMP]));
        TRY(add(out, &t[T_TMP], ROLE_SUPPORT, true, sw));
        paths_reset(&t[T_LINES]);
        TRY(tp_fill_lines(&t[T_TMP], k % 2 ? 90 : 0, p->support_spacing_mm, &t[T_LINES]));
        TRY(add(out, &t[T_LINES], ROLE_SUPPORT, false, sw));
    }
    if (sup && sup->iface.n) {
        paths_reset(&t[T_LINES]);
        TRY(clip_offset(&sup->iface, -sw / 2, CLIP_JOIN_MITER, &t[T_TMP]));
        TRY(tp_fill_lines(&t[T_TMP], k % 2 ? 90 : 0, ssp, &t[T_LINES]));
        TRY(add(out, &t[T_LINES], ROLE_INTERFACE, false, sw));
    }

    /* perimeters, inner loops first, external last */
    for (int i = p->perimeters - 1; i >= 0; i--) {
        TRY(clip_offset(&L->region, -(w / 2 + i * sp), CLIP_JOIN_MITER, &t[T_TMP]));
        TRY(add(out, &t[T_TMP], i ? ROLE_PERIMETER : ROLE_EXT_PERIMETER, true, w));
    }
    if (!paths_append(&t[T_AREA], &L->inner))
        TRY(SF_ENOMEM);
    if (!t[T_AREA].n)
        goto out;

    /* skins: solid where a top or bottom surface is within reach */
    TRY(intersect_range(s, (long)k + 1, (long)k + 1 + p->top_layers, &t[T_TOPI]));
    if (p->top_layers == 0 && !paths_append(&t[T_TOPI], &t[T_AREA]))
        TRY(SF_ENOMEM);
    TRY(intersect_range(s, (long)k - p->bottom_layers, (long)k, &t[T_BOTI]));
    if (p->bottom_layers == 0 && !paths_append(&t[T_BOTI], &t[T_AREA]))
        TRY(SF_ENOMEM);
    TRY(clip_bool(CLIP_INTERSECTION, &t[T_TOPI], &t[T_BOTI], CLIP_NONZERO, &t[T_KEEP]));
    TRY(clip_bool(CLIP_DIFFERENCE, &t[T_AREA], &t[T_KEEP], CLIP_NONZERO, &t[T_SOLID]));
    if (p->skin_margin_mm > 0) {
        /* surfaces within reach above and below, grown into the infill
           (PrusaSlicer 2.5 anchors them 3 mm: EXTERNAL_INFILL_MARGIN) */
        paths_reset(&t[T_LINES]);
        for (long j = (long)k - p->bottom_layers + 1; j < (long)k + p->top_layers; j++)
            if (j >= 0 && j < (long)s->n && !paths_append(&t[T_LINES], &s->l[j].skin))
                TRY(SF_ENOMEM);
        if (t[T_LINES].n) {
            if (!paths_append(&t[T_LINES], &t[T_SOLID]))
                TRY(SF_ENOMEM);
            TRY(clip_bool(CLIP_UNION, &t[T_LINES], NULL, CLIP_NONZERO, &t[T_TMP]));
            TRY(clip_bool(CLIP_INTERSECTION, &t[T_TMP], &t[T_AREA], CLIP_NONZERO, &t[T_SOLID]));
        }
    }
    TRY(clip_bool(CLIP_DIFFERENCE, &t[T_AREA], &t[T_SOLID], CLIP_NONZERO, &t[T_SPARSE]));
    if (p->top_layers > 0) {
        /* the part of the solid the next layer does not cover is the top surface */
        if (k + 1 < s->n) {
            TRY(clip_bool(CLIP_DIFFERENCE, &t[T_SOLID], &s->l[k + 1].region, CLIP_NONZERO,
                          &t[T_TOP]));
            TRY(clip_bool(CLIP_INTERSECTION, &t[T_SOLID], &s->l[k + 1].region, CLIP_NONZERO,
                          &t[T_TMP]));
            paths_move(&t[T_SOLID], &t[T_TMP]);
        } else {
            paths_move(&t[T_TOP], &t[T_SOLID]);
        }
    }
    double ang = k % 2 ? 135 : 45;
    paths_reset(&t[T_LINES]);
    TRY(tp_fill_lines(&t[T_SOLID], ang, ssp, &t[T_LINES]));
    TRY(add(out, &t[T_LINES], ROLE_SOLID, false, sw));
    paths_reset(&t[T_LINES]);
    TRY(tp_fill_lines(&t[T_TOP], ang, ssp, &t[T_LINES]));
    TRY(add(out, &t[T_LINES], ROLE_TOP, false, sw));
    if (p->infill_density > 0 && t[T_SPARSE].n) {
        paths_reset(&t[T_LINES]);
        if (strcmp(p->infill_pattern, "grid") == 0) {
            double gsp = 2 * sp / p->infill_density;
            TRY(tp_fill_lines(&t[T_SPARSE], 45, gsp, &t[T_LINES]));
            TRY(tp_fill_lines(&t[T_SPARSE], 135, gsp, &t[T_LINES]));
        } else {
            TRY(tp_fill_lines(&t[T_SPARSE], ang, sp / p->infill_density, &t[T_LINES]));
        }
        TRY(add(out, &t[T_LINES], ROLE_INFILL, false, w));
    }
#undef TRY
out:
    for (int i = 0; i < T_N; i++)
        paths_release(&t[i]);
    return rc;
}
