/*
 * supmodel_raster.c - the support model's raster (supmodel_int.h): each
 * column's solid intervals along up, from the ray count of shells (as
 * measure.c walks it, so overlapping shells and open meshes give material,
 * not columns), less the open layers the slicer drops (rims.h).
 */
#include "supmodel_int.h"

#include <stdlib.h>

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
