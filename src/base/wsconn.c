/*
 * wsconn.c - one server-side websocket on the loop (see wsconn.h).
 *
 * Reads go through a ws_parser (client frames must be masked), writes
 * through one output buffer flushed as the socket takes it (LOOP_WRITE is
 * watched only while bytes wait).  A connection that ends (close, error,
 * EOF, a full queue) is marked dead and reaped from a zero-delay timer, so
 * no callback ever sees its connection freed under it.
 *
 * Thread: the loop thread.
 */
#include "wsconn.h"

#include <errno.h>
#include <stdlib.h>
#include <sys/socket.h>

#include "buf.h"
#include "mem.h"
#include "ws.h"

struct wsconn {
    struct loop *l;
    int fd;
    const struct wsconn_ops *ops;
    void *ud;
    struct ws_parser in;
    struct buf out;
    bool want_write;     /* LOOP_WRITE is watched */
    bool closing;        /* a close frame was queued: send nothing more */
    bool dead;           /* to be reaped */
    uint64_t reap_timer; /* the zero-delay timer that reaps it, 0 if none */
};

static void
flush(struct wsconn *ws)
{
    while (ws->out.len && !ws->dead) {
        ssize_t k = send(ws->fd, ws->out.data, ws->out.len, MSG_NOSIGNAL);
        if (k < 0 && errno == EINTR)
            continue;
        if (k < 0 && (errno == EAGAIN || errno == EWOULDBLOCK))
            break;
        if (k <= 0) {
            ws->dead = true;
            break;
        }
        buf_consume(&ws->out, (size_t)k);
    }
    bool want = ws->out.len > 0 && !ws->dead;
    if (want != ws->want_write && !ws->dead) {
        ws->want_write = want;
        loop_mod_fd(ws->l, ws->fd, LOOP_READ | (want ? LOOP_WRITE : 0), NULL);
    }
}

static void
destroy(struct wsconn *ws)
{
    if (ws->reap_timer)
        loop_timer_cancel(ws->l, ws->reap_timer);
    loop_del_fd(ws->l, ws->fd);
    if (ws->out.len) /* a last try for the close frame */
        (void)!send(ws->fd, ws->out.data, ws->out.len, MSG_NOSIGNAL | MSG_DONTWAIT);
    shutdown(ws->fd, SHUT_RDWR);
    ws->ops->gone(ws, ws->ud);
    ws_parser_release(&ws->in);
    buf_release(&ws->out);
    free(ws);
}

static void
reap(struct loop *l, void *ud)
{
    (void)l;
    struct wsconn *ws = ud;
    ws->reap_timer = 0;
    destroy(ws);
}

static void
kill_later(struct wsconn *ws)
{
    ws->dead = true;
    if (!ws->reap_timer)
        ws->reap_timer = loop_timer_add(ws->l, 0, reap, ws);
}

static int
queue_frame(struct wsconn *ws, enum ws_op op, const char *data, size_t len)
{
    if (ws->dead || ws->closing)
        return SF_EIO;
    if (ws_frame(&ws->out, op, data, len, NULL) < 0) {
        kill_later(ws); /* a client this far behind is gone in all but name */
        return SF_EIO;
    }
    flush(ws);
    if (ws->dead)
        kill_later(ws);
    return SF_OK;
}

int
wsconn_send(struct wsconn *ws, const char *text, size_t len)
{
    return queue_frame(ws, WS_TEXT, text, len);
}

void
wsconn_close(struct wsconn *ws, uint16_t code, const char *reason)
{
    if (ws->dead || ws->closing)
        return;
    (void)ws_close_frame(&ws->out, code, reason, NULL);
    ws->closing = true;
    flush(ws);
    kill_later(ws);
}

void
wsconn_free(struct wsconn *ws, uint16_t code)
{
    if (!ws)
        return;
    if (!ws->closing && !ws->dead)
        (void)ws_close_frame(&ws->out, code, NULL, NULL);
    destroy(ws);
}

bool
wsconn_closing(const struct wsconn *ws)
{
    return ws->closing || ws->dead;
}

bool
wsconn_dead(const struct wsconn *ws)
{
    return ws->dead;
}

void
wsconn_set_ud(struct wsconn *ws, void *ud)
{
    ws->ud = ud;
}

/* One message from the client. */
static void
on_message(struct wsconn *ws, const struct ws_msg *m)
{
    switch (m->op) {
    case WS_TEXT:
    case WS_BINARY:
        if (!ws->closing)
            ws->ops->text(ws, m->data, m->len, ws->ud);
        break;
    case WS_PING:
        queue_frame(ws, WS_PONG, m->data, m->len);
        break;
    case WS_CLOSE: /* answer with its code (RFC 6455 5.5.1) */
        wsconn_close(ws, m->code == WS_CLOSE_NO_CODE ? WS_CLOSE_NORMAL : m->code, NULL);
        break;
    default:
        break;
    }
}

/* Parse what is buffered; false once the connection failed or closed. */
static bool
drain(struct wsconn *ws)
{
    struct ws_msg m;
    int rc;
    while (!ws->dead && (rc = ws_parser_next(&ws->in, &m, NULL)) == 1)
        on_message(ws, &m);
    if (!ws->dead && rc < 0) {
        wsconn_close(ws, ws->in.close_code ? ws->in.close_code : WS_CLOSE_PROTOCOL, NULL);
        return false;
    }
    return !ws->dead;
}

static void
on_fd(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)l;
    struct wsconn *ws = ud;
    if (ws->dead)
        return;
    if (events & LOOP_WRITE)
        flush(ws);
    /* At most 64 KiB a turn: a client streaming faster than its messages are handled must not
       keep the loop (which feeds the printers) from everything else; the loop's epoll is level
       triggered, so what is left is read on the next turn. */
    char chunk[16384];
    for (int reads = 0; reads < 4 && !ws->dead; reads++) {
        ssize_t k = recv(fd, chunk, sizeof(chunk), 0);
        if (k < 0 && errno == EINTR)
            continue;
        if (k < 0 && (errno == EAGAIN || errno == EWOULDBLOCK))
            break;
        if (k <= 0) { /* EOF or an error: the client is gone */
            kill_later(ws);
            return;
        }
        if (ws_parser_feed(&ws->in, chunk, (size_t)k, NULL) < 0) {
            wsconn_close(ws, WS_CLOSE_TOO_BIG, NULL);
            return;
        }
        if (!drain(ws))
            return;
    }
    if (ws->dead)
        kill_later(ws);
}

struct wsconn *
wsconn_new(struct loop *l, int fd, size_t max_msg, size_t out_max, const struct wsconn_ops *ops,
           void *ud)
{
    struct wsconn *ws = mem_calloc(1, sizeof(*ws));
    if (!ws)
        return NULL;
    *ws = (struct wsconn){ .l = l, .fd = fd, .ops = ops, .ud = ud };
    ws_parser_init(&ws->in, true, max_msg);
    buf_init(&ws->out, out_max);
    if (loop_add_fd(l, fd, LOOP_READ, on_fd, ws, NULL) < 0) {
        ws_parser_release(&ws->in);
        free(ws);
        return NULL;
    }
    return ws;
}

void
wsconn_start(struct wsconn *ws, const char *extra, size_t n)
{
    if (n && ws_parser_feed(&ws->in, extra, n, NULL) == SF_OK && !drain(ws))
        return;
    on_fd(ws->l, ws->fd, 0, ws); /* bytes that came after the 101 went out */
}
