/*
 * saliency.c - mesh saliency (Lee, Varshney & Jacobs 2005); see saliency.h.
 */
#include "saliency.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"

#define N_SIGMA 8
/* Gaussian scales in units of eps; the centre-surround pairs are (s, 2s). */
static const double sigma_eps[N_SIGMA] = { 2, 3, 4, 5, 6, 8, 10, 12 };
static const int pair_lo[5] = { 0, 1, 2, 3, 4 }; /* 2 3 4 5 6 */
static const int pair_hi[5] = { 2, 4, 5, 6, 7 }; /* 4 6 8 10 12 */

/* The wider scales average over every k-th vertex only (k grows with the
 * scale's area, picked by a hash of the index so it does not follow the
 * file's order): each scale then sees about as many neighbours as the
 * finest, and the cost stays linear in the vertices.  The Gaussian mean of
 * a dense sample is the same to within noise. */
static uint32_t
scale_stride(int k)
{
    double r = sigma_eps[k] / sigma_eps[0];
    return r * r / 2 > 1 ? (uint32_t)(r * r / 2) : 1;
}

static bool
sampled(uint32_t v, uint32_t stride)
{
    return stride == 1 || ((v * 2654435761u) >> 8) % stride == 0;
}

/* Mean curvature per vertex from the cotangent Laplacian: H = -(Lx . n) / (4 A). */
static void
mean_curvature(const struct mesh *m, struct vec3 *lap, struct vec3 *nrm, double *area, double *h)
{
    for (uint32_t f = 0; f < m->n_tris; f++) {
        const uint32_t *t = m->t[f];
        struct vec3 p[3] = { m->v[t[0]], m->v[t[1]], m->v[t[2]] };
        struct vec3 cr = v3_cross(v3_sub(p[1], p[0]), v3_sub(p[2], p[0]));
        double a = v3_len(cr) / 2;
        for (int k = 0; k < 3; k++) {
            uint32_t i = t[k], j = t[(k + 1) % 3];
            struct vec3 po = p[(k + 2) % 3];
            struct vec3 u = v3_sub(p[k], po), w = v3_sub(p[(k + 1) % 3], po);
            double s = v3_len(v3_cross(u, w));
            /* cot of the angle opposite edge ij; sliver triangles are clamped */
            double cot = s > 1e-12 ? v3_dot(u, w) / s : 0;
            cot = fmax(-100, fmin(100, cot));
            struct vec3 e = v3_scale(v3_sub(p[(k + 1) % 3], p[k]), cot);
            lap[i] = v3_add(lap[i], e);
            lap[j] = v3_sub(lap[j], e);
            nrm[t[k]] = v3_add(nrm[t[k]], cr);
            area[t[k]] += a / 3;
        }
    }
    for (uint32_t v = 0; v < m->n_verts; v++)
        h[v] = area[v] > 0 ? -v3_dot(lap[v], v3_normalize(nrm[v])) / (4 * area[v]) : 0;
}

/* Uniform grid over the bbox: cell_start[c]..cell_start[c+1] in order[]. */
struct grid {
    struct vec3 lo;
    double cell;
    int nx, ny, nz;
    uint32_t *start, *order;
};

static int
cell_of(const struct grid *g, struct vec3 p, int axis)
{
    double x = axis == 0 ? p.x - g->lo.x : axis == 1 ? p.y - g->lo.y : p.z - g->lo.z;
    int n = axis == 0 ? g->nx : axis == 1 ? g->ny : g->nz;
    int c = (int)(x / g->cell);
    return c < 0 ? 0 : c >= n ? n - 1 : c;
}

static int
grid_build(struct grid *g, const struct mesh *m, uint32_t stride, double cell, struct sf_err *err)
{
    struct vec3 hi;
    mesh_bbox(m, &g->lo, &hi);
    /* at most 256 cells an axis (a sliver of a part with a tiny scale) */
    double ext = fmax(hi.x - g->lo.x, fmax(hi.y - g->lo.y, hi.z - g->lo.z));
    g->cell = fmax(cell, ext / 255);
    g->nx = (int)((hi.x - g->lo.x) / g->cell) + 1;
    g->ny = (int)((hi.y - g->lo.y) / g->cell) + 1;
    g->nz = (int)((hi.z - g->lo.z) / g->cell) + 1;
    size_t n_cells = (size_t)g->nx * g->ny * g->nz;
    uint32_t n = 0;
    for (uint32_t v = 0; v < m->n_verts; v++)
        n += sampled(v, stride);
    g->start = mem_calloc(n_cells + 1, sizeof(uint32_t));
    g->order = mem_calloc(n ? n : 1, sizeof(uint32_t));
    if (!g->start || !g->order)
        return sf_err_set(err, SF_ENOMEM, "saliency: out of memory for the vertex grid");
    for (uint32_t v = 0; v < m->n_verts; v++) {
        if (!sampled(v, stride))
            continue;
        struct vec3 p = m->v[v];
        g->start[((size_t)cell_of(g, p, 2) * g->ny + cell_of(g, p, 1)) * g->nx + cell_of(g, p, 0) +
                 1]++;
    }
    for (size_t c = 0; c < n_cells; c++)
        g->start[c + 1] += g->start[c];
    uint32_t *fill = mem_calloc(n_cells, sizeof(uint32_t));
    if (!fill)
        return sf_err_set(err, SF_ENOMEM, "saliency: out of memory for the vertex grid");
    for (uint32_t v = 0; v < m->n_verts; v++) {
        if (!sampled(v, stride))
            continue;
        struct vec3 p = m->v[v];
        size_t c = ((size_t)cell_of(g, p, 2) * g->ny + cell_of(g, p, 1)) * g->nx + cell_of(g, p, 0);
        g->order[g->start[c] + fill[c]++] = v;
    }
    free(fill);
    return SF_OK;
}

/* Gaussian-weighted average of h around every vertex at scale k, over the
 * vertices of grid g (cells 2 sigma wide: the filter reaches 2 sigma). */
static void
gaussian_average(const struct mesh *m, const struct grid *g, const double *h, double sigma,
                 double (*avg)[N_SIGMA], int k)
{
    double cut2 = 4 * sigma * sigma, inv2s2 = 1 / (2 * sigma * sigma);
    for (uint32_t v = 0; v < m->n_verts; v++) {
        struct vec3 p = m->v[v];
        double num = 0, den = 0;
        int cx = cell_of(g, p, 0), cy = cell_of(g, p, 1), cz = cell_of(g, p, 2);
        for (int z = cz - 1; z <= cz + 1; z++) {
            if (z < 0 || z >= g->nz)
                continue;
            for (int y = cy - 1; y <= cy + 1; y++) {
                if (y < 0 || y >= g->ny)
                    continue;
                for (int x = cx - 1; x <= cx + 1; x++) {
                    if (x < 0 || x >= g->nx)
                        continue;
                    size_t c = ((size_t)z * g->ny + y) * g->nx + x;
                    for (uint32_t i = g->start[c]; i < g->start[c + 1]; i++) {
                        uint32_t u = g->order[i];
                        struct vec3 d = v3_sub(m->v[u], p);
                        double d2 = v3_dot(d, d);
                        if (d2 > cut2)
                            continue;
                        double w = exp(-d2 * inv2s2);
                        num += w * h[u];
                        den += w;
                    }
                }
            }
        }
        avg[v][k] = den > 0 ? num / den : h[v];
    }
}

/* Scale map to [0, 1] and weight it by (1 - mean of its other local maxima)^2. */
static void
normalize_map(const struct mesh *m, double *map, unsigned char *is_max)
{
    double hi = 0;
    for (uint32_t v = 0; v < m->n_verts; v++)
        hi = fmax(hi, map[v]);
    if (hi <= 0)
        return;
    memset(is_max, 1, m->n_verts);
    for (uint32_t v = 0; v < m->n_verts; v++)
        map[v] /= hi;
    for (uint32_t f = 0; f < m->n_tris; f++) {
        for (int k = 0; k < 3; k++) {
            uint32_t a = m->t[f][k], b = m->t[f][(k + 1) % 3];
            if (map[a] < map[b])
                is_max[a] = 0;
            if (map[b] < map[a])
                is_max[b] = 0;
        }
    }
    double sum = 0;
    uint32_t n = 0;
    for (uint32_t v = 0; v < m->n_verts; v++) {
        if (is_max[v] && map[v] < 1) {
            sum += map[v];
            n++;
        }
    }
    double mean = n ? sum / n : 0;
    double w = (1 - mean) * (1 - mean);
    for (uint32_t v = 0; v < m->n_verts; v++)
        map[v] *= w;
}

int
mesh_saliency(const struct mesh *m, double *out, struct sf_err *err)
{
    uint32_t n = m->n_verts;
    memset(out, 0, (size_t)n * sizeof(double));
    double diag = mesh_diag(m);
    if (n == 0 || m->n_tris == 0 || !(diag > 0))
        return SF_OK;
    double eps = 0.003 * diag;
    int rc = SF_ENOMEM;
    struct grid g = { 0 };
    struct vec3 *lap = mem_calloc(n, sizeof(*lap));
    struct vec3 *nrm = mem_calloc(n, sizeof(*nrm));
    double *area = mem_calloc(n, sizeof(*area));
    double *h = mem_calloc(n, sizeof(*h));
    double(*avg)[N_SIGMA] = mem_calloc(n, sizeof(*avg));
    double *map = mem_calloc(n, sizeof(*map));
    unsigned char *is_max = mem_calloc(n, 1);
    if (!lap || !nrm || !area || !h || !avg || !map || !is_max) {
        rc = sf_err_set(err, SF_ENOMEM, "saliency: out of memory for %u vertices", n);
        goto out;
    }
    mean_curvature(m, lap, nrm, area, h);
    for (int k = 0; k < N_SIGMA; k++) {
        double sigma = sigma_eps[k] * eps;
        if ((rc = grid_build(&g, m, scale_stride(k), 2 * sigma, err)) < 0)
            goto out;
        gaussian_average(m, &g, h, sigma, avg, k);
        free(g.start);
        free(g.order);
        g.start = g.order = NULL;
    }
    for (int i = 0; i < 5; i++) {
        for (uint32_t v = 0; v < n; v++)
            map[v] = fabs(avg[v][pair_lo[i]] - avg[v][pair_hi[i]]);
        normalize_map(m, map, is_max);
        for (uint32_t v = 0; v < n; v++)
            out[v] += map[v];
    }
    double hi = 0;
    for (uint32_t v = 0; v < n; v++)
        hi = fmax(hi, out[v]);
    for (uint32_t v = 0; v < n && hi > 0; v++)
        out[v] /= hi;
    rc = SF_OK;
out:
    free(g.start);
    free(g.order);
    free(lap);
    free(nrm);
    free(area);
    free(h);
    free(avg);
    free(map);
    free(is_max);
    return rc;
}
