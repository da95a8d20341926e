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
    int rc = SF_OK;
    struct paths *loops = p->perimeters ? mem_calloc((size_t)p->perimeters, sizeof(*loops)) : NULL;
    if (p->perimeters && !loops)
        return SF_ENOMEM;
    paths_reset(&t[T_GAP]);
    for (int i = 0; i < p->perimeters && rc == SF_OK; i++) {
        double d = w / 2 + i * sp;
        const struct paths *prev = i ? &t[T_S] : &L->region;
        paths_init(&loops[i]);
        /* the innermost loop's shrink is the inner area toolpath_areas made */
        if (i + 1 == p->perimeters) {
            paths_reset(&t[T_TMP]);
            if (!paths_append(&t[T_TMP], &L->inner)) {
                rc = SF_ENOMEM;
                break;
            }
        } else if ((rc = clip_offset(&L->region, -(d + sp / 2), CLIP_JOIN_MITER, &t[T_TMP])) < 0) {
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
    for (int i = p->perimeters - 1; i >= 0; i--) {
        if (rc == SF_OK)
            rc = tp_add(out, &loops[i], i ? ROLE_PERIMETER : ROLE_EXT_PERIMETER, true, w);
        paths_release(&loops[i]);
    }
    free(loops);
    return rc;
}
