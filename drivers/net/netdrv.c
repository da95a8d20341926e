/*
 * netdrv.c - the polling core of the Moonraker, PrusaLink and OctoPrint drivers
 * (netdrv.h): the request slot, the poll timer, losing and regaining
 * contact, the upload whose fate a poll settles, and the job operations
 * that are the same for all.
 *
 * Why one core: the drivers differ in their printers' words (which
 * netjob.c maps) and in their requests, not in how a farm must treat a
 * printer that runs its own file: the same rules for a lost answer, a
 * refused upload or a printer that stops answering mid-print keep the
 * farm's behaviour the same whichever printer it drives.
 *
 * Thread: the loop thread.
 */
#include "netdrv.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/base/log.h"

static struct netdrv *
ND(struct drv *d)
{
    return (struct netdrv *)d;
}

const char *
netdrv_rq_name(int kind, const char *const *own, size_t n_own)
{
    static const char *const n[] = { "none",  "status poll", "server info", "upload",
                                     "pause", "resume",      "cancel" };
    if (kind >= 0 && kind < NETDRV_RQ_OWN)
        return n[kind];
    size_t i = (size_t)(kind - NETDRV_RQ_OWN);
    return kind >= NETDRV_RQ_OWN && i < n_own ? own[i] : "?";
}

int
netdrv_init(struct netdrv *n, struct loop *l, const struct drv_config *cfg,
            const struct drv_ops *ops, const struct netdrv_ops *nops, drv_event_fn on_event,
            void *ud, struct sf_err *err)
{
    const char *name = cfg->name ? cfg->name : "?";
    const char *url = cfg->url;
    if (!url || !url[0])
        return sf_err_set(err, SF_EINVAL, "printer '%s': driver %s needs a url", name, ops->kind);
    if (strncmp(url, "http://", 7) != 0 && strncmp(url, "https://", 8) != 0)
        return sf_err_set(err, SF_EINVAL, "printer '%s': url '%s' is not http:// or https://", name,
                          url);
    size_t len = strlen(url);
    while (len > 0 && url[len - 1] == '/')
        len--;
    if (len >= sizeof(n->url))
        return sf_err_set(err, SF_EINVAL, "printer '%s': url too long", name);
    memcpy(n->url, url, len);
    n->url[len] = '\0';
    if (cfg->api_key && cfg->api_key[0]) {
        if (strpbrk(cfg->api_key, "\r\n") ||
            (size_t)snprintf(n->key_hdr, sizeof(n->key_hdr), "X-Api-Key: %s", cfg->api_key) >=
                sizeof(n->key_hdr))
            return sf_err_set(err, SF_EINVAL, "printer '%s': api_key too long or not one line",
                              name);
    }
    n->http = httpc_get(l, err);
    if (!n->http)
        return err ? err->code : SF_ENOMEM;
    n->nops = nops;
    n->base.ops = ops;
    n->base.loop = l;
    snprintf(n->base.name, sizeof(n->base.name), "%s", name);
    n->base.on_event = on_event;
    n->base.ud = ud;
    n->base.status.state = DRV_OFFLINE;
    n->poll_ms = cfg->poll_ms > 0 ? cfg->poll_ms : nops->poll_ms;
    n->poll_idle_ms = cfg->poll_idle_ms > 0 ? cfg->poll_idle_ms : NETDRV_IDLE_MS;
    if (n->poll_idle_ms < n->poll_ms)
        n->poll_idle_ms = n->poll_ms;
    n->poll_only = cfg->poll_only;
    return SF_OK;
}

/* ---- the request slot and the timer ---- */

static void
on_done(struct httpc_req *r, const struct httpc_result *res, void *ud)
{
    (void)r;
    struct netdrv *n = ud;
    int kind = n->rq;
    n->req = NULL;
    n->rq = NETDRV_RQ_NONE;
    n->nops->reply(n, kind, res);
    n->nops->kick(n);
}

static void
on_progress(struct httpc_req *r, uint64_t sent, uint64_t total, void *ud)
{
    (void)r;
    struct netdrv *n = ud;
    if (total > 0)
        snprintf(n->base.status.message, sizeof(n->base.status.message), "uploading %u%%",
                 (unsigned)(sent * 100 / total));
}

bool
netdrv_request(struct netdrv *n, int kind, struct httpc_opts *o)
{
    o->done = on_done;
    o->ud = n;
    if (!o->timeout_ms)
        o->timeout_ms = n->nops->timeout_ms;
    if (kind == NETDRV_RQ_UPLOAD) {
        o->timeout_ms = -1;
        o->stall_ms = n->nops->upload_stall_ms;
        o->progress = on_progress;
        n->uploads++;
    }
    struct sf_err err;
    n->req = httpc_start(n->http, o, &err);
    if (!n->req) {
        log_printer(LOG_ERROR, n->base.name, "%s: %s", o->url, err.msg);
        return false;
    }
    n->rq = kind;
    return true;
}

static void
on_timer(struct loop *l, void *ud)
{
    (void)l;
    struct netdrv *n = ud;
    n->timer = 0;
    if (!n->open)
        return;
    bool ok = !n->req && n->nops->poll(n);
    if (!n->timer) /* (poll may have set the next one, and poll_now with it) */
        n->poll_now = false;
    if (!ok) /* an action holds the slot: poll after it */
        netdrv_schedule(n, netdrv_period(n));
}

void
netdrv_schedule(struct netdrv *n, int64_t ms)
{
    if (!n->open)
        return;
    if (n->timer)
        loop_timer_cancel(n->base.loop, n->timer);
    n->timer = loop_timer_add(n->base.loop, ms, on_timer, n);
    n->poll_now = ms == 0;
}

int
netdrv_period(const struct netdrv *n)
{
    enum drv_state st = n->base.status.state;
    bool works = n->job.phase != NETJOB_NONE || st == DRV_PRINTING || st == DRV_PAUSED;
    return works ? n->poll_ms : n->poll_idle_ms;
}

/* Stop talking: no request, no timer (the job, if any, is kept). */
static void
quiet(struct netdrv *n)
{
    if (n->req)
        httpc_cancel(n->req);
    n->req = NULL;
    n->rq = NETDRV_RQ_NONE;
    if (n->timer)
        loop_timer_cancel(n->base.loop, n->timer);
    n->timer = 0;
}

void
netdrv_preempt_poll(struct netdrv *n)
{
    if (n->req && (n->rq == NETDRV_RQ_POLL || n->rq == NETDRV_RQ_INFO ||
                   (n->nops->side_rq && n->rq == n->nops->side_rq) ||
                   (n->nops->poll_rq && n->rq == n->nops->poll_rq))) {
        httpc_cancel(n->req);
        n->req = NULL;
        n->rq = NETDRV_RQ_NONE;
        netdrv_schedule(n, netdrv_period(n));
    }
}

bool
netdrv_send_want(struct netdrv *n)
{
    if (!n->open || n->req)
        return false;
    if (n->want != NETDRV_RQ_NONE) {
        int w = n->want;
        n->want = NETDRV_RQ_NONE;
        if (n->nops->start(n, w))
            return false;
    }
    return true;
}

/* ---- replies ---- */

enum netdrv_outcome
netdrv_judge(struct netdrv *n, int kind, const struct httpc_result *res, char *why, size_t len)
{
    char text[128];
    if (n->nops->judge)
        return n->nops->judge(n, kind, res, why, len);
    if (res->code != SF_OK) {
        snprintf(why, len, "%s", res->err.msg);
        return NETDRV_DOWN;
    }
    if (res->status >= 200 && res->status < 300)
        return NETDRV_OK;
    n->nops->error_text(res->body, res->body_len, text, sizeof(text));
    if (res->status == 401 ||
        (res->status == 403 && !(kind == NETDRV_RQ_UPLOAD && n->nops->upload_403))) {
        snprintf(why, len, "authentication failed (%s): HTTP %ld%s%s", n->nops->key_hint,
                 res->status, text[0] ? " " : "", text);
        return NETDRV_AUTH;
    }
    snprintf(why, len, "HTTP %ld%s%s", res->status, text[0] ? ": " : "", text);
    return res->status >= 500 ? NETDRV_DOWN : NETDRV_REFUSED;
}

static void
forget(struct netdrv *n)
{
    n->verify = false;
    n->upload_cut = false;
    n->want = NETDRV_RQ_NONE;
    if (n->nops->forget)
        n->nops->forget(n);
}

void
netdrv_time_left(struct netdrv *n, const struct netjob_obs *ob, double secs)
{
    struct drv_status *st = &n->base.status;
    st->has_time_left = n->job.phase != NETJOB_NONE && ob->ours && secs >= 0;
    st->time_left_s = st->has_time_left ? (int64_t)(secs + 0.5) : 0;
}

void
netdrv_end_job(struct netdrv *n, enum drv_state st, enum drv_event ev, const char *msg)
{
    struct netjob_verdict v = { .state = st, .ends = true, .ev = ev };
    snprintf(v.message, sizeof(v.message), "%s", msg);
    forget(n);
    netjob_report(&n->base, &n->job, &v, n->base.status.progress);
}

void
netdrv_contact_lost(struct netdrv *n, const char *why)
{
    n->fails++;
    if (n->nops->lost)
        n->nops->lost(n);
    if (n->job.phase != NETJOB_NONE && n->fails < n->nops->job_tries) {
        /* a short outage: ride it out, the printer prints on */
        int ms = drv_backoff_ms(n->fails - 1);
        log_printer(LOG_WARN, n->base.name, "%s; asking again in %d ms", why, ms);
        snprintf(n->base.status.message, sizeof(n->base.status.message),
                 "unreachable: %s (retrying)", why);
        netdrv_schedule(n, ms);
        return;
    }
    if (n->job.phase != NETJOB_NONE && n->verify && n->upload_cut) {
        /* The upload was cut short and could not be sent again: the
           printer never had the file whole, so it cannot be printing it.
           The job failed to start (the farm's retry policy sends it
           again), rather than interrupted: left to attach(), a printer
           that keeps no record of its jobs (PrusaLink idle) could only
           say that how it ended is not known, for an operator to settle. */
        char msg[sizeof(n->upload_err) + 64];
        snprintf(msg, sizeof(msg), "unreachable before the upload could be sent again (%s)",
                 n->upload_err);
        log_printer(LOG_WARN, n->base.name, "offline before job '%s' reached it: %s", n->job.name,
                    why);
        netdrv_end_job(n, DRV_IDLE, DRV_EV_JOB_FAILED, msg);
    }
    if (n->job.phase != NETJOB_NONE) {
        /* The printer prints on without us: the farm marks the job
           interrupted and offers it back through attach() once the
           printer answers again.  So does an upload whose fate is unknown
           (curl read the file to its end): attach() settles it from what
           the printer then shows, or says it cannot (an operator checks
           the bed), where failing it would have the farm print it again
           on a bed that may hold it. */
        log_printer(LOG_WARN, n->base.name, "offline with job '%s' on the printer: %s", n->job.name,
                    why);
        snprintf(n->lost_name, sizeof(n->lost_name), "%s", n->job.name);
        n->job.phase = NETJOB_NONE;
        n->verify = false;
        n->want = NETDRV_RQ_NONE;
    }
    quiet(n);
    n->open = false;
    netjob_state(&n->base, DRV_OFFLINE, "%s", why);
}

enum netdrv_outcome
netdrv_upload_reply(struct netdrv *n, const struct httpc_result *res)
{
    char why[200];
    enum netdrv_outcome o = netdrv_judge(n, NETDRV_RQ_UPLOAD, res, why, sizeof(why));
    if (n->job.phase != NETJOB_RUNNING) { /* cancelled meanwhile (netdrv_cancel) */
        if (n->job.phase == NETJOB_CANCELLING) {
            if (o == NETDRV_OK)
                n->fails = 0;
            netdrv_schedule(n, 0); /* is it printing? the cancel waits for this poll */
        }
        return NETDRV_REFUSED;
    }
    switch (o) {
    case NETDRV_OK:
        n->fails = 0;
        n->base.status.message[0] = '\0';
        return o;
    case NETDRV_AUTH:
        netdrv_end_job(n, DRV_IDLE, DRV_EV_JOB_FAILED, why);
        netdrv_contact_lost(n, why);
        return o;
    case NETDRV_REFUSED: /* 409: the printer's reason ("Printer is busy") */
        netdrv_end_job(n, DRV_IDLE, DRV_EV_JOB_FAILED, why);
        netdrv_schedule(n, 0);
        return o;
    case NETDRV_DOWN:
        /* Sent in part, or whole with the answer lost: the printer knows,
           and the next poll asks it.  Not a failed contact: the upload has
           its own budget (upload_tries), and the poll that follows counts
           if the printer does not answer.  Counted as both, one cut upload
           and three 5xx answers to the polls after it (job_tries - 1, a
           short outage the job should ride out) took the printer offline
           and left a job that never reached it interrupted. */
        snprintf(n->upload_err, sizeof(n->upload_err), "upload failed: %s", why);
        log_printer(LOG_WARN, n->base.name,
                    "upload failed (%s); asking the printer whether it arrived", why);
        n->verify = true;
        /* Fewer bytes read than the file holds: the printer cannot have it
           whole.  All of it read proves nothing either way: a small file
           sits whole in curl's buffer and the socket's before the cut (a
           10938-byte job cut half-way by the simulator was read whole),
           and a body sent whole whose answer was lost may be printing.
           Such a job is left interrupted if contact is lost (see
           netdrv_contact_lost): sending it again could print it twice. */
        n->upload_cut = res->body_read < (uint64_t)n->job.size;
        if (n->nops->lost)
            n->nops->lost(n);
        netdrv_schedule(n, drv_backoff_ms(n->fails));
        return o;
    }
    return o;
}

bool
netdrv_settle(struct netdrv *n, const struct netjob_obs *ob)
{
    if (!n->verify)
        return false;
    if (ob->ours || n->job.phase == NETJOB_CANCELLING) {
        /* (cancelling: never sent again; the judge ends it when the
           printer does not run it, or the cancel stops it) */
        n->verify = false; /* the upload did arrive and start: judge it as any job */
        return false;
    }
    if (ob->remote != NETJOB_R_IDLE && ob->remote != NETJOB_R_DONE &&
        ob->remote != NETJOB_R_CANCELLED && ob->remote != NETJOB_R_FAILED)
        return false; /* busy with something else, halted, restarting: the judge says */
    /* the printer is free and does not run our file: send it again */
    if (n->uploads < n->nops->upload_tries) {
        n->verify = false;
        if (n->nops->start(n, NETDRV_RQ_UPLOAD)) {
            netjob_state(&n->base, DRV_PRINTING, "uploading again (%s)", n->upload_err);
            return true;
        }
    }
    netdrv_end_job(n, DRV_IDLE, DRV_EV_JOB_FAILED, n->upload_err);
    netdrv_schedule(n, netdrv_period(n));
    return true;
}

void
netdrv_report(struct netdrv *n, const struct netjob_obs *ob, double progress)
{
    struct netjob_verdict v;
    netjob_judge(n->job.phase, ob, &v);
    if (n->job.phase != NETJOB_NONE && !v.ends && n->verify)
        snprintf(v.message, sizeof(v.message), "%s", n->upload_err);
    if (n->nops->lines && n->job.phase != NETJOB_NONE) {
        v.has_lines = true;
        v.lines = n->nops->lines(n, progress);
    }
    if (v.ends)
        forget(n);
    netjob_report(&n->base, &n->job, &v, progress);
}

enum netdrv_outcome
netdrv_answered(struct netdrv *n, int kind, const struct httpc_result *res, char *why, size_t len)
{
    enum netdrv_outcome o = netdrv_judge(n, kind, res, why, len);
    if (o == NETDRV_OK) {
        n->fails = 0;
        netdrv_schedule(n, 0); /* see what it did */
    }
    return o;
}

void
netdrv_action_reply(struct netdrv *n, int kind, const struct httpc_result *res)
{
    char why[200];
    enum netdrv_outcome o = netdrv_answered(n, kind, res, why, sizeof(why));
    if (o == NETDRV_OK)
        return;
    const char *what = netdrv_rq_name(kind, NULL, 0);
    log_printer(LOG_WARN, n->base.name, "%s: %s", what, why);
    snprintf(n->base.status.message, sizeof(n->base.status.message), "%s refused: %s", what, why);
    if (o == NETDRV_DOWN || o == NETDRV_AUTH)
        netdrv_contact_lost(n, why);
    else
        netdrv_schedule(n, 0);
}

/* ---- attach ---- */

int
netdrv_attach_prepare(struct netdrv *n, const char *gcode_path, const struct drv_job_scan *scan,
                      struct netjob *j, struct sf_err *err)
{
    struct drv *d = &n->base;
    if (!n->open || !n->have_last || d->status.state == DRV_OFFLINE ||
        d->status.state == DRV_CONNECTING || n->job.phase != NETJOB_NONE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is %s", d->name,
                          drv_state_name(d->status.state));
    return netjob_prepare(j, gcode_path, scan, n->path, sizeof(n->path), err);
}

void
netdrv_adopt(struct netdrv *n, const struct netjob *j, const struct netjob_obs *ob, double progress)
{
    struct drv *d = &n->base;
    n->job = *j;
    n->uploads = n->nops->upload_tries; /* never sent again */
    n->verify = false;
    n->lost_name[0] = '\0';
    d->status.lines_total = j->lines_total;
    d->status.lines_acked = 0;
    d->status.job_started_ms = loop_now_ms(d->loop);
    netdrv_report(n, ob, progress);
}

/* ---- drv_ops ---- */

int
netdrv_open(struct drv *d, struct sf_err *err)
{
    (void)err;
    struct netdrv *n = ND(d);
    if (n->open)
        return SF_OK;
    n->open = true;
    n->have_last = false;
    if (n->nops->lost)
        n->nops->lost(n);
    if (n->job.phase == NETJOB_NONE)
        netjob_state(d, DRV_CONNECTING, "%s", "");
    netdrv_schedule(n, 0);
    return SF_OK;
}

int
netdrv_start_job(struct drv *d, const char *gcode_path, uint64_t first_line,
                 const struct drv_job_scan *scan, struct sf_err *err)
{
    struct netdrv *n = ND(d);
    if (first_line > 0)
        return sf_err_set(err, SF_EUNSUPP,
                          "printer '%s': a %s printer runs a job from its start only (it reads "
                          "the file itself)",
                          d->name, n->nops->product);
    if (!n->open || d->status.state != DRV_IDLE || n->job.phase != NETJOB_NONE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is not idle (%s)", d->name,
                          drv_state_name(d->status.state));
    struct netjob j;
    int rc = netjob_prepare(&j, gcode_path, scan, n->path, sizeof(n->path), err);
    if (rc)
        return rc;
    n->job = j;
    n->uploads = 0;
    n->lost_name[0] = '\0';
    forget(n);
    d->status.lines_total = j.lines_total;
    d->status.lines_acked = 0;
    d->status.progress = 0;
    d->status.has_time_left = false;
    d->status.job_started_ms = loop_now_ms(d->loop);
    netdrv_preempt_poll(n);
    if (n->req || !n->nops->start(n, NETDRV_RQ_UPLOAD)) {
        n->job.phase = NETJOB_NONE;
        return sf_err_set(err, SF_EAGAIN, "printer '%s': the upload could not start", d->name);
    }
    netjob_state(d, DRV_PRINTING, "uploading");
    return SF_OK;
}

/* The job is still starting: its upload, or the request that starts it, is on its way. */
static bool
starting(const struct netdrv *n)
{
    return n->rq == NETDRV_RQ_UPLOAD || (n->nops->start_rq && n->rq == n->nops->start_rq);
}

static int
want(struct netdrv *n, int w)
{
    n->want = w;
    netdrv_preempt_poll(n);
    n->nops->kick(n);
    return SF_OK;
}

int
netdrv_pause(struct drv *d, struct sf_err *err)
{
    struct netdrv *n = ND(d);
    if (n->job.phase != NETJOB_RUNNING || d->status.state != DRV_PRINTING || starting(n) ||
        n->verify)
        return sf_err_set(err, SF_EAGAIN, "printer '%s': nothing to pause", d->name);
    d->status.state = DRV_PAUSED; /* the farm moves itself; the poll confirms */
    return want(n, NETDRV_RQ_PAUSE);
}

int
netdrv_resume(struct drv *d, struct sf_err *err)
{
    struct netdrv *n = ND(d);
    if (n->job.phase != NETJOB_RUNNING || d->status.state != DRV_PAUSED)
        return sf_err_set(err, SF_EAGAIN, "printer '%s': nothing to resume", d->name);
    d->status.state = DRV_PRINTING;
    return want(n, NETDRV_RQ_RESUME);
}

int
netdrv_cancel(struct drv *d, struct sf_err *err)
{
    struct netdrv *n = ND(d);
    if (n->job.phase == NETJOB_NONE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s': no job to cancel", d->name);
    bool uploading = n->rq == NETDRV_RQ_UPLOAD && n->req;
    if ((uploading && httpc_body_read(n->req) < (uint64_t)n->job.size) ||
        (!uploading && n->verify && n->upload_cut)) {
        /* The printer cannot have the file whole (curl has not read it all
           yet, or the last try was cut short), and a printer never starts
           a file it did not get whole: stop the upload, and it is over. */
        if (uploading) {
            httpc_cancel(n->req);
            n->req = NULL;
            n->rq = NETDRV_RQ_NONE;
        }
        netdrv_end_job(n, DRV_IDLE, DRV_EV_JOB_CANCELLED, "");
        netdrv_schedule(n, 0);
        return SF_OK;
    }
    /* Otherwise the printer may be printing it: the body sent whole with
       its answer still on the way (PrusaLink answers a Print-After-Upload
       PUT after it has started the file), the request that starts it
       sent, or an upload whose fate is unknown (verify).  Cutting the
       request then and calling the job cancelled left the printer printing
       a job the farm thought stopped, and the farm sent the next one to a
       busy printer (a part on a bed it thought free, on a real one).  So
       the cancel goes to the printer once the request in flight has its
       answer (want waits for the slot), and the polls settle it: a printer
       without our job ends it cancelled (netjob.c: judge_cancelling). */
    n->job.phase = NETJOB_CANCELLING; /* status stays printing until the printer says */
    return want(n, NETDRV_RQ_CANCEL);
}

void
netdrv_close(struct drv *d)
{
    struct netdrv *n = ND(d);
    quiet(n);
    n->open = false;
    n->want = NETDRV_RQ_NONE;
    if (n->nops->lost)
        n->nops->lost(n);
    netjob_state(d, DRV_OFFLINE, NULL);
}

void
netdrv_destroy(struct drv *d)
{
    struct netdrv *n = ND(d);
    quiet(n);
    httpc_put(n->http);
    free(n);
}

/* ---- JSON ---- */

json_t *
netdrv_json_load(const char *who, const char *body, size_t len, const char *what, bool object,
                 struct sf_err *err)
{
    json_error_t je;
    json_t *root = json_loadb(body, len, JSON_REJECT_DUPLICATES, &je);
    if (!root) {
        sf_err_set(err, SF_EINVAL, "%s %s: not JSON: %s (line %d)", who, what, je.text, je.line);
    } else if (object && !json_is_object(root)) {
        sf_err_set(err, SF_EINVAL, "%s %s: not an object", who, what);
        json_decref(root);
        root = NULL;
    }
    return root;
}

int
netdrv_json_str(const char *who, json_t *obj, const char *key, const char *where, char *out,
                size_t n, bool required, struct sf_err *err)
{
    json_t *v = json_object_get(obj, key);
    out[0] = '\0';
    if (!v || json_is_null(v))
        return required ? sf_err_set(err, SF_EINVAL, "%s %s.%s: missing", who, where, key) : SF_OK;
    if (!json_is_string(v))
        return sf_err_set(err, SF_EINVAL, "%s %s.%s: not a string", who, where, key);
    snprintf(out, n, "%s", json_string_value(v));
    return SF_OK;
}

int
netdrv_json_num(const char *who, json_t *obj, const char *key, const char *where, double *out,
                bool required, struct sf_err *err)
{
    json_t *v = json_object_get(obj, key);
    if (!v || json_is_null(v))
        return required ? sf_err_set(err, SF_EINVAL, "%s %s.%s: missing", who, where, key) : SF_OK;
    if (!json_is_number(v))
        return sf_err_set(err, SF_EINVAL, "%s %s.%s: not a number", who, where, key);
    *out = json_number_value(v);
    return SF_OK;
}

int
netdrv_json_int(const char *who, json_t *obj, const char *key, const char *where, int64_t *out,
                bool required, struct sf_err *err)
{
    double d = (double)*out;
    int rc = netdrv_json_num(who, obj, key, where, &d, required, err);
    if (rc == SF_OK && (d < 0 || d > 9.0e15))
        return sf_err_set(err, SF_EINVAL, "%s %s.%s: %g is out of range", who, where, key, d);
    *out = (int64_t)d;
    return rc;
}

int
netdrv_json_obj(const char *who, json_t *obj, const char *key, const char *where, json_t **out,
                struct sf_err *err)
{
    json_t *v = json_object_get(obj, key);
    *out = v && json_is_object(v) ? v : NULL;
    if (v && !json_is_null(v) && !*out)
        return sf_err_set(err, SF_EINVAL, "%s %s.%s: not an object", who, where, key);
    return SF_OK;
}

void
netdrv_first_line(const char *body, size_t len, char *out, size_t n)
{
    if (n == 0)
        return;
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
