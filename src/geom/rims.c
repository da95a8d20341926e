/*
 * rims.c - open rims and what an outside slicer keeps of an open layer
 * (see rims.h).
 */
#include "rims.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"
#include "../base/uf.h"

void
rims_release(struct rims *r)
{
    free(r->edge);
    free(r->edge_tri);
    free(r->adj);
    memset(r, 0, sizeof(*r));
}

/* A half-edge without a partner triangle: its undirected key and triangle. */
struct loose {
    uint32_t lo, hi, tri;
};

static int
loose_cmp(const void *a, const void *b)
{
    const struct loose *x = a, *y = b;
    if (x->lo != y->lo)
        return x->lo < y->lo ? -1 : 1;
    return (x->hi > y->hi) - (x->hi < y->hi);
}

int
rims_build(const struct mesh *m, struct rims *r, struct sf_err *err)
{
    memset(r, 0, sizeof(*r));
    struct mesh_topo topo;
    int rc = mesh_topo_build(m, &topo, err);
    if (rc)
        return rc;
    /* adj has no partner on boundary and non-manifold edges alike: a boundary
       edge is the one whose undirected key occurs once among those */
    size_t n = 0;
    for (uint32_t i = 0; i < m->n_tris; i++)
        for (int k = 0; k < 3; k++)
            n += topo.adj[i][k] == MESH_NO_TRI;
    struct loose *lz = n ? mem_array(n, sizeof(*lz)) : NULL;
    if (n && !lz) {
        mesh_topo_release(&topo);
        return sf_err_set(err, SF_ENOMEM, "open rims: out of memory");
    }
    n = 0;
    for (uint32_t i = 0; i < m->n_tris; i++)
        for (int k = 0; k < 3; k++)
            if (topo.adj[i][k] == MESH_NO_TRI) {
                uint32_t a = m->t[i][k], b = m->t[i][(k + 1) % 3];
                lz[n++] = (struct loose){ a < b ? a : b, a < b ? b : a, i };
            }
    if (n)
        qsort(lz, n, sizeof(*lz), loose_cmp);
    size_t n_rim = 0;
    for (size_t s = 0, e; s < n; s = e) {
        for (e = s + 1; e < n && lz[e].lo == lz[s].lo && lz[e].hi == lz[s].hi;)
            e++;
        if (e - s == 1 && lz[s].lo != lz[s].hi)
            lz[n_rim++] = lz[s];
    }
    if (n_rim) {
        r->edge = mem_array(n_rim, sizeof(*r->edge));
        r->edge_tri = mem_array(n_rim, sizeof(uint32_t));
        if (!r->edge || !r->edge_tri) {
            free(lz);
            mesh_topo_release(&topo);
            rims_release(r);
            return sf_err_set(err, SF_ENOMEM, "open rims: out of memory");
        }
        for (size_t k = 0; k < n_rim; k++) {
            r->edge[k][0] = lz[k].lo;
            r->edge[k][1] = lz[k].hi;
            r->edge_tri[k] = lz[k].tri;
        }
        r->adj = topo.adj; /* kept: a layer's loops follow it */
        topo.adj = NULL;
    }
    r->n_edges = (uint32_t)n_rim;
    free(lz);
    mesh_topo_release(&topo);
    return SF_OK;
}

void
open_sections_release(struct open_sections *s)
{
    free(s->k);
    free(s->first);
    free(s->span);
    free(s->empty_to);
    memset(s, 0, sizeof(*s));
}

bool
open_sections_keeps(const struct open_sections *s, uint32_t l, uint32_t i, uint32_t j)
{
    size_t row = (size_t)l * s->nw + j;
    for (uint32_t q = s->first[row]; q < s->first[row + 1]; q++) {
        if (i < s->span[q].i0)
            return false;
        if (i <= s->span[q].i1)
            return true;
    }
    return false;
}

/* Where layer plane k cuts a rim edge (plane coordinates), its triangle, and
   the crossing the slicer joins it to (its index in the layer), or none:
   alone, the loop stays open. */
struct crossing {
    int32_t k;
    uint32_t tri;
    double x, y;
    bool alone;
    uint32_t mate;
};

#define JOIN_WINDOW 16

/* A candidate join of two crossings of a layer, d apart. */
struct join {
    double d;
    uint32_t a, b;
};

static int
join_cmp(const void *p, const void *q)
{
    const struct join *x = p, *y = q;
    if (x->d != y->d)
        return x->d < y->d ? -1 : 1;
    if (x->a != y->a)
        return x->a < y->a ? -1 : 1;
    return (x->b > y->b) - (x->b < y->b);
}

static int
crossing_cmp(const void *a, const void *b)
{
    const struct crossing *p = a, *q = b;
    if (p->k != q->k)
        return p->k < q->k ? -1 : 1;
    return (p->x > q->x) - (p->x < q->x);
}

/* A vertex on a layer plane counts as above it (a symbolic nudge up), so a
   plane through vertices still cuts every loop in whole segments: does plane
   z cut the edge between heights a and b? */
static bool
cuts(double a, double b, double z)
{
    return (a >= z) != (b >= z);
}

/* The planes (k + 0.5) h that cut heights lo < hi: lo < z <= hi, k0..k1
   (empty when k1 < k0). */
static void
planes_between(double lo, double hi, double h, int32_t *k0, int32_t *k1)
{
    /* the division's guess, settled by the products cuts() compares */
    *k0 = (int32_t)floor(lo / h - 0.5) + 1;
    *k1 = (int32_t)floor(hi / h - 0.5);
    while ((*k0 - 0.5) * h > lo)
        --*k0;
    while ((*k0 + 0.5) * h <= lo)
        ++*k0;
    while ((*k1 + 1.5) * h <= hi)
        ++*k1;
    while ((*k1 + 0.5) * h > hi)
        --*k1;
    if (*k0 < 0)
        *k0 = 0;
}

/* The rim crossings, sorted by layer and x: *out (n), *n_alone of them alone. */
static int
rim_crossings(const struct rims *r, const struct mesh *m, const struct rim_frame *f,
              const double *hv, double gap, struct crossing **out, size_t *n_out, size_t *n_alone)
{
    size_t n = 0, cap = 0;
    struct crossing *c = NULL;
    for (uint32_t e = 0; e < r->n_edges; e++) {
        uint32_t a = r->edge[e][0], b = r->edge[e][1];
        if (hv[a] > hv[b]) {
            uint32_t t = a;
            a = b;
            b = t;
        }
        int32_t k0, k1;
        planes_between(hv[a], hv[b], f->layer_mm, &k0, &k1);
        for (int32_t k = k0; k <= k1; k++) {
            double t = ((k + 0.5) * f->layer_mm - hv[a]) / (hv[b] - hv[a]);
            struct vec3 p = v3_add(m->v[a], v3_scale(v3_sub(m->v[b], m->v[a]), t));
            void *o = c;
            if (!mem_grow(&o, &cap, n + 1, sizeof(*c))) {
                free(c);
                return SF_ENOMEM;
            }
            c = o;
            c[n++] = (struct crossing){ k,     r->edge_tri[e], v3_dot(p, f->u), v3_dot(p, f->w),
                                        false, UINT32_MAX };
        }
    }
    if (n)
        qsort(c, n, sizeof(*c), crossing_cmp);
    /* each layer's ends joined one to one, closest first, as the slicer
       closes gaps: a third end near a joined pair stays open (mech-holes-shark
       turned to direction 39: PrusaSlicer printed none of the layers where
       three ends lie within 2 mm) */
    struct join *jn = NULL;
    size_t cap_jn = 0;
    *n_alone = 0;
    for (size_t s = 0, e; s < n; s = e) {
        for (e = s + 1; e < n && c[e].k == c[s].k;)
            e++;
        size_t nj = 0;
        for (size_t i = s; i < e; i++) {
            c[i].mate = UINT32_MAX;
            /* the next JOIN_WINDOW crossings along x at most: a soup of open
               triangles has thousands of ends within the gap of each other */
            for (size_t j = i + 1; j < e && j <= i + JOIN_WINDOW && c[j].x - c[i].x <= gap; j++) {
                double d = hypot(c[j].x - c[i].x, c[j].y - c[i].y);
                if (d > gap)
                    continue;
                void *o = jn;
                if (!mem_grow(&o, &cap_jn, nj + 1, sizeof(*jn))) {
                    free(jn);
                    free(c);
                    return SF_ENOMEM;
                }
                jn = o;
                jn[nj++] = (struct join){ d, (uint32_t)(i - s), (uint32_t)(j - s) };
            }
        }
        if (nj)
            qsort(jn, nj, sizeof(*jn), join_cmp);
        for (size_t q = 0; q < nj; q++)
            if (c[s + jn[q].a].mate == UINT32_MAX && c[s + jn[q].b].mate == UINT32_MAX) {
                c[s + jn[q].a].mate = jn[q].b;
                c[s + jn[q].b].mate = jn[q].a;
            }
        for (size_t i = s; i < e; i++) {
            c[i].alone = c[i].mate == UINT32_MAX;
            *n_alone += c[i].alone;
        }
    }
    free(jn);
    *out = c;
    *n_out = n;
    return SF_OK;
}

/* Where a kept loop crosses row j: at u, winding +1 (entering) or -1. */
struct rowx {
    uint32_t j;
    int wind;
    double u;
};

static int
rowx_cmp(const void *a, const void *b)
{
    const struct rowx *p = a, *q = b;
    if (p->j != q->j)
        return p->j < q->j ? -1 : 1;
    return (p->u > q->u) - (p->u < q->u);
}

/* Per-direction scratch. */
struct work {
    const struct rims *r;
    const struct mesh *m;
    const struct rim_frame *f;
    const double *hv;
    uint32_t *loc, *par, *tris; /* a triangle's index in the layer; union-find */
    uint8_t *drop;              /* per layer index: its loop is dropped */
    struct rowx *rx;
    size_t n_rx, cap_rx;
    struct open_sections *out;
    size_t n_span, cap_span;
};

/* The point where plane z cuts edge (a, b), in (u, w). */
static void
cut_point(const struct work *wk, uint32_t a, uint32_t b, double z, double *u, double *w)
{
    double t = (z - wk->hv[a]) / (wk->hv[b] - wk->hv[a]);
    struct vec3 p = v3_add(wk->m->v[a], v3_scale(v3_sub(wk->m->v[b], wk->m->v[a]), t));
    *u = v3_dot(p, wk->f->u);
    *w = v3_dot(p, wk->f->w);
}

/* The directed segment (u0, w0) -> (u1, w1) of a loop as row crossings (rows
   with w in [lo, hi)): a row entering the solid crosses a segment running
   towards -w, as contours run counter-clockwise seen from above. */
static bool
emit_directed(struct work *wk, double u0, double w0, double u1, double w1)
{
    const struct rim_frame *f = wk->f;
    if (w0 == w1)
        return true;
    int wind = w1 < w0 ? 1 : -1;
    double ul = w0 < w1 ? u0 : u1, wl = w0 < w1 ? w0 : w1;
    double uh = w0 < w1 ? u1 : u0, wh = w0 < w1 ? w1 : w0;
    double j0 = ceil((wl - f->w0) / f->pitch), j1 = ceil((wh - f->w0) / f->pitch) - 1;
    if (j0 < 0)
        j0 = 0;
    if (j1 > (double)f->nw - 1)
        j1 = (double)f->nw - 1;
    for (double j = j0; j <= j1; j++) {
        double s = (f->w0 + j * f->pitch - wl) / (wh - wl);
        void *o = wk->rx;
        if (!mem_grow(&o, &wk->cap_rx, wk->n_rx + 1, sizeof(*wk->rx)))
            return false;
        wk->rx = o;
        wk->rx[wk->n_rx++] = (struct rowx){ (uint32_t)j, wind, ul + s * (uh - ul) };
    }
    return true;
}

/* Triangle t's segment in plane z, oriented along up x n (a contour runs
   counter-clockwise seen from above): its start and end in (u, w).  False
   when the plane does not cut two of its edges. */
static bool
tri_segment(const struct work *wk, uint32_t t, double z, double s[2], double e[2])
{
    double pu[2], pw[2];
    int np = 0;
    for (int k = 0; k < 3 && np < 2; k++) {
        uint32_t a = wk->m->t[t][k], b = wk->m->t[t][(k + 1) % 3];
        if (cuts(wk->hv[a], wk->hv[b], z)) {
            cut_point(wk, a, b, z, &pu[np], &pw[np]);
            np++;
        }
    }
    if (np < 2)
        return false;
    struct vec3 dir = v3_cross(wk->f->up, mesh_tri_cross(wk->m, t));
    int first =
        (pu[1] - pu[0]) * v3_dot(dir, wk->f->u) + (pw[1] - pw[0]) * v3_dot(dir, wk->f->w) < 0;
    s[0] = pu[first];
    s[1] = pw[first];
    e[0] = pu[1 - first];
    e[1] = pw[1 - first];
    return true;
}

/* The line the slicer closes a gap with, from the polyline ending at crossing
   a to the one starting at crossing b (rim crossings of triangles ta, tb);
   two ends or two starts (a piece the slicer turns round) add nothing. */
static bool
emit_closing(struct work *wk, const struct crossing *a, const struct crossing *b, double z)
{
    double sa[2], ea[2], sb[2], eb[2];
    if (!tri_segment(wk, a->tri, z, sa, ea) || !tri_segment(wk, b->tri, z, sb, eb))
        return true;
    bool a_end = hypot(ea[0] - a->x, ea[1] - a->y) < hypot(sa[0] - a->x, sa[1] - a->y);
    bool b_end = hypot(eb[0] - b->x, eb[1] - b->y) < hypot(sb[0] - b->x, sb[1] - b->y);
    if (a_end == b_end)
        return true;
    return a_end ? emit_directed(wk, a->x, a->y, b->x, b->y)
                 : emit_directed(wk, b->x, b->y, a->x, a->y);
}

static bool
push_span(struct work *wk, double ua, double ub)
{
    const struct rim_frame *f = wk->f;
    double i0 = ceil((ua - f->u0) / f->pitch), i1 = floor((ub - f->u0) / f->pitch);
    if (i0 < 0)
        i0 = 0;
    if (i1 > (double)f->nu - 1)
        i1 = (double)f->nu - 1;
    if (i1 < i0)
        return true;
    void *o = wk->out->span;
    if (!mem_grow(&o, &wk->cap_span, wk->n_span + 1, sizeof(*wk->out->span)))
        return false;
    wk->out->span = o;
    wk->out->span[wk->n_span++] = (struct cell_span){ (uint32_t)i0, (uint32_t)i1 };
    return true;
}

/* Open layer l (plane k): its loops (tris[0..nt), the triangles the plane
   cuts), joined across the gaps its crossings x[0..n_x) close, the ones an
   alone crossing leaves open dropped, and the rows' kept spans. */
static bool
section_layer(struct work *wk, uint32_t l, int32_t k, uint32_t nt, const struct crossing *x,
              size_t n_x)
{
    const struct rim_frame *f = wk->f;
    double z = (k + 0.5) * f->layer_mm;
    for (uint32_t q = 0; q < nt; q++) {
        wk->loc[wk->tris[q]] = q;
        wk->par[q] = q;
        wk->drop[q] = 0;
    }
    for (uint32_t q = 0; q < nt; q++) {
        uint32_t t = wk->tris[q];
        for (int e = 0; e < 3; e++) {
            uint32_t a = wk->m->t[t][e], b = wk->m->t[t][(e + 1) % 3], o = wk->r->adj[t][e];
            if (cuts(wk->hv[a], wk->hv[b], z) && o != MESH_NO_TRI && wk->loc[o] != UINT32_MAX)
                uf_union(wk->par, q, wk->loc[o]);
        }
    }
    /* the slicer joins an end to its mate: one loop */
    for (size_t i = 0; i < n_x; i++) {
        size_t p = x[i].mate;
        if (!x[i].alone && wk->loc[x[i].tri] != UINT32_MAX && wk->loc[x[p].tri] != UINT32_MAX)
            uf_union(wk->par, wk->loc[x[i].tri], wk->loc[x[p].tri]);
    }
    for (size_t i = 0; i < n_x; i++)
        if (x[i].alone && wk->loc[x[i].tri] != UINT32_MAX)
            wk->drop[uf_find(wk->par, wk->loc[x[i].tri])] = 1;
    wk->n_rx = 0;
    bool ok = true;
    for (uint32_t q = 0; q < nt && ok; q++) {
        double a[2], b[2];
        if (!wk->drop[uf_find(wk->par, q)] && tri_segment(wk, wk->tris[q], z, a, b))
            ok = emit_directed(wk, a[0], a[1], b[0], b[1]);
    }
    for (size_t i = 0; i < n_x && ok; i++)
        if (!x[i].alone && x[i].mate > i && wk->loc[x[i].tri] != UINT32_MAX &&
            !wk->drop[uf_find(wk->par, wk->loc[x[i].tri])])
            ok = emit_closing(wk, &x[i], &x[x[i].mate], z);
    for (uint32_t q = 0; q < nt; q++)
        wk->loc[wk->tris[q]] = UINT32_MAX;
    if (!ok)
        return false;
    size_t n = wk->n_rx;
    if (n)
        qsort(wk->rx, n, sizeof(*wk->rx), rowx_cmp);
    /* each row: the stretches the kept loops wind around (non-zero: what
       PrusaSlicer's make_expolygons unites in its regular slicing mode) */
    size_t q = 0;
    for (uint32_t j = 0; j < f->nw; j++) {
        wk->out->first[(size_t)l * f->nw + j] = (uint32_t)wk->n_span;
        int wind = 0;
        double start = 0;
        for (; q < n && wk->rx[q].j == j; q++) {
            int was = wind;
            wind += wk->rx[q].wind;
            if (was == 0 && wind != 0)
                start = wk->rx[q].u;
            else if (was != 0 && wind == 0 && !push_span(wk, start, wk->rx[q].u))
                return false;
        }
    }
    return true;
}

/* The triangles each open layer cuts (lidx: layer index of plane k, -1 not
   open), as (l, tri) pairs into *tk (n_tk values; grown, free()); false when
   out of memory. */
static bool
layer_tris(const struct mesh *m, const struct rim_frame *f, const double *hv, const int32_t *lidx,
           int32_t k_top, uint32_t **tk, size_t *n_tk)
{
    size_t cap_tk = 0;
    for (uint32_t t = 0; t < m->n_tris; t++) {
        double lo = hv[m->t[t][0]], hi = lo;
        for (int e = 1; e < 3; e++) {
            double h = hv[m->t[t][e]];
            lo = h < lo ? h : lo;
            hi = h > hi ? h : hi;
        }
        int32_t k0, k1;
        planes_between(lo, hi, f->layer_mm, &k0, &k1);
        for (int32_t k = k0; k <= k1 && k <= k_top; k++) {
            if (lidx[k] < 0)
                continue;
            void *o = *tk;
            if (!mem_grow(&o, &cap_tk, *n_tk + 2, sizeof(uint32_t)))
                return false;
            *tk = o;
            (*tk)[(*n_tk)++] = (uint32_t)lidx[k];
            (*tk)[(*n_tk)++] = t;
        }
    }
    return true;
}

/* out->empty_to: the last layer of each run of open layers that keep nothing
   (consecutive planes, no span in any of nw rows). */
static void
empty_runs(struct open_sections *out, uint32_t nw)
{
    for (uint32_t l = out->n_layers; l-- > 0;) {
        bool empty = out->first[(size_t)l * nw] == out->first[(size_t)(l + 1) * nw];
        out->empty_to[l] = l;
        if (empty && l + 1 < out->n_layers && out->k[l + 1] == out->k[l] + 1 &&
            out->first[(size_t)(l + 1) * nw] == out->first[(size_t)(l + 2) * nw])
            out->empty_to[l] = out->empty_to[l + 1];
    }
}

int
rims_open_sections(const struct rims *r, const struct mesh *m, const struct rim_frame *f,
                   double max_gap_mm, struct open_sections *out, struct sf_err *err)
{
    memset(out, 0, sizeof(*out));
    if (!(f->layer_mm > 0) || !(max_gap_mm >= 0) || !(f->pitch > 0))
        return sf_err_set(err, SF_EINVAL, "open rims: layer %g mm, pitch %g mm, gap %g mm",
                          f->layer_mm, f->pitch, max_gap_mm);
    if (!r->n_edges)
        return SF_OK;
    int rc = SF_OK;
    struct crossing *x = NULL;
    size_t n_x = 0, n_alone = 0;
    uint32_t *tk = NULL, *cnt = NULL, *by = NULL;
    int32_t *lidx = NULL;
    struct work wk = { .r = r, .m = m, .f = f, .out = out };
    double *hv = mem_array(m->n_verts, sizeof(double));
    if (!hv)
        goto nomem;
    for (uint32_t i = 0; i < m->n_verts; i++)
        hv[i] = v3_dot(m->v[i], f->up) - f->base;
    wk.hv = hv;
    if (rim_crossings(r, m, f, hv, max_gap_mm, &x, &n_x, &n_alone))
        goto nomem;
    if (!n_alone)
        goto done;
    /* the open layers (those with an alone crossing) and their indices */
    int32_t k_top = x[n_x - 1].k;
    lidx = mem_array((size_t)k_top + 1, sizeof(int32_t));
    out->k = mem_array(n_alone, sizeof(int32_t));
    if (!lidx || !out->k)
        goto nomem;
    for (int32_t k = 0; k <= k_top; k++)
        lidx[k] = -1;
    for (size_t i = 0; i < n_x; i++)
        if (x[i].alone && lidx[x[i].k] < 0) {
            lidx[x[i].k] = (int32_t)out->n_layers;
            out->k[out->n_layers++] = x[i].k;
        }
    out->nw = f->nw;
    out->first = mem_array((size_t)out->n_layers * f->nw + 1, sizeof(uint32_t));
    wk.loc = mem_array(m->n_tris, sizeof(uint32_t));
    wk.par = mem_array(m->n_tris, sizeof(uint32_t));
    wk.tris = mem_array(m->n_tris, sizeof(uint32_t));
    wk.drop = mem_array(m->n_tris, 1);
    if (!out->first || !wk.loc || !wk.par || !wk.tris || !wk.drop)
        goto nomem;
    memset(wk.loc, 0xff, sizeof(uint32_t) * m->n_tris);
    /* the triangles each open layer cuts, as (l, tri) pairs, then by layer */
    size_t n_tk = 0;
    if (!layer_tris(m, f, hv, lidx, k_top, &tk, &n_tk))
        goto nomem;
    size_t n_pairs = n_tk / 2;
    cnt = mem_calloc((size_t)out->n_layers + 1, sizeof(uint32_t));
    by = mem_array(n_pairs ? n_pairs : 1, sizeof(uint32_t));
    if (!cnt || !by)
        goto nomem;
    for (size_t i = 0; i < n_pairs; i++)
        cnt[tk[2 * i] + 1]++;
    for (uint32_t l = 0; l < out->n_layers; l++)
        cnt[l + 1] += cnt[l];
    for (size_t i = 0; i < n_pairs; i++)
        by[cnt[tk[2 * i]]++] = tk[2 * i + 1];
    /* cnt[l] is now the end of layer l's triangles, cnt[l - 1] their start */
    size_t xi = 0;
    for (uint32_t l = 0; l < out->n_layers; l++) {
        int32_t k = out->k[l];
        while (x[xi].k < k)
            xi++;
        size_t xs = xi;
        while (xi < n_x && x[xi].k == k)
            xi++;
        uint32_t s = l ? cnt[l - 1] : 0, e = cnt[l];
        memcpy(wk.tris, by + s, (e - s) * sizeof(uint32_t));
        if (!section_layer(&wk, l, k, e - s, x + xs, xi - xs))
            goto nomem;
    }
    out->first[(size_t)out->n_layers * f->nw] = (uint32_t)wk.n_span;
    /* runs of layers that keep nothing: a column skips each in one step */
    if (!(out->empty_to = mem_array(out->n_layers, sizeof(uint32_t))))
        goto nomem;
    empty_runs(out, f->nw);
    goto done;
nomem:
    rc = sf_err_set(err, SF_ENOMEM, "open rims: out of memory");
    open_sections_release(out);
done:
    free(hv);
    free(x);
    free(tk);
    free(cnt);
    free(by);
    free(lidx);
    free(wk.loc);
    free(wk.par);
    free(wk.tris);
    free(wk.drop);
    free(wk.rx);
    return rc;
}
