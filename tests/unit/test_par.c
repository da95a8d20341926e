/*
 * test_par.c - the compute runtime: every index runs once whatever the
 * budget, the lowest failing chunk's code comes out, nested and concurrent
 * loops never have more threads busy than their budget, the budget comes
 * from par_set_threads / par_share / SLIMFARM_THREADS; and the stages that
 * run on it (orientation, slimming's direction search, the slicer) give
 * bit-identical results with one thread and with several.
 */
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../../slicer/slice.h"
#include "../../src/base/buf.h"
#include "../../src/base/log.h"
#include "../../src/base/par.h"
#include "../../src/geom/orient.h"
#include "../../src/geom/slim.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"

/* What one loop saw. */
struct rec {
    uint32_t n;
    int *hits;             /* per index: times its body ran */
    int *worker;           /* per index: the worker slot that ran it */
    int fail_at[2];        /* indices that fail (-1: none) */
    int fail_rc[2];        /* and their codes */
    atomic_int busy;       /* bodies running now */
    atomic_int max_busy;   /* most at once */
    pthread_t caller;      /* the thread that called par_for */
    atomic_int off_caller; /* bodies run on another thread */
};

static void
enter(struct rec *r)
{
    int b = atomic_fetch_add(&r->busy, 1) + 1;
    int m = atomic_load(&r->max_busy);
    while (b > m && !atomic_compare_exchange_weak(&r->max_busy, &m, b))
        ;
    if (!pthread_equal(pthread_self(), r->caller))
        atomic_fetch_add(&r->off_caller, 1);
}

static int
body(void *ud, uint32_t begin, uint32_t end, int worker)
{
    struct rec *r = ud;
    enter(r);
    int rc = 0;
    for (uint32_t i = begin; i < end && !rc; i++) {
        r->hits[i]++;
        r->worker[i] = worker;
        for (int f = 0; f < 2; f++)
            if ((int)i == r->fail_at[f])
                rc = r->fail_rc[f];
    }
    atomic_fetch_sub(&r->busy, 1);
    return rc;
}

static void
rec_init(struct rec *r, uint32_t n)
{
    memset(r, 0, sizeof(*r));
    r->n = n;
    r->hits = calloc(n ? n : 1, sizeof(int));
    r->worker = calloc(n ? n : 1, sizeof(int));
    r->fail_at[0] = r->fail_at[1] = -1;
    r->caller = pthread_self();
}

static void
rec_release(struct rec *r)
{
    free(r->hits);
    free(r->worker);
}

T_CASE(every_index_runs_once_on_any_budget)
{
    static const uint32_t sizes[][2] = { { 0, 1 },    { 1, 1 },      { 2, 1 }, { 1000, 1 },
                                         { 1000, 7 }, { 999, 1000 }, { 64, 0 } };
    int budgets[] = { 1, 2, 5 };
    for (int b = 0; b < 3; b++) {
        par_set_threads(budgets[b], 1);
        T_EQ_INT(par_threads(), budgets[b]);
        for (size_t s = 0; s < sizeof(sizes) / sizeof(sizes[0]); s++) {
            struct rec r;
            rec_init(&r, sizes[s][0]);
            int rc = par_for(sizes[s][0], sizes[s][1], 0, body, &r);
            for (uint32_t i = 0; i < r.n; i++) {
                T_EQ_INT(r.hits[i], 1);
                T_TRUE(r.worker[i] >= 0 && r.worker[i] < budgets[b]);
            }
            T_EQ_INT(rc, 0);
            T_TRUE(atomic_load(&r.max_busy) <= budgets[b]);
            rec_release(&r);
        }
    }
    par_set_threads(0, 1);
}

/* Two failing indices: the lower one's code comes out, and every index
   below it ran, on one thread or five, however the chunks fell. */
T_CASE(lowest_failing_chunk_wins)
{
    int budgets[] = { 1, 2, 5 };
    for (int b = 0; b < 3; b++) {
        par_set_threads(budgets[b], 1);
        for (int round = 0; round < 20; round++) {
            struct rec r;
            rec_init(&r, 1000);
            r.fail_at[0] = 700;
            r.fail_rc[0] = SF_EIO;
            r.fail_at[1] = 300;
            r.fail_rc[1] = SF_EINVAL;
            int rc = par_for(r.n, round % 2 ? 3 : 1, 0, body, &r);
            T_EQ_INT(rc, SF_EINVAL);
            for (int i = 0; i <= 300; i++)
                T_EQ_INT(r.hits[i], 1);
            for (uint32_t i = 301; i < r.n; i++)
                T_TRUE(r.hits[i] <= 1);
            rec_release(&r);
        }
    }
    par_set_threads(0, 1);
}

/*
 * The lower failure is recorded first and the higher one after it: the
 * lower one's code still comes out (a runtime keeping the last failure
 * would answer SF_EIO here).  The bodies wait for each other, at most 10 s
 * each, only to make that order likely; the answer may not depend on it.
 */
struct order {
    atomic_bool high_entered, low_leaving;
};

static void
wait_for(atomic_bool *flag)
{
    for (int i = 0; i < 10000 && !atomic_load(flag); i++) {
        struct timespec ts = { 0, 1000000 };
        nanosleep(&ts, NULL);
    }
}

static int
order_body(void *ud, uint32_t begin, uint32_t end, int worker)
{
    struct order *o = ud;
    (void)worker;
    for (uint32_t i = begin; i < end; i++) {
        if (i == 1) {
            wait_for(&o->high_entered);
            atomic_store(&o->low_leaving, true);
            return SF_EINVAL;
        }
        if (i == 3) {
            atomic_store(&o->high_entered, true);
            wait_for(&o->low_leaving);
            struct timespec ts = { 0, 20000000 };
            nanosleep(&ts, NULL);
            return SF_EIO;
        }
    }
    return 0;
}

T_CASE(lowest_failure_wins_when_recorded_first)
{
    par_set_threads(4, 1);
    struct order o;
    atomic_init(&o.high_entered, false);
    atomic_init(&o.low_leaving, false);
    T_EQ_INT(par_for(4, 1, 0, order_body, &o), SF_EINVAL);
    par_set_threads(0, 1);
}

/* An outer loop whose bodies run inner loops: all share the root's budget. */
struct nest {
    struct rec outer;
    struct rec inner[6];
    atomic_int *group_busy; /* bodies of the whole call running now */
    atomic_int group_max;
};

static int
inner_body(void *ud, uint32_t begin, uint32_t end, int worker)
{
    struct nest *ns = ud;
    (void)worker;
    int b = atomic_fetch_add(ns->group_busy, 1) + 1;
    int m = atomic_load(&ns->group_max);
    while (b > m && !atomic_compare_exchange_weak(&ns->group_max, &m, b))
        ;
    volatile unsigned spin = 0; /* long enough for other threads to overlap it */
    while (spin < 20000)
        spin++;
    for (uint32_t i = begin; i < end; i++) {
        uint32_t o = i / 50, k = i % 50;
        ns->inner[o].hits[k]++;
        ns->inner[o].worker[k] = worker;
    }
    atomic_fetch_sub(ns->group_busy, 1);
    return 0;
}

/* inner loop o: its 50 indices, as a range of one shared index space */
struct inner_arg {
    struct nest *ns;
    uint32_t o;
};

static int
inner_range(void *ud, uint32_t begin, uint32_t end, int worker)
{
    struct inner_arg *a = ud;
    return inner_body(a->ns, a->o * 50 + begin, a->o * 50 + end, worker);
}

static int
outer_body(void *ud, uint32_t begin, uint32_t end, int worker)
{
    struct nest *ns = ud;
    for (uint32_t o = begin; o < end; o++) {
        ns->outer.hits[o]++;
        ns->outer.worker[o] = worker;
        struct inner_arg a = { ns, o };
        int rc = par_for(50, 1, 0, inner_range, &a);
        if (rc)
            return rc;
    }
    return 0;
}

/* One nested run; returns the number of things wrong (0). */
static int
run_nest(int budget)
{
    int bad = 0;
    struct nest ns;
    atomic_int busy = 0;
    memset(&ns, 0, sizeof(ns));
    ns.group_busy = &busy;
    rec_init(&ns.outer, 6);
    for (int o = 0; o < 6; o++)
        rec_init(&ns.inner[o], 50);
    bad += par_for(6, 1, 0, outer_body, &ns) != 0;
    for (int o = 0; o < 6; o++) {
        bad += ns.outer.hits[o] != 1;
        for (int k = 0; k < 50; k++)
            bad += ns.inner[o].hits[k] != 1 || ns.inner[o].worker[k] < 0 ||
                   ns.inner[o].worker[k] >= budget;
    }
    bad += atomic_load(&ns.group_max) > budget;
    rec_release(&ns.outer);
    for (int o = 0; o < 6; o++)
        rec_release(&ns.inner[o]);
    return bad;
}

T_CASE(nested_loops_share_the_budget)
{
    par_set_threads(3, 1);
    for (int round = 0; round < 10; round++)
        T_EQ_INT(run_nest(3), 0);
    par_set_threads(0, 1);
}

/* max_threads = 1: the whole call, nested loops too, stays on the caller. */
T_CASE(one_thread_stays_on_the_caller)
{
    par_set_threads(4, 1);
    struct rec r;
    rec_init(&r, 200);
    T_EQ_INT(par_for(r.n, 1, 1, body, &r), 0);
    T_EQ_INT(atomic_load(&r.off_caller), 0);
    T_EQ_INT(atomic_load(&r.max_busy), 1);
    rec_release(&r);
    par_set_threads(0, 1);
}

/* Three callers at once, as the daemon's prepare workers, with helpers
   for all: each call is complete and never has more than its budget of
   threads busy, its nested loops included. */
static void *
root_caller(void *arg)
{
    int *bad = arg;
    for (int round = 0; round < 30; round++) {
        struct rec r;
        rec_init(&r, 300);
        int rc = par_for(r.n, 2, 0, body, &r);
        for (uint32_t i = 0; i < r.n; i++)
            *bad += r.hits[i] != 1;
        *bad += rc != 0 || atomic_load(&r.max_busy) > 2;
        rec_release(&r);
        *bad += run_nest(2);
    }
    return NULL;
}

T_CASE(concurrent_callers_each_get_their_budget)
{
    par_set_threads(2, 3);
    pthread_t th[3];
    int bad[3] = { 0, 0, 0 };
    for (int i = 0; i < 3; i++)
        T_EQ_INT(pthread_create(&th[i], NULL, root_caller, &bad[i]), 0);
    for (int i = 0; i < 3; i++)
        pthread_join(th[i], NULL);
    T_EQ_INT(bad[0] + bad[1] + bad[2], 0);
    par_set_threads(0, 1);
}

T_CASE(share_divides_the_cores)
{
    int cores = par_cores();
    T_TRUE(cores >= 1 && cores <= PAR_THREADS_MAX);
    par_share(1);
    T_EQ_INT(par_threads(), cores);
    par_share(2);
    T_EQ_INT(par_threads(), cores / 2 > 1 ? cores / 2 : 1);
    par_share(cores * 2);
    T_EQ_INT(par_threads(), 1);
    struct rec r;
    rec_init(&r, 100);
    T_EQ_INT(par_for(r.n, 1, 0, body, &r), 0);
    T_EQ_INT(atomic_load(&r.off_caller), 0);
    rec_release(&r);
    par_set_threads(0, 1);
    T_EQ_INT(par_threads(), cores);
}

static char warned[512];

static void
sink(void *ud, enum log_level level, const char *subsys, const char *printer, const char *msg)
{
    (void)ud;
    (void)printer;
    if (level == LOG_WARN)
        snprintf(warned, sizeof(warned), "%s: %s", subsys, msg);
}

T_CASE(slimfarm_threads_sets_the_default_budget)
{
    int cores = par_cores();
    setenv("SLIMFARM_THREADS", "3", 1);
    par_set_threads(0, 1);
    T_EQ_INT(par_threads(), 3);
    static const char *bad[] = { "0", "65", "3x", "-2", "lots" };
    log_set_sink(sink, NULL);
    for (int i = 0; i < 5; i++) {
        warned[0] = '\0';
        setenv("SLIMFARM_THREADS", bad[i], 1);
        par_set_threads(0, 1);
        T_EQ_INT(par_threads(), cores);
        T_TRUE(strstr(warned, "SLIMFARM_THREADS") != NULL);
        T_TRUE(strstr(warned, bad[i]) != NULL);
    }
    log_set_sink(NULL, NULL);
    unsetenv("SLIMFARM_THREADS");
    par_set_threads(0, 1);
    T_EQ_INT(par_threads(), cores);
}

/* --- the stages on the runtime: one thread and several agree to the bit --- */

static int
orient_with(int budget, const struct mesh *m, struct orient_result *r, struct sf_err *err)
{
    par_set_threads(budget, 1);
    struct orient_params p;
    orient_params_default(&p);
    p.samples = 300;
    int rc = orient_find(m, &p, r, err);
    par_set_threads(0, 1);
    return rc;
}

static bool
same_candidate(const struct orient_candidate *a, const struct orient_candidate *b)
{
    return memcmp(&a->up, &b->up, sizeof(a->up)) == 0 && a->cost == b->cost &&
           a->source == b->source && memcmp(&a->m, &b->m, sizeof(a->m)) == 0;
}

T_CASE(orient_same_on_one_thread_and_five)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    const char *path = t_shared_mesh("elephant.stl");
    if (path)
        T_OK(mesh_load(path, &m, NULL, &err), &err);
    else
        T_OK(shape_tee(&m, &err), &err);
    struct orient_result r1, r5;
    T_OK(orient_with(1, &m, &r1, &err), &err);
    T_OK(orient_with(5, &m, &r5, &err), &err);
    T_TRUE(same_candidate(&r1.best, &r5.best));
    T_TRUE(same_candidate(&r1.input, &r5.input));
    T_EQ_INT(r1.n_candidates, r5.n_candidates);
    T_EQ_INT(r1.n_exact, r5.n_exact);
    T_EQ_INT(r1.n_runners, r5.n_runners);
    for (int k = 0; k < r1.n_runners; k++)
        T_TRUE(same_candidate(&r1.runners[k], &r5.runners[k]));
    mesh_release(&m);
}

T_CASE(slim_search_same_on_one_thread_and_three)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    struct slim_result r[2];
    int budgets[2] = { 1, 3 };
    for (int i = 0; i < 2; i++) {
        struct slim_params p;
        slim_params_default(&p);
        p.tet.cells = 8;
        p.max_iters = 10;
        p.search_direction = true;
        p.search_step_deg = 30;
        p.search_max_deg = 30;
        par_set_threads(budgets[i], 1);
        T_OK(slim_optimize(&m, &p, &r[i], &err), &err);
    }
    par_set_threads(0, 1);
    T_EQ_INT(r[0].n_dirs, 9);
    T_TRUE(memcmp(&r[0].rotation, &r[1].rotation, sizeof(r[0].rotation)) == 0);
    T_TRUE(r[0].after.volume_mm3 == r[1].after.volume_mm3);
    T_EQ_INT(r[0].out.n_verts, r[1].out.n_verts);
    T_TRUE(memcmp(r[0].out.v, r[1].out.v, r[0].out.n_verts * sizeof(*r[0].out.v)) == 0);
    slim_result_release(&r[0]);
    slim_result_release(&r[1]);
    mesh_release(&m);
}

static int
slice_with(int budget, const struct mesh *m, const char *name, struct buf *out, struct sf_err *err)
{
    struct slice_profile p;
    int rc = slice_profile_default(&p);
    if (rc)
        return rc;
    char path[512];
    snprintf(path, sizeof(path), "%s/%s-%d.gcode", t_tmpdir(), name, budget);
    par_set_threads(budget, 1);
    rc = slice_mesh(m, &p, path, NULL, NULL, NULL, err);
    par_set_threads(0, 1);
    slice_profile_release(&p);
    if (rc == SF_OK)
        rc = buf_read_file(out, path, err);
    return rc;
}

T_CASE(slice_same_gcode_on_one_thread_and_four)
{
    struct mesh m;
    struct sf_err err;
    for (int shape = 0; shape < 2; shape++) {
        mesh_init(&m);
        if (shape == 0)
            T_OK(shape_tee(&m, &err), &err);
        else
            T_OK(shape_torus(&m, 15, 5, 48, 24, &err), &err);
        mesh_place_on_bed(&m, 100, 100);
        struct buf g1, g4;
        buf_init(&g1, 1 << 28);
        buf_init(&g4, 1 << 28);
        T_OK(slice_with(1, &m, shape ? "torus" : "tee", &g1, &err), &err);
        T_OK(slice_with(4, &m, shape ? "torus" : "tee", &g4, &err), &err);
        T_TRUE(g1.len > 1000);
        T_EQ_INT(g1.len, g4.len);
        T_TRUE(memcmp(g1.data, g4.data, g1.len) == 0);
        buf_release(&g1);
        buf_release(&g4);
        mesh_release(&m);
    }
}

/*
 * Cancelling between layers: the slicer asks on the calling thread.  Here
 * the caller dawdles in its first question (as on a loaded machine) while
 * the other thread builds the remaining layers; the answer "cancel" must
 * still be heard, at the stage's end if not before.
 */
struct dawdle {
    int toolpath_calls;
};

static int
dawdle_then_cancel(void *ud, const char *stage, double done)
{
    struct dawdle *d = ud;
    if (strcmp(stage, "toolpaths") != 0)
        return 0;
    if (++d->toolpath_calls == 2) { /* the first from inside the loop */
        struct timespec ts = { 0, 500000000 };
        nanosleep(&ts, NULL);
    }
    return done > 0.2;
}

T_CASE(slice_cancel_heard_when_other_threads_built_the_layers)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_box(&m, v3(0, 0, 0), v3(10, 10, 2), &err), &err); /* 10 quick layers */
    mesh_place_on_bed(&m, 100, 100);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    char path[512];
    snprintf(path, sizeof(path), "%s/dawdle.gcode", t_tmpdir());
    par_set_threads(2, 1);
    struct dawdle d = { 0 };
    int rc = slice_mesh(&m, &p, path, NULL, dawdle_then_cancel, &d, &err);
    par_set_threads(0, 1);
    slice_profile_release(&p);
    mesh_release(&m);
    T_ERR(rc, SF_ECANCELED, &err, "cancel");
}
