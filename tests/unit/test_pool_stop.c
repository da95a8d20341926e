/*
 * test_pool_stop.c - pool_free is bounded (issue 16 item 7): a task that
 * never looks at its cancel flag cannot hold the daemon's shutdown.
 */
#include <pthread.h>
#include <stdatomic.h>
#include <time.h>

#include "../../src/base/pool.h"
#include "../t.h"

static atomic_bool release; /* set by the test: the stuck task may end */
static atomic_bool running; /* the stuck task is inside work() */
static atomic_bool ended;   /* it returned */
static int n_done;

/* Ignores cancel; ends when released, or after 60 s at the latest. */
static int
work_stuck(void *ud, const atomic_bool *cancel)
{
    (void)ud, (void)cancel;
    atomic_store(&running, true);
    for (int i = 0; i < 60000 && !atomic_load(&release); i++) {
        struct timespec ts = { 0, 1000000 };
        nanosleep(&ts, NULL);
    }
    atomic_store(&running, false);
    atomic_store(&ended, true);
    return SF_OK;
}

static void
done_count(struct loop *l, void *ud, int rc)
{
    (void)l, (void)ud, (void)rc;
    n_done++;
}

T_CASE(pool_free_does_not_wait_for_a_stuck_task)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    T_TRUE(l != NULL);
    struct pool *p = pool_new(l, 1, &err);
    T_TRUE(p != NULL);
    static int ud;
    pool_submit(p, work_stuck, done_count, &ud, &err);
    while (!atomic_load(&running)) {
        struct timespec ts = { 0, 1000000 };
        nanosleep(&ts, NULL);
    }
    pool_free(p);
    /* pool_free came back while the task still ran (it only ends when
       released, after this point, or after a full minute) */
    bool still_running = atomic_load(&running);
    atomic_store(&release, true);
    T_TRUE(still_running);
    loop_run_once(l, 0);
    T_EQ_INT(n_done, 0); /* an abandoned task's done() never runs */
    loop_free(l);
    while (!atomic_load(&ended)) {
        struct timespec ts = { 0, 1000000 };
        nanosleep(&ts, NULL);
    }
}
