/*
 * supmodel.c - layer-based support model (see supmodel.h for the rules and
 * ../shared/SUPPORT-DETECTION.md for where each constant comes from).
 *
 * Three passes over the raster: solid intervals per column (the ray count
 * of shells, as measure.c walks it, so overlapping shells and open meshes
 * give material, not columns); contacts (bottoms the layer below does not
 * reach) and their columns down to the bed or the part; then the columns
 * of each snap cell are merged into layer ranges, and the ranges give the
 * filled cell-layers, the outline and the landings.
 */
#include "supmodel.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"

void
supmodel_params_default(struct supmodel_params *p, enum supmodel_slicer s)
{
    memset(p, 0, sizeof(*p));
    p->slicer = s;
    p->angle_deg = 45;
    p->layer_mm = 0.2;
    /* PrusaSlicer's overhang step is d = 0.19 mm a layer: a bottom that flattens over
       a few tenths of a mm (a fin's tip, a curled edge) is a contact there, and it
       stands a whole 2.8 mm column (no minimum area).  A 0.47 mm raster averaged such
       bottoms away (cow, optimized: PrusaSlicer's column to z 42 missed); 0.236 mm
       (12 per snap cell) sees them. */
    p->pitch_mm = 0.25;
    p->gap_z_mm = 0.2;
    p->line_width_mm = 0.4;
    p->speed_mm_s = 60;
    p->density_g_cm3 = 1.24;
    if (s == SUPMODEL_PRUSA) {
        /* spacing 2.5 mm + flow spacing 0.336 (SM:785); s / (2.5 + s) */
        p->gap_xy_mm = 0.225;
        p->snap_mm = 2.836;
        p->interface_layers = 3;
        p->base_density = 0.118;
        p->first_density = 0.9;
        p->sheath_mm = 0.336;
        p->interface_step_mm = 0.27; /* 0.6 x 0.45 */
        /* dont_support_bridges is on in the peers' runs (and the CLI's default) */
        p->bridges = true;
        /* two perimeters of 0.45 mm, less the infill's overlap with them */
        p->bridge_band_mm = 0.8;
        p->open_gap_mm = 2; /* TriangleMeshSlicer's make_loops */
    } else {
        /* zigzag at 2.667 mm line distance: 0.4 / 2.667; join distance 2 mm */
        p->gap_xy_mm = 0.7;
        p->snap_mm = 2;
        p->base_density = 0.15;
        p->first_density = 0.15;
        p->connector_factor = 0.6;
        p->open_gap_mm = 10; /* slicer.cpp's max_stitch1 */
    }
}

void
supmodel_params_steer(struct supmodel_params *p, double angle_deg)
{
    supmodel_params_default(p, SUPMODEL_PRUSA);
    p->angle_deg = angle_deg;
    p->open_gap_mm = 0;
}

int
supmodel_params_check(const struct supmodel_params *p, struct sf_err *err)
{
    if (!(p->angle_deg >= 0 && p->angle_deg < 90))
        return sf_err_set(err, SF_EINVAL, "support model: angle_deg %g outside [0, 90)",
                          p->angle_deg);
    if (!(p->layer_mm >= 0.01 && p->layer_mm <= 2))
        return sf_err_set(err, SF_EINVAL, "support model: layer_mm %g outside [0.01, 2]",
                          p->layer_mm);
    if (!(p->pitch_mm >= 0.05 && p->pitch_mm <= 10))
        return sf_err_set(err, SF_EINVAL, "support model: pitch_mm %g outside [0.05, 10]",
                          p->pitch_mm);
    if (!(p->gap_z_mm >= 0 && p->gap_z_mm <= 5) || !(p->gap_xy_mm >= 0 && p->gap_xy_mm <= 5))
        return sf_err_set(err, SF_EINVAL, "support model: gap_z_mm/gap_xy_mm outside [0, 5]");
    if (!(p->interface_step_mm >= 0 && p->interface_step_mm <= 5) ||
        !(p->bridge_band_mm >= 0 && p->bridge_band_mm <= 10))
        return sf_err_set(err, SF_EINVAL,
                          "support model: interface_step_mm outside [0, 5] or bridge_band_mm "
                          "outside [0, 10]");
    if (!(p->open_gap_mm >= 0 && p->open_gap_mm <= 100))
        return sf_err_set(err, SF_EINVAL, "support model: open_gap_mm %g outside [0, 100]",
                          p->open_gap_mm);
    if (!(p->snap_mm >= 0 && p->snap_mm <= 50))
        return sf_err_set(err, SF_EINVAL, "support model: snap_mm %g outside [0, 50]", p->snap_mm);
    if (p->interface_layers < 0 || p->interface_layers > 50)
        return sf_err_set(err, SF_EINVAL, "support model: interface_layers %d outside [0, 50]",
                          p->interface_layers);
    if (!(p->base_density >= 0 && p->base_density <= 1) ||
        !(p->first_density >= 0 && p->first_density <= 1))
        return sf_err_set(err, SF_EINVAL, "support model: densities outside [0, 1]");
    if (!(p->line_width_mm > 0 && p->line_width_mm <= 5) || !(p->speed_mm_s > 0) ||
        !(p->density_g_cm3 > 0) || !(p->sheath_mm >= 0) || !(p->connector_factor >= 0))
        return sf_err_set(err, SF_EINVAL,
                          "support model: line_width_mm, speed_mm_s, density_g_cm3 must be "
                          "positive, sheath_mm and connector_factor not negative");
    return SF_OK;
}

/* Solid intervals of every column: cell c holds iv[first[c] .. first[c+1]). */
struct ival {
    float lo, hi;
    float cos_lo; /* n . up of the facet the bottom lies on (< 0) */
};

struct cols {
    uint32_t *first;
    struct ival *iv;
};

static void
cols_release(struct cols *c)
{
    free(c->first);
    free(c->iv);
}

/* What the slicer keeps of the open layers (rims.h) in a grid's cells. */
struct open_cut {
    const struct open_sections *os;
    double layer_mm;
    uint32_t nu;
    struct layer_run {
        int32_t k0, k1;
    } * run; /* scratch: one interval's dropped layers */
    size_t cap;
};

/* Append interval iv of cell c to out (n of cap), less the open layers the
   slicer does not keep in c (cut NULL or empty: nothing dropped). */
static bool
push_ival(struct cols *out, uint32_t *n, size_t *cap, struct ival iv, size_t c,
          struct open_cut *cut)
{
    size_t n_run = 0;
    if (cut && cut->os->n_layers && iv.hi > iv.lo) {
        const struct open_sections *os = cut->os;
        double h = cut->layer_mm;
        uint32_t i = (uint32_t)(c % cut->nu), j = (uint32_t)(c / cut->nu);
        size_t a = 0, b = os->n_layers; /* the first open plane above iv.lo */
        while (a < b) {
            size_t mid = (a + b) / 2;
            if ((os->k[mid] + 0.5) * h <= iv.lo)
                a = mid + 1;
            else
                b = mid;
        }
        for (size_t l = a; l < os->n_layers && (os->k[l] + 0.5) * h < iv.hi; l++) {
            if (open_sections_keeps(os, (uint32_t)l, i, j))
                continue;
            int32_t k0 = os->k[l];
            /* a run of layers that keep nothing at all drops in one step */
            uint32_t to = os->empty_to[l];
            while (to > l && (os->k[to] + 0.5) * h >= iv.hi)
                to--;
            l = to;
            int32_t k1 = os->k[l];
            if (n_run && cut->run[n_run - 1].k1 == k0 - 1) {
                cut->run[n_run - 1].k1 = k1;
                continue;
            }
            void *o = cut->run;
            if (!mem_grow(&o, &cut->cap, n_run + 1, sizeof(*cut->run)))
                return false;
            cut->run = o;
            cut->run[n_run++] = (struct layer_run){ k0, k1 };
        }
    }
    for (size_t q = 0; q < n_run; q++) {
        /* dropped layers k0..k1 take the slab [k0 h, (k1 + 1) h]; what is left
           on either side is printed only if a layer plane cuts it */
        double h = cut->layer_mm;
        float lo = (float)(cut->run[q].k0 * h), hi = (float)((cut->run[q].k1 + 1) * h);
        if (lo > iv.lo && (cut->run[q].k0 - 0.5) * h > iv.lo) {
            void *o = out->iv;
            if (!mem_grow(&o, cap, *n + 1, sizeof(*out->iv)))
                return false;
            out->iv = o;
            out->iv[(*n)++] = (struct ival){ iv.lo, lo, iv.cos_lo };
        }
        if (hi >= iv.hi || (cut->run[q].k1 + 1.5) * h >= iv.hi)
            return true;
        iv.lo = hi > iv.lo ? hi : iv.lo; /* the layer above a dropped one rests on nothing */
        iv.cos_lo = -1;
    }
    void *o = out->iv;
    if (!mem_grow(&o, cap, *n + 1, sizeof(*out->iv)))
        return false;
    out->iv = o;
    out->iv[(*n)++] = iv;
    return true;
}

static int
cols_build(const struct ray_grid *g, struct open_cut *cut, struct cols *out, struct sf_err *err)
{
    size_t cells = (size_t)g->nu * g->nw, cap = g->n_hits + 1;
    out->first = mem_array(cells + 1, sizeof(uint32_t));
    /* at most one interval per hit, unless open layers split them */
    out->iv = mem_array(cap, sizeof(struct ival));
    if (!out->first || !out->iv) {
        cols_release(out);
        return sf_err_set(err, SF_ENOMEM, "support model: out of memory (%zu cells)", cells);
    }
    uint32_t n = 0;
    bool ok = true;
    for (size_t c = 0; c < cells && ok; c++) {
        out->first[c] = n;
        int depth = 0;
        float lo = 0, lo_cos = 0, last = 0;
        for (uint32_t k = g->first[c]; k < g->first[c + 1] && ok; k++) {
            const struct ray_hit *h = &g->hits[k];
            last = h->h;
            if (h->cos_up > 0) {
                if (depth > 0 && --depth == 0)
                    ok = push_ival(out, &n, &cap, (struct ival){ lo, h->h, lo_cos }, c, cut);
                else if (depth == 0) /* an exit with no entry: a floor, no material */
                    ok = push_ival(out, &n, &cap, (struct ival){ h->h, h->h, 0 }, c, cut);
            } else if (h->cos_up < 0) {
                if (depth++ == 0) {
                    lo = h->h;
                    lo_cos = h->cos_up;
                }
            }
        }
        if (depth > 0 && ok) /* an open top: material up to the last hit */
            ok = push_ival(out, &n, &cap, (struct ival){ lo, last, lo_cos }, c, cut);
    }
    if (cut) {
        free(cut->run);
        cut->run = NULL;
        cut->cap = 0;
    }
    if (!ok) {
        cols_release(out);
        return sf_err_set(err, SF_ENOMEM, "support model: out of memory (%zu cells)", cells);
    }
    out->first[cells] = n;
    return SF_OK;
}

static bool
solid_at(const struct cols *cs, size_t c, float z)
{
    for (uint32_t k = cs->first[c]; k < cs->first[c + 1]; k++)
        if (cs->iv[k].lo <= z && z <= cs->iv[k].hi && cs->iv[k].hi > cs->iv[k].lo)
            return true;
    return false;
}

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
overhangs(const struct ray_grid *g, const struct cols *cs, uint32_t i, uint32_t j, float lo,
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
            if (solid_at(cs, (size_t)nj * g->nu + (size_t)ni, (float)(lo - r * slope)))
                return false;
        }
    }
    return true;
}

/* A bottom that needs a column: (cell, bottom, floor). */
struct contact {
    uint32_t cell;
    float top;   /* the overhanging bottom, mm */
    float floor; /* top of the solid below, 0 for the bed */
    bool dense;  /* overhangs by more than interface_step_mm a layer: dense interface */
};

/*
 * PrusaSlicer's dont_support_bridges (SupportMaterial.cpp
 * remove_bridges_from_contacts, LayerRegion.cpp process_external_surfaces,
 * BridgeDetector.cpp), on the raster.  The new area of layer L (cells whose
 * solid interval starts in L) falls into 8-connected regions.  Cells within
 * the perimeters' width of the layer's outline are perimeters; the rest is
 * the bottom fill.  A region is a bridge when some straight line across its
 * fill runs from material of layer L-1 to material of layer L-1 (the
 * detector's anchored lines; 8 lattice directions instead of its 5-degree
 * steps).  The direction with the most anchored fill wins.  Then the fill is
 * not supported, bar a 1.5 mm band along the edges where lines of that
 * direction end in the air (its unsupported edges; edges parallel to the
 * direction are free), and perimeter cells are not supported where a line of
 * that direction through the region is anchored at both ends (a straight
 * bridging perimeter).  Regions with no anchored line keep all their support.
 */

#define BRIDGE_DIRS 8
static const int bridge_dir[BRIDGE_DIRS][2] = { { 1, 0 }, { 2, 1 },  { 1, 1 },  { 1, 2 },
                                                { 0, 1 }, { -1, 2 }, { -1, 1 }, { -2, 1 } };

/* Layer index whose slice (at its middle height) first holds a bottom at lo. */
static int32_t
bottom_layer(float lo, double h)
{
    return (int32_t)ceil(lo / h - 0.5);
}

/* Scratch for one layer's regions: member marks are stamped with a layer tag. */
struct bridge_ctx {
    const struct ray_grid *g;
    const struct cols *cs;
    double h;
    int32_t k;         /* the layer being processed */
    uint32_t ltag;     /* its tag */
    uint32_t *mtag[2]; /* cells: ltag when mval[0] (layer k) / mval[1] (k - 1) is known */
    uint8_t *mval[2];  /* cells: solid at the middle of that layer */
    uint32_t *tag;     /* cells: tag of the layer whose new area holds it */
    uint32_t *rtag;    /* cells: tag of the region being processed */
    uint8_t *kind;     /* cells: 1 perimeter, 2 fill, |4 bridged, |8 unsupported edge */
    uint32_t *queue;   /* region cells */
    uint32_t *rimtag;  /* cells: tag of the region whose fill this cell of layer L-1 borders */
    uint32_t *rim;     /* those cells */
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
    bool v = solid_at(b->cs, c, (float)((k + 0.5) * b->h));
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

/*
 * Lines of direction d over the region's cells of a kind in mask, taken
 * run by run.  *cov sums the cells of runs anchored at both ends
 * (*longest the longest).  With mark set, the cells of kind mark_kind on
 * runs anchored at both ends get bit 4; with mark_kind 0, a run's free ends
 * get bit 8 instead.
 */
static void
bridge_lines(struct bridge_ctx *b, const uint32_t *cells, size_t n, uint32_t rt, int32_t k,
             const int d[2], uint8_t mask, bool mark, uint8_t mark_kind, size_t *cov,
             size_t *longest)
{
    const struct ray_grid *g = b->g;
#define MEMBER(ii, jj)                                                                             \
    (in_grid(g, ii, jj) && b->rtag[(size_t)(jj)*g->nu + (size_t)(ii)] == rt &&                     \
     (b->kind[(size_t)(jj)*g->nu + (size_t)(ii)] & mask))
    *cov = 0;
    *longest = 0;
    for (size_t q = 0; q < n; q++) {
        long i0 = cells[q] % g->nu, j0 = cells[q] / g->nu;
        if (!MEMBER(i0, j0) || MEMBER(i0 - d[0], j0 - d[1]))
            continue; /* not the start of a run */
        long i = i0, j = j0;
        size_t len = 0;
        while (MEMBER(i + d[0], j + d[1])) {
            i += d[0], j += d[1];
            len++;
        }
        len++;
        bool a0 = bridge_anchor(b, i0 - d[0], j0 - d[1], k);
        bool a1 = bridge_anchor(b, i + d[0], j + d[1], k);
        if (a0 && a1) {
            *cov += len;
            if (len > *longest)
                *longest = len;
        }
        if (!mark)
            continue;
        if (a0 && a1) {
            for (long x = i0, y = j0, s = 0; s < (long)len; s++, x += d[0], y += d[1])
                if (b->kind[(size_t)y * g->nu + (size_t)x] & mark_kind)
                    b->kind[(size_t)y * g->nu + (size_t)x] |= 4;
        } else {
            if (!a0 && !mark_kind)
                b->kind[(size_t)j0 * g->nu + (size_t)i0] |= 8;
            if (!a1 && !mark_kind)
                b->kind[(size_t)j * g->nu + (size_t)i] |= 8;
        }
    }
#undef MEMBER
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
    int best = -1;
    size_t best_cov = 0, best_long = 0;
    for (int d = 0; d < BRIDGE_DIRS; d++) {
        size_t cov, longest;
        bridge_lines(b, cells, n, rt, k, bridge_dir[d], 2, false, 0, &cov, &longest);
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
    bridge_lines(b, cells, n, rt, k, bridge_dir[best], 2, true, 0, &cov, &longest);
    /* ... and straight perimeters anchored at both ends */
    bridge_lines(b, cells, n, rt, k, bridge_dir[best], 3, true, 1, &cov, &longest);
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

/*
 * Drop the contacts that PrusaSlicer's bridge detection leaves unsupported.
 * Only the layers that have contacts, and of those only the regions that
 * hold a contact, are looked at: a region's verdict matters to its own
 * contacts alone.
 */
static int
remove_bridges(const struct ray_grid *g, const struct cols *cs, const struct supmodel_params *p,
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
    b.tag = mem_calloc(cells, sizeof(uint32_t));
    b.rtag = mem_calloc(cells, sizeof(uint32_t));
    b.kind = mem_calloc(cells, 1);
    b.queue = mem_array(cells, sizeof(uint32_t));
    b.rimtag = mem_calloc(cells, sizeof(uint32_t));
    b.rim = mem_array(cells, sizeof(uint32_t));
    for (int s = 0; s < 2; s++) {
        b.mtag[s] = mem_calloc(cells, sizeof(uint32_t));
        b.mval[s] = mem_array(cells, 1);
    }
    uint8_t *gone = mem_calloc(*n_ct ? *n_ct : 1, 1);
    int rc = SF_OK;
    if (!kk || !it || !b.tag || !b.rtag || !b.kind || !b.queue || !b.rimtag || !b.rim ||
        !b.mtag[0] || !b.mtag[1] || !b.mval[0] || !b.mval[1] || !gone) {
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
    free(b.tag);
    free(b.rtag);
    free(b.kind);
    free(b.queue);
    free(b.rimtag);
    free(b.rim);
    for (int s = 0; s < 2; s++) {
        free(b.mtag[s]);
        free(b.mval[s]);
    }
    free(gone);
    return rc;
}

/* A column of support in layer indices [k0, k1) of snap cell blk. */
struct run {
    uint32_t blk;
    int32_t k0, k1;
};

static int
run_cmp(const void *a, const void *b)
{
    const struct run *x = a, *y = b;
    if (x->blk != y->blk)
        return x->blk < y->blk ? -1 : 1;
    return (x->k0 > y->k0) - (x->k0 < y->k0);
}

static int
find_contacts(const struct ray_grid *g, const struct cols *cs, const struct supmodel_params *p,
              struct contact **out, size_t *n_out, struct sf_err *err)
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

/* A column range in mm of snap cell blk. */
struct frun {
    uint32_t blk;
    float lo, hi;
};

static int
frun_cmp(const void *a, const void *b)
{
    const struct frun *x = a, *y = b;
    if (x->blk != y->blk)
        return x->blk < y->blk ? -1 : 1;
    return (x->lo > y->lo) - (x->lo < y->lo);
}

static bool
push_column(struct support_column **v, size_t *n, size_t *cap, struct support_column c)
{
    void *o = *v;
    if (!mem_grow(&o, cap, *n + 1, sizeof(**v)))
        return false;
    *v = o;
    (*v)[(*n)++] = c;
    return true;
}

/*
 * Snap the contacts' columns to the grid as PrusaSlicer does (grid style):
 * every cell of a snap cell that a column touches gets the snap cell's
 * merged ranges wherever the part leaves room, and, as the projection goes
 * down until the part stops it, reaches down to its own floor.
 */
static int
snap_columns(const struct ray_grid *g, const struct cols *cs, const struct contact *ct, size_t n,
             uint32_t bs, struct support_column **cols, size_t *n_cols, struct sf_err *err)
{
    uint32_t nbu = (g->nu + bs - 1) / bs;
    struct frun *r = mem_array(n ? n : 1, sizeof(*r));
    if (!r)
        return sf_err_set(err, SF_ENOMEM, "support model: out of memory (columns)");
    for (size_t k = 0; k < n; k++) {
        uint32_t c = ct[k].cell, i = c % g->nu, j = c / g->nu;
        r[k] = (struct frun){ (j / bs) * nbu + i / bs, ct[k].floor, ct[k].top };
    }
    qsort(r, n, sizeof(*r), frun_cmp);
    size_t m = 0;
    for (size_t k = 0; k < n; k++) {
        if (m > 0 && r[m - 1].blk == r[k].blk && r[k].lo <= r[m - 1].hi) {
            if (r[k].hi > r[m - 1].hi)
                r[m - 1].hi = r[k].hi;
        } else {
            r[m++] = r[k];
        }
    }
    struct support_column *v = NULL;
    size_t nv = 0, cap = 0;
    int rc = SF_OK;
    for (size_t k = 0; k < m && rc == SF_OK; k++) {
        uint32_t bi = r[k].blk % nbu, bj = r[k].blk / nbu;
        for (uint32_t j = bj * bs; j < (bj + 1) * bs && j < g->nw && rc == SF_OK; j++) {
            for (uint32_t i = bi * bs; i < (bi + 1) * bs && i < g->nu && rc == SF_OK; i++) {
                uint32_t c = j * g->nu + i;
                /* the cell's free gaps: from the bed or a solid's top to the next bottom */
                float floor_mm = 0;
                for (uint32_t q = cs->first[c]; q <= cs->first[c + 1] && rc == SF_OK; q++) {
                    bool last = q == cs->first[c + 1];
                    if (!last && !(cs->iv[q].hi > cs->iv[q].lo))
                        continue;
                    float top = last ? r[k].hi : cs->iv[q].lo;
                    if (top > r[k].lo && floor_mm < r[k].hi) {
                        struct support_column col = { c, floor_mm, top < r[k].hi ? top : r[k].hi,
                                                      0 };
                        if (col.hi > col.lo && !push_column(&v, &nv, &cap, col))
                            rc = sf_err_set(err, SF_ENOMEM, "support model: out of memory");
                    }
                    if (!last)
                        floor_mm = cs->iv[q].hi;
                }
            }
        }
    }
    free(r);
    if (rc) {
        free(v);
        return rc;
    }
    *cols = v;
    *n_cols = nv;
    return SF_OK;
}

/*
 * The dense-interface bands of the snapped columns: under every dense
 * contact, its snap cell's columns print interface_layers dense layers
 * (PrusaSlicer's fill_contact_layer fills the whole cell), in the layers the
 * columns occupy (the gaps applied: piece [lo, hi] occupies lo + gap_z when
 * lo is on the part, up to hi - gap_z).
 */
static int
snap_bands(const struct ray_grid *g, const struct supmodel_params *p, const struct contact *ct,
           size_t n, uint32_t bs, const struct support_column *cols, size_t n_cols,
           struct support_column **bands, size_t *n_bands, struct sf_err *err)
{
    size_t cells = (size_t)g->nu * g->nw;
    uint32_t nbu = (g->nu + bs - 1) / bs;
    double gap = p->gap_z_mm, dh = p->interface_layers * p->layer_mm;
    struct frun *r = mem_array(n ? n : 1, sizeof(*r));
    uint32_t *cfirst = mem_calloc(cells + 1, sizeof(uint32_t));
    uint32_t *cidx = mem_array(n_cols ? n_cols : 1, sizeof(uint32_t));
    struct support_column *v = NULL;
    size_t nv = 0, cap = 0, m = 0;
    int rc = SF_OK;
    if (!r || !cfirst || !cidx) {
        rc = sf_err_set(err, SF_ENOMEM, "support model: out of memory (bands)");
        goto done;
    }
    for (size_t k = 0; k < n; k++) {
        if (!ct[k].dense || dh <= 0)
            continue;
        uint32_t c = ct[k].cell, i = c % g->nu, j = c / g->nu;
        r[m++] = (struct frun){ (j / bs) * nbu + i / bs, (float)(ct[k].top - gap - dh),
                                (float)(ct[k].top - gap) };
    }
    qsort(r, m, sizeof(*r), frun_cmp);
    size_t mm = 0;
    for (size_t k = 0; k < m; k++) {
        if (mm > 0 && r[mm - 1].blk == r[k].blk && r[k].lo <= r[mm - 1].hi) {
            if (r[k].hi > r[mm - 1].hi)
                r[mm - 1].hi = r[k].hi;
        } else {
            r[mm++] = r[k];
        }
    }
    /* the column pieces by cell */
    for (size_t q = 0; q < n_cols; q++)
        cfirst[cols[q].cell + 1]++;
    for (size_t c = 0; c < cells; c++)
        cfirst[c + 1] += cfirst[c];
    for (size_t q = 0; q < n_cols; q++)
        cidx[cfirst[cols[q].cell]++] = (uint32_t)q;
    for (size_t c = cells; c > 0; c--) /* back to the starts */
        cfirst[c] = cfirst[c - 1];
    cfirst[0] = 0;
    for (size_t k = 0; k < mm && rc == SF_OK; k++) {
        uint32_t bi = r[k].blk % nbu, bj = r[k].blk / nbu;
        for (uint32_t j = bj * bs; j < (bj + 1) * bs && j < g->nw && rc == SF_OK; j++) {
            for (uint32_t i = bi * bs; i < (bi + 1) * bs && i < g->nu && rc == SF_OK; i++) {
                uint32_t c = j * g->nu + i;
                for (uint32_t q = cfirst[c]; q < cfirst[c + 1] && rc == SF_OK; q++) {
                    const struct support_column *pc = &cols[cidx[q]];
                    double lo = pc->lo > 0 ? pc->lo + gap : 0, hi = pc->hi - gap;
                    lo = lo > r[k].lo ? lo : r[k].lo;
                    hi = hi < r[k].hi ? hi : r[k].hi;
                    if (hi - lo < 0.5 * p->layer_mm)
                        continue;
                    struct support_column b = { c, (float)lo, (float)hi, 0 };
                    if (!push_column(&v, &nv, &cap, b))
                        rc = sf_err_set(err, SF_ENOMEM, "support model: out of memory (bands)");
                }
            }
        }
    }
done:
    free(r);
    free(cfirst);
    free(cidx);
    if (rc) {
        free(v);
        return rc;
    }
    *bands = v;
    *n_bands = nv;
    return SF_OK;
}

int
supmodel_columns(const struct ray_grid *g, const struct supmodel_params *p,
                 struct support_column **cols, size_t *n_cols, struct support_column **bands,
                 size_t *n_bands, struct sf_err *err)
{
    *cols = NULL;
    *n_cols = 0;
    if (bands) {
        *bands = NULL;
        *n_bands = 0;
    }
    int rc = supmodel_params_check(p, err);
    if (rc)
        return rc;
    struct cols cs;
    if ((rc = cols_build(g, NULL, &cs, err)))
        return rc;
    struct contact *ct = NULL;
    size_t n = 0;
    rc = find_contacts(g, &cs, p, &ct, &n, err);
    uint32_t bs = p->snap_mm > g->pitch ? (uint32_t)lround(p->snap_mm / g->pitch) : 1;
    if (!rc && bs > 1) {
        rc = snap_columns(g, &cs, ct, n, bs, cols, n_cols, err);
        if (!rc && bands)
            rc = snap_bands(g, p, ct, n, bs, *cols, *n_cols, bands, n_bands, err);
        if (rc) {
            free(*cols);
            *cols = NULL;
            *n_cols = 0;
        }
    } else if (!rc) {
        struct support_column *out = mem_array(n ? n : 1, sizeof(*out));
        if (!out) {
            rc = sf_err_set(err, SF_ENOMEM, "support model: out of memory");
        } else {
            for (size_t k = 0; k < n; k++)
                out[k] = (struct support_column){ ct[k].cell, ct[k].floor, ct[k].top, 0 };
            *cols = out;
            *n_cols = n;
        }
    }
    free(ct);
    cols_release(&cs);
    return rc;
}

/* Sort runs by snap cell and k0 (a counting sort by cell, then each cell's
   few runs by k0) and merge each snap cell's overlapping ones into runs;
   returns how many are left.  cnt holds n_blk + 1 counters, tmp n runs. */
static size_t
merge_runs(struct run *runs, size_t n, size_t n_blk, uint32_t *cnt, struct run *tmp)
{
    memset(cnt, 0, (n_blk + 1) * sizeof(*cnt));
    for (size_t k = 0; k < n; k++)
        cnt[runs[k].blk + 1]++;
    for (size_t b = 0; b < n_blk; b++)
        cnt[b + 1] += cnt[b];
    for (size_t k = 0; k < n; k++)
        tmp[cnt[runs[k].blk]++] = runs[k];
    /* cnt[b] is now the end of cell b's runs */
    size_t m = 0;
    for (size_t b = 0, a = 0; b < n_blk; b++) {
        size_t e = cnt[b];
        if (e - a > 32) {
            qsort(tmp + a, e - a, sizeof(*tmp), run_cmp);
        } else {
            for (size_t i = a + 1; i < e; i++) { /* insertion sort by k0 */
                struct run r = tmp[i];
                size_t j = i;
                for (; j > a && tmp[j - 1].k0 > r.k0; j--)
                    tmp[j] = tmp[j - 1];
                tmp[j] = r;
            }
        }
        for (size_t k = a; k < e; k++) {
            if (m > 0 && runs[m - 1].blk == tmp[k].blk && tmp[k].k0 <= runs[m - 1].k1) {
                if (tmp[k].k1 > runs[m - 1].k1)
                    runs[m - 1].k1 = tmp[k].k1;
            } else {
                runs[m++] = tmp[k];
            }
        }
        a = e;
    }
    return m;
}

/* Layers of [lo, hi] whose middle (k + 0.5) h lies inside, clipped to [k0, k1). */
static int32_t
solid_layers(struct ival iv, double h, int32_t k0, int32_t k1)
{
    if (!(iv.hi > iv.lo))
        return 0;
    int32_t a = (int32_t)ceil(iv.lo / h - 0.5), b = (int32_t)floor(iv.hi / h - 0.5) + 1;
    a = a > k0 ? a : k0;
    b = b < k1 ? b : k1;
    return b > a ? b - a : 0;
}

/* Layers covered by exactly one of two sorted, disjoint range lists. */
static int64_t
xor_len(const struct run *a, size_t na, const struct run *b, size_t nb)
{
    int64_t la = 0, lb = 0, both = 0;
    for (size_t i = 0; i < na; i++)
        la += a[i].k1 - a[i].k0;
    for (size_t i = 0; i < nb; i++)
        lb += b[i].k1 - b[i].k0;
    size_t i = 0, k = 0;
    while (i < na && k < nb) {
        int32_t lo = a[i].k0 > b[k].k0 ? a[i].k0 : b[k].k0;
        int32_t hi = a[i].k1 < b[k].k1 ? a[i].k1 : b[k].k1;
        if (hi > lo)
            both += hi - lo;
        if (a[i].k1 < b[k].k1)
            i++;
        else
            k++;
    }
    return la + lb - 2 * both;
}

static int
eval_cut(const struct ray_grid *g, const struct supmodel_params *p, struct open_cut *cut,
         struct supmodel_result *out, struct sf_err *err)
{
    memset(out, 0, sizeof(*out));
    int rc = supmodel_params_check(p, err);
    if (rc)
        return rc;
    double h = p->layer_mm, px = g->pitch, cell_a = px * px;
    struct cols cs;
    if ((rc = cols_build(g, cut, &cs, err)))
        return rc;
    struct contact *ct = NULL;
    size_t n_ct = 0;
    if ((rc = find_contacts(g, &cs, p, &ct, &n_ct, err))) {
        cols_release(&cs);
        return rc;
    }
    uint32_t bs = p->snap_mm > px ? (uint32_t)lround(p->snap_mm / px) : 1;
    uint32_t nbu = (g->nu + bs - 1) / bs, nbw = (g->nw + bs - 1) / bs;
    size_t n_blk = (size_t)nbu * nbw;
    struct run *runs = mem_array(n_ct ? n_ct : 1, sizeof(*runs));
    struct run *iruns = mem_array(n_ct ? n_ct : 1, sizeof(*iruns));
    uint32_t *bfirst = mem_array(n_blk + 1, sizeof(uint32_t));
    struct run *tmp = mem_array(n_ct ? n_ct : 1, sizeof(*tmp));
    if (!runs || !iruns || !bfirst || !tmp) {
        rc = sf_err_set(err, SF_ENOMEM, "support model: out of memory");
        goto done;
    }
    /* the columns, their contact interface and the classic shadow volume */
    size_t n_runs = 0, n_iruns = 0;
    for (size_t k = 0; k < n_ct; k++) {
        double top = ct[k].top - p->gap_z_mm;
        double bot = ct[k].floor > 0 ? ct[k].floor + p->gap_z_mm : 0;
        int32_t k0 = (int32_t)lround(bot / h), k1 = (int32_t)lround(top / h);
        if (k1 <= k0)
            continue;
        out->n_contacts++;
        out->contact_area_mm2 += cell_a;
        out->shadow_mm3 += (top - bot) * cell_a;
        int32_t nif = k1 - k0 < p->interface_layers ? k1 - k0 : p->interface_layers;
        uint32_t c = ct[k].cell, i = c % g->nu, j = c / g->nu, blk = (j / bs) * nbu + i / bs;
        /* PrusaSlicer snaps contacts to the grid too (fill_contact_layer): the dense
           layers under a contact fill its whole snap cell */
        if (ct[k].dense)
            iruns[n_iruns++] = (struct run){ blk, k1 - nif, k1 };
        runs[n_runs++] = (struct run){ blk, k0, k1 };
    }
    /* merge each snap cell's columns (and interfaces) into disjoint layer ranges */
    n_iruns = merge_runs(iruns, n_iruns, n_blk, bfirst, tmp);
    n_runs = merge_runs(runs, n_runs, n_blk, bfirst, tmp);
    for (size_t b = 0, k = 0; b <= n_blk; b++) {
        while (k < n_runs && runs[k].blk < b)
            k++;
        bfirst[b] = (uint32_t)k;
    }
    /* filled cell-layers (cells of the snap cell where the part is not), landings */
    double filled = 0, first = 0, land = 0;
    for (size_t r = 0; r < n_runs; r++) {
        uint32_t b = runs[r].blk, bi = b % nbu, bj = b / nbu;
        int32_t k0 = runs[r].k0, k1 = runs[r].k1;
        /* the projection goes on down each cell until the part (or the range
           below in the same snap cell) stops it */
        int32_t below = r > 0 && runs[r - 1].blk == b ? runs[r - 1].k1 : 0;
        for (uint32_t j = bj * bs; j < (bj + 1) * bs && j < g->nw; j++) {
            for (uint32_t i = bi * bs; i < (bi + 1) * bs && i < g->nu; i++) {
                size_t c = (size_t)j * g->nu + i;
                int64_t free_l = k1 - k0;
                bool solid_k0 = false;
                float floor_mm = 0;
                for (uint32_t q = cs.first[c]; q < cs.first[c + 1]; q++) {
                    struct ival iv = cs.iv[q];
                    free_l -= solid_layers(iv, h, k0, k1);
                    solid_k0 |= solid_layers(iv, h, k0, k0 + 1) > 0;
                    if (iv.hi > iv.lo && iv.hi <= (k0 + 0.5) * h && iv.hi > floor_mm)
                        floor_mm = iv.hi;
                    /* a top surface the range comes down onto: a bottom contact */
                    int32_t kt = (int32_t)lround(iv.hi / h);
                    if (iv.hi > 0 && kt >= k0 - 2 && kt < k1 && kt > 0)
                        land += 1;
                }
                int32_t kb = k0;
                if (!solid_k0) {
                    int32_t kf = floor_mm > 0 ? (int32_t)lround((floor_mm + p->gap_z_mm) / h) : 0;
                    kb = kf > below ? kf : below;
                    if (kb < k0) {
                        free_l += k0 - kb;
                        if (floor_mm > 0 && kf >= below && kf < k0 - 2)
                            land += 1;
                    } else {
                        kb = k0;
                    }
                }
                filled += (double)(free_l > 0 ? free_l : 0);
                first += kb == 0 && !solid_k0;
            }
        }
    }
    /* outline of the filled snap cells, layer by layer */
    double side = bs * px, outline = 0;
    for (uint32_t bj = 0; bj < nbw; bj++) {
        for (uint32_t bi = 0; bi < nbu; bi++) {
            size_t b = (size_t)bj * nbu + bi;
            const struct run *ra = runs + bfirst[b];
            size_t na = bfirst[b + 1] - bfirst[b];
            if (bi + 1 < nbu)
                outline +=
                    (double)xor_len(ra, na, runs + bfirst[b + 1], bfirst[b + 2] - bfirst[b + 1]);
            else
                outline += (double)xor_len(ra, na, NULL, 0);
            if (bi == 0)
                outline += (double)xor_len(ra, na, NULL, 0);
            if (bj + 1 < nbw)
                outline += (double)xor_len(ra, na, runs + bfirst[b + nbu],
                                           bfirst[b + nbu + 1] - bfirst[b + nbu]);
            else
                outline += (double)xor_len(ra, na, NULL, 0);
            if (bj == 0)
                outline += (double)xor_len(ra, na, NULL, 0);
        }
    }
    outline *= side; /* mm of outline summed over layers */
    /* the dense cell-layers: the snap cells' free cells under each contact */
    double iface = 0;
    for (size_t r = 0; r < n_iruns; r++) {
        uint32_t b = iruns[r].blk, bi = b % nbu, bj = b / nbu;
        for (uint32_t j = bj * bs; j < (bj + 1) * bs && j < g->nw; j++) {
            for (uint32_t i = bi * bs; i < (bi + 1) * bs && i < g->nu; i++) {
                size_t c = (size_t)j * g->nu + i;
                int64_t free_l = iruns[r].k1 - iruns[r].k0;
                for (uint32_t q = cs.first[c]; q < cs.first[c + 1]; q++)
                    free_l -= solid_layers(cs.iv[q], h, iruns[r].k0, iruns[r].k1);
                iface += (double)(free_l > 0 ? free_l : 0);
            }
        }
    }
    filled -= iface; /* printed dense, not sparse */
    iface *= cell_a * h;
    out->base_mm3 = filled * cell_a * h * p->base_density +
                    first * cell_a * h * max_d(0, p->first_density - p->base_density);
    out->interface_mm3 = iface + land * cell_a * p->interface_layers * h;
    out->outline_mm3 = outline * h * (p->sheath_mm + p->connector_factor * p->line_width_mm);
    double vol = out->base_mm3 + out->interface_mm3 + out->outline_mm3;
    out->grams = vol * p->density_g_cm3 * 1e-3;
    out->time_s = vol / (h * p->line_width_mm) / p->speed_mm_s;
    uint32_t top_k = 0;
    for (size_t k = 0; k < g->n_hits; k++)
        top_k = (uint32_t)max_d(top_k, ceil(g->hits[k].h / h));
    out->n_layers = top_k;
done:
    free(runs);
    free(iruns);
    free(bfirst);
    free(tmp);
    free(ct);
    cols_release(&cs);
    return rc;
}

int
supmodel_eval_grid(const struct ray_grid *g, const struct supmodel_params *p,
                   struct supmodel_result *out, struct sf_err *err)
{
    return eval_cut(g, p, NULL, out, err);
}

double
supmodel_raster_pitch(const struct supmodel_params *p)
{
    if (!(p->snap_mm > p->pitch_mm))
        return p->pitch_mm;
    return p->snap_mm / ceil(p->snap_mm / p->pitch_mm - 1e-9);
}

int
supmodel_eval(struct raycast *rc, struct vec3 up, const struct supmodel_params *p,
              struct supmodel_result *out, struct sf_err *err)
{
    memset(out, 0, sizeof(*out));
    int r = supmodel_params_check(p, err);
    if (r)
        return r;
    struct ray_grid g;
    if ((r = raycast_grid(rc, v3_normalize(up), supmodel_raster_pitch(p), &g, err)))
        return r;
    struct open_sections os = { 0 };
    if (p->open_gap_mm > 0) {
        struct rim_frame f = {
            g.up, g.u, g.w, g.u0, g.w0, g.pitch, g.base, p->layer_mm, g.nu, g.nw
        };
        r = rims_open_sections(raycast_rims(rc), raycast_mesh(rc), &f, p->open_gap_mm, &os, err);
    }
    struct open_cut cut = { &os, p->layer_mm, g.nu, NULL, 0 };
    if (r == SF_OK)
        r = eval_cut(&g, p, os.n_layers ? &cut : NULL, out, err);
    open_sections_release(&os);
    ray_grid_release(&g);
    return r;
}

int
supmodel_of_mesh(const struct mesh *m, struct vec3 up, const struct supmodel_params *p,
                 struct supmodel_result *out, struct sf_err *err)
{
    memset(out, 0, sizeof(*out));
    struct raycast *rc = raycast_new(m, err);
    if (!rc)
        return err && err->code ? err->code : SF_ENOMEM;
    int r = supmodel_eval(rc, up, p, out, err);
    raycast_free(rc);
    return r;
}

int
supmodel_peers_rise(const struct mesh *before, const struct mesh *after, double angle_deg,
                    bool *rises, enum supmodel_slicer *slicer, struct sf_err *err)
{
    *rises = false;
    struct rims r;
    int rc = rims_build(before, &r, err);
    if (rc)
        return rc;
    bool open = r.n_edges > 0;
    rims_release(&r);
    if (!open)
        return SF_OK;
    /* one scene a part, both slicers' rules on each */
    struct raycast *rb = raycast_new(before, err), *ra = rb ? raycast_new(after, err) : NULL;
    rc = ra ? SF_OK : err && err->code ? err->code : SF_ENOMEM;
    for (int s = 0; s < 2 && rc == SF_OK && !*rises; s++) {
        struct supmodel_params p;
        struct supmodel_result a, b;
        supmodel_params_default(&p, s ? SUPMODEL_CURA : SUPMODEL_PRUSA);
        p.angle_deg = angle_deg;
        if ((rc = supmodel_eval(rb, v3(0, 0, 1), &p, &a, err)) == SF_OK &&
            (rc = supmodel_eval(ra, v3(0, 0, 1), &p, &b, err)) == SF_OK) {
            *rises = b.grams > a.grams;
            if (slicer)
                *slicer = p.slicer;
        }
    }
    raycast_free(ra);
    raycast_free(rb);
    return rc;
}
