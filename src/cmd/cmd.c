/*
 * cmd.c - what every command program shares: the helpers of cmd.h and the
 * main() of libexec/slimfarm/slimfarm-MODULE, which runs one of the
 * commands its cmd_MODULE.c registered (argv[1] names it).  Users reach it
 * through bin/slimfarm (slimfarm.c); `--describe MODULE` prints the rows of
 * that program's command table.  -h/--help is answered here for every
 * command, from the same table `slimfarm help` reads.  What needs a library
 * lives in cmdprofile.c and cmdreport.c (see cmd.h).
 */
#include "cmd.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define CMD_MAX 64

static const struct cmd *cmds[CMD_MAX];
static int n_cmds;
/* isatty(stderr), asked once in main: progress is drawn from worker threads
   once per scored item (orient: 50+ ioctl calls a run otherwise) */
static bool stderr_tty;

void
cmd_register(const struct cmd *c)
{
    if (n_cmds < CMD_MAX)
        cmds[n_cmds++] = c;
}

bool
cmd_parse_num(const char *cmd, const char *opt, const char *text, double lo, double hi,
              const char *want, double *out)
{
    char *end;
    double v = strtod(text, &end);
    if (end == text || *end || !isfinite(v) || v < lo || v > hi) {
        fprintf(stderr, "slimfarm %s: --%s wants %s, got '%s'\n", cmd, opt, want, text);
        return false;
    }
    *out = v;
    return true;
}

bool
cmd_parse_vec3(const char *cmd, const char *opt, const char *text, double out[3])
{
    const char *s = text;
    char *end;
    for (int i = 0; i < 3; i++) {
        out[i] = strtod(s, &end);
        if (end == s || !isfinite(out[i]) || (i < 2 && *end != ','))
            goto bad;
        s = end + (i < 2);
    }
    if (*end == '\0' && (out[0] != 0 || out[1] != 0 || out[2] != 0))
        return true;
bad:
    fprintf(stderr, "slimfarm %s: --%s wants x,y,z (not all zero), got '%s'\n", cmd, opt, text);
    return false;
}

/* If key is one of the n options in nums, parse text into its target and return 1, or print
   cmd_parse_num's message and return -1; 0 for any other key. */
static int
parse_nums(const char *cmd, const struct cmd_num *nums, int n, int key, const char *text)
{
    for (int i = 0; i < n; i++) {
        const struct cmd_num *o = &nums[i];
        double v;
        if (o->key != key)
            continue;
        if (!cmd_parse_num(cmd, o->name, text, o->lo, o->hi, o->want, &v))
            return -1;
        if (o->out)
            *o->out = o->div != 0 ? v / o->div : v;
        else
            *o->out_int = (int)v;
        return 1;
    }
    return 0;
}

int
cmd_getopt(const char *cmd, int argc, char **argv, const char *shortopts,
           const struct option *longopts, const struct cmd_num *nums, int n_nums)
{
    int c, k;
    while ((c = getopt_long(argc, argv, shortopts, longopts, NULL)) != -1) {
        if ((k = parse_nums(cmd, nums, n_nums, c, optarg)) == 0)
            return c;
        if (k < 0)
            return CMD_OPT_BAD;
    }
    return -1;
}

int
cmd_usage(const char *usage)
{
    fprintf(stderr, "usage: slimfarm %s\n", usage);
    return 2;
}

int
cmd_opt_error(int c, const char *usage)
{
    return c == CMD_OPT_BAD ? 2 : cmd_usage(usage);
}

void
cmd_progress(const char *label, double done, double total)
{
    if (!stderr_tty || total <= 0)
        return;
    double f = done / total;
    if (f > 1)
        f = 1;
    char bar[31];
    int fill = (int)(f * 30);
    for (int i = 0; i < 30; i++)
        bar[i] = i < fill ? '#' : '.';
    bar[30] = '\0';
    fprintf(stderr, "\r%-12s [%s] %3d%%%s", label, bar, (int)(f * 100), f >= 1 ? "\n" : "");
    fflush(stderr);
}

/* A C string literal of s (the build compiles --describe's output). */
static void
put_c_string(const char *s)
{
    putchar('"');
    for (; *s; s++) {
        if (*s == '\n') {
            fputs("\\n", stdout);
            continue;
        }
        if (*s == '"' || *s == '\\')
            putchar('\\');
        putchar(*s);
    }
    putchar('"');
}

static void
describe(const char *module)
{
    for (int i = 0; i < n_cmds; i++) {
        const char *f[] = { cmds[i]->name, module, cmds[i]->usage, cmds[i]->summary };
        printf("{ ");
        for (int k = 0; k < 4; k++) {
            put_c_string(f[k]);
            printf(k < 3 ? ", " : " },\n");
        }
    }
}

/* -h or --help among the arguments, before any "--" (after it they are operands). */
static bool
wants_help(int argc, char **argv)
{
    for (int i = 1; i < argc && strcmp(argv[i], "--") != 0; i++)
        if (strcmp(argv[i], "-h") == 0 || strcmp(argv[i], "--help") == 0)
            return true;
    return false;
}

/* The program's list, help and unknown names are the front door's
   (slimfarm.c): it execs this program only with one of the names --describe
   listed. */
int
main(int argc, char **argv)
{
    if (argc == 3 && strcmp(argv[1], "--describe") == 0) {
        describe(argv[2]);
        return 0;
    }
    stderr_tty = isatty(STDERR_FILENO);
    for (int i = 0; argc >= 2 && i < n_cmds; i++) {
        if (strcmp(cmds[i]->name, argv[1]) != 0)
            continue;
        if (wants_help(argc - 1, argv + 1)) {
            printf("usage: slimfarm %s\n%s\n", cmds[i]->usage, cmds[i]->summary);
            return 0;
        }
        return cmds[i]->run(argc - 1, argv + 1);
    }
    fprintf(stderr, "%s: run it as 'slimfarm COMMAND'; 'slimfarm help' lists the commands\n",
            argv[0]);
    return 2;
}
