/*
 * test_slice_overhang.c - overhang perimeters: on the tee (a 10 mm stem
 * under a 50 mm bar, supports off) the bar's first layer prints the parts
 * of its perimeter loops that hang over air as ;TYPE:Overhang perimeter,
 * PrusaSlicer's way: a round thread of nozzle width at bridge speed, under
 * overhang_fan_speed, the layer's own fan before and after, and the
 * estimator reads those moves with that feed.  Every such move lies over
 * air (a nozzle width out from the stem), none on the stem's layers, and
 * with overhangs = no there are none.
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

struct scan {
    uint32_t n_ovh, n_ovh_g1, bad_flow, bad_feed, bad_fan, bad_place, low, fan_back;
    double ovh_mm, x0, x1;
    bool in_ovh;
};

/* The G-code text line by line: the fan (M106 S / M107), the role, and
   every G1 over air checked against the bridge flow, feed and fan. */
static void
scan_text(const char *s, size_t len, double cx, struct scan *sc)
{
    memset(sc, 0, sizeof(*sc));
    long fan = 0;
    double x = 0, y = 0, e = 0, z = 0;
    bool ovh = false;
    const double epm = 0.4 * 0.4 / (1.75 * 1.75); /* round thread of nozzle width */
    for (const char *p = s, *end = s + len; p < end;) {
        const char *nl = memchr(p, '\n', (size_t)(end - p));
        size_t l = nl ? (size_t)(nl - p) : (size_t)(end - p);
        char line[256];
        snprintf(line, sizeof(line), "%.*s", (int)(l < 255 ? l : 255), p);
        p += l + 1;
        if (strncmp(line, ";TYPE:", 6) == 0) {
            bool was = ovh;
            ovh = strcmp(line + 6, "Overhang perimeter") == 0;
            if (was && !ovh)
                sc->in_ovh = true; /* the next extrusion must be back on the layer's fan */
            continue;
        }
        if (strncmp(line, "M106 S", 6) == 0) {
            fan = strtol(line + 6, NULL, 10);
            continue;
        }
        if (strncmp(line, "M107", 4) == 0) {
            fan = 0;
            continue;
        }
        if (strncmp(line, "G92 E0", 6) == 0) {
            e = 0;
            continue;
        }
        if (strncmp(line, "G1 ", 3) != 0 && strncmp(line, "G2 ", 3) != 0 &&
            strncmp(line, "G3 ", 3) != 0)
            continue;
        double nx = x, ny = y, ne = e, f = -1;
        bool has_e = false;
        for (char *t = line + 3; *t;) {
            while (*t == ' ')
                t++;
            char c = *t;
            if (!c || c == ';')
                break;
            char *next;
            double v = strtod(t + 1, &next);
            if (c == 'X')
                nx = v;
            else if (c == 'Y')
                ny = v;
            else if (c == 'Z')
                z = v;
            else if (c == 'E') {
                ne = v;
                has_e = true;
            } else if (c == 'F') {
                f = v;
            }
            t = next > t + 1 ? next : t + 1;
        }
        double d = hypot(nx - x, ny - y);
        if (has_e && ne > e && d > 0) {
            if (ovh) {
                sc->n_ovh++;
                sc->ovh_mm += ne - e;
                if (fan != 196) /* 77 % */
                    sc->bad_fan++;
                if (z < 30)
                    sc->low++;
                /* over air: the midpoint a nozzle width out from the stem
                   (x within 5 mm of the middle), up to rounding */
                if (fabs((x + nx) / 2 - cx) < 5 + 0.2 - 0.01)
                    sc->bad_place++;
                if (line[1] == '1') {
                    sc->n_ovh_g1++;
                    if (fabs((ne - e) / d - epm) > 0.01 * epm)
                        sc->bad_flow++;
                }
                if (f > 0 && fabs(f - 3600) > 0.5) /* bridge speed, 60 mm/s */
                    sc->bad_feed++;
            } else if (sc->in_ovh) {
                sc->in_ovh = false;
                sc->fan_back += fan == 51; /* the layer's 20 % */
            }
            sc->x0 = fmin(sc->x0, nx);
            sc->x1 = fmax(sc->x1, nx);
        }
        x = nx;
        y = ny;
        e = ne;
    }
}

struct est_ovh {
    double mm, min_f, max_f;
};

static int
on_move(void *ud, const struct est_move *mv)
{
    struct est_ovh *o = ud;
    if (mv->de > 0 && mv->type && mv->type_len == 18 &&
        memcmp(mv->type, "Overhang perimeter", 18) == 0) {
        o->mm += mv->de;
        o->min_f = fmin(o->min_f, mv->f_mm_s);
        o->max_f = fmax(o->max_f, mv->f_mm_s);
    }
    return SF_OK;
}

static int
slice_tee(bool overhangs, struct buf *text, struct slice_profile *p, struct sf_err *err)
{
    struct mesh m;
    mesh_init(&m);
    int rc = shape_tee(&m, err);
    if (rc == SF_OK && (rc = slice_profile_default(p)) == SF_OK) {
        p->support = false;
        p->skirts = 0;
        p->brim_auto = false;
        p->overhangs = overhangs;
        p->fan_always_on = true;
        p->min_fan_pct = p->max_fan_pct = 20;
        p->overhang_fan_pct = 77;
        p->disable_fan_first_layers = 1;
        char path[512];
        snprintf(path, sizeof(path), "%s/tee%d.gcode", t_tmpdir(), overhangs);
        struct slice_result r;
        buf_init(text, 0);
        if ((rc = slice_mesh(&m, p, path, &r, NULL, NULL, err)) == SF_OK)
            rc = buf_read_file(text, path, err);
    }
    mesh_release(&m);
    return rc;
}

T_CASE(overhang_perimeters_bridge_flow_speed_and_fan)
{
    struct sf_err err;
    struct buf text;
    struct slice_profile p;
    T_OK(slice_tee(true, &text, &p, &err), &err);
    /* the part's middle in x: the tee is centred on the bed */
    struct scan sc;
    scan_text(text.data, text.len, p.bed_x_mm / 2, &sc);
    T_TRUE(sc.n_ovh > 8);    /* both arms, on the bar's first layer */
    T_TRUE(sc.n_ovh_g1 > 4); /* straight walls: G1 */
    T_EQ_INT(sc.bad_flow, 0);
    T_EQ_INT(sc.bad_feed, 0);
    T_EQ_INT(sc.bad_fan, 0);
    T_EQ_INT(sc.bad_place, 0);
    T_EQ_INT(sc.low, 0);
    T_TRUE(sc.fan_back > 0);
    /* the arms' loops over air: about 2 x (20 + 2 x 19.8) mm of the
       external and the inner loop on the bar's first layer */
    T_TRUE(sc.ovh_mm > 2 * 0.0522 * 100 && sc.ovh_mm < 2 * 0.0522 * 240);
    /* the estimator reads them, at bridge speed */
    struct est_limits lim;
    slice_limits(&p, &lim);
    struct estimate e;
    struct est_ovh o = { 0, INFINITY, 0 };
    T_OK(estimate_gcode(text.data, text.len, "tee", &lim, on_move, &o, &e, &err), &err);
    double t_on = e.time_s;
    estimate_release(&e);
    T_EQ_DBL(o.mm, sc.ovh_mm, 1e-3 * sc.ovh_mm);
    T_EQ_DBL(o.min_f, 60, 1e-6);
    T_EQ_DBL(o.max_f, 60, 1e-6);
    buf_release(&text);
    slice_profile_release(&p);

    /* overhangs = no: plain perimeters, no bridge flow, another estimate */
    T_OK(slice_tee(false, &text, &p, &err), &err);
    T_TRUE(memmem(text.data, text.len, "Overhang perimeter", 18) == NULL);
    T_OK(estimate_gcode(text.data, text.len, "tee", &lim, NULL, NULL, &e, &err), &err);
    T_TRUE(fabs(e.time_s - t_on) > 1);
    estimate_release(&e);
    buf_release(&text);
    slice_profile_release(&p);
}
