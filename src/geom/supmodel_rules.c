/*
 * supmodel_rules.c - the support model's contacts (supmodel_int.h): the
 * slicers' overhang rules (PrusaSlicer's threshold, CuraEngine's step) on
 * the raster, and PrusaSlicer's bridge exemption.
 */
#include "supmodel_int.h"

#include <limits.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"

double
supmodel_prusa_safe_angle_deg(double angle_deg)
{
    double t = fmax(floor(90 - angle_deg + 0.5), 1);
    return fmax(90 - (t + 1), 0);
}

/* tan of the steepest face angle from the horizontal that still overhangs */
static double
slope_limit(const struct supmodel_params *p)
{
    if (p->slicer == SUPMODEL_PRUSA) {
        /* d = h / tan(T + 1), T + 1 = 90 - the safe angle */
        double safe = supmodel_prusa_safe_angle_deg(p->angle_deg);
        if (safe <= 0)
            return 1e6; /* alpha 0: every bottom that is not a vertical wall overhangs */
        return tan((90 - safe) * M_PI / 180);
    }
    /* d = h (tan A - 0.01); a face at phi steps h / tan(phi) */
    double d = tan(p->angle_deg * M_PI / 180) - 0.01;
    return d > 1e-6 ? 1 / d : 1e6;
}

/* Does the bottom at height lo of cell (i, j) overhang its neighbours? */
static bool
overhangs(const struct ray_grid *g, const struct solids *cs, uint32_t i, uint32_t j, float lo,
          double slope)
{
    for (int dj = -1; dj <= 1; dj++) {
        for (int di = -1; di <= 1; di++) {
            if (!di && !dj)
                continue;
            long ni = (long)i + di, nj = (long)j + dj;
            if (ni < 0 || nj < 0 || ni >= (long)g->nu || nj >= (long)g->nw)
                continue;
            /* a face exactly at the limit is not an overhang (PrusaSlicer's +1
               degree makes the threshold inclusive): a hair of tolerance */
            double r = g->pitch * (di && dj ? M_SQRT2 : 1) * (1 - 1e-4);
            if (supmodel_solid_at(cs, (size_t)nj * g->nu + (size_t)ni, (float)(lo - r * slope)))
                return false;
        }
    }
    return true;
}

/*
 * PrusaSlicer's dont_support_bridges (SupportMaterial.cpp
 * remove_bridges_from_contacts, LayerRegion.cpp process_external_surfaces,
 * BridgeDetector.cpp), on the raster.  The new area of layer L (cells whose
 * solid interval starts in L) falls into 8-connected regions.  Cells within
 * the perimeters' width of the layer's outline are perimeters; the rest is
 * the bottom fill.  A region is a bridge when some straight line across its
 * fill runs from material of layer L-1 to material of layer L-1 (the
 * detector's anchored lines; 8 lattice directions instead of its 5-degree
 * steps, and as its bridge_direction_candidates the directions of the
 * region's own edges: those of its convex hull at least BRIDGE_EDGE_MM
 * long, so a gusset's hypotenuse, whose parallels run leg to leg, is a
 * candidate at its own angle).  The direction with the most anchored fill
 * wins.  Then the fill is
 * not supported, bar a 1.5 mm band along the edges where lines of that
 * direction end in the air (its unsupported edges; edges parallel to the
 * direction are free), and perimeter cells are not supported where a line of
 * that direction through the region is anchored at both ends (a straight
 * bridging perimeter).  Regions with no anchored line keep all their support.
 */

#define BRIDGE_DIRS 8
static const int bridge_dir[BRIDGE_DIRS][2] = { { 1, 0 }, { 2, 1 },  { 1, 1 },  { 1, 2 },
                                                { 0, 1 }, { -1, 2 }, { -1, 1 }, { -2, 1 } };

/* A region's hull edges this long or longer are candidate directions; at
   most BRIDGE_EDGES of them, none within BRIDGE_EDGE_DEG of another
   candidate (the raster's staircases make hull edges a little apart). */
#define BRIDGE_EDGE_MM  3.0
#define BRIDGE_EDGES    8
#define BRIDGE_EDGE_DEG 2.0

/*
 * A line direction on the raster: a lattice step d (the 8 above), or, for an
 * edge's direction (d = 0), the digital line along its major axis: the cell
 * after (i, j) is one step on the major axis and round(m x) on the other,
 * so the lines of one direction partition the cells as the lattice steps do.
 */
struct bdir {
    int d[2];
    bool xmajor;
    int s;    /* the major axis' step: 1 or -1 */
    double m; /* the minor axis' change per major step */
};

/* The cell k (1 or -1) steps along dir from (i, j). */
static void
bdir_step(const struct bdir *dir, long i, long j, int k, long *ni, long *nj)
{
    if (dir->d[0] || dir->d[1]) {
        *ni = i + k * dir->d[0];
        *nj = j + k * dir->d[1];
        return;
    }
    long a = dir->xmajor ? i : j, b = dir->xmajor ? j : i;
    long a2 = a + k * dir->s;
    long b2 = b + (long)floor(dir->m * (double)a2 + 0.5) - (long)floor(dir->m * (double)a + 0.5);
    *ni = dir->xmajor ? a2 : b2;
    *nj = dir->xmajor ? b2 : a2;
}

/* Heights within this of a layer's middle are on its cutting plane: the
   ray hits are floats, and a face modelled at a plane's height (a box's
   ceiling at 23.9 mm) lands a few float steps either side of it;
   PrusaSlicer cuts in floats, where the two are equal, and keeps the
   layer (a bottom on the plane is in it, a top on it too). */
#define ON_PLANE_MM 1e-4

/* Layer index whose slice (at its middle height) first holds a bottom at lo. */
static int32_t
bottom_layer(float lo, double h)
{
    return (int32_t)ceil((lo - ON_PLANE_MM) / h - 0.5);
}

/* Scratch for one layer's regions: member marks are stamped with a layer tag. */
struct bridge_ctx {
    const struct ray_grid *g;
    const struct solids *cs;
    double h;
    int32_t k;           /* the layer being processed */
    uint32_t ltag;       /* its tag */
    uint32_t *mtag[2];   /* cells: ltag when mval[0] (layer k) / mval[1] (k - 1) is known */
    uint8_t *mval[2];    /* cells: solid at the middle of that layer */
    uint32_t *tag;       /* cells: tag of the layer whose new area holds it */
    uint32_t *rtag;      /* cells: tag of the region being processed */
    uint8_t *kind;       /* cells: 1 perimeter, 2 fill, |4 bridged, |8 unsupported edge */
    uint32_t *queue;     /* region cells */
    uint32_t *rimtag;    /* cells: tag of the region whose fill this cell of layer L-1 borders */
    uint32_t *rim;       /* those cells */
    long *rowlo, *rowhi; /* rows (nw): a region's first and last cell in each */
    long *hull;          /* a region's row ends (2 nw points), then its hull (up to twice that) */
};

static bool
in_grid(const struct ray_grid *g, long i, long j)
{
    return i >= 0 && j >= 0 && i < (long)g->nu && j < (long)g->nw;
}

/* Is cell (i, j) solid at the middle of layer k? (outside the grid: no)  The
   layer being processed and the one below are asked of the same cells many
   times (perimeter windows, line ends): their answers are kept per cell. */
static bool
solid_layer(const struct bridge_ctx *b, long i, long j, int32_t k)
{
    if (!in_grid(b->g, i, j))
        return false;
    size_t c = (size_t)j * b->g->nu + (size_t)i;
    int s = k == b->k ? 0 : k == b->k - 1 ? 1 : -1;
    if (s >= 0 && b->mtag[s][c] == b->ltag)
        return b->mval[s][c];
    double z = (k + 0.5) * b->h;
    bool v = supmodel_solid_at(b->cs, c, (float)(z + ON_PLANE_MM)) ||
             supmodel_solid_at(b->cs, c, (float)(z - ON_PLANE_MM));
    if (s >= 0) {
        b->mtag[s][c] = b->ltag;
        b->mval[s][c] = v;
    }
    return v;
}

/* Mark the region's cells perimeter or fill. */
static void
bridge_classify(struct bridge_ctx *b, const uint32_t *cells, size_t n, int32_t k, double band_mm)
{
    const struct ray_grid *g = b->g;
    /* a cell is under the perimeters when the outline is nearer than band_mm:
       a cell D centres from one outside the slice is (D - 1/2) pitches from it */
    double rmax = band_mm / g->pitch + 0.5;
    int r = (int)ceil(rmax);
    for (size_t q = 0; q < n; q++) {
        long ci = cells[q] % g->nu, cj = cells[q] / g->nu;
        bool perim = false;
        for (int dj = -r; dj <= r && !perim; dj++)
            for (int di = -r; di <= r && !perim; di++)
                if ((di || dj) && di * di + dj * dj < rmax * rmax &&
                    !solid_layer(b, ci + di, cj + dj, k))
                    perim = true;
        b->kind[cells[q]] = perim ? 1 : 2;
    }
}

/* Does the walk leave the region (kinds in mask) at (i, j) onto material of layer k - 1? */
static bool
bridge_anchor(const struct bridge_ctx *b, long i, long j, int32_t k)
{
    return solid_layer(b, i, j, k - 1);
}

/* Is (i, j) a cell of region rt of a kind in mask? */
static bool
member(const struct bridge_ctx *b, uint32_t rt, uint8_t mask, long i, long j)
{
    if (!in_grid(b->g, i, j))
        return false;
    size_t c = (size_t)j * b->g->nu + (size_t)i;
    return b->rtag[c] == rt && (b->kind[c] & mask);
}

/* A digital line along the region's edge grazes the perimeter band or the
   air past the outline and comes back: a run goes on past this many cells
   that are neither its own nor material of the layer below. */
#define BRIDGE_GRAZE 2

/* Is (i, j) beside (8 neighbours) a cell of region rt? */
static bool
beside(const struct bridge_ctx *b, uint32_t rt, long i, long j)
{
    for (int dj = -1; dj <= 1; dj++)
        for (int di = -1; di <= 1; di++)
            if (in_grid(b->g, i + di, j + dj) &&
                b->rtag[(size_t)(j + dj) * b->g->nu + (size_t)(i + di)] == rt)
                return true;
    return false;
}

/*
 * The run's next cell s (1 or -1) steps along dir from (i, j): true and the
 * cell in (*ni, *nj) when it is a member, or one is past cells that are not
 * material of the layer below: at most BRIDGE_GRAZE of them, or, with hug
 * (lines along the outline: its staircase leaves a digital line parallel
 * to the edge a cell outside now and then), any number beside the region;
 * else false and (*ni, *nj) the first cell past the run, or the cell of
 * the layer below that such cells led to.
 */
static bool
run_step(const struct bridge_ctx *b, uint32_t rt, uint8_t mask, bool hug, const struct bdir *dir,
         int32_t k, long i, long j, int s, long *ni, long *nj)
{
    long x, y;
    bdir_step(dir, i, j, s, &x, &y);
    *ni = x, *nj = y;
    if (member(b, rt, mask, x, y))
        return true;
    for (int q = 0;; q++) {
        if (!in_grid(b->g, x, y))
            return false;
        if (bridge_anchor(b, x, y, k)) {
            *ni = x, *nj = y; /* the run reached the layer below past the graze */
            return false;
        }
        if (q >= BRIDGE_GRAZE && !(hug && beside(b, rt, x, y)))
            return false;
        bdir_step(dir, x, y, s, &x, &y);
        if (member(b, rt, mask, x, y)) {
            *ni = x, *nj = y;
            return true;
        }
    }
}

/*
 * Lines of direction dir over the region's cells of a kind in mask, taken
 * run by run.  *cov sums the cells of runs anchored at both ends
 * (*longest the longest).  With mark set, the cells of kind mark_kind on
 * runs anchored at both ends get bit 4; with mark_kind 0, a run's free ends
 * get bit 8 instead.
 */
static void
bridge_lines(struct bridge_ctx *b, const uint32_t *cells, size_t n, uint32_t rt, int32_t k,
             const struct bdir *dir, uint8_t mask, bool mark, uint8_t mark_kind, size_t *cov,
             size_t *longest)
{
    const struct ray_grid *g = b->g;
    bool hug = mask & 1; /* lines over the perimeters too: along the outline */
    *cov = 0;
    *longest = 0;
    for (size_t q = 0; q < n; q++) {
        long i0 = cells[q] % g->nu, j0 = cells[q] / g->nu, pi, pj, ni, nj;
        if (!member(b, rt, mask, i0, j0) ||
            run_step(b, rt, mask, hug, dir, k, i0, j0, -1, &pi, &pj))
            continue; /* not the start of a run */
        long i = i0, j = j0;
        size_t len = 1;
        while (run_step(b, rt, mask, hug, dir, k, i, j, 1, &ni, &nj)) {
            i = ni, j = nj;
            len++;
        }
        bool a0 = bridge_anchor(b, pi, pj, k);
        bool a1 = bridge_anchor(b, ni, nj, k);
        if (a0 && a1) {
            *cov += len;
            if (len > *longest)
                *longest = len;
        }
        if (!mark)
            continue;
        if (a0 && a1) {
            long x = i0, y = j0;
            for (size_t s = 0; s < len; s++) {
                if (b->kind[(size_t)y * g->nu + (size_t)x] & mark_kind)
                    b->kind[(size_t)y * g->nu + (size_t)x] |= 4;
                if (s + 1 < len)
                    run_step(b, rt, mask, hug, dir, k, x, y, 1, &x, &y);
            }
        } else {
            if (!a0 && !mark_kind)
                b->kind[(size_t)j0 * g->nu + (size_t)i0] |= 8;
            if (!a1 && !mark_kind)
                b->kind[(size_t)j * g->nu + (size_t)i] |= 8;
        }
    }
}

/*
 * Lines of direction d along the rim (cells of layer L-1 beside the fill,
 * across d): the detector's lines that run along the fill's edge over the
 * layer below, as along the wall a shelf hangs from.  A run is anchored when
 * the layer below goes on past both its ends (past the fill, which stops
 * short of the outline by the perimeters).  Axis and diagonal directions
 * only.  *cov sums the anchored runs' cells.
 */
static void
rim_lines(const struct bridge_ctx *b, size_t n_rim, uint32_t rt, int32_t k, const int d[2],
          size_t *cov, size_t *longest)
{
    const struct ray_grid *g = b->g;
    if (abs(d[0]) > 1 || abs(d[1]) > 1)
        return;
    int px = -d[1], py = d[0];
#define FILL(ii, jj)                                                                               \
    (in_grid(g, ii, jj) && b->rtag[(size_t)(jj)*g->nu + (size_t)(ii)] == rt &&                     \
     (b->kind[(size_t)(jj)*g->nu + (size_t)(ii)] & 3) == 2)
#define RIM(ii, jj)                                                                                \
    (in_grid(g, ii, jj) && b->rimtag[(size_t)(jj)*g->nu + (size_t)(ii)] == rt &&                   \
     (FILL((ii) + px, (jj) + py) || FILL((ii)-px, (jj)-py)))
    for (size_t q = 0; q < n_rim; q++) {
        long i0 = b->rim[q] % g->nu, j0 = b->rim[q] / g->nu;
        if (!RIM(i0, j0) || RIM(i0 - d[0], j0 - d[1]))
            continue;
        long i = i0, j = j0;
        size_t len = 1;
        while (RIM(i + d[0], j + d[1])) {
            i += d[0], j += d[1];
            len++;
        }
        if (bridge_anchor(b, i0 - d[0], j0 - d[1], k) && bridge_anchor(b, i + d[0], j + d[1], k)) {
            *cov += len;
            if (len > *longest)
                *longest = len;
        }
    }
#undef RIM
#undef FILL
}

/* Is the angle (degrees, modulo 180) within BRIDGE_EDGE_DEG of a candidate's? */
static bool
dir_near(const struct bdir *dirs, int n, double deg)
{
    for (int q = 0; q < n; q++) {
        double a = dirs[q].d[0] || dirs[q].d[1]
                       ? atan2(dirs[q].d[1], dirs[q].d[0])
                       : (dirs[q].xmajor ? atan2(dirs[q].m, 1) : atan2(1, dirs[q].m));
        double diff = fabs(fmod(deg - a * 180 / M_PI + 360, 180.0));
        if (fmin(diff, 180 - diff) < BRIDGE_EDGE_DEG)
            return true;
    }
    return false;
}

/* z of the cross product (a - o) x (c - o) of hull points (row, column) */
static long
hull_cross(const long *o, const long *a, const long *c)
{
    return (a[0] - o[0]) * (c[1] - o[1]) - (a[1] - o[1]) * (c[0] - o[0]);
}

/*
 * The directions of the region's convex hull edges at least BRIDGE_EDGE_MM
 * long that no lattice direction (dirs[-BRIDGE_DIRS ..]) or earlier edge has
 * already (PrusaSlicer's bridge_direction_candidates adds the bridge
 * contour's lines); returns how many went to out.  The hull is that of the
 * first and last cell of each row (Andrew's monotone chain; rows come sorted).
 */
static int
hull_dirs(struct bridge_ctx *b, const uint32_t *cells, size_t n, struct bdir *out)
{
    const struct ray_grid *g = b->g;
    long jmin = LONG_MAX, jmax = -1;
    for (size_t q = 0; q < n; q++) {
        long j = cells[q] / g->nu;
        jmin = j < jmin ? j : jmin;
        jmax = j > jmax ? j : jmax;
    }
    for (long j = jmin; j <= jmax; j++)
        b->rowlo[j] = LONG_MAX, b->rowhi[j] = -1;
    for (size_t q = 0; q < n; q++) {
        long i = cells[q] % g->nu, j = cells[q] / g->nu;
        b->rowlo[j] = i < b->rowlo[j] ? i : b->rowlo[j];
        b->rowhi[j] = i > b->rowhi[j] ? i : b->rowhi[j];
    }
    long *pt = b->hull, *h = b->hull + 2 * (2 * (size_t)g->nw + 1);
    size_t np = 0, nh = 0;
    for (long j = jmin; j <= jmax; j++) {
        if (b->rowhi[j] < 0)
            continue;
        pt[2 * np] = j, pt[2 * np + 1] = b->rowlo[j], np++;
        if (b->rowhi[j] != b->rowlo[j])
            pt[2 * np] = j, pt[2 * np + 1] = b->rowhi[j], np++;
    }
    if (np < 3)
        return 0;
    for (int pass = 0; pass < 2; pass++) { /* lower hull, then upper */
        size_t base = nh;
        for (size_t t = 0; t < np; t++) {
            const long *p = pt + 2 * (pass ? np - 1 - t : t);
            while (nh >= base + 2 && hull_cross(h + 2 * (nh - 2), h + 2 * (nh - 1), p) <= 0)
                nh--;
            h[2 * nh] = p[0], h[2 * nh + 1] = p[1], nh++;
        }
        nh--; /* the last point starts the other half */
    }
    int n_out = 0;
    double min_cells = BRIDGE_EDGE_MM / g->pitch;
    for (size_t e = 0; e < nh && n_out < BRIDGE_EDGES; e++) {
        const long *p = h + 2 * e, *r = h + 2 * ((e + 1) % nh);
        long dj = r[0] - p[0], di = r[1] - p[1];
        if (hypot((double)di, (double)dj) < min_cells)
            continue;
        double deg = atan2((double)dj, (double)di) * 180 / M_PI;
        if (dir_near(out - BRIDGE_DIRS, BRIDGE_DIRS + n_out, deg))
            continue;
        bool xmajor = labs(di) >= labs(dj);
        out[n_out++] =
            (struct bdir){ .xmajor = xmajor,
                           .s = (xmajor ? di : dj) > 0 ? 1 : -1,
                           .m = xmajor ? (double)dj / (double)di : (double)di / (double)dj };
    }
    return n_out;
}

/* The bridge decision for one region; sets bit 4 on its unsupported cells. */
static void
bridge_region(struct bridge_ctx *b, const uint32_t *cells, size_t n, uint32_t rt, int32_t k,
              double band_mm)
{
    const struct ray_grid *g = b->g;
    bridge_classify(b, cells, n, k, band_mm);
    size_t n_rim = 0;
    for (size_t q = 0; q < n; q++) {
        if (b->kind[cells[q]] != 2)
            continue;
        long ci = cells[q] % g->nu, cj = cells[q] / g->nu;
        for (int dj = -1; dj <= 1; dj++)
            for (int di = -1; di <= 1; di++) {
                long x = ci + di, y = cj + dj;
                if (!in_grid(g, x, y))
                    continue;
                size_t c = (size_t)y * g->nu + (size_t)x;
                if (b->rtag[c] != rt && b->rimtag[c] != rt && solid_layer(b, x, y, k - 1)) {
                    b->rimtag[c] = rt;
                    b->rim[n_rim++] = (uint32_t)c;
                }
            }
    }
    struct bdir dirs[BRIDGE_DIRS + BRIDGE_EDGES];
    for (int d = 0; d < BRIDGE_DIRS; d++)
        dirs[d] = (struct bdir){ .d = { bridge_dir[d][0], bridge_dir[d][1] } };
    int n_dirs = BRIDGE_DIRS + hull_dirs(b, cells, n, dirs + BRIDGE_DIRS);
    int best = -1;
    size_t best_cov = 0, best_long = 0;
    for (int d = 0; d < n_dirs; d++) {
        size_t cov, longest;
        bridge_lines(b, cells, n, rt, k, &dirs[d], 2, false, 0, &cov, &longest);
        if (d < BRIDGE_DIRS)
            rim_lines(b, n_rim, rt, k, bridge_dir[d], &cov, &longest);
        if (cov > best_cov || (cov == best_cov && cov > 0 && longest < best_long)) {
            best = d;
            best_cov = cov;
            best_long = longest;
        }
    }
    if (best < 0)
        return; /* no anchored line: not a bridge */
    size_t cov, longest;
    /* the fill's free ends (its unsupported edges) ... */
    bridge_lines(b, cells, n, rt, k, &dirs[best], 2, true, 0, &cov, &longest);
    /* ... and straight perimeters anchored at both ends */
    bridge_lines(b, cells, n, rt, k, &dirs[best], 3, true, 1, &cov, &longest);
    /* fill is bridged, bar 1.5 mm (SUPPORT_MATERIAL_MARGIN) from a free edge: a
       cell D centres from an edge cell is (D + 1/2) pitches from the edge */
    double rmax = 1.5 / g->pitch - 0.5;
    int r = (int)floor(rmax + 1e-9);
    for (size_t q = 0; q < n; q++)
        if ((b->kind[cells[q]] & 3) == 2)
            b->kind[cells[q]] |= 4;
    for (size_t q = 0; q < n; q++) {
        if (!(b->kind[cells[q]] & 8))
            continue;
        long ci = cells[q] % g->nu, cj = cells[q] / g->nu;
        for (int dj = -r; dj <= r; dj++)
            for (int di = -r; di <= r; di++) {
                long x = ci + di, y = cj + dj;
                if (di * di + dj * dj > rmax * rmax + 1e-9 || !in_grid(g, x, y))
                    continue;
                size_t c = (size_t)y * g->nu + (size_t)x;
                if (b->rtag[c] == rt && (b->kind[c] & 3) == 2)
                    b->kind[c] &= (uint8_t)~4;
            }
    }
}

/*
 * Cells grouped by a layer index: items[first[k] .. first[k + 1]) are layer
 * k's, in the order given (a counting sort: layers are few, items many).
 */
struct by_layer {
    uint32_t *first; /* n_layers + 1 */
    uint32_t *items;
    int32_t n_layers;
};

static void
by_layer_release(struct by_layer *bl)
{
    free(bl->first);
    free(bl->items);
}

/* Group n items (item i in layer k[i], -1: left out) by layer. */
static bool
by_layer_build(struct by_layer *bl, const int32_t *k, const uint32_t *item, size_t n)
{
    int32_t kmax = -1;
    for (size_t i = 0; i < n; i++)
        kmax = k[i] > kmax ? k[i] : kmax;
    bl->n_layers = kmax + 1;
    bl->first = mem_calloc((size_t)bl->n_layers + 1, sizeof(uint32_t));
    bl->items = mem_array(n ? n : 1, sizeof(uint32_t));
    if (!bl->first || !bl->items)
        return false;
    for (size_t i = 0; i < n; i++)
        if (k[i] >= 0)
            bl->first[k[i] + 1]++;
    for (int32_t l = 0; l < bl->n_layers; l++)
        bl->first[l + 1] += bl->first[l];
    uint32_t *at = mem_array((size_t)bl->n_layers + 1, sizeof(uint32_t));
    if (!at)
        return false;
    memcpy(at, bl->first, ((size_t)bl->n_layers + 1) * sizeof(uint32_t));
    for (size_t i = 0; i < n; i++)
        if (k[i] >= 0)
            bl->items[at[k[i]]++] = item[i];
    free(at);
    return true;
}

/* The scratch of b (its grid set): false when out of memory. */
static bool
bridge_ctx_alloc(struct bridge_ctx *b)
{
    size_t cells = (size_t)b->g->nu * b->g->nw;
    b->tag = mem_calloc(cells, sizeof(uint32_t));
    b->rtag = mem_calloc(cells, sizeof(uint32_t));
    b->kind = mem_calloc(cells, 1);
    b->queue = mem_array(cells, sizeof(uint32_t));
    b->rimtag = mem_calloc(cells, sizeof(uint32_t));
    b->rim = mem_array(cells, sizeof(uint32_t));
    b->rowlo = mem_array(b->g->nw, sizeof(long));
    b->rowhi = mem_array(b->g->nw, sizeof(long));
    b->hull = mem_array(6 * ((size_t)b->g->nw * 2 + 1), sizeof(long));
    bool ok = b->tag && b->rtag && b->kind && b->queue && b->rimtag && b->rim && b->rowlo &&
              b->rowhi && b->hull;
    for (int s = 0; s < 2; s++) {
        b->mtag[s] = mem_calloc(cells, sizeof(uint32_t));
        b->mval[s] = mem_array(cells, 1);
        ok = ok && b->mtag[s] && b->mval[s];
    }
    return ok;
}

static void
bridge_ctx_release(struct bridge_ctx *b)
{
    free(b->tag);
    free(b->rtag);
    free(b->kind);
    free(b->queue);
    free(b->rimtag);
    free(b->rim);
    free(b->rowlo);
    free(b->rowhi);
    free(b->hull);
    for (int s = 0; s < 2; s++) {
        free(b->mtag[s]);
        free(b->mval[s]);
    }
}

/*
 * Drop the contacts that PrusaSlicer's bridge detection leaves unsupported.
 * Only the layers that have contacts, and of those only the regions that
 * hold a contact, are looked at: a region's verdict matters to its own
 * contacts alone.
 */
static int
remove_bridges(const struct ray_grid *g, const struct solids *cs, const struct supmodel_params *p,
               struct contact *ct, size_t *n_ct, struct sf_err *err)
{
    size_t cells = (size_t)g->nu * g->nw, n_b = 0;
    for (size_t c = 0; c < cells; c++)
        for (uint32_t q = cs->first[c]; q < cs->first[c + 1]; q++)
            n_b += cs->iv[q].hi > cs->iv[q].lo && cs->iv[q].lo > 0;
    struct bridge_ctx b = { .g = g, .cs = cs, .h = p->layer_mm };
    struct by_layer bot = { 0 }, con = { 0 };
    size_t n_k = n_b > *n_ct ? n_b : *n_ct;
    int32_t *kk = mem_array(n_k ? n_k : 1, sizeof(*kk));
    uint32_t *it = mem_array(n_k ? n_k : 1, sizeof(*it));
    bool ok = bridge_ctx_alloc(&b);
    uint8_t *gone = mem_calloc(*n_ct ? *n_ct : 1, 1);
    int rc = SF_OK;
    if (!kk || !it || !ok || !gone) {
        rc = sf_err_set(err, SF_ENOMEM, "support model: out of memory (bridges)");
        goto done;
    }
    /* every layer's new area (the cells whose solid starts in it), and the contacts */
    n_b = 0;
    for (size_t c = 0; c < cells; c++)
        for (uint32_t q = cs->first[c]; q < cs->first[c + 1]; q++)
            if (cs->iv[q].hi > cs->iv[q].lo && cs->iv[q].lo > 0) {
                kk[n_b] = bottom_layer(cs->iv[q].lo, p->layer_mm);
                it[n_b++] = (uint32_t)c;
            }
    if (!by_layer_build(&bot, kk, it, n_b)) {
        rc = sf_err_set(err, SF_ENOMEM, "support model: out of memory (bridges)");
        goto done;
    }
    for (size_t q = 0; q < *n_ct; q++) {
        kk[q] = bottom_layer(ct[q].top, p->layer_mm);
        kk[q] = kk[q] < bot.n_layers ? kk[q] : -1; /* (a contact is a bottom) */
        it[q] = (uint32_t)q;
    }
    if (!by_layer_build(&con, kk, it, *n_ct)) {
        rc = sf_err_set(err, SF_ENOMEM, "support model: out of memory (bridges)");
        goto done;
    }
    uint32_t ltag = 0, rt = 0;
    for (int32_t k = 0; k < con.n_layers; k++) {
        uint32_t c0 = con.first[k], c1 = con.first[k + 1];
        if (c0 == c1)
            continue;
        uint32_t rt0 = rt;
        b.k = k;
        b.ltag = ++ltag;
        for (uint32_t q = bot.first[k]; q < bot.first[k + 1]; q++)
            b.tag[bot.items[q]] = ltag;
        for (uint32_t q = c0; q < c1; q++) {
            uint32_t s = ct[con.items[q]].cell;
            if (b.tag[s] != ltag || b.rtag[s] > rt0)
                continue; /* not new area (cannot be), or already in a region of this layer */
            /* flood the 8-connected region of s */
            size_t n = 0;
            b.queue[n++] = s;
            b.rtag[s] = ++rt;
            for (size_t hq = 0; hq < n; hq++) {
                long ci = b.queue[hq] % g->nu, cj = b.queue[hq] / g->nu;
                for (int dj = -1; dj <= 1; dj++)
                    for (int di = -1; di <= 1; di++) {
                        long x = ci + di, y = cj + dj;
                        if (!in_grid(g, x, y))
                            continue;
                        size_t c = (size_t)y * g->nu + (size_t)x;
                        if (b.tag[c] == ltag && b.rtag[c] <= rt0) {
                            b.rtag[c] = rt;
                            b.queue[n++] = (uint32_t)c;
                        }
                    }
            }
            bridge_region(&b, b.queue, n, rt, k, p->bridge_band_mm);
            for (size_t q2 = 0; q2 < n; q2++) /* keep only the verdict */
                b.kind[b.queue[q2]] &= 4;
        }
        /* drop this layer's bridged contacts */
        for (uint32_t q = c0; q < c1; q++) {
            uint32_t c = ct[con.items[q]].cell;
            if (b.tag[c] == ltag && (b.kind[c] & 4))
                gone[con.items[q]] = 1;
        }
        for (uint32_t q = bot.first[k]; q < bot.first[k + 1]; q++)
            b.kind[bot.items[q]] = 0;
    }
    size_t m = 0;
    for (size_t q = 0; q < *n_ct; q++)
        if (!gone[q])
            ct[m++] = ct[q];
    *n_ct = m;
done:
    by_layer_release(&bot);
    by_layer_release(&con);
    free(kk);
    free(it);
    bridge_ctx_release(&b);
    free(gone);
    return rc;
}

int
supmodel_find_contacts(const struct ray_grid *g, const struct solids *cs,
                       const struct supmodel_params *p, struct contact **out, size_t *n_out,
                       struct sf_err *err)
{
    double slope = slope_limit(p), h = p->layer_mm;
    /* |n . up| of a face at the limit (a face exactly there is not an overhang:
       a hair of tolerance, as in overhangs()) */
    double cos_flat = 1 / sqrt(1 + slope * slope);
    size_t n = 0, cap = 0;
    struct contact *v = NULL;
    for (uint32_t j = 0; j < g->nw; j++) {
        for (uint32_t i = 0; i < g->nu; i++) {
            size_t c = (size_t)j * g->nu + i;
            float floor_mm = 0;
            for (uint32_t k = cs->first[c]; k < cs->first[c + 1]; k++) {
                struct ival iv = cs->iv[k];
                float below = floor_mm;
                floor_mm = iv.hi;
                if (!(iv.hi > iv.lo))
                    continue;
                /* room for a contact gap, a layer of support and the landing gap */
                double room = iv.lo - below - p->gap_z_mm - (below > 0 ? p->gap_z_mm : 0);
                if (iv.lo - p->gap_z_mm < h || room < h)
                    continue;
                /* a bottom on a facet flatter than the limit steps past the layer
                   below by more than d wherever a layer plane crosses it, however
                   narrow: a 0.5 mm 45-degree chamfer along a wall is a contact in
                   PrusaSlicer (couplingdown's bore edge: a ring of columns), while
                   the neighbours' test finds the wall a raster step away */
                if (-iv.cos_lo <= cos_flat + 1e-4 && !overhangs(g, cs, i, j, iv.lo, slope))
                    continue;
                void *o = v;
                if (!mem_grow(&o, &cap, n + 1, sizeof(*v))) {
                    free(v);
                    return sf_err_set(err, SF_ENOMEM, "support model: out of memory");
                }
                v = o;
                /* PrusaSlicer prints dense interface only where the overhang passes
                   the layer below grown by 0.6 external perimeter widths (SM:1798) */
                bool dense = p->interface_step_mm <= 0 ||
                             overhangs(g, cs, i, j, iv.lo, h / p->interface_step_mm);
                v[n++] = (struct contact){ (uint32_t)c, iv.lo, below, dense };
            }
        }
    }
    int rc = p->bridges ? remove_bridges(g, cs, p, v, &n, err) : SF_OK;
    if (rc) {
        free(v);
        return rc;
    }
    *out = v;
    *n_out = n;
    return SF_OK;
}
