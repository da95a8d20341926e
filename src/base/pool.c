/*
 * pool.c - fixed worker threads; completions go back through loop_post.
 *
 * Why a fixed pool: the heavy stages are CPU-bound, so more threads than
 * cores only add contention, and a fixed set is easy to reason about
 * (Redis's bio.c, libuv's threadpool).  Design: one mutex-protected FIFO
 * of tasks and a condition variable; a worker pops a task, runs work()
 * with the task's cancel flag, and posts the task back to the loop, where
 * deliver() calls done() and frees it.  The running list lets
 * pool_cancel() reach tasks already picked up.
 *
 * Stopping is bounded: pool_free cancels every task and waits at most
 * POOL_STOP_WAIT_MS for the workers.  A worker stuck in a step that cannot
 * look at its cancel flag (a library call on a huge part) is abandoned:
 * its thread is detached, its done() never runs, and the last abandoned
 * worker to finish frees the pool (so pool_free touches nothing of it
 * after it returns and the loop may be freed).
 *
 * Thread: see pool.h.  `mu` protects queue, running, quit, abandoned,
 * n_exited and posting.
 */
#include "pool.h"

#include <pthread.h>
#include <signal.h>
#include <string.h>
#include <time.h>

#include "log.h"
#include "mem.h"
#include "par.h"

struct task {
    uint64_t id;        /* > 0 */
    pool_work_fn work;  /* worker side */
    pool_done_fn done;  /* loop side */
    void *ud;           /* both sides' argument */
    atomic_bool cancel; /* set by pool_cancel / pool_free */
    int rc;             /* work()'s result */
    struct task *next;  /* in queue or running */
};

struct pool {
    struct loop *l;     /* where done() runs */
    pthread_t *threads; /* n workers */
    int n;
    pthread_mutex_t mu;       /* protects the fields below */
    pthread_cond_t cv;        /* signalled on new task or quit */
    struct task *head, *tail; /* queued, FIFO */
    struct task *running;     /* picked up by a worker */
    bool quit;                /* workers exit */
    uint64_t next_id;         /* next task id */
    pthread_cond_t exited_cv; /* a worker exited or finished posting */
    int n_exited;             /* workers that have left their loop */
    int posting;              /* workers inside post_back (the loop must live) */
    bool abandoned;           /* pool_free gave up waiting: workers own the pool */
};

static void
pool_destroy(struct pool *p)
{
    pthread_cond_destroy(&p->exited_cv);
    pthread_cond_destroy(&p->cv);
    pthread_mutex_destroy(&p->mu);
    free(p->threads);
    free(p);
}

static void
deliver(struct loop *l, void *ud)
{
    struct task *t = ud;
    t->done(l, t->ud, t->rc);
    free(t);
}

static void
post_back(struct pool *p, struct task *t)
{
    /* loop_post only fails when memory is exhausted; wait for some to free
       up rather than lose a completion. */
    while (loop_post(p->l, deliver, t) != SF_OK) {
        struct timespec ts = { 0, 1000000 };
        nanosleep(&ts, NULL);
    }
}

static void *
worker(void *arg)
{
    struct pool *p = arg;
    pthread_mutex_lock(&p->mu);
    for (;;) {
        while (!p->head && !p->quit)
            pthread_cond_wait(&p->cv, &p->mu);
        if (p->quit)
            break;
        struct task *t = p->head;
        p->head = t->next;
        if (!p->head)
            p->tail = NULL;
        t->next = p->running;
        p->running = t;
        pthread_mutex_unlock(&p->mu);
        t->rc = atomic_load(&t->cancel) ? SF_ECANCELED : t->work(t->ud, &t->cancel);
        pthread_mutex_lock(&p->mu);
        for (struct task **pp = &p->running; *pp; pp = &(*pp)->next)
            if (*pp == t) {
                *pp = t->next;
                break;
            }
        if (p->abandoned) {
            free(t); /* nobody is left to deliver to */
            break;
        }
        p->posting++;
        pthread_mutex_unlock(&p->mu);
        post_back(p, t);
        pthread_mutex_lock(&p->mu);
        p->posting--;
        pthread_cond_broadcast(&p->exited_cv);
    }
    bool last = ++p->n_exited == p->n && p->abandoned;
    pthread_cond_broadcast(&p->exited_cv);
    pthread_mutex_unlock(&p->mu);
    if (last)
        pool_destroy(p);
    return NULL;
}

struct pool *
pool_new(struct loop *l, int n_threads, struct sf_err *err)
{
    if (n_threads <= 0)
        n_threads = par_cores();
    if (n_threads > POOL_THREADS_MAX)
        n_threads = POOL_THREADS_MAX;
    struct pool *p = mem_calloc(1, sizeof(*p));
    pthread_t *threads = mem_calloc((size_t)n_threads, sizeof(*threads));
    if (!p || !threads) {
        free(p);
        free(threads);
        sf_err_set(err, SF_ENOMEM, "pool: out of memory");
        return NULL;
    }
    p->l = l;
    p->threads = threads;
    p->next_id = 1;
    pthread_mutex_init(&p->mu, NULL);
    pthread_cond_init(&p->cv, NULL);
    pthread_condattr_t ca;
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&p->exited_cv, &ca);
    pthread_condattr_destroy(&ca);
    /* Workers inherit this thread's signal mask: block everything so
       signals reach the loop thread (signalfd), never a worker. */
    sigset_t all, old;
    sigfillset(&all);
    pthread_sigmask(SIG_SETMASK, &all, &old);
    for (int i = 0; i < n_threads; i++) {
        if (pthread_create(&p->threads[i], NULL, worker, p) != 0) {
            sf_err_set(err, SF_EIO, "pool: cannot start worker %d of %d", i + 1, n_threads);
            pthread_sigmask(SIG_SETMASK, &old, NULL);
            pool_free(p);
            return NULL;
        }
        p->n++;
    }
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    return p;
}

void
pool_free(struct pool *p)
{
    if (!p)
        return;
    pthread_mutex_lock(&p->mu);
    p->quit = true;
    struct task *queued = p->head;
    p->head = p->tail = NULL;
    for (struct task *t = p->running; t; t = t->next)
        atomic_store(&t->cancel, true);
    pthread_cond_broadcast(&p->cv);
    struct timespec until;
    clock_gettime(CLOCK_MONOTONIC, &until);
    until.tv_sec += POOL_STOP_WAIT_MS / 1000;
    until.tv_nsec += (long)(POOL_STOP_WAIT_MS % 1000) * 1000000;
    if (until.tv_nsec >= 1000000000) {
        until.tv_sec++;
        until.tv_nsec -= 1000000000;
    }
    while (p->n_exited < p->n)
        if (pthread_cond_timedwait(&p->exited_cv, &p->mu, &until) != 0)
            break;
    bool abandon = p->n_exited < p->n;
    int stuck = p->n - p->n_exited;
    if (abandon) {
        /* Completions being posted now still need the loop: let them land. */
        while (p->posting > 0)
            pthread_cond_wait(&p->exited_cv, &p->mu);
        for (int i = 0; i < p->n; i++)
            pthread_detach(p->threads[i]);
        p->abandoned = true; /* from here on the stuck workers own p */
    }
    struct loop *l = p->l;
    pthread_mutex_unlock(&p->mu);
    if (abandon)
        log_warn("pool", "%d worker%s still busy %d ms after cancel: left to finish on %s own",
                 stuck, stuck == 1 ? "" : "s", POOL_STOP_WAIT_MS, stuck == 1 ? "its" : "their");
    else
        for (int i = 0; i < p->n; i++)
            pthread_join(p->threads[i], NULL);
    while (queued) {
        struct task *next = queued->next;
        queued->done(l, queued->ud, SF_ECANCELED);
        free(queued);
        queued = next;
    }
    if (!abandon)
        pool_destroy(p);
}

uint64_t
pool_submit(struct pool *p, pool_work_fn work, pool_done_fn done, void *ud, struct sf_err *err)
{
    struct task *t = mem_calloc(1, sizeof(*t));
    if (!t) {
        sf_err_set(err, SF_ENOMEM, "pool: out of memory");
        return 0;
    }
    t->work = work;
    t->done = done;
    t->ud = ud;
    atomic_init(&t->cancel, false);
    pthread_mutex_lock(&p->mu);
    t->id = p->next_id++;
    if (p->tail)
        p->tail->next = t;
    else
        p->head = t;
    p->tail = t;
    uint64_t id = t->id;
    pthread_cond_signal(&p->cv);
    pthread_mutex_unlock(&p->mu);
    return id;
}

void
pool_cancel(struct pool *p, uint64_t id)
{
    pthread_mutex_lock(&p->mu);
    for (struct task *t = p->head; t; t = t->next)
        if (t->id == id)
            atomic_store(&t->cancel, true);
    for (struct task *t = p->running; t; t = t->next)
        if (t->id == id)
            atomic_store(&t->cancel, true);
    pthread_mutex_unlock(&p->mu);
}

int
pool_size(const struct pool *p)
{
    return p->n;
}
