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
    p->pitch_mm = 0.5;
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
        /* dont_support_bridges is on in the peers' runs, but this raster test of it
           ranked anchor's 21 cached directions worse (Spearman 0.949 against 0.958
           without): off until it follows BridgeDetector more closely */
        p->bridges = false;
    } else {
        /* zigzag at 2.667 mm line distance: 0.4 / 2.667; join distance 2 mm */
        p->gap_xy_mm = 0.7;
        p->snap_mm = 2;
        p->base_density = 0.15;
        p->first_density = 0.15;
        p->connector_factor = 0.6;
    }
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

static int
cols_build(const struct ray_grid *g, struct cols *out, struct sf_err *err)
{
    size_t cells = (size_t)g->nu * g->nw;
    out->first = mem_array(cells + 1, sizeof(uint32_t));
    /* at most one interval per hit */
    out->iv = mem_array(g->n_hits + 1, sizeof(struct ival));
    if (!out->first || !out->iv) {
        cols_release(out);
        return sf_err_set(err, SF_ENOMEM, "support model: out of memory (%zu cells)", cells);
    }
    uint32_t n = 0;
    for (size_t c = 0; c < cells; c++) {
        out->first[c] = n;
        int depth = 0;
        float lo = 0, last = 0;
        for (uint32_t k = g->first[c]; k < g->first[c + 1]; k++) {
            const struct ray_hit *h = &g->hits[k];
            last = h->h;
            if (h->cos_up > 0) {
                if (depth > 0 && --depth == 0)
                    out->iv[n++] = (struct ival){ lo, h->h };
                else if (depth == 0) /* an exit with no entry: a floor, no material */
                    out->iv[n++] = (struct ival){ h->h, h->h };
            } else if (h->cos_up < 0) {
                if (depth++ == 0)
                    lo = h->h;
            }
        }
        if (depth > 0) /* an open top: material up to the last hit */
            out->iv[n++] = (struct ival){ lo, last };
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

/* tan of the steepest face angle from the horizontal that still overhangs */
static double
slope_limit(const struct supmodel_params *p)
{
    if (p->slicer == SUPMODEL_PRUSA) {
        /* support_material_threshold T = round(90 - alpha), at least 1; d = h / tan(T + 1) */
        double t = floor(90 - p->angle_deg + 0.5);
        if (t < 1)
            t = 1;
        if (t + 1 >= 90)
            return 1e6; /* alpha 0: every bottom that is not a vertical wall overhangs */
        return tan((t + 1) * M_PI / 180);
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

/* Bottom of the interval of cell c that holds height z, or NAN. */
static float
bottom_at(const struct cols *cs, size_t c, float z)
{
    for (uint32_t k = cs->first[c]; k < cs->first[c + 1]; k++)
        if (cs->iv[k].lo <= z && z <= cs->iv[k].hi && cs->iv[k].hi > cs->iv[k].lo)
            return cs->iv[k].lo;
    return NAN;
}

/* Walking from (i, j) along (di, dj) over the same flat bottom (within a layer
   of lo): does it end on material of the layer below (an anchor) rather than
   at a free edge? */
static bool
anchored(const struct ray_grid *g, const struct cols *cs, uint32_t i, uint32_t j, int di, int dj,
         float lo, float h)
{
    long x = i, y = j;
    for (;;) {
        x += di, y += dj;
        if (x < 0 || y < 0 || x >= (long)g->nu || y >= (long)g->nw)
            return false;
        size_t c = (size_t)y * g->nu + (size_t)x;
        if (solid_at(cs, c, lo - 0.5f * h))
            return true;
        float b = bottom_at(cs, c, lo + 0.5f * h);
        if (isnan(b) || fabsf(b - lo) > h)
            return false;
    }
}

/* PrusaSlicer's dont_support_bridges: a flat bottom that some straight line
   through it crosses from material below to material below is bridged. */
static bool
bridged(const struct ray_grid *g, const struct cols *cs, uint32_t i, uint32_t j, float lo, float h)
{
    static const int axes[4][2] = { { 1, 0 }, { 0, 1 }, { 1, 1 }, { 1, -1 } };
    for (int a = 0; a < 4; a++)
        if (anchored(g, cs, i, j, axes[a][0], axes[a][1], lo, h) &&
            anchored(g, cs, i, j, -axes[a][0], -axes[a][1], lo, h))
            return true;
    return false;
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

/* Walk the contacts: call back for each (cell, bottom, floor) that needs a column. */
struct contact {
    uint32_t cell;
    float top;   /* the overhanging bottom, mm */
    float floor; /* top of the solid below, 0 for the bed */
};

static int
find_contacts(const struct ray_grid *g, const struct cols *cs, const struct supmodel_params *p,
              struct contact **out, size_t *n_out, struct sf_err *err)
{
    double slope = slope_limit(p), h = p->layer_mm;
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
                if (!overhangs(g, cs, i, j, iv.lo, slope))
                    continue;
                if (p->bridges && bridged(g, cs, i, j, iv.lo, (float)h))
                    continue;
                void *o = v;
                if (!mem_grow(&o, &cap, n + 1, sizeof(*v))) {
                    free(v);
                    return sf_err_set(err, SF_ENOMEM, "support model: out of memory");
                }
                v = o;
                v[n++] = (struct contact){ (uint32_t)c, iv.lo, below };
            }
        }
    }
    *out = v;
    *n_out = n;
    return SF_OK;
}

/* The contacts of grid g under p's rules (*ct freed by the caller, also on error). */
static int
grid_contacts(const struct ray_grid *g, const struct supmodel_params *p, struct contact **ct,
              size_t *n, struct sf_err *err)
{
    int rc = supmodel_params_check(p, err);
    if (rc)
        return rc;
    struct cols cs;
    if ((rc = cols_build(g, &cs, err)))
        return rc;
    rc = find_contacts(g, &cs, p, ct, n, err);
    cols_release(&cs);
    return rc;
}

int
supmodel_columns(const struct ray_grid *g, const struct supmodel_params *p,
                 struct support_column **cols, size_t *n_cols, struct sf_err *err)
{
    *cols = NULL;
    *n_cols = 0;
    struct contact *ct = NULL;
    size_t n = 0;
    int rc = grid_contacts(g, p, &ct, &n, err);
    struct support_column *out = rc ? NULL : mem_array(n ? n : 1, sizeof(*out));
    if (!rc && !out)
        rc = sf_err_set(err, SF_ENOMEM, "support model: out of memory");
    if (out) {
        for (size_t k = 0; k < n; k++)
            out[k] = (struct support_column){ ct[k].cell, ct[k].floor, ct[k].top, 0 };
        *cols = out;
        *n_cols = n;
    }
    free(ct);
    return rc;
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

int
supmodel_eval_grid(const struct ray_grid *g, const struct supmodel_params *p,
                   struct supmodel_result *out, struct sf_err *err)
{
    memset(out, 0, sizeof(*out));
    int rc = supmodel_params_check(p, err);
    if (rc)
        return rc;
    double h = p->layer_mm, px = g->pitch, cell_a = px * px;
    struct cols cs;
    if ((rc = cols_build(g, &cs, err)))
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
    uint32_t *bfirst = mem_array(n_blk + 1, sizeof(uint32_t));
    if (!runs || !bfirst) {
        rc = sf_err_set(err, SF_ENOMEM, "support model: out of memory");
        goto done;
    }
    /* the columns, their contact interface and the classic shadow volume */
    size_t n_runs = 0;
    double iface = 0;
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
        iface += cell_a * nif * h;
        uint32_t c = ct[k].cell, i = c % g->nu, j = c / g->nu;
        runs[n_runs++] = (struct run){ (j / bs) * nbu + i / bs, k0, k1 };
    }
    /* merge each snap cell's columns into disjoint layer ranges */
    qsort(runs, n_runs, sizeof(*runs), run_cmp);
    size_t m = 0;
    for (size_t k = 0; k < n_runs; k++) {
        if (m > 0 && runs[m - 1].blk == runs[k].blk && runs[k].k0 <= runs[m - 1].k1) {
            if (runs[k].k1 > runs[m - 1].k1)
                runs[m - 1].k1 = runs[k].k1;
        } else {
            runs[m++] = runs[k];
        }
    }
    n_runs = m;
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
        for (uint32_t j = bj * bs; j < (bj + 1) * bs && j < g->nw; j++) {
            for (uint32_t i = bi * bs; i < (bi + 1) * bs && i < g->nu; i++) {
                size_t c = (size_t)j * g->nu + i;
                int64_t free_l = k1 - k0;
                bool bed_free = k0 == 0;
                for (uint32_t q = cs.first[c]; q < cs.first[c + 1]; q++) {
                    struct ival iv = cs.iv[q];
                    free_l -= solid_layers(iv, h, k0, k1);
                    if (k0 == 0 && solid_layers(iv, h, 0, 1))
                        bed_free = false;
                    /* a top surface the range comes down onto: a bottom contact */
                    int32_t kt = (int32_t)lround(iv.hi / h);
                    if (iv.hi > 0 && kt >= k0 - 2 && kt < k1 && kt > 0)
                        land += 1;
                }
                filled += (double)(free_l > 0 ? free_l : 0);
                first += bed_free;
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
    free(bfirst);
    free(ct);
    cols_release(&cs);
    return rc;
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
    if ((r = raycast_grid(rc, v3_normalize(up), p->pitch_mm, &g, err)))
        return r;
    r = supmodel_eval_grid(&g, p, out, err);
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
