/*
 * sim_octoprint_push.c - OctoPrint's push socket (docs/api/push.rst,
 * server/util/sockjs.py of OctoPrint 1.11.8, its vendored sockjs-tornado).
 *
 * Two transports, as OctoPrint serves them: /sockjs/websocket, SockJS's
 * raw websocket (each message one text frame of JSON, no framing), and
 * /sockjs/SERVER/SESSION/websocket, SockJS's websocket transport (the
 * server opens with "o", sends messages as 'a["<json>",...]' arrays, a
 * heartbeat "h" every SOCKJS_HEARTBEAT_MS; the client sends '["<json>"]').
 * GET /sockjs/info answers what SockJS clients ask first.
 *
 * On open the socket gets `connected`.  Nothing else until the client
 * sends {"auth": "user:session"} with the name and session of
 * /api/login (OctoPrint holds status back from a socket without the
 * STATUS permission); then `history`, then `current` every 500 ms times
 * the client's {"throttle": N}, and `event` messages as the printer's
 * state changes: PrinterStateChanged, PrintStarted, PrintPaused,
 * PrintResumed, PrintCancelling, PrintCancelled, PrintFailed (reason
 * cancelled or error), PrintDone, with OctoPrint's payload keys.  A wrong
 * auth gets reauthRequired {"reason": "stale"}.  {"subscribe": {...}}
 * picks state (true or false) and events (true, false or a list of
 * names), as since OctoPrint 1.8.  Without an API key every socket is
 * trusted from the start (no access control).
 *
 * Thread: the loop thread.
 */
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../../src/base/mem.h"
#include "../../src/base/octopush.h"
#include "../../src/base/sockjs.h"
#include "../../src/base/ws.h"
#include "sim_octoprint_int.h"
#include "sim_ws.h"

enum { RAW = 0, FRAMED = 1 }; /* the transports (sim_ws_accept's tag) */

struct op_conn {
    struct octo_sim *o;
    bool framed;             /* SockJS framing */
    bool authed;             /* a valid auth came (or no key is set) */
    struct octopush_sub sub; /* what it asked for */
    int64_t next_ms;         /* loop time of the next current */
    int64_t beat_ms;         /* ... and of the next heartbeat */
};

/* Send one message {type: payload} (payload stolen), framed as the transport wants. */
static void
emit(struct sim_ws *ws, struct op_conn *c, const char *type, json_t *payload)
{
    char *text = octopush_text(type, payload, c->framed);
    if (text)
        sim_ws_send(ws, text, strlen(text));
    free(text);
}

static double
server_time(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec / 1e9;
}

/* The payload of current and history (push.rst's data model). */
static json_t *
state_payload(struct octo_sim *o, const struct sim_np_status *st)
{
    json_t *p = sim_octoprint_job(o, st);
    json_t *text = json_object_get(p, "state");
    json_t *state = json_pack("{s:O,s:o}", "text", text, "flags", sim_octoprint_flags(o, st));
    json_t *err = json_object_get(p, "error");
    json_object_set_new(state, "error", err ? json_incref(err) : json_string(""));
    json_object_set_new(p, "state", state);
    json_object_del(p, "error");
    double now = server_time();
    json_t *busy = json_array();
    if (sim_octoprint_active(st))
        json_array_append_new(busy, json_pack("{s:s,s:s}", "origin", "local", "path", st->file));
    json_object_set_new(p, "currentZ", json_null());
    json_object_set_new(p, "offsets", json_object());
    json_object_set_new(p, "temps",
                        json_pack("[{s:i,s:{s:f,s:f},s:{s:f,s:f}}]", "time", (int)now, "tool0",
                                  "actual", st->nozzle_c, "target", st->nozzle_target_c, "bed",
                                  "actual", st->bed_c, "target", st->bed_target_c));
    json_object_set_new(p, "logs", json_array());
    json_object_set_new(p, "messages", json_array());
    json_object_set_new(p, "resends",
                        json_pack("{s:i,s:I,s:f}", "count", 0, "transmitted",
                                  (json_int_t)st->lines_done, "ratio", 0.0));
    json_object_set_new(p, "serverTime", json_real(now));
    json_object_set_new(p, "busyFiles", busy);
    json_object_set_new(p, "markings", json_array());
    return p;
}

static void
send_history(struct sim_ws *ws, struct op_conn *c)
{
    if (!c->sub.state)
        return;
    struct sim_np_status st;
    sim_netprinter_status(c->o->np, &st);
    emit(ws, c, "history", state_payload(c->o, &st));
    c->next_ms = loop_now_ms(c->o->l) + OCTOPUSH_CURRENT_MS * c->sub.throttle;
}

static void *
on_open(struct sim_ws *ws, int tag, void *ud)
{
    struct octo_sim *o = ud;
    struct op_conn *c = mem_calloc(1, sizeof(*c));
    if (!c)
        return NULL;
    c->o = o;
    c->framed = tag == FRAMED;
    octopush_sub_init(&c->sub);
    c->beat_ms = loop_now_ms(o->l) + SOCKJS_HEARTBEAT_MS;
    if (c->framed)
        sim_ws_send(ws, SOCKJS_OPEN, 1);
    emit(ws, c, "connected",
         json_pack("{s:s,s:s,s:s,s:s,s:s,s:s,s:b,s:n,s:b,s:[{s:s,s:s},{s:s,s:s}]}", "version",
                   "1.10.0", "display_version", "1.10.0", "branch", "", "python_version", "3.11.2",
                   "plugin_hash", "5e6d8c2a4b1f0d3e9a7c6b5d4e3f2a1b", "config_hash",
                   "a1b2c3d4e5f60718293a4b5c6d7e8f90", "debug", false, "safe_mode", "online", true,
                   "permissions", "key", "STATUS", "name", "Status", "key", "PRINT", "name",
                   "Print"));
    c->authed = !o->api_key || !o->api_key[0];
    if (c->authed)
        send_history(ws, c);
    return c;
}

static void
on_auth(struct sim_ws *ws, struct op_conn *c, const char *a)
{
    const char *colon = strchr(a, ':');
    if (!colon || strchr(colon + 1, ':'))
        return; /* "Got invalid auth message": ignored */
    bool ok = (size_t)(colon - a) == strlen(SIM_OCTO_USER) &&
              strncmp(a, SIM_OCTO_USER, strlen(SIM_OCTO_USER)) == 0 &&
              strcmp(colon + 1, SIM_OCTO_SESSION) == 0;
    if (!ok) {
        c->authed = false;
        emit(ws, c, "reauthRequired", json_pack("{s:s}", "reason", "stale"));
        return;
    }
    if (!c->authed) {
        c->authed = true;
        send_history(ws, c);
    }
}

/* One message of the client's (OctoPrint's on_message); a subscription
   that turns state on sends history. */
static void
on_message(struct sim_ws *ws, struct op_conn *c, const char *text, size_t len)
{
    char auth[128];
    bool history;
    enum octopush_msg m = octopush_message(&c->sub, text, len, auth, sizeof(auth), &history);
    if (m == OCTOPUSH_AUTH)
        on_auth(ws, c, auth);
    else if (history && c->authed)
        send_history(ws, c);
}

struct framed {
    struct sim_ws *ws;
    struct op_conn *c;
};

static void
framed_message(void *arg, const char *text, size_t len)
{
    struct framed *f = arg;
    on_message(f->ws, f->c, text, len);
}

static void
on_text(struct sim_ws *ws, void *conn, const char *text, size_t len, void *ud)
{
    (void)ud;
    struct op_conn *c = conn;
    if (!c)
        return;
    if (!c->framed) {
        on_message(ws, c, text, len);
        return;
    }
    /* SockJS: a JSON array of message strings, or one string */
    struct framed f = { ws, c };
    if (sockjs_unframe(text, len, framed_message, &f) < 0)
        sim_ws_close(ws, WS_CLOSE_PROTOCOL, "Broken framing.");
}

static void
on_gone(struct sim_ws *ws, void *conn, void *ud)
{
    (void)ws, (void)ud;
    struct op_conn *c = conn;
    if (!c)
        return;
    octopush_sub_release(&c->sub);
    free(c);
}

static const struct sim_ws_ops ops = { on_open, on_text, on_gone };

struct sim_ws_hub *
sim_octoprint_push_hub(struct octo_sim *o)
{
    return sim_ws_hub_new(o->l, &ops, o);
}

/* GET /sockjs/websocket, /sockjs/SERVER/SESSION/websocket; other transports 404. */
void
sim_octoprint_on_sockjs(struct sim_http_req *r, void *ud)
{
    struct octo_sim *o = ud;
    const char *rest = sim_http_rest(r);
    if (strcmp(rest, "websocket") == 0) {
        sim_ws_accept(r, o->hub, RAW);
        return;
    }
    const char *s1 = strchr(rest, '/');
    const char *s2 = s1 ? strchr(s1 + 1, '/') : NULL;
    if (!s1 || s1 == rest || !s2 || s2 == s1 + 1 || strcmp(s2, "/websocket") != 0 ||
        memchr(rest, '.', (size_t)(s2 - rest))) {
        sim_http_reply_error(r, 404, "Not Found");
        return;
    }
    sim_ws_accept(r, o->hub, FRAMED);
}

void
sim_octoprint_on_sockjs_info(struct sim_http_req *r, void *ud)
{
    (void)ud;
    sim_http_reply_json(r, 200,
                        json_pack("{s:b,s:[s],s:b,s:i}", "websocket", true, "origins", "*:*",
                                  "cookie_needed", false, "entropy", rand()));
}

/* ---- what the watch pushes ---- */

struct push {
    const char *event; /* an event to send, or NULL */
    json_t *payload;   /* its payload (borrowed) */
    bool current;      /* current is due where its time has come */
    const struct sim_np_status *st;
    int64_t now;
};

static void
push_one(struct sim_ws *ws, void *conn, void *arg)
{
    struct op_conn *c = conn;
    struct push *p = arg;
    if (!c)
        return;
    if (c->framed && p->now >= c->beat_ms) {
        sim_ws_send(ws, SOCKJS_HEARTBEAT, 1);
        c->beat_ms = p->now + SOCKJS_HEARTBEAT_MS;
    }
    if (!c->authed)
        return;
    if (p->event && octopush_wants(&c->sub, p->event))
        emit(ws, c, "event", json_pack("{s:s,s:O}", "type", p->event, "payload", p->payload));
    if (p->current && c->sub.state && p->now >= c->next_ms) {
        emit(ws, c, "current", state_payload(c->o, p->st));
        c->next_ms = p->now + OCTOPUSH_CURRENT_MS * c->sub.throttle;
    }
}

/* Send event name with payload (stolen) to every socket that wants it. */
static void
fire(struct octo_sim *o, const char *name, json_t *payload, struct push *p)
{
    p->event = name;
    p->payload = payload;
    p->current = false;
    sim_ws_hub_each(o->hub, push_one, p);
    json_decref(payload);
    p->event = NULL;
}

/* The payload keys OctoPrint's print events share, plus what is given. */
static json_t *
job_payload(const struct octo_sim *o, const char *more, double time_s)
{
    json_t *j =
        json_pack("{s:s,s:s,s:s,s:I,s:s}", "name", o->push_file, "path", o->push_file, "origin",
                  "local", "size", (json_int_t)o->push_size, "owner", SIM_OCTO_USER);
    if (strchr(more, 'u'))
        json_object_set_new(j, "user", json_string(SIM_OCTO_USER));
    if (strchr(more, 't'))
        json_object_set_new(j, "time", json_real(time_s));
    return j;
}

static const char *
state_id(const char *text)
{
    static const char *const ids[][2] = {
        { "Operational", "OPERATIONAL" },
        { "Printing", "PRINTING" },
        { "Pausing", "PAUSING" },
        { "Paused", "PAUSED" },
        { "Cancelling", "CANCELLING" },
        { "Finishing", "FINISHING" },
        { "Error", "ERROR" },
    };
    for (size_t i = 0; i < sizeof(ids) / sizeof(ids[0]); i++)
        if (strcmp(ids[i][0], text) == 0)
            return ids[i][1];
    return "UNKNOWN";
}

/* The print events for a change from state was to st's. */
static void
print_events(struct octo_sim *o, enum sim_np_state was, const struct sim_np_status *st,
             struct push *p)
{
    bool ran = was == SIM_NP_PRINTING || was == SIM_NP_PAUSING || was == SIM_NP_PAUSED ||
               was == SIM_NP_CANCELLING;
    double t = st->print_time_s;
    if (!ran && sim_octoprint_active(st)) {
        snprintf(o->push_file, sizeof(o->push_file), "%s", st->file);
        o->push_size = (uint64_t)st->file_size;
        fire(o, "PrintStarted", job_payload(o, "u", t), p);
    }
    if (st->state == SIM_NP_PAUSED && was != SIM_NP_PAUSED)
        fire(o, "PrintPaused", job_payload(o, "u", t), p);
    if (was == SIM_NP_PAUSED && st->state == SIM_NP_PRINTING)
        fire(o, "PrintResumed", job_payload(o, "u", t), p);
    if (st->state == SIM_NP_CANCELLING && was != SIM_NP_CANCELLING)
        fire(o, "PrintCancelling", job_payload(o, "u", t), p);
    if (!ran)
        return;
    if (st->state == SIM_NP_CANCELLED) {
        fire(o, "PrintCancelled", job_payload(o, "ut", t), p);
        json_t *f = job_payload(o, "t", t);
        json_object_set_new(f, "reason", json_string("cancelled"));
        fire(o, "PrintFailed", f, p);
    } else if (st->state == SIM_NP_ERROR) {
        json_t *f = job_payload(o, "t", t);
        json_object_set_new(f, "reason", json_string("error"));
        fire(o, "PrintFailed", f, p);
    } else if (st->state == SIM_NP_COMPLETE) {
        fire(o, "PrintDone", job_payload(o, "t", t), p);
    }
}

void
sim_octoprint_push_watch(struct octo_sim *o, const struct sim_np_status *st)
{
    const char *text = sim_octoprint_state_text(o, st);
    struct push p = { NULL, NULL, false, st, loop_now_ms(o->l) };
    if (!o->push_text)
        o->push_text = text;
    if (!sim_ws_hub_count(o->hub)) {
        o->push_state = st->state;
        o->push_text = text;
        return;
    }
    if (strcmp(text, o->push_text) != 0)
        fire(o, "PrinterStateChanged",
             json_pack("{s:s,s:s}", "state_id", state_id(text), "state_string", text), &p);
    o->push_text = text;
    if (st->state != o->push_state)
        print_events(o, o->push_state, st, &p);
    o->push_state = st->state;
    p.current = true;
    sim_ws_hub_each(o->hub, push_one, &p);
}
