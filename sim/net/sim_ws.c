/*
 * sim_ws.c - websocket connections of the simulated printers (sim_ws.h).
 *
 * The handshake is checked here and answered through
 * sim_http_reply_upgrade; once MHD has sent the 101 the socket is ours
 * and watched on the loop: reads go through a ws_parser (client frames
 * must be masked), writes through one output buffer flushed as the
 * socket takes it.  A connection that ends (close, error, EOF, a full
 * queue) is marked dead and reaped from a zero-delay timer, so no
 * callback ever sees its connection freed under it.
 *
 * Thread: the loop thread.
 */
#include "sim_ws.h"

#include <errno.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/socket.h>
#include <unistd.h>

#include "../../src/base/buf.h"
#include "../../src/base/mem.h"
#include "../../src/base/ws.h"

struct sim_ws {
    struct sim_ws_hub *hub;
    struct sim_http_upgraded *u;
    int fd;
    void *conn; /* the face's state */
    struct ws_parser in;
    struct buf out;
    bool want_write; /* LOOP_WRITE is watched */
    bool closing;    /* a close frame was queued: send nothing more */
    bool dead;       /* to be reaped */
    struct sim_ws *next;
};

struct sim_ws_hub {
    struct loop *l;
    const struct sim_ws_ops *ops;
    void *ud;
    struct sim_ws *conns;
    uint64_t reap_timer;
    uint64_t sent;
};

static void
flush(struct sim_ws *ws)
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
        loop_mod_fd(ws->hub->l, ws->fd, LOOP_READ | (want ? LOOP_WRITE : 0), NULL);
    }
}

static void reap(struct loop *l, void *ud);

static void
kill_later(struct sim_ws *ws)
{
    ws->dead = true;
    if (!ws->hub->reap_timer)
        ws->hub->reap_timer = loop_timer_add(ws->hub->l, 0, reap, ws->hub);
}

static void
destroy(struct sim_ws *ws)
{
    struct sim_ws_hub *hub = ws->hub;
    hub->ops->gone(ws, ws->conn, hub->ud);
    loop_del_fd(hub->l, ws->fd);
    if (ws->out.len) /* a last try for the close frame */
        (void)!send(ws->fd, ws->out.data, ws->out.len, MSG_NOSIGNAL | MSG_DONTWAIT);
    shutdown(ws->fd, SHUT_RDWR);
    sim_http_upgraded_close(ws->u);
    ws_parser_release(&ws->in);
    buf_release(&ws->out);
    free(ws);
}

static void
reap(struct loop *l, void *ud)
{
    (void)l;
    struct sim_ws_hub *hub = ud;
    hub->reap_timer = 0;
    for (struct sim_ws **pp = &hub->conns; *pp;) {
        struct sim_ws *ws = *pp;
        if (!ws->dead) {
            pp = &ws->next;
            continue;
        }
        *pp = ws->next;
        destroy(ws);
    }
}

static int
queue_frame(struct sim_ws *ws, enum ws_op op, const char *data, size_t len)
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
sim_ws_send(struct sim_ws *ws, const char *text, size_t len)
{
    int rc = queue_frame(ws, WS_TEXT, text, len);
    if (rc == SF_OK)
        ws->hub->sent++;
    return rc;
}

int
sim_ws_send_json(struct sim_ws *ws, json_t *v)
{
    char *text = v ? json_dumps(v, JSON_COMPACT) : NULL;
    json_decref(v);
    if (!text)
        return SF_ENOMEM;
    int rc = sim_ws_send(ws, text, strlen(text));
    free(text);
    return rc;
}

void
sim_ws_close(struct sim_ws *ws, uint16_t code, const char *reason)
{
    if (ws->dead || ws->closing)
        return;
    (void)ws_close_frame(&ws->out, code, reason, NULL);
    ws->closing = true;
    flush(ws);
    kill_later(ws);
}

/* One message from the client. */
static void
on_message(struct sim_ws *ws, const struct ws_msg *m)
{
    switch (m->op) {
    case WS_TEXT:
    case WS_BINARY:
        if (!ws->closing)
            ws->hub->ops->text(ws, ws->conn, m->data, m->len, ws->hub->ud);
        break;
    case WS_PING:
        queue_frame(ws, WS_PONG, m->data, m->len);
        break;
    case WS_CLOSE: /* answer with its code (RFC 6455 5.5.1) */
        sim_ws_close(ws, m->code == WS_CLOSE_NO_CODE ? WS_CLOSE_NORMAL : m->code, NULL);
        break;
    default:
        break;
    }
}

static void
on_fd(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)l;
    struct sim_ws *ws = ud;
    if (ws->dead)
        return;
    if (events & LOOP_WRITE)
        flush(ws);
    char chunk[16384];
    while (!ws->dead) {
        ssize_t k = recv(fd, chunk, sizeof(chunk), 0);
        if (k < 0 && errno == EINTR)
            continue;
        if (k < 0 && (errno == EAGAIN || errno == EWOULDBLOCK))
            break;
        if (k <= 0) { /* EOF or an error: the client is gone */
            kill_later(ws);
            return;
        }
        struct ws_msg m;
        int rc = ws_parser_feed(&ws->in, chunk, (size_t)k, NULL);
        while (rc == SF_OK && (rc = ws_parser_next(&ws->in, &m, NULL)) == 1 && !ws->dead)
            on_message(ws, &m), rc = SF_OK;
        if (rc < 0) {
            sim_ws_close(ws, ws->in.close_code ? ws->in.close_code : WS_CLOSE_PROTOCOL, NULL);
            return;
        }
    }
    if (ws->dead)
        kill_later(ws);
}

static void
on_upgraded(struct sim_http_upgraded *u, int fd, const char *extra, size_t n_extra, void *ud,
            int tag)
{
    struct sim_ws_hub *hub = ud;
    struct sim_ws *ws = mem_calloc(1, sizeof(*ws));
    if (!ws) {
        sim_http_upgraded_close(u);
        return;
    }
    ws->hub = hub;
    ws->u = u;
    ws->fd = fd;
    ws_parser_init(&ws->in, true, SIM_WS_MSG_MAX);
    buf_init(&ws->out, SIM_WS_OUT_MAX);
    if (loop_add_fd(hub->l, fd, LOOP_READ, on_fd, ws, NULL) < 0) {
        ws_parser_release(&ws->in);
        free(ws);
        sim_http_upgraded_close(u);
        return;
    }
    ws->next = hub->conns;
    hub->conns = ws;
    ws->conn = hub->ops->open(ws, tag, hub->ud);
    if (n_extra && ws_parser_feed(&ws->in, extra, n_extra, NULL) == SF_OK) {
        struct ws_msg m;
        while (!ws->dead && ws_parser_next(&ws->in, &m, NULL) == 1)
            on_message(ws, &m);
    }
    on_fd(hub->l, fd, 0, ws); /* bytes that came with the 101 in flight */
}

/* Whether header name's comma-separated value holds token (any case). */
static bool
has_token(struct sim_http_req *r, const char *name, const char *token)
{
    const char *v = sim_http_header(r, name);
    size_t n = strlen(token);
    while (v && *v) {
        while (*v == ' ' || *v == '\t' || *v == ',')
            v++;
        size_t k = strcspn(v, ",");
        size_t e = k;
        while (e && (v[e - 1] == ' ' || v[e - 1] == '\t'))
            e--;
        if (e == n && strncasecmp(v, token, n) == 0)
            return true;
        v += k;
    }
    return false;
}

void
sim_ws_accept(struct sim_http_req *r, struct sim_ws_hub *hub, int tag)
{
    const char *ver = sim_http_header(r, "Sec-WebSocket-Version");
    char accept[WS_ACCEPT_LEN + 1];
    if (strcmp(sim_http_method(r), "GET") != 0 || !has_token(r, "Upgrade", "websocket") ||
        !has_token(r, "Connection", "upgrade")) {
        /* tornado's words for a plain request on a websocket path */
        sim_http_reply(r, 400, "text/plain", "Can \"Upgrade\" only to \"WebSocket\".", 35);
        return;
    }
    if (!ver || strcmp(ver, "13") != 0) {
        sim_http_add_header(r, "Sec-WebSocket-Version", "13");
        sim_http_reply_empty(r, 426);
        return;
    }
    if (ws_accept(sim_http_header(r, "Sec-WebSocket-Key"), accept, NULL) < 0) {
        sim_http_reply(r, 400, "text/plain", "Missing/Invalid WebSocket headers", 33);
        return;
    }
    sim_http_add_header(r, "Upgrade", "websocket");
    sim_http_add_header(r, "Connection", "Upgrade");
    sim_http_add_header(r, "Sec-WebSocket-Accept", accept);
    sim_http_reply_upgrade(r, on_upgraded, hub, tag);
}

struct sim_ws_hub *
sim_ws_hub_new(struct loop *l, const struct sim_ws_ops *ops, void *ud)
{
    struct sim_ws_hub *hub = mem_calloc(1, sizeof(*hub));
    if (!hub)
        return NULL;
    hub->l = l;
    hub->ops = ops;
    hub->ud = ud;
    return hub;
}

void
sim_ws_hub_free(struct sim_ws_hub *hub)
{
    if (!hub)
        return;
    if (hub->reap_timer)
        loop_timer_cancel(hub->l, hub->reap_timer);
    while (hub->conns) {
        struct sim_ws *ws = hub->conns;
        hub->conns = ws->next;
        if (!ws->closing && !ws->dead)
            (void)ws_close_frame(&ws->out, WS_CLOSE_AWAY, NULL, NULL);
        destroy(ws);
    }
    free(hub);
}

size_t
sim_ws_hub_count(const struct sim_ws_hub *hub)
{
    size_t n = 0;
    for (const struct sim_ws *ws = hub->conns; ws; ws = ws->next)
        n += !ws->dead;
    return n;
}

void
sim_ws_hub_each(struct sim_ws_hub *hub, void (*fn)(struct sim_ws *ws, void *conn, void *arg),
                void *arg)
{
    for (struct sim_ws *ws = hub->conns; ws; ws = ws->next)
        if (!ws->dead && !ws->closing)
            fn(ws, ws->conn, arg);
}

void
sim_ws_hub_close_all(struct sim_ws_hub *hub, uint16_t code, const char *reason)
{
    for (struct sim_ws *ws = hub->conns; ws; ws = ws->next)
        sim_ws_close(ws, code, reason);
}

uint64_t
sim_ws_hub_sent(const struct sim_ws_hub *hub)
{
    return hub->sent;
}
