/*
 * cmd_estimate.c - `slimfarm estimate FILE.gcode [--printer NAME]`: print
 * time, filament and support of any Marlin G-code file, by the slicer's
 * own reader and planner with the printer profile's machine limits.  The
 * daemon uses the same code for uploaded G-code; here it also lets us
 * check our planner against other slicers' estimates of their own files.
 */
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "../../slicer/estimate.h"
#include "../../slicer/slice.h"
#include "../base/buf.h"
#include "cmd.h"
#include "cmdprofile.h"

static const char usage_line[] = "estimate FILE.gcode [--printer NAME|PATH] [--material NAME|PATH]";

static int
run(int argc, char **argv)
{
    static const struct option opts[] = { { "printer", required_argument, NULL, 'p' },
                                          { "material", required_argument, NULL, 'm' },
                                          { NULL, 0, NULL, 0 } };
    const char *printer = NULL, *material = NULL;
    int c;
    optind = 1;
    while ((c = getopt_long(argc, argv, "", opts, NULL)) != -1) {
        switch (c) {
        case 'p':
            printer = optarg;
            break;
        case 'm':
            material = optarg;
            break;
        default:
            return cmd_usage(usage_line);
        }
    }
    if (optind != argc - 1)
        return cmd_usage(usage_line);
    struct slice_profile p;
    if (!cmd_load_profile("estimate", printer, material, &p))
        return 1;
    struct sf_err err;
    struct est_limits lim;
    slice_limits(&p, &lim);
    double g_per_mm = M_PI * p.filament_mm * p.filament_mm / 4 * p.density_g_cm3 / 1000;
    slice_profile_release(&p);
    struct buf b;
    buf_init(&b, (size_t)1 << 31);
    struct estimate e;
    int rc = buf_read_file(&b, argv[optind], &err);
    if (rc == SF_OK)
        rc = estimate_gcode(b.data ? b.data : "", b.len, argv[optind], &lim, NULL, NULL, &e, &err);
    buf_release(&b);
    if (rc < 0) {
        fprintf(stderr, "slimfarm estimate: %s\n", err.msg);
        return 1;
    }
    long t = lround(e.time_s);
    printf("%s: %u layers, %u moves, filament %.0f mm %.2f g (support %.2f g), "
           "estimated %ld:%02ld:%02ld (%.0f s)\n",
           argv[optind], e.n_layers, e.n_moves, e.filament_mm, e.filament_mm * g_per_mm,
           e.support_mm * g_per_mm, t / 3600, t / 60 % 60, t % 60, e.time_s);
    estimate_release(&e);
    return 0;
}

CMD_REGISTER(estimate, "estimate", usage_line,
             "print time and filament of a G-code file by the slicer's planner", run)
