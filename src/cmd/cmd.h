/*
 * cmd.h - subcommands of the `slimfarm` CLI.
 *
 * Each subcommand lives in its own src/cmd/cmd_NAME.c and registers itself
 * with CMD_REGISTER, so adding one touches no shared table.  A command gets
 * argv with argv[0] = its own name, returns the process exit status (0 ok,
 * 1 failure, 2 usage error) and prints its own errors as
 * "slimfarm NAME: message".  -h or --help anywhere before "--" never reaches
 * it: cmd.c prints the usage and summary on stdout and exits 0.
 *
 * The helpers here link into every command program; those that pull in a
 * library live apart so only their users load it: cmdprofile.h (slicing
 * profiles: the INI parser) and cmdreport.h (support figures, JSON).
 */
#ifndef SF_CMD_CMD_H
#define SF_CMD_CMD_H

#include <getopt.h>
#include <stdbool.h>

typedef int (*cmd_fn)(int argc, char **argv);

struct cmd {
    const char *name;    /* "inspect" */
    const char *usage;   /* "inspect PART [--up x,y,z] ...": one line per form, each
                            after the first starting "slimfarm " */
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

/* A numeric option for cmd_getopt: its value as cmd_parse_num checks it. */
struct cmd_num {
    int key;          /* getopt_long's value for the option */
    const char *name; /* "angle": the option without its dashes */
    double lo, hi;    /* the range it must be in */
    const char *want; /* for the message: "degrees in [0, 90)" */
    double *out;      /* where the value goes (scaled by div); NULL: to out_int */
    int *out_int;     /* where the value goes, truncated, when out is NULL */
    double div;       /* 0, or what the value is divided by (100: a percentage) */
};

/* What cmd_getopt returns for a numeric option whose value it refused. */
#define CMD_OPT_BAD (-2)

/*
 * getopt_long(argc, argv, shortopts, longopts) (the caller sets optind to
 * 1 before the first call), parsing the n_nums numeric options of nums
 * into their targets itself: returns the next other option for the
 * caller's switch, -1 at the end, or CMD_OPT_BAD after printing
 * cmd_parse_num's message for a bad value.
 */
int cmd_getopt(const char *cmd, int argc, char **argv, const char *shortopts,
               const struct option *longopts, const struct cmd_num *nums, int n_nums);

/* Print "usage: slimfarm USAGE" on stderr; returns 2, the usage-error status. */
int cmd_usage(const char *usage);
/* For an option c from cmd_getopt that the caller does not take (its switch's default): print
   the usage unless c is CMD_OPT_BAD (whose message is out already); returns 2. */
int cmd_opt_error(int c, const char *usage);

/* `optimize --method surface` (cmd_optimize_surface.c), reached from cmd_optimize.c,
   whose usage shows this form second. */
int cmd_optimize_surface(int argc, char **argv);
#define CMD_OPTIMIZE_SURFACE_USAGE                                                                 \
    "optimize PART -o OUT --method surface [--angle DEG] [--margin DEG] [--max-mndr P] "           \
    "[--max-andr P] [--fix-bottom MM] [--iterations N] [--rounds N] [--saliency S] "               \
    "[--detail W] [--min-gain P] [--no-orient] [--search-direction K] [--gram-seconds S] "         \
    "[--material-first] [--json]"

/*
 * Draw "label [#####.....] 42%" on stderr when it is a terminal; a no-op
 * otherwise.  done == total finishes the line.
 */
void cmd_progress(const char *label, double done, double total);

#endif
