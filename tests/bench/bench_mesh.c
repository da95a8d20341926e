/*
 * bench_mesh.c - load + weld + repair + every support metric on real parts,
 * each stage timed separately (median of several runs), with the raw read
 * of the file from the page cache as the "disk speed" reference.
 *
 *   bench_mesh [FILE.stl ...]   (default: a generated 1M-facet torus)
 */
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "../../src/base/limits.h"
#include "../../src/geom/measure.h"
#include "../../src/mesh/mesh.h"
#include "../../src/mesh/shapes.h"

#define RUNS 5

static double
now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static int
cmp_d(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double
median(double *v)
{
    qsort(v, RUNS, sizeof(double), cmp_d);
    return v[RUNS / 2];
}

static int
bench(const char *path)
{
    enum { READ, PARSE, WELD, REPAIR, TOPO, SCENE, PROXY, GRID, N_STAGES };
    static const char *names[] = {
        "read (reference)", "map + stl parse", "weld",  "clean+orient",
        "topology",         "embree scene",    "proxy", "ray grid+metrics"
    };
    double t[N_STAGES][RUNS];
    struct sf_err err;
    size_t bytes = 0;
    uint32_t tris = 0;
    struct support_metrics sm;
    for (int r = 0; r < RUNS; r++) {
        struct mesh m;
        struct mesh_topo topo;
        mesh_init(&m);
        /* reference: what cat would do, read() through one reused 1 MB buffer */
        static char chunk[1 << 20];
        double t0 = now_s();
        int fd = open(path, O_RDONLY);
        if (fd < 0) {
            perror(path);
            return 1;
        }
        ssize_t got;
        size_t len = 0;
        while ((got = read(fd, chunk, sizeof(chunk))) > 0)
            len += (size_t)got;
        double t1 = now_s();
        void *map = mmap(NULL, len, PROT_READ, MAP_PRIVATE | MAP_POPULATE, fd, 0);
        close(fd);
        if (map == MAP_FAILED || stl_parse(map, len, path, &m, &err)) {
            fprintf(stderr, "bench_mesh: cannot parse %s\n", path);
            return 1;
        }
        munmap(map, len);
        double t2 = now_s();
        mesh_weld(&m, 1e-6 * mesh_diag(&m), &err);
        double t3 = now_s();
        mesh_drop_degenerate(&m);
        mesh_compact(&m);
        mesh_orient(&m, &err);
        double t4 = now_s();
        mesh_topo_build(&m, &topo, &err);
        double t5 = now_s();
        struct raycast *rc = raycast_new(&m, &err);
        double t6 = now_s();
        struct support_params p;
        support_params_default(&p);
        measure_proxy(&m, v3(0, 0, 1), &p, &sm);
        double t7 = now_s();
        measure_support(&m, rc, v3(0, 0, 1), &p, &sm, &err);
        double t8 = now_s();
        double stamps[] = { t0, t1, t2, t3, t4, t5, t6, t7, t8 };
        for (int s = 0; s < N_STAGES; s++)
            t[s][r] = stamps[s + 1] - stamps[s];
        bytes = len;
        tris = m.n_tris;
        raycast_free(rc);
        mesh_topo_release(&topo);
        mesh_release(&m);
    }
    const char *base = strrchr(path, '/') ? strrchr(path, '/') + 1 : path;
    printf("%s: %u triangles, %.1f MB; median of %d runs\n", base, tris, bytes / 1e6, RUNS);
    double total = 0;
    for (int s = 0; s < N_STAGES; s++) {
        double med = median(t[s]);
        total += med;
        printf("  %-18s %8.2f ms", names[s], med * 1e3);
        if (s <= PARSE)
            printf("  %7.0f MB/s", bytes / 1e6 / med);
        printf("\n");
    }
    printf("  %-18s %8.2f ms  (support %.0f mm3, %u columns)\n", "total", total * 1e3,
           sm.volume_mm3, sm.n_columns);
    return 0;
}

int
main(int argc, char **argv)
{
    if (argc > 1) {
        for (int i = 1; i < argc; i++)
            if (bench(argv[i]))
                return 1;
        return 0;
    }
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    const char *path = "/tmp/slimfarm-bench-torus1m.stl";
    if (shape_torus(&m, 30, 10, 1000, 500, &err) || mesh_save_stl(&m, path, &err)) {
        fprintf(stderr, "bench_mesh: %s\n", err.msg);
        return 1;
    }
    mesh_release(&m);
    int rc = bench(path);
    remove(path);
    return rc;
}
