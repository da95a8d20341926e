/*
 * selfx_moved.c - selfx_ref_count's check of a mesh against the last one it
 * cast in full (see selfx_int.h and below).
 *
 * selfx_ref_count casts each edge and triangle pair again only where its
 * verdict can have changed since the base (the last mesh it cast in full):
 * a pair none of whose five vertices moved keeps it, and a pair farther
 * apart in the base than its edge's and triangle's largest vertex moves
 * (every point of a linearly moved simplex moves at most its largest vertex
 * move) plus MARGIN cannot be pierced (Embree's float test reports nothing
 * farther than its rounding, far under MARGIN).  The base lists its pairs
 * nearer than REACH with their distance; a pair not listed can only come
 * near when its edge or triangle moved half of REACH ("at risk"), and those
 * few are matched against everything by box.  The pairs that can have
 * changed are cast through a scene of their triangles (Embree's verdict on a
 * pair depends on the two alone, so every pair that scene answers is
 * answered as in the full check), the base's other hits kept: the hits,
 * hence the count and marks, are the full check's.  Too many at risk, or
 * more than an eighth of the edges to cast, and the mesh is cast in full
 * and becomes the base.
 *
 * Exact (byte-identical searches) but slower than casting everything:
 * fandisk's search, 169 checks, 22 in full, self-intersection 5.7 s
 * against 5.3 s; cow, 676 checks, 118 in full, 65.9 s against 34.9 s.  The
 * listing (every edge's neighbourhood in a grid, a distance each) and the
 * matching of what is at risk cost more than Embree's rebuild and casts.
 *
 * Thread: one thread at a time on a selfx_ref (selfx.h).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"
#include "selfx_int.h"
#define SELFX_MARGIN 1e-5    /* of the largest coordinate: Embree's float rounding is ~1e-7 */
#define SELFX_REACH 0.25     /* of the mean edge: the base's listed pairs */
#define SELFX_RISK_DIV 8     /* more than 32 + (edges + triangles) / this at risk: in full */
#define SELFX_RECAST_DIV 8   /* more than n_edge / this edges to cast: in full */

/* A pair a cast found: edge e of the cast list pierces triangle tri. */
struct hit {
    uint32_t e, tri;
};

struct hits {
    struct hit *h;
    size_t n, cap;
};

/* An edge and a triangle nearer than REACH in the base, dist mm apart. */
struct near_pair {
    uint32_t e, tri;
    double dist;
};

/* A triangle at risk by the low x of its box. */
struct key {
    double x;
    uint32_t i;
};

/* A uniform grid of the triangles' boxes in the base. */
struct grid {
    double lo[3], h;
    int g[3];
    size_t mask;            /* the buckets: a power of two, less one */
    uint32_t *start, *item; /* bucket c holds item[start[c] .. start[c + 1]) */
};

struct moved {
    uint32_t (*edge)[2]; /* the edges cast_some casts for a count, in its order */
    uint32_t n_edge;
    uint8_t *elig;       /* per triangle: in the count's scene (sr->prim) */
    uint32_t (*tri_edge)[3]; /* per triangle: its edges' indices (UINT32_MAX: not cast) */
    double reach;        /* mm */
    bool have_base, listed; /* a base; its near pairs listed (at its first use) */
    struct vec3 *base;      /* the last mesh cast in full */
    struct hits hb, hm;  /* its hits; the check's */
    struct near_pair *np;
    size_t n_np, cap_np;
    struct grid gr; /* the base's, once listed */
    double *disp;             /* per vertex: its move since the base, mm */
    uint8_t *moved;           /* per vertex: not bit-identical to the base */
    uint8_t *in_c, *in_s;     /* per edge, triangle: cast again */
    uint32_t *list_c, *list_s, n_c, n_s;
    uint32_t *seen, epoch;    /* per edge: the epoch of the check that counted it */
    uint32_t *stamp;          /* per triangle: the edge + 1 that last met it */
    uint32_t *risk, risk_max; /* the elements at risk, room for */
    double (*risk_box)[2][3];
    struct key *risk_key;
};

void
selfx_moved_free(struct moved *mv)
{
    if (!mv)
        return;
    free(mv->edge);
    free(mv->elig);
    free(mv->tri_edge);
    free(mv->gr.start);
    free(mv->gr.item);
    free(mv->base);
    free(mv->hb.h);
    free(mv->hm.h);
    free(mv->np);
    free(mv->disp);
    free(mv->moved);
    free(mv->in_c);
    free(mv->in_s);
    free(mv->list_c);
    free(mv->list_s);
    free(mv->seen);
    free(mv->stamp);
    free(mv->risk);
    free(mv->risk_box);
    free(mv->risk_key);
    free(mv);
}

static struct moved *
moved_new(const struct selfx_ref *sr, struct sf_err *err)
{
    const struct mesh *r = sr->ref;
    size_t nv = r->n_verts ? r->n_verts : 1, nt = r->n_tris ? r->n_tris : 1, ne = 3 * nt;
    struct moved *mv = mem_calloc(1, sizeof(*mv));
    if (mv) {
        mv->edge = mem_array(ne, sizeof(*mv->edge));
        mv->elig = mem_calloc(nt, 1);
        mv->tri_edge = mem_array(nt, sizeof(*mv->tri_edge));
        mv->base = mem_array(nv, sizeof(*mv->base));
        mv->disp = mem_array(nv, sizeof(*mv->disp));
        mv->moved = mem_calloc(nv, 1);
        mv->in_c = mem_calloc(ne, 1);
        mv->in_s = mem_calloc(nt, 1);
        mv->list_c = mem_array(ne, sizeof(uint32_t));
        mv->list_s = mem_array(nt, sizeof(uint32_t));
        mv->seen = mem_calloc(ne, sizeof(uint32_t));
        mv->stamp = mem_calloc(nt, sizeof(uint32_t));
    }
    if (!mv || !mv->edge || !mv->elig || !mv->tri_edge || !mv->base || !mv->disp || !mv->moved || !mv->in_c ||
        !mv->in_s || !mv->list_c || !mv->list_s || !mv->seen || !mv->stamp) {
        selfx_moved_free(mv);
        sf_err_set(err, SF_ENOMEM, "selfx: out of memory for %u triangles", r->n_tris);
        return NULL;
    }
    double sum = 0;
    for (uint32_t i = 0; i < r->n_tris; i++)
        for (int k = 0; k < 3; k++) {
            uint32_t a = r->t[i][k], b = r->t[i][(k + 1) % 3];
            mv->tri_edge[i][k] = UINT32_MAX;
            if (a > b || sr->near[a] || sr->near[b])
                continue; /* as cast_some with skip = near */
            mv->tri_edge[i][k] = mv->n_edge;
            mv->edge[mv->n_edge][0] = a;
            mv->edge[mv->n_edge++][1] = b;
            sum += v3_len(v3_sub(r->v[b], r->v[a]));
        }
    for (uint32_t i = 0; i < sr->n_prim; i++)
        mv->elig[sr->prim[i]] = 1;
    mv->reach = mv->n_edge ? SELFX_REACH * sum / mv->n_edge : 0;
    mv->risk_max = 32 + (mv->n_edge + sr->n_prim) / SELFX_RISK_DIV;
    mv->risk = mem_array(mv->risk_max, sizeof(*mv->risk));
    mv->risk_box = mem_array(mv->risk_max, sizeof(*mv->risk_box));
    mv->risk_key = mem_array(mv->risk_max, sizeof(*mv->risk_key));
    if (!mv->risk || !mv->risk_box || !mv->risk_key) {
        selfx_moved_free(mv);
        sf_err_set(err, SF_ENOMEM, "selfx: out of memory for %u triangles", r->n_tris);
        return NULL;
    }
    return mv;
}

static bool
hits_push(struct hits *h, uint32_t e, uint32_t tri)
{
    if (h->n == h->cap) {
        size_t cap = h->cap ? 2 * h->cap : 64;
        struct hit *nh = mem_realloc_array(h->h, cap, sizeof(*nh));
        if (!nh)
            return false;
        h->h = nh;
        h->cap = cap;
    }
    h->h[h->n].e = e;
    h->h[h->n++].tri = tri;
    return true;
}

/* The judge of a recording cast: note the pair once, judge nothing. */
struct rec {
    struct hits *h;
    uint32_t e; /* the edge being cast */
    bool oom;
};

static bool
record_hit(void *ud, uint32_t a, uint32_t b, uint32_t tri)
{
    (void)a;
    (void)b;
    struct rec *r = ud;
    for (size_t i = r->h->n; i > 0 && r->h->h[i - 1].e == r->e; i--)
        if (r->h->h[i - 1].tri == tri)
            return false;
    if (!hits_push(r->h, r->e, tri))
        r->oom = true;
    return false;
}

/* Cast the listed edges (all with list NULL) of m through sc (its triangle
   i is m's prim[i]), appending what they pierce to out. */
static int
cast_into(const struct scene *sc, const uint32_t *prim, const struct mesh *m,
          const struct moved *mv, const uint32_t *list, uint32_t n, struct hits *out,
          struct sf_err *err)
{
    struct rec r = { .h = out };
    struct edge_ctx ec = { .m = m, .judge = record_hit, .ud = &r, .prim = prim };
    rtcInitIntersectContext(&ec.ctx);
    for (uint32_t k = 0; k < n; k++) {
        r.e = list ? list[k] : k;
        selfx_cast_one(sc, &ec, mv->edge[r.e][0], mv->edge[r.e][1]);
    }
    return r.oom ? sf_err_set(err, SF_ENOMEM, "selfx: out of memory for the crossings") : SF_OK;
}

/* fmin and fmax without their NaN rules (and calls): the coordinates are finite */
static inline double
lesser(double a, double b)
{
    return a < b ? a : b;
}

static inline double
greater(double a, double b)
{
    return a > b ? a : b;
}

static double
axis(struct vec3 p, int k)
{
    return k == 0 ? p.x : k == 1 ? p.y : p.z;
}

/* The box of n vertices of m (indices v). */
static void
box_of(const struct vec3 *pos, const uint32_t *v, int n, double lo[3], double hi[3])
{
    for (int k = 0; k < 3; k++) {
        lo[k] = hi[k] = axis(pos[v[0]], k);
        for (int j = 1; j < n; j++) {
            lo[k] = lesser(lo[k], axis(pos[v[j]], k));
            hi[k] = greater(hi[k], axis(pos[v[j]], k));
        }
    }
}

static bool
boxes_within(const double alo[3], const double ahi[3], const double blo[3], const double bhi[3],
             double gap)
{
    for (int k = 0; k < 3; k++)
        if (alo[k] - gap > bhi[k] || blo[k] - gap > ahi[k])
            return false;
    return true;
}

static bool
touches(const uint32_t e[2], const uint32_t *t)
{
    for (int k = 0; k < 3; k++)
        if (t[k] == e[0] || t[k] == e[1])
            return true;
    return false;
}


static int
cell_of(const struct grid *gr, double x, int k)
{
    double c = floor((x - gr->lo[k]) / gr->h);
    return !(c >= 0) ? 0 : c >= gr->g[k] ? gr->g[k] - 1 : (int)c;
}

static size_t
bucket_of(const struct grid *gr, int x, int y, int z)
{
    uint64_t k = (uint64_t)x * 73856093u ^ (uint64_t)y * 19349663u ^ (uint64_t)z * 83492791u;
    return (size_t)(k & gr->mask);
}

static int
grid_build(struct grid *gr, const struct selfx_ref *sr, const struct vec3 *pos, double h)
{
    const struct mesh *r = sr->ref;
    free(gr->start);
    free(gr->item);
    memset(gr, 0, sizeof(*gr));
    if (!(h > 0))
        h = 1; /* no edge: any cell will do */
    double hi[3];
    for (int k = 0; k < 3; k++) {
        gr->lo[k] = INFINITY;
        hi[k] = -INFINITY;
    }
    for (uint32_t v = 0; v < r->n_verts; v++)
        for (int k = 0; k < 3; k++) {
            gr->lo[k] = lesser(gr->lo[k], axis(pos[v], k));
            hi[k] = greater(hi[k], axis(pos[v], k));
        }
    /* cells of h (at most 2^20 a side), hashed into 2 to 4 buckets a
       triangle: the grid's memory is the mesh's, whatever its box */
    for (int k = 0; k < 3; k++)
        h = greater(h, (hi[k] - gr->lo[k]) / (1 << 20));
    gr->h = h;
    for (int k = 0; k < 3; k++)
        gr->g[k] = (int)floor((hi[k] - gr->lo[k]) / h) + 1;
    size_t n_cells = 1;
    while (n_cells < 2 * (size_t)r->n_tris)
        n_cells *= 2;
    gr->mask = n_cells - 1;
    if (!(gr->start = mem_calloc(n_cells + 1, sizeof(uint32_t))))
        return SF_ENOMEM;
    for (int pass = 0; pass < 2; pass++) {
        for (uint32_t i = 0; i < r->n_tris; i++) {
            double blo[3], bhi[3];
            box_of(pos, r->t[i], 3, blo, bhi);
            int c0[3], c1[3];
            for (int k = 0; k < 3; k++) {
                c0[k] = cell_of(gr, blo[k], k);
                c1[k] = cell_of(gr, bhi[k], k);
            }
            for (int x = c0[0]; x <= c1[0]; x++)
                for (int y = c0[1]; y <= c1[1]; y++)
                    for (int z = c0[2]; z <= c1[2]; z++) {
                        size_t c = bucket_of(gr, x, y, z);
                        if (pass == 0)
                            gr->start[c + 1]++;
                        else
                            gr->item[gr->start[c]++] = i;
                    }
        }
        if (pass == 0) {
            for (size_t c = 0; c < n_cells; c++)
                gr->start[c + 1] += gr->start[c];
            if (!(gr->item = mem_array(gr->start[n_cells] ? gr->start[n_cells] : 1,
                                       sizeof(uint32_t))))
                return SF_ENOMEM;
        }
    }
    for (size_t c = n_cells; c > 0; c--) /* pass 1 moved each start to the next's */
        gr->start[c] = gr->start[c - 1];
    gr->start[0] = 0;
    return SF_OK;
}

/* The cells of the grid a box, padded by pad, meets. */
static void
grid_range(const struct grid *gr, const double lo[3], const double hi[3], double pad, int c0[3],
           int c1[3])
{
    for (int k = 0; k < 3; k++) {
        c0[k] = cell_of(gr, lo[k] - pad, k);
        c1[k] = cell_of(gr, hi[k] + pad, k);
    }
}

#define GRID_EACH(gr, c0, c1, f)                                                                   \
    for (int x_ = (c0)[0]; x_ <= (c1)[0]; x_++)                                                    \
        for (int y_ = (c0)[1]; y_ <= (c1)[1]; y_++)                                                \
            for (int z_ = (c0)[2]; z_ <= (c1)[2]; z_++)                                            \
                for (size_t c_ = bucket_of((gr), x_, y_, z_), j_ = (gr)->start[c_];                \
                     j_ < (gr)->start[c_ + 1] && ((f) = (gr)->item[j_], true); j_++)

/* List the pairs nearer than reach at pos (the base), keeping its grid. */
static int
list_near(struct selfx_ref *sr, const struct vec3 *pos, struct sf_err *err)
{
    struct moved *mv = sr->inc;
    const struct mesh *r = sr->ref;
    mv->n_np = 0;
    if (grid_build(&mv->gr, sr, pos, 4 * mv->reach) < 0)
        return sf_err_set(err, SF_ENOMEM, "selfx: out of memory for the grid");
    memset(mv->stamp, 0, (size_t)r->n_tris * sizeof(uint32_t));
    for (uint32_t i = 0; i < mv->n_edge; i++) {
        const uint32_t *e = mv->edge[i];
        double elo[3], ehi[3], tlo[3], thi[3];
        box_of(pos, e, 2, elo, ehi);
        int c0[3], c1[3];
        grid_range(&mv->gr, elo, ehi, mv->reach, c0, c1);
        uint32_t f;
        GRID_EACH(&mv->gr, c0, c1, f)
        {
            const uint32_t *t = r->t[f];
            if (mv->stamp[f] == i + 1 || !mv->elig[f] || touches(e, t))
                continue;
            mv->stamp[f] = i + 1;
            box_of(pos, t, 3, tlo, thi);
            if (!boxes_within(elo, ehi, tlo, thi, mv->reach))
                continue;
            double d = selfx_seg_tri(pos[e[0]], pos[e[1]], pos[t[0]], pos[t[1]], pos[t[2]]);
            if (!(d < mv->reach))
                continue;
            if (mv->n_np == mv->cap_np) {
                size_t cap = mv->cap_np ? 2 * mv->cap_np : 1024;
                void *np = mem_realloc_array(mv->np, cap, sizeof(*mv->np));
                if (!np)
                    return sf_err_set(err, SF_ENOMEM, "selfx: out of memory for the near pairs");
                mv->np = np;
                mv->cap_np = cap;
            }
            mv->np[mv->n_np++] = (struct near_pair){ i, f, d };
        }
    }
    return SF_OK;
}

/* Cast m in full into mv->hm and make it the base. */
static int
check_full(struct selfx_ref *sr, const struct mesh *m, struct sf_err *err)
{
    struct moved *mv = sr->inc;
    mv->hm.n = 0;
    mv->have_base = false;
    selfx_scene_refit(&sr->sc, m);
    int rc = cast_into(&sr->sc, sr->prim, m, mv, NULL, mv->n_edge, &mv->hm, err);
    if (rc < 0)
        return rc;
    if (mv->hb.cap < mv->hm.n) {
        struct hit *nh = mem_realloc_array(mv->hb.h, mv->hm.n, sizeof(*nh));
        if (!nh)
            return sf_err_set(err, SF_ENOMEM, "selfx: out of memory for the crossings");
        mv->hb.h = nh;
        mv->hb.cap = mv->hm.n;
    }
    if (mv->hm.n)
        memcpy(mv->hb.h, mv->hm.h, mv->hm.n * sizeof(*mv->hm.h));
    mv->hb.n = mv->hm.n;
    memcpy(mv->base, m->v, (size_t)m->n_verts * sizeof(*m->v));
    mv->listed = false;
    for (uint32_t v = 0; v < m->n_verts; v++)
        if (!(fabs(m->v[v].x) + fabs(m->v[v].y) + fabs(m->v[v].z) < INFINITY))
            return SF_OK; /* no base: the next check is in full too */
    mv->have_base = true;
    return SF_OK;
}

static void
recast_add(struct moved *mv, uint32_t e, uint32_t tri)
{
    if (!mv->in_c[e]) {
        mv->in_c[e] = 1;
        mv->list_c[mv->n_c++] = e;
    }
    if (!mv->in_s[tri]) {
        mv->in_s[tri] = 1;
        mv->list_s[mv->n_s++] = tri;
    }
}

static void
recast_clear(struct moved *mv)
{
    for (uint32_t i = 0; i < mv->n_c; i++)
        mv->in_c[mv->list_c[i]] = 0;
    for (uint32_t i = 0; i < mv->n_s; i++)
        mv->in_s[mv->list_s[i]] = 0;
    mv->n_c = mv->n_s = 0;
}

static double
disp_of(const struct moved *mv, const uint32_t *v, int n)
{
    double d = mv->disp[v[0]];
    for (int j = 1; j < n; j++)
        d = greater(d, mv->disp[v[j]]);
    return d;
}

static int
key_cmp(const void *a, const void *b)
{
    double x = ((const struct key *)a)->x, y = ((const struct key *)b)->x;
    return (x > y) - (x < y);
}

/* Match the elements at risk (edges risk[0 .. n_e), triangles risk[n_e ..
   n); moved at_risk or more) against the other kind by their boxes in m:
   each other at risk directly, the rest through the base's grid (a box in m
   lies within at_risk of the base's, and an edge within its triangles'). */
static void
match_at_risk(struct selfx_ref *sr, const struct mesh *m, const uint32_t *risk, int n_e, int n,
              double at_risk, double margin)
{
    struct moved *mv = sr->inc;
    double blo[3], bhi[3];
#define lo(i) mv->risk_box[i][0]
#define hi(i) mv->risk_box[i][1]
    for (int i = 0; i < n; i++)
        box_of(m->v, i < n_e ? mv->edge[risk[i]] : m->t[risk[i]], i < n_e ? 2 : 3, lo(i), hi(i));
    /* each other: the triangles in x order, each edge's found by bisection
       within the widest triangle's reach */
    struct key *key = mv->risk_key;
    int n_t = n - n_e;
    double wide = 0;
    for (int j = 0; j < n_t; j++) {
        key[j] = (struct key){ lo(n_e + j)[0], (uint32_t)(n_e + j) };
        wide = greater(wide, hi(n_e + j)[0] - lo(n_e + j)[0]);
    }
    qsort(key, (size_t)n_t, sizeof(*key), key_cmp);
    for (int i = 0; i < n_e && n_t > 0; i++) {
        double from = lo(i)[0] - margin - wide, to = hi(i)[0] + margin;
        int a = 0, b = n_t;
        while (a < b) { /* the first key at or past from */
            int mid = a + (b - a) / 2;
            if (key[mid].x < from)
                a = mid + 1;
            else
                b = mid;
        }
        for (int j = a; j < n_t && key[j].x <= to; j++)
            if (boxes_within(lo(i), hi(i), lo(key[j].i), hi(key[j].i), margin) &&
                !touches(mv->edge[risk[i]], m->t[risk[key[j].i]]))
                recast_add(mv, risk[i], risk[key[j].i]);
    }
    memset(mv->stamp, 0, (size_t)m->n_tris * sizeof(uint32_t));
    for (int i = 0; i < n; i++) {
        int c0[3], c1[3];
        grid_range(&mv->gr, lo(i), hi(i), at_risk + margin, c0, c1);
        uint32_t f;
        GRID_EACH(&mv->gr, c0, c1, f)
        {
            if (mv->stamp[f] == (uint32_t)i + 1)
                continue;
            mv->stamp[f] = (uint32_t)i + 1;
            if (i < n_e) {
                const uint32_t *e = mv->edge[risk[i]];
                if (!mv->elig[f] || touches(e, m->t[f]))
                    continue;
                box_of(m->v, m->t[f], 3, blo, bhi);
                if (boxes_within(lo(i), hi(i), blo, bhi, margin))
                    recast_add(mv, risk[i], f);
                continue;
            }
            for (int k = 0; k < 3; k++) {
                uint32_t e = mv->tri_edge[f][k];
                if (e == UINT32_MAX || touches(mv->edge[e], m->t[risk[i]]))
                    continue;
                box_of(m->v, mv->edge[e], 2, blo, bhi);
                if (boxes_within(lo(i), hi(i), blo, bhi, margin))
                    recast_add(mv, e, risk[i]);
            }
        }
    }
#undef lo
#undef hi
}

/* m's hits into mv->hm from the base's and the pairs that can have
   changed: 1 done, 0 too much moved (cast in full), or a negative
   sf_status. */
static int
check_moved(struct selfx_ref *sr, const struct mesh *m, struct sf_err *err)
{
    struct moved *mv = sr->inc;
    int rc;
    if (!mv->listed && (rc = list_near(sr, mv->base, err)) < 0)
        return rc;
    mv->listed = true;
    double big = 0;
    for (uint32_t v = 0; v < m->n_verts; v++) {
        struct vec3 p = m->v[v], q = mv->base[v];
        mv->moved[v] = memcmp(&p, &q, sizeof(p)) != 0;
        mv->disp[v] = mv->moved[v] ? v3_len(v3_sub(p, q)) : 0;
        big = greater(big, greater(greater(fabs(p.x), fabs(p.y)), fabs(p.z)));
        big = greater(big, greater(greater(fabs(q.x), fabs(q.y)), fabs(q.z)));
        if (!(mv->disp[v] < INFINITY) || !(big < INFINITY))
            return 0; /* not a finite shape: the full check */
    }
    double margin = SELFX_MARGIN * big, at_risk = (mv->reach - margin) / 2;
    if (!(at_risk > 0))
        return 0;
    uint32_t *risk = mv->risk;
    int n_risk = 0;
    for (uint32_t i = 0; i < mv->n_edge; i++)
        if (disp_of(mv, mv->edge[i], 2) >= at_risk) {
            if ((uint32_t)n_risk == mv->risk_max)
                return 0;
            risk[n_risk++] = i;
        }
    int n_risk_e = n_risk;
    for (uint32_t i = 0; i < sr->n_prim; i++)
        if (disp_of(mv, m->t[sr->prim[i]], 3) >= at_risk) {
            if ((uint32_t)n_risk == mv->risk_max)
                return 0;
            risk[n_risk++] = sr->prim[i];
        }
    for (size_t i = 0; i < mv->n_np; i++) {
        const struct near_pair *np = &mv->np[i];
        const uint32_t *e = mv->edge[np->e], *t = m->t[np->tri];
        if (!(mv->moved[e[0]] | mv->moved[e[1]] | mv->moved[t[0]] | mv->moved[t[1]] |
              mv->moved[t[2]]))
            continue;
        if (np->dist <= disp_of(mv, e, 2) + disp_of(mv, t, 3) + margin)
            recast_add(mv, np->e, np->tri);
    }
    match_at_risk(sr, m, risk, n_risk_e, n_risk, at_risk, margin);
    if (mv->n_c > mv->n_edge / SELFX_RECAST_DIV) {
        recast_clear(mv);
        return 0;
    }
    mv->hm.n = 0;
    rc = SF_OK;
    for (size_t i = 0; i < mv->hb.n; i++) {
        const struct hit *h = &mv->hb.h[i];
        if (!(mv->in_c[h->e] && mv->in_s[h->tri]) && !hits_push(&mv->hm, h->e, h->tri))
            rc = sf_err_set(err, SF_ENOMEM, "selfx: out of memory for the crossings");
    }
    if (rc == SF_OK && mv->n_c) {
        struct scene sc;
        if ((rc = selfx_scene_init(&sc, m, mv->list_s, mv->n_s, true, sr->sc.dev, err)) == SF_OK) {
            rc = cast_into(&sc, mv->list_s, m, mv, mv->list_c, mv->n_c, &mv->hm, err);
            selfx_scene_release(&sc);
        }
    }
    recast_clear(mv);
    return rc < 0 ? rc : 1;
}

int
selfx_moved_count(struct selfx_ref *sr, const struct mesh *m, uint8_t *mark, struct sf_err *err)
{
    if (!sr->inc && !(sr->inc = moved_new(sr, err)))
        return SF_ENOMEM;
    struct moved *mv = sr->inc;
    int rc = mv->have_base ? check_moved(sr, m, err) : 0;
    if (rc == 0)
        rc = check_full(sr, m, err);
    if (rc < 0) {
        mv->have_base = false;
        return rc;
    }
    /* judged here, each hit (not the first of each edge: marks) */
    if (++mv->epoch == 0) {
        memset(mv->seen, 0, (size_t)mv->n_edge * sizeof(uint32_t));
        mv->epoch = 1;
    }
    struct new_ctx ctx = { .sr = sr, .mark = mark };
    int count = 0;
    for (size_t i = 0; i < mv->hm.n; i++) {
        const struct hit *h = &mv->hm.h[i];
        if (selfx_apart_in_ref(&ctx, mv->edge[h->e][0], mv->edge[h->e][1], h->tri) &&
            mv->seen[h->e] != mv->epoch) {
            mv->seen[h->e] = mv->epoch;
            count++;
        }
    }
    return count;
}
