/*
 * toolpath_anchor.c - sparse infill lines joined and anchored along the
 * boundary, as PrusaSlicer's connect_infill does (see toolpath.h:
 * tp_anchor).
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
#include "toolpath_int.h"

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

/* The working state of tp_anchor.  Arrays of 2 n are indexed by a line
   end's place among the sorted ends (bp), except slot. */
struct anchor {
    const struct paths *lines, *region;
    uint32_t n; /* lines */
    struct paths_index ix;
    double *cum;       /* per boundary point: arc length from its path's first point, mm */
    uint32_t *path_of; /* per boundary point: its path */
    struct bpos *bp;   /* the line ends found on the boundary, sorted */
    size_t nb;         /* how many */
    int32_t *slot;     /* (line, end) -> index in bp or -1 */
    uint32_t *nx, *pv; /* the next and previous end along the same path */
    double *gap;       /* forward to nx, mm */
    double *free_fw;   /* boundary not yet taken forward from each end, mm */
    double *free_bk;   /* and back */
    struct end_use *use;
    struct arc *arcs; /* between neighbouring ends */
    size_t n_arcs;
    uint32_t *uf;  /* per line: union-find of the lines joined */
    uint8_t *done; /* per line: in a chain already */
};

static void
anchor_release(struct anchor *a)
{
    paths_index_release(&a->ix);
    free(a->cum);
    free(a->path_of);
    free(a->bp);
    free(a->slot);
    free(a->nx);
    free(a->pv);
    free(a->gap);
    free(a->free_fw);
    free(a->free_bk);
    free(a->use);
    free(a->arcs);
    free(a->uf);
    free(a->done);
}

/* Allocate a's arrays (a zeroed first) and the arc lengths along the
   boundary.  SF_ENOMEM (a is released by anchor_release either way). */
static int
anchor_init(struct anchor *a, const struct paths *lines, const struct paths *region)
{
    uint32_t n = lines->n;
    memset(a, 0, sizeof(*a));
    a->lines = lines;
    a->region = region;
    a->n = n;
    size_t np = region->start[region->n];
    a->cum = mem_array(np + 1, sizeof(*a->cum));
    a->path_of = mem_array(np + 1, sizeof(*a->path_of));
    a->bp = mem_array(2 * (size_t)n, sizeof(*a->bp));
    a->slot = mem_array(2 * (size_t)n, sizeof(*a->slot));
    a->nx = mem_array(2 * (size_t)n, sizeof(*a->nx));
    a->pv = mem_array(2 * (size_t)n, sizeof(*a->pv));
    a->gap = mem_array(2 * (size_t)n, sizeof(*a->gap));
    a->free_fw = mem_array(2 * (size_t)n, sizeof(*a->free_fw));
    a->free_bk = mem_array(2 * (size_t)n, sizeof(*a->free_bk));
    a->use = mem_calloc(2 * (size_t)n, sizeof(*a->use));
    a->arcs = mem_array(2 * (size_t)n, sizeof(*a->arcs));
    a->uf = mem_array(n, sizeof(*a->uf));
    a->done = mem_calloc(n, 1);
    if (!(a->cum && a->path_of && a->bp && a->slot && a->nx && a->pv && a->gap && a->free_fw &&
          a->free_bk && a->use && a->arcs && a->uf && a->done && paths_index_init(&a->ix, region)))
        return SF_ENOMEM;
    for (uint32_t k = 0; k < region->n; k++) {
        double c = 0;
        for (uint32_t i = region->start[k]; i < region->start[k + 1]; i++) {
            a->cum[i] = c;
            a->path_of[i] = k;
            uint32_t j = i + 1 < region->start[k + 1] ? i + 1 : region->start[k];
            c += dist_mm(region->pts[i], region->pts[j]);
        }
    }
    return SF_OK;
}

/* Locate every line end on its boundary edge (within 2 units: Clipper
   rounds intersections to the unit) into a->bp, sorted along each path. */
static void
locate_ends(struct anchor *a)
{
    const struct paths *lines = a->lines, *region = a->region;
    const struct paths_index *ix = &a->ix;
    size_t nb = 0;
    for (uint32_t l = 0; l < a->n; l++) {
        a->uf[l] = l;
        for (uint32_t e = 0; e < 2; e++) {
            a->slot[2 * l + e] = -1;
            struct ipt q = lines->pts[e ? lines->start[l + 1] - 1 : lines->start[l]];
            uint32_t band = band_of_index(ix, q.y);
            double best = 4.0; /* units^2: Clipper rounds intersections to the unit */
            uint32_t ba = 0, bb = 0;
            bool found = false;
            for (uint32_t i = ix->first[band]; i < ix->first[band + 1]; i++) {
                struct ipt pa = ix->pts[ix->edges[i][0]], pb = ix->pts[ix->edges[i][1]];
                double dx = (double)(pb.x - pa.x), dy = (double)(pb.y - pa.y);
                double px = (double)(q.x - pa.x), py = (double)(q.y - pa.y);
                double l2 = dx * dx + dy * dy, t = l2 > 0 ? (px * dx + py * dy) / l2 : 0;
                t = t < 0 ? 0 : t > 1 ? 1 : t;
                double ex = px - t * dx, ey = py - t * dy, d = ex * ex + ey * ey;
                if (d <= best) {
                    best = d;
                    ba = ix->edges[i][0];
                    bb = ix->edges[i][1];
                    found = true;
                }
            }
            if (!found)
                continue;
            struct bpos *p = &a->bp[nb];
            p->line = l;
            p->end = e;
            p->path = a->path_of[ba];
            p->a = ba;
            p->b = bb;
            p->s = a->cum[ba] + dist_mm(region->pts[ba], q);
            nb++;
        }
    }
    qsort(a->bp, nb, sizeof(*a->bp), cmp_bpos);
    a->nb = nb;
}

/* Neighbours along each boundary path, the arcs between them (sorted,
   shortest first) and the boundary free on either side of each end. */
static void
find_arcs(struct anchor *a)
{
    const struct paths *region = a->region;
    const struct bpos *bp = a->bp;
    size_t nb = a->nb, n_arcs = 0;
    for (size_t g0 = 0, g1; g0 < nb; g0 = g1) {
        uint32_t k = bp[g0].path;
        for (g1 = g0 + 1; g1 < nb && bp[g1].path == k;)
            g1++;
        uint32_t last = region->start[k + 1] - 1;
        double per = a->cum[last] + dist_mm(region->pts[last], region->pts[region->start[k]]);
        for (size_t i = g0; i < g1; i++) {
            a->nx[i] = (uint32_t)(i + 1 < g1 ? i + 1 : g0);
            a->pv[i] = (uint32_t)(i > g0 ? i - 1 : g1 - 1);
            a->gap[i] = a->nx[i] == i ? per : bp[a->nx[i]].s - bp[i].s;
            if (a->gap[i] < 0)
                a->gap[i] += per;
            if (a->nx[i] != i)
                a->arcs[n_arcs++] = (struct arc){ (uint32_t)i, a->gap[i] };
        }
        for (size_t i = g0; i < g1; i++) {
            a->free_fw[i] = a->gap[i];
            a->free_bk[i] = a->gap[a->pv[i]];
        }
    }
    for (size_t i = 0; i < nb; i++) {
        a->use[i].to = -1;
        a->slot[2 * bp[i].line + bp[i].end] = (int32_t)i;
    }
    qsort(a->arcs, n_arcs, sizeof(*a->arcs), cmp_arc);
    a->n_arcs = n_arcs;
}

/* PrusaSlicer's connect_infill: the shortest arcs first, each joining
   two lines not yet joined (no loops) along the whole arc when it is
   shorter than max_mm; a longer one gives both ends a stub instead. */
static void
join_arcs(struct anchor *a, double len_mm, double max_mm, double half_w_mm)
{
    double *free_fw = a->free_fw, *free_bk = a->free_bk, *gap = a->gap;
    struct end_use *use = a->use;
    for (size_t k = 0; k < a->n_arcs; k++) {
        uint32_t i = a->arcs[k].i, j = a->nx[i];
        if (use[i].consumed || use[j].consumed)
            continue;
        uint32_t li = uf_find(a->uf, a->bp[i].line), lj = uf_find(a->uf, a->bp[j].line);
        if (li == lj)
            continue;
        if (a->arcs[k].len_mm < max_mm) {
            use[i] = (struct end_use){ (int32_t)j, a->arcs[k].len_mm, 0, 1 };
            use[j] = (struct end_use){ (int32_t)i, a->arcs[k].len_mm, 1, 1 };
            free_fw[i] = free_bk[j] = 0;
            a->uf[lj] = li;
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
}

/* The ends left: a stub toward the side with more boundary free, in
   line order (PrusaSlicer's order). */
static void
stub_leftovers(struct anchor *a, double len_mm, double half_w_mm)
{
    double *free_fw = a->free_fw, *free_bk = a->free_bk, *gap = a->gap;
    for (uint32_t k = 0; k < 2 * a->n && len_mm > 0; k++) {
        int32_t i = a->slot[k];
        if (i < 0 || a->use[i].consumed)
            continue;
        bool back = free_bk[i] > free_fw[i];
        uint32_t j = back ? a->pv[i] : a->nx[i];
        double g = back ? gap[a->pv[i]] : gap[i];
        double t = fmax(0, fmin(fmin(len_mm, back ? free_bk[i] : free_fw[i]), g - half_w_mm));
        a->use[i] = (struct end_use){ -1, t, back, 1 };
        if ((uint32_t)i != j) {
            if (back)
                free_fw[j] = fmin(free_fw[j], g - t);
            else
                free_bk[j] = fmin(free_bk[j], g - t);
        }
    }
}

/* One chain into out (a path begun): from line l0's free end e0, its
   stub reversed, the line, then arc, line, ..., stub.  stub: scratch. */
static int
chain_from(struct anchor *a, uint32_t l0, uint32_t e0, struct paths *out, struct paths *stub)
{
    const struct paths *lines = a->lines;
    const struct end_use *use = a->use;
    int rc = SF_OK;
    int32_t si = a->slot[2 * l0 + e0];
    if (si >= 0 && use[si].len_mm > 0) {
        struct ipt q = lines->pts[e0 ? lines->start[l0 + 1] - 1 : lines->start[l0]];
        paths_reset(stub);
        if (!paths_begin(stub) ||
            !walk(a->region, &a->bp[si], q, use[si].len_mm, use[si].back, stub))
            rc = SF_ENOMEM;
        for (uint32_t i = rc == SF_OK ? paths_len(stub, 0) : 0; i-- > 0;)
            if (!paths_push(out, stub->pts[i]))
                rc = SF_ENOMEM;
    }
    uint32_t l = l0, e = e0;
    while (rc == SF_OK) {
        a->done[l] = 1;
        const struct ipt *q = lines->pts + lines->start[l];
        uint32_t m = paths_len(lines, l);
        for (uint32_t i = 0; i < m && rc == SF_OK; i++) {
            struct ipt pt = q[e ? m - 1 - i : i];
            if (!paths_push(out, pt))
                rc = SF_ENOMEM;
        }
        int32_t sf = a->slot[2 * l + (1 - e)]; /* the far end */
        if (rc < 0 || sf < 0)
            break;
        struct ipt qe = q[e ? 0 : m - 1];
        if (!walk(a->region, &a->bp[sf], qe, use[sf].len_mm, use[sf].back, out)) {
            rc = SF_ENOMEM;
            break;
        }
        if (use[sf].to < 0)
            break;
        const struct bpos *nxt = &a->bp[use[sf].to];
        l = nxt->line;
        e = nxt->end;
        if (a->done[l])
            break; /* cannot happen: no cycles */
    }
    return rc;
}

/* The chains, each from a line with a free end (no cycles: every chain
   has two), into out. */
static int
chains(struct anchor *a, struct paths *out, struct paths *stub)
{
    int rc = SF_OK;
    for (uint32_t l0 = 0; l0 < a->n && rc == SF_OK; l0++) {
        if (a->done[l0])
            continue;
        int32_t s0 = a->slot[2 * l0], s1 = a->slot[2 * l0 + 1];
        uint32_t e0; /* the end the chain starts at */
        if (s0 < 0 || a->use[s0].to < 0)
            e0 = 0;
        else if (s1 < 0 || a->use[s1].to < 0)
            e0 = 1;
        else
            continue; /* inside a chain: reached from its ends */
        if (!paths_begin(out)) {
            rc = SF_ENOMEM;
            break;
        }
        rc = chain_from(a, l0, e0, out, stub);
        /* drop points within 1 um of the one before (an arc's or stub's
           end on the next line's end): a zero-length move is not a move */
        uint32_t o = out->start[out->n - 1], w = o + 1;
        for (uint32_t i = o + 1; i < out->start[out->n]; i++)
            if (tp_d2(out->pts[w - 1], out->pts[i]) >= 1e4)
                out->pts[w++] = out->pts[i];
        out->start[out->n] = w;
    }
    return rc;
}

int
tp_anchor(struct paths *lines, const struct paths *region, double len_mm, double max_mm,
          double half_w_mm)
{
    if (!lines->n || !region->n || (len_mm <= 0 && max_mm <= 0))
        return SF_OK;
    struct anchor a;
    struct paths out, stub;
    paths_init(&out);
    paths_init(&stub);
    int rc = anchor_init(&a, lines, region);
    if (rc == SF_OK) {
        locate_ends(&a);
        find_arcs(&a);
        join_arcs(&a, len_mm, max_mm, half_w_mm);
        stub_leftovers(&a, len_mm, half_w_mm);
        rc = chains(&a, &out, &stub);
    }
    if (rc == SF_OK)
        paths_move(lines, &out);
    anchor_release(&a);
    paths_release(&out);
    paths_release(&stub);
    return rc;
}
