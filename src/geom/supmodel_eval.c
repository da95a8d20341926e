/*
 * supmodel_eval.c - the support model's volumes (supmodel.h): the columns
 * of each snap cell merged into layer ranges, and the ranges' filled
 * cell-layers, outline and landings; the evaluations on a grid, on a
 * raycast (open sections cut as the slicer cuts them) and on a mesh.
 */
#include "supmodel_int.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"

/* A column of support in layer indices [k0, k1) of snap cell blk. */
struct run {
    uint32_t blk;
    int32_t k0, k1;
};

static int
run_cmp(const void *a, const void *b)
{
    const struct run *x = a, *y = b;
    return supmodel_blk_cmp(x->blk, x->k0, y->blk, y->k0);
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

/* The contacts' columns (runs) and dense interfaces (iruns, *n_iruns of them)
   in layer indices of their snap cells, and the contact figures of out;
   returns how many runs. */
static size_t
contact_runs(const struct ray_grid *g, const struct supmodel_params *p, const struct contact *ct,
             size_t n_ct, struct supmodel_snap sn, struct supmodel_result *out, struct run *runs,
             struct run *iruns, size_t *n_iruns)
{
    double h = p->layer_mm, px = g->pitch, cell_a = px * px;
    size_t n_runs = 0;
    *n_iruns = 0;
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
        uint32_t blk[4], seed[4];
        int nt = supmodel_snap_touch(g, sn, ct[k].cell, blk, seed);
        for (int t = 0; t < nt; t++) {
            /* PrusaSlicer snaps contacts to the grid too (fill_contact_layer): the
               dense layers under a contact fill its whole snap cell */
            if (ct[k].dense)
                iruns[(*n_iruns)++] = (struct run){ blk[t], k1 - nif, k1 };
            runs[n_runs++] = (struct run){ blk[t], k0, k1 };
        }
    }
    return n_runs;
}

/* Filled cell-layers (cells of the snap cell where the part is not) of the
   merged runs, those at the bed (*first) and the landings on the part. */
static void
fill_runs(const struct ray_grid *g, const struct supmodel_params *p, const struct solids *cs,
          const struct run *runs, size_t n_runs, struct supmodel_snap sn, double *filled_out,
          double *first_out, double *land_out)
{
    double h = p->layer_mm, filled = 0, first = 0, land = 0;
    for (size_t r = 0; r < n_runs; r++) {
        uint32_t b = runs[r].blk, i0, i1, j0, j1;
        supmodel_snap_cells(g, sn, b, &i0, &i1, &j0, &j1);
        int32_t k0 = runs[r].k0, k1 = runs[r].k1;
        /* the projection goes on down each cell until the part (or the range
           below in the same snap cell) stops it */
        int32_t below = r > 0 && runs[r - 1].blk == b ? runs[r - 1].k1 : 0;
        for (uint32_t j = j0; j < j1; j++) {
            for (uint32_t i = i0; i < i1; i++) {
                size_t c = (size_t)j * g->nu + i;
                int64_t free_l = k1 - k0;
                bool solid_k0 = false;
                float floor_mm = 0;
                for (uint32_t q = cs->first[c]; q < cs->first[c + 1]; q++) {
                    struct ival iv = cs->iv[q];
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
    *filled_out = filled;
    *first_out = first;
    *land_out = land;
}

/* Outline of the filled snap cells in snap-cell sides, summed over layers
   (snap cell b holds runs[bfirst[b] .. bfirst[b + 1])). */
static double
outline_runs(const struct run *runs, const uint32_t *bfirst, struct supmodel_snap sn)
{
    uint32_t nbu = sn.nbu, nbw = sn.nbw;
    double outline = 0;
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
    return outline;
}

/* The dense cell-layers: the snap cells' free cells under each contact. */
static double
iface_runs(const struct ray_grid *g, double h, const struct solids *cs, const struct run *iruns,
           size_t n_iruns, struct supmodel_snap sn)
{
    double iface = 0;
    for (size_t r = 0; r < n_iruns; r++) {
        uint32_t i0, i1, j0, j1;
        supmodel_snap_cells(g, sn, iruns[r].blk, &i0, &i1, &j0, &j1);
        for (uint32_t j = j0; j < j1; j++) {
            for (uint32_t i = i0; i < i1; i++) {
                size_t c = (size_t)j * g->nu + i;
                int64_t free_l = iruns[r].k1 - iruns[r].k0;
                for (uint32_t q = cs->first[c]; q < cs->first[c + 1]; q++)
                    free_l -= solid_layers(cs->iv[q], h, iruns[r].k0, iruns[r].k1);
                iface += (double)(free_l > 0 ? free_l : 0);
            }
        }
    }
    return iface;
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
    struct solids cs;
    if ((rc = supmodel_solids_build(g, cut, &cs, err)))
        return rc;
    struct contact *ct = NULL;
    size_t n_ct = 0;
    if ((rc = supmodel_find_contacts(g, &cs, p, &ct, &n_ct, err))) {
        supmodel_solids_release(&cs);
        return rc;
    }
    uint32_t bs = p->snap_mm > px ? (uint32_t)lround(p->snap_mm / px) : 1;
    struct supmodel_snap sn = supmodel_snap_of(g, bs);
    size_t n_blk = (size_t)sn.nbu * sn.nbw;
    /* a contact touches up to 4 snap cells (supmodel_snap_touch) */
    struct run *runs = mem_array(n_ct ? 4 * n_ct : 1, sizeof(*runs));
    struct run *iruns = mem_array(n_ct ? 4 * n_ct : 1, sizeof(*iruns));
    uint32_t *bfirst = mem_array(n_blk + 1, sizeof(uint32_t));
    struct run *tmp = mem_array(n_ct ? 4 * n_ct : 1, sizeof(*tmp));
    if (!runs || !iruns || !bfirst || !tmp) {
        rc = sf_err_set(err, SF_ENOMEM, "support model: out of memory");
        goto done;
    }
    /* the columns, their contact interface and the classic shadow volume */
    size_t n_iruns, n_runs = contact_runs(g, p, ct, n_ct, sn, out, runs, iruns, &n_iruns);
    /* merge each snap cell's columns (and interfaces) into disjoint layer ranges */
    n_iruns = merge_runs(iruns, n_iruns, n_blk, bfirst, tmp);
    n_runs = merge_runs(runs, n_runs, n_blk, bfirst, tmp);
    for (size_t b = 0, k = 0; b <= n_blk; b++) {
        while (k < n_runs && runs[k].blk < b)
            k++;
        bfirst[b] = (uint32_t)k;
    }
    double filled, first, land;
    fill_runs(g, p, &cs, runs, n_runs, sn, &filled, &first, &land);
    /* outline of the filled snap cells, layer by layer */
    double side = bs * px, outline = outline_runs(runs, bfirst, sn);
    outline *= side; /* mm of outline summed over layers */
    double iface = iface_runs(g, h, &cs, iruns, n_iruns, sn);
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
    supmodel_solids_release(&cs);
    return rc;
}

int
supmodel_eval_grid(const struct ray_grid *g, const struct supmodel_params *p,
                   struct supmodel_result *out, struct sf_err *err)
{
    return eval_cut(g, p, NULL, out, err);
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
    /* a snap cell of margin, as the slicer's columns have (support_cols.c) */
    if (p->snap_mm > g.pitch &&
        (r = supmodel_pad_grid(&g, (uint32_t)lround(p->snap_mm / g.pitch), err))) {
        ray_grid_release(&g);
        return r;
    }
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
