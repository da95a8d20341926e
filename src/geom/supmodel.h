/*
 * supmodel.h - a layer-based model of the support an outside slicer prints:
 * what PrusaSlicer 2.5 (grid style) or CuraEngine 4.13 (normal supports)
 * decide layer by layer, in grams and print seconds, for one up-direction.
 *
 * The part is a raster of vertical columns (the ray grid of raycast.h at
 * pitch_mm), each holding the solid intervals along up.  A column's bottom
 * (a solid interval starting above the bed) overhangs when the layer below
 * does not come within the slicer's allowed step of it: PrusaSlicer's
 * d = h / tan(T + 1 deg), CuraEngine's d = h (tan A - 0.01).  A planar face
 * steps h / tan(phi) a layer, so over a raster step r the test is whether a
 * neighbouring column is solid r / (d / h) below the bottom: the slicers'
 * per-layer rule, applied over r instead of h, which ignores facet noise
 * finer than the raster as the slicers ignore it finer than a layer.
 * Contacts sit gap_z_mm below the bottom and project down to the bed or to
 * the first solid below (plus the bottom gap); PrusaSlicer snaps support to
 * a grid of snap_mm cells (every touched cell is filled where the part is
 * not), CuraEngine closes gaps under 2 * join (modelled as the same snap).
 * Volumes (../shared/SUPPORT-DETECTION.md (5) and (6)):
 *   base      = filled cells * h * base_density
 *   sheath    = outline of the filled cells * h * sheath_mm (PrusaSlicer)
 *   connectors = outline * h * line_width * connector_factor (CuraEngine zigzag)
 *   interface = (contacts + landings on the part) * interface_layers * h
 *   first layer = filled cells at the bed * h * (first_density - base_density)
 * PrusaSlicer's bridge exemption (dont_support_bridges, on in the peers'
 * runs and in its CLI): a layer's new area, less its perimeters, is a
 * bridge when a straight line crosses it from the layer below to the layer
 * below; then only 1.5 mm bands along its free edges not parallel to the
 * bridge keep support, and perimeters keep it unless a straight line of the
 * bridge's direction anchors them at both ends (supmodel_rules.c says how the
 * raster follows BridgeDetector).  CuraEngine supports bridges.
 * Open shells (supmodel_eval only: it needs the mesh): where a layer cuts
 * an open rim and the slicer cannot close the section (open_gap_mm), the
 * component's solid in that layer is dropped, as the slicers drop it, and
 * the layer above rests on nothing (rims.h).
 *
 * Pure functions: thread-safe on distinct outputs; the raycast may be shared.
 */
#ifndef SF_GEOM_SUPMODEL_H
#define SF_GEOM_SUPMODEL_H

#include <stdint.h>

#include "../base/err.h"
#include "../mesh/mesh.h"
#include "measure.h"
#include "raycast.h"

enum supmodel_slicer { SUPMODEL_PRUSA, SUPMODEL_CURA };

struct supmodel_params {
    enum supmodel_slicer slicer; /* whose rules: PrusaSlicer 2.5 or CuraEngine 4.13 */
    double angle_deg;            /* alpha, largest self-supporting angle from vertical (45) */
    double layer_mm;             /* layer height (0.2, as ../shared/peers sets) */
    double pitch_mm;             /* raster pitch, at most (0.25; see supmodel_raster_pitch) */
    double gap_z_mm;             /* contact distance above and below support (0.2) */
    double gap_xy_mm;            /* support kept this far from the part (0.225 / 0.7) */
    double snap_mm;              /* support footprint cell (PrusaSlicer 2.84, CuraEngine 2) */
    int interface_layers;        /* dense layers at contacts and landings (3 / 0) */
    double interface_step_mm;    /* dense only where a layer overhangs the one below by
                                    more than this (0.27 / 0: everywhere) */
    double base_density;         /* sparse support fill (0.118 / 0.15) */
    double first_density;        /* fill of the bed layer (0.9 / 0.15) */
    double sheath_mm;            /* extrusion spacing of the loop around support (0.336 / 0) */
    double connector_factor;     /* zigzag connector path per mm of outline (0 / 0.6) */
    double line_width_mm;        /* support line width (0.4) */
    double speed_mm_s;           /* support print speed for the time estimate (60) */
    double density_g_cm3;        /* filament density (1.24) */
    bool bridges;                /* PrusaSlicer's dont_support_bridges: bottoms its bridge
                                    detector anchors need no support (on / off) */
    double bridge_band_mm;       /* perimeters' width inside a layer's outline: bottom
                                    there is perimeter, not bridge fill (0.8) */
    double open_gap_mm;          /* a cross-section an open rim leaves open is closed
                                    across gaps up to this, else dropped (rims.h; 2 / 10);
                                    0: closed by winding, as our slicer prints it */
};

/* The defaults of ../shared/peers/slice-peers.sh for slicer s at 45 degrees. */
void supmodel_params_default(struct supmodel_params *p, enum supmodel_slicer s);

/*
 * What the optimizers steer by: PrusaSlicer's rules at angle_deg on the part
 * as our own slicer prints it, open sections closed by winding (open_gap_mm
 * 0).  The farm prints what it steered by; an open shell is not scored by
 * the little of it PrusaSlicer would print (mech-holes-shark: 1.1 g of
 * support and almost no part in the direction PrusaSlicer rates best).
 */
void supmodel_params_steer(struct supmodel_params *p, double angle_deg);

/*
 * PrusaSlicer 2.5's overhang rule at overhang angle alpha (degrees from
 * vertical): its threshold T = round(90 - alpha), at least 1, supports faces
 * up to T + 1 degrees from the horizontal (../shared/SUPPORT-DETECTION.md).
 * Returns the steepest face angle from vertical it leaves unsupported,
 * 90 - (T + 1), never below 0.  The model's SUPMODEL_PRUSA rule and the
 * slimming loop's risky-face test both use it.
 */
double supmodel_prusa_safe_angle_deg(double angle_deg);

/*
 * Does either outside slicer need more support for after than for before
 * (both printed along +z), each by its own rules and its own treatment of
 * open rims (supmodel_params_default at angle_deg)?  *rises says so and
 * *slicer which.  A closed before answers no at once: there the steering
 * model is PrusaSlicer's own.  For an open shell the optimizers score the
 * part as our slicer prints it; this is their check that a result does not
 * cost more in the slicers that drop what the rims leave open.
 */
int supmodel_peers_rise(const struct mesh *before, const struct mesh *after, double angle_deg,
                        bool *rises, enum supmodel_slicer *slicer, struct sf_err *err);

struct supmodel_result {
    double grams;            /* all support extrusion */
    double time_s;           /* support path length / speed */
    double base_mm3;         /* sparse fill, first layer included */
    double interface_mm3;    /* dense contact and landing layers */
    double outline_mm3;      /* sheath or zigzag connectors */
    double contact_area_mm2; /* part surface that support touches from below */
    double shadow_mm3;       /* contact area times column length (the classic volume) */
    uint32_t n_contacts;     /* raster columns with a contact */
    uint32_t n_layers;       /* layers of the part */
};

/* Validate p: SF_EINVAL naming the field when a value is out of range. */
int supmodel_params_check(const struct supmodel_params *p, struct sf_err *err);

/* The model on a cast grid (g's pitch is the raster; p->pitch_mm is ignored;
   cross-sections closed by winding whatever p->open_gap_mm). */
int supmodel_eval_grid(const struct ray_grid *g, const struct supmodel_params *p,
                       struct supmodel_result *out, struct sf_err *err);

/*
 * The raster pitch the model casts at: p->pitch_mm, made finer where needed
 * so that a snap cell is a whole number of raster cells (PrusaSlicer's
 * 2.836 mm cell is 6 cells of 0.473 mm, not 6 of 0.5 = 3 mm: footprints
 * rounded up to 3 mm cells ranked the pig's directions worse, Spearman
 * with PrusaSlicer 0.882 against 0.915 on 16 directions).
 */
double supmodel_raster_pitch(const struct supmodel_params *p);

/*
 * g grown by pad empty cells on every side (its hits kept; none past
 * SF_GRID_CELLS_MAX cells: the part goes without the margin).  PrusaSlicer
 * fills every grid cell a contact touches, out past the part's outline (an
 * enclosure's ear ending at its widest point: support 1.3 mm beyond it),
 * where the raster of the part's shadow would stop the columns at its
 * edge; a pad of whole snap cells keeps their phase.  The slicer's columns
 * and supmodel_eval pad by one snap cell.  SF_ENOMEM.
 */
int supmodel_pad_grid(struct ray_grid *g, uint32_t pad, struct sf_err *err);

/* Cast the grid for up at supmodel_raster_pitch(p), pad it by a snap cell
   (supmodel_pad_grid) and evaluate. */
int supmodel_eval(struct raycast *rc, struct vec3 up, const struct supmodel_params *p,
                  struct supmodel_result *out, struct sf_err *err);

/* The same for a mesh alone: builds and frees its own ray scene (one part, one
   direction; callers scoring many directions keep a raycast and use the above). */
int supmodel_of_mesh(const struct mesh *m, struct vec3 up, const struct supmodel_params *p,
                     struct supmodel_result *out, struct sf_err *err);

/*
 * The model's columns in measure_columns' form (measure.h: lo is the bed or
 * the top of the part below, hi the overhanging bottom, tri 0), for a
 * slicer that prints what the model predicts.  *cols is allocated (free()).
 * With bands non-NULL (snapped columns only, else none), also the dense
 * interface (iface set): cell, and the heights lo..hi (gaps applied: layers
 * wholly inside print dense) under every contact the model gives a dense
 * interface, over its whole snap cell, interface_layers deep.
 */
int supmodel_columns(const struct ray_grid *g, const struct supmodel_params *p,
                     struct support_column **cols, size_t *n_cols, struct support_column **bands,
                     size_t *n_bands, struct sf_err *err);

#endif
