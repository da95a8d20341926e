/*
 * test_ini.c - the INI wrapper and the slicer profiles: values, ranges,
 * continuation lines, and every error naming file:line, option, section.
 */
#include <stdio.h>
#include <string.h>

#include "../../slicer/profile.h"
#include "../../src/base/ini.h"
#include "../t.h"

static int
parse(struct slice_profile *p, const char *text, const char *set, struct sf_err *err)
{
    return slice_profile_parse(p, text, strlen(text), "printers/x.cfg", set, err);
}

T_CASE(profile_defaults_match_peers)
{
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    T_EQ_DBL(p.layer_mm, 0.2, 0);
    T_EQ_INT(p.perimeters, 2);
    T_EQ_INT(p.top_layers, 4);
    T_EQ_INT(p.bottom_layers, 3);
    T_EQ_DBL(p.infill_density, 0.15, 0);
    T_EQ_STR(p.infill_pattern, "grid");
    T_EQ_DBL(p.nozzle_mm, 0.4, 0);
    T_EQ_DBL(p.filament_mm, 1.75, 0);
    T_EQ_DBL(p.density_g_cm3, 1.24, 0);
    T_OK(slice_profile_check(&p, NULL), NULL);
    slice_profile_release(&p);
}

T_CASE(profile_parses_both_syntaxes_and_continuations)
{
    struct slice_profile p;
    struct sf_err err;
    T_OK(slice_profile_default(&p), NULL);
    T_OK(parse(&p,
               "# a printer\n[printer]\nname = mk3\nbed_x: 250\nmax_overhang = 50 ; deg\n"
               "start_gcode = G28\n  M109 S{nozzle_temp}\n  G1 Z5\n[print]\nsupport = no\n"
               "perimeters = 3\n",
               "printer", &err),
         &err);
    T_EQ_STR(p.printer_name, "mk3");
    T_EQ_DBL(p.max_overhang_deg, 50, 0);
    T_EQ_STR(p.start_gcode, "G28\nM109 S{nozzle_temp}\nG1 Z5");
    T_TRUE(!p.support);
    T_EQ_INT(p.perimeters, 3);
    T_OK(slice_profile_set(&p, "layer_height=0.1", &err), &err);
    T_EQ_DBL(p.layer_mm, 0.1, 0);
    T_OK(slice_profile_set(&p, "material.name=petg", &err), &err);
    T_EQ_STR(p.material_name, "petg");
    T_EQ_STR(p.printer_name, "mk3");
    T_OK(slice_profile_set(&p, "print.support=yes", &err), &err);
    T_TRUE(p.support);
    T_ERR(slice_profile_set(&p, "material.perimeters=3", &err), SF_EINVAL, &err,
          "no option 'material.perimeters'");
    slice_profile_release(&p);
}

T_CASE(profile_errors_name_file_line_option_section)
{
    struct slice_profile p;
    struct sf_err err;
    T_OK(slice_profile_default(&p), NULL);
    T_ERR(parse(&p, "[printer]\nname = a\nbaud = 115200\n", "printer", &err), SF_EINVAL, &err,
          "printers/x.cfg:3: option 'baud' is not valid in section 'printer'");
    T_ERR(parse(&p, "[printer]\n\nbed_x = wide\n", "printer", &err), SF_EINVAL, &err,
          "printers/x.cfg:3: option 'bed_x': 'wide' is not a number");
    T_ERR(parse(&p, "[print]\nperimeters = 2.5\n", "printer", &err), SF_EINVAL, &err,
          "printers/x.cfg:2: option 'perimeters': '2.5' is not a whole number");
    T_ERR(parse(&p, "[print]\nlayer_height = 7\n", "printer", &err), SF_EINVAL, &err,
          "printers/x.cfg:2: option 'layer_height': 7 is outside [0.02, 1]");
    T_ERR(parse(&p, "[printer]\nbed_x = 200\n[material]\ndensity = 1\n", "printer", &err),
          SF_EINVAL, &err,
          "printers/x.cfg:4: section 'material' is not valid in a printer profile");
    T_ERR(parse(&p, "[printer]\nthis line has no equals sign\n", "printer", &err), SF_EINVAL, &err,
          "printers/x.cfg:2: expected '[section]' or 'key = value'");
    T_ERR(parse(&p, "[print]\nsupport = maybe\n", "printer", &err), SF_EINVAL, &err,
          "printers/x.cfg:2: option 'support': 'maybe' is not a boolean");
    T_ERR(parse(&p, "[printer]\nbed_x = 200\n  300\n", "printer", &err), SF_EINVAL, &err,
          "printers/x.cfg:3: option 'bed_x' takes one line");
    char longline[400];
    memset(longline, 'x', sizeof(longline));
    memcpy(longline, "[printer]\nname = ", 17);
    longline[sizeof(longline) - 1] = '\0';
    T_ERR(parse(&p, longline, "printer", &err), SF_EINVAL, &err, "printers/x.cfg:2: line longer");
    T_ERR(slice_profile_set(&p, "warp=9", &err), SF_EINVAL, &err, "no option 'warp'");
    T_ERR(slice_profile_set(&p, "infill_density=1.5", &err), SF_EINVAL, &err, "outside [0, 1]");
    slice_profile_release(&p);
}

T_CASE(profile_load_files_and_cross_checks)
{
    char pp[512], mp[512];
    snprintf(pp, sizeof(pp), "%s/p.cfg", t_tmpdir());
    snprintf(mp, sizeof(mp), "%s/m.cfg", t_tmpdir());
    FILE *f = fopen(pp, "w");
    T_TRUE(f != NULL);
    fputs("[printer]\nname = t\nnozzle = 0.2\n", f);
    fclose(f);
    f = fopen(mp, "w");
    T_TRUE(f != NULL);
    fputs("[material]\nname = petg\nnozzle_temp = 240\n", f);
    fclose(f);
    struct slice_profile p;
    struct sf_err err;
    /* 0.2 mm layers on a 0.2 mm nozzle are too thick */
    T_ERR(slice_profile_load(pp, mp, &p, &err), SF_EINVAL, &err, "too thick");
    T_ERR(slice_profile_load("/nonexistent/p.cfg", NULL, &p, &err), SF_EIO, &err,
          "/nonexistent/p.cfg");
    f = fopen(pp, "w");
    T_TRUE(f != NULL);
    fputs("[printer]\nname = t\n[print]\nlayer_height = 0.15\n", f);
    fclose(f);
    T_OK(slice_profile_load(pp, mp, &p, &err), &err);
    T_EQ_STR(p.material_name, "petg");
    T_EQ_DBL(p.nozzle_c, 240, 0);
    T_EQ_DBL(p.layer_mm, 0.15, 0);
    slice_profile_release(&p);
}

T_CASE(shipped_profiles_load)
{
    static const char *const printers[] = { "config/printers/generic-marlin.cfg",
                                            "config/printers/prusa-mk3s.cfg" };
    static const char *const materials[] = { "config/materials/pla.cfg",
                                             "config/materials/petg.cfg" };
    for (int i = 0; i < 2; i++) {
        struct slice_profile p;
        struct sf_err err;
        T_OK(slice_profile_load(printers[i], materials[i], &p, &err), &err);
        slice_profile_release(&p);
    }
}
