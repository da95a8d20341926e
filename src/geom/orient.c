/*
 * orient.c - orientation search (see orient.h).
 *
 * Pipeline: candidates -> proxy score for all (O(tris) each, cheap) ->
 * the exact_top best by proxy plus every stable hull base and the input ->
 * exact ray-cast metrics on a pool of threads sharing one Embree scene ->
 * a cap of refinement samples around the three best -> pick.
 * Rays are rotated, never the mesh.  Hull bases that are too small or on
 * which the centre of mass falls outside (margin) are rejected; other
 * directions are kept only if the part either rests on a real face or is
 * held by support columns from the bed.
 */
#include "orient.h"

#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "../base/mem.h"
#include "hull.h"

void
orient_params_default(struct orient_params *p)
{
    memset(p, 0, sizeof(*p));
    p->angle_deg = 45;
    p->pitch_mm = 1;
    p->samples = 1000;
    p->exact_top = 48;
    p->w_contact_mm = 1;
    p->w_stability_mm2 = 0.5;
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
    double proxy_cost; /* for pruning */
    bool exact;        /* chosen for the ray cast */
    bool dropped;      /* would stand on a point */
};

struct job {
    const struct mesh *m;
    const struct orient_params *p;
    struct raycast *rc;
    struct support_params sp;
    struct cand *cands;
    uint32_t *todo; /* indices of candidates to score */
    uint32_t n_todo;
    atomic_uint next;
    atomic_uint done;
    atomic_int failed; /* first error code, 0 if none */
    uint32_t progress_base, progress_total;
};

/* Area of faces lying on the bed (within 0.1 mm of the lowest point, facing down). */
static double
bed_contact_area(const struct mesh *m, struct vec3 up)
{
    double lo = INFINITY;
    for (uint32_t i = 0; i < m->n_verts; i++)
        lo = fmin(lo, v3_dot(m->v[i], up));
    double area = 0;
    for (uint32_t i = 0; i < m->n_tris; i++) {
        const uint32_t *t = m->t[i];
        if (v3_dot(m->v[t[0]], up) - lo < 0.1 && v3_dot(m->v[t[1]], up) - lo < 0.1 &&
            v3_dot(m->v[t[2]], up) - lo < 0.1)
            area += mesh_tri_area(m, i);
    }
    return area;
}

static double
cost_of(const struct orient_params *p, const struct support_metrics *s)
{
    return s->volume_mm3 + p->w_contact_mm * s->contact_area_mm2 +
           p->w_stability_mm2 * s->com_height_mm;
}

static void *
worker(void *arg)
{
    struct job *j = arg;
    for (;;) {
        uint32_t k = atomic_fetch_add(&j->next, 1);
        if (k >= j->n_todo || atomic_load(&j->failed))
            break;
        struct cand *c = &j->cands[j->todo[k]];
        struct sf_err err;
        if (measure_support(j->m, j->rc, c->c.up, &j->sp, &c->c.m, &err) != SF_OK) {
            int zero = 0;
            atomic_compare_exchange_strong(&j->failed, &zero, err.code ? err.code : SF_EBUG);
            break;
        }
        c->c.cost = cost_of(j->p, &c->c.m);
        /* Standing on a point with no support column from the bed: it would topple. */
        if (c->c.source != ORIENT_HULL &&
            bed_contact_area(j->m, c->c.up) < j->p->min_base_mm2 && c->c.m.n_columns == 0)
            c->dropped = true;
        /* Growth simulation: the part built so far would tip off its base. */
        if (c->c.m.base_margin_mm < 0)
            c->dropped = true;
        unsigned d = atomic_fetch_add(&j->done, 1) + 1;
        if (j->p->progress)
            j->p->progress(j->p->progress_ud, j->progress_base + d, j->progress_total);
    }
    return NULL;
}

static int
score_exact(struct job *j, uint32_t *todo, uint32_t n, struct sf_err *err)
{
    j->todo = todo;
    j->n_todo = n;
    atomic_store(&j->next, 0);
    atomic_store(&j->done, 0);
    atomic_store(&j->failed, 0);
    int threads = j->p->threads > 0 ? j->p->threads : (int)sysconf(_SC_NPROCESSORS_ONLN);
    if (threads < 1)
        threads = 1;
    if (threads > 64)
        threads = 64;
    pthread_t tid[64];
    int started = 0;
    for (int i = 1; i < threads; i++)
        if (pthread_create(&tid[started], NULL, worker, j) == 0)
            started++;
    worker(j);
    for (int i = 0; i < started; i++)
        pthread_join(tid[i], NULL);
    j->progress_base += n;
    int f = atomic_load(&j->failed);
    if (f)
        return sf_err_set(err, f, "orientation: scoring a direction failed");
    return SF_OK;
}

static int
cmp_proxy(const void *a, const void *b, void *ud)
{
    const struct cand *c = ud;
    double x = c[*(const uint32_t *)a].proxy_cost, y = c[*(const uint32_t *)b].proxy_cost;
    return (x > y) - (x < y);
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

static bool
better(const struct cand *a, const struct cand *b)
{
    if (a->dropped != b->dropped)
        return !a->dropped;
    return a->c.cost < b->c.cost;
}

int
orient_find(const struct mesh *m, const struct orient_params *p, struct orient_result *res,
            struct sf_err *err)
{
    memset(res, 0, sizeof(*res));
    struct timespec t0, t1;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    struct cand *cands = NULL;
    uint32_t n = 0, *todo = NULL;
    size_t cap = 0;
    struct hull_base *bases = NULL;
    uint32_t n_bases = 0;
    struct raycast *rc = NULL;
    int rcode = SF_OK;

    struct vec3 com;
    mesh_volume(m, &com);
    if ((rcode = hull_bases(m, com, &bases, &n_bases, err)))
        return rcode;
    if ((rcode = push(&cands, &n, &cap, v3(0, 0, 1), ORIENT_INPUT)))
        goto oom;
    for (uint32_t i = 0; i < n_bases; i++)
        if (bases[i].area_mm2 >= p->min_base_mm2 && bases[i].margin_mm >= p->min_margin_mm)
            if ((rcode = push(&cands, &n, &cap, v3_scale(bases[i].normal, -1), ORIENT_HULL)))
                goto oom;
    for (int i = 0; i < p->samples; i++)
        if ((rcode = push(&cands, &n, &cap, fibonacci(i, p->samples), ORIENT_SPHERE)))
            goto oom;

    struct job j = { .m = m, .p = p };
    support_params_default(&j.sp);
    j.sp.angle_deg = p->angle_deg;
    j.sp.pitch_mm = p->pitch_mm;
    struct proxy_cache pc;
    if ((rcode = proxy_cache_init(&pc, m, err)))
        goto out;
    for (uint32_t i = 0; i < n; i++) {
        struct support_metrics s;
        measure_proxy_cached(&pc, cands[i].c.up, &j.sp, &s);
        cands[i].proxy_cost = s.proxy_mm3 + p->w_contact_mm * s.risky_area_mm2;
    }
    proxy_cache_release(&pc);
    todo = mem_array(n + 64, sizeof(uint32_t));
    if (!todo)
        goto oom;
    for (uint32_t i = 0; i < n; i++)
        todo[i] = i;
    qsort_r(todo, n, sizeof(uint32_t), cmp_proxy, cands);
    uint32_t n_exact = 0;
    for (uint32_t k = 0; k < n; k++) {
        struct cand *c = &cands[todo[k]];
        if ((int)k < p->exact_top || c->c.source != ORIENT_SPHERE)
            c->exact = true;
    }
    for (uint32_t i = 0; i < n; i++)
        if (cands[i].exact)
            todo[n_exact++] = i;
    if (!(rc = raycast_new(m, err))) {
        rcode = err ? err->code : SF_ENOMEM;
        goto out;
    }
    j.rc = rc;
    j.cands = cands;
    j.progress_total = n_exact + 3 * 24;
    if ((rcode = score_exact(&j, todo, n_exact, err)))
        goto out;

    /* refine around the three best: 24 directions within 8 degrees of each */
    uint32_t best3[3] = { UINT32_MAX, UINT32_MAX, UINT32_MAX };
    for (uint32_t i = 0; i < n; i++) {
        if (!cands[i].exact)
            continue;
        for (int b = 0; b < 3; b++) {
            if (best3[b] == UINT32_MAX || better(&cands[i], &cands[best3[b]])) {
                for (int s = 2; s > b; s--)
                    best3[s] = best3[s - 1];
                best3[b] = i;
                break;
            }
        }
    }
    uint32_t first_refine = n;
    for (int b = 0; b < 3; b++) {
        if (best3[b] == UINT32_MAX)
            continue;
        struct vec3 up = cands[best3[b]].c.up;
        struct mat3 to = m3_rotate_onto(v3(0, 0, 1), up);
        for (int k = 0; k < 24; k++) {
            double ring = (k < 8 ? 3.0 : 8.0) * M_PI / 180, az = 2 * M_PI * (k % 8) / 8 +
                                                              (k >= 16 ? M_PI / 8 : 0);
            if (k >= 16)
                ring = 5.5 * M_PI / 180;
            struct vec3 local = v3(sin(ring) * cos(az), sin(ring) * sin(az), cos(ring));
            if ((rcode = push(&cands, &n, &cap, m3_mul_v(to, local), ORIENT_REFINE)))
                goto oom;
        }
    }
    uint32_t *t2 = mem_realloc_array(todo, n, sizeof(uint32_t));
    if (!t2)
        goto oom;
    todo = t2;
    uint32_t n_ref = 0;
    for (uint32_t i = first_refine; i < n; i++) {
        cands[i].exact = true;
        todo[n_ref++] = i;
    }
    j.cands = cands; /* push may have moved the array */
    if ((rcode = score_exact(&j, todo, n_ref, err)))
        goto out;

    /* pick */
    uint32_t best = 0;
    for (uint32_t i = 1; i < n; i++)
        if (cands[i].exact && better(&cands[i], &cands[best]))
            best = i;
    res->best = cands[best].c;
    res->input = cands[0].c;
    res->n_candidates = n;
    res->n_exact = n_exact + n_ref;
    /* runners-up: the cheapest others, each 10+ degrees from the best and each other */
    uint32_t n_ok = 0;
    for (uint32_t i = 0; i < n; i++)
        if (cands[i].exact && !cands[i].dropped && i != best)
            todo[n_ok++] = i;
    for (uint32_t i = 0; i < n_ok; i++)
        cands[todo[i]].proxy_cost = cands[todo[i]].c.cost; /* sort key */
    qsort_r(todo, n_ok, sizeof(uint32_t), cmp_proxy, cands);
    double min_cos = cos(10 * M_PI / 180);
    for (uint32_t k = 0; k < n_ok && res->n_runners < 4; k++) {
        const struct orient_candidate *c = &cands[todo[k]].c;
        bool distinct = v3_dot(c->up, res->best.up) < min_cos;
        for (int r = 0; r < res->n_runners && distinct; r++)
            distinct = v3_dot(c->up, res->runners[r].up) < min_cos;
        if (distinct)
            res->runners[res->n_runners++] = *c;
    }
    clock_gettime(CLOCK_MONOTONIC, &t1);
    res->seconds = (t1.tv_sec - t0.tv_sec) + (t1.tv_nsec - t0.tv_nsec) * 1e-9;
    goto out;
oom:
    rcode = sf_err_set(err, SF_ENOMEM, "orientation: out of memory");
out:
    raycast_free(rc);
    free(todo);
    free(cands);
    free(bases);
    return rcode;
}

void
orient_apply(struct mesh *m, struct vec3 up, double cx, double cy)
{
    mesh_rotate_up(m, up);
    mesh_place_on_bed(m, cx, cy);
}
