/*
 * test_loopcontract.c - the event loop against the contract in loop.h:
 * fd readiness, timers in deadline order, cancel, re-arm without
 * starvation, loop_post from another thread in FIFO order, signals
 * through signalfd, loop_stop.  Written against the header only, so it
 * checks whichever loop.c is built (branch farm's stand-in or the real
 * one once merged).
 */
#include <pthread.h>
#include <signal.h>
#include <unistd.h>

#include "../../src/base/loop.h"
#include "../t.h"

static char trace[64];

static void
mark(struct loop *l, void *ud)
{
    (void)l;
    size_t n = strlen(trace);
    if (n + 1 < sizeof(trace)) {
        trace[n] = *(const char *)ud;
        trace[n + 1] = '\0';
    }
}

T_CASE(loop_timers_fire_in_deadline_order_and_cancel)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    T_TRUE(l != NULL);
    trace[0] = '\0';
    loop_timer_add(l, 30, mark, "c");
    loop_timer_add(l, 10, mark, "a");
    uint64_t x = loop_timer_add(l, 20, mark, "x");
    loop_timer_add(l, 20, mark, "b");
    loop_timer_cancel(l, x);
    loop_timer_cancel(l, 12345); /* unknown: harmless */
    for (int i = 0; i < 10 && strlen(trace) < 3; i++)
        T_OK(loop_run_once(l, 100), &err);
    T_EQ_STR(trace, "abc");
    loop_timer_cancel(l, x); /* fired/cancelled: harmless */
    loop_free(l);
}

static void
rearm(struct loop *l, void *ud)
{
    int *n = ud;
    if (++*n < 1000)
        loop_timer_add(l, 0, rearm, ud);
}

T_CASE(loop_zero_delay_rearm_does_not_starve)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    int n = 0;
    loop_timer_add(l, 0, rearm, &n);
    T_OK(loop_run_once(l, 0), &err);
    T_EQ_INT(n, 1); /* one per iteration, not 1000 at once */
    loop_free(l);
}

static void
on_read(struct loop *l, int fd, unsigned events, void *ud)
{
    char c;
    T_TRUE(events & LOOP_READ);
    if (read(fd, &c, 1) == 1)
        *(char *)ud = c;
    loop_del_fd(l, fd); /* allowed from its own callback */
}

T_CASE(loop_fd_readiness)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    int p[2];
    T_TRUE(pipe(p) == 0);
    char got = 0;
    T_OK(loop_add_fd(l, p[0], LOOP_READ, on_read, &got, &err), &err);
    T_EQ_INT(loop_add_fd(l, p[0], LOOP_READ, on_read, &got, &err), SF_EINVAL);
    T_EQ_INT(loop_run_once(l, 0), 0);
    T_TRUE(write(p[1], "z", 1) == 1);
    T_EQ_INT(loop_run_once(l, 1000), 1);
    T_EQ_INT(got, 'z');
    close(p[0]);
    close(p[1]);
    loop_free(l);
}

static struct loop *post_loop;

static void *
poster(void *arg)
{
    (void)arg;
    static const char letters[] = "0123456789";
    for (int i = 0; i < 10; i++)
        loop_post(post_loop, mark, (void *)&letters[i]);
    loop_stop(post_loop);
    return NULL;
}

T_CASE(loop_post_from_thread_is_fifo_and_stop_works)
{
    struct sf_err err;
    post_loop = loop_new(&err);
    trace[0] = '\0';
    pthread_t t;
    pthread_create(&t, NULL, poster, NULL);
    T_OK(loop_run(post_loop), &err); /* returns after loop_stop */
    pthread_join(t, NULL);
    for (int i = 0; i < 10 && strlen(trace) < 10; i++)
        loop_run_once(post_loop, 100);
    T_EQ_STR(trace, "0123456789");
    loop_free(post_loop);
}

static void
on_signal(struct loop *l, int signo, void *ud)
{
    (void)l;
    *(int *)ud = signo;
}

T_CASE(loop_signals_arrive_as_callbacks)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    int got = 0;
    T_OK(loop_add_signal(l, SIGUSR1, on_signal, &got, &err), &err);
    kill(getpid(), SIGUSR1);
    for (int i = 0; i < 10 && !got; i++)
        loop_run_once(l, 100);
    T_EQ_INT(got, SIGUSR1);
    loop_free(l);
}
