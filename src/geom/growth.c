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
        top = fmaxf(top, g->hits[i].h);
    uint32_t layers = (uint32_t)ceil(top / layer_mm);
    if (layers == 0 || cells == 0)
        return SF_OK;
    out->n_layers = layers;

    uint8_t *prev = mem_calloc(cells, 1), *cur = mem_calloc(cells, 1);
    uint32_t *stack = mem_array(cells, sizeof(uint32_t));
    uint32_t *cursor = mem_array(cells, sizeof(uint32_t)); /* next hit index per cell */
    float *col_top = mem_array(cells, sizeof(float));      /* highest column top per cell */
    float *floor_h = mem_array(cells, sizeof(float));      /* last exit below, per cell */
    uint16_t *depth = mem_calloc(cells, sizeof(uint16_t));  /* shells each ray is inside */
    struct pt *base = mem_array(cells + n_cols + 1, sizeof(struct pt));
    struct pt *hull = mem_array(cells + n_cols + 2, sizeof(struct pt));
    int rc = SF_OK;
    if (!prev || !cur || !stack || !cursor || !col_top || !floor_h || !depth || !base || !hull) {
        rc = sf_err_set(err, SF_ENOMEM, "growth: out of memory for %zu cells", cells);
        goto out;
    }
    for (size_t c = 0; c < cells; c++) {
        cursor[c] = g->first[c];
        col_top[c] = -1;
        floor_h[c] = 0;
    }
    size_t n_base = 0;
    for (size_t i = 0; i < n_cols; i++) {
        col_top[cols[i].cell] = fmaxf(col_top[cols[i].cell], cols[i].hi);
        if (cols[i].lo < layer_mm) {
            uint32_t c = cols[i].cell;
            base[n_base++] =
                (struct pt){ g->u0 + (c % g->nu) * g->pitch, g->w0 + (c / g->nu) * g->pitch };
        }
    }
    double sx = 0, sy = 0, count = 0;
    size_t hull_n = 0;
    float half = (float)(0.5 * layer_mm);
    for (uint32_t k = 0; k < layers; k++) {
        float z = (float)((k + 0.5) * layer_mm);
        /* solid voxels of this layer: advance each ray's hit cursor to z,
           counting shells as measure_columns does */
        for (size_t c = 0; c < cells; c++) {
            uint32_t e = g->first[c + 1];
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
                sx += g->u0 + (c % g->nu) * g->pitch;
                sy += g->w0 + (c / g->nu) * g->pitch;
                count++;
            }
        }
        if (k == 0) {
            for (size_t c = 0; c < cells; c++)
                if (cur[c])
                    base[n_base++] = (struct pt){ g->u0 + (c % g->nu) * g->pitch,
                                                  g->w0 + (c / g->nu) * g->pitch };
            hull_n = convex_hull(base, n_base, hull);
        }
        /* label regions; a region held by nothing is an island */
        for (size_t seed = 0; seed < cells; seed++) {
            if (cur[seed] != 1)
                continue;
            size_t sp = 0, first = 0;
            bool held = k == 0;
            double island_vol = 0;
            stack[sp++] = (uint32_t)seed;
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
            double m = margin_in(hull, hull_n, (struct pt){ sx / count, sy / count });
            if (m < out->min_margin_mm)
                out->min_margin_mm = m;
            if (m < 0 && out->unstable_layer < 0)
                out->unstable_layer = (int)k;
        }
        uint8_t *t = prev;
        prev = cur;
        cur = t;
        for (size_t c = 0; c < cells; c++)
            prev[c] = prev[c] != 0;
    }
out:
    free(prev);
    free(cur);
    free(stack);
    free(cursor);
    free(col_top);
    free(floor_h);
    free(depth);
    free(base);
    free(hull);
    return rc;
}
