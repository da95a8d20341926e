/*
 * test_slice_cool.c - cooling on generated parts, read back from the
 * G-code the slicer writes: every layer of a small cube lasts at least the
 * minimum layer time in the estimator (and not without cooling), the
 * slowdown never goes below min_print_speed, the fan follows the layer
 * time between the two thresholds and is off on the first layers, and
 * bridges get the bridge fan.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../slicer/estimate.h"
#include "../../slicer/gcwrite.h"
#include "../../slicer/slice.h"
#include "../../src/base/buf.h"
#include "../../src/base/mem.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"
#include "slice_run.h"
#include "slice_shapes.h"

struct layer_feeds {
    double min_f[512];    /* slowest extrusion feed per layer, mm/s */
    double cruise_s[512]; /* per layer: length / feed of every move */
    double last[4];
    uint32_t n_layers;
    uint32_t first_line; /* of the first ;LAYER_CHANGE: the start G-code is no layer */
};

static int
on_feed(void *ud, const struct est_move *mv)
{
    struct layer_feeds *c = ud;
    if (mv->layer < 512 && mv->line > c->first_line) {
        double dx = mv->x - c->last[0], dy = mv->y - c->last[1], dz = mv->z - c->last[2];
        double d = sqrt(dx * dx + dy * dy + dz * dz);
        if (d < 1e-9)
            d = fabs(mv->de);
        if (mv->f_mm_s > 0 && (dx != 0 || dy != 0 || mv->de != 0)) /* not the layer's Z move */
            c->cruise_s[mv->layer] += d / mv->f_mm_s;
        if (mv->de > 0 && (dx != 0 || dy != 0) && mv->f_mm_s < c->min_f[mv->layer])
            c->min_f[mv->layer] = mv->f_mm_s;
        if (mv->layer + 1 > c->n_layers)
            c->n_layers = mv->layer + 1;
    }
    c->last[0] = mv->x;
    c->last[1] = mv->y;
    c->last[2] = mv->z;
    c->last[3] = mv->e;
    return SF_OK;
}

static int
estimate_text(const struct buf *text, const struct slice_profile *p, struct layer_feeds *lf,
              struct estimate *e, struct sf_err *err)
{
    struct est_limits lim;
    slice_limits(p, &lim);
    memset(lf, 0, sizeof(*lf));
    for (int k = 0; k < 512; k++)
        lf->min_f[k] = INFINITY;
    const char *lc = memmem(text->data, text->len, ";LAYER_CHANGE", 13);
    lf->first_line = 1;
    for (const char *q = text->data; lc && q < lc; q++)
        lf->first_line += *q == '\n';
    return estimate_gcode(text->data, text->len, "cool", &lim, on_feed, lf, e, err);
}

/* Duration of layer k in the estimator (the last one runs to the end). */
static double
layer_s(const struct estimate *e, uint32_t k)
{
    return (k + 1 < e->n_layers ? e->layer_start_s[k + 1] : e->time_s) - e->layer_start_s[k];
}

T_CASE(cool_cube_layers_last_the_minimum_layer_time)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_box(&m, v3(0, 0, 0), v3(10, 10, 10), &err), &err);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    p.support = false;
    p.slowdown_below_s = 15;
    p.fan_below_s = 60;
    p.min_print_mm_s = 5;
    struct buf text;
    struct estimate e;
    struct layer_feeds lf;
    /* without cooling most layers of a 10 mm cube are much shorter */
    p.cooling = false;
    T_OK(ts_slice_text(&m, &p, "cool_off", &text, NULL, &err), &err);
    T_OK(estimate_text(&text, &p, &lf, &e, &err), &err);
    T_EQ_INT(e.n_layers, 50);
    uint32_t n_short = 0;
    for (uint32_t k = 0; k < e.n_layers; k++)
        n_short += layer_s(&e, k) < p.slowdown_below_s;
    T_TRUE(n_short > 40);
    double t_off = e.time_s, cruise_off[50];
    memcpy(cruise_off, lf.cruise_s, sizeof(cruise_off));
    estimate_release(&e);
    buf_release(&text);
    /* with it every layer lasts at least 15 s in the estimator */
    p.cooling = true;
    T_OK(ts_slice_text(&m, &p, "cool_on", &text, NULL, &err), &err);
    T_OK(estimate_text(&text, &p, &lf, &e, &err), &err);
    T_EQ_INT(e.n_layers, 50);
    for (uint32_t k = 0; k < e.n_layers; k++) {
        double t = layer_s(&e, k);
        if (t < p.slowdown_below_s - 1e-3) {
            t_fail(__FILE__, __LINE__, "layer %u lasts %.2f s", k, t);
            break;
        }
        /* a short layer is stretched to the target at cruise speed, not
           beyond (the planner's acceleration adds to it); a long one is left */
        double want = cruise_off[k] < p.slowdown_below_s ? p.slowdown_below_s : cruise_off[k];
        if (k + 1 < e.n_layers && fabs(lf.cruise_s[k] - want) > 0.02 * want) { /* end G-code */
            t_fail(__FILE__, __LINE__, "layer %u: %.2f s at cruise, want %.2f", k, lf.cruise_s[k],
                   want);
            break;
        }
    }
    /* the estimate sees the slowdown: the top layers are slower than before */
    T_TRUE(e.time_s > t_off + 0.5 * n_short * 5);
    estimate_release(&e);
    buf_release(&text);
    slice_profile_release(&p);
    mesh_release(&m);
}

T_CASE(cool_slowdown_stops_at_min_print_speed)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_box(&m, v3(0, 0, 0), v3(10, 10, 4), &err), &err);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    p.support = false;
    p.slowdown_below_s = 600; /* out of reach: every layer hits the floor */
    p.fan_below_s = 600;
    p.min_print_mm_s = 12;
    struct buf text;
    struct estimate e;
    struct layer_feeds lf;
    T_OK(ts_slice_text(&m, &p, "cool_floor", &text, NULL, &err), &err);
    T_OK(estimate_text(&text, &p, &lf, &e, &err), &err);
    for (uint32_t k = 0; k < lf.n_layers; k++) {
        /* every programmed speed is 15 mm/s or more, so none falls below the floor */
        if (lf.min_f[k] < 12 - 1e-6 || lf.min_f[k] > 12 + 1e-6) {
            t_fail(__FILE__, __LINE__, "layer %u: slowest extrusion %.3f mm/s, want 12", k,
                   lf.min_f[k]);
            break;
        }
    }
    estimate_release(&e);
    buf_release(&text);
    slice_profile_release(&p);
    mesh_release(&m);
}

/* Walk the G-code text: the fan in effect (percent) on every extrusion,
   per layer and by whether it is a bridge. */
struct fan_seen {
    int fan_pct[512]; /* -1: no extrusion, -2: more than one value */
    int bridge_pct[512];
    uint32_t n_layers;
};

static void
scan_fans(const struct buf *text, struct fan_seen *f)
{
    for (int k = 0; k < 512; k++)
        f->fan_pct[k] = f->bridge_pct[k] = -1;
    int fan = 0, layer = -1;
    bool bridge = false;
    const char *s = text->data, *end = s + text->len;
    while (s < end) {
        const char *nl = memchr(s, '\n', (size_t)(end - s));
        size_t l = nl ? (size_t)(nl - s) : (size_t)(end - s);
        if (l >= 13 && memcmp(s, ";LAYER_CHANGE", 13) == 0)
            layer++;
        else if (l >= 6 && memcmp(s, ";TYPE:", 6) == 0)
            bridge = l - 6 == 13 && memcmp(s + 6, "Bridge infill", 13) == 0;
        else if (l >= 4 && memcmp(s, "M107", 4) == 0)
            fan = 0;
        else if (l >= 6 && memcmp(s, "M106 S", 6) == 0)
            fan = (int)lround(strtod(s + 6, NULL) / 2.55);
        else if (l >= 3 && memcmp(s, "G1 ", 3) == 0 && layer >= 0 && layer < 512 &&
                 memchr(s, 'E', l) && (memchr(s, 'X', l) || memchr(s, 'Y', l))) {
            int *slot = bridge ? &f->bridge_pct[layer] : &f->fan_pct[layer];
            if (*slot == -1)
                *slot = fan;
            else if (*slot != fan)
                *slot = -2;
            f->n_layers = (uint32_t)layer + 1;
        }
        s += l + 1;
    }
}

T_CASE(cool_fan_follows_layer_time)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_box(&m, v3(0, 0, 0), v3(20, 20, 8), &err), &err);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    p.support = false;
    p.slowdown_below_s = 2;
    p.fan_below_s = 40;
    p.min_fan_pct = 20;
    p.max_fan_pct = 90;
    p.fan_always_on = true;
    p.disable_fan_first_layers = 2;
    struct buf text;
    struct estimate e;
    struct layer_feeds lf;
    T_OK(ts_slice_text(&m, &p, "cool_fan", &text, NULL, &err), &err);
    T_OK(estimate_text(&text, &p, &lf, &e, &err), &err);
    struct fan_seen fs;
    scan_fans(&text, &fs);
    T_EQ_INT(fs.n_layers, 40);
    int n_between = 0;
    for (uint32_t k = 0; k < fs.n_layers; k++) {
        /* the rule, on the layer time read back from the file (cruise time
           of every move, as the writer's cooling pass counts it) */
        double t = lf.cruise_s[k], want;
        if (k < 2)
            want = 0;
        else if (t < 2)
            want = 90;
        else if (t < 40)
            want = 90 - (90 - 20) * (t - 2) / (40 - 2);
        else
            want = 20;
        if (fs.fan_pct[k] < 0 || fabs(fs.fan_pct[k] - want) > 1.5) {
            t_fail(__FILE__, __LINE__, "layer %u (%.2f s): fan %d %%, want %.1f", k, t,
                   fs.fan_pct[k], want);
            break;
        }
        n_between += fs.fan_pct[k] > 21 && fs.fan_pct[k] < 89;
        /* within a percent: the writer times a layer without the layer
           change's retraction (0.05 s here), which this reading counts */
        T_TRUE(abs(gcw_fan_pct(&p, k, t, false) - fs.fan_pct[k]) <= 1);
    }
    /* the cube has both: long solid layers and quick sparse ones in between */
    T_TRUE(n_between >= 5);
    T_TRUE(fs.fan_pct[39] == 20);
    estimate_release(&e);
    buf_release(&text);
    slice_profile_release(&p);
    mesh_release(&m);
}

T_CASE(cool_fan_ramps_and_bridges)
{
    /* the rule itself: ramp from disable_fan_first_layers to full_fan_speed_layer */
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    p.fan_always_on = true;
    p.min_fan_pct = p.max_fan_pct = 80;
    p.bridge_fan_pct = 100;
    p.disable_fan_first_layers = 1;
    p.full_fan_speed_layer = 5;
    T_EQ_INT(gcw_fan_pct(&p, 0, 100, false), 0);
    T_EQ_INT(gcw_fan_pct(&p, 0, 100, true), 0);
    T_EQ_INT(gcw_fan_pct(&p, 1, 100, false), 20); /* (1 + 1 - 1) / (5 - 1) of 80 */
    T_EQ_INT(gcw_fan_pct(&p, 2, 100, true), 50);
    T_EQ_INT(gcw_fan_pct(&p, 4, 100, false), 80);
    T_EQ_INT(gcw_fan_pct(&p, 9, 100, true), 100);
    p.fan_always_on = false;
    p.full_fan_speed_layer = 0;
    T_EQ_INT(gcw_fan_pct(&p, 9, 100, false), 0);

    /* a slab on two posts: its first layer bridges the 10 mm gap under the
       bridge fan, the rest of that layer prints at the layer's fan */
    struct mesh m, b;
    struct sf_err err;
    mesh_init(&m);
    mesh_init(&b);
    T_OK(shape_box(&m, v3(0, 0, 0), v3(5, 10, 6), &err), &err);
    T_OK(shape_box(&b, v3(15, 0, 0), v3(20, 10, 6), &err), &err);
    T_OK(ts_merge(&m, &b), NULL);
    mesh_release(&b);
    mesh_init(&b);
    T_OK(shape_box(&b, v3(0, 0, 6), v3(20, 10, 8), &err), &err);
    T_OK(ts_merge(&m, &b), NULL);
    p.support = false;
    p.fan_always_on = true;
    p.min_fan_pct = p.max_fan_pct = 30;
    p.overhangs = false; /* the loops over the gap: test_slice_overhang */
    struct buf text;
    T_OK(ts_slice_text(&m, &p, "cool_bridge", &text, NULL, &err), &err);
    struct fan_seen fs;
    scan_fans(&text, &fs);
    int n_bridge = 0;
    for (uint32_t k = 0; k < fs.n_layers; k++) {
        if (fs.bridge_pct[k] != -1) {
            n_bridge++;
            T_EQ_INT(fs.bridge_pct[k], 100);
        }
        if (k >= 1)
            T_EQ_INT(fs.fan_pct[k], 30);
    }
    T_TRUE(n_bridge >= 1);
    buf_release(&text);
    slice_profile_release(&p);
    mesh_release(&m);
    mesh_release(&b);
}

T_CASE(cool_profile_checks)
{
    struct slice_profile p;
    struct sf_err err;
    T_OK(slice_profile_default(&p), NULL);
    T_OK(slice_profile_set(&p, "min_fan_speed=60", &err), &err);
    T_OK(slice_profile_set(&p, "max_fan_speed=50", &err), &err);
    T_ERR(slice_profile_check(&p, &err), SF_EINVAL, &err, "min_fan_speed");
    T_OK(slice_profile_set(&p, "max_fan_speed=70", &err), &err);
    T_OK(slice_profile_set(&p, "slowdown_below_layer_time=30", &err), &err);
    T_OK(slice_profile_set(&p, "fan_below_layer_time=20", &err), &err);
    T_ERR(slice_profile_check(&p, &err), SF_EINVAL, &err, "fan_below_layer_time");
    T_OK(slice_profile_set(&p, "cooling=no", &err), &err);
    T_OK(slice_profile_check(&p, &err), &err);
    slice_profile_release(&p);
}
