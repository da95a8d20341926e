/*
 * api_octopush.h - OctoPrint's push socket on slimfarmd's OctoPrint face
 * (api_octoprint.h), so OctoPrint apps and OctoPrint-based farm managers
 * watch the farm live instead of polling it: the farm as one printer, or
 * with ?printer=NAME on the socket's URL one farm printer.
 *
 *   GET /sockjs/websocket                     SockJS's raw websocket: one JSON message a
 *                                             text frame
 *   GET /sockjs/SERVER/SESSION/websocket      SockJS's websocket transport: "o" first,
 *                                             messages in 'a["..."]' frames, "h" every 25 s
 *                                             (src/base/sockjs.h); other transports 404
 *   GET /sockjs/info                          what SockJS clients ask first
 *
 * None needs a key on the upgrade (OctoPrint's need none: a socket logs in
 * with a message); one sent is checked as on any request, and the socket
 * may then only log in as that key.  The socket gets `connected`; after
 * {"auth": "NAME:SESSION"}, the name and session of POST /api/login's
 * answer, `history` and then `current` every OCTOPUSH_CURRENT_MS (500) times
 * the client's {"throttle": N} (1..1000), and `event` messages as prints
 * start, pause, resume, end (PrintStarted, PrintPaused, PrintResumed,
 * PrintDone, PrintFailed {reason: "error"}, PrintCancelled and PrintFailed
 * {reason: "cancelled"}), read from the farm's event log, and
 * PrinterStateChanged as the summary's state text changes.  {"subscribe":
 * {"state": bool, "events": bool or [names]}} narrows them as OctoPrint
 * 1.8+ does.  A wrong or ended session gets reauthRequired {"reason":
 * "stale"}; nothing is sent but `connected` until a valid auth.  Each
 * auth counts as a login of the client's address with its REST logins
 * (http_upgraded_login, authlimit.h): past the burst of failures the
 * socket gets reauthRequired and is closed (1013), whatever it sent.
 *
 * Sessions: POST /api/login makes one per login (api_octopush_login): 128
 * random bits, tied to the key it was made with, in a table of this
 * module's own (session.h: idle and absolute expiry, SESSION_PER_KEY_MAX a
 * key, least recently used evicted), apart from the dashboard's, so
 * OctoPrint clients never log the dashboard's browsers out.  An
 * authenticated socket checks its session every tick: when it ended
 * (expired, evicted, or its key removed by a reload) the socket gets
 * reauthRequired {"reason": "logout"} and closes (1008).
 *
 * Budgets: an unauthenticated socket holds a keyless connection slot
 * (http.h) and is closed (1008) after API_OCTOPUSH_AUTH_WAIT_MS; its auth
 * moves it into its key's class and counts it with the key's event
 * streams (HTTP_STREAMS_PER_KEY: past it, reauthRequired and close 1013).
 * The socket takes no commands, for any key: cancels go through POST
 * /api/job or the farm's API, which a read-only key may not use.
 *
 * Thread: the loop thread.
 */
#ifndef SF_API_API_OCTOPUSH_H
#define SF_API_API_OCTOPUSH_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"
#include "../base/loop.h"
#include "../farm/farm.h"
#include "../farm/farmcfg.h"
#include "../farm/store.h"
#include "api_read.h"
#include "http.h"
#include "route.h"
#include "session.h"

#define API_OCTOPUSH_TICK_MS 100 /* how often sockets are looked at */
/* An unauthenticated socket's life: it holds a keyless slot, which is sized for page loads
   (http.h); clients send their auth right after `connected`. */
#define API_OCTOPUSH_AUTH_WAIT_MS (HTTP_KEYLESS_IDLE_S * 1000)

struct api_octopush;

/* Sockets on loop l watching farm f and the store's event log, read on the API's reader
   reads (freed after p: a read in flight ends there); sessions with idle_ms and max_ms (<= 0:
   session.h's defaults).  NULL with err set. */
struct api_octopush *api_octopush_new(struct loop *l, struct api_read *reads, struct farm *f,
                                      int64_t idle_ms, int64_t max_ms, struct sf_err *err);
/* Close every socket (1001) and free; before http_free.  NULL is fine. */
void api_octopush_free(struct api_octopush *p);

/* A new login session for key into session (SESSION_TOKEN_LEN + 1 bytes); session.h's errors. */
int api_octopush_login(struct api_octopush *p, const char *key, char *session, struct sf_err *err);
/* A reload kept only keys: their sessions end (their sockets close on the next tick); how many. */
size_t api_octopush_keys_changed(struct api_octopush *p, const struct farmcfg_key *keys,
                                 size_t n_keys);
/* Open sockets (tests, logs). */
size_t api_octopush_count(const struct api_octopush *p);

/* Whether path is one of the socket's (they need no key). */
bool api_octopush_public(const char *path);
/* GET /sockjs/websocket and /sockjs/{*}: ctx is the struct api_compat_env. */
void api_octopush_route(void *ctx, const struct route_args *args, const struct http_req *req,
                        struct http_resp *resp);

#endif
