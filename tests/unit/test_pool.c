/*
 * test_pool.c - the worker pool on a real loop: every task's done() runs
 * exactly once on the loop thread with work()'s result; cancel reaches
 * queued and running tasks; pool_free cancels what is left.
 */
#include <pthread.h>
#include <time.h>

#include "../../src/base/pool.h"
#include "../t.h"

/* One task's record. */
struct job {
    long n;            /* input: sum 1..n */
    long sum;          /* output, written by the worker */
    int rc;            /* done()'s rc */
    int done_calls;    /* how often done() ran */
    bool on_loop;      /* done() ran on the loop thread */
    atomic_bool *gate; /* if set, work waits for it (or cancel) */
};

static pthread_t loop_thread;
static int n_done;

static int
work_sum(void *ud, const atomic_bool *cancel)
{
    struct job *j = ud;
    while (j->gate && !atomic_load(j->gate)) {
        if (atomic_load(cancel))
            return SF_ECANCELED;
        struct timespec ts = { 0, 1000000 };
        nanosleep(&ts, NULL);
    }
    for (long i = 1; i <= j->n; i++)
        j->sum += i;
    return SF_OK;
}

static void
done_sum(struct loop *l, void *ud, int rc)
{
    (void)l;
    struct job *j = ud;
    j->rc = rc;
    j->done_calls++;
    j->on_loop = pthread_equal(pthread_self(), loop_thread);
    n_done++;
}

static void
run_until(struct loop *l, int want)
{
    for (int i = 0; i < 500 && n_done < want; i++)
        loop_run_once(l, 10);
}

T_CASE(pool_runs_every_task_and_reports_on_loop)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    struct pool *p = pool_new(l, 2, &err);
    T_TRUE(p != NULL);
    T_EQ_INT(pool_size(p), 2);
    loop_thread = pthread_self();
    n_done = 0;
    struct job jobs[40];
    memset(jobs, 0, sizeof(jobs));
    for (int i = 0; i < 40; i++) {
        jobs[i].n = 1000 * (i + 1);
        T_TRUE(pool_submit(p, work_sum, done_sum, &jobs[i], &err) > 0);
    }
    run_until(l, 40);
    for (int i = 0; i < 40; i++) {
        T_EQ_INT(jobs[i].done_calls, 1);
        T_EQ_INT(jobs[i].rc, SF_OK);
        T_TRUE(jobs[i].on_loop);
        T_EQ_INT(jobs[i].sum, jobs[i].n * (jobs[i].n + 1) / 2);
    }
    pool_free(p);
    loop_free(l);
}

T_CASE(pool_cancel_reaches_queued_and_running_tasks)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    struct pool *p = pool_new(l, 1, &err);
    loop_thread = pthread_self();
    n_done = 0;
    atomic_bool closed = false;
    struct job running = { .n = 10, .gate = &closed }, queued = { .n = 10 };
    uint64_t a = pool_submit(p, work_sum, done_sum, &running, &err);
    uint64_t b = pool_submit(p, work_sum, done_sum, &queued, &err);
    struct timespec ts = { 0, 20000000 };
    nanosleep(&ts, NULL); /* the single worker is now blocked in `running` */
    pool_cancel(p, b);
    pool_cancel(p, a);
    pool_cancel(p, 999); /* unknown: harmless */
    run_until(l, 2);
    T_EQ_INT(running.rc, SF_ECANCELED);
    T_EQ_INT(queued.rc, SF_ECANCELED);
    T_EQ_INT(queued.sum, 0); /* never ran */
    T_EQ_INT(running.done_calls + queued.done_calls, 2);
    pool_free(p);
    loop_free(l);
}

T_CASE(pool_free_cancels_what_is_left)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    struct pool *p = pool_new(l, 1, &err);
    loop_thread = pthread_self();
    n_done = 0;
    atomic_bool closed = false;
    struct job blocker = { .n = 1, .gate = &closed }, rest[5];
    memset(rest, 0, sizeof(rest));
    pool_submit(p, work_sum, done_sum, &blocker, &err);
    for (int i = 0; i < 5; i++)
        pool_submit(p, work_sum, done_sum, &rest[i], &err);
    struct timespec ts = { 0, 20000000 };
    nanosleep(&ts, NULL);
    pool_free(p);
    T_EQ_INT(n_done, 5); /* queued ones, synchronously */
    run_until(l, 6);     /* the running one, through the loop */
    T_EQ_INT(blocker.rc, SF_ECANCELED);
    for (int i = 0; i < 5; i++)
        T_EQ_INT(rest[i].rc, SF_ECANCELED);
    loop_free(l);
}
