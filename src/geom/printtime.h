/*
 * printtime.h - an estimate of the seconds a part takes to print along an
 * up-direction, and the one rule by which the optimizers weigh print time
 * beside support grams (issue 36: printer-hours are a farm's capacity).
 *
 * The part's time is summed layer by layer from its faces, with the
 * settings ../shared/peers gives PrusaSlicer 2.5 (0.2 mm layers, two
 * perimeters, 3 bottom / 4 top solid layers, 15 % infill, its default
 * speeds and its 5 s minimum layer time):
 *   perimeters  a face of area A at angle a from vertical adds A sin(a) / h
 *               of outline over its layers, printed once per perimeter;
 *   solid       a face facing up (down) is backed by top (bottom) layers:
 *               A |cos a| times their thickness, in full up to
 *               solid_full_deg from the horizontal, none past
 *               solid_none_deg (PrusaSlicer keeps its shell under slopes);
 *               a flat face's shell in the whole layers the slicer cuts
 *               (a 1.3 mm floor is 7 layers or 6 by where the layers'
 *               middles fall), and no layer's solid more than its section
 *               inside the perimeters (a thin slab's top and bottom shells
 *               overlap);
 *   infill      each layer's cross-section (from the faces above it: by the
 *               divergence theorem the area of the section at z is the sum
 *               of n_z dA over the surface above z), less its perimeters,
 *               at infill_density;
 *   layers      each layer costs layer_change_s more, and at least
 *               min_layer_s (PrusaSlicer slows a quick layer down to let it
 *               cool);
 *   loops       from each layer's cut (printtime_loops.h): a loop no longer
 *               than small_loop_mm prints its perimeters at
 *               small_perimeter_mm_s, an island whose infill region is
 *               under solid_below_mm2 is filled solid;
 *   bridges     a bottom over air (not on the bed) starts with a bridge
 *               layer, lines of bridge_line_mm at bridge_mm_s.
 * The support's seconds come from the support model (supmodel.h time_s,
 * scaled by support_factor): the estimate of the whole print is part_s +
 * support_factor * support_s; solid_factor scales the solid layers'
 * seconds (both calibrated against PrusaSlicer's estimates, see below).  It ranks the directions of
 * one part; it is no slicer's figure (no accelerations, no travel between islands beyond
 * layer_change_s, top and bottom surfaces at one speed).  Without the
 * loops it called scad example008 turned on its side 29 % faster where
 * PrusaSlicer said 11 % slower: cut into letter-bits, the part's inner
 * perimeters went from 12 to 38 m at 15 mm/s and its solid infill up 24 m
 * (the estimate now says +22 %); without the bridges, mech box_upside
 * turned over lost its 60 mm/s roof layer unseen.  Its floor, 6.5 layers
 * thick, is 6 layers as a roof and 7 on the bed in PrusaSlicer; with the
 * whole layers the turn is -2.9 % here (was -4.7 %), +3.4 % in PrusaSlicer:
 * the rest is solid_factor, which halves the floor's extra layer (a flat
 * layer's solid is PrusaSlicer's own speed at 1.0, but a 30 x 15 mm disc
 * and the shared meshes' changes ask 0.5, see below).
 *
 * The value of a result in seconds is its estimated print time plus
 * gram_s for each gram of support (the material, the removal): an
 * operator sets how much a gram is worth.  printtime_worth() is the
 * keep-the-input rule of the direction search and the shape steps.
 *
 * Pure functions: thread-safe.
 */
#ifndef SF_GEOM_PRINTTIME_H
#define SF_GEOM_PRINTTIME_H

#include <stdbool.h>
#include <stdint.h>

#include "../base/err.h"
#include "../mesh/mesh.h"

struct printtime_params {
    double layer_mm;               /* layer height (0.2) */
    double line_width_mm;          /* extrusion width (0.45) */
    int perimeters;                /* loops per layer outline (2) */
    double ext_perimeter_mm_s;     /* outer loop speed (30: PrusaSlicer's 50 % of 60) */
    double perimeter_mm_s;         /* inner loops (60) */
    int top_layers, bottom_layers; /* solid layers under a top / over a bottom (4, 3) */
    double solid_mm_s;             /* solid infill speed (20) */
    double infill_density;         /* sparse infill share (0.15) */
    double infill_mm_s;            /* sparse infill speed (80) */
    double layer_change_s;         /* per layer: lift, retract, travel to the start (0.3) */
    double min_layer_s;            /* a layer printed faster is slowed to this, its change
                                      included (5) */
    double small_perimeter_mm_s;   /* every perimeter of a small loop (15) */
    double bridge_mm_s;            /* a bottom's first layer over air (60) */
    double bridge_line_mm;         /* its line width: the nozzle's (0.4) */
    double small_loop_mm;          /* a loop this long or shorter is small (2 pi 6.5 mm) */
    double solid_below_mm2;        /* an island's infill region under this is filled solid
                                      (70; printtime_loops.h) */
    double solid_full_deg;         /* a face up to this slope from the horizontal is backed
                                      by its whole solid shell (45) */
    double solid_none_deg;         /* and past this by none, linear between (60) */
    double solid_factor;           /* the solid layers' seconds times this (0.5) */
    double support_factor;         /* the support model's seconds (its path at 60 mm/s)
                                      times this (1.3) */
    /* support_factor is calibrated on the shared meshes (the tuning set)
       as given and as main's search returned them, against PrusaSlicer's
       estimates (11 parts: mech-holes-shark left out, PrusaSlicer gives
       that open shell 974 s): the change of print time from given to
       searched errs by 9.3 points rms with support 1.3 and solid 0.5
       (7.8-9.3 for support 1.0-1.3 and solid 0.5-1.0; 15.4 with the old
       support 2.5, solid 1).  The shared set does not pin solid_factor; a
       30 x 15 mm disc does (PrusaSlicer: 9 % slower on its side; solid 1
       says 14 % faster, 0.5 says 8 % slower), and with 1 the estimate
       calls slower three mech turns PrusaSlicer prints faster (bracket_up,
       bracket_side, thread_side: looked at before 0.5 was chosen, so those
       are no clean hold-out).  On mech and scad it errs by 12.3 points rms
       (was 15.8).  With the loops and bridges (kept at 1.3 and 0.5), on
       the search results of e172a82 (main): 7.2 points on the
       shared meshes (9.3 without), 4.9 on mech and scad (10.7); on the
       shared meshes alone solid 1.0 would err least (5.5), but the disc
       says 0.5 and mech and scad err more with 1.0 (5.1 and 7.3). */
};

/* The defaults above: the peers' settings for PrusaSlicer 2.5. */
void printtime_params_default(struct printtime_params *p);

struct printtime_result {
    double part_s;      /* the part, every layer, slowdowns and changes included */
    double perimeter_s; /* of which perimeters (before slowdowns) */
    double solid_s;     /* of which solid layers (times solid_factor) */
    double infill_s;    /* of which sparse infill */
    double layers_s;    /* of which layer changes and minimum-layer-time slowdowns */
    uint32_t n_layers;
};

/* The whole print's seconds: r's part and the support model's support_s. */
double printtime_total_s(const struct printtime_params *p, const struct printtime_result *r,
                         double support_s);

/* Upper bound on layers (a part 2 m tall at 0.02 mm); more is SF_EINVAL. */
#define PRINTTIME_LAYERS_MAX 100000u

/*
 * Estimate the part's seconds printed with up (unit) as the build direction.
 * Errors: SF_EINVAL (bad parameters, a part taller than PRINTTIME_LAYERS_MAX
 * layers), SF_ENOMEM.
 */
int printtime_eval(const struct mesh *m, struct vec3 up, const struct printtime_params *p,
                   struct printtime_result *out, struct sf_err *err);

/* What a result is worth, to the keep-the-input rule. */
struct printtime_cost {
    double support_g; /* support grams (the model's) */
    double print_s;   /* estimated print seconds, part and support */
};

struct printtime_policy {
    double gram_s;        /* a gram of support is worth this many print seconds (60) */
    double min_gain;      /* a saving must pass this share of the input's grams or of its
                             print seconds (0.02: the peers' noise) */
    double min_gain_g;    /* and, in grams, this much more (0.05 g: the peers' noise on a
                             small part) */
    double min_gain_time; /* a saving in time alone (grams saved within the noise above)
                             must pass this share of the input's seconds (0.05): the
                             estimate's own error on a change of direction, 4.9 to 7.2
                             points rms against PrusaSlicer, not the peers' 2 % (scad
                             example012 turned: -4 % here, +7 % in PrusaSlicer) */
    bool material_first;  /* the operator asked for material over time: a result may
                             print slower than the input (false) */
};

void printtime_policy_default(struct printtime_policy *p);

/* Validate p: SF_EINVAL naming the field. */
int printtime_policy_check(const struct printtime_policy *p, struct sf_err *err);

/* c's value in seconds: print_s + gram_s * support_g. */
double printtime_value_s(const struct printtime_policy *p, const struct printtime_cost *c);

/*
 * Is out worth handing back instead of in?  Only if it needs no more
 * support and prints no slower (unless material_first), and it saves
 * either support grams beyond the noise (min_gain of the input's grams
 * plus min_gain_g: on a 2 g part 0.09 g, on a 25 g part 0.55 g, where a
 * flat 5 % asked 0.1 and 1.25 g) or print time beyond the estimate's error
 * (min_gain_time of the input's seconds).  Among results that pass, the optimizers prefer the
 * least printtime_value_s.
 */
bool printtime_worth(const struct printtime_policy *p, const struct printtime_cost *in,
                     const struct printtime_cost *out);

#endif
