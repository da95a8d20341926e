/*
 * http.c - libmicrohttpd on the daemon's event loop: keys, caps, multipart,
 * deferred answers; how an answer is sent (JSON, raw bodies, errors, the
 * status map) is http_resp.c's, streams (SSE) http_stream.c's and
 * connections taken over (websockets) http_upgrade.c's.
 *
 * Why external epoll mode: the daemon owns one loop and every socket
 * (STYLE.md, "Threads"); MHD's internal threads would put request handlers
 * on another thread, next to a SQLite connection and printer state that
 * are not locked.  MHD exposes one epoll fd; readable means "call MHD_run".
 *
 * Design: MHD calls on_request() several times per request: first with
 * headers only (we authenticate, ask the routes which body the method and
 * path take, check Content-Length, and refuse early with 400/401/403/413
 * so an unwanted body is never read, let alone stored), then once per body
 * chunk (appended to a capped buffer, or fed to MHD's multipart post
 * processor, whose iterator streams the "file" part into the upload sink),
 * and a last time with no data, when the route runs.  Errors found while
 * the body streams are remembered and answered at that last call; a
 * multipart body is complete only if the post processor ends in its final
 * state (the closing boundary seen).  A stream response (SSE) that has
 * nothing to send suspends its connection; http_wake_streams() resumes
 * every suspended one.
 *
 * Slow and hostile clients: MHD's own timeout is an idle timeout, which a
 * client that sends a header line every few seconds never trips, and its
 * one connection limit is filled by whoever asks most.  So every
 * connection is counted from accept (MHD's connection notifier) in a class
 * of http_budget.c: pending until its request head is complete (past the
 * header deadline, or past the pending caps, its socket is shut down and
 * MHD closes it), then keyless, read or write as its request asked, each
 * with its own cap and idle timeout; MHD's limit is their sum.  The
 * request head is checked for two-way framing (http_frame.c) before
 * anything else.  Event streams are counted per key and end past their
 * lifetime.  Error text is made valid UTF-8 before it is put in JSON
 * (jansson refuses anything else, which used to turn a 400 into 500).
 *
 * Thread: whichever thread calls http_run(), the loop thread in the daemon.
 */
#include "http.h"

#include <arpa/inet.h>
#include <microhttpd.h>
#include <netinet/in.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <strings.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "../base/buf.h"
#include "../base/clock.h"
#include "../base/log.h"
#include "../base/mem.h"
#include "authlimit.h"
#include "http_budget.h"
#include "http_frame.h"
#include "http_int.h"

/* Per-request state, MHD's *con_cls (made by the URI logger, before the headers). */
struct conn {
    bool started;                 /* on_request has seen the headers */
    bool now;                     /* answer status before any body, and close */
    enum http_class cls;          /* the class its request asked as */
    bool nul_in_url;              /* the raw URL has %00 */
    int status;                   /* early error to answer with, 0 if none */
    char msg[SF_ERR_MSG_MAX];     /* its message */
    bool read_only;               /* authenticated with a read-only key */
    bool multipart;               /* multipart/form-data body */
    bool has_body;                /* the head announces a body (length > 0 or chunked) */
    bool expect;                  /* the client waits for 100 Continue before its body */
    size_t received;              /* body bytes so far */
    struct MHD_PostProcessor *pp; /* multipart parser */
    struct buf body;              /* non-multipart body */
    size_t n_fields;              /* multipart fields */
    char *field_name[HTTP_FIELDS_MAX];
    struct buf field_value[HTTP_FIELDS_MAX];
    char upload_name[256];         /* the file part's filename */
    void *upload;                  /* sink context */
    bool upload_seen;              /* a file part started */
    char key[FARMCFG_KEY_MAX + 1]; /* the API key it came with */
    size_t max;                    /* body limit in force when its head arrived */
    struct http *h;                /* owner */
    char query[256];               /* the raw query string, cut at 255 bytes */
    struct http_defer *defer;      /* its deferred answer, while the route works */
    struct http_upgraded *up;      /* its socket to be taken over (http_upgrade.c), until taken */
};

/* A route's answer to come (http.h); freed by http_defer_answer. */
struct http_defer {
    struct http *h;              /* owner, while the connection lives */
    struct conn *c;              /* the request, NULL once the client is gone */
    struct MHD_Connection *conn; /* its connection, suspended; NULL once gone */
    bool ready;                  /* resp holds the answer; the connection was resumed */
    struct http_resp resp;       /* the answer */
    char audit[192];             /* http_defer_audit's line, "" if none */
    struct http_defer *next;     /* in h->defers */
};

static void
defer_unlink(struct http *h, struct http_defer *d)
{
    for (struct http_defer **pp = &h->defers; *pp; pp = &(*pp)->next)
        if (*pp == d) {
            *pp = d->next;
            return;
        }
}

static void fail(struct conn *c, int status, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

static void
fail(struct conn *c, int status, const char *fmt, ...)
{
    if (c->status)
        return; /* the first error is the one to report */
    c->status = status;
    char raw[SF_ERR_MSG_MAX];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(raw, sizeof(raw), fmt, ap);
    va_end(ap);
    http_text_clean(c->msg, sizeof(c->msg), raw);
}

static enum MHD_Result
on_post(void *cls, enum MHD_ValueKind kind, const char *key, const char *filename,
        const char *content_type, const char *transfer_encoding, const char *data, uint64_t off,
        size_t size)
{
    (void)kind, (void)content_type, (void)transfer_encoding;
    struct conn *c = cls;
    const struct http_upload_sink *sink = c->h->cfg.sink;
    struct sf_err err;
    if (c->status)
        return MHD_NO;
    if (!key) { /* a part without a name (MHD passes NULL): found by fuzz_http */
        fail(c, MHD_HTTP_BAD_REQUEST, "a multipart/form-data part has no name");
        return MHD_NO;
    }
    if (strcmp(key, "file") == 0) {
        if (!filename) {
            fail(c, MHD_HTTP_BAD_REQUEST, "field 'file' must be a file upload");
            return MHD_NO;
        }
        if (off == 0 && c->upload_seen) {
            fail(c, MHD_HTTP_BAD_REQUEST, "one file per request");
            return MHD_NO;
        }
        if (!c->upload_seen) {
            c->upload_seen = true;
            snprintf(c->upload_name, sizeof(c->upload_name), "%s", filename);
            if (!sink) {
                fail(c, MHD_HTTP_BAD_REQUEST, "this endpoint takes no file");
                return MHD_NO;
            }
            sf_err_clear(&err);
            c->upload = sink->begin(c->h->cfg.ud, filename, &err);
            if (!c->upload) {
                fail(c,
                     err.code == SF_EINVAL ? MHD_HTTP_BAD_REQUEST : MHD_HTTP_INTERNAL_SERVER_ERROR,
                     "%s", err.msg);
                return MHD_NO;
            }
        }
        if (size && sink->write(c->upload, data, size, &err)) {
            fail(c, MHD_HTTP_INTERNAL_SERVER_ERROR, "%s", err.msg);
            return MHD_NO;
        }
        return MHD_YES;
    }
    size_t i = 0;
    while (i < c->n_fields && strcmp(c->field_name[i], key) != 0)
        i++;
    if (i == c->n_fields) {
        if (i == HTTP_FIELDS_MAX) {
            fail(c, MHD_HTTP_BAD_REQUEST, "more than %d form fields", HTTP_FIELDS_MAX);
            return MHD_NO;
        }
        c->field_name[i] = mem_strdup(key);
        if (!c->field_name[i]) {
            fail(c, MHD_HTTP_INTERNAL_SERVER_ERROR, "out of memory");
            return MHD_NO;
        }
        buf_init(&c->field_value[i], HTTP_FIELD_MAX);
        c->n_fields++;
    }
    if (size && buf_append(&c->field_value[i], data, size)) {
        fail(c, MHD_HTTP_CONTENT_TOO_LARGE, "form field '%s' is over %d bytes", key,
             HTTP_FIELD_MAX);
        return MHD_NO;
    }
    return MHD_YES;
}

static void
conn_free(struct http *h, struct conn *c)
{
    if (!c)
        return;
    if (c->defer) {
        struct http_defer *d = c->defer;
        defer_unlink(h, d);
        if (d->ready) { /* answered, never sent: the server stopped first */
            http_resp_discard(&d->resp);
            free(d);
        } else { /* the answer to come only frees it */
            d->c = NULL;
            d->conn = NULL;
        }
    }
    http_upgrade_done(c->up);
    if (c->pp)
        MHD_destroy_post_processor(c->pp);
    if (c->upload)
        h->cfg.sink->discard(c->upload);
    buf_release(&c->body);
    for (size_t i = 0; i < c->n_fields; i++) {
        free(c->field_name[i]);
        buf_release(&c->field_value[i]);
    }
    free(c);
}

/* Discard the upload's temporary file now, not when MHD ends the request
   (after the response went out): a client that heard "400" finds nothing. */
static void
drop_upload(struct conn *c)
{
    if (c->upload)
        c->h->cfg.sink->discard(c->upload);
    c->upload = NULL;
}

static void
on_completed(void *cls, struct MHD_Connection *conn, void **con_cls,
             enum MHD_RequestTerminationCode toe)
{
    (void)conn, (void)toe;
    conn_free(cls, *con_cls);
    *con_cls = NULL;
}

/* ---- connection budgets (http_budget.h) ---- */

static void
on_connection(void *cls, struct MHD_Connection *conn, void **socket_context,
              enum MHD_ConnectionNotificationCode toe)
{
    struct http *h = cls;
    struct http_slot *s = *socket_context;
    if (toe == MHD_CONNECTION_NOTIFY_CLOSED) {
        if (s)
            http_budget_close(&h->budget, s);
        free(s);
        *socket_context = NULL;
        return;
    }
    const union MHD_ConnectionInfo *fd =
        MHD_get_connection_info(conn, MHD_CONNECTION_INFO_CONNECTION_FD);
    const union MHD_ConnectionInfo *addr =
        MHD_get_connection_info(conn, MHD_CONNECTION_INFO_CLIENT_ADDRESS);
    s = mem_calloc(1, sizeof(*s));
    if (!s || !fd) {
        free(s);
        return; /* untracked: MHD's idle timeout still applies */
    }
    unsigned ms = h->cfg.header_timeout_ms ? h->cfg.header_timeout_ms : HTTP_HEADER_TIMEOUT_MS;
    *s = (struct http_slot){ .fd = fd->connect_fd, .deadline_ms = clock_mono_ms() + ms };
    if (addr && addr->client_addr && addr->client_addr->sa_family == AF_INET)
        s->addr = ((const struct sockaddr_in *)(const void *)addr->client_addr)->sin_addr.s_addr;
    *socket_context = s;
    http_budget_accept(&h->budget, s);
}

/* The request head is in: count the connection in the class it asked as
   (nowhere if it is refused and closed), or refuse it when that is full. */
static void
head_counted(struct http *h, struct conn *c, struct MHD_Connection *conn)
{
    const union MHD_ConnectionInfo *info =
        MHD_get_connection_info(conn, MHD_CONNECTION_INFO_SOCKET_CONTEXT);
    struct http_slot *s = info ? info->socket_context : NULL;
    if (!s)
        return;
    if (c->cls == HTTP_CLASS_N || (c->status && c->now)) {
        http_budget_close(&h->budget, s);
        return;
    }
    if (!http_budget_enter(&h->budget, s, c->cls)) {
        static const char *const what[] = { "", "clients without a key", "read-only keys",
                                            "read-write keys" };
        c->status = 0;
        fail(c, MHD_HTTP_SERVICE_UNAVAILABLE, "every connection for %s is taken; try again",
             what[c->cls]);
        c->now = true;
        return;
    }
    unsigned idle_s = h->cfg.idle_s ? h->cfg.idle_s : HTTP_IDLE_S;
    if (c->cls == HTTP_CLASS_KEYLESS && idle_s > HTTP_KEYLESS_IDLE_S)
        idle_s = HTTP_KEYLESS_IDLE_S;
    MHD_set_connection_option(conn, MHD_CONNECTION_OPTION_TIMEOUT, idle_s);
}

/* ---- requests ---- */

/* Every Content-Length header must agree (a proxy may frame by another). */
struct cl_scan {
    const char *first; /* the first value */
    bool conflict;     /* another value differs */
};

static enum MHD_Result
scan_cl(void *cls, enum MHD_ValueKind kind, const char *key, const char *value)
{
    (void)kind;
    struct cl_scan *sc = cls;
    if (strcasecmp(key, MHD_HTTP_HEADER_CONTENT_LENGTH) == 0 && value) {
        if (!sc->first)
            sc->first = value;
        else if (strcmp(sc->first, value) != 0)
            sc->conflict = true;
    }
    return MHD_YES;
}

/* First call: the request head.  Decides everything that can be decided
   before a body byte is read; sets c->status to refuse. */
static void
on_headers(struct http *h, struct conn *c, struct MHD_Connection *conn, const char *url,
           const char *method)
{
    c->cls = HTTP_CLASS_N;
    char why[SF_ERR_MSG_MAX];
    int frame = http_frame_check(conn, why, sizeof(why));
    if (frame) { /* framed two ways: read no body, answer, close */
        fail(c, frame, "%s", why);
        c->now = true;
        return;
    }
    if (c->nul_in_url) {
        fail(c, MHD_HTTP_BAD_REQUEST, "the URL holds an encoded NUL (%%00)");
        return;
    }
    struct cl_scan sc = { 0 };
    MHD_get_connection_values(conn, MHD_HEADER_KIND, scan_cl, &sc);
    if (sc.conflict) {
        fail(c, MHD_HTTP_BAD_REQUEST, "conflicting Content-Length headers");
        return;
    }
    const char *cl = sc.first;
    unsigned long long n = 0;
    bool cl_ok = false;
    if (cl) {
        char *end;
        n = strtoull(cl, &end, 10);
        cl_ok = end != cl && !*end;
    }
    bool chunked = MHD_lookup_connection_value(conn, MHD_HEADER_KIND,
                                               MHD_HTTP_HEADER_TRANSFER_ENCODING) != NULL;
    c->has_body = chunked || (cl && (!cl_ok || n > 0));
    c->expect = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, MHD_HTTP_HEADER_EXPECT) != NULL;
    const char *key = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "X-Api-Key");
    const char *bearer = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "Authorization");
    if (!key && bearer && strncasecmp(bearer, "Bearer ", 7) == 0)
        key = bearer + 7;
    bool get = strcmp(method, "GET") == 0 || strcmp(method, "HEAD") == 0;
    if (!key && h->cfg.is_public && h->cfg.is_public(h->cfg.ud, url)) {
        c->read_only = true; /* a static file or log out: no key, no data */
        c->cls = HTTP_CLASS_KEYLESS;
        return;
    }
    const char *cookie = MHD_lookup_connection_value(
        conn, MHD_COOKIE_KIND, h->cfg.session_cookie ? h->cfg.session_cookie : HTTP_SESSION_COOKIE);
    const char *csrf = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, HTTP_CSRF_HEADER);
    if (!key && cookie && h->cfg.session_key)
        key = h->cfg.session_key(h->cfg.ud, cookie, get ? NULL : csrf ? csrf : "");
    const struct farmcfg_key *k = key ? http_find_key(h, key) : NULL;
    if (!key) {
        fail(c, MHD_HTTP_UNAUTHORIZED, "%s",
             !cookie       ? "missing X-Api-Key header"
             : get || csrf ? "session expired or ended: log in again"
                           : "missing X-Api-Key header (a session cookie needs X-Csrf-Token to "
                             "change things)");
        return;
    }
    if (!k) {
        fail(c, MHD_HTTP_UNAUTHORIZED, "unknown API key");
        return;
    }
    snprintf(c->key, sizeof(c->key), "%s", k->key);
    c->read_only = k->read_only;
    c->cls = k->read_only || k->metrics_only ? HTTP_CLASS_READ : HTTP_CLASS_WRITE;
    if (k->metrics_only && (strcmp(method, "GET") != 0 || strcmp(url, "/metrics") != 0)) {
        fail(c, MHD_HTTP_FORBIDDEN, "metrics key: only GET /metrics is allowed");
        return;
    }
    if (k->read_only && strcmp(method, "GET") != 0 && strcmp(method, "HEAD") != 0) {
        fail(c, MHD_HTTP_FORBIDDEN, "read-only API key: %s is not allowed", method);
        return;
    }
    if (k->read_only && c->has_body) {
        fail(c, MHD_HTTP_FORBIDDEN, "read-only API key: a request body is not allowed");
        return;
    }
    const char *ct = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "Content-Type");
    c->multipart = ct && strncasecmp(ct, "multipart/form-data", 19) == 0;
    enum http_body kind = h->cfg.body_kind ? h->cfg.body_kind(h->cfg.ud, method, url)
                                           : (c->multipart ? HTTP_BODY_UPLOAD : HTTP_BODY_JSON);
    if (c->multipart && kind != HTTP_BODY_UPLOAD) {
        fail(c, MHD_HTTP_BAD_REQUEST, "%s %.100s takes no multipart/form-data upload", method, url);
        return;
    }
    c->max = c->multipart ? h->cfg.upload_max : h->cfg.body_max;
    if (cl_ok && n > c->max) {
        fail(c, MHD_HTTP_CONTENT_TOO_LARGE, "request body of %llu bytes is over the limit of %zu",
             n, c->max);
        return;
    }
    if (c->multipart) {
        c->pp = MHD_create_post_processor(conn, 64 << 10, on_post, c);
        if (!c->pp)
            fail(c, MHD_HTTP_BAD_REQUEST, "malformed multipart/form-data header");
    }
}

/* Failed logins are counted and logged per client address, and an address
   past its burst is answered 429 whatever its key (authlimit.h). */
static void
limit_logins(struct http *h, struct conn *c, struct MHD_Connection *conn)
{
    bool failed = c->status == MHD_HTTP_UNAUTHORIZED;
    if (!h->authlimit || (!failed && !c->key[0]))
        return; /* a public path, or refused before its key was read */
    const union MHD_ConnectionInfo *ci =
        MHD_get_connection_info(conn, MHD_CONNECTION_INFO_CLIENT_ADDRESS);
    char addr[AUTHLIMIT_ADDR_MAX];
    authlimit_addr(ci ? ci->client_addr : NULL, addr);
    unsigned wait_s = authlimit_check(h->authlimit, addr, failed, c->msg, clock_mono_ms());
    if (wait_s) {
        c->status = 0;
        fail(c, MHD_HTTP_TOO_MANY_REQUESTS, "too many failed logins from %s: try again in %u s",
             addr, wait_s);
    }
}

/* The raw URL, before MHD decodes it (MHD's URI logger): its return value
   becomes the request's *con_cls. */
static void *
on_uri(void *cls, const char *uri, struct MHD_Connection *conn)
{
    (void)conn;
    struct http *h = cls;
    struct conn *c = mem_calloc(1, sizeof(*c));
    if (!c)
        return NULL;
    c->h = h;
    buf_init(&c->body, h->cfg.body_max);
    const char *q = strchr(uri, '?');
    size_t n = q ? (size_t)(q - uri) : strlen(uri);
    for (size_t i = 0; i + 2 < n; i++)
        if (uri[i] == '%' && uri[i + 1] == '0' && uri[i + 2] == '0')
            c->nul_in_url = true;
    if (q)
        snprintf(c->query, sizeof(c->query), "%s", q + 1);
    return c;
}

/* Send what a route answered. */
static enum MHD_Result
respond(struct http *h, struct conn *c, struct MHD_Connection *conn, struct http_resp *resp)
{
    drop_upload(c); /* the route committed it, or it goes before the answer does */
    if (resp->stream)
        return http_send_stream(h, conn, c->key, resp);
    if (resp->upgrade)
        return http_send_upgrade(h, conn, c->key, resp, &c->up);
    if (resp->body || resp->fd > 0 || resp->status == MHD_HTTP_NOT_MODIFIED) {
        json_decref(resp->json);
        return http_send_raw(conn, resp);
    }
    if (!resp->json)
        resp->json = json_object();
    if (resp->n_headers) { /* JSON with headers of the route's (Set-Cookie, Location) */
        char *text = json_dumps(resp->json, JSON_COMPACT);
        json_decref(resp->json);
        if (!text)
            return http_send_error(conn, MHD_HTTP_INTERNAL_SERVER_ERROR, "out of memory");
        resp->body = text, resp->body_len = strlen(text), resp->body_free = free;
        resp->content_type = "application/json";
        return http_send_raw(conn, resp);
    }
    return http_send_json(conn, resp->status, resp->json, false);
}

static enum MHD_Result
on_request(void *cls, struct MHD_Connection *conn, const char *url, const char *method,
           const char *version, const char *upload_data, size_t *upload_data_size, void **con_cls)
{
    (void)version;
    struct http *h = cls;
    struct conn *c = *con_cls;
    if (!c) /* the URI logger ran out of memory */
        return MHD_NO;
    if (!c->started) {
        c->started = true;
        on_headers(h, c, conn, url, method);
        limit_logins(h, c, conn);
        head_counted(h, c, conn);
        /* Refuse now when the client sent no body or waits for 100
           Continue before it (curl does for large ones), when it has no
           key, announced too much, framed its request two ways or finds
           its class full.  A client already sending its body would lose
           the answer to the reset of a socket closed on unread bytes: its
           body is read and dropped (never stored), and the answer comes at
           its end. */
        if (c->status &&
            (!c->has_body || c->expect || c->now || c->status == MHD_HTTP_UNAUTHORIZED ||
             c->status == MHD_HTTP_CONTENT_TOO_LARGE))
            return http_send_error(conn, c->status, c->msg);
        return MHD_YES;
    }
    if (*upload_data_size) {
        size_t n = *upload_data_size;
        *upload_data_size = 0;
        if (c->status)
            return MHD_YES; /* drain (nothing is kept); answered at the end */
        c->received += n;
        size_t max = c->max;
        if (c->received > max)
            fail(c, MHD_HTTP_CONTENT_TOO_LARGE, "request body is over the limit of %zu bytes", max);
        else if (c->multipart) {
            if (MHD_post_process(c->pp, upload_data, n) != MHD_YES)
                fail(c, MHD_HTTP_BAD_REQUEST, "malformed multipart/form-data body");
        } else if (buf_append(&c->body, upload_data, n)) {
            fail(c, MHD_HTTP_CONTENT_TOO_LARGE, "request body is over the limit of %zu bytes", max);
        }
        return MHD_YES;
    }
    if (c->defer) { /* resumed: the deferred answer is in */
        struct http_defer *d = c->defer;
        if (!d->ready)
            return MHD_YES;
        defer_unlink(h, d);
        c->defer = NULL;
        struct http_resp resp = d->resp;
        free(d);
        return respond(h, c, conn, &resp);
    }
    if (c->pp) {
        /* Flushes the last part; MHD_NO unless the body ended in the post
           processor's final state: a body cut before its closing boundary
           is refused, whatever was streamed into the sink is discarded. */
        enum MHD_Result whole = MHD_destroy_post_processor(c->pp);
        c->pp = NULL;
        if (whole != MHD_YES)
            fail(c, MHD_HTTP_BAD_REQUEST,
                 "multipart/form-data body is incomplete (no closing boundary)");
    }
    struct sf_err err;
    sf_err_clear(&err);
    if (!c->status && c->upload && h->cfg.sink->finish(c->upload, &err))
        fail(c, http_status_of(err.code), "%s", err.msg);
    if (c->status) {
        drop_upload(c); /* before the client hears of it */
        return http_send_error(conn, c->status, c->msg);
    }

    struct http_req req = { .method = method,
                            .path = url,
                            .read_only = c->read_only,
                            .key = c->key,
                            .body = c->body.data ? c->body.data : "",
                            .body_len = c->body.len,
                            .upload_name = c->upload_seen ? c->upload_name : NULL,
                            .upload = c->upload,
                            .conn = conn };
    req.last_event_id = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "Last-Event-ID");
    req.host = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, MHD_HTTP_HEADER_HOST);
    req.query = c->query[0] ? c->query : NULL;
    req.n_fields = c->n_fields;
    for (size_t i = 0; i < c->n_fields; i++) {
        req.field_name[i] = c->field_name[i];
        req.field_value[i] = c->field_value[i].data ? c->field_value[i].data : "";
    }
    struct http_resp resp = { .status = MHD_HTTP_OK };
    h->cfg.route(h->cfg.ud, &req, &resp);
    if (resp.defer) {
        /* The answer comes later (http_defer_answer): keep the upload and
           wait, suspended, so other clients and printers go on. */
        struct http_defer *d = resp.defer;
        http_resp_discard(&resp); /* a deferring route answers nothing now */
        d->h = h;
        d->c = c;
        d->conn = conn;
        d->next = h->defers;
        h->defers = d;
        c->defer = d;
        MHD_suspend_connection(conn);
        return MHD_YES;
    }
    return respond(h, c, conn, &resp);
}

struct http_defer *
http_defer(struct http_resp *resp)
{
    resp->defer = mem_calloc(1, sizeof(*resp->defer));
    return resp->defer;
}

bool
http_defer_alive(const struct http_defer *d)
{
    return d->conn != NULL;
}

void *
http_defer_upload(struct http_defer *d)
{
    return d->c ? d->c->upload : NULL;
}

void
http_defer_audit(struct http_defer *d, const char *line)
{
    if (d)
        snprintf(d->audit, sizeof(d->audit), "%s", line);
}

void
http_defer_answer(struct http_defer *d, struct http_resp *resp)
{
    if (d->audit[0]) /* what came of it, whether the client waited for it or not */
        log_info("api", "%s: %d%s", d->audit, resp->status, d->conn ? "" : " (the client left)");
    if (!d->conn) {
        http_resp_discard(resp);
        free(d);
        return;
    }
    d->resp = *resp;
    d->ready = true;
    MHD_resume_connection(d->conn); /* MHD calls on_request again: deferred_reply */
    if (d->h && d->h->wake)
        d->h->wake(d->h->wake_ud);
}

static void
mhd_log(void *cls, const char *fmt, va_list ap)
{
    (void)cls;
    char msg[512];
    vsnprintf(msg, sizeof(msg), fmt, ap);
    size_t n = strlen(msg);
    while (n && msg[n - 1] == '\n')
        msg[--n] = '\0';
    /* MHD reports client disconnects here too (a watcher quitting), so
       its messages are information, not warnings. */
    log_info("http", "%s", msg);
}

int
http_set_keys(struct http *h, const struct farmcfg_key *keys, size_t n_keys, size_t *n_closed)
{
    if (n_closed)
        *n_closed = 0;
    struct farmcfg_key *copy = mem_array(n_keys ? n_keys : 1, sizeof(*copy));
    if (!copy)
        return SF_ENOMEM;
    if (n_keys)
        memcpy(copy, keys, n_keys * sizeof(*copy));
    free(h->keys);
    h->keys = copy;
    h->cfg.keys = copy;
    h->cfg.n_keys = n_keys;
    size_t n = http_streams_revoke(h);
    if (n_closed)
        *n_closed = n;
    return SF_OK;
}

void
http_set_upload_max(struct http *h, size_t upload_max)
{
    h->cfg.upload_max = upload_max;
}

int
http_add_connection(struct http *h, int fd)
{
    struct sockaddr_in sa = { .sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK) };
    return MHD_add_connection(h->d, fd, (const struct sockaddr *)&sa, sizeof(sa)) == MHD_YES
               ? SF_OK
               : SF_EIO;
}

struct http *
http_new(const struct http_config *cfg, struct sf_err *err)
{
    struct sockaddr_in sa = { .sin_family = AF_INET,
                              .sin_port = htons(cfg->port < 0 ? 0 : (uint16_t)cfg->port) };
    if (strcmp(cfg->host, "*") == 0)
        sa.sin_addr.s_addr = htonl(INADDR_ANY);
    else if (inet_pton(AF_INET, cfg->host, &sa.sin_addr) != 1) {
        sf_err_set(err, SF_EINVAL, "http: '%s' is not an IPv4 address", cfg->host);
        return NULL;
    }
    struct http *h = mem_calloc(1, sizeof(*h));
    if (!h || http_set_keys(h, cfg->keys, cfg->n_keys, NULL) || !(h->authlimit = authlimit_new())) {
        free(h ? h->keys : NULL);
        free(h);
        sf_err_set(err, SF_ENOMEM, "http: out of memory");
        return NULL;
    }
    struct farmcfg_key *keys = h->keys;
    h->cfg = *cfg;
    h->cfg.keys = keys;
    h->next_end_ms = -1;
    struct http_budget_caps caps;
    http_budget_size(&caps);
    http_budget_init(&h->budget, &caps);
    unsigned flags =
        MHD_USE_EPOLL | MHD_ALLOW_SUSPEND_RESUME | MHD_ALLOW_UPGRADE | MHD_USE_ERROR_LOG;
    if (cfg->port < 0)
        flags |= MHD_USE_NO_LISTEN_SOCKET;
    h->d = MHD_start_daemon(flags, cfg->port < 0 ? 0 : (uint16_t)cfg->port, NULL, NULL, on_request,
                            h, MHD_OPTION_EXTERNAL_LOGGER, mhd_log, NULL, MHD_OPTION_SOCK_ADDR,
                            cfg->port < 0 ? NULL : &sa, MHD_OPTION_NOTIFY_COMPLETED, on_completed,
                            h, MHD_OPTION_NOTIFY_CONNECTION, on_connection, h,
                            MHD_OPTION_URI_LOG_CALLBACK, on_uri, h, MHD_OPTION_CONNECTION_LIMIT,
                            caps.total, MHD_OPTION_CONNECTION_TIMEOUT,
                            cfg->idle_s ? cfg->idle_s : (unsigned)HTTP_IDLE_S, MHD_OPTION_END);
    if (!h->d) {
        sf_err_set(err, SF_EIO, "http: cannot listen on %s:%d (in use, or not allowed)", cfg->host,
                   cfg->port);
        free(h->keys);
        authlimit_free(h->authlimit);
        free(h);
        return NULL;
    }
    const union MHD_DaemonInfo *info =
        cfg->port < 0 ? NULL : MHD_get_daemon_info(h->d, MHD_DAEMON_INFO_BIND_PORT);
    h->port = info ? info->port : cfg->port;
    return h;
}

void
http_free(struct http *h)
{
    if (!h)
        return;
    /* MHD requires every suspended connection resumed before stopping;
       a deferred answer still to come finds its client gone (conn_free). */
    http_wake_streams(h);
    for (struct http_defer *d = h->defers; d; d = d->next)
        if (!d->ready)
            MHD_resume_connection(d->conn);
    http_upgraded_close_all(h);
    MHD_stop_daemon(h->d);
    authlimit_free(h->authlimit);
    free(h->keys);
    free(h);
}

int
http_port(const struct http *h)
{
    return h->port;
}

int
http_fd(const struct http *h)
{
    const union MHD_DaemonInfo *info = MHD_get_daemon_info(h->d, MHD_DAEMON_INFO_EPOLL_FD);
    return info ? info->epoll_fd : -1;
}

int64_t
http_timeout_ms(struct http *h)
{
    MHD_UNSIGNED_LONG_LONG ms;
    int64_t t = -1;
    if (MHD_get_timeout(h->d, &ms) == MHD_YES)
        t = ms > INT64_MAX ? INT64_MAX : (int64_t)ms;
    int64_t due[2] = { http_budget_next_ms(&h->budget), h->next_end_ms };
    for (int i = 0; i < 2; i++)
        if (due[i] >= 0) {
            int64_t left = due[i] - clock_mono_ms();
            if (left < 0)
                left = 0;
            if (t < 0 || left < t)
                t = left;
        }
    return t;
}

int
http_run(struct http *h)
{
    int rc = MHD_run(h->d) == MHD_YES ? SF_OK : SF_EIO;
    http_budget_expire(&h->budget, clock_mono_ms());
    http_streams_expire(h);
    return rc;
}
