/*
 * measure_dist.c - the distance metrics of measure.h: Hausdorff distance
 * and surface-distance queries, on Embree point queries with an exact
 * closest point on triangle (Ericson, Real-Time Collision Detection,
 * 5.1.5).
 *
 * Apart from measure.c so that programs which only score support
 * (slimfarm-orient) do not link Embree: loading libembree3 and libtbb cost
 * ~8 ms of every start.
 *
 * Pure functions; thread-safe on distinct outputs.
 */
#include "measure.h"

#include <embree3/rtcore.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"

/* ---- Hausdorff ----------------------------------------------------------- */

/* Closest point to p on triangle abc (Ericson 5.1.5). */
static struct vec3
closest_on_tri(struct vec3 p, struct vec3 a, struct vec3 b, struct vec3 c)
{
    struct vec3 ab = v3_sub(b, a), ac = v3_sub(c, a), ap = v3_sub(p, a);
    double d1 = v3_dot(ab, ap), d2 = v3_dot(ac, ap);
    if (d1 <= 0 && d2 <= 0)
        return a;
    struct vec3 bp = v3_sub(p, b);
    double d3 = v3_dot(ab, bp), d4 = v3_dot(ac, bp);
    if (d3 >= 0 && d4 <= d3)
        return b;
    double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0)
        return v3_add(a, v3_scale(ab, d1 / (d1 - d3)));
    struct vec3 cp = v3_sub(p, c);
    double d5 = v3_dot(ab, cp), d6 = v3_dot(ac, cp);
    if (d6 >= 0 && d5 <= d6)
        return c;
    double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0)
        return v3_add(a, v3_scale(ac, d2 / (d2 - d6)));
    double va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
        return v3_add(b, v3_scale(v3_sub(c, b), (d4 - d3) / ((d4 - d3) + (d5 - d6))));
    double denom = 1 / (va + vb + vc);
    return v3_add(a, v3_add(v3_scale(ab, vb * denom), v3_scale(ac, vc * denom)));
}

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
    struct vec3 q = closest_on_tri(c->p, c->m->v[t[0]], c->m->v[t[1]], c->m->v[t[2]]);
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
