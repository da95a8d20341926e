/*
 * gcwrite.h - toolpaths to Marlin G-code text (the body of the file).
 *
 * Absolute XYZ (G90), E absolute (M82, reset with G92 E0 at each layer)
 * or relative (M83) per profile.  Each layer starts with PrusaSlicer's
 * comments (;LAYER_CHANGE, ;Z:, ;HEIGHT:) so viewers and our estimator
 * find it; roles are tagged ;TYPE:<PrusaSlicer name> and ;WIDTH:.  Paths of
 * one role are visited nearest-first (loops start at their vertex nearest
 * the nozzle); a travel longer than retract_min_travel retracts (and
 * lifts, if set).  The first layer runs at first_layer_speed and the
 * first-layer temperatures; layer 1 switches to the normal ones.
 *
 * Cooling (PrusaSlicer's CoolingBuffer semantics): each layer is first
 * timed dry at its programmed feeds; a layer faster than
 * slowdown_below_layer_time has its extrusion feeds capped (fastest
 * first, never below min_print_speed) until it lasts that long, and the
 * fan follows the layer time between the two thresholds (gcw_fan_pct),
 * with bridge_fan_speed over bridges and overhang_fan_speed over
 * overhanging perimeter runs (toolpath.h's ovh flags: they print as
 * ;TYPE:Overhang perimeter with bridge flow and speed).  Bridges and
 * overhangs are never slowed down.  The header, start/end G-code and M73 progress are added by
 * slice.c around this body.
 *
 * Thread: reentrant; writes only into the caller's buffer.
 */
#ifndef SF_SLICER_GCWRITE_H
#define SF_SLICER_GCWRITE_H

#include <stdbool.h>

#include "../src/base/buf.h"
#include "layers.h"
#include "profile.h"
#include "toolpath.h"

/* What the writer extruded, for cross-checks. */
struct gcw_stats {
    double e_mm[ROLE_N]; /* filament per role, mm */
    double travel_mm;    /* XY travel */
    uint32_t n_retracts;
    uint32_t n_moves;     /* G1, G2 and G3 lines written */
    uint32_t n_arcs;      /* of which G2/G3 */
    double *layer_time_s; /* n_layers: each layer's time at the programmed feeds
                             before the cooling slowdown (what the fan follows) */
    uint32_t n_layers;
};

/* Free st->layer_time_s (gcw_body fills it, also on some failures). */
void gcw_stats_release(struct gcw_stats *st);

/*
 * The fan, percent, for layer (0-based) of a layer time t_s, or for its
 * bridges: PrusaSlicer's cooling rules.  Off below disable_fan_first_layers;
 * then min_fan_speed if fan_always_on, else off; with cooling, max_fan_speed
 * under slowdown_below_layer_time and a linear blend from max to min up to
 * fan_below_layer_time; bridges take bridge_fan_speed; everything ramps
 * up linearly until full_fan_speed_layer.
 */
int gcw_fan_pct(const struct slice_profile *p, uint32_t layer, double t_s, bool bridge);

/* The same for overhang perimeters: overhang_fan_speed in place of the
   layer's fan, within the same first-layers and ramp rules. */
int gcw_overhang_fan_pct(const struct slice_profile *p, uint32_t layer, double t_s);

/* Called after each G1 written, with the machine position it moves to
   (E in the absolute sense, as estimate.h reports it). */
typedef void (*gcw_move_fn)(void *ud, double x, double y, double z, double e);

/*
 * Append the G-code of every layer's paths (lp[k] for layer k of s) to
 * out.  on_move (may be NULL) sees every move as written.  SF_ENOMEM when
 * out's cap is hit.  Release st with gcw_stats_release, also on failure.
 */
int gcw_body(const struct layer_stack *s, const struct layer_paths *lp,
             const struct slice_profile *p, struct buf *out, struct gcw_stats *st,
             gcw_move_fn on_move, void *ud, struct sf_err *err);

/* Filament mm per mm of a line of width w on layer h (flow model, flow). */
double gcw_e_per_mm(const struct slice_profile *p, double w_mm, double h_mm);

/* Fixed-point decimal of v with up to dec decimals, trailing zeros cut
   ("12.3", "-0.05", "7"); returns the length.  buf holds 32 bytes. */
int gcw_fmt(char *buf, double v, int dec);

#endif
