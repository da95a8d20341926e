/*
 * test_loop.c - the event loop: fds, timers in order, cancel, post from a
 * thread, signals, deleting fds from callbacks.  Real pipes, threads and
 * signals; no mocks.
 */
#include <pthread.h>
#include <signal.h>
#include <unistd.h>

#include "../../src/base/loop.h"
#include "../t.h"

static int order[16];
static int n_order;

static void
note(struct loop *l, void *ud)
{
    (void)l;
    if (n_order < 16)
        order[n_order++] = (int)(long)ud;
}

T_CASE(loop_timers_fire_in_due_order)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    T_TRUE(l != NULL);
    n_order = 0;
    loop_timer_add(l, 30, note, (void *)3L);
    loop_timer_add(l, 10, note, (void *)1L);
    uint64_t c = loop_timer_add(l, 20, note, (void *)9L);
    loop_timer_add(l, 20, note, (void *)2L);
    loop_timer_cancel(l, c);
    loop_timer_cancel(l, 12345); /* unknown: harmless */
    int64_t t0 = loop_now_ms(l);
    while (n_order < 3)
        T_OK(loop_run_once(l, 100), NULL);
    T_EQ_INT(order[0], 1);
    T_EQ_INT(order[1], 2);
    T_EQ_INT(order[2], 3);
    T_TRUE(loop_now_ms(l) - t0 >= 30);
    loop_free(l);
}

struct pipe_ctx {
    int reads;
    char got[32];
};

static void
on_pipe(struct loop *l, int fd, unsigned events, void *ud)
{
    struct pipe_ctx *c = ud;
    if (events & LOOP_READ) {
        ssize_t n = read(fd, c->got, sizeof(c->got) - 1);
        if (n > 0)
            c->got[n] = '\0';
        c->reads++;
        loop_del_fd(l, fd); /* deleting itself from its callback is allowed */
    }
}

T_CASE(loop_fd_readable_and_self_delete)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    int p[2];
    T_EQ_INT(pipe(p), 0);
    struct pipe_ctx c = { 0 };
    T_OK(loop_add_fd(l, p[0], LOOP_READ, on_pipe, &c, &err), &err);
    T_ERR(loop_add_fd(l, p[0], LOOP_READ, on_pipe, &c, &err), SF_EINVAL, &err, "already");
    T_EQ_INT(loop_run_once(l, 0), 0); /* nothing ready yet */
    T_EQ_INT(write(p[1], "hello", 5), 5);
    T_EQ_INT(loop_run_once(l, 1000), 1);
    T_EQ_STR(c.got, "hello");
    T_EQ_INT(write(p[1], "again", 5), 5);
    T_EQ_INT(loop_run_once(l, 20), 0); /* deleted: no more callbacks */
    T_EQ_INT(c.reads, 1);
    T_ERR(loop_mod_fd(l, p[0], LOOP_READ, &err), SF_ENOTFOUND, &err, "not watched");
    close(p[0]);
    close(p[1]);
    loop_free(l);
}

static void
on_writable(struct loop *l, int fd, unsigned events, void *ud)
{
    int *n = ud;
    if (events & LOOP_WRITE) {
        (*n)++;
        loop_mod_fd(l, fd, 0, NULL);
    }
}

T_CASE(loop_write_interest_toggles)
{
    struct loop *l = loop_new(NULL);
    int p[2];
    T_EQ_INT(pipe(p), 0);
    int n = 0;
    T_OK(loop_add_fd(l, p[1], LOOP_WRITE, on_writable, &n, NULL), NULL);
    loop_run_once(l, 100);
    loop_run_once(l, 10);
    T_EQ_INT(n, 1);
    loop_del_fd(l, p[1]);
    close(p[0]);
    close(p[1]);
    loop_free(l);
}

struct post_ctx {
    struct loop *l;
    int got;
};

static void
posted(struct loop *l, void *ud)
{
    struct post_ctx *c = ud;
    c->got++;
    if (c->got == 100)
        loop_stop(l);
}

static void *
poster(void *ud)
{
    struct post_ctx *c = ud;
    for (int i = 0; i < 100; i++)
        loop_post(c->l, posted, c);
    return NULL;
}

T_CASE(loop_post_from_thread_runs_on_loop)
{
    struct loop *l = loop_new(NULL);
    struct post_ctx c = { l, 0 };
    pthread_t th;
    T_EQ_INT(pthread_create(&th, NULL, poster, &c), 0);
    T_OK(loop_run(l), NULL);
    pthread_join(th, NULL);
    T_EQ_INT(c.got, 100);
    loop_free(l);
}

static void
on_sig(struct loop *l, int signo, void *ud)
{
    (void)l;
    *(int *)ud = signo;
}

T_CASE(loop_signal_arrives_as_callback)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    int got = 0;
    T_OK(loop_add_signal(l, SIGUSR1, on_sig, &got, &err), &err);
    T_ERR(loop_add_signal(l, SIGUSR1, on_sig, &got, &err), SF_EINVAL, &err, "already");
    kill(getpid(), SIGUSR1);
    for (int i = 0; i < 10 && !got; i++)
        loop_run_once(l, 100);
    T_EQ_INT(got, SIGUSR1);
    loop_free(l);
}

static void
rearm(struct loop *l, void *ud)
{
    int *n = ud;
    if (++*n < 5)
        loop_timer_add(l, 0, rearm, ud);
}

T_CASE(loop_zero_delay_rearm_waits_a_round)
{
    struct loop *l = loop_new(NULL);
    int n = 0;
    loop_timer_add(l, 0, rearm, &n);
    T_EQ_INT(loop_run_once(l, 0), 1);
    T_EQ_INT(n, 1);
    for (int i = 0; i < 10 && n < 5; i++)
        loop_run_once(l, 0);
    T_EQ_INT(n, 5);
    loop_free(l);
}
