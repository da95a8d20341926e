/*
 * http.c - libmicrohttpd on the daemon's event loop: keys, caps, multipart,
 * JSON replies, suspended streams.
 *
 * Why external epoll mode: the daemon owns one loop and every socket
 * (STYLE.md, "Threads"); MHD's internal threads would put request handlers
 * on another thread, next to a SQLite connection and printer state that
 * are not locked.  MHD exposes one epoll fd; readable means "call MHD_run".
 *
 * Design: MHD calls on_request() several times per request: first with
 * headers only (we authenticate and check Content-Length, and refuse early
 * with 401/403/413 so an unwanted body is never read), then once per body
 * chunk (appended to a capped buffer, or fed to MHD's multipart post
 * processor, whose iterator streams the "file" part into the upload sink),
 * and a last time with no data, when the route runs.  Errors found while
 * the body streams are remembered and answered at that last call.  A
 * stream response (SSE) that has nothing to send suspends its connection;
 * http_wake_streams() resumes every suspended one.
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

#include "../base/buf.h"
#include "../base/log.h"
#include "../base/mem.h"

/* A streamed response; lives from the route's answer until MHD frees it. */
struct stream {
    struct http *h;              /* owner */
    struct MHD_Connection *conn; /* its connection */
    http_stream_fn fn;           /* produces the body */
    void *ud;                    /* fn's argument */
    void (*free_fn)(void *ud);   /* frees ud */
    bool suspended;              /* waiting for http_wake_streams */
    struct stream *next;         /* in h->streams */
};

struct http {
    struct MHD_Daemon *d;     /* the MHD daemon, external epoll mode */
    struct http_config cfg;   /* as given; keys point at our copy */
    struct farmcfg_key *keys; /* copy of the API keys */
    int port;                 /* bound port */
    struct stream *streams;   /* live streams */
};

/* Per-request state, MHD's *con_cls. */
struct conn {
    int status;                   /* early error to answer with, 0 if none */
    char msg[SF_ERR_MSG_MAX];     /* its message */
    bool read_only;               /* authenticated with a read-only key */
    bool multipart;               /* multipart/form-data body */
    size_t received;              /* body bytes so far */
    struct MHD_PostProcessor *pp; /* multipart parser */
    struct buf body;              /* non-multipart body */
    size_t n_fields;              /* multipart fields */
    char *field_name[HTTP_FIELDS_MAX];
    struct buf field_value[HTTP_FIELDS_MAX];
    char upload_name[256]; /* the file part's filename */
    void *upload;          /* sink context */
    bool upload_seen;      /* a file part started */
    struct http *h;        /* owner */
};

static void fail(struct conn *c, int status, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

static void
fail(struct conn *c, int status, const char *fmt, ...)
{
    if (c->status)
        return; /* the first error is the one to report */
    c->status = status;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(c->msg, sizeof(c->msg), fmt, ap);
    va_end(ap);
}

void
http_error(struct http_resp *resp, int status, const char *fmt, ...)
{
    char msg[SF_ERR_MSG_MAX];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof(msg), fmt, ap);
    va_end(ap);
    resp->status = status;
    json_decref(resp->json);
    resp->json = json_pack("{s:s}", "error", msg);
}

static enum MHD_Result
send_json(struct MHD_Connection *conn, int status, json_t *j)
{
    char *s = j ? json_dumps(j, JSON_COMPACT) : NULL;
    json_decref(j);
    struct MHD_Response *r;
    if (s) {
        r = MHD_create_response_from_buffer(strlen(s), s, MHD_RESPMEM_MUST_FREE);
    } else {
        static const char oom[] = "{\"error\":\"out of memory\"}";
        status = MHD_HTTP_INTERNAL_SERVER_ERROR;
        r = MHD_create_response_from_buffer(sizeof(oom) - 1, (void *)oom, MHD_RESPMEM_PERSISTENT);
    }
    if (!r) {
        free(s);
        return MHD_NO;
    }
    MHD_add_response_header(r, MHD_HTTP_HEADER_CONTENT_TYPE, "application/json");
    enum MHD_Result rc = MHD_queue_response(conn, (unsigned)status, r);
    MHD_destroy_response(r);
    return rc;
}

static enum MHD_Result
send_error(struct MHD_Connection *conn, int status, const char *msg)
{
    return send_json(conn, status, json_pack("{s:s}", "error", msg));
}

/* ---- streams ---- */

static ssize_t
stream_read(void *cls, uint64_t pos, char *buf, size_t max)
{
    (void)pos;
    struct stream *st = cls;
    ssize_t n = st->fn(st->ud, buf, max);
    if (n < 0)
        return MHD_CONTENT_READER_END_OF_STREAM;
    if (n == 0 && !st->suspended) {
        MHD_suspend_connection(st->conn);
        st->suspended = true;
    }
    return n;
}

static void
stream_free(void *cls)
{
    struct stream *st = cls;
    for (struct stream **pp = &st->h->streams; *pp; pp = &(*pp)->next)
        if (*pp == st) {
            *pp = st->next;
            break;
        }
    if (st->free_fn)
        st->free_fn(st->ud);
    free(st);
}

void
http_wake_streams(struct http *h)
{
    for (struct stream *st = h->streams; st; st = st->next)
        if (st->suspended) {
            st->suspended = false;
            MHD_resume_connection(st->conn);
        }
}

static enum MHD_Result
send_stream(struct http *h, struct MHD_Connection *conn, struct http_resp *resp)
{
    struct stream *st = mem_calloc(1, sizeof(*st));
    struct MHD_Response *r = NULL;
    if (st)
        r = MHD_create_response_from_callback(MHD_SIZE_UNKNOWN, 4096, stream_read, st, stream_free);
    if (!r) {
        if (resp->stream_free)
            resp->stream_free(resp->stream_ud);
        free(st);
        return send_error(conn, MHD_HTTP_INTERNAL_SERVER_ERROR, "out of memory");
    }
    *st = (struct stream){ h,     conn,      resp->stream, resp->stream_ud, resp->stream_free,
                           false, h->streams };
    h->streams = st;
    MHD_add_response_header(r, MHD_HTTP_HEADER_CONTENT_TYPE, "text/event-stream");
    MHD_add_response_header(r, MHD_HTTP_HEADER_CACHE_CONTROL, "no-cache");
    enum MHD_Result rc = MHD_queue_response(conn, (unsigned)resp->status, r);
    MHD_destroy_response(r);
    return rc;
}

/* ---- requests ---- */

static const struct farmcfg_key *
find_key(const struct http *h, const char *key)
{
    struct farmcfg view = { .keys = h->keys, .n_keys = h->cfg.n_keys };
    return farmcfg_key(&view, key);
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

static void
on_completed(void *cls, struct MHD_Connection *conn, void **con_cls,
             enum MHD_RequestTerminationCode toe)
{
    (void)conn, (void)toe;
    conn_free(cls, *con_cls);
    *con_cls = NULL;
}

/* First call: headers only.  Returns an early status (0 = go on). */
static void
on_headers(struct http *h, struct conn *c, struct MHD_Connection *conn, const char *method)
{
    const char *key = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "X-Api-Key");
    const struct farmcfg_key *k = key ? find_key(h, key) : NULL;
    if (!key) {
        fail(c, MHD_HTTP_UNAUTHORIZED, "missing X-Api-Key header");
        return;
    }
    if (!k) {
        fail(c, MHD_HTTP_UNAUTHORIZED, "unknown API key");
        return;
    }
    c->read_only = k->read_only;
    if (k->read_only && strcmp(method, "GET") != 0 && strcmp(method, "HEAD") != 0) {
        fail(c, MHD_HTTP_FORBIDDEN, "read-only API key: %s is not allowed", method);
        return;
    }
    const char *ct = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "Content-Type");
    c->multipart = ct && strncasecmp(ct, "multipart/form-data", 19) == 0;
    size_t max = c->multipart ? h->cfg.upload_max : h->cfg.body_max;
    const char *cl = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "Content-Length");
    if (cl) {
        char *end;
        unsigned long long n = strtoull(cl, &end, 10);
        if (end != cl && !*end && n > max) {
            fail(c, MHD_HTTP_CONTENT_TOO_LARGE,
                 "request body of %llu bytes is over the limit of %zu", n, max);
            return;
        }
    }
    if (c->multipart) {
        c->pp = MHD_create_post_processor(conn, 64 << 10, on_post, c);
        if (!c->pp)
            fail(c, MHD_HTTP_BAD_REQUEST, "malformed multipart/form-data header");
    }
}

static enum MHD_Result
on_request(void *cls, struct MHD_Connection *conn, const char *url, const char *method,
           const char *version, const char *upload_data, size_t *upload_data_size, void **con_cls)
{
    (void)version;
    struct http *h = cls;
    struct conn *c = *con_cls;
    if (!c) {
        c = mem_calloc(1, sizeof(*c));
        if (!c)
            return MHD_NO;
        c->h = h;
        buf_init(&c->body, h->cfg.body_max);
        *con_cls = c;
        on_headers(h, c, conn, method);
        /* Refuse now: the client (curl waits on Expect: 100-continue) never
           sends a body nobody wants. */
        if (c->status)
            return send_error(conn, c->status, c->msg);
        return MHD_YES;
    }
    if (*upload_data_size) {
        size_t n = *upload_data_size;
        *upload_data_size = 0;
        if (c->status)
            return MHD_YES; /* drain; answered at the end */
        c->received += n;
        size_t max = c->multipart ? h->cfg.upload_max : h->cfg.body_max;
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
    if (c->pp) {
        /* flushes the last part */
        MHD_destroy_post_processor(c->pp);
        c->pp = NULL;
    }
    struct sf_err err;
    if (!c->status && c->upload && h->cfg.sink->finish(c->upload, &err))
        fail(c, MHD_HTTP_INTERNAL_SERVER_ERROR, "%s", err.msg);
    if (c->status)
        return send_error(conn, c->status, c->msg);

    struct http_req req = { .method = method,
                            .path = url,
                            .read_only = c->read_only,
                            .body = c->body.data ? c->body.data : "",
                            .body_len = c->body.len,
                            .upload_name = c->upload_seen ? c->upload_name : NULL,
                            .upload = c->upload };
    req.last_event_id = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "Last-Event-ID");
    req.n_fields = c->n_fields;
    for (size_t i = 0; i < c->n_fields; i++) {
        req.field_name[i] = c->field_name[i];
        req.field_value[i] = c->field_value[i].data ? c->field_value[i].data : "";
    }
    struct http_resp resp = { .status = MHD_HTTP_OK };
    h->cfg.route(h->cfg.ud, &req, &resp);
    if (resp.stream)
        return send_stream(h, conn, &resp);
    if (!resp.json)
        resp.json = json_object();
    return send_json(conn, resp.status, resp.json);
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
http_set_keys(struct http *h, const struct farmcfg_key *keys, size_t n_keys)
{
    struct farmcfg_key *copy = mem_array(n_keys ? n_keys : 1, sizeof(*copy));
    if (!copy)
        return SF_ENOMEM;
    if (n_keys)
        memcpy(copy, keys, n_keys * sizeof(*copy));
    free(h->keys);
    h->keys = copy;
    h->cfg.keys = copy;
    h->cfg.n_keys = n_keys;
    return SF_OK;
}

struct http *
http_new(const struct http_config *cfg, struct sf_err *err)
{
    struct sockaddr_in sa = { .sin_family = AF_INET, .sin_port = htons((uint16_t)cfg->port) };
    if (strcmp(cfg->host, "*") == 0)
        sa.sin_addr.s_addr = htonl(INADDR_ANY);
    else if (inet_pton(AF_INET, cfg->host, &sa.sin_addr) != 1) {
        sf_err_set(err, SF_EINVAL, "http: '%s' is not an IPv4 address", cfg->host);
        return NULL;
    }
    struct http *h = mem_calloc(1, sizeof(*h));
    if (!h || http_set_keys(h, cfg->keys, cfg->n_keys)) {
        free(h);
        sf_err_set(err, SF_ENOMEM, "http: out of memory");
        return NULL;
    }
    struct farmcfg_key *keys = h->keys;
    h->cfg = *cfg;
    h->cfg.keys = keys;
    h->d =
        MHD_start_daemon(MHD_USE_EPOLL | MHD_ALLOW_SUSPEND_RESUME | MHD_USE_ERROR_LOG, 0, NULL,
                         NULL, on_request, h, MHD_OPTION_EXTERNAL_LOGGER, mhd_log, NULL,
                         MHD_OPTION_SOCK_ADDR, &sa, MHD_OPTION_NOTIFY_COMPLETED, on_completed, h,
                         MHD_OPTION_CONNECTION_LIMIT, (unsigned)HTTP_CONNECTIONS_MAX,
                         MHD_OPTION_CONNECTION_TIMEOUT, (unsigned)HTTP_TIMEOUT_S, MHD_OPTION_END);
    if (!h->d) {
        sf_err_set(err, SF_EIO, "http: cannot listen on %s:%d (in use, or not allowed)", cfg->host,
                   cfg->port);
        free(h->keys);
        free(h);
        return NULL;
    }
    const union MHD_DaemonInfo *info = MHD_get_daemon_info(h->d, MHD_DAEMON_INFO_BIND_PORT);
    h->port = info ? info->port : cfg->port;
    return h;
}

void
http_free(struct http *h)
{
    if (!h)
        return;
    /* MHD requires every suspended connection resumed before stopping. */
    http_wake_streams(h);
    MHD_stop_daemon(h->d);
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
    if (MHD_get_timeout(h->d, &ms) != MHD_YES)
        return -1;
    return ms > INT64_MAX ? INT64_MAX : (int64_t)ms;
}

int
http_run(struct http *h)
{
    return MHD_run(h->d) == MHD_YES ? SF_OK : SF_EIO;
}
