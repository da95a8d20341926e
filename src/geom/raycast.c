/*
 * raycast.c - the rays structure on Embree 3 (see raycast.h).
 *
 * One process-wide Embree device (created once; its thread pool is shared)
 * and one scene per part.  A grid is cast in bands of four rows, as
 * rtcIntersect16 packets of 4 x 4 rays; an intersection filter on the
 * geometry records every hit (ray id, distance, triangle) into the band's
 * collector and rejects it, so one traversal per ray yields all hits, in no
 * particular order.  The band's hits are then bucketed by cell (counting
 * sort), each bucket sorted by height (ties by triangle), and duplicates
 * removed: a ray through an edge shared by two triangles facing the same
 * way reports the crossing twice.
 *
 * The collector rides in an extended RTCIntersectContext (Embree passes the
 * context to filters), so concurrent grids on one scene never share state.
 */
#include "raycast.h"

#include <embree3/rtcore.h>
#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

#include "../base/limits.h"
#include "../base/log.h"
#include "../base/mem.h"

struct raycast {
    RTCScene scene;
    const struct mesh *mesh;
    float *normal;     /* 3 per triangle: unit outward normals */
    struct vec3 com;   /* centre of mass (raycast_com) */
    uint32_t *extreme; /* hull vertices (raycast_set_extreme), or NULL: every vertex */
    uint32_t n_extreme;
    struct rims rims; /* open rims, for models of how other slicers treat them */
};

int
raycast_set_extreme(struct raycast *rc, const uint32_t *verts, uint32_t n, struct sf_err *err)
{
    free(rc->extreme);
    rc->extreme = NULL;
    rc->n_extreme = 0;
    if (!verts || !n)
        return SF_OK;
    rc->extreme = mem_array(n, sizeof(uint32_t));
    if (!rc->extreme)
        return sf_err_set(err, SF_ENOMEM, "ray grid: out of memory");
    for (uint32_t k = 0; k < n; k++)
        if (verts[k] >= rc->mesh->n_verts) {
            free(rc->extreme);
            rc->extreme = NULL;
            return sf_err_set(err, SF_EINVAL, "ray grid: extreme vertex %u of %u", verts[k],
                              rc->mesh->n_verts);
        }
    memcpy(rc->extreme, verts, n * sizeof(uint32_t));
    rc->n_extreme = n;
    return SF_OK;
}

/* Solid centre of mass, or the area-weighted surface centroid for a soup. */
static struct vec3
centre_of_mass(const struct mesh *m)
{
    struct vec3 com;
    double vol = mesh_volume(m, &com);
    if (fabs(vol) > 1e-9)
        return com;
    double area = 0;
    com = v3(0, 0, 0);
    for (uint32_t i = 0; i < m->n_tris; i++) {
        double a = mesh_tri_area(m, i);
        com = v3_add(com, v3_scale(mesh_tri_centroid(m, i), a));
        area += a;
    }
    return area > 0 ? v3_scale(com, 1 / area) : com;
}

struct vec3
raycast_com(const struct raycast *rc)
{
    return rc->com;
}

const struct mesh *
raycast_mesh(const struct raycast *rc)
{
    return rc->mesh;
}

const struct rims *
raycast_rims(const struct raycast *rc)
{
    return &rc->rims;
}

static pthread_once_t device_once = PTHREAD_ONCE_INIT;
static RTCDevice device;

static void
embree_error(void *ud, enum RTCError code, const char *str)
{
    (void)ud;
    log_error("embree", "error %d: %s", (int)code, str ? str : "");
}

static void
device_init(void)
{
    device = rtcNewDevice(NULL);
    if (device)
        rtcSetDeviceErrorFunction(device, embree_error, NULL);
}

/* Hits collected for one band of rays. */
struct collector {
    struct ray_hit *hits;
    uint32_t *ray; /* ray (cell within the row) of each hit */
    size_t n, cap;
    bool oom; /* a growth failed: the row is incomplete */
};

struct hit_context {
    struct RTCIntersectContext ctx; /* must be first: Embree hands us this pointer */
    struct collector *col;
};

/* Embree's RTCRayN/RTCHitN accessors are C++-only; these follow its SOA layout
   (rtcore_ray.h: tfar is the 9th float field, id the 11th, primID the 6th). */
static inline float
rayn_tfar(const struct RTCRayN *ray, unsigned n, unsigned i)
{
    return ((const float *)ray)[8 * n + i];
}

static inline unsigned
rayn_id(const struct RTCRayN *ray, unsigned n, unsigned i)
{
    return ((const unsigned *)ray)[10 * n + i];
}

static inline unsigned
hitn_prim(const struct RTCHitN *hit, unsigned n, unsigned i)
{
    return ((const unsigned *)hit)[5 * n + i];
}

static void
collect_filter(const struct RTCFilterFunctionNArguments *args)
{
    struct hit_context *hc = (struct hit_context *)args->context;
    struct collector *c = hc->col;
    for (unsigned i = 0; i < args->N; i++) {
        if (!args->valid[i])
            continue;
        args->valid[i] = 0; /* reject: traversal goes on to the next hit */
        if (c->n == c->cap) {
            size_t cap = c->cap;
            void *h = c->hits, *r = c->ray;
            if (!mem_grow(&h, &cap, c->n + 1, sizeof(*c->hits))) {
                c->oom = true;
                continue;
            }
            c->hits = h;
            cap = c->cap;
            if (!mem_grow(&r, &cap, c->n + 1, sizeof(*c->ray))) {
                c->oom = true;
                continue;
            }
            c->ray = r;
            c->cap = cap;
        }
        /* cos_up is filled in when the row is bucketed: the normal's load missed
           the cache here, inside the traversal (perf: 83 % of this filter) */
        struct ray_hit *h = &c->hits[c->n];
        h->h = rayn_tfar(args->ray, args->N, i);
        h->tri = hitn_prim(args->hit, args->N, i);
        c->ray[c->n] = rayn_id(args->ray, args->N, i);
        c->n++;
    }
}

struct raycast *
raycast_new(const struct mesh *m, struct sf_err *err)
{
    pthread_once(&device_once, device_init);
    if (!device) {
        sf_err_set(err, SF_EIO, "embree: cannot create a device (error %d)",
                   (int)rtcGetDeviceError(NULL));
        return NULL;
    }
    struct raycast *rc = mem_calloc(1, sizeof(*rc));
    if (!rc) {
        sf_err_set(err, SF_ENOMEM, "out of memory");
        return NULL;
    }
    rc->mesh = m;
    rc->com = centre_of_mass(m);
    if (rims_build(m, &rc->rims, err)) {
        free(rc);
        return NULL;
    }
    rc->normal = mem_array((size_t)m->n_tris * 3 + 3, sizeof(float));
    RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    float *vb = geom ? rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                               3 * sizeof(float), m->n_verts + 1)
                     : NULL;
    unsigned *ib = geom ? rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                  3 * sizeof(unsigned), m->n_tris ? m->n_tris : 1)
                        : NULL;
    if (!rc->normal || !vb || !ib) {
        if (geom)
            rtcReleaseGeometry(geom);
        raycast_free(rc);
        sf_err_set(err, SF_ENOMEM, "embree: out of memory for %u triangles", m->n_tris);
        return NULL;
    }
    for (uint32_t i = 0; i < m->n_verts; i++) {
        vb[3 * i] = (float)m->v[i].x;
        vb[3 * i + 1] = (float)m->v[i].y;
        vb[3 * i + 2] = (float)m->v[i].z;
    }
    for (uint32_t i = 0; i < m->n_tris; i++) {
        memcpy(ib + 3 * (size_t)i, m->t[i], 3 * sizeof(unsigned));
        struct vec3 n = mesh_tri_normal(m, i);
        rc->normal[3 * i] = (float)n.x;
        rc->normal[3 * i + 1] = (float)n.y;
        rc->normal[3 * i + 2] = (float)n.z;
    }
    rtcSetGeometryIntersectFilterFunction(geom, collect_filter);
    rtcCommitGeometry(geom);
    rc->scene = rtcNewScene(device);
    if (!rc->scene) {
        rtcReleaseGeometry(geom);
        raycast_free(rc);
        sf_err_set(err, SF_ENOMEM, "embree: cannot create a scene");
        return NULL;
    }
    rtcSetSceneFlags(rc->scene, RTC_SCENE_FLAG_ROBUST);
    /* medium: a high-quality BVH took 1.3 s to build for 1M facets, more than
       all the casts it speeds up */
    rtcSetSceneBuildQuality(rc->scene, RTC_BUILD_QUALITY_MEDIUM);
    rtcAttachGeometry(rc->scene, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(rc->scene);
    return rc;
}

void
raycast_free(struct raycast *rc)
{
    if (!rc)
        return;
    if (rc->scene)
        rtcReleaseScene(rc->scene);
    free(rc->normal);
    free(rc->extreme);
    rims_release(&rc->rims);
    free(rc);
}

void
ray_grid_release(struct ray_grid *g)
{
    free(g->first);
    free(g->hits);
    memset(g, 0, sizeof(*g));
}

/* Any unit vector perpendicular to d; +x for d = +z so grids align with the bed. */
static struct vec3
perpendicular(struct vec3 d)
{
    if (fabs(d.z) > 0.999999 && d.z > 0)
        return v3(1, 0, 0);
    struct vec3 a = fabs(d.x) < 0.9 ? v3(1, 0, 0) : v3(0, 1, 0);
    return v3_normalize(v3_sub(a, v3_scale(d, v3_dot(a, d))));
}

/* Sort one ray's hits by height, equal heights by triangle, so the order
   (and which of two hits through a shared edge the dedupe keeps) does not
   depend on the order Embree reported them in: a handful each, so insertion
   sort (qsort's merge sort with its indirect calls cost more than the
   sorting). */
static void
sort_hits(struct ray_hit *b, size_t n)
{
    for (size_t i = 1; i < n; i++) {
        struct ray_hit x = b[i];
        size_t k = i;
        while (k > 0 && (b[k - 1].h > x.h || (b[k - 1].h == x.h && b[k - 1].tri > x.tri))) {
            b[k] = b[k - 1];
            k--;
        }
        b[k] = x;
    }
}

/* g's frame for up at pitch: the axes, the cells over the part's shadow and
   its extent along up (*dlo, *dhi); SF_EINVAL, SF_ENOMEM over the cap. */
static int
grid_frame(const struct raycast *rc, struct vec3 up, double pitch, struct ray_grid *g,
           double *dlo_out, double *dhi_out, struct sf_err *err)
{
    const struct mesh *m = rc->mesh;
    if (!(pitch > 0) || m->n_verts == 0)
        return sf_err_set(err, SF_EINVAL,
                          "ray grid: pitch must be positive and the mesh non-empty");
    g->up = v3_normalize(up);
    g->u = perpendicular(g->up);
    g->w = v3_cross(g->up, g->u);
    g->pitch = pitch;
    double ulo = INFINITY, uhi = -INFINITY, wlo = INFINITY, whi = -INFINITY;
    double dlo = INFINITY, dhi = -INFINITY;
    /* the extremes along any direction lie on the hull's vertices, if known */
    uint32_t n_ext = rc->extreme ? rc->n_extreme : m->n_verts;
    for (uint32_t k = 0; k < n_ext; k++) {
        struct vec3 v = m->v[rc->extreme ? rc->extreme[k] : k];
        double u = v3_dot(v, g->u), w = v3_dot(v, g->w), d = v3_dot(v, g->up);
        ulo = u < ulo ? u : ulo, uhi = u > uhi ? u : uhi; /* not fmin: a libm call at -O2 */
        wlo = w < wlo ? w : wlo, whi = w > whi ? w : whi;
        dlo = d < dlo ? d : dlo, dhi = d > dhi ? d : dhi;
    }
    double nu = ceil((uhi - ulo) / pitch), nw = ceil((whi - wlo) / pitch);
    if (nu < 1)
        nu = 1;
    if (nw < 1)
        nw = 1;
    if (nu * nw > SF_GRID_CELLS_MAX)
        return sf_err_set(err, SF_ENOMEM,
                          "ray grid of %.0f x %.0f cells at %g mm is over the limit of %u", nu, nw,
                          pitch, SF_GRID_CELLS_MAX);
    g->nu = (uint32_t)nu;
    g->nw = (uint32_t)nw;
    /* centre the grid on the shadow; a tiny irrational offset keeps rays off the
       edges and vertices of parts modelled on round coordinates */
    g->u0 = 0.5 * (ulo + uhi) - 0.5 * (nu - 1) * pitch + 1.23e-4 * pitch * M_SQRT2;
    g->w0 = 0.5 * (wlo + whi) - 0.5 * (nw - 1) * pitch + 1.17e-4 * pitch * M_PI;
    g->base = dlo;
    *dlo_out = dlo;
    *dhi_out = dhi;
    return SF_OK;
}

/* Cast the rows j0 .. j0 + rows of g from height start along up, a 4 x 4
   tile a packet; the hits go to hc's collector. */
static void
cast_band(const struct raycast *rc, const struct ray_grid *g, uint32_t j0, uint32_t rows,
          double start, struct hit_context *hc, struct RTCRayHit16 *pk, int *valid)
{
    enum { TILE = 4 };
    double pitch = g->pitch;
    for (uint32_t i0 = 0; i0 < g->nu; i0 += TILE) {
        for (int q = 0; q < 16; q++) {
            uint32_t r = (uint32_t)q / TILE, i = i0 + (uint32_t)q % TILE;
            valid[q] = r < rows && i < g->nu ? -1 : 0;
            double wc = g->w0 + (j0 + r) * pitch;
            struct vec3 o = v3_add(v3_add(v3_scale(g->u, g->u0 + i * pitch), v3_scale(g->w, wc)),
                                   v3_scale(g->up, start));
            pk->ray.org_x[q] = (float)o.x;
            pk->ray.org_y[q] = (float)o.y;
            pk->ray.org_z[q] = (float)o.z;
            pk->ray.dir_x[q] = (float)g->up.x;
            pk->ray.dir_y[q] = (float)g->up.y;
            pk->ray.dir_z[q] = (float)g->up.z;
            pk->ray.tnear[q] = 0;
            pk->ray.time[q] = 0;
            pk->ray.tfar[q] = INFINITY;
            pk->ray.mask[q] = UINT32_MAX;
            pk->ray.id[q] = r * g->nu + i; /* the cell, counted from the band's first */
            pk->ray.flags[q] = 0;
            pk->hit.geomID[q] = RTC_INVALID_GEOMETRY_ID;
        }
        rtcIntersect16(valid, rc->scene, &hc->ctx, pk);
    }
}

/* Append the band's hits (col, n_rays cells from row j0) to g in grid order:
   bucketed by cell (count: n_rays + 1 counters), sorted, deduped within eps;
   SF_ENOMEM. */
static int
append_band(const struct raycast *rc, struct ray_grid *g, uint32_t j0, size_t n_rays,
            const struct collector *col, float eps, uint32_t *count, size_t *cap_hits,
            struct sf_err *err)
{
    memset(count, 0, sizeof(uint32_t) * (n_rays + 1));
    for (size_t k = 0; k < col->n; k++)
        count[col->ray[k] + 1]++;
    for (size_t i = 0; i < n_rays; i++)
        count[i + 1] += count[i];
    size_t base = g->n_hits;
    void *hp = g->hits;
    if (!mem_grow(&hp, cap_hits, base + col->n + 1, sizeof(struct ray_hit)))
        return sf_err_set(err, SF_ENOMEM, "ray grid: out of memory for hits");
    g->hits = hp;
    struct ray_hit *band = g->hits + base;
    for (size_t k = 0; k < col->n; k++) {
        struct ray_hit h = col->hits[k];
        const float *n = rc->normal + 3 * (size_t)h.tri;
        h.cos_up = (float)(n[0] * g->up.x + n[1] * g->up.y + n[2] * g->up.z);
        band[count[col->ray[k]]++] = h;
    }
    /* count[c] is now the end of bucket c; walk the cells in grid order */
    size_t out_n = base, bstart = 0, cell0 = (size_t)j0 * g->nu;
    for (size_t c = 0; c < n_rays; c++) {
        size_t bend = count[c];
        struct ray_hit *b = band + bstart;
        size_t bn = bend - bstart;
        sort_hits(b, bn);
        for (size_t k = 0; k < bn; k++) {
            struct ray_hit h = b[k];
            h.h = (float)(h.h - 1.0); /* from the ray start to the bed */
            if (out_n > g->first[cell0 + c] && fabsf(g->hits[out_n - 1].h - h.h) < eps &&
                (g->hits[out_n - 1].cos_up < 0) == (h.cos_up < 0))
                continue; /* the same crossing seen through a shared edge */
            g->hits[out_n++] = h;
        }
        g->first[cell0 + c + 1] = (uint32_t)out_n;
        bstart = bend;
    }
    g->n_hits = out_n;
    return SF_OK;
}

int
raycast_grid(struct raycast *rc, struct vec3 up, double pitch, struct ray_grid *g,
             struct sf_err *err)
{
    memset(g, 0, sizeof(*g));
    double dlo = 0, dhi = 0;
    int rc_out = grid_frame(rc, up, pitch, g, &dlo, &dhi, err);
    if (rc_out)
        return rc_out;
    size_t cells = (size_t)g->nu * g->nw;
    g->first = mem_array(cells + 1, sizeof(uint32_t));
    /* Rays go to Embree as packets of 16, each a 4 x 4 tile of the grid:
       a square packet's frustum is tighter than a line's (a row-by-row
       stream: native thread CPU, armadillo, 20 pitch-1 grids 51 -> 39 ms),
       and packets skip Embree's stream-to-packet copy.  BAND rows of tiles
       are collected, bucketed by cell and walked in grid order. */
    enum { BAND = 4 };
    size_t band_rays = (size_t)g->nu * BAND;
    uint32_t *count = mem_array(band_rays + 1, sizeof(uint32_t));
    struct collector col = { 0 };
    size_t cap_hits = 0;
    if (!g->first || !count) {
        rc_out = sf_err_set(err, SF_ENOMEM, "ray grid: out of memory");
        goto out;
    }
    double start = dlo - 1.0; /* rays start 1 mm below the part */
    float eps = (float)(1e-5 * (dhi - dlo + 1));
    struct hit_context hc;
    rtcInitIntersectContext(&hc.ctx);
    hc.ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    hc.col = &col;
    g->first[0] = 0;
    /* Embree reads both with aligned 64-byte loads */
    _Alignas(64) struct RTCRayHit16 pk;
    _Alignas(64) int valid[16];
    for (uint32_t j0 = 0; j0 < g->nw; j0 += BAND) {
        uint32_t rows = g->nw - j0 < BAND ? g->nw - j0 : BAND;
        size_t n_rays = (size_t)rows * g->nu;
        col.n = 0;
        cast_band(rc, g, j0, rows, start, &hc, &pk, valid);
        if (col.oom) {
            rc_out = sf_err_set(err, SF_ENOMEM, "ray grid: out of memory for hits");
            goto out;
        }
        /* bucket the band's hits by cell, then sort and dedupe each bucket */
        if ((rc_out = append_band(rc, g, j0, n_rays, &col, eps, count, &cap_hits, err)))
            goto out;
    }
out:
    free(count);
    free(col.hits);
    free(col.ray);
    if (rc_out)
        ray_grid_release(g);
    return rc_out;
}
