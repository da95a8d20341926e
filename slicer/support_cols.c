/*
 * support_cols.c - the printed columns from a slicer profile (see
 * support.h): the part of the support module the part picture uses too,
 * apart from the layers' clipping so the picture does not link Clipper.
 *
 * Thread: reentrant.
 */
#include <math.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>

#include "../src/base/mem.h"
#include "../src/geom/raycast.h"
#include "support.h"

void
support_model_params(const struct slice_profile *p, struct supmodel_params *mp)
{
    supmodel_params_default(mp, SUPMODEL_PRUSA);
    mp->angle_deg = slice_profile_angle(p);
    mp->layer_mm = p->layer_mm;
    mp->pitch_mm = p->support_pitch_mm;
    mp->gap_z_mm = p->support_z_gap_mm;
    mp->interface_layers = support_interface_count(p);
}

int
support_interface_count(const struct slice_profile *p)
{
    double ps_h = 0.75 * p->nozzle_mm > p->layer_mm ? 0.75 * p->nozzle_mm : p->layer_mm;
    return (int)ceil(p->support_interface_layers * ps_h / p->layer_mm - 1e-6);
}

int
support_columns(const struct mesh *m, const struct slice_profile *p, struct support_grid *g,
                struct support_column **cols, size_t *n, size_t *cap, size_t *n_body,
                struct sf_err *err)
{
    *cols = NULL;
    *n = *cap = *n_body = 0;
    memset(g, 0, sizeof(*g));
    struct raycast *rc = raycast_new(m, err);
    if (!rc)
        return err ? err->code : SF_ENOMEM;
    struct supmodel_params mp;
    support_model_params(p, &mp);
    struct ray_grid rg;
    memset(&rg, 0, sizeof(rg));
    /* at the model's raster: its snap cells are whole numbers of columns */
    double pitch = supmodel_raster_pitch(&mp);
    int st = raycast_grid(rc, v3(0, 0, 1), pitch, &rg, err);
    if (st == SF_OK && mp.snap_mm > pitch)
        st = supmodel_pad_grid(&rg, (uint32_t)lround(mp.snap_mm / pitch), err);
    struct support_column *bands = NULL;
    size_t nb = 0;
    if (st == SF_OK)
        st = supmodel_columns(&rg, &mp, cols, n_body, &bands, &nb, err);
    if (st == SF_OK && nb) { /* the bands after the columns, in one array */
        void *o = *cols;
        size_t c = *n_body;
        if (!mem_grow(&o, &c, *n_body + nb, sizeof(**cols)))
            st = sf_err_set(err, SF_ENOMEM, "support: out of memory");
        else
            memcpy((struct support_column *)o + *n_body, bands, nb * sizeof(*bands));
        *cols = o;
    }
    if (st == SF_OK) {
        *g = (struct support_grid){ rg.u0, rg.w0, rg.base, rg.pitch, rg.nu, rg.nw };
        *n = *cap = *n_body + nb;
    } else {
        free(*cols);
        *cols = NULL;
        *n_body = 0;
    }
    free(bands);
    ray_grid_release(&rg);
    raycast_free(rc);
    return st;
}
