/*
 * test_filament.c - a G-code file's net E by command line (filament.h): E
 * modes and resets, comments and blank lines not counted, and a file of
 * more lines than marks (the marks thin out, the share stays exact for
 * even extrusion).  Real files.
 */
#include <stdio.h>
#include <string.h>

#include "../../src/farm/filament.h"
#include "../t.h"

static const char *
write_file(const char *name, const char *text)
{
    static char path[512];
    snprintf(path, sizeof(path), "%s/%s", t_tmpdir(), name);
    FILE *f = fopen(path, "w");
    if (f) {
        fputs(text, f);
        fclose(f);
    }
    return path;
}

T_CASE(filament_follows_e_modes_and_resets)
{
    struct sf_err err;
    struct filament f;
    const char *path = write_file("modes.gcode", "; header\n"
                                                 "G28\n"
                                                 "G1 X1 E2\n"          /* absolute: 2 */
                                                 "G1 X2 E1.5 ; wipe\n" /* retract 0.5 */
                                                 "\n"
                                                 "G1 X3 E4\n" /* 2.5 */
                                                 "G92 E0\n"
                                                 "M83\n"
                                                 "G1 X4 E1\n"           /* relative: 1 */
                                                 "G1 E-1\nG1 E1\n"      /* retract, prime: 0 */
                                                 "G90\n"                /* E absolute again */
                                                 "G92 E10\nG1 X5 E11\n" /* 1 */
                                                 "G2 X6 Y1 I1 E12\n");  /* an arc: 1 */
    T_OK(filament_scan(path, &f, &err), &err);
    T_EQ_INT(f.lines, 13);
    T_EQ_DBL(f.total_mm, 2 - 0.5 + 2.5 + 1 + 1 + 1, 1e-9);
    T_EQ_DBL(filament_at(&f, 0), 0, 0);
    T_EQ_DBL(filament_at(&f, 2), 2, 1e-9);
    T_EQ_DBL(filament_at(&f, 3), 1.5, 1e-9);
    T_EQ_DBL(filament_at(&f, 4), 4, 1e-9);
    T_EQ_DBL(filament_at(&f, 7), 5, 1e-9);
    T_EQ_DBL(filament_at(&f, 99), f.total_mm, 0);
    T_ERR(filament_scan("/nonexistent/x.gcode", &f, &err), SF_EIO, &err, "cannot open");
}

T_CASE(filament_of_a_long_file_thins_its_marks)
{
    struct sf_err err;
    char path[512];
    snprintf(path, sizeof(path), "%s/long.gcode", t_tmpdir());
    FILE *out = fopen(path, "w");
    T_TRUE(out != NULL);
    fputs("M83\n", out);
    for (int i = 0; i < 100000; i++)
        fputs(i % 2 ? "G1 X1 E0.5\n" : "G1 X0 E1.5\n", out); /* 1 mm a line on average */
    fclose(out);
    static struct filament f;
    T_OK(filament_scan(path, &f, &err), &err);
    T_EQ_INT(f.lines, 100001);
    T_TRUE(f.n_marks <= FILAMENT_MARKS + 1);
    T_EQ_INT(f.step, 128); /* 100,001 lines over at most 1024 spans */
    T_EQ_DBL(f.total_mm, 100000, 1e-6);
    T_EQ_DBL(filament_at(&f, 128 * 300), 128 * 300 - 0.5,
             1e-6);                                           /* on a mark: M83, then 38399 G1s */
    T_EQ_DBL(filament_at(&f, 1 + 2 * 12345), 2 * 12345, 1.0); /* between marks: by lines */
    T_EQ_DBL(filament_at(&f, 100000), 100000 - 0.5, 1.0);
}
