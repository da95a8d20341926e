/*
 * octopush.h - OctoPrint's push socket protocol without the I/O
 * (docs/api/push.rst and server/util/sockjs.py's PrinterStateConnection,
 * OctoPrint 1.11): what a client's messages ask for (auth, throttle,
 * subscribe) and how a server message is written for either transport.
 * Shared by the OctoPrint simulator (sim/net/sim_octoprint_push.c) and
 * slimfarmd's OctoPrint face (src/api/api_octopush.c), which own the
 * sockets (wsconn.h) and decide what to send.
 *
 * Thread: any; a struct octopush_sub is one socket's.
 */
#ifndef SF_BASE_OCTOPUSH_H
#define SF_BASE_OCTOPUSH_H

#include <jansson.h>
#include <stdbool.h>
#include <stddef.h>

#define OCTOPUSH_CURRENT_MS   500  /* OctoPrint's base rate of `current` */
#define OCTOPUSH_THROTTLE_MAX 1000 /* the largest {"throttle": N} taken */

/* What one socket asked for. */
struct octopush_sub {
    bool state;     /* current and history wanted */
    json_t *events; /* event names wanted; NULL: all; an empty array: none */
    int throttle;   /* current every OCTOPUSH_CURRENT_MS times this */
};

enum octopush_msg {
    OCTOPUSH_IGNORED,   /* not JSON, not an object, a bad value: OctoPrint logs and drops it */
    OCTOPUSH_AUTH,      /* {"auth": "NAME:SESSION"}: the string is in auth */
    OCTOPUSH_THROTTLE,  /* {"throttle": N}: applied */
    OCTOPUSH_SUBSCRIBE, /* {"subscribe": {...}}: applied (what it does not give is off) */
};

/* A new socket's: state on, every event, throttle 1. */
void octopush_sub_init(struct octopush_sub *s);
void octopush_sub_release(struct octopush_sub *s);

/*
 * One client message (text, len): throttle and subscribe are applied to s
 * (*history set when state was turned on: send history then); for
 * OCTOPUSH_AUTH its string is copied to auth (auth_cap bytes; a longer one
 * is OCTOPUSH_IGNORED).
 */
enum octopush_msg octopush_message(struct octopush_sub *s, const char *text, size_t len, char *auth,
                                   size_t auth_cap, bool *history);

/* Whether s wants event name. */
bool octopush_wants(const struct octopush_sub *s, const char *name);

/*
 * The text of message {type: payload} (payload stolen; NULL sends null),
 * in a SockJS frame when framed (sockjs.h); free() it.  NULL when out of
 * memory.
 */
char *octopush_text(const char *type, json_t *payload, bool framed);

#endif
