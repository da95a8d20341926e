/*
 * supmodel_int.h - internal to the support model (supmodel*.c), not a
 * contract for anyone else: the raster of solid intervals the model's
 * passes share, and the entry points of its files.
 *
 *   supmodel_raster.c  the columns' solid intervals from the ray grid, less
 *                      the open layers the slicer drops (rims.h); the snap
 *                      grid over the raster; the grid's padding
 *   supmodel_rules.c   the slicers' overhang rules and PrusaSlicer's bridge
 *                      exemption: which bottoms are contacts
 *   supmodel_eval.c    the layer model's volumes (eval_cut) and the public
 *                      evaluations built on it
 *   supmodel.c         parameters, the raster pitch, the snapped columns
 *
 * Pure functions, as supmodel.h.
 */
#ifndef SF_GEOM_SUPMODEL_INT_H
#define SF_GEOM_SUPMODEL_INT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"
#include "raycast.h"
#include "rims.h"
#include "supmodel.h"

/* The part's solid intervals along every grid cell (what the model reads,
   not support): cell c holds iv[first[c] .. first[c+1]). */
struct ival {
    float lo, hi;
    float cos_lo; /* n . up of the facet the bottom lies on (< 0) */
};

struct solids {
    uint32_t *first;
    struct ival *iv;
};

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

/* Build the solid intervals of every cell of g, less what cut drops (NULL:
   nothing); SF_ENOMEM.  Free out with supmodel_solids_release. */
int supmodel_solids_build(const struct ray_grid *g, struct open_cut *cut, struct solids *out,
                          struct sf_err *err);
void supmodel_solids_release(struct solids *c);

/* Is cell c solid at height z? */
static inline bool
supmodel_solid_at(const struct solids *cs, size_t c, float z)
{
    for (uint32_t k = cs->first[c]; k < cs->first[c + 1]; k++)
        if (cs->iv[k].lo <= z && z <= cs->iv[k].hi && cs->iv[k].hi > cs->iv[k].lo)
            return true;
    return false;
}

/* A bottom that needs a column: (cell, bottom, floor). */
struct contact {
    uint32_t cell;
    float top;   /* the overhanging bottom, mm */
    float floor; /* top of the solid below, 0 for the bed */
    bool dense;  /* overhangs by more than interface_step_mm a layer: dense interface */
};

/* The contacts of cs by p's slicer rules (bridges removed when p->bridges),
   allocated into out (free()); SF_ENOMEM. */
int supmodel_find_contacts(const struct ray_grid *g, const struct solids *cs,
                           const struct supmodel_params *p, struct contact **out, size_t *n_out,
                           struct sf_err *err);

/*
 * The snap grid over the raster: cells of bs x bs raster cells, their sides
 * on whole multiples of the snap cell from the shadow's centre, where
 * PrusaSlicer's support grid has its lines (SupportGridPattern aligns its
 * box to multiples of the grid step in object coordinates, whose origin is
 * the object's centre).  The raster is centred on the shadow too, so raster
 * cell i's left side lies (i - nu / 2) cells from the centre: ou (0 <= ou <
 * bs) shifts the cells so that sides at multiples of bs fall there (within
 * half a raster cell when nu is odd), ow the same along w.  Snapped at the
 * raster's corner instead, a 0.8 mm bead along a wall took whichever of one
 * or two snap cells its offset from the corner gave: 2.6 mm of support where
 * PrusaSlicer prints 1.5 (box_open of the mech set).  The slicer's columns
 * (supmodel_columns) and the model's volumes (supmodel_eval) share it.
 */
struct supmodel_snap {
    uint32_t bs, ou, ow, nbu, nbw; /* nbu x nbw snap cells */
};

struct supmodel_snap supmodel_snap_of(const struct ray_grid *g, uint32_t bs);

/* The snap cell of raster cell c. */
uint32_t supmodel_snap_blk(const struct ray_grid *g, struct supmodel_snap s, uint32_t c);

/*
 * The snap cells a contact in raster cell c touches, into blk[] (up to 4),
 * each with the raster cell of it nearest c (the column's seed) in seed[];
 * returns how many.  PrusaSlicer's grid takes every cell the contact area
 * overlaps at all (SupportGridPattern: its raster is anti-aliased, a pixel
 * with any coverage is set and fills its cell), so an area that reaches a
 * hair across a grid line takes the cell past it.  Along an axis with an odd
 * number of raster cells, the raster's centres lie on the grid's lines (a
 * snap cell's first row or column): a contact there reaches across the line,
 * and touches the snap cell on the other side too.  (Along an even axis the
 * lines run between centres: a contact reaching less than half a raster cell
 * across one is not seen.)
 */
int supmodel_snap_touch(const struct ray_grid *g, struct supmodel_snap s, uint32_t c,
                        uint32_t blk[4], uint32_t seed[4]);

/* The raster cells of snap cell blk: [*i0, *i1) x [*j0, *j1). */
void supmodel_snap_cells(const struct ray_grid *g, struct supmodel_snap s, uint32_t blk,
                         uint32_t *i0, uint32_t *i1, uint32_t *j0, uint32_t *j1);

/* Order of two ranges of snap cells: by cell, then by key (a range's lower end). */
static inline int
supmodel_blk_cmp(uint32_t blk_a, double key_a, uint32_t blk_b, double key_b)
{
    if (blk_a != blk_b)
        return blk_a < blk_b ? -1 : 1;
    return (key_a > key_b) - (key_a < key_b);
}

#endif
