/*
 * toolpath_perim.c - perimeter loops and their overhanging segments.
 *
 * Thread: reentrant; no state outside the arguments.
 */
#include "toolpath.h"

#include <stdlib.h>

#include "../src/base/err.h"
#include "../src/base/mem.h"
#include "clip_shim.h"
#include "toolpath_int.h"

/* The loops' grown outlines reach this much further when the gaps are cut
   out of the region: 1 um, more than the offsets' rounding. */
#define GAP_SAFETY_MM 0.001

/* Flags of q[a..b] (one segment, split to ~0.05 mm where it leaves
   below): append the points after a and their segments' flags. */
static bool
ovh_segment(const struct paths_index *below, struct ipt a, struct ipt b, bool in_a, bool in_b,
            struct paths *pts, uint8_t **fl, size_t *cap, size_t *n, int depth)
{
    if (in_a == in_b && !paths_index_crosses(below, a, b)) {
        if (!mem_grow((void **)fl, cap, *n + 1, 1) || !paths_push(pts, b))
            return false;
        (*fl)[(*n)++] = !in_a; /* the flag of the segment ending at b */
        return true;
    }
    if (depth == 0 || tp_d2(a, b) < (double)poly_i(0.05) * (double)poly_i(0.05)) {
        struct ipt m = { a.x / 2 + b.x / 2, a.y / 2 + b.y / 2 };
        if (!mem_grow((void **)fl, cap, *n + 1, 1) || !paths_push(pts, b))
            return false;
        (*fl)[(*n)++] = !paths_index_contains(below, m);
        return true;
    }
    struct ipt m = { a.x / 2 + b.x / 2, a.y / 2 + b.y / 2 };
    bool in_m = paths_index_contains(below, m);
    return ovh_segment(below, a, m, in_a, in_m, pts, fl, cap, n, depth - 1) &&
           ovh_segment(below, m, b, in_m, in_b, pts, fl, cap, n, depth - 1);
}

/*
 * Overhang perimeters (PrusaSlicer's "overhangs": bridge flow, bridge
 * speed and fan): the segments of layer k's perimeter loops whose centre
 * line lies outside the layer below grown by half a nozzle, i.e. where
 * the whole nozzle width is over air.  Loops are rebuilt with a vertex
 * where they leave and re-enter that area; out gets the flags.
 */
int
tp_mark_overhangs(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
                  struct layer_paths *out, struct paths *grown, struct paths *tmp)
{
    /* a loop's centre (at least half a line in) more than half a nozzle
       out from the layer below puts a disc that wide in the bottom
       surface, which its opening (a tenth of a line) keeps: no bottom
       skin, no overhang */
    if (k == 0 || !p->overhangs || !out->p.n || !s->l[k].skin_bottom.n)
        return SF_OK;
    int rc = clip_offset(&s->l[k - 1].region, p->nozzle_mm / 2, CLIP_JOIN_MITER, grown);
    if (rc < 0)
        return rc;
    struct paths_index below = { 0 };
    if (!paths_index_init(&below, grown))
        return SF_ENOMEM;
    struct layer_paths lp;
    layer_paths_init(&lp);
    uint8_t *fl = NULL;
    size_t cap = 0;
    bool any = false;
    rc = SF_OK;
    for (uint32_t k2 = 0; k2 < out->p.n && rc == SF_OK; k2++) {
        const struct tp_info *in = &out->info[k2];
        const struct ipt *q = out->p.pts + out->p.start[k2];
        uint32_t m = paths_len(&out->p, k2);
        size_t nf = 0;
        paths_reset(tmp);
        bool is_loop = in->closed && (in->role == ROLE_PERIMETER || in->role == ROLE_EXT_PERIMETER);
        bool hit = false;
        if (is_loop) {
            if (!paths_begin(tmp) || !paths_push(tmp, q[0]))
                rc = SF_ENOMEM;
            bool in0 = paths_index_contains(&below, q[0]), in_a = in0;
            for (uint32_t i = 0; i < m && rc == SF_OK; i++) {
                struct ipt b = q[(i + 1) % m];
                bool in_b = i + 1 < m ? paths_index_contains(&below, b) : in0;
                if (!ovh_segment(&below, q[i], b, in_a, in_b, tmp, &fl, &cap, &nf, 12))
                    rc = SF_ENOMEM;
                in_a = in_b;
            }
            for (size_t i = 0; i < nf; i++)
                hit |= fl[i];
        }
        if (rc < 0)
            break;
        if (lp.p.n + 1 > lp.cap_info) {
            size_t c = lp.cap_info;
            if (!mem_grow((void **)&lp.info, &c, lp.p.n + 1, sizeof(*lp.info))) {
                rc = SF_ENOMEM;
                break;
            }
            lp.cap_info = (uint32_t)c;
        }
        if (hit) {
            /* tmp holds q[0], the points after it and q[0] again: drop the
               last (the loop closes itself); flag i is of the segment
               from point i, so fl is already in place */
            uint32_t nt = paths_len(tmp, 0) - 1;
            if (!paths_add(&lp.p, tmp->pts, nt) ||
                !tp_ovh_fill(&lp, lp.p.start[lp.p.n - 1], fl, nt))
                rc = SF_ENOMEM;
            any = true;
        } else if (!paths_add(&lp.p, q, m) || (lp.ovh && !tp_ovh_fill(&lp, 0, NULL, 0))) {
            rc = SF_ENOMEM;
        }
        if (rc == SF_OK)
            lp.info[lp.p.n - 1] = *in;
    }
    if (rc == SF_OK && any) {
        layer_paths_release(out);
        *out = lp;
        layer_paths_init(&lp);
    }
    free(fl);
    layer_paths_release(&lp);
    paths_index_release(&below);
    return rc;
}

/* Length of the closed outlines of c inside region r (tmp: scratch). */
static int
outline_inside(const struct paths *c, const struct paths *r, double *len)
{
    struct paths lines, in;
    paths_init(&lines);
    paths_init(&in);
    int rc = SF_OK;
    for (uint32_t j = 0; j < c->n && rc == SF_OK; j++) {
        const struct ipt *q = c->pts + c->start[j];
        uint32_t m = paths_len(c, j);
        if (m > 1 && !(paths_add(&lines, q, m) && paths_push(&lines, q[0])))
            rc = SF_ENOMEM;
    }
    if (rc == SF_OK)
        rc = clip_lines(&lines, r, &in);
    *len = 0;
    for (uint32_t j = 0; rc == SF_OK && j < in.n; j++)
        *len += paths_length_k(&in, j, false);
    paths_release(&lines);
    paths_release(&in);
    return rc;
}

/*
 * PrusaSlicer 2.5's extra_perimeters (PrintObject::_make_perimeters): an
 * island of layer k gets one more perimeter while more than 30 % of the
 * length of the layer above's outlines lies in the critical band just
 * inside its perimeters (1.5 perimeter spacings deep), where the upper
 * layer's walls would stand on infill; at most LAYER_MORE_MAX more.  A lid's
 * plate gets four loops on its last layer under the lip standing 1.35 mm in
 * (PrusaSlicer's too), so the lip's walls stand on perimeters.  Islands are
 * an outline and the holes after it (clip_shim's order).
 */
int
tp_extra_perimeters(struct layer_stack *s, uint32_t k, const struct slice_profile *p)
{
    struct layer *L = &s->l[k];
    for (int e = 0; e < LAYER_MORE_MAX; e++)
        paths_reset(&L->more[e]);
    L->n_more = 0;
    if (!p->extra_perimeters || p->perimeters <= 0 || p->infill_density <= 0 || k + 1 >= s->n)
        return SF_OK;
    const struct paths *up = &s->l[k + 1].region;
    double total = 0;
    for (uint32_t j = 0; j < up->n; j++)
        total += paths_length_k(up, j, true);
    if (total <= 0)
        return SF_OK;
    double sp = tp_spacing(p->width_mm, L->h_mm);
    struct paths isl, a, b, band;
    paths_init(&isl);
    paths_init(&a);
    paths_init(&b);
    paths_init(&band);
    int rc = SF_OK;
    const struct paths *r = &L->region;
    for (uint32_t i = 0, j; i < r->n && rc == SF_OK; i = j) {
        for (j = i + 1; j < r->n && paths_area_k(r, j) < 0; j++)
            ;
        paths_reset(&isl);
        for (uint32_t h = i; h < j; h++)
            if (!paths_add(&isl, r->pts + r->start[h], paths_len(r, h)))
                rc = SF_ENOMEM;
        int e = 0;
        while (rc == SF_OK && e < LAYER_MORE_MAX) {
            double th = p->width_mm / 2 + (p->perimeters - 1 + e) * sp + sp / 2, len = 0;
            if ((rc = clip_offset(&isl, -th, CLIP_JOIN_MITER, &a)) < 0 ||
                (rc = clip_offset(&isl, -(th + 1.5 * sp), CLIP_JOIN_MITER, &b)) < 0 ||
                (rc = clip_bool(CLIP_DIFFERENCE, &a, &b, CLIP_NONZERO, &band)) < 0 ||
                (rc = outline_inside(up, &band, &len)) < 0)
                break;
            if (len <= 0.3 * total)
                break;
            if (!paths_append(&L->more[e], &isl))
                rc = SF_ENOMEM;
            e++;
            L->n_more = (uint32_t)e > L->n_more ? (uint32_t)e : L->n_more;
        }
    }
    paths_release(&isl);
    paths_release(&a);
    paths_release(&b);
    paths_release(&band);
    return rc;
}

/* The area inside island set r's n perimeters. */
static int
shrink_loops(const struct paths *r, const struct slice_profile *p, double sp, int n,
             struct paths *out)
{
    return clip_offset(r, -(p->width_mm / 2 + (n - 1) * sp + sp / 2), CLIP_JOIN_MITER, out);
}

int
tp_inner(const struct layer *L, const struct slice_profile *p, double sp, struct paths *out)
{
    paths_reset(out);
    if (!L->n_more)
        return shrink_loops(&L->region, p, sp, p->perimeters, out);
    struct paths x, in;
    paths_init(&x);
    paths_init(&in);
    int rc = SF_OK;
    /* the islands with e more loops: those with at least e less those with e + 1 */
    for (uint32_t e = 0; e <= L->n_more && rc == SF_OK; e++) {
        const struct paths *at_least = e ? &L->more[e - 1] : &L->region;
        if (e < L->n_more)
            rc = clip_bool(CLIP_DIFFERENCE, at_least, &L->more[e], CLIP_NONZERO, &x);
        else if (!paths_append(&x, at_least))
            rc = SF_ENOMEM;
        if (rc == SF_OK)
            rc = shrink_loops(&x, p, sp, p->perimeters + (int)e, &in);
        if (rc == SF_OK && !paths_append(out, &in))
            rc = SF_ENOMEM;
        paths_reset(&x);
    }
    paths_release(&x);
    paths_release(&in);
    return rc;
}

/*
 * Perimeters, inner loops first, external last.  Loop i's centre line
 * is opened by half a spacing (shrunk by that much more, grown back),
 * so a loop never wraps a sliver it cannot fill (it would lay two lines
 * where one fits), as PrusaSlicer's classic generator does.  What the
 * loops leave between them, the part's edge and the infill goes to
 * gap fill: S is the area inside loop i - 1 (the region for i = 0),
 * and the gap is the part of it loop i does not reach.
 */
int
tp_perimeters(const struct layer *L, const struct slice_profile *p, double sp, struct paths *t,
              struct layer_paths *out)
{
    double w = p->width_mm;
    int rc = SF_OK, n = p->perimeters > 0 ? p->perimeters + (int)L->n_more : 0;
    struct paths *loops = n ? mem_calloc((size_t)n, sizeof(*loops)) : NULL;
    if (n && !loops)
        return SF_ENOMEM;
    struct paths pv; /* an extra loop's islands inside the loop before */
    paths_init(&pv);
    paths_reset(&t[T_GAP]);
    for (int i = 0; i < n && rc == SF_OK; i++) {
        double d = w / 2 + i * sp;
        /* the islands with loop i: all, or those with extra perimeters */
        const struct paths *r = i < p->perimeters ? &L->region : &L->more[i - p->perimeters];
        const struct paths *prev = i ? &t[T_S] : &L->region;
        paths_init(&loops[i]);
        if (i >= p->perimeters) {
            if ((rc = clip_offset(r, -(d - sp + sp / 2), CLIP_JOIN_MITER, &pv)) < 0)
                break;
            prev = &pv;
        }
        /* the innermost loop's shrink is the inner area toolpath_areas made */
        if (i + 1 == n && !L->n_more) {
            paths_reset(&t[T_TMP]);
            if (!paths_append(&t[T_TMP], &L->inner)) {
                rc = SF_ENOMEM;
                break;
            }
        } else if ((rc = clip_offset(r, -(d + sp / 2), CLIP_JOIN_MITER, &t[T_TMP])) < 0) {
            break;
        }
        if ((rc = clip_offset(&t[T_TMP], sp / 2, CLIP_JOIN_MITER, &loops[i])) < 0)
            break;
        if (p->gap_fill) {
            /* 1 um more: where the loop follows the edge, the offsets'
               rounding leaves no hairline for the difference to trace
               (PrusaSlicer's safety offset, for the same reason) */
            if ((rc = clip_offset(&loops[i], (i ? sp / 2 : w / 2) + GAP_SAFETY_MM, CLIP_JOIN_MITER,
                                  &t[T_LINES])) < 0 ||
                (rc = clip_bool(CLIP_DIFFERENCE, prev, &t[T_LINES], CLIP_NONZERO, &t[T_KEEP])) < 0)
                break;
            if (!paths_append(&t[T_GAP], &t[T_KEEP]))
                rc = SF_ENOMEM;
        }
        paths_move(&t[T_S], &t[T_TMP]);
    }
    for (int i = n - 1; i >= 0; i--) {
        if (rc == SF_OK)
            rc = tp_add(out, &loops[i], i ? ROLE_PERIMETER : ROLE_EXT_PERIMETER, true, w);
        paths_release(&loops[i]);
    }
    paths_release(&pv);
    free(loops);
    return rc;
}
