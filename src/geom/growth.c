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

    uint8_t *prev = mem_calloc(cells, 1), *cur = mem_calloc(cells, 1);
    uint32_t *stack = mem_array(cells, sizeof(uint32_t));
    uint32_t *active = mem_array(cells, sizeof(uint32_t)); /* cells the part is still ahead of */
    uint32_t *cursor = mem_array(cells, sizeof(uint32_t)); /* next hit index per cell */
    float *col_top = mem_array(cells, sizeof(float));      /* highest column top per cell */
    float *floor_h = mem_array(cells, sizeof(float));      /* last exit below, per cell */
    uint16_t *depth = mem_calloc(cells, sizeof(uint16_t)); /* shells each ray is inside */
    uint32_t *row_lo = mem_array(2 * (size_t)g->nw, sizeof(uint32_t)), *row_hi = row_lo + g->nw;
    struct pt *base = mem_array(2 * (size_t)g->nw + 1, sizeof(struct pt));
    struct pt *hull = mem_array(2 * (size_t)g->nw + 2, sizeof(struct pt));
    int rc = SF_OK;
    if (!prev || !cur || !stack || !active || !cursor || !col_top || !floor_h || !depth ||
        !row_lo || !base || !hull) {
        rc = sf_err_set(err, SF_ENOMEM, "growth: out of memory for %zu cells", cells);
        goto out;
    }
    /* only cells with hits can ever be solid; a cell leaves the active list
       once the part is wholly below the layer (every hit passed, outside) */
    size_t n_active = 0;
    for (size_t c = 0; c < cells; c++) {
        cursor[c] = g->first[c];
        col_top[c] = -1;
        floor_h[c] = 0;
        if (g->first[c] < g->first[c + 1])
            active[n_active++] = (uint32_t)c;
    }
    for (uint32_t j = 0; j < g->nw; j++)
        row_lo[j] = UINT32_MAX, row_hi[j] = 0;
    for (size_t i = 0; i < n_cols; i++) {
        uint32_t c = cols[i].cell;
        col_top[c] = cols[i].hi > col_top[c] ? cols[i].hi : col_top[c];
        if (cols[i].lo < layer_mm)
            base_add(row_lo, row_hi, c % g->nu, c / g->nu);
    }
    uint64_t si = 0, sj = 0, count = 0; /* voxel column and row sums so far */
    size_t hull_n = 0;
    float half = (float)(0.5 * layer_mm);
    for (uint32_t k = 0; k < layers; k++) {
        float z = (float)((k + 0.5) * layer_mm);
        /* solid voxels of this layer: advance each ray's hit cursor to z,
           counting shells as measure_columns does */
        size_t kept = 0;
        for (size_t a = 0; a < n_active; a++) {
            uint32_t c = active[a], e = g->first[c + 1];
            while (cursor[c] < e && g->hits[cursor[c]].h <= z) {
                const struct ray_hit *h = &g->hits[cursor[c]];
                if (h->cos_up > 0) {
                    depth[c] -= depth[c] > 0;
                    if (depth[c] == 0)
                        floor_h[c] = h->h;
                } else if (h->cos_up < 0) {
                    depth[c]++;
                }
                cursor[c]++;
            }
            cur[c] = depth[c] > 0;
            if (cur[c]) {
                si += c % g->nu;
                sj += c / g->nu;
                count++;
            }
            if (cursor[c] < e || depth[c] > 0)
                active[kept++] = c;
            else
                cur[c] = prev[c] = 0; /* never read again: no solid voxel reaches it */
        }
        n_active = kept;
        if (k == 0) {
            for (size_t a = 0; a < n_active; a++)
                if (cur[active[a]])
                    base_add(row_lo, row_hi, active[a] % g->nu, active[a] / g->nu);
            hull_n = base_hull(g, row_lo, row_hi, base, hull);
        }
        /* label regions; a region held by nothing is an island */
        for (size_t a = 0; a < n_active; a++) {
            uint32_t seed = active[a];
            if (cur[seed] != 1)
                continue;
            size_t sp = 0, first = 0;
            bool held = k == 0;
            double island_vol = 0;
            stack[sp++] = seed;
            cur[seed] = 2;
            while (sp > first) {
                uint32_t c = stack[first++];
                if (prev[c] || (col_top[c] >= z - 3 * half && col_top[c] <= z + half))
                    held = true;
                island_vol += (z - half - floor_h[c]) * g->pitch * g->pitch;
                uint32_t ci = c % g->nu, cj = c / g->nu;
                uint32_t nb[4] = { ci > 0 ? c - 1 : UINT32_MAX, ci + 1 < g->nu ? c + 1 : UINT32_MAX,
                                   cj > 0 ? c - g->nu : UINT32_MAX,
                                   cj + 1 < g->nw ? c + g->nu : UINT32_MAX };
                for (int q = 0; q < 4; q++)
                    if (nb[q] != UINT32_MAX && cur[nb[q]] == 1) {
                        cur[nb[q]] = 2;
                        stack[sp++] = nb[q];
                    }
            }
            if (!held) {
                out->n_islands++;
                out->island_volume_mm3 += island_vol;
            }
        }
        /* what is built so far must stand on the extended base */
        if (count > 0) {
            struct pt com = { g->u0 + g->pitch * ((double)si / (double)count),
                              g->w0 + g->pitch * ((double)sj / (double)count) };
            double m = margin_in(hull, hull_n, com);
            if (m < out->min_margin_mm)
                out->min_margin_mm = m;
            if (m < 0 && out->unstable_layer < 0)
                out->unstable_layer = (int)k;
        }
        /* solid voxels of this layer (1 or 2) hold the next one */
        uint8_t *t = prev;
        prev = cur;
        cur = t;
    }
out:
    free(prev);
    free(cur);
    free(stack);
    free(active);
    free(cursor);
    free(col_top);
    free(floor_h);
    free(depth);
    free(row_lo);
    free(base);
    free(hull);
    return rc;
}
