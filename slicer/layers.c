/*
 * layers.c - mesh to per-layer polygons (see layers.h for the method).
 *
 * Triangles are bucketed by the layers they cross (a counting sort into
 * one CSR array, so each layer reads a contiguous list), then each layer
 * cuts its triangles into segments, chains them with a small open-
 * addressing hash keyed by the crossed edge, and unites the loops with
 * Clipper.  Layers are independent, so par_for (src/base/par.h) spreads
 * them over the process's thread budget, each into its own slot.
 *
 * Thread: runs on par_for's threads; the call itself is reentrant.
 */
#include "layers.h"

#include <math.h>
#include <stdatomic.h>
#include <string.h>

#include "../src/base/limits.h"
#include "../src/base/mem.h"
#include "../src/base/par.h"
#include "clip_shim.h"

#define LAYERS_SIMPLIFY_MM 0.01
/* Widest crack between open chains that is bridged (PrusaSlicer's max_gap,
   TriangleMeshSlicer.cpp): meshes made of unwelded patches leave cracks of
   micrometres to tenths of a millimetre between their chains. */
#define LAYERS_GAP_MAX_MM 2.0
/* A vertex this close to a cutting plane lies on it (and counts as above):
   the part's coordinates are floats, the planes doubles, and a face
   modelled at a plane's height (a 1.3 mm plate's top) lands within a few
   float steps of it, below as often as above; PrusaSlicer cuts in floats,
   where the two are equal, and keeps that layer. */
#define LAYERS_ON_PLANE_MM 1e-4

struct seg {
    struct ipt a, b;  /* from the above->below crossing to the below->above one */
    int64_t ka0, ka1; /* edge of a (vertex indices, sorted) */
    int64_t kb0, kb1; /* edge of b */
};

/* Open-addressing map from a pair of int64 to a segment index. */
struct map {
    int64_t (*k)[2];
    uint32_t *v; /* UINT32_MAX: empty */
    size_t mask;
};

static bool
map_init(struct map *m, size_t n)
{
    size_t cap = 16;
    while (cap < 2 * n)
        cap *= 2;
    m->k = mem_array(cap, sizeof(*m->k));
    m->v = mem_array(cap, sizeof(*m->v));
    m->mask = cap - 1;
    if (!m->k || !m->v)
        return false;
    memset(m->v, 0xff, cap * sizeof(*m->v));
    return true;
}

static void
map_release(struct map *m)
{
    free(m->k);
    free(m->v);
}

static size_t
hash2(int64_t a, int64_t b)
{
    uint64_t h = (uint64_t)a * 0x9E3779B97F4A7C15ull ^ ((uint64_t)b + 0x632BE59BD9B4E019ull);
    h ^= h >> 29;
    h *= 0xBF58476D1CE4E5B9ull;
    return (size_t)(h ^ (h >> 32));
}

/* Insert unless present; a duplicate key keeps the first value. */
static void
map_put(struct map *m, int64_t a, int64_t b, uint32_t v)
{
    for (size_t i = hash2(a, b) & m->mask;; i = (i + 1) & m->mask) {
        if (m->v[i] == UINT32_MAX) {
            m->k[i][0] = a;
            m->k[i][1] = b;
            m->v[i] = v;
            return;
        }
        if (m->k[i][0] == a && m->k[i][1] == b)
            return;
    }
}

static uint32_t
map_get(const struct map *m, int64_t a, int64_t b)
{
    for (size_t i = hash2(a, b) & m->mask;; i = (i + 1) & m->mask) {
        if (m->v[i] == UINT32_MAX)
            return UINT32_MAX;
        if (m->k[i][0] == a && m->k[i][1] == b)
            return m->v[i];
    }
}

/* A worker's segment buffer, grown as needed and kept across its layers. */
struct scratch {
    struct seg *segs;
    size_t cap;
};

struct job {
    const struct mesh *m;
    struct layer_stack *out;
    const uint32_t *first, *tris; /* CSR: triangles of layer k */
    double zmin;
    struct scratch *scratch; /* one per par_for worker */
    atomic_uint n_open;      /* a sum of counts: the same in any order */
};

/* Crossing of edge (u, v) with plane p, computed from the below end. */
static struct ipt
cross_pt(const struct mesh *m, uint32_t u, uint32_t v, double p, double dx, double dy)
{
    struct vec3 a = m->v[u], b = m->v[v];
    if (a.z > b.z) {
        struct vec3 t = a;
        a = b;
        b = t;
    }
    double t = (p - a.z) / (b.z - a.z);
    struct ipt q = { poly_i(a.x + t * (b.x - a.x) + dx), poly_i(a.y + t * (b.y - a.y) + dy) };
    return q;
}

/* Squared distance, units^2. */
static double
d2(struct ipt a, struct ipt b)
{
    double dx = (double)(a.x - b.x), dy = (double)(a.y - b.y);
    return dx * dx + dy * dy;
}

/* Chains of pieces of open: pieces link head to tail, each maybe walked backwards. */
struct chains {
    const struct paths *open;
    uint32_t *nxt;  /* next piece of the chain, UINT32_MAX after the tail */
    uint32_t *tail; /* of a head: the chain's last piece */
    uint8_t *rev;   /* piece walked last point first */
    uint8_t *head;  /* 1: the piece starts a live (still open) chain */
};

static struct ipt
piece_end(const struct chains *c, uint32_t k, bool last)
{
    const struct paths *o = c->open;
    return last != (bool)c->rev[k] ? o->pts[o->start[k + 1] - 1] : o->pts[o->start[k]];
}

/* Append chain h to out as one path (dropped if it has under 3 points). */
static bool
emit_chain(const struct chains *c, uint32_t h, struct paths *out)
{
    if (!paths_begin(out))
        return false;
    for (uint32_t k = h; k != UINT32_MAX; k = c->nxt[k]) {
        const struct ipt *q = c->open->pts + c->open->start[k];
        uint32_t m = paths_len(c->open, k);
        for (uint32_t i = 0; i < m; i++) {
            struct ipt p = q[c->rev[k] ? m - 1 - i : i];
            uint32_t at = out->start[out->n]; /* points so far, all paths */
            if (at > out->start[out->n - 1] && out->pts[at - 1].x == p.x &&
                out->pts[at - 1].y == p.y)
                continue; /* pieces that meet exactly share the point */
            if (!paths_push(out, p))
                return false;
        }
    }
    if (out->start[out->n] - out->start[out->n - 1] < 3)
        out->n--;
    return true;
}

/*
 * Join open chains across cracks up to max_mm and append the loops to
 * loops, as PrusaSlicer does: each chain's end goes to the nearest chain
 * start (its own start closes it), first keeping directions (the facets of
 * a consistently oriented surface), then also reversing a chain.  Straight
 * closing instead would add a chord per chain, and the chords of a loop
 * cut into several chains enclose a polygon that the nonzero union
 * removes from the part.  Chains that reach nothing are closed straight
 * and counted in *n_left.  false when memory runs out.
 */
static bool
close_gaps(const struct paths *open, double max_mm, struct paths *loops, uint32_t *n_left)
{
    uint32_t n = open->n;
    struct chains c = { .open = open,
                        .nxt = mem_array(n, sizeof(uint32_t)),
                        .tail = mem_array(n, sizeof(uint32_t)),
                        .rev = mem_calloc(n, 1),
                        .head = mem_array(n, 1) };
    bool ok = c.nxt && c.tail && c.rev && c.head;
    for (uint32_t k = 0; ok && k < n; k++) {
        c.nxt[k] = UINT32_MAX;
        c.tail[k] = k;
        c.head[k] = paths_len(open, k) >= 2;
    }
    double lim = max_mm * POLY_SCALE * max_mm * POLY_SCALE;
    for (int round = 0; ok && round < 2; round++) {
        for (uint32_t h = 0; ok && h < n; h++) {
            while (c.head[h]) {
                struct ipt e = piece_end(&c, c.tail[h], true);
                double best = lim * (1 + 1e-12);
                uint32_t pick = UINT32_MAX;
                bool flip = false;
                for (uint32_t g = 0; g < n; g++) {
                    if (!c.head[g])
                        continue;
                    double d = d2(e, piece_end(&c, g, false));
                    if (d < best)
                        best = d, pick = g, flip = false;
                    if (round == 1 && g != h) {
                        d = d2(e, piece_end(&c, c.tail[g], true));
                        if (d < best)
                            best = d, pick = g, flip = true;
                    }
                }
                if (pick == UINT32_MAX)
                    break;
                if (pick == h) { /* back at its own start: a loop */
                    c.head[h] = 0;
                    ok = emit_chain(&c, h, loops);
                    break;
                }
                if (flip) { /* reverse chain pick: its tail becomes its head */
                    uint32_t prev = UINT32_MAX, t = c.tail[pick];
                    for (uint32_t k = pick; k != UINT32_MAX;) {
                        uint32_t nx = c.nxt[k];
                        c.nxt[k] = prev;
                        c.rev[k] ^= 1;
                        prev = k;
                        k = nx;
                    }
                    c.head[pick] = 0;
                    c.head[t] = 1;
                    c.tail[t] = pick;
                    pick = t;
                }
                c.nxt[c.tail[h]] = pick;
                c.tail[h] = c.tail[pick];
                c.head[pick] = 0;
            }
        }
    }
    for (uint32_t h = 0; ok && h < n; h++) {
        if (c.head[h]) {
            (*n_left)++;
            ok = emit_chain(&c, h, loops);
        }
    }
    free(c.nxt);
    free(c.tail);
    free(c.rev);
    free(c.head);
    return ok;
}

static int
slice_one(struct job *j, uint32_t k, struct seg **segs, size_t *cap)
{
    const struct mesh *m = j->m;
    struct layer *L = &j->out->l[k];
    double p = j->zmin + L->z_mm - L->h_mm / 2;
    uint32_t n = j->first[k + 1] - j->first[k];
    const uint32_t *tri = j->tris + j->first[k];
    if (!mem_grow((void **)segs, cap, n ? n : 1, sizeof(struct seg)))
        return SF_ENOMEM;
    struct seg *s = *segs;
    uint32_t ns = 0;
    for (uint32_t i = 0; i < n; i++) {
        const uint32_t *t = m->t[tri[i]];
        bool up[3];
        for (int c = 0; c < 3; c++)
            up[c] = m->v[t[c]].z >= p - LAYERS_ON_PLANE_MM;
        int e_ab = -1, e_ba = -1; /* edge going above->below, below->above */
        for (int c = 0; c < 3; c++) {
            int d = (c + 1) % 3;
            if (up[c] && !up[d])
                e_ab = c;
            else if (!up[c] && up[d])
                e_ba = c;
        }
        if (e_ab < 0 || e_ba < 0)
            continue;
        uint32_t a0 = t[e_ab], a1 = t[(e_ab + 1) % 3], b0 = t[e_ba], b1 = t[(e_ba + 1) % 3];
        struct seg *g = &s[ns++];
        g->a = cross_pt(m, a0, a1, p, j->out->dx, j->out->dy);
        g->b = cross_pt(m, b0, b1, p, j->out->dx, j->out->dy);
        g->ka0 = a0 < a1 ? a0 : a1;
        g->ka1 = a0 < a1 ? a1 : a0;
        g->kb0 = b0 < b1 ? b0 : b1;
        g->kb1 = b0 < b1 ? b1 : b0;
    }
    int rc = SF_ENOMEM;
    struct map by_edge = { 0 }, by_pt = { 0 };
    uint32_t *next = mem_array(ns ? ns : 1, sizeof(*next));
    uint8_t *has_prev = mem_calloc(ns ? ns : 1, 1);
    uint8_t *used = mem_calloc(ns ? ns : 1, 1);
    struct paths loops, open;
    paths_init(&loops);
    paths_init(&open);
    if (!next || !has_prev || !used || !map_init(&by_edge, ns) || !map_init(&by_pt, ns))
        goto out;
    for (uint32_t i = 0; i < ns; i++)
        map_put(&by_edge, s[i].ka0, s[i].ka1, i);
    for (uint32_t i = 0; i < ns; i++) {
        next[i] = map_get(&by_edge, s[i].kb0, s[i].kb1);
        if (next[i] != UINT32_MAX) {
            if (has_prev[next[i]])
                next[i] = UINT32_MAX; /* non-manifold edge: leave for the point pass */
            else
                has_prev[next[i]] = 1;
        }
    }
    /* Point pass: join loose ends at exactly equal points. */
    for (uint32_t i = 0; i < ns; i++)
        if (!has_prev[i])
            map_put(&by_pt, s[i].a.x, s[i].a.y, i);
    for (uint32_t i = 0; i < ns; i++) {
        if (next[i] != UINT32_MAX)
            continue;
        uint32_t t = map_get(&by_pt, s[i].b.x, s[i].b.y);
        if (t != UINT32_MAX && !has_prev[t]) {
            next[i] = t;
            has_prev[t] = 1;
        }
    }
    for (int pass = 0; pass < 2; pass++) {
        for (uint32_t i = 0; i < ns; i++) {
            if (used[i] || (pass == 0 && has_prev[i]))
                continue;
            uint32_t c = i;
            bool closed = false;
            struct paths *dst = &loops;
            if (pass == 0) { /* a chain with a loose start: open */
                dst = &open;
            } else { /* in a cycle: closed */
                closed = true;
            }
            if (!paths_begin(dst))
                goto out;
            while (c != UINT32_MAX && !used[c]) {
                used[c] = 1;
                if (!paths_push(dst, s[c].a))
                    goto out;
                if (next[c] == UINT32_MAX && !paths_push(dst, s[c].b))
                    goto out;
                c = next[c];
            }
            if (closed && paths_len(dst, dst->n - 1) < 3)
                dst->n--; /* a lone segment encloses nothing */
        }
    }
    uint32_t n_open = 0;
    if (open.n && !close_gaps(&open, LAYERS_GAP_MAX_MM, &loops, &n_open))
        goto out;
    atomic_fetch_add(&j->n_open, n_open);
    rc = clip_bool(CLIP_UNION, &loops, NULL, CLIP_NONZERO, &L->region);
    /* 10 um: far below what a 0.4 mm nozzle draws, and dense meshes give
       loops with 0.05 mm segments that would slow every later stage */
    if (rc == SF_OK && !paths_simplify(&L->region, LAYERS_SIMPLIFY_MM))
        rc = SF_ENOMEM;
out:
    paths_release(&loops);
    paths_release(&open);
    map_release(&by_edge);
    map_release(&by_pt);
    free(next);
    free(has_prev);
    free(used);
    return rc;
}

/* par_for body: layers [begin, end), with the worker's segment buffer. */
static int
slice_layers(void *ud, uint32_t begin, uint32_t end, int worker)
{
    struct job *j = ud;
    struct scratch *w = &j->scratch[worker];
    for (uint32_t k = begin; k < end; k++) {
        int rc = slice_one(j, k, &w->segs, &w->cap);
        if (rc < 0)
            return rc;
    }
    return SF_OK;
}

/* Plane height of layer k above the bed. */
static double
plane_of(const struct layer_stack *s, uint32_t k)
{
    return s->l[k].z_mm - s->l[k].h_mm / 2;
}

/* out->l: n layers from first_mm up, layer_mm apart, each initialised;
   out->n stops at the first whose plane is at or above height (at least
   one).  SF_ENOMEM. */
static int
plan_layers(struct layer_stack *out, uint32_t n, double first_mm, double layer_mm, double height)
{
    out->l = mem_calloc(n, sizeof(*out->l));
    if (!out->l)
        return SF_ENOMEM;
    uint32_t k = 0;
    for (; k < n; k++) {
        out->l[k].h_mm = k ? layer_mm : first_mm;
        out->l[k].z_mm = first_mm + k * layer_mm;
        paths_init(&out->l[k].region);
        paths_init(&out->l[k].inner);
        for (int e = 0; e < LAYER_MORE_MAX; e++)
            paths_init(&out->l[k].more[e]);
        paths_init(&out->l[k].skin);
        paths_init(&out->l[k].skin_bottom);
        paths_init(&out->l[k].small);
        paths_init(&out->l[k].top_in);
        paths_init(&out->l[k].solid);
        paths_init(&out->l[k].top);
        paths_init(&out->l[k].sparse);
        out->l[k].has_regions = false;
        if (plane_of(out, k) >= height)
            break;
    }
    out->n = k ? k : 1;
    return SF_OK;
}

/* The layers [r[0], r[1]) whose plane p satisfies z0 < p <= z1 (z from
   the part's bottom). */
static void
layer_range(const struct layer_stack *out, double z0, double z1, double first_mm, double layer_mm,
            uint32_t r[2])
{
    /* first k with plane > z0, last k with plane <= z1 */
    double f = (z0 - first_mm) / layer_mm + 0.5;
    long a = z0 < first_mm / 2 ? 0 : (long)floor(f) + 1;
    if (a < 0)
        a = 0;
    if (a > (long)out->n) /* above the last plane (a top face): an empty range */
        a = out->n;
    while (a > 0 && plane_of(out, (uint32_t)a - 1) > z0)
        a--;
    while ((uint32_t)a < out->n && plane_of(out, (uint32_t)a) <= z0)
        a++;
    long b = a;
    double g = (z1 - first_mm) / layer_mm + 0.5;
    if (z1 >= first_mm / 2 && (long)floor(g) + 1 > b)
        b = (long)floor(g) + 1;
    if (b > (long)out->n)
        b = out->n;
    while (b > a && plane_of(out, (uint32_t)b - 1) > z1)
        b--;
    while ((uint32_t)b < out->n && plane_of(out, (uint32_t)b) <= z1)
        b++;
    r[0] = (uint32_t)a;
    r[1] = (uint32_t)b; /* exclusive */
}

/* Bucket triangles by the layers whose plane p satisfies zmin < p <= zmax:
   *first (out->n + 1 offsets into *tris; both free, also on an error).
   SF_ENOMEM. */
static int
bucket_tris(const struct mesh *m, const struct layer_stack *out, double zmin, double first_mm,
            double layer_mm, uint32_t **first_out, uint32_t **tris_out)
{
    uint32_t *first = mem_calloc((size_t)out->n + 1, sizeof(*first));
    uint32_t(*range)[2] = mem_array(m->n_tris, sizeof(*range));
    *first_out = first;
    *tris_out = NULL;
    if (!first || !range) {
        free(range);
        return SF_ENOMEM;
    }
    size_t total = 0;
    for (uint32_t i = 0; i < m->n_tris; i++) {
        double z0 = m->v[m->t[i][0]].z, z1 = z0;
        for (int c = 1; c < 3; c++) {
            z0 = fmin(z0, m->v[m->t[i][c]].z);
            z1 = fmax(z1, m->v[m->t[i][c]].z);
        }
        /* a top within LAYERS_ON_PLANE_MM below a plane reaches it */
        z0 -= zmin;
        z1 -= zmin - LAYERS_ON_PLANE_MM;
        layer_range(out, z0, z1, first_mm, layer_mm, range[i]);
        for (uint32_t q = range[i][0]; q < range[i][1]; q++)
            first[q + 1]++;
        total += range[i][1] - range[i][0];
    }
    for (uint32_t q = 0; q < out->n; q++)
        first[q + 1] += first[q];
    uint32_t *tris = mem_array(total ? total : 1, sizeof(*tris));
    uint32_t *fill = mem_array(out->n, sizeof(*fill));
    *tris_out = tris;
    if (!tris || !fill) {
        free(fill);
        free(range);
        return SF_ENOMEM;
    }
    memcpy(fill, first, out->n * sizeof(*fill));
    for (uint32_t i = 0; i < m->n_tris; i++)
        for (uint32_t q = range[i][0]; q < range[i][1]; q++)
            tris[fill[q]++] = i;
    free(fill);
    free(range);
    return SF_OK;
}

/* Cut every layer of out on the par_for threads (first, tris: the
   triangles of each layer, bucket_tris).  SF_ENOMEM / SF_EBUG. */
static int
slice_all(const struct mesh *m, struct layer_stack *out, const uint32_t *first,
          const uint32_t *tris, double zmin)
{
    int n_work = par_threads();
    struct job j = { .m = m, .out = out, .first = first, .tris = tris, .zmin = zmin };
    j.scratch = mem_calloc((size_t)n_work, sizeof(*j.scratch));
    if (!j.scratch)
        return SF_ENOMEM;
    atomic_init(&j.n_open, 0);
    int rc = par_for(out->n, 1, 0, slice_layers, &j);
    for (int w = 0; w < n_work; w++)
        free(j.scratch[w].segs);
    free(j.scratch);
    out->n_open = atomic_load(&j.n_open);
    return rc;
}

int
layers_slice(const struct mesh *m, double first_mm, double layer_mm, double cx, double cy,
             struct layer_stack *out, struct sf_err *err)
{
    memset(out, 0, sizeof(*out));
    if (!m->n_tris)
        return sf_err_set(err, SF_EINVAL, "slice: the mesh has no triangles");
    struct vec3 lo = m->v[m->t[0][0]], hi = lo;
    for (uint32_t i = 0; i < m->n_tris; i++)
        for (int c = 0; c < 3; c++) {
            struct vec3 p = m->v[m->t[i][c]];
            if (!v3_isfinite(p))
                return sf_err_set(err, SF_EINVAL, "slice: triangle %u has a non-finite vertex", i);
            lo = v3_min(lo, p);
            hi = v3_max(hi, p);
        }
    double height = hi.z - lo.z;
    if (height <= 0)
        return sf_err_set(err, SF_EINVAL, "slice: the mesh is flat (height 0)");
    double nl = ceil((height - first_mm / 2) / layer_mm + 0.5);
    if (nl < 1)
        nl = 1;
    if (nl > SF_SLICE_LAYERS_MAX)
        return sf_err_set(err, SF_EINVAL, "slice: %.0f layers exceed the cap of %u", nl,
                          SF_SLICE_LAYERS_MAX);
    /* drop layers whose plane is at or above the top */
    if (plan_layers(out, (uint32_t)nl, first_mm, layer_mm, height) < 0)
        return sf_err_set(err, SF_ENOMEM, "slice: out of memory");
    out->cx_mm = cx;
    out->cy_mm = cy;
    out->dx = cx - (lo.x + hi.x) / 2;
    out->dy = cy - (lo.y + hi.y) / 2;
    out->dz = -lo.z;

    uint32_t *first, *tris;
    int rc = bucket_tris(m, out, lo.z, first_mm, layer_mm, &first, &tris);
    if (rc == SF_OK)
        rc = slice_all(m, out, first, tris, lo.z);
    free(first);
    free(tris);
    if (rc < 0) {
        layer_stack_release(out);
        return sf_err_set(err, rc == SF_EBUG ? SF_EBUG : SF_ENOMEM, "slice: %s",
                          rc == SF_EBUG ? "polygon clipping failed" : "out of memory");
    }
    return SF_OK;
}

void
layer_stack_release(struct layer_stack *s)
{
    for (uint32_t k = 0; s->l && k < s->n; k++) {
        paths_release(&s->l[k].region);
        paths_release(&s->l[k].inner);
        for (int e = 0; e < LAYER_MORE_MAX; e++)
            paths_release(&s->l[k].more[e]);
        paths_release(&s->l[k].skin);
        paths_release(&s->l[k].skin_bottom);
        paths_release(&s->l[k].small);
        paths_release(&s->l[k].top_in);
        paths_release(&s->l[k].solid);
        paths_release(&s->l[k].top);
        paths_release(&s->l[k].sparse);
    }
    free(s->l);
    memset(s, 0, sizeof(*s));
}
