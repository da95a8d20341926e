/*
 * selfx.c - self-intersection test on Embree (see selfx.h).
 *
 * Two triangles that cross (other than by touching along a shared edge or
 * vertex) have an edge of one passing through the other.  So every edge
 * (a, b) becomes a ray from a of length |b - a|, cast with an occlusion
 * filter that ignores the triangles having a or b as a vertex (they touch
 * the edge by construction) or whose plane holds the edge.  Coplanar
 * overlaps are not seen, which is fine for deformed copies of a valid part.  Embree works in float,
 * so each segment is trimmed by a relative 1e-5 at both ends.
 *
 * Thread: any; each call owns its device and scene.
 */
#include "selfx.h"

#include <embree3/rtcore.h>
#include <math.h>
#include <stdlib.h>

#include "../base/mem.h"

struct edge_ctx {
    struct RTCIntersectContext ctx; /* first: Embree hands the filter this pointer */
    const struct mesh *m;
    uint32_t a, b; /* the edge's vertices */
};

static void
skip_touching(const struct RTCFilterFunctionNArguments *args)
{
    const struct edge_ctx *ec = (const struct edge_ctx *)args->context;
    for (unsigned i = 0; i < args->N; i++) {
        if (!args->valid[i])
            continue;
        unsigned prim = ((const unsigned *)args->hit)[5 * args->N + i];
        const uint32_t *t = ec->m->t[prim];
        for (int k = 0; k < 3; k++)
            if (t[k] == ec->a || t[k] == ec->b)
                args->valid[i] = 0;
        /* An edge in the triangle's plane touches it, it cannot pierce it;
         * Embree's float test reports such grazing hits (a subdivided torus
         * of revolution, whose quads are planar, showed 8 of them). */
        struct vec3 d = v3_sub(ec->m->v[ec->b], ec->m->v[ec->a]);
        struct vec3 n = mesh_tri_cross(ec->m, prim);
        if (fabs(v3_dot(n, d)) <= 1e-6 * v3_len(n) * v3_len(d)) /* float-stored parts */
            args->valid[i] = 0;
    }
}

int
selfx_count(const struct mesh *m, struct sf_err *err)
{
    if (!m->n_tris)
        return 0;
    RTCDevice dev = rtcNewDevice("threads=1");
    RTCScene s = dev ? rtcNewScene(dev) : NULL;
    RTCGeometry g = dev ? rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE) : NULL;
    float *vb = g ? rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                            3 * sizeof(float), m->n_verts + 1)
                  : NULL;
    unsigned *ib = g ? rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                               3 * sizeof(unsigned), m->n_tris)
                     : NULL;
    int count = 0;
    if (!s || !vb || !ib) {
        count = sf_err_set(err, SF_ENOMEM, "selfx: cannot build an Embree scene");
        goto done;
    }
    for (uint32_t i = 0; i < m->n_verts; i++) {
        vb[3 * i] = (float)m->v[i].x;
        vb[3 * i + 1] = (float)m->v[i].y;
        vb[3 * i + 2] = (float)m->v[i].z;
    }
    for (uint32_t i = 0; i < m->n_tris; i++)
        for (int k = 0; k < 3; k++)
            ib[3 * i + (uint32_t)k] = m->t[i][k];
    rtcSetGeometryOccludedFilterFunction(g, skip_touching);
    rtcCommitGeometry(g);
    rtcAttachGeometry(s, g);
    rtcSetSceneFlags(s, RTC_SCENE_FLAG_ROBUST);
    rtcCommitScene(s);
    struct edge_ctx ec;
    rtcInitIntersectContext(&ec.ctx);
    ec.m = m;
    for (uint32_t i = 0; i < m->n_tris; i++) {
        for (int k = 0; k < 3; k++) {
            uint32_t a = m->t[i][k], b = m->t[i][(k + 1) % 3];
            if (a > b)
                continue; /* each edge once (closed meshes list it both ways) */
            struct vec3 pa = m->v[a], d = v3_sub(m->v[b], pa);
            double len = v3_len(d);
            if (!(len > 0))
                continue;
            ec.a = a;
            ec.b = b;
            struct RTCRay ray = { 0 };
            ray.org_x = (float)pa.x;
            ray.org_y = (float)pa.y;
            ray.org_z = (float)pa.z;
            ray.dir_x = (float)(d.x / len);
            ray.dir_y = (float)(d.y / len);
            ray.dir_z = (float)(d.z / len);
            ray.tnear = (float)(1e-5 * len);
            ray.tfar = (float)(len * (1 - 1e-5));
            ray.mask = 0xffffffffu;
            rtcOccluded1(s, &ec.ctx, &ray);
            count += ray.tfar < 0; /* Embree marks an occluded ray with tfar = -inf */
        }
    }
done:
    if (g)
        rtcReleaseGeometry(g);
    if (s)
        rtcReleaseScene(s);
    if (dev)
        rtcReleaseDevice(dev);
    return count;
}
