/*
 * http_int.h - internal to the http module (http.c, http_resp.c,
 * http_stream.c, http_upgrade.c): the server's state, its streams and
 * upgraded sockets, and how an answer is sent on an MHD connection.
 * Nothing outside src/api/http*.c includes it.
 *
 * Thread: whichever thread calls http_run().
 */
#ifndef SF_API_HTTP_INT_H
#define SF_API_HTTP_INT_H

#include <jansson.h>
#include <microhttpd.h>
#include <stdbool.h>

#include "http.h"
#include "http_budget.h"

struct authlimit;

/* A streamed response; lives from the route's answer until MHD frees it. */
struct stream {
    struct http *h;                /* owner */
    struct MHD_Connection *conn;   /* its connection */
    http_stream_fn fn;             /* produces the body */
    void *ud;                      /* fn's argument */
    void (*free_fn)(void *ud);     /* frees ud */
    bool suspended;                /* waiting for http_wake_streams */
    bool revoked;                  /* its key is gone: end it */
    bool event;                    /* an event stream (text/event-stream): counted per key */
    bool expired;                  /* past its lifetime: ends at its next quiet moment */
    bool retry_sent;               /* the "retry:" hint before that end is out */
    int64_t end_ms;                /* event stream: monotonic end of its lifetime */
    char key[FARMCFG_KEY_MAX + 1]; /* the API key it was opened with */
    struct stream *next;           /* in h->streams */
};

struct http {
    struct MHD_Daemon *d;        /* the MHD daemon, external epoll mode */
    struct http_config cfg;      /* as given; keys point at our copy */
    struct farmcfg_key *keys;    /* copy of the API keys */
    int port;                    /* bound port, -1 if none */
    struct stream *streams;      /* live streams */
    struct http_upgraded *ups;   /* websockets taken over by routes (http_upgrade.c) */
    struct http_defer *defers;   /* requests waiting for their answer */
    struct http_budget budget;   /* connections per class (http_budget.h) */
    int64_t next_end_ms;         /* earliest event stream lifetime end, or -1 */
    struct authlimit *authlimit; /* failed logins per address */
    void (*wake)(void *ud);      /* http_set_wake's hook, or NULL */
    void *wake_ud;
};

/* The answer of a stream route (resp->stream): queued on conn, or a 429
   past HTTP_STREAMS_PER_KEY event streams and sockets of key. */
enum MHD_Result http_send_stream(struct http *h, struct MHD_Connection *conn, const char *key,
                                 struct http_resp *resp);
/* 429: the key has HTTP_STREAMS_PER_KEY event streams and sockets open. */
enum MHD_Result http_send_too_many(struct MHD_Connection *conn);
/* End the event streams past their lifetime (at their next quiet moment). */
void http_streams_expire(struct http *h);
/* End the streams and sockets whose key is gone; returns how many. */
size_t http_streams_revoke(struct http *h);
/* Event streams and websockets open with key. */
size_t http_streams_of(const struct http *h, const char *key);
/* The configured key record of key, or NULL. */
const struct farmcfg_key *http_find_key(const struct http *h, const char *key);
/* May key still watch the farm (an event stream, a push socket): it exists and is not
   metrics-only (a reload can turn a key into one). */
bool http_key_may_watch(const struct http *h, const char *key);

/* The answer of an upgrading route (resp->upgrade): the 101 with the
   route's headers, the socket handed to it once sent (http_upgrade.c). */
enum MHD_Result http_send_upgrade(struct http *h, struct MHD_Connection *conn, const char *key,
                                  struct http_resp *resp, struct http_upgraded **pending);
/* The request that asked for pending is over: free it unless it was taken. */
void http_upgrade_done(struct http_upgraded *pending);
/* Sockets counted under key. */
size_t http_upgraded_of(const struct http *h, const char *key);
/* Mark the sockets whose key is gone revoked; returns how many. */
size_t http_upgraded_revoke(struct http *h);
/* Close every socket still open (http_free: their owners should have). */
void http_upgraded_close_all(struct http *h);

/* Queue j (the reference is taken) as the JSON answer; close: end the
   connection after it. */
enum MHD_Result http_send_json(struct MHD_Connection *conn, int status, json_t *j, bool close);
/* {"error": msg}; a 400, 401, 501 or 503 closes the connection. */
enum MHD_Result http_send_error(struct MHD_Connection *conn, int status, const char *msg);
/* A route's raw body (resp->body, freed by body_free) or open file (resp->fd, closed). */
enum MHD_Result http_send_raw(struct MHD_Connection *conn, struct http_resp *resp);
/* Put the route's extra headers on r. */
void http_add_headers(struct MHD_Response *r, const struct http_resp *resp);
/* Free what a route answered without sending it. */
void http_resp_discard(struct http_resp *resp);

#endif
