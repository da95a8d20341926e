/*
 * estimate.c - G-code interpreter and trapezoidal planner (see estimate.h).
 *
 * Blocks stream through a look-ahead window (5 floats each, at most
 * EST_LOOKAHEAD_BLOCKS of them: 1.3 MB): a block leaves it, timed, once no later
 * block can lower its entry speed (the window's last block could stop
 * from it), so the time is the same as a firmware with an endless
 * look-ahead would take.  Only a window full of blocks that all still
 * depend on what follows (a file whose deceleration spans more than
 * EST_LOOKAHEAD_BLOCKS / 2 moves) plans its older half as if the window's end
 * stopped, as a firmware with a full buffer does.
 * Junction speeds follow Marlin 2's planner.cpp (classic jerk and
 * junction deviation), re-derived, not copied.
 *
 * Thread: reentrant.
 */
#include "estimate.h"

#include <math.h>
#include <string.h>

#include "../src/base/gcode.h"
#include "../src/base/limits.h"
#include "../src/base/mem.h"

/* Beyond these a file is broken (1 km of axis travel, 1000 km of filament),
   and the planner's floats would overflow. */
#define EST_COORD_MAX 1e6
#define EST_E_MAX     1e9

struct block {
    float len;      /* mm (XYZ, or |E| for E-only moves) */
    float v_nom;    /* nominal speed, mm/s */
    float accel;    /* mm/s^2 */
    float v_max_in; /* junction limit, mm/s */
    float v_safe;   /* jerk-limited speed from / to rest */
};

/* A move's planner quantities before its junction with the one before it. */
struct seg {
    double len;     /* mm (XYZ, or |E| for E-only moves) */
    double v;       /* nominal speed: F capped per axis, mm/s */
    double acc;     /* mm/s^2, capped per axis */
    double safe;    /* jerk-limited speed from / to rest, mm/s */
    double unit[4]; /* direction, X Y Z E per mm */
    double vel[4];  /* axis velocities at v */
    bool e_only;    /* no XYZ motion */
};

struct plan {
    struct block *b; /* the window: blocks [0, n) are file blocks [done, done + n) */
    size_t n, cap;
    size_t done;         /* blocks timed and dropped */
    size_t peak;         /* most blocks held at once */
    double t;            /* time of the dropped blocks */
    size_t *layer_block; /* file block at each ;LAYER_CHANGE */
    double *layer_s;     /* its start time, set as that block is timed */
    size_t n_layers, next_layer;
    size_t n_blocks; /* blocks planned in all */
    struct seg prev; /* the previous block, for the junction */
    bool have_prev;
};

static double
trapezoid_s(double len, double v0, double v1, double vn, double a)
{
    double d_acc = (vn * vn - v0 * v0) / (2 * a), d_dec = (vn * vn - v1 * v1) / (2 * a);
    if (d_acc + d_dec <= len)
        return (vn - v0) / a + (vn - v1) / a + (len - d_acc - d_dec) / vn;
    double vp = sqrt(fmax(0, (2 * a * len + v0 * v0 + v1 * v1) / 2));
    return (vp - v0) / a + (vp - v1) / a;
}

/*
 * Time the window's blocks whose entry speeds are final and drop them.
 * Backward, each block must be able to slow to the next one's entry;
 * forward, reach it from the previous one's.  At the end of the file
 * (last) the final block ends at its safe speed and all are timed.
 * Otherwise block k is final when it keeps its junction limit even if
 * the window's last block stopped: then no later block can lower it, nor
 * any block before it, and blocks [0, k) are timed.  A full window with
 * fewer than half final times its older half as if its end stopped.
 */
static void
plan_flush(struct plan *pl, bool last)
{
    struct block *b = pl->b;
    size_t n = pl->n, k = n;
    if (!n)
        return;
    double next = last ? b[n - 1].v_safe : 0;
    if (!last) {
        size_t half = n / 2;
        for (k = n; k-- > 0;) {
            double lim = sqrt(next * next + 2.0 * b[k].accel * b[k].len);
            if (b[k].v_max_in <= lim)
                break; /* final */
            if (k == half && pl->n == EST_LOOKAHEAD_BLOCKS)
                break; /* forced: b[half] as if the window's end stopped */
            next = (float)lim;
        }
        if (k == (size_t)-1 || k == 0)
            return;
        if (b[k].v_max_in > sqrt(next * next + 2.0 * b[k].accel * b[k].len))
            b[k].v_max_in = (float)sqrt(next * next + 2.0 * b[k].accel * b[k].len);
        next = b[k].v_max_in;
    } else {
        k = n;
    }
    for (size_t i = k; i-- > 0;) {
        double lim = sqrt(next * next + 2.0 * b[i].accel * b[i].len);
        if (b[i].v_max_in > lim)
            b[i].v_max_in = (float)lim;
        next = b[i].v_max_in;
    }
    size_t end = last ? n : k + 1; /* forward pass over [0, end) */
    for (size_t i = 0; i + 1 < end; i++) {
        double lim = sqrt((double)b[i].v_max_in * b[i].v_max_in + 2.0 * b[i].accel * b[i].len);
        if (b[i + 1].v_max_in > lim)
            b[i + 1].v_max_in = (float)lim;
    }
    double t = pl->t;
    for (size_t i = 0; i < k; i++) {
        while (pl->next_layer < pl->n_layers && pl->layer_block[pl->next_layer] <= pl->done + i)
            pl->layer_s[pl->next_layer++] = t;
        double v1 = i + 1 < n ? b[i + 1].v_max_in : fminf(b[i].v_safe, b[i].v_nom);
        double v0 = b[i].v_max_in;
        t += trapezoid_s(b[i].len, v0, fmin(v1, b[i].v_nom), b[i].v_nom, b[i].accel);
    }
    pl->t = t;
    pl->done += k;
    pl->n = n - k;
    memmove(b, b + k, pl->n * sizeof(*b));
}

/* The planner quantities of a move by d (X Y Z E, mm) at f_mm_s; false for a move too short to
   plan. */
static bool
seg_init(struct seg *s, const struct est_limits *lim, const double d[4], double f_mm_s)
{
    double lxyz = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    s->e_only = lxyz < 1e-9;
    s->len = s->e_only ? fabs(d[3]) : lxyz;
    if (s->len < 1e-9)
        return false;
    /* nominal speed: F capped so no axis exceeds its max feed */
    double v = f_mm_s;
    for (int a = 0; a < 4; a++) {
        double c = fabs(d[a]) / s->len * v;
        if (c > lim->max_feed_mm_s[a] && lim->max_feed_mm_s[a] > 0)
            v *= lim->max_feed_mm_s[a] / c;
    }
    double acc = s->e_only ? lim->accel_retract_mm_s2
                           : (d[3] > 0 ? lim->accel_extrude_mm_s2 : lim->accel_travel_mm_s2);
    for (int a = 0; a < 4; a++) {
        s->unit[a] = d[a] / s->len;
        s->vel[a] = s->unit[a] * v;
        /* no axis beyond its own maximum acceleration (Marlin's M201) */
        if (lim->max_accel_mm_s2[a] > 0 && fabs(s->unit[a]) * acc > lim->max_accel_mm_s2[a])
            acc = lim->max_accel_mm_s2[a] / fabs(s->unit[a]);
    }
    /* safe speed: the most this block may start or stop at, from rest */
    double safe = v;
    for (int a = 0; a < 4; a++) {
        double j = fabs(s->vel[a]);
        if (j > lim->jerk_mm_s[a] && j * safe / v > lim->jerk_mm_s[a])
            safe = fmin(safe, lim->jerk_mm_s[a] * v / j);
    }
    s->v = v;
    s->acc = acc;
    s->safe = safe;
    return true;
}

/* The most speed at the junction from prev (NULL: none, the print starts) into s. */
static double
junction_mm_s(const struct est_limits *lim, const struct seg *prev, const struct seg *s)
{
    double v = s->v, vj = s->safe;
    if (!prev)
        return vj;
    if (lim->junction_dev_mm > 0) {
        /* junction deviation: the speed at which a circle of that
           deviation, tangent to both moves, takes acc centripetally */
        double cos_t = 0;
        for (int a = 0; a < 3; a++)
            cos_t -= prev->unit[a] * s->unit[a];
        if (s->e_only)
            cos_t = 0;
        vj = fmin(v, prev->v);
        if (cos_t < 0.999999) {
            if (cos_t <= -0.999999) {
                vj = fmin(vj, 1e9);
            } else {
                double sin_half = sqrt(0.5 * (1 - cos_t));
                double r = lim->junction_dev_mm * sin_half / (1 - sin_half);
                vj = fmin(vj, sqrt(s->acc * r));
            }
        } else {
            vj = fmin(vj, s->safe); /* a full reversal */
        }
    } else {
        /* classic jerk: scale the junction until each axis' change fits */
        vj = fmin(v, prev->v);
        double smaller = vj / prev->v, factor = 1;
        for (int a = 0; a < 4; a++) {
            double v_exit = prev->vel[a] * smaller * factor, v_entry = s->unit[a] * vj * factor;
            double jerk;
            if (v_exit > v_entry)
                jerk = (v_entry > 0 || v_exit < 0) ? v_exit - v_entry : fmax(v_exit, -v_entry);
            else
                jerk = (v_entry < 0 || v_exit > 0) ? v_entry - v_exit : fmax(-v_exit, v_entry);
            if (jerk > lim->jerk_mm_s[a])
                factor *= lim->jerk_mm_s[a] / jerk;
        }
        vj *= factor;
        double th = 0.99 * fmin(v, prev->v);
        if (prev->safe > th && s->safe > th)
            vj = fmax(vj, fmin(s->safe, prev->safe));
    }
    return vj;
}

/* Make s, cruising at v_nom, the previous block of the next junction. */
static void
set_prev(struct plan *pl, const struct seg *s, double v_nom)
{
    pl->prev = *s;
    pl->have_prev = true;
    if (v_nom == s->v)
        return;
    pl->prev.v = v_nom;
    pl->prev.safe = fmin(s->safe, v_nom);
    for (int a = 0; a < 4; a++)
        pl->prev.vel[a] = s->unit[a] * v_nom;
}

/* Append s as a block entered at most at vj, cruising at v_nom (s->v, or less for an arc's
   coarse block), and make it the previous block of the next junction. */
static int
plan_push(struct plan *pl, const struct seg *s, double v_nom, double vj)
{
    if (pl->n == EST_LOOKAHEAD_BLOCKS)
        plan_flush(pl, false);
    if (!mem_grow((void **)&pl->b, &pl->cap, pl->n + 1, sizeof(*pl->b)))
        return SF_ENOMEM;
    struct block *b = &pl->b[pl->n++];
    if (pl->n > pl->peak)
        pl->peak = pl->n;
    pl->n_blocks++;
    double safe = s->safe < v_nom ? s->safe : v_nom; /* not fmin: a call, per block */
    b->len = (float)s->len;
    b->v_nom = (float)v_nom;
    b->accel = (float)s->acc;
    b->v_max_in = (float)(vj < v_nom ? vj : v_nom);
    b->v_safe = (float)safe;
    if (pl->done == 0 && pl->n == 1) /* the print starts from rest */
        b->v_max_in = fminf(b->v_max_in, b->v_safe);
    set_prev(pl, s, v_nom);
    return SF_OK;
}

static int
plan_add(struct plan *pl, const struct est_limits *lim, const double d[4], double f_mm_s)
{
    struct seg s;
    if (!seg_init(&s, lim, d, f_mm_s))
        return SF_OK;
    return plan_push(pl, &s, s.v, junction_mm_s(lim, pl->have_prev ? &pl->prev : NULL, &s));
}

/*
 * An arc (G2 clockwise, G3 counter-clockwise around pos + (i, j)) as
 * Marlin plans it with ARC_SUPPORT: straight segments of at most
 * EST_ARC_SEGMENT_MM along the arc, Z and E shared out evenly.  Start
 * and end at the same point sweep a full turn.  A radius of zero (no
 * centre offset) is a straight move.  An arc of more than
 * EST_ARC_BLOCKS_MAX such segments is planned as that many coarse blocks
 * (plan_arc_coarse), so a file's work is bounded by its size.
 */
#define EST_ARC_SEGMENT_MM 1.0
/* Longer than any printer's bed holds (a full turn around a 1 m bed is
   3.1 m): the file is broken. */
#define EST_ARC_MM_MAX 10000.0
/* Fine junctions sampled per coarse block: how classic jerk's limit turns
   with the direction is averaged over 4 per block (0.05 rad apart on a full
   turn), not 1 (worst error on a set of random arcs at 500 mm/s: 0.5 %
   with 1, 0.3 % with 4). */
#define EST_ARC_SAMPLES 4

/* A chord of an arc, len mm long (negative: clockwise) around the angle mid of its middle,
   with its share dz, de of Z and E. */
static bool
arc_seg(struct seg *s, const struct est_limits *lim, double len, double mid, double dz, double de,
        double f_mm_s)
{
    double d[4] = { -len * sin(mid), len * cos(mid), dz, de };
    return seg_init(s, lim, d, f_mm_s);
}

/*
 * An arc of nf fine segments (more than EST_ARC_BLOCKS_MAX) as
 * EST_ARC_BLOCKS_MAX blocks: its first and last fine segment as they
 * are, and between them coarse blocks, each along its own part of the
 * arc, as long as the fine segments it stands for and taking the time
 * they would.  All fine junctions of an arc are alike (the same turn
 * between segments of the same length), so the firmware either keeps full
 * speed through them or, when their limit vj is below the nominal speed,
 * saws between vj and a peak on every segment, averaging
 * len / trapezoid(len, vj, vj).  A coarse block cruises at that average
 * over EST_ARC_SAMPLES of its fine junctions (classic jerk's limit turns
 * with the direction), and the junctions between coarse blocks take it,
 * so the middle of the arc times as its fine segments would (to within
 * how the average changes from block to block: the planner ramps between
 * blocks where the saw-tooth changes speed within itself).  The first
 * and last coarse block meet a fine junction, vj, and ramp between it and
 * the average v where the saw-tooth would have kept it: each is shortened
 * by the distance the ramp loses, (v - vj)^2 / 2a, which gives it the
 * saw-tooth's time.
 */
static int
plan_arc_coarse(struct plan *pl, const struct est_limits *lim, const double d[4], double r,
                double a0, double sweep, int nf, double f_mm_s)
{
    const int n = EST_ARC_BLOCKS_MAX - 2; /* coarse blocks, for fine segments 2 to nf - 1 */
    double step = sweep / nf, dz = d[2] / nf, de = d[3] / nf;
    double chord = 2 * r * sin(step / 2); /* a fine segment's, negative clockwise */
    double c_step = cos(step), s_step = sin(step);
    double a1 = a0 + step, msweep = sweep - 2 * step; /* the coarse part */
    struct seg fa, fb, c, first, last;
    /* the first and last fine segment, and the fine junctions after and before them */
    double vj_first = 0, vj_last = 0;
    bool have_first = arc_seg(&first, lim, chord, a1 - step / 2, dz, de, f_mm_s);
    bool have_last = arc_seg(&last, lim, chord, a0 + sweep - step / 2, dz, de, f_mm_s);
    if (have_first && arc_seg(&fb, lim, chord, a1 + step / 2, dz, de, f_mm_s))
        vj_first = fmin(junction_mm_s(lim, &first, &fb), fb.v);
    if (have_last && arc_seg(&fb, lim, chord, a0 + sweep - 1.5 * step, dz, de, f_mm_s))
        vj_last = fmin(junction_mm_s(lim, &fb, &last), fb.v);
    int rc;
    if (have_first) {
        double vj = junction_mm_s(lim, pl->have_prev ? &pl->prev : NULL, &first);
        if ((rc = plan_push(pl, &first, first.v, vj)) < 0)
            return rc;
    }
    double v_prev = vj_first, part = (double)(nf - 2) / n;
    for (int k = 1; k <= n; k++) {
        /* along the arc at the block's middle, as long as the fine segments it stands for */
        if (!arc_seg(&c, lim, chord * part, a1 + msweep * (k - 0.5) / n, dz * part, de * part,
                     f_mm_s))
            continue;
        /* fine junctions spread over the block: the average speed through them */
        double v_nom = c.v, len_s = 0, t_s = 0;
        for (int m = 0; m < EST_ARC_SAMPLES; m++) {
            double am = a1 + msweep * (k - 1 + (m + 0.5) / EST_ARC_SAMPLES) / n;
            double sa = sin(am - step / 2), ca = cos(am - step / 2);
            double da[4] = { -chord * sa, chord * ca, dz, de };
            double db[4] = { da[0] * c_step - da[1] * s_step, da[0] * s_step + da[1] * c_step, dz,
                             de }; /* the next one: da turned by a step */
            if (!seg_init(&fa, lim, da, f_mm_s) || !seg_init(&fb, lim, db, f_mm_s))
                continue;
            double vj = junction_mm_s(lim, &fa, &fb);
            if (vj > fb.v)
                vj = fb.v;
            len_s += fb.len;
            t_s += trapezoid_s(fb.len, vj, vj, fb.v, fb.acc);
        }
        if (t_s > 0 && len_s / t_s < v_nom)
            v_nom = len_s / t_s;
        /* the first and last ramp from and to a fine junction, where the
           saw-tooth would have kept its average: the time the ramp loses,
           as the distance this block cruises in it */
        double cut = 0;
        if (k == 1 && vj_first < v_nom)
            cut += (v_nom - vj_first) * (v_nom - vj_first) / (2 * c.acc);
        if (k == n && have_last && vj_last < v_nom)
            cut += (v_nom - vj_last) * (v_nom - vj_last) / (2 * c.acc);
        c.len -= fmin(cut, c.len / 2);
        if ((rc = plan_push(pl, &c, v_nom, k == 1 ? vj_first : fmin(v_prev, v_nom))) < 0)
            return rc;
        v_prev = v_nom;
    }
    if (have_last && (rc = plan_push(pl, &last, last.v, fmin(vj_last, v_prev))) < 0)
        return rc;
    return SF_OK;
}

static int
plan_arc(struct plan *pl, const struct est_limits *lim, const double pos[4], const double d[4],
         double i, double j, bool cw, double f_mm_s, double *len_mm)
{
    double r = hypot(i, j);
    if (r < 1e-9)
        return plan_add(pl, lim, d, f_mm_s);
    double cx = pos[0] + i, cy = pos[1] + j;
    double a0 = atan2(-j, -i), a1 = atan2(pos[1] + d[1] - cy, pos[0] + d[0] - cx);
    double sweep = cw ? a0 - a1 : a1 - a0;
    while (sweep <= 1e-9)
        sweep += 2 * M_PI;
    double len = sweep * r;
    *len_mm = len;
    if (!(len <= EST_ARC_MM_MAX))
        return SF_EINVAL;
    int n = (int)ceil(len / EST_ARC_SEGMENT_MM);
    if (n < 1)
        n = 1;
    if (n > EST_ARC_BLOCKS_MAX)
        return plan_arc_coarse(pl, lim, d, r, a0, cw ? -sweep : sweep, n, f_mm_s);
    double px = pos[0], py = pos[1];
    for (int k = 1; k <= n; k++) {
        double a = a0 + (cw ? -1 : 1) * sweep * k / n;
        double x = k == n ? pos[0] + d[0] : cx + r * cos(a);
        double y = k == n ? pos[1] + d[1] : cy + r * sin(a);
        double s[4] = { x - px, y - py, d[2] / n, d[3] / n };
        int rc = plan_add(pl, lim, s, f_mm_s);
        if (rc < 0)
            return rc;
        px = x;
        py = y;
    }
    return SF_OK;
}

static bool
has_prefix(const char *s, size_t len, const char *p)
{
    size_t n = strlen(p);
    return len >= n && memcmp(s, p, n) == 0;
}

/* Set v from word c of l when it is a sane limit: finite, under 1e6, and
   positive (or, if zero_ok, zero: jerk 0 and J0 mean "none"). */
static void
take(const struct gcode_line *l, char c, double *v, bool zero_ok)
{
    double x;
    if (gcode_get(l, c, &x) && isfinite(x) && x < EST_COORD_MAX && (x > 0 || (zero_ok && x == 0)))
        *v = x;
}

/* Marlin's limit commands: M201 axis accelerations, M203 axis feed rates
   (mm/s), M204 accelerations by kind, M205 jerk and junction deviation. */
static void
firmware_limits(const struct gcode_line *l, struct est_limits *lim)
{
    static const char ax[4] = { 'X', 'Y', 'Z', 'E' };
    switch (l->code) {
    case 201:
        for (int a = 0; a < 4; a++)
            take(l, ax[a], &lim->max_accel_mm_s2[a], false);
        break;
    case 203:
        for (int a = 0; a < 4; a++)
            take(l, ax[a], &lim->max_feed_mm_s[a], false);
        break;
    case 204:
        take(l, 'S', &lim->accel_extrude_mm_s2, false);
        take(l, 'S', &lim->accel_travel_mm_s2, false);
        take(l, 'P', &lim->accel_extrude_mm_s2, false);
        take(l, 'T', &lim->accel_travel_mm_s2, false);
        take(l, 'R', &lim->accel_retract_mm_s2, false);
        break;
    case 205:
        for (int a = 0; a < 4; a++)
            take(l, ax[a], &lim->jerk_mm_s[a], true);
        take(l, 'J', &lim->junction_dev_mm, true);
        break;
    default:
        break;
    }
}

/* The reader's state from one line of estimate_gcode to the next. */
struct reader {
    const char *name;
    struct est_limits cur; /* as changed by the file's M201-M205 */
    struct plan pl;
    size_t cap_layers, cap_layer_s;
    double pos[4], f, dwell;
    bool rel_xyz, rel_e, support;
    const char *type; /* the last ;TYPE: (not NUL-terminated) */
    size_t type_len;
    uint32_t lineno;
    est_move_fn on_move;
    void *ud;
    struct estimate *out;
};

/* A comment line s[0..l): ;LAYER_CHANGE starts a layer, ;TYPE: sets the
   role.  SF_ENOMEM (err set). */
static int
comment_line(struct reader *r, const char *s, size_t l, struct sf_err *err)
{
    struct plan *pl = &r->pl;
    struct estimate *out = r->out;
    if (has_prefix(s, l, ";LAYER_CHANGE")) {
        if (!mem_grow((void **)&pl->layer_block, &r->cap_layers, out->n_layers + 1,
                      sizeof(*pl->layer_block)) ||
            !mem_grow((void **)&pl->layer_s, &r->cap_layer_s, out->n_layers + 1,
                      sizeof(*pl->layer_s)))
            return sf_err_set(err, SF_ENOMEM, "%s: out of memory", r->name);
        pl->layer_block[out->n_layers++] = pl->done + pl->n;
        pl->n_layers = out->n_layers;
    } else if (has_prefix(s, l, ";TYPE:")) {
        r->support = has_prefix(s, l, ";TYPE:Support material");
        r->type = s + 6;
        r->type_len = l - 6;
    }
    return SF_OK;
}

/* A G0-G3 move: planned (arcs in segments), filament counted, the move
   callback called.  SF_EINVAL (out of range, an arc too long), SF_ENOMEM,
   the planner's or the callback's status; err set. */
static int
move_line(struct reader *r, const struct gcode_line *gl, struct sf_err *err)
{
    const char *name = r->name;
    uint32_t lineno = r->lineno;
    struct estimate *out = r->out;
    double *pos = r->pos;
    int rc;
    double v, tgt[4], d[4];
    bool xy = false;
    static const char ax[4] = { 'X', 'Y', 'Z', 'E' };
    for (int a = 0; a < 4; a++) {
        bool rel = a == 3 ? r->rel_e : r->rel_xyz;
        tgt[a] = pos[a];
        if (gcode_get(gl, ax[a], &v) && !isnan(v)) {
            tgt[a] = rel ? pos[a] + v : v;
            if (!isfinite(tgt[a]) || fabs(tgt[a]) > (a == 3 ? EST_E_MAX : EST_COORD_MAX))
                return sf_err_set(err, SF_EINVAL, "%s:%u: %c%g is out of range", name, lineno,
                                  ax[a], v);
            if (a < 2 && tgt[a] != pos[a])
                xy = true;
        }
        d[a] = tgt[a] - pos[a];
    }
    if (gcode_get(gl, 'F', &v) && isfinite(v) && v > 0)
        r->f = fmin(v, EST_COORD_MAX) / 60;
    double f = r->f;
    double ci = 0, cj = 0;
    bool has_i = gcode_get(gl, 'I', &ci) && isfinite(ci) && fabs(ci) < EST_COORD_MAX;
    bool has_j = gcode_get(gl, 'J', &cj) && isfinite(cj) && fabs(cj) < EST_COORD_MAX;
    double arc_mm = 0;
    if (gl->code >= 2 && (has_i || has_j))
        rc = plan_arc(&r->pl, &r->cur, pos, d, has_i ? ci : 0, has_j ? cj : 0, gl->code == 2, f,
                      &arc_mm);
    else
        rc = plan_add(&r->pl, &r->cur, d, f);
    if (rc == SF_EINVAL)
        return sf_err_set(err, rc, "%s:%u: arc of %.0f mm is longer than %.0f m", name, lineno,
                          arc_mm, EST_ARC_MM_MAX / 1000);
    if (rc < 0)
        return sf_err_set(err, rc, "%s:%u: %s", name, lineno,
                          rc == SF_ENOMEM ? "out of memory" : "the planner failed");
    if (xy && d[3] > 0) {
        out->filament_mm += d[3];
        if (r->support)
            out->support_mm += d[3];
    }
    memcpy(pos, tgt, sizeof(r->pos));
    out->n_moves++;
    if (r->on_move) {
        struct est_move mv = {
            pos[0], pos[1],     pos[2],  pos[3],      d[3],
            f,      r->support, r->type, r->type_len, out->n_layers ? out->n_layers - 1 : 0,
            lineno
        };
        if ((rc = r->on_move(r->ud, &mv)) < 0)
            return sf_err_set(err, rc, "%s:%u: stopped by the move callback (%s)", name, lineno,
                              sf_status_name(rc));
    }
    return rc;
}

/* Any other line: modes (G90/G91, M82/M83), G92, M201-M205, G28, G4. */
static void
other_line(struct reader *r, const struct gcode_line *gl)
{
    if (gcode_is(gl, 'G', 90)) {
        r->rel_xyz = false;
    } else if (gcode_is(gl, 'G', 91)) {
        r->rel_xyz = true;
    } else if (gcode_is(gl, 'M', 82)) {
        r->rel_e = false;
    } else if (gcode_is(gl, 'M', 83)) {
        r->rel_e = true;
    } else if (gcode_is(gl, 'G', 92)) {
        static const char ax[4] = { 'X', 'Y', 'Z', 'E' };
        double v;
        for (int a = 0; a < 4; a++)
            if (gcode_get(gl, ax[a], &v) && isfinite(v) &&
                fabs(v) <= (a == 3 ? EST_E_MAX : EST_COORD_MAX))
                r->pos[a] = v;
    } else if (gl->letter == 'M' && gl->code >= 201 && gl->code <= 205) {
        firmware_limits(gl, &r->cur);
    } else if (gcode_is(gl, 'G', 28)) {
        r->pos[0] = r->pos[1] = r->pos[2] = 0;
    } else if (gcode_is(gl, 'G', 4)) {
        double v;
        if (gcode_get(gl, 'S', &v) && isfinite(v) && v > 0)
            r->dwell += fmin(v, EST_COORD_MAX);
        else if (gcode_get(gl, 'P', &v) && isfinite(v) && v > 0)
            r->dwell += fmin(v / 1000, EST_COORD_MAX);
    }
}

int
estimate_gcode(const char *text, size_t len, const char *name, const struct est_limits *lim,
               est_move_fn on_move, void *ud, struct estimate *out, struct sf_err *err)
{
    memset(out, 0, sizeof(*out));
    struct reader r = {
        .name = name, .cur = *lim, .f = 25, .on_move = on_move, .ud = ud, .out = out
    };
    struct plan *pl = &r.pl;
    int rc = SF_OK;
    struct gcode_line gl;
    for (size_t i = 0; i < len;) {
        const char *s = text + i;
        const char *nl = memchr(s, '\n', len - i);
        size_t l = nl ? (size_t)(nl - s) : len - i;
        i += l + 1;
        r.lineno++;
        if (l && s[l - 1] == '\r')
            l--;
        if (l > SF_GCODE_LINE_MAX) {
            rc = sf_err_set(err, SF_EINVAL, "%s:%u: line longer than %d bytes", name, r.lineno,
                            SF_GCODE_LINE_MAX);
            goto fail;
        }
        if (l && s[0] == ';') {
            if ((rc = comment_line(&r, s, l, err)) < 0)
                goto fail;
            continue;
        }
        if ((rc = gcode_parse(s, l, &gl, err)) < 0) {
            /* rc, not sf_err_prefix's SF_EBUG for a NULL err */
            sf_err_prefix(err, "%s:%u", name, r.lineno);
            goto fail;
        }
        if (gl.letter == 'G' && gl.code >= 0 && gl.code <= 3) {
            if ((rc = move_line(&r, &gl, err)) < 0)
                goto fail;
        } else {
            other_line(&r, &gl);
        }
    }
    plan_flush(pl, true);
    out->time_s = pl->t + r.dwell;
    out->peak_blocks = pl->peak;
    out->n_blocks = pl->n_blocks;
    while (pl->next_layer < pl->n_layers)
        pl->layer_s[pl->next_layer++] = pl->t;
    if (!out->n_layers) {
        free(pl->layer_s);
        pl->layer_s = mem_calloc(1, sizeof(double));
        if (!pl->layer_s) {
            rc = sf_err_set(err, SF_ENOMEM, "%s: out of memory", name);
            goto fail;
        }
    }
    out->layer_start_s = pl->layer_s;
    free(pl->b);
    free(pl->layer_block);
    return SF_OK;
fail:
    free(pl->b);
    free(pl->layer_block);
    free(pl->layer_s);
    estimate_release(out);
    if (rc >= 0) /* every path above sets a status: a failure without one is ours */
        rc = sf_err_set(err, SF_EBUG, "%s:%u: estimate failed without a status", name, r.lineno);
    return rc;
}

void
estimate_release(struct estimate *e)
{
    free(e->layer_start_s);
    e->layer_start_s = NULL;
}
