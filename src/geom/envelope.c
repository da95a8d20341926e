/*
 * envelope.c - offset surface by marching tetrahedra on a signed distance
 * lattice (see envelope.h).
 *
 * Design: a lattice of pitch h around the part; at each point the signed
 * distance to the part (unsigned distance from Embree point queries in
 * measure.c, sign from the rays structure: inside if the last surface hit
 * below the point enters the part).  The field f = sd - offset is
 * contoured by marching tetrahedra over the Kuhn split of every cube (six
 * tets around the main diagonal), which tiles space consistently, so the
 * surface is closed and manifold and needs no case table beyond 1, 2 or 3
 * corners inside.  A contour vertex belongs to a lattice edge, so shared
 * vertices are found by indexing (point, edge direction) - no welding.
 * Crossings are clamped to 10..90 % of an edge so no triangle degenerates
 * (TetGen rejects near-coincident input points).  Triangles are oriented
 * from the inside corners to the outside ones.
 *
 * Thread: any; the work is the caller's.
 */
#include "envelope.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"
#include "measure.h"
#include "raycast.h"

struct lattice {
    struct vec3 o;      /* position of point (0,0,0) */
    double h;           /* pitch */
    uint32_t n[3];      /* points along x, y, z */
    float *f;           /* field per point: signed distance - offset */
    int32_t *edge_vert; /* 7 per point: contour vertex on edge (p, p + delta) or -1 */
};

static size_t
lat_index(const struct lattice *l, uint32_t i, uint32_t j, uint32_t k)
{
    return ((size_t)k * l->n[1] + j) * l->n[0] + i;
}

static struct vec3
lat_pos(const struct lattice *l, size_t idx)
{
    uint32_t i = (uint32_t)(idx % l->n[0]), j = (uint32_t)(idx / l->n[0] % l->n[1]);
    uint32_t k = (uint32_t)(idx / ((size_t)l->n[0] * l->n[1]));
    return v3(l->o.x + i * l->h, l->o.y + j * l->h, l->o.z + k * l->h);
}

/*
 * Inside test from the rays structure: the winding count of column (ci, cj)
 * below z (entering hits +1, leaving -1) and the same counted down from
 * above z (leaving +1, entering -1) are both positive.  For a closed part
 * the two are equal (a column's hits sum to zero) and this is the plain
 * winding test, overlapping shells included.  An open shell (a missing
 * top, a hole) leaves a column with an entering hit and no leaving one:
 * counted from below alone everything above it is inside up to the
 * lattice's top, the contour runs off the lattice and is not closed, and
 * TetGen, carving the tets outside a surface that does not enclose them,
 * keeps none ("no tetrahedra").  Counted from both ends, such a column is
 * inside only under hits that do leave the part.
 */
static bool
inside_at(const struct ray_grid *g, long ci, long cj, double z)
{
    if (ci < 0 || cj < 0 || ci >= (long)g->nu || cj >= (long)g->nw)
        return false;
    uint32_t c = ray_grid_cell(g, (uint32_t)ci, (uint32_t)cj);
    double hz = z - g->base;
    int below = 0, above = 0;
    for (uint32_t k = g->first[c]; k < g->first[c + 1]; k++) {
        int s = g->hits[k].cos_up < 0 ? 1 : g->hits[k].cos_up > 0 ? -1 : 0;
        if (g->hits[k].h < hz)
            below += s;
        else
            above -= s;
    }
    return below > 0 && above > 0;
}

static int
fill_field(struct lattice *l, const struct mesh *part, double offset, struct sf_err *err)
{
    struct raycast *rc = raycast_new(part, err);
    if (!rc)
        return err ? err->code : SF_ENOMEM;
    struct ray_grid g;
    int rcode = raycast_grid(rc, v3(0, 0, 1), l->h, &g, err);
    if (rcode) {
        raycast_free(rc);
        return rcode;
    }
    struct surface_dist *sd = surface_dist_new(part, err);
    if (!sd) {
        ray_grid_release(&g);
        raycast_free(rc);
        return err ? err->code : SF_ENOMEM;
    }
    /* align lattice columns with the rays: x_i = u0 + (i - pad) h */
    long pad_x = (long)lrint((g.u0 - l->o.x) / l->h), pad_y = (long)lrint((g.w0 - l->o.y) / l->h);
    l->o.x = g.u0 - pad_x * l->h;
    l->o.y = g.w0 - pad_y * l->h;
    for (uint32_t k = 0; k < l->n[2]; k++)
        for (uint32_t j = 0; j < l->n[1]; j++)
            for (uint32_t i = 0; i < l->n[0]; i++) {
                size_t idx = lat_index(l, i, j, k);
                struct vec3 p = lat_pos(l, idx);
                double d = surface_dist_query(sd, p);
                if (inside_at(&g, (long)i - pad_x, (long)j - pad_y, p.z))
                    d = -d;
                float f = (float)(d - offset);
                /* the lattice's border lies 2 pitches past the offset: outside, always, so
                   the contour closes whatever the inside test says */
                bool border = i == 0 || j == 0 || k == 0 || i + 1 == l->n[0] || j + 1 == l->n[1] ||
                              k + 1 == l->n[2];
                if (border)
                    f = fmaxf(f, 1e-6f);
                l->f[idx] = f != 0 ? f : 1e-6f; /* no corner exactly on the contour */
            }
    surface_dist_free(sd);
    ray_grid_release(&g);
    raycast_free(rc);
    return SF_OK;
}

struct builder {
    struct lattice *l;
    struct vec3 *v;
    uint32_t (*t)[3];
    size_t nv, cap_v, nt, cap_t;
    bool oom;
};

/* Contour vertex on the edge from point a to point a + delta (delta 1..7 as xyz bits). */
static int32_t
edge_vertex(struct builder *b, size_t a, int delta, size_t c)
{
    int32_t *slot = &b->l->edge_vert[a * 7 + (size_t)(delta - 1)];
    if (*slot >= 0)
        return *slot;
    if (!mem_grow((void **)&b->v, &b->cap_v, b->nv + 1, sizeof(*b->v))) {
        b->oom = true;
        return 0;
    }
    double fa = b->l->f[a], fc = b->l->f[c];
    double t = fa / (fa - fc);
    t = fmin(0.9, fmax(0.1, t));
    struct vec3 pa = lat_pos(b->l, a), pc = lat_pos(b->l, c);
    b->v[b->nv] = v3_add(pa, v3_scale(v3_sub(pc, pa), t));
    *slot = (int32_t)b->nv;
    return (int32_t)b->nv++;
}

static void
emit(struct builder *b, int32_t v0, int32_t v1, int32_t v2, struct vec3 out_dir)
{
    if (b->oom || !mem_grow((void **)&b->t, &b->cap_t, b->nt + 1, sizeof(*b->t))) {
        b->oom = true;
        return;
    }
    struct vec3 n = v3_cross(v3_sub(b->v[v1], b->v[v0]), v3_sub(b->v[v2], b->v[v0]));
    if (v3_dot(n, out_dir) < 0) {
        int32_t s = v1;
        v1 = v2;
        v2 = s;
    }
    b->t[b->nt][0] = (uint32_t)v0;
    b->t[b->nt][1] = (uint32_t)v1;
    b->t[b->nt][2] = (uint32_t)v2;
    b->nt++;
}

/* Vertex on the edge between lattice points p and q of one cube (offsets op, oq). */
static int32_t
vert_between(struct builder *b, size_t base, const size_t off[8], int cp, int cq)
{
    if (cp > cq) {
        int s = cp;
        cp = cq;
        cq = s;
    }
    /* Kuhn edges join corners whose offsets nest, so cq = cp + delta bitwise */
    return edge_vertex(b, base + off[cp], cq - cp, base + off[cq]);
}

static void
march_tet(struct builder *b, size_t base, const size_t off[8], const int c[4])
{
    int in[4], out[4], ni = 0, no = 0;
    struct vec3 ci = v3(0, 0, 0), co = v3(0, 0, 0);
    for (int q = 0; q < 4; q++) {
        struct vec3 p = lat_pos(b->l, base + off[c[q]]);
        if (b->l->f[base + off[c[q]]] < 0)
            in[ni++] = c[q], ci = v3_add(ci, p);
        else
            out[no++] = c[q], co = v3_add(co, p);
    }
    if (ni == 0 || no == 0)
        return;
    struct vec3 dir = v3_sub(v3_scale(co, 1.0 / no), v3_scale(ci, 1.0 / ni));
    if (ni == 1 || no == 1) {
        int apex = ni == 1 ? in[0] : out[0];
        const int *others = ni == 1 ? out : in;
        int32_t v[3];
        for (int q = 0; q < 3; q++)
            v[q] = vert_between(b, base, off, apex, others[q]);
        if (!b->oom)
            emit(b, v[0], v[1], v[2], dir);
        return;
    }
    int32_t a = vert_between(b, base, off, in[0], out[0]);
    int32_t d = vert_between(b, base, off, in[0], out[1]);
    int32_t e = vert_between(b, base, off, in[1], out[1]);
    int32_t f = vert_between(b, base, off, in[1], out[0]);
    if (b->oom)
        return;
    emit(b, a, d, e, dir);
    emit(b, a, e, f, dir);
}

int
envelope_build(const struct mesh *part, double h, double offset, struct mesh *out,
               struct sf_err *err)
{
    if (!part->n_tris)
        return sf_err_set(err, SF_EINVAL, "envelope: the part has no triangles");
    if (!(h > 0) || !(offset >= 0) || !isfinite(h) || !isfinite(offset))
        return sf_err_set(err, SF_EINVAL, "envelope: pitch %g and offset %g mm are not valid", h,
                          offset);
    struct vec3 lo, hi;
    mesh_bbox(part, &lo, &hi);
    double pad = offset + 2 * h;
    struct lattice l = { 0 };
    l.h = h;
    l.o = v3_sub(lo, v3(pad, pad, pad));
    double span[3] = { hi.x - lo.x, hi.y - lo.y, hi.z - lo.z };
    double npts = 1;
    for (int a = 0; a < 3; a++) {
        double n = ceil((span[a] + 2 * pad) / h) + 2;
        npts *= n;
        l.n[a] = npts <= ENVELOPE_POINTS_MAX ? (uint32_t)n : 0;
    }
    if (npts > ENVELOPE_POINTS_MAX)
        return sf_err_set(err, SF_ENOMEM, "envelope: a %g mm lattice needs %.0f points (cap %u)", h,
                          npts, ENVELOPE_POINTS_MAX);
    size_t np = (size_t)npts;
    l.f = mem_array(np, sizeof(float));
    l.edge_vert = mem_array(np, 7 * sizeof(int32_t));
    int rc = SF_OK;
    struct builder b = { &l, NULL, NULL, 0, 0, 0, 0, false };
    if (!l.f || !l.edge_vert) {
        rc = sf_err_set(err, SF_ENOMEM, "envelope: out of memory for %zu lattice points", np);
        goto done;
    }
    memset(l.edge_vert, 0xff, np * 7 * sizeof(int32_t));
    rc = fill_field(&l, part, offset, err);
    if (rc)
        goto done;
    size_t off[8];
    for (int c = 0; c < 8; c++)
        off[c] = (size_t)(c & 1) + (size_t)((c >> 1) & 1) * l.n[0] +
                 (size_t)((c >> 2) & 1) * l.n[0] * l.n[1];
    static const int axes[6][2] = { { 1, 2 }, { 1, 4 }, { 2, 1 }, { 2, 4 }, { 4, 1 }, { 4, 2 } };
    for (uint32_t k = 0; k + 1 < l.n[2]; k++)
        for (uint32_t j = 0; j + 1 < l.n[1]; j++)
            for (uint32_t i = 0; i + 1 < l.n[0]; i++) {
                size_t base = lat_index(&l, i, j, k);
                for (int t = 0; t < 6; t++) {
                    int c[4] = { 0, axes[t][0], axes[t][0] + axes[t][1], 7 };
                    march_tet(&b, base, off, c);
                }
            }
    if (b.oom) {
        rc = sf_err_set(err, SF_ENOMEM, "envelope: out of memory for %zu triangles", b.nt);
        goto done;
    }
    if (b.nt == 0) {
        rc = sf_err_set(err, SF_EINVAL, "envelope: no surface at offset %g mm", offset);
        goto done;
    }
    mesh_release(out);
    out->v = b.v;
    out->t = b.t;
    out->n_verts = (uint32_t)b.nv;
    out->n_tris = (uint32_t)b.nt;
    b.v = NULL;
    b.t = NULL;
done:
    free(b.v);
    free(b.t);
    free(l.f);
    free(l.edge_vert);
    return rc;
}
