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
 * Thread: any; selfx_count owns its device and scene, a selfx_ref holds
 * one of the reference's triangles with no corner near its crossings (the
 * only ones a new crossing can have) and recommits it with each mesh it
 * counts, casting only the edges with no end near.  Embree 3.13.5 rebuilds
 * the BVH of robust triangles (BVH8<triangle4v>, two-level builder) at
 * every commit: RTC_BUILD_QUALITY_REFIT is not honoured (callgrind: the
 * same instructions with and without it, 50 M a commit for cow's 23 k
 * triangles, beside 40 M for the edges' casts).
 */
#include "selfx.h"

#include <embree3/rtcore.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"

struct edge_ctx {
    struct RTCIntersectContext ctx; /* first: Embree hands the filter this pointer */
    const struct mesh *m;
    uint32_t a, b; /* the edge's vertices */
    /* optional: a pierced triangle is judged here (true: a crossing); the
       search goes on along the edge past every hit, so the judge sees each
       triangle the edge pierces, whatever order the BVH finds them in */
    bool (*judge)(void *ud, uint32_t a, uint32_t b, uint32_t tri);
    void *ud;
    bool crossed;         /* the judge said yes on this edge */
    const uint32_t *prim; /* optional: the scene's triangle i is the mesh's prim[i] */
    const uint8_t *skip;  /* optional: per vertex, cast no edge from or to it */
};

static void
skip_touching(const struct RTCFilterFunctionNArguments *args)
{
    struct edge_ctx *ec = (struct edge_ctx *)args->context;
    for (unsigned i = 0; i < args->N; i++) {
        if (!args->valid[i])
            continue;
        unsigned prim = ((const unsigned *)args->hit)[5 * args->N + i];
        if (ec->prim)
            prim = ec->prim[prim];
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
        if (args->valid[i] && ec->judge) {
            ec->crossed |= ec->judge(ec->ud, ec->a, ec->b, prim);
            args->valid[i] = 0; /* judged: the search goes on along the edge */
        }
    }
}

/* An Embree scene of one mesh's triangles, kept to be refitted when the
   vertices move (the same connectivity: a deformation's iterates). */
struct scene {
    RTCDevice dev;
    RTCScene s;
    RTCGeometry g;
    float *vb;
    uint32_t n_verts;
};

static void
scene_release(struct scene *sc)
{
    if (sc->g)
        rtcReleaseGeometry(sc->g);
    if (sc->s)
        rtcReleaseScene(sc->s);
    if (sc->dev)
        rtcReleaseDevice(sc->dev);
    memset(sc, 0, sizeof(*sc));
}

static void
scene_load(struct scene *sc, const struct mesh *m)
{
    for (uint32_t i = 0; i < m->n_verts; i++) {
        sc->vb[3 * i] = (float)m->v[i].x;
        sc->vb[3 * i + 1] = (float)m->v[i].y;
        sc->vb[3 * i + 2] = (float)m->v[i].z;
    }
}

/* Build the scene of m's triangles (with prim, only its n_prim: the
   scene's triangle i is m's prim[i]); refit says it will be refitted
   (RTC_BUILD_QUALITY_REFIT). */
static int
scene_init_some(struct scene *sc, const struct mesh *m, const uint32_t *prim, uint32_t n_prim,
                bool refit, struct sf_err *err)
{
    memset(sc, 0, sizeof(*sc));
    sc->dev = rtcNewDevice("threads=1");
    sc->s = sc->dev ? rtcNewScene(sc->dev) : NULL;
    sc->g = sc->dev ? rtcNewGeometry(sc->dev, RTC_GEOMETRY_TYPE_TRIANGLE) : NULL;
    sc->vb = sc->g ? rtcSetNewGeometryBuffer(sc->g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                             3 * sizeof(float), m->n_verts + 1)
                   : NULL;
    unsigned *ib = sc->g
                       ? rtcSetNewGeometryBuffer(sc->g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                 3 * sizeof(unsigned), prim ? n_prim : m->n_tris)
                       : NULL;
    if (!sc->s || !sc->vb || !ib) {
        scene_release(sc);
        return sf_err_set(err, SF_ENOMEM, "selfx: cannot build an Embree scene");
    }
    sc->n_verts = m->n_verts;
    scene_load(sc, m);
    for (uint32_t i = 0; i < (prim ? n_prim : m->n_tris); i++)
        for (int k = 0; k < 3; k++)
            ib[3 * i + (uint32_t)k] = m->t[prim ? prim[i] : i][k];
    rtcSetGeometryOccludedFilterFunction(sc->g, skip_touching);
    if (refit) { /* Embree heeds a geometry's REFIT only in a LOW quality scene */
        rtcSetSceneBuildQuality(sc->s, RTC_BUILD_QUALITY_LOW);
        rtcSetGeometryBuildQuality(sc->g, RTC_BUILD_QUALITY_REFIT);
    }
    rtcCommitGeometry(sc->g);
    rtcAttachGeometry(sc->s, sc->g);
    rtcSetSceneFlags(sc->s, RTC_SCENE_FLAG_ROBUST);
    rtcCommitScene(sc->s);
    return SF_OK;
}

static int
scene_init(struct scene *sc, const struct mesh *m, bool refit, struct sf_err *err)
{
    return scene_init_some(sc, m, NULL, 0, refit, err);
}

/* Move the scene's vertices to m's (same connectivity) and refit its BVH. */
static void
scene_refit(struct scene *sc, const struct mesh *m)
{
    scene_load(sc, m);
    rtcUpdateGeometryBuffer(sc->g, RTC_BUFFER_TYPE_VERTEX, 0);
    rtcCommitGeometry(sc->g);
    rtcCommitScene(sc->s);
}

/* Cast every edge of ec->m (whose positions sc holds; but those with an
   end ec->skip names) once: the count of edges that pierce a triangle not
   touching them (with a judge: that the judge calls a crossing). */
static int
cast_some(const struct scene *sc, const struct edge_ctx *ec0)
{
    struct edge_ctx ec = *ec0;
    const struct mesh *m = ec.m;
    rtcInitIntersectContext(&ec.ctx);
    int count = 0;
    for (uint32_t i = 0; i < m->n_tris; i++) {
        for (int k = 0; k < 3; k++) {
            uint32_t a = m->t[i][k], b = m->t[i][(k + 1) % 3];
            if (a > b)
                continue; /* each edge once (closed meshes list it both ways) */
            if (ec.skip && (ec.skip[a] || ec.skip[b]))
                continue;
            struct vec3 pa = m->v[a], d = v3_sub(m->v[b], pa);
            double len = v3_len(d);
            if (!(len > 0))
                continue;
            ec.a = a;
            ec.b = b;
            ec.crossed = false;
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
            rtcOccluded1(sc->s, &ec.ctx, &ray);
            /* Embree marks an occluded ray with tfar = -inf */
            count += ec.judge ? ec.crossed : ray.tfar < 0;
        }
    }
    return count;
}

/* Cast every edge of m through sc, which holds all of m's triangles. */
static int
cast_edges(const struct scene *sc, const struct mesh *m,
           bool (*judge)(void *, uint32_t, uint32_t, uint32_t), void *ud)
{
    struct edge_ctx ec = { .m = m, .judge = judge, .ud = ud };
    return cast_some(sc, &ec);
}

static int
edges_pierced(const struct mesh *m, bool (*judge)(void *, uint32_t, uint32_t, uint32_t), void *ud,
              struct sf_err *err)
{
    if (!m->n_tris)
        return 0;
    struct scene sc;
    int rc = scene_init(&sc, m, false, err);
    if (rc < 0)
        return rc;
    int count = cast_edges(&sc, m, judge, ud);
    scene_release(&sc);
    return count;
}

int
selfx_count(const struct mesh *m, struct sf_err *err)
{
    return edges_pierced(m, NULL, NULL, err);
}

/* ---- distances, for what was already touching in the reference ---- */

/* Distance between segments p0p1 and q0q1 (Ericson 5.1.9). */
static double
seg_seg(struct vec3 p0, struct vec3 p1, struct vec3 q0, struct vec3 q1)
{
    struct vec3 d1 = v3_sub(p1, p0), d2 = v3_sub(q1, q0), r = v3_sub(p0, q0);
    double a = v3_dot(d1, d1), e = v3_dot(d2, d2), f = v3_dot(d2, r);
    double s = 0, t = 0;
    if (a <= 1e-300 && e <= 1e-300)
        return v3_len(r);
    if (a <= 1e-300) {
        t = fmin(fmax(f / e, 0), 1);
    } else {
        double c = v3_dot(d1, r);
        if (e <= 1e-300) {
            s = fmin(fmax(-c / a, 0), 1);
        } else {
            double b = v3_dot(d1, d2), den = a * e - b * b;
            s = den > 0 ? fmin(fmax((b * f - c * e) / den, 0), 1) : 0;
            t = (b * s + f) / e;
            if (t < 0)
                t = 0, s = fmin(fmax(-c / a, 0), 1);
            else if (t > 1)
                t = 1, s = fmin(fmax((b - c) / a, 0), 1);
        }
    }
    return v3_len(v3_sub(v3_add(p0, v3_scale(d1, s)), v3_add(q0, v3_scale(d2, t))));
}

/* Distance from segment pq to triangle abc (0 when it crosses it). */
static double
seg_tri(struct vec3 p, struct vec3 q, struct vec3 a, struct vec3 b, struct vec3 c)
{
    struct vec3 n = v3_cross(v3_sub(b, a), v3_sub(c, a));
    double sp = v3_dot(n, v3_sub(p, a)), sq = v3_dot(n, v3_sub(q, a));
    if ((sp <= 0 && sq >= 0) || (sp >= 0 && sq <= 0)) {
        double den = sp - sq;
        struct vec3 x = den != 0 ? v3_add(p, v3_scale(v3_sub(q, p), sp / den)) : p;
        if (v3_len(v3_sub(v3_closest_on_tri(x, a, b, c), x)) <= 1e-12 * (1 + v3_len(x)))
            return 0;
    }
    double d = fmin(v3_len(v3_sub(v3_closest_on_tri(p, a, b, c), p)),
                    v3_len(v3_sub(v3_closest_on_tri(q, a, b, c), q)));
    d = fmin(d, seg_seg(p, q, a, b));
    d = fmin(d, seg_seg(p, q, b, c));
    return fmin(d, seg_seg(p, q, c, a));
}

struct selfx_ref {
    const struct mesh *ref;
    double tol;
    uint32_t *comp;       /* per vertex: its connected shell (a representative vertex) */
    uint8_t *near;        /* per vertex: within two rings of a crossing the input has */
    uint32_t (*pairs)[2]; /* shells that cross each other in the input */
    size_t n_pairs, cap_pairs;
    int n_input; /* edges of ref crossing it (selfx_count) */
    bool oom;
    /* the triangles with no corner near: a crossing needs one of them, and
       an edge with no end near (apart_in_ref); refitted to each mesh
       counted (none: sc is empty, nothing can be new) */
    struct scene sc;
    uint32_t *prim; /* the scene's triangle i is ref's prim[i] */
    uint32_t n_prim;
};

/* One check of a deformed mesh against a prepared reference. */
struct new_ctx {
    const struct selfx_ref *sr;
    uint8_t *mark; /* optional: vertices of new crossings are set to 1 */
};

static uint32_t
find(uint32_t *up, uint32_t v)
{
    while (up[v] != v)
        v = up[v] = up[up[v]];
    return v;
}

/* The input's crossings: mark the vertices and the pair of shells. */
static bool
note_input(void *ud, uint32_t a, uint32_t b, uint32_t tri)
{
    struct selfx_ref *nc = ud;
    const uint32_t *t = nc->ref->t[tri];
    nc->near[a] = nc->near[b] = 1;
    for (int k = 0; k < 3; k++)
        nc->near[t[k]] = 1;
    uint32_t ca = nc->comp[a], ct = nc->comp[t[0]];
    if (ca != ct) {
        uint32_t lo = ca < ct ? ca : ct, hi = ca < ct ? ct : ca;
        for (size_t i = 0; i < nc->n_pairs; i++)
            if (nc->pairs[i][0] == lo && nc->pairs[i][1] == hi)
                return true;
        if (nc->n_pairs == nc->cap_pairs) {
            size_t cap = nc->cap_pairs ? 2 * nc->cap_pairs : 16;
            void *np = realloc(nc->pairs, cap * sizeof(*nc->pairs));
            if (!np) {
                nc->oom = true;
                return true;
            }
            nc->pairs = np;
            nc->cap_pairs = cap;
        }
        nc->pairs[nc->n_pairs][0] = lo;
        nc->pairs[nc->n_pairs++][1] = hi;
    }
    return true;
}

/* Is this crossing new: not between shells that crossed in the input, not in
   the neighbourhood of a crossing the input had, and apart there?  A new one
   marks its edge's and triangle's vertices when the caller asked. */
static bool
apart_in_ref(void *ud, uint32_t a, uint32_t b, uint32_t tri)
{
    const struct new_ctx *ctx = ud;
    const struct selfx_ref *nc = ctx->sr;
    const struct mesh *r = nc->ref;
    const uint32_t *t = r->t[tri];
    if (nc->near[a] || nc->near[b] || nc->near[t[0]] || nc->near[t[1]] || nc->near[t[2]])
        return false;
    uint32_t ca = nc->comp[a], ct = nc->comp[t[0]];
    if (ca != ct) {
        uint32_t lo = ca < ct ? ca : ct, hi = ca < ct ? ct : ca;
        for (size_t i = 0; i < nc->n_pairs; i++)
            if (nc->pairs[i][0] == lo && nc->pairs[i][1] == hi)
                return false;
    }
    if (!(seg_tri(r->v[a], r->v[b], r->v[t[0]], r->v[t[1]], r->v[t[2]]) > nc->tol))
        return false;
    if (ctx->mark)
        ctx->mark[a] = ctx->mark[b] = ctx->mark[t[0]] = ctx->mark[t[1]] = ctx->mark[t[2]] = 1;
    return true;
}

void
selfx_ref_free(struct selfx_ref *sr)
{
    if (!sr)
        return;
    scene_release(&sr->sc);
    free(sr->prim);
    free(sr->comp);
    free(sr->near);
    free(sr->pairs);
    free(sr);
}

struct selfx_ref *
selfx_ref_new(const struct mesh *ref, double tol, struct sf_err *err)
{
    if (!(tol >= 0)) {
        sf_err_set(err, SF_EINVAL, "selfx: tolerance %g: want >= 0", tol);
        return NULL;
    }
    struct selfx_ref *nc = mem_calloc(1, sizeof(*nc));
    uint8_t *grow = mem_calloc(ref->n_verts ? ref->n_verts : 1, 1);
    if (nc) {
        nc->ref = ref;
        nc->tol = tol;
        nc->comp = mem_array(ref->n_verts ? ref->n_verts : 1, sizeof(uint32_t));
        nc->near = mem_calloc(ref->n_verts ? ref->n_verts : 1, 1);
    }
    if (!nc || !nc->comp || !nc->near || !grow) {
        sf_err_set(err, SF_ENOMEM, "selfx: out of memory for %u vertices", ref->n_verts);
        goto fail;
    }
    for (uint32_t v = 0; v < ref->n_verts; v++)
        nc->comp[v] = v;
    for (uint32_t f = 0; f < ref->n_tris; f++)
        for (int k = 1; k < 3; k++) {
            uint32_t x = find(nc->comp, ref->t[f][0]), y = find(nc->comp, ref->t[f][k]);
            if (x != y)
                nc->comp[x > y ? x : y] = x < y ? x : y;
        }
    for (uint32_t v = 0; v < ref->n_verts; v++)
        nc->comp[v] = find(nc->comp, v);
    if (ref->n_tris && scene_init(&nc->sc, ref, true, err) < 0)
        goto fail;
    nc->n_input = ref->n_tris ? cast_edges(&nc->sc, ref, note_input, nc) : 0;
    if (nc->oom) {
        sf_err_set(err, SF_ENOMEM, "selfx: out of memory for the crossing shells");
        goto fail;
    }
    /* two rings around the input's crossings: a deformation slides the
       crossing curve over the triangles next to it */
    for (int ring = 0; ring < 2; ring++) {
        for (uint32_t f = 0; f < ref->n_tris; f++) {
            const uint32_t *t = ref->t[f];
            if (nc->near[t[0]] || nc->near[t[1]] || nc->near[t[2]])
                grow[t[0]] = grow[t[1]] = grow[t[2]] = 1;
        }
        for (uint32_t v = 0; v < ref->n_verts; v++)
            nc->near[v] |= grow[v];
    }
    free(grow);
    grow = NULL;
    /* the counts' scene: only the triangles that can cross anew */
    scene_release(&nc->sc);
    if (!(nc->prim = mem_array(ref->n_tris ? ref->n_tris : 1, sizeof(uint32_t)))) {
        sf_err_set(err, SF_ENOMEM, "selfx: out of memory for %u triangles", ref->n_tris);
        goto fail;
    }
    for (uint32_t f = 0; f < ref->n_tris; f++) {
        const uint32_t *t = ref->t[f];
        if (!nc->near[t[0]] && !nc->near[t[1]] && !nc->near[t[2]])
            nc->prim[nc->n_prim++] = f;
    }
    if (nc->n_prim && scene_init_some(&nc->sc, ref, nc->prim, nc->n_prim, true, err) < 0)
        goto fail;
    return nc;
fail:
    free(grow);
    selfx_ref_free(nc);
    return NULL;
}

int
selfx_ref_input_count(const struct selfx_ref *sr)
{
    return sr->n_input;
}

int
selfx_ref_rebind(struct selfx_ref *sr, const struct mesh *ref, struct sf_err *err)
{
    if (ref->n_verts != sr->ref->n_verts || ref->n_tris != sr->ref->n_tris)
        return sf_err_set(err, SF_EINVAL,
                          "selfx: the reference has %u/%u vertices/triangles, the new one %u/%u",
                          sr->ref->n_verts, sr->ref->n_tris, ref->n_verts, ref->n_tris);
    sr->ref = ref;
    return SF_OK;
}

int
selfx_ref_count(struct selfx_ref *sr, const struct mesh *m, uint8_t *mark, struct sf_err *err)
{
    const struct mesh *ref = sr->ref;
    if (ref->n_verts != m->n_verts || ref->n_tris != m->n_tris)
        return sf_err_set(err, SF_EINVAL,
                          "selfx: the reference has %u/%u vertices/triangles, the mesh %u/%u",
                          ref->n_verts, ref->n_tris, m->n_verts, m->n_tris);
    if (mark)
        memset(mark, 0, m->n_verts);
    if (!m->n_tris)
        return 0;
    if (!sr->n_prim)
        return 0;
    struct new_ctx ctx = { .sr = sr, .mark = mark };
    scene_refit(&sr->sc, m);
    struct edge_ctx ec = {
        .m = m, .judge = apart_in_ref, .ud = &ctx, .prim = sr->prim, .skip = sr->near
    };
    return cast_some(&sr->sc, &ec);
}

int
selfx_ref_count_all(struct selfx_ref *sr, const struct mesh *m, uint8_t *mark, struct sf_err *err)
{
    const struct mesh *ref = sr->ref;
    if (ref->n_verts != m->n_verts || ref->n_tris != m->n_tris)
        return sf_err_set(err, SF_EINVAL,
                          "selfx: the reference has %u/%u vertices/triangles, the mesh %u/%u",
                          ref->n_verts, ref->n_tris, m->n_verts, m->n_tris);
    if (mark)
        memset(mark, 0, m->n_verts);
    if (!m->n_tris)
        return 0;
    struct new_ctx ctx = { .sr = sr, .mark = mark };
    struct scene sc;
    int rc = scene_init(&sc, m, true, err);
    if (rc < 0)
        return rc;
    rc = cast_edges(&sc, m, apart_in_ref, &ctx);
    scene_release(&sc);
    return rc;
}

int
selfx_count_new(const struct mesh *ref, const struct mesh *m, double tol, struct sf_err *err)
{
    if (ref->n_verts != m->n_verts || ref->n_tris != m->n_tris)
        return sf_err_set(err, SF_EINVAL,
                          "selfx: the reference has %u/%u vertices/triangles, the mesh %u/%u",
                          ref->n_verts, ref->n_tris, m->n_verts, m->n_tris);
    struct selfx_ref *sr = selfx_ref_new(ref, tol, err);
    if (!sr)
        return err->code;
    int rc = selfx_ref_count(sr, m, NULL, err);
    selfx_ref_free(sr);
    return rc;
}
