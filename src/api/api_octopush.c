/*
 * api_octopush.c - OctoPrint's push socket on slimfarmd's OctoPrint face
 * (see api_octopush.h).
 *
 * Shapes: OctoPrint 1.11 docs/api/push.rst (connected, history, current,
 * event, reauthRequired), server/util/sockjs.py (auth, throttle,
 * subscribe); the simulator serves the same (sim/net/sim_octoprint_push.c)
 * and both frame through src/base/wsconn.h and sockjs.h.
 *
 * One timer (API_OCTOPUSH_TICK_MS, while a socket is open) drives every
 * socket: each socket's session is checked, and one read on the API's
 * reader (api_read_post: the loop's own connection sends nothing, issue
 * 32) brings the event log's new rows (an indexed range, as the SSE
 * streams read it), which become `event`s, and the one job of each socket
 * whose `history` or `current` is due (its summary taken when the read
 * was posted).  One read at a time: a tick while one runs posts none, and
 * what came due meanwhile goes with the next.  The summary is
 * api_octoprint.c's, the one GET /api/printer answers.  A socket gets
 * nothing after its auth but its `history`, then events and `current`, as
 * OctoPrint sends them.
 *
 * Thread: the loop thread; the reads on the reader's.
 */
#include "api_octopush.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../base/clock.h"
#include "../base/mem.h"
#include "../base/octopush.h"
#include "../base/sockjs.h"
#include "../base/ws.h"
#include "../base/wsconn.h"
#include "api_compat.h"
#include "api_octoprint.h"
#include "api_read.h"

#define MSG_MAX    ((size_t)64 << 10) /* a client's message: auth, throttle, subscribe */
#define OUT_MAX    ((size_t)4 << 20)  /* queued to a client that reads slowly */
#define EVENTS_MAX 64                 /* event log rows read a tick */

/* What the read in flight answers for a socket. */
enum ask { ASK_NONE, ASK_HISTORY, ASK_CURRENT };

struct op_conn {
    struct api_octopush *p;
    struct wsconn *wc;
    struct http_upgraded *u;
    bool framed;             /* SockJS framing */
    bool authed;             /* a valid auth came */
    struct octopush_sub sub; /* what it asked for */
    int64_t open_ms;         /* when it opened */
    int64_t next_ms;         /* when the next current is due */
    int64_t beat_ms;         /* ... and the next heartbeat */
    const char *text;        /* the state text last sent (a static string) */
    bool history;            /* history is due (auth, or asked): the next read's */
    bool told;               /* history went out (or none was due): events and current follow */
    enum ask ask;            /* what the read in flight answers for it */
    struct api_octoprint_summary s; /* ... with this summary (taken when it was posted) */
    char session[SESSION_TOKEN_LEN + 1];
    char key[FARMCFG_KEY_MAX + 1];
    char printer[64]; /* "" for the whole farm */
    struct op_conn *next;
};

struct api_octopush {
    struct loop *l;
    struct api_read *reads; /* the API's reader */
    struct farm *farm;
    struct sessions *sessions;
    struct op_conn *conns;
    uint64_t timer;            /* the tick, while a socket is open */
    int64_t last_id;           /* the event log's newest row seen */
    bool known;                /* last_id was read since the sockets opened */
    struct push_read *reading; /* the read in flight, or NULL */
};

/* What the reader found for one event row: its print event's printer (in the row) and job. */
struct push_event {
    bool print;              /* a print event: the row's printer is the print's */
    char name[JOB_NAME_MAX]; /* the job's name; "" if not read */
};

/* One tick's read on the API's reader (api_read_post): the jobs the due sockets show, and
   the log's newest id (sockets just opened) or its rows after last_id. */
struct push_read {
    struct api_octopush *p; /* NULL once p is freed: the read's end frees the read alone */
    bool newest;            /* the newest id only */
    int64_t after;          /* the rows after this id; the newest id (newest) */
    int rc;                 /* the rows' read */
    struct event_row *ev;
    struct push_event *pe;
    size_t n;
    int64_t *jobs; /* the jobs to read ... */
    struct job_row *rows;
    bool *found; /* ... what was read of them */
    size_t n_jobs;
};

/* What a route hands to the upgrade (owned by it until taken). */
struct pending {
    struct api_octopush *p;
    bool framed;
    char printer[64];
};

/* Send one message {type: payload} (payload stolen), framed as the transport wants. */
static void
emit(struct op_conn *c, const char *type, json_t *payload)
{
    char *text = octopush_text(type, payload, c->framed);
    if (text)
        wsconn_send(c->wc, text, strlen(text));
    free(text);
}

/* The key's label as api_octoprint's login names it (route_key_label). */
static void
key_label(const char *key, char *out, size_t n)
{
    struct http_req req = { .key = key };
    route_key_label(&req, out, n);
}

/* current's and history's payload (push.rst's data model). */
static json_t *
state_payload(const struct api_octoprint_summary *s, const struct job_row *j)
{
    json_t *p = api_octoprint_job_json(j, s);
    json_t *state = api_octoprint_state_json(s);
    json_object_set_new(state, "error", json_string(""));
    json_object_set_new(p, "state", state);
    json_t *busy = json_array();
    json_t *path = json_object_get(json_object_get(json_object_get(p, "job"), "file"), "path");
    if (json_is_string(path))
        json_array_append_new(busy, json_pack("{s:s,s:O}", "origin", "local", "path", path));
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    json_object_set_new(p, "currentZ", json_null());
    json_object_set_new(p, "offsets", json_object());
    json_object_set_new(p, "temps", json_array()); /* a farm has no one temperature */
    json_object_set_new(p, "logs", json_array());
    json_object_set_new(p, "messages", json_array());
    json_object_set_new(p, "resends",
                        json_pack("{s:i,s:i,s:f}", "count", 0, "transmitted", 0, "ratio", 0.0));
    json_object_set_new(p, "serverTime", json_real((double)ts.tv_sec + ts.tv_nsec / 1e9));
    json_object_set_new(p, "busyFiles", busy);
    json_object_set_new(p, "markings", json_array());
    return p;
}

/* history or current with the summary c's read was posted with and its job j (NULL: none). */
static void
send_state(struct op_conn *c, const char *type, const struct job_row *j, int64_t now)
{
    emit(c, type, state_payload(&c->s, j));
    c->next_ms = now + (int64_t)OCTOPUSH_CURRENT_MS * c->sub.throttle;
}

/* ---- messages from the client (OctoPrint's on_message) ---- */

/* reauthRequired with reason; code: then close with it, and text (NULL: reason) */
static void
refuse(struct op_conn *c, const char *reason, uint16_t code, const char *text)
{
    c->authed = c->told = c->history = false;
    emit(c, "reauthRequired", json_pack("{s:s}", "reason", reason));
    if (code)
        wsconn_close(c->wc, code, text ? text : reason);
}

static void
on_auth(struct op_conn *c, const char *a)
{
    const char *colon = strrchr(a, ':');
    if (!colon)
        return; /* "Got invalid auth message": ignored */
    int64_t now = clock_mono_ms();
    const char *key = sessions_key(c->p->sessions, colon + 1, NULL, now);
    char label[32];
    key_label(key ? key : "", label, sizeof(label));
    bool bad =
        !key || (size_t)(colon - a) != strlen(label) || strncmp(a, label, strlen(label)) != 0;
    /* Counted with its address's REST logins (authlimit.h): guessing
       sessions, many a socket, once went unslowed and unlogged.  Past the
       burst, the socket is closed whatever it sent, as a 429 answers. */
    unsigned wait_s = http_upgraded_login(c->u, bad, "push socket auth: unknown or stale session");
    if (wait_s) {
        char text[64];
        snprintf(text, sizeof(text), "too many failed logins: try again in %u s", wait_s);
        refuse(c, "stale", 1013, text); /* 1013: try again later */
        return;
    }
    if (bad) {
        refuse(c, "stale", 0, NULL);
        return;
    }
    bool ro;
    struct sf_err err;
    int rc = http_upgraded_auth(c->u, key, &ro, &err);
    if (rc) {
        refuse(c, "stale", rc == SF_EAGAIN ? 1013 : 1008, NULL); /* 1013: try again later */
        return;
    }
    snprintf(c->session, sizeof(c->session), "%s", colon + 1);
    snprintf(c->key, sizeof(c->key), "%s", key);
    if (!c->authed) { /* history after the next read; nothing before it */
        c->authed = true;
        c->history = c->sub.state;
        c->told = !c->sub.state;
    }
}

static void
on_message(void *arg, const char *text, size_t len)
{
    struct op_conn *c = arg;
    char auth[128];
    bool history;
    enum octopush_msg m = octopush_message(&c->sub, text, len, auth, sizeof(auth), &history);
    if (m == OCTOPUSH_AUTH)
        on_auth(c, auth);
    else if (history && c->authed)
        c->history = true; /* after the next read */
}

static void
on_text(struct wsconn *wc, const char *text, size_t len, void *ud)
{
    struct op_conn *c = ud;
    if (!c->framed)
        on_message(c, text, len);
    else if (sockjs_unframe(text, len, on_message, c) < 0)
        wsconn_close(wc, WS_CLOSE_PROTOCOL, "Broken framing.");
}

static void
on_gone(struct wsconn *wc, void *ud)
{
    (void)wc;
    struct op_conn *c = ud;
    for (struct op_conn **pp = &c->p->conns; *pp; pp = &(*pp)->next)
        if (*pp == c) {
            *pp = c->next;
            break;
        }
    http_upgraded_close(c->u);
    octopush_sub_release(&c->sub);
    free(c);
}

static const struct wsconn_ops ops = { on_text, on_gone };

/* ---- what the tick pushes ---- */

static void
fire(struct api_octopush *p, const char *printer, const char *name, json_t *payload)
{
    for (struct op_conn *c = p->conns; c; c = c->next)
        if (c->told && !wsconn_closing(c->wc) && octopush_wants(&c->sub, name) &&
            (!c->printer[0] || strcmp(c->printer, printer) == 0))
            emit(c, "event", json_pack("{s:s,s:O}", "type", name, "payload", payload));
    json_decref(payload);
}

/* The payload keys OctoPrint's print events share, for the job of ev. */
static json_t *
job_payload(const struct event_row *ev, const struct push_event *pe, const char *reason)
{
    char path[JOB_NAME_MAX + 32];
    snprintf(path, sizeof(path), "job-%lld/%s", (long long)ev->job_id, pe->name);
    json_t *o =
        json_pack("{s:s,s:s,s:s,s:{s:s,s:I}}", "name", pe->name, "path", path, "origin", "local",
                  "slimfarm", "printer", ev->printer, "job_id", (json_int_t)ev->job_id);
    if (reason)
        json_object_set_new(o, "reason", json_string(reason));
    return o;
}

/* A job that left its printer (done, failed, cancelled) is logged without
   it: ev gets the printer of the job's last print; false if it has none, or
   ev is a cancel and the last print did not end by it (a queued job's).
   The reader's thread, with its store st. */
static bool
print_printer(struct store *st, struct event_row *ev)
{
    struct print_row *pr;
    size_t n;
    if (store_prints(st, ev->job_id, &pr, &n, NULL) || !n)
        return false;
    const struct print_row *last = &pr[n - 1];
    bool ok = strcmp(ev->kind, "job-cancel") != 0 || !last->outcome[0] ||
              strcmp(last->outcome, "cancelled") == 0;
    if (ok)
        snprintf(ev->printer, sizeof(ev->printer), "%s", last->printer);
    free(pr);
    return ok;
}

/* The farm's job events as OctoPrint's print events (the rows r read). */
static void
log_events(struct api_octopush *p, const struct push_read *r)
{
    static const char *const map[][3] = {
        /* the log's kind, OctoPrint's event, a second event with reason */
        { "job-start", "PrintStarted", NULL },
        { "job-pause", "PrintPaused", NULL },
        { "job-resume", "PrintResumed", NULL },
        { "job-print-done", "PrintDone", NULL },
        { "job-print-failed", "PrintFailed", "error" },
        { "job-cancel", "PrintCancelled", "cancelled" },
    };
    for (size_t i = 0; i < r->n; i++) {
        const struct event_row *ev = &r->ev[i];
        p->last_id = ev->id;
        if (!r->pe[i].print)
            continue; /* a job that was on no printer: no print event */
        for (size_t k = 0; k < sizeof(map) / sizeof(map[0]); k++) {
            if (strcmp(ev->kind, map[k][0]) != 0)
                continue;
            bool failed = strcmp(map[k][1], "PrintFailed") == 0;
            fire(p, ev->printer, map[k][1], job_payload(ev, &r->pe[i], failed ? map[k][2] : NULL));
            if (map[k][2] && !failed)
                fire(p, ev->printer, "PrintFailed", job_payload(ev, &r->pe[i], map[k][2]));
        }
    }
}

static const char *
state_id(const char *text)
{
    static const char *const ids[][2] = {
        { "Operational", "OPERATIONAL" }, { "Printing", "PRINTING" },
        { "Paused", "PAUSED" },           { "Error", "ERROR" },
        { "Offline", "OFFLINE" },
    };
    for (size_t i = 0; i < sizeof(ids) / sizeof(ids[0]); i++)
        if (strcmp(ids[i][0], text) == 0)
            return ids[i][1];
    return "UNKNOWN";
}

/* One socket's turn: its session, its state text, its heartbeat and current. */
static void
tick_one(struct op_conn *c, int64_t now)
{
    if (c->framed && now >= c->beat_ms) {
        wsconn_send(c->wc, SOCKJS_HEARTBEAT, 1);
        c->beat_ms = now + SOCKJS_HEARTBEAT_MS;
    }
    /* A socket's life is an event stream's (a silent client that vanished is found at the
       latest then; OctoPrint's clients reconnect, as EventSource does). */
    if (now - c->open_ms >= http_upgraded_lifetime_ms(c->u)) {
        wsconn_close(c->wc, 1001, "socket lifetime over: connect again"); /* 1001: going away */
        return;
    }
    if (!c->authed) {
        if (now - c->open_ms >= API_OCTOPUSH_AUTH_WAIT_MS)
            wsconn_close(c->wc, 1008, "no auth message came"); /* 1008: policy violation */
        return;
    }
    const char *key = sessions_key(c->p->sessions, c->session, NULL, now);
    if (!key || strcmp(key, c->key) != 0 || http_upgraded_revoked(c->u)) {
        refuse(c, "logout", 1008, NULL);
        return;
    }
    if (!c->told)
        return; /* its history first (push_post) */
    struct api_octoprint_summary s;
    api_octoprint_summarize(c->p->farm, c->printer, &s);
    if (c->text && strcmp(s.text, c->text) != 0 && octopush_wants(&c->sub, "PrinterStateChanged"))
        emit(c, "event",
             json_pack("{s:s,s:{s:s,s:s}}", "type", "PrinterStateChanged", "payload", "state_id",
                       state_id(s.text), "state_string", s.text));
    c->text = s.text;
}

/* ---- the tick's read ---- */

static void
push_read_free(struct push_read *r)
{
    free(r->ev);
    free(r->pe);
    free(r->jobs);
    free(r->rows);
    free(r->found);
    free(r);
}

/* The reader's thread, with its connection st: the jobs, then the newest id or the rows. */
static void
push_read(struct store *st, void *ud)
{
    struct push_read *r = ud;
    for (size_t i = 0; i < r->n_jobs; i++)
        r->found[i] = store_job_get(st, r->jobs[i], &r->rows[i], NULL) == SF_OK;
    if (r->newest) {
        r->after = store_event_last(st);
        return;
    }
    if ((r->rc = store_events(st, r->after, EVENTS_MAX, &r->ev, &r->n, NULL)) || !r->n)
        return;
    if (!(r->pe = mem_calloc(r->n, sizeof(*r->pe)))) {
        r->rc = SF_ENOMEM; /* read again on a later tick */
        return;
    }
    for (size_t i = 0; i < r->n; i++) {
        struct event_row *ev = &r->ev[i];
        r->pe[i].print = ev->job_id && (ev->printer[0] || print_printer(st, ev));
        struct job_row j;
        if (r->pe[i].print && store_job_get(st, ev->job_id, &j, NULL) == SF_OK)
            snprintf(r->pe[i].name, sizeof(r->pe[i].name), "%s", j.opts.name);
    }
}

/* The sockets' asks back to none; what was due stays due (the next read's). */
static void
asks_drop(struct api_octopush *p)
{
    for (struct op_conn *c = p->conns; c; c = c->next) {
        c->history |= c->ask == ASK_HISTORY;
        c->ask = ASK_NONE;
    }
}

/* On the loop: the events go out, then each socket's history or current it asked for (the
   sockets that left meanwhile are not in the list; one refused meanwhile gets none). */
static void
push_done(void *ud, bool ran)
{
    struct push_read *r = ud;
    struct api_octopush *p = r->p;
    if (!p) {
        push_read_free(r);
        return;
    }
    p->reading = NULL;
    if (!ran) {
        asks_drop(p);
        push_read_free(r);
        return;
    }
    if (r->newest) {
        p->last_id = r->after;
        p->known = true;
    } else if (p->known && r->rc == SF_OK) { /* not when the sockets all left and came again */
        log_events(p, r);
    }
    int64_t now = clock_mono_ms();
    for (struct op_conn *c = p->conns; c; c = c->next) {
        enum ask a = c->ask;
        c->ask = ASK_NONE;
        if (a == ASK_NONE || !c->authed || wsconn_closing(c->wc) || (a == ASK_CURRENT && !c->told))
            continue;
        const struct job_row *j = NULL;
        for (size_t i = 0; c->s.job && i < r->n_jobs; i++)
            if (r->jobs[i] == c->s.job && r->found[i])
                j = &r->rows[i];
        send_state(c, a == ASK_HISTORY ? "history" : "current", j, now);
        if (a == ASK_HISTORY) {
            c->told = true;
            if (!c->text)
                c->text = c->s.text;
        }
    }
    push_read_free(r);
}

/* Post the tick's read: the sockets whose history or current is due ask with the summary of
   now.  Out of memory: nothing is posted, the next tick tries again. */
static void
push_post(struct api_octopush *p, int64_t now)
{
    size_t n = 0;
    for (struct op_conn *c = p->conns; c; c = c->next)
        n++;
    struct push_read *r = mem_calloc(1, sizeof(*r));
    if (!r)
        return;
    *r = (struct push_read){ .p = p, .newest = !p->known, .after = p->last_id };
    if (n && (!(r->jobs = mem_calloc(n, sizeof(*r->jobs))) ||
              !(r->rows = mem_calloc(n, sizeof(*r->rows))) ||
              !(r->found = mem_calloc(n, sizeof(*r->found))))) {
        push_read_free(r);
        return;
    }
    for (struct op_conn *c = p->conns; c; c = c->next) {
        if (!c->authed || wsconn_closing(c->wc))
            continue;
        if (c->history)
            c->ask = ASK_HISTORY;
        else if (c->told && c->sub.state && now >= c->next_ms)
            c->ask = ASK_CURRENT;
        else
            continue;
        c->history = false;
        api_octoprint_summarize(p->farm, c->printer, &c->s);
        bool have = false;
        for (size_t i = 0; i < r->n_jobs; i++)
            have |= r->jobs[i] == c->s.job;
        if (c->s.job && !have)
            r->jobs[r->n_jobs++] = c->s.job;
    }
    p->reading = r; /* without a reader thread, push_done runs before this returns */
    if (!api_read_post(p->reads, push_read, push_done, r)) {
        p->reading = NULL;
        asks_drop(p);
        push_read_free(r);
    }
}

static void
tick(struct loop *l, void *ud)
{
    (void)l;
    struct api_octopush *p = ud;
    p->timer = 0;
    if (!p->conns)
        return;
    int64_t now = clock_mono_ms();
    for (struct op_conn *c = p->conns; c; c = c->next)
        if (!wsconn_closing(c->wc))
            tick_one(c, now);
    if (!p->reading)
        push_post(p, now);
    p->timer = loop_timer_add(p->l, API_OCTOPUSH_TICK_MS, tick, p);
}

/* ---- the upgrade ---- */

static void
on_upgraded(void *ud, struct http_upgraded *u, int fd, const char *extra, size_t n_extra)
{
    struct pending *pd = ud;
    struct api_octopush *p = pd->p;
    struct op_conn *c = mem_calloc(1, sizeof(*c));
    if (c)
        c->wc = wsconn_new(p->l, fd, MSG_MAX, OUT_MAX, &ops, c);
    if (!c || !c->wc) {
        free(c);
        free(pd);
        http_upgraded_close(u);
        return;
    }
    int64_t now = clock_mono_ms();
    *c = (struct op_conn){ .p = p,
                           .wc = c->wc,
                           .u = u,
                           .framed = pd->framed,
                           .open_ms = now,
                           .beat_ms = now + SOCKJS_HEARTBEAT_MS,
                           .next = p->conns };
    octopush_sub_init(&c->sub);
    snprintf(c->printer, sizeof(c->printer), "%s", pd->printer);
    free(pd);
    if (!p->conns && !p->timer) {
        p->known = false; /* the next read reads the newest row's id */
        p->timer = loop_timer_add(p->l, API_OCTOPUSH_TICK_MS, tick, p);
    }
    p->conns = c;
    if (c->framed)
        wsconn_send(c->wc, SOCKJS_OPEN, 1);
    emit(c, "connected",
         json_pack("{s:s,s:s,s:s,s:s,s:s,s:s,s:b,s:n,s:b,s:[{s:s,s:s},{s:s,s:s}]}", "version",
                   API_COMPAT_OCTOPRINT, "display_version", API_COMPAT_OCTOPRINT, "branch", "",
                   "python_version", "", "plugin_hash", "slimfarm", "config_hash", "slimfarm",
                   "debug", false, "safe_mode", "online", true, "permissions", "key", "STATUS",
                   "name", "Status", "key", "PRINT", "name", "Print"));
    wsconn_start(c->wc, extra, n_extra);
}

bool
api_octopush_public(const char *path)
{
    if (strncmp(path, "/sockjs/", 8) != 0)
        return false;
    const char *rest = path + 8;
    if (strcmp(rest, "websocket") == 0 || strcmp(rest, "info") == 0)
        return true;
    const char *s1 = strchr(rest, '/');
    const char *s2 = s1 ? strchr(s1 + 1, '/') : NULL;
    /* SERVER/SESSION/websocket, as SockJS clients name it (no dots: not a file) */
    return s1 && s1 != rest && s2 && s2 != s1 + 1 && strcmp(s2, "/websocket") == 0 &&
           !memchr(rest, '.', (size_t)(s2 - rest));
}

void
api_octopush_route(void *ctx, const struct route_args *args, const struct http_req *req,
                   struct http_resp *resp)
{
    (void)args;
    const struct api_compat_env *env = ctx;
    if (strcmp(req->path, "/sockjs/info") == 0) {
        resp->json = json_pack("{s:b,s:[s],s:b,s:i}", "websocket", true, "origins", "*:*",
                               "cookie_needed", false, "entropy", rand());
        return;
    }
    if (!api_octopush_public(req->path)) {
        http_error(resp, 404, "no such resource: %.100s (SockJS: websocket transports only)",
                   req->path);
        return;
    }
    const char *printer = http_req_arg(req, "printer");
    struct api_octoprint_summary s;
    if (!api_octoprint_summarize(env->farm, printer, &s) || (printer && strlen(printer) >= 64)) {
        http_error(resp, 404, "printer '%.64s' (query 'printer') is not in the farm", printer);
        return;
    }
    char accept[WS_ACCEPT_LEN + 1];
    const char *why;
    int status = ws_handshake(req->method, http_req_header(req, "Upgrade"),
                              http_req_header(req, "Connection"),
                              http_req_header(req, "Sec-WebSocket-Version"),
                              http_req_header(req, "Sec-WebSocket-Key"), accept, &why);
    if (status != 101) {
        if (status == 426)
            http_resp_header(resp, "Sec-WebSocket-Version", "13");
        http_error(resp, status, "%s", why);
        return;
    }
    struct pending *pd = mem_calloc(1, sizeof(*pd));
    if (!pd) {
        http_error(resp, 500, "out of memory");
        return;
    }
    *pd = (struct pending){ .p = env->push, .framed = strcmp(req->path, "/sockjs/websocket") != 0 };
    snprintf(pd->printer, sizeof(pd->printer), "%s", printer ? printer : "");
    http_resp_header(resp, "Upgrade", "websocket");
    http_resp_header(resp, "Connection", "Upgrade");
    http_resp_header(resp, "Sec-WebSocket-Accept", "%s", accept);
    resp->status = 101;
    resp->upgrade = on_upgraded;
    resp->upgrade_ud = pd;
    resp->upgrade_free = free;
}

/* ---- lifecycle ---- */

struct api_octopush *
api_octopush_new(struct loop *l, struct api_read *reads, struct farm *f, int64_t idle_ms,
                 int64_t max_ms, struct sf_err *err)
{
    struct api_octopush *p = mem_calloc(1, sizeof(*p));
    if (!p) {
        sf_err_set(err, SF_ENOMEM, "api: out of memory");
        return NULL;
    }
    *p = (struct api_octopush){ .l = l, .reads = reads, .farm = f };
    if (!(p->sessions = sessions_new(idle_ms, max_ms, err))) {
        free(p);
        return NULL;
    }
    return p;
}

void
api_octopush_free(struct api_octopush *p)
{
    if (!p)
        return;
    while (p->conns) /* each leaves the list in on_gone */
        wsconn_free(p->conns->wc, WS_CLOSE_AWAY);
    if (p->timer)
        loop_timer_cancel(p->l, p->timer);
    if (p->reading) /* its end comes later (api_read_free): it frees the read alone */
        p->reading->p = NULL;
    sessions_free(p->sessions);
    free(p);
}

int
api_octopush_login(struct api_octopush *p, const char *key, char *session, struct sf_err *err)
{
    char csrf[SESSION_TOKEN_LEN + 1];
    return sessions_make(p->sessions, key, clock_mono_ms(), session, csrf, err);
}

size_t
api_octopush_keys_changed(struct api_octopush *p, const struct farmcfg_key *keys, size_t n_keys)
{
    return sessions_keep_keys(p->sessions, keys, n_keys);
}

size_t
api_octopush_count(const struct api_octopush *p)
{
    size_t n = 0;
    for (const struct op_conn *c = p->conns; c; c = c->next)
        n++;
    return n;
}
