/*
 * printtime_loops.c - the part's loops layer by layer (see printtime_loops.h).
 */
#include "printtime_loops.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"

#define NO_KEY UINT64_MAX

/* Holes are matched to outer loops pairwise; past this many pairs in one
   layer they are not (each outer loop then counts without its holes). */
#define PAIRS_MAX 200000u

/* A segment of a layer's cut: from its triangle's edge going down through
   the plane to the edge going up (for faces wound counter-clockwise from
   outside, outer loops run counter-clockwise seen from above). */
struct seg {
    uint64_t from, to; /* the edges, as (low vertex << 32 | high vertex) */
    double ax, ay, bx, by;
};

struct loop {
    double len_mm, area_mm2; /* signed: outer loops positive */
    double x0, y0, x1, y1;   /* bounding box */
    double isl_mm2, isl_mm;  /* an outer loop's island: with its holes */
};

struct work {
    uint32_t *tri;    /* triangles by first layer */
    uint32_t *first;  /* per layer + 1: start of its triangles in tri */
    uint32_t *active; /* triangles the current plane may cut */
    struct seg *seg;
    uint64_t *key; /* hash of segments by their from-edge */
    uint32_t *val;
    uint8_t *seen;
    struct loop *loop;
    uint32_t cap; /* segments and loops hold up to cap */
    uint32_t hash_cap;
};

static uint64_t
edge_key(uint32_t a, uint32_t b)
{
    return a < b ? (uint64_t)a << 32 | b : (uint64_t)b << 32 | a;
}

static uint32_t
hash_slot(uint64_t k, uint32_t mask)
{
    k ^= k >> 33;
    k *= 0xff51afd7ed558ccdULL;
    k ^= k >> 33;
    return (uint32_t)k & mask;
}

/* The layers [*k0, *k1] whose middle plane (k + 0.5) h cuts the triangle
   (a vertex on the plane counts as above it); *k1 < *k0 when none. */
static void
tri_layers(const double *z, const uint32_t *t, double h, uint32_t n, int64_t *k0, int64_t *k1)
{
    double lo = fmin(z[t[0]], fmin(z[t[1]], z[t[2]])), hi = fmax(z[t[0]], fmax(z[t[1]], z[t[2]]));
    int64_t a = (int64_t)floor(lo / h - 0.5) + 1, b = (int64_t)floor(hi / h - 0.5);
    /* floor's rounding: a is the first plane above lo, b the last at or under hi */
    while (a > 0 && (a - 1 + 0.5) * h > lo)
        a--;
    while ((a + 0.5) * h <= lo)
        a++;
    while ((b + 1 + 0.5) * h <= hi)
        b++;
    while (b >= 0 && (b + 0.5) * h > hi)
        b--;
    *k0 = a < 0 ? 0 : a;
    *k1 = b >= (int64_t)n ? (int64_t)n - 1 : b;
}

/* Sort the triangles by their first layer (counting sort into w->tri). */
static void
bucket(const struct mesh *m, const double *z, double h, uint32_t n, struct work *w)
{
    memset(w->first, 0, ((size_t)n + 1) * sizeof(uint32_t));
    for (uint32_t i = 0; i < m->n_tris; i++) {
        int64_t k0, k1;
        tri_layers(z, m->t[i], h, n, &k0, &k1);
        if (k1 >= k0)
            w->first[k0 + 1]++;
    }
    for (uint32_t k = 0; k < n; k++)
        w->first[k + 1] += w->first[k];
    uint32_t *fill = w->active; /* scratch: next free slot per layer */
    for (uint32_t k = 0; k < n; k++)
        fill[k] = w->first[k];
    for (uint32_t i = 0; i < m->n_tris; i++) {
        int64_t k0, k1;
        tri_layers(z, m->t[i], h, n, &k0, &k1);
        if (k1 >= k0)
            w->tri[fill[k0]++] = i;
    }
}

/* The segment plane zc cuts from triangle t, if any. */
static bool
cut(const struct mesh *m, const double *z, const double (*xy)[2], uint32_t t, double zc,
    struct seg *s)
{
    const uint32_t *v = m->t[t];
    if (v[0] == v[1] || v[1] == v[2] || v[2] == v[0])
        return false;
    bool got_from = false, got_to = false;
    for (int e = 0; e < 3; e++) {
        uint32_t a = v[e], b = v[(e + 1) % 3];
        bool up_a = z[a] >= zc, up_b = z[b] >= zc;
        if (up_a == up_b)
            continue;
        double f = (zc - z[a]) / (z[b] - z[a]);
        double x = xy[a][0] + f * (xy[b][0] - xy[a][0]), y = xy[a][1] + f * (xy[b][1] - xy[a][1]);
        if (up_a) { /* going down: the segment starts here */
            s->from = edge_key(a, b), s->ax = x, s->ay = y;
            got_from = true;
        } else {
            s->to = edge_key(a, b), s->bx = x, s->by = y;
            got_to = true;
        }
    }
    return got_from && got_to;
}

/* Chain the layer's ns segments into loops (w->loop); returns how many
   closed (open chains are dropped). */
static uint32_t
chain(struct work *w, uint32_t ns)
{
    uint32_t mask = w->hash_cap - 1, nl = 0;
    for (uint32_t i = 0; i <= mask; i++)
        w->key[i] = NO_KEY;
    for (uint32_t i = 0; i < ns; i++) {
        uint32_t h = hash_slot(w->seg[i].from, mask);
        while (w->key[h] != NO_KEY && w->key[h] != w->seg[i].from)
            h = (h + 1) & mask;
        if (w->key[h] == NO_KEY)
            w->key[h] = w->seg[i].from, w->val[h] = i;
    }
    memset(w->seen, 0, ns);
    for (uint32_t s0 = 0; s0 < ns; s0++) {
        if (w->seen[s0])
            continue;
        struct loop L = { 0, 0, INFINITY, INFINITY, -INFINITY, -INFINITY, 0, 0 };
        uint32_t s = s0;
        bool closed = false;
        for (;;) {
            const struct seg *g = &w->seg[s];
            w->seen[s] = 1;
            L.len_mm += hypot(g->bx - g->ax, g->by - g->ay);
            L.area_mm2 += 0.5 * (g->ax * g->by - g->bx * g->ay);
            L.x0 = fmin(L.x0, g->ax), L.y0 = fmin(L.y0, g->ay);
            L.x1 = fmax(L.x1, g->ax), L.y1 = fmax(L.y1, g->ay);
            uint32_t h = hash_slot(g->to, mask);
            while (w->key[h] != NO_KEY && w->key[h] != g->to)
                h = (h + 1) & mask;
            if (w->key[h] == NO_KEY)
                break;
            s = w->val[h];
            if (s == s0) {
                closed = true;
                break;
            }
            if (w->seen[s])
                break;
        }
        if (closed) {
            L.isl_mm2 = L.area_mm2, L.isl_mm = L.len_mm;
            w->loop[nl++] = L;
        }
    }
    return nl;
}

/* One layer's nl loops: add the small ones' length and the small infill
   regions' area.  A hole joins the smallest outer loop that holds it. */
static void
layer_sums(struct work *w, uint32_t nl, const struct printtime_loops_params *p, double *small_mm,
           double *small_fill_mm2)
{
    uint64_t n_out = 0, n_hole = 0;
    for (uint32_t i = 0; i < nl; i++) {
        if (w->loop[i].len_mm <= p->small_loop_mm)
            *small_mm += w->loop[i].len_mm;
        if (w->loop[i].area_mm2 > 0)
            n_out++;
        else
            n_hole++;
    }
    for (uint32_t i = 0; n_out * n_hole <= PAIRS_MAX && i < nl; i++) {
        const struct loop *hl = &w->loop[i];
        if (hl->area_mm2 > 0)
            continue;
        struct loop *best = NULL;
        for (uint32_t j = 0; j < nl; j++) {
            struct loop *o = &w->loop[j];
            if (o->area_mm2 >= -hl->area_mm2 && o->area_mm2 > 0 && o->x0 <= hl->x0 &&
                o->y0 <= hl->y0 && o->x1 >= hl->x1 && o->y1 >= hl->y1 &&
                (!best || o->area_mm2 < best->area_mm2))
                best = o;
        }
        if (best)
            best->isl_mm2 += hl->area_mm2, best->isl_mm += hl->len_mm;
    }
    for (uint32_t j = 0; j < nl; j++) {
        const struct loop *o = &w->loop[j];
        double inner = o->isl_mm2 - p->perimeter_mm * o->isl_mm;
        if (o->area_mm2 > 0 && inner > 0 && inner < p->solid_below_mm2)
            *small_fill_mm2 += inner;
    }
}

static void
work_free(struct work *w)
{
    free(w->tri); /* with first and active */
    free(w->seg); /* with loop and seen */
    free(w->key); /* with val */
}

/* Room for cap segments (and loops) and a hash twice that, rounded up to a
   power of two: one block for the segments, loops and flags, one for the
   hash's keys and values. */
static int
work_reserve(struct work *w, uint32_t cap)
{
    if (cap < 1) /* a first layer no triangle crosses still needs the hash */
        cap = 1;
    if (cap <= w->cap)
        return SF_OK;
    uint32_t hc = 16;
    while (hc < 2 * (uint64_t)cap)
        hc *= 2;
    free(w->seg);
    free(w->key);
    size_t per = sizeof(struct seg) + sizeof(struct loop) + 1;
    w->seg = mem_array(cap, per);
    w->key = mem_array(hc, sizeof(uint64_t) + sizeof(uint32_t));
    if (!w->seg || !w->key) {
        w->cap = 0;
        return SF_ENOMEM;
    }
    w->loop = (struct loop *)(w->seg + cap);
    w->seen = (uint8_t *)(w->loop + cap);
    w->val = (uint32_t *)(w->key + hc);
    w->cap = cap, w->hash_cap = hc;
    return SF_OK;
}

/* The part's heights above zmin along up and its points in a plane
   across up (a right-handed frame: +z up gives x, y). */
static void
project(const struct mesh *m, struct vec3 up, double zmin, double *z, double (*xy)[2])
{
    struct vec3 a = fabs(up.x) < 0.9 ? v3(1, 0, 0) : v3(0, 1, 0);
    struct vec3 e1 = v3_normalize(v3_sub(a, v3_scale(up, v3_dot(a, up))));
    struct vec3 e2 = v3_cross(up, e1);
    for (uint32_t i = 0; i < m->n_verts; i++) {
        z[i] = v3_dot(m->v[i], up) - zmin;
        xy[i][0] = v3_dot(m->v[i], e1);
        xy[i][1] = v3_dot(m->v[i], e2);
    }
}

/* Sweep the layers: triangles join the active list at their first layer
   and leave after their last. */
static int
sweep(const struct mesh *m, const double *z, const double (*xy)[2], uint32_t n,
      const struct printtime_loops_params *p, struct work *w, double *small_mm,
      double *small_fill_mm2)
{
    double h = p->layer_mm;
    uint32_t na = 0;
    for (uint32_t k = 0; k < n; k++) {
        for (uint32_t i = w->first[k]; i < w->first[k + 1]; i++)
            w->active[na++] = w->tri[i];
        uint32_t keep = 0;
        for (uint32_t i = 0; i < na; i++) {
            int64_t k0, k1;
            tri_layers(z, m->t[w->active[i]], h, n, &k0, &k1);
            if (k1 >= (int64_t)k)
                w->active[keep++] = w->active[i];
        }
        na = keep;
        if (work_reserve(w, na) < 0)
            return SF_ENOMEM;
        uint32_t ns = 0;
        double zc = (k + 0.5) * h;
        for (uint32_t i = 0; i < na; i++)
            if (cut(m, z, xy, w->active[i], zc, &w->seg[ns]))
                ns++;
        uint32_t nl = chain(w, ns);
        layer_sums(w, nl, p, &small_mm[k], &small_fill_mm2[k]);
    }
    return SF_OK;
}

int
printtime_loops_eval(const struct mesh *m, struct vec3 up, double zmin, uint32_t n,
                     const struct printtime_loops_params *p, double *small_mm,
                     double *small_fill_mm2, struct sf_err *err)
{
    if (n == 0 || m->n_tris == 0)
        return SF_OK;
    struct work w = { 0 };
    double *z = mem_array(m->n_verts, sizeof(double));
    double(*xy)[2] = mem_array(m->n_verts, sizeof(*xy));
    /* triangles by layer, the layers' starts, the active list (at least n:
       bucket's scratch) */
    size_t n_act = m->n_tris > n ? m->n_tris : n;
    w.tri = mem_array((size_t)m->n_tris + n + 1 + n_act, sizeof(uint32_t));
    int rc = SF_ENOMEM;
    if (!z || !xy || !w.tri)
        goto out;
    w.first = w.tri + m->n_tris;
    w.active = w.first + n + 1;
    project(m, up, zmin, z, xy);
    bucket(m, z, p->layer_mm, n, &w);
    rc = sweep(m, z, (const double(*)[2])xy, n, p, &w, small_mm, small_fill_mm2);
out:
    free(z);
    free(xy);
    work_free(&w);
    if (rc < 0)
        return sf_err_set(err, rc, "print time: out of memory for the layers' loops");
    return SF_OK;
}
