/*
 * loop.h - the event loop: one epoll loop on the main thread that owns every
 * printer connection, socket, timer and signal (STYLE.md, "Threads").
 *
 * Contract:
 *  - All functions except loop_post() must be called on the loop's thread.
 *  - Callbacks run on the loop's thread and must not block: no sleeping,
 *    no blocking I/O, no long computation (hand that to pool.h's workers).
 *  - Time is CLOCK_MONOTONIC in milliseconds, cached once per iteration
 *    (loop_now_ms), so every callback of one iteration sees the same "now".
 *  - Timers live in a min-heap; a timer fires once (re-arm from its
 *    callback for periodic work).  Cancelling an unknown or fired timer id
 *    is harmless.
 *  - loop_post() is the one thread-safe entry: workers use it to hand
 *    results back (eventfd wake-up); posted functions run in FIFO order.
 *  - Signals arrive through signalfd as ordinary callbacks.
 *  - Tests drive the loop deterministically with loop_run_once().
 */
#ifndef SF_BASE_LOOP_H
#define SF_BASE_LOOP_H

#include <stdbool.h>
#include <stdint.h>

#include "err.h"

struct loop;

enum { LOOP_READ = 1, LOOP_WRITE = 2, LOOP_HUP = 4, LOOP_ERROR = 8 };

typedef void (*loop_fd_fn)(struct loop *l, int fd, unsigned events, void *ud);
typedef void (*loop_timer_fn)(struct loop *l, void *ud);
typedef void (*loop_post_fn)(struct loop *l, void *ud);
typedef void (*loop_signal_fn)(struct loop *l, int signo, void *ud);

/* New loop; NULL with err set on failure. */
struct loop *loop_new(struct sf_err *err);
/* Free the loop; fds registered with it are not closed (their owners close them). */
void loop_free(struct loop *l);

/* Watch fd for events (LOOP_READ | LOOP_WRITE); LOOP_HUP/LOOP_ERROR are always reported. */
int loop_add_fd(struct loop *l, int fd, unsigned events, loop_fd_fn fn, void *ud,
                struct sf_err *err);
/* Change the events watched on fd. */
int loop_mod_fd(struct loop *l, int fd, unsigned events, struct sf_err *err);
/* Stop watching fd (safe from within its own callback). */
void loop_del_fd(struct loop *l, int fd);

/* Run fn once after delay_ms; returns a timer id > 0 (0 on allocation failure). */
uint64_t loop_timer_add(struct loop *l, int64_t delay_ms, loop_timer_fn fn, void *ud);
void loop_timer_cancel(struct loop *l, uint64_t id);

/* Cached monotonic time of this iteration, ms. */
int64_t loop_now_ms(struct loop *l);

/*
 * Simulated time, for soaks and tests of timers over links that deliver at
 * once (socketpairs): loop_run_once never sleeps, and when no fd is ready
 * the clock jumps to the next due timer.  Hours of printer time run as
 * fast as the CPU allows.  Call before adding timers; there is no way back.
 */
void loop_set_virtual(struct loop *l);

/* Thread-safe: run fn(ud) on the loop thread soon.  SF_ENOMEM on failure. */
int loop_post(struct loop *l, loop_post_fn fn, void *ud);

/* Deliver signo through fn (blocks it for normal delivery in this process). */
int loop_add_signal(struct loop *l, int signo, loop_signal_fn fn, void *ud, struct sf_err *err);

/*
 * Wait up to timeout_ms (-1: until the next timer or event) and dispatch
 * what is ready.  Returns the number of callbacks run (>= 0) or an error.
 */
int loop_run_once(struct loop *l, int timeout_ms);
/*
 * The longest one loop_run_once spent running callbacks since loop_new, ms
 * (0 with simulated time): how long the loop stalled at worst, every
 * printer and socket waiting meanwhile.
 */
int64_t loop_turn_max_ms(const struct loop *l);
/* Run until loop_stop(). */
int loop_run(struct loop *l);
/* Make loop_run() return after the current iteration (thread-safe). */
void loop_stop(struct loop *l);

#endif
