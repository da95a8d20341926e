/*
 * transport.c - serial (libserialport), pty (plain fd) and TCP byte
 * transports on the event loop (transport.h).
 *
 * Why three: libserialport is the right tool for real USB/UART devices
 * (port enumeration with USB ids, portable termios), but its Linux backend
 * refuses pseudo-terminals, and serial bridges speak TCP.  The protocol
 * engines above see one interface.
 *
 * Design: each kind only differs in how it opens and how it reads/writes
 * (sp_nonblocking_read/write for serial, read/write for the others); all
 * of them expose an fd the loop watches.  Writes go straight out while the
 * OS takes them, the rest waits in a capped buffer with write interest on.
 * Errors and hang-ups close the transport once and report why.
 *
 * Host names: a numeric address connects at once; a name is looked up on a
 * thread of its own (getaddrinfo may wait out a dead nameserver for tens of
 * seconds, which on the loop thread would stall every printer).  The thread
 * signals an eventfd the transport watches, never the loop itself, so
 * closing the transport cancels the lookup synchronously (loop_del_fd, then
 * the abandoned request is freed by whichever side finishes last) and the
 * loop may even be freed while a lookup still hangs.  Not getaddrinfo_a():
 * gai_cancel() cannot stop a lookup in progress either (EAI_NOTCANCELED),
 * so the same hand-over would be needed on top of glibc's own thread pool,
 * and a test could not inject a resolver that never answers.  Not
 * loop_post(): a post cannot be taken back, and loop_free() drops pending
 * posts unrun, so a result posted just before shutdown would leak.  One
 * thread per lookup, so one dead name never delays another; lookups happen
 * on (re)connect only, and SF_RESOLVER_THREADS_MAX caps them.
 *
 * Thread: loop thread; the lookup threads touch only their struct lookup.
 */
#include "transport.h"

#include <errno.h>
#include <fcntl.h>
#include <libserialport.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <termios.h>
#include <unistd.h>

#include "../../src/base/buf.h"
#include "../../src/base/limits.h"
#include "../../src/base/log.h"
#include "../../src/base/mem.h"

/* Queued output cap: a Marlin job never has more than a few KiB in flight. */
#define TRANSPORT_OUT_MAX (256 * 1024)

enum tkind { T_SERIAL, T_PTY, T_TCP };

/*
 * One host name lookup, shared by a transport (loop thread) and the thread
 * that runs it.  `lock` protects done, abandoned and the results; the side
 * that finds the other one gone frees the request (lookup_destroy).
 */
struct lookup {
    pthread_mutex_t lock;
    int efd;                      /* eventfd the thread signals when done */
    transport_resolve_fn resolve; /* getaddrinfo unless a test injected one */
    char host[128];               /* name to resolve */
    char port[8];                 /* decimal port */
    bool done;                    /* the thread finished; rc, sys_errno, ai are set */
    bool abandoned;               /* the transport was freed first; the thread frees */
    int rc;                       /* resolve()'s return, 0 = resolved */
    int sys_errno;                /* errno after resolve() (for EAI_SYSTEM) */
    struct addrinfo *ai;          /* result (freeaddrinfo) until taken */
};

/* The resolver lookups use; set by tests before transports open. */
static _Atomic(transport_resolve_fn) resolver = getaddrinfo;
/* Lookup threads alive (capped by SF_RESOLVER_THREADS_MAX). */
static atomic_int lookups_alive;

struct transport {
    struct loop *loop;
    enum tkind kind;
    int fd;                /* watched fd (the port handle for serial) */
    struct sp_port *port;  /* serial only */
    bool connecting;       /* TCP name lookup or connect in progress */
    struct lookup *lookup; /* TCP host name lookup in flight, or NULL */
    bool closed;           /* on_close was called; inert */
    unsigned events;       /* current loop interest */
    struct buf out;        /* bytes waiting for the OS */
    transport_data_fn on_data;
    transport_close_fn on_close;
    void *ud;
    char spec[160]; /* for messages */
};

static void on_io(struct loop *l, int fd, unsigned events, void *ud);

static void
fail(struct transport *t, const char *why)
{
    if (t->closed)
        return;
    t->closed = true;
    loop_del_fd(t->loop, t->fd);
    t->on_close(t->ud, why);
}

static ssize_t
raw_read(struct transport *t, char *b, size_t n)
{
    if (t->kind == T_SERIAL) {
        enum sp_return r = sp_nonblocking_read(t->port, b, n);
        if (r < 0) {
            errno = EIO;
            return -1;
        }
        if (r == 0) {
            errno = EAGAIN;
            return -1;
        }
        return r;
    }
    return read(t->fd, b, n);
}

static ssize_t
raw_write(struct transport *t, const char *b, size_t n)
{
    if (t->kind == T_SERIAL) {
        enum sp_return r = sp_nonblocking_write(t->port, b, n);
        if (r < 0) {
            errno = EIO;
            return -1;
        }
        return r;
    }
    return t->kind == T_TCP ? send(t->fd, b, n, MSG_NOSIGNAL) : write(t->fd, b, n);
}

static void
set_interest(struct transport *t)
{
    unsigned ev = LOOP_READ | (t->out.len > 0 || t->connecting ? LOOP_WRITE : 0);
    if (ev != t->events && loop_mod_fd(t->loop, t->fd, ev, NULL) == 0)
        t->events = ev;
}

static void
flush_out(struct transport *t)
{
    while (t->out.len > 0 && !t->closed) {
        ssize_t n = raw_write(t, t->out.data, t->out.len);
        if (n > 0) {
            log_trace("serial", t->spec, ">", t->out.data, (size_t)n);
            buf_consume(&t->out, (size_t)n);
            continue;
        }
        if (n < 0 && (errno == EAGAIN || errno == EINTR))
            break;
        char why[128];
        snprintf(why, sizeof(why), "write: %s", n < 0 ? strerror(errno) : "no progress");
        fail(t, why);
        return;
    }
    if (!t->closed)
        set_interest(t);
}

static void
on_io(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)l;
    (void)fd;
    struct transport *t = ud;
    if (t->closed)
        return;
    if (t->connecting && (events & (LOOP_WRITE | LOOP_ERROR | LOOP_HUP))) {
        int e = 0;
        socklen_t el = sizeof(e);
        getsockopt(t->fd, SOL_SOCKET, SO_ERROR, &e, &el);
        if (e) {
            char why[160];
            snprintf(why, sizeof(why), "connect %s: %s", t->spec, strerror(e));
            fail(t, why);
            return;
        }
        t->connecting = false;
    }
    if (events & (LOOP_READ | LOOP_HUP | LOOP_ERROR)) {
        char b[4096];
        for (int round = 0; round < 16; round++) {
            ssize_t n = raw_read(t, b, sizeof(b));
            if (n > 0) {
                log_trace("serial", t->spec, "<", b, (size_t)n);
                t->on_data(t->ud, b, (size_t)n);
                if (t->closed)
                    return;
                if ((size_t)n < sizeof(b))
                    break;
                continue;
            }
            if (n < 0 && (errno == EAGAIN || errno == EINTR)) {
                if (events & (LOOP_HUP | LOOP_ERROR))
                    break;
                return flush_out(t);
            }
            char why[128];
            snprintf(why, sizeof(why), "%s", n == 0 ? "connection closed" : strerror(errno));
            fail(t, why);
            return;
        }
        if ((events & (LOOP_HUP | LOOP_ERROR)) && !(events & LOOP_READ)) {
            fail(t, "hang-up");
            return;
        }
    }
    flush_out(t);
}

static int
open_fd_tty(struct transport *t, const char *path, struct sf_err *err)
{
    int fd = open(path, O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0)
        return sf_err_sys(err, "open '%s'", path);
    if (!isatty(fd)) {
        close(fd);
        return sf_err_set(err, SF_EINVAL, "'%s' is not a terminal", path);
    }
    struct termios tio;
    if (tcgetattr(fd, &tio) == 0) {
        cfmakeraw(&tio);
        tcsetattr(fd, TCSANOW, &tio);
    }
    t->fd = fd;
    return SF_OK;
}

static int
open_serial(struct transport *t, const char *path, int baud, struct sf_err *err)
{
    if (sp_get_port_by_name(path, &t->port) != SP_OK)
        return sf_err_set(err, SF_EINVAL, "serial port '%s' not found", path);
    if (sp_open(t->port, SP_MODE_READ_WRITE) != SP_OK) {
        char *m = sp_last_error_message();
        sf_err_set(err, SF_EIO, "open serial port '%s': %s", path, m ? m : "failed");
        sp_free_error_message(m);
        return SF_EIO;
    }
    if (sp_set_baudrate(t->port, baud) != SP_OK || sp_set_bits(t->port, 8) != SP_OK ||
        sp_set_parity(t->port, SP_PARITY_NONE) != SP_OK || sp_set_stopbits(t->port, 1) != SP_OK ||
        sp_set_flowcontrol(t->port, SP_FLOWCONTROL_NONE) != SP_OK)
        return sf_err_set(err, SF_EIO, "serial port '%s': cannot set %d 8N1", path, baud);
    if (sp_get_port_handle(t->port, &t->fd) != SP_OK)
        return sf_err_set(err, SF_EIO, "serial port '%s': no handle", path);
    return SF_OK;
}

/* Connect to ai in the background; on_io sees the outcome. */
static int
connect_tcp(struct transport *t, const struct addrinfo *ai, struct sf_err *err)
{
    int fd = socket(ai->ai_family, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (fd < 0)
        return sf_err_sys(err, "'%s': socket", t->spec);
    int one = 1;
    setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
    int rc = connect(fd, ai->ai_addr, ai->ai_addrlen);
    if (rc < 0 && errno != EINPROGRESS) {
        int r = sf_err_sys(err, "connect '%s'", t->spec);
        close(fd);
        return r;
    }
    t->connecting = rc < 0;
    t->fd = fd;
    return SF_OK;
}

static void
lookup_destroy(struct lookup *lk)
{
    if (lk->ai)
        freeaddrinfo(lk->ai);
    close(lk->efd);
    pthread_mutex_destroy(&lk->lock);
    free(lk);
}

static void *
lookup_run(void *arg)
{
    struct lookup *lk = arg;
    struct addrinfo hints = { .ai_socktype = SOCK_STREAM, .ai_flags = AI_NUMERICSERV };
    struct addrinfo *ai = NULL;
    errno = 0;
    int rc = lk->resolve(lk->host, lk->port, &hints, &ai);
    int e = errno;
    pthread_mutex_lock(&lk->lock);
    lk->rc = rc;
    lk->sys_errno = e;
    lk->ai = rc == 0 ? ai : NULL;
    lk->done = true;
    bool abandoned = lk->abandoned;
    if (!abandoned) {
        uint64_t one = 1;
        /* An eventfd write only fails on counter overflow, which one write cannot cause. */
        if (write(lk->efd, &one, sizeof(one)) < 0)
            lk->sys_errno = errno;
    }
    pthread_mutex_unlock(&lk->lock);
    if (abandoned)
        lookup_destroy(lk);
    atomic_fetch_sub(&lookups_alive, 1);
    return NULL;
}

/* Loop thread: the lookup finished; connect, or close with the reason. */
static void
on_lookup(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)fd;
    (void)events;
    struct transport *t = ud;
    struct lookup *lk = t->lookup;
    pthread_mutex_lock(&lk->lock);
    bool done = lk->done;
    pthread_mutex_unlock(&lk->lock);
    if (!done)
        return; /* cannot happen: the thread signals after setting done */
    loop_del_fd(l, lk->efd);
    t->lookup = NULL;
    char why[256];
    struct sf_err err;
    int rc = lk->rc;
    if (rc != 0) {
        const char *what = rc == EAI_SYSTEM ? strerror(lk->sys_errno) : gai_strerror(rc);
        /* Short: drivers quote at most 80 bytes of it ("link lost (...)"). */
        snprintf(why, sizeof(why), "cannot resolve host '%s': %s", lk->host, what);
    } else if (connect_tcp(t, lk->ai, &err) < 0) {
        snprintf(why, sizeof(why), "%s", err.msg);
        rc = -1;
    } else {
        t->events = LOOP_READ | LOOP_WRITE; /* writable = connected; queued bytes go then */
        if (loop_add_fd(l, t->fd, t->events, on_io, t, &err) < 0) {
            snprintf(why, sizeof(why), "%s", err.msg);
            rc = -1;
        }
    }
    lookup_destroy(lk);
    if (rc != 0 && !t->closed) {
        t->closed = true;
        t->on_close(t->ud, why);
    }
}

/* Start a background lookup of host; on_lookup finishes the open. */
static int
start_lookup(struct transport *t, const char *host, const char *port, struct sf_err *err)
{
    if (atomic_fetch_add(&lookups_alive, 1) >= SF_RESOLVER_THREADS_MAX) {
        atomic_fetch_sub(&lookups_alive, 1);
        return sf_err_set(err, SF_EAGAIN, "'%s': %d host name lookups already in progress", t->spec,
                          SF_RESOLVER_THREADS_MAX);
    }
    struct lookup *lk = mem_calloc(1, sizeof(*lk));
    if (!lk) {
        atomic_fetch_sub(&lookups_alive, 1);
        return sf_err_set(err, SF_ENOMEM, "out of memory");
    }
    snprintf(lk->host, sizeof(lk->host), "%s", host);
    snprintf(lk->port, sizeof(lk->port), "%s", port);
    lk->resolve = atomic_load(&resolver);
    lk->efd = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    if (lk->efd < 0) {
        int r = sf_err_sys(err, "'%s': eventfd", t->spec);
        free(lk);
        atomic_fetch_sub(&lookups_alive, 1);
        return r;
    }
    pthread_mutex_init(&lk->lock, NULL);
    if (loop_add_fd(t->loop, lk->efd, LOOP_READ, on_lookup, t, err) < 0) {
        lookup_destroy(lk);
        atomic_fetch_sub(&lookups_alive, 1);
        return err ? err->code : SF_EIO;
    }
    /* The thread must not take the signals the loop reads through signalfd. */
    sigset_t all, old;
    sigfillset(&all);
    pthread_attr_t attr;
    pthread_attr_init(&attr);
    pthread_attr_setdetachstate(&attr, PTHREAD_CREATE_DETACHED);
    pthread_t th;
    pthread_sigmask(SIG_BLOCK, &all, &old);
    int rc = pthread_create(&th, &attr, lookup_run, lk);
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    pthread_attr_destroy(&attr);
    if (rc != 0) {
        loop_del_fd(t->loop, lk->efd);
        lookup_destroy(lk);
        atomic_fetch_sub(&lookups_alive, 1);
        errno = rc;
        return sf_err_sys(err, "'%s': cannot start a host name lookup", t->spec);
    }
    t->lookup = lk;
    t->connecting = true;
    return SF_OK;
}

/* Loop thread: forget a lookup in flight; the thread frees it if still running. */
static void
cancel_lookup(struct transport *t)
{
    struct lookup *lk = t->lookup;
    if (!lk)
        return;
    t->lookup = NULL;
    loop_del_fd(t->loop, lk->efd);
    pthread_mutex_lock(&lk->lock);
    bool done = lk->done;
    lk->abandoned = true;
    pthread_mutex_unlock(&lk->lock);
    if (done)
        lookup_destroy(lk);
}

static int
open_tcp(struct transport *t, const char *hostport, struct sf_err *err)
{
    char host[128];
    const char *colon = strrchr(hostport, ':');
    if (!colon || colon == hostport || (size_t)(colon - hostport) >= sizeof(host) || !colon[1])
        return sf_err_set(err, SF_EINVAL, "'%s': expected tcp://host:port", t->spec);
    memcpy(host, hostport, (size_t)(colon - hostport));
    host[colon - hostport] = '\0';
    char *end;
    errno = 0;
    long port = strtol(colon + 1, &end, 10);
    if (errno || *end || port < 1 || port > 65535)
        return sf_err_set(err, SF_EINVAL, "'%s': port must be 1-65535", t->spec);
    char port_s[8];
    snprintf(port_s, sizeof(port_s), "%ld", port);
    /* A numeric address never blocks: connect now.  A name goes to a lookup thread. */
    struct addrinfo hints = { .ai_socktype = SOCK_STREAM,
                              .ai_flags = AI_NUMERICHOST | AI_NUMERICSERV },
                    *ai;
    int rc = getaddrinfo(host, port_s, &hints, &ai);
    if (rc == EAI_NONAME)
        return start_lookup(t, host, port_s, err);
    if (rc != 0)
        return sf_err_set(err, SF_EINVAL, "'%s': %s", t->spec, gai_strerror(rc));
    rc = connect_tcp(t, ai, err);
    freeaddrinfo(ai);
    return rc;
}

/* "fd:N": a copy of the caller's connected stream fd N (a socketpair end). */
static int
adopt_fd(struct transport *t, const char *num, struct sf_err *err)
{
    char *end;
    errno = 0;
    long fd = strtol(num, &end, 10);
    if (errno || end == num || *end || fd < 0 || fd > 65535)
        return sf_err_set(err, SF_EINVAL, "'%s': expected fd:N", t->spec);
    t->fd = fcntl((int)fd, F_DUPFD_CLOEXEC, 3);
    if (t->fd < 0)
        return sf_err_sys(err, "'%s'", t->spec);
    int fl = fcntl(t->fd, F_GETFL);
    if (fl < 0 || fcntl(t->fd, F_SETFL, fl | O_NONBLOCK) < 0)
        return sf_err_sys(err, "'%s': non-blocking", t->spec);
    return SF_OK;
}

/* Close the port or fd (out of the loop already) and free t. */
static void
close_free(struct transport *t)
{
    if (t->port) {
        sp_close(t->port);
        sp_free_port(t->port);
    } else if (t->fd >= 0) {
        close(t->fd);
    }
    buf_release(&t->out);
    free(t);
}

struct transport *
transport_open(struct loop *l, const char *spec, int baud, transport_data_fn on_data,
               transport_close_fn on_close, void *ud, struct sf_err *err)
{
    if (!spec || !*spec) {
        sf_err_set(err, SF_EINVAL, "no port given");
        return NULL;
    }
    if (baud == 0)
        baud = 115200;
    if (baud < 300 || baud > 4000000) {
        sf_err_set(err, SF_EINVAL, "port '%s': baud %d out of range 300-4000000", spec, baud);
        return NULL;
    }
    struct transport *t = mem_calloc(1, sizeof(*t));
    if (!t) {
        sf_err_set(err, SF_ENOMEM, "out of memory");
        return NULL;
    }
    t->loop = l;
    t->fd = -1;
    t->on_data = on_data;
    t->on_close = on_close;
    t->ud = ud;
    snprintf(t->spec, sizeof(t->spec), "%s", spec);
    buf_init(&t->out, TRANSPORT_OUT_MAX);
    int rc;
    if (strncmp(spec, "tcp://", 6) == 0) {
        t->kind = T_TCP;
        rc = open_tcp(t, spec + 6, err);
    } else if (strncmp(spec, "fd:", 3) == 0) {
        t->kind = T_TCP; /* a connected stream socket: plain reads and writes */
        rc = adopt_fd(t, spec + 3, err);
    } else {
        const char *path = strncmp(spec, "pty:", 4) == 0 ? spec + 4 : spec;
        char real[256];
        bool pty = path != spec || (realpath(path, real) && strncmp(real, "/dev/pts/", 9) == 0);
        t->kind = pty ? T_PTY : T_SERIAL;
        rc = pty ? open_fd_tty(t, path, err) : open_serial(t, path, baud, err);
    }
    if (rc < 0)
        goto fail;
    if (t->lookup)
        return t; /* on_lookup watches the fd once there is one */
    t->events = LOOP_READ | (t->connecting ? LOOP_WRITE : 0);
    if (loop_add_fd(l, t->fd, t->events, on_io, t, err) < 0)
        goto fail;
    return t;
fail:
    close_free(t);
    return NULL;
}

int
transport_write(struct transport *t, const void *data, size_t n)
{
    if (t->closed)
        return SF_EIO;
    if (buf_append(&t->out, data, n) < 0)
        return SF_ENOMEM;
    if (!t->connecting)
        flush_out(t);
    return t->closed ? SF_EIO : SF_OK;
}

size_t
transport_pending(const struct transport *t)
{
    return t->out.len;
}

void
transport_flush_input(struct transport *t)
{
    if (t->kind == T_SERIAL)
        sp_flush(t->port, SP_BUF_INPUT);
    else if (t->kind == T_PTY)
        tcflush(t->fd, TCIFLUSH);
}

void
transport_free(struct transport *t)
{
    if (!t)
        return;
    cancel_lookup(t);
    if (!t->closed && t->fd >= 0)
        loop_del_fd(t->loop, t->fd);
    close_free(t);
}

void
transport_set_resolver(transport_resolve_fn fn)
{
    atomic_store(&resolver, fn ? fn : getaddrinfo);
}

int
transport_lookups_alive(void)
{
    return atomic_load(&lookups_alive);
}

int
transport_list_ports(struct transport_port **out, size_t *n_out, struct sf_err *err)
{
    struct sp_port **ports;
    *out = NULL;
    *n_out = 0;
    if (sp_list_ports(&ports) != SP_OK)
        return sf_err_set(err, SF_EIO, "cannot list serial ports");
    size_t n = 0;
    while (ports[n])
        n++;
    struct transport_port *list = n ? mem_calloc(n, sizeof(*list)) : NULL;
    if (n && !list) {
        sp_free_port_list(ports);
        return sf_err_set(err, SF_ENOMEM, "out of memory");
    }
    for (size_t i = 0; i < n; i++) {
        struct transport_port *p = &list[i];
        const char *name = sp_get_port_name(ports[i]);
        const char *desc = sp_get_port_description(ports[i]);
        snprintf(p->name, sizeof(p->name), "%s", name ? name : "?");
        snprintf(p->description, sizeof(p->description), "%s", desc ? desc : "");
        p->vid = p->pid = -1;
        int vid, pid;
        if (sp_get_port_transport(ports[i]) == SP_TRANSPORT_USB &&
            sp_get_port_usb_vid_pid(ports[i], &vid, &pid) == SP_OK) {
            p->vid = vid;
            p->pid = pid;
            const char *sn = sp_get_port_usb_serial(ports[i]);
            snprintf(p->serial, sizeof(p->serial), "%s", sn ? sn : "");
        }
    }
    sp_free_port_list(ports);
    *out = list;
    *n_out = n;
    return SF_OK;
}
