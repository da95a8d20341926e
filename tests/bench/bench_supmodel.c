/*
 * bench_supmodel.c - the layer-based support model (src/geom/supmodel.h)
 * and today's ray-cast support volume (measure.h) for a list of
 * up-directions of one part, with the time each takes.
 *
 *   bench_supmodel PART DIRS [PITCH_MM]
 *
 * DIRS has one "i ux uy uz" a line (tests/bench/peer_dirs.sh writes it).
 * Prints one line a direction: i, PrusaSlicer-model grams, CuraEngine-model
 * grams, ray-cast volume mm3 at 45 and at 40 degrees (orient's scoring
 * margin), model shadow mm3, then the direction search's own objective
 * (dirsearch.c's input_cost at 45 degrees): the steering model's grams
 * (supmodel_params_steer) and the estimated print seconds, part and support
 * (printtime.h); then the median milliseconds of one model evaluation
 * (cast included) and of one measure_support on a "# " line.
 * SUPMODEL_BRIDGES=0 turns the PrusaSlicer model's bridge rule off.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../../src/geom/measure.h"
#include "../../src/geom/printtime.h"
#include "../../src/geom/supmodel.h"

#define DIRS_MAX 4096

static double
now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

static int
cmp_d(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

int
main(int argc, char **argv)
{
    if (argc < 3) {
        fprintf(stderr, "usage: bench_supmodel PART DIRS [PITCH_MM]\n");
        return 2;
    }
    struct sf_err err;
    struct mesh m;
    mesh_init(&m);
    if (mesh_load(argv[1], &m, NULL, &err)) {
        fprintf(stderr, "bench_supmodel: %s\n", err.msg);
        return 1;
    }
    FILE *f = fopen(argv[2], "r");
    if (!f) {
        fprintf(stderr, "bench_supmodel: %s: cannot open\n", argv[2]);
        return 1;
    }
    static struct vec3 dirs[DIRS_MAX];
    static int ids[DIRS_MAX];
    int n = 0, line = 0;
    char buf[256];
    while (n < DIRS_MAX && fgets(buf, sizeof buf, f)) {
        line++;
        double x, y, z;
        if (sscanf(buf, "%d %lf %lf %lf", &ids[n], &x, &y, &z) != 4) {
            fprintf(stderr, "bench_supmodel: %s:%d: expected \"i ux uy uz\"\n", argv[2], line);
            fclose(f);
            return 1;
        }
        dirs[n++] = v3(x, y, z);
    }
    fclose(f);
    struct supmodel_params ps, ce, steer;
    supmodel_params_default(&ps, SUPMODEL_PRUSA);
    supmodel_params_steer(&steer, 45);
    struct printtime_params pt;
    printtime_params_default(&pt);
    supmodel_params_default(&ce, SUPMODEL_CURA);
    if (argc > 3)
        ps.pitch_mm = ce.pitch_mm = strtod(argv[3], NULL);
    /* SUPMODEL_BRIDGES=0: PrusaSlicer's model supports bridges (to measure the rule) */
    const char *br = getenv("SUPMODEL_BRIDGES");
    if (br && *br)
        ps.bridges = strcmp(br, "0") != 0;
    struct support_params sp[2];
    support_params_default(&sp[0]);
    sp[1] = sp[0];
    sp[1].angle_deg = 40;
    struct raycast *rc = raycast_new(&m, &err);
    if (!rc) {
        fprintf(stderr, "bench_supmodel: %s\n", err.msg);
        return 1;
    }
    static double t_model[DIRS_MAX], t_ray[DIRS_MAX];
    for (int k = 0; k < n; k++) {
        struct supmodel_result a, b;
        struct support_metrics sm[2];
        double t0 = now_ms();
        if (supmodel_eval(rc, dirs[k], &ps, &a, &err))
            goto fail;
        double t1 = now_ms();
        if (supmodel_eval(rc, dirs[k], &ce, &b, &err))
            goto fail;
        double t2 = now_ms();
        if (measure_support_angles(&m, rc, NULL, dirs[k], sp, 2, sm, &err))
            goto fail;
        double t3 = now_ms();
        t_model[k] = t1 - t0;
        t_ray[k] = t3 - t2;
        struct supmodel_result st;
        struct printtime_result pr;
        if (supmodel_eval(rc, dirs[k], &steer, &st, &err) ||
            printtime_eval(&m, dirs[k], &pt, &pr, &err))
            goto fail;
        printf("%d %.3f %.3f %.1f %.1f %.1f %.3f %.1f\n", ids[k], a.grams, b.grams,
               sm[0].volume_mm3, sm[1].volume_mm3, a.shadow_mm3, st.grams,
               printtime_total_s(&pt, &pr, st.time_s));
    }
    qsort(t_model, (size_t)n, sizeof(double), cmp_d);
    qsort(t_ray, (size_t)n, sizeof(double), cmp_d);
    printf("# model_ms %.2f raycast_ms %.2f pitch %.2f\n", n ? t_model[n / 2] : 0,
           n ? t_ray[n / 2] : 0, ps.pitch_mm);
    raycast_free(rc);
    mesh_release(&m);
    return 0;
fail:
    fprintf(stderr, "bench_supmodel: %s\n", err.msg);
    return 1;
}
