/*
 * support.c - columns to per-layer support regions (see support.h).
 *
 * Columns are sorted by cell once; per layer, one pass picks the active
 * ones, merges runs of neighbouring cells in a row into rectangles and
 * hands them to one Clipper union, then subtracts the grown part.
 * Islands are found by intersecting each new piece of a layer with the
 * layer below; their columns reach down to the highest layer below whose
 * cross-section covers the cell centre, or to the bed.
 *
 * Thread: reentrant.
 */
#include "support.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../src/base/mem.h"
#include "clip_shim.h"

#define EPS 1e-4
/* PrusaSlicer 2.5's raft_first_layer_expansion default (flange below) */
#define SUPPORT_FLANGE_MM 3.0

static int
cmp_col(const void *a, const void *b)
{
    const struct support_column *x = a, *y = b; /* by row, cell in the row, height */
    if (x->cell != y->cell)
        return x->cell < y->cell ? -1 : 1;
    return x->lo < y->lo ? -1 : x->lo > y->lo;
}

static bool
push_col(struct support_column **cols, size_t *n, size_t *cap, struct support_column c)
{
    if (!mem_grow((void **)cols, cap, *n + 1, sizeof(**cols)))
        return false;
    (*cols)[(*n)++] = c;
    return true;
}

/* Is there already a column in cell c ending within 1 mm of z? */
static bool
has_column_near(const struct support_column *cols, size_t n, uint32_t c, double z)
{
    for (size_t k = 0; k < n; k++)
        if (!cols[k].iface && cols[k].cell == c && fabs(cols[k].hi - z) < 1)
            return true;
    return false;
}

static int
island_columns(const struct layer_stack *s, uint32_t k, const struct paths *isl,
               const struct support_grid *g, struct support_column **cols, size_t *n, size_t *cap,
               size_t n_ray)
{
    struct ipt lo, hi;
    if (!paths_bbox(isl, &lo, &hi))
        return SF_OK;
    double zb = s->l[k].z_mm - s->l[k].h_mm;
    long i0 = (long)ceil((poly_mm(lo.x) - g->x0) / g->pitch);
    long i1 = (long)floor((poly_mm(hi.x) - g->x0) / g->pitch);
    long j0 = (long)ceil((poly_mm(lo.y) - g->y0) / g->pitch);
    long j1 = (long)floor((poly_mm(hi.y) - g->y0) / g->pitch);
    bool any = false;
    for (int pass = 0; pass < 2 && !any; pass++) {
        if (pass == 1) { /* too small to hold a cell centre: the nearest cell */
            i0 = i1 = lround((poly_mm(lo.x + (hi.x - lo.x) / 2) - g->x0) / g->pitch);
            j0 = j1 = lround((poly_mm(lo.y + (hi.y - lo.y) / 2) - g->y0) / g->pitch);
        }
        for (long j = j0; j <= j1; j++) {
            for (long i = i0; i <= i1; i++) {
                if (i < 0 || j < 0 || i >= (long)g->nu || j >= (long)g->nw)
                    continue;
                struct ipt c = { poly_i(g->x0 + i * g->pitch), poly_i(g->y0 + j * g->pitch) };
                if (pass == 0 && !paths_contains(isl, c))
                    continue;
                any = true;
                uint32_t cell = (uint32_t)j * g->nu + (uint32_t)i;
                if (has_column_near(*cols, n_ray, cell, zb))
                    continue;
                double floor_z = 0;
                for (long q = (long)k - 1; q >= 0; q--) {
                    if (paths_contains(&s->l[q].region, c)) {
                        floor_z = s->l[q].z_mm;
                        break;
                    }
                }
                struct support_column col = { cell, (float)floor_z, (float)zb, SUPPORT_ISLAND_TRI,
                                              false };
                if (zb > floor_z && !push_col(cols, n, cap, col))
                    return SF_ENOMEM;
            }
        }
    }
    return SF_OK;
}

int
support_islands(const struct layer_stack *s, const struct support_grid *g,
                struct support_column **cols, size_t *n, size_t *cap)
{
    size_t n_ray = *n;
    struct paths isl, both;
    paths_init(&isl);
    paths_init(&both);
    int rc = SF_OK;
    for (uint32_t k = 1; k < s->n && rc == SF_OK; k++) {
        const struct paths *r = &s->l[k].region;
        for (uint32_t a = 0; a < r->n && rc == SF_OK;) {
            uint32_t b = a + 1; /* an island: outer a and its holes up to the next outer */
            while (b < r->n && paths_area_k(r, b) < 0)
                b++;
            paths_reset(&isl);
            for (uint32_t q = a; q < b; q++)
                if (!paths_add(&isl, r->pts + r->start[q], paths_len(r, q)))
                    rc = SF_ENOMEM;
            a = b;
            if (rc < 0)
                break;
            rc = clip_bool(CLIP_INTERSECTION, &isl, &s->l[k - 1].region, CLIP_NONZERO, &both);
            if (rc == SF_OK && paths_area(&both) < 1e-3)
                rc = island_columns(s, k, &isl, g, cols, n, cap, n_ray);
        }
    }
    paths_release(&isl);
    paths_release(&both);
    return rc;
}

void
support_layer_release(struct support_layer *l)
{
    paths_release(&l->body);
    paths_release(&l->iface);
}

/* Add one rectangle per run of neighbouring cells in a row among the
   columns idx[0..m) (ascending: cols are sorted by cell). */
static bool
add_runs(struct paths *rects, const struct support_grid *g, const struct support_column *cols,
         const uint32_t *idx, size_t m)
{
    double hp = g->pitch / 2;
    for (size_t a = 0; a < m;) {
        size_t last = a;
        uint32_t j = cols[idx[a]].cell / g->nu;
        while (last + 1 < m && cols[idx[last + 1]].cell / g->nu == j &&
               cols[idx[last + 1]].cell % g->nu <= cols[idx[last]].cell % g->nu + 1)
            last++;
        uint32_t ia = cols[idx[a]].cell % g->nu, il = cols[idx[last]].cell % g->nu;
        double x0 = g->x0 + ia * g->pitch - hp, x1 = g->x0 + il * g->pitch + hp;
        double y = g->y0 + j * g->pitch;
        /* 1 um overlap so neighbouring rows merge in the union */
        struct ipt r[4] = { { poly_i(x0 - 1e-3), poly_i(y - hp - 1e-3) },
                            { poly_i(x1 + 1e-3), poly_i(y - hp - 1e-3) },
                            { poly_i(x1 + 1e-3), poly_i(y + hp + 1e-3) },
                            { poly_i(x0 - 1e-3), poly_i(y + hp + 1e-3) } };
        if (!paths_add(rects, r, 4))
            return false;
        a = last + 1;
    }
    return true;
}

/* The first layer whose top is above z (s->n if none). */
static uint32_t
layer_above(const struct layer_stack *s, double z)
{
    uint32_t a = 0, b = s->n;
    while (a < b) {
        uint32_t mid = a + (b - a) / 2;
        if (s->l[mid].z_mm > z)
            b = mid;
        else
            a = mid + 1;
    }
    return a;
}

/*
 * The columns that may print in each layer, a layer at a time: live holds
 * them in cell order (their indices ascending), from the layer that holds a
 * column's foot (less 1 mm) to the one that holds its head (plus 1 mm), so
 * a layer looks at its own columns, not at every column of the part.
 */
struct live_cols {
    uint32_t *k0, *k1;    /* a column's first and last layer (k0: the block of the five) */
    uint32_t *first, *by; /* by[first[k] .. first[k + 1]): the columns starting at layer k */
    uint32_t *live, *tmp; /* the live columns, and scratch */
    size_t n_live;
};

static bool
live_init(struct live_cols *lc, const struct layer_stack *s, const struct support_column *cols,
          size_t n)
{
    size_t m = n ? n : 1;
    /* k0, k1, by, live and tmp in one block */
    lc->k0 = mem_array(5 * m, sizeof(uint32_t));
    lc->first = mem_calloc((size_t)s->n + 2, sizeof(uint32_t));
    lc->n_live = 0;
    if (!lc->k0 || !lc->first)
        return false;
    lc->k1 = lc->k0 + m;
    lc->by = lc->k1 + m;
    lc->live = lc->by + m;
    lc->tmp = lc->live + m;
    for (size_t c = 0; c < n; c++) {
        lc->k0[c] = layer_above(s, cols[c].lo - 1.0);
        uint32_t k1 = layer_above(s, cols[c].hi + 1.0);
        lc->k1[c] = k1 < s->n ? k1 : s->n - 1;
        lc->first[lc->k0[c] + 1]++;
    }
    for (uint32_t k = 0; k <= s->n; k++)
        lc->first[k + 1] += lc->first[k];
    for (size_t c = 0; c < n; c++) /* ascending within a layer's bucket */
        lc->by[lc->first[lc->k0[c]]++] = (uint32_t)c;
    for (uint32_t k = s->n + 1; k > 0; k--)
        lc->first[k] = lc->first[k - 1];
    lc->first[0] = 0;
    return true;
}

/* Advance to layer k: drop the columns that ended, merge in those that start. */
static void
live_step(struct live_cols *lc, uint32_t k)
{
    const uint32_t *add = lc->by + lc->first[k];
    size_t n_add = lc->first[k + 1] - lc->first[k], a = 0, m = 0;
    for (size_t q = 0; q < lc->n_live || a < n_add;) {
        uint32_t c;
        if (a < n_add && (q == lc->n_live || add[a] < lc->live[q]))
            c = add[a++];
        else
            c = lc->live[q++];
        if (lc->k1[c] >= k)
            lc->tmp[m++] = c;
    }
    uint32_t *t = lc->live;
    lc->live = lc->tmp;
    lc->tmp = t;
    lc->n_live = m;
}

static void
live_release(struct live_cols *lc)
{
    free(lc->k0); /* the block */
    free(lc->first);
}

/*
 * The bed layer's support grown SUPPORT_FLANGE_MM all round, as PrusaSlicer
 * 2.5 widens its first support layer for adhesion (raft_first_layer_
 * expansion, 3 mm by default and in the peers' runs: anchor's bed layer
 * 7783 mm of support lines where the columns alone take 3057), in steps
 * of at most 0.6 mm less the part grown by the xy gap (grown), so it does
 * not leak through thin walls (its generate_raft_base).  a, b: scratch.
 */
static int
flange(struct paths *body, const struct paths *grown, struct paths *a, struct paths *b)
{
    int steps = (int)ceil(SUPPORT_FLANGE_MM / 0.6);
    int rc = SF_OK;
    for (int i = 0; i < steps && rc == SF_OK; i++) {
        rc = clip_offset(body, SUPPORT_FLANGE_MM / steps, CLIP_JOIN_SQUARE, a);
        if (rc == SF_OK)
            rc = clip_bool(CLIP_DIFFERENCE, a, grown, CLIP_NONZERO, b);
        if (rc == SF_OK)
            paths_move(body, b);
    }
    return rc;
}

int
support_layers(const struct layer_stack *s, const struct support_grid *g,
               struct support_column *cols, size_t n, const struct slice_profile *p,
               struct support_layer *out, struct sf_err *err)
{
    for (uint32_t k = 0; k < s->n; k++) {
        paths_init(&out[k].body);
        paths_init(&out[k].iface);
    }
    if (n)
        qsort(cols, n, sizeof(*cols), cmp_col);
    struct live_cols lc;
    uint32_t *on = mem_array(n ? n : 1, sizeof(uint32_t)),
             *top = mem_array(n ? n : 1, sizeof(uint32_t));
    struct paths rects, all, grown, tmp;
    paths_init(&rects);
    paths_init(&all);
    paths_init(&grown);
    paths_init(&tmp);
    int rc = live_init(&lc, s, cols, n) && on && top ? SF_OK : SF_ENOMEM;
    double gap = p->support_z_gap_mm, if_h = support_interface_count(p) * p->layer_mm;
    for (uint32_t k = 0; k < s->n && rc == SF_OK; k++) {
        double zt = s->l[k].z_mm, zb = zt - s->l[k].h_mm;
        size_t n_on = 0, n_top = 0;
        live_step(&lc, k);
        for (size_t q = 0; q < lc.n_live; q++) {
            uint32_t c = lc.live[q];
            if (cols[c].iface) { /* a dense band (supmodel.h): inside a column */
                if (zb >= cols[c].lo - EPS && zt <= cols[c].hi + EPS)
                    top[n_top++] = c;
                continue;
            }
            double floor_z = cols[c].lo > EPS ? cols[c].lo + gap : 0;
            if (!(zb >= floor_z - EPS && zt <= cols[c].hi - gap + EPS))
                continue;
            on[n_on++] = c;
            /* dense where it lands on the part (PrusaSlicer: as many bottom
               interface layers as top ones), and under an island it holds up;
               under the model's contacts the bands say where (only where a
               layer steps out far enough: PrusaSlicer prints a gentle
               slope's contacts sparse) */
            if ((cols[c].tri == SUPPORT_ISLAND_TRI && zt > cols[c].hi - gap - if_h + EPS) ||
                (cols[c].lo > EPS && zb < floor_z + if_h - EPS))
                top[n_top++] = c;
        }
        if (!n_on)
            continue;
        rc = clip_offset(&s->l[k].region, p->support_xy_gap_mm, CLIP_JOIN_MITER, &grown);
        for (int pass = 0; pass < 2 && rc == SF_OK; pass++) {
            if (pass == 1 && !n_top)
                break;
            paths_reset(&rects);
            if (!add_runs(&rects, g, cols, pass ? top : on, pass ? n_top : n_on)) {
                rc = SF_ENOMEM;
                break;
            }
            rc = clip_bool(CLIP_UNION, &rects, NULL, CLIP_NONZERO, &all);
            if (rc == SF_OK)
                rc = clip_bool(CLIP_DIFFERENCE, &all, &grown, CLIP_NONZERO,
                               pass ? &out[k].iface : &out[k].body);
        }
        if (rc == SF_OK && k == 0 && out[k].body.n)
            rc = flange(&out[k].body, &grown, &all, &tmp);
        if (rc == SF_OK && out[k].iface.n) {
            rc = clip_bool(CLIP_DIFFERENCE, &out[k].body, &out[k].iface, CLIP_NONZERO, &tmp);
            paths_move(&out[k].body, &tmp);
        }
    }
    live_release(&lc);
    free(on);
    free(top);
    paths_release(&rects);
    paths_release(&all);
    paths_release(&grown);
    paths_release(&tmp);
    if (rc < 0) {
        for (uint32_t k = 0; k < s->n; k++)
            support_layer_release(&out[k]);
        return sf_err_set(err, rc, "support: %s",
                          rc == SF_ENOMEM ? "out of memory" : "polygon clipping failed");
    }
    return SF_OK;
}

double
support_volume(const struct layer_stack *s, const struct support_layer *sup)
{
    double v = 0;
    for (uint32_t k = 0; k < s->n; k++)
        v += (paths_area(&sup[k].body) + paths_area(&sup[k].iface)) * s->l[k].h_mm;
    return v;
}
