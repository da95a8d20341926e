/*
 * test_transport.c - TCP host names are resolved off the loop: a lookup that
 * never answers leaves the other transports on the loop flowing, bytes
 * written meanwhile go out once it resolves, freeing the transport cancels
 * it (ASan sees no leak or use after free), a name that does not resolve
 * closes the transport with a message naming the host, and the number of
 * lookups in flight is capped.  Real sockets, threads and the system
 * resolver; the only stand-in is an injected resolver that waits on a pipe
 * before calling the real getaddrinfo (a nameserver that does not answer
 * cannot be set up without root).
 */
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "../../drivers/marlin/transport.h"
#include "../../src/base/limits.h"
#include "../t.h"

/* Read end of the gate the stalled resolver waits on; closing the write end opens it. */
static atomic_int gate_fd = -1;
static atomic_int resolver_calls;

static int
stalled_resolver(const char *host, const char *service, const struct addrinfo *hints,
                 struct addrinfo **res)
{
    (void)host;
    atomic_fetch_add(&resolver_calls, 1);
    char c;
    while (read(atomic_load(&gate_fd), &c, 1) < 0 && errno == EINTR)
        ;
    /* The gate is open: answer like a resolver that knew the name all along. */
    return getaddrinfo("127.0.0.1", service, hints, res);
}

/* A closed gate; *release is the write end to close. */
static int
gate_close(int *release)
{
    int p[2];
    if (pipe(p) < 0)
        return -1;
    atomic_store(&gate_fd, p[0]);
    atomic_store(&resolver_calls, 0);
    *release = p[1];
    return 0;
}

static void
gate_done(int release)
{
    if (release >= 0)
        close(release);
}

/* Wait until every lookup thread has ended, then drop the gate's read end. */
static bool
lookups_drained(void)
{
    for (int i = 0; i < 400 && transport_lookups_alive() > 0; i++)
        usleep(5000);
    int fd = atomic_exchange(&gate_fd, -1);
    if (fd >= 0)
        close(fd);
    return transport_lookups_alive() == 0;
}

struct sink {
    char got[512];
    size_t n;
    int closes;
    char why[256];
};

static void
sink_data(void *ud, const char *data, size_t n)
{
    struct sink *s = ud;
    size_t room = sizeof(s->got) - 1 - s->n;
    if (n > room)
        n = room;
    memcpy(s->got + s->n, data, n);
    s->n += n;
    s->got[s->n] = '\0';
}

static void
sink_close(void *ud, const char *why)
{
    struct sink *s = ud;
    s->closes++;
    snprintf(s->why, sizeof(s->why), "%s", why);
}

/* A listening loopback socket; *port gets its port. */
static int
listener(int *port)
{
    int fd = socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    struct sockaddr_in a = { .sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK) };
    socklen_t al = sizeof(a);
    if (fd < 0 || bind(fd, (struct sockaddr *)&a, sizeof(a)) < 0 || listen(fd, 8) < 0 ||
        getsockname(fd, (struct sockaddr *)&a, &al) < 0)
        return -1;
    *port = ntohs(a.sin_port);
    return fd;
}

/* Run the loop until the listener accepts a connection (or 2 s pass). */
static int
accept_on_loop(struct loop *l, int lfd)
{
    for (int i = 0; i < 200; i++) {
        int c = accept4(lfd, NULL, NULL, SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (c >= 0)
            return c;
        loop_run_once(l, 10);
    }
    return -1;
}

/* Run the loop until s holds want (or 2 s pass). */
static bool
loop_until_got(struct loop *l, struct sink *s, const char *want)
{
    for (int i = 0; i < 200 && !strstr(s->got, want); i++)
        loop_run_once(l, 10);
    return strstr(s->got, want) != NULL;
}

/* Read from a non-blocking peer socket, running the loop, until want arrives. */
static bool
peer_until_got(struct loop *l, int fd, char *buf, size_t cap, const char *want)
{
    size_t n = 0;
    buf[0] = '\0';
    for (int i = 0; i < 200 && !strstr(buf, want); i++) {
        ssize_t r = read(fd, buf + n, cap - 1 - n);
        if (r > 0) {
            n += (size_t)r;
            buf[n] = '\0';
            continue;
        }
        loop_run_once(l, 10);
    }
    return strstr(buf, want) != NULL;
}

T_CASE(transport_stalled_lookup_leaves_other_links_flowing)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    T_TRUE(l != NULL);
    int port, release;
    int lfd = listener(&port);
    T_TRUE(lfd >= 0);
    T_TRUE(gate_close(&release) == 0);
    transport_set_resolver(stalled_resolver);

    char spec[64];
    snprintf(spec, sizeof(spec), "tcp://127.0.0.1:%d", port);
    struct sink fast = { 0 }, late = { 0 };
    struct transport *tf = transport_open(l, spec, 0, sink_data, sink_close, &fast, &err);
    T_TRUE(tf != NULL);
    int pf = accept_on_loop(l, lfd);
    T_TRUE(pf >= 0);

    /* Before this change transport_open ran the lookup itself and hung here. */
    snprintf(spec, sizeof(spec), "tcp://printer-7.farm.test:%d", port);
    struct transport *tl = transport_open(l, spec, 0, sink_data, sink_close, &late, &err);
    T_TRUE(tl != NULL);
    T_OK(transport_write(tl, "queued while resolving\n", 23), NULL);
    for (int i = 0; i < 200 && atomic_load(&resolver_calls) == 0; i++)
        usleep(5000);
    T_EQ_INT(atomic_load(&resolver_calls), 1);

    /* 50 round trips on the numeric link while the lookup hangs. */
    struct timespec t0, t1;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    char buf[512];
    for (int i = 0; i < 50; i++) {
        char ping[32];
        int n = snprintf(ping, sizeof(ping), "ping %d\n", i);
        T_EQ_INT(write(pf, ping, (size_t)n), n);
        T_TRUE(loop_until_got(l, &fast, ping));
        T_OK(transport_write(tf, ping, (size_t)n), NULL);
        T_TRUE(peer_until_got(l, pf, buf, sizeof(buf), ping));
    }
    clock_gettime(CLOCK_MONOTONIC, &t1);
    double secs = (double)(t1.tv_sec - t0.tv_sec) + 1e-9 * (double)(t1.tv_nsec - t0.tv_nsec);
    T_TRUE(secs < 2.0);
    T_EQ_INT(transport_lookups_alive(), 1);
    T_EQ_INT(late.closes, 0);
    T_EQ_INT(fast.closes, 0);

    /* The lookup answers: the late transport connects and sends what was queued. */
    gate_done(release);
    int pl = accept_on_loop(l, lfd);
    T_TRUE(pl >= 0);
    T_TRUE(peer_until_got(l, pl, buf, sizeof(buf), "queued while resolving\n"));
    T_OK(write(pl, "ok\n", 3) == 3 ? 0 : -1, NULL);
    T_TRUE(loop_until_got(l, &late, "ok\n"));
    T_EQ_INT(late.closes, 0);

    transport_free(tl);
    transport_free(tf);
    close(pl);
    close(pf);
    close(lfd);
    transport_set_resolver(NULL);
    T_TRUE(lookups_drained());
    loop_free(l);
}

T_CASE(transport_free_cancels_a_lookup)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    T_TRUE(l != NULL);
    int release;
    T_TRUE(gate_close(&release) == 0);
    transport_set_resolver(stalled_resolver);
    struct sink s = { 0 };

    /* Freed while the thread still waits: the thread frees the request. */
    struct transport *t =
        transport_open(l, "tcp://stuck.farm.test:23", 0, sink_data, sink_close, &s, &err);
    T_TRUE(t != NULL);
    T_OK(transport_write(t, "M105\n", 5), NULL);
    transport_free(t);
    gate_done(release);
    T_TRUE(lookups_drained());

    /* Freed after the thread answered but before the loop saw it: freed here. */
    T_TRUE(gate_close(&release) == 0);
    gate_done(release);
    t = transport_open(l, "tcp://done.farm.test:23", 0, sink_data, sink_close, &s, &err);
    T_TRUE(t != NULL);
    for (int i = 0; i < 400 && transport_lookups_alive() > 0; i++)
        usleep(5000);
    T_EQ_INT(transport_lookups_alive(), 0);
    transport_free(t);
    T_TRUE(lookups_drained());

    for (int i = 0; i < 5; i++)
        loop_run_once(l, 1);
    T_EQ_INT(s.closes, 0);
    transport_set_resolver(NULL);
    loop_free(l);
}

T_CASE(transport_unresolvable_host_is_named)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    T_TRUE(l != NULL);
    /* The real resolver: one try, 1 s, so an offline machine answers EAI_AGAIN soon. */
    setenv("RES_OPTIONS", "timeout:1 attempts:1", 1);
    transport_set_resolver(NULL);
    struct sink s = { 0 };
    /* .invalid never resolves (RFC 6761). */
    struct transport *t =
        transport_open(l, "tcp://no-such-printer.invalid:8899", 0, sink_data, sink_close, &s, &err);
    T_TRUE(t != NULL);
    for (int i = 0; i < 1000 && s.closes == 0; i++)
        loop_run_once(l, 10);
    T_EQ_INT(s.closes, 1);
    T_TRUE(strstr(s.why, "cannot resolve host 'no-such-printer.invalid'") != NULL);
    T_EQ_INT(transport_write(t, "x", 1), SF_EIO);
    transport_free(t);
    T_TRUE(lookups_drained());
    loop_free(l);
}

T_CASE(transport_lookups_are_capped)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    T_TRUE(l != NULL);
    int release;
    T_TRUE(gate_close(&release) == 0);
    transport_set_resolver(stalled_resolver);
    struct sink s = { 0 };
    struct transport *t[SF_RESOLVER_THREADS_MAX];
    for (int i = 0; i < SF_RESOLVER_THREADS_MAX; i++) {
        t[i] = transport_open(l, "tcp://stuck.farm.test:23", 0, sink_data, sink_close, &s, &err);
        T_TRUE(t[i] != NULL);
    }
    struct transport *over =
        transport_open(l, "tcp://one-more.farm.test:23", 0, sink_data, sink_close, &s, &err);
    T_TRUE(over == NULL);
    T_ERR(err.code, SF_EAGAIN, &err, "host name lookups already in progress");
    /* Numeric addresses need no lookup and still open. */
    over = transport_open(l, "tcp://127.0.0.1:9", 0, sink_data, sink_close, &s, &err);
    T_TRUE(over != NULL);
    transport_free(over);
    for (int i = 0; i < SF_RESOLVER_THREADS_MAX; i++)
        transport_free(t[i]);
    gate_done(release);
    T_TRUE(lookups_drained());
    transport_set_resolver(NULL);
    loop_free(l);
}
