/*
 * test_slice_estimate.c - the planner against hand computations on short
 * move sequences, and the interpreter's modes (relative E, G92, roles).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../slicer/estimate.h"
#include "../t.h"

static void
limits(struct est_limits *l, double accel, double jerk)
{
    memset(l, 0, sizeof(*l));
    for (int a = 0; a < 4; a++) {
        l->max_feed_mm_s[a] = 1000;
        l->jerk_mm_s[a] = jerk;
    }
    l->accel_extrude_mm_s2 = l->accel_travel_mm_s2 = l->accel_retract_mm_s2 = accel;
}

static double
est(const char *g, const struct est_limits *l, struct estimate *e)
{
    struct sf_err err;
    if (estimate_gcode(g, strlen(g), "t", l, NULL, NULL, e, &err) < 0)
        return -1;
    double t = e->time_s;
    return t;
}

T_CASE(estimate_single_move_triangle_profile)
{
    /* 10 mm at 100 mm/s, 1000 mm/s^2, no jerk: accelerates 5 mm, brakes
       5 mm, never cruises: t = 2 sqrt(L / a) = 0.2 s */
    struct est_limits l;
    struct estimate e;
    limits(&l, 1000, 0);
    T_EQ_DBL(est("G1 X10 F6000\n", &l, &e), 0.2, 1e-6);
    estimate_release(&e);
}

T_CASE(estimate_single_move_with_jerk)
{
    /* jerk 10: starts and ends at 10 mm/s; 4.95 mm up, 4.95 mm down,
       0.1 mm at 100 mm/s: 0.09 + 0.09 + 0.001 = 0.181 s */
    struct est_limits l;
    struct estimate e;
    limits(&l, 1000, 10);
    T_EQ_DBL(est("G1 X10 F6000\n", &l, &e), 0.181, 1e-6);
    estimate_release(&e);
    /* split in two collinear halves: the junction runs at full speed */
    T_EQ_DBL(est("G1 X5 F6000\nG1 X10\n", &l, &e), 0.181, 1e-6);
    estimate_release(&e);
}

T_CASE(estimate_right_angle_corner)
{
    /* X then Y at 100 mm/s, jerk 10: the corner is taken at 10 mm/s (the
       X axis may drop by at most 10), so each leg is the 0.181 s above */
    struct est_limits l;
    struct estimate e;
    limits(&l, 1000, 10);
    T_EQ_DBL(est("G1 X10 F6000\nG1 Y10\n", &l, &e), 0.362, 1e-6);
    estimate_release(&e);
    /* a reversal: the same, by Marlin's rule (max of the two speeds) */
    T_EQ_DBL(est("G1 X10 F6000\nG1 X0\n", &l, &e), 0.362, 1e-6);
    estimate_release(&e);
}

T_CASE(estimate_cruise_and_feed_cap)
{
    /* 100 mm at F6000 but X capped at 50 mm/s: 50 mm/s cruise,
       accel 0.025 s over 0.625 mm at each end: 0.05 + 98.75 / 50 = 2.025 s */
    struct est_limits l;
    struct estimate e;
    limits(&l, 2000, 0);
    l.max_feed_mm_s[0] = 50;
    T_EQ_DBL(est("G1 X100 F6000\n", &l, &e), 2.025, 1e-6);
    estimate_release(&e);
}

T_CASE(estimate_filament_modes_and_roles)
{
    struct est_limits l;
    struct estimate e;
    limits(&l, 1000, 10);
    const char *abs_e = "M82\nG92 E0\n;LAYER_CHANGE\nG1 X10 E1 F1200\nG1 E0.2\n"
                        ";TYPE:Support material\nG1 X20 E1.7\nG92 E0\n;LAYER_CHANGE\n"
                        ";TYPE:Perimeter\nG1 Y10 E0.5\nG4 S2\n";
    T_TRUE(est(abs_e, &l, &e) > 2);
    T_EQ_DBL(e.filament_mm, 1 + 1.5 + 0.5, 1e-9);
    T_EQ_DBL(e.support_mm, 1.5, 1e-9);
    T_EQ_INT(e.n_layers, 2);
    T_TRUE(e.layer_start_s[1] > e.layer_start_s[0]);
    estimate_release(&e);
    const char *rel_e = "M83\nG1 X10 E1 F1200\nG1 E-0.8\nG1 E0.8\nG91\nG1 X10 E1\n";
    T_TRUE(est(rel_e, &l, &e) > 0);
    T_EQ_DBL(e.filament_mm, 2, 1e-9);
    T_EQ_INT(e.n_moves, 4);
    estimate_release(&e);
}

T_CASE(estimate_bad_line_names_it)
{
    struct est_limits l;
    struct estimate e;
    struct sf_err err;
    limits(&l, 1000, 10);
    const char *g = "G1 X1\nG1 X\xff"
                    "5\n";
    int rc = estimate_gcode(g, strlen(g), "part.gcode", &l, NULL, NULL, &e, &err);
    T_TRUE(rc == SF_OK || (rc == SF_EINVAL && strstr(err.msg, "part.gcode:2") != NULL));
}

/* A malformed line is SF_EINVAL naming it, with or without a message buffer (the fuzz
   harness passes none; it was SF_EBUG then). */
T_CASE(estimate_bad_line_is_einval_even_without_err)
{
    struct est_limits l;
    struct estimate e;
    struct sf_err err;
    limits(&l, 1000, 10);
    const char *g = "G1 X1\n5 X2\n";
    T_EQ_INT(estimate_gcode(g, strlen(g), "bad.gcode", &l, NULL, NULL, &e, NULL), SF_EINVAL);
    T_ERR(estimate_gcode(g, strlen(g), "bad.gcode", &l, NULL, NULL, &e, &err), SF_EINVAL, &err,
          "bad.gcode:2: column 1: command expected");
}

static int
stop_at_second(void *ud, const struct est_move *mv)
{
    (void)mv;
    return ++*(int *)ud == 2 ? SF_ECANCELED : SF_OK;
}

/* A move callback that stops the walk gets its status back, and the message says where and
   why (it was left empty). */
T_CASE(estimate_names_the_line_a_move_callback_stopped_at)
{
    struct est_limits l;
    struct estimate e;
    struct sf_err err;
    limits(&l, 1000, 10);
    const char *g = "G1 X1 F600\n;TYPE:Perimeter\nG1 X2\nG1 X3\n";
    int calls = 0;
    sf_err_clear(&err);
    T_ERR(estimate_gcode(g, strlen(g), "stop.gcode", &l, stop_at_second, &calls, &e, &err),
          SF_ECANCELED, &err, "stop.gcode:3: stopped by the move callback (ECANCELED)");
    T_EQ_INT(calls, 2);
}

T_CASE(estimate_rejects_absurd_coordinates)
{
    struct est_limits l;
    struct estimate e;
    struct sf_err err;
    limits(&l, 1000, 10);
    const char *g = "G1 X10\nG1 X2000000\n";
    T_ERR(estimate_gcode(g, strlen(g), "big.gcode", &l, NULL, NULL, &e, &err), SF_EINVAL, &err,
          "big.gcode:2: X2e+06 is out of range");
}

T_CASE(estimate_junction_deviation_corner)
{
    /* JD 0.05 mm, 1000 mm/s^2, 100 mm/s, no jerk (start and end at rest):
       a 90 degree corner allows v = sqrt(a * jd * s / (1 - s)), s = sin 45;
       each 10 mm leg: up from 0 to 100, cruise, down to v (or the mirror) */
    struct est_limits l;
    struct estimate e;
    limits(&l, 1000, 0);
    l.junction_dev_mm = 0.05;
    double a = 1000, vn = 100, len = 10, s = sqrt(0.5);
    double v = sqrt(a * 0.05 * s / (1 - s));
    double d_up = vn * vn / (2 * a), d_down = (vn * vn - v * v) / (2 * a);
    double leg = vn / a + (vn - v) / a + (len - d_up - d_down) / vn;
    T_EQ_DBL(est("G1 X10 F6000\nG1 Y10\n", &l, &e), 2 * leg, 1e-6);
    estimate_release(&e);
    /* straight on: no limit at the junction */
    double two = est("G1 X10 F6000\nG1 X20\n", &l, &e);
    estimate_release(&e);
    double one = est("G1 X20 F6000\n", &l, &e);
    estimate_release(&e);
    T_EQ_DBL(two, one, 1e-9);
}

T_CASE(estimate_follows_firmware_limits_in_the_file)
{
    /* the file's M201-M205 replace the caller's limits from that line on */
    struct est_limits l;
    struct estimate e;
    limits(&l, 1000, 0);
    /* M204 P500: an extruding 10 mm triangle at 500 mm/s2: 2 sqrt(10 / 500) */
    T_EQ_DBL(est("M204 P500\nG1 X10 E1 F6000\n", &l, &e), 2 * sqrt(10.0 / 500), 1e-6);
    estimate_release(&e);
    /* ... but travel keeps 1000 (0.2 s); M204 T250 makes it 0.4 s */
    T_EQ_DBL(est("M204 P500\nG1 X10 F6000\n", &l, &e), 0.2, 1e-6);
    estimate_release(&e);
    T_EQ_DBL(est("M204 T250\nG1 X10 F6000\n", &l, &e), 0.4, 1e-6);
    estimate_release(&e);
    /* M204 S sets print and travel */
    T_EQ_DBL(est("M204 S250\nG1 X10 F6000\nG1 X20 E1\n", &l, &e), 0.8, 1e-6);
    estimate_release(&e);
    /* M201 X250 Y1000 on a 45 degree move of 14.14 mm: X takes 250 at
       cos 45, so the move gets 353.6 mm/s2: 2 sqrt(14.142 / 353.55) = 0.4 s */
    T_EQ_DBL(est("M201 X250 Y1000\nG1 X10 Y10 F6000\n", &l, &e), 0.4, 1e-6);
    estimate_release(&e);
    /* M203 X50 (mm/s): the feed-cap case, 2.025 s at 2000 mm/s2 */
    limits(&l, 2000, 0);
    T_EQ_DBL(est("M203 X50\nG1 X100 F6000\n", &l, &e), 2.025, 1e-6);
    estimate_release(&e);
    /* M205 X10 Y10: the jerk case, 0.181 s */
    limits(&l, 1000, 0);
    T_EQ_DBL(est("M205 X10 Y10\nG1 X10 F6000\n", &l, &e), 0.181, 1e-6);
    estimate_release(&e);
    /* limits apply from their line on: the first move keeps 1000 */
    T_EQ_DBL(est("G1 X10 F6000\nM204 T250\nG1 X0\n", &l, &e), 0.2 + 0.4, 1e-6);
    estimate_release(&e);
    /* nonsense values are ignored */
    T_EQ_DBL(est("M204 T-5 S0\nM201 X0\nM203 X-1\nG1 X10 F6000\n", &l, &e), 0.2, 1e-6);
    estimate_release(&e);
}

/* n copies of line into a fresh buffer (free()), after head. */
static char *
repeat(const char *head, const char *line, size_t n)
{
    size_t hl = strlen(head), ll = strlen(line);
    char *g = malloc(hl + n * ll + 1);
    if (!g)
        return NULL;
    memcpy(g, head, hl);
    for (size_t i = 0; i < n; i++)
        memcpy(g + hl + i * ll, line, ll);
    g[hl + n * ll] = 0;
    return g;
}

T_CASE(estimate_refuses_an_arc_longer_than_any_printer_naming_its_line)
{
    /* radius 100 m: a full turn is 628 km of 1 mm segments */
    struct est_limits l;
    struct estimate e;
    struct sf_err err;
    limits(&l, 1000, 10);
    char *g = repeat("G1 X10 F6000\n", "G2 I100000\n", 370);
    T_TRUE(g != NULL);
    T_ERR(estimate_gcode(g, strlen(g), "arc.gcode", &l, NULL, NULL, &e, &err), SF_EINVAL, &err,
          "arc.gcode:2: arc of 628319 mm is longer than 10 m");
    free(g);
}

T_CASE(estimate_holds_a_bounded_window_of_arc_segments)
{
    /* 3000 full turns of radius 1 m (EST_ARC_BLOCKS_MAX blocks each, more
       than a window's worth), with sane and with absurdly low acceleration
       (no block is final until the window is full) */
    struct est_limits l;
    struct estimate e;
    limits(&l, 1000, 10);
    static const char *heads[] = { "G1 X10 F6000\n", "M204 S0.001\nG1 X10 F6000\n" };
    for (int h = 0; h < 2; h++) {
        char *g = repeat(heads[h], "G2 I1000\n", 3000);
        T_TRUE(g != NULL);
        double t = est(g, &l, &e);
        free(g);
        T_TRUE(t > 0 && isfinite(t));
        T_EQ_INT(e.n_moves, 3001);
        T_TRUE(e.n_blocks > EST_LOOKAHEAD_BLOCKS);
        T_TRUE(e.peak_blocks > 0 && e.peak_blocks <= EST_LOOKAHEAD_BLOCKS);
        estimate_release(&e);
    }
}

/* An upload of arcs just under the 10 m limit, a few bytes each, was
   planned as 1 mm segments: 10000 blocks per 9-byte line.  Each arc now
   costs at most EST_ARC_BLOCKS_MAX blocks, and its time is still that of
   its 1 mm segments: here every turn continues the one before, so the
   whole file is one smooth path at 100 mm/s. */
T_CASE(estimate_bounds_the_work_of_arcs_just_under_the_limit)
{
    struct est_limits l;
    struct estimate e;
    limits(&l, 1000, 10);
    size_t n = 200;
    double r = 1591; /* 9996.5 mm a turn */
    char *g = repeat("G1 Y10 F6000\n", "G2 I1591\n", n);
    T_TRUE(g != NULL);
    double t = est(g, &l, &e);
    size_t len = strlen(g);
    free(g);
    T_EQ_INT(e.n_moves, n + 1);
    T_TRUE(e.n_blocks <= 1 + n * EST_ARC_BLOCKS_MAX);
    /* the rule in estimate.h: at most 8 blocks per byte of G-code */
    T_TRUE(e.n_blocks <= len * 8);
    /* jerk 10 to 100 mm/s and back: 0.09 s and 4.95 mm at each end */
    double path = 10 + n * 2 * M_PI * r;
    T_EQ_DBL(t, 0.18 + (path - 9.9) / 100, 1e-3);
    estimate_release(&e);
}

/* The arc of lines 2- as 1 mm chords: G1 lines after head (free()). */
static char *
arc_as_chords(const char *head, double x0, double y0, double r, double sweep)
{
    int n = (int)ceil(fabs(sweep) * r);
    size_t cap = strlen(head) + (size_t)n * 48 + 1, used = 0;
    char *g = malloc(cap);
    if (!g)
        return NULL;
    used += (size_t)snprintf(g, cap, "%s", head);
    double cx = x0 - r, cy = y0; /* the arc starts at angle 0 */
    for (int k = 1; k <= n; k++) {
        double a = sweep * k / n;
        used += (size_t)snprintf(g + used, cap - used, "G1 X%.9f Y%.9f E%.9f\n", cx + r * cos(a),
                                 cy + r * sin(a), 0.03 * fabs(sweep) * r / n);
    }
    return g;
}

/* A long arc planned as EST_ARC_BLOCKS_MAX blocks times as its 1 mm
   segments do: at full speed through them (jerk 10 at 100 mm/s, radius
   100), sawing between junction stops (jerk 1 at 200 mm/s, radius 20;
   jerk 0: every segment a triangle), by junction deviation, and at an
   acceleration too low to reach speed on the arc. */
T_CASE(estimate_times_a_long_arc_as_its_1mm_segments)
{
    static const struct {
        double r, sweep, jerk, jd, accel;
        const char *f;
    } c[] = {
        { 100, 5.5, 10, 0, 1000, "F6000" }, { 20, -5.9, 1, 0, 1000, "F12000" },
        { 50, 3.0, 0, 0, 1500, "F3000" },   { 10, 6.0, 10, 0.02, 1500, "F12000" },
        { 300, -4.0, 10, 0, 0.5, "F6000" },
    };
    for (size_t i = 0; i < sizeof(c) / sizeof(c[0]); i++) {
        struct est_limits l;
        struct estimate e;
        limits(&l, c[i].accel, c[i].jerk);
        l.junction_dev_mm = c[i].jd;
        char head[96], arc[160];
        snprintf(head, sizeof(head), "M83\nG1 X%.1f Y0 %s\n", c[i].r + 5, c[i].f);
        double x1 = 5 + cos(c[i].sweep) * c[i].r, y1 = sin(c[i].sweep) * c[i].r;
        snprintf(arc, sizeof(arc), "%sG%d X%.9f Y%.9f I%.1f J0 E%.9f\nG1 X%.9f Y%.9f\n", head,
                 c[i].sweep < 0 ? 2 : 3, x1, y1, -c[i].r, 0.03 * fabs(c[i].sweep) * c[i].r, x1 + 5,
                 y1);
        double t_arc = est(arc, &l, &e);
        T_TRUE(e.n_blocks <= 2 + EST_ARC_BLOCKS_MAX);
        estimate_release(&e);
        char *g = arc_as_chords(head, c[i].r + 5, 0, c[i].r, c[i].sweep);
        T_TRUE(g != NULL);
        char *g2 = malloc(strlen(g) + 64);
        T_TRUE(g2 != NULL);
        snprintf(g2, strlen(g) + 64, "%sG1 X%.9f Y%.9f\n", g, x1 + 5, y1);
        double t_seg = est(g2, &l, &e);
        T_TRUE(e.n_blocks > 2 + EST_ARC_BLOCKS_MAX);
        estimate_release(&e);
        free(g);
        free(g2);
        /* within estimate.h's 1 % */
        T_EQ_DBL(t_arc, t_seg, 0.01 * t_seg);
    }
}

T_CASE(estimate_streams_a_long_file_as_one_plan)
{
    /* 200000 collinear 0.5 mm moves (three windows' worth) plan as one
       100 m move: 0.09 s up from jerk 10 to 100 mm/s over 4.95 mm, the
       same down, the rest at 100 mm/s; the layer at move 100000 starts
       0.09 s + (50000 - 4.95) mm / 100 mm/s in */
    struct est_limits l;
    struct estimate e;
    limits(&l, 1000, 10);
    size_t n = 200000;
    size_t cap = n * 24 + 64, used = 0;
    char *g = malloc(cap);
    T_TRUE(g != NULL);
    used += (size_t)snprintf(g, cap, "G1 F6000\n");
    for (size_t i = 1; i <= n; i++) {
        if (i == n / 2 + 1)
            used += (size_t)snprintf(g + used, cap - used, ";LAYER_CHANGE\n");
        used += (size_t)snprintf(g + used, cap - used, "G1 X%.1f\n", (double)i * 0.5);
    }
    double t = est(g, &l, &e);
    free(g);
    T_EQ_DBL(t, 0.18 + (100000 - 9.9) / 100, 1e-3);
    T_EQ_INT(e.n_layers, 1);
    T_EQ_DBL(e.layer_start_s[0], 0.09 + (50000 - 4.95) / 100, 1e-3);
    T_TRUE(e.peak_blocks <= EST_LOOKAHEAD_BLOCKS);
    estimate_release(&e);
}
