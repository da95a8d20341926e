/*
 * bench_files.c - one step of sharing a file through the store, timed
 * (tests/bench/bench_files.sh runs the steps, each in a process of its own
 * under /usr/bin/time -v for its peak RSS, and puts them side by side):
 *
 *   bench_files make FILE MB KIND          write MB MiB of KIND (gcode: G-code
 *                                          text, random: incompressible, as a
 *                                          3MF's deflated parts) to FILE
 *   bench_files put DATA_DIR FILE [URL]    stream FILE into the store through a
 *                                          writer (store_file_begin/write/commit),
 *                                          64 KiB at a time, as an API upload does
 *   bench_files adopt DATA_DIR FILE [URL]  adopt FILE (moved into the store), then
 *                                          record it, as a slice's output is
 *   bench_files fetch DATA_DIR SHA URL     store_file_path of SHA on a host whose
 *                                          cache lacks it
 *
 * The store is SQLite in DATA_DIR, or PostgreSQL at URL.  Each prints one
 * line: the step, the bytes, the milliseconds and the SHA-256.
 */
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "../../src/base/clock.h"
#include "../../src/base/log.h"
#include "../../src/farm/store.h"

/* MB MiB of G-code-like text or random bytes into path. */
static int
make(const char *path, long mb, const char *kind)
{
    FILE *fp = fopen(path, "w");
    if (!fp)
        return 1;
    long want = mb << 20, n = 0;
    unsigned x = 12345;
    bool text = strcmp(kind, "gcode") == 0;
    while (n < want) {
        char line[64];
        int len;
        x = x * 1103515245u + 12345u;
        if (text) {
            len = snprintf(line, sizeof(line), "G1 X%u.%03u Y%u.%03u E%u.%05u\n", (x >> 8) % 250,
                           (x >> 3) % 1000, (x >> 12) % 210, (x >> 5) % 1000, (x >> 16) % 9,
                           x % 100000);
        } else {
            for (len = 0; len < 32; len++) {
                x = x * 1103515245u + 12345u;
                line[len] = (char)(x >> 24);
            }
        }
        if (n + len > want)
            len = (int)(want - n);
        fwrite(line, 1, (size_t)len, fp);
        n += len;
    }
    return fclose(fp) != 0;
}

static int
put(struct store *s, const char *file, char sha[STORE_SHA_HEX], long *bytes, struct sf_err *err)
{
    int fd = open(file, O_RDONLY);
    if (fd < 0)
        return sf_err_sys(err, "cannot read '%s'", file);
    struct store_file *f = store_file_begin(s, err);
    if (!f)
        return err->code;
    static char buf[1 << 16];
    ssize_t n;
    while ((n = read(fd, buf, sizeof(buf))) > 0) {
        *bytes += n;
        if (store_file_write(f, buf, (size_t)n, err)) {
            store_file_abort(f);
            close(fd);
            return err->code;
        }
    }
    close(fd);
    return store_file_commit(f, sha, err);
}

int
main(int argc, char **argv)
{
    if (argc >= 5 && strcmp(argv[1], "make") == 0)
        return make(argv[2], strtol(argv[3], NULL, 10), argv[4]);
    if (argc < 4) {
        fprintf(stderr, "usage: bench_files make|put|adopt|fetch ... (see bench_files.c)\n");
        return 2;
    }
    const char *step = argv[1], *dir = argv[2], *url = argc > 4 ? argv[4] : NULL;
    struct sf_err err;
    log_set_level(LOG_WARN);
    struct store *s = store_open_db(dir, url, NULL, &err);
    char sha[STORE_SHA_HEX] = "", path[1200];
    long bytes = 0;
    int64_t size = 0, t0 = clock_mono_ms(), t1 = t0;
    int rc = s ? SF_OK : err.code;
    if (rc == SF_OK && strcmp(step, "put") == 0) {
        rc = put(s, argv[3], sha, &bytes, &err);
    } else if (rc == SF_OK && strcmp(step, "adopt") == 0) {
        if ((rc = store_file_adopt(s, argv[3], sha, &size, &err)) == SF_OK &&
            (t1 = clock_mono_ms(), rc = store_file_record(s, sha, size, &err)) == SF_OK)
            printf("adopt (worker) %lld ms, then record (store's thread) %lld ms; ",
                   (long long)(t1 - t0), (long long)(clock_mono_ms() - t1));
        bytes = (long)size;
    } else if (rc == SF_OK && strcmp(step, "fetch") == 0) {
        snprintf(sha, sizeof(sha), "%s", argv[3]);
        struct stat sb;
        if ((rc = store_file_path(s, sha, path, sizeof(path), &err)) == SF_OK && !stat(path, &sb))
            bytes = (long)sb.st_size;
    } else if (rc == SF_OK) {
        rc = sf_err_set(&err, SF_EINVAL, "no step '%s'", step);
    }
    if (rc) {
        fprintf(stderr, "bench_files %s: %s\n", step, err.msg);
        store_close(s);
        return 1;
    }
    printf("%s %ld bytes: %lld ms, sha %s\n", step, bytes, (long long)(clock_mono_ms() - t0), sha);
    store_close(s);
    return 0;
}
