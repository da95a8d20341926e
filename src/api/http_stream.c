/*
 * http_stream.c - the HTTP server's streamed answers (Server-Sent Events):
 * a stream that has nothing to send suspends its connection until
 * http_wake_streams(); event streams are counted per key (with the
 * websockets of http_upgrade.c: HTTP_STREAMS_PER_KEY in all), end at
 * their first quiet moment past their lifetime (with a "retry:" hint),
 * and end when their key is revoked.
 *
 * Why apart from http.c: http.c takes requests in; a stream outlives its
 * request and has its own life (suspend, wake, expiry, revocation).
 *
 * Thread: whichever thread calls http_run().
 */
#include <microhttpd.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/clock.h"
#include "../base/mem.h"
#include "http.h"
#include "http_int.h"

static ssize_t
stream_read(void *cls, uint64_t pos, char *buf, size_t max)
{
    (void)pos;
    struct stream *st = cls;
    if (st->revoked)
        return MHD_CONTENT_READER_END_OF_STREAM;
    ssize_t n = st->fn(st->ud, buf, max);
    if (n < 0)
        return MHD_CONTENT_READER_END_OF_STREAM;
    if (n == 0 && st->expired) { /* a quiet moment past its lifetime: end it */
        int len = snprintf(buf, max, "retry: %d\n\n", HTTP_STREAM_RETRY_MS);
        if (st->retry_sent || len < 0 || (size_t)len >= max)
            return MHD_CONTENT_READER_END_OF_STREAM;
        st->retry_sent = true;
        return len;
    }
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
    bool resumed = false;
    for (struct stream *st = h->streams; st; st = st->next)
        if (st->suspended) {
            st->suspended = false;
            MHD_resume_connection(st->conn);
            resumed = true;
        }
    if (resumed && h->wake)
        h->wake(h->wake_ud);
}

void
http_wake_stream(struct http *h, void *ud)
{
    for (struct stream *st = h->streams; st; st = st->next)
        if (st->ud == ud && st->suspended) {
            st->suspended = false;
            MHD_resume_connection(st->conn);
            if (h->wake)
                h->wake(h->wake_ud);
            return;
        }
}

void
http_set_wake(struct http *h, void (*wake)(void *ud), void *ud)
{
    h->wake = wake;
    h->wake_ud = ud;
}

/* Also notes when the next one is due. */
void
http_streams_expire(struct http *h)
{
    int64_t now = clock_mono_ms();
    if (h->next_end_ms < 0 || now < h->next_end_ms)
        return;
    h->next_end_ms = -1;
    for (struct stream *st = h->streams; st; st = st->next) {
        if (!st->event || st->expired)
            continue;
        if (st->end_ms <= now) {
            st->expired = true;
            if (st->suspended) {
                st->suspended = false;
                MHD_resume_connection(st->conn);
            }
        } else if (h->next_end_ms < 0 || st->end_ms < h->next_end_ms) {
            h->next_end_ms = st->end_ms;
        }
    }
}

static bool
is_event_stream(const struct http_resp *resp)
{
    return !resp->content_type || strcmp(resp->content_type, "text/event-stream") == 0;
}

size_t
http_streams_of(const struct http *h, const char *key)
{
    size_t n = http_upgraded_of(h, key);
    for (const struct stream *st = h->streams; st; st = st->next)
        n += st->event && !st->revoked && !st->expired && strcmp(st->key, key) == 0;
    return n;
}

enum MHD_Result
http_send_too_many(struct MHD_Connection *conn)
{
    char msg[128];
    snprintf(msg, sizeof(msg), "this API key has %d event streams and sockets open already",
             HTTP_STREAMS_PER_KEY);
    return http_send_json(conn, MHD_HTTP_TOO_MANY_REQUESTS, json_pack("{s:s}", "error", msg),
                          false);
}

enum MHD_Result
http_send_stream(struct http *h, struct MHD_Connection *conn, const char *key,
                 struct http_resp *resp)
{
    if (is_event_stream(resp) && http_streams_of(h, key) >= HTTP_STREAMS_PER_KEY) {
        if (resp->stream_free)
            resp->stream_free(resp->stream_ud);
        return http_send_too_many(conn);
    }
    struct stream *st = mem_calloc(1, sizeof(*st));
    struct MHD_Response *r = NULL;
    if (st)
        r = MHD_create_response_from_callback(MHD_SIZE_UNKNOWN, 4096, stream_read, st, stream_free);
    if (!r) {
        if (resp->stream_free)
            resp->stream_free(resp->stream_ud);
        free(st);
        return http_send_error(conn, MHD_HTTP_INTERNAL_SERVER_ERROR, "out of memory");
    }
    *st = (struct stream){ .h = h,
                           .conn = conn,
                           .fn = resp->stream,
                           .ud = resp->stream_ud,
                           .free_fn = resp->stream_free,
                           .event = is_event_stream(resp),
                           .next = h->streams };
    if (st->event) {
        unsigned life_ms =
            h->cfg.stream_lifetime_ms ? h->cfg.stream_lifetime_ms : HTTP_STREAM_LIFETIME_S * 1000u;
        st->end_ms = clock_mono_ms() + life_ms;
        if (h->next_end_ms < 0 || st->end_ms < h->next_end_ms)
            h->next_end_ms = st->end_ms;
    }
    snprintf(st->key, sizeof(st->key), "%s", key);
    h->streams = st;
    MHD_add_response_header(r, MHD_HTTP_HEADER_CONTENT_TYPE,
                            resp->content_type ? resp->content_type : "text/event-stream");
    http_add_headers(r, resp);
    if (!MHD_get_response_header(r, MHD_HTTP_HEADER_CACHE_CONTROL))
        MHD_add_response_header(r, MHD_HTTP_HEADER_CACHE_CONTROL, "no-cache");
    enum MHD_Result rc = MHD_queue_response(conn, (unsigned)resp->status, r);
    MHD_destroy_response(r);
    return rc;
}

const struct farmcfg_key *
http_find_key(const struct http *h, const char *key)
{
    struct farmcfg view = { .keys = h->keys, .n_keys = h->cfg.n_keys };
    return farmcfg_key(&view, key);
}

bool
http_key_may_watch(const struct http *h, const char *key)
{
    const struct farmcfg_key *k = http_find_key(h, key);
    return k && !k->metrics_only;
}

/* A revoked key's streams end, and those of a key now metrics-only (a key
   turned read-only keeps them: streams are GETs, which read-only keys may
   make). */
size_t
http_streams_revoke(struct http *h)
{
    size_t n = http_upgraded_revoke(h);
    for (struct stream *st = h->streams; st; st = st->next)
        if (!st->revoked && !http_key_may_watch(h, st->key)) {
            st->revoked = true;
            n++;
            if (st->suspended) {
                st->suspended = false;
                MHD_resume_connection(st->conn);
            }
        }
    return n;
}
