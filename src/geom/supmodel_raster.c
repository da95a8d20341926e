/*
 * supmodel_raster.c - the support model's raster (supmodel_int.h): each
 * column's solid intervals along up, from the ray count of shells (as
 * measure.c walks it, so overlapping shells and open meshes give material,
 * not columns), less the open layers the slicer drops (rims.h).
 */
#include "supmodel_int.h"

#include <stdlib.h>

#include "../base/limits.h"
#include "../base/mem.h"

void
supmodel_solids_release(struct solids *c)
{
    free(c->first);
    free(c->iv);
}

/* Append interval iv of cell c to out (n of cap), less the open layers the
   slicer does not keep in c (cut NULL or empty: nothing dropped). */
static bool
push_ival(struct solids *out, uint32_t *n, size_t *cap, struct ival iv, size_t c,
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

int
supmodel_solids_build(const struct ray_grid *g, struct open_cut *cut, struct solids *out,
                      struct sf_err *err)
{
    size_t cells = (size_t)g->nu * g->nw, cap = g->n_hits + 1;
    out->first = mem_array(cells + 1, sizeof(uint32_t));
    /* at most one interval per hit, unless open layers split them */
    out->iv = mem_array(cap, sizeof(struct ival));
    if (!out->first || !out->iv) {
        supmodel_solids_release(out);
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
        supmodel_solids_release(out);
        return sf_err_set(err, SF_ENOMEM, "support model: out of memory (%zu cells)", cells);
    }
    out->first[cells] = n;
    return SF_OK;
}

struct supmodel_snap
supmodel_snap_of(const struct ray_grid *g, uint32_t bs)
{
    struct supmodel_snap s = { bs, (bs - (g->nu / 2) % bs) % bs, (bs - (g->nw / 2) % bs) % bs, 0,
                               0 };
    s.nbu = (g->nu + s.ou + bs - 1) / bs;
    s.nbw = (g->nw + s.ow + bs - 1) / bs;
    return s;
}

uint32_t
supmodel_snap_blk(const struct ray_grid *g, struct supmodel_snap s, uint32_t c)
{
    uint32_t i = c % g->nu, j = c / g->nu;
    return ((j + s.ow) / s.bs) * s.nbu + (i + s.ou) / s.bs;
}

int
supmodel_snap_touch(const struct ray_grid *g, struct supmodel_snap s, uint32_t c, uint32_t blk[4],
                    uint32_t seed[4])
{
    uint32_t i = c % g->nu, j = c / g->nu;
    /* across the line at the cell's own centre: one cell back along that axis (a snap cell of
       one raster cell has no line through a centre) */
    bool au = s.bs > 1 && g->nu % 2 && (i + s.ou) % s.bs == 0 && i > 0;
    bool aw = s.bs > 1 && g->nw % 2 && (j + s.ow) % s.bs == 0 && j > 0;
    int n = 0;
    for (int dw = 0; dw <= (int)aw; dw++)
        for (int du = 0; du <= (int)au; du++) {
            seed[n] = (j - (uint32_t)dw) * g->nu + (i - (uint32_t)du);
            blk[n] = supmodel_snap_blk(g, s, seed[n]);
            n++;
        }
    return n;
}

void
supmodel_snap_cells(const struct ray_grid *g, struct supmodel_snap s, uint32_t blk, uint32_t *i0,
                    uint32_t *i1, uint32_t *j0, uint32_t *j1)
{
    uint32_t bi = blk % s.nbu, bj = blk / s.nbu;
    *i0 = bi * s.bs > s.ou ? bi * s.bs - s.ou : 0;
    *j0 = bj * s.bs > s.ow ? bj * s.bs - s.ow : 0;
    *i1 = (bi + 1) * s.bs - s.ou < g->nu ? (bi + 1) * s.bs - s.ou : g->nu;
    *j1 = (bj + 1) * s.bs - s.ow < g->nw ? (bj + 1) * s.bs - s.ow : g->nw;
}

int
supmodel_pad_grid(struct ray_grid *g, uint32_t pad, struct sf_err *err)
{
    uint32_t nu = g->nu + 2 * pad, nw = g->nw + 2 * pad;
    if (!pad || (uint64_t)nu * nw > SF_GRID_CELLS_MAX)
        return SF_OK; /* a part this big goes without the margin */
    uint32_t *first = mem_array((size_t)nu * nw + 1, sizeof(uint32_t));
    if (!first)
        return sf_err_set(err, SF_ENOMEM, "support model: out of memory (%u x %u cells)", nu, nw);
    uint32_t at = 0; /* where the hits of the cells so far end */
    for (uint32_t j = 0; j < nw; j++) {
        for (uint32_t i = 0; i < nu; i++) {
            size_t c = (size_t)j * nu + i;
            if (i >= pad && i < pad + g->nu && j >= pad && j < pad + g->nw) {
                size_t o = (size_t)(j - pad) * g->nu + (i - pad);
                first[c] = g->first[o];
                at = g->first[o + 1];
            } else {
                first[c] = at; /* empty */
            }
        }
    }
    first[(size_t)nu * nw] = g->first[(size_t)g->nu * g->nw];
    free(g->first);
    g->first = first;
    g->u0 -= pad * g->pitch;
    g->w0 -= pad * g->pitch;
    g->nu = nu;
    g->nw = nw;
    return SF_OK;
}
