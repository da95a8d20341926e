/*
 * drv_octoprint_push.c - the OctoPrint driver's push socket (how it stands
 * in for the polls: drv_octoprint_int.h).
 *
 * As OctoPrint's docs/api/push.rst (1.10/1.11) has it: the socket opens
 * with `connected`; the client sends {"auth": "name:session"} (the passive
 * login's user name and session: OctoPrint sends no status to a socket
 * without the STATUS permission), {"throttle": N} (`current` every N x
 * 500 ms: the poll period's rate) and {"subscribe": ...} (state without
 * logs and messages, the print events; an OctoPrint before 1.8 ignores it
 * and sends all).  `history` and then `current` carry state {text, flags,
 * error}, job, progress and temps: each is rewritten into the shapes of
 * GET /api/job and /api/printer and read by their parsers, so one parser
 * checks both.  reauthRequired (a stale session) closes the socket and
 * forgets the session: the next one logs in again.
 *
 * Thread: the loop thread.
 */
#include <stdlib.h>
#include <string.h>

#include "../../src/base/log.h"
#include "drv_octoprint_int.h"

static const char subscribe_msg[] =
    "{\"subscribe\":{\"state\":{\"logs\":false,\"messages\":false},"
    "\"events\":[\"PrintStarted\",\"PrintPaused\",\"PrintResumed\",\"PrintDone\","
    "\"PrintFailed\",\"PrintCancelled\"]}}";

static void
send_msg(struct octo *o, json_t *msg)
{
    char *text = msg ? json_dumps(msg, JSON_COMPACT) : NULL;
    json_decref(msg);
    if (text && o->push.ws)
        wsc_send(o->push.ws, text, strlen(text)); /* a failure closes the socket: closed() says */
    free(text);
}

/* Ask for `current` at the rate the printer's state sets, if that is not what was asked. */
static void
set_throttle(struct octo *o)
{
    int t = netdrv_period(&o->n) / 500;
    t = t < 1 ? 1 : t > 60 ? 60 : t;
    if (o->push.ws && t != o->throttle) {
        o->throttle = t;
        send_msg(o, json_pack("{s:i}", "throttle", t));
    }
}

static void
on_open(struct wsc *w, void *ud)
{
    (void)w;
    struct octo *o = ud;
    send_msg(o, json_pack("{s:s}", "auth", o->auth));
    o->throttle = 0;
    set_throttle(o);
    send_msg(o, json_loads(subscribe_msg, 0, NULL));
}

/*
 * A current or history payload into o->ws_job and o->ws_printer, through
 * the REST parsers: state.text becomes /api/job's state, the last temps
 * entry /api/printer's temperature.
 */
static int
read_state(struct octo *o, json_t *p, struct sf_err *err)
{
    json_t *state = json_object_get(p, "state");
    if (!json_is_object(state))
        return sf_err_set(err, SF_EINVAL, "octoprint push current: no \"state\" object");
    json_t *temps = json_object_get(p, "temps");
    json_t *t = json_array_size(temps) ? json_array_get(temps, json_array_size(temps) - 1) : NULL;
    json_t *job = json_pack("{s:O?,s:O?,s:O?,s:O?}", "job", json_object_get(p, "job"), "progress",
                            json_object_get(p, "progress"), "state", json_object_get(state, "text"),
                            "error", json_object_get(state, "error"));
    json_t *prn = json_pack("{s:O,s:{s:O?,s:O?}}", "state", state, "temperature", "tool0",
                            json_object_get(t, "tool0"), "bed", json_object_get(t, "bed"));
    char *jt = job ? json_dumps(job, JSON_COMPACT) : NULL;
    char *pt = prn ? json_dumps(prn, JSON_COMPACT) : NULL;
    json_decref(job);
    json_decref(prn);
    int rc = !jt || !pt ? sf_err_set(err, SF_ENOMEM, "out of memory")
             : octo_parse_job(jt, strlen(jt), &o->ws_job, err) < 0         ? SF_EINVAL
             : octo_parse_printer(pt, strlen(pt), &o->ws_printer, err) < 0 ? SF_EINVAL
                                                                           : SF_OK;
    free(jt);
    free(pt);
    return rc;
}

/* A print event: its end is confirmed over REST at once, as after an action. */
static void
on_event(struct octo *o, json_t *ev)
{
    const char *type = json_string_value(json_object_get(ev, "type"));
    const char *name = json_string_value(json_object_get(json_object_get(ev, "payload"), "name"));
    if (!type || !name || strcmp(name, o->n.job.name) != 0)
        return;
    if (strcmp(type, "PrintDone") == 0 || strcmp(type, "PrintFailed") == 0 ||
        strcmp(type, "PrintCancelled") == 0) {
        log_printer(LOG_DEBUG, o->n.base.name, "push socket: %s '%s'", type, name);
        if (!o->n.req)
            netdrv_schedule(&o->n, 0);
    }
}

static void
on_text(struct wsc *w, const char *text, size_t len, void *ud)
{
    (void)w;
    struct octo *o = ud;
    json_t *msg = json_loadb(text, len, 0, NULL);
    json_t *p;
    if ((p = json_object_get(msg, "current")) || (p = json_object_get(msg, "history"))) {
        struct sf_err err;
        if (read_state(o, p, &err)) {
            char why[SF_ERR_MSG_MAX + 16];
            snprintf(why, sizeof(why), "push socket: %s", err.msg);
            json_decref(msg);
            octo_push_close(o, why);
            return;
        }
        if (!o->push.live)
            netpush_live(&o->push, &o->n);
        o->push.updates++;
        o->push.dirty = true;
        octo_push_apply(o);
        if (o->push.ws) /* (apply may have closed it) */
            set_throttle(o);
    } else if ((p = json_object_get(msg, "event"))) {
        on_event(o, p);
    } else if (json_object_get(msg, "reauthRequired")) {
        o->auth[0] = '\0';
        octo_push_close(o, "push socket: OctoPrint asks to log in again");
    }
    json_decref(msg);
}

static void
on_closed(struct wsc *w, const char *why, void *ud)
{
    (void)w;
    octo_push_close(ud, why);
}

static const struct wsc_ops ops = { on_open, on_text, on_closed };

void
octo_push_kick(struct octo *o)
{
    struct netdrv *n = &o->n;
    if (o->throttle)
        set_throttle(o);
    if (o->no_login || !netpush_may_open(&o->push, n))
        return;
    if (!o->auth[0]) {
        if (!n->req)
            octo_start(n, RQ_LOGIN); /* logged if it could not start */
        return;
    }
    netpush_open(&o->push, n, o->peer_ip[0] ? o->peer_ip : NULL, "/sockjs/websocket", &ops, o);
}

/* The login's user name and session into o->auth. */
static int
read_login(struct octo *o, const struct httpc_result *res, struct sf_err *err)
{
    static const char who[] = "octoprint";
    char name[128], session[128];
    json_t *j = netdrv_json_load(who, res->body, res->body_len, "/api/login", true, err);
    if (!j)
        return SF_EINVAL;
    int rc = netdrv_json_str(who, j, "name", "/api/login", name, sizeof(name), true, err);
    if (!rc)
        rc = netdrv_json_str(who, j, "session", "/api/login", session, sizeof(session), true, err);
    json_decref(j);
    if (rc)
        return rc;
    if (strchr(name, ':') || strchr(session, ':') || !session[0])
        return sf_err_set(err, SF_EINVAL,
                          "octoprint /api/login: name or session holds ':' or "
                          "is empty");
    snprintf(o->auth, sizeof(o->auth), "%s:%s", name, session);
    return SF_OK;
}

void
octo_push_login_reply(struct octo *o, const struct httpc_result *res)
{
    struct netdrv *n = &o->n;
    char why[SF_ERR_MSG_MAX];
    struct sf_err err;
    enum netdrv_outcome oc = netdrv_judge(n, RQ_LOGIN, res, why, sizeof(why));
    if (oc == NETDRV_DOWN) {
        netdrv_contact_lost(n, why);
        return;
    }
    if (oc == NETDRV_OK && read_login(o, res, &err) == SF_OK) {
        octo_push_kick(o);
        return;
    }
    o->no_login = true;
    log_printer(LOG_INFO, n->base.name, "no push socket (%s): polling",
                oc == NETDRV_OK ? err.msg : why);
}

void
octo_push_apply(struct octo *o)
{
    struct netdrv *n = &o->n;
    if (!netpush_due(&o->push, n))
        return;
    o->last = o->ws_job;
    octo_temps(o, &o->ws_printer);
    n->fails = 0;
    octo_evaluate(o);
}

void
octo_push_close(struct octo *o, const char *why)
{
    o->throttle = 0;
    netpush_close(&o->push, &o->n, why);
}
