/*
 * drv_moonraker_ws.c - the Moonraker driver's push socket (how it stands
 * in for the polls: drv_moonraker_int.h).
 *
 * On the socket, as Moonraker's JSON-RPC wants it (docs/external_api/
 * server.md, printer.md, jsonrpc_notifications.md of v0.10): first
 * server.connection.identify (with the API key when the printer has one:
 * the upgrade's X-Api-Key header suffices for Moonraker, identify is for
 * a proxy that drops headers), then printer.objects.subscribe to the
 * objects the poll asks.  Its reply is the full status; each
 * notify_status_update after it is merged in, field by field, and the
 * whole read as a poll's answer would be (drv_moonraker_parse_status),
 * so one parser checks both.  notify_klippy_disconnected (Klippy went
 * away, and Moonraker dropped every subscription with it: klippy_
 * connection.py's _on_connection_closed) holds the socket open but polling
 * takes over, asking /server/info until Klippy is back; notify_klippy_ready
 * subscribes again on the same socket, and its reply makes the socket
 * stand again; so does /server/info saying Klippy is ready, should the
 * socket have missed the notification.  A subscribe refused with 503
 * (Klippy not connected yet) waits for notify_klippy_ready the same way.
 * Any other error reply or a status that does not parse closes the socket
 * and polling takes over.
 *
 * Thread: the loop thread.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/base/log.h"
#include "drv_moonraker_int.h"

#define ID_IDENTIFY  1
#define ID_SUBSCRIBE 2

static const char subscribe_objects[] =
    "{\"webhooks\":null,\"print_stats\":null,"
    "\"virtual_sdcard\":[\"progress\",\"file_position\",\"file_size\"],"
    "\"extruder\":[\"temperature\",\"target\"],\"heater_bed\":[\"temperature\",\"target\"]}";

static void
send_rpc(struct moonraker *m, const char *method, json_t *params, int id)
{
    json_t *req = json_pack("{s:s,s:s,s:o,s:i}", "jsonrpc", "2.0", "method", method, "params",
                            params ? params : json_object(), "id", id);
    char *text = req ? json_dumps(req, JSON_COMPACT) : NULL;
    json_decref(req);
    /* a failure closes the socket: closed() says so */
    if (text && m->push.ws)
        wsc_send(m->push.ws, text, strlen(text));
    free(text);
}

static void
subscribe(struct moonraker *m)
{
    send_rpc(m, "printer.objects.subscribe",
             json_pack("{s:o}", "objects", json_loads(subscribe_objects, 0, NULL)), ID_SUBSCRIBE);
}

/* Klippy is gone (or not up yet): the socket waits for notify_klippy_ready while the polls
   ask /server/info when it is back (as after a poll that saw Klippy starting). */
static void
hold(struct moonraker *m, const char *why)
{
    m->ready = false;
    m->ws_held = true;
    netpush_hold(&m->push, &m->n, why);
    json_decref(m->ws_status);
    m->ws_status = NULL;
}

static void
on_open(struct wsc *w, void *ud)
{
    (void)w;
    struct moonraker *m = ud;
    json_t *id = json_pack("{s:s,s:s,s:s,s:s}", "client_name", "slimfarm", "version", "1", "type",
                           "other", "url", "https://github.com/slimfarm/slimfarm");
    const char *key = m->n.key_hdr[0] ? strchr(m->n.key_hdr, ':') : NULL;
    if (key) {
        key++;
        while (*key == ' ')
            key++;
        json_object_set_new(id, "api_key", json_string(key));
    }
    send_rpc(m, "server.connection.identify", id, ID_IDENTIFY);
    subscribe(m);
}

/* Merge a notify_status_update's changed fields into the status. */
static void
merge(json_t *status, json_t *diff)
{
    const char *obj;
    json_t *fields;
    json_object_foreach(diff, obj, fields)
    {
        json_t *have = json_object_get(status, obj);
        if (json_is_object(have) && json_is_object(fields))
            json_object_update(have, fields);
        else if (json_is_object(fields))
            json_object_set(status, obj, fields);
    }
}

/* A reply to one of ours: identify's needs nothing, subscribe's starts the push. */
static void
on_reply(struct moonraker *m, json_t *msg, json_int_t id)
{
    json_t *e = json_object_get(msg, "error");
    if (e && id == ID_SUBSCRIBE && json_integer_value(json_object_get(e, "code")) == 503) {
        hold(m, "push socket: Klippy is not connected to Moonraker yet");
        return;
    }
    if (e) {
        char why[200];
        snprintf(why, sizeof(why), "push socket: %s refused: %s",
                 id == ID_IDENTIFY ? "identify" : "subscribe",
                 json_string_value(json_object_get(e, "message"))
                     ? json_string_value(json_object_get(e, "message"))
                     : "(no message)");
        drv_moonraker_ws_close(m, why);
        return;
    }
    json_t *status = json_object_get(json_object_get(msg, "result"), "status");
    if (id != ID_SUBSCRIBE)
        return;
    if (!json_is_object(status)) {
        drv_moonraker_ws_close(m, "push socket: the subscription's reply has no status");
        return;
    }
    json_decref(m->ws_status);
    m->ws_status = json_deep_copy(status);
    m->ws_held = false;
    netpush_live(&m->push, &m->n);
    drv_moonraker_ws_apply(m);
}

static void
on_text(struct wsc *w, const char *text, size_t len, void *ud)
{
    (void)w;
    struct moonraker *m = ud;
    json_t *msg = json_loadb(text, len, 0, NULL);
    json_t *id = json_object_get(msg, "id");
    const char *method = json_string_value(json_object_get(msg, "method"));
    if (json_is_integer(id)) {
        on_reply(m, msg, json_integer_value(id));
    } else if (method && strcmp(method, "notify_status_update") == 0 && m->push.live) {
        json_t *diff = json_array_get(json_object_get(msg, "params"), 0);
        if (json_is_object(diff)) {
            merge(m->ws_status, diff);
            m->push.updates++;
            m->push.dirty = true;
            drv_moonraker_ws_apply(m);
        }
    } else if (method && strcmp(method, "notify_klippy_disconnected") == 0) {
        hold(m, "push socket: Klippy disconnected from Moonraker, its subscription with it");
    } else if (method && strcmp(method, "notify_klippy_ready") == 0 && !m->push.live) {
        subscribe(m); /* the reply makes the socket stand again */
    }
    json_decref(msg);
}

static void
on_closed(struct wsc *w, const char *why, void *ud)
{
    (void)w;
    drv_moonraker_ws_close(ud, why);
}

static const struct wsc_ops ops = { on_open, on_text, on_closed };

void
drv_moonraker_ws_open(struct moonraker *m, const char *ip)
{
    if (m->ready)
        netpush_open(&m->push, &m->n, ip, "/websocket", &ops, m);
}

void
drv_moonraker_ws_close(struct moonraker *m, const char *why)
{
    netpush_close(&m->push, &m->n, why);
    json_decref(m->ws_status);
    m->ws_status = NULL;
    m->ws_held = false;
}

void
drv_moonraker_ws_klippy_ready(struct moonraker *m)
{
    /* Moonraker says notify_klippy_ready once; a socket that missed it
       (lost, or sent before the socket was held) would have waited for it
       for ever, the printer polled meanwhile at the poll rate */
    if (m->ws_held && m->push.ws && !m->push.live) {
        log_printer(LOG_INFO, m->n.base.name,
                    "push socket: Klippy is ready again (/server/info): subscribing again");
        m->ws_held = false;
        subscribe(m);
    }
}

void
drv_moonraker_ws_apply(struct moonraker *m)
{
    struct netdrv *n = &m->n;
    /* not while a request holds the slot, nor before the poll that confirms an action: what
       the socket said may predate the action (its updates and our requests are two streams) */
    if (!netpush_due(&m->push, n))
        return;
    json_t *wrap = json_pack("{s:{s:O}}", "result", "status", m->ws_status);
    char *text = wrap ? json_dumps(wrap, JSON_COMPACT) : NULL;
    json_decref(wrap);
    struct moonraker_status st;
    struct sf_err err;
    int rc = text ? drv_moonraker_parse_status(text, strlen(text), &st, &err)
                  : sf_err_set(&err, SF_ENOMEM, "out of memory");
    free(text);
    if (rc) {
        char why[300];
        snprintf(why, sizeof(why), "push socket: %s", err.msg);
        drv_moonraker_ws_close(m, why);
        return;
    }
    drv_moonraker_seen(m, &st, true);
    if (!n->req)
        n->nops->kick(n); /* what the status asks for (the file's metadata) */
}
