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

#include "../src/base/log.h"
#include "../src/base/mem.h"
#include "httpc.h"

/* ---- JSON helpers: field access that names what is wrong ---- */

static json_t *
load(const char *body, size_t len, const char *what, struct sf_err *err)
{
    json_error_t je;
    json_t *root = json_loadb(body, len, JSON_REJECT_DUPLICATES, &je);
    if (!root)
        sf_err_set(err, SF_EINVAL, "moonraker %s: not JSON: %s (line %d)", what, je.text, je.line);
    return root;
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
    json_t *v = json_object_get(obj, key);
    if (!v || json_is_null(v)) {
        out[0] = '\0';
        return required ? sf_err_set(err, SF_EINVAL, "moonraker %s.%s: missing", where, key)
                        : SF_OK;
    }
    if (!json_is_string(v))
        return sf_err_set(err, SF_EINVAL, "moonraker %s.%s: not a string", where, key);
    snprintf(out, n, "%s", json_string_value(v));
    return SF_OK;
}

static int
get_num(json_t *obj, const char *key, const char *where, double *out, struct sf_err *err)
{
    json_t *v = json_object_get(obj, key);
    if (!v || json_is_null(v))
        return SF_OK;
    if (!json_is_number(v))
        return sf_err_set(err, SF_EINVAL, "moonraker %s.%s: not a number", where, key);
    *out = json_number_value(v);
    return SF_OK;
}

static int
get_int(json_t *obj, const char *key, const char *where, int64_t *out, struct sf_err *err)
{
    double d = (double)*out;
    int rc = get_num(obj, key, where, &d, err);
    if (rc == SF_OK && (d < 0 || d > 9.0e15))
        return sf_err_set(err, SF_EINVAL, "moonraker %s.%s: %g is out of range", where, key, d);
    *out = (int64_t)d;
    return rc;
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
    json_t *v = json_object_get(status, key);
    *out = v && json_is_object(v) ? v : NULL;
    if (v && !json_is_null(v) && !*out)
        return sf_err_set(err, SF_EINVAL, "moonraker status.%s: not an object", key);
    return SF_OK;
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
    size_t i = 0;
    while (i < len && (body[i] == ' ' || body[i] == '\n' || body[i] == '\r' || body[i] == '\t'))
        i++;
    size_t k = 0;
    for (; i < len && body[i] != '\n' && body[i] != '\r' && k + 1 < n; i++)
        out[k++] = (unsigned char)body[i] < 0x20 ? ' ' : body[i];
    while (k > 0 && out[k - 1] == ' ')
        k--;
    out[k] = '\0';
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

/* ---- the driver ---- */

/*
 * How it talks: one request at a time per printer.  Polls run on a timer
 * (MR_POLL_MS, the rate Moonraker's docs give simple polling clients:
 * "1 to 2 seconds"); an action (upload, start, pause, resume, cancel, a
 * manual command) takes the slot as soon as it is free, cancelling a poll
 * under way, so no poll begun before an action can report the printer as
 * it was before it.  Polling rather than the websocket subscription: one
 * GET a second per printer is what Moonraker recommends for simple
 * clients, it needs no websocket client in C, and a missed update is
 * simply the next poll (a subscription's missed delta is a wrong state
 * until the next full snapshot).
 *
 * Losing contact (5xx, timeout, refused): without a job the printer goes
 * DRV_OFFLINE with the reason and the farm reconnects with its backoff.
 * With a job the driver rides out MR_JOB_TRIES - 1 failed polls (backoff
 * 0.5, 1, 2 s: the printer prints on without us); then it goes offline
 * too and lets go of the job, which the farm marks interrupted and offers
 * back through attach() when the printer answers.  An upload whose answer
 * was lost is settled by the next poll: the printer runs our file, or it
 * is sent again (at most MR_UPLOAD_TRIES times), or the job fails with the
 * reason.
 */
#define MR_POLL_MS         1000  /* drv_config.poll_ms 0 */
#define MR_STARTUP_MS      2000  /* docs: ask /server/info again after 2 s while Klippy starts */
#define MR_TIMEOUT_MS      10000 /* a poll or an action */
#define MR_UPLOAD_STALL_MS 30000 /* an upload that moves nothing for this long has failed */
#define MR_UPLOAD_TRIES    4
#define MR_JOB_TRIES       4    /* failed contacts in a row a job rides out before going offline */
#define MR_SCRIPT_MAX      4096 /* manual commands waiting to be sent */

enum rq {
    RQ_NONE,
    RQ_INFO,
    RQ_POLL,
    RQ_UPLOAD,
    RQ_START,
    RQ_PAUSE,
    RQ_RESUME,
    RQ_CANCEL,
    RQ_GCODE
};

struct moonraker {
    struct drv base;
    struct httpc *http;           /* the loop's shared client (httpc_get) */
    char url[256];                /* base URL, no trailing '/' */
    char key_hdr[160];            /* "X-Api-Key: ..." */
    const char *hdrs[3];          /* the key (if any), NULL */
    const char *json_hdrs[4];     /* the key, Content-Type: application/json, NULL */
    bool open;                    /* open() and not closed or gone offline */
    bool ready;                   /* Klippy answered /server/info: poll the objects */
    struct httpc_req *req;        /* the request in flight, or NULL */
    enum rq rq;                   /* its kind */
    uint64_t timer;               /* the next poll (or info, or upload retry), 0 if none */
    int fails;                    /* contacts failed in a row */
    struct netjob job;            /* the job on the printer */
    char path[1024];              /* its file on disk (for a second upload) */
    int uploads;                  /* upload attempts for it */
    bool verify;                  /* the upload's fate is unknown: the next poll settles it */
    char upload_err[128];         /* why it is unknown */
    int poll_ms;                  /* the poll period */
    struct moonraker_status last; /* the last poll's answer (attach reads it) */
    bool have_last;               /* there is one since open() */
    enum rq want;                 /* RQ_PAUSE/RESUME/CANCEL to send when the slot frees */
    char script[MR_SCRIPT_MAX];   /* manual commands waiting, '\n'-separated */
    size_t script_len;
};

static const struct drv_ops moonraker_ops;

static struct moonraker *
MR(struct drv *d)
{
    return (struct moonraker *)d;
}

static void kick(struct moonraker *m);
static void schedule(struct moonraker *m, int64_t ms);

static const char *
rq_name(enum rq r)
{
    static const char *const n[] = { "none",   "server info", "status poll",
                                     "upload", "print start", "pause",
                                     "resume", "cancel",      "gcode script" };
    return n[r];
}

static bool start_req(struct moonraker *m, enum rq kind, const char *method, const char *path,
                      const char *body, const struct httpc_part *parts, size_t n_parts);

/* The job ends here (not from a poll): report it with state st and message msg. */
static void
end_job(struct moonraker *m, enum drv_state st, enum drv_event ev, const char *msg)
{
    struct netjob_verdict v = { .state = st, .ends = true, .ev = ev };
    snprintf(v.message, sizeof(v.message), "%s", msg);
    m->verify = false;
    m->want = RQ_NONE;
    netjob_report(&m->base, &m->job, &v, m->base.status.progress);
}

/* Stop talking: no request, no timer (the job, if any, is kept). */
static void
quiet(struct moonraker *m)
{
    if (m->req)
        httpc_cancel(m->req);
    m->req = NULL;
    m->rq = RQ_NONE;
    if (m->timer)
        loop_timer_cancel(m->base.loop, m->timer);
    m->timer = 0;
}

/*
 * The printer did not answer usefully (why): offline without a job; with
 * one, keep it and ask again after a growing pause.
 */
static void
contact_lost(struct moonraker *m, const char *why)
{
    m->fails++;
    m->ready = false;
    if (m->job.phase != NETJOB_NONE && m->fails < MR_JOB_TRIES) {
        /* a short outage: ride it out, the printer prints on */
        int ms = drv_backoff_ms(m->fails - 1);
        log_printer(LOG_WARN, m->base.name, "%s; asking again in %d ms", why, ms);
        snprintf(m->base.status.message, sizeof(m->base.status.message),
                 "unreachable: %s (retrying)", why);
        schedule(m, ms);
        return;
    }
    if (m->job.phase != NETJOB_NONE) {
        /* The printer prints on without us: the farm marks the job
           interrupted and offers it back through attach() once the
           printer answers again. */
        log_printer(LOG_WARN, m->base.name, "offline with job '%s' on the printer: %s", m->job.name,
                    why);
        m->job.phase = NETJOB_NONE;
        m->verify = false;
        m->want = RQ_NONE;
    }
    quiet(m);
    m->open = false;
    netjob_state(&m->base, DRV_OFFLINE, "%s", why);
}

/* What a finished request amounts to. */
enum outcome { O_OK, O_DOWN, O_AUTH, O_REFUSED };

static enum outcome
judge_reply(struct moonraker *m, const struct httpc_result *res, char *why, size_t n)
{
    char text[128];
    if (res->code != SF_OK) {
        snprintf(why, n, "%s", res->err.msg);
        return O_DOWN;
    }
    if (res->status >= 200 && res->status < 300)
        return O_OK;
    drv_moonraker_error_text(res->body, res->body_len, text, sizeof(text));
    if (res->status == 401 || (res->status == 403 && m->rq != RQ_UPLOAD)) {
        snprintf(why, n, "authentication failed (check api_key): HTTP %ld%s%s", res->status,
                 text[0] ? " " : "", text);
        return O_AUTH;
    }
    snprintf(why, n, "HTTP %ld%s%s", res->status, text[0] ? ": " : "", text);
    return res->status >= 500 ? O_DOWN : O_REFUSED;
}

static void
on_poll(struct moonraker *m, const struct httpc_result *res)
{
    char why[200];
    enum outcome o = judge_reply(m, res, why, sizeof(why));
    if (o != O_OK) {
        contact_lost(m, why);
        return;
    }
    struct moonraker_status st;
    struct sf_err err;
    if (drv_moonraker_parse_status(res->body, res->body_len, &st, &err)) {
        contact_lost(m, err.msg);
        return;
    }
    m->fails = 0;
    m->last = st;
    m->have_last = true;
    netjob_temps(&m->base, st.nozzle_c, st.nozzle_target_c, st.bed_c, st.bed_target_c);
    struct netjob_obs ob;
    drv_moonraker_observe(&st, m->job.name, m->job.size, &ob);
    if (m->verify) {
        bool free_now = ob.remote == NETJOB_R_IDLE || ob.remote == NETJOB_R_DONE ||
                        ob.remote == NETJOB_R_CANCELLED || ob.remote == NETJOB_R_FAILED;
        if (ob.ours) {
            m->verify = false; /* the upload did arrive and start: judge it as any job */
        } else if (free_now) {
            /* the printer is free and does not run our file: send it again */
            if (m->uploads < MR_UPLOAD_TRIES) {
                m->verify = false;
                if (start_req(m, RQ_UPLOAD, "POST", "/server/files/upload", NULL, NULL, 0)) {
                    netjob_state(&m->base, DRV_PRINTING, "uploading again (%s)", m->upload_err);
                    return;
                }
            }
            end_job(m, DRV_IDLE, DRV_EV_JOB_FAILED, m->upload_err);
            schedule(m, m->poll_ms);
            return;
        }
        /* busy with something else, halted, restarting: the judge says */
    }
    struct netjob_verdict v;
    netjob_judge(m->job.phase, &ob, &v);
    if (m->job.phase != NETJOB_NONE && !v.ends && m->verify)
        snprintf(v.message, sizeof(v.message), "%s", m->upload_err);
    if (v.ends)
        m->verify = false;
    netjob_report(&m->base, &m->job, &v, st.progress);
    /* Klippy restarting: /server/info tells when it is back (docs: every 2 s) */
    if (ob.remote == NETJOB_R_STARTING) {
        m->ready = false;
        schedule(m, MR_STARTUP_MS);
    } else {
        schedule(m, m->poll_ms);
    }
}

static void
on_info(struct moonraker *m, const struct httpc_result *res)
{
    char why[200];
    enum outcome o = judge_reply(m, res, why, sizeof(why));
    char state[32];
    struct sf_err err;
    if (o != O_OK) {
        contact_lost(m, why);
        return;
    }
    if (drv_moonraker_parse_info(res->body, res->body_len, state, sizeof(state), &err)) {
        contact_lost(m, err.msg);
        return;
    }
    if (strcmp(state, "startup") == 0) {
        m->fails = 0;
        if (m->job.phase == NETJOB_NONE)
            netjob_state(&m->base, DRV_CONNECTING, "Klipper is starting");
        schedule(m, MR_STARTUP_MS);
        return;
    }
    if (strcmp(state, "disconnected") == 0) {
        contact_lost(m, "Moonraker runs but Klipper is not connected to it");
        return;
    }
    /* ready, shutdown, error: the object query says the rest (webhooks) */
    snprintf(m->base.caps.firmware, sizeof(m->base.caps.firmware), "Klipper (Moonraker)");
    m->ready = true;
    schedule(m, 0);
}

static void
on_upload(struct moonraker *m, const struct httpc_result *res)
{
    char why[200];
    enum outcome o = judge_reply(m, res, why, sizeof(why));
    if (m->job.phase != NETJOB_RUNNING) /* cancelled meanwhile */
        return;
    if (o == O_AUTH) {
        end_job(m, DRV_IDLE, DRV_EV_JOB_FAILED, why);
        contact_lost(m, why);
        return;
    }
    if (o == O_REFUSED) {
        end_job(m, DRV_IDLE, DRV_EV_JOB_FAILED, why);
        schedule(m, 0);
        return;
    }
    if (o == O_DOWN) {
        /* sent in part, or whole with the answer lost: the printer knows */
        snprintf(m->upload_err, sizeof(m->upload_err), "upload failed: %s", why);
        log_printer(LOG_WARN, m->base.name,
                    "upload failed (%s); asking the printer whether it arrived", why);
        m->verify = true;
        m->fails++;
        m->ready = false;
        schedule(m, drv_backoff_ms(m->fails - 1));
        return;
    }
    struct moonraker_upload up;
    struct sf_err err;
    if (drv_moonraker_parse_upload(res->body, res->body_len, &up, &err)) {
        snprintf(m->upload_err, sizeof(m->upload_err), "upload: %s", err.msg);
        m->verify = true;
        schedule(m, 0);
        return;
    }
    m->fails = 0;
    snprintf(m->base.status.message, sizeof(m->base.status.message), "%s", "");
    if (up.print_started) {
        schedule(m, 0);
        return;
    }
    if (up.print_queued) {
        end_job(m, DRV_IDLE, DRV_EV_JOB_FAILED,
                "Moonraker queued the file instead of printing it (turn off [file_manager] "
                "queue_gcode_uploads for a farm printer)");
        schedule(m, 0);
        return;
    }
    /* stored but not started (OrcaSlicer's case): start it by name */
    json_t *b = json_pack("{s:s}", "filename", up.path[0] ? up.path : m->job.name);
    char *body = b ? json_dumps(b, JSON_COMPACT) : NULL;
    json_decref(b);
    bool ok = body && start_req(m, RQ_START, "POST", "/printer/print/start", body, NULL, 0);
    free(body);
    if (!ok) {
        end_job(m, DRV_IDLE, DRV_EV_JOB_FAILED, "could not ask the printer to start the file");
        schedule(m, 0);
    }
}

static void
on_action(struct moonraker *m, enum rq kind, const struct httpc_result *res)
{
    char why[200];
    enum outcome o = judge_reply(m, res, why, sizeof(why));
    if (o == O_OK) {
        m->fails = 0;
        schedule(m, 0);
        return;
    }
    log_printer(LOG_WARN, m->base.name, "%s: %s", rq_name(kind), why);
    if (kind == RQ_START && m->job.phase == NETJOB_RUNNING && o != O_DOWN) {
        end_job(m, DRV_IDLE, DRV_EV_JOB_FAILED, why); /* "SD busy" */
        schedule(m, 0);
        return;
    }
    if (kind == RQ_START && m->job.phase == NETJOB_RUNNING) {
        snprintf(m->upload_err, sizeof(m->upload_err), "print start failed: %s", why);
        m->verify = true;
    }
    if (kind == RQ_GCODE)
        snprintf(m->base.status.message, sizeof(m->base.status.message), "command failed: %s", why);
    else if (kind != RQ_START)
        snprintf(m->base.status.message, sizeof(m->base.status.message), "%s refused: %s",
                 rq_name(kind), why);
    if (o == O_DOWN || o == O_AUTH)
        contact_lost(m, why);
    else
        schedule(m, 0);
}

static void
on_done(struct httpc_req *r, const struct httpc_result *res, void *ud)
{
    (void)r;
    struct moonraker *m = ud;
    enum rq kind = m->rq;
    m->req = NULL;
    m->rq = RQ_NONE;
    switch (kind) {
    case RQ_INFO:
        on_info(m, res);
        break;
    case RQ_POLL:
        on_poll(m, res);
        break;
    case RQ_UPLOAD:
        on_upload(m, res);
        break;
    default:
        on_action(m, kind, res);
        break;
    }
    kick(m);
}

static void
on_progress(struct httpc_req *r, uint64_t sent, uint64_t total, void *ud)
{
    (void)r;
    struct moonraker *m = ud;
    if (total > 0)
        snprintf(m->base.status.message, sizeof(m->base.status.message), "uploading %u%%",
                 (unsigned)(sent * 100 / total));
}

/* Start a request in the free slot; false (logged) if it could not start. */
static bool
start_req(struct moonraker *m, enum rq kind, const char *method, const char *path, const char *body,
          const struct httpc_part *parts, size_t n_parts)
{
    char url[512];
    snprintf(url, sizeof(url), "%s%s", m->url, path);
    struct httpc_part up[3];
    struct httpc_opts o = { .method = method,
                            .url = url,
                            .headers = body ? m->json_hdrs : m->hdrs,
                            .body = body,
                            .body_len = body ? strlen(body) : 0,
                            .parts = parts,
                            .n_parts = n_parts,
                            .timeout_ms = MR_TIMEOUT_MS,
                            .done = on_done,
                            .ud = m };
    if (kind == RQ_UPLOAD) {
        /* POST /server/files/upload, multipart/form-data: the file
           streamed from disk, root and print=true (file_manager.md) */
        up[0] = (struct httpc_part){ .name = "file",
                                     .file_path = m->path,
                                     .filename = m->job.name,
                                     .type = "application/octet-stream" };
        up[1] = (struct httpc_part){ .name = "root", .value = "gcodes" };
        up[2] = (struct httpc_part){ .name = "print", .value = "true" };
        o.parts = up;
        o.n_parts = 3;
        o.timeout_ms = -1;
        o.stall_ms = MR_UPLOAD_STALL_MS;
        o.progress = on_progress;
        m->uploads++;
    }
    struct sf_err err;
    m->req = httpc_start(m->http, &o, &err);
    if (!m->req) {
        log_printer(LOG_ERROR, m->base.name, "%s: %s", rq_name(kind), err.msg);
        return false;
    }
    m->rq = kind;
    return true;
}

/* Send what waits (an action, then manual commands) if the slot is free. */
static void
kick(struct moonraker *m)
{
    if (!m->open || m->req)
        return;
    if (m->want != RQ_NONE) {
        enum rq w = m->want;
        m->want = RQ_NONE;
        const char *path = w == RQ_PAUSE    ? "/printer/print/pause"
                           : w == RQ_RESUME ? "/printer/print/resume"
                                            : "/printer/print/cancel";
        if (start_req(m, w, "POST", path, NULL, NULL, 0))
            return;
    }
    if (m->script_len > 0) {
        m->script[m->script_len] = '\0';
        json_t *b = json_pack("{s:s}", "script", m->script);
        char *body = b ? json_dumps(b, JSON_COMPACT) : NULL;
        json_decref(b);
        m->script_len = 0;
        bool ok = body && start_req(m, RQ_GCODE, "POST", "/printer/gcode/script", body, NULL, 0);
        free(body);
        if (ok)
            return;
    }
}

static void
on_timer(struct loop *l, void *ud)
{
    (void)l;
    struct moonraker *m = ud;
    m->timer = 0;
    if (!m->open)
        return;
    if (m->req) { /* an action holds the slot: poll after it */
        schedule(m, m->poll_ms);
        return;
    }
    bool ok = m->ready ? start_req(m, RQ_POLL, "GET",
                                   "/printer/objects/query?webhooks&print_stats&virtual_sdcard"
                                   "&extruder&heater_bed&display_status",
                                   NULL, NULL, 0)
                       : start_req(m, RQ_INFO, "GET", "/server/info", NULL, NULL, 0);
    if (!ok)
        schedule(m, m->poll_ms);
}

static void
schedule(struct moonraker *m, int64_t ms)
{
    if (!m->open)
        return;
    if (m->timer)
        loop_timer_cancel(m->base.loop, m->timer);
    m->timer = loop_timer_add(m->base.loop, ms, on_timer, m);
}

/* Free the slot of a poll so an action goes first. */
static void
preempt_poll(struct moonraker *m)
{
    if (m->req && (m->rq == RQ_POLL || m->rq == RQ_INFO)) {
        httpc_cancel(m->req);
        m->req = NULL;
        m->rq = RQ_NONE;
        schedule(m, m->poll_ms);
    }
}

/* ---- drv_ops ---- */

static int
mr_open(struct drv *d, struct sf_err *err)
{
    (void)err;
    struct moonraker *m = MR(d);
    if (m->open)
        return SF_OK;
    m->open = true;
    m->ready = false;
    m->have_last = false;
    if (m->job.phase == NETJOB_NONE)
        netjob_state(d, DRV_CONNECTING, "%s", "");
    schedule(m, 0);
    return SF_OK;
}

static int
mr_start_job(struct drv *d, const char *gcode_path, uint64_t first_line,
             const struct drv_job_scan *scan, struct sf_err *err)
{
    struct moonraker *m = MR(d);
    if (first_line > 0)
        return sf_err_set(err, SF_EUNSUPP,
                          "printer '%s': a Moonraker printer runs a job from its start only (it "
                          "reads the file itself)",
                          d->name);
    if (!m->open || d->status.state != DRV_IDLE || m->job.phase != NETJOB_NONE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is %s", d->name,
                          drv_state_name(d->status.state));
    struct netjob j;
    int rc = netjob_prepare(&j, gcode_path, scan, m->path, sizeof(m->path), err);
    if (rc)
        return rc;
    m->job = j;
    m->uploads = 0;
    m->verify = false;
    m->want = RQ_NONE;
    d->status.lines_total = j.lines_total;
    d->status.lines_acked = 0;
    d->status.progress = 0;
    d->status.job_started_ms = loop_now_ms(d->loop);
    preempt_poll(m);
    if (m->req || !start_req(m, RQ_UPLOAD, "POST", "/server/files/upload", NULL, NULL, 0)) {
        m->job.phase = NETJOB_NONE;
        return sf_err_set(err, SF_EAGAIN, "printer '%s': the upload could not start", d->name);
    }
    netjob_state(d, DRV_PRINTING, "uploading");
    return SF_OK;
}

static int
mr_attach(struct drv *d, const char *gcode_path, const struct drv_job_scan *scan,
          struct sf_err *err)
{
    struct moonraker *m = MR(d);
    if (!m->open || !m->have_last || d->status.state == DRV_OFFLINE ||
        d->status.state == DRV_CONNECTING || m->job.phase != NETJOB_NONE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is %s", d->name,
                          drv_state_name(d->status.state));
    struct netjob j;
    int rc = netjob_prepare(&j, gcode_path, scan, m->path, sizeof(m->path), err);
    if (rc)
        return rc;
    /* print_stats keeps the last job's file and end state until the next one */
    struct netjob_obs ob;
    drv_moonraker_observe(&m->last, j.name, j.size, &ob);
    if (!ob.ours)
        return sf_err_set(err, SF_ENOTFOUND, "printer '%s' has no job '%s' (print_stats: %s '%s')",
                          d->name, j.name, m->last.state, m->last.filename);
    log_printer(LOG_INFO, d->name, "re-attached to '%s', which the printer still knows (%s)",
                j.name, m->last.state);
    m->job = j;
    m->uploads = MR_UPLOAD_TRIES; /* never sent again */
    m->verify = false;
    d->status.lines_total = j.lines_total;
    d->status.lines_acked = 0;
    d->status.job_started_ms = loop_now_ms(d->loop);
    struct netjob_verdict v;
    netjob_judge(NETJOB_RUNNING, &ob, &v);
    netjob_report(d, &m->job, &v, m->last.progress);
    return SF_OK;
}

static int
want(struct moonraker *m, enum rq w, struct sf_err *err)
{
    m->want = w;
    preempt_poll(m);
    kick(m);
    (void)err;
    return SF_OK;
}

static int
mr_pause(struct drv *d, struct sf_err *err)
{
    struct moonraker *m = MR(d);
    if (m->job.phase != NETJOB_RUNNING || d->status.state != DRV_PRINTING || m->rq == RQ_UPLOAD ||
        m->verify)
        return sf_err_set(err, SF_EAGAIN, "printer '%s': nothing to pause", d->name);
    d->status.state = DRV_PAUSED; /* the farm moves itself; the poll confirms */
    return want(m, RQ_PAUSE, err);
}

static int
mr_resume(struct drv *d, struct sf_err *err)
{
    struct moonraker *m = MR(d);
    if (m->job.phase != NETJOB_RUNNING || d->status.state != DRV_PAUSED)
        return sf_err_set(err, SF_EAGAIN, "printer '%s': nothing to resume", d->name);
    d->status.state = DRV_PRINTING;
    return want(m, RQ_RESUME, err);
}

static int
mr_cancel(struct drv *d, struct sf_err *err)
{
    struct moonraker *m = MR(d);
    if (m->job.phase == NETJOB_NONE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s': no job to cancel", d->name);
    if (m->rq == RQ_UPLOAD || m->verify) {
        /* not printing yet: stop the upload; the printer never starts a
           file it did not get whole */
        if (m->rq == RQ_UPLOAD) {
            httpc_cancel(m->req);
            m->req = NULL;
            m->rq = RQ_NONE;
        }
        end_job(m, DRV_IDLE, DRV_EV_JOB_CANCELLED, "");
        schedule(m, 0);
        return SF_OK;
    }
    m->job.phase = NETJOB_CANCELLING; /* status stays printing until the printer says */
    return want(m, RQ_CANCEL, err);
}

static int
mr_command(struct drv *d, const char *line, struct sf_err *err)
{
    struct moonraker *m = MR(d);
    size_t n = strlen(line);
    if (n == 0 || strchr(line, '\n') || strchr(line, '\r'))
        return sf_err_set(err, SF_EINVAL, "printer '%s': a command is one non-empty line", d->name);
    if (!m->open || d->status.state == DRV_OFFLINE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is offline", d->name);
    if (d->status.state == DRV_PRINTING)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is printing", d->name);
    if (m->script_len + n + 2 > sizeof(m->script))
        return sf_err_set(err, SF_EAGAIN, "printer '%s': too many commands waiting", d->name);
    if (m->script_len)
        m->script[m->script_len++] = '\n';
    memcpy(m->script + m->script_len, line, n);
    m->script_len += n;
    preempt_poll(m);
    kick(m);
    return SF_OK;
}

static void
mr_close(struct drv *d)
{
    struct moonraker *m = MR(d);
    quiet(m);
    m->open = false;
    m->ready = false;
    m->want = RQ_NONE;
    m->script_len = 0;
    netjob_state(d, DRV_OFFLINE, NULL);
}

static void
mr_destroy(struct drv *d)
{
    struct moonraker *m = MR(d);
    quiet(m);
    httpc_put(m->http);
    free(m);
}

static const struct drv_ops moonraker_ops = {
    .version = DRV_OPS_VERSION,
    .kind = "moonraker",
    .open = mr_open,
    .start_job = mr_start_job,
    .pause = mr_pause,
    .resume = mr_resume,
    .cancel = mr_cancel,
    .command = mr_command,
    .close = mr_close,
    .destroy = mr_destroy,
    .attach = mr_attach,
};

struct drv *
drv_moonraker_new(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event, void *ud,
                  struct sf_err *err)
{
    const char *url = cfg->url;
    if (!url || !url[0]) {
        sf_err_set(err, SF_EINVAL, "printer '%s': driver moonraker needs a url", cfg->name);
        return NULL;
    }
    if (strncmp(url, "http://", 7) != 0 && strncmp(url, "https://", 8) != 0) {
        sf_err_set(err, SF_EINVAL, "printer '%s': url '%s' is not http:// or https://", cfg->name,
                   url);
        return NULL;
    }
    struct moonraker *m = mem_calloc(1, sizeof(*m));
    if (!m) {
        sf_err_set(err, SF_ENOMEM, "printer '%s': out of memory", cfg->name);
        return NULL;
    }
    size_t n = strlen(url);
    while (n > 0 && url[n - 1] == '/')
        n--;
    if (n >= sizeof(m->url)) {
        free(m);
        sf_err_set(err, SF_EINVAL, "printer '%s': url too long", cfg->name);
        return NULL;
    }
    memcpy(m->url, url, n);
    m->url[n] = '\0';
    size_t h = 0;
    if (cfg->api_key && cfg->api_key[0]) {
        snprintf(m->key_hdr, sizeof(m->key_hdr), "X-Api-Key: %s", cfg->api_key);
        m->hdrs[h] = m->key_hdr;
        m->json_hdrs[h++] = m->key_hdr;
    }
    m->json_hdrs[h] = "Content-Type: application/json";
    m->http = httpc_get(l, err);
    if (!m->http) {
        free(m);
        return NULL;
    }
    m->base.ops = &moonraker_ops;
    m->base.loop = l;
    snprintf(m->base.name, sizeof(m->base.name), "%s", cfg->name ? cfg->name : "?");
    m->base.on_event = on_event;
    m->base.ud = ud;
    m->poll_ms = cfg->poll_ms > 0 ? cfg->poll_ms : MR_POLL_MS;
    m->base.status.state = DRV_OFFLINE;
    return &m->base;
}
