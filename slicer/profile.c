/*
 * profile.c - printer, print and material profiles (see profile.h).
 *
 * One table lists every option once: its section, key, type, field,
 * range and help.  Defaults, INI loading, --set overrides, validation
 * messages and the G-code header dump all read the same table, so an
 * option cannot be half-added.  Defaults follow PrusaSlicer 2.5's stock
 * 0.2 mm settings as used by shared/peers (0.45 mm lines, 2 perimeters,
 * 4 top / 3 bottom, 15 % grid, Marlin 2 machine limits), for fair
 * comparisons.
 *
 * Thread: none; a profile is loaded on one thread and read-only after.
 */
#include "profile.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "../src/base/ini.h"

#define OFF(f) offsetof(struct slice_profile, f)
#define R(sec, k, f, lo, hi, h)                                                                    \
    {                                                                                              \
        sec,                                                                                       \
        {                                                                                          \
#k, INI_REAL, OFF(f), lo, hi, h                                                        \
        }                                                                                          \
    }
#define I(sec, k, f, lo, hi, h)                                                                    \
    {                                                                                              \
        sec,                                                                                       \
        {                                                                                          \
#k, INI_INT, OFF(f), lo, hi, h                                                         \
        }                                                                                          \
    }
#define B(sec, k, f, h)                                                                            \
    {                                                                                              \
        sec,                                                                                       \
        {                                                                                          \
#k, INI_BOOL, OFF(f), 0, 0, h                                                          \
        }                                                                                          \
    }
#define S(sec, k, f, h)                                                                            \
    {                                                                                              \
        sec,                                                                                       \
        {                                                                                          \
#k, INI_STR, OFF(f), 0, 0, h                                                           \
        }                                                                                          \
    }
#define X(sec, k, f, h)                                                                            \
    {                                                                                              \
        sec,                                                                                       \
        {                                                                                          \
#k, INI_TEXT, OFF(f), 0, 0, h                                                          \
        }                                                                                          \
    }

struct popt {
    const char *section;
    struct ini_opt o;
};

static const struct popt popts[] = {
    S("printer", name, printer_name, "printer name"),
    R("printer", bed_x, bed_x_mm, 10, 2000, "bed width, mm"),
    R("printer", bed_y, bed_y_mm, 10, 2000, "bed depth, mm"),
    R("printer", max_z, max_z_mm, 10, 2000, "build height, mm"),
    R("printer", nozzle, nozzle_mm, 0.1, 2, "nozzle diameter, mm"),
    R("printer", max_overhang, max_overhang_deg, 0, 89,
      "largest unsupported angle from vertical, deg"),
    R("printer", max_feed_xy, max_feed_xy_mm_s, 1, 2000, "max XY feed rate, mm/s"),
    R("printer", max_feed_z, max_feed_z_mm_s, 0.1, 500, "max Z feed rate, mm/s"),
    R("printer", max_feed_e, max_feed_e_mm_s, 1, 500, "max E feed rate, mm/s"),
    R("printer", accel_extrude, accel_extrude_mm_s2, 10, 100000,
      "acceleration when printing, mm/s2"),
    R("printer", accel_travel, accel_travel_mm_s2, 10, 100000, "acceleration on travel, mm/s2"),
    R("printer", accel_retract, accel_retract_mm_s2, 10, 100000,
      "acceleration of retractions, mm/s2"),
    R("printer", max_accel_xy, max_accel_xy_mm_s2, 0, 100000,
      "X and Y axis acceleration limit, mm/s2 (M201; 0: none)"),
    R("printer", max_accel_z, max_accel_z_mm_s2, 0, 100000,
      "Z axis acceleration limit, mm/s2 (M201; 0: none)"),
    R("printer", max_accel_e, max_accel_e_mm_s2, 0, 100000,
      "E axis acceleration limit, mm/s2 (M201; 0: none)"),
    R("printer", jerk_xy, jerk_xy_mm_s, 0, 100, "XY jerk, mm/s"),
    R("printer", jerk_z, jerk_z_mm_s, 0, 100, "Z jerk, mm/s"),
    R("printer", jerk_e, jerk_e_mm_s, 0, 100, "E jerk, mm/s"),
    R("printer", junction_deviation, junction_dev_mm, 0, 1, "junction deviation, mm (0: use jerk)"),
    R("printer", travel_speed, travel_mm_s, 1, 2000, "travel speed, mm/s"),
    R("printer", retract_length, retract_mm, 0, 20, "retraction, mm of filament"),
    R("printer", retract_speed, retract_mm_s, 1, 200, "retraction speed, mm/s"),
    R("printer", retract_lift, retract_lift_mm, 0, 5, "Z hop on retraction, mm"),
    R("printer", retract_min_travel, retract_min_travel_mm, 0, 100,
      "retract only for travel longer than this, mm"),
    B("printer", e_relative, e_relative, "relative E (M83) instead of absolute (M82)"),
    B("printer", arc_fitting, arc_fitting,
      "the firmware takes G2/G3 (Marlin 2 ARC_SUPPORT): curved perimeters become arcs"),
    R("printer", arc_tolerance, arc_tolerance_mm, 0.001, 1,
      "largest distance between a fitted arc and the polyline it replaces, mm"),
    B("printer", retract_only_crossing, retract_only_crossing,
      "retract only when a travel leaves the part"),
    X("printer", start_gcode, start_gcode, "start G-code; {placeholders}"),
    X("printer", end_gcode, end_gcode, "end G-code; {placeholders}"),
    R("print", layer_height, layer_mm, 0.02, 1, "layer height, mm"),
    R("print", first_layer_height, first_layer_mm, 0.02, 1, "first layer height, mm"),
    I("print", perimeters, perimeters, 0, 50, "perimeter loops"),
    I("print", top_layers, top_layers, 0, 100, "top solid layers"),
    I("print", bottom_layers, bottom_layers, 0, 100, "bottom solid layers"),
    S("print", seam_position, seam_position,
      "where perimeter loops start: aligned (up the part from the rear), rear or nearest"),
    R("print", skin_margin, skin_margin_mm, 0, 20,
      "solid skins reach this far into the infill, mm"),
    B("print", ensure_vertical_shells, vertical_shells,
      "solid on slopes too, where the layers within reach differ"),
    R("print", solid_infill_below_area, solid_below_mm2, 0, 10000,
      "sparse islands smaller than this print solid, mm2"),
    R("print", infill_density, infill_density, 0, 1, "sparse infill density, 0..1"),
    S("print", infill_pattern, infill_pattern, "grid or rectilinear"),
    R("print", infill_anchor, infill_anchor_mm, 0, 50,
      "sparse lines follow the boundary this far, mm"),
    R("print", infill_anchor_max, infill_anchor_max_mm, 0, 1000,
      "sparse lines whose ends lie closer than this along the boundary are joined, mm"),
    R("print", line_width, width_mm, 0.1, 3, "perimeter and infill line width, mm"),
    R("print", solid_line_width, solid_width_mm, 0.1, 3, "solid and top line width, mm"),
    R("print", support_line_width, support_width_mm, 0.1, 3,
      "support and interface line width, mm"),
    R("print", perimeter_speed, perimeter_mm_s, 1, 1000, "inner perimeters, mm/s"),
    R("print", external_perimeter_speed, ext_perimeter_mm_s, 1, 1000, "outer perimeter, mm/s"),
    R("print", infill_speed, infill_mm_s, 1, 1000, "sparse infill, mm/s"),
    R("print", solid_infill_speed, solid_mm_s, 1, 1000, "solid infill, mm/s"),
    R("print", top_solid_infill_speed, top_mm_s, 1, 1000, "top solid infill, mm/s"),
    R("print", support_speed, support_mm_s, 1, 1000, "support, mm/s"),
    R("print", gap_fill_speed, gap_fill_mm_s, 1, 1000, "gap fill and thin walls, mm/s"),
    B("print", gap_fill, gap_fill,
      "gaps and walls narrower than two lines get one line of matching width"),
    R("print", min_bead_width, min_bead, 0, 2,
      "leftovers inside the perimeters narrower than this x the nozzle are gap fill, "
      "wider ones infill"),
    R("print", infill_overlap, infill_overlap, 0, 1,
      "infill reaches this fraction of the perimeter line spacing into the perimeters"),
    B("print", extra_perimeters, extra_perimeters,
      "an island gets more perimeters while over 30 % of the layer above's outline lies in the "
      "1.5 spacings just inside its loops (PrusaSlicer's extra_perimeters)"),
    B("print", overhangs, overhangs,
      "perimeters over air (a nozzle width out from the layer below) print with bridge flow, "
      "speed and overhang_fan_speed"),
    R("print", first_layer_speed, first_layer_mm_s, 1, 1000, "every move of the first layer, mm/s"),
    R("print", bridge_speed, bridge_mm_s, 0, 1000, "solid over air, mm/s (0: print it as solid)"),
    B("print", support, support, "generate column supports"),
    R("print", support_angle, support_angle_deg, 0, 89,
      "overhang angle from vertical, deg (0: printer's)"),
    R("print", support_pitch, support_pitch_mm, 0.2, 10, "support column grid pitch, mm"),
    R("print", support_z_gap, support_z_gap_mm, 0, 2, "gap between support top and part, mm"),
    R("print", support_xy_gap, support_xy_gap_mm, 0, 5, "gap between support and part walls, mm"),
    I("print", support_interface_layers, support_interface_layers, 0, 20,
      "dense layers under the part, in PrusaSlicer's support layers (0.75 nozzle thick)"),
    R("print", support_spacing, support_spacing_mm, 0.5, 20,
      "gap between support lines (they lie this plus a line apart), mm"),
    I("print", skirts, skirts, 0, 20, "skirt loops (0: none)"),
    R("print", skirt_distance, skirt_distance_mm, 0, 100,
      "gap between the skirt and the part, its brim and support, mm"),
    I("print", skirt_height, skirt_height, 1, 1000, "skirt layers"),
    R("print", brim_width, brim_width_mm, 0, 100, "brim width, mm (0: none, or automatic)"),
    B("print", brim_auto, brim_auto,
      "brim_auto_width of brim when height > brim_auto_ratio x first layer's 4 area / perimeter"),
    R("print", brim_auto_ratio, brim_auto_ratio, 0.1, 1000,
      "automatic brim above this height / first-layer width"),
    R("print", brim_auto_width, brim_auto_width_mm, 0, 100, "automatic brim width, mm"),
    S("material", name, material_name, "material name"),
    R("material", diameter, filament_mm, 0.5, 5, "filament diameter, mm"),
    R("material", density, density_g_cm3, 0.1, 20, "density, g/cm3"),
    R("material", nozzle_temp, nozzle_c, 0, 500, "nozzle temperature, C"),
    R("material", first_layer_nozzle_temp, first_layer_nozzle_c, 0, 500,
      "first layer nozzle temperature, C"),
    R("material", bed_temp, bed_c, 0, 150, "bed temperature, C"),
    R("material", first_layer_bed_temp, first_layer_bed_c, 0, 150,
      "first layer bed temperature, C"),
    R("material", flow, flow, 0.5, 2, "extrusion multiplier"),
    B("material", cooling, cooling, "slow short layers down and set the fan by layer time"),
    B("material", fan_always_on, fan_always_on, "fan at min_fan_speed at least on long layers"),
    R("material", min_fan_speed, min_fan_pct, 0, 100, "fan on long layers, percent"),
    R("material", max_fan_speed, max_fan_pct, 0, 100, "fan on short layers, percent"),
    R("material", bridge_fan_speed, bridge_fan_pct, 0, 100, "fan over bridges, percent"),
    R("material", overhang_fan_speed, overhang_fan_pct, 0, 100,
      "fan over overhanging perimeters, percent"),
    R("material", fan_below_layer_time, fan_below_s, 0, 3600,
      "layers faster than this get more than min_fan_speed, s"),
    R("material", slowdown_below_layer_time, slowdown_below_s, 0, 3600,
      "minimum layer time: faster layers are slowed down to it, s"),
    R("material", min_print_speed, min_print_mm_s, 1, 1000,
      "the slowdown never goes below this, mm/s"),
    I("material", disable_fan_first_layers, disable_fan_first_layers, 0, 1000,
      "fan off on this many first layers"),
    I("material", full_fan_speed_layer, full_fan_speed_layer, 0, 1000,
      "fan ramps up to full until this layer (0: no ramp)"),
};
#define N_POPTS (sizeof(popts) / sizeof(popts[0]))

static const char default_start[] = "M140 S{first_layer_bed_temp}\n"
                                    "M104 S{first_layer_nozzle_temp}\n"
                                    "G28\n"
                                    "M190 S{first_layer_bed_temp}\n"
                                    "M109 S{first_layer_nozzle_temp}\n"
                                    "G1 Z5 F3000";
static const char default_end[] = "M104 S0\n"
                                  "M140 S0\n"
                                  "M107\n"
                                  "G91\n"
                                  "G1 Z10 F600\n"
                                  "G90\n"
                                  "G1 X0 Y{bed_y} F3000\n"
                                  "M84";

int
slice_profile_default(struct slice_profile *p)
{
    struct slice_profile d = {
        .printer_name = (char *)"generic-marlin",
        .bed_x_mm = 250,
        .bed_y_mm = 210,
        .max_z_mm = 210,
        .nozzle_mm = 0.4,
        .max_overhang_deg = 45,
        .max_feed_xy_mm_s = 500,
        .max_feed_z_mm_s = 12,
        .max_feed_e_mm_s = 120,
        .accel_extrude_mm_s2 = 1500,
        .accel_travel_mm_s2 = 1250,
        .accel_retract_mm_s2 = 1500,
        .jerk_xy_mm_s = 10,
        .jerk_z_mm_s = 0.2,
        .jerk_e_mm_s = 2.5,
        .junction_dev_mm = 0,
        .travel_mm_s = 130,
        .retract_mm = 2,
        .retract_mm_s = 40,
        .retract_lift_mm = 0,
        .retract_min_travel_mm = 2,
        .e_relative = false,
        .arc_fitting = true,
        .arc_tolerance_mm = 0.02,
        .start_gcode = (char *)default_start,
        .end_gcode = (char *)default_end,
        .layer_mm = 0.2,
        .first_layer_mm = 0.2,
        .perimeters = 2,
        .top_layers = 4,
        .bottom_layers = 3,
        .seam_position = (char *)"aligned",
        .skin_margin_mm = 3,
        .vertical_shells = false,
        .solid_below_mm2 = 70,
        .infill_density = 0.15,
        .infill_pattern = (char *)"grid",
        .infill_anchor_mm = 2.44,   /* PrusaSlicer 2.5: 600 % of the infill spacing */
        .infill_anchor_max_mm = 50, /* PrusaSlicer 2.5: infill_anchor_max 50 mm */
        .width_mm = 0.45,
        .solid_width_mm = 0.45,
        .support_width_mm = 0.4, /* PrusaSlicer 2.5: support_material_extrusion_width 0,
                                    its automatic width for support, the nozzle's */
        .perimeter_mm_s = 60,
        .ext_perimeter_mm_s = 30,
        .infill_mm_s = 80,
        .solid_mm_s = 20,
        .top_mm_s = 15,
        .support_mm_s = 60,
        .first_layer_mm_s = 30,
        .bridge_mm_s = 60,
        .gap_fill_mm_s = 20,
        .gap_fill = true,
        .min_bead = 0.85,       /* PrusaSlicer 2.5: min_bead_width 85 % */
        .infill_overlap = 0.25, /* PrusaSlicer 2.5: infill_overlap 25 % */
        .overhangs = true,
        .extra_perimeters = true, /* PrusaSlicer 2.5's default (its G-code's config) */
        .retract_only_crossing = true,
        .support = true,
        .support_angle_deg = 0,
        .support_pitch_mm = 0.25, /* the support model's raster (supmodel.h) */
        .support_z_gap_mm = 0.2,
        .support_xy_gap_mm = 0.3,
        .support_interface_layers = 3, /* PrusaSlicer 2.5: 3 top, as many bottom */
        .support_spacing_mm = 2.5,
        .skirts = 1,
        .skirt_distance_mm = 6,
        .skirt_height = 1,
        .brim_width_mm = 0,
        .brim_auto = true,
        .brim_auto_ratio = 3,
        .brim_auto_width_mm = 5,
        .material_name = (char *)"generic-pla",
        .filament_mm = 1.75,
        .density_g_cm3 = 1.24,
        .nozzle_c = 210,
        .first_layer_nozzle_c = 215,
        .bed_c = 60,
        .first_layer_bed_c = 60,
        .flow = 1,
        /* PrusaSlicer 2.5's built-in cooling defaults (the peers' settings) */
        .cooling = true,
        .fan_always_on = false,
        .min_fan_pct = 35,
        .max_fan_pct = 100,
        .bridge_fan_pct = 100,
        .overhang_fan_pct = 100, /* PrusaSlicer 2.5 runs bridge_fan_speed there */
        .fan_below_s = 60,
        .slowdown_below_s = 5,
        .min_print_mm_s = 10,
        .disable_fan_first_layers = 3,
        .full_fan_speed_layer = 0,
    };
    *p = d;
    for (size_t i = 0; i < N_POPTS; i++) {
        if (ini_opts_dup(&popts[i].o, 1, p) < 0) {
            /* free the ones already duplicated, null the rest */
            for (size_t j = i + 1; j < N_POPTS; j++)
                if (popts[j].o.type == INI_STR || popts[j].o.type == INI_TEXT) {
                    char *nul = NULL;
                    memcpy((char *)p + popts[j].o.offset, &nul, sizeof(nul));
                }
            slice_profile_release(p);
            return SF_ENOMEM;
        }
    }
    return SF_OK;
}

void
slice_profile_release(struct slice_profile *p)
{
    for (size_t i = 0; i < N_POPTS; i++)
        ini_opts_release(&popts[i].o, 1, p);
}

struct pctx {
    struct slice_profile *p;
    const char *set; /* "printer" or "material" */
};

static bool
section_ok(const char *set, const char *section)
{
    if (strcmp(set, "material") == 0)
        return strcmp(section, "material") == 0;
    return strcmp(section, "printer") == 0 || strcmp(section, "print") == 0;
}

static int
on_key(void *ud, const char *section, const char *key, const char *value, bool cont,
       struct sf_err *err)
{
    struct pctx *c = ud;
    if (!section_ok(c->set, section))
        return sf_err_set(err, SF_EINVAL, "section '%s' is not valid in a %s profile", section,
                          c->set);
    for (size_t i = 0; i < N_POPTS; i++) {
        if (strcmp(popts[i].section, section) != 0 || strcmp(popts[i].o.key, key) != 0)
            continue;
        if (cont && popts[i].o.type != INI_TEXT)
            return sf_err_set(err, SF_EINVAL, "option '%s' takes one line", key);
        return ini_opt_set(&popts[i].o, c->p, value, cont, err);
    }
    return sf_err_set(err, SF_EINVAL, "option '%s' is not valid in section '%s'", key, section);
}

int
slice_profile_parse(struct slice_profile *p, const char *text, size_t len, const char *name,
                    const char *section_set, struct sf_err *err)
{
    struct pctx c = { p, section_set };
    return ini_parse_mem(text, len, name, on_key, &c, err);
}

static int
load_one(struct slice_profile *p, const char *path, const char *set, struct sf_err *err)
{
    struct pctx c = { p, set };
    return ini_load(path, on_key, &c, err);
}

int
slice_profile_load(const char *printer_cfg, const char *material_cfg, struct slice_profile *p,
                   struct sf_err *err)
{
    if (slice_profile_default(p) < 0)
        return sf_err_set(err, SF_ENOMEM, "profile: out of memory");
    int rc = SF_OK;
    if (printer_cfg)
        rc = load_one(p, printer_cfg, "printer", err);
    if (rc == SF_OK && material_cfg)
        rc = load_one(p, material_cfg, "material", err);
    if (rc == SF_OK)
        rc = slice_profile_check(p, err);
    if (rc < 0)
        slice_profile_release(p);
    return rc;
}

int
slice_profile_set(struct slice_profile *p, const char *kv, struct sf_err *err)
{
    const char *eq = strchr(kv, '=');
    if (!eq || eq == kv)
        return sf_err_set(err, SF_EINVAL, "--set '%s': expected key=value", kv);
    /* "section.key" picks a section ("material.name"); a bare key takes the first match */
    const char *dot = memchr(kv, '.', (size_t)(eq - kv));
    const char *key = dot ? dot + 1 : kv;
    size_t kl = (size_t)(eq - key), sl = dot ? (size_t)(dot - kv) : 0;
    for (size_t i = 0; i < N_POPTS; i++) {
        const struct ini_opt *o = &popts[i].o;
        if (strlen(o->key) != kl || strncmp(o->key, key, kl) != 0)
            continue;
        if (dot && (strlen(popts[i].section) != sl || strncmp(popts[i].section, kv, sl) != 0))
            continue;
        return ini_opt_set(o, p, eq + 1, false, err);
    }
    return sf_err_set(err, SF_EINVAL, "--set: no option '%.*s'", (int)(eq - kv), kv);
}

int
slice_profile_check(const struct slice_profile *p, struct sf_err *err)
{
    if (strcmp(p->infill_pattern, "grid") != 0 && strcmp(p->infill_pattern, "rectilinear") != 0)
        return sf_err_set(err, SF_EINVAL,
                          "option 'infill_pattern': '%s' is not grid or rectilinear",
                          p->infill_pattern);
    if (strcmp(p->seam_position, "aligned") != 0 && strcmp(p->seam_position, "nearest") != 0 &&
        strcmp(p->seam_position, "rear") != 0)
        return sf_err_set(err, SF_EINVAL,
                          "option 'seam_position': '%s' is not aligned, nearest or rear",
                          p->seam_position);
    if (p->layer_mm > 0.8 * p->nozzle_mm || p->first_layer_mm > 0.9 * p->nozzle_mm)
        return sf_err_set(err, SF_EINVAL,
                          "layer height %g / first layer %g too thick for a %g mm nozzle",
                          p->layer_mm, p->first_layer_mm, p->nozzle_mm);
    if (p->width_mm < p->layer_mm || p->solid_width_mm < p->layer_mm ||
        p->support_width_mm < p->layer_mm)
        return sf_err_set(err, SF_EINVAL, "line width below the layer height");
    if (p->min_fan_pct > p->max_fan_pct)
        return sf_err_set(err, SF_EINVAL, "min_fan_speed %g is above max_fan_speed %g",
                          p->min_fan_pct, p->max_fan_pct);
    if (p->cooling && p->fan_below_s < p->slowdown_below_s)
        return sf_err_set(err, SF_EINVAL,
                          "fan_below_layer_time %g is below slowdown_below_layer_time %g",
                          p->fan_below_s, p->slowdown_below_s);
    /* the pitch is the detection raster: columns fill whole snap cells (supmodel.h) */
    if (p->support_pitch_mm < 0.5 * p->support_width_mm)
        return sf_err_set(err, SF_EINVAL, "support_pitch %g is below half the line width",
                          p->support_pitch_mm);
    return SF_OK;
}

double
slice_profile_angle(const struct slice_profile *p)
{
    return p->support_angle_deg > 0 ? p->support_angle_deg : p->max_overhang_deg;
}

void
slice_profile_dump(const struct slice_profile *p, void *file)
{
    FILE *f = file;
    for (size_t i = 0; i < N_POPTS; i++) {
        const struct ini_opt *o = &popts[i].o;
        const char *base = (const char *)p + o->offset;
        fprintf(f, "; %s.%s = ", popts[i].section, o->key);
        double d;
        int n;
        bool b;
        const char *s;
        switch (o->type) {
        case INI_REAL:
            memcpy(&d, base, sizeof(d));
            fprintf(f, "%g\n", d);
            break;
        case INI_INT:
            memcpy(&n, base, sizeof(n));
            fprintf(f, "%d\n", n);
            break;
        case INI_BOOL:
            memcpy(&b, base, sizeof(b));
            fprintf(f, "%s\n", b ? "yes" : "no");
            break;
        default:
            memcpy(&s, base, sizeof(s));
            for (; s && *s; s++) {
                fputc(*s == '\n' ? '|' : *s, f);
            }
            fputc('\n', f);
        }
    }
}
