/*
 * poly.c - flat integer polygon sets (see poly.h).
 *
 * Two growable arrays and a handful of measures.  Areas use the shoelace
 * formula in double on coordinates relative to the path's first point, so
 * large offsets lose no precision.  Point-in-polygon is the winding number
 * (nonzero), counted with exact integer orientation tests.
 *
 * Thread: none of its own; a set belongs to one thread at a time.
 */
#include "poly.h"

#include <math.h>
#include <string.h>

#include "../src/base/mem.h"

void
paths_init(struct paths *p)
{
    memset(p, 0, sizeof(*p));
}

void
paths_release(struct paths *p)
{
    free(p->pts);
    free(p->start);
    paths_init(p);
}

void
paths_reset(struct paths *p)
{
    p->n = 0;
    if (p->start)
        p->start[0] = 0;
}

static bool
reserve_paths(struct paths *p, uint32_t need)
{
    if (p->start && need <= p->cap_paths)
        return true;
    size_t cap = p->cap_paths ? p->cap_paths : 8;
    while (cap < need)
        cap *= 2;
    uint32_t *s = mem_realloc_array(p->start, cap + 1, sizeof(*s));
    if (!s)
        return false;
    if (!p->start)
        s[0] = 0;
    p->start = s;
    p->cap_paths = (uint32_t)cap;
    return true;
}

static bool
reserve_pts(struct paths *p, size_t need)
{
    if (need <= p->cap_pts)
        return true;
    size_t cap = p->cap_pts;
    if (need < 64)
        need = 64;
    if (!mem_grow((void **)&p->pts, &cap, need, sizeof(struct ipt)))
        return false;
    p->cap_pts = cap;
    return true;
}

bool
paths_add(struct paths *p, const struct ipt *pts, uint32_t n)
{
    if (!paths_begin(p))
        return false;
    size_t at = p->start[p->n - 1];
    if (!reserve_pts(p, at + n)) {
        p->n--;
        return false;
    }
    if (n)
        memcpy(p->pts + at, pts, n * sizeof(*pts));
    p->start[p->n] = (uint32_t)(at + n);
    return true;
}

bool
paths_begin(struct paths *p)
{
    if (!reserve_paths(p, p->n + 1))
        return false;
    p->start[p->n + 1] = p->start[p->n];
    p->n++;
    return true;
}

bool
paths_push(struct paths *p, struct ipt pt)
{
    size_t at = p->start[p->n];
    if (!reserve_pts(p, at + 1))
        return false;
    p->pts[at] = pt;
    p->start[p->n] = (uint32_t)(at + 1);
    return true;
}

bool
paths_append(struct paths *dst, const struct paths *src)
{
    for (uint32_t k = 0; k < src->n; k++)
        if (!paths_add(dst, src->pts + src->start[k], paths_len(src, k)))
            return false;
    return true;
}

void
paths_move(struct paths *dst, struct paths *src)
{
    paths_release(dst);
    *dst = *src;
    paths_init(src);
}

double
paths_area_k(const struct paths *p, uint32_t k)
{
    const struct ipt *q = p->pts + p->start[k];
    uint32_t n = paths_len(p, k);
    if (n < 3)
        return 0;
    double a = 0;
    int64_t x0 = q[0].x, y0 = q[0].y;
    for (uint32_t i = 1; i + 1 < n; i++) {
        double ax = (double)(q[i].x - x0), ay = (double)(q[i].y - y0);
        double bx = (double)(q[i + 1].x - x0), by = (double)(q[i + 1].y - y0);
        a += ax * by - ay * bx;
    }
    return a / (2.0 * POLY_SCALE * POLY_SCALE);
}

double
paths_area(const struct paths *p)
{
    double a = 0;
    for (uint32_t k = 0; k < p->n; k++)
        a += paths_area_k(p, k);
    return a;
}

double
paths_length_k(const struct paths *p, uint32_t k, bool closed)
{
    const struct ipt *q = p->pts + p->start[k];
    uint32_t n = paths_len(p, k);
    double l = 0;
    for (uint32_t i = 1; i < n; i++)
        l += hypot((double)(q[i].x - q[i - 1].x), (double)(q[i].y - q[i - 1].y));
    if (closed && n > 2)
        l += hypot((double)(q[0].x - q[n - 1].x), (double)(q[0].y - q[n - 1].y));
    return l / POLY_SCALE;
}

/* What edge a->b adds to the winding number about q: +1 crossing q's
   level upward with q on its left, -1 downward with q on its right. */
static long
wind_step(struct ipt a, struct ipt b, struct ipt q)
{
    /* orientation of q against a->b, in long double to avoid overflow */
    long double cr =
        (long double)(b.x - a.x) * (q.y - a.y) - (long double)(q.x - a.x) * (b.y - a.y);
    if (a.y <= q.y)
        return b.y > q.y && cr > 0 ? 1 : 0;
    return b.y <= q.y && cr < 0 ? -1 : 0;
}

/* Winding number of path k about q. */
static long
winding_k(const struct paths *p, uint32_t k, struct ipt q)
{
    long wind = 0;
    const struct ipt *v = p->pts + p->start[k];
    uint32_t n = paths_len(p, k);
    for (uint32_t i = 0; i < n; i++) {
        struct ipt a = v[i], b = v[i + 1 < n ? i + 1 : 0];
        wind += wind_step(a, b, q);
    }
    return wind;
}

bool
paths_contains(const struct paths *p, struct ipt q)
{
    long wind = 0;
    for (uint32_t k = 0; k < p->n; k++)
        wind += winding_k(p, k, q);
    return wind != 0;
}

static uint32_t
band_of(const struct paths_index *ix, int64_t y)
{
    if (y < ix->y0)
        return 0;
    uint64_t b = (uint64_t)(y - ix->y0) / (uint64_t)ix->band_h;
    return b >= ix->n_bands ? ix->n_bands - 1 : (uint32_t)b;
}

uint32_t
band_of_index(const struct paths_index *ix, int64_t y)
{
    return band_of(ix, y);
}

bool
paths_index_init(struct paths_index *ix, const struct paths *p)
{
    memset(ix, 0, sizeof(*ix));
    ix->pts = p->pts;
    struct ipt lo, hi;
    size_t n_edges = p->n ? p->start[p->n] : 0;
    if (!paths_bbox(p, &lo, &hi))
        lo = hi = (struct ipt){ 0, 0 };
    ix->y0 = lo.y;
    ix->n_bands = n_edges / 4 > 1024 ? 1024 : (uint32_t)(n_edges / 4) + 1;
    ix->band_h = (hi.y - lo.y) / ix->n_bands + 1;
    ix->first = mem_calloc((size_t)ix->n_bands + 1, sizeof(*ix->first));
    uint32_t *fill = mem_array(ix->n_bands, sizeof(*fill));
    if (!ix->first || !fill) {
        free(fill);
        paths_index_release(ix);
        return false;
    }
    size_t total = 0;
    for (int pass = 0; pass < 2; pass++) {
        for (uint32_t k = 0; k < p->n; k++) {
            uint32_t s0 = p->start[k], n = paths_len(p, k);
            for (uint32_t i = 0; i < n; i++) {
                uint32_t a = s0 + i, b = s0 + (i + 1 < n ? i + 1 : 0);
                int64_t ya = p->pts[a].y, yb = p->pts[b].y;
                uint32_t b0 = band_of(ix, ya < yb ? ya : yb), b1 = band_of(ix, ya < yb ? yb : ya);
                for (uint32_t bb = b0; bb <= b1; bb++) {
                    if (pass == 0) {
                        ix->first[bb + 1]++;
                        total++;
                    } else {
                        ix->edges[fill[bb]][0] = a;
                        ix->edges[fill[bb]++][1] = b;
                    }
                }
            }
        }
        if (pass == 0) {
            for (uint32_t bb = 0; bb < ix->n_bands; bb++)
                ix->first[bb + 1] += ix->first[bb];
            memcpy(fill, ix->first, ix->n_bands * sizeof(*fill));
            ix->edges = mem_array(total ? total : 1, sizeof(*ix->edges));
            if (!ix->edges) {
                free(fill);
                paths_index_release(ix);
                return false;
            }
        }
    }
    free(fill);
    return true;
}

void
paths_index_release(struct paths_index *ix)
{
    free(ix->first);
    free(ix->edges);
    ix->first = NULL;
    ix->edges = NULL;
}

bool
paths_index_contains(const struct paths_index *ix, struct ipt q)
{
    if (!ix->first)
        return false;
    uint32_t bb = band_of(ix, q.y);
    long wind = 0;
    for (uint32_t e = ix->first[bb]; e < ix->first[bb + 1]; e++) {
        struct ipt a = ix->pts[ix->edges[e][0]], b = ix->pts[ix->edges[e][1]];
        wind += wind_step(a, b, q);
    }
    return wind != 0;
}

static int
orient(struct ipt a, struct ipt b, struct ipt c)
{
    long double v = (long double)(b.x - a.x) * (c.y - a.y) - (long double)(b.y - a.y) * (c.x - a.x);
    return v > 0 ? 1 : v < 0 ? -1 : 0;
}

static bool
on_seg(struct ipt a, struct ipt b, struct ipt c) /* c on a-b, given collinear */
{
    return c.x >= (a.x < b.x ? a.x : b.x) && c.x <= (a.x < b.x ? b.x : a.x) &&
           c.y >= (a.y < b.y ? a.y : b.y) && c.y <= (a.y < b.y ? b.y : a.y);
}

bool
paths_index_crosses(const struct paths_index *ix, struct ipt a, struct ipt b)
{
    if (!ix->first)
        return false;
    uint32_t b0 = band_of(ix, a.y < b.y ? a.y : b.y), b1 = band_of(ix, a.y < b.y ? b.y : a.y);
    for (uint32_t bb = b0; bb <= b1; bb++) {
        for (uint32_t e = ix->first[bb]; e < ix->first[bb + 1]; e++) {
            struct ipt c = ix->pts[ix->edges[e][0]], d = ix->pts[ix->edges[e][1]];
            int o1 = orient(a, b, c), o2 = orient(a, b, d), o3 = orient(c, d, a),
                o4 = orient(c, d, b);
            if (o1 != o2 && o3 != o4)
                return true;
            if ((!o1 && on_seg(a, b, c)) || (!o2 && on_seg(a, b, d)) || (!o3 && on_seg(c, d, a)) ||
                (!o4 && on_seg(c, d, b)))
                return true;
        }
    }
    return false;
}

bool
paths_bbox(const struct paths *p, struct ipt *lo, struct ipt *hi)
{
    size_t n = p->n ? p->start[p->n] : 0;
    if (!n)
        return false;
    *lo = *hi = p->pts[0];
    for (size_t i = 1; i < n; i++) {
        struct ipt q = p->pts[i];
        if (q.x < lo->x)
            lo->x = q.x;
        if (q.y < lo->y)
            lo->y = q.y;
        if (q.x > hi->x)
            hi->x = q.x;
        if (q.y > hi->y)
            hi->y = q.y;
    }
    return true;
}

/* Squared distance from q to segment a-b, in units^2. */
static double
seg_dist2(struct ipt q, struct ipt a, struct ipt b)
{
    double dx = (double)(b.x - a.x), dy = (double)(b.y - a.y);
    double px = (double)(q.x - a.x), py = (double)(q.y - a.y);
    double l2 = dx * dx + dy * dy;
    double t = l2 > 0 ? (px * dx + py * dy) / l2 : 0;
    t = t < 0 ? 0 : t > 1 ? 1 : t;
    double ex = px - t * dx, ey = py - t * dy;
    return ex * ex + ey * ey;
}

/* Mark keep[] for q[a..b] (a and b kept) by Douglas-Peucker; stack holds pairs. */
static void
dp_range(const struct ipt *q, uint32_t a, uint32_t b, double tol2, uint8_t *keep, uint32_t *stack)
{
    uint32_t sp = 0;
    stack[sp++] = a;
    stack[sp++] = b;
    while (sp) {
        uint32_t hi = stack[--sp], lo = stack[--sp];
        double best = tol2;
        uint32_t at = 0;
        for (uint32_t i = lo + 1; i < hi; i++) {
            double d = seg_dist2(q[i], q[lo], q[hi]);
            if (d > best)
                best = d, at = i;
        }
        if (at) {
            keep[at] = 1;
            stack[sp++] = lo;
            stack[sp++] = at;
            stack[sp++] = at;
            stack[sp++] = hi;
        }
    }
}

bool
paths_simplify(struct paths *p, double tol_mm)
{
    uint32_t maxn = 0;
    for (uint32_t k = 0; k < p->n; k++)
        if (paths_len(p, k) > maxn)
            maxn = paths_len(p, k);
    if (!maxn)
        return true;
    /* the path is closed: work on pts 0..n (n = pts[0] again) */
    uint8_t *keep = mem_alloc((size_t)maxn + 1);
    uint32_t *stack = mem_array(4 * ((size_t)maxn + 1), sizeof(*stack));
    struct ipt *q = mem_array((size_t)maxn + 1, sizeof(*q));
    if (!keep || !stack || !q) {
        free(keep);
        free(stack);
        free(q);
        return false;
    }
    double tol2 = tol_mm * POLY_SCALE * tol_mm * POLY_SCALE;
    size_t w = 0;
    uint32_t nk = 0;
    uint32_t s1 = p->start[0];
    for (uint32_t k = 0; k < p->n; k++) {
        /* read the original bounds before this iteration rewrites start[] */
        uint32_t s0 = s1;
        s1 = p->start[k + 1];
        uint32_t n = s1 - s0;
        memcpy(q, p->pts + s0, n * sizeof(*q));
        size_t begin = w;
        if (n >= 3) {
            /* anchors: point 0 and the point farthest from it */
            uint32_t far = 0;
            double fd = -1;
            for (uint32_t i = 1; i < n; i++) {
                double dx = (double)(q[i].x - q[0].x), dy = (double)(q[i].y - q[0].y);
                if (dx * dx + dy * dy > fd)
                    fd = dx * dx + dy * dy, far = i;
            }
            q[n] = q[0];
            memset(keep, 0, n + 1);
            keep[0] = keep[far] = 1;
            dp_range(q, 0, far, tol2, keep, stack);
            dp_range(q, far, n, tol2, keep, stack);
            for (uint32_t i = 0; i < n; i++)
                if (keep[i])
                    p->pts[w++] = q[i];
        }
        if (w - begin < 3) {
            w = begin;
            continue;
        }
        p->start[nk] = (uint32_t)begin;
        p->start[++nk] = (uint32_t)w;
    }
    p->n = nk;
    if (!nk && p->start)
        p->start[0] = 0;
    free(keep);
    free(stack);
    free(q);
    return true;
}
