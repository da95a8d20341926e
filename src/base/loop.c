/*
 * loop.c - the epoll event loop behind loop.h.
 *
 * Why: every printer link, socket, timer and signal of the daemon lives on
 * one thread (STYLE.md, "Threads"), so printer state needs no locks and
 * tests can step the loop with loop_run_once().
 *
 * Design: fds are registered with a heap-allocated record whose pointer is
 * the epoll cookie, found by fd in a table indexed by the fd (a farm of
 * 1,000 network printers watches 2,000 fds and adds and deletes a few
 * hundred a second as libcurl's connections come and go: a list walked
 * for each cost a fifth of the daemon's time); loop_del_fd() only marks
 * the record dead and parks it on a list freed after the current
 * dispatch, so a callback may delete any fd (its own included) while
 * events for it are still in the batch.  Timers
 * sit in a binary min-heap ordered by (due time, id); cancelling searches
 * the heap linearly, which is fine for the few dozen timers a farm has.
 * loop_post() appends to a mutex-protected FIFO and writes an eventfd, the
 * only cross-thread path.  Signals come through one signalfd.
 *
 * Thread: loop thread only, except loop_post() and loop_stop().
 */
#include "loop.h"

#include <errno.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/eventfd.h>
#include <sys/signalfd.h>
#include <time.h>
#include <unistd.h>

#include "clock.h"
#include "mem.h"

#define LOOP_EVENTS_MAX  64
#define LOOP_SIGNALS_MAX 8

struct fd_reg {
    int fd;              /* watched descriptor */
    unsigned events;     /* LOOP_READ | LOOP_WRITE currently asked for */
    loop_fd_fn fn;       /* callback */
    void *ud;            /* its argument */
    bool dead;           /* deleted; freed after the current dispatch */
    struct fd_reg *next; /* in loop->graveyard, once dead */
};

struct timer {
    int64_t due_ms;   /* loop time it fires */
    uint64_t id;      /* > 0, unique per loop */
    loop_timer_fn fn; /* callback */
    void *ud;         /* its argument */
};

struct post {
    loop_post_fn fn;   /* callback */
    void *ud;          /* its argument */
    struct post *next; /* FIFO link */
};

struct sig_reg {
    int signo;         /* signal number, 0 = slot free */
    loop_signal_fn fn; /* callback */
    void *ud;          /* its argument */
};

struct loop {
    int epfd;                 /* the epoll instance */
    int evfd;                 /* eventfd woken by loop_post() */
    int sigfd;                /* signalfd, -1 until the first loop_add_signal() */
    sigset_t sigmask;         /* signals routed to sigfd */
    int64_t now_ms;           /* cached CLOCK_MONOTONIC of this iteration */
    struct fd_reg **by_fd;    /* live registrations by fd (NULL: not watched) */
    size_t n_by_fd;           /* entries of by_fd */
    struct fd_reg *graveyard; /* deleted during dispatch, freed after it */
    struct timer *heap;       /* min-heap of timers */
    size_t n_timers, cap_timers;
    uint64_t next_timer_id;    /* last id handed out */
    pthread_mutex_t post_lock; /* protects post_head/post_tail */
    struct post *post_head, *post_tail;
    struct sig_reg sigs[LOOP_SIGNALS_MAX];
    atomic_bool stop;    /* loop_run() should return */
    bool virtual_time;   /* loop_set_virtual(): now_ms moves only to the next due timer */
    int64_t turn_max_ms; /* the longest dispatch of one loop_run_once (loop_turn_max_ms) */
};

static void
on_eventfd(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)events;
    (void)ud;
    uint64_t v;
    if (read(fd, &v, sizeof(v)) < 0 && errno != EAGAIN)
        return;
    pthread_mutex_lock(&l->post_lock);
    struct post *p = l->post_head;
    l->post_head = l->post_tail = NULL;
    pthread_mutex_unlock(&l->post_lock);
    while (p) {
        struct post *next = p->next;
        p->fn(l, p->ud);
        free(p);
        p = next;
    }
}

struct loop *
loop_new(struct sf_err *err)
{
    struct loop *l = mem_calloc(1, sizeof(*l));
    if (!l) {
        sf_err_set(err, SF_ENOMEM, "loop: out of memory");
        return NULL;
    }
    l->sigfd = -1;
    l->epfd = epoll_create1(EPOLL_CLOEXEC);
    if (l->epfd < 0) {
        sf_err_sys(err, "loop: epoll_create1");
        goto free_loop;
    }
    l->evfd = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    if (l->evfd < 0) {
        sf_err_sys(err, "loop: eventfd");
        goto close_ep;
    }
    pthread_mutex_init(&l->post_lock, NULL);
    sigemptyset(&l->sigmask);
    l->now_ms = clock_mono_ms();
    if (loop_add_fd(l, l->evfd, LOOP_READ, on_eventfd, NULL, err) < 0)
        goto close_ev;
    return l;
close_ev:
    close(l->evfd);
    pthread_mutex_destroy(&l->post_lock);
close_ep:
    close(l->epfd);
free_loop:
    free(l);
    return NULL;
}

static void
free_regs(struct fd_reg *r)
{
    while (r) {
        struct fd_reg *next = r->next;
        free(r);
        r = next;
    }
}

void
loop_free(struct loop *l)
{
    if (!l)
        return;
    for (size_t i = 0; i < l->n_by_fd; i++)
        free(l->by_fd[i]);
    free(l->by_fd);
    free_regs(l->graveyard);
    free(l->heap);
    struct post *p = l->post_head;
    while (p) {
        struct post *next = p->next;
        free(p);
        p = next;
    }
    if (l->sigfd >= 0) {
        close(l->sigfd);
        sigprocmask(SIG_UNBLOCK, &l->sigmask, NULL);
    }
    close(l->evfd);
    close(l->epfd);
    pthread_mutex_destroy(&l->post_lock);
    free(l);
}

static uint32_t
to_epoll(unsigned events)
{
    return (events & LOOP_READ ? EPOLLIN : 0u) | (events & LOOP_WRITE ? EPOLLOUT : 0u);
}

static struct fd_reg *
find_reg(struct loop *l, int fd)
{
    return fd >= 0 && (size_t)fd < l->n_by_fd ? l->by_fd[fd] : NULL;
}

/* Room in by_fd for fd; false when out of memory. */
static bool
grow_by_fd(struct loop *l, int fd)
{
    if ((size_t)fd < l->n_by_fd)
        return true;
    size_t n = l->n_by_fd ? l->n_by_fd : 64;
    while (n <= (size_t)fd)
        n *= 2;
    struct fd_reg **t = mem_realloc_array(l->by_fd, n, sizeof(*t));
    if (!t)
        return false;
    memset(t + l->n_by_fd, 0, (n - l->n_by_fd) * sizeof(*t));
    l->by_fd = t;
    l->n_by_fd = n;
    return true;
}

int
loop_add_fd(struct loop *l, int fd, unsigned events, loop_fd_fn fn, void *ud, struct sf_err *err)
{
    if (fd < 0 || !fn)
        return sf_err_set(err, SF_EINVAL, "loop: bad fd %d or no callback", fd);
    if (find_reg(l, fd))
        return sf_err_set(err, SF_EINVAL, "loop: fd %d is already watched", fd);
    struct fd_reg *r = grow_by_fd(l, fd) ? mem_calloc(1, sizeof(*r)) : NULL;
    if (!r)
        return sf_err_set(err, SF_ENOMEM, "loop: out of memory");
    r->fd = fd;
    r->events = events;
    r->fn = fn;
    r->ud = ud;
    struct epoll_event ev = { .events = to_epoll(events), .data.ptr = r };
    if (epoll_ctl(l->epfd, EPOLL_CTL_ADD, fd, &ev) < 0) {
        free(r);
        return sf_err_sys(err, "loop: watch fd %d", fd);
    }
    l->by_fd[fd] = r;
    return SF_OK;
}

int
loop_mod_fd(struct loop *l, int fd, unsigned events, struct sf_err *err)
{
    struct fd_reg *r = find_reg(l, fd);
    if (!r)
        return sf_err_set(err, SF_ENOTFOUND, "loop: fd %d is not watched", fd);
    if (r->events == events)
        return SF_OK;
    struct epoll_event ev = { .events = to_epoll(events), .data.ptr = r };
    if (epoll_ctl(l->epfd, EPOLL_CTL_MOD, fd, &ev) < 0)
        return sf_err_sys(err, "loop: change events of fd %d", fd);
    r->events = events;
    return SF_OK;
}

void
loop_del_fd(struct loop *l, int fd)
{
    struct fd_reg *r = find_reg(l, fd);
    if (!r)
        return;
    l->by_fd[fd] = NULL;
    /* The fd may already be closed by its owner; then epoll dropped it. */
    epoll_ctl(l->epfd, EPOLL_CTL_DEL, fd, NULL);
    r->dead = true;
    r->next = l->graveyard;
    l->graveyard = r;
}

/* Heap order: earlier due first, then lower id (FIFO among equal times). */
static bool
timer_less(const struct timer *a, const struct timer *b)
{
    return a->due_ms < b->due_ms || (a->due_ms == b->due_ms && a->id < b->id);
}

static void
heap_swap(struct loop *l, size_t a, size_t b)
{
    struct timer t = l->heap[a];
    l->heap[a] = l->heap[b];
    l->heap[b] = t;
}

static void
sift_up(struct loop *l, size_t i)
{
    while (i > 0) {
        size_t parent = (i - 1) / 2;
        if (!timer_less(&l->heap[i], &l->heap[parent]))
            break;
        heap_swap(l, i, parent);
        i = parent;
    }
}

static void
sift_down(struct loop *l, size_t i)
{
    for (;;) {
        size_t left = 2 * i + 1, right = left + 1, best = i;
        if (left < l->n_timers && timer_less(&l->heap[left], &l->heap[best]))
            best = left;
        if (right < l->n_timers && timer_less(&l->heap[right], &l->heap[best]))
            best = right;
        if (best == i)
            return;
        heap_swap(l, i, best);
        i = best;
    }
}

static void
heap_remove(struct loop *l, size_t i)
{
    l->n_timers--;
    if (i == l->n_timers)
        return;
    l->heap[i] = l->heap[l->n_timers];
    sift_down(l, i);
    sift_up(l, i);
}

uint64_t
loop_timer_add(struct loop *l, int64_t delay_ms, loop_timer_fn fn, void *ud)
{
    if (!mem_grow((void **)&l->heap, &l->cap_timers, l->n_timers + 1, sizeof(*l->heap)))
        return 0;
    if (delay_ms < 0)
        delay_ms = 0;
    struct timer *t = &l->heap[l->n_timers];
    t->due_ms = l->now_ms + delay_ms;
    t->id = ++l->next_timer_id;
    t->fn = fn;
    t->ud = ud;
    sift_up(l, l->n_timers++);
    return l->next_timer_id;
}

void
loop_timer_cancel(struct loop *l, uint64_t id)
{
    for (size_t i = 0; i < l->n_timers; i++) {
        if (l->heap[i].id == id) {
            heap_remove(l, i);
            return;
        }
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
    p->fn = fn;
    p->ud = ud;
    p->next = NULL;
    pthread_mutex_lock(&l->post_lock);
    if (l->post_tail)
        l->post_tail->next = p;
    else
        l->post_head = p;
    l->post_tail = p;
    pthread_mutex_unlock(&l->post_lock);
    uint64_t one = 1;
    if (write(l->evfd, &one, sizeof(one)) < 0 && errno != EAGAIN)
        return SF_EIO;
    return SF_OK;
}

static void
on_signalfd(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)events;
    (void)ud;
    struct signalfd_siginfo si;
    while (read(fd, &si, sizeof(si)) == (ssize_t)sizeof(si)) {
        for (int i = 0; i < LOOP_SIGNALS_MAX; i++)
            if (l->sigs[i].signo == (int)si.ssi_signo)
                l->sigs[i].fn(l, (int)si.ssi_signo, l->sigs[i].ud);
    }
}

int
loop_add_signal(struct loop *l, int signo, loop_signal_fn fn, void *ud, struct sf_err *err)
{
    int slot = -1;
    for (int i = 0; i < LOOP_SIGNALS_MAX; i++) {
        if (l->sigs[i].signo == signo)
            return sf_err_set(err, SF_EINVAL, "loop: signal %d already handled", signo);
        if (l->sigs[i].signo == 0 && slot < 0)
            slot = i;
    }
    if (slot < 0)
        return sf_err_set(err, SF_ENOMEM, "loop: more than %d signals", LOOP_SIGNALS_MAX);
    sigset_t mask = l->sigmask;
    if (sigaddset(&mask, signo) < 0)
        return sf_err_set(err, SF_EINVAL, "loop: bad signal %d", signo);
    if (sigprocmask(SIG_BLOCK, &mask, NULL) < 0)
        return sf_err_sys(err, "loop: block signal %d", signo);
    int fd = signalfd(l->sigfd, &mask, SFD_NONBLOCK | SFD_CLOEXEC);
    if (fd < 0)
        return sf_err_sys(err, "loop: signalfd");
    if (l->sigfd < 0) {
        int rc = loop_add_fd(l, fd, LOOP_READ, on_signalfd, NULL, err);
        if (rc < 0) {
            close(fd);
            return rc;
        }
        l->sigfd = fd;
    }
    l->sigmask = mask;
    l->sigs[slot].signo = signo;
    l->sigs[slot].fn = fn;
    l->sigs[slot].ud = ud;
    return SF_OK;
}

static unsigned
from_epoll(uint32_t ev)
{
    return (ev & EPOLLIN ? LOOP_READ : 0u) | (ev & EPOLLOUT ? LOOP_WRITE : 0u) |
           (ev & (EPOLLHUP | EPOLLRDHUP) ? LOOP_HUP : 0u) | (ev & EPOLLERR ? LOOP_ERROR : 0u);
}

void
loop_set_virtual(struct loop *l)
{
    l->virtual_time = true;
}

/* Simulated time: wait for nothing; when nothing is ready, time jumps to the next timer. */
static int
run_once_virtual(struct loop *l, struct epoll_event *evs)
{
    int n = epoll_wait(l->epfd, evs, LOOP_EVENTS_MAX, 0);
    if (n == 0 && l->n_timers > 0 && l->heap[0].due_ms > l->now_ms)
        l->now_ms = l->heap[0].due_ms;
    return n;
}

int
loop_run_once(struct loop *l, int timeout_ms)
{
    struct epoll_event evs[LOOP_EVENTS_MAX];
    int n;
    if (l->virtual_time) {
        n = run_once_virtual(l, evs);
        goto dispatch;
    }
    l->now_ms = clock_mono_ms();
    if (l->n_timers > 0) {
        int64_t wait = l->heap[0].due_ms - l->now_ms;
        if (wait < 0)
            wait = 0;
        if (timeout_ms < 0 || wait < timeout_ms)
            timeout_ms = (int)(wait > 1000000 ? 1000000 : wait);
    }
    n = epoll_wait(l->epfd, evs, LOOP_EVENTS_MAX, timeout_ms);
    l->now_ms = clock_mono_ms();
dispatch:
    if (n < 0) {
        if (errno == EINTR)
            return 0;
        return SF_EIO;
    }
    int ran = 0;
    for (int i = 0; i < n; i++) {
        struct fd_reg *r = evs[i].data.ptr;
        if (r->dead)
            continue;
        r->fn(l, r->fd, from_epoll(evs[i].events), r->ud);
        ran++;
    }
    /* Timers due now; ones added by callbacks with delay 0 wait a round. */
    int64_t now = l->now_ms;
    uint64_t last_id = l->next_timer_id;
    while (l->n_timers > 0 && l->heap[0].due_ms <= now && l->heap[0].id <= last_id) {
        struct timer t = l->heap[0];
        heap_remove(l, 0);
        t.fn(l, t.ud);
        ran++;
    }
    free_regs(l->graveyard);
    l->graveyard = NULL;
    if (!l->virtual_time) {
        int64_t took = clock_mono_ms() - l->now_ms;
        if (took > l->turn_max_ms)
            l->turn_max_ms = took;
    }
    return ran;
}

int64_t
loop_turn_max_ms(const struct loop *l)
{
    return l->turn_max_ms;
}

int
loop_run(struct loop *l)
{
    /* A stop asked for before run started still counts (a thread may call
       loop_stop first): clear it on the way out, never on the way in. */
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
    /* Wake epoll_wait; a full eventfd counter means a wake-up is pending anyway. */
    if (write(l->evfd, &one, sizeof(one)) < 0)
        return;
}
