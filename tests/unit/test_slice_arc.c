/*
 * test_slice_arc.c - arcs: with arc_fitting, a cylinder's and a torus's
 * curved perimeters become G2/G3; every arc, sampled along its length,
 * stays within arc_tolerance of the polyline it replaces (the same file
 * sliced without arcs), the estimator sees the same print, and the
 * command count drops by a measured factor.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../slicer/estimate.h"
#include "../../slicer/slice.h"
#include "../../src/base/buf.h"
#include "../../src/base/gcode.h"
#include "../../src/base/mem.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"
#include "slice_run.h"

struct seg {
    double x0, y0, x1, y1;
    uint32_t layer;
};

/* Every extrusion of a file: straight segments, arcs sampled into chords
   of at most 0.1 mm (arcs also listed whole with their layer). */
struct walk {
    struct seg *lines;
    size_t n_lines, cap_lines;
    struct seg *arcpts; /* samples along arcs: (x0, y0) a point on the arc */
    size_t n_arcpts, cap_arcpts;
    uint32_t n_cmds, n_arcs;
};

static int
walk_file(const struct buf *b, struct walk *w)
{
    memset(w, 0, sizeof(*w));
    double x = 0, y = 0, e = 0;
    uint32_t layer = 0;
    const char *s = b->data, *end = s + b->len;
    while (s < end) {
        const char *nl = memchr(s, '\n', (size_t)(end - s));
        size_t l = nl ? (size_t)(nl - s) : (size_t)(end - s);
        struct gcode_line g;
        if (l >= 13 && memcmp(s, ";LAYER_CHANGE", 13) == 0)
            layer++;
        if (l && s[0] != ';' && gcode_parse(s, l, &g, NULL) == SF_OK && g.letter == 'G') {
            double v, nx = x, ny = y, ne = e, i = 0, j = 0;
            if (g.code <= 3) {
                w->n_cmds++;
                if (gcode_get(&g, 'X', &v))
                    nx = v;
                if (gcode_get(&g, 'Y', &v))
                    ny = v;
                if (gcode_get(&g, 'E', &v))
                    ne = v;
            }
            if ((g.code == 0 || g.code == 1) && ne > e && (nx != x || ny != y)) {
                if (!mem_grow((void **)&w->lines, &w->cap_lines, w->n_lines + 1, sizeof(*w->lines)))
                    return SF_ENOMEM;
                w->lines[w->n_lines++] = (struct seg){ x, y, nx, ny, layer };
            } else if (g.code == 2 || g.code == 3) {
                w->n_arcs++;
                gcode_get(&g, 'I', &i);
                gcode_get(&g, 'J', &j);
                double cx = x + i, cy = y + j, r = hypot(i, j);
                double a0 = atan2(y - cy, x - cx), a1 = atan2(ny - cy, nx - cx);
                double sw = g.code == 2 ? a0 - a1 : a1 - a0;
                while (sw <= 1e-9)
                    sw += 2 * M_PI;
                int n = (int)ceil(sw * r / 0.1);
                for (int k = 0; k <= n; k++) {
                    double a = a0 + (g.code == 2 ? -1 : 1) * sw * k / n;
                    if (!mem_grow((void **)&w->arcpts, &w->cap_arcpts, w->n_arcpts + 1,
                                  sizeof(*w->arcpts)))
                        return SF_ENOMEM;
                    w->arcpts[w->n_arcpts++] =
                        (struct seg){ cx + r * cos(a), cy + r * sin(a), 0, 0, layer };
                }
            }
            if (g.code == 92 && gcode_get(&g, 'E', &v))
                ne = v;
            x = nx, y = ny, e = ne;
        }
        s += l + 1;
    }
    return SF_OK;
}

static double
pt_seg(double px, double py, const struct seg *s)
{
    double dx = s->x1 - s->x0, dy = s->y1 - s->y0, l2 = dx * dx + dy * dy;
    double t = l2 > 0 ? ((px - s->x0) * dx + (py - s->y0) * dy) / l2 : 0;
    t = t < 0 ? 0 : t > 1 ? 1 : t;
    return hypot(s->x0 + t * dx - px, s->y0 + t * dy - py);
}

static void
check_part(const struct mesh *m, const char *name, double min_ratio)
{
    struct sf_err err;
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    p.support = false;
    struct buf arcs, lines;
    struct slice_result ra, rl;
    char nm[64];
    snprintf(nm, sizeof(nm), "%s_arcs", name);
    T_OK(ts_slice_text(m, &p, nm, &arcs, &ra, &err), &err);
    p.arc_fitting = false;
    snprintf(nm, sizeof(nm), "%s_lines", name);
    T_OK(ts_slice_text(m, &p, nm, &lines, &rl, &err), &err);
    struct walk wa, wl;
    T_OK(walk_file(&arcs, &wa), NULL);
    T_OK(walk_file(&lines, &wl), NULL);
    T_TRUE(wa.n_arcs > 0);
    T_EQ_INT(wl.n_arcs, 0);
    /* every sample of every arc lies within the tolerance (plus the
       3-decimal rounding of the centre) of the polyline of its layer */
    double worst = 0;
    size_t from = 0;
    for (size_t i = 0; i < wa.n_arcpts; i++) {
        const struct seg *q = &wa.arcpts[i];
        while (from < wl.n_lines && wl.lines[from].layer < q->layer)
            from++;
        double best = INFINITY;
        for (size_t k = from; k < wl.n_lines && wl.lines[k].layer == q->layer; k++)
            best = fmin(best, pt_seg(q->x0, q->y0, &wl.lines[k]));
        worst = fmax(worst, best);
    }
    if (worst > p.arc_tolerance_mm + 0.003)
        t_fail(__FILE__, __LINE__, "%s: an arc strays %.4f mm from the polyline", name, worst);
    /* the same print: filament and time agree, in fewer commands */
    T_TRUE(fabs(ra.filament_mm - rl.filament_mm) < 0.002 * rl.filament_mm);
    T_TRUE(fabs(ra.time_s - rl.time_s) < 0.02 * rl.time_s);
    double ratio = (double)wl.n_cmds / wa.n_cmds;
    printf("    %s: %u moves without arcs, %u with (%u arcs): %.2fx fewer\n", name, wl.n_cmds,
           wa.n_cmds, wa.n_arcs, ratio);
    T_TRUE(ratio > min_ratio);
    free(wa.lines);
    free(wa.arcpts);
    free(wl.lines);
    free(wl.arcpts);
    buf_release(&arcs);
    buf_release(&lines);
    slice_profile_release(&p);
}

T_CASE(arcs_follow_the_polyline_and_cut_commands)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    double r[4] = { 0, 10, 10, 0 }, z[4] = { 0, 0, 10, 10 };
    T_OK(shape_revolve(&m, r, z, 4, 180, &err), &err);
    check_part(&m, "cylinder", 2);
    mesh_release(&m);
    mesh_init(&m);
    T_OK(shape_torus(&m, 15, 5, 72, 24, &err), &err);
    check_part(&m, "torus", 1.3);
    mesh_release(&m);
}
