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
 * Thread: loop thread.
 */
#include "transport.h"

#include <errno.h>
#include <fcntl.h>
#include <libserialport.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <termios.h>
#include <unistd.h>

#include "../src/base/buf.h"
#include "../src/base/log.h"
#include "../src/base/mem.h"

/* Queued output cap: a Marlin job never has more than a few KiB in flight. */
#define TRANSPORT_OUT_MAX (256 * 1024)

enum tkind { T_SERIAL, T_PTY, T_TCP };

struct transport {
    struct loop *loop;
    enum tkind kind;
    int fd;               /* watched fd (the port handle for serial) */
    struct sp_port *port; /* serial only */
    bool connecting;      /* TCP connect in progress */
    bool closed;          /* on_close was called; inert */
    unsigned events;      /* current loop interest */
    struct buf out;       /* bytes waiting for the OS */
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
    struct addrinfo hints = { .ai_socktype = SOCK_STREAM }, *ai;
    /* Numeric addresses never block; a name lookup may (TODO #7: resolve host names
       on the pool before the daemon opens a tcp:// printer). */
    int rc = getaddrinfo(host, colon + 1, &hints, &ai);
    if (rc != 0)
        return sf_err_set(err, SF_EINVAL, "'%s': %s", t->spec, gai_strerror(rc));
    int fd = socket(ai->ai_family, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (fd < 0) {
        freeaddrinfo(ai);
        return sf_err_sys(err, "'%s': socket", t->spec);
    }
    int one = 1;
    setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
    rc = connect(fd, ai->ai_addr, ai->ai_addrlen);
    freeaddrinfo(ai);
    if (rc < 0 && errno != EINPROGRESS) {
        int r = sf_err_sys(err, "connect '%s'", t->spec);
        close(fd);
        return r;
    }
    t->connecting = rc < 0;
    t->fd = fd;
    return SF_OK;
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
    } else {
        const char *path = strncmp(spec, "pty:", 4) == 0 ? spec + 4 : spec;
        char real[256];
        bool pty = path != spec || (realpath(path, real) && strncmp(real, "/dev/pts/", 9) == 0);
        t->kind = pty ? T_PTY : T_SERIAL;
        rc = pty ? open_fd_tty(t, path, err) : open_serial(t, path, baud, err);
    }
    if (rc < 0)
        goto fail;
    t->events = LOOP_READ | (t->connecting ? LOOP_WRITE : 0);
    if (loop_add_fd(l, t->fd, t->events, on_io, t, err) < 0)
        goto fail;
    return t;
fail:
    if (t->port) {
        sp_close(t->port);
        sp_free_port(t->port);
    } else if (t->fd >= 0) {
        close(t->fd);
    }
    buf_release(&t->out);
    free(t);
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
    if (!t->closed)
        loop_del_fd(t->loop, t->fd);
    if (t->port) {
        sp_close(t->port);
        sp_free_port(t->port);
    } else if (t->fd >= 0) {
        close(t->fd);
    }
    buf_release(&t->out);
    free(t);
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
