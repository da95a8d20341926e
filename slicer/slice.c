/*
 * slice.c - the slicer pipeline and the G-code file (see slice.h).
 *
 * Stages run one after the other on plain arrays; the per-layer stages
 * (cutting, toolpaths) spread the layers over par_for (src/base/par.h),
 * each layer into its own slot, so the G-code is the same on any number
 * of threads.  The body is written to memory first so the estimator can
 * read it back (the same interpreter the tests use), then the file is
 * assembled: header with the estimates, start G-code, the body with an
 * M73 line at each layer change, end G-code, and PrusaSlicer-style
 * footer lines that shared/peers' script and G-code viewers read.
 *
 * Thread: see slice.h.
 */
#include "slice.h"

#include <math.h>
#include <stdatomic.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "../src/base/buf.h"
#include "../src/base/clock.h"
#include "../src/base/mem.h"
#include "../src/base/par.h"
#include "estimate.h"
#include "gcwrite.h"
#include "layers.h"
#include "support.h"
#include "toolpath.h"

/* Biggest G-code we build in memory: ~20M lines. */
#define GCODE_BODY_MAX ((size_t)1 << 30)

void
slice_limits(const struct slice_profile *p, struct est_limits *lim)
{
    memset(lim, 0, sizeof(*lim));
    lim->max_feed_mm_s[0] = lim->max_feed_mm_s[1] = p->max_feed_xy_mm_s;
    lim->max_feed_mm_s[2] = p->max_feed_z_mm_s;
    lim->max_feed_mm_s[3] = p->max_feed_e_mm_s;
    lim->accel_extrude_mm_s2 = p->accel_extrude_mm_s2;
    lim->accel_travel_mm_s2 = p->accel_travel_mm_s2;
    lim->accel_retract_mm_s2 = p->accel_retract_mm_s2;
    lim->max_accel_mm_s2[0] = lim->max_accel_mm_s2[1] = p->max_accel_xy_mm_s2;
    lim->max_accel_mm_s2[2] = p->max_accel_z_mm_s2;
    lim->max_accel_mm_s2[3] = p->max_accel_e_mm_s2;
    lim->jerk_mm_s[0] = lim->jerk_mm_s[1] = p->jerk_xy_mm_s;
    lim->jerk_mm_s[2] = p->jerk_z_mm_s;
    lim->jerk_mm_s[3] = p->jerk_e_mm_s;
    lim->junction_dev_mm = p->junction_dev_mm;
}

int
slice_expand(const struct slice_profile *p, const char *what, const char *t, struct buf *out,
             struct sf_err *err)
{
    struct {
        const char *name;
        double v;
    } nums[] = {
        { "bed_temp", p->bed_c },
        { "nozzle_temp", p->nozzle_c },
        { "first_layer_bed_temp", p->first_layer_bed_c },
        { "first_layer_nozzle_temp", p->first_layer_nozzle_c },
        { "bed_x", p->bed_x_mm },
        { "bed_y", p->bed_y_mm },
        { "max_z", p->max_z_mm },
        { "layer_height", p->layer_mm },
        { "first_layer_height", p->first_layer_mm },
        { "filament_diameter", p->filament_mm },
        { "nozzle_diameter", p->nozzle_mm },
    };
    for (const char *s = t; s && *s;) {
        const char *o = strchr(s, '{');
        if (!o) {
            if (buf_append(out, s, strlen(s)) < 0)
                return sf_err_set(err, SF_ENOMEM, "%s: out of memory", what);
            break;
        }
        if (buf_append(out, s, (size_t)(o - s)) < 0)
            return sf_err_set(err, SF_ENOMEM, "%s: out of memory", what);
        const char *c = strchr(o, '}');
        if (!c)
            return sf_err_set(err, SF_EINVAL, "%s: '{' without '}'", what);
        size_t n = (size_t)(c - o - 1);
        bool found = false;
        for (size_t i = 0; i < sizeof(nums) / sizeof(nums[0]) && !found; i++) {
            if (strlen(nums[i].name) == n && memcmp(nums[i].name, o + 1, n) == 0) {
                buf_printf(out, "%g", nums[i].v);
                found = true;
            }
        }
        if (!found && n == 7 && memcmp(o + 1, "printer", 7) == 0)
            found = buf_printf(out, "%s", p->printer_name) == SF_OK;
        if (!found && n == 8 && memcmp(o + 1, "material", 8) == 0)
            found = buf_printf(out, "%s", p->material_name) == SF_OK;
        if (!found)
            return sf_err_set(err, SF_EINVAL, "%s: unknown placeholder '{%.*s}'", what, (int)n,
                              o + 1);
        s = c + 1;
    }
    if (out->len && out->data[out->len - 1] != '\n' && buf_append(out, "\n", 1) < 0)
        return sf_err_set(err, SF_ENOMEM, "%s: out of memory", what);
    return SF_OK;
}

/* The printed columns (support_columns), moved onto the bed. */
static int
ray_columns(const struct mesh *m, const struct slice_profile *p, const struct layer_stack *s,
            struct support_grid *g, struct support_column **cols, size_t *n, size_t *cap,
            struct slice_result *res, struct sf_err *err)
{
    size_t n_body = 0;
    int st = support_columns(m, p, g, cols, n, cap, &n_body, err);
    if (st == SF_OK) {
        g->x0 += s->dx;
        g->y0 += s->dy;
        double vol = 0;
        for (size_t i = 0; i < n_body; i++)
            vol += (double)((*cols)[i].hi - (*cols)[i].lo) * g->pitch * g->pitch;
        res->ray_volume_mm3 = vol;
        res->n_columns = (uint32_t)n_body;
    }
    return st;
}

struct tp_job {
    struct layer_stack *s;
    int phase; /* 0: inner areas, 1: solid/top/sparse regions, 2: toolpaths */
    const struct slice_profile *p;
    const struct support_layer *sup;
    struct layer_paths *lp;
    slice_progress_fn progress; /* phase 1: asked on the calling thread between layers */
    void *ud;
    atomic_uint done; /* layers finished in this phase */
};

static void
fmt_hms(char *out, size_t cap, double s)
{
    long t = lround(s);
    if (t >= 3600)
        snprintf(out, cap, "%ldh %ldm %lds", t / 3600, t / 60 % 60, t % 60);
    else
        snprintf(out, cap, "%ldm %lds", t / 60, t % 60);
}

/* Header, start G-code, body with M73, end G-code, footer. */
static int
write_file(const char *path, const struct slice_profile *p, const struct buf *body,
           const struct estimate *est, const struct slice_result *r, struct sf_err *err)
{
    struct buf start, end;
    buf_init(&start, 0);
    buf_init(&end, 0);
    int rc = slice_expand(p, "start_gcode", p->start_gcode, &start, err);
    if (rc == SF_OK)
        rc = slice_expand(p, "end_gcode", p->end_gcode, &end, err);
    FILE *f = NULL;
    if (rc == SF_OK && !(f = fopen(path, "w")))
        rc = sf_err_sys(err, "gcode '%s'", path);
    if (rc < 0)
        goto out;
    char hms[64];
    fmt_hms(hms, sizeof(hms), r->time_s);
    fprintf(f, "; generated by slimfarm slicer\n");
    fprintf(f, "; printer = %s\n; material = %s\n", p->printer_name, p->material_name);
    fprintf(f, "; estimated printing time (normal mode) = %s\n", hms);
    fprintf(f, "; estimated printing time [s] = %.0f\n", r->time_s);
    fprintf(f, "; filament used [mm] = %.2f\n; filament used [g] = %.2f\n", r->filament_mm,
            r->filament_g);
    fprintf(f, "; support material used [mm] = %.2f\n; support material used [g] = %.2f\n",
            r->support_mm, r->support_g);
    fprintf(f, "; total layers = %u\n; support columns = %u + %u under islands\n", r->n_layers,
            r->n_columns, r->n_island_columns);
    fprintf(f, "M73 P0 R%ld\n", lround(r->time_s / 60));
    fwrite(start.data ? start.data : "", 1, start.len, f);
    /* body, with M73 before each layer */
    uint32_t layer = 0;
    const char *s = body->data ? body->data : "", *e = s + body->len;
    while (s < e) {
        const char *nl = memchr(s, '\n', (size_t)(e - s));
        size_t l = nl ? (size_t)(nl - s) + 1 : (size_t)(e - s);
        if (l >= 13 && memcmp(s, ";LAYER_CHANGE", 13) == 0 && layer < est->n_layers) {
            double t = est->layer_start_s[layer++];
            double tot = est->time_s > 0 ? est->time_s : 1;
            fprintf(f, "M73 P%ld R%ld\n", lround(100 * t / tot), lround((tot - t) / 60));
        }
        fwrite(s, 1, l, f);
        s += l;
    }
    fprintf(f, "M73 P100 R0\n");
    fwrite(end.data ? end.data : "", 1, end.len, f);
    fprintf(f, "; filament used [mm] = %.2f\n", r->filament_mm);
    fprintf(f, "; filament used [g] = %.2f\n", r->filament_g);
    fprintf(f, "; estimated printing time (normal mode) = %s\n", hms);
    slice_profile_dump(p, f);
    if (ferror(f) | (fclose(f) != 0)) {
        rc = sf_err_sys(err, "gcode '%s': write failed", path);
        unlink(path);
    }
out:
    buf_release(&start);
    buf_release(&end);
    return rc;
}

/* Report progress; true when the caller asks to cancel. */
static bool
cancelled(slice_progress_fn fn, void *ud, const char *stage, double done)
{
    return fn && fn(ud, stage, done) != 0;
}

#define STAGE(name)                                                                                \
    do {                                                                                           \
        if (cancelled(progress, ud, name, 0)) {                                                    \
            rc = sf_err_set(err, SF_ECANCELED, "slice: cancelled before %s", name);                \
            goto out;                                                                              \
        }                                                                                          \
    } while (0)

/* par_for body: phase j->phase of layers [begin, end), each into its own slot. */
static int
tp_layers(void *ud, uint32_t begin, uint32_t end, int worker)
{
    struct tp_job *j = ud;
    for (uint32_t k = begin; k < end; k++) {
        /* the calling thread (worker 0) reports between the layers it builds,
           and a cancel stops either phase there (issue 16: a cancelled job's
           worker must stop) */
        if (worker == 0 && cancelled(j->progress, j->ud, "toolpaths",
                                     (j->phase + (double)atomic_load(&j->done) / j->s->n) / 3))
            return SF_ECANCELED;
        int rc = j->phase == 2
                     ? toolpath_layer(j->s, k, j->p, j->sup ? &j->sup[k] : NULL, &j->lp[k])
                 : j->phase ? toolpath_store_regions(j->s, k, j->p)
                            : toolpath_areas(j->s, k, j->p);
        if (rc < 0)
            return rc;
        atomic_fetch_add(&j->done, 1);
    }
    return SF_OK;
}

/* The part's height into res->height_mm; SF_EINVAL when it has no
   triangles or does not fit the printer. */
static int
check_fit(const struct mesh *m, const struct slice_profile *p, struct slice_result *res,
          struct sf_err *err)
{
    if (!m->n_tris)
        return sf_err_set(err, SF_EINVAL, "slice: the part has no triangles");
    struct vec3 lo = m->v[m->t[0][0]], hi = lo;
    for (uint32_t i = 0; i < m->n_tris; i++)
        for (int c = 0; c < 3; c++) {
            lo = v3_min(lo, m->v[m->t[i][c]]);
            hi = v3_max(hi, m->v[m->t[i][c]]);
        }
    if (hi.x - lo.x > p->bed_x_mm || hi.y - lo.y > p->bed_y_mm || hi.z - lo.z > p->max_z_mm)
        return sf_err_set(err, SF_EINVAL,
                          "slice: the part (%.1f x %.1f x %.1f mm) does not fit printer '%s' "
                          "(%.0f x %.0f x %.0f mm)",
                          hi.x - lo.x, hi.y - lo.y, hi.z - lo.z, p->printer_name, p->bed_x_mm,
                          p->bed_y_mm, p->max_z_mm);
    res->height_mm = hi.z - lo.z;
    return SF_OK;
}

/* The support regions of every layer into *sup (s->n of them, freed with
   support_layer_release each and free; NULL on an error), from the ray
   grid's columns and the islands'; *cols (free) holds the columns. */
static int
supports(const struct mesh *m, const struct slice_profile *p, const struct layer_stack *s,
         struct support_layer **sup, struct support_column **cols, struct slice_result *res,
         struct sf_err *err)
{
    size_t n_cols = 0, cap_cols = 0;
    struct support_grid g;
    int rc = ray_columns(m, p, s, &g, cols, &n_cols, &cap_cols, res, err);
    size_t n_ray = n_cols;
    if (rc == SF_OK && (rc = support_islands(s, &g, cols, &n_cols, &cap_cols)) < 0)
        sf_err_set(err, rc, "support islands: %s",
                   rc == SF_ENOMEM ? "out of memory" : "clipping failed");
    res->n_island_columns = (uint32_t)(n_cols - n_ray);
    if (rc == SF_OK && !(*sup = mem_calloc(s->n, sizeof(**sup))))
        rc = sf_err_set(err, SF_ENOMEM, "support: out of memory");
    if (rc == SF_OK)
        rc = support_layers(s, &g, *cols, n_cols, p, *sup, err);
    if (rc < 0) {
        free(*sup);
        *sup = NULL;
        return rc;
    }
    res->support_volume_mm3 = support_volume(s, *sup);
    return rc;
}

/* Every layer's paths into lp (the three phases on the par_for threads),
   then the skirt and brim (res->brim_mm). */
static int
toolpaths(struct layer_stack *s, const struct slice_profile *p, const struct support_layer *sup,
          struct layer_paths *lp, slice_progress_fn progress, void *ud, struct slice_result *res,
          struct sf_err *err)
{
    struct tp_job j = { .s = s, .p = p, .sup = sup, .lp = lp, .progress = progress, .ud = ud };
    int rc = SF_OK;
    for (j.phase = 0; j.phase < 3 && rc == SF_OK; j.phase++) {
        atomic_init(&j.done, 0);
        rc = par_for(s->n, 1, 0, tp_layers, &j);
    }
    /* the stage's last report, also when other threads built the last layers */
    if (rc == SF_OK && cancelled(progress, ud, "toolpaths", 1))
        rc = SF_ECANCELED;
    if (rc < 0)
        return sf_err_set(err, rc, "toolpaths: %s",
                          rc == SF_ECANCELED ? "cancelled"
                          : rc == SF_ENOMEM  ? "out of memory"
                                             : "clipping failed");

    res->brim_mm = tp_brim_width(s, p, res->height_mm);
    for (uint32_t k = 0; k < s->n && rc == SF_OK && (k == 0 || (int)k < p->skirt_height); k++)
        if ((rc = toolpath_skirt_brim(s, k, p, sup, res->brim_mm, &lp[k])) < 0)
            sf_err_set(err, rc, "skirt and brim: %s",
                       rc == SF_ENOMEM ? "out of memory" : "clipping failed");
    return rc;
}

/* The estimate of the G-code body into est (estimate_release) and the
   filament and time figures into res. */
static int
estimate_body(const struct slice_profile *p, const struct buf *body, struct estimate *est,
              struct slice_result *res, struct sf_err *err)
{
    struct est_limits lim;
    slice_limits(p, &lim);
    int rc = estimate_gcode(body->data ? body->data : "", body->len, "gcode body", &lim, NULL, NULL,
                            est, err);
    if (rc < 0)
        return rc;
    double g_per_mm = M_PI * p->filament_mm * p->filament_mm / 4 * p->density_g_cm3 / 1000;
    res->filament_mm = est->filament_mm;
    res->filament_g = est->filament_mm * g_per_mm;
    res->support_mm = est->support_mm;
    res->support_g = est->support_mm * g_per_mm;
    res->time_s = est->time_s;
    return rc;
}

int
slice_mesh(const struct mesh *m, const struct slice_profile *p, const char *gcode_path,
           struct slice_result *res, slice_progress_fn progress, void *ud, struct sf_err *err)
{
    double t0 = clock_mono_s();
    struct slice_result dummy;
    if (!res)
        res = &dummy;
    memset(res, 0, sizeof(*res));
    int rc = slice_profile_check(p, err);
    if (rc < 0 || (rc = check_fit(m, p, res, err)) < 0)
        return rc;

    struct layer_stack s;
    struct support_layer *sup = NULL;
    struct layer_paths *lp = NULL;
    struct support_column *cols = NULL;
    struct buf body;
    struct estimate est;
    memset(&est, 0, sizeof(est));
    buf_init(&body, GCODE_BODY_MAX);

    if (cancelled(progress, ud, "layers", 0))
        return sf_err_set(err, SF_ECANCELED, "slice: cancelled before layers");
    rc = layers_slice(m, p->first_layer_mm, p->layer_mm, p->bed_x_mm / 2, p->bed_y_mm / 2, &s, err);
    if (rc < 0)
        return rc;
    res->n_layers = s.n;
    res->n_open_loops = s.n_open;

    if (p->support) {
        STAGE("supports");
        if ((rc = supports(m, p, &s, &sup, &cols, res, err)) < 0)
            goto out;
    }

    STAGE("toolpaths");
    lp = mem_calloc(s.n, sizeof(*lp));
    if (!lp) {
        rc = sf_err_set(err, SF_ENOMEM, "toolpaths: out of memory");
        goto out;
    }
    if ((rc = toolpaths(&s, p, sup, lp, progress, ud, res, err)) < 0)
        goto out;

    STAGE("gcode");
    struct gcw_stats st;
    rc = gcw_body(&s, lp, p, &body, &st, NULL, NULL, err);
    gcw_stats_release(&st);
    if (rc < 0)
        goto out;
    STAGE("estimate");
    if ((rc = estimate_body(p, &body, &est, res, err)) < 0)
        goto out;
    STAGE("write");
    rc = write_file(gcode_path, p, &body, &est, res, err);
    if (rc == SF_OK)
        (void)cancelled(progress, ud, "done", 1);
out:
    res->wall_s = clock_mono_s() - t0;
    estimate_release(&est);
    buf_release(&body);
    for (uint32_t k = 0; k < s.n; k++) {
        if (lp)
            layer_paths_release(&lp[k]);
        if (sup)
            support_layer_release(&sup[k]);
    }
    free(lp);
    free(sup);
    free(cols);
    layer_stack_release(&s);
    return rc;
}
