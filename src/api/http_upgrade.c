/*
 * http_upgrade.c - connections a route takes over (websockets, http.h's
 * struct http_upgraded): MHD sends the route's 101, then hands the socket
 * here and on to the route's owner, which reads and writes it on the loop
 * and closes it through http_upgraded_close.
 *
 * Each one stays counted where its request was (its http_budget slot is
 * MHD's socket context until the socket closes), and by key with the event
 * streams (HTTP_STREAMS_PER_KEY): a socket opened without a key (OctoPrint's
 * push socket logs in with a message after its upgrade) holds a keyless
 * slot until http_upgraded_auth moves it into its key's class.  A reload
 * that removes a key marks its sockets revoked; their owner closes them.
 *
 * Order of MHD's calls: the upgrade handler runs once the 101 is out and
 * before the request's completion callback (which comes when the socket
 * is closed), so the request's link to a pending upgrade (owner) is cut
 * when it is taken; one never taken (the client left first) is freed with
 * the request (http_upgrade_done).
 *
 * Thread: whichever thread calls http_run().
 */
#include <fcntl.h>
#include <microhttpd.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/clock.h"
#include "../base/mem.h"
#include "authlimit.h"
#include "http.h"
#include "http_int.h"

struct http_upgraded {
    struct http *h;
    struct MHD_UpgradeResponseHandle *urh; /* NULL until MHD hands the socket over */
    struct http_slot *slot;                /* its budget slot (MHD's socket context), or NULL */
    struct http_upgraded **owner;          /* the request's link to it, until taken */
    http_upgrade_fn fn;                    /* the route's taker */
    void *ud;
    void (*ud_free)(void *ud);     /* frees ud if it is never taken */
    bool revoked;                  /* its key is gone */
    char key[FARMCFG_KEY_MAX + 1]; /* the key it is counted under, "" for none */
    char addr[AUTHLIMIT_ADDR_MAX]; /* the client's address (http_upgraded_login) */
    struct http_upgraded *next;    /* in h->ups */
};

static void
unlink_up(struct http_upgraded *u)
{
    for (struct http_upgraded **pp = &u->h->ups; *pp; pp = &(*pp)->next)
        if (*pp == u) {
            *pp = u->next;
            return;
        }
}

static void
on_upgraded(void *cls, struct MHD_Connection *conn, void *req_cls, const char *extra,
            size_t n_extra, MHD_socket sock, struct MHD_UpgradeResponseHandle *urh)
{
    (void)req_cls;
    struct http_upgraded *u = cls;
    if (u->owner)
        *u->owner = NULL; /* taken: the request's end no longer frees it */
    u->owner = NULL;
    u->urh = urh;
    const union MHD_ConnectionInfo *info =
        MHD_get_connection_info(conn, MHD_CONNECTION_INFO_SOCKET_CONTEXT);
    u->slot = info ? info->socket_context : NULL;
    info = MHD_get_connection_info(conn, MHD_CONNECTION_INFO_CLIENT_ADDRESS);
    authlimit_addr(info ? info->client_addr : NULL, u->addr);
    /* the socket's life is its owner's now: no idle timeout of MHD's */
    MHD_set_connection_option(conn, MHD_CONNECTION_OPTION_TIMEOUT, 0);
    int fl = fcntl(sock, F_GETFL);
    if (fl >= 0)
        fcntl(sock, F_SETFL, fl | O_NONBLOCK);
    u->fn(u->ud, u, sock, extra, n_extra);
}

enum MHD_Result
http_send_upgrade(struct http *h, struct MHD_Connection *conn, const char *key,
                  struct http_resp *resp, struct http_upgraded **pending)
{
    json_decref(resp->json);
    resp->json = NULL;
    if (key[0] && http_streams_of(h, key) >= HTTP_STREAMS_PER_KEY) {
        if (resp->upgrade_free)
            resp->upgrade_free(resp->upgrade_ud);
        return http_send_too_many(conn);
    }
    struct http_upgraded *u = mem_calloc(1, sizeof(*u));
    struct MHD_Response *r = u ? MHD_create_response_for_upgrade(on_upgraded, u) : NULL;
    if (!r) {
        free(u);
        if (resp->upgrade_free)
            resp->upgrade_free(resp->upgrade_ud);
        return http_send_error(conn, MHD_HTTP_INTERNAL_SERVER_ERROR, "out of memory");
    }
    *u = (struct http_upgraded){ .h = h,
                                 .owner = pending,
                                 .fn = resp->upgrade,
                                 .ud = resp->upgrade_ud,
                                 .ud_free = resp->upgrade_free,
                                 .next = h->ups };
    snprintf(u->key, sizeof(u->key), "%s", key);
    h->ups = u;
    *pending = u;
    http_add_headers(r, resp);
    enum MHD_Result rc = MHD_queue_response(conn, MHD_HTTP_SWITCHING_PROTOCOLS, r);
    MHD_destroy_response(r);
    return rc;
}

void
http_upgrade_done(struct http_upgraded *pending)
{
    if (!pending || pending->urh)
        return;
    unlink_up(pending);
    if (pending->ud_free)
        pending->ud_free(pending->ud);
    free(pending);
}

size_t
http_upgraded_of(const struct http *h, const char *key)
{
    size_t n = 0;
    for (const struct http_upgraded *u = h->ups; u; u = u->next)
        n += u->urh && !u->revoked && strcmp(u->key, key) == 0;
    return n;
}

size_t
http_upgraded_revoke(struct http *h)
{
    size_t n = 0;
    for (struct http_upgraded *u = h->ups; u; u = u->next)
        if (u->urh && u->key[0] && !u->revoked && !http_key_may_watch(h, u->key)) {
            u->revoked = true;
            n++;
        }
    return n;
}

void
http_upgraded_close_all(struct http *h)
{
    struct http_upgraded *u = h->ups;
    while (u) {
        struct http_upgraded *next = u->next;
        if (u->urh)
            http_upgraded_close(u);
        u = next;
    }
}

const char *
http_upgraded_key(const struct http_upgraded *u)
{
    return u->key;
}

unsigned
http_upgraded_login(struct http_upgraded *u, bool failed, const char *why)
{
    return u->h->authlimit ? authlimit_check(u->h->authlimit, u->addr[0] ? u->addr : "?", failed,
                                             why, clock_mono_ms())
                           : 0;
}

bool
http_upgraded_revoked(const struct http_upgraded *u)
{
    return u->revoked;
}

int64_t
http_upgraded_lifetime_ms(const struct http_upgraded *u)
{
    return u->h->cfg.stream_lifetime_ms ? u->h->cfg.stream_lifetime_ms
                                        : (int64_t)HTTP_STREAM_LIFETIME_S * 1000;
}

int
http_upgraded_auth(struct http_upgraded *u, const char *key, bool *read_only, struct sf_err *err)
{
    const struct farmcfg_key *k = http_find_key(u->h, key);
    if (!k)
        return sf_err_set(err, SF_EINVAL, "unknown API key");
    if (k->metrics_only)
        return sf_err_set(err, SF_EINVAL, "a metrics key opens no socket");
    if (u->key[0] && strcmp(u->key, key) != 0)
        return sf_err_set(err, SF_EINVAL, "the socket was opened with another API key");
    *read_only = k->read_only;
    if (u->key[0])
        return SF_OK;
    if (http_streams_of(u->h, key) >= HTTP_STREAMS_PER_KEY)
        return sf_err_set(err, SF_EAGAIN, "this API key has %d event streams and sockets open",
                          HTTP_STREAMS_PER_KEY);
    enum http_class cls = k->read_only ? HTTP_CLASS_READ : HTTP_CLASS_WRITE;
    if (u->slot && !http_budget_enter(&u->h->budget, u->slot, cls)) {
        u->slot = NULL;
        return sf_err_set(err, SF_EAGAIN, "every connection for %s keys is taken",
                          k->read_only ? "read-only" : "read-write");
    }
    snprintf(u->key, sizeof(u->key), "%s", key);
    return SF_OK;
}

void
http_upgraded_close(struct http_upgraded *u)
{
    unlink_up(u);
    if (u->urh)
        MHD_upgrade_action(u->urh, MHD_UPGRADE_ACTION_CLOSE);
    free(u);
}
