/*
 * http_resp.c - the response side of the HTTP server: what a route
 * answers and how MHD sends it (JSON, a raw body or an open file, an error
 * in {"error": ...} made valid UTF-8), the one map from failure codes to
 * statuses, extra response headers, and the request's headers and query
 * arguments.
 *
 * Why apart from http.c: http.c takes requests in (keys, limits, bodies,
 * multipart, slow clients, streams and deferred answers); this is the
 * stateless half every answer goes out through, and it needs none of the
 * server's or the connection's state.
 *
 * Thread: whichever thread calls http_run().
 */
#include "http.h"

#include <microhttpd.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "../base/utf8.h"
#include "http_int.h"

char *
http_text_clean(char *out, size_t cap, const char *s)
{
    static const char repl[] = "\xef\xbf\xbd"; /* U+FFFD */
    size_t o = 0;
    const unsigned char *p = (const unsigned char *)s;
    while (*p) {
        int n = utf8_seq(p);
        if (n < 0)
            break; /* a character cut by whoever cut the text: drop it */
        const char *src = n ? (const char *)p : repl;
        size_t len = n ? (size_t)n : 3;
        if (o + len >= cap)
            break;
        memcpy(out + o, src, len);
        o += len;
        p += n ? n : 1;
    }
    if (cap)
        out[o] = '\0';
    return out;
}

void
http_error(struct http_resp *resp, int status, const char *fmt, ...)
{
    /* longer than an sf_err: a refused upload names up to 20 lines (gpolicy.h) */
    char raw[4096], msg[4096];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(raw, sizeof(raw), fmt, ap);
    va_end(ap);
    http_text_clean(msg, sizeof(msg), raw);
    resp->status = status;
    json_decref(resp->json);
    resp->json = json_pack("{s:s}", "error", msg);
}

int
http_status_of(int code)
{
    switch (code) {
    case SF_EINVAL:
        return MHD_HTTP_BAD_REQUEST;
    case SF_ENOTFOUND:
        return MHD_HTTP_NOT_FOUND;
    case SF_EAGAIN:
    case SF_ESTALE: /* a fencing token or lease another host has since replaced */
        return MHD_HTTP_CONFLICT;
    case SF_EUNSUPP:
        return MHD_HTTP_NOT_IMPLEMENTED;
    case SF_EUNREACH:
    case SF_EBUSY: /* the database, busy past its retries */
    case SF_ECANCELED:
        return MHD_HTTP_SERVICE_UNAVAILABLE;
    default:
        return MHD_HTTP_INTERNAL_SERVER_ERROR;
    }
}

void
http_fail(struct http_resp *resp, int code, const char *msg)
{
    http_error(resp, http_status_of(code), "%s", msg);
}

enum MHD_Result
http_send_json(struct MHD_Connection *conn, int status, json_t *j, bool close)
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
    if (close) /* MHD closes the connection after a response saying so */
        MHD_add_response_header(r, MHD_HTTP_HEADER_CONNECTION, "close");
    enum MHD_Result rc = MHD_queue_response(conn, (unsigned)status, r);
    MHD_destroy_response(r);
    return rc;
}

/* An error; a client without a valid key, or one that sent a bad request
   head (400, or 501: a transfer coding we do not read, so its body cannot
   be skipped), finds every connection of its class taken (503) or is
   slowed for failed logins (429: its connection counts in no class, so it
   must not stay open), is not served again on this connection. */
enum MHD_Result
http_send_error(struct MHD_Connection *conn, int status, const char *msg)
{
    bool close = status == MHD_HTTP_UNAUTHORIZED || status == MHD_HTTP_BAD_REQUEST ||
                 status == MHD_HTTP_NOT_IMPLEMENTED || status == MHD_HTTP_SERVICE_UNAVAILABLE ||
                 status == MHD_HTTP_TOO_MANY_REQUESTS;
    return http_send_json(conn, status, json_pack("{s:s}", "error", msg), close);
}

int
http_resp_header(struct http_resp *resp, const char *name, const char *fmt, ...)
{
    if (resp->n_headers == HTTP_RESP_HEADERS_MAX || strlen(name) >= sizeof(resp->headers[0].name))
        return SF_EINVAL;
    struct http_header *hd = &resp->headers[resp->n_headers];
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(hd->value, sizeof(hd->value), fmt, ap);
    va_end(ap);
    if (n < 0 || (size_t)n >= sizeof(hd->value))
        return SF_EINVAL;
    snprintf(hd->name, sizeof(hd->name), "%s", name);
    resp->n_headers++;
    return SF_OK;
}

void
http_add_headers(struct MHD_Response *r, const struct http_resp *resp)
{
    for (size_t i = 0; i < resp->n_headers; i++)
        MHD_add_response_header(r, resp->headers[i].name, resp->headers[i].value);
}

/* Free what a route answered without sending it. */
void
http_resp_discard(struct http_resp *resp)
{
    json_decref(resp->json);
    if (resp->body && resp->body_free)
        resp->body_free((void *)resp->body);
    if (resp->fd > 0)
        close(resp->fd);
    if (resp->stream_free)
        resp->stream_free(resp->stream_ud);
}

/* A raw body (static file, picture) or an open file. */
enum MHD_Result
http_send_raw(struct MHD_Connection *conn, struct http_resp *resp)
{
    struct MHD_Response *r;
    if (resp->fd > 0) {
        r = MHD_create_response_from_fd(resp->fd_size, resp->fd);
        if (!r)
            close(resp->fd);
    } else {
        size_t len = resp->status == MHD_HTTP_NOT_MODIFIED ? 0 : resp->body_len;
        r = MHD_create_response_from_buffer_with_free_callback(len, (void *)resp->body,
                                                               resp->body_free);
        if (!r && resp->body_free)
            resp->body_free((void *)resp->body);
    }
    if (!r)
        return http_send_error(conn, MHD_HTTP_INTERNAL_SERVER_ERROR, "out of memory");
    if (resp->content_type)
        MHD_add_response_header(r, MHD_HTTP_HEADER_CONTENT_TYPE, resp->content_type);
    http_add_headers(r, resp);
    enum MHD_Result rc = MHD_queue_response(conn, (unsigned)resp->status, r);
    MHD_destroy_response(r);
    return rc;
}

const char *
http_req_header(const struct http_req *req, const char *name)
{
    return MHD_lookup_connection_value(req->conn, MHD_HEADER_KIND, name);
}

const char *
http_req_arg(const struct http_req *req, const char *name)
{
    return MHD_lookup_connection_value(req->conn, MHD_GET_ARGUMENT_KIND, name);
}

const char *
http_req_field(const struct http_req *req, const char *name)
{
    for (size_t i = 0; i < req->n_fields; i++)
        if (strcmp(req->field_name[i], name) == 0)
            return req->field_value[i];
    return NULL;
}
