/*
 * toolpath.c - perimeters, skins and infill of one layer (see toolpath.h).
 *
 * Everything is Clipper offsets and booleans on the layer's region and its
 * neighbours' (read-only), so layers can be built in any order and on any
 * thread.  Infill lines come from tp_fill_lines: a family of parallel
 * lines over the region's bounding box, clipped as open paths.
 *
 * Thread: reentrant; no state outside the arguments.
 */
#include "toolpath.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../src/base/err.h"
#include "../src/base/mem.h"
#include "../src/base/uf.h"
#include "clip_shim.h"

/* Gap pieces under this x nozzle^2 are not filled. */
#define GAP_MIN_AREA 0.1
/* The loops' grown outlines reach this much further when the gaps are cut
   out of the region: 1 um, more than the offsets' rounding. */
#define GAP_SAFETY_MM 0.001

const char *
tp_role_name(enum tp_role r)
{
    static const char *const names[ROLE_N] = {
        "Support material",   "Support material interface",
        "Perimeter",          "External perimeter",
        "Solid infill",       "Top solid infill",
        "Internal infill",    "Bridge infill",
        "Skirt/Brim",         "Gap fill",
        "Overhang perimeter",
    };
    return (unsigned)r < ROLE_N ? names[r] : "Custom";
}

void
layer_paths_init(struct layer_paths *lp)
{
    paths_init(&lp->p);
    lp->info = NULL;
    lp->cap_info = 0;
    lp->ovh = NULL;
    lp->cap_ovh = 0;
}

void
layer_paths_release(struct layer_paths *lp)
{
    paths_release(&lp->p);
    free(lp->info);
    free(lp->ovh);
    layer_paths_init(lp);
}

/* Make lp->ovh cover every point of lp->p (new ones 0); copy from
   src[0..n) at point `at` when src is given.  False on ENOMEM. */
static bool
ovh_fill(struct layer_paths *lp, size_t at, const uint8_t *src, size_t n)
{
    size_t np = lp->p.n ? lp->p.start[lp->p.n] : 0, old = lp->ovh ? lp->cap_ovh : 0;
    if (!mem_grow((void **)&lp->ovh, &lp->cap_ovh, np, 1))
        return false;
    if (lp->cap_ovh > old)
        memset(lp->ovh + old, 0, lp->cap_ovh - old);
    if (src)
        memcpy(lp->ovh + at, src, n);
    return true;
}

double
tp_spacing(double w_mm, double h_mm)
{
    return w_mm - h_mm * (1 - M_PI / 4);
}

/* Append every path of src with the same role. */
static int
add(struct layer_paths *lp, const struct paths *src, enum tp_role role, bool closed, double w)
{
    for (uint32_t k = 0; k < src->n; k++) {
        uint32_t n = paths_len(src, k);
        if (n < (closed ? 3u : 2u))
            continue;
        if (lp->p.n + 1 > lp->cap_info) {
            size_t cap = lp->cap_info;
            if (!mem_grow((void **)&lp->info, &cap, lp->p.n + 1, sizeof(*lp->info)))
                return SF_ENOMEM;
            lp->cap_info = (uint32_t)cap;
        }
        if (!paths_add(&lp->p, src->pts + src->start[k], n))
            return SF_ENOMEM;
        if (lp->ovh && !ovh_fill(lp, 0, NULL, 0))
            return SF_ENOMEM;
        struct tp_info *i = &lp->info[lp->p.n - 1];
        i->role = (uint8_t)role;
        i->closed = closed;
        i->width_mm = (float)w;
    }
    return SF_OK;
}

/* Where a fill line crosses the region's boundary. */
struct xing {
    int64_t line; /* index of the line along the normal */
    double t;     /* position along it, units */
    int w;        /* +1 / -1: the edge's direction across the lines */
};

static int
cmp_xing(const void *x, const void *y)
{
    const struct xing *p = x, *q = y;
    if (p->line != q->line)
        return p->line < q->line ? -1 : 1;
    return p->t < q->t ? -1 : p->t > q->t;
}

/*
 * Lines of one island (or any set) at angle_deg, spacing_mm apart, one
 * through org, cut to the region (nonzero rule) by a scanline: each edge
 * adds its crossings with the lines it spans (half-open in the normal
 * direction, so a vertex on a line counts once), and each line's sorted
 * crossings open and close its pieces by the winding they add.  The same
 * pieces as clipping the lines with Clipper, a fraction of the work.
 */
static int
fill_set(const struct paths *region, double angle_deg, double spacing_mm, const double org[2],
         struct paths *out)
{
    if (!region->n || spacing_mm <= 0)
        return SF_OK;
    double a = angle_deg * M_PI / 180, dx = cos(a), dy = sin(a);
    double nx = -dy, ny = dx; /* line normal */
    double sp = spacing_mm * POLY_SCALE;
    double oc = (org[0] * nx + org[1] * ny) * POLY_SCALE; /* a line runs through org */
    size_t np = region->start[region->n], cap = np + 16, n = 0;
    struct xing *x = mem_array(cap, sizeof(*x));
    if (!x)
        return SF_ENOMEM;
    int rc = SF_OK;
    for (uint32_t k = 0; k < region->n && rc == SF_OK; k++) {
        uint32_t s0 = region->start[k], m = paths_len(region, k);
        for (uint32_t i = 0; i < m; i++) {
            struct ipt p = region->pts[s0 + i], q = region->pts[s0 + (i + 1) % m];
            double op = (double)p.x * nx + (double)p.y * ny,
                   oq = (double)q.x * nx + (double)q.y * ny;
            if (op == oq)
                continue;
            double lo = op < oq ? op : oq, hi = op < oq ? oq : op;
            double tp = (double)p.x * dx + (double)p.y * dy,
                   tq = (double)q.x * dx + (double)q.y * dy;
            for (int64_t l = (int64_t)ceil((lo - oc) / sp); oc + (double)l * sp < hi; l++) {
                if (n == cap && !mem_grow((void **)&x, &cap, n + 1, sizeof(*x))) {
                    rc = SF_ENOMEM;
                    break;
                }
                double o = oc + (double)l * sp;
                x[n++] =
                    (struct xing){ l, tp + (o - op) / (oq - op) * (tq - tp), oq > op ? 1 : -1 };
            }
        }
    }
    if (rc == SF_OK)
        qsort(x, n, sizeof(*x), cmp_xing);
    for (size_t i = 0; i < n && rc == SF_OK;) {
        size_t j = i;
        int w = 0;
        double t0 = 0;
        for (; j < n && x[j].line == x[i].line; j++) {
            int was = w;
            w += x[j].w;
            if (was == 0 && w != 0) {
                t0 = x[j].t;
            } else if (was != 0 && w == 0 && x[j].t > t0) {
                double o = oc + (double)x[i].line * sp;
                struct ipt seg[2] = {
                    { llround(o * nx + t0 * dx), llround(o * ny + t0 * dy) },
                    { llround(o * nx + x[j].t * dx), llround(o * ny + x[j].t * dy) },
                };
                if ((seg[0].x != seg[1].x || seg[0].y != seg[1].y) && !paths_add(out, seg, 2))
                    rc = SF_ENOMEM;
            }
        }
        i = j;
    }
    free(x);
    return rc;
}

int
tp_fill_lines(const struct paths *region, double angle_deg, double spacing_mm, double ox_mm,
              double oy_mm, struct paths *out)
{
    const double org[2] = { ox_mm, oy_mm };
    /* island by island: lines cover only their own island's box, so
       Clipper does not intersect every line with every sliver of a layer */
    struct paths isl;
    paths_init(&isl);
    int rc = SF_OK;
    for (uint32_t a = 0; a < region->n && rc == SF_OK;) {
        uint32_t b = a + 1;
        while (b < region->n && paths_area_k(region, b) < 0)
            b++;
        paths_reset(&isl);
        for (uint32_t k = a; k < b && rc == SF_OK; k++)
            if (!paths_add(&isl, region->pts + region->start[k], paths_len(region, k)))
                rc = SF_ENOMEM;
        if (rc == SF_OK)
            rc = fill_set(&isl, angle_deg, spacing_mm, org, out);
        a = b;
    }
    paths_release(&isl);
    return rc;
}

/* Squared distance between two points, in units^2. */
static double
d2(struct ipt a, struct ipt b)
{
    double dx = (double)(a.x - b.x), dy = (double)(a.y - b.y);
    return dx * dx + dy * dy;
}

static bool
link_inside(const struct paths_index *g, struct ipt a, struct ipt b)
{
    for (int i = 1; i <= 3; i++) {
        struct ipt q = { a.x + (b.x - a.x) * i / 4, a.y + (b.y - a.y) * i / 4 };
        if (!paths_index_contains(g, q))
            return false;
    }
    return true;
}

/* Endpoints of a line set bucketed in square cells (CSR), for near-end queries. */
struct ends {
    int64_t x0, y0, cell;
    uint32_t nx, ny;
    uint32_t *first; /* nx*ny + 1 offsets into ids */
    uint32_t *ids;   /* 2 * line + (0: start, 1: end) */
};

static int
ends_build(struct ends *e, const struct paths *lines, double cell_mm)
{
    struct ipt lo, hi;
    memset(e, 0, sizeof(*e));
    if (!paths_bbox(lines, &lo, &hi))
        return SF_OK;
    e->cell = poly_i(cell_mm) > 0 ? poly_i(cell_mm) : 1;
    e->x0 = lo.x;
    e->y0 = lo.y;
    uint64_t nx = (uint64_t)((hi.x - lo.x) / e->cell) + 1,
             ny = (uint64_t)((hi.y - lo.y) / e->cell) + 1;
    while (nx * ny > 4u * lines->n + 64) { /* keep the table small: coarser cells */
        e->cell *= 2;
        nx = (uint64_t)((hi.x - lo.x) / e->cell) + 1;
        ny = (uint64_t)((hi.y - lo.y) / e->cell) + 1;
    }
    e->nx = (uint32_t)nx;
    e->ny = (uint32_t)ny;
    e->first = mem_calloc(nx * ny + 1, sizeof(*e->first));
    e->ids = mem_array(2 * (size_t)lines->n, sizeof(*e->ids));
    uint32_t *fill = mem_array(nx * ny, sizeof(*fill));
    if (!e->first || !e->ids || !fill) {
        free(fill);
        return SF_ENOMEM;
    }
    for (int pass = 0; pass < 2; pass++) {
        for (uint32_t k = 0; k < 2 * lines->n; k++) {
            uint32_t l = k / 2;
            struct ipt q = lines->pts[k % 2 ? lines->start[l + 1] - 1 : lines->start[l]];
            size_t c =
                (size_t)((q.y - e->y0) / e->cell) * e->nx + (size_t)((q.x - e->x0) / e->cell);
            if (pass == 0)
                e->first[c + 1]++;
            else
                e->ids[fill[c]++] = k;
        }
        if (pass == 0) {
            for (size_t c = 0; c < nx * ny; c++)
                e->first[c + 1] += e->first[c];
            memcpy(fill, e->first, nx * ny * sizeof(*fill));
        }
    }
    free(fill);
    return SF_OK;
}

static void
ends_release(struct ends *e)
{
    free(e->first);
    free(e->ids);
}

int
tp_link(struct paths *lines, const struct paths *region, double link_max_mm, double grow_mm)
{
    uint32_t n = lines->n;
    if (n < 2)
        return SF_OK;
    struct paths g, out;
    struct ends e = { 0 };
    paths_init(&g);
    paths_init(&out);
    uint8_t *used = mem_calloc(n, 1);
    int rc = used ? ends_build(&e, lines, link_max_mm) : SF_ENOMEM;
    if (rc == SF_OK)
        rc = clip_offset(region, grow_mm, CLIP_JOIN_MITER, &g);
    struct paths_index gi = { 0 };
    if (rc == SF_OK && !paths_index_init(&gi, &g))
        rc = SF_ENOMEM;
    double lim2 = link_max_mm * POLY_SCALE * link_max_mm * POLY_SCALE;
    for (uint32_t s0 = 0; s0 < n && rc == SF_OK; s0++) {
        if (used[s0])
            continue;
        used[s0] = 1;
        const struct ipt *q = lines->pts + lines->start[s0];
        uint32_t m = paths_len(lines, s0);
        if (!paths_begin(&out)) {
            rc = SF_ENOMEM;
            break;
        }
        for (uint32_t i = 0; i < m && rc == SF_OK; i++)
            if (!paths_push(&out, q[i]))
                rc = SF_ENOMEM;
        struct ipt end = q[m - 1];
        for (;;) {
            /* the nearest free line end, if close enough and the link stays inside */
            double best = lim2;
            uint32_t bk = UINT32_MAX;
            bool brev = false;
            long cx = (long)((end.x - e.x0) / e.cell), cy = (long)((end.y - e.y0) / e.cell);
            for (long y = cy - 1; y <= cy + 1; y++) {
                for (long x = cx - 1; x <= cx + 1; x++) {
                    if (x < 0 || y < 0 || x >= (long)e.nx || y >= (long)e.ny)
                        continue;
                    size_t c = (size_t)y * e.nx + (size_t)x;
                    for (uint32_t i = e.first[c]; i < e.first[c + 1]; i++) {
                        uint32_t id = e.ids[i], k = id / 2;
                        if (used[k])
                            continue;
                        struct ipt r =
                            lines->pts[id % 2 ? lines->start[k + 1] - 1 : lines->start[k]];
                        double d = d2(end, r);
                        if (d < best || (d == best && k < bk))
                            best = d, bk = k, brev = id % 2;
                    }
                }
            }
            if (bk == UINT32_MAX)
                break;
            const struct ipt *r = lines->pts + lines->start[bk];
            uint32_t rm = paths_len(lines, bk);
            if (!link_inside(&gi, end, brev ? r[rm - 1] : r[0]))
                break;
            used[bk] = 1;
            for (uint32_t i = 0; i < rm && rc == SF_OK; i++)
                if (!paths_push(&out, brev ? r[rm - 1 - i] : r[i]))
                    rc = SF_ENOMEM;
            end = brev ? r[0] : r[rm - 1];
        }
    }
    if (rc == SF_OK)
        paths_move(lines, &out);
    free(used);
    paths_index_release(&gi);
    ends_release(&e);
    paths_release(&g);
    paths_release(&out);
    return rc;
}

/* Where a line end sits on the region's boundary. */
struct bpos {
    uint32_t line, end;  /* end 0: first point, 1: last */
    uint32_t path, a, b; /* boundary path and the edge's point indices (global) */
    double s;            /* arc length from the path's first point, mm */
};

static int
cmp_bpos(const void *x, const void *y)
{
    const struct bpos *p = x, *q = y;
    if (p->path != q->path)
        return p->path < q->path ? -1 : 1;
    if (p->s != q->s)
        return p->s < q->s ? -1 : 1;
    return p->line != q->line ? (p->line < q->line ? -1 : 1) : (int)p->end - (int)q->end;
}

static double
dist_mm(struct ipt a, struct ipt b)
{
    return hypot((double)(a.x - b.x), (double)(a.y - b.y)) / POLY_SCALE;
}

/* Points of the walk along the boundary from pos (at point from) for len
   mm, forward (the path's order) or back, excluding the start. */
static bool
walk(const struct paths *r, const struct bpos *pos, struct ipt from, double len, bool back,
     struct paths *out)
{
    uint32_t s0 = r->start[pos->path], n = paths_len(r, pos->path);
    uint32_t v = back ? pos->a : pos->b;
    struct ipt cur = from;
    for (uint32_t steps = 0; steps <= n && len > 1e-6; steps++) {
        struct ipt nx = r->pts[v];
        double d = dist_mm(cur, nx);
        if (d >= len) {
            double t = len / d;
            struct ipt q = { cur.x + (int64_t)llround((double)(nx.x - cur.x) * t),
                             cur.y + (int64_t)llround((double)(nx.y - cur.y) * t) };
            return paths_push(out, q);
        }
        if (d > 0 && !paths_push(out, nx))
            return false;
        len -= d;
        cur = nx;
        v = s0 + (back ? v - s0 + n - 1 : v - s0 + 1) % n;
    }
    return true;
}

/* An arc between two neighbouring line ends on one boundary path. */
struct arc {
    uint32_t i; /* index in the sorted ends; the arc runs forward to its next */
    double len_mm;
};

static int
cmp_arc(const void *x, const void *y)
{
    const struct arc *p = x, *q = y;
    if (p->len_mm != q->len_mm)
        return p->len_mm < q->len_mm ? -1 : 1;
    return p->i < q->i ? -1 : p->i > q->i;
}

/* What happens at one line end (index in the sorted ends). */
struct end_use {
    int32_t to;       /* the end it is joined to along the boundary, -1 none */
    double len_mm;    /* the joining arc, or the stub's length (0: none) */
    uint8_t back;     /* the arc or stub runs against the path's order */
    uint8_t consumed; /* joined or anchored (PrusaSlicer's "consumed") */
};

int
tp_anchor(struct paths *lines, const struct paths *region, double len_mm, double max_mm,
          double half_w_mm)
{
    uint32_t n = lines->n;
    if (!n || !region->n || (len_mm <= 0 && max_mm <= 0))
        return SF_OK;
    struct paths_index ix = { 0 };
    struct paths out, stub;
    paths_init(&out);
    paths_init(&stub);
    size_t np = region->start[region->n];
    double *cum = mem_array(np + 1, sizeof(*cum));
    uint32_t *path_of = mem_array(np + 1, sizeof(*path_of));
    struct bpos *bp = mem_array(2 * (size_t)n, sizeof(*bp));
    int32_t *slot = mem_array(2 * (size_t)n, sizeof(*slot)); /* (line, end) -> index in bp or -1 */
    uint32_t *nx = mem_array(2 * (size_t)n, sizeof(*nx)),
             *pv = mem_array(2 * (size_t)n, sizeof(*pv));
    double *gap = mem_array(2 * (size_t)n, sizeof(*gap)); /* forward to nx, mm */
    /* boundary not yet taken forward and back from each end, mm */
    double *free_fw = mem_array(2 * (size_t)n, sizeof(*free_fw));
    double *free_bk = mem_array(2 * (size_t)n, sizeof(*free_bk));
    struct end_use *use = mem_calloc(2 * (size_t)n, sizeof(*use));
    struct arc *arcs = mem_array(2 * (size_t)n, sizeof(*arcs));
    uint32_t *uf = mem_array(n, sizeof(*uf));
    uint8_t *done = mem_calloc(n, 1);
    int rc = cum && path_of && bp && slot && nx && pv && gap && free_fw && free_bk && use && arcs &&
                     uf && done && paths_index_init(&ix, region)
                 ? SF_OK
                 : SF_ENOMEM;
    if (rc < 0)
        goto out;
    for (uint32_t k = 0; k < region->n; k++) {
        double c = 0;
        for (uint32_t i = region->start[k]; i < region->start[k + 1]; i++) {
            cum[i] = c;
            path_of[i] = k;
            uint32_t j = i + 1 < region->start[k + 1] ? i + 1 : region->start[k];
            c += dist_mm(region->pts[i], region->pts[j]);
        }
    }
    /* locate every line end on its boundary edge */
    size_t nb = 0;
    for (uint32_t l = 0; l < n; l++) {
        uf[l] = l;
        for (uint32_t e = 0; e < 2; e++) {
            slot[2 * l + e] = -1;
            struct ipt q = lines->pts[e ? lines->start[l + 1] - 1 : lines->start[l]];
            uint32_t band = band_of_index(&ix, q.y);
            double best = 4.0; /* units^2: Clipper rounds intersections to the unit */
            uint32_t ba = 0, bb = 0;
            bool found = false;
            for (uint32_t i = ix.first[band]; i < ix.first[band + 1]; i++) {
                struct ipt a = ix.pts[ix.edges[i][0]], b = ix.pts[ix.edges[i][1]];
                double dx = (double)(b.x - a.x), dy = (double)(b.y - a.y);
                double px = (double)(q.x - a.x), py = (double)(q.y - a.y);
                double l2 = dx * dx + dy * dy, t = l2 > 0 ? (px * dx + py * dy) / l2 : 0;
                t = t < 0 ? 0 : t > 1 ? 1 : t;
                double ex = px - t * dx, ey = py - t * dy, d = ex * ex + ey * ey;
                if (d <= best) {
                    best = d;
                    ba = ix.edges[i][0];
                    bb = ix.edges[i][1];
                    found = true;
                }
            }
            if (!found)
                continue;
            struct bpos *p = &bp[nb];
            p->line = l;
            p->end = e;
            p->path = path_of[ba];
            p->a = ba;
            p->b = bb;
            p->s = cum[ba] + dist_mm(region->pts[ba], q);
            nb++;
        }
    }
    qsort(bp, nb, sizeof(*bp), cmp_bpos);
    /* neighbours along each boundary path and the arcs between them */
    size_t n_arcs = 0;
    for (size_t g0 = 0, g1; g0 < nb; g0 = g1) {
        uint32_t k = bp[g0].path;
        for (g1 = g0 + 1; g1 < nb && bp[g1].path == k;)
            g1++;
        uint32_t last = region->start[k + 1] - 1;
        double per = cum[last] + dist_mm(region->pts[last], region->pts[region->start[k]]);
        for (size_t i = g0; i < g1; i++) {
            nx[i] = (uint32_t)(i + 1 < g1 ? i + 1 : g0);
            pv[i] = (uint32_t)(i > g0 ? i - 1 : g1 - 1);
            gap[i] = nx[i] == i ? per : bp[nx[i]].s - bp[i].s;
            if (gap[i] < 0)
                gap[i] += per;
            if (nx[i] != i)
                arcs[n_arcs++] = (struct arc){ (uint32_t)i, gap[i] };
        }
        for (size_t i = g0; i < g1; i++) {
            free_fw[i] = gap[i];
            free_bk[i] = gap[pv[i]];
        }
    }
    for (size_t i = 0; i < nb; i++) {
        use[i].to = -1;
        slot[2 * bp[i].line + bp[i].end] = (int32_t)i;
    }
    /* PrusaSlicer's connect_infill: the shortest arcs first, each joining
       two lines not yet joined (no loops) along the whole arc when it is
       shorter than max_mm; a longer one gives both ends a stub instead */
    qsort(arcs, n_arcs, sizeof(*arcs), cmp_arc);
    for (size_t a = 0; a < n_arcs; a++) {
        uint32_t i = arcs[a].i, j = nx[i];
        if (use[i].consumed || use[j].consumed)
            continue;
        uint32_t li = uf_find(uf, bp[i].line), lj = uf_find(uf, bp[j].line);
        if (li == lj)
            continue;
        if (arcs[a].len_mm < max_mm) {
            use[i] = (struct end_use){ (int32_t)j, arcs[a].len_mm, 0, 1 };
            use[j] = (struct end_use){ (int32_t)i, arcs[a].len_mm, 1, 1 };
            free_fw[i] = free_bk[j] = 0;
            uf[lj] = li;
            continue;
        }
        /* stubs toward each other, each stopping half a line short of the other's */
        double t = fmax(0, fmin(fmin(len_mm, free_fw[i]), gap[i] - half_w_mm));
        use[i] = (struct end_use){ -1, t, 0, 1 };
        free_bk[j] = fmin(free_bk[j], gap[i] - t);
        t = fmax(0, fmin(fmin(len_mm, free_bk[j]), gap[i] - half_w_mm));
        use[j] = (struct end_use){ -1, t, 1, 1 };
        free_fw[i] = fmin(free_fw[i], gap[i] - t);
    }
    /* the ends left: a stub toward the side with more boundary free, in
       line order (PrusaSlicer's order) */
    for (uint32_t k = 0; k < 2 * n && len_mm > 0; k++) {
        int32_t i = slot[k];
        if (i < 0 || use[i].consumed)
            continue;
        bool back = free_bk[i] > free_fw[i];
        uint32_t j = back ? pv[i] : nx[i];
        double g = back ? gap[pv[i]] : gap[i];
        double t = fmax(0, fmin(fmin(len_mm, back ? free_bk[i] : free_fw[i]), g - half_w_mm));
        use[i] = (struct end_use){ -1, t, back, 1 };
        if ((uint32_t)i != j) {
            if (back)
                free_fw[j] = fmin(free_fw[j], g - t);
            else
                free_bk[j] = fmin(free_bk[j], g - t);
        }
    }
    /* chains: from a line with a free end (no cycles: every chain has
       two), its stub reversed, the line, then arc, line, ..., stub */
    for (uint32_t l0 = 0; l0 < n && rc == SF_OK; l0++) {
        if (done[l0])
            continue;
        int32_t s0 = slot[2 * l0], s1 = slot[2 * l0 + 1];
        uint32_t e0; /* the end the chain starts at */
        if (s0 < 0 || use[s0].to < 0)
            e0 = 0;
        else if (s1 < 0 || use[s1].to < 0)
            e0 = 1;
        else
            continue; /* inside a chain: reached from its ends */
        if (!paths_begin(&out)) {
            rc = SF_ENOMEM;
            break;
        }
        int32_t si = slot[2 * l0 + e0];
        if (si >= 0 && use[si].len_mm > 0) {
            struct ipt q = lines->pts[e0 ? lines->start[l0 + 1] - 1 : lines->start[l0]];
            paths_reset(&stub);
            if (!paths_begin(&stub) ||
                !walk(region, &bp[si], q, use[si].len_mm, use[si].back, &stub))
                rc = SF_ENOMEM;
            for (uint32_t i = rc == SF_OK ? paths_len(&stub, 0) : 0; i-- > 0;)
                if (!paths_push(&out, stub.pts[i]))
                    rc = SF_ENOMEM;
        }
        uint32_t l = l0, e = e0;
        while (rc == SF_OK) {
            done[l] = 1;
            const struct ipt *q = lines->pts + lines->start[l];
            uint32_t m = paths_len(lines, l);
            for (uint32_t i = 0; i < m && rc == SF_OK; i++) {
                struct ipt pt = q[e ? m - 1 - i : i];
                if (!paths_push(&out, pt))
                    rc = SF_ENOMEM;
            }
            int32_t sf = slot[2 * l + (1 - e)]; /* the far end */
            if (rc < 0 || sf < 0)
                break;
            struct ipt qe = q[e ? 0 : m - 1];
            if (!walk(region, &bp[sf], qe, use[sf].len_mm, use[sf].back, &out)) {
                rc = SF_ENOMEM;
                break;
            }
            if (use[sf].to < 0)
                break;
            const struct bpos *nxt = &bp[use[sf].to];
            l = nxt->line;
            e = nxt->end;
            if (done[l])
                break; /* cannot happen: no cycles */
        }
        /* drop points within 1 um of the one before (an arc's or stub's
           end on the next line's end): a zero-length move is not a move */
        uint32_t o = out.start[out.n - 1], w = o + 1;
        for (uint32_t i = o + 1; i < out.start[out.n]; i++)
            if (d2(out.pts[w - 1], out.pts[i]) >= 1e4)
                out.pts[w++] = out.pts[i];
        out.start[out.n] = w;
    }
    if (rc == SF_OK)
        paths_move(lines, &out);
out:
    paths_index_release(&ix);
    paths_release(&out);
    paths_release(&stub);
    free(cum);
    free(path_of);
    free(bp);
    free(slot);
    free(nx);
    free(pv);
    free(gap);
    free(free_fw);
    free(free_bk);
    free(use);
    free(arcs);
    free(uf);
    free(done);
    return rc;
}

/* out = intersection of the inner areas of layers [a, b); empty if the
   range leaves the stack (a surface is within reach). */
static int
intersect_range(const struct layer_stack *s, long a, long b, struct paths *out)
{
    paths_reset(out);
    if (a < 0 || b > (long)s->n)
        return SF_OK;
    struct paths tmp;
    paths_init(&tmp);
    if (!paths_append(out, &s->l[a].inner)) {
        paths_release(&tmp);
        return SF_ENOMEM;
    }
    int rc = SF_OK;
    for (long j = a + 1; j < b && rc == SF_OK && out->n; j++) {
        rc = clip_bool(CLIP_INTERSECTION, out, &s->l[j].inner, CLIP_NONZERO, &tmp);
        paths_move(out, &tmp);
    }
    paths_release(&tmp);
    return rc;
}

/*
 * The skin of one surface a (the cross-section open to the air on one
 * side; a is used up): without slivers under a tenth of a line wide, as
 * PrusaSlicer 2.5 finds top and bottom surfaces (detect_surfaces_type:
 * opening by the external perimeter width / 10), then kept where it
 * reaches the inner area, grown skin_margin into it.  The skin is that
 * grown part and the surface itself, perimeter zone included: projected
 * onto the layers within reach, a sloping surface's band lands inside
 * their inner areas (PrusaSlicer's discover_horizontal_shells projects
 * the slices' surfaces so).  b, c: scratch; reach (may be NULL) gets the
 * surface's part in the inner area appended.
 */
static int
skin_of(struct paths *a, const struct paths *inner, const struct slice_profile *p, struct paths *b,
        struct paths *c, struct paths *out, struct paths *reach)
{
    paths_reset(out);
    paths_reset(c);
    if (!a->n)
        return SF_OK;
    double open = p->width_mm / 10;
    int rc = clip_offset(a, -open, CLIP_JOIN_MITER, b);
    if (rc < 0 || !b->n)
        return rc;
    if ((rc = clip_offset(b, open, CLIP_JOIN_MITER, a)) < 0)
        return rc;
    if ((rc = clip_bool(CLIP_INTERSECTION, a, inner, CLIP_NONZERO, b)) < 0)
        return rc;
    if (reach && !paths_append(reach, b))
        return SF_ENOMEM;
    if (b->n && (rc = clip_offset(b, p->skin_margin_mm, CLIP_JOIN_SQUARE, c)) < 0)
        return rc;
    paths_reset(b);
    if (c->n && (rc = clip_bool(CLIP_INTERSECTION, c, inner, CLIP_NONZERO, b)) < 0)
        return rc;
    if (!paths_append(b, a))
        return SF_ENOMEM;
    return b->n ? clip_bool(CLIP_UNION, b, NULL, CLIP_NONZERO, out) : SF_OK;
}

/* Append to out the pieces (an outer and its holes) of set whose area,
   grown grow_mm all round, is at most lim_mm2 (above: at least).  The
   grown area is the area plus grow_mm x the perimeter (Steiner's formula,
   without its grow^2 term). */
static int
pieces_by_area(const struct paths *set, double lim_mm2, double grow_mm, bool above,
               struct paths *out)
{
    for (uint32_t a = 0, b; a < set->n; a = b) {
        double area = paths_area_k(set, a);
        if (grow_mm > 0)
            area += grow_mm * paths_length_k(set, a, true);
        for (b = a + 1; b < set->n && paths_area_k(set, b) < 0; b++)
            area += paths_area_k(set, b) + grow_mm * paths_length_k(set, b, true);
        if (above ? area < lim_mm2 : area > lim_mm2)
            continue;
        for (uint32_t j = a; j < b; j++)
            if (!paths_add(out, set->pts + set->start[j], paths_len(set, j)))
                return SF_ENOMEM;
    }
    return SF_OK;
}

int
toolpath_areas(struct layer_stack *s, uint32_t k, const struct slice_profile *p)
{
    struct layer *L = &s->l[k];
    double sp = tp_spacing(p->width_mm, L->h_mm);
    paths_reset(&L->inner);
    paths_reset(&L->skin);
    paths_reset(&L->skin_bottom);
    paths_reset(&L->small);
    paths_reset(&L->top_in);
    int rc;
    if (p->perimeters > 0)
        rc = clip_offset(&L->region, -(p->width_mm / 2 + (p->perimeters - 1) * sp + sp / 2),
                         CLIP_JOIN_MITER, &L->inner);
    else
        rc = paths_append(&L->inner, &L->region) ? SF_OK : SF_ENOMEM;
    if (rc < 0 || !L->inner.n)
        return rc;
    /* the seeds of the skins: the cross-section open to the air above
       (top) and below (bottom), each its own skin, since a top surface
       thickens the layers under it and a bottom surface those over it,
       never the other way (PrusaSlicer's discover_horizontal_shells; one
       skin for both put solid under every overhang and over every top) */
    struct paths a, b, c, seeds;
    paths_init(&a);
    paths_init(&b);
    paths_init(&c);
    paths_init(&seeds);
    for (int side = 0; side < 2 && rc == SF_OK; side++) {
        struct paths *out = side ? &L->skin_bottom : &L->skin;
        long nb = side ? (long)k - 1 : (long)k + 1;
        if (nb >= 0 && nb < (long)s->n)
            rc = clip_bool(CLIP_DIFFERENCE, &L->region, &s->l[nb].region, CLIP_NONZERO, &a);
        else
            rc = paths_append(&a, &L->region) ? SF_OK : SF_ENOMEM;
        if (rc == SF_OK)
            rc = skin_of(&a, &L->inner, p, &b, &c, out, side ? &seeds : &L->top_in);
        paths_reset(&a);
    }
    if (rc == SF_OK && !paths_append(&seeds, &L->top_in))
        rc = SF_ENOMEM;
    if (rc == SF_OK && p->solid_below_mm2 > 0 && p->infill_density > 0) {
        /* the inner area away from this layer's own top and bottom
           surfaces, piece by piece: pieces no larger than
           solid_infill_below_area print solid (PrusaSlicer's
           prepare_fill_surfaces, which sees the internal surfaces before
           the skins of other layers are projected onto them, so a big
           island that the skins cut into small pieces stays sparse; its
           surfaces reach infill_overlap into the loops, so do ours here) */
        const struct paths *in = &L->inner; /* seeds: the surfaces' parts in it */
        if (seeds.n) {
            rc = clip_bool(CLIP_DIFFERENCE, &L->inner, &seeds, CLIP_NONZERO, &b);
            in = &b;
        }
        if (rc == SF_OK)
            rc = pieces_by_area(in, p->solid_below_mm2, p->infill_overlap * sp, false, &L->small);
    }
    paths_release(&a);
    paths_release(&b);
    paths_release(&c);
    paths_release(&seeds);
    return rc;
}

/* Islands beyond this print role by role across the layer (the grouping is
   islands x paths point-in-polygon tests). */
#define ISLANDS_MAX 64

/*
 * Reorder the part's paths island by island (support stays first), keeping
 * the role order within an island, so the nozzle finishes one island
 * before travelling to the next instead of visiting every island once per
 * role.  Islands are visited nearest-first from the first one.
 */
static int
group_by_island(const struct paths *region, struct layer_paths *lp)
{
    uint32_t outers[ISLANDS_MAX], n_isl = 0;
    for (uint32_t k = 0; k < region->n; k++) {
        if (paths_area_k(region, k) <= 0)
            continue;
        if (n_isl == ISLANDS_MAX)
            return SF_OK;
        outers[n_isl++] = k;
    }
    if (n_isl < 2 || lp->p.n < 2)
        return SF_OK;
    int rc = SF_ENOMEM;
    uint8_t *isl = mem_array(lp->p.n, 1);
    struct paths outline[ISLANDS_MAX];
    struct paths_index ix[ISLANDS_MAX];
    double area[ISLANDS_MAX], cx[ISLANDS_MAX], cy[ISLANDS_MAX];
    uint32_t n_ix = 0;
    struct layer_paths out;
    layer_paths_init(&out);
    for (uint32_t i = 0; i < n_isl; i++)
        paths_init(&outline[i]);
    if (!isl)
        goto fail;
    for (; n_ix < n_isl; n_ix++) {
        uint32_t k = outers[n_ix];
        struct ipt lo, hi;
        if (!paths_add(&outline[n_ix], region->pts + region->start[k], paths_len(region, k)) ||
            !paths_index_init(&ix[n_ix], &outline[n_ix]))
            goto fail;
        paths_bbox(&outline[n_ix], &lo, &hi);
        cx[n_ix] = poly_mm(lo.x / 2 + hi.x / 2);
        cy[n_ix] = poly_mm(lo.y / 2 + hi.y / 2);
        area[n_ix] = paths_area_k(region, k);
    }
    /* each part path belongs to the smallest island outline containing its first point */
    for (uint32_t k = 0; k < lp->p.n; k++) {
        isl[k] = 0xff;
        if (tp_role_is_support(lp->info[k].role))
            continue;
        struct ipt q = lp->p.pts[lp->p.start[k]];
        double best = INFINITY;
        for (uint32_t i = 0; i < n_isl; i++)
            if (area[i] < best && paths_index_contains(&ix[i], q))
                best = area[i], isl[k] = (uint8_t)i;
        if (isl[k] == 0xff)
            isl[k] = 0; /* on an outline exactly: any island will do */
    }
    /* support first, then islands nearest-first */
    bool done[ISLANDS_MAX] = { false };
    double x = cx[0], y = cy[0];
    for (int pass = -1; pass < (int)n_isl; pass++) {
        uint32_t pick = 0xff;
        if (pass >= 0) {
            double bd = INFINITY;
            for (uint32_t i = 0; i < n_isl; i++) {
                double d = hypot(cx[i] - x, cy[i] - y);
                if (!done[i] && d < bd)
                    bd = d, pick = i;
            }
            done[pick] = true;
            x = cx[pick];
            y = cy[pick];
        }
        for (uint32_t k = 0; k < lp->p.n; k++) {
            bool sup = tp_role_is_support(lp->info[k].role);
            if (pass < 0 ? !sup : (sup || isl[k] != pick))
                continue;
            if (out.p.n + 1 > out.cap_info) {
                size_t cap = out.cap_info;
                if (!mem_grow((void **)&out.info, &cap, out.p.n + 1, sizeof(*out.info)))
                    goto fail;
                out.cap_info = (uint32_t)cap;
            }
            if (!paths_add(&out.p, lp->p.pts + lp->p.start[k], paths_len(&lp->p, k)))
                goto fail;
            if (lp->ovh && !ovh_fill(&out, out.p.start[out.p.n - 1], lp->ovh + lp->p.start[k],
                                     paths_len(&lp->p, k)))
                goto fail;
            out.info[out.p.n - 1] = lp->info[k];
        }
    }
    layer_paths_release(lp);
    *lp = out;
    layer_paths_init(&out);
    rc = SF_OK;
fail:
    for (uint32_t i = 0; i < n_ix; i++)
        paths_index_release(&ix[i]);
    for (uint32_t i = 0; i < n_isl; i++)
        paths_release(&outline[i]);
    layer_paths_release(&out);
    free(isl);
    return rc;
}

enum {
    T_AREA,
    T_TMP,
    T_TOPI,
    T_BOTI,
    T_KEEP,
    T_SOLID,
    T_TOP,
    T_SPARSE,
    T_LINES,
    T_GAP,
    T_S,
    T_C,
    T_BELOW,
    T_N
};

/*
 * The direction of a bridge over piece: PrusaSlicer's BridgeDetector
 * idea.  Every 10 degrees, lines across the piece; the angle whose lines
 * have the most length anchored at both ends (an end within a nozzle
 * width of the layer below) wins, and of angles within 1 % of that, the
 * one whose longest anchored line is shortest: the shortest span between
 * anchors.
 */
static double
bridge_angle(const struct paths *piece, const struct paths_index *below, double spacing,
             const double org[2], struct paths *lines, int *rc)
{
    double best_cov = -1, best_max = INFINITY, best = 0;
    double cov[18], mx[18];
    for (int a = 0; a < 18; a++) {
        paths_reset(lines);
        cov[a] = 0;
        mx[a] = 0;
        if ((*rc = tp_fill_lines(piece, a * 10.0, spacing, org[0], org[1], lines)) < 0)
            return 0;
        for (uint32_t i = 0; i < lines->n; i++) {
            uint32_t n = paths_len(lines, i);
            const struct ipt *q = lines->pts + lines->start[i];
            if (paths_index_contains(below, q[0]) && paths_index_contains(below, q[n - 1])) {
                double l = paths_length_k(lines, i, false);
                cov[a] += l;
                mx[a] = fmax(mx[a], l);
            }
        }
        best_cov = fmax(best_cov, cov[a]);
    }
    for (int a = 0; a < 18; a++)
        if (cov[a] >= 0.99 * best_cov && mx[a] < best_max)
            best_max = mx[a], best = a * 10.0;
    return best;
}

/* Bridge lines over each piece of area (one outer and its holes), in
   the piece's own direction (bridge_angle) over the layer below. */
static int
bridges(const struct paths *area, const struct paths *below, double nz, const double org[2],
        struct layer_paths *out, struct paths *grown, struct paths *lines, struct paths *piece)
{
    struct paths_index ix;
    int rc = clip_offset(below, nz, CLIP_JOIN_MITER, grown);
    if (rc < 0)
        return rc;
    if (!paths_index_init(&ix, grown))
        return SF_ENOMEM;
    for (uint32_t k = 0; k < area->n && rc == SF_OK;) {
        uint32_t e = k + 1;
        while (e < area->n && paths_area_k(area, e) < 0)
            e++;
        paths_reset(piece);
        for (uint32_t i = k; i < e; i++)
            if (!paths_add(piece, area->pts + area->start[i], paths_len(area, i)))
                rc = SF_ENOMEM;
        k = e;
        double ang = rc == SF_OK ? bridge_angle(piece, &ix, nz + 0.05, org, lines, &rc) : 0;
        paths_reset(lines);
        if (rc == SF_OK)
            rc = tp_fill_lines(piece, ang, nz + 0.05, org[0], org[1], lines);
        if (rc == SF_OK)
            rc = tp_link(lines, piece, 2 * (nz + 0.05), nz / 2);
        if (rc == SF_OK)
            rc = add(out, lines, ROLE_BRIDGE, false, nz);
    }
    paths_index_release(&ix);
    return rc;
}

/* Move the pieces (outer and holes) of set narrower than t_mm (2 area /
   perimeter) to narrow; tmp is scratch. */
static int
split_narrow(struct paths *set, double t_mm, struct paths *narrow, struct paths *tmp)
{
    paths_reset(tmp);
    bool moved = false;
    for (uint32_t k = 0; k < set->n;) {
        uint32_t e = k + 1;
        while (e < set->n && paths_area_k(set, e) < 0)
            e++;
        double area = 0, per = 0;
        for (uint32_t i = k; i < e; i++) {
            area += paths_area_k(set, i);
            per += paths_length_k(set, i, true);
        }
        bool thin = per > 0 && 2 * area / per < t_mm;
        moved |= thin;
        for (uint32_t i = k; i < e; i++)
            if (!paths_add(thin ? narrow : tmp, set->pts + set->start[i], paths_len(set, i)))
                return SF_ENOMEM;
        k = e;
    }
    if (moved) {
        paths_reset(set);
        if (!paths_append(set, tmp))
            return SF_ENOMEM;
    }
    return SF_OK;
}

/* The vertex of q farthest from q[from]. */
static uint32_t
farthest(const struct ipt *q, uint32_t n, uint32_t from)
{
    uint32_t best = from;
    double bd = -1;
    for (uint32_t i = 0; i < n; i++) {
        double d = d2(q[i], q[from]);
        if (d > bd)
            bd = d, best = i;
    }
    return best;
}

/*
 * Gap fill and thin walls: every piece of gap (a region no perimeter loop
 * or infill reaches, narrower than two lines) gets one line along its
 * middle instead of nothing.  The middle is found by shrinking the piece
 * to a sliver by nearly half its mean width (2 area / perimeter); a sliver
 * with a hole (a thin ring) prints its outer loop, an open one the side
 * between its two far ends.  The line's width is set so the piece's area
 * is laid down whole (length x spacing = area): a fixed width per piece,
 * the classic generator's answer to what PrusaSlicer's Arachne does with
 * widths varying along the line.
 */
static int
gap_fill(const struct paths *gap, double h, double nozzle, double sp, double overlap,
         double min_bead, struct layer_paths *out, struct paths *piece, struct paths *sliver,
         struct paths *line)
{
    int rc = SF_OK;
    for (uint32_t k = 0; k < gap->n && rc == SF_OK;) {
        /* one outer and its holes (Clipper's tree order) */
        uint32_t e = k + 1;
        while (e < gap->n && paths_area_k(gap, e) < 0)
            e++;
        paths_reset(piece);
        double area = 0, per = 0;
        uint32_t k_first = k;
        for (uint32_t i = k; i < e; i++) {
            if (!paths_add(piece, gap->pts + gap->start[i], paths_len(gap, i)))
                return SF_ENOMEM;
            area += paths_area_k(gap, i);
            per += paths_length_k(gap, i, true);
        }
        k = e;
        if (area < GAP_MIN_AREA * nozzle * nozzle || per <= 0)
            continue;
        double t = 2 * area / per;
        /* an infill piece at least min_bead_width wide is infill in
           PrusaSlicer too, grown infill_overlap into the loops around it
           (bonding): lay that band as well.  Narrower leftovers are what
           Arachne's beads absorb, without overlap. */
        double fill = overlap > 0 && t >= min_bead ? area + overlap * per : area;
        /* wider than 1.5 spacings: two lines, the loop a quarter width in */
        bool two = t > 1.5 * sp;
        /* a short piece (a corner's gap, a stub of wall) is one straight
           line between its far ends: no offsets for the many small ones */
        const struct ipt *o = piece->pts;
        uint32_t no = paths_len(piece, 0), fa = farthest(o, no, 0), fb = farthest(o, no, fa);
        double dia = sqrt(d2(o[fa], o[fb])) / POLY_SCALE;
        if (!two && e == k_first + 1 && dia < 3) {
            struct ipt seg[2] = { o[fa], o[fb] };
            /* the line's ends sit half a width in from the piece's ends */
            double len = dia - t > 0.1 * dia ? dia - t : 0.1 * dia;
            double dx = (double)(o[fb].x - o[fa].x) / (dia * POLY_SCALE),
                   dy = (double)(o[fb].y - o[fa].y) / (dia * POLY_SCALE);
            double cut = (dia - len) / 2 * POLY_SCALE;
            seg[0].x += (int64_t)llround(dx * cut);
            seg[0].y += (int64_t)llround(dy * cut);
            seg[1].x -= (int64_t)llround(dx * cut);
            seg[1].y -= (int64_t)llround(dy * cut);
            paths_reset(line);
            if (!paths_add(line, seg, 2))
                return SF_ENOMEM;
            double wl = fill / len + h * (1 - M_PI / 4);
            rc = add(out, line, ROLE_GAP_FILL, false, wl < 2.5 * nozzle ? wl : 2.5 * nozzle);
            continue;
        }
        paths_reset(sliver);
        for (double f = two ? 0.25 : 0.45; f > 0.1 && !sliver->n && rc == SF_OK; f -= 0.15)
            rc = clip_offset(piece, -f * t, CLIP_JOIN_MITER, sliver);
        if (rc < 0 || !sliver->n)
            continue;
        paths_reset(line);
        bool ring = two;
        for (uint32_t i = 0; i < sliver->n; i++)
            ring |= paths_area_k(sliver, i) < 0;
        double len = 0;
        for (uint32_t i = 0; i < sliver->n; i++) {
            const struct ipt *q = sliver->pts + sliver->start[i];
            uint32_t n = paths_len(sliver, i);
            if (paths_area_k(sliver, i) < 0 && !two)
                continue;
            if (ring) {
                if (!paths_add(line, q, n))
                    return SF_ENOMEM;
                len += paths_length_k(sliver, i, true);
                continue;
            }
            uint32_t a = farthest(q, n, 0), b = farthest(q, n, a);
            if (!paths_begin(line))
                return SF_ENOMEM;
            for (uint32_t j = a;; j = (j + 1) % n) {
                if (!paths_push(line, q[j]))
                    return SF_ENOMEM;
                if (j == b)
                    break;
            }
            len += paths_length_k(line, line->n - 1, false);
        }
        if (len < 1e-3)
            continue;
        double wl = fill / len + h * (1 - M_PI / 4);
        if (wl > 2.5 * nozzle)
            wl = 2.5 * nozzle;
        rc = add(out, line, ROLE_GAP_FILL, ring, wl);
    }
    return rc;
}

int
toolpath_regions(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
                 struct paths *solid, struct paths *top, struct paths *sparse)
{
    const struct layer *L = &s->l[k];
    double ssp = tp_spacing(p->solid_width_mm, L->h_mm);
    struct paths t[T_N];
    for (int i = 0; i < T_N; i++)
        paths_init(&t[i]);
    paths_reset(solid);
    paths_reset(top);
    paths_reset(sparse);
    int rc = SF_OK;
#define TRY(x)                                                                                     \
    do {                                                                                           \
        if ((rc = (x)) < 0)                                                                        \
            goto out;                                                                              \
    } while (0)
    if (!paths_append(&t[T_AREA], &L->inner))
        TRY(SF_ENOMEM);
    if (!t[T_AREA].n)
        goto out;
    if (p->vertical_shells) {
        /* solid wherever the inner areas of the top_layers above and the
           bottom_layers below do not all cover it: keeps the shell thick
           on slopes (PrusaSlicer's ensure_vertical_shell_thickness, off by
           default and in the peers' runs) */
        TRY(intersect_range(s, (long)k + 1, (long)k + 1 + p->top_layers, &t[T_TOPI]));
        if (p->top_layers == 0 && !paths_append(&t[T_TOPI], &t[T_AREA]))
            TRY(SF_ENOMEM);
        TRY(intersect_range(s, (long)k - p->bottom_layers, (long)k, &t[T_BOTI]));
        if (p->bottom_layers == 0 && !paths_append(&t[T_BOTI], &t[T_AREA]))
            TRY(SF_ENOMEM);
        TRY(clip_bool(CLIP_INTERSECTION, &t[T_TOPI], &t[T_BOTI], CLIP_NONZERO, &t[T_KEEP]));
        TRY(clip_bool(CLIP_DIFFERENCE, &t[T_AREA], &t[T_KEEP], CLIP_NONZERO, &t[T_SOLID]));
    }
    {
        /* the top and bottom surfaces of the layers within reach (top_layers
           - 1 above, bottom_layers - 1 below, and this one), grown
           skin_margin into the infill: PrusaSlicer 2.5 grows them 3 mm
           (EXTERNAL_INFILL_MARGIN) and projects them so
           (discover_horizontal_shells) */
        paths_reset(&t[T_LINES]);
        for (long j = k; j < (long)k + p->top_layers && j < (long)s->n; j++)
            if (!paths_append(&t[T_LINES], &s->l[j].skin))
                TRY(SF_ENOMEM);
        for (long j = k; j > (long)k - p->bottom_layers && j >= 0; j--)
            if (!paths_append(&t[T_LINES], &s->l[j].skin_bottom))
                TRY(SF_ENOMEM);
        /* PrusaSlicer's infill areas reach infill_overlap into the loops
           (its fill_expolygons): a skin projected from a slope can end
           just inside them, short of the inner area, and its sliver there
           grows below into a band of solid along the slope */
        bool grown = !p->vertical_shells && p->infill_overlap > 0 && t[T_LINES].n;
        if (grown)
            TRY(clip_offset(&t[T_AREA], p->infill_overlap * tp_spacing(p->width_mm, L->h_mm),
                            CLIP_JOIN_MITER, &t[T_BELOW]));
        if (t[T_LINES].n) {
            /* one pass: under the nonzero rule the overlapping skins are
               their union, clipped to the area at once (a separate union
               of the stacked skins first cost 41 % of knot1's
               instructions, most of it joining their common edges) */
            if (!paths_append(&t[T_LINES], &t[T_SOLID]))
                TRY(SF_ENOMEM);
            TRY(clip_bool(CLIP_INTERSECTION, &t[T_LINES], grown ? &t[T_BELOW] : &t[T_AREA],
                          CLIP_NONZERO, &t[T_SOLID]));
        }
        if (!p->vertical_shells && t[T_SOLID].n) {
            /* bands narrower than 3 solid lines grow 3 lines wider, so
               the solid can be filled and holds (PrusaSlicer's "too
               narrow" regularization in discover_horizontal_shells) */
            double mg = 3 * p->solid_width_mm;
            TRY(clip_offset(&t[T_SOLID], -mg, CLIP_JOIN_MITER, &t[T_TMP]));
            TRY(clip_offset(&t[T_TMP], mg, CLIP_JOIN_MITER, &t[T_KEEP]));
            TRY(clip_bool(CLIP_DIFFERENCE, &t[T_SOLID], &t[T_KEEP], CLIP_NONZERO, &t[T_TMP]));
            if (t[T_TMP].n) {
                TRY(clip_offset(&t[T_TMP], mg, CLIP_JOIN_MITER, &t[T_LINES]));
                if (!paths_append(&t[T_LINES], &t[T_SOLID]))
                    TRY(SF_ENOMEM);
                TRY(clip_bool(CLIP_UNION, &t[T_LINES], NULL, CLIP_NONZERO, &t[T_TMP]));
                TRY(clip_bool(CLIP_INTERSECTION, &t[T_TMP], &t[T_AREA], CLIP_NONZERO, &t[T_SOLID]));
            } else if (grown) {
                TRY(clip_bool(CLIP_INTERSECTION, &t[T_SOLID], &t[T_AREA], CLIP_NONZERO, &t[T_TMP]));
                paths_move(&t[T_SOLID], &t[T_TMP]);
            }
            paths_reset(&t[T_KEEP]);
        }
    }
    if (t[T_SOLID].n && t[T_KEEP].n) {
        /* solid narrower than a line is a sliver along a slope, not a
           skin: drop it and grow the rest a little, as PrusaSlicer 2.5
           regularizes its vertical shells: offset2(-0.5 s, +0.8 s) with
           s = 1.05 x the solid line spacing (min_perimeter_infill_spacing
           in PrintObject::discover_vertical_shells) */
        double ms = 1.05 * ssp;
        TRY(clip_offset(&t[T_SOLID], -0.5 * ms, CLIP_JOIN_SQUARE, &t[T_TMP]));
        TRY(clip_offset(&t[T_TMP], 0.8 * ms, CLIP_JOIN_SQUARE, &t[T_LINES]));
        TRY(clip_bool(CLIP_INTERSECTION, &t[T_LINES], &t[T_AREA], CLIP_NONZERO, &t[T_SOLID]));
    }
    if (L->small.n && p->solid_below_mm2 > 0 && p->infill_density > 0) {
        /* internal pieces too small for the grid to hold anything print
           solid (solid_infill_below_area, 70 mm2: thin limbs, ears and
           tails; toolpath_areas found them) */
        paths_reset(&t[T_LINES]);
        if (!paths_append(&t[T_LINES], &L->small) || !paths_append(&t[T_LINES], &t[T_SOLID]))
            TRY(SF_ENOMEM);
        TRY(clip_bool(CLIP_UNION, &t[T_LINES], NULL, CLIP_NONZERO, &t[T_SOLID]));
    }
    TRY(clip_bool(CLIP_DIFFERENCE, &t[T_AREA], &t[T_SOLID], CLIP_NONZERO, &t[T_SPARSE]));
    if (p->top_layers > 0) {
        /* the solid on this layer's top surface (opened, as
           PrusaSlicer's detect_surfaces_type finds stTop) is top solid;
           most layers of a smooth part have none inside the loops */
        if (k + 1 < s->n) {
            if (L->top_in.n && t[T_SOLID].n) {
                TRY(clip_bool(CLIP_INTERSECTION, &t[T_SOLID], &L->top_in, CLIP_NONZERO, &t[T_TOP]));
                TRY(clip_bool(CLIP_DIFFERENCE, &t[T_SOLID], &L->top_in, CLIP_NONZERO, &t[T_TMP]));
                paths_move(&t[T_SOLID], &t[T_TMP]);
            }
        } else {
            paths_move(&t[T_TOP], &t[T_SOLID]);
        }
    }
    paths_move(solid, &t[T_SOLID]);
    paths_move(top, &t[T_TOP]);
    paths_move(sparse, &t[T_SPARSE]);
#undef TRY
out:
    for (int i = 0; i < T_N; i++)
        paths_release(&t[i]);
    return rc;
}

int
toolpath_store_regions(struct layer_stack *s, uint32_t k, const struct slice_profile *p)
{
    struct layer *L = &s->l[k];
    int rc = toolpath_regions(s, k, p, &L->solid, &L->top, &L->sparse);
    L->has_regions = rc == SF_OK;
    return rc;
}

/* The regions of layer k: kept ones copied, else computed. */
static int
regions_of(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
           struct paths *solid, struct paths *top, struct paths *sparse)
{
    const struct layer *L = &s->l[k];
    if (!L->has_regions)
        return toolpath_regions(s, k, p, solid, top, sparse);
    paths_reset(solid);
    paths_reset(top);
    paths_reset(sparse);
    return paths_append(solid, &L->solid) && paths_append(top, &L->top) &&
                   paths_append(sparse, &L->sparse)
               ? SF_OK
               : SF_ENOMEM;
}

/*
 * Internal bridges: solid infill laid straight over the sparse infill of
 * the layer below prints as bridge lines (nozzle-wide round threads at
 * bridge speed, as over air), since under it is mostly air between the
 * grid's lines: PrusaSlicer's bridge_over_infill.  Pieces narrower than 6
 * nozzle widths stay solid (its opening by 3 bridge widths).  The lines
 * keep the solid infill's direction.  solid loses what is bridged.
 */
static int
internal_bridges(struct paths *solid, const struct paths *below_sparse, double nz, double ang,
                 const double org[2], struct layer_paths *out, struct paths *t1, struct paths *t2,
                 struct paths *lines)
{
    int rc = clip_bool(CLIP_INTERSECTION, solid, below_sparse, CLIP_NONZERO, t1);
    if (rc < 0 || !t1->n)
        return rc;
    if ((rc = clip_offset(t1, -3 * nz, CLIP_JOIN_MITER, t2)) < 0 || !t2->n)
        return rc;
    if ((rc = clip_offset(t2, 3 * nz, CLIP_JOIN_MITER, t1)) < 0)
        return rc;
    if ((rc = clip_bool(CLIP_INTERSECTION, t1, solid, CLIP_NONZERO, t2)) < 0 || !t2->n)
        return rc;
    if ((rc = clip_bool(CLIP_DIFFERENCE, solid, t2, CLIP_NONZERO, t1)) < 0)
        return rc;
    paths_move(solid, t1);
    paths_reset(lines);
    if ((rc = tp_fill_lines(t2, ang, nz + 0.05, org[0], org[1], lines)) < 0)
        return rc;
    if ((rc = tp_link(lines, t2, 2 * (nz + 0.05), nz / 2)) < 0)
        return rc;
    return add(out, lines, ROLE_BRIDGE, false, nz);
}

/* Flags of q[a..b] (one segment, split to ~0.05 mm where it leaves
   below): append the points after a and their segments' flags. */
static bool
ovh_segment(const struct paths_index *below, struct ipt a, struct ipt b, bool in_a, bool in_b,
            struct paths *pts, uint8_t **fl, size_t *cap, size_t *n, int depth)
{
    if (in_a == in_b && !paths_index_crosses(below, a, b)) {
        if (!mem_grow((void **)fl, cap, *n + 1, 1) || !paths_push(pts, b))
            return false;
        (*fl)[(*n)++] = !in_a; /* the flag of the segment ending at b */
        return true;
    }
    if (depth == 0 || d2(a, b) < (double)poly_i(0.05) * (double)poly_i(0.05)) {
        struct ipt m = { a.x / 2 + b.x / 2, a.y / 2 + b.y / 2 };
        if (!mem_grow((void **)fl, cap, *n + 1, 1) || !paths_push(pts, b))
            return false;
        (*fl)[(*n)++] = !paths_index_contains(below, m);
        return true;
    }
    struct ipt m = { a.x / 2 + b.x / 2, a.y / 2 + b.y / 2 };
    bool in_m = paths_index_contains(below, m);
    return ovh_segment(below, a, m, in_a, in_m, pts, fl, cap, n, depth - 1) &&
           ovh_segment(below, m, b, in_m, in_b, pts, fl, cap, n, depth - 1);
}

/*
 * Overhang perimeters (PrusaSlicer's "overhangs": bridge flow, bridge
 * speed and fan): the segments of layer k's perimeter loops whose centre
 * line lies outside the layer below grown by half a nozzle, i.e. where
 * the whole nozzle width is over air.  Loops are rebuilt with a vertex
 * where they leave and re-enter that area; out gets the flags.
 */
static int
mark_overhangs(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
               struct layer_paths *out, struct paths *grown, struct paths *tmp)
{
    /* a loop's centre (at least half a line in) more than half a nozzle
       out from the layer below puts a disc that wide in the bottom
       surface, which its opening (a tenth of a line) keeps: no bottom
       skin, no overhang */
    if (k == 0 || !p->overhangs || !out->p.n || !s->l[k].skin_bottom.n)
        return SF_OK;
    int rc = clip_offset(&s->l[k - 1].region, p->nozzle_mm / 2, CLIP_JOIN_MITER, grown);
    if (rc < 0)
        return rc;
    struct paths_index below = { 0 };
    if (!paths_index_init(&below, grown))
        return SF_ENOMEM;
    struct layer_paths lp;
    layer_paths_init(&lp);
    uint8_t *fl = NULL;
    size_t cap = 0;
    bool any = false;
    rc = SF_OK;
    for (uint32_t k2 = 0; k2 < out->p.n && rc == SF_OK; k2++) {
        const struct tp_info *in = &out->info[k2];
        const struct ipt *q = out->p.pts + out->p.start[k2];
        uint32_t m = paths_len(&out->p, k2);
        size_t nf = 0;
        paths_reset(tmp);
        bool is_loop = in->closed && (in->role == ROLE_PERIMETER || in->role == ROLE_EXT_PERIMETER);
        bool hit = false;
        if (is_loop) {
            if (!paths_begin(tmp) || !paths_push(tmp, q[0]))
                rc = SF_ENOMEM;
            bool in0 = paths_index_contains(&below, q[0]), in_a = in0;
            for (uint32_t i = 0; i < m && rc == SF_OK; i++) {
                struct ipt b = q[(i + 1) % m];
                bool in_b = i + 1 < m ? paths_index_contains(&below, b) : in0;
                if (!ovh_segment(&below, q[i], b, in_a, in_b, tmp, &fl, &cap, &nf, 12))
                    rc = SF_ENOMEM;
                in_a = in_b;
            }
            for (size_t i = 0; i < nf; i++)
                hit |= fl[i];
        }
        if (rc < 0)
            break;
        if (lp.p.n + 1 > lp.cap_info) {
            size_t c = lp.cap_info;
            if (!mem_grow((void **)&lp.info, &c, lp.p.n + 1, sizeof(*lp.info))) {
                rc = SF_ENOMEM;
                break;
            }
            lp.cap_info = (uint32_t)c;
        }
        if (hit) {
            /* tmp holds q[0], the points after it and q[0] again: drop the
               last (the loop closes itself); flag i is of the segment
               from point i, so fl is already in place */
            uint32_t nt = paths_len(tmp, 0) - 1;
            if (!paths_add(&lp.p, tmp->pts, nt) || !ovh_fill(&lp, lp.p.start[lp.p.n - 1], fl, nt))
                rc = SF_ENOMEM;
            any = true;
        } else if (!paths_add(&lp.p, q, m) || (lp.ovh && !ovh_fill(&lp, 0, NULL, 0))) {
            rc = SF_ENOMEM;
        }
        if (rc == SF_OK)
            lp.info[lp.p.n - 1] = *in;
    }
    if (rc == SF_OK && any) {
        layer_paths_release(out);
        *out = lp;
        layer_paths_init(&lp);
    }
    free(fl);
    layer_paths_release(&lp);
    paths_index_release(&below);
    return rc;
}

int
toolpath_layer(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
               const struct support_layer *sup, struct layer_paths *out)
{
    const struct layer *L = &s->l[k];
    double h = L->h_mm, w = p->width_mm, sw = p->solid_width_mm;
    double sp = tp_spacing(w, h), ssp = tp_spacing(sw, h);
    /* the part's fills run on a grid through its bounding-box centre, as
       PrusaSlicer's (Fill::_infill_direction), so both line up on a part */
    const double org[2] = { s->cx_mm, s->cy_mm };
    struct paths t[T_N];
    for (int i = 0; i < T_N; i++)
        paths_init(&t[i]);
    int rc = SF_OK;
#define TRY(x)                                                                                     \
    do {                                                                                           \
        if ((rc = (x)) < 0)                                                                        \
            goto out;                                                                              \
    } while (0)

    /* support first: it is printed before the part it holds */
    if (sup && sup->body.n) {
        TRY(clip_offset(&sup->body, -sw / 2, CLIP_JOIN_MITER, &t[T_TMP]));
        TRY(add(out, &t[T_TMP], ROLE_SUPPORT, true, sw));
        paths_reset(&t[T_LINES]);
        /* the bed layer holds the columns down: 90 % dense, as PrusaSlicer prints it */
        double bsp = k == 0 ? ssp / 0.9 : p->support_spacing_mm;
        TRY(tp_fill_lines(&t[T_TMP], k % 2 ? 90 : 0, bsp, 0, 0, &t[T_LINES]));
        TRY(tp_link(&t[T_LINES], &t[T_TMP], 1.5 * bsp, sw / 2));
        TRY(add(out, &t[T_LINES], ROLE_SUPPORT, false, sw));
    }
    if (sup && sup->iface.n) {
        paths_reset(&t[T_LINES]);
        TRY(clip_offset(&sup->iface, -sw / 2, CLIP_JOIN_MITER, &t[T_TMP]));
        TRY(tp_fill_lines(&t[T_TMP], k % 2 ? 90 : 0, ssp, 0, 0, &t[T_LINES]));
        TRY(tp_link(&t[T_LINES], &t[T_TMP], 2 * ssp, sw / 2));
        TRY(add(out, &t[T_LINES], ROLE_INTERFACE, false, sw));
    }

    /*
     * Perimeters, inner loops first, external last.  Loop i's centre line
     * is opened by half a spacing (shrunk by that much more, grown back),
     * so a loop never wraps a sliver it cannot fill (it would lay two lines
     * where one fits), as PrusaSlicer's classic generator does.  What the
     * loops leave between them, the part's edge and the infill goes to
     * gap fill: S is the area inside loop i - 1 (the region for i = 0),
     * and the gap is the part of it loop i does not reach.
     */
    struct paths *loops = p->perimeters ? mem_calloc((size_t)p->perimeters, sizeof(*loops)) : NULL;
    if (p->perimeters && !loops)
        TRY(SF_ENOMEM);
    paths_reset(&t[T_GAP]);
    for (int i = 0; i < p->perimeters && rc == SF_OK; i++) {
        double d = w / 2 + i * sp;
        const struct paths *prev = i ? &t[T_S] : &L->region;
        paths_init(&loops[i]);
        /* the innermost loop's shrink is the inner area toolpath_areas made */
        if (i + 1 == p->perimeters) {
            paths_reset(&t[T_TMP]);
            if (!paths_append(&t[T_TMP], &L->inner)) {
                rc = SF_ENOMEM;
                break;
            }
        } else if ((rc = clip_offset(&L->region, -(d + sp / 2), CLIP_JOIN_MITER, &t[T_TMP])) < 0) {
            break;
        }
        if ((rc = clip_offset(&t[T_TMP], sp / 2, CLIP_JOIN_MITER, &loops[i])) < 0)
            break;
        if (p->gap_fill) {
            /* 1 um more: where the loop follows the edge, the offsets'
               rounding leaves no hairline for the difference to trace
               (PrusaSlicer's safety offset, for the same reason) */
            if ((rc = clip_offset(&loops[i], (i ? sp / 2 : w / 2) + GAP_SAFETY_MM, CLIP_JOIN_MITER,
                                  &t[T_LINES])) < 0 ||
                (rc = clip_bool(CLIP_DIFFERENCE, prev, &t[T_LINES], CLIP_NONZERO, &t[T_KEEP])) < 0)
                break;
            if (!paths_append(&t[T_GAP], &t[T_KEEP]))
                rc = SF_ENOMEM;
        }
        paths_move(&t[T_S], &t[T_TMP]);
    }
    for (int i = p->perimeters - 1; i >= 0; i--) {
        if (rc == SF_OK)
            rc = add(out, &loops[i], i ? ROLE_PERIMETER : ROLE_EXT_PERIMETER, true, w);
        paths_release(&loops[i]);
    }
    free(loops);
    if (rc < 0)
        goto out;
    if (t[T_GAP].n) {
        /* drop slivers under a quarter spacing wide (where the loops' bands
           meet at corners), then fill; pieces too small to fill go
           first (opening only shrinks them) */
        paths_reset(&t[T_TMP]);
        TRY(pieces_by_area(&t[T_GAP], GAP_MIN_AREA * p->nozzle_mm * p->nozzle_mm, 0, true,
                           &t[T_TMP]));
        paths_move(&t[T_GAP], &t[T_TMP]);
        TRY(clip_offset(&t[T_GAP], -sp / 8, CLIP_JOIN_MITER, &t[T_TMP]));
        TRY(clip_offset(&t[T_TMP], sp / 8, CLIP_JOIN_MITER, &t[T_GAP]));
        TRY(gap_fill(&t[T_GAP], h, p->nozzle_mm, sp, 0, 0, out, &t[T_TMP], &t[T_S], &t[T_LINES]));
    }
    if (!L->inner.n)
        goto out;
    TRY(regions_of(s, k, p, &t[T_SOLID], &t[T_TOP], &t[T_SPARSE]));
    if (p->gap_fill) {
        /* infill pieces under 3.5 spacings wide: zig-zag links would lay
           more than their area there, so they are gap-filled instead */
        paths_reset(&t[T_GAP]);
        struct paths *sets[3] = { &t[T_SOLID], &t[T_TOP], &t[T_SPARSE] };
        for (int i = 0; i < 3; i++)
            TRY(split_narrow(sets[i], 3.5 * ssp, &t[T_GAP], &t[T_TMP]));
        if (t[T_GAP].n)
            TRY(gap_fill(&t[T_GAP], h, p->nozzle_mm, ssp, p->infill_overlap * sp,
                         p->min_bead * p->nozzle_mm, out, &t[T_TMP], &t[T_S], &t[T_LINES]));
    }
    double ang = k % 2 ? 135 : 45;
    if (k > 0 && t[T_SOLID].n && p->bridge_mm_s > 0) {
        /* solid over air is a bridge; slivers narrower than the nozzle are not */
        double nz = p->nozzle_mm;
        TRY(clip_bool(CLIP_DIFFERENCE, &t[T_SOLID], &s->l[k - 1].region, CLIP_NONZERO, &t[T_TMP]));
        TRY(clip_offset(&t[T_TMP], -nz / 2, CLIP_JOIN_MITER, &t[T_KEEP]));
        TRY(clip_offset(&t[T_KEEP], nz / 2, CLIP_JOIN_MITER, &t[T_TMP]));
        if (t[T_TMP].n) {
            TRY(clip_bool(CLIP_INTERSECTION, &t[T_TMP], &t[T_SOLID], CLIP_NONZERO, &t[T_KEEP]));
            TRY(clip_bool(CLIP_DIFFERENCE, &t[T_SOLID], &t[T_KEEP], CLIP_NONZERO, &t[T_TMP]));
            paths_move(&t[T_SOLID], &t[T_TMP]);
            TRY(bridges(&t[T_KEEP], &s->l[k - 1].region, nz, org, out, &t[T_TMP], &t[T_LINES],
                        &t[T_S]));
        }
    }
    if (k > 0 && t[T_SOLID].n && p->bridge_mm_s > 0 && p->infill_density > 0 &&
        p->infill_density < 1) { /* 100 % "sparse" is solid: nothing to bridge */
        /* sparse in every layer a thick bridge's thread reaches down
           into (a nozzle deep: PrusaSlicer's bridge_over_infill looks
           down the bridge flow's height) */
        long depth = (long)floor(p->nozzle_mm / h + 1e-6);
        const struct paths *below = &t[T_BELOW];
        paths_reset(&t[T_BELOW]);
        for (long j = (long)k - 1; j >= 0 && j >= (long)k - (depth > 1 ? depth : 1); j--) {
            const struct paths *sj = &s->l[j].sparse;
            if (!s->l[j].has_regions) {
                TRY(toolpath_regions(s, (uint32_t)j, p, &t[T_TMP], &t[T_KEEP], &t[T_LINES]));
                sj = &t[T_LINES];
            }
            if (j == (long)k - 1) {
                if (!paths_append(&t[T_BELOW], sj))
                    TRY(SF_ENOMEM);
            } else if (t[T_BELOW].n) {
                TRY(clip_bool(CLIP_INTERSECTION, &t[T_BELOW], sj, CLIP_NONZERO, &t[T_TMP]));
                paths_move(&t[T_BELOW], &t[T_TMP]);
            }
            if (!t[T_BELOW].n)
                break;
        }
        if (below->n)
            TRY(internal_bridges(&t[T_SOLID], below, p->nozzle_mm, ang, org, out, &t[T_TMP],
                                 &t[T_KEEP], &t[T_LINES]));
    }
    paths_reset(&t[T_LINES]);
    TRY(tp_fill_lines(&t[T_SOLID], ang, ssp, org[0], org[1], &t[T_LINES]));
    TRY(tp_link(&t[T_LINES], &t[T_SOLID], 2 * ssp, sw / 2));
    TRY(add(out, &t[T_LINES], ROLE_SOLID, false, sw));
    paths_reset(&t[T_LINES]);
    TRY(tp_fill_lines(&t[T_TOP], ang, ssp, org[0], org[1], &t[T_LINES]));
    TRY(tp_link(&t[T_LINES], &t[T_TOP], 2 * ssp, sw / 2));
    TRY(add(out, &t[T_LINES], ROLE_TOP, false, sw));
    if (p->infill_density > 0 && t[T_SPARSE].n) {
        /* the lines' ends and anchors run half a line inside the sparse
           area grown infill_overlap into the loops, as PrusaSlicer fills
           its infill areas (fill_surface_by_multilines: the area shrunk by
           half a spacing) */
        TRY(clip_offset(&t[T_SPARSE], p->infill_overlap * sp - sp / 2, CLIP_JOIN_MITER,
                        &t[T_KEEP]));
        paths_reset(&t[T_LINES]);
        if (strcmp(p->infill_pattern, "grid") == 0) {
            double gsp = 2 * sp / p->infill_density;
            TRY(tp_fill_lines(&t[T_KEEP], 45, gsp, org[0], org[1], &t[T_LINES]));
            TRY(tp_fill_lines(&t[T_KEEP], 135, gsp, org[0], org[1], &t[T_LINES]));
        } else {
            TRY(tp_fill_lines(&t[T_KEEP], ang, sp / p->infill_density, org[0], org[1],
                              &t[T_LINES]));
        }
        TRY(tp_anchor(&t[T_LINES], &t[T_KEEP], p->infill_anchor_mm, p->infill_anchor_max_mm,
                      sp / 2));
        TRY(add(out, &t[T_LINES], ROLE_INFILL, false, w));
    }
    TRY(mark_overhangs(s, k, p, out, &t[T_TMP], &t[T_LINES]));
    TRY(group_by_island(&L->region, out));
#undef TRY
out:
    for (int i = 0; i < T_N; i++)
        paths_release(&t[i]);
    return rc;
}

double
tp_brim_width(const struct layer_stack *s, const struct slice_profile *p, double height_mm)
{
    if (p->brim_width_mm > 0)
        return p->brim_width_mm;
    if (!p->brim_auto || !s->n)
        return 0;
    const struct paths *r = &s->l[0].region;
    double area = paths_area(r), per = 0;
    for (uint32_t k = 0; k < r->n; k++)
        per += paths_length_k(r, k, true);
    if (area <= 0 || per <= 0)
        return 0;
    return height_mm > p->brim_auto_ratio * 4 * area / per ? p->brim_auto_width_mm : 0;
}

static int
cmp_ipt(const void *a, const void *b)
{
    const struct ipt *p = a, *q = b;
    if (p->x != q->x)
        return p->x < q->x ? -1 : 1;
    return (p->y > q->y) - (p->y < q->y);
}

/* Twice the signed area of o-a-b (coordinates within a bed fit int64 products). */
static int64_t
cross3(struct ipt o, struct ipt a, struct ipt b)
{
    return (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x);
}

/* Convex hull of every point of in (monotone chain), counter-clockwise, into out. */
static int
hull_of(const struct paths *in, struct paths *out)
{
    paths_reset(out);
    size_t n = in->n ? in->start[in->n] : 0;
    if (n < 3)
        return SF_OK;
    struct ipt *pt = mem_array(n, sizeof(*pt)), *h = mem_array(2 * n, sizeof(*h));
    if (!pt || !h) {
        free(pt);
        free(h);
        return SF_ENOMEM;
    }
    memcpy(pt, in->pts, n * sizeof(*pt));
    qsort(pt, n, sizeof(*pt), cmp_ipt);
    size_t m = 0;
    for (size_t i = 0; i < n; i++) {
        while (m >= 2 && cross3(h[m - 2], h[m - 1], pt[i]) <= 0)
            m--;
        h[m++] = pt[i];
    }
    for (size_t i = n - 1, t = m + 1; i-- > 0;) {
        while (m >= t && cross3(h[m - 2], h[m - 1], pt[i]) <= 0)
            m--;
        h[m++] = pt[i];
    }
    int rc = m > 3 && !paths_add(out, h, (uint32_t)(m - 1)) ? SF_ENOMEM : SF_OK;
    free(pt);
    free(h);
    return rc;
}

/* Loops of width w at offsets d0, d0 + sp, ... (n of them) outside region. */
static int
loops_around(const struct paths *region, double d0, double sp, int n, struct paths *out,
             struct paths *tmp)
{
    paths_reset(out);
    for (int i = 0; i < n; i++) {
        int rc = clip_offset(region, d0 + i * sp, CLIP_JOIN_ROUND, tmp);
        if (rc < 0)
            return rc;
        if (!paths_append(out, tmp))
            return SF_ENOMEM;
    }
    return SF_OK;
}

/* Add closed loops to out as skirt/brim: whole, or when allowed is given,
   cut open to the pieces inside it. */
static int
add_loops(struct layer_paths *out, const struct paths *loops, const struct paths *allowed, double w,
          struct paths *tmp, struct paths *tmp2)
{
    if (!allowed)
        return add(out, loops, ROLE_SKIRT, true, w);
    paths_reset(tmp);
    for (uint32_t i = 0; i < loops->n; i++) {
        const struct ipt *q = loops->pts + loops->start[i];
        uint32_t n = paths_len(loops, i);
        if (!paths_begin(tmp))
            return SF_ENOMEM;
        for (uint32_t j = 0; j <= n; j++)
            if (!paths_push(tmp, q[j % n]))
                return SF_ENOMEM;
    }
    int rc = clip_lines(tmp, allowed, tmp2);
    return rc < 0 ? rc : add(out, tmp2, ROLE_SKIRT, false, w);
}

/* True when every point of p lies on the bed. */
static bool
on_bed(const struct paths *p, const struct paths *bed)
{
    struct ipt lo, hi, blo, bhi;
    if (!paths_bbox(p, &lo, &hi) || !paths_bbox(bed, &blo, &bhi))
        return true;
    return lo.x >= blo.x && lo.y >= blo.y && hi.x <= bhi.x && hi.y <= bhi.y;
}

int
toolpath_skirt_brim(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
                    const struct support_layer *sup0, double brim_mm, struct layer_paths *lp)
{
    bool skirt = p->skirts > 0 && (int)k < p->skirt_height;
    if (!s->n || (!skirt && (k > 0 || brim_mm <= 0)))
        return SF_OK;
    double w = p->width_mm, h = s->l[0].h_mm, sp = tp_spacing(w, h);
    enum { OUTER, ROUND, KEEP, BRIM, HULL, LOOPS, TMP, TMP2, BED, N };
    struct paths t[N];
    for (int i = 0; i < N; i++)
        paths_init(&t[i]);
    struct layer_paths out;
    layer_paths_init(&out);
    int rc = SF_OK;
#define TRY(x)                                                                                     \
    do {                                                                                           \
        if ((rc = (x)) < 0)                                                                        \
            goto done;                                                                             \
    } while (0)
    struct ipt bed[4] = { { 0, 0 },
                          { poly_i(p->bed_x_mm), 0 },
                          { poly_i(p->bed_x_mm), poly_i(p->bed_y_mm) },
                          { 0, poly_i(p->bed_y_mm) } };
    if (!paths_add(&t[BED], bed, 4))
        TRY(SF_ENOMEM);
    /* the part's outer contours (a brim stays out of holes, PrusaSlicer's outer_only) */
    const struct paths *r = &s->l[0].region;
    for (uint32_t i = 0; i < r->n; i++)
        if (paths_area_k(r, i) > 0 && !paths_add(&t[TMP], r->pts + r->start[i], paths_len(r, i)))
            TRY(SF_ENOMEM);
    TRY(clip_bool(CLIP_UNION, &t[TMP], NULL, CLIP_NONZERO, &t[OUTER]));
    /* ROUND: what the skirt goes around (part, support, brim); KEEP: the support */
    paths_reset(&t[TMP]);
    if (sup0 && (!paths_append(&t[TMP], &sup0->body) || !paths_append(&t[TMP], &sup0->iface)))
        TRY(SF_ENOMEM);
    TRY(clip_bool(CLIP_UNION, &t[TMP], NULL, CLIP_NONZERO, &t[KEEP]));
    int n_brim = brim_mm > 0 ? (int)floor(brim_mm / sp + 1e-9) : 0;
    if (n_brim > 0) {
        /* loops from the part outwards, the first half a spacing out, as
           PrusaSlicer's (it overlaps the external perimeter, to bond) */
        TRY(loops_around(&t[OUTER], sp / 2, sp, n_brim, &t[BRIM], &t[TMP]));
        TRY(clip_offset(&t[OUTER], n_brim * sp, CLIP_JOIN_ROUND, &t[ROUND]));
    } else if (!paths_append(&t[ROUND], &t[OUTER])) {
        TRY(SF_ENOMEM);
    }
    if (!paths_append(&t[ROUND], &t[KEEP]))
        TRY(SF_ENOMEM);
    if (skirt) {
        TRY(hull_of(&t[ROUND], &t[HULL]));
        TRY(loops_around(&t[HULL], p->skirt_distance_mm + w / 2, sp, p->skirts, &t[LOOPS],
                         &t[TMP]));
        /* outermost first: the nozzle primes far from the part */
        paths_reset(&t[TMP2]);
        for (uint32_t i = t[LOOPS].n; i-- > 0;)
            if (!paths_add(&t[TMP2], t[LOOPS].pts + t[LOOPS].start[i], paths_len(&t[LOOPS], i)))
                TRY(SF_ENOMEM);
        paths_move(&t[LOOPS], &t[TMP2]);
        TRY(add_loops(&out, &t[LOOPS], on_bed(&t[LOOPS], &t[BED]) ? NULL : &t[BED], w, &t[TMP],
                      &t[TMP2]));
    }
    if (k == 0 && n_brim > 0) {
        /* a line width clear of the support: the loops are cut open there */
        bool clear = on_bed(&t[BRIM], &t[BED]);
        if (t[KEEP].n) {
            TRY(clip_offset(&t[KEEP], w, CLIP_JOIN_ROUND, &t[TMP]));
            paths_move(&t[KEEP], &t[TMP]);
            TRY(clip_bool(CLIP_INTERSECTION, &t[BRIM], &t[KEEP], CLIP_NONZERO, &t[TMP]));
            clear = clear && t[TMP].n == 0;
        }
        if (!clear) {
            TRY(clip_offset(&t[OUTER], n_brim * sp + w, CLIP_JOIN_ROUND, &t[TMP]));
            TRY(clip_bool(CLIP_INTERSECTION, &t[TMP], &t[BED], CLIP_NONZERO, &t[TMP2]));
            TRY(clip_bool(CLIP_DIFFERENCE, &t[TMP2], &t[KEEP], CLIP_NONZERO, &t[HULL]));
        }
        TRY(add_loops(&out, &t[BRIM], clear ? NULL : &t[HULL], w, &t[TMP], &t[TMP2]));
    }
    if (out.p.n) {
        uint32_t n_own = out.p.n;
        if (!paths_append(&out.p, &lp->p))
            TRY(SF_ENOMEM);
        size_t cap = out.cap_info;
        if (!mem_grow((void **)&out.info, &cap, out.p.n, sizeof(*out.info)))
            TRY(SF_ENOMEM);
        out.cap_info = (uint32_t)cap;
        if (lp->p.n)
            memcpy(out.info + n_own, lp->info, lp->p.n * sizeof(*lp->info));
        if (lp->ovh && lp->p.n &&
            !ovh_fill(&out, out.p.start[n_own], lp->ovh, lp->p.start[lp->p.n]))
            TRY(SF_ENOMEM);
        layer_paths_release(lp);
        *lp = out;
        layer_paths_init(&out);
    }
#undef TRY
done:
    layer_paths_release(&out);
    for (int i = 0; i < N; i++)
        paths_release(&t[i]);
    return rc;
}
