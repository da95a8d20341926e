/*
 * toolpath_bridge.c - bridges: solid over air, each piece in the
 * direction of its shortest anchored span, and internal bridges over the
 * sparse infill below (PrusaSlicer's BridgeDetector and
 * bridge_over_infill ideas).
 *
 * Thread: reentrant; no state outside the arguments.
 */
#include "toolpath.h"

#include <math.h>

#include "../src/base/err.h"
#include "clip_shim.h"
#include "toolpath_int.h"

/*
 * The direction of a bridge over piece: PrusaSlicer's BridgeDetector
 * idea.  Every 10 degrees, lines across the piece; the angle whose lines
 * have the most length anchored at both ends (an end within a nozzle
 * width of the layer below) wins, and of angles within 1 % of that, the
 * one whose longest anchored line is shortest: the shortest span between
 * anchors.
 */
static double
bridge_angle(const struct paths *piece, const struct paths_index *below, double spacing,
             const double org[2], struct paths *lines, int *rc)
{
    double best_cov = -1, best_max = INFINITY, best = 0;
    double cov[18], mx[18];
    for (int a = 0; a < 18; a++) {
        paths_reset(lines);
        cov[a] = 0;
        mx[a] = 0;
        if ((*rc = tp_fill_lines(piece, a * 10.0, spacing, org[0], org[1], lines)) < 0)
            return 0;
        for (uint32_t i = 0; i < lines->n; i++) {
            uint32_t n = paths_len(lines, i);
            const struct ipt *q = lines->pts + lines->start[i];
            if (paths_index_contains(below, q[0]) && paths_index_contains(below, q[n - 1])) {
                double l = paths_length_k(lines, i, false);
                cov[a] += l;
                mx[a] = fmax(mx[a], l);
            }
        }
        best_cov = fmax(best_cov, cov[a]);
    }
    for (int a = 0; a < 18; a++)
        if (cov[a] >= 0.99 * best_cov && mx[a] < best_max)
            best_max = mx[a], best = a * 10.0;
    return best;
}

/* Bridge lines over each piece of area (one outer and its holes), in
   the piece's own direction (bridge_angle) over the layer below. */
static int
bridges(const struct paths *area, const struct paths *below, double nz, const double org[2],
        struct layer_paths *out, struct paths *grown, struct paths *lines, struct paths *piece)
{
    struct paths_index ix;
    int rc = clip_offset(below, nz, CLIP_JOIN_MITER, grown);
    if (rc < 0)
        return rc;
    if (!paths_index_init(&ix, grown))
        return SF_ENOMEM;
    for (uint32_t k = 0; k < area->n && rc == SF_OK;) {
        uint32_t e = k + 1;
        while (e < area->n && paths_area_k(area, e) < 0)
            e++;
        paths_reset(piece);
        for (uint32_t i = k; i < e; i++)
            if (!paths_add(piece, area->pts + area->start[i], paths_len(area, i)))
                rc = SF_ENOMEM;
        k = e;
        double ang = rc == SF_OK ? bridge_angle(piece, &ix, nz + 0.05, org, lines, &rc) : 0;
        paths_reset(lines);
        if (rc == SF_OK)
            rc = tp_fill_lines(piece, ang, nz + 0.05, org[0], org[1], lines);
        if (rc == SF_OK)
            rc = tp_link(lines, piece, 2 * (nz + 0.05), nz / 2);
        if (rc == SF_OK)
            rc = tp_add(out, lines, ROLE_BRIDGE, false, nz);
    }
    paths_index_release(&ix);
    return rc;
}

/*
 * Internal bridges: solid infill laid straight over the sparse infill of
 * the layer below prints as bridge lines (nozzle-wide round threads at
 * bridge speed, as over air), since under it is mostly air between the
 * grid's lines: PrusaSlicer's bridge_over_infill.  Pieces narrower than 6
 * nozzle widths stay solid (its opening by 3 bridge widths).  The lines
 * keep the solid infill's direction.  solid loses what is bridged.
 */
static int
internal_bridges(struct paths *solid, const struct paths *below_sparse, double nz, double ang,
                 const double org[2], struct layer_paths *out, struct paths *t1, struct paths *t2,
                 struct paths *lines)
{
    int rc = clip_bool(CLIP_INTERSECTION, solid, below_sparse, CLIP_NONZERO, t1);
    if (rc < 0 || !t1->n)
        return rc;
    if ((rc = clip_offset(t1, -3 * nz, CLIP_JOIN_MITER, t2)) < 0 || !t2->n)
        return rc;
    if ((rc = clip_offset(t2, 3 * nz, CLIP_JOIN_MITER, t1)) < 0)
        return rc;
    if ((rc = clip_bool(CLIP_INTERSECTION, t1, solid, CLIP_NONZERO, t2)) < 0 || !t2->n)
        return rc;
    if ((rc = clip_bool(CLIP_DIFFERENCE, solid, t2, CLIP_NONZERO, t1)) < 0)
        return rc;
    paths_move(solid, t1);
    paths_reset(lines);
    if ((rc = tp_fill_lines(t2, ang, nz + 0.05, org[0], org[1], lines)) < 0)
        return rc;
    if ((rc = tp_link(lines, t2, 2 * (nz + 0.05), nz / 2)) < 0)
        return rc;
    return tp_add(out, lines, ROLE_BRIDGE, false, nz);
}

int
tp_bridges_over_air(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
                    const double org[2], struct paths *t, struct layer_paths *out)
{
    int rc = SF_OK;
    if (k > 0 && t[T_SOLID].n && p->bridge_mm_s > 0) {
        /* solid over air is a bridge; slivers narrower than the nozzle are not */
        double nz = p->nozzle_mm;
        TP_TRY(
            clip_bool(CLIP_DIFFERENCE, &t[T_SOLID], &s->l[k - 1].region, CLIP_NONZERO, &t[T_TMP]));
        TP_TRY(clip_offset(&t[T_TMP], -nz / 2, CLIP_JOIN_MITER, &t[T_KEEP]));
        TP_TRY(clip_offset(&t[T_KEEP], nz / 2, CLIP_JOIN_MITER, &t[T_TMP]));
        if (t[T_TMP].n) {
            TP_TRY(clip_bool(CLIP_INTERSECTION, &t[T_TMP], &t[T_SOLID], CLIP_NONZERO, &t[T_KEEP]));
            TP_TRY(clip_bool(CLIP_DIFFERENCE, &t[T_SOLID], &t[T_KEEP], CLIP_NONZERO, &t[T_TMP]));
            paths_move(&t[T_SOLID], &t[T_TMP]);
            TP_TRY(bridges(&t[T_KEEP], &s->l[k - 1].region, nz, org, out, &t[T_TMP], &t[T_LINES],
                           &t[T_S]));
        }
    }
out:
    return rc;
}

int
tp_bridges_over_sparse(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
                       double ang, const double org[2], struct paths *t, struct layer_paths *out)
{
    int rc = SF_OK;
    if (k > 0 && t[T_SOLID].n && p->bridge_mm_s > 0 && p->infill_density > 0 &&
        p->infill_density < 1) { /* 100 % "sparse" is solid: nothing to bridge */
        /* sparse in every layer a thick bridge's thread reaches down
           into (a nozzle deep: PrusaSlicer's bridge_over_infill looks
           down the bridge flow's height) */
        long depth = (long)floor(p->nozzle_mm / s->l[k].h_mm + 1e-6);
        const struct paths *below = &t[T_BELOW];
        paths_reset(&t[T_BELOW]);
        for (long j = (long)k - 1; j >= 0 && j >= (long)k - (depth > 1 ? depth : 1); j--) {
            const struct paths *sj = &s->l[j].sparse;
            if (!s->l[j].has_regions) {
                TP_TRY(toolpath_regions(s, (uint32_t)j, p, &t[T_TMP], &t[T_KEEP], &t[T_LINES]));
                sj = &t[T_LINES];
            }
            if (j == (long)k - 1) {
                if (!paths_append(&t[T_BELOW], sj))
                    TP_TRY(SF_ENOMEM);
            } else if (t[T_BELOW].n) {
                TP_TRY(clip_bool(CLIP_INTERSECTION, &t[T_BELOW], sj, CLIP_NONZERO, &t[T_TMP]));
                paths_move(&t[T_BELOW], &t[T_TMP]);
            }
            if (!t[T_BELOW].n)
                break;
        }
        if (below->n)
            TP_TRY(internal_bridges(&t[T_SOLID], below, p->nozzle_mm, ang, org, out, &t[T_TMP],
                                    &t[T_KEEP], &t[T_LINES]));
    }
out:
    return rc;
}
