/*
 * proxy.c - the binned support proxy (see proxy.h).
 *
 * Bins: the cube map of normals, PROXY_K x PROXY_K cells per face, about
 * 5 degrees wide at K = 16.  A bin's cone is its centre and the widest
 * member angle.  For direction d with angle t between the centre and d and
 * cone radius r, every member's n.d lies in [cos(t + r), cos(t - r)], so
 * the bin is wholly risky when cos(t - r) < -tau, wholly safe when
 * cos(t + r) >= -tau.  Faces within min_gap of the bed are left out of the
 * proxy, so a bin is summed in closed form only if its centroids' bounding
 * box lies wholly above that: otherwise it is walked face by face.
 * Sums are kept in double; the walked loops are branch-free float SoA so
 * they vectorise (this file is built at -O3, see the Makefile).
 */
#include "proxy.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"
#include "measure.h"

#define PROXY_K 16

/* Cube-map bin of a unit normal. */
static uint32_t
bin_of(struct vec3 n)
{
    double ax = fabs(n.x), ay = fabs(n.y), az = fabs(n.z);
    int face;
    double u, v, major;
    if (ax >= ay && ax >= az)
        face = n.x > 0 ? 0 : 1, major = ax, u = n.y, v = n.z;
    else if (ay >= az)
        face = n.y > 0 ? 2 : 3, major = ay, u = n.x, v = n.z;
    else
        face = n.z > 0 ? 4 : 5, major = az, u = n.x, v = n.y;
    int i = (int)((u / major + 1) * 0.5 * PROXY_K), j = (int)((v / major + 1) * 0.5 * PROXY_K);
    i = i < 0 ? 0 : i >= PROXY_K ? PROXY_K - 1 : i;
    j = j < 0 ? 0 : j >= PROXY_K ? PROXY_K - 1 : j;
    return (uint32_t)((face * PROXY_K + j) * PROXY_K + i);
}

int
proxy_cache_init(struct proxy_cache *pc, const struct mesh *m, const uint32_t *extreme,
                 uint32_t n_extreme, struct sf_err *err)
{
    memset(pc, 0, sizeof(*pc));
    uint32_t n_bins = 6 * PROXY_K * PROXY_K;
    uint32_t n_v = extreme ? n_extreme : m->n_verts;
    size_t nt = m->n_tris ? m->n_tris : 1, nv = n_v ? n_v : 1;
    float *block = mem_array(7 * nt + 3 * nv, sizeof(float));
    uint32_t *bin = mem_array(nt, sizeof(uint32_t));
    uint32_t *fill = mem_calloc(n_bins + 1, sizeof(uint32_t));
    pc->bins = mem_calloc(n_bins, sizeof(*pc->bins));
    if (!block || !bin || !fill || !pc->bins) {
        free(block);
        free(bin);
        free(fill);
        free(pc->bins);
        pc->bins = NULL;
        return sf_err_set(err, SF_ENOMEM, "proxy: out of memory for %u triangles", m->n_tris);
    }
    pc->nx = block, pc->ny = block + nt, pc->nz = block + 2 * nt, pc->area = block + 3 * nt;
    pc->gx = block + 4 * nt, pc->gy = block + 5 * nt, pc->gz = block + 6 * nt;
    pc->vx = block + 7 * nt, pc->vy = block + 7 * nt + nv, pc->vz = block + 7 * nt + 2 * nv;
    pc->n_bins = n_bins;
    pc->n_verts = n_v;
    for (uint32_t i = 0; i < n_v; i++) {
        struct vec3 v = m->v[extreme ? extreme[i] : i];
        pc->vx[i] = (float)v.x, pc->vy[i] = (float)v.y, pc->vz[i] = (float)v.z;
    }
    /* counting sort of the faces by bin */
    for (uint32_t i = 0; i < m->n_tris; i++) {
        struct vec3 c = mesh_tri_cross(m, i);
        double len = v3_len(c);
        bin[i] = len > 0 ? bin_of(v3_scale(c, 1 / len)) : UINT32_MAX;
        if (bin[i] != UINT32_MAX)
            fill[bin[i] + 1]++;
    }
    for (uint32_t b = 0; b < n_bins; b++) {
        fill[b + 1] += fill[b];
        pc->bins[b].first = fill[b];
        pc->bins[b].n = fill[b + 1] - fill[b];
    }
    pc->n_tris = fill[n_bins];
    for (uint32_t i = 0; i < m->n_tris; i++) {
        if (bin[i] == UINT32_MAX)
            continue;
        uint32_t k = fill[bin[i]]++;
        struct vec3 c = mesh_tri_cross(m, i), g = mesh_tri_centroid(m, i);
        double len = v3_len(c);
        struct vec3 n = v3_scale(c, 1 / len);
        double a = 0.5 * len;
        pc->nx[k] = (float)n.x, pc->ny[k] = (float)n.y, pc->nz[k] = (float)n.z;
        pc->area[k] = (float)a;
        pc->gx[k] = (float)g.x, pc->gy[k] = (float)g.y, pc->gz[k] = (float)g.z;
        struct proxy_bin *pb = &pc->bins[bin[i]];
        float gf[3] = { (float)g.x, (float)g.y, (float)g.z };
        for (int q = 0; q < 3; q++) {
            if (pb->area == 0 || gf[q] < pb->lo[q])
                pb->lo[q] = gf[q];
            if (pb->area == 0 || gf[q] > pb->hi[q])
                pb->hi[q] = gf[q];
        }
        double nn[3] = { n.x, n.y, n.z }, gg[3] = { g.x, g.y, g.z };
        pb->area += a;
        for (int r = 0; r < 3; r++) {
            pb->s[r] += a * nn[r];
            for (int q = 0; q < 3; q++)
                pb->mm[3 * r + q] += a * nn[r] * gg[q];
        }
    }
    /* cone of each bin: centre = normalised area-weighted mean normal */
    for (uint32_t b = 0; b < n_bins; b++) {
        struct proxy_bin *pb = &pc->bins[b];
        if (!pb->n)
            continue;
        struct vec3 c = v3_normalize(v3(pb->s[0], pb->s[1], pb->s[2]));
        if (v3_len(c) == 0) /* opposite normals cancelled: impossible within one cube cell */
            c = v3(pc->nx[pb->first], pc->ny[pb->first], pc->nz[pb->first]);
        float mincos = 1;
        for (uint32_t k = pb->first; k < pb->first + pb->n; k++) {
            float d = (float)(pc->nx[k] * c.x + pc->ny[k] * c.y + pc->nz[k] * c.z);
            mincos = d < mincos ? d : mincos;
        }
        /* widen a little so float rounding never puts a member outside */
        double r = acos(fmax(-1, fmin(1, (double)mincos))) + 1e-4;
        pb->cx = (float)c.x, pb->cy = (float)c.y, pb->cz = (float)c.z;
        pb->cos_radius = (float)cos(r);
        pb->sin_radius = (float)sin(r);
    }
    /* Keep only the bins that hold faces, in order: every evaluation walks the
       bins, and most of the 1,536 are empty on a part of few face directions
       (anchor: 11 of 23 M proxy instructions went to skipping empty bins).
       The sums see the same bins in the same order, so nothing changes. */
    uint32_t kept = 0;
    for (uint32_t b = 0; b < n_bins; b++)
        if (pc->bins[b].n)
            pc->bins[kept++] = pc->bins[b];
    pc->n_bins = kept;
    free(bin);
    free(fill);
    return SF_OK;
}

void
proxy_cache_release(struct proxy_cache *pc)
{
    free(pc->nx);
    free(pc->bins);
    memset(pc, 0, sizeof(*pc));
}

static void
height_range(const struct proxy_cache *pc, float ux, float uy, float uz, float *lo, float *hi)
{
    float a = INFINITY, b = -INFINITY;
    for (uint32_t i = 0; i < pc->n_verts; i++) {
        float d = pc->vx[i] * ux + pc->vy[i] * uy + pc->vz[i] * uz;
        a = d < a ? d : a;
        b = d > b ? d : b;
    }
    *lo = a;
    *hi = b;
}

void
proxy_eval(const struct proxy_cache *pc, struct vec3 up, const struct support_params *p,
           struct support_metrics *out)
{
    memset(out, 0, sizeof(*out));
    up = v3_normalize(up);
    float ux = (float)up.x, uy = (float)up.y, uz = (float)up.z;
    float lo, hi;
    height_range(pc, ux, uy, uz, &lo, &hi);
    float tau = (float)sin(p->angle_deg * M_PI / 180);
    float floor_h = lo + (float)p->min_gap_mm;
    double area = 0, proxy = 0, n = 0;
    for (uint32_t b = 0; b < pc->n_bins; b++) {
        const struct proxy_bin *pb = &pc->bins[b];
        if (!pb->n)
            continue;
        float ct = pb->cx * ux + pb->cy * uy + pb->cz * uz; /* cos t */
        float st2 = 1 - ct * ct;
        float st = sqrtf(st2 > 0 ? st2 : 0);                         /* not fmaxf: a libm call */
        float cos_plus = ct * pb->cos_radius - st * pb->sin_radius;  /* cos(t + r) */
        float cos_minus = ct * pb->cos_radius + st * pb->sin_radius; /* cos(t - r) */
        bool holds_down = -ct >= pb->cos_radius; /* -d inside the cone: bed faces */
        if (cos_plus >= -tau && !holds_down)
            continue; /* every member safe (cos(t + r) is the least n.d unless the cone
                         wraps past -d) */
        /* lowest member centroid can be no lower than the box's support point */
        float box_lo = (ux > 0 ? pb->lo[0] : pb->hi[0]) * ux +
                       (uy > 0 ? pb->lo[1] : pb->hi[1]) * uy +
                       (uz > 0 ? pb->lo[2] : pb->hi[2]) * uz;
        if (cos_minus < -tau && !holds_down && box_lo >= floor_h + 1e-3f) {
            /* every member risky: the closed form (proxy.h) */
            double d[3] = { ux, uy, uz }, dmd = 0, sd = 0;
            for (int r = 0; r < 3; r++) {
                sd += pb->s[r] * d[r];
                for (int q = 0; q < 3; q++)
                    dmd += d[r] * pb->mm[3 * r + q] * d[q];
            }
            n += pb->n;
            area += pb->area;
            proxy += -dmd + lo * sd;
            continue;
        }
        float fa = 0, fp = 0, fn = 0;
        for (uint32_t k = pb->first; k < pb->first + pb->n; k++) {
            float cosd = pc->nx[k] * ux + pc->ny[k] * uy + pc->nz[k] * uz;
            float h = pc->gx[k] * ux + pc->gy[k] * uy + pc->gz[k] * uz;
            float risky = (cosd < -tau) & (h >= floor_h) ? 1.0f : 0.0f;
            fn += risky;
            fa += risky * pc->area[k];
            fp += risky * pc->area[k] * -cosd * (h - lo);
        }
        n += fn;
        area += fa;
        proxy += fp;
    }
    out->n_risky = (uint32_t)n;
    out->risky_area_mm2 = area;
    out->proxy_mm3 = proxy;
    out->build_height_mm = hi - lo;
}

double
proxy_bed_contact(const struct proxy_cache *pc, struct vec3 up)
{
    up = v3_normalize(up);
    float ux = (float)up.x, uy = (float)up.y, uz = (float)up.z;
    float lo, hi;
    height_range(pc, ux, uy, uz, &lo, &hi);
    double area = 0;
    for (uint32_t b = 0; b < pc->n_bins; b++) {
        const struct proxy_bin *pb = &pc->bins[b];
        /* only the bins whose cone holds -d can hold faces facing straight down */
        if (!pb->n || -(pb->cx * ux + pb->cy * uy + pb->cz * uz) < pb->cos_radius - 1e-3f)
            continue;
        float a = 0;
        for (uint32_t k = pb->first; k < pb->first + pb->n; k++) {
            float cosd = pc->nx[k] * ux + pc->ny[k] * uy + pc->nz[k] * uz;
            float h = pc->gx[k] * ux + pc->gy[k] * uy + pc->gz[k] * uz - lo;
            a += (cosd < -0.9999f) & (h < 0.1f) ? pc->area[k] : 0.0f;
        }
        area += a;
    }
    return area;
}
