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

#include "../../src/base/log.h"
#include "../../src/base/mem.h"
#include "netdrv.h"

/* ---- JSON helpers: field access that names what is wrong ---- */

#define WHO "prusalink"

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
    json_t *root = netdrv_json_load(WHO, body, len, "status", true, err);
    if (!root)
        return SF_EINVAL;
    int rc;
    json_t *pr, *job, *sto, *sp;
    if ((rc = netdrv_json_obj(WHO, root, "printer", "status", &pr, err)) ||
        (rc = netdrv_json_obj(WHO, root, "job", "status", &job, err)) ||
        (rc = netdrv_json_obj(WHO, root, "storage", "status", &sto, err)))
        goto out;
    if (!pr) { /* the one required member (StatusPrinter.state with it) */
        rc = sf_err_set(err, SF_EINVAL, "prusalink status.printer: missing");
        goto out;
    }
    if ((rc = netdrv_json_str(WHO, pr, "state", "printer", st->state, sizeof(st->state), true,
                              err)) ||
        (rc = netdrv_json_num(WHO, pr, "temp_nozzle", "printer", &st->nozzle_c, false, err)) ||
        (rc = netdrv_json_num(WHO, pr, "target_nozzle", "printer", &st->nozzle_target_c, false,
                              err)) ||
        (rc = netdrv_json_num(WHO, pr, "temp_bed", "printer", &st->bed_c, false, err)) ||
        (rc = netdrv_json_num(WHO, pr, "target_bed", "printer", &st->bed_target_c, false, err)) ||
        (rc = netdrv_json_obj(WHO, pr, "status_printer", "printer", &sp, err)))
        goto out;
    if (sp) {
        json_t *ok = json_object_get(sp, "ok");
        if (ok && json_is_false(ok) &&
            (rc = netdrv_json_str(WHO, sp, "message", "printer.status_printer", st->message,
                                  sizeof(st->message), false, err)))
            goto out;
    }
    if (job) {
        st->has_job = true;
        double tr = -1;
        if ((rc = netdrv_json_int(WHO, job, "id", "job", &st->job_id, false, err)) ||
            (rc = netdrv_json_num(WHO, job, "progress", "job", &st->progress, false, err)) ||
            (rc = percent(&st->progress, "job", err)) ||
            (rc = netdrv_json_num(WHO, job, "time_remaining", "job", &tr, false, err)))
            goto out;
        st->time_remaining_s = tr < 0 ? -1 : (int64_t)tr;
    }
    if (sto) {
        char path[64];
        json_t *ro = json_object_get(sto, "read_only");
        if ((rc = netdrv_json_str(WHO, sto, "path", "storage", path, sizeof(path), true, err)))
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
    json_t *root = netdrv_json_load(WHO, body, len, "job", true, err);
    if (!root)
        return SF_EINVAL;
    int rc;
    json_t *file;
    if ((rc = netdrv_json_int(WHO, root, "id", "job", &job->id, true, err)) ||
        (rc = netdrv_json_str(WHO, root, "state", "job", job->state, sizeof(job->state), true,
                              err)) ||
        (rc = netdrv_json_num(WHO, root, "progress", "job", &job->progress, true, err)) ||
        (rc = percent(&job->progress, "job", err)) ||
        (rc = netdrv_json_obj(WHO, root, "file", "job", &file, err)))
        goto out;
    if (file) {
        if ((rc = netdrv_json_str(WHO, file, "display_name", "job.file", job->name,
                                  sizeof(job->name), false, err)) ||
            (!job->name[0] && (rc = netdrv_json_str(WHO, file, "name", "job.file", job->name,
                                                    sizeof(job->name), true, err))) ||
            (rc = netdrv_json_int(WHO, file, "size", "job.file", &job->size, false, err)))
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
    netdrv_first_line(body, len, out, n);
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
 * How it talks: netdrv.h's core (one request at a time, polls on a timer
 * that actions pre-empt, a short outage ridden out with a job on the
 * printer, a longer one offline with the job left to attach()), over
 * PrusaLink's v1 API: GET /api/v1/status every PL_POLL_MS (Prusa Connect
 * and PrusaSlicer poll the printer at about this rate), PUT
 * /api/v1/files/{storage}/{name} with Print-After-Upload: ?1 and
 * Overwrite: ?1 (the body streamed from disk), then GET /api/v1/job once
 * per job id to learn its file (so our job is told by name and size from
 * someone else's); pause and resume are PUT /api/v1/job/{id}/pause|resume,
 * cancel is DELETE /api/v1/job/{id}.  Every request says Accept:
 * application/json, so errors come as the spec's Error object and 409's
 * reason reaches the operator.  Auth is X-Api-Key (older firmware) or
 * user/password by HTTP Digest (current).  PrusaLink v1 has no endpoint
 * for a console command.
 *
 * How a print that ended unseen is told: the job id.  PrusaLink numbers
 * its jobs; while the printer shows FINISHED or STOPPED its status still
 * carries the last job's id, and /api/v1/job its file, so attach() finds
 * the print done or stopped.  Once the printer is idle again (the finished
 * screen dismissed) it keeps no record of the job: v1 has no job history,
 * and a file's metadata (GET /api/v1/files/...) says nothing of prints.
 * Then, or when the printer has run another job since (a newer id), how
 * our print ended cannot be known and attach() says so: the job stays
 * interrupted for an operator.
 */
#define PL_POLL_MS 1000 /* drv_config.poll_ms 0 */

enum { RQ_JOB = NETDRV_RQ_OWN }; /* GET /api/v1/job */

struct prusalink {
    struct netdrv n;
    const char *hdrs[3];           /* the key (if any), Accept, NULL */
    char user[64];                 /* digest user, "" for none */
    char password[128];            /* its password */
    struct prusalink_status last;  /* the last status (attach reads it) */
    struct prusalink_job last_job; /* what /api/v1/job last said */
    bool have_job;                 /* ... and it is still the printer's job */
    int64_t asked_id;              /* the job id /api/v1/job was last asked about */
    int64_t job_id;                /* our job's id on the printer, 0 until learnt; kept when
                                      contact is lost with it (n.lost_name) */
    char storage[32];              /* the printer's storage ("usb", "local") */
};

static struct prusalink *
PL(struct netdrv *n)
{
    return (struct prusalink *)n;
}

/* The job the last status reports is the one /api/v1/job last described. */
static bool
job_known(const struct prusalink *p, const struct prusalink_status *st)
{
    return st->has_job && p->have_job && p->last_job.id == st->job_id;
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
pl_start(struct netdrv *n, int kind)
{
    struct prusalink *p = PL(n);
    char url[768], name[400];
    const char *up_hdrs[6];
    struct httpc_opts o = { .method = "GET",
                            .url = url,
                            .headers = p->hdrs,
                            .user = p->user[0] ? p->user : NULL,
                            .password = p->password,
                            .digest = p->user[0] != '\0' };
    switch (kind) {
    case NETDRV_RQ_POLL:
        snprintf(url, sizeof(url), "%s/api/v1/status", n->url);
        break;
    case RQ_JOB:
        snprintf(url, sizeof(url), "%s/api/v1/job", n->url);
        break;
    case NETDRV_RQ_UPLOAD: {
        if (!escape(n->job.name, name, sizeof(name)))
            return false;
        snprintf(url, sizeof(url), "%s/api/v1/files/%s/%s", n->url,
                 p->storage[0] ? p->storage : "usb", name);
        o.method = "PUT";
        size_t h = 0;
        for (size_t i = 0; p->hdrs[i]; i++)
            up_hdrs[h++] = p->hdrs[i];
        up_hdrs[h++] = "Content-Type: application/octet-stream";
        up_hdrs[h++] = "Print-After-Upload: ?1";
        up_hdrs[h++] = "Overwrite: ?1";
        up_hdrs[h] = NULL;
        o.headers = up_hdrs;
        o.body_path = n->path;
        break;
    }
    case NETDRV_RQ_PAUSE:
    case NETDRV_RQ_RESUME:
        snprintf(url, sizeof(url), "%s/api/v1/job/%lld/%s", n->url, (long long)p->job_id,
                 kind == NETDRV_RQ_PAUSE ? "pause" : "resume");
        o.method = "PUT";
        break;
    case NETDRV_RQ_CANCEL:
        snprintf(url, sizeof(url), "%s/api/v1/job/%lld", n->url, (long long)p->job_id);
        o.method = "DELETE";
        break;
    default:
        return false;
    }
    return netdrv_request(n, kind, &o);
}

static bool
pl_poll(struct netdrv *n)
{
    return pl_start(n, NETDRV_RQ_POLL);
}

static void
on_status(struct prusalink *p, const struct httpc_result *res)
{
    struct netdrv *n = &p->n;
    char why[200];
    if (netdrv_judge(n, NETDRV_RQ_POLL, res, why, sizeof(why)) != NETDRV_OK) {
        netdrv_contact_lost(n, why);
        return;
    }
    struct prusalink_status st;
    struct sf_err err;
    if (drv_prusalink_parse_status(res->body, res->body_len, &st, &err)) {
        netdrv_contact_lost(n, err.msg);
        return;
    }
    n->fails = 0;
    p->last = st;
    n->have_last = true;
    if (st.storage[0] && !st.read_only)
        snprintf(p->storage, sizeof(p->storage), "%s", st.storage);
    netjob_temps(&n->base, st.nozzle_c, st.nozzle_target_c, st.bed_c, st.bed_target_c);
    /* A job we have not seen described: ask /api/v1/job for its file (once
       per job id) before judging, so a restarted daemon can recognise its
       print (attach) and a fresh upload is told from someone else's job. */
    if (!st.has_job) {
        p->have_job = false;
        p->asked_id = 0;
    } else if (!job_known(p, &st) && p->asked_id != st.job_id) {
        p->asked_id = st.job_id;
        if (pl_start(n, RQ_JOB))
            return;
    }
    bool known = job_known(p, &st);
    if (n->job.phase != NETJOB_NONE && p->job_id == 0 && known &&
        strcmp(p->last_job.name, n->job.name) == 0 &&
        (p->last_job.size == 0 || p->last_job.size == n->job.size)) {
        p->job_id = st.job_id;
        log_printer(LOG_INFO, n->base.name, "job '%s' is job %lld on the printer", n->job.name,
                    (long long)p->job_id);
    }
    struct netjob_obs ob;
    drv_prusalink_observe(&st, p->job_id, &ob);
    if (known)
        ob.file = p->last_job.name;
    if (n->job.phase != NETJOB_NONE && p->job_id == 0)
        ob.ours = false; /* a job we could not name is not known ours */
    if (netdrv_settle(n, &ob))
        return;
    if (n->job.phase != NETJOB_NONE && p->job_id == 0 && !n->verify &&
        (ob.remote == NETJOB_R_IDLE || ob.remote == NETJOB_R_BUSY) && n->uploads > 0 &&
        loop_now_ms(n->base.loop) - n->base.status.job_started_ms < 2 * n->poll_ms) {
        /* just uploaded: the printer takes a moment to start the file */
        netdrv_schedule(n, netdrv_period(n));
        return;
    }
    /* job.time_remaining (s): the firmware's own estimate (from the file's
       M73 R lines when the slicer wrote them) */
    netdrv_time_left(n, &ob, st.has_job ? (double)st.time_remaining_s : -1);
    netdrv_report(n, &ob, st.has_job ? st.progress : n->base.status.progress);
    netdrv_schedule(n, netdrv_period(n));
}

static void
on_job(struct prusalink *p, const struct httpc_result *res)
{
    struct netdrv *n = &p->n;
    char why[200];
    if (netdrv_judge(n, RQ_JOB, res, why, sizeof(why)) != NETDRV_OK) {
        netdrv_contact_lost(n, why); /* which asks about the job again */
        return;
    }
    if (res->status == 204) { /* no job after all */
        p->have_job = false;
        netdrv_schedule(n, 0);
        return;
    }
    struct prusalink_job job;
    struct sf_err err;
    if (drv_prusalink_parse_job(res->body, res->body_len, &job, &err)) {
        netdrv_contact_lost(n, err.msg);
        return;
    }
    p->last_job = job;
    p->have_job = true;
    netdrv_schedule(n, 0); /* the status again, now judged with the job's file */
}

static void
pl_reply(struct netdrv *n, int kind, const struct httpc_result *res)
{
    struct prusalink *p = PL(n);
    switch (kind) {
    case NETDRV_RQ_POLL:
        on_status(p, res);
        break;
    case RQ_JOB:
        on_job(p, res);
        break;
    case NETDRV_RQ_UPLOAD:
        if (netdrv_upload_reply(n, res) == NETDRV_OK) {
            n->base.status.job_started_ms = loop_now_ms(n->base.loop);
            netdrv_schedule(n, 0);
        }
        break;
    default:
        netdrv_action_reply(n, kind, res);
        break;
    }
}

static void
pl_kick(struct netdrv *n)
{
    struct prusalink *p = PL(n);
    if (!n->open || n->req || n->want == NETDRV_RQ_NONE)
        return;
    if (p->job_id == 0) {
        /* Learn the id first: the status polls do (on_status asks
           /api/v1/job of a job it does not know, and the kick after it
           sends the want).  Asking /api/v1/job from here left no slot for
           the poll that reads the answer: each kick asked again (a cancel
           while the upload's answer was on its way spun so). */
        return;
    }
    int w = n->want;
    n->want = NETDRV_RQ_NONE;
    pl_start(n, w);
}

static void
pl_forget(struct netdrv *n)
{
    PL(n)->job_id = 0;
}

/* Contact lost, or a new connection: what the printer said of its job is stale. */
static void
pl_lost(struct netdrv *n)
{
    struct prusalink *p = PL(n);
    p->have_job = false;
    p->asked_id = 0;
}

/* ---- drv_ops ---- */

static int
pl_attach(struct drv *d, const char *gcode_path, const struct drv_job_scan *scan,
          struct sf_err *err)
{
    struct prusalink *p = (struct prusalink *)d;
    struct netjob j;
    if (p->n.have_last && p->last.has_job && !job_known(p, &p->last))
        return sf_err_set(err, SF_EAGAIN, "printer '%s': its job is not described yet", d->name);
    int rc = netdrv_attach_prepare(&p->n, gcode_path, scan, &j, err);
    if (rc)
        return rc;
    /* the id of our job when contact was lost (this daemon run), or 0 */
    int64_t lost_id = strcmp(p->n.lost_name, j.name) == 0 ? p->job_id : 0;
    if (!p->last.has_job)
        return sf_err_set(err, SF_ENOTFOUND,
                          "printer '%s' is %s with no job: PrusaLink keeps no record of a job "
                          "once the printer is idle again, so how '%s' ended is not known "
                          "(check the bed)",
                          d->name, p->last.state, j.name);
    if (strcmp(p->last_job.name, j.name) != 0 ||
        (p->last_job.size != 0 && p->last_job.size != j.size))
        return sf_err_set(err, SF_ENOTFOUND,
                          "printer '%s' has job %lld '%s', not '%s': how that one ended is not "
                          "known",
                          d->name, (long long)p->last_job.id, p->last_job.name, j.name);
    if (lost_id && p->last_job.id != lost_id)
        return sf_err_set(err, SF_ENOTFOUND,
                          "printer '%s' has run job %lld of the same file since this job (job "
                          "%lld): how this one ended is not known",
                          d->name, (long long)p->last_job.id, (long long)lost_id);
    log_printer(LOG_INFO, d->name, "re-attached to '%s', job %lld on the printer (%s)", j.name,
                (long long)p->last_job.id, p->last.state);
    p->job_id = p->last_job.id;
    struct netjob_obs ob;
    drv_prusalink_observe(&p->last, p->job_id, &ob);
    ob.file = p->last_job.name;
    netdrv_adopt(&p->n, &j, &ob, p->last.progress);
    return SF_OK;
}

static int
pl_command(struct drv *d, const char *line, struct sf_err *err)
{
    (void)line;
    return sf_err_set(err, SF_EUNSUPP,
                      "printer '%s': PrusaLink has no endpoint for a console command", d->name);
}

static const struct drv_ops prusalink_ops = {
    .version = DRV_OPS_VERSION,
    .kind = "prusalink",
    .open = netdrv_open,
    .start_job = netdrv_start_job,
    .pause = netdrv_pause,
    .resume = netdrv_resume,
    .cancel = netdrv_cancel,
    .command = pl_command,
    .close = netdrv_close,
    .destroy = netdrv_destroy,
    .attach = pl_attach,
};

static const struct netdrv_ops prusalink_nops = {
    .product = "PrusaLink",
    .key_hint = "check api_key, or user and password",
    .poll_ms = PL_POLL_MS,
    .job_tries = 4,
    .upload_tries = 4,
    .timeout_ms = 10000,
    .upload_stall_ms = 30000,
    .start = pl_start,
    .poll = pl_poll,
    .reply = pl_reply,
    .kick = pl_kick,
    .error_text = drv_prusalink_error_text,
    .forget = pl_forget,
    .lost = pl_lost,
};

struct drv *
drv_prusalink_new(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event, void *ud,
                  struct sf_err *err)
{
    struct prusalink *p = mem_calloc(1, sizeof(*p));
    if (!p) {
        sf_err_set(err, SF_ENOMEM, "printer '%s': out of memory", cfg->name);
        return NULL;
    }
    if (netdrv_init(&p->n, l, cfg, &prusalink_ops, &prusalink_nops, on_event, ud, err)) {
        free(p);
        return NULL;
    }
    size_t h = 0;
    if (p->n.key_hdr[0])
        p->hdrs[h++] = p->n.key_hdr;
    p->hdrs[h] = "Accept: application/json";
    if (cfg->user && cfg->user[0]) {
        snprintf(p->user, sizeof(p->user), "%s", cfg->user);
        snprintf(p->password, sizeof(p->password), "%s", cfg->password ? cfg->password : "");
    }
    snprintf(p->n.base.caps.firmware, sizeof(p->n.base.caps.firmware), "PrusaLink");
    return &p->n.base;
}
