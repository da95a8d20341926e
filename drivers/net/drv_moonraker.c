/*
 * drv_moonraker.c - Klipper through Moonraker (drv_moonraker.h).
 *
 * This part reads Moonraker's replies: the object query the driver polls,
 * /server/info, the upload's answer and error bodies, each checked against
 * the documented shape (docs/external_api/ (server, printer, file_manager), docs/printer_objects.md
 * of Arksine/moonraker v0.10.0-31) with a message naming the field that is wrong, and the mapping
 * of Klipper's states onto netjob's words.
 *
 * Thread: the parsers are pure; the driver runs on the loop thread.
 */
#include "drv_moonraker.h"

#include <jansson.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/base/log.h"
#include "../../src/base/mem.h"
#include "drv_moonraker_int.h"
#include "netdrv.h"

/* ---- JSON helpers: field access that names what is wrong ---- */

#define WHO "moonraker"

static json_t *
load(const char *body, size_t len, const char *what, struct sf_err *err)
{
    return netdrv_json_load(WHO, body, len, what, false, err);
}

/* root.result if the reply is wrapped, else root. */
static json_t *
unwrap(json_t *root)
{
    json_t *r = json_object_get(root, "result");
    return r ? r : root;
}

static int
get_str(json_t *obj, const char *key, const char *where, char *out, size_t n, bool required,
        struct sf_err *err)
{
    return netdrv_json_str(WHO, obj, key, where, out, n, required, err);
}

static int
get_num(json_t *obj, const char *key, const char *where, double *out, struct sf_err *err)
{
    return netdrv_json_num(WHO, obj, key, where, out, false, err);
}

static int
get_int(json_t *obj, const char *key, const char *where, int64_t *out, struct sf_err *err)
{
    return netdrv_json_int(WHO, obj, key, where, out, false, err);
}

static int
get_bool(json_t *obj, const char *key, const char *where, bool *out, struct sf_err *err)
{
    json_t *v = json_object_get(obj, key);
    if (!v)
        return sf_err_set(err, SF_EINVAL, "moonraker %s.%s: missing", where, key);
    if (!json_is_boolean(v))
        return sf_err_set(err, SF_EINVAL, "moonraker %s.%s: not a boolean", where, key);
    *out = json_is_true(v);
    return SF_OK;
}

static json_t *
get_obj(json_t *obj, const char *key, const char *where, bool required, struct sf_err *err)
{
    json_t *v = json_object_get(obj, key);
    if (v && json_is_object(v))
        return v;
    if (v || required)
        sf_err_set(err, SF_EINVAL, "moonraker %s.%s: %s", where, key,
                   v ? "not an object" : "missing");
    return NULL;
}

/* status.key into *out if it is there (NULL if not); SF_EINVAL if it is not an object. */
static int
opt_obj(json_t *status, const char *key, json_t **out, struct sf_err *err)
{
    return netdrv_json_obj(WHO, status, key, "status", out, err);
}

/* ---- parsers ---- */

int
drv_moonraker_parse_status(const char *body, size_t len, struct moonraker_status *st,
                           struct sf_err *err)
{
    memset(st, 0, sizeof(*st));
    json_t *root = load(body, len, "objects query", err);
    if (!root)
        return SF_EINVAL;
    int rc = SF_EINVAL;
    json_t *status = get_obj(unwrap(root), "status", "result", true, err);
    json_t *wh = status ? get_obj(status, "webhooks", "status", true, err) : NULL;
    json_t *ps = wh ? get_obj(status, "print_stats", "status", true, err) : NULL;
    if (!ps)
        goto out;
    if ((rc = get_str(wh, "state", "webhooks", st->klippy, sizeof(st->klippy), true, err)) ||
        (rc = get_str(wh, "state_message", "webhooks", st->klippy_message,
                      sizeof(st->klippy_message), false, err)) ||
        (rc = get_str(ps, "state", "print_stats", st->state, sizeof(st->state), true, err)) ||
        (rc = get_str(ps, "filename", "print_stats", st->filename, sizeof(st->filename), false,
                      err)) ||
        (rc =
             get_str(ps, "message", "print_stats", st->message, sizeof(st->message), false, err)) ||
        (rc = get_num(ps, "print_duration", "print_stats", &st->print_duration_s, err)))
        goto out;
    json_t *vs, *ex, *bed;
    if ((rc = opt_obj(status, "virtual_sdcard", &vs, err)) ||
        (rc = opt_obj(status, "extruder", &ex, err)) ||
        (rc = opt_obj(status, "heater_bed", &bed, err)))
        goto out;
    if (vs && ((rc = get_num(vs, "progress", "virtual_sdcard", &st->progress, err)) ||
               (rc = get_int(vs, "file_position", "virtual_sdcard", &st->file_position, err)) ||
               (rc = get_int(vs, "file_size", "virtual_sdcard", &st->file_size, err))))
        goto out;
    if (ex && ((rc = get_num(ex, "temperature", "extruder", &st->nozzle_c, err)) ||
               (rc = get_num(ex, "target", "extruder", &st->nozzle_target_c, err))))
        goto out;
    if (bed && ((rc = get_num(bed, "temperature", "heater_bed", &st->bed_c, err)) ||
                (rc = get_num(bed, "target", "heater_bed", &st->bed_target_c, err))))
        goto out;
    if (st->progress < 0 || st->progress > 1) {
        rc = sf_err_set(err, SF_EINVAL, "moonraker virtual_sdcard.progress: %g is not in 0..1",
                        st->progress);
        goto out;
    }
    rc = SF_OK;
out:
    json_decref(root);
    return rc;
}

int
drv_moonraker_parse_info(const char *body, size_t len, char *state, size_t n, struct sf_err *err)
{
    json_t *root = load(body, len, "server info", err);
    if (!root)
        return SF_EINVAL;
    json_t *res = json_object_get(root, "result");
    int rc = res && json_is_object(res)
                 ? get_str(res, "klippy_state", "result", state, n, true, err)
                 : sf_err_set(err, SF_EINVAL, "moonraker server info: no result object");
    json_decref(root);
    return rc;
}

int
drv_moonraker_parse_upload(const char *body, size_t len, struct moonraker_upload *up,
                           struct sf_err *err)
{
    memset(up, 0, sizeof(*up));
    json_t *root = load(body, len, "upload", err);
    if (!root)
        return SF_EINVAL;
    int rc = SF_EINVAL;
    json_t *r = unwrap(root);
    json_t *item = json_is_object(r) ? get_obj(r, "item", "upload", true, err) : NULL;
    if (!item) {
        if (!json_is_object(r))
            sf_err_set(err, SF_EINVAL, "moonraker upload: not an object");
        goto out;
    }
    if ((rc = get_str(item, "path", "item", up->path, sizeof(up->path), true, err)) ||
        (rc = get_int(item, "size", "item", &up->size, err)) ||
        (rc = get_bool(r, "print_started", "upload", &up->print_started, err)))
        goto out;
    /* print_queued came with the job queue (API 1.1); older servers lack it */
    if (json_object_get(r, "print_queued"))
        rc = get_bool(r, "print_queued", "upload", &up->print_queued, err);
out:
    json_decref(root);
    return rc;
}

int
drv_moonraker_parse_meta(const char *body, size_t len, struct moonraker_meta *m, struct sf_err *err)
{
    memset(m, 0, sizeof(*m));
    m->estimated_s = -1;
    json_t *root = load(body, len, "file metadata", err);
    if (!root)
        return SF_EINVAL;
    json_t *r = json_object_get(root, "result");
    int rc;
    if (!r || !json_is_object(r)) {
        rc = sf_err_set(err, SF_EINVAL, "moonraker file metadata: no result object");
        goto out;
    }
    if ((rc = netdrv_json_num(WHO, r, "modified", "result", &m->modified, true, err)) ||
        (rc = netdrv_json_int(WHO, r, "size", "result", &m->size, true, err)) ||
        (rc = get_num(r, "estimated_time", "result", &m->estimated_s, err)))
        goto out;
    if (m->estimated_s < 0)
        m->estimated_s = -1;
out:
    json_decref(root);
    return rc;
}

int
drv_moonraker_parse_history(const char *body, size_t len, const char *filename, double since,
                            struct moonraker_hist *h, struct sf_err *err)
{
    memset(h, 0, sizeof(*h));
    h->size = -1;
    json_t *root = load(body, len, "history list", err);
    if (!root)
        return SF_EINVAL;
    int rc = SF_EINVAL;
    json_t *r = json_object_get(root, "result");
    json_t *jobs = r && json_is_object(r) ? json_object_get(r, "jobs") : NULL;
    if (!jobs || !json_is_array(jobs)) {
        sf_err_set(err, SF_EINVAL, "moonraker history list: %s",
                   r && json_is_object(r) ? "result.jobs: missing or not a list"
                                          : "no result object");
        goto out;
    }
    size_t i;
    json_t *job;
    json_array_foreach(jobs, i, job)
    {
        char where[32], name[256], status[24];
        double start = 0, end = 0;
        snprintf(where, sizeof(where), "jobs[%zu]", i);
        if (!json_is_object(job)) {
            sf_err_set(err, SF_EINVAL, "moonraker history %s: not an object", where);
            goto out;
        }
        if ((rc = get_str(job, "filename", where, name, sizeof(name), true, err)) ||
            (rc = get_str(job, "status", where, status, sizeof(status), true, err)) ||
            (rc = netdrv_json_num(WHO, job, "start_time", where, &start, true, err)))
            goto out;
        json_t *e = json_object_get(job, "end_time"); /* null while in progress */
        if (e && !json_is_null(e) && (rc = get_num(job, "end_time", where, &end, err)))
            goto out;
        rc = SF_EINVAL;
        if (strcmp(name, filename) != 0 || start < since || (h->found && start <= h->start_time))
            continue;
        h->found = true;
        snprintf(h->status, sizeof(h->status), "%s", status);
        h->start_time = start;
        h->end_time = end;
        h->size = -1;
        json_t *md = json_object_get(job, "metadata");
        json_t *sz = md && json_is_object(md) ? json_object_get(md, "size") : NULL;
        if (sz && json_is_integer(sz))
            h->size = (int64_t)json_integer_value(sz);
    }
    rc = SF_OK;
out:
    json_decref(root);
    return rc;
}

double
drv_moonraker_time_left(const struct moonraker_status *st, double estimated_s)
{
    double d = st->print_duration_s;
    if (estimated_s > 0 && d > 0 && estimated_s > d)
        return estimated_s - d; /* Mainsail's "slicer" */
    if (d > 0 && st->progress > 0)
        return d / st->progress - d; /* Mainsail's "file" */
    return -1;
}

void
drv_moonraker_error_text(const char *body, size_t len, char *out, size_t n)
{
    out[0] = '\0';
    if (n == 0)
        return;
    json_t *root = json_loadb(body, len, 0, NULL);
    json_t *e = root ? json_object_get(root, "error") : NULL;
    json_t *m = e && json_is_string(e) ? e : e ? json_object_get(e, "message") : NULL;
    if (m &&
        json_is_string(m)) { /* Moonraker's {"error": {"message"}}; a proxy's {"error": "..."} */
        snprintf(out, n, "%s", json_string_value(m));
        json_decref(root);
        return;
    }
    json_decref(root);
    /* not the documented shape (a proxy's page): its first non-blank line */
    netdrv_first_line(body, len, out, n);
}

void
drv_moonraker_observe(const struct moonraker_status *st, const char *job_name, int64_t job_size,
                      struct netjob_obs *o)
{
    memset(o, 0, sizeof(*o));
    o->file = st->filename;
    o->message = st->message;
    o->ours = job_name && job_name[0] && strcmp(st->filename, job_name) == 0 &&
              (job_size <= 0 || st->file_size == 0 || st->file_size == job_size);
    if (strcmp(st->klippy, "ready") != 0) {
        /* startup, shutdown, error (and anything newer): the host first */
        o->message = st->klippy_message;
        o->remote = strcmp(st->klippy, "startup") == 0 ? NETJOB_R_STARTING : NETJOB_R_HALTED;
        return;
    }
    static const struct {
        const char *name;
        enum netjob_remote r;
    } map[] = {
        { "standby", NETJOB_R_IDLE },        { "printing", NETJOB_R_PRINTING },
        { "paused", NETJOB_R_PAUSED },       { "complete", NETJOB_R_DONE },
        { "cancelled", NETJOB_R_CANCELLED }, { "error", NETJOB_R_FAILED },
    };
    o->remote = NETJOB_R_BUSY; /* a state newer than this driver: send it nothing */
    for (size_t i = 0; i < sizeof(map) / sizeof(map[0]); i++)
        if (strcmp(st->state, map[i].name) == 0)
            o->remote = map[i].r;
}

/* ---- the driver (its state and how it talks: drv_moonraker_int.h) ---- */

static const char *const own_names[] = { "print start", "gcode script", "file metadata", "history",
                                         "emergency stop" };

static struct moonraker *
MR(struct netdrv *n)
{
    return (struct moonraker *)n;
}

static const char *
rq_name(int kind)
{
    return netdrv_rq_name(kind, own_names, sizeof(own_names) / sizeof(own_names[0]));
}

/* POST or GET path (body: JSON, or NULL) in the free slot. */
static bool
send_req(struct moonraker *m, int kind, const char *method, const char *path, const char *body)
{
    char url[512];
    snprintf(url, sizeof(url), "%s%s", m->n.url, path);
    struct httpc_opts o = { .method = method,
                            .url = url,
                            .headers = body ? m->json_hdrs : m->hdrs,
                            .body = body,
                            .body_len = body ? strlen(body) : 0 };
    if (kind == NETDRV_RQ_UPLOAD) {
        /* POST /server/files/upload, multipart/form-data: the file
           streamed from disk, root and print=true (file_manager.md) */
        struct httpc_part up[3] = {
            { .name = "file",
              .file_path = m->n.path,
              .filename = m->n.job.name,
              .type = "application/octet-stream" },
            { .name = "root", .value = "gcodes" },
            { .name = "print", .value = "true" },
        };
        o.parts = up;
        o.n_parts = 3;
        return netdrv_request(&m->n, kind, &o); /* httpc_start copies the parts */
    }
    return netdrv_request(&m->n, kind, &o);
}

/* POST path with {key: value}. */
static bool
send_json(struct moonraker *m, int kind, const char *path, const char *key, const char *value)
{
    json_t *b = json_pack("{s:s}", key, value);
    char *body = b ? json_dumps(b, JSON_COMPACT) : NULL;
    json_decref(b);
    bool ok = body && send_req(m, kind, "POST", path, body);
    free(body);
    return ok;
}

static bool
mr_start(struct netdrv *n, int kind)
{
    struct moonraker *m = MR(n);
    switch (kind) {
    case NETDRV_RQ_UPLOAD:
        return send_req(m, kind, "POST", "/server/files/upload", NULL);
    case NETDRV_RQ_PAUSE:
        return send_req(m, kind, "POST", "/printer/print/pause", NULL);
    case NETDRV_RQ_RESUME:
        return send_req(m, kind, "POST", "/printer/print/resume", NULL);
    case NETDRV_RQ_CANCEL:
        return send_req(m, kind, "POST", "/printer/print/cancel", NULL);
    case RQ_META: {
        char path[256];
        snprintf(path, sizeof(path), "/server/files/metadata?filename=%s", m->meta_name);
        return send_req(m, kind, "GET", path, NULL);
    }
    case RQ_HISTORY: {
        /* the entries created since the file was written, newest first */
        char path[160];
        snprintf(path, sizeof(path), "/server/history/list?limit=50&order=desc&since=%.3f",
                 m->meta.modified - 1);
        return send_req(m, kind, "GET", path, NULL);
    }
    default:
        return false;
    }
}

/* Ask for name's metadata when the slot is free (our remote names need no escaping). */
static void
want_meta(struct moonraker *m, const char *name)
{
    snprintf(m->meta_name, sizeof(m->meta_name), "%s", name);
    m->meta_known = m->meta_found = false;
    m->want_meta = true;
}

static bool
mr_poll(struct netdrv *n)
{
    struct moonraker *m = MR(n);
    if (!m->ready)
        return send_req(m, NETDRV_RQ_INFO, "GET", "/server/info", NULL);
    if (netpush_standing(&m->push, n)) { /* the socket's updates stand in for the polls */
        drv_moonraker_ws_apply(m);
        return true;
    }
    return send_req(m, NETDRV_RQ_POLL, "GET",
                    "/printer/objects/query?webhooks&print_stats&virtual_sdcard"
                    "&extruder&heater_bed&display_status",
                    NULL);
}

void
drv_moonraker_seen(struct moonraker *m, const struct moonraker_status *stp, bool pushed)
{
    struct netdrv *n = &m->n;
    struct moonraker_status st = *stp;
    if (!pushed)
        m->push.dirty = false; /* a poll's answer is as new as anything the socket said before it */
    n->fails = 0;
    m->last = st;
    n->have_last = true;
    netjob_temps(&n->base, st.nozzle_c, st.nozzle_target_c, st.bed_c, st.bed_target_c);
    struct netjob_obs ob;
    drv_moonraker_observe(&st, n->job.name, n->job.size, &ob);
    if (netdrv_settle(n, &ob))
        return;
    /* the time left as Mainsail tells it (drv_moonraker_time_left): the
       slicer's estimate from the file's metadata, asked once per job */
    bool meta = m->meta_found && strcmp(m->meta_name, st.filename) == 0;
    netdrv_time_left(n, &ob,
                     ob.ours ? drv_moonraker_time_left(&st, meta ? m->meta.estimated_s : -1) : -1);
    if (ob.ours && n->job.phase != NETJOB_NONE && strcmp(m->meta_name, st.filename) != 0)
        want_meta(m, st.filename);
    netdrv_report(n, &ob, st.progress);
    /* Klippy restarting: /server/info tells when it is back (docs: every 2 s) */
    if (ob.remote == NETJOB_R_STARTING) {
        m->ready = false;
        if (!m->push.ws || m->push.live) /* one held waits for notify_klippy_ready */
            drv_moonraker_ws_close(m, NULL);
        netdrv_schedule(n, MR_STARTUP_MS);
    } else if (!pushed) {
        netdrv_schedule(n, netdrv_period(n));
    }
}

static void
on_poll(struct moonraker *m, const struct httpc_result *res)
{
    struct netdrv *n = &m->n;
    char why[200];
    if (netdrv_judge(n, NETDRV_RQ_POLL, res, why, sizeof(why)) != NETDRV_OK) {
        netdrv_contact_lost(n, why);
        return;
    }
    struct moonraker_status st;
    struct sf_err err;
    if (drv_moonraker_parse_status(res->body, res->body_len, &st, &err)) {
        netdrv_contact_lost(n, err.msg);
        return;
    }
    drv_moonraker_seen(m, &st, false);
    drv_moonraker_ws_open(m, res->peer_ip); /* a push socket, if there is none */
}

static void
on_info(struct moonraker *m, const struct httpc_result *res)
{
    struct netdrv *n = &m->n;
    char why[200];
    char state[32];
    struct sf_err err;
    if (netdrv_judge(n, NETDRV_RQ_INFO, res, why, sizeof(why)) != NETDRV_OK) {
        netdrv_contact_lost(n, why);
        return;
    }
    if (drv_moonraker_parse_info(res->body, res->body_len, state, sizeof(state), &err)) {
        netdrv_contact_lost(n, err.msg);
        return;
    }
    if (strcmp(state, "startup") == 0) {
        n->fails = 0;
        if (n->job.phase == NETJOB_NONE)
            netjob_state(&n->base, DRV_CONNECTING, "Klipper is starting");
        netdrv_schedule(n, MR_STARTUP_MS);
        return;
    }
    if (strcmp(state, "disconnected") == 0) {
        netdrv_contact_lost(n, "Moonraker runs but Klipper is not connected to it");
        return;
    }
    /* ready, shutdown, error: the object query says the rest (webhooks) */
    snprintf(n->base.caps.firmware, sizeof(n->base.caps.firmware), "Klipper (Moonraker)");
    m->ready = true;
    drv_moonraker_ws_klippy_ready(m);
    netdrv_schedule(n, 0);
}

static void
on_upload(struct moonraker *m, const struct httpc_result *res)
{
    struct netdrv *n = &m->n;
    if (netdrv_upload_reply(n, res) != NETDRV_OK)
        return;
    struct moonraker_upload up;
    struct sf_err err;
    if (drv_moonraker_parse_upload(res->body, res->body_len, &up, &err)) {
        snprintf(n->upload_err, sizeof(n->upload_err), "upload: %s", err.msg);
        n->verify = true;
        netdrv_schedule(n, 0);
        return;
    }
    if (up.print_started) {
        netdrv_schedule(n, 0);
        return;
    }
    if (up.print_queued) {
        netdrv_end_job(n, DRV_IDLE, DRV_EV_JOB_FAILED,
                       "Moonraker queued the file instead of printing it (turn off [file_manager] "
                       "queue_gcode_uploads for a farm printer)");
        netdrv_schedule(n, 0);
        return;
    }
    /* stored but not started (OrcaSlicer's case): start it by name */
    if (!send_json(m, RQ_START, "/printer/print/start", "filename",
                   up.path[0] ? up.path : n->job.name)) {
        netdrv_end_job(n, DRV_IDLE, DRV_EV_JOB_FAILED,
                       "could not ask the printer to start the file");
        netdrv_schedule(n, 0);
    }
}

/* The answer to print start or a manual command. */
static void
on_own(struct moonraker *m, int kind, const struct httpc_result *res)
{
    struct netdrv *n = &m->n;
    char why[200];
    enum netdrv_outcome o = netdrv_answered(n, kind, res, why, sizeof(why));
    if (o == NETDRV_OK)
        return;
    log_printer(LOG_WARN, n->base.name, "%s: %s", rq_name(kind), why);
    if (kind == RQ_START && n->job.phase == NETJOB_RUNNING && o != NETDRV_DOWN) {
        netdrv_end_job(n, DRV_IDLE, DRV_EV_JOB_FAILED, why); /* "SD busy" */
        netdrv_schedule(n, 0);
        return;
    }
    if (kind == RQ_START && n->job.phase == NETJOB_RUNNING) {
        snprintf(n->upload_err, sizeof(n->upload_err), "print start failed: %s", why);
        n->verify = true;
    }
    if (kind == RQ_GCODE)
        snprintf(n->base.status.message, sizeof(n->base.status.message), "command failed: %s", why);
    if (o == NETDRV_DOWN || o == NETDRV_AUTH)
        netdrv_contact_lost(n, why);
    else
        netdrv_schedule(n, 0);
}

/* The history look-up of hist_name ends (hist_why: why it could not tell, or ""). */
static void
hist_answered(struct moonraker *m, const char *why)
{
    m->hist_state = H_ANSWERED;
    snprintf(m->hist_why, sizeof(m->hist_why), "%s", why);
}

static void
on_meta(struct moonraker *m, const struct httpc_result *res)
{
    struct netdrv *n = &m->n;
    char why[200];
    enum netdrv_outcome o = netdrv_judge(n, RQ_META, res, why, sizeof(why));
    if (o == NETDRV_DOWN || o == NETDRV_AUTH) {
        netdrv_contact_lost(n, why);
        return;
    }
    struct sf_err err;
    m->meta_known = true;
    m->meta_found = o == NETDRV_OK &&
                    drv_moonraker_parse_meta(res->body, res->body_len, &m->meta, &err) == SF_OK;
    if (o == NETDRV_OK && !m->meta_found)
        log_printer(LOG_WARN, n->base.name, "%s", err.msg);
    if (m->hist_state == H_ASKING && strcmp(m->hist_name, m->meta_name) == 0) {
        if (!m->meta_found) {
            hist_answered(m, o == NETDRV_OK ? err.msg : "the file is no longer on the printer");
        } else if (mr_start(n, RQ_HISTORY)) {
            return;
        } else {
            hist_answered(m, "could not ask Moonraker's job history");
        }
    }
    netdrv_schedule(n, 0);
}

static void
on_history(struct moonraker *m, const struct httpc_result *res)
{
    struct netdrv *n = &m->n;
    char why[200];
    enum netdrv_outcome o = netdrv_judge(n, RQ_HISTORY, res, why, sizeof(why));
    if (o == NETDRV_DOWN || o == NETDRV_AUTH) {
        netdrv_contact_lost(n, why);
        return;
    }
    struct sf_err err;
    if (o != NETDRV_OK) {
        char msg[260];
        snprintf(msg, sizeof(msg), "Moonraker keeps no job history (%s)", why);
        hist_answered(m, msg);
    } else if (drv_moonraker_parse_history(res->body, res->body_len, m->hist_name,
                                           m->meta.modified - 1, &m->hist, &err)) {
        hist_answered(m, err.msg);
    } else {
        hist_answered(m, "");
    }
    netdrv_schedule(n, 0);
}

static void
mr_reply(struct netdrv *n, int kind, const struct httpc_result *res)
{
    struct moonraker *m = MR(n);
    switch (kind) {
    case NETDRV_RQ_INFO:
        on_info(m, res);
        break;
    case NETDRV_RQ_POLL:
        on_poll(m, res);
        break;
    case NETDRV_RQ_UPLOAD:
        on_upload(m, res);
        break;
    case RQ_START:
    case RQ_GCODE:
    case RQ_ESTOP:
        on_own(m, kind, res);
        break;
    case RQ_META:
        on_meta(m, res);
        break;
    case RQ_HISTORY:
        on_history(m, res);
        break;
    default:
        netdrv_action_reply(n, kind, res);
        break;
    }
}

/* Send what waits (an action, then manual commands) if the slot is free. */
static void
mr_kick(struct netdrv *n)
{
    struct moonraker *m = MR(n);
    if (!netdrv_send_want(n))
        return;
    if (m->want_estop) {
        /* Klipper's own emergency stop (the webhook): at once, not queued behind G-code as an
           M112 script would be; what else waited is dropped */
        m->want_estop = false;
        m->script_len = 0;
        send_req(m, RQ_ESTOP, "POST", "/printer/emergency_stop", NULL);
        return;
    }
    if (m->script_len > 0) {
        m->script[m->script_len] = '\0';
        m->script_len = 0;
        send_json(m, RQ_GCODE, "/printer/gcode/script", "script", m->script);
        return;
    }
    if (m->want_meta) {
        m->want_meta = false;
        mr_start(n, RQ_META);
        return;
    }
    drv_moonraker_ws_apply(m); /* what the socket said while the slot was taken */
}

static void
mr_lost(struct netdrv *n)
{
    struct moonraker *m = MR(n);
    drv_moonraker_ws_close(m, NULL);
    m->ready = false;
    m->want_meta = false;
    m->meta_name[0] = '\0';
    m->hist_state = H_NONE; /* a look-up cut short is asked again */
}

/* ---- drv_ops ---- */

static int
mr_attach(struct drv *d, const char *gcode_path, const struct drv_job_scan *scan,
          struct sf_err *err)
{
    struct moonraker *m = (struct moonraker *)d;
    struct netjob j;
    int rc = netdrv_attach_prepare(&m->n, gcode_path, scan, &j, err);
    if (rc)
        return rc;
    /* print_stats keeps the last job's file and end state until the next
       one (Klipper's docs), so a print that ended while we were away still
       says how it ended */
    struct netjob_obs ob;
    drv_moonraker_observe(&m->last, j.name, j.size, &ob);
    if (ob.ours) {
        log_printer(LOG_INFO, d->name, "re-attached to '%s', which the printer still knows (%s)",
                    j.name, m->last.state);
        netdrv_adopt(&m->n, &j, &ob, m->last.progress);
        return SF_OK;
    }
    if (ob.remote == NETJOB_R_STARTING || ob.remote == NETJOB_R_HALTED)
        return sf_err_set(err, SF_EAGAIN, "printer '%s': Klipper is %s", d->name, m->last.klippy);
    /* print_stats forgot it (a Klipper restart, another print since):
       Moonraker's job history tells how the newest run of this file,
       started after it was uploaded, ended */
    if (m->hist_state != H_ANSWERED || strcmp(m->hist_name, j.name) != 0) {
        if (m->hist_state == H_NONE || strcmp(m->hist_name, j.name) != 0) {
            snprintf(m->hist_name, sizeof(m->hist_name), "%s", j.name);
            m->hist_state = H_ASKING;
            want_meta(m, j.name);
            netdrv_preempt_poll(&m->n);
            mr_kick(&m->n);
        }
        return sf_err_set(err, SF_EAGAIN,
                          "printer '%s': looking '%s' up in Moonraker's job history", d->name,
                          j.name);
    }
    m->hist_state = H_NONE; /* the answer is used once: a later attach asks again */
    const struct moonraker_hist *h = &m->hist;
    if (m->hist_why[0] || !h->found || (h->size >= 0 && h->size != j.size))
        return sf_err_set(err, SF_ENOTFOUND,
                          "printer '%s' has no job '%s' (print_stats: %s '%s'; job history: %s): "
                          "how it ended is not known",
                          d->name, j.name, m->last.state, m->last.filename,
                          m->hist_why[0] ? m->hist_why
                          : h->found     ? "a run of another size"
                                         : "no run since the upload");
    static const struct {
        const char *status;
        enum netjob_remote r;
    } ends[] = {
        { "completed", NETJOB_R_DONE },
        { "cancelled", NETJOB_R_CANCELLED },
        { "error", NETJOB_R_FAILED },
        { "klippy_shutdown", NETJOB_R_FAILED },
        { "klippy_disconnect", NETJOB_R_FAILED },
    };
    char msg[160];
    snprintf(msg, sizeof(msg), "Moonraker's job history: %s", h->status);
    struct netjob_obs hob = { .ours = true, .file = j.name, .message = msg };
    bool known = false;
    for (size_t i = 0; i < sizeof(ends) / sizeof(ends[0]); i++)
        if (strcmp(h->status, ends[i].status) == 0) {
            hob.remote = ends[i].r;
            known = true;
        }
    if (!known) /* interrupted (Moonraker died), in_progress with print_stats idle */
        return sf_err_set(err, SF_ENOTFOUND,
                          "printer '%s': job history says '%s' of '%s': how it ended is not known",
                          d->name, h->status, j.name);
    log_printer(LOG_INFO, d->name, "re-attached to '%s', which ended while we were away (%s)",
                j.name, msg);
    netdrv_adopt(&m->n, &j, &hob, hob.remote == NETJOB_R_DONE ? 1.0 : 0);
    return SF_OK;
}

static int
mr_command(struct drv *d, const char *line, struct sf_err *err)
{
    struct moonraker *m = (struct moonraker *)d;
    size_t len = strlen(line);
    if (len == 0 || strchr(line, '\n') || strchr(line, '\r'))
        return sf_err_set(err, SF_EINVAL, "printer '%s': a command is one non-empty line", d->name);
    if (!m->n.open || d->status.state == DRV_OFFLINE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is offline", d->name);
    if (d->status.state == DRV_PRINTING)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is printing", d->name);
    if (m->script_len + len + 2 > sizeof(m->script))
        return sf_err_set(err, SF_EAGAIN, "printer '%s': too many commands waiting", d->name);
    if (m->script_len)
        m->script[m->script_len++] = '\n';
    memcpy(m->script + m->script_len, line, len);
    m->script_len += len;
    netdrv_preempt_poll(&m->n);
    mr_kick(&m->n);
    return SF_OK;
}

/* drv.h estop: Moonraker's /printer/emergency_stop, ahead of anything waiting. */
static int
mr_estop(struct drv *d, struct sf_err *err)
{
    struct moonraker *m = (struct moonraker *)d;
    if (!m->n.open || d->status.state == DRV_OFFLINE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is offline", d->name);
    m->want_estop = true;
    netdrv_preempt_poll(&m->n);
    mr_kick(&m->n);
    return SF_OK;
}

static void
mr_destroy(struct drv *d)
{
    drv_moonraker_ws_close((struct moonraker *)d, NULL);
    netdrv_destroy(d);
}

static void
mr_close(struct drv *d)
{
    ((struct moonraker *)d)->script_len = 0;
    ((struct moonraker *)d)->want_estop = false;
    netdrv_close(d);
}

static const struct drv_ops moonraker_ops = {
    .version = DRV_OPS_VERSION,
    .kind = "moonraker",
    .open = netdrv_open,
    .start_job = netdrv_start_job,
    .pause = netdrv_pause,
    .resume = netdrv_resume,
    .cancel = netdrv_cancel,
    .command = mr_command,
    .close = mr_close,
    .estop = mr_estop,
    .destroy = mr_destroy,
    .attach = mr_attach,
};

static const struct netdrv_ops moonraker_nops = {
    .product = "Moonraker",
    .key_hint = "check api_key",
    .poll_ms = MR_POLL_MS,
    .job_tries = 4,
    .upload_tries = 4,
    .timeout_ms = 10000,
    .upload_stall_ms = 30000,
    .upload_403 = true, /* "File is loaded, upload not permitted" */
    .start = mr_start,
    .poll = mr_poll,
    .reply = mr_reply,
    .kick = mr_kick,
    .error_text = drv_moonraker_error_text,
    .lost = mr_lost,
};

struct drv *
drv_moonraker_new(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event, void *ud,
                  struct sf_err *err)
{
    struct moonraker *m = mem_calloc(1, sizeof(*m));
    if (!m) {
        sf_err_set(err, SF_ENOMEM, "printer '%s': out of memory", cfg->name);
        return NULL;
    }
    if (netdrv_init(&m->n, l, cfg, &moonraker_ops, &moonraker_nops, on_event, ud, err)) {
        free(m);
        return NULL;
    }
    size_t h = 0;
    if (m->n.key_hdr[0]) {
        m->hdrs[0] = m->n.key_hdr;
        m->json_hdrs[h++] = m->n.key_hdr;
    }
    m->json_hdrs[h] = "Content-Type: application/json";
    return &m->n.base;
}
