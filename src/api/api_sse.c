/*
 * api_sse.c - the event log as Server-Sent Events (api_sse.h).
 *
 * Each stream reads its next events on the API's reader thread
 * (api_read_post), one read at a time, from the id it sent last: the
 * events come in the log's order, none twice, none lost (a wake that came
 * while a read ran reads again after it).  The loop's own store connection
 * sends nothing for a stream: a PostgreSQL round trip per wake per stream
 * held every printer (issue 32).  A stream whose client left while its
 * read ran is freed by the read's end.
 *
 * Thread: the loop thread; the reads on the reader's.
 */
#include "api_sse.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/buf.h"
#include "../base/mem.h"
#include "../farm/farm_host.h"
#include "../farm/farm_view.h"
#include "api_json.h"
#include "route.h"

#define SSE_BATCH 64 /* events read from the store per stream refill */

/* One event stream client. */
struct sse {
    struct api_sse_env *env; /* the API's (lives as long as the API) */
    int64_t last_id;         /* last event id sent */
    unsigned tick_seen;      /* last api tick answered with progress or a keepalive */
    struct buf out;          /* formatted, not yet sent */
    bool reading;            /* the events after last_id are being read (the reader thread) */
    bool again;              /* woken while they were: there may be more, read again */
    bool gone;               /* the stream ended while they were: the read's end frees it */
    bool failed;             /* the store refused them: the stream ends */
};

/*
 * One of several hosts: the other hosts' printers with a job, into arr
 * (sse_progress), as farm_view.h last read them: progress from the job's
 * stored lines (its owner saves them as it prints), time left as the owner
 * published it; each with its host.  A host down shows none.
 */
static void
remote_progress(struct farm *f, json_t *arr)
{
    const struct store_command_printer *r;
    size_t n = farm_view_printers(f, &r);
    for (size_t i = 0; arr && i < n; i++) {
        if (!r[i].job_id || !r[i].live)
            continue;
        double pr = r[i].gcode_lines > 0 ? (double)r[i].lines_acked / r[i].gcode_lines : 0;
        json_t *o =
            json_pack("{ss sI ss sf ss}", "printer", r[i].name, "job_id", (json_int_t)r[i].job_id,
                      "state", r[i].state[0] ? r[i].state : "unknown", "progress",
                      pr > 1 ? 1.0 : pr, "host", r[i].host);
        json_t *v = r[i].view[0] ? json_loads(r[i].view, 0, NULL) : NULL;
        json_t *left = json_object_get(v, "time_left_s");
        if (o)
            json_object_set_new(o, "time_left_s",
                                json_is_integer(left) ? json_incref(left) : json_null());
        if (o)
            json_object_set(o, "time_left_from",
                            json_is_string(json_object_get(v, "time_left_from"))
                                ? json_object_get(v, "time_left_from")
                                : json_null());
        json_decref(v);
        json_array_append_new(arr, o);
    }
}

/*
 * On each tick: the progress of every printer with a job, as an event
 * without id (a snapshot, not part of the log), or a comment line that
 * keeps proxies from closing a quiet stream.
 */
static void
sse_progress(struct sse *s)
{
    struct farm *f = s->env->farm;
    size_t n = f ? farm_printer_count(f) : 0;
    json_t *arr = json_array();
    char me[STORE_HOST_NAME_MAX] = ""; /* one of several hosts: each print names its host */
    if (f && !farm_host_reader(f, me, sizeof(me)))
        me[0] = '\0';
    for (size_t i = 0; arr && i < n; i++) {
        struct printer_info p;
        farm_printer_info(f, i, &p);
        if (p.job_id) {
            json_t *o =
                json_pack("{ss sI ss sf}", "printer", p.cfg->name, "job_id", (json_int_t)p.job_id,
                          "state", printer_state_name(p.state), "progress", p.progress);
            if (o)
                api_time_left_json(o, &p);
            if (o && me[0])
                json_object_set_new(o, "host", json_string(me));
            json_array_append_new(arr, o);
        }
    }
    remote_progress(f, arr);
    char *text = json_array_size(arr) ? json_dumps(arr, JSON_COMPACT) : NULL;
    json_decref(arr);
    if (text)
        buf_printf(&s->out, "event: progress\ndata: %s\n\n", text);
    else
        buf_printf(&s->out, ": keepalive\n\n");
    free(text);
}

/* A read of a stream's next events, on the reader's thread (api_read_post). */
struct sse_batch {
    struct sse *s;
    int64_t after; /* s->last_id when it was asked */
    struct event_row *ev;
    size_t n;
    int rc;
};

static void
sse_batch_read(struct store *st, void *ud)
{
    struct sse_batch *b = ud;
    b->rc = store_events(st, b->after, SSE_BATCH, &b->ev, &b->n, NULL);
}

static void
sse_release(struct sse *s)
{
    buf_release(&s->out);
    free(s);
}

/* On the loop: the events read, formatted into s->out in order; the stream woken if
   there is something to send or to read again. */
static void
sse_batch_done(void *ud, bool ran)
{
    struct sse_batch *b = ud;
    struct sse *s = b->s;
    s->reading = false;
    if (s->gone) {
        sse_release(s);
    } else if (!ran || b->rc) {
        s->failed = true;
        http_wake_stream(s->env->http, s);
    } else {
        size_t i = 0;
        for (; i < b->n; i++) {
            json_t *j = api_event_json(&b->ev[i]);
            char *text = j ? json_dumps(j, JSON_COMPACT) : NULL;
            json_decref(j);
            if (!text || buf_printf(&s->out, "id: %lld\nevent: %s\ndata: %s\n\n",
                                    (long long)b->ev[i].id, b->ev[i].kind, text)) {
                free(text);
                break;
            }
            free(text);
            s->last_id = b->ev[i].id;
        }
        if (i || s->again) { /* something to send, or news that came while reading */
            s->again = false;
            http_wake_stream(s->env->http, s);
        }
    }
    free(b->ev);
    free(b);
}

/* Ask the reader for the events after s->last_id (one read at a time: they come in order). */
static void
sse_refill(struct sse *s)
{
    struct sse_batch *b = mem_calloc(1, sizeof(*b));
    if (!b) {
        s->failed = true;
        return;
    }
    *b = (struct sse_batch){ .s = s, .after = s->last_id };
    s->reading = true;
    s->again = false;
    if (!api_read_post(s->env->reads, sse_batch_read, sse_batch_done, b)) {
        s->reading = false;
        s->failed = true;
        free(b);
    }
}

static ssize_t
sse_read(void *ud, char *buf, size_t max)
{
    struct sse *s = ud;
    if (s->out.len == 0 && !s->failed) {
        if (s->reading)
            s->again = true; /* woken: what woke it may have come after the read began */
        else
            sse_refill(s); /* without a reader thread the events are in s->out now */
    }
    if (s->out.len == 0 && s->failed)
        return -1;
    if (s->out.len == 0 && s->tick_seen != s->env->tick) {
        s->tick_seen = s->env->tick;
        sse_progress(s);
    }
    size_t n = s->out.len < max ? s->out.len : max;
    if (n == 0)
        return 0; /* nothing new: http.c suspends the stream until woken */
    memcpy(buf, s->out.data, n);
    buf_consume(&s->out, n);
    return (ssize_t)n;
}

static void
sse_free(void *ud)
{
    struct sse *s = ud;
    if (s->reading)
        s->gone = true; /* its read's end frees it */
    else
        sse_release(s);
}

/* A GET /api/events on its way: the reader reads the newest event's id, the loop opens the
   stream. */
struct sse_open {
    struct api_sse_env *env;
    bool resume;    /* the client gave Last-Event-ID */
    int64_t id;     /* its value */
    int64_t newest; /* the newest event's id (the reader's) */
};

static void
sse_open_read(struct store *st, void *ud, struct http_resp *resp)
{
    (void)resp;
    struct sse_open *q = ud;
    q->newest = store_event_last(st);
}

static void
sse_open_finish(void *ud, struct http_resp *resp)
{
    struct sse_open *q = ud;
    struct sse *s = mem_calloc(1, sizeof(*s));
    if (!s) {
        http_error(resp, 500, "out of memory");
        return;
    }
    s->env = q->env;
    buf_init(&s->out, 1 << 20);
    int64_t id = q->id, newest = q->newest;
    /* Resume after the client's last event, or start live.  An id above the
       newest is from another (restored or reset) event log: the client is
       told so and gets this log from its start, rather than silence until
       the log catches up with a number that means nothing here. */
    if (q->resume) {
        s->last_id = id;
        if (id > newest) {
            s->last_id = 0;
            buf_printf(&s->out,
                       "event: reset\ndata: {\"last_event_id\":%lld,\"newest\":%lld,"
                       "\"reason\":\"the event log was reset; replaying it from the start\"}\n\n",
                       (long long)id, (long long)newest);
        }
    } else {
        s->last_id = newest;
    }
    s->tick_seen = q->env->tick;
    resp->stream = sse_read;
    resp->stream_ud = s;
    resp->stream_free = sse_free;
}

void
api_sse_open(struct api_sse_env *env, const struct http_req *req, struct http_resp *resp)
{
    struct sse_open *q = mem_calloc(1, sizeof(*q));
    if (!q) {
        http_error(resp, 500, "out of memory");
        return;
    }
    q->env = env;
    q->resume =
        req->last_event_id && route_num(req->last_event_id, strlen(req->last_event_id), &q->id);
    api_read_run(env->reads, resp, sse_open_read, sse_open_finish, q, free);
}
