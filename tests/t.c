/*
 * t.c - main() and bookkeeping for tests/t.h.
 *
 * Cases run in registration order, in one process: a crash takes the whole
 * program down and run.sh counts its cases as failed.  Each case gets a
 * fresh scratch directory under $TMPDIR, removed at exit unless the
 * environment sets T_KEEP=1.
 */
#include "t.h"

#include <stdarg.h>
#include <stdlib.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#define T_MAX_CASES 512

static struct {
    const char *name;
    t_fn fn;
} cases[T_MAX_CASES];
static int n_cases;
static int cur_failed, cur_skipped;
static char tmpdir[256];
static char shared_path[512];

void
t_register(const char *name, t_fn fn)
{
    if (n_cases == T_MAX_CASES) {
        fprintf(stderr, "t: too many cases\n");
        exit(2);
    }
    cases[n_cases].name = name;
    cases[n_cases].fn = fn;
    n_cases++;
}

void
t_fail(const char *file, int line, const char *fmt, ...)
{
    va_list ap;
    fprintf(stdout, "    %s:%d: ", file, line);
    va_start(ap, fmt);
    vfprintf(stdout, fmt, ap);
    va_end(ap);
    fputc('\n', stdout);
    fflush(stdout);
    cur_failed = 1;
}

void
t_skip(const char *why)
{
    printf("    skipped: %s\n", why);
    cur_skipped = 1;
}

const char *
t_tmpdir(void)
{
    if (!tmpdir[0]) {
        const char *base = getenv("TMPDIR");
        snprintf(tmpdir, sizeof(tmpdir), "%s/sft.XXXXXX", base ? base : "/tmp");
        if (!mkdtemp(tmpdir)) {
            perror("mkdtemp");
            exit(2);
        }
    }
    return tmpdir;
}

const char *
t_shared_mesh(const char *name)
{
    /* Tests run from the repository root; ../shared sits beside it. */
    const char *root = getenv("SLIMFARM_SHARED");
    snprintf(shared_path, sizeof(shared_path), "%s/meshes/%s", root ? root : "../shared", name);
    return access(shared_path, R_OK) == 0 ? shared_path : NULL;
}

static void
remove_tmpdir(void)
{
    if (tmpdir[0] && !getenv("T_KEEP")) {
        char cmd[300];
        snprintf(cmd, sizeof(cmd), "rm -rf '%s'", tmpdir);
        if (system(cmd) != 0)
            fprintf(stderr, "t: could not remove %s\n", tmpdir);
    }
}

int
main(int argc, char **argv)
{
    if (argc > 1 && strcmp(argv[1], "--count") == 0) {
        printf("%d\n", n_cases);
        return 0;
    }
    atexit(remove_tmpdir);
    setvbuf(stdout, NULL, _IOLBF, 0);
    int passed = 0, failed = 0, skipped = 0;
    for (int i = 0; i < n_cases; i++) {
        if (argc > 1 && !strstr(cases[i].name, argv[1]))
            continue;
        cur_failed = cur_skipped = 0;
        struct timespec t0, t1;
        clock_gettime(CLOCK_MONOTONIC, &t0);
        cases[i].fn();
        clock_gettime(CLOCK_MONOTONIC, &t1);
        double ms = (t1.tv_sec - t0.tv_sec) * 1e3 + (t1.tv_nsec - t0.tv_nsec) / 1e6;
        if (cur_failed) {
            failed++;
            printf("FAIL %s (%.0f ms)\n", cases[i].name, ms);
        } else if (cur_skipped) {
            skipped++;
            printf("skip %s\n", cases[i].name);
        } else {
            passed++;
            printf("ok   %s (%.0f ms)\n", cases[i].name, ms);
        }
    }
    printf("%d passed, %d failed, %d skipped\n", passed, failed, skipped);
    return failed ? 1 : 0;
}

const char *
t_slurp(const char *path)
{
    static char b[512];
    b[0] = '\0';
    FILE *f = fopen(path, "r");
    if (f) {
        size_t n = fread(b, 1, sizeof(b) - 1, f);
        b[n] = '\0';
        fclose(f);
    }
    return b;
}
