/*
 * slimfarm.c - the command-line tool's front door: runs any pipeline stage
 * alone (inspect, orient, optimize, slice, send ...) or talks to a running
 * slimfarmd.
 *
 * Each src/cmd/cmd_MODULE.c is its own program, libexec/slimfarm/
 * slimfarm-MODULE, linked with only the libraries its commands use; this
 * one links none, finds the command in the table the build generates from
 * those programs (`slimfarm-MODULE --describe MODULE`, see the Makefile)
 * and execs it.  Why: one program holding every command loaded 74 shared
 * libraries on each start (curl's TLS stack, cairo's X11, CHOLMOD's BLAS),
 * 25-30 ms before main() on this machine class, more than `slimfarm
 * orient` spends turning a small part; it now loads 13.  This program is
 * linked statically (see the Makefile), so it starts without the dynamic
 * loader: half the page faults of a dynamic libc-only program.
 */
#include <errno.h>
#include <limits.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

struct entry {
    const char *name, *module, *usage, *summary;
};

static const struct entry commands[] = {
#include "commands.inc"
};
enum { N_COMMANDS = sizeof(commands) / sizeof(commands[0]) };

static const struct entry *
lookup(const char *name)
{
    for (int i = 0; i < N_COMMANDS; i++)
        if (strcmp(commands[i].name, name) == 0)
            return &commands[i];
    return NULL;
}

static void
usage(FILE *f)
{
    fprintf(f, "usage: slimfarm COMMAND [ARGS]\n\ncommands:\n");
    for (int i = 0; i < N_COMMANDS; i++)
        fprintf(f, "  %-10s %s\n", commands[i].name, commands[i].summary);
    fprintf(f, "\n'slimfarm help COMMAND' shows a command's usage.  The commands that talk to\n"
               "slimfarmd take --url URL and --key KEY (or $SLIMFARM_URL, default\n"
               "http://127.0.0.1:7420, and $SLIMFARM_API_KEY):");
    for (int i = 0; i < N_COMMANDS; i++)
        if (strcmp(commands[i].module, "farm") == 0)
            fprintf(f, " %s", commands[i].name);
    fprintf(f, ".\n");
}

/* Run libexec/slimfarm/slimfarm-MODULE beside our bin/ with argv[1..]; returns only on failure. */
static int
run(const struct entry *e, char **argv)
{
    char self[PATH_MAX], path[PATH_MAX + 64], name[64];
    ssize_t n = readlink("/proc/self/exe", self, sizeof(self) - 1);
    char *slash = n > 0 ? memrchr(self, '/', (size_t)n) : NULL;
    if (!slash) {
        fprintf(stderr, "slimfarm: cannot find where this program is installed: %s\n",
                n < 0 ? strerror(errno) : "no directory in /proc/self/exe");
        return 1;
    }
    *slash = '\0';
    snprintf(name, sizeof(name), "slimfarm-%s", e->module);
    snprintf(path, sizeof(path), "%s/../libexec/slimfarm/%s", self, name);
    argv[0] = name;
    execv(path, argv);
    fprintf(stderr, "slimfarm %s: cannot run %s: %s\n", e->name, path, strerror(errno));
    return 1;
}

int
main(int argc, char **argv)
{
    if (argc < 2 || strcmp(argv[1], "-h") == 0 || strcmp(argv[1], "--help") == 0) {
        usage(argc < 2 ? stderr : stdout);
        return argc < 2 ? 2 : 0;
    }
    if (strcmp(argv[1], "help") == 0) {
        if (argc < 3) {
            usage(stdout);
            return 0;
        }
        const struct entry *e = lookup(argv[2]);
        if (!e) {
            fprintf(stderr, "slimfarm: unknown command '%s'\n", argv[2]);
            return 2;
        }
        printf("usage: slimfarm %s\n%s\n", e->usage, e->summary);
        return 0;
    }
    const struct entry *e = lookup(argv[1]);
    if (!e) {
        fprintf(stderr, "slimfarm: unknown command '%s'\n", argv[1]);
        usage(stderr);
        return 2;
    }
    return run(e, argv);
}
