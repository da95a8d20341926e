/*
 * orient.c - orientation search (see orient.h).
 *
 * Pipeline: candidates -> proxy score for all (O(tris) each, cheap) ->
 * the exact_top best by proxy, the exact_hull best stable hull bases by
 * proxy and the input ->
 * exact ray-cast metrics on par_for's threads (base/par.h) sharing one
 * Embree scene, built while the proxy stage runs ->
 * a cap of refinement samples around the two best -> pick.
 * Rays are rotated, never the mesh.  Hull bases that are too small or on
 * which the centre of mass falls outside (margin) are rejected; other
 * directions are kept only if the part either rests on a real face or is
 * held by support columns from the bed.
 */
#include "orient.h"

#include <math.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../base/mem.h"
#include "../base/par.h"
#include "hull.h"
#include "supmodel.h"

void
orient_params_default(struct orient_params *p)
{
    memset(p, 0, sizeof(*p));
    p->angle_deg = 45;
    p->margin_deg = 5;
    p->pitch_mm = 1;
    p->samples = 1000;
    p->exact_top = 24;
    p->exact_hull = 12;
    p->w_contact_mm = 1;
    p->w_stability_mm2 = 0.5;
    p->min_gain = 0.05;
    p->max_open_rays = 0.01;
    p->min_base_mm2 = 25;
    p->min_margin_mm = 1;
}

const char *
orient_source_name(enum orient_source s)
{
    static const char *names[] = { "input", "hull base", "sphere sample", "refinement" };
    return (unsigned)s < 4 ? names[s] : "?";
}

struct cand {
    struct orient_candidate c;
    double key;                /* sort key of the current stage */
    int stage;                 /* 0: proxy only, 1: coarse ray cast, 2: full ray cast */
    struct support_metrics at; /* stage 2: the metrics at the operator's angle */
    double model_g;            /* stage 2: the layer-based model's support grams */
    bool dropped;              /* would stand on a point or tip over */
};

/* A batch of candidates scored by par_for (one stage). */
struct job {
    const struct mesh *m;
    const struct orient_params *p;
    const struct proxy_cache *pc; /* proxy stage */
    struct raycast *rc;           /* ray-cast stages */
    struct support_params sp;     /* scoring: the angle less the margin */
    struct support_params at;     /* reporting: the operator's angle */
    struct supmodel_params mp;    /* finalists: the layer-based model (PrusaSlicer's rules) */
    struct cand *cands;
    const uint32_t *batch; /* indices of candidates to score */
    int stage;
    atomic_uint done; /* progress across stages */
    uint32_t progress_total;
};

static double
cost_of(const struct orient_params *p, const struct support_metrics *s)
{
    return s->volume_mm3 + p->w_contact_mm * s->contact_area_mm2 +
           p->w_stability_mm2 * s->com_height_mm;
}

static int
score_one(struct job *j, struct cand *c, struct sf_err *err)
{
    if (j->stage == 0) {
        struct support_metrics s;
        proxy_eval(j->pc, c->c.up, &j->sp, &s);
        c->key = s.proxy_mm3 + j->p->w_contact_mm * s.risky_area_mm2;
        return SF_OK;
    }
    int rc;
    if (j->stage == 1) {
        struct support_params sp = j->sp;
        sp.pitch_mm *= 2; /* coarse: a quarter of the rays, for ranking */
        rc = measure_support_cached(j->m, j->rc, j->pc, c->c.up, &sp, &c->c.m, err);
    } else {
        /* finalists: the report's figures come from the same cast */
        struct support_params sp[2] = { j->sp, j->at };
        struct support_metrics out[2];
        rc = measure_support_angles(j->m, j->rc, j->pc, c->c.up, sp, 2, out, err);
        c->c.m = out[0];
        c->at = out[1];
        struct supmodel_result mr;
        if (rc == SF_OK && (rc = supmodel_eval(j->rc, c->c.up, &j->mp, &mr, err)) == SF_OK)
            c->model_g = mr.grams;
    }
    if (rc)
        return rc;
    c->c.cost = c->key = cost_of(j->p, &c->c.m);
    if (j->stage == 2) {
        /* finalists are ranked by the model's grams, the ray-cast cost breaking ties
           (it adds at most a milligram) */
        c->c.support_g = c->model_g;
        c->key = c->model_g + 1e-9 * c->c.cost;
    }
    c->stage = j->stage;
    c->dropped = false;
    /* Standing on a point with no support column from the bed: it would topple. */
    if (c->c.source != ORIENT_HULL && c->c.m.n_columns == 0 &&
        proxy_bed_contact(j->pc, c->c.up) < j->p->min_base_mm2)
        c->dropped = true;
    /* Growth simulation: the part built so far would tip off its base. */
    if (c->c.m.base_margin_mm < 0)
        c->dropped = true;
    return SF_OK;
}

/* par_for body: score batch[begin..end), each into its own candidate. */
static int
score_chunk(void *ud, uint32_t begin, uint32_t end, int worker)
{
    struct job *j = ud;
    (void)worker;
    for (uint32_t k = begin; k < end; k++) {
        if (j->p->cancel && atomic_load(j->p->cancel))
            return SF_ECANCELED;
        struct sf_err err;
        sf_err_clear(&err);
        if (score_one(j, &j->cands[j->batch[k]], &err) != SF_OK)
            return err.code ? err.code : SF_EBUG;
        if (j->stage > 0) {
            unsigned d = atomic_fetch_add(&j->done, 1) + 1;
            if (j->p->progress)
                j->p->progress(j->p->progress_ud, d, j->progress_total);
        }
    }
    return SF_OK;
}

static int
run_stage(struct job *j, int stage, const uint32_t *batch, uint32_t n, struct sf_err *err)
{
    j->stage = stage;
    j->batch = batch;
    int f = par_for(n, 1, j->p->threads, score_chunk, j);
    if (f == SF_ECANCELED)
        return sf_err_set(err, f, "orientation: cancelled");
    if (f)
        return sf_err_set(err, f, "orientation: scoring a direction failed");
    return SF_OK;
}

/* Order: not dropped before dropped, then by key. */
static int
cmp_key(const void *a, const void *b, void *ud)
{
    const struct cand *c = ud, *x = &c[*(const uint32_t *)a], *y = &c[*(const uint32_t *)b];
    if (x->dropped != y->dropped)
        return x->dropped ? 1 : -1;
    return (x->key > y->key) - (x->key < y->key);
}

static int
push(struct cand **cands, uint32_t *n, size_t *cap, struct vec3 up, enum orient_source src)
{
    void *p = *cands;
    if (!mem_grow(&p, cap, *n + 1, sizeof(struct cand)))
        return SF_ENOMEM;
    *cands = p;
    struct cand *c = &(*cands)[(*n)++];
    memset(c, 0, sizeof(*c));
    c->c.up = v3_normalize(up);
    c->c.source = src;
    return SF_OK;
}

/* Fibonacci sphere: n near-uniform unit vectors. */
static struct vec3
fibonacci(int i, int n)
{
    double golden = M_PI * (3 - sqrt(5));
    double z = 1 - (i + 0.5) * 2.0 / n;
    double r = sqrt(fmax(0, 1 - z * z));
    return v3(r * cos(golden * i), r * sin(golden * i), z);
}

static double
elapsed(const struct timespec *a)
{
    struct timespec b;
    clock_gettime(CLOCK_MONOTONIC, &b);
    return (b.tv_sec - a->tv_sec) + (b.tv_nsec - a->tv_nsec) * 1e-9;
}

/*
 * Pick up to max indices from sorted order[] whose directions are at least
 * min_deg apart (and from the ones in keep[0..n_keep)); returns the count.
 */
static uint32_t
pick_distinct(const struct cand *c, const uint32_t *order, uint32_t n, uint32_t max, double min_deg,
              uint32_t *out)
{
    double min_cos = cos(min_deg * M_PI / 180);
    uint32_t k = 0;
    for (uint32_t i = 0; i < n && k < max; i++) {
        bool distinct = true;
        for (uint32_t q = 0; q < k && distinct; q++)
            distinct = v3_dot(c[order[i]].c.up, c[out[q]].c.up) < min_cos;
        if (distinct)
            out[k++] = order[i];
    }
    return k;
}

/*
 * refinement: REFINE_PER samples (two rings, 3 and 7 degrees out) around each of the
 * REFINE_SEEDS best distinct directions; the FINAL best distinct directions and the input
 * are cast again at the full pitch, which fills the report's 4 runners-up.  (6 finalists
 * cost 37 % of anchor's instructions; on the 12 shared meshes the pick was always among
 * the coarse stage's 3 best, so 4 cut that share with no pick changed; the
 * support model now ranks the finalists, and it reorders the ray cast's best, so
 * 8 are cast and weighed by it)
 */
enum { REFINE_SEEDS = 2, REFINE_PER = 8, FINAL = 8 };

/*
 * The search's opening, two tasks of one par_for: the candidates, the proxy
 * cache and the proxy stage (task 0, its stage a loop nested in it), and
 * the Embree scene (task 1), which needs none of them.  With two threads
 * one builds the scene while the other scores proxies, and the first done
 * helps with the other's loop.  Task 0 fills orient_find's variables
 * through the pointers.
 */
struct opening {
    const struct mesh *m;
    const struct orient_params *p;
    struct orient_result *res;
    const struct timespec *t0;
    struct job *j;
    struct cand **cands;
    uint32_t *n, **order;
    size_t *cap;
    struct hull_base **bases;
    uint32_t *n_bases, **hull_verts, *n_hull_verts;
    struct proxy_cache *pc;
    struct raycast *rc;   /* task 1's scene */
    struct sf_err err[2]; /* each task's error */
};

static int
open_candidates(struct opening *o, struct sf_err *err)
{
    const struct orient_params *p = o->p;
    struct vec3 com;
    mesh_volume(o->m, &com);
    int rcode = hull_bases(o->m, com, o->bases, o->n_bases, o->hull_verts, o->n_hull_verts, err);
    if (rcode)
        return rcode;
    struct hull_base *bases = *o->bases;
    if (push(o->cands, o->n, o->cap, v3(0, 0, 1), ORIENT_INPUT))
        goto oom;
    for (uint32_t i = 0; i < *o->n_bases; i++)
        if (bases[i].area_mm2 >= p->min_base_mm2 && bases[i].margin_mm >= p->min_margin_mm)
            if (push(o->cands, o->n, o->cap, v3_scale(bases[i].normal, -1), ORIENT_HULL))
                goto oom;
    for (int i = 0; i < p->samples; i++)
        if (push(o->cands, o->n, o->cap, fibonacci(i, p->samples), ORIENT_SPHERE))
            goto oom;
    uint32_t n = *o->n;
    /* room for the refinement samples, so cands never moves under the workers */
    void *grow = *o->cands;
    if (!mem_grow(&grow, o->cap, n + REFINE_SEEDS * REFINE_PER, sizeof(struct cand)))
        goto oom;
    *o->cands = grow;
    uint32_t *order = *o->order = mem_array(n + REFINE_SEEDS * REFINE_PER, sizeof(uint32_t));
    if (!order)
        goto oom;
    if ((rcode = proxy_cache_init(o->pc, o->m, *o->hull_verts, *o->n_hull_verts, err)))
        return rcode;
    o->res->seconds_setup = elapsed(o->t0);

    /* stage 0: proxy for every direction */
    o->j->cands = *o->cands;
    for (uint32_t i = 0; i < n; i++)
        order[i] = i;
    if ((rcode = run_stage(o->j, 0, order, n, err)))
        return rcode;
    o->res->seconds_proxy = elapsed(o->t0) - o->res->seconds_setup;
    qsort_r(order, n, sizeof(uint32_t), cmp_key, *o->cands);
    return SF_OK;
oom:
    return sf_err_set(err, SF_ENOMEM, "orientation: out of memory");
}

/* par_for body: the opening's tasks. */
static int
open_task(void *ud, uint32_t begin, uint32_t end, int worker)
{
    struct opening *o = ud;
    (void)worker;
    for (uint32_t i = begin; i < end; i++) {
        int rc;
        if (i == 0) {
            rc = open_candidates(o, &o->err[0]);
        } else {
            o->rc = raycast_new(o->m, &o->err[1]);
            rc = o->rc ? SF_OK : o->err[1].code ? o->err[1].code : SF_ENOMEM;
        }
        if (rc)
            return rc;
    }
    return SF_OK;
}

/* Two rings of REFINE_PER / 2 directions around each seed, pushed onto cands
   (room reserved) and appended to order after n_coarse; returns the new count. */
static uint32_t
push_refine(struct cand **cands, uint32_t *n, size_t *cap, uint32_t *order, uint32_t n_coarse,
            const uint32_t *seeds, uint32_t n_seeds)
{
    for (uint32_t b = 0; b < n_seeds; b++) {
        struct mat3 to = m3_rotate_onto(v3(0, 0, 1), (*cands)[seeds[b]].c.up);
        for (int k = 0; k < REFINE_PER; k++) {
            const int h = REFINE_PER / 2; /* per ring, the outer one turned half a step */
            double ring = (k < h ? 3.0 : 7.0) * M_PI / 180;
            double az = 2 * M_PI * (k % h) / h + (k < h ? 0 : M_PI / h);
            struct vec3 local = v3(sin(ring) * cos(az), sin(ring) * sin(az), cos(ring));
            push(cands, n, cap, m3_mul_v(to, local), ORIENT_REFINE); /* room reserved */
            order[n_coarse++] = *n - 1;
        }
    }
    return n_coarse;
}

/* The answer from the final stage's directions (sorted, final[0] the best):
   the best, the input and the runners-up. */
static void
fill_result(const struct cand *cands, uint32_t n, uint32_t n_coarse, const uint32_t *final,
            uint32_t n_final, const struct orient_params *p, struct orient_result *res)
{
    uint32_t best = final[0];
    /* Not worth turning the part unless the model's grams fall by min_gain; where
       neither needs support (under a hundredth of a gram) the ray-cast cost, whose
       centre-of-mass term prefers the lower pose, decides as it did before */
    bool none = cands[0].model_g < 0.01 && cands[best].model_g < 0.01;
    if (!cands[0].dropped && (none ? cands[best].c.cost > (1 - p->min_gain) * cands[0].c.cost
                                   : !(cands[best].model_g < (1 - p->min_gain) * cands[0].model_g)))
        best = 0;
    const struct support_metrics *in = &cands[0].c.m;
    if (in->n_rays && in->n_rays_open > p->max_open_rays * in->n_rays) {
        best = 0; /* rays cannot tell inside from outside: no figure to trust */
        res->not_solid = true;
    }
    res->best = cands[best].c;
    res->best.m = cands[best].at;
    res->input = cands[0].c;
    res->input.m = cands[0].at;
    res->n_candidates = n;
    res->n_exact = n_coarse + n_final;
    for (uint32_t i = 0; i < n_final && res->n_runners < 4; i++) {
        if (final[i] == best || cands[final[i]].dropped)
            continue;
        struct orient_candidate *r = &res->runners[res->n_runners++];
        *r = cands[final[i]].c;
        r->m = cands[final[i]].at;
    }
}

int
orient_find(const struct mesh *m, const struct orient_params *p, struct orient_result *res,
            struct sf_err *err)
{
    memset(res, 0, sizeof(*res));
    struct timespec t0;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    struct cand *cands = NULL;
    uint32_t n = 0, *order = NULL;
    size_t cap = 0;
    struct hull_base *bases = NULL;
    uint32_t n_bases = 0;
    struct raycast *rc = NULL;
    struct proxy_cache pc = { 0 };
    uint32_t *hull_verts = NULL, n_hull_verts = 0;
    int rcode = SF_OK;

    struct job j = { .m = m, .p = p, .pc = &pc };
    atomic_init(&j.done, 0);
    support_params_default(&j.sp);
    j.sp.angle_deg = fmax(0, p->angle_deg - p->margin_deg);
    j.sp.pitch_mm = p->pitch_mm;
    /* report at the operator's angle: the margin only steers the choice */
    j.at = j.sp;
    j.at.angle_deg = p->angle_deg;
    supmodel_params_steer(&j.mp, p->angle_deg);

    struct opening o = { .m = m,
                         .p = p,
                         .res = res,
                         .t0 = &t0,
                         .j = &j,
                         .cands = &cands,
                         .n = &n,
                         .order = &order,
                         .cap = &cap,
                         .bases = &bases,
                         .n_bases = &n_bases,
                         .hull_verts = &hull_verts,
                         .n_hull_verts = &n_hull_verts,
                         .pc = &pc };
    sf_err_clear(&o.err[0]);
    sf_err_clear(&o.err[1]);
    rcode = par_for(2, 1, p->threads, open_task, &o);
    rc = o.rc;
    if (rcode) {
        if (err) /* the lowest failing task's error, as par_for's code */
            *err = o.err[0].code ? o.err[0] : o.err[1];
        goto out;
    }
    if ((rcode = raycast_set_extreme(rc, hull_verts, n_hull_verts, err)))
        goto out;
    j.rc = rc;

    /* stage 1: coarse ray cast of the proxy's best sphere samples and hull bases, and the input */
    uint32_t n_coarse = 0;
    int n_hull = 0;
    for (uint32_t k = 0; k < n; k++) {
        enum orient_source src = cands[order[k]].c.source;
        bool keep = src == ORIENT_INPUT || (src == ORIENT_SPHERE && (int)k < p->exact_top) ||
                    (src == ORIENT_HULL && n_hull++ < p->exact_hull);
        if (keep)
            order[n_coarse++] = order[k];
    }
    j.progress_total = n_coarse + REFINE_SEEDS * REFINE_PER + FINAL + 1;
    if ((rcode = run_stage(&j, 1, order, n_coarse, err)))
        goto out;
    qsort_r(order, n_coarse, sizeof(uint32_t), cmp_key, cands);

    /* refine around the best distinct directions, still coarse */
    uint32_t seeds[REFINE_SEEDS],
        n_seeds = pick_distinct(cands, order, n_coarse, REFINE_SEEDS, 10, seeds);
    n_coarse = push_refine(&cands, &n, &cap, order, n_coarse, seeds, n_seeds);
    if ((rcode =
             run_stage(&j, 1, order + n_coarse - n_seeds * REFINE_PER, n_seeds * REFINE_PER, err)))
        goto out;
    qsort_r(order, n_coarse, sizeof(uint32_t), cmp_key, cands);

    /* stage 2: the best few distinct directions and the input at the full pitch */
    uint32_t final[FINAL + 1];
    uint32_t n_final = pick_distinct(cands, order, n_coarse, FINAL, 3, final);
    bool has_input = false;
    for (uint32_t i = 0; i < n_final; i++)
        has_input |= final[i] == 0;
    if (!has_input)
        final[n_final++] = 0;
    if ((rcode = run_stage(&j, 2, final, n_final, err)))
        goto out;
    qsort_r(final, n_final, sizeof(uint32_t), cmp_key, cands);

    fill_result(cands, n, n_coarse, final, n_final, p, res);
    res->seconds = elapsed(&t0);
    res->seconds_exact = res->seconds - res->seconds_setup - res->seconds_proxy;
out:
    raycast_free(rc);
    proxy_cache_release(&pc);
    free(order);
    free(cands);
    free(bases);
    free(hull_verts);
    return rcode;
}

void
orient_apply(struct mesh *m, struct vec3 up, double cx, double cy)
{
    mesh_rotate_up(m, up);
    mesh_place_on_bed(m, cx, cy);
}
