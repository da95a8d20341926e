/*
 * printtime.c - print-time estimate and the value rule (see printtime.h).
 */
#include "printtime.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"
#include "printtime_loops.h"

void
printtime_params_default(struct printtime_params *p)
{
    *p = (struct printtime_params){ .layer_mm = 0.2,
                                    .line_width_mm = 0.45,
                                    .perimeters = 2,
                                    .ext_perimeter_mm_s = 30,
                                    .perimeter_mm_s = 60,
                                    .top_layers = 4,
                                    .bottom_layers = 3,
                                    .solid_mm_s = 20,
                                    .infill_density = 0.15,
                                    .infill_mm_s = 80,
                                    .layer_change_s = 0.3,
                                    .min_layer_s = 5,
                                    .small_perimeter_mm_s = 15,
                                    .bridge_mm_s = 60,
                                    .bridge_line_mm = 0.4,
                                    .small_loop_mm = 2 * M_PI * 6.5,
                                    .solid_below_mm2 = 70,
                                    .solid_full_deg = 45,
                                    .solid_none_deg = 60,
                                    .solid_factor = 0.5,
                                    .support_factor = 1.3 };
}

void
printtime_policy_default(struct printtime_policy *p)
{
    *p = (struct printtime_policy){
        .gram_s = 60, .min_gain = 0.02, .min_gain_g = 0.05, .min_gain_time = 0.05
    };
}

int
printtime_policy_check(const struct printtime_policy *p, struct sf_err *err)
{
    if (!(p->gram_s >= 0 && p->gram_s <= 1e6))
        return sf_err_set(err, SF_EINVAL, "gram-seconds %g: want seconds in [0, 1000000]",
                          p->gram_s);
    if (!(p->min_gain >= 0 && p->min_gain < 1))
        return sf_err_set(err, SF_EINVAL, "min-gain %g: want a share in [0, 1)", p->min_gain);
    if (!(p->min_gain_g >= 0 && p->min_gain_g <= 1000))
        return sf_err_set(err, SF_EINVAL, "min_gain_g %g: want grams in [0, 1000]", p->min_gain_g);
    if (!(p->min_gain_time >= 0 && p->min_gain_time < 1))
        return sf_err_set(err, SF_EINVAL, "min_gain_time %g: want a share in [0, 1)",
                          p->min_gain_time);
    return SF_OK;
}

double
printtime_value_s(const struct printtime_policy *p, const struct printtime_cost *c)
{
    return c->print_s + p->gram_s * c->support_g;
}

bool
printtime_worth(const struct printtime_policy *p, const struct printtime_cost *in,
                const struct printtime_cost *out)
{
    if (!(out->support_g <= in->support_g))
        return false; /* never more support than the input */
    if (!p->material_first && out->print_s > in->print_s)
        return false; /* never slower, unless asked */
    double saved_g = in->support_g - out->support_g, saved_s = in->print_s - out->print_s;
    return saved_g >= p->min_gain * in->support_g + p->min_gain_g ||
           saved_s >= p->min_gain_time * in->print_s;
}

double
printtime_total_s(const struct printtime_params *p, const struct printtime_result *r,
                  double support_s)
{
    return r->part_s + p->support_factor * support_s;
}

static int
check_params(const struct printtime_params *p, struct sf_err *err)
{
    if (!(p->layer_mm >= 0.01 && p->layer_mm <= 2) ||
        !(p->line_width_mm >= 0.05 && p->line_width_mm <= 5))
        return sf_err_set(err, SF_EINVAL,
                          "print time: layer_mm and line_width_mm must be in [0.01, 2] and "
                          "[0.05, 5]");
    if (p->perimeters < 0 || p->perimeters > 100 || p->top_layers < 0 || p->top_layers > 1000 ||
        p->bottom_layers < 0 || p->bottom_layers > 1000)
        return sf_err_set(err, SF_EINVAL,
                          "print time: perimeters, top_layers, bottom_layers out of range");
    if (!(p->ext_perimeter_mm_s > 0) || !(p->perimeter_mm_s > 0) || !(p->solid_mm_s > 0) ||
        !(p->infill_mm_s > 0) || !(p->small_perimeter_mm_s > 0) || !(p->bridge_mm_s > 0) ||
        !(p->bridge_line_mm > 0))
        return sf_err_set(err, SF_EINVAL,
                          "print time: every speed and the bridge line width must be positive");
    if (!(p->infill_density >= 0 && p->infill_density <= 1) || !(p->layer_change_s >= 0) ||
        !(p->min_layer_s >= 0) || !(p->support_factor >= 0 && p->support_factor <= 100) ||
        !(p->solid_factor >= 0 && p->solid_factor <= 100) ||
        !(p->small_loop_mm >= 0 && p->small_loop_mm <= 1e4) ||
        !(p->solid_below_mm2 >= 0 && p->solid_below_mm2 <= 1e6) ||
        !(p->solid_full_deg >= 0 && p->solid_full_deg <= p->solid_none_deg &&
          p->solid_none_deg <= 90))
        return sf_err_set(err, SF_EINVAL,
                          "print time: infill_density in [0, 1], layer_change_s and "
                          "min_layer_s not negative, support_factor and solid_factor in "
                          "[0, 100], small_loop_mm in [0, 10000], solid_below_mm2 in [0, 1e6], "
                          "0 <= solid_full_deg <= solid_none_deg <= 90");
    return SF_OK;
}

/* Add amount to the layers [a, b) (heights in layers, 0 <= a <= b <= n), in
   proportion to each layer's overlap; a face inside one layer adds it there. */
static void
spread(double *acc, uint32_t n, double a, double b, double amount)
{
    if (!(amount != 0))
        return;
    if (b - a < 1e-9) {
        uint32_t l = a < n ? (uint32_t)a : n - 1;
        acc[l] += amount;
        return;
    }
    uint32_t l0 = (uint32_t)a, l1 = (uint32_t)ceil(b);
    if (l1 > n)
        l1 = n;
    double per = amount / (b - a);
    for (uint32_t l = l0; l < l1; l++) {
        double lo = a > l ? a : l, hi = b < l + 1 ? b : l + 1;
        if (hi > lo)
            acc[l] += per * (hi - lo);
    }
}

/* Per-layer sums of one part: outline length, seconds of solid fill, and
   n_z dA (the section's area, summed from the top down); from its loops
   (printtime_loops.h), the small loops' length and the small islands'
   infill area. */
struct layers {
    double *outline_mm, *solid_s, *dsec_mm2, *small_mm, *small_fill_mm2;
};
#define LAYER_SUMS 5

/*
 * The share of a face's shadow that PrusaSlicer backs with its solid shell,
 * at slope deg from the horizontal: all of it up to solid_full_deg, none
 * past solid_none_deg, linear between.  A rule that took the perimeters'
 * width off the shell across the face (share 1 - pw tan a / t: nothing
 * past 42 degrees, a quarter at 34) called a 40 x 40 x 10 mm slab tilted
 * 30 degrees 5 % faster than flat where PrusaSlicer 2.5 prints it 50 %
 * slower, its solid infill 1.5 times the flat slab's (1119 against 742 +
 * 173 mm of bridge); tilted 45 degrees 0.82 times, 60 and 75 degrees
 * 0.26 and 0.24 (the slab's flatter sides).  Turned 34 degrees, scad
 * example012's lettered top lost 70 % of its solid here where PrusaSlicer's
 * grew 3 %: the search handed back a turn it printed 7 % slower.
 */
static double
solid_share(const struct printtime_params *p, double deg)
{
    if (deg <= p->solid_full_deg)
        return 1;
    if (deg >= p->solid_none_deg)
        return 0;
    return (p->solid_none_deg - deg) / (p->solid_none_deg - p->solid_full_deg);
}

/* A face spanning less than this many layers is flat. */
#define FLAT_LAYERS 1e-6

/*
 * The last layer whose cut holds the solid under a flat face at z mm over
 * the part's lowest point (-1: none).  PrusaSlicer cuts layer k at its
 * middle, (k + 0.5) h, taken as a float as the STL's coordinates are, and
 * a face lying on that plane counts as the solid below it: a top face at z
 * is the top of that layer, a bottom face the bottom of the next.  A 1.3 mm
 * floor (6.5 layers) is 7 layers on the bed (its top 1.3000011 over the
 * plane's 1.2999999) and 6 as a roof from 23.9 (on the plane) to 25.2 (mech
 * box_upside: turned over, PrusaSlicer printed one solid layer more and no
 * bridge, 3.4 % slower, where a shell of 1.3 mm either way said 4.7 %
 * faster).
 */
static int64_t
flat_layer(double z, double h)
{
    z = (double)(float)z; /* as an STL holds it */
    int64_t k = (int64_t)floor(z / h - 0.5);
    while ((double)(float)((k + 1.5) * h) <= z)
        k++;
    while (k >= 0 && (double)(float)((k + 0.5) * h) > z)
        k--;
    return k < -1 ? -1 : k;
}

static void
add_faces(const struct mesh *m, struct vec3 up, double zmin, uint32_t n,
          const struct printtime_params *p, struct layers *L)
{
    double h = p->layer_mm;
    for (uint32_t i = 0; i < m->n_tris; i++) {
        const uint32_t *t = m->t[i];
        double z[3], z_mm[3];
        for (int k = 0; k < 3; k++)
            z[k] = (z_mm[k] = v3_dot(m->v[t[k]], up) - zmin) / h;
        double a = fmin(z[0], fmin(z[1], z[2])), b = fmax(z[0], fmax(z[1], z[2]));
        struct vec3 c = mesh_tri_cross(m, i);
        double area = 0.5 * v3_len(c);
        if (!(area > 0))
            continue;
        double nz = v3_dot(c, up) / (2 * area), s = sqrt(fmax(0, 1 - nz * nz));
        /* a flat face is cut where the slicer cuts it, at the layers'
           middles (flat_layer) */
        bool flat = b - a < FLAT_LAYERS;
        int64_t kf = flat ? flat_layer(fmin(z_mm[0], fmin(z_mm[1], z_mm[2])), h) : 0;
        spread(L->outline_mm, n, a, b, area * s / h);
        if (!flat)
            spread(L->dsec_mm2, n, a, b, area * nz);
        else if (kf >= 0) /* the sections it bounds: the layers up to kf */
            L->dsec_mm2[kf < n ? kf : n - 1] += area * nz;
        /* solid backing: the shell's thickness under (over) the face's
           shadow, in full up to solid_full_deg from the horizontal, none
           past solid_none_deg (solid_share) */
        double an = fabs(nz);
        double th = (nz > 0 ? p->top_layers : p->bottom_layers) * h;
        if (an < 1e-6 || th <= 0)
            continue;
        double share = solid_share(p, atan2(s, an) * (180 / M_PI));
        if (share <= 0)
            continue;
        double vol = area * an * th * share;
        double secs = vol / (p->line_width_mm * h * p->solid_mm_s);
        /* a bottom over air starts with a bridge layer: lines of the
           nozzle's width at bridge_mm_s (mech box_upside's floor as a roof:
           PrusaSlicer bridges it at 60 mm/s, on the bed it is solid at 20) */
        if (nz < 0 && a >= 1 && p->bottom_layers > 0)
            secs *=
                1 - (1 - p->line_width_mm * p->solid_mm_s / (p->bridge_line_mm * p->bridge_mm_s)) /
                        p->bottom_layers;
        /* under a top, over a bottom: a flat face's shell in whole layers
           from the first layer its cut holds (its top layer, or its
           bottom's), the others' spread along the face */
        double nl = th / h;
        if (flat) {
            double k0 = nz > 0 ? (double)kf + 1 - nl : (double)kf + 1;
            if (nz > 0 ? kf >= 0 : kf + 1 < (int64_t)n)
                spread(L->solid_s, n, fmax(0, k0), fmin(k0 + nl, n), secs);
        } else if (nz > 0)
            spread(L->solid_s, n, fmax(0, a - nl), b, secs);
        else
            spread(L->solid_s, n, a, fmin(b + nl, n), secs);
    }
}

int
printtime_eval(const struct mesh *m, struct vec3 up, const struct printtime_params *p,
               struct printtime_result *out, struct sf_err *err)
{
    memset(out, 0, sizeof(*out));
    int rc = check_params(p, err);
    if (rc)
        return rc;
    if (m->n_verts == 0)
        return SF_OK;
    double zmin = INFINITY, zmax = -INFINITY;
    for (uint32_t i = 0; i < m->n_verts; i++) {
        double z = v3_dot(m->v[i], up);
        zmin = fmin(zmin, z);
        zmax = fmax(zmax, z);
    }
    double layers = ceil((zmax - zmin) / p->layer_mm - 1e-9);
    if (!(layers <= PRINTTIME_LAYERS_MAX))
        return sf_err_set(err, SF_EINVAL, "print time: part %.1f mm tall is over %u layers",
                          zmax - zmin, PRINTTIME_LAYERS_MAX);
    uint32_t n = layers < 1 ? 1 : (uint32_t)layers;
    double *buf = mem_array((size_t)LAYER_SUMS * n, sizeof(double));
    if (!buf)
        return sf_err_set(err, SF_ENOMEM, "print time: out of memory for %u layers", n);
    memset(buf, 0, (size_t)LAYER_SUMS * n * sizeof(double));
    struct layers L = { buf, buf + n, buf + 2 * n, buf + 3 * n, buf + 4 * n };
    add_faces(m, up, zmin, n, p, &L);
    struct printtime_loops_params lp = { .layer_mm = p->layer_mm,
                                         .small_loop_mm = p->small_loop_mm,
                                         .perimeter_mm = p->perimeters * p->line_width_mm,
                                         .solid_below_mm2 = p->solid_below_mm2 };
    if ((rc = printtime_loops_eval(m, up, zmin, n, &lp, L.small_mm, L.small_fill_mm2, err)) < 0) {
        free(buf);
        return rc;
    }
    double per_mm =
        p->perimeters > 0 ? 1 / p->ext_perimeter_mm_s + (p->perimeters - 1) / p->perimeter_mm_s : 0;
    /* a small loop's perimeters all print at small_perimeter_mm_s */
    double small_per_mm = fmax(0, p->perimeters / p->small_perimeter_mm_s - per_mm);
    double pw = p->perimeters * p->line_width_mm, section = 0;
    for (uint32_t k = n; k-- > 0;) {
        section += L.dsec_mm2[k];
        /* sparse where neither perimeters nor solid layers fill the section,
           nor a small island's infill, which is solid; the solid layers
           fill at most what the perimeters leave (a thin slab's top and
           bottom shells overlap: once) */
        double free_mm2 = fmax(0, section - L.outline_mm[k] * pw);
        double solid_mm2 = fmin(L.solid_s[k] * p->line_width_mm * p->solid_mm_s, free_mm2);
        double inner = free_mm2 - solid_mm2;
        double small_mm2 = fmin(inner, L.small_fill_mm2[k]);
        inner -= small_mm2;
        double per_s = L.outline_mm[k] * per_mm + L.small_mm[k] * small_per_mm;
        double fill_s = inner * p->infill_density / p->line_width_mm / p->infill_mm_s;
        double solid_s =
            (solid_mm2 + small_mm2) / (p->line_width_mm * p->solid_mm_s) * p->solid_factor;
        double work = per_s + fill_s + solid_s;
        out->perimeter_s += per_s;
        out->infill_s += fill_s;
        out->solid_s += solid_s;
        double layer = fmax(work + p->layer_change_s, p->min_layer_s);
        out->layers_s += layer - work;
        out->part_s += layer;
    }
    out->n_layers = n;
    free(buf);
    return SF_OK;
}
