/*
 * bench_slim.c - the support-slimming loop (Hu 2015) timed by phase: 100
 * local/global iterations on a tet mesh of about 8k tets (the paper's
 * Armadillo has 2,373 vertices and 8,189 tets), split into nearest
 * rotations, minimal rotations, right-hand side and solve, plus the one-off
 * setup (tet mesh, factorization) and the per-iteration bookkeeping on the
 * part (mapping, measuring, drives).  Median of the runs; one thread.
 *
 *   bench_slim [PART.stl] [MAX_TET_VERTS] [RUNS]   (default: a generated torus, 2400, 3)
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/geom/slim.h"
#include "../../src/mesh/shapes.h"

#define RUNS_MAX 9

static int runs = 3;

static int
cmp_d(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double
median(double *v)
{
    qsort(v, (size_t)runs, sizeof(double), cmp_d);
    return v[runs / 2];
}

int
main(int argc, char **argv)
{
    struct mesh m;
    struct sf_err err;
    const char *name = "torus R30 r10 (generated)";
    mesh_init(&m);
    if (argc > 1 && argv[1][0]) {
        name = argv[1];
        if (mesh_load(argv[1], &m, NULL, &err)) {
            fprintf(stderr, "bench_slim: %s\n", err.msg);
            return 1;
        }
    } else if (shape_torus(&m, 30, 10, 192, 96, &err)) {
        fprintf(stderr, "bench_slim: %s\n", err.msg);
        return 1;
    }
    struct slim_params p;
    slim_params_default(&p);
    p.tet.max_verts = argc > 2 && argv[2][0] ? (uint32_t)strtoul(argv[2], NULL, 10) : 2400;
    if (argc > 3)
        runs = (int)strtol(argv[3], NULL, 10);
    if (runs < 1 || runs > RUNS_MAX)
        runs = 3;
    p.tet.cells = 10; /* coarse from the start: no rebuilds at this target */
    p.max_iters = 100;
    p.patience = 1000; /* exactly 100 iterations */
    p.beta_step_deg = 0;
    p.max_mndr = p.max_andr = 1;
    p.threads = 1;
    double t[8][RUNS_MAX];
    struct slim_result r;
    for (int run = 0; run < runs; run++) {
        if (slim_optimize(&m, &p, &r, &err)) {
            fprintf(stderr, "bench_slim: %s\n", err.msg);
            return 1;
        }
        const struct slim_timing *s = &r.timing;
        double loop = s->local_s + s->minrot_s + s->rhs_s + s->solve_s;
        double v[8] = { r.setup_s,   s->factor_s, loop,       s->local_s,
                        s->minrot_s, s->rhs_s,    s->solve_s, s->part_s };
        for (int k = 0; k < 8; k++)
            t[k][run] = v[k];
        if (run + 1 < runs)
            slim_result_release(&r);
    }
    printf("slim %s: %u triangles; tet mesh %u vertices, %u tets; %d iterations; risky %u -> %u\n",
           name, m.n_tris, r.tet_verts, r.tet_tets, r.timing.iterations, r.curve[0],
           r.curve[r.n_curve - 1]);
    printf("  minimal rotations applied %llu, nearest rotations on the scalar path %llu\n",
           (unsigned long long)r.timing.rotated, (unsigned long long)r.timing.slow_polar);
    static const char *label[8] = {
        "setup: tet mesh + face hosts", "setup: factorization",
        "100 iterations: ARAP total",   "  J, nearest rotation, RHS pass",
        "  minimal rotations",          "  RHS Dirichlet terms",
        "  solve (back-substitution)",  "per-iteration part bookkeeping"
    };
    for (int k = 0; k < 8; k++)
        printf("  %-32s %8.4f s\n", label[k], median(t[k]));
    slim_result_release(&r);
    mesh_release(&m);
    return 0;
}
