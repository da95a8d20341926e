/*
 * sim_bambu_relay.c - the simulated printer's MQTT port (sim_bambu_relay.h).
 *
 * Each accepted client gets a connection of its own to the broker (a
 * blocking connect: loopback answers at once), and bytes are copied both
 * ways through one 16 kB buffer per direction.  A side is read only while
 * its buffer is empty and written while the other side's buffer holds
 * bytes, so a slow reader slows its writer and nothing grows.  Either
 * side's end (or error) closes both: an MQTT session lives no longer than
 * its TCP connection.
 *
 * Thread: loop thread.
 */
#include "sim_bambu_relay.h"

#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include "../../src/base/log.h"
#include "../../src/base/mem.h"

#define RELAY_BUF 16384 /* bytes in flight per direction: one TLS record */

struct side {
    int fd;
    char buf[RELAY_BUF]; /* read from this side, not yet written to the other */
    size_t len, off;     /* bytes in buf, and of those already written */
};

struct pair {
    struct sim_bambu_relay *r;
    struct side s[2]; /* 0: the client, 1: the broker */
    struct pair *next;
};

struct sim_bambu_relay {
    struct loop *l;
    int lfd;               /* listening socket */
    int port;              /* its port */
    struct sockaddr_in up; /* the broker */
    bool down;             /* refusing: the printer's MQTT service is away */
    size_t accepted;       /* connections relayed */
    struct pair *pairs;    /* live ones */
};

static void
pair_close(struct pair *p)
{
    struct sim_bambu_relay *r = p->r;
    for (struct pair **pp = &r->pairs; *pp; pp = &(*pp)->next)
        if (*pp == p) {
            *pp = p->next;
            break;
        }
    for (int i = 0; i < 2; i++) {
        loop_del_fd(r->l, p->s[i].fd);
        close(p->s[i].fd);
    }
    free(p);
}

/* Write what side `from` read to the other side; false when that side is gone. */
static bool
flush(struct pair *p, int from)
{
    struct side *f = &p->s[from];
    while (f->off < f->len) {
        ssize_t n = send(p->s[1 - from].fd, f->buf + f->off, f->len - f->off, MSG_NOSIGNAL);
        if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK))
            return true;
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0)
            return false;
        f->off += (size_t)n;
    }
    f->len = f->off = 0;
    return true;
}

static void
watch(struct pair *p)
{
    for (int i = 0; i < 2; i++) {
        unsigned ev = 0;
        if (p->s[i].len == 0)
            ev |= LOOP_READ;
        if (p->s[1 - i].len > 0)
            ev |= LOOP_WRITE;
        loop_mod_fd(p->r->l, p->s[i].fd, ev, NULL);
    }
}

static void
on_pair(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)l;
    struct pair *p = ud;
    int i = fd == p->s[0].fd ? 0 : 1;
    if ((events & LOOP_WRITE) && !flush(p, 1 - i)) {
        pair_close(p);
        return;
    }
    if ((events & (LOOP_READ | LOOP_HUP | LOOP_ERROR)) && p->s[i].len == 0) {
        ssize_t n = recv(fd, p->s[i].buf, RELAY_BUF, 0);
        if (n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)) {
            pair_close(p);
            return;
        }
        if (n > 0) {
            p->s[i].len = (size_t)n;
            p->s[i].off = 0;
            if (!flush(p, i)) {
                pair_close(p);
                return;
            }
        }
    }
    watch(p);
}

static int
connect_up(struct sim_bambu_relay *r)
{
    int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0)
        return -1;
    if (connect(fd, (struct sockaddr *)&r->up, sizeof(r->up)) < 0) {
        close(fd);
        return -1;
    }
    int fl = fcntl(fd, F_GETFL);
    if (fl < 0 || fcntl(fd, F_SETFL, fl | O_NONBLOCK) < 0) {
        close(fd);
        return -1;
    }
    return fd;
}

static void
on_accept(struct loop *l, int lfd, unsigned events, void *ud)
{
    (void)events;
    struct sim_bambu_relay *r = ud;
    int c = accept4(lfd, NULL, NULL, SOCK_NONBLOCK | SOCK_CLOEXEC);
    if (c < 0)
        return;
    if (r->down) {
        close(c); /* the printer's MQTT service is away */
        return;
    }
    int u = connect_up(r);
    struct pair *p = u >= 0 ? mem_calloc(1, sizeof(*p)) : NULL;
    if (!p) {
        log_info("sim-bambu", "relay: the broker is unreachable; client refused");
        if (u >= 0)
            close(u);
        close(c);
        return;
    }
    p->r = r;
    p->s[0].fd = c;
    p->s[1].fd = u;
    if (loop_add_fd(l, c, LOOP_READ, on_pair, p, NULL) < 0 ||
        loop_add_fd(l, u, LOOP_READ, on_pair, p, NULL) < 0) {
        loop_del_fd(l, c);
        close(c);
        close(u);
        free(p);
        return;
    }
    p->next = r->pairs;
    r->pairs = p;
    r->accepted++;
}

struct sim_bambu_relay *
sim_bambu_relay_new(struct loop *l, const char *host, int port, struct sf_err *err)
{
    struct sim_bambu_relay *r = mem_calloc(1, sizeof(*r));
    if (!r) {
        sf_err_set(err, SF_ENOMEM, "sim bambu: out of memory");
        return NULL;
    }
    r->l = l;
    r->up.sin_family = AF_INET;
    r->up.sin_port = htons((uint16_t)port);
    if (inet_pton(AF_INET, host, &r->up.sin_addr) != 1) {
        sf_err_set(err, SF_EINVAL, "sim bambu: broker address '%s' is not an IPv4 address", host);
        free(r);
        return NULL;
    }
    r->lfd = socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    struct sockaddr_in a = { .sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK) };
    socklen_t al = sizeof(a);
    if (r->lfd < 0 || bind(r->lfd, (struct sockaddr *)&a, sizeof(a)) < 0 ||
        listen(r->lfd, 16) < 0 || getsockname(r->lfd, (struct sockaddr *)&a, &al) < 0) {
        sf_err_sys(err, "sim bambu: cannot listen for MQTT clients");
        goto fail;
    }
    r->port = ntohs(a.sin_port);
    if (loop_add_fd(l, r->lfd, LOOP_READ, on_accept, r, err) < 0)
        goto fail;
    return r;
fail:
    if (r->lfd >= 0)
        close(r->lfd);
    free(r);
    return NULL;
}

int
sim_bambu_relay_port(const struct sim_bambu_relay *r)
{
    return r->port;
}

size_t
sim_bambu_relay_set_down(struct sim_bambu_relay *r, bool down)
{
    r->down = down;
    size_t n = 0;
    while (down && r->pairs) {
        pair_close(r->pairs);
        n++;
    }
    return n;
}

size_t
sim_bambu_relay_accepted(const struct sim_bambu_relay *r)
{
    return r->accepted;
}

void
sim_bambu_relay_free(struct sim_bambu_relay *r)
{
    if (!r)
        return;
    while (r->pairs)
        pair_close(r->pairs);
    loop_del_fd(r->l, r->lfd);
    close(r->lfd);
    free(r);
}
