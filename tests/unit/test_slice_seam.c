/*
 * test_slice_seam.c - where perimeter loops start, read back from the
 * G-code: on a cylinder, aligned and rear seams of every layer fall within
 * one line width of each other at the rear; nearest ones scatter.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../slicer/estimate.h"
#include "../../slicer/slice.h"
#include "../../src/base/buf.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"
#include "slice_run.h"

struct seams {
    double x[1024], y[1024]; /* where each external perimeter starts */
    uint32_t n;
    double px, py;
    bool in_ext; /* the previous move extruded an external perimeter */
};

static int
on_move(void *ud, const struct est_move *mv)
{
    struct seams *s = ud;
    bool ext = mv->type && mv->type_len == 18 && memcmp(mv->type, "External perimeter", 18) == 0;
    bool extruding = mv->de > 0 && (mv->x != s->px || mv->y != s->py);
    if (ext && extruding && !s->in_ext && s->n < 1024) {
        s->x[s->n] = s->px;
        s->y[s->n++] = s->py;
    }
    s->in_ext = ext && extruding;
    s->px = mv->x;
    s->py = mv->y;
    return SF_OK;
}

static int
seams_of(const struct mesh *m, const struct slice_profile *p, const char *name, struct seams *s,
         struct sf_err *err)
{
    memset(s, 0, sizeof(*s));
    return ts_slice_walk(m, p, name, NULL, on_move, s, err);
}

/* Largest distance between two seams. */
static double
spread(const struct seams *s)
{
    double d = 0;
    for (uint32_t i = 0; i < s->n; i++)
        for (uint32_t j = i + 1; j < s->n; j++)
            d = fmax(d, hypot(s->x[i] - s->x[j], s->y[i] - s->y[j]));
    return d;
}

T_CASE(seam_aligned_cylinder_in_one_line)
{
    /* a 10 mm radius cylinder, 90 facets (0.7 mm each), 10 mm tall */
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    double r[4] = { 0, 10, 10, 0 }, z[4] = { 0, 0, 10, 10 };
    T_OK(shape_revolve(&m, r, z, 4, 90, &err), &err);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    p.support = false;
    p.skirts = 0;
    struct seams s;
    const char *kinds[2] = { "aligned", "rear" };
    for (int i = 0; i < 2; i++) {
        char kv[64];
        snprintf(kv, sizeof(kv), "seam_position=%s", kinds[i]);
        T_OK(slice_profile_set(&p, kv, &err), &err);
        T_OK(seams_of(&m, &p, kinds[i], &s, &err), &err);
        T_EQ_INT(s.n, 50); /* one external perimeter per layer */
        double d = spread(&s);
        if (d > p.width_mm)
            t_fail(__FILE__, __LINE__, "%s: seams %.3f mm apart", kinds[i], d);
        /* at the rear: the cylinder stands centred on the bed at (125, 105) */
        for (uint32_t k = 0; k < s.n; k++)
            if (s.y[k] - 105 < 0.95 * (10 - p.width_mm / 2)) {
                t_fail(__FILE__, __LINE__, "%s: layer %u seam at (%.2f, %.2f)", kinds[i], k, s.x[k],
                       s.y[k]);
                break;
            }
    }
    /* nearest starts wherever the nozzle is */
    T_OK(slice_profile_set(&p, "seam_position=nearest", &err), &err);
    T_OK(seams_of(&m, &p, "nearest", &s, &err), &err);
    T_TRUE(spread(&s) > 5);
    T_ERR(slice_profile_set(&p, "seam_position=random", &err) == SF_OK
              ? slice_profile_check(&p, &err)
              : SF_OK,
          SF_EINVAL, &err, "seam_position");
    slice_profile_release(&p);
    mesh_release(&m);
}
