/*
 * sockjs.h - the SockJS websocket transport's framing (sockjs-protocol
 * 0.3, as sockjs-tornado serves it under OctoPrint's /sockjs/SERVER/
 * SESSION/websocket): the server opens with "o", sends its messages as
 * 'a["<msg>",...]' and a heartbeat "h"; the client sends '["<msg>",...]'
 * (or one JSON string).  Shared by the OctoPrint simulator's push socket
 * and slimfarmd's (sim/net/sim_octoprint_push.c, src/api/api_octopush.c).
 *
 * Thread: any; no state.
 */
#ifndef SF_BASE_SOCKJS_H
#define SF_BASE_SOCKJS_H

#include <stddef.h>

#define SOCKJS_OPEN         "o"   /* the server's first frame */
#define SOCKJS_HEARTBEAT    "h"   /* the server's heartbeat frame */
#define SOCKJS_HEARTBEAT_MS 25000 /* sockjs-tornado's heartbeat_delay */

/* msg (len bytes) as one server frame 'a["<msg>"]'; free() it.  NULL when out of memory. */
char *sockjs_frame(const char *msg, size_t len);

/*
 * Each message of a client frame (text, len) to fn in order; -1 when the
 * frame is neither a JSON array nor a JSON string (the server then closes
 * with 1002 "Broken framing."), else the number of messages.  Array items
 * that are not strings are skipped.
 */
int sockjs_unframe(const char *text, size_t len, void (*fn)(void *arg, const char *msg, size_t len),
                   void *arg);

#endif
