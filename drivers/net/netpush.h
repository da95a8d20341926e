/*
 * netpush.h - a network driver's push socket and how it stands in for the
 * polls (Moonraker's /websocket, OctoPrint's /sockjs/websocket): the
 * lifecycle both drivers share, over wsc.h.
 *
 * The driver opens the socket after a poll has answered (to the address
 * that poll reached); once the printer has said its first full status
 * (netpush_live), the socket's messages take the polls' place: the
 * driver's poll() sees netpush_standing and makes no request (the timer
 * stops), and a poll is still made at once after each action, to confirm
 * it.  What the socket says while a request holds the slot waits for the
 * slot to free (netpush_due), and is not judged before the poll that
 * confirms an action: its messages and our requests are two streams.
 * When the socket closes, goes silent or says what does not parse
 * (netpush_close with a reason), polling takes over at once and the
 * socket is tried again later, backoff 1 s doubling to
 * NETPUSH_BACKOFF_MAX_MS.  A URL the socket cannot take (https, a host
 * name: wsc.h) is polled only.
 *
 * Thread: the loop thread.
 */
#ifndef SF_DRIVERS_NET_NETPUSH_H
#define SF_DRIVERS_NET_NETPUSH_H

#include <stdbool.h>
#include <stdint.h>

#include "netdrv.h"
#include "wsc.h"

#define NETPUSH_BACKOFF_MAX_MS 60000 /* the longest wait before another socket */

struct netpush {
    struct wsc *ws;   /* open or opening, NULL if none */
    bool live;        /* its messages stand in for the polls */
    bool dirty;       /* a status not yet judged (the slot was taken) */
    bool never;       /* the URL cannot take a socket: poll only */
    int64_t retry_ms; /* loop time before which no socket is opened again */
    int backoff_ms;   /* the wait after the next failure */
    uint64_t updates; /* status messages taken */
};

/* A socket may be opened now: none is, the URL can take one, the config did not turn it off
   (poll_only), n is open, the backoff passed. */
bool netpush_may_open(const struct netpush *p, const struct netdrv *n);

/*
 * Open the socket to path at ip (the address the poll reached; NULL: the
 * URL's host) with n's key header and ops (ud: the driver).  False if it
 * could not (logged; a URL it can never reach sets never).
 */
bool netpush_open(struct netpush *p, struct netdrv *n, const char *ip, const char *path,
                  const struct wsc_ops *ops, void *ud);

/* The printer's first full status came: its messages replace the polls from now on. */
void netpush_live(struct netpush *p, struct netdrv *n);

/* The socket stands and its messages replace the polls (poll() makes no request). */
bool netpush_standing(const struct netpush *p, const struct netdrv *n);

/*
 * Close it.  why: logged, the backoff set, and when the socket stood,
 * polling takes over at once; NULL: quietly (the caller polls, or contact
 * is lost).  True if it stood.
 */
bool netpush_close(struct netpush *p, struct netdrv *n, const char *why);

/*
 * The socket stays open but its messages stand for the polls no longer
 * (the printer's side behind it went away and will say when it is back:
 * Moonraker's notify_klippy_disconnected); why is logged and, if it stood,
 * polling takes over at once.  netpush_live makes it stand again.
 */
void netpush_hold(struct netpush *p, struct netdrv *n, const char *why);
/* What the socket said is new and may be judged now (the slot free, no action to confirm
   first); true clears dirty: the caller judges it. */
bool netpush_due(struct netpush *p, const struct netdrv *n);

#endif
