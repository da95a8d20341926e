/*
 * wsc.c - a websocket client connection on the loop (wsc.h).
 *
 * One state machine: connecting (the socket writable tells the connect's
 * outcome), handshake (the request goes out from the output buffer, the
 * reply head, up to HEAD_MAX bytes, is gathered and checked), open (frames
 * through ws_parser, which must see no mask on the server's frames).  One
 * timer serves the handshake's deadline, then the pings.  Callbacks run
 * with a depth count, so the owner may free the connection from inside
 * one: the memory goes when the last callback returns.
 *
 * Thread: the loop thread.
 */
#include "wsc.h"

#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <openssl/evp.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/random.h>
#include <sys/socket.h>
#include <unistd.h>

#include "../../src/base/buf.h"
#include "../../src/base/mem.h"
#include "../../src/base/ws.h"

#define HEAD_MAX 8192              /* the handshake reply's head */
#define OUT_MAX  ((size_t)1 << 20) /* queued bytes to the server */

enum wsc_state { W_CONNECTING, W_HANDSHAKE, W_OPEN, W_DEAD };

struct wsc {
    struct loop *l;
    const struct wsc_ops *ops;
    void *ud;
    int fd;
    enum wsc_state st;
    char key[25];
    struct buf out;
    struct buf head;
    struct ws_parser in;
    uint64_t timer;
    int64_t heard_ms; /* loop time the server last sent a byte */
    bool want_write;
    int depth;         /* callbacks under way */
    bool free_pending; /* wsc_free came during one */
};

static void
teardown(struct wsc *w)
{
    if (w->fd >= 0) {
        loop_del_fd(w->l, w->fd);
        close(w->fd);
        w->fd = -1;
    }
    if (w->timer)
        loop_timer_cancel(w->l, w->timer);
    w->timer = 0;
}

static void
release(struct wsc *w)
{
    teardown(w);
    buf_release(&w->out);
    buf_release(&w->head);
    ws_parser_release(&w->in);
    free(w);
}

/* After a callback: false when the owner freed w in it (w is gone). */
static bool
survived(struct wsc *w)
{
    if (--w->depth == 0 && w->free_pending) {
        release(w);
        return false;
    }
    return !w->free_pending;
}

/* Drop the connection and say why, once.  False when w is gone. */
static bool
die(struct wsc *w, const char *why)
{
    if (w->st == W_DEAD)
        return !w->free_pending;
    w->st = W_DEAD;
    teardown(w);
    w->depth++;
    w->ops->closed(w, why, w->ud);
    return survived(w);
}

static void
watch_write(struct wsc *w, bool want)
{
    if (want != w->want_write && w->fd >= 0) {
        w->want_write = want;
        loop_mod_fd(w->l, w->fd, LOOP_READ | (want ? LOOP_WRITE : 0), NULL);
    }
}

/* Send what is queued.  False when w is gone. */
static bool
flush(struct wsc *w)
{
    while (w->out.len) {
        ssize_t k = send(w->fd, w->out.data, w->out.len, MSG_NOSIGNAL);
        if (k < 0 && errno == EINTR)
            continue;
        if (k < 0 && (errno == EAGAIN || errno == EWOULDBLOCK))
            break;
        if (k <= 0) {
            char why[160];
            snprintf(why, sizeof(why), "websocket send: %s", strerror(errno));
            return die(w, why);
        }
        buf_consume(&w->out, (size_t)k);
    }
    watch_write(w, w->out.len > 0);
    return true;
}

/* Queue a frame: 1 sent or queued, 0 the queue was full (the connection is closed, its
   closed() said so), -1 the connection died (and w may be gone). */
static int
queue_frame(struct wsc *w, enum ws_op op, const char *data, size_t len)
{
    uint8_t mask[4];
    /* GRND_NONBLOCK: a mask need not be secret, and the loop must not wait
       for an early-boot entropy pool */
    if (getrandom(mask, sizeof(mask), GRND_NONBLOCK) != (ssize_t)sizeof(mask))
        memset(mask, 0x5a, sizeof(mask));
    if (ws_frame(&w->out, op, data, len, mask) < 0)
        return die(w, "websocket: send queue full") ? 0 : -1;
    bool alive = flush(w);
    return alive && w->st != W_DEAD ? 1 : -1;
}

int
wsc_send(struct wsc *w, const char *text, size_t len)
{
    if (!w || w->st != W_OPEN)
        return SF_EIO;
    return queue_frame(w, WS_TEXT, text, len) == 1 ? SF_OK : SF_EIO;
}

static void on_timer(struct loop *l, void *ud);

/* The handshake reply's head is whole at end: check it.  False when w is gone. */
static bool
handshake_done(struct wsc *w, const char *end)
{
    char accept[WS_ACCEPT_LEN + 1];
    const char *h = w->head.data;
    bool ok = strncmp(h, "HTTP/1.1 101", 12) == 0 && ws_accept(w->key, accept, NULL) == SF_OK;
    bool accepted = false;
    for (const char *line = strstr(h, "\r\n"); ok && line && line < end;
         line = strstr(line, "\r\n")) {
        line += 2;
        if (strncasecmp(line, "Sec-WebSocket-Accept:", 21) == 0) {
            const char *v = line + 21;
            while (*v == ' ' || *v == '\t')
                v++;
            accepted = strncmp(v, accept, WS_ACCEPT_LEN) == 0 &&
                       (v[WS_ACCEPT_LEN] == '\r' || v[WS_ACCEPT_LEN] == ' ');
        }
    }
    if (!ok || !accepted) {
        char why[200];
        size_t n = strcspn(h, "\r\n");
        snprintf(why, sizeof(why), "websocket handshake refused: %.*s%s", (int)(n > 80 ? 80 : n), h,
                 ok ? " (bad Sec-WebSocket-Accept)" : "");
        return die(w, why);
    }
    w->st = W_OPEN;
    const char *rest = end + 4;
    size_t n_rest = w->head.len - (size_t)(rest - h);
    if (n_rest && ws_parser_feed(&w->in, rest, n_rest, NULL) < 0)
        return die(w, "websocket: the first frames are too big");
    buf_release(&w->head);
    if (w->timer)
        loop_timer_cancel(w->l, w->timer);
    w->timer = loop_timer_add(w->l, WSC_PING_MS, on_timer, w);
    w->depth++;
    w->ops->open(w, w->ud);
    return survived(w);
}

/* Hand out the whole messages parsed so far.  False when w is gone. */
static bool
drain(struct wsc *w)
{
    struct ws_msg m;
    struct sf_err err;
    int rc;
    while (w->st == W_OPEN && (rc = ws_parser_next(&w->in, &m, &err)) != 0) {
        if (rc < 0)
            return die(w, err.msg);
        if (m.op == WS_PING) {
            if (queue_frame(w, WS_PONG, m.data, m.len) < 0)
                return false; /* died: w may be gone */
        } else if (m.op == WS_CLOSE) {
            char why[160];
            snprintf(why, sizeof(why), "websocket closed by the printer (%u%s%.100s)",
                     (unsigned)m.code, m.len ? ": " : "", m.data);
            uint8_t mask[4] = { 1, 2, 3, 4 };
            (void)ws_close_frame(&w->out, m.code == WS_CLOSE_NO_CODE ? WS_CLOSE_NORMAL : m.code,
                                 NULL, mask);
            (void)!send(w->fd, w->out.data, w->out.len, MSG_NOSIGNAL | MSG_DONTWAIT);
            return die(w, why);
        } else if (m.op == WS_TEXT || m.op == WS_BINARY) {
            w->depth++;
            w->ops->text(w, m.data, m.len, w->ud);
            if (!survived(w))
                return false;
        }
    }
    return true;
}

static void
on_fd(struct loop *l, int fd, unsigned events, void *ud)
{
    struct wsc *w = ud;
    if (w->st == W_CONNECTING) {
        int e = 0;
        socklen_t el = sizeof(e);
        if (getsockopt(fd, SOL_SOCKET, SO_ERROR, &e, &el) < 0)
            e = errno;
        if (e) {
            char why[160];
            snprintf(why, sizeof(why), "websocket connect: %s", strerror(e));
            die(w, why);
            return;
        }
        if (!(events & (LOOP_WRITE | LOOP_READ)))
            return;
        w->st = W_HANDSHAKE;
    }
    if ((events & LOOP_WRITE) && !flush(w))
        return;
    char chunk[16384];
    while (w->st == W_HANDSHAKE || w->st == W_OPEN) {
        ssize_t k = recv(fd, chunk, sizeof(chunk), 0);
        if (k < 0 && errno == EINTR)
            continue;
        if (k < 0 && (errno == EAGAIN || errno == EWOULDBLOCK))
            return;
        if (k <= 0) {
            die(w, k == 0 ? "websocket closed by the printer" : "websocket receive failed");
            return;
        }
        w->heard_ms = loop_now_ms(l);
        if (w->st == W_HANDSHAKE) {
            /* the head's bound is HEAD_MAX; the buffer also holds the frames
               a server sends in the same read as its 101 */
            const char *end = buf_append(&w->head, chunk, (size_t)k) < 0
                                  ? NULL
                                  : strstr(w->head.data, "\r\n\r\n");
            if (end ? end - w->head.data > HEAD_MAX : w->head.len >= HEAD_MAX) {
                die(w, "websocket handshake reply too long");
                return;
            }
            if (end && (!handshake_done(w, end) || !drain(w)))
                return;
            continue;
        }
        if (ws_parser_feed(&w->in, chunk, (size_t)k, NULL) < 0) {
            die(w, "websocket: message too big");
            return;
        }
        if (!drain(w))
            return;
    }
}

static void
on_timer(struct loop *l, void *ud)
{
    struct wsc *w = ud;
    w->timer = 0;
    if (w->st != W_OPEN) {
        die(w, "websocket: no handshake in time");
        return;
    }
    if (loop_now_ms(l) - w->heard_ms > WSC_DEAD_MS) {
        die(w, "websocket: the printer went silent");
        return;
    }
    if (queue_frame(w, WS_PING, "", 0) != 1)
        return; /* closed (w may be gone) */
    w->timer = loop_timer_add(l, WSC_PING_MS, on_timer, w);
}

/* url's host and port into an address, and *prefix its path ("" or "/octoprint" behind a
   proxy, which the socket's path follows); SF_EUNSUPP for what wsc does not reach. */
static int
address(const char *url, const char *at, struct sockaddr_storage *sa, socklen_t *sl, char *host,
        size_t hn, const char **prefix, struct sf_err *err)
{
    if (strncmp(url, "http://", 7) != 0)
        return sf_err_set(err, SF_EUNSUPP, "websocket: only http:// URLs, not '%.60s'", url);
    const char *h = url + 7;
    bool v6 = *h == '[';
    size_t n = v6 ? strcspn(h, "]") + 1 : strcspn(h, ":/");
    if (n == 0 || n >= hn || (v6 && h[n - 1] != ']'))
        return sf_err_set(err, SF_EUNSUPP, "websocket: no host in '%.60s'", url);
    snprintf(host, hn, "%.*s", (int)n, h);
    *prefix = h + n + strcspn(h + n, "/");
    long port = 80;
    if (h[n] == ':') {
        char *end;
        port = strtol(h + n + 1, &end, 10);
        if (port < 1 || port > 65535 || (*end && *end != '/'))
            return sf_err_set(err, SF_EUNSUPP, "websocket: bad port in '%.60s'", url);
    }
    char ip[64];
    snprintf(ip, sizeof(ip), "%.*s", (int)(v6 ? n - 2 : n), v6 ? h + 1 : h);
    if (at && at[0])
        snprintf(ip, sizeof(ip), "%s", at);
    if (strcmp(ip, "localhost") == 0)
        snprintf(ip, sizeof(ip), "127.0.0.1");
    memset(sa, 0, sizeof(*sa));
    struct sockaddr_in *s4 = (struct sockaddr_in *)sa;
    struct sockaddr_in6 *s6 = (struct sockaddr_in6 *)sa;
    if (inet_pton(AF_INET, ip, &s4->sin_addr) == 1) {
        s4->sin_family = AF_INET;
        s4->sin_port = htons((uint16_t)port);
        *sl = sizeof(*s4);
    } else if (inet_pton(AF_INET6, ip, &s6->sin6_addr) == 1) {
        s6->sin6_family = AF_INET6;
        s6->sin6_port = htons((uint16_t)port);
        *sl = sizeof(*s6);
    } else {
        return sf_err_set(err, SF_EUNSUPP, "websocket: '%s' is no IP address (not resolved here)",
                          ip);
    }
    size_t hl = strlen(host);
    snprintf(host + hl, hn - hl, ":%ld", port);
    return SF_OK;
}

struct wsc *
wsc_new(struct loop *l, const char *url, const char *ip, const char *path, const char *headers,
        const struct wsc_ops *ops, void *ud, struct sf_err *err)
{
    struct sockaddr_storage sa;
    socklen_t sl = 0;
    char host[128];
    const char *prefix = "";
    if (address(url, ip, &sa, &sl, host, sizeof(host), &prefix, err))
        return NULL;
    size_t pl = strlen(prefix);
    while (pl && prefix[pl - 1] == '/')
        pl--;
    struct wsc *w = mem_calloc(1, sizeof(*w));
    if (!w) {
        sf_err_set(err, SF_ENOMEM, "websocket: out of memory");
        return NULL;
    }
    w->l = l;
    w->ops = ops;
    w->ud = ud;
    buf_init(&w->out, OUT_MAX);
    buf_init(&w->head, HEAD_MAX + 16384); /* + one read's frames after the head */
    ws_parser_init(&w->in, false, WSC_MSG_MAX);
    /* the key: 16 random bytes in base64 (24 characters and a NUL) */
    unsigned char raw[16];
    if (getrandom(raw, sizeof(raw), GRND_NONBLOCK) != (ssize_t)sizeof(raw))
        memset(raw, 0x3c, sizeof(raw));
    EVP_EncodeBlock((unsigned char *)w->key, raw, (int)sizeof(raw));
    int rc = SF_OK;
    w->fd = socket(sa.ss_family, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (w->fd < 0 || (connect(w->fd, (struct sockaddr *)&sa, sl) < 0 && errno != EINPROGRESS))
        rc = sf_err_sys(err, "websocket connect to %s", host);
    else if (buf_printf(&w->out,
                        "GET %.*s%s HTTP/1.1\r\nHost: %s\r\nUpgrade: websocket\r\n"
                        "Connection: Upgrade\r\nSec-WebSocket-Key: %s\r\n"
                        "Sec-WebSocket-Version: 13\r\n%s\r\n",
                        (int)pl, prefix, path, host, w->key, headers ? headers : "") < 0)
        rc = sf_err_set(err, SF_ENOMEM, "websocket: request too long");
    else
        rc = loop_add_fd(l, w->fd, LOOP_READ | LOOP_WRITE, on_fd, w, err);
    if (rc < 0) {
        if (w->fd >= 0)
            close(w->fd);
        w->fd = -1;
        release(w);
        return NULL;
    }
    w->want_write = true;
    w->heard_ms = loop_now_ms(l);
    w->timer = loop_timer_add(l, WSC_HANDSHAKE_MS, on_timer, w);
    return w;
}

void
wsc_free(struct wsc *w)
{
    if (!w)
        return;
    if (w->depth > 0) {
        w->free_pending = true;
        w->st = W_DEAD;
        teardown(w);
        return;
    }
    release(w);
}
