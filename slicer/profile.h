/*
 * profile.h - everything the slicer needs to know about the printer, the
 * print settings and the material, loaded from INI profiles.
 *
 * A printer profile (config/printers/NAME.cfg) holds a [printer] section
 * (bed, nozzle, kinematics, start/end G-code, the printer's own max
 * overhang angle) and may hold a [print] section (layers, walls, infill,
 * speeds, supports).  A material profile (config/materials/NAME.cfg) holds
 * a [material] section.  Every option has a default matching a common
 * 0.2 mm PLA profile (the peers' settings in shared/peers/README.md), so
 * either file may be omitted.  Unknown options are errors naming
 * file:line, option and section.
 *
 * Strings in the struct are owned by it: slice_profile_release() frees
 * them.  Not thread-safe per profile; load on one thread, then share
 * read-only.
 */
#ifndef SF_SLICER_PROFILE_H
#define SF_SLICER_PROFILE_H

#include <stdbool.h>
#include <stddef.h>

#include "../src/base/err.h"

struct slice_profile {
    /* [printer] */
    char *printer_name;
    double bed_x_mm, bed_y_mm, max_z_mm;
    double nozzle_mm;
    double max_overhang_deg; /* largest self-supporting angle from vertical */
    double max_feed_xy_mm_s, max_feed_z_mm_s, max_feed_e_mm_s;
    double accel_extrude_mm_s2, accel_travel_mm_s2, accel_retract_mm_s2;
    double max_accel_xy_mm_s2, max_accel_z_mm_s2, max_accel_e_mm_s2; /* M201; 0: none */
    double jerk_xy_mm_s, jerk_z_mm_s, jerk_e_mm_s;
    double junction_dev_mm; /* > 0: Marlin junction deviation instead of jerk */
    double travel_mm_s;
    double retract_mm, retract_mm_s, retract_lift_mm, retract_min_travel_mm;
    bool e_relative;               /* M83 instead of M82 */
    bool arc_fitting;              /* the firmware takes G2/G3: fit arcs to curved perimeters */
    double arc_tolerance_mm;       /* how far a fitted arc may stray from the polyline */
    char *start_gcode, *end_gcode; /* with {placeholders} */
    /* [print] */
    double layer_mm, first_layer_mm;
    int perimeters, top_layers, bottom_layers;
    char *seam_position;         /* "aligned", "nearest" or "rear" */
    double skin_margin_mm;       /* solid skins grow this far into the infill */
    bool vertical_shells;        /* solid wherever the neighbours' inner areas differ */
    double solid_below_mm2;      /* sparse islands smaller than this print solid */
    double infill_density;       /* 0..1 */
    char *infill_pattern;        /* "grid" or "rectilinear" */
    double infill_anchor_mm;     /* sparse lines hook along the boundary this far */
    double infill_anchor_max_mm; /* neighbouring sparse lines closer than this along the
                                    boundary are joined */
    double width_mm;             /* perimeters and sparse infill */
    double solid_width_mm;       /* solid and top lines */
    double support_width_mm;     /* support and its interface */
    double perimeter_mm_s, ext_perimeter_mm_s, infill_mm_s, solid_mm_s, top_mm_s;
    double support_mm_s, first_layer_mm_s, bridge_mm_s, gap_fill_mm_s;
    bool gap_fill;              /* thin walls and gaps get one line of matching width */
    double min_bead;            /* leftovers inside the loops narrower than this x nozzle
                                   are gap fill, wider ones infill */
    double infill_overlap;      /* infill reaches this x the loop spacing into the loops */
    bool overhangs;             /* perimeters over air: bridge flow, speed and fan */
    bool extra_perimeters;      /* PrusaSlicer's: more loops where the layer above's outline
                                   would stand on the infill just inside them */
    bool retract_only_crossing; /* no retraction for travel inside the part */
    bool support;
    double support_angle_deg; /* 0: the printer's max_overhang_deg */
    double support_pitch_mm;  /* column grid pitch */
    double support_z_gap_mm, support_xy_gap_mm;
    int support_interface_layers;
    double support_spacing_mm; /* between support lines */
    int skirts, skirt_height;  /* loops; layers */
    double skirt_distance_mm;  /* from the part, its support and brim */
    double brim_width_mm;      /* 0: none, unless brim_auto decides */
    bool brim_auto;            /* brim for tall parts on small footprints */
    double brim_auto_ratio;    /* height over first-layer hydraulic diameter */
    double brim_auto_width_mm;
    /* [material] */
    char *material_name;
    double filament_mm, density_g_cm3;
    double nozzle_c, first_layer_nozzle_c, bed_c, first_layer_bed_c;
    double flow;
    /* cooling, PrusaSlicer's options of the same names */
    bool cooling;       /* slow short layers down, fan by layer time */
    bool fan_always_on; /* min_fan_pct at least, from disable_fan_first_layers */
    double min_fan_pct, max_fan_pct, bridge_fan_pct, overhang_fan_pct;
    double fan_below_s;      /* fan_below_layer_time */
    double slowdown_below_s; /* slowdown_below_layer_time: the minimum layer time */
    double min_print_mm_s;   /* slowdown never goes below this */
    int disable_fan_first_layers, full_fan_speed_layer;
};

/* Fill p with the defaults (strings allocated).  SF_ENOMEM. */
int slice_profile_default(struct slice_profile *p);

/* Free the strings; p may then be defaulted again. */
void slice_profile_release(struct slice_profile *p);

/*
 * Defaults, then printer_cfg then material_cfg (either may be NULL).
 * SF_EIO / SF_EINVAL with "path:line: ..." messages; on failure p holds
 * nothing to free.
 */
int slice_profile_load(const char *printer_cfg, const char *material_cfg, struct slice_profile *p,
                       struct sf_err *err);

/* The same from text in memory (name for messages); section_set is
   "printer" (printer and print sections) or "material". */
int slice_profile_parse(struct slice_profile *p, const char *text, size_t len, const char *name,
                        const char *section_set, struct sf_err *err);

/* Override one option, "key=value" (any section).  SF_EINVAL. */
int slice_profile_set(struct slice_profile *p, const char *kv, struct sf_err *err);

/* Cross-field checks (widths vs nozzle, layer vs width...).  SF_EINVAL. */
int slice_profile_check(const struct slice_profile *p, struct sf_err *err);

/* The overhang angle supports use (support_angle_deg or the printer's). */
double slice_profile_angle(const struct slice_profile *p);

/* Write every option with its value and help as a commented INI file
   body into f (used by the G-code header and the docs). */
void slice_profile_dump(const struct slice_profile *p, void *file);

#endif
