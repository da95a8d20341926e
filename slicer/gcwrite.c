/*
 * gcwrite.c - the G-code body writer (see gcwrite.h).
 *
 * Positions are rounded to the 3 decimals written before E is computed
 * from them, so reading the file back gives exactly the lengths the
 * extrusion was computed for.  Numbers go through a small fixed-point
 * formatter (no printf on the hot path: a big part writes millions of
 * numbers).  Path order is a greedy nearest-neighbour walk per run of
 * same-role paths; runs longer than ORDER_MAX keep their order, bounding
 * the quadratic cost.
 *
 * Thread: reentrant.
 */
#include "gcwrite.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "../src/base/mem.h"

#define ORDER_MAX 4000

int
gcw_fmt(char *buf, double v, int dec)
{
    static const double pow10[] = { 1, 10, 100, 1000, 10000, 100000, 1000000 };
    char *p = buf;
    long long m = llround(v * pow10[dec]);
    if (m < 0) {
        *p++ = '-';
        m = -m;
    }
    long long ip = m / (long long)pow10[dec], fp = m % (long long)pow10[dec];
    char tmp[24];
    int n = 0;
    do {
        tmp[n++] = (char)('0' + ip % 10);
        ip /= 10;
    } while (ip);
    while (n)
        *p++ = tmp[--n];
    if (fp) {
        *p++ = '.';
        for (int d = dec - 1; d >= 0 && fp; d--) {
            long long q = (long long)pow10[d];
            *p++ = (char)('0' + fp / q);
            fp %= q;
        }
    }
    *p = '\0';
    if (p - buf == 2 && buf[0] == '-' && buf[1] == '0') { /* "-0" */
        buf[0] = '0';
        buf[1] = '\0';
        return 1;
    }
    return (int)(p - buf);
}

double
gcw_e_per_mm(const struct slice_profile *p, double w_mm, double h_mm)
{
    double fil = M_PI * p->filament_mm * p->filament_mm / 4;
    return h_mm * tp_spacing(w_mm, h_mm) / fil * p->flow;
}

/* One path in print order: path k from vertex at (open paths reversed if rev). */
struct step {
    uint32_t k, at;
    bool rev;
};

/* A layer's moves as cooling sees them (the dry pass): the extrusions it
   may slow down and the time of everything else, at the programmed feeds. */
struct cool_move {
    double len_mm, f_mm_min;
};
struct cool {
    struct cool_move *mv;
    size_t n, cap;
    double fixed_s;
    struct step *steps;
    size_t n_steps, cap_steps;
    /* seams: kind, and the external perimeters' seams of the layer below
       and of this one (aligned seams follow them up the part) */
    int seam;
    double align_mm;
    double (*pt)[2]; /* scratch: the points of the path being written */
    size_t cap_pt;
    struct ipt *seam_prev, *seam_cur;
    size_t n_prev, n_cur, cap_prev, cap_cur;
};

enum { SEAM_NEAREST, SEAM_ALIGNED, SEAM_REAR };

/* The rear-most vertex of loop q: largest y - x / 1000, so of two at
   nearly the same depth (a round back) the left one wins on every layer,
   and a flat back puts the seam in its left corner. */
static uint32_t
rear_vertex(const struct ipt *q, uint32_t n)
{
    uint32_t best = 0;
    for (uint32_t i = 1; i < n; i++)
        if (1000 * q[i].y - q[i].x > 1000 * q[best].y - q[best].x)
            best = i;
    return best;
}

static double
d2i(struct ipt a, struct ipt b)
{
    double dx = (double)(a.x - b.x), dy = (double)(a.y - b.y);
    return dx * dx + dy * dy;
}

/*
 * Where a perimeter loop starts and ends.  rear: its rear-most vertex.
 * aligned: the vertex nearest to the seam of the layer below closest to
 * the loop's rear vertex, when one is within align_mm of it (a wall
 * that moves a little between layers keeps its seam line), else rear.
 */
static uint32_t
seam_vertex(const struct cool *c, const struct ipt *q, uint32_t n, double align_mm)
{
    uint32_t r = rear_vertex(q, n);
    if (c->seam == SEAM_REAR || !c->n_prev)
        return r;
    double best = INFINITY;
    struct ipt t = q[r];
    for (size_t i = 0; i < c->n_prev; i++) {
        double d = d2i(c->seam_prev[i], q[r]);
        if (d < best)
            best = d, t = c->seam_prev[i];
    }
    double lim = (double)poly_i(align_mm);
    if (best > lim * lim)
        return r;
    uint32_t bi = r;
    best = INFINITY;
    for (uint32_t i = 0; i < n; i++) {
        double d = d2i(q[i], t);
        if (d < best)
            best = d, bi = i;
    }
    return bi;
}

struct wr {
    struct buf *out;
    const struct slice_profile *p;
    struct gcw_stats *st;
    double x, y, z, e; /* position as written */
    double f;          /* last F written, mm/min */
    bool retracted;
    int role;                  /* last ;TYPE: written, -1 none */
    struct paths_index inside; /* this layer's region, for retract_only_crossing */
    gcw_move_fn on_move;
    void *ud;
    float width;
    int rc;
    bool dry;          /* time the moves, write nothing (cooling's first pass) */
    bool adj;          /* the move being emitted is an extrusion cooling may slow */
    struct cool *cool; /* what the dry pass measured */
    double f_cap;      /* extrusion feed cap of this layer, mm/min (INFINITY: none) */
    int fan_pct;       /* fan as last written, percent; -1: not yet */
    int layer_fan_pct, bridge_fan_pct, overhang_fan_pct;
};

/* Dry pass: account a move of d mm at feed f (mm/min). */
static void
dry_move(struct wr *w, double d, double f)
{
    struct cool *c = w->cool;
    if (f <= 0 || d <= 0)
        return;
    if (!w->adj) {
        c->fixed_s += d / f * 60;
        return;
    }
    if (!mem_grow((void **)&c->mv, &c->cap, c->n + 1, sizeof(*c->mv))) {
        w->rc = SF_ENOMEM;
        return;
    }
    c->mv[c->n++] = (struct cool_move){ d, f };
}

/* Append "G1" + words; letters with NAN are skipped. */
static void
emit(struct wr *w, double x, double y, double z, double e, double f_mm_min)
{
    if (w->dry) {
        double fe = isnan(f_mm_min) ? w->f : f_mm_min;
        double dx = isnan(x) ? 0 : x - w->x, dy = isnan(y) ? 0 : y - w->y;
        double dz = isnan(z) ? 0 : z - w->z;
        double d = sqrt(dx * dx + dy * dy + dz * dz);
        if (d < 1e-12 && !isnan(e))
            d = w->p->retract_mm; /* the writer's only E-alone moves */
        w->f = fe;
        dry_move(w, d, fe);
        return;
    }
    char line[160], num[32];
    size_t n = 0;
    memcpy(line, "G1", 2);
    n = 2;
    const char letters[4] = { 'X', 'Y', 'Z', 'E' };
    double vals[4] = { x, y, z, e };
    int decs[4] = { 3, 3, 3, 5 };
    for (int i = 0; i < 4; i++) {
        if (isnan(vals[i]))
            continue;
        line[n++] = ' ';
        line[n++] = letters[i];
        int l = gcw_fmt(num, vals[i], decs[i]);
        memcpy(line + n, num, (size_t)l);
        n += (size_t)l;
    }
    if (!isnan(f_mm_min) && fabs(f_mm_min - w->f) > 1e-9) {
        line[n++] = ' ';
        line[n++] = 'F';
        int l = gcw_fmt(num, f_mm_min, 0);
        memcpy(line + n, num, (size_t)l);
        n += (size_t)l;
        w->f = f_mm_min;
    }
    line[n++] = '\n';
    if (w->rc == SF_OK && buf_append(w->out, line, n) < 0)
        w->rc = SF_ENOMEM;
    w->st->n_moves++;
    if (w->on_move)
        w->on_move(w->ud, isnan(x) ? w->x : x, isnan(y) ? w->y : y, isnan(z) ? w->z : z, w->e);
}

static void __attribute__((format(printf, 2, 3))) put(struct wr *w, const char *fmt, ...)
{
    char line[256];
    if (w->dry)
        return;
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(line, sizeof(line), fmt, ap);
    va_end(ap);
    if (n < 0 || (size_t)n >= sizeof(line))
        n = 0;
    if (w->rc == SF_OK && buf_append(w->out, line, (size_t)n) < 0)
        w->rc = SF_ENOMEM;
}

static double
r3(double v)
{
    return round(v * 1000) / 1000;
}

static double
r5(double v)
{
    return round(v * 100000) / 100000;
}

/* Move E by de (negative retracts); returns the E word to write.  In
   relative mode the word is the difference of the rounded absolute
   positions, so the rounding of the 5 decimals written never adds up. */
static double
e_word(struct wr *w, double de)
{
    double before = w->e;
    w->e += de;
    return w->p->e_relative ? r5(w->e) - r5(before) : w->e;
}

static void
retract(struct wr *w)
{
    const struct slice_profile *p = w->p;
    if (w->retracted || p->retract_mm <= 0)
        return;
    emit(w, NAN, NAN, NAN, e_word(w, -p->retract_mm), p->retract_mm_s * 60);
    if (p->retract_lift_mm > 0)
        emit(w, NAN, NAN, r3(w->z + p->retract_lift_mm), NAN, p->max_feed_z_mm_s * 60);
    w->retracted = true;
    w->st->n_retracts++;
}

static void
unretract(struct wr *w)
{
    const struct slice_profile *p = w->p;
    if (!w->retracted)
        return;
    if (p->retract_lift_mm > 0)
        emit(w, NAN, NAN, w->z, NAN, p->max_feed_z_mm_s * 60);
    emit(w, NAN, NAN, NAN, e_word(w, p->retract_mm), p->retract_mm_s * 60);
    w->retracted = false;
}

static void
travel(struct wr *w, double x, double y)
{
    x = r3(x);
    y = r3(y);
    double d = hypot(x - w->x, y - w->y);
    if (d < 1e-9)
        return;
    if (d > w->p->retract_min_travel_mm &&
        (!w->p->retract_only_crossing || !w->inside.first ||
         paths_index_crosses(&w->inside, (struct ipt){ poly_i(w->x), poly_i(w->y) },
                             (struct ipt){ poly_i(x), poly_i(y) })))
        retract(w);
    emit(w, x, y, NAN, NAN, w->p->travel_mm_s * 60);
    w->st->travel_mm += d;
    w->x = x;
    w->y = y;
}

/* Cooling slows every extrusion but bridges and overhangs: they keep
   their speed (PrusaSlicer's CoolingBuffer leaves them out). */
static bool
slowable(int role)
{
    return role != ROLE_BRIDGE && role != ROLE_OVERHANG;
}

static void
extrude_to(struct wr *w, double x, double y, double e_per_mm, double f, int role)
{
    x = r3(x);
    y = r3(y);
    double d = hypot(x - w->x, y - w->y);
    if (d < 1e-9)
        return;
    double de = d * e_per_mm;
    w->adj = slowable(role);
    emit(w, x, y, NAN, e_word(w, de), f < w->f_cap && w->adj ? f : w->adj ? w->f_cap : f);
    w->adj = false;
    w->st->e_mm[role] += de;
    w->x = x;
    w->y = y;
}

static double
role_speed(const struct slice_profile *p, int role, bool first)
{
    double v;
    switch (role) {
    case ROLE_EXT_PERIMETER:
        v = p->ext_perimeter_mm_s;
        break;
    case ROLE_PERIMETER:
        v = p->perimeter_mm_s;
        break;
    case ROLE_INFILL:
        v = p->infill_mm_s;
        break;
    case ROLE_SOLID:
        v = p->solid_mm_s;
        break;
    case ROLE_TOP:
        v = p->top_mm_s;
        break;
    case ROLE_BRIDGE:
        v = p->bridge_mm_s;
        break;
    case ROLE_SKIRT:
        v = p->perimeter_mm_s;
        break;
    case ROLE_GAP_FILL:
        v = p->gap_fill_mm_s;
        break;
    case ROLE_OVERHANG:
        v = p->bridge_mm_s > 0 ? p->bridge_mm_s : p->ext_perimeter_mm_s;
        break;
    default:
        v = p->support_mm_s;
        break;
    }
    return first && p->first_layer_mm_s < v ? p->first_layer_mm_s : v;
}

static double
dist2(struct ipt a, double x, double y)
{
    double dx = poly_mm(a.x) - x, dy = poly_mm(a.y) - y;
    return dx * dx + dy * dy;
}

/* Append "G2"/"G3" to (x, y) around centre (cx, cy) over len mm of arc. */
static void
emit_arc(struct wr *w, bool cw, double x, double y, double cx, double cy, double len, double epm,
         double f_mm_min, int role)
{
    double de = len * epm;
    double e = e_word(w, de);
    double f = f_mm_min < w->f_cap || !slowable(role) ? f_mm_min : w->f_cap;
    w->st->e_mm[role] += de;
    if (w->dry) {
        w->adj = slowable(role);
        dry_move(w, len, f);
        w->adj = false;
        w->f = f;
        w->x = x;
        w->y = y;
        return;
    }
    char line[200], num[32];
    size_t n = 0;
    memcpy(line, cw ? "G2" : "G3", 2);
    n = 2;
    const char letters[5] = { 'X', 'Y', 'I', 'J', 'E' };
    double vals[5] = { x, y, cx - w->x, cy - w->y, e };
    int decs[5] = { 3, 3, 3, 3, 5 };
    for (int i = 0; i < 5; i++) {
        line[n++] = ' ';
        line[n++] = letters[i];
        int l = gcw_fmt(num, vals[i], decs[i]);
        memcpy(line + n, num, (size_t)l);
        n += (size_t)l;
    }
    if (fabs(f - w->f) > 1e-9) {
        line[n++] = ' ';
        line[n++] = 'F';
        int l = gcw_fmt(num, f, 0);
        memcpy(line + n, num, (size_t)l);
        n += (size_t)l;
        w->f = f;
    }
    line[n++] = '\n';
    if (w->rc == SF_OK && buf_append(w->out, line, n) < 0)
        w->rc = SF_ENOMEM;
    w->st->n_moves++;
    w->st->n_arcs++;
    w->x = x;
    w->y = y;
    if (w->on_move)
        w->on_move(w->ud, x, y, w->z, w->e);
}

/*
 * Does one circle carry points pt[a..b] within tol?  The circle through
 * pt[a], pt[(a + b) / 2] and pt[b]; the points turning one way by less
 * than 90 degrees a step and under a turn in all, and along each chord
 * the arc's bulge (r (1 - cos(step / 2))) plus the larger distance of the
 * chord's ends from the circle at most tol, so the arc stays within tol
 * of the polyline.
 */
static bool
arc_fits(const double (*pt)[2], size_t a, size_t b, double tol, double *cx, double *cy, double *len,
         bool *cw)
{
    size_t m = (a + b) / 2;
    double ax = pt[a][0], ay = pt[a][1], bx = pt[m][0], by = pt[m][1], ex = pt[b][0], ey = pt[b][1];
    double d = 2 * (ax * (by - ey) + bx * (ey - ay) + ex * (ay - by));
    if (fabs(d) < 1e-9)
        return false;
    double a2 = ax * ax + ay * ay, b2 = bx * bx + by * by, e2 = ex * ex + ey * ey;
    double ux = (a2 * (by - ey) + b2 * (ey - ay) + e2 * (ay - by)) / d;
    double uy = (a2 * (ex - bx) + b2 * (ax - ex) + e2 * (bx - ax)) / d;
    double r = hypot(ax - ux, ay - uy);
    if (r < 0.5 || r > 1000)
        return false;
    double sweep = 0, dir = 0, prev_err = 0;
    for (size_t i = a; i <= b; i++) {
        double err = fabs(hypot(pt[i][0] - ux, pt[i][1] - uy) - r);
        if (err > tol)
            return false;
        double ends = fmax(err, prev_err);
        prev_err = err;
        if (i == a)
            continue;
        double px = pt[i - 1][0] - ux, py = pt[i - 1][1] - uy, qx = pt[i][0] - ux,
               qy = pt[i][1] - uy;
        double t = atan2(px * qy - py * qx, px * qx + py * qy); /* the step's turn */
        if (fabs(t) < 1e-9 || fabs(t) > M_PI / 2 || (dir != 0 && (t > 0) != (dir > 0)))
            return false;
        dir = t;
        if (ends + r * (1 - cos(t / 2)) > tol) /* the arc off the chord, both ends' errors in */
            return false;
        sweep += t;
    }
    if (fabs(sweep) > 2 * M_PI - 0.1)
        return false;
    *cx = ux;
    *cy = uy;
    *len = fabs(sweep) * r;
    *cw = sweep < 0;
    return true;
}

/* Extrude along pts[0..n) (pts[0] is where the nozzle is), fitting arcs. */
static void
extrude_arcs(struct wr *w, const double (*pt)[2], size_t n, double epm, double f, int role)
{
    double tol = w->p->arc_tolerance_mm;
    for (size_t a = 0; a + 1 < n;) {
        double cx, cy, len, bcx = 0, bcy = 0, blen = 0;
        bool cw, bcw = false;
        size_t best = a;
        /* longest arc from a: doubling, then bisection (arcs of 3+ segments) */
        size_t lo = a, hi = a + 3;
        while (hi < n && hi - a <= 512 && arc_fits(pt, a, hi, tol, &cx, &cy, &len, &cw)) {
            best = hi, bcx = cx, bcy = cy, blen = len, bcw = cw;
            lo = hi;
            hi = a + 2 * (hi - a);
        }
        if (best > a) {
            if (hi > n - 1)
                hi = n;
            while (hi - lo > 1) {
                size_t mid = (lo + hi) / 2;
                if (arc_fits(pt, a, mid, tol, &cx, &cy, &len, &cw))
                    lo = mid, best = mid, bcx = cx, bcy = cy, blen = len, bcw = cw;
                else
                    hi = mid;
            }
            emit_arc(w, bcw, pt[best][0], pt[best][1], bcx, bcy, blen, epm, f, role);
            a = best;
        } else {
            extrude_to(w, pt[a + 1][0], pt[a + 1][1], epm, f, role);
            a++;
        }
    }
}

/* The fan of the moves being written: bridges and overhangs have theirs. */
static void set_fan(struct wr *w, int pct);

/* Write ;TYPE: and ;WIDTH: when they change. */
static void
tag(struct wr *w, int role, float width)
{
    if (role != w->role)
        put(w, ";TYPE:%s\n", tp_role_name(role));
    if (role != w->role || width != w->width)
        put(w, ";WIDTH:%g\n", width);
    w->role = role;
    w->width = width;
}

/* Extrude pt[0..m) (pt[0]: the nozzle) as role, arcs where they fit. */
static void
extrude_run(struct wr *w, const double (*pt)[2], size_t m, double epm, double f, int role)
{
    if (w->p->arc_fitting && m >= 4) {
        extrude_arcs(w, pt, m, epm, f, role);
        return;
    }
    for (size_t i = 1; i < m; i++)
        extrude_to(w, pt[i][0], pt[i][1], epm, f, role);
}

/*
 * A perimeter loop with overhang segments (flags ov, from its vertex at):
 * runs over the layer below print as the loop's role; runs over air as
 * ROLE_OVERHANG, PrusaSlicer's overhang perimeters: a round thread of
 * nozzle width (bridge flow) at bridge speed, with overhang_fan_speed.
 */
static void
print_loop_overhangs(struct wr *w, const struct tp_info *in, const struct ipt *q, const uint8_t *ov,
                     uint32_t n, uint32_t at, double h, double epm, double f)
{
    (void)h;
    struct cool *c = w->cool;
    const struct slice_profile *p = w->p;
    double nz = p->nozzle_mm;
    double epm_o = nz * nz / (p->filament_mm * p->filament_mm) * p->flow;
    double f_o = role_speed(p, ROLE_OVERHANG, false) * 60;
    if (!mem_grow((void **)&c->pt, &c->cap_pt, n + 1, sizeof(*c->pt))) {
        w->rc = SF_ENOMEM;
        return;
    }
    uint32_t s = 0;
    while (s < n && w->rc == SF_OK) {
        /* one run of equal flags: segments s.. from vertex (at + s) */
        uint8_t o = ov[(at + s) % n];
        size_t m = 0;
        c->pt[m][0] = w->x;
        c->pt[m++][1] = w->y;
        for (; s < n && ov[(at + s) % n] == o; s++) {
            uint32_t i = (at + s + 1) % n;
            double x = r3(poly_mm(q[i].x)), y = r3(poly_mm(q[i].y));
            if (x != c->pt[m - 1][0] || y != c->pt[m - 1][1]) {
                c->pt[m][0] = x;
                c->pt[m++][1] = y;
            }
        }
        if (m < 2)
            continue;
        if (o) {
            set_fan(w, w->overhang_fan_pct);
            tag(w, ROLE_OVERHANG, (float)nz);
            extrude_run(w, (const double(*)[2])c->pt, m, epm_o, f_o, ROLE_OVERHANG);
        } else {
            set_fan(w, w->layer_fan_pct);
            tag(w, in->role, in->width_mm);
            extrude_run(w, (const double(*)[2])c->pt, m, epm, f, in->role);
        }
    }
    set_fan(w, w->layer_fan_pct);
}

/* Print path k starting at vertex `at` (reversed for open paths if rev). */
static void
print_path(struct wr *w, const struct layer_paths *lp, uint32_t k, uint32_t at, bool rev, double h,
           bool first)
{
    const struct tp_info *in = &lp->info[k];
    const struct ipt *q = lp->p.pts + lp->p.start[k];
    uint32_t n = paths_len(&lp->p, k);
    if (in->role != w->role || in->width_mm != w->width) {
        if (in->role != w->role)
            put(w, ";TYPE:%s\n", tp_role_name(in->role));
        put(w, ";WIDTH:%g\n", in->width_mm);
        w->role = in->role;
        w->width = in->width_mm;
    }
    uint32_t i0 = in->closed ? at : (rev ? n - 1 : 0);
    travel(w, poly_mm(q[i0].x), poly_mm(q[i0].y));
    unretract(w);
    double epm = gcw_e_per_mm(w->p, in->width_mm, h);
    if (in->role == ROLE_BRIDGE) /* a round thread of nozzle width, hanging in air */
        epm = in->width_mm * in->width_mm / (w->p->filament_mm * w->p->filament_mm) * w->p->flow;
    double f = role_speed(w->p, in->role, first) * 60;
    struct cool *c = w->cool;
    if (in->closed && lp->ovh && (in->role == ROLE_PERIMETER || in->role == ROLE_EXT_PERIMETER)) {
        const uint8_t *ov = lp->ovh + lp->p.start[k];
        bool any = false;
        for (uint32_t i = 0; i < n && !any; i++)
            any = ov[i];
        if (any) {
            print_loop_overhangs(w, in, q, ov, n, at, h, epm, f);
            return;
        }
    }
    if (w->p->arc_fitting && n >= 4 &&
        (in->role == ROLE_PERIMETER || in->role == ROLE_EXT_PERIMETER || in->role == ROLE_SKIRT) &&
        mem_grow((void **)&c->pt, &c->cap_pt, n + 1, sizeof(*c->pt))) {
        size_t m = 0;
        c->pt[m][0] = w->x;
        c->pt[m++][1] = w->y;
        for (uint32_t s = 1; s < n + in->closed; s++) {
            uint32_t i = in->closed ? (at + s) % n : rev ? n - 1 - s : s;
            double x = r3(poly_mm(q[i].x)), y = r3(poly_mm(q[i].y));
            if (x != c->pt[m - 1][0] || y != c->pt[m - 1][1]) {
                c->pt[m][0] = x;
                c->pt[m++][1] = y;
            }
        }
        extrude_arcs(w, (const double(*)[2])c->pt, m, epm, f, in->role);
        return;
    }
    if (in->closed) {
        for (uint32_t s = 1; s <= n; s++) {
            uint32_t i = (at + s) % n;
            extrude_to(w, poly_mm(q[i].x), poly_mm(q[i].y), epm, f, in->role);
        }
    } else {
        for (uint32_t s = 1; s < n; s++) {
            uint32_t i = rev ? n - 1 - s : s;
            extrude_to(w, poly_mm(q[i].x), poly_mm(q[i].y), epm, f, in->role);
        }
    }
}

static bool
add_step(struct cool *c, uint32_t k, uint32_t at, bool rev)
{
    if (!mem_grow((void **)&c->steps, &c->cap_steps, c->n_steps + 1, sizeof(*c->steps)))
        return false;
    c->steps[c->n_steps++] = (struct step){ k, at, rev };
    return true;
}

/* Order paths [a, b) of one role nearest-first from (*cx, *cy), appending
   to c->steps and moving the cursor to where the last one ends. */
static int
order_run(struct cool *c, const struct layer_paths *lp, uint32_t a, uint32_t b, double *cx,
          double *cy)
{
    uint32_t n = b - a;
    if (n > ORDER_MAX) {
        for (uint32_t k = a; k < b; k++)
            if (!add_step(c, k, 0, false))
                return SF_ENOMEM;
        const struct ipt *q = lp->p.pts + lp->p.start[b - 1];
        uint32_t m = paths_len(&lp->p, b - 1);
        struct ipt e = lp->info[b - 1].closed ? q[0] : q[m - 1];
        *cx = r3(poly_mm(e.x));
        *cy = r3(poly_mm(e.y));
        return SF_OK;
    }
    uint8_t *done = mem_calloc(n, 1);
    if (!done)
        return SF_ENOMEM;
    for (uint32_t s = 0; s < n; s++) {
        double best = INFINITY;
        uint32_t bk = a, bat = 0;
        bool brev = false;
        for (uint32_t k = a; k < b; k++) {
            if (done[k - a])
                continue;
            const struct ipt *q = lp->p.pts + lp->p.start[k];
            uint32_t m = paths_len(&lp->p, k);
            uint8_t role = lp->info[k].role;
            if (lp->info[k].closed && c->seam != SEAM_NEAREST &&
                (role == ROLE_PERIMETER || role == ROLE_EXT_PERIMETER)) {
                /* the seam is fixed: the loop is as near as its seam */
                uint32_t i = seam_vertex(c, q, m, c->align_mm);
                double d = dist2(q[i], *cx, *cy);
                if (d < best)
                    best = d, bk = k, bat = i, brev = false;
            } else if (lp->info[k].closed) {
                for (uint32_t i = 0; i < m; i++) {
                    double d = dist2(q[i], *cx, *cy);
                    if (d < best)
                        best = d, bk = k, bat = i, brev = false;
                }
            } else {
                double d0 = dist2(q[0], *cx, *cy), d1 = dist2(q[m - 1], *cx, *cy);
                if (d0 < best)
                    best = d0, bk = k, bat = 0, brev = false;
                if (d1 < best)
                    best = d1, bk = k, bat = 0, brev = true;
            }
        }
        done[bk - a] = 1;
        if (!add_step(c, bk, bat, brev)) {
            free(done);
            return SF_ENOMEM;
        }
        const struct ipt *q = lp->p.pts + lp->p.start[bk];
        uint32_t m = paths_len(&lp->p, bk);
        struct ipt e = lp->info[bk].closed ? q[bat] : q[brev ? 0 : m - 1];
        if (lp->info[bk].role == ROLE_EXT_PERIMETER && lp->info[bk].closed) {
            if (!mem_grow((void **)&c->seam_cur, &c->cap_cur, c->n_cur + 1, sizeof(*c->seam_cur))) {
                free(done);
                return SF_ENOMEM;
            }
            c->seam_cur[c->n_cur++] = e;
        }
        *cx = r3(poly_mm(e.x));
        *cy = r3(poly_mm(e.y));
    }
    free(done);
    return SF_OK;
}

static void
set_fan(struct wr *w, int pct)
{
    if (pct == w->fan_pct)
        return;
    if (pct <= 0)
        put(w, "M107\n");
    else
        put(w, "M106 S%ld\n", lround(pct * 2.55));
    if (!w->dry)
        w->fan_pct = pct;
}

/* Write (or, dry, time) the layer's steps. */
static void
write_steps(struct wr *w, const struct layer_paths *l, const struct cool *c, double h, bool first)
{
    for (size_t i = 0; i < c->n_steps && w->rc == SF_OK; i++) {
        const struct step *st = &c->steps[i];
        set_fan(w, l->info[st->k].role == ROLE_BRIDGE ? w->bridge_fan_pct : w->layer_fan_pct);
        print_path(w, l, st->k, st->at, st->rev, h, first);
    }
}

/* Layer time with extrusions capped at v mm/min (moves already slower keep their feed). */
static double
time_capped(const struct cool *c, double v)
{
    double t = c->fixed_s;
    for (size_t i = 0; i < c->n; i++)
        t += c->mv[i].len_mm / (c->mv[i].f_mm_min < v ? c->mv[i].f_mm_min : v) * 60;
    return t;
}

/*
 * PrusaSlicer's cooling slowdown (CoolingBuffer, non-proportional logic):
 * a layer that takes less than slowdown_below_layer_time is stretched to
 * it by capping the feed of its extrusions, fastest first, never below
 * min_print_speed (nor slowing a move already slower than that).  The
 * cap is found by bisection on the monotone layer time; it errs slow, so
 * the layer never ends up shorter than the target.  No lift-and-wait.
 */
static double
cool_cap(const struct slice_profile *p, const struct cool *c, double t_s)
{
    if (!p->cooling || t_s >= p->slowdown_below_s || c->n == 0)
        return INFINITY;
    double lo = p->min_print_mm_s * 60, hi = 0;
    for (size_t i = 0; i < c->n; i++)
        if (c->mv[i].f_mm_min > hi)
            hi = c->mv[i].f_mm_min;
    if (hi <= lo || time_capped(c, lo) <= p->slowdown_below_s)
        return lo;
    for (int it = 0; it < 60 && hi - lo > 1e-6; it++) {
        double mid = 0.5 * (lo + hi);
        if (time_capped(c, mid) >= p->slowdown_below_s)
            lo = mid;
        else
            hi = mid;
    }
    return lo;
}

static int fan_pct(const struct slice_profile *p, uint32_t layer, double layer_time_s,
                   double special);

int
gcw_fan_pct(const struct slice_profile *p, uint32_t layer, double layer_time_s, bool bridge)
{
    return fan_pct(p, layer, layer_time_s, bridge ? p->bridge_fan_pct : -1);
}

int
gcw_overhang_fan_pct(const struct slice_profile *p, uint32_t layer, double layer_time_s)
{
    return fan_pct(p, layer, layer_time_s, p->overhang_fan_pct);
}

/* The fan by PrusaSlicer's rules; special >= 0: a bridge's or overhang's own. */
static int
fan_pct(const struct slice_profile *p, uint32_t layer, double layer_time_s, double special)
{
    int off = p->disable_fan_first_layers;
    if (off <= 0 && p->full_fan_speed_layer > 0)
        off = 1; /* a ramp starts from a layer with the fan off */
    if ((long)layer < off)
        return 0;
    double fan = p->fan_always_on ? p->min_fan_pct : 0;
    if (p->cooling) {
        if (layer_time_s < p->slowdown_below_s) {
            fan = p->max_fan_pct;
        } else if (layer_time_s < p->fan_below_s) {
            double t =
                (layer_time_s - p->slowdown_below_s) / (p->fan_below_s - p->slowdown_below_s);
            fan = floor(t * p->min_fan_pct + (1 - t) * p->max_fan_pct + 0.5);
        }
    }
    if (special >= 0)
        fan = special;
    if ((long)layer + 1 < p->full_fan_speed_layer) {
        double ramp = (double)((long)layer + 1 - off) / (p->full_fan_speed_layer - off);
        fan = floor(fan * ramp + 0.5);
    }
    return (int)(fan < 0 ? 0 : fan > 100 ? 100 : fan);
}

void
gcw_stats_release(struct gcw_stats *st)
{
    free(st->layer_time_s);
    st->layer_time_s = NULL;
}

int
gcw_body(const struct layer_stack *s, const struct layer_paths *lp, const struct slice_profile *p,
         struct buf *out, struct gcw_stats *st, gcw_move_fn on_move, void *ud, struct sf_err *err)
{
    memset(st, 0, sizeof(*st));
    struct cool c;
    memset(&c, 0, sizeof(c));
    c.seam = strcmp(p->seam_position, "rear") == 0      ? SEAM_REAR
             : strcmp(p->seam_position, "aligned") == 0 ? SEAM_ALIGNED
                                                        : SEAM_NEAREST;
    c.align_mm = 4 * p->width_mm;
    struct wr w = { .out = out,
                    .p = p,
                    .st = st,
                    .f = -1,
                    .role = -1,
                    .rc = SF_OK,
                    .on_move = on_move,
                    .ud = ud,
                    .cool = &c,
                    .f_cap = INFINITY,
                    .fan_pct = -1 };
    if (s->n && !(st->layer_time_s = mem_calloc(s->n, sizeof(double))))
        return sf_err_set(err, SF_ENOMEM, "gcode: out of memory");
    st->n_layers = s->n;
    put(&w, "G21\nG90\n%s\nG92 E0\n", p->e_relative ? "M83" : "M82");
    for (uint32_t k = 0; k < s->n && w.rc == SF_OK; k++) {
        const struct layer *L = &s->l[k];
        double z = r3(L->z_mm);
        put(&w, ";LAYER_CHANGE\n;Z:%g\n;HEIGHT:%g\n", z, L->h_mm);
        if (k == 1)
            put(&w, "M104 S%g\nM140 S%g\n", p->nozzle_c, p->bed_c);
        if (!p->e_relative) {
            put(&w, "G92 E0\n");
            w.e = 0;
        }
        retract(&w);
        emit(&w, NAN, NAN, z, NAN, p->max_feed_z_mm_s * 60);
        w.z = z;
        paths_index_release(&w.inside);
        if (p->retract_only_crossing && !paths_index_init(&w.inside, &L->region))
            w.rc = SF_ENOMEM;
        const struct layer_paths *l = &lp[k];
        c.n_steps = 0;
        c.n_cur = 0;
        double cx = w.x, cy = w.y;
        for (uint32_t a = 0; a < l->p.n && w.rc == SF_OK;) {
            uint32_t b = a + 1;
            while (b < l->p.n && l->info[b].role == l->info[a].role)
                b++;
            if (order_run(&c, l, a, b, &cx, &cy) < 0)
                w.rc = SF_ENOMEM;
            a = b;
        }
        /* this layer's seams guide the next one's */
        struct ipt *sw = c.seam_prev;
        size_t cw = c.cap_prev;
        c.seam_prev = c.seam_cur;
        c.cap_prev = c.cap_cur;
        c.n_prev = c.n_cur;
        c.seam_cur = sw;
        c.cap_cur = cw;
        /* cooling: time the layer dry, then write it with the fan and the
           feed cap that time calls for */
        struct wr saved = w;
        struct gcw_stats saved_st = *st;
        c.n = 0;
        c.fixed_s = 0;
        w.dry = true;
        write_steps(&w, l, &c, L->h_mm, k == 0);
        double t_s = time_capped(&c, INFINITY);
        int rc = w.rc;
        w = saved;
        *st = saved_st;
        w.rc = rc;
        st->layer_time_s[k] = t_s;
        w.layer_fan_pct = gcw_fan_pct(p, k, t_s, false);
        w.bridge_fan_pct = gcw_fan_pct(p, k, t_s, true);
        w.overhang_fan_pct = gcw_overhang_fan_pct(p, k, t_s);
        w.f_cap = cool_cap(p, &c, t_s);
        set_fan(&w, w.layer_fan_pct);
        write_steps(&w, l, &c, L->h_mm, k == 0);
        w.f_cap = INFINITY;
    }
    paths_index_release(&w.inside);
    free(c.mv);
    free(c.steps);
    free(c.seam_prev);
    free(c.seam_cur);
    free(c.pt);
    retract(&w);
    if (w.rc < 0) {
        gcw_stats_release(st);
        if (out->len + 4096 < out->max)
            return sf_err_set(err, SF_ENOMEM, "gcode: out of memory");
        return sf_err_set(err, SF_ENOMEM, "gcode: output larger than the cap of %zu bytes",
                          out->max);
    }
    return SF_OK;
}
