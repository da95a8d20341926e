/*
 * api_writes.c - the API's job writes and printer actions through the
 * farm's store queue, answered once committed (api_writes.h).
 *
 * Why: each of these wrote on the loop's own connection, so a store held
 * busy (another process holding SQLite's write lock: 5 s a write, then an
 * error) stopped every printer's stream while the operator's request
 * waited; on PostgreSQL each is a network round trip.  Now the store's
 * thread writes it (storeq_call), in order with the farm's writes, while
 * the request waits suspended (http_defer), and the loop goes on.
 *
 * A write that the queue tries again (the store busy) must not be done
 * twice: each request's struct api_write records what is done (the file
 * adopted, the job added) and a retry goes on from there.
 *
 * Thread: the loop thread; the *_write functions on the store's thread,
 * touching only their struct api_write's fields down to `size`.
 */
#include "api_writes.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/log.h"
#include "../base/mem.h"
#include "../farm/farm_remote.h"
#include "../farm/jobctl.h"
#include "api_compat.h"
#include "api_json.h"
#include "api_remote.h"
#include "partcheck.h"

/*
 * A write waiting for the store.  The store's thread reads and writes the
 * fields down to `size`; the loop the rest.  The answer may come after
 * api_free (a NULL ws: the farm's queue drains when the daemon stops).
 */
struct api_write {
    int64_t id;                /* the job; after an add or again, the new one */
    int n;                     /* a priority, or the places to move */
    bool move;                 /* n is a move */
    struct job_opts o;         /* a new job's options */
    char tmp[1200];            /* a new job's upload, adopted on the thread */
    const struct store *store; /* whose data dir it goes to (read only) */
    bool adopted, added;       /* done already: not again on a retry */
    int adopt_rc;              /* the adopt's failure, kept for a retry */
    struct sf_err adopt_err;
    char sha[STORE_SHA_HEX];
    char on[64]; /* a cancel found the job on this printer (jobctl_cancel_stored_on) */
    /* the answer, read on the store's thread after the write (answer_read) */
    struct job_row j;
    struct print_row *prints; /* with a 200's job */
    size_t n_prints;
    int64_t size;
    /* the loop's */
    struct api_writes *ws;  /* NULL once the API is freed */
    struct http_defer *d;   /* the request's answer to come */
    char printer[64];       /* an action on this printer: answered with it; "": with the job */
    char who[16];           /* the operator (route_key_label): a cancel another host carries */
    char *command;          /* a manual command's line: the printer's answer carries it */
    int status;             /* 201 (a new job: {"job"}) or 200 */
    bool not_now;           /* a refusal of the job rules (SF_EINVAL) is "not now" (409) */
    bool answering;         /* the answer's read follows the write on the store's thread */
    struct api_write *next; /* in ws->pending */
};

/* After a write on the loop (rc SF_OK): the job as it is now; else the failure. */
static void
job_changed(struct api_writes *ws, int64_t id, int rc, const struct sf_err *err,
            struct http_resp *resp)
{
    if (rc) {
        http_fail(resp, rc, err->msg);
        return;
    }
    ws->job(ws->ud, id, resp); /* read at once on the loop: the client waits for its change */
    ws->changed(ws->ud);
}

static void link_pending(struct api_writes *ws, struct api_write *w);

/* On the store's thread, after the write: the job as it is now for the answer (a 201's: the job
   alone; a 200's: with its prints), so the loop's connection reads nothing. */
static int
answer_read(struct store *s, void *ud, struct sf_err *err)
{
    struct api_write *w = ud;
    free(w->prints); /* a retry reads again */
    w->prints = NULL;
    w->n_prints = 0;
    int rc = store_job_get(s, w->id, &w->j, err);
    if (rc == SF_OK && w->status != 201)
        rc = store_prints(s, w->id, &w->prints, &w->n_prints, err);
    return rc;
}

static void on_written(void *ud, const struct storeq_result *r);

/* The write of w committed: read its answer behind it on the store's thread (true), or false
   (no queue, no memory): the loop reads it now, as before. */
static bool
answer_later(struct api_writes *ws, struct api_write *w)
{
    struct storeq *q = farm_storeq(ws->farm);
    w->answering = true;
    if (q && storeq_read(q, answer_read, w, on_written, w) == SF_OK) {
        link_pending(ws, w);
        return true;
    }
    w->answering = false;
    return false;
}

/* The answer read on the store's thread (answer_read) as the API gives it. */
static void
answer_json(struct api_writes *ws, struct api_write *w, struct http_resp *resp)
{
    if (w->status == 201) {
        log_info("api", "job %lld: '%s' submitted, %d copies", (long long)w->id, w->j.opts.name,
                 w->j.opts.copies);
        resp->status = 201;
        resp->json = json_pack("{so}", "job", api_job_json(&w->j));
    } else {
        json_t *prints = json_array();
        for (size_t i = 0; prints && i < w->n_prints; i++)
            json_array_append_new(prints, api_print_json(&w->prints[i]));
        resp->json = json_pack("{soso}", "job", api_job_json(&w->j), "prints", prints);
        if (ws->job_more)
            ws->job_more(ws->ud, w->id, resp);
    }
    ws->changed(ws->ud);
}

/* A write came back from the store's thread (then its answer's read, answer_read): answer it
   with the job or printer as it is. */
static void
on_written(void *ud, const struct storeq_result *r)
{
    struct api_write *w = ud;
    struct http_resp resp = { .status = 200 };
    struct api_writes *ws = w->ws;
    if (ws) {
        for (struct api_write **pp = &ws->pending; *pp; pp = &(*pp)->next)
            if (*pp == w) {
                *pp = w->next;
                break;
            }
        /* a cancel of a job on another host's printer: that host stops it, and answers; by
           the job's id, so that it refuses once its printer prints another job */
        char id[24];
        snprintf(id, sizeof(id), "%lld", (long long)w->id);
        if (r->rc == SF_EAGAIN && w->on[0] && !w->answering &&
            api_remote_answer(ws->farm, w->on, FARM_REMOTE_CANCEL_JOB, id, w->who, w->d)) {
            free(w);
            return;
        }
        struct sf_err err = *r->err;
        int rc = r->rc;
        if (rc == SF_EINVAL && w->not_now)
            rc = err.code = SF_EAGAIN;
        if (rc && w->adopted && w->adopt_rc) { /* submit_write: the part was not stored */
            rc = w->adopt_rc;
            sf_err_set(&err, rc, "the part could not be stored, try again: %s", w->adopt_err.msg);
        }
        struct job_row j;
        if (rc == SF_OK && !w->printer[0] && !w->answering && answer_later(ws, w))
            return; /* answered once the job is read */
        if (rc) {
            if (w->printer[0] && !w->command) /* acted: the store refused the write */
                log_warn("api", "printer %s: %s", w->printer, err.msg);
            http_fail(&resp, rc, err.msg);
        } else if (w->answering) {
            answer_json(ws, w, &resp);
        } else if (w->printer[0]) {
            ws->printer(ws->ud, w->printer, &resp);
            if (w->command && resp.json)
                json_object_set_new(resp.json, "command", json_string(w->command));
            ws->changed(ws->ud);
        } else if (w->status != 201) {
            job_changed(ws, w->id, SF_OK, NULL, &resp);
        } else if ((rc = store_job_get(ws->store, w->id, &j, &err)) == SF_OK) {
            log_info("api", "job %lld: '%s' submitted, %d copies", (long long)w->id, j.opts.name,
                     j.opts.copies);
            resp.status = 201;
            resp.json = json_pack("{so}", "job", api_job_json(&j));
            ws->changed(ws->ud);
        } else {
            http_fail(&resp, rc, err.msg);
        }
    }
    http_defer_answer(w->d, &resp);
    free(w->prints);
    free(w->command);
    free(w);
}

/* Defer resp's answer to w (linked into ws); false when out of memory (answer now). */
static bool
defer(struct api_writes *ws, struct http_resp *resp, struct api_write *w)
{
    if (!(w->d = http_defer(resp)))
        return false;
    w->ws = ws;
    w->store = ws->store;
    return true;
}

/* Take back a deferral whose write was refused at once (answered now). */
static void
undefer(struct http_resp *resp)
{
    free(resp->defer);
    resp->defer = NULL;
}

static void
link_pending(struct api_writes *ws, struct api_write *w)
{
    w->next = ws->pending;
    ws->pending = w;
}

/*
 * Post write fn (NULL: nothing, the answer follows what is queued) for w
 * on the farm's store queue, the answer deferred until it commits.  False
 * when there is no queue or no memory: the caller writes now, as before.
 */
static bool
post(struct api_writes *ws, struct http_resp *resp, struct api_write *w, storeq_call_fn fn)
{
    struct storeq *q = farm_storeq(ws->farm);
    if (!q || !defer(ws, resp, w))
        return false;
    if (storeq_call(q, fn, w, NULL, on_written, w)) {
        undefer(resp);
        return false;
    }
    link_pending(ws, w);
    return true;
}

/* On the store's thread: a new job from its upload (jobs_submit); each half once. */
static int
submit_write(struct store *s, void *ud, struct sf_err *err)
{
    struct api_write *w = ud;
    if (!w->adopted) { /* the file system's half: not tried again (its temporary is moved) */
        w->adopted = true;
        w->adopt_rc = store_file_adopt(w->store, w->tmp, w->sha, &w->size, &w->adopt_err);
    }
    if (w->adopt_rc) {
        /* Not the queue's to retry: the adoption is not tried again (its temporary has
           moved), so waiting out STOREQ_RETRY_MS on its busy or unreachable answer held
           every write behind it for a minute, then said the same.  Reported at once (a
           code the queue does not retry); on_written answers with adopt_rc (503). */
        *err = w->adopt_err;
        return SF_ECANCELED;
    }
    int rc = store_file_record(s, w->sha, w->size, err);
    if (rc == SF_OK && !w->added && (rc = store_job_add(s, &w->o, w->sha, &w->id, err)) == SF_OK)
        w->added = true; /* a retry after this adds nothing twice */
    return rc;
}

static void
jobs_submit(void *ctx, const struct route_args *args, const struct http_req *req,
            struct http_resp *resp)
{
    (void)args;
    struct api_writes *ws = ctx;
    struct sf_err err;
    if (!req->upload_name || !req->upload) {
        http_error(resp, 400, "multipart field 'file' (the part) is required");
        return;
    }
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "%s", req->upload_name);
    const char *opts = http_req_field(req, "options");
    char clipped[65];
    for (size_t i = 0; i < req->n_fields; i++)
        if (strcmp(req->field_name[i], "options") != 0) {
            http_error(resp, 400, "unknown form field '%s' (expected 'file' and 'options')",
                       route_clip(clipped, sizeof(clipped), req->field_name[i]));
            return;
        }
    if (api_opts_parse(opts ? opts : "", opts ? strlen(opts) : 0, &o, &err) ||
        job_opts_validate(&o, &err)) {
        http_error(resp, 400, "%s", err.msg);
        return;
    }
    if (api_compat_is_gcode(o.name)) {
        http_error(resp, 400,
                   "'%s' is G-code: send it to POST /api/files/local, which prints it as is",
                   o.name);
        return;
    }
    /* Options are good: only now does the file reach its content address, once
       its content is what its name says (on a refusal, http.c discards the
       temporary file). */
    struct upload *u = req->upload;
    char sha[STORE_SHA_HEX];
    int64_t id;
    struct job_row j;
    int rc = partcheck_file(store_file_tmp_path(u->f), o.name, &err);
    if (rc) {
        http_fail(resp, rc, err.msg);
        return;
    }
    /* Through the farm's store queue: the file adopted and the job added on its thread, the
       answer once committed (the upload's temporary stays until then). */
    struct api_write *w = mem_calloc(1, sizeof(*w));
    if (w) {
        w->o = o;
        w->status = 201;
        snprintf(w->tmp, sizeof(w->tmp), "%s", store_file_tmp_path(u->f));
        if (post(ws, resp, w, submit_write))
            return;
        free(w);
    }
    rc = store_file_commit(u->f, sha, &err);
    u->f = NULL; /* commit frees the writer either way */
    if (rc || (rc = store_job_add(ws->store, &o, sha, &id, &err)) ||
        (rc = store_job_get(ws->store, id, &j, &err))) {
        http_fail(resp, rc, err.msg);
        return;
    }
    log_info("api", "job %lld: '%s' submitted, %d copies", (long long)id, o.name, o.copies);
    resp->status = 201;
    resp->json = json_pack("{so}", "job", api_job_json(&j));
    ws->changed(ws->ud);
}

/* On the store's thread: a priority or a move (job_order). */
static int
order_write(struct store *s, void *ud, struct sf_err *err)
{
    struct api_write *w = ud;
    return w->move ? store_job_move(s, w->id, w->n, err)
                   : store_job_set_priority(s, w->id, w->n, err);
}

/* On the store's thread: an operator's cancel of a job on no printer, or a restart. */
static int
cancel_write(struct store *s, void *ud, struct sf_err *err)
{
    struct api_write *w = ud;
    return jobctl_cancel_stored_on(s, w->id, w->on, sizeof(w->on), err);
}

static int
restart_write(struct store *s, void *ud, struct sf_err *err)
{
    return jobctl_restart(s, ((struct api_write *)ud)->id, err);
}

/* On the store's thread: "print again" (jobctl_again), once. */
static int
again_write(struct store *s, void *ud, struct sf_err *err)
{
    struct api_write *w = ud;
    if (w->added)
        return SF_OK;
    int64_t id;
    int rc = jobctl_again(s, w->id, &id, err);
    if (rc == SF_OK) {
        w->id = id;
        w->added = true;
    }
    return rc;
}

/* PATCH /api/jobs/ID {"priority": N}, or POST /api/jobs/ID/move {"by": -1 | 1}: one place
   up or down among the waiting jobs. */
static void
job_order(void *ctx, const struct route_args *args, const struct http_req *req,
          struct http_resp *resp)
{
    struct api_writes *ws = ctx;
    struct sf_err err;
    bool move = strcmp(req->method, "POST") == 0;
    int n;
    int rc = move ? api_move_parse(req->body, req->body_len, &n, &err)
                  : api_priority_parse(req->body, req->body_len, &n, &err);
    struct api_write *w = rc == SF_OK ? mem_calloc(1, sizeof(*w)) : NULL;
    if (w) {
        *w = (struct api_write){ .id = args->id, .n = n, .move = move, .status = 200 };
        if (post(ws, resp, w, order_write))
            return;
        free(w);
    }
    if (rc == SF_OK)
        rc = move ? store_job_move(ws->store, args->id, n, &err)
                  : store_job_set_priority(ws->store, args->id, n, &err);
    job_changed(ws, args->id, rc, &err, resp);
}

/* POST /api/jobs/ID/cancel, or /restart: the operator prints an
   interrupted job's copy again from the start. */
static void
job_cancel_restart(void *ctx, const struct route_args *args, const struct http_req *req,
                   struct http_resp *resp)
{
    struct api_writes *ws = ctx;
    struct sf_err err;
    bool cancel = strcmp(strrchr(req->path, '/'), "/cancel") == 0;
    /* A job on a printer is cancelled by stopping the printer, answered once that is written;
       any other through the store's queue. */
    const char *on = cancel ? jobctl_printer_of(ws->farm, args->id) : NULL;
    struct api_write *w = mem_calloc(1, sizeof(*w));
    if (w && !on) {
        *w = (struct api_write){ .id = args->id, .status = 200, .not_now = true };
        route_key_label(req, w->who, sizeof(w->who));
        if (post(ws, resp, w, cancel ? cancel_write : restart_write))
            return;
    }
    if (w && on) {
        *w = (struct api_write){ .id = args->id, .status = 200, .not_now = true };
        if (defer(ws, resp, w)) {
            int rc =
                jobctl_printer_action_then(ws->farm, on, PRINTER_ACT_CANCEL, on_written, w, &err);
            if (rc == SF_OK) {
                link_pending(ws, w);
                return;
            }
            undefer(resp);
            free(w);
            job_changed(ws, args->id, rc, &err, resp);
            return;
        }
    }
    free(w);
    int rc = cancel ? jobctl_cancel(ws->farm, ws->store, args->id, &err)
                    : jobctl_restart(ws->store, args->id, &err);
    job_changed(ws, args->id, rc, &err, resp);
}

/* POST /api/jobs/ID/again: a new job from the same file and options (jobctl_again). */
static void
job_again(void *ctx, const struct route_args *args, const struct http_req *req,
          struct http_resp *resp)
{
    (void)req;
    struct api_writes *ws = ctx;
    struct sf_err err;
    int64_t id;
    struct job_row j;
    struct api_write *w = mem_calloc(1, sizeof(*w));
    if (w) {
        *w = (struct api_write){ .id = args->id, .status = 201 };
        if (post(ws, resp, w, again_write))
            return;
        free(w);
    }
    int rc = jobctl_again(ws->store, args->id, &id, &err);
    if (rc || (rc = store_job_get(ws->store, id, &j, &err))) {
        http_fail(resp, rc, err.msg);
        return;
    }
    log_info("api", "job %lld: '%s' submitted again as job %lld", (long long)args->id, j.opts.name,
             (long long)id);
    resp->status = 201;
    resp->json = json_pack("{so}", "job", api_job_json(&j));
    ws->changed(ws->ud);
}

/* The operator continues an interrupted job where its printer stopped. */
static void
job_resume(void *ctx, const struct route_args *args, const struct http_req *req,
           struct http_resp *resp)
{
    struct api_writes *ws = ctx;
    struct sf_err err;
    int64_t line;
    if (api_resume_parse(req->body, req->body_len, &line, &err)) {
        http_error(resp, 400, "%s", err.msg);
        return;
    }
    /* the job read on the store's thread, resumed when it comes back, answered once its
       RESUME committed; a refusal of the job rules is "not now" */
    struct api_write *w = ws->farm ? mem_calloc(1, sizeof(*w)) : NULL;
    if (w)
        *w = (struct api_write){ .id = args->id, .status = 200, .not_now = true };
    if (w && defer(ws, resp, w)) {
        int rc = jobctl_resume_then(ws->farm, args->id, line, on_written, w, &err);
        if (rc == SF_OK) {
            link_pending(ws, w);
            return;
        }
        undefer(resp);
        free(w);
        http_fail(resp, rc, err.msg);
        return;
    }
    free(w); /* no queue, out of memory: read on the loop */
    int rc = jobctl_resume(ws->farm, args->id, line, &err);
    job_changed(ws, args->id, rc, &err, resp);
}

void
api_writes_printer_act(struct api_writes *ws, const char *name, enum printer_action act,
                       const char *who, struct http_resp *resp)
{
    struct sf_err err;
    if (api_remote_try(ws->farm, name, printer_action_name(act), NULL, who, resp))
        return; /* another host's printer: carried to it */
    struct api_write *w = mem_calloc(1, sizeof(*w));
    if (w && defer(ws, resp, w)) {
        snprintf(w->printer, sizeof(w->printer), "%s", name);
        int rc = jobctl_printer_action_then(ws->farm, name, act, on_written, w, &err);
        if (rc == SF_OK) {
            link_pending(ws, w);
            return;
        }
        undefer(resp); /* refused now: answered now */
        free(w);
        http_fail(resp, rc, err.msg);
        return;
    }
    free(w); /* out of memory: acted without waiting for the store */
    int rc = jobctl_printer_action(ws->farm, name, act, &err);
    if (rc) {
        http_fail(resp, rc, err.msg);
        return;
    }
    ws->printer(ws->ud, name, resp);
    ws->changed(ws->ud);
}

void
api_writes_printer_cmd(struct api_writes *ws, const char *name, const char *line, const char *who,
                       struct http_resp *resp)
{
    struct sf_err err;
    struct api_write *w = mem_calloc(1, sizeof(*w));
    if (w && (w->command = mem_strdup(line)) && defer(ws, resp, w)) {
        snprintf(w->printer, sizeof(w->printer), "%s", name);
        int rc = jobctl_printer_command_then(ws->farm, name, line, who, on_written, w, &err);
        if (rc == SF_OK) {
            link_pending(ws, w);
            return;
        }
        undefer(resp); /* refused now: answered now */
        free(w->command);
        free(w);
        http_fail(resp, rc, err.msg);
        return;
    }
    if (w)
        free(w->command);
    free(w); /* out of memory: sent with the loop's read */
    int rc = jobctl_printer_command(ws->farm, name, line, who, &err);
    if (rc) {
        http_fail(resp, rc, err.msg);
        return;
    }
    ws->printer(ws->ud, name, resp);
    if (resp->json)
        json_object_set_new(resp->json, "command", json_string(line));
}

void
api_writes_orphan(struct api_writes *ws)
{
    for (struct api_write *w = ws->pending; w; w = w->next)
        w->ws = NULL;
    ws->pending = NULL;
}

static const struct route rows[] = {
    /* methods, pattern, match, body, scope, handler, 405 message */
    { ROUTE_POST, "/api/jobs", NULL, HTTP_BODY_UPLOAD, ROUTE_WRITE, jobs_submit, ROUTE_405 },
    { ROUTE_PATCH, "/api/jobs/{id}", NULL, HTTP_BODY_JSON, ROUTE_WRITE, job_order, ROUTE_405 },
    { ROUTE_POST, "/api/jobs/{id}/move", NULL, HTTP_BODY_JSON, ROUTE_WRITE, job_order, ROUTE_405 },
    { ROUTE_POST, "/api/jobs/{id}/cancel", NULL, HTTP_BODY_NONE, ROUTE_WRITE, job_cancel_restart,
      ROUTE_405 },
    { ROUTE_POST, "/api/jobs/{id}/restart", NULL, HTTP_BODY_NONE, ROUTE_WRITE, job_cancel_restart,
      ROUTE_405 },
    { ROUTE_POST, "/api/jobs/{id}/resume", NULL, HTTP_BODY_JSON, ROUTE_WRITE, job_resume,
      ROUTE_405 },
    { ROUTE_POST, "/api/jobs/{id}/again", NULL, HTTP_BODY_NONE, ROUTE_WRITE, job_again, ROUTE_405 },
};

const struct route *
api_writes_routes(size_t *n)
{
    *n = sizeof(rows) / sizeof(rows[0]);
    return rows;
}
