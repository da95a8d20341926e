/*
 * test_prepare.c - the prepare stage's choice between a reshaped part and
 * the part it came from: the G-code left is the one with less support in
 * our slicer (the farm's whole pipeline is in test_farm.c).
 */
#include <stdbool.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "../../slicer/profile.h"
#include "../../slicer/slice.h"
#include "../../src/base/buf.h"
#include "../../src/base/log.h"
#include "../../src/farm/prepare.h"
#include "../../src/mesh/mesh.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"

/* The support grams a G-code file's header reports (-1 if it has none). */
static double
support_g_in(const char *path)
{
    struct buf g;
    struct sf_err err;
    buf_init(&g, 64 << 20);
    double grams = -1;
    if (buf_read_file(&g, path, &err) == SF_OK && g.data) {
        const char *s = strstr(g.data, "; support material used [g] = ");
        if (s)
            sscanf(s + strlen("; support material used [g] = "), "%lf", &grams);
    }
    buf_release(&g);
    return grams;
}

/* Whether two files hold the same bytes. */
static bool
same_bytes(const char *a, const char *b)
{
    struct buf x, y;
    struct sf_err err;
    buf_init(&x, 64 << 20);
    buf_init(&y, 64 << 20);
    bool same = buf_read_file(&x, a, &err) == SF_OK && buf_read_file(&y, b, &err) == SF_OK &&
                x.len > 0 && x.len == y.len && memcmp(x.data, y.data, x.len) == 0;
    buf_release(&x);
    buf_release(&y);
    return same;
}

/* The tee standing on its stem (its arms overhang) and turned upside down (flat top down). */
static void
tees(struct mesh *standing, struct mesh *flipped, const struct slice_profile *p)
{
    struct sf_err err;
    mesh_init(standing);
    mesh_init(flipped);
    T_OK(shape_tee(standing, &err), &err);
    T_OK(mesh_copy(flipped, standing, &err), &err);
    mesh_rotate_up(flipped, v3(0, 0, -1));
    mesh_place_on_bed(standing, p->bed_x_mm / 2, p->bed_y_mm / 2);
    mesh_place_on_bed(flipped, p->bed_x_mm / 2, p->bed_y_mm / 2);
}

T_CASE(prepare_keeps_the_slicing_with_less_support)
{
    struct sf_err err;
    struct slice_profile p;
    T_OK(slice_profile_load("config/printers/generic-marlin.cfg", "config/materials/pla.cfg", &p,
                            &err),
         &err);
    struct mesh standing, flipped;
    tees(&standing, &flipped, &p);
    char out[512], other[600];
    snprintf(out, sizeof(out), "%s/part.gcode", t_tmpdir());
    snprintf(other, sizeof(other), "%s.start", out);
    atomic_bool cancel = false;
    struct prepare_choice ch;

    /* the reshaped part needs less: its G-code stays */
    T_OK(prepare_slice_better(&standing, &flipped, &p, out, &cancel, &ch, &err), &err);
    T_TRUE(ch.took_shaped);
    T_TRUE(ch.support_g_start > 1); /* the arms need columns */
    T_EQ_DBL(ch.support_g_shaped, 0, 1e-9);
    T_EQ_DBL(support_g_in(out), 0, 1e-9);
    T_TRUE(access(other, F_OK) != 0);

    /* the reshaped part needs more: the start's G-code is left at out */
    T_OK(prepare_slice_better(&flipped, &standing, &p, out, &cancel, &ch, &err), &err);
    T_TRUE(!ch.took_shaped);
    T_EQ_DBL(support_g_in(out), ch.support_g_start, 0.005);
    T_EQ_DBL(ch.support_g_start, 0, 1e-9);
    T_TRUE(ch.support_g_shaped > 1);
    T_TRUE(access(other, F_OK) != 0);

    /* a tie goes to the unchanged part */
    T_OK(prepare_slice_better(&standing, &standing, &p, out, &cancel, &ch, &err), &err);
    T_TRUE(!ch.took_shaped);
    T_EQ_DBL(support_g_in(out), ch.support_g_start, 0.005);

    /* a cancelled slicing leaves no file behind */
    atomic_store(&cancel, true);
    T_EQ_INT(prepare_slice_better(&standing, &flipped, &p, out, &cancel, &ch, &err), SF_ECANCELED);
    T_TRUE(access(out, F_OK) != 0 && access(other, F_OK) != 0);
    mesh_release(&standing);
    mesh_release(&flipped);
    slice_profile_release(&p);
}

/* Prepare the part in part_path with method, a deviation budget and an overhang angle (0: the
   printer's, 45) for a generic 220 mm Marlin printer. */
static int
prepare_job(const char *part_path, const char *method, double deviation_mm, double overhang_deg,
            struct prepare_out *out, struct sf_err *err)
{
    static struct prepare_req req;
    memset(&req, 0, sizeof(req));
    req.job_id = 1;
    snprintf(req.part_path, sizeof(req.part_path), "%s", part_path);
    snprintf(req.part_name, sizeof(req.part_name), "part.stl");
    job_opts_init(&req.opts);
    snprintf(req.opts.method, sizeof(req.opts.method), "%s", method);
    req.opts.deviation_mm = deviation_mm;
    req.opts.overhang_deg = overhang_deg;
    req.gram_s = 60; /* farmcfg's default */
    snprintf(req.printer.name, sizeof(req.printer.name), "a");
    snprintf(req.printer.profile, sizeof(req.printer.profile), "generic-marlin");
    snprintf(req.printer.material, sizeof(req.printer.material), "PLA");
    req.printer.nozzle_mm = 0.4;
    req.printer.bed_mm[0] = req.printer.bed_mm[1] = 220;
    req.printer.bed_mm[2] = 250;
    req.printer.overhang_deg = 45;
    snprintf(req.profiles_dir, sizeof(req.profiles_dir), "config");
    snprintf(req.out_path, sizeof(req.out_path), "%s/prep-%s.gcode", t_tmpdir(), method);
    atomic_bool cancel = false;
    memset(out, 0, sizeof(*out));
    return prepare_part(&req, out, &cancel, err);
}

/* The same with a 2 mm budget. */
static int
prepare_with(const char *part_path, const char *method, struct prepare_out *out, struct sf_err *err)
{
    return prepare_job(part_path, method, 2, 0, out, err);
}

/*
 * The deviation a shape method leaves (MNDR / ANDR, measure.h) comes out of
 * prepare_part for the farm to record: the surface method reshapes a
 * torus standing upright (its tube's underside overhangs whichever way it
 * stands or lies, so no axis pose turned up unreshaped beats a reshape; the
 * sphere on its stem lying on its side now does) within the 2 mm budget;
 * slimming measures too (0 where it keeps the shape); orientation alone
 * measures nothing.
 */
T_CASE(prepare_reports_the_deviation_of_a_reshaped_part)
{
    struct sf_err err;
    struct mesh m;
    mesh_init(&m);
    T_OK(shape_torus(&m, 30, 10, 64, 32, &err), &err);
    mesh_transform(&m, m3_axis_angle(v3(1, 0, 0), M_PI / 2), v3(0, 0, 0));
    mesh_place_on_bed(&m, 0, 0);
    double diag = mesh_diag(&m);
    char part[512];
    snprintf(part, sizeof(part), "%s/part.stl", t_tmpdir());
    T_OK(mesh_save_stl(&m, part, &err), &err);
    mesh_release(&m);
    struct prepare_out out;
    T_OK(prepare_with(part, "orient", &out, &err), &err);
    T_TRUE(!out.dev_measured && !out.shape_changed);
    T_EQ_DBL(out.mndr, 0, 0);
    T_OK(prepare_with(part, "surface", &out, &err), &err);
    printf("    surface: changed %d, mndr %.4f andr %.4f (diagonal %.1f mm)\n", out.shape_changed,
           out.mndr, out.andr, diag);
    T_TRUE(out.dev_measured && out.shape_changed);
    T_TRUE(out.mndr > 0 && out.andr > 0 && out.andr <= out.mndr);
    T_TRUE(out.mndr * diag <= 2 + 1e-6); /* the job's deviation budget */
    T_OK(prepare_with(part, "slim", &out, &err), &err);
    T_TRUE(out.dev_measured);
    T_TRUE(out.shape_changed ? out.mndr > 0 && out.andr > 0 : out.mndr == 0 && out.andr == 0);
}

/* The tee saved as STL under name in the test's tmpdir: its path in part. */
static void
tee_file(const char *name, char *part, size_t n)
{
    struct sf_err err;
    struct mesh m;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    snprintf(part, n, "%s/%s", t_tmpdir(), name);
    T_OK(mesh_save_stl(&m, part, &err), &err);
    mesh_release(&m);
}

/* What prepare logged at warn level, one line per call, appended. */
static char warned[4096];

static void
warn_sink(void *ud, enum log_level level, const char *subsys, const char *printer, const char *msg)
{
    (void)ud, (void)printer;
    size_t n = strlen(warned);
    if (level == LOG_WARN && strcmp(subsys, "prepare") == 0)
        snprintf(warned + n, sizeof(warned) - n, "%s\n", msg);
}

/*
 * A slimming that fails does not fail the job: the part prints as
 * oriented.  The failure here is slimming's own: a job's deviation budget
 * may be 0 mm (job.c takes 0..10), which slim_optimize refuses ("deviation
 * limits must be positive"), as it refuses a part TetGen cannot enclose.
 * The job then gives the G-code of the part as oriented (the orient
 * method's, figure for figure), reports the shape unchanged and says why.
 */
T_CASE(prepare_prints_the_oriented_part_when_slimming_fails)
{
    struct sf_err err;
    char part[512];
    tee_file("tee.stl", part, sizeof(part));
    struct prepare_out oriented, out;
    T_OK(prepare_job(part, "orient", 0, 0, &oriented, &err), &err);
    T_TRUE(oriented.shape_failed[0] == '\0');

    warned[0] = '\0';
    log_set_sink(warn_sink, NULL);
    int rc = prepare_job(part, "slim", 0, 0, &out, &err);
    log_set_sink(NULL, NULL);
    T_OK(rc, &err);
    printf("    %s", warned);
    /* the G-code is there and is the oriented part's */
    char gcode[600], gcode_oriented[600];
    snprintf(gcode, sizeof(gcode), "%s/prep-slim.gcode", t_tmpdir());
    snprintf(gcode_oriented, sizeof(gcode_oriented), "%s/prep-orient.gcode", t_tmpdir());
    T_TRUE(same_bytes(gcode, gcode_oriented));
    T_EQ_DBL(support_g_in(gcode), oriented.support_g, 0.005);
    for (int i = 0; i < 3; i++)
        T_EQ_DBL(out.size_mm[i], oriented.size_mm[i], 1e-9);
    T_EQ_DBL(out.filament_g, oriented.filament_g, 1e-9);
    T_EQ_DBL(out.support_g, oriented.support_g, 1e-9);
    /* the shape is reported unchanged, and why slimming did not run */
    T_TRUE(out.dev_measured && !out.shape_changed);
    T_EQ_DBL(out.mndr, 0, 0);
    T_EQ_DBL(out.andr, 0, 0);
    T_TRUE(strstr(out.shape_failed, "deviation limits") != NULL);
    T_TRUE(strstr(warned, "job 1: slimming failed") != NULL);
    T_TRUE(strstr(warned, "deviation limits") != NULL);
    T_TRUE(strstr(warned, "as oriented, unchanged") != NULL);
    T_EQ_DBL(out.support_saved_g, oriented.support_saved_g, 1e-9); /* orientation's saving */
}

/*
 * The same for the surface method: its optimizer refuses a 0 mm budget as
 * slimming does, and the job prints the part as given (the method none's
 * G-code, byte for byte) and says why.
 */
T_CASE(prepare_prints_the_part_as_given_when_surface_optimization_fails)
{
    struct sf_err err;
    char part[512];
    tee_file("tee-s.stl", part, sizeof(part));
    struct prepare_out given, out;
    T_OK(prepare_job(part, "none", 0, 0, &given, &err), &err);
    warned[0] = '\0';
    log_set_sink(warn_sink, NULL);
    int rc = prepare_job(part, "surface", 0, 0, &out, &err);
    log_set_sink(NULL, NULL);
    T_OK(rc, &err);
    printf("    %s", warned);
    char gcode[600], gcode_given[600];
    snprintf(gcode, sizeof(gcode), "%s/prep-surface.gcode", t_tmpdir());
    snprintf(gcode_given, sizeof(gcode_given), "%s/prep-none.gcode", t_tmpdir());
    T_TRUE(same_bytes(gcode, gcode_given));
    T_EQ_DBL(out.support_g, given.support_g, 1e-9);
    T_TRUE(out.dev_measured && !out.shape_changed);
    T_TRUE(strstr(out.shape_failed, "surface optimization failed") != NULL);
    T_TRUE(strstr(out.shape_failed, "deviation limits") != NULL);
    T_TRUE(strstr(out.shape_failed, "printed as given, unchanged") != NULL);
    T_TRUE(strstr(warned, "job 1: surface optimization failed") != NULL);
}

/*
 * A job may ask for any overhang angle from 1 to 89 degrees (job.c); below
 * slimming's 5 degree margin it refused the angle, so a slim job printed
 * the part unslimmed.  The margin narrows to the angle, as the surface
 * method's does.
 */
T_CASE(prepare_slims_at_an_angle_below_the_margin)
{
    struct sf_err err;
    char part[512];
    tee_file("tee3.stl", part, sizeof(part));
    struct prepare_out out;
    T_OK(prepare_job(part, "slim", 2, 3, &out, &err), &err);
    printf("    shape_failed \"%s\", changed %d\n", out.shape_failed, out.shape_changed);
    T_EQ_STR(out.shape_failed, "");
    T_TRUE(out.dev_measured);
}
