/*
 * pool.h - a fixed set of worker threads for the heavy stages (load,
 * orient, shape, slice), with results handed back to the event loop.
 *
 * A task is two functions: work() runs on a worker and touches only the
 * data it is handed (ud); done() runs afterwards on the loop thread
 * (delivered with loop_post), so it may use the store and printer state.
 * Cancelling sets a flag work() should check between steps (Embree-style);
 * a task cancelled before a worker picked it up never runs work(), and
 * done() gets SF_ECANCELED.  Every submitted task gets exactly one done().
 *
 * Thread: pool_new/submit/cancel/free on the loop thread; work() on a
 * worker; done() on the loop thread.
 */
#ifndef SF_BASE_POOL_H
#define SF_BASE_POOL_H

#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>

#include "err.h"
#include "loop.h"

#define POOL_THREADS_MAX 64 /* beyond the machine's cores more threads only contend */

struct pool;

/* Runs on a worker; returns an enum sf_status handed to done(). */
typedef int (*pool_work_fn)(void *ud, const atomic_bool *cancel);
/* Runs on the loop thread with work()'s result (or SF_ECANCELED if it never ran). */
typedef void (*pool_done_fn)(struct loop *l, void *ud, int rc);

/* n_threads workers (0: one per core, par_cores(); at most POOL_THREADS_MAX). */
struct pool *pool_new(struct loop *l, int n_threads, struct sf_err *err);

/* How long pool_free waits for running tasks to see their cancel flag. */
#define POOL_STOP_WAIT_MS 3000

/*
 * Cancel everything, wait for the workers to stop and free the pool.
 * Queued tasks get done(SF_ECANCELED) before this returns; running tasks'
 * done() calls are posted to the loop: run the loop once more to deliver
 * them.  A task still running POOL_STOP_WAIT_MS after its cancel is
 * abandoned (logged): its done() never runs, its ud is never handed back
 * (so it must not point at anything the caller frees after this), and the
 * pool is freed by the last such worker when its work() returns.
 */
void pool_free(struct pool *p);

/* Queue a task; returns its id (> 0), or 0 with err set (SF_ENOMEM). */
uint64_t pool_submit(struct pool *p, pool_work_fn work, pool_done_fn done, void *ud,
                     struct sf_err *err);

/* Ask task id to stop (harmless if it already finished). */
void pool_cancel(struct pool *p, uint64_t id);

/* Number of worker threads. */
int pool_size(const struct pool *p);

#endif
