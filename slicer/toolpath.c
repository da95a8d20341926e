/*
 * toolpath.c - the paths of one layer (see toolpath.h): the per-layer
 * driver that runs the stages in print order (support, perimeters and
 * their gaps, gap fill of narrow infill, bridges, solid, top and sparse
 * infill, overhang marks) and groups the result island by island; and
 * the layer_paths container the stages append to.
 *
 * The stages live in toolpath_*.c (toolpath_int.h): regions (inner
 * areas, skins, solid/top/sparse), perim (loops, overhangs), gap, bridge,
 * infill (fill lines, links), anchor (sparse lines joined along the
 * boundary), skirt (skirt and brim).  Everything is Clipper offsets and
 * booleans on the layer's region and its neighbours' (read-only), so
 * layers can be built in any order and on any thread.
 *
 * Thread: reentrant; no state outside the arguments.
 */
#include "toolpath.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../src/base/err.h"
#include "../src/base/mem.h"
#include "../src/base/uf.h"
#include "clip_shim.h"
#include "toolpath_int.h"

const char *
tp_role_name(enum tp_role r)
{
    static const char *const names[ROLE_N] = {
        "Support material",   "Support material interface",
        "Perimeter",          "External perimeter",
        "Solid infill",       "Top solid infill",
        "Internal infill",    "Bridge infill",
        "Skirt/Brim",         "Gap fill",
        "Overhang perimeter",
    };
    return (unsigned)r < ROLE_N ? names[r] : "Custom";
}

void
layer_paths_init(struct layer_paths *lp)
{
    paths_init(&lp->p);
    lp->info = NULL;
    lp->cap_info = 0;
    lp->ovh = NULL;
    lp->cap_ovh = 0;
}

void
layer_paths_release(struct layer_paths *lp)
{
    paths_release(&lp->p);
    free(lp->info);
    free(lp->ovh);
    layer_paths_init(lp);
}

/* Make lp->ovh cover every point of lp->p (new ones 0); copy from
   src[0..n) at point `at` when src is given.  False on ENOMEM. */
bool
tp_ovh_fill(struct layer_paths *lp, size_t at, const uint8_t *src, size_t n)
{
    size_t np = lp->p.n ? lp->p.start[lp->p.n] : 0, old = lp->ovh ? lp->cap_ovh : 0;
    if (!mem_grow((void **)&lp->ovh, &lp->cap_ovh, np, 1))
        return false;
    if (lp->cap_ovh > old)
        memset(lp->ovh + old, 0, lp->cap_ovh - old);
    if (src)
        memcpy(lp->ovh + at, src, n);
    return true;
}

double
tp_spacing(double w_mm, double h_mm)
{
    return w_mm - h_mm * (1 - M_PI / 4);
}

/* Append every path of src with the same role. */
int
tp_add(struct layer_paths *lp, const struct paths *src, enum tp_role role, bool closed, double w)
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
        if (lp->ovh && !tp_ovh_fill(lp, 0, NULL, 0))
            return SF_ENOMEM;
        struct tp_info *i = &lp->info[lp->p.n - 1];
        i->role = (uint8_t)role;
        i->closed = closed;
        i->width_mm = (float)w;
    }
    return SF_OK;
}

/* Islands beyond this print role by role across the layer (the grouping is
   islands x paths point-in-polygon tests). */
#define ISLANDS_MAX 64
/* Support lines are joined along the boundary however long the arc, as
   PrusaSlicer 2.5 links its support fill (link_max_length_factor 0 in
   SupportMaterial.cpp: no limit); this only bounds the search. */
#define SUPPORT_LINK_MAX_MM 1000.0

/*
 * Reorder the part's paths island by island (support stays first), keeping
 * the role order within an island, so the nozzle finishes one island
 * before travelling to the next instead of visiting every island once per
 * role.  Islands are visited nearest-first from the first one.
 */
static int
group_by_island(const struct paths *region, struct layer_paths *lp)
{
    uint32_t outers[ISLANDS_MAX], n_isl = 0;
    for (uint32_t k = 0; k < region->n; k++) {
        if (paths_area_k(region, k) <= 0)
            continue;
        if (n_isl == ISLANDS_MAX)
            return SF_OK;
        outers[n_isl++] = k;
    }
    if (n_isl < 2 || lp->p.n < 2)
        return SF_OK;
    int rc = SF_ENOMEM;
    uint8_t *isl = mem_array(lp->p.n, 1);
    struct paths outline[ISLANDS_MAX];
    struct paths_index ix[ISLANDS_MAX];
    double area[ISLANDS_MAX], cx[ISLANDS_MAX], cy[ISLANDS_MAX];
    uint32_t n_ix = 0;
    struct layer_paths out;
    layer_paths_init(&out);
    for (uint32_t i = 0; i < n_isl; i++)
        paths_init(&outline[i]);
    if (!isl)
        goto fail;
    for (; n_ix < n_isl; n_ix++) {
        uint32_t k = outers[n_ix];
        struct ipt lo, hi;
        if (!paths_add(&outline[n_ix], region->pts + region->start[k], paths_len(region, k)) ||
            !paths_index_init(&ix[n_ix], &outline[n_ix]))
            goto fail;
        paths_bbox(&outline[n_ix], &lo, &hi);
        cx[n_ix] = poly_mm(lo.x / 2 + hi.x / 2);
        cy[n_ix] = poly_mm(lo.y / 2 + hi.y / 2);
        area[n_ix] = paths_area_k(region, k);
    }
    /* each part path belongs to the smallest island outline containing its first point */
    for (uint32_t k = 0; k < lp->p.n; k++) {
        isl[k] = 0xff;
        if (tp_role_is_support(lp->info[k].role))
            continue;
        struct ipt q = lp->p.pts[lp->p.start[k]];
        double best = INFINITY;
        for (uint32_t i = 0; i < n_isl; i++)
            if (area[i] < best && paths_index_contains(&ix[i], q))
                best = area[i], isl[k] = (uint8_t)i;
        if (isl[k] == 0xff)
            isl[k] = 0; /* on an outline exactly: any island will do */
    }
    /* support first, then islands nearest-first */
    bool done[ISLANDS_MAX] = { false };
    double x = cx[0], y = cy[0];
    for (int pass = -1; pass < (int)n_isl; pass++) {
        uint32_t pick = 0xff;
        if (pass >= 0) {
            double bd = INFINITY;
            for (uint32_t i = 0; i < n_isl; i++) {
                double d = hypot(cx[i] - x, cy[i] - y);
                if (!done[i] && d < bd)
                    bd = d, pick = i;
            }
            done[pick] = true;
            x = cx[pick];
            y = cy[pick];
        }
        for (uint32_t k = 0; k < lp->p.n; k++) {
            bool sup = tp_role_is_support(lp->info[k].role);
            if (pass < 0 ? !sup : (sup || isl[k] != pick))
                continue;
            if (out.p.n + 1 > out.cap_info) {
                size_t cap = out.cap_info;
                if (!mem_grow((void **)&out.info, &cap, out.p.n + 1, sizeof(*out.info)))
                    goto fail;
                out.cap_info = (uint32_t)cap;
            }
            if (!paths_add(&out.p, lp->p.pts + lp->p.start[k], paths_len(&lp->p, k)))
                goto fail;
            if (lp->ovh && !tp_ovh_fill(&out, out.p.start[out.p.n - 1], lp->ovh + lp->p.start[k],
                                        paths_len(&lp->p, k)))
                goto fail;
            out.info[out.p.n - 1] = lp->info[k];
        }
    }
    layer_paths_release(lp);
    *lp = out;
    layer_paths_init(&out);
    rc = SF_OK;
fail:
    for (uint32_t i = 0; i < n_ix; i++)
        paths_index_release(&ix[i]);
    for (uint32_t i = 0; i < n_isl; i++)
        paths_release(&outline[i]);
    layer_paths_release(&out);
    free(isl);
    return rc;
}

/* Support paths of layer k (sup: its regions), printed before the part
   they hold: the body's outline (sheath) and lines, the interface's dense
   lines; all of support_line_width (h: the layer's height).  As
   PrusaSlicer 2.5 prints grid-style support (SupportMaterial.cpp,
   generate_toolpaths): the body's lines all run one way (its
   support_material_angle, 0), support_spacing apart plus a line
   (support_material_spacing is the gap between lines), over the sheath's
   inside less 0.4 spacing, on a grid through the part's centre (org); the
   interface's across them; the bed layer 90 % dense across them too. */
static int
support_paths(uint32_t k, const struct slice_profile *p, double h, const double org[2],
              const struct support_layer *sup, struct paths *t, struct layer_paths *out)
{
    double sw = p->support_width_mm, ssp = tp_spacing(sw, h);
    int rc = SF_OK;
    if (sup && sup->body.n) {
        TP_TRY(clip_offset(&sup->body, -sw / 2, CLIP_JOIN_MITER, &t[T_TMP]));
        TP_TRY(tp_add(out, &t[T_TMP], ROLE_SUPPORT, true, sw));
        TP_TRY(clip_offset(&t[T_TMP], -0.4 * ssp, CLIP_JOIN_MITER, &t[T_KEEP]));
        paths_reset(&t[T_LINES]);
        double bsp = k == 0 ? ssp / 0.9 : p->support_spacing_mm + tp_spacing(sw, p->layer_mm);
        TP_TRY(tp_fill_lines(&t[T_KEEP], k == 0 ? 90 : 0, bsp, org[0], org[1], &t[T_LINES]));
        TP_TRY(tp_anchor(&t[T_LINES], &t[T_KEEP], 0, SUPPORT_LINK_MAX_MM, sw / 2));
        TP_TRY(tp_add(out, &t[T_LINES], ROLE_SUPPORT, false, sw));
    }
    if (sup && sup->iface.n) {
        paths_reset(&t[T_LINES]);
        TP_TRY(clip_offset(&sup->iface, -sw / 2, CLIP_JOIN_MITER, &t[T_TMP]));
        TP_TRY(tp_fill_lines(&t[T_TMP], 90, ssp, org[0], org[1], &t[T_LINES]));
        TP_TRY(tp_link(&t[T_LINES], &t[T_TMP], 2 * ssp, sw / 2));
        TP_TRY(tp_add(out, &t[T_LINES], ROLE_INTERFACE, false, sw));
    }
out:
    return rc;
}

/* Solid and top solid lines over t[T_SOLID] and t[T_TOP], zig-zag linked,
   at angle ang.  The lines and their links stop half a spacing inside the
   area grown infill_overlap (sp: the loops' spacing) into the loops, as
   PrusaSlicer 2.5's zig-zag does (FillRectilinear links its lines along
   the area shrunk half a spacing): 0.1 mm inside the inner area at the
   defaults.  Run to the inner edge, a 4 mm arm's solid laid 3.93 mm of
   lines across where PrusaSlicer lays 3.73 (the hook of the mech set:
   5.9 % more solid infill on every layer). */
static int
solid_paths(const struct slice_profile *p, double sp, double ssp, double ang, const double org[2],
            struct paths *t, struct layer_paths *out)
{
    double sw = p->solid_width_mm, in = 0.5 * ssp - p->infill_overlap * sp;
    int rc = SF_OK;
    for (int top = 0; top < 2; top++) {
        const struct paths *area = &t[top ? T_TOP : T_SOLID];
        if (!area->n)
            continue;
        paths_reset(&t[T_KEEP]);
        if (in > 0)
            TP_TRY(clip_offset(area, -in, CLIP_JOIN_MITER, &t[T_KEEP]));
        else if (!paths_append(&t[T_KEEP], area))
            TP_TRY(SF_ENOMEM);
        paths_reset(&t[T_LINES]);
        TP_TRY(tp_fill_lines(&t[T_KEEP], ang, ssp, org[0], org[1], &t[T_LINES]));
        TP_TRY(tp_link(&t[T_LINES], &t[T_KEEP], 2 * ssp, sw / 2));
        TP_TRY(tp_add(out, &t[T_LINES], top ? ROLE_TOP : ROLE_SOLID, false, sw));
    }
out:
    return rc;
}

/* Sparse infill over t[T_SPARSE]: grid or rectilinear lines, joined and
   anchored along the boundary (tp_anchor). */
static int
sparse_paths(const struct slice_profile *p, double sp, double ang, const double org[2],
             struct paths *t, struct layer_paths *out)
{
    double w = p->width_mm;
    int rc = SF_OK;
    if (p->infill_density > 0 && t[T_SPARSE].n) {
        /* the lines' ends and anchors run half a line inside the sparse
           area grown infill_overlap into the loops, as PrusaSlicer fills
           its infill areas (fill_surface_by_multilines: the area shrunk by
           half a spacing) */
        TP_TRY(clip_offset(&t[T_SPARSE], p->infill_overlap * sp - sp / 2, CLIP_JOIN_MITER,
                           &t[T_KEEP]));
        paths_reset(&t[T_LINES]);
        if (strcmp(p->infill_pattern, "grid") == 0) {
            double gsp = 2 * sp / p->infill_density;
            TP_TRY(tp_fill_lines(&t[T_KEEP], 45, gsp, org[0], org[1], &t[T_LINES]));
            TP_TRY(tp_fill_lines(&t[T_KEEP], 135, gsp, org[0], org[1], &t[T_LINES]));
        } else {
            TP_TRY(tp_fill_lines(&t[T_KEEP], ang, sp / p->infill_density, org[0], org[1],
                                 &t[T_LINES]));
        }
        TP_TRY(tp_anchor(&t[T_LINES], &t[T_KEEP], p->infill_anchor_mm, p->infill_anchor_max_mm,
                         sp / 2));
        TP_TRY(tp_add(out, &t[T_LINES], ROLE_INFILL, false, w));
    }
out:
    return rc;
}

void
tp_scratch_init(struct paths *t)
{
    for (int i = 0; i < T_N; i++)
        paths_init(&t[i]);
}

void
tp_scratch_release(struct paths *t)
{
    for (int i = 0; i < T_N; i++)
        paths_release(&t[i]);
}

int
toolpath_layer(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
               const struct support_layer *sup, struct layer_paths *out)
{
    const struct layer *L = &s->l[k];
    double h = L->h_mm, w = p->width_mm, sw = p->solid_width_mm;
    double sp = tp_spacing(w, h), ssp = tp_spacing(sw, h);
    /* the part's fills run on a grid through its bounding-box centre, as
       PrusaSlicer's (Fill::_infill_direction), so both line up on a part */
    const double org[2] = { s->cx_mm, s->cy_mm };
    struct paths t[T_N];
    tp_scratch_init(t);
    int rc;
    TP_TRY(support_paths(k, p, h, org, sup, t, out));
    TP_TRY(tp_perimeters(L, p, sp, t, out));
    TP_TRY(tp_gap_fill_loops(h, p, sp, t, out));
    if (!L->inner.n)
        goto out;
    TP_TRY(tp_regions_of(s, k, p, &t[T_SOLID], &t[T_TOP], &t[T_SPARSE]));
    if (p->gap_fill)
        TP_TRY(tp_gap_fill_narrow(h, p, sp, ssp, t, out));
    double ang = k % 2 ? 135 : 45;
    TP_TRY(tp_bridges_over_air(s, k, p, org, t, out));
    TP_TRY(tp_bridges_over_sparse(s, k, p, ang, org, t, out));
    TP_TRY(solid_paths(p, sp, ssp, ang, org, t, out));
    TP_TRY(sparse_paths(p, sp, ang, org, t, out));
    TP_TRY(tp_mark_overhangs(s, k, p, out, &t[T_TMP], &t[T_LINES]));
    TP_TRY(group_by_island(&L->region, out));
out:
    tp_scratch_release(t);
    return rc;
}
