/*
 * wsc.h - a websocket client on the daemon's loop, for a printer's push
 * socket (Moonraker's /websocket, OctoPrint's /sockjs/websocket): RFC 6455 over plain TCP, framed
 * by src/base/ws.h.
 *
 * wsc_new connects without blocking (http:// URLs; to the address the
 * caller gives, the one its HTTP client reached, else to the URL's host
 * if that is an IP address or "localhost": a name would need a resolver
 * off the loop.  https:// would need a TLS stack here.  For what it
 * cannot reach it fails with SF_EUNSUPP and the caller keeps polling),
 * sends the upgrade request with the caller's
 * headers, checks the 101 and Sec-WebSocket-Accept, then hands each text
 * message to ops->text.  Frames go out masked, as a client's must.  A
 * ping is answered; every WSC_PING_MS the client pings, and a server that
 * sends nothing for WSC_DEAD_MS, or does not finish the handshake in
 * WSC_HANDSHAKE_MS, is dropped: ops->closed says why, once.
 *
 * Thread: the loop thread.  The owner frees it (wsc_free), also from its
 * own callbacks.
 */
#ifndef SF_DRIVERS_NET_WSC_H
#define SF_DRIVERS_NET_WSC_H

#include <stddef.h>

#include "../../src/base/err.h"
#include "../../src/base/loop.h"

#define WSC_HANDSHAKE_MS 5000
#define WSC_PING_MS      5000
#define WSC_DEAD_MS      15000
#define WSC_MSG_MAX      ((size_t)4 << 20) /* a status update is a few KiB; a file list more */

struct wsc;

struct wsc_ops {
    void (*open)(struct wsc *w, void *ud);                               /* the 101 came */
    void (*text)(struct wsc *w, const char *text, size_t len, void *ud); /* a message */
    void (*closed)(struct wsc *w, const char *why, void *ud);            /* gone, once */
};

/*
 * Connect to url (http://HOST[:PORT]) at address ip (NULL or "": HOST, an
 * IP address or localhost) and ask for path with extra header lines (each
 * ending "\r\n", or NULL).  NULL with err set: SF_EUNSUPP for a URL it
 * cannot reach this way, SF_EIO for a socket error.
 */
struct wsc *wsc_new(struct loop *l, const char *url, const char *ip, const char *path,
                    const char *headers, const struct wsc_ops *ops, void *ud, struct sf_err *err);

/* Queue a text message.  SF_EIO when the socket is not open (or its queue is full). */
int wsc_send(struct wsc *w, const char *text, size_t len);

/* Close and free (no callback).  NULL is fine. */
void wsc_free(struct wsc *w);

#endif
