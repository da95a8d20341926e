/*
 * toolpath_int.h - internal to the toolpath module: what its files
 * (toolpath.c, the per-layer driver, and toolpath_*.c, one stage each)
 * share.  Nothing outside slicer/toolpath*.c includes it; toolpath.h is
 * the contract.
 *
 * Thread: as toolpath.h (reentrant; no state outside the arguments).
 */
#ifndef SF_SLICER_TOOLPATH_INT_H
#define SF_SLICER_TOOLPATH_INT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "poly.h"
#include "profile.h"
#include "toolpath.h"

/* Gap pieces under this x nozzle^2 are not filled. */
#define GAP_MIN_AREA 0.1

/* The scratch sets a layer's stages share (toolpath_regions, toolpath_layer). */
enum {
    T_AREA,
    T_TMP,
    T_TOPI,
    T_BOTI,
    T_KEEP,
    T_SOLID,
    T_TOP,
    T_SPARSE,
    T_LINES,
    T_GAP,
    T_S,
    T_C,
    T_BELOW,
    T_N
};

/* In a function with `int rc` and a label `out`: keep x's status in rc,
   and on an error go to out. */
#define TP_TRY(x)                                                                                  \
    do {                                                                                           \
        if ((rc = (x)) < 0)                                                                        \
            goto out;                                                                              \
    } while (0)

/* Init / release the T_N scratch sets of t. */
void tp_scratch_init(struct paths *t);
void tp_scratch_release(struct paths *t);

/* Squared distance between two points, in units^2. */
static inline double
tp_d2(struct ipt a, struct ipt b)
{
    double dx = (double)(a.x - b.x), dy = (double)(a.y - b.y);
    return dx * dx + dy * dy;
}

/* Make lp->ovh cover every point of lp->p (new ones 0); copy from
   src[0..n) at point `at` when src is given.  False on ENOMEM. */
bool tp_ovh_fill(struct layer_paths *lp, size_t at, const uint8_t *src, size_t n);

/* Append every path of src to lp with the same role and width (loops of
   fewer than 3 points and lines of fewer than 2 are skipped).  SF_ENOMEM. */
int tp_add(struct layer_paths *lp, const struct paths *src, enum tp_role role, bool closed,
           double w);

/* Append to out the pieces (an outer and its holes) of set whose area,
   grown grow_mm all round, is at most lim_mm2 (above: at least).  The
   grown area is the area plus grow_mm x the perimeter (Steiner's formula,
   without its grow^2 term).  SF_ENOMEM. */
int tp_pieces_by_area(const struct paths *set, double lim_mm2, double grow_mm, bool above,
                      struct paths *out);

/* The regions of layer k: kept ones (toolpath_store_regions) copied, else
   computed (toolpath_regions). */
int tp_regions_of(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
                  struct paths *solid, struct paths *top, struct paths *sparse);

/* Move the pieces (outer and holes) of set narrower than t_mm (2 area /
   perimeter) to narrow; tmp is scratch.  SF_ENOMEM. */
int tp_split_narrow(struct paths *set, double t_mm, struct paths *narrow, struct paths *tmp);

/*
 * Gap fill: one line (or, over 1.5 sp wide, a loop) along the middle of
 * every piece of gap, as wide as lays the piece's area (plus overlap x its
 * perimeter when it is min_bead wide), appended to out as ROLE_GAP_FILL.
 * piece, sliver, line: scratch.  SF_ENOMEM / SF_EBUG.
 */
int tp_gap_fill(const struct paths *gap, double h, double nozzle, double sp, double overlap,
                double min_bead, struct layer_paths *out, struct paths *piece, struct paths *sliver,
                struct paths *line);

/*
 * Stages of toolpath_layer, in its order.  t is its scratch (T_N sets):
 * each stage reads and leaves the sets its comment names; out gets the
 * paths.  SF_ENOMEM / SF_EBUG.
 */
/* The islands of layer k that get extra perimeters, into its more[] and
   n_more (extra_perimeters; none without).  SF_ENOMEM / SF_EBUG. */
int tp_extra_perimeters(struct layer_stack *s, uint32_t k, const struct slice_profile *p);
/* The area inside L's perimeters, more[] counted (out is reset). */
int tp_inner(const struct layer *L, const struct slice_profile *p, double sp, struct paths *out);
/* Perimeter loops of L (external last); the gaps they leave in t[T_GAP]. */
int tp_perimeters(const struct layer *L, const struct slice_profile *p, double sp, struct paths *t,
                  struct layer_paths *out);
/* Gap fill of the loops' gaps, t[T_GAP] (opened by an eighth of sp first). */
int tp_gap_fill_loops(double h, const struct slice_profile *p, double sp, struct paths *t,
                      struct layer_paths *out);
/* Gap fill's lines over the pieces of t[T_SOLID] and t[T_TOP] under 3.5
   solid spacings (ssp) wide (printed as solid and top solid infill) and of
   t[T_SPARSE] under a spacing (gap fill), which those sets lose. */
int tp_gap_fill_narrow(double h, const struct slice_profile *p, double sp, double ssp,
                       struct paths *t, struct layer_paths *out);
/* Bridges: t[T_SOLID] over air on layer k (each piece in the direction
   of its shortest anchored span), which t[T_SOLID] loses. */
int tp_bridges_over_air(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
                        const double org[2], struct paths *t, struct layer_paths *out);
/* Internal bridges: t[T_SOLID] over the sparse infill of every layer a
   nozzle deep below (lines at ang), which t[T_SOLID] loses. */
int tp_bridges_over_sparse(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
                           double ang, const double org[2], struct paths *t,
                           struct layer_paths *out);
/* Flag the overhanging segments of layer k's perimeter loops in out
   (layer_paths.ovh); grown, tmp: scratch.  SF_ENOMEM / SF_EBUG. */
int tp_mark_overhangs(const struct layer_stack *s, uint32_t k, const struct slice_profile *p,
                      struct layer_paths *out, struct paths *grown, struct paths *tmp);

#endif
