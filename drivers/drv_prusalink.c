/*
 * drv_prusalink.c - Prusa printers through PrusaLink v1 (drv_prusalink.h).
 *
 * This part reads PrusaLink's replies: /api/v1/status (polled), /api/v1/job
 * and error bodies, checked against the OpenAPI specification
 * (prusa3d/Prusa-Link-Web spec/openapi.yaml, 1.0.0-draft, commit
 * 337fabbd) with a message naming the field that is wrong, and the
 * mapping of the printer states onto netjob's words.
 *
 * Thread: the parsers are pure; the driver runs on the loop thread.
 */
#include "drv_prusalink.h"

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
        sf_err_set(err, SF_EINVAL, "prusalink %s: not JSON: %s (line %d)", what, je.text, je.line);
    else if (!json_is_object(root)) {
        sf_err_set(err, SF_EINVAL, "prusalink %s: not an object", what);
        json_decref(root);
        root = NULL;
    }
    return root;
}

static int
get_str(json_t *obj, const char *key, const char *where, char *out, size_t n, bool required,
        struct sf_err *err)
{
    json_t *v = json_object_get(obj, key);
    out[0] = '\0';
    if (!v || json_is_null(v))
        return required ? sf_err_set(err, SF_EINVAL, "prusalink %s.%s: missing", where, key)
                        : SF_OK;
    if (!json_is_string(v))
        return sf_err_set(err, SF_EINVAL, "prusalink %s.%s: not a string", where, key);
    snprintf(out, n, "%s", json_string_value(v));
    return SF_OK;
}

static int
get_num(json_t *obj, const char *key, const char *where, double *out, bool required,
        struct sf_err *err)
{
    json_t *v = json_object_get(obj, key);
    if (!v || json_is_null(v))
        return required ? sf_err_set(err, SF_EINVAL, "prusalink %s.%s: missing", where, key)
                        : SF_OK;
    if (!json_is_number(v))
        return sf_err_set(err, SF_EINVAL, "prusalink %s.%s: not a number", where, key);
    *out = json_number_value(v);
    return SF_OK;
}

static int
get_int(json_t *obj, const char *key, const char *where, int64_t *out, bool required,
        struct sf_err *err)
{
    double d = (double)*out;
    int rc = get_num(obj, key, where, &d, required, err);
    if (rc == SF_OK && (d < 0 || d > 9.0e15))
        return sf_err_set(err, SF_EINVAL, "prusalink %s.%s: %g is out of range", where, key, d);
    *out = (int64_t)d;
    return rc;
}

static int
opt_obj(json_t *obj, const char *key, const char *where, json_t **out, struct sf_err *err)
{
    json_t *v = json_object_get(obj, key);
    *out = v && json_is_object(v) ? v : NULL;
    if (v && !json_is_null(v) && !*out)
        return sf_err_set(err, SF_EINVAL, "prusalink %s.%s: not an object", where, key);
    return SF_OK;
}

static int
percent(double *p, const char *where, struct sf_err *err)
{
    if (*p < 0 || *p > 100)
        return sf_err_set(err, SF_EINVAL, "prusalink %s.progress: %g is not a percentage", where,
                          *p);
    *p /= 100;
    return SF_OK;
}

/* ---- parsers ---- */

int
drv_prusalink_parse_status(const char *body, size_t len, struct prusalink_status *st,
                           struct sf_err *err)
{
    memset(st, 0, sizeof(*st));
    st->time_remaining_s = -1;
    json_t *root = load(body, len, "status", err);
    if (!root)
        return SF_EINVAL;
    int rc;
    json_t *pr, *job, *sto, *sp;
    if ((rc = opt_obj(root, "printer", "status", &pr, err)) ||
        (rc = opt_obj(root, "job", "status", &job, err)) ||
        (rc = opt_obj(root, "storage", "status", &sto, err)))
        goto out;
    if (!pr) { /* the one required member (StatusPrinter.state with it) */
        rc = sf_err_set(err, SF_EINVAL, "prusalink status.printer: missing");
        goto out;
    }
    if ((rc = get_str(pr, "state", "printer", st->state, sizeof(st->state), true, err)) ||
        (rc = get_num(pr, "temp_nozzle", "printer", &st->nozzle_c, false, err)) ||
        (rc = get_num(pr, "target_nozzle", "printer", &st->nozzle_target_c, false, err)) ||
        (rc = get_num(pr, "temp_bed", "printer", &st->bed_c, false, err)) ||
        (rc = get_num(pr, "target_bed", "printer", &st->bed_target_c, false, err)) ||
        (rc = opt_obj(pr, "status_printer", "printer", &sp, err)))
        goto out;
    if (sp) {
        json_t *ok = json_object_get(sp, "ok");
        if (ok && json_is_false(ok) &&
            (rc = get_str(sp, "message", "printer.status_printer", st->message, sizeof(st->message),
                          false, err)))
            goto out;
    }
    if (job) {
        st->has_job = true;
        double tr = -1;
        if ((rc = get_int(job, "id", "job", &st->job_id, false, err)) ||
            (rc = get_num(job, "progress", "job", &st->progress, false, err)) ||
            (rc = percent(&st->progress, "job", err)) ||
            (rc = get_num(job, "time_remaining", "job", &tr, false, err)))
            goto out;
        st->time_remaining_s = tr < 0 ? -1 : (int64_t)tr;
    }
    if (sto) {
        char path[64];
        json_t *ro = json_object_get(sto, "read_only");
        if ((rc = get_str(sto, "path", "storage", path, sizeof(path), true, err)))
            goto out;
        if (ro && !json_is_boolean(ro)) {
            rc = sf_err_set(err, SF_EINVAL, "prusalink storage.read_only: not a boolean");
            goto out;
        }
        st->read_only = ro && json_is_true(ro);
        /* "/usb/" -> "usb": the {storage} of /api/v1/files/{storage}/{path} */
        size_t k = 0;
        for (const char *c = path; *c && k + 1 < sizeof(st->storage); c++)
            if (*c != '/')
                st->storage[k++] = *c;
        st->storage[k] = '\0';
    }
    rc = SF_OK;
out:
    json_decref(root);
    return rc;
}

int
drv_prusalink_parse_job(const char *body, size_t len, struct prusalink_job *job, struct sf_err *err)
{
    memset(job, 0, sizeof(*job));
    json_t *root = load(body, len, "job", err);
    if (!root)
        return SF_EINVAL;
    int rc;
    json_t *file;
    if ((rc = get_int(root, "id", "job", &job->id, true, err)) ||
        (rc = get_str(root, "state", "job", job->state, sizeof(job->state), true, err)) ||
        (rc = get_num(root, "progress", "job", &job->progress, true, err)) ||
        (rc = percent(&job->progress, "job", err)) ||
        (rc = opt_obj(root, "file", "job", &file, err)))
        goto out;
    if (file) {
        if ((rc = get_str(file, "display_name", "job.file", job->name, sizeof(job->name), false,
                          err)) ||
            (!job->name[0] &&
             (rc = get_str(file, "name", "job.file", job->name, sizeof(job->name), true, err))) ||
            (rc = get_int(file, "size", "job.file", &job->size, false, err)))
            goto out;
    }
out:
    json_decref(root);
    return rc;
}

void
drv_prusalink_error_text(const char *body, size_t len, char *out, size_t n)
{
    out[0] = '\0';
    if (n == 0)
        return;
    json_t *root = json_loadb(body, len, 0, NULL);
    json_t *title = root ? json_object_get(root, "title") : NULL;
    json_t *text = root ? json_object_get(root, "text") : NULL;
    if (text && json_is_string(text)) {
        if (title && json_is_string(title) && json_string_length(title) > 0)
            snprintf(out, n, "%s: %s", json_string_value(title), json_string_value(text));
        else
            snprintf(out, n, "%s", json_string_value(text));
        json_decref(root);
        return;
    }
    json_decref(root);
    /* text/plain (the spec's default without Accept: application/json) */
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
drv_prusalink_observe(const struct prusalink_status *st, int64_t job_id, struct netjob_obs *o)
{
    static const struct {
        const char *name;
        enum netjob_remote r;
    } map[] = {
        { "IDLE", NETJOB_R_IDLE },     { "READY", NETJOB_R_IDLE },
        { "BUSY", NETJOB_R_BUSY },     { "PRINTING", NETJOB_R_PRINTING },
        { "PAUSED", NETJOB_R_PAUSED }, { "ATTENTION", NETJOB_R_PAUSED },
        { "FINISHED", NETJOB_R_DONE }, { "STOPPED", NETJOB_R_CANCELLED },
        { "ERROR", NETJOB_R_HALTED },
    };
    memset(o, 0, sizeof(*o));
    o->remote = NETJOB_R_BUSY; /* a state newer than this driver: send it nothing */
    for (size_t i = 0; i < sizeof(map) / sizeof(map[0]); i++)
        if (strcmp(st->state, map[i].name) == 0)
            o->remote = map[i].r;
    o->message = st->message;
    if (o->remote == NETJOB_R_PAUSED && strcmp(st->state, "ATTENTION") == 0 && !st->message[0])
        o->message = "the printer needs attention";
    if (o->remote == NETJOB_R_HALTED && !st->message[0])
        o->message = "the printer reports an error";
    o->ours = job_id > 0 &&
              ((st->has_job && st->job_id == job_id) ||
               (!st->has_job && (o->remote == NETJOB_R_DONE || o->remote == NETJOB_R_CANCELLED)));
}

/* ---- the driver ---- */

/*
 * How it talks: as drv_moonraker.c (one request at a time, polls on a
 * timer that actions pre-empt, a short outage ridden out with a job on the
 * printer, a longer one offline with the job left to attach()), over
 * PrusaLink's v1 API: GET /api/v1/status every PL_POLL_MS (Prusa Connect
 * and PrusaSlicer poll the printer at about this rate), PUT
 * /api/v1/files/{storage}/{name} with Print-After-Upload: ?1 and
 * Overwrite: ?1 (the body streamed from disk), then GET /api/v1/job once to
 * learn the job's id by its file name and size; pause and resume are PUT
 * /api/v1/job/{id}/pause|resume, cancel is DELETE /api/v1/job/{id}.
 * Every request says Accept: application/json, so errors come as the
 * spec's Error object and 409's reason reaches the operator.  Auth is
 * X-Api-Key (older firmware) or user/password by HTTP Digest (current).
 * PrusaLink v1 has no endpoint for a console command.
 */
#define PL_POLL_MS         1000 /* drv_config.poll_ms 0 */
#define PL_TIMEOUT_MS      10000
#define PL_UPLOAD_STALL_MS 30000
#define PL_UPLOAD_TRIES    4
#define PL_JOB_TRIES       4 /* failed contacts in a row a job rides out before going offline */

enum rq { RQ_NONE, RQ_POLL, RQ_JOB, RQ_UPLOAD, RQ_PAUSE, RQ_RESUME, RQ_CANCEL };

struct prusalink {
    struct drv base;
    struct httpc *http;            /* the loop's shared client (httpc_get) */
    char url[256];                 /* base URL, no trailing '/' */
    char key_hdr[160];             /* "X-Api-Key: ..." */
    const char *hdrs[3];           /* the key (if any), Accept, NULL */
    char user[64];                 /* digest user, "" for none */
    char password[128];            /* its password */
    bool open;                     /* open() and not closed or gone offline */
    int poll_ms;                   /* the poll period */
    struct prusalink_status last;  /* the last status (attach reads it) */
    bool have_last;                /* there is one since open() */
    struct prusalink_job last_job; /* what /api/v1/job last said */
    bool have_job;                 /* ... and it is still the printer's job */
    int64_t asked_id;              /* the job id /api/v1/job was last asked about */
    struct httpc_req *req;         /* the request in flight, or NULL */
    enum rq rq;                    /* its kind */
    uint64_t timer;                /* the next poll, 0 if none */
    int fails;                     /* contacts failed in a row */
    struct netjob job;             /* the job on the printer */
    int64_t job_id;                /* its id on the printer, 0 until learnt */
    char path[1024];               /* its file on disk */
    char storage[32];              /* the printer's storage ("usb", "local") */
    int uploads;                   /* upload attempts for the job */
    bool verify;                   /* the upload's fate is unknown: the next poll settles it */
    char upload_err[128];          /* why it is unknown */
    enum rq want;                  /* RQ_PAUSE/RESUME/CANCEL to send when the slot frees */
};

static struct prusalink *
PL(struct drv *d)
{
    return (struct prusalink *)d;
}

static void kick(struct prusalink *p);
static void schedule(struct prusalink *p, int64_t ms);
static bool start_req(struct prusalink *p, enum rq kind);

static const char *
rq_name(enum rq r)
{
    static const char *const n[] = { "none",  "status poll", "job query", "upload",
                                     "pause", "resume",      "cancel" };
    return n[r];
}

static void
end_job(struct prusalink *p, enum drv_state st, enum drv_event ev, const char *msg)
{
    struct netjob_verdict v = { .state = st, .ends = true, .ev = ev };
    snprintf(v.message, sizeof(v.message), "%s", msg);
    p->verify = false;
    p->want = RQ_NONE;
    p->job_id = 0;
    netjob_report(&p->base, &p->job, &v, p->base.status.progress);
}

static void
quiet(struct prusalink *p)
{
    if (p->req)
        httpc_cancel(p->req);
    p->req = NULL;
    p->rq = RQ_NONE;
    if (p->timer)
        loop_timer_cancel(p->base.loop, p->timer);
    p->timer = 0;
}

static void
contact_lost(struct prusalink *p, const char *why)
{
    p->fails++;
    if (p->job.phase != NETJOB_NONE && p->fails < PL_JOB_TRIES) {
        /* a short outage: ride it out, the printer prints on */
        int ms = drv_backoff_ms(p->fails - 1);
        log_printer(LOG_WARN, p->base.name, "%s; asking again in %d ms", why, ms);
        snprintf(p->base.status.message, sizeof(p->base.status.message),
                 "unreachable: %s (retrying)", why);
        schedule(p, ms);
        return;
    }
    if (p->job.phase != NETJOB_NONE) {
        /* The printer prints on without us: the farm marks the job
           interrupted and offers it back through attach() once the
           printer answers again. */
        log_printer(LOG_WARN, p->base.name, "offline with job '%s' on the printer: %s", p->job.name,
                    why);
        p->job.phase = NETJOB_NONE;
        p->verify = false;
        p->want = RQ_NONE;
    }
    quiet(p);
    p->open = false;
    netjob_state(&p->base, DRV_OFFLINE, "%s", why);
}

enum outcome { O_OK, O_DOWN, O_AUTH, O_REFUSED };

static enum outcome
judge_reply(const struct httpc_result *res, char *why, size_t n)
{
    char text[128];
    if (res->code != SF_OK) {
        snprintf(why, n, "%s", res->err.msg);
        return O_DOWN;
    }
    if (res->status >= 200 && res->status < 300)
        return O_OK;
    drv_prusalink_error_text(res->body, res->body_len, text, sizeof(text));
    if (res->status == 401 || res->status == 403) {
        snprintf(why, n, "authentication failed (check api_key, or user and password): HTTP %ld",
                 res->status);
        return O_AUTH;
    }
    snprintf(why, n, "HTTP %ld%s%s", res->status, text[0] ? ": " : "", text);
    return res->status >= 500 ? O_DOWN : O_REFUSED;
}

/* The job the last status reports is the one /api/v1/job last described. */
static bool
job_known(const struct prusalink *p, const struct prusalink_status *st)
{
    return st->has_job && p->have_job && p->last_job.id == st->job_id;
}

static void
on_status(struct prusalink *p, const struct httpc_result *res)
{
    char why[200];
    if (judge_reply(res, why, sizeof(why)) != O_OK) {
        contact_lost(p, why);
        return;
    }
    struct prusalink_status st;
    struct sf_err err;
    if (drv_prusalink_parse_status(res->body, res->body_len, &st, &err)) {
        contact_lost(p, err.msg);
        return;
    }
    p->fails = 0;
    p->last = st;
    p->have_last = true;
    if (st.storage[0] && !st.read_only)
        snprintf(p->storage, sizeof(p->storage), "%s", st.storage);
    netjob_temps(&p->base, st.nozzle_c, st.nozzle_target_c, st.bed_c, st.bed_target_c);
    /* A job we have not seen described: ask /api/v1/job for its file (once
       per job id) before judging, so a restarted daemon can recognise its
       print (attach) and a fresh upload is told from someone else's job. */
    if (!st.has_job) {
        p->have_job = false;
        p->asked_id = 0;
    } else if (!job_known(p, &st) && p->asked_id != st.job_id) {
        p->asked_id = st.job_id;
        if (start_req(p, RQ_JOB))
            return;
    }
    bool known = job_known(p, &st);
    if (p->job.phase != NETJOB_NONE && p->job_id == 0 && known &&
        strcmp(p->last_job.name, p->job.name) == 0 &&
        (p->last_job.size == 0 || p->last_job.size == p->job.size)) {
        p->job_id = st.job_id;
        log_printer(LOG_INFO, p->base.name, "job '%s' is job %lld on the printer", p->job.name,
                    (long long)p->job_id);
    }
    struct netjob_obs ob;
    drv_prusalink_observe(&st, p->job_id, &ob);
    if (known)
        ob.file = p->last_job.name;
    if (p->job.phase != NETJOB_NONE && p->job_id == 0)
        ob.ours = false; /* a job we could not name is not known ours */
    if (p->verify) {
        bool free_now = ob.remote == NETJOB_R_IDLE || ob.remote == NETJOB_R_DONE ||
                        ob.remote == NETJOB_R_CANCELLED;
        if (ob.ours) {
            p->verify = false;
        } else if (free_now) {
            /* the printer is free and does not run our file: send it again */
            if (p->uploads < PL_UPLOAD_TRIES) {
                p->verify = false;
                if (start_req(p, RQ_UPLOAD)) {
                    netjob_state(&p->base, DRV_PRINTING, "uploading again (%s)", p->upload_err);
                    return;
                }
            }
            end_job(p, DRV_IDLE, DRV_EV_JOB_FAILED, p->upload_err);
            schedule(p, p->poll_ms);
            return;
        }
    }
    if (p->job.phase != NETJOB_NONE && p->job_id == 0 && !p->verify &&
        (ob.remote == NETJOB_R_IDLE || ob.remote == NETJOB_R_BUSY) && p->uploads > 0 &&
        loop_now_ms(p->base.loop) - p->base.status.job_started_ms < 2 * p->poll_ms) {
        /* just uploaded: the printer takes a moment to start the file */
        schedule(p, p->poll_ms);
        return;
    }
    struct netjob_verdict v;
    netjob_judge(p->job.phase, &ob, &v);
    if (p->job.phase != NETJOB_NONE && !v.ends && p->verify)
        snprintf(v.message, sizeof(v.message), "%s", p->upload_err);
    if (v.ends) {
        p->verify = false;
        p->job_id = 0;
    }
    netjob_report(&p->base, &p->job, &v, st.has_job ? st.progress : p->base.status.progress);
    schedule(p, p->poll_ms);
}

static void
on_job(struct prusalink *p, const struct httpc_result *res)
{
    char why[200];
    if (judge_reply(res, why, sizeof(why)) != O_OK) {
        contact_lost(p, why);
        return;
    }
    if (res->status == 204) { /* no job after all */
        p->have_job = false;
        schedule(p, 0);
        return;
    }
    struct prusalink_job job;
    struct sf_err err;
    if (drv_prusalink_parse_job(res->body, res->body_len, &job, &err)) {
        contact_lost(p, err.msg);
        return;
    }
    p->last_job = job;
    p->have_job = true;
    schedule(p, 0); /* the status again, now judged with the job's file */
}

static void
on_upload(struct prusalink *p, const struct httpc_result *res)
{
    char why[200];
    enum outcome o = judge_reply(res, why, sizeof(why));
    if (p->job.phase != NETJOB_RUNNING)
        return;
    if (o == O_AUTH) {
        end_job(p, DRV_IDLE, DRV_EV_JOB_FAILED, why);
        contact_lost(p, why);
        return;
    }
    if (o == O_REFUSED) { /* 409: the printer's reason ("Printer is busy") */
        end_job(p, DRV_IDLE, DRV_EV_JOB_FAILED, why);
        schedule(p, 0);
        return;
    }
    if (o == O_DOWN) {
        snprintf(p->upload_err, sizeof(p->upload_err), "upload failed: %s", why);
        log_printer(LOG_WARN, p->base.name,
                    "upload failed (%s); asking the printer whether it arrived", why);
        p->verify = true;
        p->fails++;
        schedule(p, drv_backoff_ms(p->fails - 1));
        return;
    }
    p->fails = 0;
    p->base.status.message[0] = '\0';
    p->base.status.job_started_ms = loop_now_ms(p->base.loop);
    schedule(p, 0);
}

static void
on_action(struct prusalink *p, enum rq kind, const struct httpc_result *res)
{
    char why[200];
    enum outcome o = judge_reply(res, why, sizeof(why));
    if (o == O_OK) {
        p->fails = 0;
        schedule(p, 0);
        return;
    }
    log_printer(LOG_WARN, p->base.name, "%s: %s", rq_name(kind), why);
    snprintf(p->base.status.message, sizeof(p->base.status.message), "%s refused: %s",
             rq_name(kind), why);
    if (o == O_DOWN || o == O_AUTH)
        contact_lost(p, why);
    else
        schedule(p, 0);
}

static void
on_done(struct httpc_req *r, const struct httpc_result *res, void *ud)
{
    (void)r;
    struct prusalink *p = ud;
    enum rq kind = p->rq;
    p->req = NULL;
    p->rq = RQ_NONE;
    switch (kind) {
    case RQ_POLL:
        on_status(p, res);
        break;
    case RQ_JOB:
        on_job(p, res);
        break;
    case RQ_UPLOAD:
        on_upload(p, res);
        break;
    default:
        on_action(p, kind, res);
        break;
    }
    kick(p);
}

static void
on_progress(struct httpc_req *r, uint64_t sent, uint64_t total, void *ud)
{
    (void)r;
    struct prusalink *p = ud;
    if (total > 0)
        snprintf(p->base.status.message, sizeof(p->base.status.message), "uploading %u%%",
                 (unsigned)(sent * 100 / total));
}

/* Percent-encode one path segment (RFC 3986 unreserved bytes stay). */
static bool
escape(const char *s, char *out, size_t n)
{
    static const char hex[] = "0123456789ABCDEF";
    size_t k = 0;
    for (; *s; s++) {
        unsigned char c = (unsigned char)*s;
        bool plain = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                     c == '-' || c == '.' || c == '_' || c == '~';
        if (k + (plain ? 1 : 3) >= n)
            return false;
        if (plain) {
            out[k++] = (char)c;
        } else {
            out[k++] = '%';
            out[k++] = hex[c >> 4];
            out[k++] = hex[c & 15];
        }
    }
    out[k] = '\0';
    return true;
}

static bool
start_req(struct prusalink *p, enum rq kind)
{
    char url[768], name[400];
    const char *method = "GET";
    const char *up_hdrs[6];
    struct httpc_opts o = { .headers = p->hdrs,
                            .timeout_ms = PL_TIMEOUT_MS,
                            .done = on_done,
                            .ud = p,
                            .user = p->user[0] ? p->user : NULL,
                            .password = p->password,
                            .digest = p->user[0] != '\0' };
    switch (kind) {
    case RQ_POLL:
        snprintf(url, sizeof(url), "%s/api/v1/status", p->url);
        break;
    case RQ_JOB:
        snprintf(url, sizeof(url), "%s/api/v1/job", p->url);
        break;
    case RQ_UPLOAD: {
        if (!escape(p->job.name, name, sizeof(name)))
            return false;
        snprintf(url, sizeof(url), "%s/api/v1/files/%s/%s", p->url,
                 p->storage[0] ? p->storage : "usb", name);
        method = "PUT";
        size_t h = 0;
        for (size_t i = 0; p->hdrs[i]; i++)
            up_hdrs[h++] = p->hdrs[i];
        up_hdrs[h++] = "Content-Type: application/octet-stream";
        up_hdrs[h++] = "Print-After-Upload: ?1";
        up_hdrs[h++] = "Overwrite: ?1";
        up_hdrs[h] = NULL;
        o.headers = up_hdrs;
        o.body_path = p->path;
        o.timeout_ms = -1;
        o.stall_ms = PL_UPLOAD_STALL_MS;
        o.progress = on_progress;
        p->uploads++;
        break;
    }
    case RQ_PAUSE:
    case RQ_RESUME:
        snprintf(url, sizeof(url), "%s/api/v1/job/%lld/%s", p->url, (long long)p->job_id,
                 kind == RQ_PAUSE ? "pause" : "resume");
        method = "PUT";
        break;
    case RQ_CANCEL:
        snprintf(url, sizeof(url), "%s/api/v1/job/%lld", p->url, (long long)p->job_id);
        method = "DELETE";
        break;
    default:
        return false;
    }
    o.method = method;
    o.url = url;
    struct sf_err err;
    p->req = httpc_start(p->http, &o, &err);
    if (!p->req) {
        log_printer(LOG_ERROR, p->base.name, "%s: %s", rq_name(kind), err.msg);
        return false;
    }
    p->rq = kind;
    return true;
}

static void
kick(struct prusalink *p)
{
    if (!p->open || p->req || p->want == RQ_NONE)
        return;
    if (p->job_id == 0) { /* learn the id first */
        if (p->job.phase != NETJOB_NONE)
            start_req(p, RQ_JOB);
        return;
    }
    enum rq w = p->want;
    p->want = RQ_NONE;
    start_req(p, w);
}

static void
on_timer(struct loop *l, void *ud)
{
    (void)l;
    struct prusalink *p = ud;
    p->timer = 0;
    if (!p->open)
        return;
    if (p->req || !start_req(p, RQ_POLL))
        schedule(p, p->poll_ms);
}

static void
schedule(struct prusalink *p, int64_t ms)
{
    if (!p->open)
        return;
    if (p->timer)
        loop_timer_cancel(p->base.loop, p->timer);
    p->timer = loop_timer_add(p->base.loop, ms, on_timer, p);
}

static void
preempt_poll(struct prusalink *p)
{
    if (p->req && p->rq == RQ_POLL) {
        httpc_cancel(p->req);
        p->req = NULL;
        p->rq = RQ_NONE;
        schedule(p, p->poll_ms);
    }
}

/* ---- drv_ops ---- */

static int
pl_open(struct drv *d, struct sf_err *err)
{
    (void)err;
    struct prusalink *p = PL(d);
    if (p->open)
        return SF_OK;
    p->open = true;
    p->have_last = false;
    p->have_job = false;
    p->asked_id = 0;
    if (p->job.phase == NETJOB_NONE)
        netjob_state(d, DRV_CONNECTING, "%s", "");
    snprintf(d->caps.firmware, sizeof(d->caps.firmware), "PrusaLink");
    schedule(p, 0);
    return SF_OK;
}

static int
pl_start_job(struct drv *d, const char *gcode_path, uint64_t first_line,
             const struct drv_job_scan *scan, struct sf_err *err)
{
    struct prusalink *p = PL(d);
    if (first_line > 0)
        return sf_err_set(err, SF_EUNSUPP,
                          "printer '%s': a PrusaLink printer runs a job from its start only (it "
                          "reads the file itself)",
                          d->name);
    if (!p->open || d->status.state != DRV_IDLE || p->job.phase != NETJOB_NONE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is %s", d->name,
                          drv_state_name(d->status.state));
    struct netjob j;
    int rc = netjob_prepare(&j, gcode_path, scan, p->path, sizeof(p->path), err);
    if (rc)
        return rc;
    p->job = j;
    p->job_id = 0;
    p->uploads = 0;
    p->verify = false;
    p->want = RQ_NONE;
    d->status.lines_total = j.lines_total;
    d->status.lines_acked = 0;
    d->status.progress = 0;
    d->status.job_started_ms = loop_now_ms(d->loop);
    preempt_poll(p);
    if (p->req || !start_req(p, RQ_UPLOAD)) {
        p->job.phase = NETJOB_NONE;
        return sf_err_set(err, SF_EAGAIN, "printer '%s': the upload could not start", d->name);
    }
    netjob_state(d, DRV_PRINTING, "uploading");
    return SF_OK;
}

static int
pl_attach(struct drv *d, const char *gcode_path, const struct drv_job_scan *scan,
          struct sf_err *err)
{
    struct prusalink *p = PL(d);
    if (!p->open || !p->have_last || d->status.state == DRV_OFFLINE ||
        d->status.state == DRV_CONNECTING || p->job.phase != NETJOB_NONE ||
        (p->last.has_job && !job_known(p, &p->last)))
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is %s", d->name,
                          drv_state_name(d->status.state));
    struct netjob j;
    int rc = netjob_prepare(&j, gcode_path, scan, p->path, sizeof(p->path), err);
    if (rc)
        return rc;
    if (!p->last.has_job)
        return sf_err_set(err, SF_ENOTFOUND, "printer '%s' has no job (it is %s)", d->name,
                          p->last.state);
    if (strcmp(p->last_job.name, j.name) != 0 ||
        (p->last_job.size != 0 && p->last_job.size != j.size))
        return sf_err_set(err, SF_ENOTFOUND, "printer '%s' has job %lld '%s', not '%s'", d->name,
                          (long long)p->last_job.id, p->last_job.name, j.name);
    log_printer(LOG_INFO, d->name, "re-attached to '%s', job %lld on the printer (%s)", j.name,
                (long long)p->last_job.id, p->last.state);
    p->job = j;
    p->job_id = p->last_job.id;
    p->uploads = PL_UPLOAD_TRIES; /* never sent again */
    p->verify = false;
    d->status.lines_total = j.lines_total;
    d->status.lines_acked = 0;
    d->status.job_started_ms = loop_now_ms(d->loop);
    struct netjob_obs ob;
    drv_prusalink_observe(&p->last, p->job_id, &ob);
    ob.file = p->last_job.name;
    struct netjob_verdict v;
    netjob_judge(NETJOB_RUNNING, &ob, &v);
    if (v.ends)
        p->job_id = 0;
    netjob_report(d, &p->job, &v, p->last.progress);
    return SF_OK;
}

static int
want(struct prusalink *p, enum rq w)
{
    p->want = w;
    preempt_poll(p);
    kick(p);
    return SF_OK;
}

static int
pl_pause(struct drv *d, struct sf_err *err)
{
    struct prusalink *p = PL(d);
    if (p->job.phase != NETJOB_RUNNING || d->status.state != DRV_PRINTING || p->rq == RQ_UPLOAD ||
        p->verify)
        return sf_err_set(err, SF_EAGAIN, "printer '%s': nothing to pause", d->name);
    d->status.state = DRV_PAUSED;
    return want(p, RQ_PAUSE);
}

static int
pl_resume(struct drv *d, struct sf_err *err)
{
    struct prusalink *p = PL(d);
    if (p->job.phase != NETJOB_RUNNING || d->status.state != DRV_PAUSED)
        return sf_err_set(err, SF_EAGAIN, "printer '%s': nothing to resume", d->name);
    d->status.state = DRV_PRINTING;
    return want(p, RQ_RESUME);
}

static int
pl_cancel(struct drv *d, struct sf_err *err)
{
    struct prusalink *p = PL(d);
    if (p->job.phase == NETJOB_NONE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s': no job to cancel", d->name);
    if (p->rq == RQ_UPLOAD || p->verify) {
        if (p->rq == RQ_UPLOAD) {
            httpc_cancel(p->req);
            p->req = NULL;
            p->rq = RQ_NONE;
        }
        end_job(p, DRV_IDLE, DRV_EV_JOB_CANCELLED, "");
        schedule(p, 0);
        return SF_OK;
    }
    p->job.phase = NETJOB_CANCELLING;
    return want(p, RQ_CANCEL);
}

static int
pl_command(struct drv *d, const char *line, struct sf_err *err)
{
    (void)line;
    return sf_err_set(err, SF_EUNSUPP,
                      "printer '%s': PrusaLink has no endpoint for a console command", d->name);
}

static void
pl_close(struct drv *d)
{
    struct prusalink *p = PL(d);
    quiet(p);
    p->open = false;
    p->want = RQ_NONE;
    netjob_state(d, DRV_OFFLINE, NULL);
}

static void
pl_destroy(struct drv *d)
{
    struct prusalink *p = PL(d);
    quiet(p);
    httpc_put(p->http);
    free(p);
}

static const struct drv_ops prusalink_ops = {
    .version = DRV_OPS_VERSION,
    .kind = "prusalink",
    .open = pl_open,
    .start_job = pl_start_job,
    .pause = pl_pause,
    .resume = pl_resume,
    .cancel = pl_cancel,
    .command = pl_command,
    .close = pl_close,
    .destroy = pl_destroy,
    .attach = pl_attach,
};

struct drv *
drv_prusalink_new(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event, void *ud,
                  struct sf_err *err)
{
    const char *url = cfg->url;
    if (!url || !url[0]) {
        sf_err_set(err, SF_EINVAL, "printer '%s': driver prusalink needs a url", cfg->name);
        return NULL;
    }
    if (strncmp(url, "http://", 7) != 0 && strncmp(url, "https://", 8) != 0) {
        sf_err_set(err, SF_EINVAL, "printer '%s': url '%s' is not http:// or https://", cfg->name,
                   url);
        return NULL;
    }
    struct prusalink *p = mem_calloc(1, sizeof(*p));
    if (!p) {
        sf_err_set(err, SF_ENOMEM, "printer '%s': out of memory", cfg->name);
        return NULL;
    }
    size_t n = strlen(url);
    while (n > 0 && url[n - 1] == '/')
        n--;
    if (n >= sizeof(p->url)) {
        free(p);
        sf_err_set(err, SF_EINVAL, "printer '%s': url too long", cfg->name);
        return NULL;
    }
    memcpy(p->url, url, n);
    p->url[n] = '\0';
    size_t h = 0;
    if (cfg->api_key && cfg->api_key[0]) {
        snprintf(p->key_hdr, sizeof(p->key_hdr), "X-Api-Key: %s", cfg->api_key);
        p->hdrs[h++] = p->key_hdr;
    }
    p->hdrs[h] = "Accept: application/json";
    if (cfg->user && cfg->user[0]) {
        snprintf(p->user, sizeof(p->user), "%s", cfg->user);
        snprintf(p->password, sizeof(p->password), "%s", cfg->password ? cfg->password : "");
    }
    p->poll_ms = cfg->poll_ms > 0 ? cfg->poll_ms : PL_POLL_MS;
    p->http = httpc_get(l, err);
    if (!p->http) {
        free(p);
        return NULL;
    }
    p->base.ops = &prusalink_ops;
    p->base.loop = l;
    snprintf(p->base.name, sizeof(p->base.name), "%s", cfg->name ? cfg->name : "?");
    p->base.on_event = on_event;
    p->base.ud = ud;
    p->base.status.state = DRV_OFFLINE;
    return &p->base;
}
