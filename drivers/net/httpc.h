/*
 * httpc.h - HTTP(S) and FTP(S) requests on the event loop: libcurl's multi
 * interface driven by loop.h, for every network printer driver (OctoPrint,
 * Moonraker, PrusaLink, and Bambu's FTPS upload).
 *
 * How it runs: curl's sockets are watched with loop_add_fd/loop_mod_fd/
 * loop_del_fd (CURLMOPT_SOCKETFUNCTION), its one timeout is a loop timer
 * (CURLMOPT_TIMERFUNCTION), and curl_multi_socket_action does only what is
 * ready.  No thread of ours and no blocking call: a request is started,
 * and its completion arrives later as a callback on the loop thread.  (Name
 * lookups run on libcurl's own resolver threads when libcurl is built with
 * the threaded resolver, as Debian's is; nothing of ours runs there.)
 *
 * One client per loop, shared: all printers of a farm go through one curl
 * multi handle, so connections to a printer are kept alive and reused
 * between polls (one TCP/TLS handshake per printer, not one per poll: with
 * 50 printers polled every second that is the difference between 100 new
 * connections a second and none), and there is one socket table and one
 * timer.  httpc_get(loop) hands out that shared client, created on first
 * use and freed by the last httpc_put(); drivers call it from create and
 * put it in destroy, so neither the farm nor the tests plumb a client
 * through drv_config.  httpc_new()/httpc_free() make a private one (tests,
 * tools).
 *
 * Request bodies come from memory (copied), from a file streamed from disk
 * in small reads (a 100 MB G-code file never sits in memory), or as
 * multipart/form-data whose file parts are also streamed from disk.  The
 * response body goes into a buffer capped per request (max_body): a larger
 * body fails the request with SF_ENOMEM and a message saying so.
 *
 * Thread: the loop thread only (the shared-client registry behind
 * httpc_get/httpc_put is locked, so clients of different loops on
 * different threads are fine).  Callbacks run on the loop thread.
 */
#ifndef SF_DRIVERS_NET_HTTPC_H
#define SF_DRIVERS_NET_HTTPC_H

#include <curl/curl.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../../src/base/err.h"
#include "../../src/base/loop.h"

/* Response body cap when a request gives none: status JSON is a few kB. */
#define HTTPC_BODY_MAX_DEFAULT ((size_t)1 << 20)
/* Response headers kept per request (for Location and friends). */
#define HTTPC_HEADERS_MAX ((size_t)16 << 10)
/* Whole-request timeout when a request gives none. */
#define HTTPC_TIMEOUT_MS_DEFAULT 30000
/* Connect timeout when a request gives none. */
#define HTTPC_CONNECT_TIMEOUT_MS_DEFAULT 5000

struct httpc;
struct httpc_req;

/* The outcome of one request, valid only during the done callback. */
struct httpc_result {
    int code;            /* SF_OK: a response arrived (any status, even 500); else SF_ETIMEDOUT
                            (timeout or stall), SF_EIO (refused, reset, DNS, TLS; see err), SF_ENOMEM
                            (body over max_body, or out of memory) */
    long status;         /* HTTP status (or FTP reply code); 0 if no response */
    const char *body;    /* response body, NUL-terminated (not counted in body_len); never NULL */
    size_t body_len;     /* its bytes */
    const char *headers; /* the final response's header block, "Name: value\r\n" lines */
    const char *peer_ip; /* the address it reached (libcurl's primary IP), "" if none: a
                            socket of the caller's own goes there without resolving again */
    struct sf_err err;   /* code != SF_OK: what happened, naming the URL */
    const char *detail;  /* code != SF_OK: libcurl's own words, without the URL ("" if none) */
    bool tls_peer;       /* SF_EIO because the server's certificate failed verification (its
                            chain, or the name: an operator's fix, not worth a retry) */
    uint64_t body_read;  /* a body_path body: its bytes handed to curl, which cannot rewind
                            it, so no attempt sent more; a form with file parts: the most
                            of each handed to curl in any one attempt (curl rewinds a form
                            to send it again), summed.  Fewer than the file holds: the
                            server never had it whole.  UINT64_MAX for other bodies */
};

/* One multipart/form-data part: a value or a file streamed from disk. */
struct httpc_part {
    const char *name;      /* field name */
    const char *value;     /* a text value, or NULL for a file part */
    const char *file_path; /* a file part: read from here while sending */
    const char *filename;  /* the file name sent (NULL: file_path's base name) */
    const char *type;      /* Content-Type of the part, or NULL */
};

typedef void (*httpc_done_fn)(struct httpc_req *r, const struct httpc_result *res, void *ud);
/* Upload progress: bytes sent of total (total 0 when unknown). */
typedef void (*httpc_progress_fn)(struct httpc_req *r, uint64_t sent, uint64_t total, void *ud);
/*
 * Extra curl options on the easy handle before the request starts (the
 * room left for FTPS: CURLOPT_USE_SSL, CURLOPT_SSL_SESSIONID_CACHE,
 * CURLOPT_FTP_SSL_CCC, certificate pinning...).  Return CURLE_OK, or a
 * code that fails httpc_start with SF_EINVAL.
 */
typedef CURLcode (*httpc_setopt_fn)(CURL *easy, void *ud);

/* One request.  Zero-initialise, then fill what you need. */
struct httpc_opts {
    const char *method;         /* "GET" (NULL: GET, or POST when a body is given), "POST", "PUT",
                                   "DELETE", ...; for ftp(s):// only "PUT" (an upload) or GET */
    const char *url;            /* http://, https://, ftp://, ftps:// */
    const char *const *headers; /* NULL-terminated "Name: value" lines, or NULL */
    /* The body: at most one of these three. */
    const void *body;               /* bytes, copied by httpc_start */
    size_t body_len;                /* their count */
    const char *body_path;          /* a file, streamed from disk as the raw body */
    const struct httpc_part *parts; /* multipart/form-data parts, copied by httpc_start */
    size_t n_parts;                 /* their count */
    size_t max_body;                /* response body cap (0: HTTPC_BODY_MAX_DEFAULT) */
    int timeout_ms;         /* whole request (0: HTTPC_TIMEOUT_MS_DEFAULT; -1: none, use stall) */
    int connect_timeout_ms; /* (0: HTTPC_CONNECT_TIMEOUT_MS_DEFAULT) */
    int stall_ms;           /* fail when under 1 byte/s moves for this long (0: off); for long
                               uploads, where a whole-request timeout would be a guess */
    const char *user;       /* HTTP auth user, or NULL */
    const char *password;   /* its password */
    bool digest;            /* HTTP Digest (PrusaLink) rather than Basic */
    httpc_done_fn done;     /* required: called exactly once unless cancelled */
    httpc_progress_fn progress; /* optional: upload progress */
    void *ud;                   /* argument of done and progress */
    httpc_setopt_fn setopt;     /* optional: extra curl options */
    void *setopt_ud;            /* its argument */
};

/* A private client on loop l.  NULL with err set. */
struct httpc *httpc_new(struct loop *l, struct sf_err *err);
/*
 * Cancel every request (their done callbacks are not called) and free.
 * Not from within one of its callbacks.  NULL is fine.
 */
void httpc_free(struct httpc *h);

/* The loop's shared client (created on first use), counted: pair with httpc_put. */
struct httpc *httpc_get(struct loop *l, struct sf_err *err);
/* Drop one reference to a shared client; the last one frees it (as httpc_free). */
void httpc_put(struct httpc *h);

/*
 * Start a request.  Returns its handle, owned by the client: it is freed
 * after done returns, or by httpc_cancel.  NULL with err set (SF_EINVAL for
 * bad options, SF_EIO for a body file that cannot be opened, SF_ENOMEM).
 * done is never called from within httpc_start.
 */
struct httpc_req *httpc_start(struct httpc *h, const struct httpc_opts *o, struct sf_err *err);

/*
 * Abandon r: its done callback will not be called, its connection is
 * closed, and r is invalid after this returns.  Safe from within any
 * callback of this client, r's own progress callback included (there the
 * transfer is aborted and r freed when curl lets go of it).  Cancelling r
 * from within r's own done callback is a harmless no-op.
 */
void httpc_cancel(struct httpc_req *r);

/*
 * A request in flight: its body's bytes handed to curl so far, counted as
 * httpc_result.body_read counts them (UINT64_MAX for a body from memory or
 * none).  Fewer than the file holds: the server cannot have it whole yet,
 * so cancelling r now leaves it without the file.
 */
uint64_t httpc_body_read(const struct httpc_req *r);

/* Requests started and not yet done or cancelled. */
size_t httpc_active(const struct httpc *h);

/*
 * Copy the value of response header name (case-insensitive, the last one
 * wins) from res into out (NUL-terminated, truncated to n).  False if absent.
 */
bool httpc_header(const struct httpc_result *res, const char *name, char *out, size_t n);

#endif
