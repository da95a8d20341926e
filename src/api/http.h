/*
 * http.h - the HTTP server under the REST API: libmicrohttpd in external
 * epoll mode, so it runs on the daemon's loop with no thread of its own.
 *
 * It owns what every route needs and no route should repeat: API keys on
 * every request (X-Api-Key; missing or unknown -> 401, read-only key on
 * anything but GET/HEAD -> 403), capped bodies (JSON body over body_max or
 * upload over upload_max -> 413, refused from Content-Length before any
 * byte is read when the client announces it), multipart/form-data parsing
 * (MHD's post processor) streaming the "file" part into an upload sink, and
 * JSON replies.  Routes see a struct http_req and fill a struct http_resp.
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

#define HTTP_FIELDS_MAX      8          /* multipart fields besides the file */
#define HTTP_FIELD_MAX       (64 << 10) /* bytes per field: options JSON is far smaller */
#define HTTP_CONNECTIONS_MAX 256        /* concurrent clients: a farm has few operators */
#define HTTP_TIMEOUT_S       60         /* idle connection timeout */

struct http;

/* A request as a route sees it. */
struct http_req {
    const char *method;                       /* "GET", "POST", ... */
    const char *path;                         /* URL path without the query */
    bool read_only;                           /* authenticated with a read-only key */
    const char *body;                         /* non-multipart body, NUL-terminated ("" if none) */
    size_t body_len;                          /* its length */
    const char *last_event_id;                /* Last-Event-ID header or NULL */
    size_t n_fields;                          /* multipart fields other than the file */
    const char *field_name[HTTP_FIELDS_MAX];  /* their names */
    const char *field_value[HTTP_FIELDS_MAX]; /* their values, NUL-terminated */
    const char *upload_name; /* filename of the multipart "file" part, NULL if none */
    void *upload;            /* the sink's context for it, finished successfully */
};

/*
 * Stream body: write up to max bytes to buf and return how many; 0 when
 * there is nothing to send now (the connection is suspended until
 * http_wake_streams), -1 to end the stream.
 */
typedef ssize_t (*http_stream_fn)(void *ud, char *buf, size_t max);

/* What a route answers. */
struct http_resp {
    int status;                    /* HTTP status */
    json_t *json;                  /* body (the server takes the reference) */
    http_stream_fn stream;         /* or a streamed text/event-stream body */
    void *stream_ud;               /* its argument */
    void (*stream_free)(void *ud); /* called when the stream ends */
};

typedef void (*http_route_fn)(void *ud, const struct http_req *req, struct http_resp *resp);

/* Where the multipart "file" part goes, chunk by chunk. */
struct http_upload_sink {
    /* Start a file; NULL with err set (SF_EINVAL -> 400) to refuse it. */
    void *(*begin)(void *ud, const char *filename, struct sf_err *err);
    int (*write)(void *ctx, const char *data, size_t len, struct sf_err *err);
    /* The last chunk arrived; ctx stays valid for the route. */
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
    http_route_fn route;                 /* every authenticated request */
    void *ud;                            /* route's and sink's argument */
    const struct http_upload_sink *sink; /* NULL: multipart files are refused */
};

/* Start listening; NULL with err set (SF_EIO: address in use ...). */
struct http *http_new(const struct http_config *cfg, struct sf_err *err);
/* Resume and close every stream, stop listening, free. */
void http_free(struct http *h);

/* Replace the API keys (SIGHUP reload); SF_ENOMEM on failure (old keys kept). */
int http_set_keys(struct http *h, const struct farmcfg_key *keys, size_t n_keys);

int http_port(const struct http *h);
/* The fd to watch for reading. */
int http_fd(const struct http *h);
/* ms until http_run() must be called even without I/O; -1 for none. */
int64_t http_timeout_ms(struct http *h);
/* Do all pending work; SF_EIO if MHD failed. */
int http_run(struct http *h);
/* Resume suspended streams (there is news for them). */
void http_wake_streams(struct http *h);

/* Helpers for routes: status with {"error": msg} body. */
void http_error(struct http_resp *resp, int status, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

#endif
