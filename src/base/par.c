/*
 * par.c - data-parallel loops on one persistent set of helpers (see par.h).
 *
 * Why one runtime: orientation, slimming and the slicer each used to start
 * their own threads (a crew, an array of up to 64, one extra thread in two
 * slicer stages), and the daemon's prepare pool ran beside them, so nothing
 * bounded the threads busy at once and every stage paid thread starts.
 *
 * Design (fork-join, as OpenMP's and TBB's parallel_for): a call posts a
 * job on the open list and broadcasts; idle helpers join it while its
 * group - the root call and every loop nested in it - has fewer threads
 * busy than its budget.  Chunks are claimed from an atomic counter, so
 * the split adapts to load while each index still has one owner.  The
 * caller runs chunks too and, once none is left, waits only for threads
 * that joined (never for one to start), so a loop finishes even when no
 * helper is free.  While it waits it works on loops nested in its group:
 * with two threads, a helper running a nested loop gets the caller's help
 * as soon as the caller's own chunks are done.
 *
 * Thread: see par.h.  `g.mu` protects every field of g, and of the jobs
 * and groups, that is not atomic; `g.cv` is broadcast on any change a
 * waiter may care for (a job posted, a thread leaving a job, quit).
 */
#include "par.h"

#include <pthread.h>
#include <sched.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdlib.h>
#include <unistd.h>

#include "log.h"

/* A root call and every loop nested in it: they share its budget. */
struct group {
    int budget; /* threads that may run chunks of the group at once */
    int busy;   /* threads running chunks of the group now */
};

struct job {
    par_fn fn;
    void *ud;
    uint32_t n, chunk, n_chunks;
    atomic_uint next;   /* next chunk to claim */
    atomic_bool stop;   /* a chunk failed: claim no more */
    int want;           /* threads that may join besides the caller */
    int joined;         /* threads that joined (worker slots 1..joined) */
    int active;         /* joined threads not yet done */
    uint32_t fail_k;    /* lowest failing chunk, n_chunks if none */
    int fail_rc;        /* its code */
    struct group *grp;  /* whose budget it spends */
    struct job *next_o; /* in g.open */
};

static struct {
    pthread_mutex_t mu;
    pthread_cond_t cv;
    struct job *open;               /* jobs that may still take threads */
    int budget;                     /* 0: not set yet */
    int helpers_max;                /* helpers to start */
    int n_helpers;                  /* started */
    bool started;                   /* the helpers were started */
    bool quit;                      /* helpers exit */
    pthread_t tid[PAR_THREADS_MAX]; /* at most PAR_THREADS_MAX helpers */
} g = { .mu = PTHREAD_MUTEX_INITIALIZER, .cv = PTHREAD_COND_INITIALIZER };

/* The group whose chunks this thread is running, NULL outside par_for. */
static _Thread_local struct group *tls_group;

int
par_cores(void)
{
    cpu_set_t set;
    long n = 0;
    if (sched_getaffinity(0, sizeof(set), &set) == 0)
        n = CPU_COUNT(&set);
    if (n < 1)
        n = sysconf(_SC_NPROCESSORS_ONLN);
    if (n < 1)
        n = 1;
    return n > PAR_THREADS_MAX ? PAR_THREADS_MAX : (int)n;
}

/* SLIMFARM_THREADS, or the cores.  Called under g.mu. */
static int
default_budget(void)
{
    const char *s = getenv("SLIMFARM_THREADS");
    if (s && *s) {
        char *end;
        long v = strtol(s, &end, 10);
        if (*end == '\0' && v >= 1 && v <= PAR_THREADS_MAX)
            return (int)v;
        log_warn("par", "SLIMFARM_THREADS='%s' is not a thread count in 1..%d: using %d cores", s,
                 PAR_THREADS_MAX, par_cores());
    }
    return par_cores();
}

static void
record_failure(struct job *j, uint32_t k, int rc)
{
    pthread_mutex_lock(&g.mu);
    if (k < j->fail_k) {
        j->fail_k = k;
        j->fail_rc = rc;
    }
    pthread_mutex_unlock(&g.mu);
    atomic_store(&j->stop, true);
}

static void
run_chunks(struct job *j, int worker)
{
    while (!atomic_load(&j->stop)) {
        uint32_t k = atomic_fetch_add(&j->next, 1);
        if (k >= j->n_chunks)
            break;
        uint32_t begin = k * j->chunk;
        uint32_t end = j->n - begin > j->chunk ? begin + j->chunk : j->n;
        int rc = j->fn(j->ud, begin, end, worker);
        if (rc)
            record_failure(j, k, rc);
    }
}

/* Whether a thread of group grp (any group if NULL) may join j now.  Under g.mu. */
static bool
joinable(const struct job *j, const struct group *grp)
{
    return (!grp || j->grp == grp) && j->joined < j->want && j->grp->busy < j->grp->budget &&
           !atomic_load(&j->stop) && atomic_load(&j->next) < j->n_chunks;
}

static struct job *
find_job(const struct group *grp)
{
    for (struct job *j = g.open; j; j = j->next_o)
        if (joinable(j, grp))
            return j;
    return NULL;
}

/* Join j, run chunks until none is left, leave.  Called and returns under g.mu. */
static void
work_in(struct job *j)
{
    int worker = ++j->joined;
    j->active++;
    j->grp->busy++;
    pthread_mutex_unlock(&g.mu);
    struct group *saved = tls_group;
    tls_group = j->grp;
    run_chunks(j, worker);
    tls_group = saved;
    pthread_mutex_lock(&g.mu);
    j->grp->busy--;
    j->active--;
    pthread_cond_broadcast(&g.cv);
}

static void *
helper(void *arg)
{
    (void)arg;
    pthread_mutex_lock(&g.mu);
    while (!g.quit) {
        struct job *j = find_job(NULL);
        if (j)
            work_in(j);
        else
            pthread_cond_wait(&g.cv, &g.mu);
    }
    pthread_mutex_unlock(&g.mu);
    return NULL;
}

/* Set the budget if unset and start the helpers once.  Under g.mu. */
static void
start_helpers(void)
{
    if (g.budget == 0) {
        g.budget = default_budget();
        g.helpers_max = g.budget - 1;
    }
    if (g.started)
        return;
    g.started = true;
    /* Helpers inherit this thread's signal mask: block everything so signals
       reach the loop thread (signalfd), never a helper. */
    sigset_t all, old;
    sigfillset(&all);
    pthread_sigmask(SIG_SETMASK, &all, &old);
    int max = g.helpers_max < PAR_THREADS_MAX ? g.helpers_max : PAR_THREADS_MAX;
    while (g.n_helpers < max && pthread_create(&g.tid[g.n_helpers], NULL, helper, NULL) == 0)
        g.n_helpers++;
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    if (g.n_helpers < max)
        log_warn("par", "started %d of %d helper threads", g.n_helpers, max);
}

static int
run_serial(uint32_t n, uint32_t chunk, par_fn fn, void *ud)
{
    for (uint32_t begin = 0; begin < n; begin += chunk) {
        uint32_t end = n - begin > chunk ? begin + chunk : n;
        int rc = fn(ud, begin, end, 0);
        if (rc)
            return rc;
        if (end == n)
            break;
    }
    return 0;
}

int
par_for(uint32_t n, uint32_t chunk, int max_threads, par_fn fn, void *ud)
{
    if (n == 0)
        return 0;
    if (chunk == 0)
        chunk = 1;
    uint32_t n_chunks = n / chunk + (n % chunk != 0);
    struct group *outer = tls_group, root;
    pthread_mutex_lock(&g.mu);
    start_helpers();
    /* cap: the threads of the whole call, nested loops included */
    int cap = outer ? outer->budget : g.budget;
    if (max_threads > 0 && max_threads < cap)
        cap = max_threads;
    int threads = (uint32_t)cap > n_chunks ? (int)n_chunks : cap;
    if (!outer) {
        root.budget = cap;
        root.busy = 1; /* this thread */
        tls_group = &root;
    }
    if (threads <= 1 || g.n_helpers == 0) {
        pthread_mutex_unlock(&g.mu);
        int rc = run_serial(n, chunk, fn, ud);
        tls_group = outer;
        return rc;
    }
    struct job j = { .fn = fn,
                     .ud = ud,
                     .n = n,
                     .chunk = chunk,
                     .n_chunks = n_chunks,
                     .want = threads - 1,
                     .fail_k = n_chunks,
                     .grp = outer ? outer : &root };
    atomic_init(&j.next, 0);
    atomic_init(&j.stop, false);
    j.next_o = g.open;
    g.open = &j;
    pthread_cond_broadcast(&g.cv);
    pthread_mutex_unlock(&g.mu);

    run_chunks(&j, 0);

    pthread_mutex_lock(&g.mu);
    for (struct job **pp = &g.open; *pp; pp = &(*pp)->next_o)
        if (*pp == &j) {
            *pp = j.next_o;
            break;
        }
    /* Idle until the joined threads are done: meanwhile help the group's
       nested loops (a joined thread may be running one). */
    j.grp->busy--;
    pthread_cond_broadcast(&g.cv);
    while (j.active > 0) {
        struct job *nested = find_job(j.grp);
        if (nested)
            work_in(nested);
        else
            pthread_cond_wait(&g.cv, &g.mu);
    }
    j.grp->busy++;
    int rc = j.fail_k < n_chunks ? j.fail_rc : 0;
    pthread_mutex_unlock(&g.mu);
    tls_group = outer;
    return rc;
}

int
par_threads(void)
{
    pthread_mutex_lock(&g.mu);
    if (g.budget == 0) {
        g.budget = default_budget();
        g.helpers_max = g.budget - 1;
    }
    int n = g.budget;
    pthread_mutex_unlock(&g.mu);
    return n;
}

static void
stop_helpers(void)
{
    pthread_mutex_lock(&g.mu);
    g.quit = true;
    pthread_cond_broadcast(&g.cv);
    pthread_mutex_unlock(&g.mu);
    for (int i = 0; i < g.n_helpers; i++)
        pthread_join(g.tid[i], NULL);
    pthread_mutex_lock(&g.mu);
    g.n_helpers = 0;
    g.started = false;
    g.quit = false;
    pthread_mutex_unlock(&g.mu);
}

void
par_set_threads(int n, int n_callers)
{
    if (n_callers < 1)
        n_callers = 1;
    stop_helpers();
    pthread_mutex_lock(&g.mu);
    if (n > PAR_THREADS_MAX)
        n = PAR_THREADS_MAX;
    g.budget = n > 0 ? n : default_budget();
    g.helpers_max = n_callers * (g.budget - 1);
    pthread_mutex_unlock(&g.mu);
}

void
par_share(int n_callers)
{
    if (n_callers < 1)
        n_callers = 1;
    int cores = par_cores();
    par_set_threads(cores / n_callers > 1 ? cores / n_callers : 1, n_callers);
}
