/*
 * sim_ws.c - websocket connections of the simulated printers (sim_ws.h).
 *
 * The handshake is checked here and answered through
 * sim_http_reply_upgrade; once MHD has sent the 101 the socket is served
 * by src/base/wsconn.c (the frames, the queue, the close handshake, the
 * reaping on a later turn), which slimfarmd's own push socket shares.
 * The hub keeps the list of a face's sockets and counts what they send.
 *
 * Thread: the loop thread.
 */
#include "sim_ws.h"

#include <stdbool.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/base/mem.h"
#include "../../src/base/ws.h"
#include "../../src/base/wsconn.h"

struct sim_ws {
    struct sim_ws_hub *hub;
    struct sim_http_upgraded *u;
    struct wsconn *wc; /* the socket (src/base/wsconn.h) */
    void *conn;        /* the face's state */
    struct sim_ws *next;
};

struct sim_ws_hub {
    struct loop *l;
    const struct sim_ws_ops *ops;
    void *ud;
    struct sim_ws *conns;
    uint64_t sent;
};

int
sim_ws_send(struct sim_ws *ws, const char *text, size_t len)
{
    int rc = wsconn_send(ws->wc, text, len);
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
    wsconn_close(ws->wc, code, reason);
}

static void
on_text(struct wsconn *wc, const char *text, size_t len, void *ud)
{
    (void)wc;
    struct sim_ws *ws = ud;
    ws->hub->ops->text(ws, ws->conn, text, len, ws->hub->ud);
}

/* The socket is gone: the face drops its state, MHD closes the socket. */
static void
on_gone(struct wsconn *wc, void *ud)
{
    (void)wc;
    struct sim_ws *ws = ud;
    struct sim_ws_hub *hub = ws->hub;
    for (struct sim_ws **pp = &hub->conns; *pp; pp = &(*pp)->next)
        if (*pp == ws) {
            *pp = ws->next;
            break;
        }
    hub->ops->gone(ws, ws->conn, hub->ud);
    sim_http_upgraded_close(ws->u);
    free(ws);
}

static const struct wsconn_ops wc_ops = { on_text, on_gone };

static void
on_upgraded(struct sim_http_upgraded *u, int fd, const char *extra, size_t n_extra, void *ud,
            int tag)
{
    struct sim_ws_hub *hub = ud;
    struct sim_ws *ws = mem_calloc(1, sizeof(*ws));
    if (ws)
        ws->wc = wsconn_new(hub->l, fd, SIM_WS_MSG_MAX, SIM_WS_OUT_MAX, &wc_ops, ws);
    if (!ws || !ws->wc) {
        free(ws);
        sim_http_upgraded_close(u);
        return;
    }
    ws->hub = hub;
    ws->u = u;
    ws->next = hub->conns;
    hub->conns = ws;
    ws->conn = hub->ops->open(ws, tag, hub->ud);
    wsconn_start(ws->wc, extra, n_extra);
}

void
sim_ws_accept(struct sim_http_req *r, struct sim_ws_hub *hub, int tag)
{
    char accept[WS_ACCEPT_LEN + 1];
    const char *why;
    int status =
        ws_handshake(sim_http_method(r), sim_http_header(r, "Upgrade"),
                     sim_http_header(r, "Connection"), sim_http_header(r, "Sec-WebSocket-Version"),
                     sim_http_header(r, "Sec-WebSocket-Key"), accept, &why);
    if (status == 426) {
        sim_http_add_header(r, "Sec-WebSocket-Version", "13");
        sim_http_reply_empty(r, 426);
        return;
    }
    if (status != 101) {
        sim_http_reply(r, (unsigned)status, "text/plain", why, strlen(why));
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
    while (hub->conns) /* each leaves the list in on_gone */
        wsconn_free(hub->conns->wc, WS_CLOSE_AWAY);
    free(hub);
}

size_t
sim_ws_hub_count(const struct sim_ws_hub *hub)
{
    size_t n = 0;
    for (const struct sim_ws *ws = hub->conns; ws; ws = ws->next)
        n += !wsconn_dead(ws->wc);
    return n;
}

void
sim_ws_hub_each(struct sim_ws_hub *hub, void (*fn)(struct sim_ws *ws, void *conn, void *arg),
                void *arg)
{
    for (struct sim_ws *ws = hub->conns; ws; ws = ws->next)
        if (!wsconn_closing(ws->wc))
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
