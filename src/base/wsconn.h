/*
 * wsconn.h - the server side of one websocket on the event loop: a socket
 * whose HTTP upgrade is done (libmicrohttpd hands it over after the 101),
 * read and written as RFC 6455 frames through ws.h.  Shared by the
 * simulators' push sockets (sim/net/sim_ws.c) and slimfarmd's OctoPrint
 * push socket (src/api/api_octopush.c), so the two serve one protocol
 * engine.
 *
 * Client frames must be masked.  Text (and binary) messages go to
 * ops->text; pings are answered with pongs; a close is answered with the
 * client's code and the connection goes; a protocol error closes with
 * ws.h's code.  Writes queue up to out_max bytes: a client that reads
 * slower than that loses its connection (a queue that would pass the cap
 * closes it).
 *
 * A connection ends only on a later loop turn (a zero-delay timer), never
 * inside a callback: then its fd leaves the loop, a last try sends what is
 * queued (the close frame), the socket is shut down and ops->gone runs,
 * in which the owner drops its state and closes the fd (or the upgrade
 * handle that owns it); the wsconn is freed after.
 *
 * Thread: the loop's thread.  The fd stays the owner's to close.
 */
#ifndef SF_BASE_WSCONN_H
#define SF_BASE_WSCONN_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "loop.h"

struct wsconn;

struct wsconn_ops {
    /* A text or binary message (NUL-terminated; valid during the call). */
    void (*text)(struct wsconn *ws, const char *text, size_t len, void *ud);
    /* It is gone (shut down, off the loop): the owner drops it and closes the fd. */
    void (*gone)(struct wsconn *ws, void *ud);
};

/*
 * Serve fd (non-blocking, upgraded) on l: messages up to max_msg bytes in,
 * up to out_max bytes queued out.  Nothing is read until wsconn_start.
 * NULL when out of memory or the loop refuses the fd (the caller closes it).
 */
struct wsconn *wsconn_new(struct loop *l, int fd, size_t max_msg, size_t out_max,
                          const struct wsconn_ops *ops, void *ud);
/* Take the bytes that came with the upgrade (extra, n), then read the socket. */
void wsconn_start(struct wsconn *ws, const char *extra, size_t n);
/* Set the owner's argument for ops. */
void wsconn_set_ud(struct wsconn *ws, void *ud);

/*
 * Queue a text message.  SF_EIO once the connection is closing or gone,
 * or when the queue would pass out_max (the connection then closes).
 */
int wsconn_send(struct wsconn *ws, const char *text, size_t len);
/* Send a close frame with code and reason (NULL: none); the connection goes on a later turn. */
void wsconn_close(struct wsconn *ws, uint16_t code, const char *reason);
/* Close now (a close frame with code is tried if none was sent), ops->gone, free. */
void wsconn_free(struct wsconn *ws, uint16_t code);

/* Whether it is closing (a close frame queued) or gone: nothing more is sent. */
bool wsconn_closing(const struct wsconn *ws);
/* Whether it is gone (to be freed on a later turn). */
bool wsconn_dead(const struct wsconn *ws);

#endif
