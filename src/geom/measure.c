/*
 * measure.c - support and deviation metrics shared by every stage
 * (see measure.h for the conventions).
 *
 * Support columns follow the rays structure of Allen & Dutta: walking up a
 * ray, the last surface below is the bed or the part's last exit (an
 * up-facing hit); a down-facing hit on a risky face higher than min_gap
 * above it needs a column from there.  The ray counts the shells it is in,
 * so a down-facing face met from inside (overlapping shells, or an open mesh
 * missing its top) never gets a column through material.  Volume is exact for the grid: each
 * column contributes length * pitch^2.  Anchor points are clusters of
 * supported hits on neighbouring rays at similar heights (union-find), the
 * "contact clusters" of the support-slimming paper's direction search.
 *
 * Hausdorff distance uses Embree point queries with an exact closest point
 * on triangle (Ericson, Real-Time Collision Detection, 5.1.5).
 *
 * Pure functions; thread-safe on distinct outputs.
 */
#include "measure.h"

#include <embree3/rtcore.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"
#include "../base/uf.h"
#include "growth.h"

void
support_params_default(struct support_params *p)
{
    p->angle_deg = 45;
    p->pitch_mm = 1;
    p->min_gap_mm = 0.05;
}

static void
height_range(const struct mesh *m, struct vec3 up, double *lo, double *hi)
{
    double a = INFINITY, b = -INFINITY;
    for (uint32_t i = 0; i < m->n_verts; i++) {
        double d = v3_dot(m->v[i], up);
        a = min_d(a, d);
        b = max_d(b, d);
    }
    *lo = a;
    *hi = b;
}

void
measure_proxy(const struct mesh *m, struct vec3 up, const struct support_params *p,
              struct support_metrics *out)
{
    memset(out, 0, sizeof(*out));
    up = v3_normalize(up);
    double lo, hi;
    height_range(m, up, &lo, &hi);
    double tau = sin(p->angle_deg * M_PI / 180);
    for (uint32_t i = 0; i < m->n_tris; i++) {
        struct vec3 c = mesh_tri_cross(m, i);
        double twice_area = v3_len(c);
        if (!(twice_area > 0))
            continue;
        double cosd = v3_dot(c, up) / twice_area;
        if (cosd >= -tau)
            continue;
        double h = v3_dot(mesh_tri_centroid(m, i), up) - lo;
        if (h < p->min_gap_mm)
            continue; /* resting on the bed */
        out->n_risky++;
        out->risky_area_mm2 += 0.5 * twice_area;
        out->proxy_mm3 += 0.5 * twice_area * -cosd * h;
    }
    out->build_height_mm = hi - lo;
}

int
measure_columns(const struct ray_grid *g, const struct support_params *p,
                struct support_column **cols, size_t *n_cols, struct sf_err *err)
{
    float tau = (float)sin(p->angle_deg * M_PI / 180);
    float gap = (float)p->min_gap_mm;
    size_t n = 0, cap = 0;
    struct support_column *out = NULL;
    size_t cells = (size_t)g->nu * g->nw;
    for (size_t c = 0; c < cells; c++) {
        float below = 0; /* the bed */
        int depth = 0;   /* shells the ray is inside */
        for (uint32_t k = g->first[c]; k < g->first[c + 1]; k++) {
            const struct ray_hit *h = &g->hits[k];
            if (h->cos_up > 0) {
                /* leaving the part: its top surface is the new floor.  An exit
                   with no entry (a hole in an open mesh) still is a floor. */
                if (depth > 0)
                    depth--;
                if (depth == 0)
                    below = h->h;
                continue;
            }
            if (h->cos_up == 0)
                continue;
            /* entering: only a face met from outside can need a column; inside
               a shell (a missing top face, overlapping shells) it is material */
            bool outside = depth == 0;
            depth++;
            if (outside && h->cos_up < -tau && h->h - below > gap) {
                void *o = out;
                if (!mem_grow(&o, &cap, n + 1, sizeof(*out))) {
                    free(out);
                    return sf_err_set(err, SF_ENOMEM, "support columns: out of memory");
                }
                out = o;
                out[n].cell = (uint32_t)c;
                out[n].lo = below;
                out[n].hi = h->h;
                out[n].tri = h->tri;
                out[n].iface = false;
                n++;
            }
        }
    }
    *cols = out;
    *n_cols = n;
    return SF_OK;
}

/* Clusters of columns on 4-neighbouring cells whose tops are within 2 pitches. */
static uint32_t
count_anchors(const struct ray_grid *g, const struct support_column *cols, size_t n)
{
    if (n == 0)
        return 0;
    uint32_t *parent = mem_array(n, sizeof(uint32_t));
    /* columns are in cell order; index the first column of every cell */
    size_t cells = (size_t)g->nu * g->nw;
    uint32_t *start = mem_array(cells + 1, sizeof(uint32_t));
    if (!parent || !start) {
        free(parent);
        free(start);
        return 0;
    }
    for (size_t i = 0; i < n; i++)
        parent[i] = (uint32_t)i;
    size_t k = 0;
    for (size_t c = 0; c <= cells; c++) {
        while (k < n && cols[k].cell < c)
            k++;
        start[c] = (uint32_t)k;
    }
    float reach = (float)(2 * g->pitch);
    for (size_t i = 0; i < n; i++) {
        uint32_t c = cols[i].cell, ci = c % g->nu, cj = c / g->nu;
        uint32_t nb[2] = { UINT32_MAX, UINT32_MAX };
        if (ci + 1 < g->nu)
            nb[0] = c + 1;
        if (cj + 1 < g->nw)
            nb[1] = c + g->nu;
        for (int q = 0; q < 2; q++) {
            if (nb[q] == UINT32_MAX)
                continue;
            for (uint32_t o = start[nb[q]]; o < start[nb[q] + 1]; o++) {
                if (fabsf(cols[o].hi - cols[i].hi) <= reach)
                    uf_union(parent, (uint32_t)i, o);
            }
        }
    }
    uint32_t roots = 0;
    for (size_t i = 0; i < n; i++)
        roots += uf_find(parent, (uint32_t)i) == i;
    free(parent);
    free(start);
    return roots;
}

int
measure_support(const struct mesh *m, struct raycast *rc, struct vec3 up,
                const struct support_params *p, struct support_metrics *out, struct sf_err *err)
{
    return measure_support_cached(m, rc, NULL, up, p, out, err);
}

int
measure_support_cached(const struct mesh *m, struct raycast *rc, const struct proxy_cache *pc,
                       struct vec3 up, const struct support_params *p, struct support_metrics *out,
                       struct sf_err *err)
{
    return measure_support_angles(m, rc, pc, up, p, 1, out, err);
}

/* Everything but the risky-face figures, from a cast grid at p's angle. */
static int
metrics_on_grid(const struct ray_grid *g, struct raycast *rc, struct vec3 up,
                const struct support_params *p, struct support_metrics *out, struct sf_err *err)
{
    struct support_column *cols = NULL;
    size_t n = 0;
    int rcode = measure_columns(g, p, &cols, &n, err);
    if (rcode)
        return rcode;
    double cell = g->pitch * g->pitch;
    double len = 0;
    for (size_t i = 0; i < n; i++)
        len += cols[i].hi - cols[i].lo;
    out->volume_mm3 = len * cell;
    out->contact_area_mm2 = (double)n * cell;
    out->n_columns = (uint32_t)n;
    out->n_anchors = count_anchors(g, cols, n);
    out->n_rays = out->n_rays_open = 0;
    for (size_t c = 0; c < (size_t)g->nu * g->nw; c++) {
        if (g->first[c] == g->first[c + 1])
            continue;
        int depth = 0;
        bool unmatched = false;
        for (uint32_t k = g->first[c]; k < g->first[c + 1]; k++) {
            if (g->hits[k].cos_up < 0)
                depth++;
            else if (g->hits[k].cos_up > 0 && depth-- == 0)
                unmatched = true, depth = 0;
        }
        out->n_rays++;
        out->n_rays_open += unmatched || depth != 0;
    }
    struct vec3 com = raycast_com(rc);
    out->com_height_mm = v3_dot(com, up) - g->base;
    struct growth_report gr;
    rcode = growth_simulate(g, cols, n, g->pitch, &gr, err);
    if (rcode == SF_OK) {
        out->n_islands = gr.n_islands;
        out->island_volume_mm3 = gr.island_volume_mm3;
        out->volume_mm3 += gr.island_volume_mm3;
        out->base_margin_mm = gr.min_margin_mm;
    }
    free(cols);
    return rcode;
}

int
measure_support_angles(const struct mesh *m, struct raycast *rc, const struct proxy_cache *pc,
                       struct vec3 up, const struct support_params *p, int n_p,
                       struct support_metrics *out, struct sf_err *err)
{
    up = v3_normalize(up);
    for (int i = 1; i < n_p; i++)
        if (p[i].pitch_mm != p[0].pitch_mm)
            return sf_err_set(err, SF_EINVAL, "support metrics: one pitch for every angle");
    for (int i = 0; i < n_p; i++) {
        if (pc)
            proxy_eval(pc, up, &p[i], &out[i]);
        else
            measure_proxy(m, up, &p[i], &out[i]);
    }
    struct ray_grid g;
    int rcode = raycast_grid(rc, up, p[0].pitch_mm, &g, err);
    for (int i = 0; i < n_p && rcode == SF_OK; i++)
        rcode = metrics_on_grid(&g, rc, up, &p[i], &out[i], err);
    ray_grid_release(&g);
    return rcode;
}

int
measure_deviation(const struct mesh *a, const struct mesh *b, struct deviation *out,
                  struct sf_err *err)
{
    memset(out, 0, sizeof(*out));
    if (a->n_verts != b->n_verts || a->n_tris != b->n_tris)
        return sf_err_set(
            err, SF_EINVAL,
            "deviation needs the same connectivity (%u/%u vs %u/%u vertices/triangles)", a->n_verts,
            a->n_tris, b->n_verts, b->n_tris);
    measure_deviation_diag(a, b, mesh_diag(a), out);
    return SF_OK;
}

void
measure_deviation_diag(const struct mesh *a, const struct mesh *b, double diag,
                       struct deviation *out)
{
    memset(out, 0, sizeof(*out));
    double sum = 0;
    for (uint32_t i = 0; i < a->n_verts; i++) {
        double d = v3_len(v3_sub(a->v[i], b->v[i]));
        out->max_mm = max_d(out->max_mm, d);
        sum += d;
    }
    out->mean_mm = a->n_verts ? sum / a->n_verts : 0;
    if (diag > 0) {
        out->mndr = out->max_mm / diag;
        out->andr = out->mean_mm / diag;
    }
}

/* ---- Hausdorff ----------------------------------------------------------- */

struct closest {
    const struct mesh *m;
    struct vec3 p;
    double best2;
};

static bool
closest_fn(struct RTCPointQueryFunctionArguments *args)
{
    struct closest *c = args->userPtr;
    const uint32_t *t = c->m->t[args->primID];
    struct vec3 q = v3_closest_on_tri(c->p, c->m->v[t[0]], c->m->v[t[1]], c->m->v[t[2]]);
    struct vec3 d = v3_sub(q, c->p);
    double d2 = v3_dot(d, d);
    if (d2 < c->best2) {
        c->best2 = d2;
        args->query->radius = (float)(sqrt(d2) * (1 + 1e-6) + 1e-6);
        return true;
    }
    return false;
}

/* Scene for point queries over b (user bounds are not needed: triangles). */
static RTCScene
point_scene(RTCDevice dev, const struct mesh *b)
{
    RTCScene s = rtcNewScene(dev);
    RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
    float *vb = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                        3 * sizeof(float), b->n_verts + 1);
    unsigned *ib = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                           3 * sizeof(unsigned), b->n_tris);
    if (!s || !g || !vb || !ib) {
        if (g)
            rtcReleaseGeometry(g);
        if (s)
            rtcReleaseScene(s);
        return NULL;
    }
    for (uint32_t i = 0; i < b->n_verts; i++) {
        vb[3 * i] = (float)b->v[i].x;
        vb[3 * i + 1] = (float)b->v[i].y;
        vb[3 * i + 2] = (float)b->v[i].z;
    }
    memcpy(ib, b->t, sizeof(*b->t) * b->n_tris);
    rtcCommitGeometry(g);
    rtcAttachGeometry(s, g);
    rtcReleaseGeometry(g);
    rtcCommitScene(s);
    return s;
}

static double
dist_to(RTCScene s, const struct mesh *b, struct vec3 p)
{
    struct closest c = { b, p, INFINITY };
    struct RTCPointQuery q = { (float)p.x, (float)p.y, (float)p.z, 0, INFINITY };
    struct RTCPointQueryContext ctx;
    rtcInitPointQueryContext(&ctx);
    rtcPointQuery(s, &q, &ctx, closest_fn, &c);
    return sqrt(c.best2);
}

/* Max over a's vertices, edge midpoints and centroids of the distance to b. */
static double
one_sided(RTCScene sb, const struct mesh *a, const struct mesh *b)
{
    double worst = 0;
    for (uint32_t i = 0; i < a->n_verts; i++)
        worst = fmax(worst, dist_to(sb, b, a->v[i]));
    for (uint32_t i = 0; i < a->n_tris; i++) {
        struct vec3 p0 = a->v[a->t[i][0]], p1 = a->v[a->t[i][1]], p2 = a->v[a->t[i][2]];
        worst = fmax(worst, dist_to(sb, b, mesh_tri_centroid(a, i)));
        worst = fmax(worst, dist_to(sb, b, v3_scale(v3_add(p0, p1), 0.5)));
        worst = fmax(worst, dist_to(sb, b, v3_scale(v3_add(p1, p2), 0.5)));
        worst = fmax(worst, dist_to(sb, b, v3_scale(v3_add(p2, p0), 0.5)));
    }
    return worst;
}

int
measure_hausdorff(const struct mesh *a, const struct mesh *b, double *one, double *sym,
                  struct sf_err *err)
{
    if (!a->n_tris || !b->n_tris)
        return sf_err_set(err, SF_EINVAL, "Hausdorff distance of an empty mesh");
    RTCDevice dev = rtcNewDevice("threads=1");
    RTCScene sa = dev ? point_scene(dev, a) : NULL, sb = dev ? point_scene(dev, b) : NULL;
    int rc = SF_OK;
    if (!sa || !sb) {
        rc = sf_err_set(err, SF_ENOMEM, "embree: cannot build point-query scenes");
    } else {
        double ab = one_sided(sb, a, b);
        if (one)
            *one = ab;
        if (sym)
            *sym = fmax(ab, one_sided(sa, b, a));
    }
    if (sa)
        rtcReleaseScene(sa);
    if (sb)
        rtcReleaseScene(sb);
    if (dev)
        rtcReleaseDevice(dev);
    return rc;
}

/* ---- distance queries ---------------------------------------------------- */

struct surface_dist {
    RTCDevice dev;
    RTCScene scene;
    const struct mesh *m;
};

struct surface_dist *
surface_dist_new(const struct mesh *m, struct sf_err *err)
{
    if (!m->n_tris) {
        sf_err_set(err, SF_EINVAL, "distance to an empty mesh");
        return NULL;
    }
    struct surface_dist *d = mem_calloc(1, sizeof(*d));
    if (!d) {
        sf_err_set(err, SF_ENOMEM, "distance: out of memory");
        return NULL;
    }
    d->m = m;
    d->dev = rtcNewDevice("threads=1");
    d->scene = d->dev ? point_scene(d->dev, m) : NULL;
    if (!d->scene) {
        surface_dist_free(d);
        sf_err_set(err, SF_ENOMEM, "embree: cannot build a point-query scene");
        return NULL;
    }
    return d;
}

double
surface_dist_query(const struct surface_dist *d, struct vec3 p)
{
    return dist_to(d->scene, d->m, p);
}

void
surface_dist_free(struct surface_dist *d)
{
    if (!d)
        return;
    if (d->scene)
        rtcReleaseScene(d->scene);
    if (d->dev)
        rtcReleaseDevice(d->dev);
    free(d);
}
