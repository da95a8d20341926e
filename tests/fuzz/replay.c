/*
 * replay.c - run one fuzz target's harness over its committed corpus with a
 * plain gcc build (SQLite's fuzzcheck idea), so `make check` exercises every
 * parser on every crash input ever found, under ASan and UBSan, without
 * clang.  Each corpus file is one case; the output ends with the runner's
 * "N passed, N failed, N skipped" line.
 *
 * The target name comes from the program name (test_fuzz_NAME); the corpus
 * is tests/fuzz/corpus/NAME/.  A crash aborts the program, which run.sh
 * counts as failure.
 */
#include <dirent.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/base/buf.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int
main(int argc, char **argv)
{
    const char *slash = strrchr(argv[0], '/');
    const char *name = slash ? slash + 1 : argv[0];
    if (strncmp(name, "test_fuzz_", 10) == 0)
        name += 10;
    if (argc > 1 && strcmp(argv[1], "--count") == 0) {
        printf("1\n");
        return 0;
    }
    char dir[512];
    snprintf(dir, sizeof(dir), "tests/fuzz/corpus/%s", name);
    DIR *d = opendir(dir);
    if (!d) {
        printf("no corpus at %s\n0 passed, 1 failed, 0 skipped\n", dir);
        return 1;
    }
    int n = 0;
    struct dirent *e;
    while ((e = readdir(d))) {
        if (e->d_name[0] == '.')
            continue;
        char path[1024];
        snprintf(path, sizeof(path), "%s/%s", dir, e->d_name);
        struct buf b;
        buf_init(&b, 0);
        if (buf_read_file(&b, path, NULL) != 0) {
            buf_release(&b);
            continue;
        }
        LLVMFuzzerTestOneInput((const uint8_t *)(b.data ? b.data : ""), b.len);
        buf_release(&b);
        n++;
    }
    closedir(d);
    printf("replayed %d inputs of corpus/%s\n%d passed, 0 failed, 0 skipped\n", n, name, n);
    return 0;
}
