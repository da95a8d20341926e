/*
 * cmd.h - subcommands of the `slimfarm` CLI.
 *
 * Each subcommand lives in its own src/cmd/cmd_NAME.c and registers itself
 * with CMD_REGISTER, so adding one touches no shared table.  A command gets
 * argv with argv[0] = its own name, returns the process exit status (0 ok,
 * 1 failure, 2 usage error) and prints its own errors as
 * "slimfarm NAME: message".
 */
#ifndef SF_CMD_CMD_H
#define SF_CMD_CMD_H

#include <jansson.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../../slicer/profile.h"
#include "../geom/measure.h"

typedef int (*cmd_fn)(int argc, char **argv);

struct cmd {
    const char *name;    /* "inspect" */
    const char *usage;   /* one line: "inspect PART [--up x,y,z] ..." */
    const char *summary; /* one line: what it does */
    cmd_fn run;
};

void cmd_register(const struct cmd *c);

#define CMD_REGISTER(ident, name_, usage_, summary_, fn_)                                          \
    static const struct cmd cmd_def_##ident = { name_, usage_, summary_, fn_ };                    \
    __attribute__((constructor)) static void cmd_reg_##ident(void)                                 \
    {                                                                                              \
        cmd_register(&cmd_def_##ident);                                                            \
    }

/*
 * Parse an option's value: a finite number in [lo, hi], or three finite
 * numbers "x,y,z" not all zero.  On failure print "slimfarm CMD: --OPT
 * wants WANT, got 'TEXT'" on stderr and return false.
 */
bool cmd_parse_num(const char *cmd, const char *opt, const char *text, double lo, double hi,
                   const char *want, double *out);
bool cmd_parse_vec3(const char *cmd, const char *opt, const char *text, double out[3]);

/*
 * Load the slicing profile from a printer and a material (either NULL for
 * the defaults).  Each NAME is a path when it holds a '/' or ends in
 * ".cfg", else KIND/NAME.cfg under $SLIMFARM_CONFIG, ./config, then the
 * installed share/slimfarm/config folders.  On failure print "slimfarm
 * CMD: no printer profile 'NAME'" or the loader's error and return false.
 */
bool cmd_load_profile(const char *cmd, const char *printer, const char *material,
                      struct slice_profile *p);

/* The support figures the optimizers report, as JSON and as one text line
 * ("  LABEL    risky faces ..."), and a risky-faces-per-iteration curve. */
json_t *cmd_metrics_json(const struct support_metrics *m);
void cmd_print_metrics(const char *label, const struct support_metrics *m);
void cmd_print_curve(const uint32_t *curve, int n);
json_t *cmd_curve_json(const uint32_t *curve, int n);

/* Print o (taking its reference; NULL means it could not be built) as
 * indented JSON on stdout: 0, or 1 with "slimfarm CMD: out of memory". */
int cmd_put_json(const char *cmd, json_t *o);

/* `optimize --method surface` (cmd_optimize_surface.c), reached from cmd_optimize.c. */
int cmd_optimize_surface(int argc, char **argv);

/* True when stdout is a terminal and NO_COLOR-style progress is wanted. */
bool cmd_stdout_is_tty(void);

/*
 * Draw "label [#####.....] 42%" on stderr when it is a terminal; a no-op
 * otherwise.  done == total finishes the line.
 */
void cmd_progress(const char *label, double done, double total);

#endif
