/*
 * cmd_slice.c - `slimfarm slice PART -o OUT.gcode`: load a part, slice it
 * with a printer and a material profile, write Marlin G-code and print
 * the figures (layers, filament, support, estimated time).
 *
 * Profiles are named (--printer mk3 reads config/printers/mk3.cfg, looked
 * up under $SLIMFARM_CONFIG, ./config, then the installed share folder) or
 * given as paths; --set key=value overrides any option after loading.
 * A progress bar is drawn on stderr when it is a terminal.
 */
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "../../slicer/slice.h"
#include "../mesh/mesh.h"
#include "cmd.h"
#include "cmdmesh.h"
#include "cmdprofile.h"

static const char usage_line[] = "slice PART -o OUT.gcode [--printer NAME] [--material NAME] "
                                 "[--no-support] [--set key=value]...";

#define SET_MAX 64

static int
on_progress(void *ud, const char *stage, double done)
{
    (void)ud;
    static const char *const stages[] = { "layers",   "supports", "toolpaths", "gcode",
                                          "estimate", "write",    "done" };
    int i = 0;
    while (i < 6 && strcmp(stages[i], stage) != 0)
        i++;
    cmd_progress("slicing", i + done, 6);
    return 0;
}

static int
run(int argc, char **argv)
{
    static const struct option opts[] = {
        { "output", required_argument, NULL, 'o' },   { "printer", required_argument, NULL, 'p' },
        { "material", required_argument, NULL, 'm' }, { "no-support", no_argument, NULL, 'n' },
        { "set", required_argument, NULL, 's' },      { NULL, 0, NULL, 0 }
    };
    const char *out = NULL, *printer = NULL, *material = NULL, *sets[SET_MAX];
    int n_sets = 0, c;
    bool no_support = false;
    optind = 1;
    while ((c = getopt_long(argc, argv, "o:", opts, NULL)) != -1) {
        switch (c) {
        case 'o':
            out = optarg;
            break;
        case 'p':
            printer = optarg;
            break;
        case 'm':
            material = optarg;
            break;
        case 'n':
            no_support = true;
            break;
        case 's':
            if (n_sets == SET_MAX) {
                fprintf(stderr, "slimfarm slice: more than %d --set options\n", SET_MAX);
                return 2;
            }
            sets[n_sets++] = optarg;
            break;
        default:
            return cmd_usage(usage_line);
        }
    }
    if (optind != argc - 1 || !out)
        return cmd_usage(usage_line);
    const char *part = argv[optind];
    struct slice_profile prof;
    if (!cmd_load_profile("slice", printer, material, &prof))
        return 1;
    struct sf_err err;
    int status = 1;
    struct mesh m;
    mesh_init(&m);
    for (int i = 0; i < n_sets; i++) {
        if (slice_profile_set(&prof, sets[i], &err) < 0) {
            fprintf(stderr, "slimfarm slice: %s\n", err.msg);
            goto out;
        }
    }
    if (no_support)
        prof.support = false;
    if (!cmd_load_part("slice", part, &m, NULL))
        goto out;
    struct slice_result r;
    if (slice_mesh(&m, &prof, out, &r, on_progress, NULL, &err) < 0) {
        fprintf(stderr, "slimfarm slice: %s\n", err.msg);
        goto out;
    }
    long t = (long)(r.time_s + 0.5);
    printf("%s: %u layers, filament %.0f mm %.2f g (support %.2f g), "
           "estimated %ld:%02ld:%02ld, sliced in %.2f s\n",
           out, r.n_layers, r.filament_mm, r.filament_g, r.support_g, t / 3600, t / 60 % 60, t % 60,
           r.wall_s);
    status = 0;
out:
    mesh_release(&m);
    slice_profile_release(&prof);
    return status;
}

CMD_REGISTER(slice, "slice", usage_line, "slice a part into Marlin G-code with column supports",
             run)
