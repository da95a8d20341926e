/*
 * growth.c - layer-by-layer growth on the rays structure (see growth.h).
 *
 * Voxels: cell c is solid in layer k when the layer's mid-height lies
 * inside one of the ray's solid intervals (between an entering and the next
 * exiting hit).  Regions are labelled per layer with a flood fill over a
 * reused stack; "held" means a voxel of the region sits on a solid voxel of
 * the previous layer, on the bed, or on the top of a support column.  The
 * centre of mass is accumulated layer by layer from voxel counts (uniform
 * density) and tested against the extended base's convex hull (Andrew's
 * monotone chain).
 */
#include "growth.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"
#include "measure.h"

struct pt {
    double x, y;
};

static int
cmp_pt(const void *a, const void *b)
{
    const struct pt *p = a, *q = b;
    if (p->x != q->x)
        return (p->x > q->x) - (p->x < q->x);
    return (p->y > q->y) - (p->y < q->y);
}

static double
cross(struct pt o, struct pt a, struct pt b)
{
    return (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x);
}

/* Convex hull of pts (sorted in place), CCW into hull; returns its size. */
static size_t
convex_hull(struct pt *pts, size_t n, struct pt *hull)
{
    if (n < 3) {
        memcpy(hull, pts, n * sizeof(*pts));
        return n;
    }
    qsort(pts, n, sizeof(*pts), cmp_pt);
    size_t k = 0;
    for (size_t i = 0; i < n; i++) {
        while (k >= 2 && cross(hull[k - 2], hull[k - 1], pts[i]) <= 0)
            k--;
        hull[k++] = pts[i];
    }
    for (size_t i = n - 1, t = k + 1; i-- > 0;) {
        while (k >= t && cross(hull[k - 2], hull[k - 1], pts[i]) <= 0)
            k--;
        hull[k++] = pts[i];
    }
    return k - 1;
}

/* Signed distance of p inside the CCW convex polygon (negative outside). */
static double
margin_in(const struct pt *h, size_t n, struct pt p)
{
    if (n < 3) {
        double best = INFINITY; /* a point or a segment: distance, negative */
        for (size_t i = 0; i < n; i++)
            best = fmin(best, hypot(p.x - h[i].x, p.y - h[i].y));
        return n ? -best : -INFINITY;
    }
    double m = INFINITY;
    for (size_t i = 0; i < n; i++) {
        struct pt a = h[i], b = h[(i + 1) % n];
        double len = hypot(b.x - a.x, b.y - a.y);
        if (len > 0)
            m = fmin(m, cross(a, b, p) / len);
    }
    return m;
}

/*
 * The extended base's hull from its grid cells: the hull of the points on
 * one grid row is that of the row's two ends, so only those are sorted.
 * row_lo/row_hi hold the least and greatest cell column per row (row_lo >
 * row_hi: an empty row).
 */
static size_t
base_hull(const struct ray_grid *g, const uint32_t *row_lo, const uint32_t *row_hi, struct pt *pts,
          struct pt *hull)
{
    size_t n = 0;
    for (uint32_t j = 0; j < g->nw; j++) {
        if (row_lo[j] > row_hi[j])
            continue;
        double w = g->w0 + j * g->pitch;
        pts[n++] = (struct pt){ g->u0 + row_lo[j] * g->pitch, w };
        if (row_hi[j] != row_lo[j])
            pts[n++] = (struct pt){ g->u0 + row_hi[j] * g->pitch, w };
    }
    return convex_hull(pts, n, hull);
}

static void
base_add(uint32_t *row_lo, uint32_t *row_hi, uint32_t i, uint32_t j)
{
    row_lo[j] = i < row_lo[j] ? i : row_lo[j];
    row_hi[j] = i > row_hi[j] ? i : row_hi[j];
}

/* The first layer whose mid-height z_k = (k + 0.5) * layer lies at or above h
   (the layer in which the hit takes effect), computed as the layer loop's
   float z is, so a hit on the boundary falls where a per-layer scan puts it. */
static uint32_t
layer_of(float h, double layer_mm)
{
    /* a first guess, truncated rather than ceil()ed (a libm call per hit: 9 % of
       the simulation's instructions); the loops below end on the one layer that
       fits whatever the guess, as (l + 0.5) * layer grows with l */
    double k = h / layer_mm - 0.5;
    uint32_t l = k > 0 ? (uint32_t)k : 0;
    while (l > 0 && h <= (float)((l - 0.5) * layer_mm))
        l--;
    while (h > (float)((l + 0.5) * layer_mm))
        l++;
    return l;
}

/* The simulation's per-cell state and scratch (growth_simulate). */
struct sim {
    const struct ray_grid *g;
    uint8_t *solid, *was;
    uint32_t *changed_at; /* layer + 1 of the last change */
    uint32_t *visit;      /* id of the search that met it */
    uint32_t *stack, *changed;
    uint32_t *ev_first, *ev_hit, *ev_cell;
    uint32_t *ev_layer; /* layer of each hit */
    float *col_top;     /* highest column top per cell */
    float *floor_h;     /* last exit below, per cell */
    uint16_t *depth;    /* shells each ray is inside */
    uint32_t *row_lo, *row_hi;
    struct pt *base, *hull;
};

static void
sim_release(struct sim *s)
{
    free(s->solid);
    free(s->was);
    free(s->changed_at);
    free(s->visit);
    free(s->stack);
    free(s->changed);
    free(s->ev_first);
    free(s->ev_hit);
    free(s->ev_cell);
    free(s->ev_layer);
    free(s->col_top);
    free(s->floor_h);
    free(s->depth);
    free(s->row_lo);
    free(s->base);
    free(s->hull);
}

static bool
sim_alloc(struct sim *s, const struct ray_grid *g, size_t cells, uint32_t layers)
{
    size_t nh = g->n_hits ? g->n_hits : 1;
    s->g = g;
    s->solid = mem_calloc(cells, 1), s->was = mem_calloc(cells, 1);
    s->changed_at = mem_array(cells, sizeof(uint32_t));
    s->visit = mem_calloc(cells, sizeof(uint32_t));
    s->stack = mem_array(cells, sizeof(uint32_t));
    s->changed = mem_array(cells, sizeof(uint32_t));
    s->ev_first = mem_calloc((size_t)layers + 2, sizeof(uint32_t));
    s->ev_hit = mem_array(nh, sizeof(uint32_t)), s->ev_cell = mem_array(nh, sizeof(uint32_t));
    s->ev_layer = mem_array(nh, sizeof(uint32_t));
    s->col_top = mem_array(cells, sizeof(float));
    s->floor_h = mem_array(cells, sizeof(float));
    s->depth = mem_calloc(cells, sizeof(uint16_t));
    s->row_lo = mem_array(2 * (size_t)g->nw, sizeof(uint32_t));
    s->row_hi = s->row_lo ? s->row_lo + g->nw : NULL;
    s->base = mem_array(2 * (size_t)g->nw + 1, sizeof(struct pt));
    s->hull = mem_array(2 * (size_t)g->nw + 2, sizeof(struct pt));
    return s->solid && s->was && s->changed_at && s->visit && s->stack && s->changed &&
           s->ev_first && s->ev_hit && s->ev_cell && s->ev_layer && s->col_top && s->floor_h &&
           s->depth && s->row_lo && s->base && s->hull;
}

/* Counting sort of the hits by layer, stable: each cell's hits stay in height
   order.  Layer k's hits are ev_hit/ev_cell[ev_first[k] .. ev_first[k + 1]). */
static void
sort_events(struct sim *s, double layer_mm, uint32_t layers)
{
    const struct ray_grid *g = s->g;
    size_t cells = (size_t)g->nu * g->nw;
    for (size_t k = 0; k < g->n_hits; k++) {
        s->ev_layer[k] = layer_of(g->hits[k].h, layer_mm);
        if (s->ev_layer[k] < layers)
            s->ev_first[s->ev_layer[k] + 1]++;
    }
    for (uint32_t l = 0; l < layers; l++)
        s->ev_first[l + 1] += s->ev_first[l];
    for (size_t c = 0; c < cells; c++)
        for (uint32_t k = g->first[c]; k < g->first[c + 1]; k++)
            if (s->ev_layer[k] < layers) {
                uint32_t e = s->ev_first[s->ev_layer[k]]++;
                s->ev_hit[e] = k;
                s->ev_cell[e] = (uint32_t)c;
            }
    for (uint32_t l = layers; l > 0; l--) /* back to bucket starts */
        s->ev_first[l] = s->ev_first[l - 1];
    s->ev_first[0] = 0;
}

/* Apply layer k's hits, counting shells as measure_columns does, and keep the
   sums of this layer's voxels (li, lj, ln) up to date.  The new voxels go to
   the front of changed[], as seeds; returns how many. */
static size_t
apply_layer(struct sim *s, uint32_t k, uint64_t *li, uint64_t *lj, uint64_t *ln)
{
    const struct ray_grid *g = s->g;
    size_t n_changed = 0;
    for (uint32_t e = s->ev_first[k]; e < s->ev_first[k + 1]; e++) {
        uint32_t c = s->ev_cell[e];
        const struct ray_hit *h = &g->hits[s->ev_hit[e]];
        if (s->changed_at[c] != k + 1) {
            s->changed_at[c] = k + 1;
            s->was[c] = s->solid[c];
            s->changed[n_changed++] = c;
        }
        if (h->cos_up > 0) {
            s->depth[c] -= s->depth[c] > 0;
            if (s->depth[c] == 0)
                s->floor_h[c] = h->h;
        } else if (h->cos_up < 0) {
            s->depth[c]++;
        }
    }
    size_t n_new = 0;
    for (size_t q = 0; q < n_changed; q++) {
        uint32_t c = s->changed[q];
        uint8_t now = s->depth[c] > 0;
        if (now != s->solid[c]) {
            int64_t sign = now ? 1 : -1;
            *li += (uint64_t)(sign * (int64_t)(c % g->nu));
            *lj += (uint64_t)(sign * (int64_t)(c / g->nu));
            *ln += (uint64_t)sign;
            s->solid[c] = now;
        }
        if (now && !s->was[c])
            s->changed[n_new++] = c;
    }
    return n_new;
}

/* Regions of layer k (mid-height z) with a new voxel: held by the layer below,
   a column or (layer 0) the bed?  Those that are not are islands of out;
   *search numbers the searches. */
static void
find_islands(struct sim *s, uint32_t k, size_t n_new, float z, float half, uint32_t *search,
             struct growth_report *out)
{
    const struct ray_grid *g = s->g;
    uint32_t *visit = s->visit, *stack = s->stack;
    uint32_t layer_first = *search + 1;
    for (size_t q = 0; q < n_new && k > 0; q++) {
        uint32_t seed = s->changed[q];
        if (visit[seed] >= layer_first)
            continue; /* in a region searched already */
        size_t sp = 0, first = 0;
        bool held = false;
        double island_vol = 0;
        uint32_t id = ++*search;
        stack[sp++] = seed;
        visit[seed] = id;
        while (sp > first && !held) {
            uint32_t c = stack[first++];
            bool below = s->changed_at[c] == k + 1 ? s->was[c] : s->solid[c];
            if (below || (s->col_top[c] >= z - 3 * half && s->col_top[c] <= z + half)) {
                held = true;
                break;
            }
            island_vol += (z - half - s->floor_h[c]) * g->pitch * g->pitch;
            uint32_t ci = c % g->nu, cj = c / g->nu;
            uint32_t nb[4] = { ci > 0 ? c - 1 : UINT32_MAX, ci + 1 < g->nu ? c + 1 : UINT32_MAX,
                               cj > 0 ? c - g->nu : UINT32_MAX,
                               cj + 1 < g->nw ? c + g->nu : UINT32_MAX };
            for (int d = 0; d < 4; d++) {
                uint32_t n = nb[d];
                if (n == UINT32_MAX || !s->solid[n] || visit[n] == id)
                    continue;
                if (visit[n] >= layer_first) {
                    held = true; /* an earlier search of this layer stopped there, held */
                    break;
                }
                visit[n] = id;
                stack[sp++] = n;
            }
        }
        if (!held) {
            out->n_islands++;
            out->island_volume_mm3 += island_vol;
        }
    }
}

/*
 * Event-driven: a cell's solidity changes only at its hits, so the hits are
 * bucketed by the layer in which they take effect and each layer touches only
 * the cells that change in it.  Only a region holding a voxel that is new in
 * this layer (solid now, not below) can be an island, so the regions are
 * searched from the new voxels, and a search stops as soon as it meets a voxel
 * that is held, or one an earlier search of this layer met (that one stopped
 * held too: a search that finds no hold visits its whole region).
 */
int
growth_simulate(const struct ray_grid *g, const struct support_column *cols, size_t n_cols,
                double layer_mm, struct growth_report *out, struct sf_err *err)
{
    memset(out, 0, sizeof(*out));
    out->unstable_layer = -1;
    out->min_margin_mm = INFINITY;
    size_t cells = (size_t)g->nu * g->nw;
    float top = 0;
    for (size_t i = 0; i < g->n_hits; i++)
        top = g->hits[i].h > top ? g->hits[i].h : top;
    uint32_t layers = (uint32_t)ceil(top / layer_mm);
    if (layers == 0 || cells == 0)
        return SF_OK;
    out->n_layers = layers;

    struct sim s = { 0 };
    int rc = SF_OK;
    if (!sim_alloc(&s, g, cells, layers)) {
        rc = sf_err_set(err, SF_ENOMEM, "growth: out of memory for %zu cells", cells);
        goto out;
    }
    for (size_t c = 0; c < cells; c++) {
        s.changed_at[c] = 0;
        s.col_top[c] = -1;
        s.floor_h[c] = 0;
    }
    sort_events(&s, layer_mm, layers);
    for (uint32_t j = 0; j < g->nw; j++)
        s.row_lo[j] = UINT32_MAX, s.row_hi[j] = 0;
    for (size_t i = 0; i < n_cols; i++) {
        uint32_t c = cols[i].cell;
        s.col_top[c] = cols[i].hi > s.col_top[c] ? cols[i].hi : s.col_top[c];
        if (cols[i].lo < layer_mm)
            base_add(s.row_lo, s.row_hi, c % g->nu, c / g->nu);
    }
    uint64_t li = 0, lj = 0, ln = 0;    /* column and row sums and count of this layer's voxels */
    uint64_t si = 0, sj = 0, count = 0; /* the same over every layer so far */
    uint32_t search = 0;
    size_t hull_n = 0;
    float half = (float)(0.5 * layer_mm);
    for (uint32_t k = 0; k < layers; k++) {
        float z = (float)((k + 0.5) * layer_mm);
        size_t n_new = apply_layer(&s, k, &li, &lj, &ln);
        si += li, sj += lj, count += ln;
        if (k == 0) {
            for (size_t q = 0; q < n_new; q++)
                base_add(s.row_lo, s.row_hi, s.changed[q] % g->nu, s.changed[q] / g->nu);
            hull_n = base_hull(g, s.row_lo, s.row_hi, s.base, s.hull);
        }
        find_islands(&s, k, n_new, z, half, &search, out);
        /* what is built so far must stand on the extended base */
        if (count > 0) {
            struct pt com = { g->u0 + g->pitch * ((double)si / (double)count),
                              g->w0 + g->pitch * ((double)sj / (double)count) };
            double m = margin_in(s.hull, hull_n, com);
            if (m < out->min_margin_mm)
                out->min_margin_mm = m;
            if (m < 0 && out->unstable_layer < 0)
                out->unstable_layer = (int)k;
        }
    }
out:
    sim_release(&s);
    return rc;
}
