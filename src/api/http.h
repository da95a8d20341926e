/*
 * http.h - the HTTP server under the REST API: libmicrohttpd in external
 * epoll mode, so it runs on the daemon's loop with no thread of its own.
 *
 * It owns what every route needs and no route should repeat: API keys on
 * every request (X-Api-Key, or "Authorization: Bearer KEY" as Prometheus
 * and OctoPrint clients send it; missing or unknown -> 401, read-only key
 * on anything but GET/HEAD or with a request body -> 403, a metrics key on
 * anything but GET /metrics -> 403), which body a route
 * takes (a multipart upload only where body_kind says so), all of it
 * decided from the headers before a single body byte is read; capped
 * bodies (JSON body over body_max or upload over upload_max -> 413,
 * refused from Content-Length when the client announces it), multipart/
 * form-data parsing (MHD's post processor) streaming the "file" part into
 * an upload sink (a body that ends before its closing boundary -> 400),
 * and JSON replies whose text is valid UTF-8 whatever a client sent.
 * Routes see a struct http_req and fill a struct http_resp.
 *
 * Two ways in without an X-Api-Key header, both decided by the owner's
 * hooks: a public path (the dashboard's static files, which hold no data,
 * and its log out), and the session cookie (named by session_cookie) that
 * session_key() maps to an API key (a browser's EventSource and <img>
 * cannot send headers).  A cookie authorizes another method than GET/HEAD
 * only with the session's CSRF token in the X-Csrf-Token header, which no
 * page of another origin can read or make a browser send.
 *
 * Failed logins (401) are counted per client address (authlimit.h): an
 * address past its burst is answered 429 on every keyed request.
 *
 * Connections are budgeted by class (the limits below, with their
 * reasons; http_budget.h keeps the count): a connection that has not sent
 * a complete request head within header_timeout_ms, or is the oldest of
 * more than HTTP_PREAUTH_MAX such connections (or HTTP_PREAUTH_PER_IP_MAX
 * of its address), is closed; a request without a valid key is answered
 * 401 and its connection closed; keyless, read-only and read-write
 * requests each have their own slots (503 and close when full), so
 * neither clients without a key nor a read-only key can lock out the
 * read-write keys.  Event streams count per key, and end at their first
 * quiet moment past their lifetime.  A request framed two ways (http_frame.h)
 * is answered 400 and its connection closed.
 *
 * Driving it: the owner watches http_fd() for reading and calls http_run()
 * when it is readable or when http_timeout_ms() passes (http_loop.c does
 * this on the event loop; tests do it with epoll_wait).  Streams (Server-
 * Sent Events) that have nothing to send are suspended; http_wake_streams()
 * resumes them when there is news.
 *
 * Thread: every function on the thread that calls http_run().
 */
#ifndef SF_API_HTTP_H
#define SF_API_HTTP_H

#include <jansson.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <sys/types.h>

#include "../base/err.h"
#include "../farm/farmcfg.h"

#define HTTP_FIELDS_MAX 8          /* multipart fields besides the file */
#define HTTP_FIELD_MAX  (64 << 10) /* bytes per field: options JSON is far smaller */

/*
 * Connection budgets.  A connection is counted, from accept to close, in
 * one class: "pending" until its first request head is in, then the class
 * of its latest request: keyless (the login page's static files, or a
 * request about to be answered 401), read (a read-only or metrics key) or
 * write (a read-write key).  Each class has its own cap, and MHD's limit is
 * their sum, so no class can take another's slots: with every keyless and
 * read slot held, a read-write key still connects.  A request whose class
 * is full is answered 503 and its connection closed.  Behind a reverse
 * proxy every client has the proxy's address, so only classes without a
 * key are also capped per address.  The caps shrink (in proportion) when
 * RLIMIT_NOFILE cannot be raised to cover them plus HTTP_FD_RESERVE.
 */
/* Connections still sending their first request head; past this the
   oldest is closed (slow clients end their own, not others'). */
#define HTTP_PREAUTH_MAX 64
/* ... of which from one address; past this that address's oldest goes. */
#define HTTP_PREAUTH_PER_IP_MAX 16
/* Keyless connections: the login page is 4 files and a browser opens at
   most 6 connections to a host, so a few people logging in at once fit. */
#define HTTP_KEYLESS_MAX 32
/* ... from one address: one browser's worth. */
#define HTTP_KEYLESS_PER_IP_MAX 8
/* A keyless connection idle this long is closed: a page load is over in
   well under a second, and an idle keyless slot serves nobody. */
#define HTTP_KEYLESS_IDLE_S 5
/* Read-only and metrics keys: dashboards, scrapers and their streams. */
#define HTTP_READ_MAX 128
/* Read-write keys: operators, the CLI and slicers; no other class may
   take these. */
#define HTTP_WRITE_MAX 128
/* Above the class caps: connections already refused or shut down but not
   yet closed by MHD, so they never hold up a new keyed client. */
#define HTTP_CONNECTIONS_SPARE 32
#define HTTP_CONNECTIONS_MAX                                                                       \
    (HTTP_PREAUTH_MAX + HTTP_KEYLESS_MAX + HTTP_READ_MAX + HTTP_WRITE_MAX + HTTP_CONNECTIONS_SPARE)
/* File descriptors kept for everything else (printers, the store, uploads,
   libcurl, the pool): the soft RLIMIT_NOFILE is raised toward its hard
   limit to cover HTTP_CONNECTIONS_MAX plus this. */
#define HTTP_FD_RESERVE 256
/* A keyed connection idle this long is closed (keep-alive): the dashboard
   asks every 5 s, a script that waits longer reconnects. */
#define HTTP_IDLE_S 30
/* A request head must arrive within this (a client trickling header lines
   is never idle, so the idle timeout alone does not end it). */
#define HTTP_HEADER_TIMEOUT_MS 10000
/* Event streams (text/event-stream) open per API key (429 past it): a few
   operators sharing a key, each with a tab or two and `slimfarm watch`. */
#define HTTP_STREAMS_PER_KEY 16
/* An event stream ends at its first quiet moment after this (with a
   "retry:" hint): a client that stopped reading holds its slot no longer,
   and EventSource reconnects with Last-Event-ID, missing nothing.  The
   heartbeat is the events route's (a comment line every API_TICK_MS); a
   client that reads nothing fills the socket, the heartbeat cannot be
   written and HTTP_IDLE_S closes the stream sooner. */
#define HTTP_STREAM_LIFETIME_S 600
/* Reconnection delay a stream ended by its lifetime asks for (SSE retry:). */
#define HTTP_STREAM_RETRY_MS 1000
/* Extra response headers a route may set (ETag, Cache-Control, CSP ...). */
#define HTTP_RESP_HEADERS_MAX 8
#define HTTP_SESSION_COOKIE   "sf_session"   /* the session cookie's name unless configured */
#define HTTP_CSRF_HEADER      "X-Csrf-Token" /* lets a session cookie change things */

struct http;

/* A request as a route sees it. */
struct http_req {
    const char *method; /* "GET", "POST", ... */
    const char *path;   /* URL path without the query */
    bool read_only;     /* authenticated with a read-only key */
    const char *key;    /* the API key it came with (header or session); "" for a public path */
    const char *body;   /* non-multipart body, NUL-terminated ("" if none) */
    size_t body_len;    /* its length */
    const char *last_event_id;                /* Last-Event-ID header or NULL */
    const char *host;                         /* Host header or NULL */
    const char *query;                        /* raw query string after '?', or NULL */
    size_t n_fields;                          /* multipart fields other than the file */
    const char *field_name[HTTP_FIELDS_MAX];  /* their names */
    const char *field_value[HTTP_FIELDS_MAX]; /* their values, NUL-terminated */
    const char *upload_name; /* filename of the multipart "file" part, NULL if none */
    void *upload;            /* the sink's context for it, finished successfully */
    void *conn;              /* the connection, for http_req_header/http_req_arg */
};

/* Request header name (case-insensitive) or NULL. */
const char *http_req_header(const struct http_req *req, const char *name);
/* Query argument name (URL-decoded) or NULL. */
const char *http_req_arg(const struct http_req *req, const char *name);
/* The multipart form field name (its first value) or NULL. */
const char *http_req_field(const struct http_req *req, const char *name);

/*
 * Stream body: write up to max bytes to buf and return how many; 0 when
 * there is nothing to send now (the connection is suspended until
 * http_wake_streams), -1 to end the stream.
 */
typedef ssize_t (*http_stream_fn)(void *ud, char *buf, size_t max);

/*
 * A connection a route took over (a websocket): from the 101 on its socket
 * is the route's, counted like an event stream (HTTP_STREAMS_PER_KEY per
 * key, streams and sockets together) in its key's connection class.
 * fn gets the socket (non-blocking) and the bytes the client sent after
 * its request head; the owner closes it with http_upgraded_close, always
 * before http_free.
 */
struct http_upgraded;
typedef void (*http_upgrade_fn)(void *ud, struct http_upgraded *u, int fd, const char *extra,
                                size_t n_extra);

/* One extra response header. */
struct http_header {
    char name[32];
    char value[512];
};

/* What a route answers: json, or a raw body (body, or fd), or a stream. */
struct http_resp {
    int status;                    /* HTTP status */
    json_t *json;                  /* body (the server takes the reference) */
    const char *content_type;      /* of body, fd or stream (static string); NULL: the
                                      JSON or event-stream default */
    const void *body;              /* a raw body instead of json, body_len bytes */
    size_t body_len;               /* (status 304: none is sent) */
    void (*body_free)(void *body); /* frees body after sending; NULL: static */
    int fd;                        /* > 0: send fd_size bytes of this open file (closed
                                      by the server); 0: none */
    uint64_t fd_size;
    size_t n_headers; /* headers added with http_resp_header */
    struct http_header headers[HTTP_RESP_HEADERS_MAX];
    http_stream_fn stream;          /* or a streamed text/event-stream body */
    void *stream_ud;                /* its argument */
    void (*stream_free)(void *ud);  /* called when the stream ends */
    struct http_defer *defer;       /* set by http_defer(): the answer comes later */
    http_upgrade_fn upgrade;        /* or take the connection over: 101 with the headers */
    void *upgrade_ud;               /* its argument, the taker's once taken */
    void (*upgrade_free)(void *ud); /* frees upgrade_ud if it is never taken (NULL: not owned) */
};

typedef void (*http_route_fn)(void *ud, const struct http_req *req, struct http_resp *resp);

/* Add a response header; SF_EINVAL when full or too long (then not added). */
int http_resp_header(struct http_resp *resp, const char *name, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

/* The body a route takes, asked with the request head only. */
enum http_body {
    HTTP_BODY_NONE,   /* none (a small JSON body is read and ignored) */
    HTTP_BODY_JSON,   /* a JSON body up to body_max */
    HTTP_BODY_UPLOAD, /* multipart/form-data with a "file" part, up to upload_max */
};
typedef enum http_body (*http_body_fn)(void *ud, const char *method, const char *path);

/* Where the multipart "file" part goes, chunk by chunk. */
struct http_upload_sink {
    /* Start a file; NULL with err set (SF_EINVAL -> 400) to refuse it. */
    void *(*begin)(void *ud, const char *filename, struct sf_err *err);
    int (*write)(void *ctx, const char *data, size_t len, struct sf_err *err);
    /* The whole body arrived intact; SF_EINVAL (-> 400) to refuse the file
       (empty, say).  ctx stays valid for the route, which decides whether
       to keep the file; discard follows the route at once. */
    int (*finish)(void *ctx, struct sf_err *err);
    /* Free ctx, finished or not. */
    void (*discard)(void *ctx);
};

struct http_config {
    const char *host;               /* IPv4 address or "*" */
    int port;                       /* 0: pick a free one (see http_port) */
    const struct farmcfg_key *keys; /* n_keys API keys (copied) */
    size_t n_keys;
    size_t body_max;                     /* largest non-multipart body */
    size_t upload_max;                   /* largest multipart request */
    unsigned header_timeout_ms;          /* 0: HTTP_HEADER_TIMEOUT_MS */
    unsigned stream_lifetime_ms;         /* 0: HTTP_STREAM_LIFETIME_S */
    unsigned idle_s;                     /* 0: HTTP_IDLE_S (keyless: at most HTTP_KEYLESS_IDLE_S) */
    http_route_fn route;                 /* every authenticated request */
    http_body_fn body_kind;              /* NULL: every route takes any body */
    void *ud;                            /* route's and sink's argument */
    const struct http_upload_sink *sink; /* NULL: multipart files are refused */
    /* NULL or: path needs no key (static files; the routes refuse other
       methods than theirs). */
    bool (*is_public)(void *ud, const char *path);
    /* NULL or: the API key a session cookie's value stands for, NULL if
       none (then the request needs its header).  csrf is NULL for GET/HEAD,
       else the X-Csrf-Token header ("" if none), which must match. */
    const char *(*session_key)(void *ud, const char *token, const char *csrf);
    const char *session_cookie; /* its cookie's name (kept by the owner); NULL: sf_session */
};

/*
 * Start listening; NULL with err set (SF_EIO: address in use ...).  A port
 * of -1 listens nowhere: connections come only through http_add_connection.
 */
struct http *http_new(const struct http_config *cfg, struct sf_err *err);
/* Resume and close every stream, stop listening, free. */
void http_free(struct http *h);

/*
 * Replace the API keys (SIGHUP reload); SF_ENOMEM on failure (old keys
 * kept).  Streams opened with a key that is gone end (after what they have
 * already produced); returns how many through *n_closed (NULL allowed).
 */
int http_set_keys(struct http *h, const struct farmcfg_key *keys, size_t n_keys, size_t *n_closed);
/* Replace the upload limit (SIGHUP reload); requests already reading keep theirs. */
void http_set_upload_max(struct http *h, size_t upload_max);

/* Serve a connected socket (the fuzz target's socketpair); SF_EIO if refused. */
int http_add_connection(struct http *h, int fd);

int http_port(const struct http *h);
/* The fd to watch for reading. */
int http_fd(const struct http *h);
/* ms until http_run() must be called even without I/O; -1 for none. */
int64_t http_timeout_ms(struct http *h);
/* Do all pending work; SF_EIO if MHD failed. */
int http_run(struct http *h);
/* Resume suspended streams (there is news for them). */
void http_wake_streams(struct http *h);
/* Resume the one stream whose stream_ud is ud, if it is suspended (its own news came). */
void http_wake_stream(struct http *h, void *ud);
/*
 * The owner's hook for a connection resumed outside http_run() (a stream
 * woken, a deferred answer given): MHD only sends it when it runs again,
 * so wake(ud) must make http_run() happen soon and re-arm its timeout.
 * wake is called from wherever the resume happened (a route included), so
 * it must not run the server itself: http_loop.c schedules a 0 ms timer.
 */
void http_set_wake(struct http *h, void (*wake)(void *ud), void *ud);

/*
 * Copy s into out (cap bytes with the NUL) as valid UTF-8: each byte that
 * starts no valid sequence becomes U+FFFD, and the text is cut only
 * between characters.  Returns out.
 */
char *http_text_clean(char *out, size_t cap, const char *s);

/*
 * A route that must wait for a worker (checking an uploaded file off the
 * loop thread) defers its answer: it calls http_defer(resp) and returns;
 * the connection waits, suspended, keeping its upload; later, on this
 * thread, http_defer_answer() gives the answer (a struct http_resp filled
 * as a route fills it) and frees the handle.  If the client leaves or the
 * server is freed first, the handle stays until then and the answer is
 * dropped (http_defer_alive() says so; the upload is gone).  NULL when out
 * of memory: the route answers now.
 */
struct http_defer;
struct http_defer *http_defer(struct http_resp *resp);
bool http_defer_alive(const struct http_defer *d);
/* The request's upload (the sink's context), NULL once the client is gone. */
void *http_defer_upload(struct http_defer *d);
void http_defer_answer(struct http_defer *d, struct http_resp *resp);
/* The line that logs the deferred answer's status when it goes out ("METHOD PATH by WHO":
   ": STATUS" follows): an operator's change is logged with what came of it, deferred or not.
   NULL d is ignored. */
void http_defer_audit(struct http_defer *d, const char *line);

/* The API key u's request came with ("" for a public path). */
const char *http_upgraded_key(const struct http_upgraded *u);
/*
 * Count u under key from now on (a socket that logs in after its upgrade,
 * as OctoPrint's push socket does), in key's connection class; *read_only
 * says whether key is read-only.  SF_EINVAL when key is unknown or is not
 * the one u came with; SF_EAGAIN when key has HTTP_STREAMS_PER_KEY event
 * streams and sockets open or its class is full (close u then).  Again with
 * the same key: SF_OK, nothing changes.
 */
int http_upgraded_auth(struct http_upgraded *u, const char *key, bool *read_only,
                       struct sf_err *err);
/*
 * A login on u (its owner's own, as OctoPrint's push socket's auth
 * message) that failed or passed, counted with the REST logins of u's
 * client address (authlimit.h): 0, or the seconds to wait when the
 * address is past its burst (refuse the login then, whatever it was).
 */
unsigned http_upgraded_login(struct http_upgraded *u, bool failed, const char *why);
/* Whether u's key was revoked (http_set_keys): its owner closes it. */
bool http_upgraded_revoked(const struct http_upgraded *u);
/* How long an upgraded socket may live, ms: an event stream's lifetime (stream_lifetime_ms). */
int64_t http_upgraded_lifetime_ms(const struct http_upgraded *u);
/* Close u's socket and free u: the owner's last call on it. */
void http_upgraded_close(struct http_upgraded *u);

/* Helpers for routes: status with {"error": msg} body (msg made valid UTF-8). */
void http_error(struct http_resp *resp, int status, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

/*
 * The HTTP status of a failure, the one map every route uses:
 *   SF_EINVAL 400 (bad input), SF_ENOTFOUND 404, SF_EAGAIN 409 (not now:
 *   not in a state for it, or busy), SF_EUNSUPP 501, SF_EUNREACH 503 (a
 *   printer that does not answer), SF_ECANCELED 503 (the daemon is
 *   stopping), anything else 500.
 */
int http_status_of(int code);
/* http_error with the status of failure code and its message msg. */
void http_fail(struct http_resp *resp, int code, const char *msg);

#endif
