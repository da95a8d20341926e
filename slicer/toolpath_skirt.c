/*
 * toolpath_skirt.c - the skirt and the brim (see toolpath.h:
 * tp_brim_width, toolpath_skirt_brim).
 *
 * Thread: reentrant; no state outside the arguments.
 */
#include "toolpath.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../src/base/err.h"
#include "../src/base/mem.h"
#include "clip_shim.h"
#include "toolpath_int.h"

double
tp_brim_width(const struct layer_stack *s, const struct slice_profile *p, double height_mm)
{
    if (p->brim_width_mm > 0)
        return p->brim_width_mm;
    if (!p->brim_auto || !s->n)
        return 0;
    const struct paths *r = &s->l[0].region;
    double area = paths_area(r), per = 0;
    for (uint32_t k = 0; k < r->n; k++)
        per += paths_length_k(r, k, true);
    if (area <= 0 || per <= 0)
        return 0;
    return height_mm > p->brim_auto_ratio * 4 * area / per ? p->brim_auto_width_mm : 0;
}

static int
cmp_ipt(const void *a, const void *b)
{
    const struct ipt *p = a, *q = b;
    if (p->x != q->x)
        return p->x < q->x ? -1 : 1;
    return (p->y > q->y) - (p->y < q->y);
}

/* Twice the signed area of o-a-b (coordinates within a bed fit int64 products). */
static int64_t
cross3(struct ipt o, struct ipt a, struct ipt b)
{
    return (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x);
}

/* Convex hull of every point of in (monotone chain), counter-clockwise, into out. */
static int
hull_of(const struct paths *in, struct paths *out)
{
    paths_reset(out);
    size_t n = in->n ? in->start[in->n] : 0;
    if (n < 3)
        return SF_OK;
    struct ipt *pt = mem_array(n, sizeof(*pt)), *h = mem_array(2 * n, sizeof(*h));
    if (!pt || !h) {
        free(pt);
        free(h);
        return SF_ENOMEM;
    }
    memcpy(pt, in->pts, n * sizeof(*pt));
    qsort(pt, n, sizeof(*pt), cmp_ipt);
    size_t m = 0;
    for (size_t i = 0; i < n; i++) {
        while (m >= 2 && cross3(h[m - 2], h[m - 1], pt[i]) <= 0)
            m--;
        h[m++] = pt[i];
    }
    for (size_t i = n - 1, t = m + 1; i-- > 0;) {
        while (m >= t && cross3(h[m - 2], h[m - 1], pt[i]) <= 0)
            m--;
        h[m++] = pt[i];
    }
    int rc = m > 3 && !paths_add(out, h, (uint32_t)(m - 1)) ? SF_ENOMEM : SF_OK;
    free(pt);
    free(h);
    return rc;
}

/* Loops of width w at offsets d0, d0 + sp, ... (n of them) outside region. */
static int
loops_around(const struct paths *region, double d0, double sp, int n, struct paths *out,
             struct paths *tmp)
{
    paths_reset(out);
    for (int i = 0; i < n; i++) {
        int rc = clip_offset(region, d0 + i * sp, CLIP_JOIN_ROUND, tmp);
        if (rc < 0)
            return rc;
        if (!paths_append(out, tmp))
            return SF_ENOMEM;
    }
    return SF_OK;
}

/* Add closed loops to out as skirt/brim: whole, or when allowed is given,
   cut open to the pieces inside it. */
static int
add_loops(struct layer_paths *out, const struct paths *loops, const struct paths *allowed, double w,
          struct paths *tmp, struct paths *tmp2)
{
    if (!allowed)
        return tp_add(out, loops, ROLE_SKIRT, true, w);
    paths_reset(tmp);
    for (uint32_t i = 0; i < loops->n; i++) {
        const struct ipt *q = loops->pts + loops->start[i];
        uint32_t n = paths_len(loops, i);
        if (!paths_begin(tmp))
            return SF_ENOMEM;
        for (uint32_t j = 0; j <= n; j++)
            if (!paths_push(tmp, q[j % n]))
                return SF_ENOMEM;
    }
    int rc = clip_lines(tmp, allowed, tmp2);
    return rc < 0 ? rc : tp_add(out, tmp2, ROLE_SKIRT, false, w);
}

/* True when every point of p lies on the bed. */
static bool
on_bed(const struct paths *p, const struct paths *bed)
{
    struct ipt lo, hi, blo, bhi;
    if (!paths_bbox(p, &lo, &hi) || !paths_bbox(bed, &blo, &bhi))
        return true;
    return lo.x >= blo.x && lo.y >= blo.y && hi.x <= bhi.x && hi.y <= bhi.y;
}

int
toolpath_skirt_brim(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
                    const struct support_layer *sup0, double brim_mm, struct layer_paths *lp)
{
    bool skirt = p->skirts > 0 && (int)k < p->skirt_height;
    if (!s->n || (!skirt && (k > 0 || brim_mm <= 0)))
        return SF_OK;
    double w = p->width_mm, h = s->l[0].h_mm, sp = tp_spacing(w, h);
    enum { OUTER, ROUND, KEEP, BRIM, HULL, LOOPS, TMP, TMP2, BED, N };
    struct paths t[N];
    for (int i = 0; i < N; i++)
        paths_init(&t[i]);
    struct layer_paths out;
    layer_paths_init(&out);
    int rc = SF_OK;
#define TRY(x)                                                                                     \
    do {                                                                                           \
        if ((rc = (x)) < 0)                                                                        \
            goto done;                                                                             \
    } while (0)
    struct ipt bed[4] = { { 0, 0 },
                          { poly_i(p->bed_x_mm), 0 },
                          { poly_i(p->bed_x_mm), poly_i(p->bed_y_mm) },
                          { 0, poly_i(p->bed_y_mm) } };
    if (!paths_add(&t[BED], bed, 4))
        TRY(SF_ENOMEM);
    /* the part's outer contours (a brim stays out of holes, PrusaSlicer's outer_only) */
    const struct paths *r = &s->l[0].region;
    for (uint32_t i = 0; i < r->n; i++)
        if (paths_area_k(r, i) > 0 && !paths_add(&t[TMP], r->pts + r->start[i], paths_len(r, i)))
            TRY(SF_ENOMEM);
    TRY(clip_bool(CLIP_UNION, &t[TMP], NULL, CLIP_NONZERO, &t[OUTER]));
    /* ROUND: what the skirt goes around (part, support, brim); KEEP: the support */
    paths_reset(&t[TMP]);
    if (sup0 && (!paths_append(&t[TMP], &sup0->body) || !paths_append(&t[TMP], &sup0->iface)))
        TRY(SF_ENOMEM);
    TRY(clip_bool(CLIP_UNION, &t[TMP], NULL, CLIP_NONZERO, &t[KEEP]));
    int n_brim = brim_mm > 0 ? (int)floor(brim_mm / sp + 1e-9) : 0;
    if (n_brim > 0) {
        /* loops from the part outwards, the first half a spacing out, as
           PrusaSlicer's (it overlaps the external perimeter, to bond) */
        TRY(loops_around(&t[OUTER], sp / 2, sp, n_brim, &t[BRIM], &t[TMP]));
        TRY(clip_offset(&t[OUTER], n_brim * sp, CLIP_JOIN_ROUND, &t[ROUND]));
    } else if (!paths_append(&t[ROUND], &t[OUTER])) {
        TRY(SF_ENOMEM);
    }
    if (!paths_append(&t[ROUND], &t[KEEP]))
        TRY(SF_ENOMEM);
    if (skirt) {
        TRY(hull_of(&t[ROUND], &t[HULL]));
        TRY(loops_around(&t[HULL], p->skirt_distance_mm + w / 2, sp, p->skirts, &t[LOOPS],
                         &t[TMP]));
        /* outermost first: the nozzle primes far from the part */
        paths_reset(&t[TMP2]);
        for (uint32_t i = t[LOOPS].n; i-- > 0;)
            if (!paths_add(&t[TMP2], t[LOOPS].pts + t[LOOPS].start[i], paths_len(&t[LOOPS], i)))
                TRY(SF_ENOMEM);
        paths_move(&t[LOOPS], &t[TMP2]);
        TRY(add_loops(&out, &t[LOOPS], on_bed(&t[LOOPS], &t[BED]) ? NULL : &t[BED], w, &t[TMP],
                      &t[TMP2]));
    }
    if (k == 0 && n_brim > 0) {
        /* a line width clear of the support: the loops are cut open there */
        bool clear = on_bed(&t[BRIM], &t[BED]);
        if (t[KEEP].n) {
            TRY(clip_offset(&t[KEEP], w, CLIP_JOIN_ROUND, &t[TMP]));
            paths_move(&t[KEEP], &t[TMP]);
            TRY(clip_bool(CLIP_INTERSECTION, &t[BRIM], &t[KEEP], CLIP_NONZERO, &t[TMP]));
            clear = clear && t[TMP].n == 0;
        }
        if (!clear) {
            TRY(clip_offset(&t[OUTER], n_brim * sp + w, CLIP_JOIN_ROUND, &t[TMP]));
            TRY(clip_bool(CLIP_INTERSECTION, &t[TMP], &t[BED], CLIP_NONZERO, &t[TMP2]));
            TRY(clip_bool(CLIP_DIFFERENCE, &t[TMP2], &t[KEEP], CLIP_NONZERO, &t[HULL]));
        }
        TRY(add_loops(&out, &t[BRIM], clear ? NULL : &t[HULL], w, &t[TMP], &t[TMP2]));
    }
    if (out.p.n) {
        uint32_t n_own = out.p.n;
        if (!paths_append(&out.p, &lp->p))
            TRY(SF_ENOMEM);
        size_t cap = out.cap_info;
        if (!mem_grow((void **)&out.info, &cap, out.p.n, sizeof(*out.info)))
            TRY(SF_ENOMEM);
        out.cap_info = (uint32_t)cap;
        if (lp->p.n)
            memcpy(out.info + n_own, lp->info, lp->p.n * sizeof(*lp->info));
        if (lp->ovh && lp->p.n &&
            !tp_ovh_fill(&out, out.p.start[n_own], lp->ovh, lp->p.start[lp->p.n]))
            TRY(SF_ENOMEM);
        layer_paths_release(lp);
        *lp = out;
        layer_paths_init(&out);
    }
#undef TRY
done:
    layer_paths_release(&out);
    for (int i = 0; i < N; i++)
        paths_release(&t[i]);
    return rc;
}
