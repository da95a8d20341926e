/*
 * supmodel.c - layer-based support model (see supmodel.h for the rules and
 * ../shared/SUPPORT-DETECTION.md for where each constant comes from).
 *
 * Three passes over the raster: solid intervals per column
 * (supmodel_raster.c); contacts, bottoms the layer below does not reach
 * (supmodel_rules.c), and their columns down to the bed or the part; then
 * the columns of each snap cell are merged into layer ranges, and the
 * ranges give the filled cell-layers, the outline and the landings
 * (supmodel_eval.c).  Here: the parameters, the raster pitch and the
 * snapped columns our own slicer prints.
 */
#include "supmodel.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"
#include "supmodel_int.h"

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

/* A column range in mm of snap cell blk. */
struct frun {
    uint32_t blk;
    float lo, hi;
    uint32_t cell; /* (snap_columns: the contact's own cell) */
};

static int
frun_cmp(const void *a, const void *b)
{
    const struct frun *x = a, *y = b;
    return supmodel_blk_cmp(x->blk, x->lo, y->blk, y->lo);
}

/* Sort r by snap cell and lo and merge each cell's overlapping ranges;
   returns how many are left. */
static size_t
merge_fruns(struct frun *r, size_t n)
{
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
    return m;
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
 * Which cells of a snap cell the run's support reaches, layer by layer
 * (reach[m * w * hh + cell in the block], layer m's middle (m + 1/2) h):
 * PrusaSlicer's grid support keeps, of each layer's snapped area less the
 * part, only the islands that hold a sample of the area projected from the
 * contacts above (SupportGridPattern::extract_support), so a snap cell
 * spilling across a wall does not print on the wall's far side (a box
 * printed upside down: the outer half of its wall cut back at the rim
 * leaves a ledge outside the inner half; the ledge's cells reach inside the
 * box too), and the support it keeps goes on down to the layers below.
 * Here, from the run's top down: the cells free at the layer's middle
 * joined (4 neighbours, within the block) to a contact's own cell whose
 * column spans that height, or to a cell the layer above reached.
 */
struct reach_ctx {
    const struct ray_grid *g;
    const struct solids *cs;
    uint32_t i0, j0, w, hh; /* the block */
    double h;               /* layer height */
    uint8_t *reach;         /* layers x w x hh */
    uint32_t *queue;        /* w x hh */
};

static void
reach_layers(struct reach_ctx *rc, const struct frun *seed, size_t n_seed, int32_t n_layers)
{
    size_t wb = (size_t)rc->w * rc->hh;
    memset(rc->reach, 0, (size_t)n_layers * wb);
    for (int32_t m = n_layers - 1; m >= 0; m--) {
        float z = (float)((m + 0.5) * rc->h);
        uint8_t *rm = rc->reach + (size_t)m * wb;
        size_t nq = 0;
        /* the layer above's support goes on down where the part leaves room */
        for (size_t b = 0; m + 1 < n_layers && b < wb; b++) {
            size_t c = (size_t)(b / rc->w + rc->j0) * rc->g->nu + (b % rc->w + rc->i0);
            if (rm[wb + b] && !supmodel_solid_at(rc->cs, c, z)) {
                rm[b] = 1;
                rc->queue[nq++] = (uint32_t)b;
            }
        }
        for (size_t s = 0; s < n_seed; s++) {
            uint32_t c = seed[s].cell, bi = c % rc->g->nu - rc->i0, bj = c / rc->g->nu - rc->j0;
            size_t b = (size_t)bj * rc->w + bi;
            if (seed[s].lo <= z && z <= seed[s].hi && !rm[b] && !supmodel_solid_at(rc->cs, c, z)) {
                rm[b] = 1;
                rc->queue[nq++] = (uint32_t)b;
            }
        }
        for (size_t q = 0; q < nq; q++) {
            uint32_t bi = rc->queue[q] % rc->w, bj = rc->queue[q] / rc->w;
            static const int d4[4][2] = { { 1, 0 }, { -1, 0 }, { 0, 1 }, { 0, -1 } };
            for (int d = 0; d < 4; d++) {
                long ni = (long)bi + d4[d][0], nj = (long)bj + d4[d][1];
                if (ni < 0 || nj < 0 || ni >= (long)rc->w || nj >= (long)rc->hh)
                    continue;
                size_t b = (size_t)nj * rc->w + (size_t)ni;
                size_t c = (size_t)(nj + rc->j0) * rc->g->nu + (size_t)(ni + rc->i0);
                if (!rm[b] && !supmodel_solid_at(rc->cs, c, z)) {
                    rm[b] = 1;
                    rc->queue[nq++] = (uint32_t)b;
                }
            }
        }
    }
}

/* Push the parts of column piece [lo, hi] of block cell b that the reach
   holds (its layers' middles), whole where it spans no layer's middle. */
static bool
push_reached(const struct reach_ctx *rc, uint32_t c, size_t b, float lo, float hi, int32_t n_layers,
             struct support_column **v, size_t *nv, size_t *cap)
{
    size_t wb = (size_t)rc->w * rc->hh;
    int32_t m0 = (int32_t)ceil(lo / rc->h - 0.5), m1 = (int32_t)floor(hi / rc->h - 0.5);
    m1 = m1 < n_layers ? m1 : n_layers - 1;
    if (m0 > m1)
        return push_column(v, nv, cap, (struct support_column){ c, lo, hi, 0, false });
    for (int32_t m = m0; m <= m1;) {
        if (!rc->reach[(size_t)m * wb + b]) {
            m++;
            continue;
        }
        int32_t e = m;
        while (e + 1 <= m1 && rc->reach[(size_t)(e + 1) * wb + b])
            e++;
        float a = m == m0 ? lo : (float)(m * rc->h), z = e == m1 ? hi : (float)((e + 1) * rc->h);
        if (!push_column(v, nv, cap, (struct support_column){ c, a, z, 0, false }))
            return false;
        m = e + 1;
    }
    return true;
}

/*
 * Snap the contacts' columns to the grid as PrusaSlicer does (grid style):
 * every cell of a snap cell that a column touches gets the snap cell's
 * merged ranges wherever the part leaves room and the support reaches
 * (reach_layers), and, as the projection goes down until the part stops
 * it, reaches down to its own floor.
 */
static int
snap_columns(const struct ray_grid *g, const struct solids *cs, const struct contact *ct, size_t n,
             uint32_t bs, double layer_mm, struct support_column **cols, size_t *n_cols,
             struct sf_err *err)
{
    struct supmodel_snap sg = supmodel_snap_of(g, bs);
    struct frun *r = mem_array(n ? 4 * n : 1, sizeof(*r));
    struct reach_ctx rx = { .g = g, .cs = cs, .h = layer_mm };
    rx.queue = mem_array((size_t)bs * bs, sizeof(uint32_t));
    size_t reach_cap = 0;
    if (!r || !rx.queue) {
        free(r);
        free(rx.queue);
        return sf_err_set(err, SF_ENOMEM, "support model: out of memory (columns)");
    }
    size_t nr = 0;
    for (size_t k = 0; k < n; k++) {
        uint32_t blk[4], seed[4];
        int nt = supmodel_snap_touch(g, sg, ct[k].cell, blk, seed);
        for (int t = 0; t < nt; t++)
            r[nr++] = (struct frun){ blk[t], ct[k].floor, ct[k].top, seed[t] };
    }
    n = nr;
    qsort(r, n, sizeof(*r), frun_cmp);
    struct support_column *v = NULL;
    size_t nv = 0, cap = 0;
    int rc = SF_OK;
    for (size_t k = 0; k < n && rc == SF_OK;) {
        /* the run: this snap cell's contacts whose ranges overlap */
        size_t e = k + 1;
        float lo = r[k].lo, hi = r[k].hi;
        for (; e < n && r[e].blk == r[k].blk && r[e].lo <= hi; e++)
            hi = r[e].hi > hi ? r[e].hi : hi;
        uint32_t i0, i1, j0, j1;
        supmodel_snap_cells(g, sg, r[k].blk, &i0, &i1, &j0, &j1);
        rx.i0 = i0, rx.j0 = j0, rx.w = i1 - i0, rx.hh = j1 - j0;
        int32_t n_layers = (int32_t)floor(hi / layer_mm - 0.5) + 1;
        n_layers = n_layers > 0 ? n_layers : 0;
        size_t need = (size_t)n_layers * rx.w * rx.hh;
        if (need > reach_cap) {
            void *o = rx.reach;
            if (!mem_grow(&o, &reach_cap, need, 1)) {
                rc = sf_err_set(err, SF_ENOMEM, "support model: out of memory (columns)");
                break;
            }
            rx.reach = o;
        }
        reach_layers(&rx, r + k, e - k, n_layers);
        for (uint32_t j = j0; j < j1 && rc == SF_OK; j++) {
            for (uint32_t i = i0; i < i1 && rc == SF_OK; i++) {
                uint32_t c = j * g->nu + i;
                size_t b = (size_t)(j - j0) * rx.w + (i - i0);
                /* the cell's free gaps: from the bed or a solid's top to the next bottom */
                float floor_mm = 0;
                for (uint32_t q = cs->first[c]; q <= cs->first[c + 1] && rc == SF_OK; q++) {
                    bool last = q == cs->first[c + 1];
                    if (!last && !(cs->iv[q].hi > cs->iv[q].lo))
                        continue;
                    float top = last ? hi : cs->iv[q].lo;
                    if (top > lo && floor_mm < hi &&
                        !push_reached(&rx, c, b, floor_mm, top < hi ? top : hi, n_layers, &v, &nv,
                                      &cap))
                        rc = sf_err_set(err, SF_ENOMEM, "support model: out of memory");
                    if (!last)
                        floor_mm = cs->iv[q].hi;
                }
            }
        }
        k = e;
    }
    free(r);
    free(rx.queue);
    free(rx.reach);
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
    struct supmodel_snap sg = supmodel_snap_of(g, bs);
    double gap = p->gap_z_mm, dh = p->interface_layers * p->layer_mm;
    struct frun *r = mem_array(n ? 4 * n : 1, sizeof(*r));
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
        uint32_t blk[4], seed[4];
        int nt = supmodel_snap_touch(g, sg, ct[k].cell, blk, seed);
        for (int t = 0; t < nt; t++)
            r[m++] = (struct frun){ blk[t], (float)(ct[k].top - gap - dh), (float)(ct[k].top - gap),
                                    seed[t] };
    }
    size_t mm = merge_fruns(r, m);
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
        uint32_t i0, i1, j0, j1;
        supmodel_snap_cells(g, sg, r[k].blk, &i0, &i1, &j0, &j1);
        for (uint32_t j = j0; j < j1 && rc == SF_OK; j++) {
            for (uint32_t i = i0; i < i1 && rc == SF_OK; i++) {
                uint32_t c = j * g->nu + i;
                for (uint32_t q = cfirst[c]; q < cfirst[c + 1] && rc == SF_OK; q++) {
                    const struct support_column *pc = &cols[cidx[q]];
                    double lo = pc->lo > 0 ? pc->lo + gap : 0, hi = pc->hi - gap;
                    lo = lo > r[k].lo ? lo : r[k].lo;
                    hi = hi < r[k].hi ? hi : r[k].hi;
                    if (hi - lo < 0.5 * p->layer_mm)
                        continue;
                    struct support_column b = { c, (float)lo, (float)hi, 0, true };
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
    struct solids cs;
    if ((rc = supmodel_solids_build(g, NULL, &cs, err)))
        return rc;
    struct contact *ct = NULL;
    size_t n = 0;
    rc = supmodel_find_contacts(g, &cs, p, &ct, &n, err);
    uint32_t bs = p->snap_mm > g->pitch ? (uint32_t)lround(p->snap_mm / g->pitch) : 1;
    if (!rc && bs > 1) {
        rc = snap_columns(g, &cs, ct, n, bs, p->layer_mm, cols, n_cols, err);
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
                out[k] = (struct support_column){ ct[k].cell, ct[k].floor, ct[k].top, 0, false };
            *cols = out;
            *n_cols = n;
        }
    }
    free(ct);
    supmodel_solids_release(&cs);
    return rc;
}

double
supmodel_raster_pitch(const struct supmodel_params *p)
{
    if (!(p->snap_mm > p->pitch_mm))
        return p->pitch_mm;
    return p->snap_mm / ceil(p->snap_mm / p->pitch_mm - 1e-9);
}
