/*
 * drv_octoprint.c - a printer behind OctoPrint (drv_octoprint.h).
 *
 * OctoPrint streams the G-code itself, so the driver's job is a file
 * transfer plus a watch, as for Moonraker and PrusaLink: it runs on their
 * core (netdrv.h: the request slot, the poll timer, losing contact, the
 * job operations), and judges what OctoPrint says with netjob.h's table.
 * This file holds what is OctoPrint's own: its replies' parsers (pure,
 * exposed for the replay tests and the fuzz target), its routes and auth
 * header, its words for a fault, its state texts in netjob's words, and
 * the job's lines counted from OctoPrint's file position.
 *
 * Thread: the parsers are pure; the driver runs on the loop thread.
 */
#include "drv_octoprint.h"

#include <jansson.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/base/gcode.h"
#include "../../src/base/limits.h"
#include "../../src/base/log.h"
#include "../../src/base/mem.h"
#include "drv_octoprint_int.h"

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
        { "Sending file to SD", OCTO_R_PRINTING },
        { "Transferring file to SD", OCTO_R_PRINTING },
        { "Paused", OCTO_R_PAUSED },
        /* between the pause command and Paused, while the printer finishes the moves it
           holds: a pause taking effect (said printing, the farm took it for a resume at
           the printer, and the job went paused, printing, paused within two polls) */
        { "Pausing", OCTO_R_PAUSED },
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

/* ---- the driver ---- */

/*
 * How it talks: netdrv.h's core (one request at a time, polls on a timer
 * that actions pre-empt), with job_tries and upload_tries 1: any poll that
 * finds OctoPrint unreachable (refused, timeout, 5xx), refusing our key or
 * answering what is not OctoPrint takes the printer offline at once, and a
 * job OctoPrint runs is left to attach() on reconnect; an upload that fails
 * fails the job (the farm's retry policy sends it again).  Over OctoPrint's
 * API: GET /api/version on connecting, then a poll is GET /api/job and
 * GET /api/printer one after the other, judged when both are in; the
 * upload is multipart POST /api/files/local with select and print, then
 * select+print if OctoPrint stored it without starting it.
 *
 * How a job ends: OctoPrint reports bytes and has no job id, so the job is
 * ours while its file has our name; Operational with our file read to its
 * end is done, Operational short of it after we saw it print is stopped
 * at the printer, and a file OctoPrint does not show for
 * OCTO_GRACE_POLLS polls (it takes a moment to start one) is gone.
 */
/* Replies we read are small; a status reply of a few kB, 256 kB is plenty. */
#define OCTO_BODY_MAX ((size_t)256 << 10)
/* Polls that may pass without our file printing before the job counts as gone. */
#define OCTO_GRACE_POLLS 3
#define OCTO_POLL_MS     1000 /* drv_config.poll_ms 0 */

static struct octo *
OC(struct netdrv *n)
{
    return (struct octo *)n;
}

/* OctoPrint's routes, and what each request is called in messages ("GET /api/job answered
   HTTP 503"); select+print appends the file name, a command brings its own body. */
static const struct route {
    int kind;
    const char *method, *path, *body, *name;
} routes[] = {
    { NETDRV_RQ_INFO, "GET", "/api/version", NULL, "GET /api/version" },
    { NETDRV_RQ_POLL, "GET", "/api/job", NULL, "GET /api/job" },
    { RQ_PRINTER, "GET", "/api/printer?exclude=sd", NULL, "GET /api/printer" },
    { NETDRV_RQ_UPLOAD, "POST", "/api/files/local", NULL, "upload" },
    { RQ_SELECT, "POST", "/api/files/local/", "{\"command\":\"select\",\"print\":true}",
      "select+print" },
    { NETDRV_RQ_PAUSE, "POST", "/api/job", "{\"command\":\"pause\",\"action\":\"pause\"}",
      "POST /api/job" },
    { NETDRV_RQ_RESUME, "POST", "/api/job", "{\"command\":\"pause\",\"action\":\"resume\"}",
      "POST /api/job" },
    { NETDRV_RQ_CANCEL, "POST", "/api/job", "{\"command\":\"cancel\"}", "POST /api/job" },
    { RQ_COMMAND, "POST", "/api/printer/command", NULL, "POST /api/printer/command" },
    { RQ_LOGIN, "POST", "/api/login", "{\"passive\":true}", "POST /api/login" },
};

static const struct route *
route(int kind)
{
    for (size_t i = 0; i < sizeof(routes) / sizeof(routes[0]); i++)
        if (routes[i].kind == kind)
            return &routes[i];
    return NULL;
}

static enum netdrv_outcome
octo_judge(struct netdrv *n, int kind, const struct httpc_result *res, char *why, size_t len)
{
    (void)n;
    char reason[160];
    const struct route *rt = route(kind);
    const char *w = rt ? rt->name : "?";
    if (res->code != SF_OK) {
        snprintf(why, len, "OctoPrint unreachable: %s", res->err.msg);
        return NETDRV_DOWN;
    }
    if (res->status >= 200 && res->status < 300) {
        why[0] = 0;
        return NETDRV_OK;
    }
    octo_reason(res->body, res->body_len, reason, sizeof(reason));
    if (res->status == 401 || res->status == 403) {
        snprintf(why, len, "authentication failed (check api_key): %s answered %ld", w,
                 res->status);
        return NETDRV_AUTH;
    }
    if (res->status == 409)
        snprintf(why, len, "OctoPrint: %s", reason[0] ? reason : "conflict (409)");
    else if (res->status == 404)
        snprintf(why, len, "OctoPrint: %s: not found (404)", w);
    else
        snprintf(why, len, "OctoPrint: %s answered HTTP %ld%s%s", w, res->status,
                 reason[0] ? ": " : "", reason);
    return res->status >= 500 ? NETDRV_DOWN : NETDRV_REFUSED;
}

/* A 2xx reply whose body the parser refused (rc < 0): refused, with the parser's reason. */
static enum netdrv_outcome
parsed(int rc, const struct sf_err *err, char *why, size_t n)
{
    if (rc >= 0)
        return NETDRV_OK;
    snprintf(why, n, "%s", err->msg);
    return NETDRV_REFUSED;
}

/* Request kind in the free slot: its route, the key, JSON when there is a body. */
bool
octo_start(struct netdrv *n, int kind)
{
    struct octo *o = OC(n);
    const struct route *rt = route(kind);
    if (!rt)
        return false;
    char url[512], *cmd = NULL;
    snprintf(url, sizeof(url), "%s%s%s", n->url, rt->path, kind == RQ_SELECT ? n->job.name : "");
    const char *body = rt->body;
    if (kind == RQ_COMMAND) {
        json_t *j = json_pack("{s:s}", "command", o->cmd);
        body = cmd = j ? json_dumps(j, JSON_COMPACT) : NULL;
        json_decref(j);
        if (!cmd)
            return false;
    }
    struct httpc_opts opt = { .method = rt->method,
                              .url = url,
                              .headers = body ? o->json_hdrs : o->hdrs,
                              .body = body,
                              .body_len = body ? strlen(body) : 0,
                              .max_body = OCTO_BODY_MAX };
    struct httpc_part parts[] = {
        { .name = "select", .value = "true" },
        { .name = "print", .value = "true" },
        { .name = "file",
          .file_path = n->path,
          .filename = n->job.name,
          .type = "application/octet-stream" },
    };
    if (kind == NETDRV_RQ_UPLOAD) {
        opt.parts = parts; /* httpc_start copies them, and the body */
        opt.n_parts = 3;
    }
    bool ok = netdrv_request(n, kind, &opt);
    free(cmd);
    return ok;
}

static bool
octo_poll(struct netdrv *n)
{
    struct octo *o = OC(n);
    if (o->ready && netpush_standing(&o->push, n)) { /* the socket stands in for the polls */
        octo_push_apply(o);
        return true;
    }
    return octo_start(n, o->ready ? NETDRV_RQ_POLL : NETDRV_RQ_INFO);
}

/* ---- the job's lines ---- */

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

/* netdrv lines: those wholly before OctoPrint's file position; they only rise, and the
   last one counts at DONE. */
static uint64_t
octo_lines(struct netdrv *n, double progress)
{
    struct octo *o = OC(n);
    const struct drv_status *st = &n->base.status;
    if (strcmp(o->last.file, n->job.name) != 0)
        return st->lines_acked; /* another file's position says nothing of ours */
    uint64_t lines = o->last.filepos >= 0 && o->cur
                         ? lines_before(o, o->last.filepos)
                         : (uint64_t)((double)n->job.lines_total * progress);
    if (lines >= n->job.lines_total && n->job.lines_total)
        lines = n->job.lines_total - 1;
    return lines > st->lines_acked ? lines : st->lines_acked;
}

/* The job's progress 0..1 from the last /api/job. */
static double
progress_of(struct octo *o)
{
    const struct octo_job *j = &o->last;
    /* Bytes first: OctoPrint's own docs show "completion" both as a
       percentage (the data model) and as a fraction (the GET /api/job example). */
    double p = j->filepos >= 0 && j->size > 0 ? (double)j->filepos / (double)j->size
               : j->completion >= 0           ? j->completion / 100.0
                                              : o->n.base.status.progress;
    return p > 1 ? 1 : p;
}

static bool
finished(const struct octo_job *j)
{
    return (j->filepos >= 0 && j->size > 0 && j->filepos >= j->size) || j->completion >= 99.9999;
}

/* ---- what a poll means ---- */

/* OctoPrint's state with no job of ours, in netjob's words. */
static void
observe_free(struct octo *o, enum octo_remote r, struct netjob_obs *ob, char *msg, size_t n)
{
    const struct octo_job *j = &o->last;
    if (r == OCTO_R_ERROR) {
        ob->remote = NETJOB_R_HALTED;
        snprintf(msg, n, "OctoPrint: %s%s%s", j->state, j->error[0] ? ": " : "", j->error);
    } else if (r == OCTO_R_IDLE) {
        ob->remote = NETJOB_R_IDLE;
    } else if (r == OCTO_R_PAUSED) {
        ob->remote = NETJOB_R_PAUSED;
    } else {
        ob->remote = NETJOB_R_BUSY;
        snprintf(msg, n, "OctoPrint is busy (%s '%s')", j->state, j->file);
    }
}

/* OctoPrint's state with our job on it, in netjob's words. */
static void
observe_job(struct octo *o, enum octo_remote r, struct netjob_obs *ob, char *msg, size_t n)
{
    const struct octo_job *j = &o->last;
    ob->ours = strcmp(j->file, o->n.job.name) == 0;
    if (r == OCTO_R_ERROR) {
        ob->remote = NETJOB_R_HALTED;
        snprintf(msg, n, "OctoPrint: %s%s%s", j->state, j->error[0] ? ": " : "", j->error);
        return;
    }
    if (ob->ours && r != OCTO_R_IDLE) {
        o->saw_printing = true;
        o->missing_polls = 0;
        ob->remote = r == OCTO_R_PAUSED ? NETJOB_R_PAUSED : NETJOB_R_PRINTING;
        return;
    }
    if (o->n.job.phase == NETJOB_CANCELLING) {
        ob->remote = r == OCTO_R_IDLE ? NETJOB_R_IDLE : NETJOB_R_PRINTING;
        ob->ours = false; /* idle, or on to another file: the cancel is done */
        return;
    }
    if (ob->ours && finished(j)) {
        ob->remote = NETJOB_R_DONE;
        return;
    }
    if (ob->ours && o->saw_printing) {
        ob->remote = NETJOB_R_FAILED;
        snprintf(msg, n, "the print was stopped at the printer at %.0f %%",
                 j->completion >= 0 ? j->completion : 0);
        return;
    }
    if (++o->missing_polls < OCTO_GRACE_POLLS) {
        ob->remote = NETJOB_R_BUSY; /* OctoPrint takes a moment to start a file */
        return;
    }
    if (!ob->ours && r != OCTO_R_IDLE) {
        ob->remote = r == OCTO_R_PAUSED ? NETJOB_R_PAUSED : NETJOB_R_PRINTING;
        return;
    }
    ob->remote = NETJOB_R_FAILED; /* told as ours, to end it with OctoPrint's reason */
    ob->ours = true;
    if (strcmp(j->file, o->n.job.name) != 0)
        snprintf(msg, n, "OctoPrint no longer has the job's file '%s'", o->n.job.name);
    else
        snprintf(msg, n, "OctoPrint did not start the print of '%s'", o->n.job.name);
}

/* The reply to GET /api/printer closes a poll: judge it. */
void
octo_evaluate(struct octo *o)
{
    struct netdrv *n = &o->n;
    const struct octo_job *j = &o->last;
    enum octo_remote r = octo_classify(j->state);
    n->have_last = true;
    if (r == OCTO_R_OFFLINE) {
        char why[160];
        if (n->job.phase != NETJOB_NONE) {
            snprintf(why, sizeof(why), "OctoPrint lost the printer (%s)", j->state);
            netdrv_end_job(n, DRV_IDLE, DRV_EV_JOB_FAILED, why); /* failed, then offline */
        }
        snprintf(why, sizeof(why), "OctoPrint is up, its printer is not connected (%s)", j->state);
        netdrv_contact_lost(n, why);
        return;
    }
    char msg[160] = "";
    struct netjob_obs ob = { .file = j->file, .message = msg };
    if (n->job.phase == NETJOB_NONE)
        observe_free(o, r, &ob, msg, sizeof(msg));
    else
        observe_job(o, r, &ob, msg, sizeof(msg));
    /* OctoPrint's own estimate (progress.printTimeLeft: its estimator, from
       the file's analysis and the progress so far; null until it has one) */
    netdrv_time_left(n, &ob, j->time_left_s);
    netdrv_report(n, &ob, ob.ours ? progress_of(o) : n->base.status.progress);
}

/* ---- replies ---- */

/* A poll's reply (or the version's) is good: else contact is lost, with OctoPrint's reason. */
static bool
reply_ok(struct netdrv *n, int kind, const struct httpc_result *res)
{
    char why[SF_ERR_MSG_MAX];
    if (netdrv_judge(n, kind, res, why, sizeof(why)) == NETDRV_OK)
        return true;
    netdrv_contact_lost(n, why);
    return false;
}

static void
on_version(struct octo *o, const struct httpc_result *res)
{
    struct netdrv *n = &o->n;
    char text[64];
    struct sf_err err;
    if (!reply_ok(n, NETDRV_RQ_INFO, res))
        return;
    if (octo_parse_version(res->body, res->body_len, text, sizeof(text), &err) < 0) {
        netdrv_contact_lost(n, err.msg);
        return;
    }
    snprintf(n->base.caps.firmware, sizeof(n->base.caps.firmware), "%s", text);
    o->ready = true;
    if (!octo_start(n, NETDRV_RQ_POLL)) /* its answer sets the state */
        netdrv_contact_lost(n, "out of memory starting a poll");
}

static void
on_job(struct octo *o, const struct httpc_result *res)
{
    struct netdrv *n = &o->n;
    struct sf_err err;
    if (!reply_ok(n, NETDRV_RQ_POLL, res))
        return;
    if (octo_parse_job(res->body, res->body_len, &o->last, &err) < 0) {
        netdrv_contact_lost(n, err.msg);
        return;
    }
    if (!octo_start(n, RQ_PRINTER))
        netdrv_contact_lost(n, "out of memory starting a poll");
}

void
octo_temps(struct octo *o, const struct octo_printer *p)
{
    if (p->tool_c >= 0)
        netjob_temps(&o->n.base, p->tool_c, p->tool_target_c > 0 ? p->tool_target_c : 0,
                     p->bed_c >= 0 ? p->bed_c : 0, p->bed_target_c > 0 ? p->bed_target_c : 0);
}

static void
on_printer(struct octo *o, const struct httpc_result *res)
{
    struct netdrv *n = &o->n;
    struct octo_printer p;
    struct sf_err err;
    /* 409: the printer is not operational; /api/job says how */
    if (res->code != SF_OK || res->status != 409) {
        if (!reply_ok(n, RQ_PRINTER, res))
            return;
        if (octo_parse_printer(res->body, res->body_len, &p, &err) < 0) {
            netdrv_contact_lost(n, err.msg);
            return;
        }
        octo_temps(o, &p);
        snprintf(o->peer_ip, sizeof(o->peer_ip), "%s", res->peer_ip ? res->peer_ip : "");
    }
    o->push.dirty = false; /* a poll's answer is as new as anything the socket said before */
    n->fails = 0;
    int period = netdrv_period(n);
    netdrv_schedule(n, period);
    uint64_t next = n->timer;
    /* An action asked meanwhile goes first (kick): this poll began before it, so it says
       nothing of what the action did; the action's answer polls again. */
    if (n->want == NETDRV_RQ_NONE)
        octo_evaluate(o);
    /* The judgement moved the printer between working and waiting: the next poll at the new
       state's rate, unless the judgement set its own. */
    if (next && n->timer == next && netdrv_period(n) != period)
        netdrv_schedule(n, netdrv_period(n));
}

/* OctoPrint took the job and prints it: the polls say how it goes. */
static void
print_started(struct octo *o)
{
    o->n.fails = 0;
    o->missing_polls = 0;
    o->n.base.status.message[0] = 0;
    netdrv_schedule(&o->n, 0);
}

/* The upload or select+print failed (why): contact lost (oc) or refused, the job fails. */
static void
start_failed(struct octo *o, enum netdrv_outcome oc, const char *prefix, const char *why)
{
    char msg[SF_ERR_MSG_MAX + 64];
    if (oc == NETDRV_DOWN || oc == NETDRV_AUTH) {
        /* failed first, then offline: the farm takes a printer going offline
           with a job as the job interrupted, not failed */
        snprintf(msg, sizeof(msg), "upload failed: %s", why);
        netdrv_end_job(&o->n, DRV_IDLE, DRV_EV_JOB_FAILED, msg);
        netdrv_contact_lost(&o->n, why);
        return;
    }
    snprintf(msg, sizeof(msg), "%s%s", prefix, why);
    netdrv_end_job(&o->n, DRV_IDLE, DRV_EV_JOB_FAILED, msg);
    netdrv_schedule(&o->n, 0);
}

static void
on_upload(struct octo *o, const struct httpc_result *res)
{
    struct netdrv *n = &o->n;
    char why[SF_ERR_MSG_MAX], name[128];
    bool printing = false;
    struct sf_err err;
    enum netdrv_outcome oc = netdrv_judge(n, NETDRV_RQ_UPLOAD, res, why, sizeof(why));
    if (n->job.phase != NETJOB_RUNNING) /* cancelled meanwhile */
        return;
    if (oc == NETDRV_OK)
        oc =
            parsed(octo_parse_upload(res->body, res->body_len, &printing, name, sizeof(name), &err),
                   &err, why, sizeof(why));
    if (oc != NETDRV_OK) {
        start_failed(o, oc, "upload refused: ", why);
        return;
    }
    if (printing) {
        print_started(o);
        return;
    }
    /* Stored, not started (OctoPrint drops print=true when it cannot start):
       ask explicitly, which says why if it refuses. */
    if (!octo_start(n, RQ_SELECT))
        start_failed(o, NETDRV_REFUSED, "", "out of memory asking OctoPrint to print");
}

static void
on_select(struct octo *o, const struct httpc_result *res)
{
    char why[SF_ERR_MSG_MAX];
    enum netdrv_outcome oc = netdrv_judge(&o->n, RQ_SELECT, res, why, sizeof(why));
    if (o->n.job.phase != NETJOB_RUNNING)
        return;
    if (oc == NETDRV_OK)
        print_started(o);
    else
        start_failed(o, oc, "OctoPrint did not start the print: ", why);
}

static void
on_command(struct octo *o, const struct httpc_result *res)
{
    char why[SF_ERR_MSG_MAX];
    enum netdrv_outcome oc = netdrv_judge(&o->n, RQ_COMMAND, res, why, sizeof(why));
    if (oc == NETDRV_DOWN || oc == NETDRV_AUTH)
        netdrv_contact_lost(&o->n, why);
    else if (oc != NETDRV_OK)
        log_printer(LOG_WARN, o->n.base.name, "command refused: %s", why);
}

static void
octo_reply(struct netdrv *n, int kind, const struct httpc_result *res)
{
    static const struct {
        int kind;
        void (*fn)(struct octo *o, const struct httpc_result *res);
    } own[] = {
        { NETDRV_RQ_INFO, on_version },      { NETDRV_RQ_POLL, on_job }, { RQ_PRINTER, on_printer },
        { NETDRV_RQ_UPLOAD, on_upload },     { RQ_SELECT, on_select },   { RQ_COMMAND, on_command },
        { RQ_LOGIN, octo_push_login_reply },
    };
    for (size_t i = 0; i < sizeof(own) / sizeof(own[0]); i++)
        if (own[i].kind == kind) {
            own[i].fn(OC(n), res);
            return;
        }
    netdrv_action_reply(n, kind, res); /* pause, resume, cancel */
}

/* Send what waits (an action, then a manual command) if the slot is free. */
static void
octo_kick(struct netdrv *n)
{
    struct octo *o = OC(n);
    if (!netdrv_send_want(n))
        return;
    if (o->want_cmd) {
        o->want_cmd = false;
        octo_start(n, RQ_COMMAND); /* logged if it could not start */
        return;
    }
    if (o->ready && n->have_last)
        octo_push_kick(o); /* the login, the socket */
    if (!n->req)
        octo_push_apply(o); /* what the socket said while the slot was taken */
}

/* The job ended: its file is read no more. */
static void
octo_forget(struct netdrv *n)
{
    struct octo *o = OC(n);
    cursor_close(o);
    o->saw_printing = false;
    o->missing_polls = 0;
}

/* Contact lost, or a new connection: ask /api/version first; a command waiting is dropped. */
static void
octo_lost(struct netdrv *n)
{
    struct octo *o = OC(n);
    octo_push_close(o, NULL);
    o->ready = false;
    o->want_cmd = false;
    o->auth[0] = '\0';   /* a new session after a new contact */
    o->no_login = false; /* the server may have changed (an upgrade): ask again */
}

/* ---- drv_ops ---- */

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
    int rc = netdrv_start_job(d, gcode_path, 0, scan, err);
    if (rc == SF_OK)
        cursor_open(o, o->n.path);
    return rc;
}

static int
octo_command(struct drv *d, const char *line, struct sf_err *err)
{
    struct octo *o = (struct octo *)d;
    if (!o->n.open || !o->ready)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is not connected", d->name);
    if (o->want_cmd || o->n.rq == RQ_COMMAND)
        return sf_err_set(err, SF_EAGAIN, "printer '%s': the last command is still on its way",
                          d->name);
    snprintf(o->cmd, sizeof(o->cmd), "%s", line ? line : "");
    o->want_cmd = true;
    netdrv_preempt_poll(&o->n);
    octo_kick(&o->n);
    return SF_OK;
}

static int
octo_attach(struct drv *d, const char *gcode_path, const struct drv_job_scan *scan,
            struct sf_err *err)
{
    struct octo *o = (struct octo *)d;
    struct netjob j;
    int rc = netdrv_attach_prepare(&o->n, gcode_path, scan, &j, err);
    if (rc)
        return rc;
    const struct octo_job *last = &o->last;
    if (strcmp(last->file, j.name) != 0 || last->size != j.size)
        return sf_err_set(err, SF_ENOTFOUND,
                          "printer '%s': OctoPrint's job is '%s' (%lld bytes), not the farm's "
                          "'%s' (%lld bytes)",
                          d->name, last->file[0] ? last->file : "none", (long long)last->size,
                          j.name, (long long)j.size);
    enum octo_remote r = octo_classify(last->state);
    cursor_open(o, o->n.path);
    o->saw_printing = true; /* it printed this before the daemon went away */
    o->missing_polls = 0;
    log_printer(LOG_INFO, d->name, "re-attached to '%s' at %.0f %% (%s)", j.name,
                progress_of(o) * 100, last->state);
    /* The next poll tells how it goes on (or that it ended meanwhile). */
    struct netjob_obs ob = { .remote = r == OCTO_R_PAUSED ? NETJOB_R_PAUSED : NETJOB_R_PRINTING,
                             .ours = true,
                             .file = last->file };
    netdrv_adopt(&o->n, &j, &ob, progress_of(o));
    netdrv_schedule(&o->n, 0);
    return SF_OK;
}

static void
octo_destroy(struct drv *d)
{
    struct octo *o = (struct octo *)d;
    octo_push_close(o, NULL);
    cursor_close(o);
    free(o->cur_buf);
    netdrv_destroy(d);
}

static const struct drv_ops octo_ops = {
    .version = DRV_OPS_VERSION,
    .kind = "octoprint",
    .open = netdrv_open,
    .start_job = octo_start_job,
    .pause = netdrv_pause,
    .resume = netdrv_resume,
    .cancel = netdrv_cancel,
    .command = octo_command,
    .close = netdrv_close,
    .destroy = octo_destroy,
    .attach = octo_attach,
};

static const struct netdrv_ops octo_nops = {
    .product = "OctoPrint",
    .key_hint = "check api_key",
    .poll_ms = OCTO_POLL_MS,
    .job_tries = 1,    /* a failed contact: offline at once, the job left to attach() */
    .upload_tries = 1, /* a failed upload fails the job: the farm's retry sends it again */
    .timeout_ms = 10000,
    .upload_stall_ms = 60000,
    .start_rq = RQ_SELECT,
    .start = octo_start,
    .poll = octo_poll,
    .reply = octo_reply,
    .kick = octo_kick,
    .error_text = octo_reason,
    .forget = octo_forget,
    .lost = octo_lost,
    .judge = octo_judge,
    .lines = octo_lines,
    .side_rq = RQ_LOGIN,
    .poll_rq = RQ_PRINTER,
};

struct drv *
drv_octoprint_new(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event, void *ud,
                  struct sf_err *err)
{
    const char *name = cfg->name ? cfg->name : "?";
    if (!cfg->api_key || !cfg->api_key[0]) {
        sf_err_set(err, SF_EINVAL, "printer '%s': octoprint needs an api_key", name);
        return NULL;
    }
    struct octo *o = mem_calloc(1, sizeof(*o));
    if (!o) {
        sf_err_set(err, SF_ENOMEM, "printer '%s': out of memory", name);
        return NULL;
    }
    if (netdrv_init(&o->n, l, cfg, &octo_ops, &octo_nops, on_event, ud, err)) {
        free(o);
        return NULL;
    }
    o->hdrs[0] = o->n.key_hdr;
    o->json_hdrs[0] = o->n.key_hdr;
    o->json_hdrs[1] = "Content-Type: application/json";
    snprintf(o->n.base.caps.firmware, sizeof(o->n.base.caps.firmware), "OctoPrint");
    return &o->n.base;
}
