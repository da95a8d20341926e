/*
 * test_gpolicy.c - the G-code policy (drivers/gpolicy.h): each row of the
 * table refused in a job file with its line named (M110 in the middle and
 * as the first line, "M110" in another command's text, M118 "Resend: 1",
 * control and non-ASCII bytes, EEPROM and firmware commands, waits for a
 * person, M112), waits passed on an attended printer and a row passed by
 * allow_gcode, protocol rows never allowable, manual commands (a raw M118
 * reply rewritten to M118 E1), the "and N more" cap, and every part the
 * farm slices (each generated shape, each shipped printer profile) passing
 * with no finding.
 */
#include <stdio.h>
#include <string.h>

#include "../../drivers/gpolicy.h"
#include "../../slicer/profile.h"
#include "../../src/base/buf.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"
#include "slice_run.h"

/* Findings of text judged by p (NULL: the defaults), the message in msg. */
static size_t
judge(const struct gpolicy *p, const char *text, char *msg, size_t n)
{
    struct gpolicy def;
    gpolicy_init(&def);
    return gpolicy_check_text(p ? p : &def, text, strlen(text), "t.gcode", msg, n);
}

T_CASE(gpolicy_refuses_m110_naming_its_line)
{
    char msg[4096];
    T_EQ_INT(judge(NULL, "G28\nG1 X10 F600\nM110 N0\nG1 X20\n", msg, sizeof(msg)), 1);
    T_TRUE(strstr(msg, "G-code 't.gcode': line 3: M110: the host numbers the lines") != NULL);
    T_EQ_INT(judge(NULL, "M110 N0\nG28\n", msg, sizeof(msg)), 1);
    T_TRUE(strstr(msg, "line 1: M110") != NULL);
    /* as Marlin reads them: leading zeros, a line number first, "M110" in a text */
    T_EQ_INT(judge(NULL, "M0110 N5\nN7 M110\nM117 M110 N1\nm110\n", msg, sizeof(msg)), 4);
    T_TRUE(strstr(msg, "line 3: M117: the line holds \"M110\"") != NULL);
    /* a comment may say so */
    T_EQ_INT(judge(NULL, "G28 ; no M110 here\n; M110 N0\n", msg, sizeof(msg)), 0);
    T_EQ_STR(msg, "");
}

T_CASE(gpolicy_refuses_text_that_reads_as_a_host_reply)
{
    char msg[4096];
    T_EQ_INT(judge(NULL, "G28\nM118 Resend: 1\n", msg, sizeof(msg)), 1);
    T_TRUE(strstr(msg, "line 2: M118: prints its text raw") != NULL);
    const char *bad[] = {
        "M118 ok",      "M118 ok T:210", "M118 Error:x", "M118 busy: x",   "M118 E1 busy: x",
        "M118 start",   "M118 wait",     "M118 !! x",    "M117 Resend: 3", "M118 A1 action:cancel",
        "M118 P0 rs 4", "M118 T:20 /0",  "M118 oR T:210"
    };
    for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++)
        T_EQ_INT(judge(NULL, bad[i], msg, sizeof(msg)), 1);
    const char *good[] = { "M118 E1 Resend: 1", "M118 A1 hello",  "M117 Printing...",
                           "M118 okay",         "M118 Starting",  "M117 Layer 3 of 40",
                           "M117 start wide",   "M118 wait a bit" };
    for (size_t i = 0; i < sizeof(good) / sizeof(good[0]); i++)
        T_EQ_INT(judge(NULL, good[i], msg, sizeof(msg)), 0);
}

T_CASE(gpolicy_refuses_control_and_non_ascii_bytes)
{
    char msg[4096];
    const char nul[] = "G28\nG1 X1\0M110\nG1 X2\n";
    struct gpolicy p;
    gpolicy_init(&p);
    T_EQ_INT(gpolicy_check_text(&p, nul, sizeof(nul) - 1, "t.gcode", msg, sizeof(msg)), 1);
    T_TRUE(strstr(msg, "line 2: byte 0x00: control bytes") != NULL);
    T_EQ_INT(judge(NULL, "G1 X1\rM110 N3\n", msg, sizeof(msg)), 1); /* a CR: a line end */
    T_EQ_INT(judge(NULL, "G1 X1\r\nG1 X2\x1b\n", msg, sizeof(msg)), 1);
    T_TRUE(strstr(msg, "line 2: byte 0x1b") != NULL);
    T_EQ_INT(judge(NULL, "G1 X1 \xc2\xb0\n", msg, sizeof(msg)), 1);
    T_TRUE(strstr(msg, "non-ASCII") != NULL);
    T_EQ_INT(judge(NULL,
                   "G1 X1 ; 210 \xc2\xb0"
                   "C\n\tG1 X2\n",
                   msg, sizeof(msg)),
             0);
}

T_CASE(gpolicy_refuses_eeprom_firmware_waits_and_stops)
{
    char msg[4096];
    const char *rows[] = { "M502", "M500",       "M501",        "M997",
                           "M999", "M0",         "M1",          "M600",
                           "M25",  "M226 P1 S0", "M112",        "M108",
                           "M410", "M111 S7",    "SAVE_CONFIG", "FIRMWARE_RESTART",
                           "pause" };
    for (size_t i = 0; i < sizeof(rows) / sizeof(rows[0]); i++) {
        char text[64];
        snprintf(text, sizeof(text), "G28\n%s\n", rows[i]);
        T_EQ_INT(judge(NULL, text, msg, sizeof(msg)), 1);
        T_TRUE(strstr(msg, "line 2: ") != NULL);
    }
    /* M10, M104 and M1000 are not M1 */
    T_EQ_INT(judge(NULL, "M104 S200\nM10\nM1000\nG1 X1\n", msg, sizeof(msg)), 0);
}

/*
 * The line as the printer receives it: Marlin skips blanks between a
 * command's letter and its number, and our driver sends the line without
 * (paren) comments and checksum, so none of these spellings gets past.
 */
T_CASE(gpolicy_judges_the_line_the_printer_runs)
{
    char msg[4096];
    const char *bad[] = { "M 110 N1000",       "M\t110 N1000", "M(c)110 N5",    "(x)M112",
                          "N3 M 112*40",       "M 500",        "M118 start*57", "M118 (x)ok",
                          "M118 (x)Resend: 1", "M118 wait*1" };
    for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
        T_EQ_INT(judge(NULL, bad[i], msg, sizeof(msg)), 1);
        T_TRUE(strstr(msg, "line 1: ") != NULL);
    }
    /* "M110" in a line an attended printer passes still resets the numbering */
    struct gpolicy p;
    gpolicy_init(&p);
    p.attended = true;
    T_EQ_INT(judge(&p, "M600 M110 N1000\nM600\n", msg, sizeof(msg)), 1);
    T_TRUE(strstr(msg, "line 1: ") != NULL);
    /* a manual command is judged the same way */
    struct gpolicy_verdict v;
    T_EQ_INT(gpolicy_check_line(&p, GPOLICY_MANUAL, "M 110 N1000", 11, &v), GPOLICY_REFUSE);
    T_EQ_INT(gpolicy_check_line(&p, GPOLICY_MANUAL, "G 28", 4, &v), GPOLICY_PASS);
}

T_CASE(gpolicy_attended_and_allowed_printers_pass_their_rows)
{
    char msg[4096];
    struct sf_err err;
    struct gpolicy p;
    gpolicy_init(&p);
    p.attended = true;
    T_EQ_INT(judge(&p, "M600\nM0\nM25\nM500\n", msg, sizeof(msg)), 1); /* M500: not a wait */
    gpolicy_init(&p);
    T_OK(gpolicy_allow(&p, "m600, M500", &err), &err);
    T_EQ_INT(judge(&p, "M600\nM500\nM0\n", msg, sizeof(msg)), 1);
    T_TRUE(strstr(msg, "line 3: M0:") != NULL);
    T_ERR(gpolicy_allow(&p, "M110", &err), SF_EINVAL, &err, "'M110' is the host's protocol");
    T_ERR(gpolicy_allow(&p, "M600 G28", &err), SF_EINVAL, &err, "'G28' is not a command");
    /* a group: what every printer of it passes */
    struct gpolicy acc, att;
    gpolicy_all(&acc);
    gpolicy_init(&att);
    att.attended = true;
    gpolicy_meet(&acc, &att);
    T_EQ_INT(judge(&acc, "M600\n", msg, sizeof(msg)), 0);
    gpolicy_meet(&acc, &p); /* p: M600 and M500 */
    T_EQ_INT(judge(&acc, "M600\nM0\nM500\n", msg, sizeof(msg)), 2);
}

T_CASE(gpolicy_manual_commands)
{
    struct gpolicy p;
    struct gpolicy_verdict v;
    gpolicy_init(&p);
    const char *c = "M118 Resend: 1";
    T_EQ_INT(gpolicy_check_line(&p, GPOLICY_MANUAL, c, strlen(c), &v), GPOLICY_REWRITE);
    T_EQ_STR(v.line, "M118 E1 Resend: 1");
    c = "M108";
    T_EQ_INT(gpolicy_check_line(&p, GPOLICY_MANUAL, c, strlen(c), &v), GPOLICY_PASS);
    T_EQ_INT(gpolicy_check_line(&p, GPOLICY_FILE, c, strlen(c), &v), GPOLICY_REFUSE);
    c = "M110 N1000";
    T_EQ_INT(gpolicy_check_line(&p, GPOLICY_MANUAL, c, strlen(c), &v), GPOLICY_REFUSE);
    T_EQ_STR(v.cmd, "M110");
    c = "M112";
    T_EQ_INT(gpolicy_check_line(&p, GPOLICY_MANUAL, c, strlen(c), &v), GPOLICY_REFUSE);
    T_TRUE(strstr(v.why, "emergency stop") != NULL);
    c = "G28\nM110";
    T_EQ_INT(gpolicy_check_line(&p, GPOLICY_MANUAL, c, strlen(c), &v), GPOLICY_REFUSE);
}

T_CASE(gpolicy_names_twenty_lines_then_counts)
{
    char text[4096] = "", msg[4096];
    for (int i = 0; i < 25; i++)
        memcpy(text + 3 * i, "M0\n", 4);
    T_EQ_INT(judge(NULL, text, msg, sizeof(msg)), 25);
    T_TRUE(strstr(msg, "line 20: M0") != NULL);
    T_TRUE(strstr(msg, "line 21:") == NULL);
    T_TRUE(strstr(msg, "; and 5 more") != NULL);
    /* a small buffer is cut, never overrun */
    char small[40];
    T_EQ_INT(judge(NULL, text, small, sizeof(small)), 25);
    T_EQ_INT(strlen(small), sizeof(small) - 1);
}

T_CASE(gpolicy_file_reader_matches_the_text_judge)
{
    char path[512], msg[4096], msg2[4096];
    snprintf(path, sizeof(path), "%s/p.gcode", t_tmpdir());
    const char text[] = "G28\nM600\nG1 X1\nM118 ok\nG1 X2"; /* no final newline */
    FILE *f = fopen(path, "wb");
    T_TRUE(f != NULL);
    fwrite(text, 1, sizeof(text) - 1, f);
    fclose(f);
    struct gpolicy p;
    struct sf_err err;
    size_t n = 0;
    gpolicy_init(&p);
    T_ERR(gpolicy_check_file(&p, path, "p.gcode", msg, sizeof(msg), &n, &err), SF_EINVAL, &err,
          "line 2: M600");
    T_EQ_INT(n, 2);
    T_EQ_INT(gpolicy_check_text(&p, text, sizeof(text) - 1, "p.gcode", msg2, sizeof(msg2)), 2);
    T_EQ_STR(msg, msg2);
    T_EQ_INT(gpolicy_check_file(&p, "/nonexistent/x.gcode", "x", msg, sizeof(msg), &n, &err),
             SF_EIO);
}

/* Every part the farm slices, by every shipped printer profile, passes. */
T_CASE(gpolicy_passes_every_part_the_farm_slices)
{
    const char *profiles[] = { "config/printers/generic-marlin.cfg",
                               "config/printers/prusa-mk3s.cfg" };
    int (*shapes[])(struct mesh *, struct sf_err *) = { shape_tee, shape_arch, shape_lbracket,
                                                        shape_sphere_on_stem, shape_frame };
    struct sf_err err;
    struct gpolicy p;
    gpolicy_init(&p);
    for (size_t k = 0; k < sizeof(profiles) / sizeof(profiles[0]); k++) {
        struct slice_profile sp;
        T_OK(slice_profile_load(profiles[k], "config/materials/pla.cfg", &sp, &err), &err);
        for (size_t s = 0; s < sizeof(shapes) / sizeof(shapes[0]); s++) {
            struct mesh m;
            mesh_init(&m);
            char path[512], msg[4096];
            size_t n = 99;
            T_OK(shapes[s](&m, &err), &err);
            T_OK(ts_slice(&m, &sp, "part", NULL, path, sizeof(path), &err), &err);
            T_OK(gpolicy_check_file(&p, path, "part.gcode", msg, sizeof(msg), &n, &err), &err);
            T_EQ_INT(n, 0);
            mesh_release(&m);
        }
        slice_profile_release(&sp);
    }
}
