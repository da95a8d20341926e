/*
 * drv_octoprint.c - a printer behind OctoPrint (drv_octoprint.h).
 *
 * Why this shape: OctoPrint streams the G-code itself, so the driver's job
 * is a file transfer plus a watch.  Everything is a request on the shared
 * httpc client; the driver never waits.  Three kinds of traffic:
 *  - the link: GET /api/version on open(), then a poll cycle (GET /api/job
 *    and GET /api/printer, both answered, then the next cycle after
 *    poll_ms).  Any poll that finds OctoPrint unreachable (refused,
 *    timeout, 5xx) or refusing our key takes the link down (DRV_OFFLINE);
 *    the owner re-open()s after drv_backoff_ms.
 *  - the job: an upload (multipart, streamed from disk by curl) with
 *    print=true, select+print if OctoPrint did not start it, then the poll
 *    decides how it ends (evaluate()).
 *  - actions: pause/resume/cancel/command, one request each.  A poll that
 *    started before an action was answered says nothing about the action's
 *    effect, so state changes from such polls are dropped (act_epoch).
 *
 * Thread: the loop thread.
 */
#include "drv_octoprint.h"

#include <jansson.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "../../src/base/gcode.h"
#include "../../src/base/limits.h"
#include "../../src/base/log.h"
#include "../../src/base/mem.h"
#include "httpc.h"

/* Replies we read are small; a status reply of a few kB, 256 kB is plenty. */
#define OCTO_BODY_MAX ((size_t)256 << 10)
/* A poll or an action that takes longer than this finds OctoPrint down. */
#define OCTO_REQ_TIMEOUT_MS 10000
/* An upload that moves nothing for this long has failed. */
#define OCTO_STALL_MS 60000
/* Polls that may pass without our file printing before the job counts as gone. */
#define OCTO_GRACE_POLLS 3

enum link { L_DOWN, L_VERSION, L_UP };
enum job { J_NONE, J_UPLOADING, J_SELECTING, J_RUNNING, J_CANCELLING };

struct octo {
    struct drv base;
    struct httpc *http; /* the loop's shared client (httpc_get) */
    char url[256];      /* base URL, no trailing '/' */
    char key_hdr[200];  /* "X-Api-Key: ..." */
    int poll_ms;        /* poll period */
    enum link link;     /* connection progress */
    bool polled;        /* a whole poll cycle came back since the link came up */
    struct httpc_req *req_version, *req_job, *req_printer;            /* link and poll requests */
    struct httpc_req *req_upload, *req_select, *req_action, *req_cmd; /* job and actions */
    int poll_pending;          /* poll replies still awaited this cycle */
    bool poll_again;           /* poll once more at once when this cycle ends */
    uint64_t poll_timer;       /* next cycle */
    uint64_t act_epoch;        /* bumped when an action is answered */
    uint64_t poll_epoch;       /* act_epoch when this cycle started */
    struct octo_job last;      /* the last /api/job */
    struct octo_printer lastp; /* the last /api/printer (temperatures) */
    enum job job;              /* our job's phase */
    char remote[80];           /* its name on OctoPrint (drv_remote_name) */
    int64_t file_size;         /* its size */
    bool saw_printing;         /* OctoPrint was seen printing it (or we re-attached) */
    int missing_polls;         /* cycles without it where it should be */
    FILE *cur;                 /* the job file, read up to OctoPrint's file position */
    int64_t cur_pos;           /* bytes of it counted */
    uint64_t cur_lines;        /* command lines in those bytes */
    char *cur_buf;             /* getline buffer */
    size_t cur_cap;
};

/* ---- reply parsing (pure) ---- */

enum octo_remote
octo_classify(const char *s)
{
    static const struct {
        const char *prefix;
        enum octo_remote r;
    } map[] = {
        { "Operational", OCTO_R_IDLE },
        { "Ready", OCTO_R_IDLE },
        { "Printing", OCTO_R_PRINTING }, /* and "Printing from SD" */
        { "Starting", OCTO_R_PRINTING },
        { "Resuming", OCTO_R_PRINTING },
        { "Finishing", OCTO_R_PRINTING },
        { "Pausing", OCTO_R_PRINTING },
        { "Sending file to SD", OCTO_R_PRINTING },
        { "Transferring file to SD", OCTO_R_PRINTING },
        { "Paused", OCTO_R_PAUSED },
        { "Cancelling", OCTO_R_CANCELLING },
        { "Offline after error", OCTO_R_ERROR },
        { "Error", OCTO_R_ERROR },
        { "Offline", OCTO_R_OFFLINE },
        { "Closed", OCTO_R_OFFLINE },
        { "Opening serial", OCTO_R_OFFLINE },
        { "Connecting", OCTO_R_OFFLINE },
        { "Detecting", OCTO_R_OFFLINE },
    };
    for (size_t i = 0; s && i < sizeof(map) / sizeof(map[0]); i++)
        if (strncmp(s, map[i].prefix, strlen(map[i].prefix)) == 0)
            return map[i].r;
    return OCTO_R_UNKNOWN;
}

static json_t *
load(const char *body, size_t len, const char *what, struct sf_err *err)
{
    json_error_t je;
    json_t *j = json_loadb(body, len, 0, &je);
    if (!j) {
        sf_err_set(err, SF_EINVAL, "octoprint %s: not JSON: %s (line %d)", what, je.text, je.line);
        return NULL;
    }
    if (!json_is_object(j)) {
        json_decref(j);
        sf_err_set(err, SF_EINVAL, "octoprint %s: not a JSON object", what);
        return NULL;
    }
    return j;
}

static void
copy_str(json_t *v, char *out, size_t n)
{
    const char *s = json_string_value(v);
    snprintf(out, n, "%s", s ? s : "");
}

static double
num_or(json_t *v, double dflt)
{
    return json_is_number(v) ? json_number_value(v) : dflt;
}

/* A byte count or offset: a number from 0 to 2^53 (exact in a double), else dflt. */
static int64_t
bytes_or(json_t *v, int64_t dflt)
{
    double d = num_or(v, -1);
    return d >= 0 && d <= 9007199254740992.0 ? (int64_t)d : dflt;
}

int
octo_parse_job(const char *body, size_t len, struct octo_job *out, struct sf_err *err)
{
    memset(out, 0, sizeof(*out));
    out->size = out->filepos = -1;
    out->completion = out->print_time_s = out->time_left_s = -1;
    json_t *j = load(body, len, "/api/job", err);
    if (!j)
        return SF_EINVAL;
    json_t *state = json_object_get(j, "state");
    if (!json_is_string(state)) {
        json_decref(j);
        return sf_err_set(err, SF_EINVAL, "octoprint /api/job: no \"state\" text");
    }
    copy_str(state, out->state, sizeof(out->state));
    json_t *file = json_object_get(json_object_get(j, "job"), "file");
    copy_str(json_object_get(file, "name"), out->file, sizeof(out->file));
    out->size = bytes_or(json_object_get(file, "size"), -1);
    json_t *p = json_object_get(j, "progress");
    out->completion = num_or(json_object_get(p, "completion"), -1);
    out->filepos = bytes_or(json_object_get(p, "filepos"), -1);
    out->print_time_s = num_or(json_object_get(p, "printTime"), -1);
    out->time_left_s = num_or(json_object_get(p, "printTimeLeft"), -1);
    copy_str(json_object_get(j, "error"), out->error, sizeof(out->error));
    json_decref(j);
    if (out->completion > 100 || (out->completion < 0 && out->completion != -1))
        return sf_err_set(err, SF_EINVAL, "octoprint /api/job: completion %g is not a percentage",
                          out->completion);
    return SF_OK;
}

static void
temp(json_t *t, double *actual, double *target)
{
    *actual = num_or(json_object_get(t, "actual"), -1);
    *target = num_or(json_object_get(t, "target"), -1);
}

int
octo_parse_printer(const char *body, size_t len, struct octo_printer *out, struct sf_err *err)
{
    memset(out, 0, sizeof(*out));
    json_t *j = load(body, len, "/api/printer", err);
    if (!j)
        return SF_EINVAL;
    json_t *st = json_object_get(j, "state");
    copy_str(json_object_get(st, "text"), out->state, sizeof(out->state));
    json_t *f = json_object_get(st, "flags");
    out->operational = json_is_true(json_object_get(f, "operational"));
    out->printing = json_is_true(json_object_get(f, "printing"));
    out->paused = json_is_true(json_object_get(f, "paused"));
    out->error = json_is_true(json_object_get(f, "error"));
    out->closed_or_error = json_is_true(json_object_get(f, "closedOrError"));
    json_t *t = json_object_get(j, "temperature");
    temp(json_object_get(t, "tool0"), &out->tool_c, &out->tool_target_c);
    temp(json_object_get(t, "bed"), &out->bed_c, &out->bed_target_c);
    json_decref(j);
    return SF_OK;
}

int
octo_parse_version(const char *body, size_t len, char *text, size_t n, struct sf_err *err)
{
    if (n)
        text[0] = 0;
    json_t *j = load(body, len, "/api/version", err);
    if (!j)
        return SF_EINVAL;
    json_t *api = json_object_get(j, "api");
    json_t *t = json_object_get(j, "text");
    int rc = SF_OK;
    if (!json_is_string(api))
        rc = sf_err_set(err, SF_EINVAL, "octoprint /api/version: no \"api\" version");
    else if (json_is_string(t) && strncmp(json_string_value(t), "OctoPrint", 9) != 0)
        rc =
            sf_err_set(err, SF_EINVAL, "octoprint /api/version: server says '%.60s', not OctoPrint",
                       json_string_value(t));
    else
        snprintf(text, n, "%s", json_is_string(t) ? json_string_value(t) : "OctoPrint");
    json_decref(j);
    return rc;
}

int
octo_parse_upload(const char *body, size_t len, bool *effective_print, char *name, size_t n,
                  struct sf_err *err)
{
    *effective_print = false;
    if (n)
        name[0] = 0;
    json_t *j = load(body, len, "upload", err);
    if (!j)
        return SF_EINVAL;
    json_t *local = json_object_get(json_object_get(j, "files"), "local");
    if (!json_is_object(local)) {
        json_decref(j);
        return sf_err_set(err, SF_EINVAL, "octoprint upload: no \"files.local\" in the reply");
    }
    copy_str(json_object_get(local, "name"), name, n);
    *effective_print = json_is_true(json_object_get(j, "effectivePrint"));
    json_decref(j);
    return SF_OK;
}

void
octo_reason(const char *body, size_t len, char *out, size_t n)
{
    if (!n)
        return;
    out[0] = 0;
    json_t *j = body && len ? json_loadb(body, len, 0, NULL) : NULL;
    const char *e = j ? json_string_value(json_object_get(j, "error")) : NULL;
    if (e) {
        snprintf(out, n, "%s", e);
    } else if (body && !j) {
        /* body need not be NUL-terminated: stop at len */
        size_t k = 0;
        while (k < len && body[k] && body[k] != '\r' && body[k] != '\n')
            k++;
        snprintf(out, n, "%.*s", (int)(k < n ? k : n - 1), body);
    }
    json_decref(j);
    /* A reason is one line of text for an operator. */
    for (char *c = out; *c; c++)
        if ((unsigned char)*c < ' ')
            *c = ' ';
}

/* ---- driver plumbing ---- */

static void
emit(struct octo *o, enum drv_event ev)
{
    if (o->base.on_event)
        o->base.on_event(&o->base, ev, o->base.ud);
}

static void
set_state(struct octo *o, enum drv_state s)
{
    if (o->base.status.state == s)
        return;
    o->base.status.state = s;
    emit(o, DRV_EV_STATE);
}

static void msg(struct octo *o, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void
msg(struct octo *o, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(o->base.status.message, sizeof(o->base.status.message), fmt, ap);
    va_end(ap);
}

static void
cancel_req(struct httpc_req **r)
{
    if (*r)
        httpc_cancel(*r);
    *r = NULL;
}

/* What an HTTP outcome means for us. */
enum outcome { O_OK, O_AUTH, O_CONFLICT, O_NOTFOUND, O_DOWN, O_REFUSED };

static enum outcome
judge(const struct httpc_result *res, const char *what, char *why, size_t n)
{
    char reason[160];
    if (res->code != SF_OK) {
        snprintf(why, n, "OctoPrint unreachable: %s", res->err.msg);
        return O_DOWN;
    }
    if (res->status >= 200 && res->status < 300) {
        why[0] = 0;
        return O_OK;
    }
    octo_reason(res->body, res->body_len, reason, sizeof(reason));
    if (res->status == 401 || res->status == 403) {
        snprintf(why, n, "authentication failed (check api_key): %s answered %ld", what,
                 res->status);
        return O_AUTH;
    }
    if (res->status == 409) {
        snprintf(why, n, "OctoPrint: %s", reason[0] ? reason : "conflict (409)");
        return O_CONFLICT;
    }
    if (res->status == 404) {
        snprintf(why, n, "OctoPrint: %s: not found (404)", what);
        return O_NOTFOUND;
    }
    if (res->status >= 500) {
        snprintf(why, n, "OctoPrint: %s answered HTTP %ld%s%s", what, res->status,
                 reason[0] ? ": " : "", reason);
        return O_DOWN;
    }
    snprintf(why, n, "OctoPrint: %s answered HTTP %ld%s%s", what, res->status,
             reason[0] ? ": " : "", reason);
    return O_REFUSED;
}

/* The reply to the request held in *slot (which empties): what it amounts to. */
static enum outcome
answered(struct httpc_req **slot, const struct httpc_result *res, const char *what, char *why,
         size_t n)
{
    *slot = NULL;
    return judge(res, what, why, n);
}

/* A 2xx reply whose body the parser refused (rc < 0): refused, with the parser's reason. */
static enum outcome
parsed(int rc, const struct sf_err *err, char *why, size_t n)
{
    if (rc >= 0)
        return O_OK;
    snprintf(why, n, "%s", err->msg);
    return O_REFUSED;
}

static struct httpc_req *
request(struct octo *o, const char *method, const char *path, const char *json,
        const struct httpc_part *parts, size_t n_parts, httpc_done_fn done)
{
    char url[512];
    snprintf(url, sizeof(url), "%s%s", o->url, path);
    const char *hdrs[3] = { o->key_hdr, json ? "Content-Type: application/json" : NULL, NULL };
    struct httpc_opts opt = {
        .method = method,
        .url = url,
        .headers = hdrs,
        .body = json,
        .body_len = json ? strlen(json) : 0,
        .parts = parts,
        .n_parts = n_parts,
        .max_body = OCTO_BODY_MAX,
        .timeout_ms = parts ? -1 : OCTO_REQ_TIMEOUT_MS,
        .stall_ms = parts ? OCTO_STALL_MS : 0,
        .done = done,
        .ud = o,
    };
    struct sf_err err;
    struct httpc_req *r = httpc_start(o->http, &opt, &err);
    if (!r)
        log_printer(LOG_WARN, o->base.name, "%s", err.msg);
    return r;
}

/* ---- the job's end ---- */

static void
cursor_close(struct octo *o)
{
    if (o->cur)
        fclose(o->cur);
    o->cur = NULL;
    o->cur_pos = 0;
    o->cur_lines = 0;
}

static void
cursor_open(struct octo *o, const char *path)
{
    cursor_close(o);
    o->cur = fopen(path, "r");
}

/*
 * Command lines wholly before byte pos of the job file: OctoPrint reports
 * bytes, the farm counts lines.  The cursor only moves forward, so over a
 * whole print the file is read once, a little per poll.
 */
static uint64_t
lines_before(struct octo *o, int64_t pos)
{
    char cmd[SF_GCODE_LINE_MAX];
    while (o->cur && o->cur_pos < pos) {
        ssize_t k = getline(&o->cur_buf, &o->cur_cap, o->cur);
        if (k <= 0)
            break;
        if (o->cur_pos + k > pos) {
            fseeko(o->cur, o->cur_pos, SEEK_SET); /* not all of it sent yet */
            break;
        }
        o->cur_pos += k;
        if (gcode_strip(o->cur_buf, (size_t)k, cmd, sizeof(cmd), NULL) > 0)
            o->cur_lines++;
    }
    return o->cur_lines;
}

static void
job_end(struct octo *o, enum drv_event ev, enum drv_state next)
{
    struct drv_status *st = &o->base.status;
    o->job = J_NONE;
    cursor_close(o);
    st->has_time_left = false;
    if (ev == DRV_EV_JOB_DONE) {
        st->lines_acked = st->lines_total;
        st->progress = 1.0;
        st->message[0] = 0;
    } else if (ev == DRV_EV_JOB_FAILED) {
        log_printer(LOG_WARN, o->base.name, "job failed: %s", st->message);
    }
    st->state = next; /* the event carries the state the job left the printer in */
    emit(o, ev);
    emit(o, DRV_EV_STATE);
}

static void job_fail(struct octo *o, enum drv_state next, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
static void
job_fail(struct octo *o, enum drv_state next, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(o->base.status.message, sizeof(o->base.status.message), fmt, ap);
    va_end(ap);
    job_end(o, DRV_EV_JOB_FAILED, next);
}

/* ---- the link ---- */

static void poll_start(struct octo *o);
static void on_poll_timer(struct loop *l, void *ud);

/* Cancel every request but the upload, and the poll timer: the link is down. */
static void
drop_requests(struct octo *o)
{
    cancel_req(&o->req_version);
    cancel_req(&o->req_job);
    cancel_req(&o->req_printer);
    cancel_req(&o->req_select);
    cancel_req(&o->req_action);
    cancel_req(&o->req_cmd);
    if (o->poll_timer)
        loop_timer_cancel(o->base.loop, o->poll_timer);
    o->poll_timer = 0;
    o->poll_pending = 0;
    o->link = L_DOWN;
    o->polled = false;
}

static void
link_down(struct octo *o, const char *why)
{
    drop_requests(o);
    log_printer(LOG_WARN, o->base.name, "%s", why);
    if (o->job == J_UPLOADING || o->job == J_SELECTING) {
        cancel_req(&o->req_upload);
        job_fail(o, DRV_OFFLINE, "upload failed: %s", why);
    }
    /* A job OctoPrint runs goes on without us: the owner re-attaches it
       (drv.h attach) once the link is back. */
    o->job = J_NONE;
    cursor_close(o);
    msg(o, "%s", why);
    set_state(o, DRV_OFFLINE);
}

static void
poll_soon(struct octo *o, int64_t delay_ms)
{
    if (o->link != L_UP)
        return;
    if (o->poll_pending) {
        if (delay_ms == 0)
            o->poll_again = true;
        return;
    }
    if (o->poll_timer)
        loop_timer_cancel(o->base.loop, o->poll_timer);
    o->poll_timer = 0;
    if (delay_ms == 0) {
        poll_start(o);
        return;
    }
    o->poll_timer = loop_timer_add(o->base.loop, delay_ms, on_poll_timer, o);
}

static void
update_progress(struct octo *o)
{
    struct drv_status *st = &o->base.status;
    const struct octo_job *j = &o->last;
    uint64_t before = st->lines_acked;
    /* Bytes first: OctoPrint's own docs show "completion" both as a
       percentage (the data model) and as a fraction (the GET /api/job example). */
    double p = j->filepos >= 0 && j->size > 0 ? (double)j->filepos / (double)j->size
               : j->completion >= 0           ? j->completion / 100.0
                                              : st->progress;
    if (p > 1)
        p = 1;
    st->progress = p;
    /* OctoPrint's own estimate (progress.printTimeLeft: its estimator, from
       the file's analysis and the progress so far; null until it has one) */
    st->has_time_left = j->time_left_s >= 0;
    st->time_left_s = st->has_time_left ? (int64_t)(j->time_left_s + 0.5) : 0;
    /* OctoPrint counts bytes; the lines are those wholly before its position. */
    uint64_t lines = j->filepos >= 0 && o->cur ? lines_before(o, j->filepos)
                                               : (uint64_t)((double)st->lines_total * p);
    if (lines >= st->lines_total && st->lines_total)
        lines = st->lines_total - 1; /* the last line counts at DONE */
    if (lines > before)
        st->lines_acked = lines;
    if (st->lines_acked != before)
        emit(o, DRV_EV_PROGRESS);
}

static bool
finished(const struct octo_job *j)
{
    return (j->filepos >= 0 && j->size > 0 && j->filepos >= j->size) || j->completion >= 99.9999;
}

/* A whole poll cycle came back: what it means. */
static void
evaluate(struct octo *o)
{
    const struct octo_job *j = &o->last;
    enum octo_remote r = octo_classify(j->state);
    bool fresh = o->poll_epoch == o->act_epoch && !o->req_action;
    o->polled = true;
    if (r == OCTO_R_OFFLINE) {
        if (o->job == J_RUNNING || o->job == J_CANCELLING)
            job_fail(o, DRV_OFFLINE, "OctoPrint lost the printer (%s)", j->state);
        char why[160];
        snprintf(why, sizeof(why), "OctoPrint is up, its printer is not connected (%s)", j->state);
        link_down(o, why);
        return;
    }
    bool ours = o->remote[0] && strcmp(j->file, o->remote) == 0;
    switch (o->job) {
    case J_NONE:
        if (!fresh)
            break;
        if (r == OCTO_R_ERROR) {
            msg(o, "OctoPrint: %s%s%s", j->state, j->error[0] ? ": " : "", j->error);
            set_state(o, DRV_ERROR);
        } else if (r == OCTO_R_IDLE) {
            if (o->base.status.state == DRV_CONNECTING || o->base.status.state == DRV_ERROR)
                o->base.status.message[0] = 0;
            set_state(o, DRV_IDLE);
        } else if (r == OCTO_R_PAUSED) {
            msg(o, "OctoPrint is paused on '%s', which the farm did not start", j->file);
            set_state(o, DRV_PAUSED);
        } else {
            msg(o, "OctoPrint is busy (%s '%s')", j->state, j->file);
            set_state(o, DRV_PRINTING);
        }
        break;
    case J_UPLOADING:
    case J_SELECTING:
        break;
    case J_RUNNING:
    case J_CANCELLING:
        if (r == OCTO_R_ERROR) {
            job_fail(o, DRV_ERROR, "OctoPrint: %s%s%s", j->state, j->error[0] ? ": " : "",
                     j->error);
            break;
        }
        if (ours && r != OCTO_R_IDLE) {
            o->saw_printing = true;
            o->missing_polls = 0;
            update_progress(o);
            if (fresh && o->job == J_RUNNING)
                set_state(o, r == OCTO_R_PAUSED ? DRV_PAUSED : DRV_PRINTING);
            break;
        }
        if (o->job == J_CANCELLING && (r == OCTO_R_IDLE || !ours)) {
            msg(o, "cancelled at %.0f %%", o->base.status.progress * 100);
            job_end(o, DRV_EV_JOB_CANCELLED, r == OCTO_R_IDLE ? DRV_IDLE : DRV_PRINTING);
            break;
        }
        if (ours && r == OCTO_R_IDLE && finished(j)) {
            job_end(o, DRV_EV_JOB_DONE, DRV_IDLE);
            break;
        }
        if (ours && r == OCTO_R_IDLE && o->saw_printing) {
            update_progress(o);
            job_fail(o, DRV_IDLE, "the print was stopped at the printer at %.0f %%",
                     j->completion >= 0 ? j->completion : 0);
            break;
        }
        if (++o->missing_polls < OCTO_GRACE_POLLS)
            break;
        if (!ours && r != OCTO_R_IDLE)
            job_fail(o, DRV_PRINTING, "OctoPrint prints '%s' instead of the job's '%s'", j->file,
                     o->remote);
        else if (!ours)
            job_fail(o, DRV_IDLE, "OctoPrint no longer has the job's file '%s'", o->remote);
        else
            job_fail(o, DRV_IDLE, "OctoPrint did not start the print of '%s'", o->remote);
        break;
    }
}

static void
poll_done(struct octo *o)
{
    if (--o->poll_pending > 0 || o->link != L_UP)
        return;
    evaluate(o);
    if (o->link != L_UP)
        return;
    if (o->poll_again) {
        o->poll_again = false;
        poll_start(o);
        return;
    }
    o->poll_timer = loop_timer_add(o->base.loop, o->poll_ms, on_poll_timer, o);
}

static void
on_job(struct httpc_req *r, const struct httpc_result *res, void *ud)
{
    (void)r;
    struct octo *o = ud;
    char why[SF_ERR_MSG_MAX];
    enum outcome oc = answered(&o->req_job, res, "GET /api/job", why, sizeof(why));
    struct sf_err err;
    if (oc == O_OK)
        oc = parsed(octo_parse_job(res->body, res->body_len, &o->last, &err), &err, why,
                    sizeof(why));
    if (oc != O_OK) {
        link_down(o, why);
        return;
    }
    poll_done(o);
}

static void
on_printer(struct httpc_req *r, const struct httpc_result *res, void *ud)
{
    (void)r;
    struct octo *o = ud;
    char why[SF_ERR_MSG_MAX];
    enum outcome oc = answered(&o->req_printer, res, "GET /api/printer", why, sizeof(why));
    if (oc == O_CONFLICT) {
        poll_done(o); /* 409: the printer is not operational; /api/job says how */
        return;
    }
    struct octo_printer p;
    struct sf_err err;
    if (oc == O_OK)
        oc = parsed(octo_parse_printer(res->body, res->body_len, &p, &err), &err, why, sizeof(why));
    if (oc != O_OK) {
        link_down(o, why);
        return;
    }
    struct drv_status *st = &o->base.status;
    if (p.tool_c >= 0 &&
        (p.tool_c != st->nozzle_c || p.bed_c != st->bed_c ||
         p.tool_target_c != st->nozzle_target_c || p.bed_target_c != st->bed_target_c)) {
        st->nozzle_c = p.tool_c;
        st->nozzle_target_c = p.tool_target_c > 0 ? p.tool_target_c : 0;
        st->bed_c = p.bed_c >= 0 ? p.bed_c : 0;
        st->bed_target_c = p.bed_target_c > 0 ? p.bed_target_c : 0;
        emit(o, DRV_EV_TEMPS);
    }
    o->lastp = p;
    poll_done(o);
}

static void
poll_start(struct octo *o)
{
    if (o->link != L_UP || o->poll_pending)
        return;
    if (o->poll_timer)
        loop_timer_cancel(o->base.loop, o->poll_timer);
    o->poll_timer = 0;
    o->poll_epoch = o->act_epoch;
    o->req_job = request(o, "GET", "/api/job", NULL, NULL, 0, on_job);
    o->req_printer = request(o, "GET", "/api/printer?exclude=sd", NULL, NULL, 0, on_printer);
    if (!o->req_job || !o->req_printer) {
        link_down(o, "out of memory starting a poll");
        return;
    }
    o->poll_pending = 2;
}

static void
on_poll_timer(struct loop *l, void *ud)
{
    (void)l;
    struct octo *o = ud;
    o->poll_timer = 0;
    poll_start(o);
}

static void
on_version(struct httpc_req *r, const struct httpc_result *res, void *ud)
{
    (void)r;
    struct octo *o = ud;
    char why[SF_ERR_MSG_MAX];
    enum outcome oc = answered(&o->req_version, res, "GET /api/version", why, sizeof(why));
    struct sf_err err;
    char text[64];
    if (oc == O_OK)
        oc = parsed(octo_parse_version(res->body, res->body_len, text, sizeof(text), &err), &err,
                    why, sizeof(why));
    if (oc != O_OK) {
        link_down(o, why);
        return;
    }
    snprintf(o->base.caps.firmware, sizeof(o->base.caps.firmware), "%s", text);
    o->link = L_UP;
    poll_start(o); /* its answer sets the state */
}

/* ---- ops ---- */

static int
octo_open(struct drv *d, struct sf_err *err)
{
    struct octo *o = (struct octo *)d;
    (void)err;
    if (o->link != L_DOWN)
        return SF_OK;
    o->link = L_VERSION;
    o->polled = false;
    set_state(o, DRV_CONNECTING);
    o->req_version = request(o, "GET", "/api/version", NULL, NULL, 0, on_version);
    if (!o->req_version) {
        o->link = L_DOWN;
        set_state(o, DRV_OFFLINE);
        return sf_err_set(err, SF_ENOMEM, "printer '%s': cannot start a request", d->name);
    }
    return SF_OK;
}

/* OctoPrint took the job and prints it: the polls say how it goes. */
static void
print_started(struct octo *o)
{
    o->job = J_RUNNING;
    o->missing_polls = 0;
    o->base.status.message[0] = 0;
    poll_soon(o, 0);
}

static void
on_select(struct httpc_req *r, const struct httpc_result *res, void *ud)
{
    (void)r;
    struct octo *o = ud;
    char why[SF_ERR_MSG_MAX];
    enum outcome oc = answered(&o->req_select, res, "select+print", why, sizeof(why));
    if (oc == O_OK) {
        print_started(o);
    } else if (oc == O_DOWN || oc == O_AUTH) {
        link_down(o, why);
    } else {
        job_fail(o, DRV_IDLE, "OctoPrint did not start the print: %s", why);
        poll_soon(o, 0);
    }
}

static void
on_upload(struct httpc_req *r, const struct httpc_result *res, void *ud)
{
    (void)r;
    struct octo *o = ud;
    char why[SF_ERR_MSG_MAX];
    enum outcome oc = answered(&o->req_upload, res, "upload", why, sizeof(why));
    bool printing = false;
    char name[128];
    struct sf_err err;
    if (oc == O_OK)
        oc =
            parsed(octo_parse_upload(res->body, res->body_len, &printing, name, sizeof(name), &err),
                   &err, why, sizeof(why));
    if (oc == O_DOWN || oc == O_AUTH) {
        link_down(o, why); /* fails the job, as an upload */
        return;
    }
    if (oc != O_OK) {
        job_fail(o, DRV_IDLE, "upload refused: %s", why);
        poll_soon(o, 0);
        return;
    }
    if (printing) {
        print_started(o);
        return;
    }
    /* Stored, not started (OctoPrint drops print=true when it cannot start):
       ask explicitly, which says why if it refuses. */
    o->job = J_SELECTING;
    char path[200];
    snprintf(path, sizeof(path), "/api/files/local/%s", o->remote);
    o->req_select =
        request(o, "POST", path, "{\"command\":\"select\",\"print\":true}", NULL, 0, on_select);
    if (!o->req_select)
        job_fail(o, DRV_IDLE, "out of memory asking OctoPrint to print");
}

static void
on_upload_progress(struct httpc_req *r, uint64_t sent, uint64_t total, void *ud)
{
    (void)r;
    struct octo *o = ud;
    if (total)
        msg(o, "uploading %.0f %%", 100.0 * (double)sent / (double)total);
}

static int
file_size(const char *path, int64_t *size, struct sf_err *err)
{
    struct stat st;
    if (stat(path, &st) < 0 || !S_ISREG(st.st_mode))
        return sf_err_sys(err, "octoprint: cannot read '%s'", path);
    *size = (int64_t)st.st_size;
    return SF_OK;
}

static int
octo_start_job(struct drv *d, const char *gcode_path, uint64_t first_line,
               const struct drv_job_scan *scan, struct sf_err *err)
{
    struct octo *o = (struct octo *)d;
    if (first_line > 0)
        return sf_err_set(err, SF_EUNSUPP,
                          "printer '%s': OctoPrint prints whole files; resuming at line %llu is "
                          "not supported (restart the job)",
                          d->name, (unsigned long long)first_line);
    if (o->link != L_UP || d->status.state != DRV_IDLE || o->job != J_NONE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is not idle (%s)", d->name,
                          drv_state_name(d->status.state));
    int64_t size = 0;
    if (file_size(gcode_path, &size, err) < 0)
        return err ? err->code : SF_EIO;
    struct drv_job_scan own;
    if (!scan) {
        int rc = drv_job_scan(gcode_path, &own, err);
        if (rc < 0)
            return rc;
        scan = &own;
    }
    drv_remote_name(gcode_path, o->remote, sizeof(o->remote));
    o->file_size = size;
    struct httpc_part parts[] = {
        { .name = "select", .value = "true" },
        { .name = "print", .value = "true" },
        { .name = "file",
          .file_path = gcode_path,
          .filename = o->remote,
          .type = "application/octet-stream" },
    };
    char url[512];
    snprintf(url, sizeof(url), "%s/api/files/local", o->url);
    const char *hdrs[] = { o->key_hdr, NULL };
    struct httpc_opts opt = { .url = url,
                              .headers = hdrs,
                              .parts = parts,
                              .n_parts = 3,
                              .max_body = OCTO_BODY_MAX,
                              .timeout_ms = -1,
                              .stall_ms = OCTO_STALL_MS,
                              .done = on_upload,
                              .progress = on_upload_progress,
                              .ud = o };
    o->req_upload = httpc_start(o->http, &opt, err);
    if (!o->req_upload)
        return err ? err->code : SF_EIO;
    struct drv_status *st = &d->status;
    o->job = J_UPLOADING;
    cursor_open(o, gcode_path);
    o->saw_printing = false;
    o->missing_polls = 0;
    st->lines_total = scan->lines_total;
    st->lines_acked = 0;
    st->progress = 0;
    st->has_time_left = false;
    st->job_started_ms = loop_now_ms(d->loop);
    msg(o, "uploading");
    set_state(o, DRV_PRINTING);
    return SF_OK;
}

static void
on_action(struct httpc_req *r, const struct httpc_result *res, void *ud)
{
    (void)r;
    struct octo *o = ud;
    o->act_epoch++;
    char why[SF_ERR_MSG_MAX];
    enum outcome oc = answered(&o->req_action, res, "POST /api/job", why, sizeof(why));
    if (oc == O_DOWN || oc == O_AUTH) {
        link_down(o, why);
        return;
    }
    if (oc != O_OK) {
        msg(o, "%s", why);
        log_printer(LOG_WARN, o->base.name, "%s", why);
    }
    poll_soon(o, 0); /* see what it did */
}

static int
action(struct octo *o, const char *body, struct sf_err *err)
{
    if (o->req_action)
        return sf_err_set(err, SF_EAGAIN, "printer '%s': another action is still on its way",
                          o->base.name);
    o->req_action = request(o, "POST", "/api/job", body, NULL, 0, on_action);
    if (!o->req_action)
        return sf_err_set(err, SF_ENOMEM, "printer '%s': cannot start a request", o->base.name);
    return SF_OK;
}

/* POST /api/job {"command": "pause", "action": pause or resume}, from state `from`. */
static int
pause_action(struct drv *d, bool pause, struct sf_err *err)
{
    struct octo *o = (struct octo *)d;
    enum drv_state from = pause ? DRV_PRINTING : DRV_PAUSED;
    if (o->job != J_RUNNING || d->status.state != from)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is not %s", d->name,
                          pause ? "printing a job" : "paused");
    int rc = action(o,
                    pause ? "{\"command\":\"pause\",\"action\":\"pause\"}"
                          : "{\"command\":\"pause\",\"action\":\"resume\"}",
                    err);
    if (rc == SF_OK)
        set_state(o, pause ? DRV_PAUSED : DRV_PRINTING);
    return rc;
}

static int
octo_pause(struct drv *d, struct sf_err *err)
{
    return pause_action(d, true, err);
}

static int
octo_resume(struct drv *d, struct sf_err *err)
{
    return pause_action(d, false, err);
}

static int
octo_cancel(struct drv *d, struct sf_err *err)
{
    struct octo *o = (struct octo *)d;
    if (o->job == J_UPLOADING || o->job == J_SELECTING) {
        /* Not printing yet: stop the transfer and it is over. */
        cancel_req(&o->req_upload);
        cancel_req(&o->req_select);
        msg(o, "cancelled before the print started");
        job_end(o, DRV_EV_JOB_CANCELLED, DRV_IDLE);
        return SF_OK;
    }
    if (o->job != J_RUNNING)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' has no job to cancel", d->name);
    int rc = action(o, "{\"command\":\"cancel\"}", err);
    if (rc == SF_OK) {
        o->job = J_CANCELLING;
        d->status.state = DRV_PRINTING; /* until OctoPrint is done cancelling */
    }
    return rc;
}

static void
on_command(struct httpc_req *r, const struct httpc_result *res, void *ud)
{
    (void)r;
    struct octo *o = ud;
    char why[SF_ERR_MSG_MAX];
    enum outcome oc = answered(&o->req_cmd, res, "POST /api/printer/command", why, sizeof(why));
    if (oc == O_DOWN || oc == O_AUTH)
        link_down(o, why);
    else if (oc != O_OK)
        log_printer(LOG_WARN, o->base.name, "command refused: %s", why);
}

static int
octo_command(struct drv *d, const char *line, struct sf_err *err)
{
    struct octo *o = (struct octo *)d;
    if (o->link != L_UP)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is not connected", d->name);
    if (o->req_cmd)
        return sf_err_set(err, SF_EAGAIN, "printer '%s': the last command is still on its way",
                          d->name);
    json_t *j = json_pack("{s:s}", "command", line ? line : "");
    char *body = j ? json_dumps(j, JSON_COMPACT) : NULL;
    json_decref(j);
    if (!body)
        return sf_err_set(err, SF_ENOMEM, "out of memory");
    o->req_cmd = request(o, "POST", "/api/printer/command", body, NULL, 0, on_command);
    free(body);
    if (!o->req_cmd)
        return sf_err_set(err, SF_ENOMEM, "printer '%s': cannot start a request", d->name);
    return SF_OK;
}

static int
octo_attach(struct drv *d, const char *gcode_path, const struct drv_job_scan *scan,
            struct sf_err *err)
{
    struct octo *o = (struct octo *)d;
    if (o->link != L_UP || !o->polled)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is not connected yet", d->name);
    if (o->job != J_NONE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' already has a job", d->name);
    int64_t size = 0;
    if (file_size(gcode_path, &size, err) < 0)
        return err ? err->code : SF_EIO;
    char remote[80];
    drv_remote_name(gcode_path, remote, sizeof(remote));
    const struct octo_job *j = &o->last;
    if (strcmp(j->file, remote) != 0 || j->size != size)
        return sf_err_set(err, SF_ENOTFOUND,
                          "printer '%s': OctoPrint's job is '%s' (%lld bytes), not the farm's "
                          "'%s' (%lld bytes)",
                          d->name, j->file[0] ? j->file : "none", (long long)j->size, remote,
                          (long long)size);
    enum octo_remote r = octo_classify(j->state);
    if (r == OCTO_R_OFFLINE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s': OctoPrint has no printer", d->name);
    snprintf(o->remote, sizeof(o->remote), "%s", remote);
    o->file_size = size;
    o->job = J_RUNNING;
    cursor_open(o, gcode_path);
    o->saw_printing = true; /* it printed this before the daemon went away */
    d->status.message[0] = 0;
    o->missing_polls = 0;
    struct drv_status *st = &d->status;
    if (scan)
        st->lines_total = scan->lines_total;
    else {
        struct drv_job_scan own;
        st->lines_total = drv_job_scan(gcode_path, &own, NULL) == SF_OK ? own.lines_total : 0;
    }
    st->lines_acked = 0;
    st->job_started_ms = loop_now_ms(d->loop);
    update_progress(o);
    log_printer(LOG_INFO, d->name, "re-attached to '%s' at %.0f %% (%s)", remote,
                st->progress * 100, j->state);
    /* The next poll tells how it goes on (or that it ended meanwhile). */
    if (r == OCTO_R_PAUSED)
        set_state(o, DRV_PAUSED);
    else
        set_state(o, DRV_PRINTING);
    poll_soon(o, 0);
    return SF_OK;
}

static void
octo_close(struct drv *d)
{
    struct octo *o = (struct octo *)d;
    cancel_req(&o->req_upload);
    drop_requests(o);
    o->job = J_NONE;
    cursor_close(o);
    set_state(o, DRV_OFFLINE);
}

static void
octo_destroy(struct drv *d)
{
    struct octo *o = (struct octo *)d;
    httpc_put(o->http);
    cursor_close(o);
    free(o->cur_buf);
    free(o);
}

static const struct drv_ops octo_ops = {
    .version = DRV_OPS_VERSION,
    .kind = "octoprint",
    .open = octo_open,
    .start_job = octo_start_job,
    .pause = octo_pause,
    .resume = octo_resume,
    .cancel = octo_cancel,
    .command = octo_command,
    .close = octo_close,
    .destroy = octo_destroy,
    .attach = octo_attach,
};

struct drv *
drv_octoprint_new(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event, void *ud,
                  struct sf_err *err)
{
    const char *name = cfg->name ? cfg->name : "?";
    if (!cfg->url || (strncmp(cfg->url, "http://", 7) != 0 && strncmp(cfg->url, "https://", 8))) {
        sf_err_set(err, SF_EINVAL, "printer '%s': octoprint needs an http:// or https:// url",
                   name);
        return NULL;
    }
    if (!cfg->api_key || !cfg->api_key[0]) {
        sf_err_set(err, SF_EINVAL, "printer '%s': octoprint needs an api_key", name);
        return NULL;
    }
    if (strlen(cfg->url) >= sizeof(((struct octo *)0)->url) || strlen(cfg->api_key) > 160 ||
        strpbrk(cfg->api_key, "\r\n")) {
        sf_err_set(err, SF_EINVAL, "printer '%s': url or api_key too long or not one line", name);
        return NULL;
    }
    struct octo *o = mem_calloc(1, sizeof(*o));
    if (!o) {
        sf_err_set(err, SF_ENOMEM, "printer '%s': out of memory", name);
        return NULL;
    }
    o->http = httpc_get(l, err);
    if (!o->http) {
        free(o);
        return NULL;
    }
    o->base.ops = &octo_ops;
    o->base.loop = l;
    snprintf(o->base.name, sizeof(o->base.name), "%s", name);
    o->base.on_event = on_event;
    o->base.ud = ud;
    o->base.status.state = DRV_OFFLINE;
    snprintf(o->base.caps.firmware, sizeof(o->base.caps.firmware), "OctoPrint");
    snprintf(o->url, sizeof(o->url), "%s", cfg->url);
    size_t n = strlen(o->url);
    while (n && o->url[n - 1] == '/')
        o->url[--n] = 0;
    snprintf(o->key_hdr, sizeof(o->key_hdr), "X-Api-Key: %s", cfg->api_key);
    o->poll_ms = cfg->poll_ms > 0 ? cfg->poll_ms : 1000;
    return &o->base;
}
