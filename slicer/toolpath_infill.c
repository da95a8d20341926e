/*
 * toolpath_infill.c - fill lines and their zig-zag links (see toolpath.h:
 * tp_fill_lines, tp_link).
 *
 * Lines come from a scanline over the region's edges, island by island;
 * links join a line's end to the nearest free end when the link stays
 * inside the region.
 *
 * Thread: reentrant; no state outside the arguments.
 */
#include "toolpath.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../src/base/err.h"
#include "../src/base/mem.h"
#include "clip_shim.h"
#include "toolpath_int.h"

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
                        double d = tp_d2(end, r);
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
