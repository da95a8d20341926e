/*
 * sim_http.h - the HTTP side shared by the simulated network printers
 * (sim_octoprint.c, sim_moonraker.c, sim_prusalink.c): a libmicrohttpd
 * server on our loop with a route table, an API-key or digest check, JSON
 * bodies and replies (jansson), uploads streamed to a file (multipart
 * through MHD's post processor, or a raw PUT body), and the HTTP faults
 * every face shares.
 *
 * A face fills a route table and a config, and writes handlers: each gets
 * the request once its whole body has arrived (an upload already sits in a
 * temporary file in upload_dir) and replies once with sim_http_reply*.  A
 * handler that does not reply answers 500.  Everything is synchronous: the
 * handlers read and drive a sim_netprinter, which never blocks.
 *
 * Checks before a body byte is stored: the route (404, or 405 for a known
 * path with another method), the key (key_header must equal api_key:
 * auth_status, 401 or 403 as the face's API says) or digest credentials
 * (401 with a challenge), and the injected 5xx faults.
 *
 * Faults (sim_http_fault_parse, specs of --fault):
 *   5xx=N[@K]     after K requests (default 0), the next N answer 503
 *   slow=MS       every reply leaves MS milliseconds late (the connection is
 *                 suspended, the loop keeps serving others)
 *   slow-upload=MS[@N] an upload's reply (a route taking a file body) leaves
 *                 MS milliseconds late (only the first N uploads' with @N),
 *                 after its handler ran: a print it
 *                 started runs meanwhile, as on a PrusaLink that answers a
 *                 Print-After-Upload PUT once the file is stored and started,
 *                 or whose answer is slow to come back
 *   drop-upload=N the first N uploads lose their connection half-way
 *                 through the body (after 64 KiB, or half a smaller body).
 *                 (libcurl re-sends a request whose reused connection died
 *                 before any reply, up to 5 times, so a client may see fewer
 *                 failures than cuts.)
 *   drop=N        the Nth request (1-based) loses its connection unanswered
 *   outage=L      the printer is unreachable across its job's end: once a
 *                 job has L lines done, every request answers 503 until the
 *                 job has ended and at least SIM_HTTP_OUTAGE_MIN requests
 *                 have been refused (once per run; the face reports its job
 *                 through sim_http_outage_watch)
 * Faults of the printer itself (error state, cancel at the printer, busy)
 * belong to the face.
 *
 * Thread: the loop thread.  Owns its MHD daemon and temporary files.
 */
#ifndef SF_SIM_NET_SIM_HTTP_H
#define SF_SIM_NET_SIM_HTTP_H

#include <jansson.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../../src/base/err.h"
#include "../../src/base/loop.h"

struct sim_http;
struct sim_http_req;

typedef void (*sim_http_fn)(struct sim_http_req *r, void *ud);

enum sim_http_body {
    SIM_HTTP_BODY_MEM = 0, /* the body in memory, capped at SIM_HTTP_BODY_MAX (JSON) */
    SIM_HTTP_BODY_FORM,    /* multipart/form-data: text fields in memory, the first file
                              part streamed to a temporary file */
    SIM_HTTP_BODY_FILE,    /* the raw body streamed to a temporary file (PrusaLink's PUT) */
};

/* Largest in-memory request body, and text form field. */
#define SIM_HTTP_BODY_MAX  ((size_t)1 << 20)
#define SIM_HTTP_FIELD_MAX 4096

/* One route: method and path; a path ending in '*' matches any path with that prefix. */
struct sim_http_route {
    const char *method;      /* "GET", "POST", ... */
    const char *path;        /* "/api/job"; "/api/files/local/" then a star: a prefix */
    enum sim_http_body body; /* how the body is taken */
    bool open;               /* no authentication (e.g. a login endpoint) */
    sim_http_fn fn;          /* the handler */
};

struct sim_http_faults {
    long err5xx_after;  /* 5xx=N@K: K */
    long err5xx_count;  /* N (0: none) */
    int slow_ms;        /* every reply this late */
    int slow_upload_ms; /* an upload's reply this late */
    long slow_uploads;  /* ... the first this many uploads' (0: all) */
    long drop_upload;   /* the Nth upload is cut (0: none) */
    long drop_request;  /* the Nth request is cut (0: none) */
    long outage_line;   /* outage=L: L (0: none) */
};

/* Requests an outage refuses at the least: more than a driver's failed polls
   in a row before it lets go of its job (4), so it always does. */
#define SIM_HTTP_OUTAGE_MIN 6

struct sim_http_config {
    int port;                            /* 0: any free loopback port */
    const struct sim_http_route *routes; /* n_routes, first match wins */
    size_t n_routes;
    void *ud;                    /* handlers' argument */
    const char *api_key;         /* NULL: no key check */
    const char *key_header;      /* header holding it (NULL: "X-Api-Key") */
    int auth_status;             /* status for a missing or wrong key (0: 403) */
    const char *auth_body;       /* its JSON body (NULL: {"error": "Invalid API key"}) */
    const char *digest_user;     /* non-NULL: HTTP Digest (MD5) with this user ... */
    const char *digest_password; /* ... and password */
    const char *realm;           /* digest realm (NULL: "Printer API") */
    const char *upload_dir;      /* temporary upload files go here (the machine's uploads dir) */
    uint64_t upload_max;         /* largest upload, bytes (0: 1 GiB) */
    struct sim_http_faults faults;
};

/* An upload's temporary file, valid during the handler. */
struct sim_http_file {
    const char *field;    /* its form field name ("" for a raw body) */
    const char *filename; /* the name the client sent ("" for a raw body) */
    const char *path;     /* the temporary file; removed after the handler unless kept */
    uint64_t size;        /* bytes received */
};

/* Apply one fault spec; SF_EUNSUPP when the name is not an HTTP fault (the face may know it),
   SF_EINVAL for a bad value. */
int sim_http_fault_parse(struct sim_http_faults *f, const char *spec, struct sf_err *err);

/* Listen and serve on loop l.  NULL with err set. */
struct sim_http *sim_http_new(struct loop *l, const struct sim_http_config *c, struct sf_err *err);
/* Close every connection, remove temporary files, free.  NULL is fine. */
void sim_http_free(struct sim_http *h);
/* The port it listens on. */
int sim_http_port(const struct sim_http *h);
/* Requests answered so far (any status). */
uint64_t sim_http_served(const struct sim_http *h);
/*
 * The outage fault's clock: the face calls it on each watch turn with
 * whether its job runs (printing, paused) and its lines done.  Does nothing
 * without the fault.
 */
void sim_http_outage_watch(struct sim_http *h, bool running, uint64_t lines_done);
/*
 * Whether the server is in a simulated failure: an outage, or a 5xx burst
 * begun and not yet spent.  A face closes its push sockets then (a server
 * in trouble loses them too), so clients see the failure as pollers do.
 */
bool sim_http_refusing(const struct sim_http *h);

/* ---- inside a handler ---- */

const char *sim_http_method(const struct sim_http_req *r);
/* The path (no query string); for a prefix route, sim_http_rest() is what follows the prefix. */
const char *sim_http_path(const struct sim_http_req *r);
const char *sim_http_rest(const struct sim_http_req *r);
/* A query argument, a request header, a form field; NULL if absent. */
const char *sim_http_query(const struct sim_http_req *r, const char *name);
const char *sim_http_header(const struct sim_http_req *r, const char *name);
const char *sim_http_field(const struct sim_http_req *r, const char *name);
/* The in-memory body (NUL-terminated) and its length. */
const char *sim_http_body(const struct sim_http_req *r, size_t *len);
/* The body parsed as a JSON object (caller json_decref()s), or NULL with err set. */
json_t *sim_http_json(const struct sim_http_req *r, struct sf_err *err);
/* The upload, or NULL if none arrived. */
const struct sim_http_file *sim_http_upload(const struct sim_http_req *r);
/* Move the upload's file to path (rename); SF_EIO with err set on failure. */
int sim_http_keep_upload(struct sim_http_req *r, const char *path, struct sf_err *err);

/* Add a reply header (before replying). */
void sim_http_add_header(struct sim_http_req *r, const char *name, const char *value);
/* Reply once: bytes with a content type, a JSON value (stolen; NULL: empty), or nothing. */
void sim_http_reply(struct sim_http_req *r, unsigned status, const char *type, const char *body,
                    size_t len);
void sim_http_reply_json(struct sim_http_req *r, unsigned status, json_t *value);
void sim_http_reply_empty(struct sim_http_req *r, unsigned status);
/* Reply status with {"error": text} (OctoPrint's and fdm-monster's error shape). */
void sim_http_reply_error(struct sim_http_req *r, unsigned status, const char *text);

/*
 * A protocol upgrade (sim_ws.c's websockets): reply 101 Switching Protocols
 * with the headers added, and once it is sent call fn with the socket (in
 * non-blocking mode; never close() it: sim_http_upgraded_close), the bytes
 * that came after the request, and ud and tag as given here.  If the
 * connection dies before, fn is never called.  Whoever gets the socket
 * must close it before sim_http_free.
 */
struct sim_http_upgraded;
typedef void (*sim_http_upgrade_fn)(struct sim_http_upgraded *u, int fd, const char *extra,
                                    size_t n_extra, void *ud, int tag);
void sim_http_reply_upgrade(struct sim_http_req *r, sim_http_upgrade_fn fn, void *ud, int tag);
/* Close an upgraded connection's socket. */
void sim_http_upgraded_close(struct sim_http_upgraded *u);

#endif
