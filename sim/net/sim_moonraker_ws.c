/*
 * sim_moonraker_ws.c - Moonraker's websocket (/websocket): JSON-RPC 2.0
 * as moonraker/common.py's JsonRPC answers it, the methods a web client
 * opens with, and the notifications it then lives on.
 *
 * Methods: server.connection.identify (client_name, version, type, url;
 * api_key or access_token optional; once a connection), server.websocket.id,
 * server.info, printer.info, printer.objects.list, printer.objects.query
 * and printer.objects.subscribe (objects: {name: null or [attributes]};
 * the reply is the status now, and every SIM_MR_PUSH_MS the connection
 * gets notify_status_update, params [changed fields only, eventtime], as
 * Klipper batches them).  A new subscription replaces the last.  Klippy's
 * state changes go to every connection: notify_klippy_ready,
 * notify_klippy_shutdown, notify_klippy_disconnected (a restart, which
 * drops every subscription as klippy_connection.py's _on_connection_closed
 * does: a client subscribes again after notify_klippy_ready).
 * printer.gcode.script runs G-code as POST /printer/gcode/script does; its
 * output (RESPOND, M118, errors) goes to every socket as
 * notify_gcode_response, params [line].
 *
 * Errors are JSON-RPC error objects with Moonraker's codes: -32700 Parse
 * error, -32600 Invalid Request (no "jsonrpc": "2.0"), -32601 Method not
 * found, -32602 Invalid params (and Unauthorized: Moonraker maps its 401
 * there), 400 for a bad argument, 503 while Klippy is not connected.  With
 * an API key set, a socket opened without the X-Api-Key header may only
 * identify (with the key) or ask server.info until it has.
 *
 * Thread: the loop thread.
 */
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "../../src/base/mem.h"
#include "../../src/base/ws.h"
#include "sim_moonraker_int.h"
#include "sim_ws.h"

/* One client's socket. */
struct mr_conn {
    struct sim_moonraker *s;
    int id;          /* connection_id */
    bool identified; /* server.connection.identify done */
    bool authed;     /* the key came with the upgrade or with identify */
    json_t *sub;     /* the subscription's objects, NULL if none */
    json_t *last;    /* what the client was last told of them */
};

struct rpc_err {
    int code;
    char msg[256];
};

static json_t *
rpc_fail(struct rpc_err *e, int code, const char *msg)
{
    e->code = code;
    snprintf(e->msg, sizeof(e->msg), "%s", msg);
    return NULL;
}

/* A string argument, NULL (with e set, as Moonraker's get_str) if absent and required. */
static const char *
str_arg(json_t *params, const char *name, bool required, struct rpc_err *e)
{
    json_t *v = json_object_get(params, name);
    if (json_is_string(v))
        return json_string_value(v);
    if (required || v) {
        char m[128];
        snprintf(m, sizeof(m),
                 v ? "Unable to convert argument [%s] to str"
                   : "No data for "
                     "argument: %s",
                 name);
        rpc_fail(e, 400, m);
    }
    return NULL;
}

static json_t *
m_identify(struct mr_conn *c, json_t *params, struct rpc_err *e)
{
    static const char *const types[] = { "web", "mobile", "desktop", "display",
                                         "bot", "agent",  "other" };
    if (c->identified)
        return rpc_fail(e, 400, "Connection already identified");
    const char *fields[] = { "client_name", "version", "type", "url" };
    const char *type = NULL;
    for (int i = 0; i < 4; i++) {
        const char *v = str_arg(params, fields[i], true, e);
        if (!v)
            return NULL;
        if (i == 2)
            type = v;
    }
    const char *key = str_arg(params, "api_key", false, e);
    if (e->code)
        return NULL;
    if (key && !c->authed) {
        if (!c->s->cfg.api_key || strcmp(key, c->s->cfg.api_key) != 0)
            return rpc_fail(e, -32602, "Invalid API Key");
        c->authed = true;
    } else if (!c->authed) { /* no users here: an access_token cannot be valid */
        return rpc_fail(e, -32602, "Unauthorized");
    }
    bool known = false;
    for (size_t i = 0; i < sizeof(types) / sizeof(types[0]); i++)
        known |= strcasecmp(type, types[i]) == 0;
    if (!known) {
        char m[160];
        snprintf(m, sizeof(m), "Invalid Client Type: %.100s", type);
        return rpc_fail(e, 400, m);
    }
    c->identified = true;
    return json_pack("{s:i}", "connection_id", c->id);
}

/* The objects argument of a query or subscription: an object, else e set. */
static json_t *
objects_arg(json_t *params, struct rpc_err *e)
{
    json_t *want = json_object_get(params, "objects");
    if (!json_is_object(want))
        return rpc_fail(e, 400, "Invalid argument 'objects'");
    return want;
}

static json_t *
m_query(struct mr_conn *c, json_t *params, struct rpc_err *e)
{
    json_t *want = objects_arg(params, e);
    if (!want)
        return NULL;
    struct sim_np_status st;
    sim_netprinter_status(c->s->b.np, &st);
    return json_pack("{s:f,s:o}", "eventtime", sim_moonraker_eventtime(), "status",
                     sim_moonraker_pick(c->s, want, &st));
}

static json_t *
m_subscribe(struct mr_conn *c, json_t *params, struct rpc_err *e)
{
    json_t *want = objects_arg(params, e);
    if (!want)
        return NULL;
    json_t *reply = m_query(c, params, e);
    json_decref(c->sub);
    json_decref(c->last);
    c->sub = json_deep_copy(want);
    c->last = json_deep_copy(json_object_get(reply, "status"));
    return reply;
}

static json_t *
m_server_info(struct mr_conn *c, json_t *params, struct rpc_err *e)
{
    (void)params, (void)e;
    return sim_moonraker_server_info(c->s);
}

static json_t *
m_printer_info(struct mr_conn *c, json_t *params, struct rpc_err *e)
{
    (void)params, (void)e;
    return sim_moonraker_printer_info(c->s);
}

static json_t *
m_objects_list(struct mr_conn *c, json_t *params, struct rpc_err *e)
{
    (void)c, (void)params, (void)e;
    return sim_moonraker_objects_list();
}

/* printer.gcode.script: as POST /printer/gcode/script ("ok", or 400 with the error). */
static json_t *
m_script(struct mr_conn *c, json_t *params, struct rpc_err *e)
{
    const char *script = str_arg(params, "script", true, e);
    struct sf_err err;
    if (!script)
        return NULL;
    if (c->s->klippy == K_SHUTDOWN)
        return rpc_fail(e, 400, "Printer is shutdown");
    if (sim_moonraker_script(c->s, script, &err))
        return rpc_fail(e, 400, err.msg);
    return json_string("ok");
}

static json_t *
m_websocket_id(struct mr_conn *c, json_t *params, struct rpc_err *e)
{
    (void)params, (void)e;
    return json_pack("{s:i}", "websocket_id", c->id);
}

static const struct {
    const char *name;
    bool open;   /* no authentication needed */
    bool klippy; /* Klippy must be connected */
    json_t *(*fn)(struct mr_conn *c, json_t *params, struct rpc_err *e);
} methods[] = {
    { "server.connection.identify", true, false, m_identify },
    { "server.websocket.id", false, false, m_websocket_id },
    { "server.info", true, false, m_server_info },
    { "printer.info", false, true, m_printer_info },
    { "printer.objects.list", false, true, m_objects_list },
    { "printer.objects.query", false, true, m_query },
    { "printer.objects.subscribe", false, true, m_subscribe },
    { "printer.gcode.script", false, true, m_script },
};

/* The reply to one request object (NULL: none, a notification or a response). */
static json_t *
process(struct mr_conn *c, json_t *req)
{
    json_t *id = json_object_get(req, "id");
    json_t *idv = id ? json_incref(id) : json_null();
    json_t *method = json_object_get(req, "method");
    json_t *params = json_object_get(req, "params");
    struct rpc_err e = { 0 };
    json_t *result = NULL;
    const char *ver = json_string_value(json_object_get(req, "jsonrpc"));
    if (!json_is_object(req) || !ver || strcmp(ver, "2.0") != 0) {
        rpc_fail(&e, -32600, "Invalid Request");
    } else if (!method) {
        json_decref(idv); /* a response to a request of ours: there are none */
        return NULL;
    } else if (!json_is_string(method)) {
        rpc_fail(&e, -32600, "Invalid Request");
    } else if (params && !json_is_object(params)) {
        rpc_fail(&e, -32602, "Invalid params:");
    } else {
        size_t i = 0, n = sizeof(methods) / sizeof(methods[0]);
        while (i < n && strcmp(methods[i].name, json_string_value(method)) != 0)
            i++;
        json_t *none = json_object();
        if (i == n)
            rpc_fail(&e, -32601, "Method not found");
        else if (!methods[i].open && !c->authed)
            rpc_fail(&e, -32602, "Unauthorized");
        else if (methods[i].klippy && c->s->klippy == K_STARTUP)
            rpc_fail(&e, 503, "Klippy Host not connected");
        else
            result = methods[i].fn(c, params ? params : none, &e);
        json_decref(none);
    }
    if (!id && ver && method) { /* a notification: no answer, even to an error */
        json_decref(result);
        json_decref(idv);
        return NULL;
    }
    if (e.code)
        return json_pack("{s:s,s:{s:i,s:s},s:o}", "jsonrpc", "2.0", "error", "code", e.code,
                         "message", e.msg, "id", idv);
    return json_pack("{s:s,s:o,s:o}", "jsonrpc", "2.0", "result", result ? result : json_null(),
                     "id", idv);
}

static void *
on_open(struct sim_ws *ws, int tag, void *ud)
{
    (void)ws;
    struct sim_moonraker *s = ud;
    struct mr_conn *c = mem_calloc(1, sizeof(*c));
    if (!c)
        return NULL;
    c->s = s;
    c->id = ++s->ws_ids;
    c->authed = tag != 0;
    return c;
}

static void
on_text(struct sim_ws *ws, void *conn, const char *text, size_t len, void *ud)
{
    (void)ud;
    struct mr_conn *c = conn;
    if (!c)
        return;
    json_t *req = json_loadb(text, len, 0, NULL);
    json_t *reply;
    if (!req) {
        reply = json_pack("{s:s,s:{s:i,s:s},s:n}", "jsonrpc", "2.0", "error", "code", -32700,
                          "message", "Parse error", "id");
    } else if (json_is_array(req)) { /* a batch: the answers in one array */
        reply = json_array();
        size_t i;
        json_t *one;
        json_array_foreach(req, i, one)
        {
            json_t *r = process(c, one);
            if (r)
                json_array_append_new(reply, r);
        }
        if (!json_array_size(reply)) {
            json_decref(reply);
            reply = NULL;
        }
    } else {
        reply = process(c, req);
    }
    json_decref(req);
    if (reply)
        sim_ws_send_json(ws, reply);
}

static void
on_gone(struct sim_ws *ws, void *conn, void *ud)
{
    (void)ws, (void)ud;
    struct mr_conn *c = conn;
    if (!c)
        return;
    json_decref(c->sub);
    json_decref(c->last);
    free(c);
}

static const struct sim_ws_ops ops = { on_open, on_text, on_gone };

struct sim_ws_hub *
sim_moonraker_ws_hub(struct sim_moonraker *s)
{
    return sim_ws_hub_new(s->b.l, &ops, s);
}

void
sim_moonraker_on_websocket(struct sim_http_req *r, void *ud)
{
    struct sim_moonraker *s = ud;
    const char *key = sim_http_header(r, "X-Api-Key");
    bool authed =
        !s->cfg.api_key || !s->cfg.api_key[0] || (key && strcmp(key, s->cfg.api_key) == 0);
    sim_ws_accept(r, s->b.hub, authed);
}

static void
count_sub(struct sim_ws *ws, void *conn, void *arg)
{
    (void)ws;
    struct mr_conn *c = conn;
    if (c && c->sub)
        ++*(int *)arg;
}

int
sim_moonraker_subscribed(struct sim_moonraker *s)
{
    int n = 0;
    sim_ws_hub_each(s->b.hub, count_sub, &n);
    return n;
}

/* The fields of cur that differ from last (updating last), NULL if none. */
static json_t *
changed(json_t *cur, json_t *last)
{
    json_t *diff = NULL;
    const char *obj;
    json_t *fields;
    json_object_foreach(cur, obj, fields)
    {
        json_t *was = json_object_get(last, obj);
        if (!was) {
            was = json_object();
            json_object_set_new(last, obj, was);
        }
        const char *k;
        json_t *v;
        json_object_foreach(fields, k, v)
        {
            if (json_equal(json_object_get(was, k), v))
                continue;
            if (!diff)
                diff = json_object();
            json_t *d = json_object_get(diff, obj);
            if (!d)
                json_object_set_new(diff, obj, d = json_object());
            json_object_set(d, k, v);
            json_object_set(was, k, v);
        }
    }
    return diff;
}

struct push {
    const struct sim_np_status *st;
    const char *klippy_note; /* a notify_klippy_* to send first, or NULL */
    bool status_due;
};

static void
push_one(struct sim_ws *ws, void *conn, void *arg)
{
    struct mr_conn *c = conn;
    struct push *p = arg;
    if (!c)
        return;
    if (p->klippy_note)
        sim_ws_send_json(ws, json_pack("{s:s,s:s}", "jsonrpc", "2.0", "method", p->klippy_note));
    if (!p->status_due || !c->sub || c->s->klippy == K_STARTUP)
        return;
    json_t *cur = sim_moonraker_pick(c->s, c->sub, p->st);
    json_t *diff = changed(cur, c->last);
    json_decref(cur);
    if (diff)
        sim_ws_send_json(ws, json_pack("{s:s,s:s,s:[o,f]}", "jsonrpc", "2.0", "method",
                                       "notify_status_update", "params", diff,
                                       sim_moonraker_eventtime()));
}

static void
lose_sub(struct sim_ws *ws, void *conn, void *arg)
{
    (void)arg;
    struct mr_conn *c = conn;
    if (!c)
        return;
    json_decref(c->sub);
    json_decref(c->last);
    c->sub = c->last = NULL;
    sim_ws_send_json(
        ws, json_pack("{s:s,s:s}", "jsonrpc", "2.0", "method", "notify_klippy_disconnected"));
}

void
sim_moonraker_ws_klippy_lost(struct sim_moonraker *s)
{
    if (!s->b.hub)
        return;
    sim_ws_hub_each(s->b.hub, lose_sub, NULL);
    s->ws_klippy = K_STARTUP; /* told: the watch sends notify_klippy_ready when it is */
}

static void
gcode_response(struct sim_ws *ws, void *conn, void *arg)
{
    struct mr_conn *c = conn;
    if (c && c->authed)
        sim_ws_send_json(ws, json_pack("{s:s,s:s,s:[s]}", "jsonrpc", "2.0", "method",
                                       "notify_gcode_response", "params", (const char *)arg));
}

void
sim_moonraker_ws_gcode_response(struct sim_moonraker *s, const char *line)
{
    if (s->b.hub)
        sim_ws_hub_each(s->b.hub, gcode_response, (void *)line);
}

void
sim_moonraker_ws_watch(struct sim_moonraker *s, const struct sim_np_status *st)
{
    if (!s->b.hub || !sim_ws_hub_count(s->b.hub)) {
        s->ws_klippy = s->klippy;
        return;
    }
    if (sim_http_refusing(s->b.http)) { /* a simulated 5xx burst or outage: sockets die too */
        sim_ws_hub_close_all(s->b.hub, WS_CLOSE_AWAY, "simulated failure");
        return;
    }
    struct push p = { st, NULL, false };
    if (s->klippy != s->ws_klippy) {
        p.klippy_note = s->klippy == K_READY      ? "notify_klippy_ready"
                        : s->klippy == K_SHUTDOWN ? "notify_klippy_shutdown"
                                                  : "notify_klippy_disconnected";
        s->ws_klippy = s->klippy;
        if (s->klippy == K_READY && s->ready_missed < s->cfg.miss_ready) {
            s->ready_missed++;
            p.klippy_note = NULL; /* lost on its way */
        }
    }
    int64_t now = loop_now_ms(s->b.l);
    if (now >= s->next_push_ms) {
        p.status_due = true;
        s->next_push_ms = now + SIM_MR_PUSH_MS;
    }
    if (p.klippy_note || p.status_due)
        sim_ws_hub_each(s->b.hub, push_one, &p);
}
