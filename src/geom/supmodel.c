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
 * Snap the contacts' columns to the grid as PrusaSlicer does (grid style):
 * every cell of a snap cell that a column touches gets the snap cell's
 * merged ranges wherever the part leaves room, and, as the projection goes
 * down until the part stops it, reaches down to its own floor.
 */
static int
snap_columns(const struct ray_grid *g, const struct solids *cs, const struct contact *ct, size_t n,
             uint32_t bs, struct support_column **cols, size_t *n_cols, struct sf_err *err)
{
    struct supmodel_snap sg = supmodel_snap_of(g, bs);
    struct frun *r = mem_array(n ? n : 1, sizeof(*r));
    if (!r)
        return sf_err_set(err, SF_ENOMEM, "support model: out of memory (columns)");
    for (size_t k = 0; k < n; k++)
        r[k] = (struct frun){ supmodel_snap_blk(g, sg, ct[k].cell), ct[k].floor, ct[k].top };
    size_t m = merge_fruns(r, n);
    struct support_column *v = NULL;
    size_t nv = 0, cap = 0;
    int rc = SF_OK;
    for (size_t k = 0; k < m && rc == SF_OK; k++) {
        uint32_t i0, i1, j0, j1;
        supmodel_snap_cells(g, sg, r[k].blk, &i0, &i1, &j0, &j1);
        for (uint32_t j = j0; j < j1 && rc == SF_OK; j++) {
            for (uint32_t i = i0; i < i1 && rc == SF_OK; i++) {
                uint32_t c = j * g->nu + i;
                /* the cell's free gaps: from the bed or a solid's top to the next bottom */
                float floor_mm = 0;
                for (uint32_t q = cs->first[c]; q <= cs->first[c + 1] && rc == SF_OK; q++) {
                    bool last = q == cs->first[c + 1];
                    if (!last && !(cs->iv[q].hi > cs->iv[q].lo))
                        continue;
                    float top = last ? r[k].hi : cs->iv[q].lo;
                    if (top > r[k].lo && floor_mm < r[k].hi) {
                        struct support_column col = { c, floor_mm, top < r[k].hi ? top : r[k].hi, 0,
                                                      false };
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
    struct supmodel_snap sg = supmodel_snap_of(g, bs);
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
        r[m++] = (struct frun){ supmodel_snap_blk(g, sg, ct[k].cell), (float)(ct[k].top - gap - dh),
                                (float)(ct[k].top - gap) };
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
