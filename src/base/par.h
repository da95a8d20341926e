/*
 * par.h - the one compute runtime: data-parallel loops (par_for) on a
 * persistent set of helper threads, within a thread budget set once per
 * process.
 *
 * par_for(n, chunk, ...) cuts [0, n) into chunks of `chunk` indices; the
 * calling thread and up to budget - 1 helpers claim chunks in increasing
 * order and call fn(ud, begin, end, worker) on each.  The runtime does no
 * reduction of its own: fn writes only what its indices own (or the
 * scratch of its `worker` slot) and the caller combines the results in
 * index order after par_for returns, so the answer is bit-identical
 * whatever the thread count and whoever ran which chunk.  A failing chunk
 * stops further claims; par_for returns the code of the lowest failing
 * chunk, so the error is the same as the single-threaded run's (every
 * chunk below it was claimed before it and ran to the end).
 *
 * Nesting: a par_for called from inside fn is allowed and shares the
 * outer call's budget (its threads are those the outer call leaves idle;
 * a caller waiting for its helpers works on its nested loops meanwhile),
 * so one root call never has more than its budget of threads busy.
 *
 * Budget: the threads one root par_for may use, the caller included.  By
 * default every core the process may run on (sched_getaffinity), or
 * SLIMFARM_THREADS=N (1..PAR_THREADS_MAX).  A process with several
 * independent callers (the daemon's prepare pool) divides the machine
 * with par_share().  The helpers start at the first par_for that needs
 * them and live until par_set_threads()/par_share() or exit; they block
 * every signal (the loop thread takes them through signalfd).
 *
 * Thread: par_for from any thread, concurrently.  par_set_threads and
 * par_share at start-up (tests: between runs), with no par_for running.
 */
#ifndef SF_BASE_PAR_H
#define SF_BASE_PAR_H

#include <stdint.h>

#define PAR_THREADS_MAX 64 /* beyond the machine's cores more threads only contend */

/*
 * One chunk, indices [begin, end), run by worker slot `worker` (0 is the
 * calling thread; always < the call's thread count, so < par_threads()).
 * Returns 0, or a code (an enum sf_status) that stops the loop.
 */
typedef int (*par_fn)(void *ud, uint32_t begin, uint32_t end, int worker);

/*
 * Run fn over [0, n) in chunks of `chunk` indices (0: 1) on at most
 * max_threads threads (0: the budget; never more than the budget).
 * Returns 0, or the code of the lowest failing chunk.  Chunks above a
 * failing one may or may not have run.  Never fails by itself: with no
 * helper free it runs every chunk on the calling thread.
 */
int par_for(uint32_t n, uint32_t chunk, int max_threads, par_fn fn, void *ud);

/* Threads a root par_for may use (the budget), the caller included; >= 1. */
int par_threads(void);

/* Cores this process may run on (>= 1, at most PAR_THREADS_MAX). */
int par_cores(void);

/*
 * Set the budget to n threads (0: the default above), for n_callers threads
 * that may call par_for at once (< 1: 1).  Stops the helpers; the next
 * par_for starts n_callers * (budget - 1) of them.
 */
void par_set_threads(int n, int n_callers);

/*
 * The machine is shared by n_callers threads that each run par_for (the
 * prepare pool's workers): par_set_threads(max(1, cores / n_callers),
 * n_callers).
 */
void par_share(int n_callers);

#endif
