/*
 * sim_ws.h - websocket push sockets for the simulated network printers
 * (OctoPrint's /sockjs, Moonraker's /websocket): the handshake on a
 * sim_http request, then the socket on our loop, framed by src/base/ws.h.
 *
 * A face owns a hub: its open connections, the callbacks they report to,
 * and the way to reach them all (sim_ws_hub_each, for pushes).  A route's
 * handler calls sim_ws_accept, which checks the handshake (GET with
 * Upgrade: websocket, Connection: upgrade, Sec-WebSocket-Version 13 and a
 * valid Sec-WebSocket-Key; else 400, or 426 for another version) and
 * answers 101.  Text (and binary) messages arrive through ops->text; pings
 * are answered; a close is answered and the connection goes.  A protocol
 * error closes with ws.h's code.  Writes queue up to SIM_WS_OUT_MAX bytes;
 * a client that reads slower loses its connection.
 *
 * Connections go away only on a later loop turn (never inside a
 * callback), after ops->gone.
 *
 * Thread: the loop thread.  The hub owns its connections; free it before
 * the sim_http the sockets came through.
 */
#ifndef SF_SIM_NET_SIM_WS_H
#define SF_SIM_NET_SIM_WS_H

#include <jansson.h>
#include <stddef.h>
#include <stdint.h>

#include "../../src/base/loop.h"
#include "sim_http.h"

/* Largest message a client may send, and bytes queued to one client. */
#define SIM_WS_MSG_MAX ((size_t)1 << 20)
#define SIM_WS_OUT_MAX ((size_t)8 << 20)

struct sim_ws;
struct sim_ws_hub;

struct sim_ws_ops {
    /* A connection opened (tag as given to sim_ws_accept): its state, NULL if none. */
    void *(*open)(struct sim_ws *ws, int tag, void *ud);
    /* A message from it (NUL-terminated; valid during the call). */
    void (*text)(struct sim_ws *ws, void *conn, const char *text, size_t len, void *ud);
    /* It is going: free conn; ws must not be used after. */
    void (*gone)(struct sim_ws *ws, void *conn, void *ud);
};

/* A hub on loop l reporting to ops with ud; NULL if out of memory. */
struct sim_ws_hub *sim_ws_hub_new(struct loop *l, const struct sim_ws_ops *ops, void *ud);
/* Close every connection (1001, going away), each through ops->gone, and free.  NULL is fine. */
void sim_ws_hub_free(struct sim_ws_hub *hub);
/* Open connections. */
size_t sim_ws_hub_count(const struct sim_ws_hub *hub);
/* Call fn on each open (not closing) connection with its state. */
void sim_ws_hub_each(struct sim_ws_hub *hub, void (*fn)(struct sim_ws *ws, void *conn, void *arg),
                     void *arg);
/* Close every open connection with code and reason (they go on a later turn). */
void sim_ws_hub_close_all(struct sim_ws_hub *hub, uint16_t code, const char *reason);
/* Messages sent to clients so far (all connections; the push rate in stats). */
uint64_t sim_ws_hub_sent(const struct sim_ws_hub *hub);

/* In a handler: answer the websocket handshake (101) for hub, or 400/426 if it is none. */
void sim_ws_accept(struct sim_http_req *r, struct sim_ws_hub *hub, int tag);

/* Queue a text message.  SF_EIO once the connection closes, or when the queue would pass its cap
 * (the connection is then closed). */
int sim_ws_send(struct sim_ws *ws, const char *text, size_t len);
/* Queue a JSON value as text (stolen). */
int sim_ws_send_json(struct sim_ws *ws, json_t *v);
/* Send a close frame with code and reason; the connection goes on a later turn. */
void sim_ws_close(struct sim_ws *ws, uint16_t code, const char *reason);

#endif
