/*
 * loop.c - PRIVATE STAND-IN for the event loop of loop.h, on branch farm
 * only.  The real loop.c is being written on another branch; when it
 * reaches main, `git merge main` replaces this file (delete this one on
 * the conflict) and nothing else changes, because the farm code uses only
 * loop.h.
 *
 * What it does: epoll for fds; timers in a binary min-heap keyed by
 * deadline (cancel is a linear search, fine for the handful of timers the
 * daemon keeps); loop_post() appends to a mutex-protected FIFO and writes
 * an eventfd; signals come through one signalfd.  Time is CLOCK_MONOTONIC,
 * read once per iteration.
 *
 * Thread: the loop's thread, except loop_post() and loop_stop(), which any
 * thread may call (the mutex protects the post queue; stop is atomic).
 */
#include "loop.h"

#include <errno.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/eventfd.h>
#include <sys/signalfd.h>
#include <time.h>
#include <unistd.h>

#include "mem.h"

#define LOOP_SIGNALS_MAX 16 /* SIGINT, SIGTERM, SIGHUP, SIGCHLD: a few suffice */

/* A watched fd; slot fds[fd] while watched. */
struct watch {
    loop_fd_fn fn; /* callback */
    void *ud;      /* its argument */
};

struct timer {
    int64_t when_ms;  /* deadline, loop time */
    uint64_t id;      /* > 0 */
    loop_timer_fn fn; /* callback */
    void *ud;         /* its argument */
};

struct post {
    loop_post_fn fn;   /* to run on the loop thread */
    void *ud;          /* its argument */
    struct post *next; /* FIFO */
};

struct loop {
    int ep;             /* epoll fd */
    int wake;           /* eventfd: posts and stop */
    int sig;            /* signalfd, -1 until a signal is added */
    sigset_t sigmask;   /* signals delivered through sig */
    struct watch **fds; /* indexed by fd; NULL if unwatched */
    size_t n_fds;       /* size of fds */
    struct timer *heap; /* min-heap on when_ms */
    size_t n_timers, cap_timers;
    uint64_t next_id;         /* next timer id */
    int64_t now_ms;           /* cached time of this iteration */
    pthread_mutex_t mu;       /* protects head/tail */
    struct post *head, *tail; /* posted work */
    atomic_bool stop;         /* loop_run returns */
    struct {
        int signo;
        loop_signal_fn fn;
        void *ud;
    } sigs[LOOP_SIGNALS_MAX]; /* signal callbacks */
    int n_sigs;
};

static int64_t
mono_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000 + ts.tv_nsec / 1000000;
}

struct loop *
loop_new(struct sf_err *err)
{
    struct loop *l = mem_calloc(1, sizeof(*l));
    if (!l) {
        sf_err_set(err, SF_ENOMEM, "loop: out of memory");
        return NULL;
    }
    l->sig = -1;
    l->wake = -1;
    sigemptyset(&l->sigmask);
    pthread_mutex_init(&l->mu, NULL);
    l->ep = epoll_create1(EPOLL_CLOEXEC);
    l->wake = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    struct epoll_event ev = { .events = EPOLLIN, .data.fd = -1 };
    if (l->ep < 0 || l->wake < 0 || epoll_ctl(l->ep, EPOLL_CTL_ADD, l->wake, &ev) != 0) {
        sf_err_sys(err, "loop: epoll/eventfd");
        loop_free(l);
        return NULL;
    }
    l->now_ms = mono_ms();
    l->next_id = 1;
    return l;
}

void
loop_free(struct loop *l)
{
    if (!l)
        return;
    for (size_t i = 0; i < l->n_fds; i++)
        free(l->fds[i]);
    free(l->fds);
    free(l->heap);
    for (struct post *p = l->head, *n; p; p = n) {
        n = p->next;
        free(p);
    }
    if (l->ep >= 0)
        close(l->ep);
    if (l->wake >= 0)
        close(l->wake);
    if (l->sig >= 0) {
        close(l->sig);
        sigprocmask(SIG_UNBLOCK, &l->sigmask, NULL);
    }
    pthread_mutex_destroy(&l->mu);
    free(l);
}

static uint32_t
ep_events(unsigned events)
{
    return (events & LOOP_READ ? EPOLLIN : 0) | (events & LOOP_WRITE ? EPOLLOUT : 0);
}

int
loop_add_fd(struct loop *l, int fd, unsigned events, loop_fd_fn fn, void *ud, struct sf_err *err)
{
    if (fd < 0)
        return sf_err_set(err, SF_EINVAL, "loop: bad fd %d", fd);
    if ((size_t)fd >= l->n_fds) {
        size_t n = l->n_fds;
        if (!mem_grow((void **)&l->fds, &n, (size_t)fd + 1, sizeof(*l->fds)))
            return sf_err_set(err, SF_ENOMEM, "loop: out of memory");
        memset(l->fds + l->n_fds, 0, (n - l->n_fds) * sizeof(*l->fds));
        l->n_fds = n;
    }
    if (l->fds[fd])
        return sf_err_set(err, SF_EINVAL, "loop: fd %d is already watched", fd);
    struct watch *w = mem_calloc(1, sizeof(*w));
    if (!w)
        return sf_err_set(err, SF_ENOMEM, "loop: out of memory");
    *w = (struct watch){ fn, ud };
    struct epoll_event ev = { .events = ep_events(events), .data.fd = fd };
    if (epoll_ctl(l->ep, EPOLL_CTL_ADD, fd, &ev) != 0) {
        free(w);
        return sf_err_sys(err, "loop: watch fd %d", fd);
    }
    l->fds[fd] = w;
    return SF_OK;
}

int
loop_mod_fd(struct loop *l, int fd, unsigned events, struct sf_err *err)
{
    struct epoll_event ev = { .events = ep_events(events), .data.fd = fd };
    if (fd < 0 || (size_t)fd >= l->n_fds || !l->fds[fd])
        return sf_err_set(err, SF_EINVAL, "loop: fd %d is not watched", fd);
    if (epoll_ctl(l->ep, EPOLL_CTL_MOD, fd, &ev) != 0)
        return sf_err_sys(err, "loop: modify fd %d", fd);
    return SF_OK;
}

void
loop_del_fd(struct loop *l, int fd)
{
    if (fd < 0 || (size_t)fd >= l->n_fds || !l->fds[fd])
        return;
    epoll_ctl(l->ep, EPOLL_CTL_DEL, fd, NULL);
    free(l->fds[fd]);
    l->fds[fd] = NULL;
}

static bool
earlier(const struct timer *a, const struct timer *b)
{
    return a->when_ms < b->when_ms || (a->when_ms == b->when_ms && a->id < b->id);
}

static void
heap_up(struct timer *h, size_t i)
{
    while (i > 0 && earlier(&h[i], &h[(i - 1) / 2])) {
        struct timer t = h[i];
        h[i] = h[(i - 1) / 2];
        h[(i - 1) / 2] = t;
        i = (i - 1) / 2;
    }
}

static void
heap_down(struct timer *h, size_t n, size_t i)
{
    for (;;) {
        size_t m = i, a = 2 * i + 1, b = a + 1;
        if (a < n && earlier(&h[a], &h[m]))
            m = a;
        if (b < n && earlier(&h[b], &h[m]))
            m = b;
        if (m == i)
            return;
        struct timer t = h[i];
        h[i] = h[m];
        h[m] = t;
        i = m;
    }
}

uint64_t
loop_timer_add(struct loop *l, int64_t delay_ms, loop_timer_fn fn, void *ud)
{
    if (!mem_grow((void **)&l->heap, &l->cap_timers, l->n_timers + 1, sizeof(*l->heap)))
        return 0;
    struct timer *t = &l->heap[l->n_timers];
    *t = (struct timer){ l->now_ms + (delay_ms > 0 ? delay_ms : 0), l->next_id++, fn, ud };
    heap_up(l->heap, l->n_timers++);
    return l->next_id - 1;
}

static void
heap_remove(struct loop *l, size_t i)
{
    l->heap[i] = l->heap[--l->n_timers];
    if (i < l->n_timers) {
        heap_down(l->heap, l->n_timers, i);
        heap_up(l->heap, i);
    }
}

void
loop_timer_cancel(struct loop *l, uint64_t id)
{
    for (size_t i = 0; i < l->n_timers; i++)
        if (l->heap[i].id == id) {
            heap_remove(l, i);
            return;
        }
}

int64_t
loop_now_ms(struct loop *l)
{
    return l->now_ms;
}

int
loop_post(struct loop *l, loop_post_fn fn, void *ud)
{
    struct post *p = mem_alloc(sizeof(*p));
    if (!p)
        return SF_ENOMEM;
    *p = (struct post){ fn, ud, NULL };
    pthread_mutex_lock(&l->mu);
    if (l->tail)
        l->tail->next = p;
    else
        l->head = p;
    l->tail = p;
    pthread_mutex_unlock(&l->mu);
    uint64_t one = 1;
    ssize_t w = write(l->wake, &one, sizeof(one));
    (void)w; /* a full counter still wakes the loop */
    return SF_OK;
}

int
loop_add_signal(struct loop *l, int signo, loop_signal_fn fn, void *ud, struct sf_err *err)
{
    if (l->n_sigs == LOOP_SIGNALS_MAX)
        return sf_err_set(err, SF_ENOMEM, "loop: too many signals");
    sigaddset(&l->sigmask, signo);
    if (sigprocmask(SIG_BLOCK, &l->sigmask, NULL) != 0)
        return sf_err_sys(err, "loop: block signal %d", signo);
    int fd = signalfd(l->sig, &l->sigmask, SFD_NONBLOCK | SFD_CLOEXEC);
    if (fd < 0)
        return sf_err_sys(err, "loop: signalfd");
    if (l->sig < 0) {
        struct epoll_event ev = { .events = EPOLLIN, .data.fd = -2 };
        if (epoll_ctl(l->ep, EPOLL_CTL_ADD, fd, &ev) != 0) {
            close(fd);
            return sf_err_sys(err, "loop: watch signalfd");
        }
        l->sig = fd;
    }
    l->sigs[l->n_sigs].signo = signo;
    l->sigs[l->n_sigs].fn = fn;
    l->sigs[l->n_sigs].ud = ud;
    l->n_sigs++;
    return SF_OK;
}

static int
run_posts(struct loop *l)
{
    uint64_t v;
    ssize_t r = read(l->wake, &v, sizeof(v));
    (void)r;
    pthread_mutex_lock(&l->mu);
    struct post *p = l->head;
    l->head = l->tail = NULL;
    pthread_mutex_unlock(&l->mu);
    int n = 0;
    while (p) {
        struct post *next = p->next;
        p->fn(l, p->ud);
        free(p);
        p = next;
        n++;
    }
    return n;
}

static int
run_signals(struct loop *l)
{
    struct signalfd_siginfo si;
    int n = 0;
    while (read(l->sig, &si, sizeof(si)) == sizeof(si))
        for (int i = 0; i < l->n_sigs; i++)
            if ((int)si.ssi_signo == l->sigs[i].signo) {
                l->sigs[i].fn(l, l->sigs[i].signo, l->sigs[i].ud);
                n++;
            }
    return n;
}

int
loop_run_once(struct loop *l, int timeout_ms)
{
    l->now_ms = mono_ms();
    int wait = timeout_ms;
    if (l->n_timers) {
        int64_t due = l->heap[0].when_ms - l->now_ms;
        if (due < 0)
            due = 0;
        if (wait < 0 || due < wait)
            wait = due > 1000000 ? 1000000 : (int)due;
    }
    struct epoll_event ev[64];
    int n = epoll_wait(l->ep, ev, 64, wait);
    if (n < 0 && errno != EINTR)
        return SF_EIO;
    l->now_ms = mono_ms();
    int ran = 0;
    for (int i = 0; i < n; i++) {
        int fd = ev[i].data.fd;
        if (fd == -1) {
            ran += run_posts(l);
            continue;
        }
        if (fd == -2) {
            ran += run_signals(l);
            continue;
        }
        if ((size_t)fd >= l->n_fds || !l->fds[fd])
            continue; /* removed by an earlier callback of this iteration */
        unsigned e =
            (ev[i].events & EPOLLIN ? LOOP_READ : 0) | (ev[i].events & EPOLLOUT ? LOOP_WRITE : 0) |
            (ev[i].events & EPOLLHUP ? LOOP_HUP : 0) | (ev[i].events & EPOLLERR ? LOOP_ERROR : 0);
        struct watch w = *l->fds[fd];
        w.fn(l, fd, e, w.ud);
        ran++;
    }
    /* Timers armed by these callbacks wait for the next iteration, so a
       timer re-arming itself with delay 0 cannot starve everything else. */
    uint64_t first_new = l->next_id;
    while (l->n_timers && l->heap[0].when_ms <= l->now_ms && l->heap[0].id < first_new) {
        struct timer t = l->heap[0];
        heap_remove(l, 0);
        t.fn(l, t.ud);
        ran++;
    }
    return ran;
}

int
loop_run(struct loop *l)
{
    while (!atomic_load(&l->stop)) {
        int rc = loop_run_once(l, -1);
        if (rc < 0)
            return rc;
    }
    atomic_store(&l->stop, false);
    return SF_OK;
}

void
loop_stop(struct loop *l)
{
    atomic_store(&l->stop, true);
    uint64_t one = 1;
    ssize_t w = write(l->wake, &one, sizeof(one));
    (void)w;
}
