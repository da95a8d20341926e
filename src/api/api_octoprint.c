/*
 * api_octoprint.c - the farm as one OctoPrint printer for OctoPrint
 * clients (see api_octoprint.h).
 *
 * Shapes: OctoPrint 1.10/1.11 docs (api/general.rst login and
 * currentuser, api/files.rst, api/printer.rst, api/job.rst) and
 * server/api/__init__.py (User.as_dict plus session); FDM Monster's and
 * OctoPrint's web UI sessions (tests/replay/clients) are what they are
 * checked against.  Permissions and groups follow OctoPrint's defaults:
 * admins hold ADMIN and the rest, the readonly group STATUS and
 * FILES_LIST.
 *
 * Thread: the loop thread; files_read on the API's reader thread.
 */
#include "api_octoprint.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "../base/mem.h"
#include "../farm/jobctl.h"
#include "api_compat.h"
#include "api_octopush.h"
#include "api_read.h"

/* ---- the user ---- */

static json_t *
permissions(bool rw)
{
    return rw ? json_pack("[ssssssss]", "ADMIN", "STATUS", "CONNECTION", "FILES_LIST",
                          "FILES_UPLOAD", "FILES_DOWNLOAD", "FILES_SELECT", "PRINT")
              : json_pack("[ss]", "STATUS", "FILES_LIST");
}

static json_t *
groups(bool rw)
{
    return rw ? json_pack("[ss]", "admins", "users") : json_pack("[s]", "readonly");
}

void
api_octoprint_user(void *ctx, const struct route_args *args, const struct http_req *req,
                   struct http_resp *resp)
{
    (void)ctx, (void)args;
    char label[32];
    route_key_label(req, label, sizeof(label));
    resp->json = json_pack("{ss so so}", "name", label, "permissions", permissions(!req->read_only),
                           "groups", groups(!req->read_only));
}

void
api_octoprint_login(void *ctx, const struct route_args *args, const struct http_req *req,
                    struct http_resp *resp)
{
    (void)args;
    const struct api_compat_env *env = ctx;
    json_t *b = req->body_len ? json_loadb(req->body, req->body_len, 0, NULL) : NULL;
    if (req->body_len && !json_is_object(b)) {
        json_decref(b);
        http_error(resp, 400, "body must be a JSON object ({\"passive\": true})");
        return;
    }
    /* OctoPrint reads the query when the JSON is empty (FDM Monster sends {} ?passive=true) */
    bool passive = json_object_size(b) ? json_object_get(b, "passive") != NULL
                                       : http_req_arg(req, "passive") != NULL;
    bool userpass = json_object_get(b, "user") && json_object_get(b, "pass");
    json_decref(b);
    if (userpass) {
        http_error(resp, 403, "no users here: log in with \"passive\": true and an API key");
        return;
    }
    if (!passive) {
        http_error(resp, 400, "field 'passive' is required (user and pass are not taken)");
        return;
    }
    char label[32], session[SESSION_TOKEN_LEN + 1];
    route_key_label(req, label, sizeof(label));
    struct sf_err err;
    int rc = api_octopush_login(env->push, req->key, session, &err);
    if (rc) {
        http_fail(resp, rc, err.msg);
        return;
    }
    bool rw = !req->read_only;
    json_t *roles = rw ? json_pack("[ss]", "user", "admin") : json_pack("[s]", "user");
    resp->json = json_pack("{ss sb so so ss sb sb so s{s[s] s[s]} s{} sb ss}", "name", label,
                           "active", 1, "permissions", permissions(rw), "groups", groups(rw),
                           "session", session, "admin", rw, "user", 1, "roles", roles, "needs",
                           "role", rw ? "admin" : "user", "group", rw ? "admins" : "readonly",
                           "settings", "_is_external_client", 0, "_login_mechanism", "apikey");
}

/* ---- the files: the newest jobs ---- */

struct files {
    char base[256]; /* scheme and host for refs, "" for relative ones */
};

/* The stored G-code's (else the upload's) size in bytes; 0 if not known. */
static json_int_t
file_size(struct store *s, const struct job_row *j)
{
    char path[1024];
    struct stat st;
    const char *sha = j->gcode_sha[0] ? j->gcode_sha : j->file_sha;
    if (!sha[0] || store_file_path(s, sha, path, sizeof(path), NULL) || stat(path, &st))
        return 0;
    return (json_int_t)st.st_size;
}

static json_t *
file_entry(struct store *s, const struct job_row *j, const char *base)
{
    char path[JOB_NAME_MAX + 32], esc[3 * JOB_NAME_MAX + 1], res[512 + 3 * JOB_NAME_MAX];
    char dl[320];
    snprintf(path, sizeof(path), "job-%lld/%s", (long long)j->id, j->opts.name);
    api_compat_url_escape(j->opts.name, esc, sizeof(esc));
    snprintf(res, sizeof(res), "%s/api/files/local/job-%lld/%s", base, (long long)j->id, esc);
    snprintf(dl, sizeof(dl), "%s/api/jobs/%lld", base, (long long)j->id);
    json_t *est = j->est_known && j->est_s >= 0 ? json_real(j->est_s) : json_null();
    return json_pack("{ss ss ss ss s[ss] ss sI sI s{ss ss} s{so} s{si si} s{ss sI}}", "name",
                     j->opts.name, "display", j->opts.name, "path", path, "type", "machinecode",
                     "typePath", "machinecode", "gcode", "origin", "local", "size", file_size(s, j),
                     "date", (json_int_t)(j->created_ms / 1000), "refs", "resource", res,
                     "download", dl, "gcodeAnalysis", "estimatedPrintTime", est, "prints",
                     "success", j->counts.copies_done, "failure", j->counts.failures, "slimfarm",
                     "state", job_state_name(j->state), "job_id", (json_int_t)j->id);
}

static void
files_read(struct store *s, void *ud, struct http_resp *resp)
{
    const struct files *fl = ud;
    struct store_job_filter f = { .newest_first = true };
    struct job_row *rows = NULL;
    size_t n = 0;
    struct sf_err err;
    if (store_job_page(s, &f, API_OCTOPRINT_FILES, &rows, &n, NULL, &err)) {
        http_fail(resp, err.code, err.msg);
        return;
    }
    json_t *files = json_array();
    for (size_t i = 0; i < n; i++)
        json_array_append_new(files, file_entry(s, &rows[i], fl->base));
    free(rows);
    /* free and total: the farm stores what it is sent; OctoPrint clients want numbers */
    resp->json =
        json_pack("{so sI sI}", "files", files, "free", (json_int_t)0, "total", (json_int_t)0);
}

void
api_octoprint_files(void *ctx, const struct route_args *args, const struct http_req *req,
                    struct http_resp *resp)
{
    (void)args;
    const struct api_compat_env *env = ctx;
    struct files *fl = mem_calloc(1, sizeof(*fl));
    if (!fl) {
        http_error(resp, 500, "out of memory");
        return;
    }
    api_compat_base_url(req, fl->base, sizeof(fl->base));
    api_read_run(env->reads, resp, files_read, NULL, fl, free);
}

/* ---- the farm as one printer ---- */

bool
api_octoprint_summarize(struct farm *f, const char *printer, struct api_octoprint_summary *s)
{
    *s = (struct api_octoprint_summary){ .left_s = -1 };
    size_t n = f ? farm_printer_count(f) : 0;
    double sum = 0;
    for (size_t i = 0; i < n; i++) {
        struct printer_info pi;
        farm_printer_info(f, i, &pi);
        if (printer && printer[0] && strcmp(pi.cfg->name, printer) != 0)
            continue;
        s->n++;
        s->offline += pi.state == PRINTER_OFFLINE;
        s->error += pi.state == PRINTER_ERROR;
        if (pi.state != PRINTER_PRINTING && pi.state != PRINTER_PAUSED)
            continue;
        s->printing += pi.state == PRINTER_PRINTING;
        s->paused += pi.state == PRINTER_PAUSED;
        sum += pi.progress;
        s->job = s->printing + s->paused == 1 ? pi.job_id : 0;
        if (pi.time_left_s > s->left_s)
            s->left_s = pi.time_left_s;
    }
    size_t busy = s->printing + s->paused;
    s->progress = busy ? sum / (double)busy : 0;
    if (s->printing)
        s->text = "Printing";
    else if (s->paused)
        s->text = "Paused";
    else if (s->offline == s->n)
        s->text = "Offline";
    else if (s->offline + s->error == s->n)
        s->text = "Error";
    else
        s->text = "Operational";
    return s->n > 0 || !printer || !printer[0];
}

json_t *
api_octoprint_state_json(const struct api_octoprint_summary *s)
{
    bool down = strcmp(s->text, "Offline") == 0 || strcmp(s->text, "Error") == 0;
    return json_pack("{ss s{sb sb sb sb sb sb sb sb sb sb}}", "text", s->text, "flags",
                     "operational", !down, "ready", !down && !s->printing && !s->paused, "printing",
                     s->printing > 0, "paused", !s->printing && s->paused, "pausing", 0,
                     "cancelling", 0, "error", strcmp(s->text, "Error") == 0, "closedOrError", down,
                     "sdReady", 0, "finishing", 0);
}

/* GET /api/job's answer, with s's one job j (NULL: none, or not read). */
static json_t *
job_json(const struct job_row *jr, const struct api_octoprint_summary *s)
{
    bool one = jr != NULL;
    struct job_row j = one ? *jr : (struct job_row){ 0 };
    json_t *name = one ? json_string(j.opts.name) : json_null();
    json_t *path = json_null();
    if (one) {
        char p[JOB_NAME_MAX + 32];
        snprintf(p, sizeof(p), "job-%lld/%s", (long long)j.id, j.opts.name);
        path = json_string(p);
    }
    json_t *est = one && j.est_known && j.est_s >= 0 ? json_real(j.est_s) : json_null();
    bool busy = s->printing + s->paused > 0;
    json_t *completion = busy ? json_real(100.0 * s->progress) : json_null();
    json_t *left = busy && s->left_s >= 0 ? json_integer(s->left_s) : json_null();
    return json_pack("{s{s{so so ss} so} s{so sn so} ss}", "job", "file", "name", name, "path",
                     path, "origin", "local", "estimatedPrintTime", est, "progress", "completion",
                     completion, "printTime", "printTimeLeft", left, "state", s->text);
}

static json_t *
printer_json(const struct api_octoprint_summary *s)
{
    return json_pack("{so s{} s{sb} s{si si si si si}}", "state", api_octoprint_state_json(s),
                     "temperature", "sd", "ready", 0, "slimfarm", "printers", (int)s->n, "printing",
                     (int)s->printing, "paused", (int)s->paused, "offline", (int)s->offline,
                     "error", (int)s->error);
}

json_t *
api_octoprint_job_json(const struct job_row *j, const struct api_octoprint_summary *s)
{
    return job_json(j, s);
}

/* A GET /api/job on its way: the one job's row read on the API's reader (the farm's
   summary taken when it came). */
struct job_ask {
    struct api_octoprint_summary s;
    bool one; /* j was read */
    struct job_row j;
};

static void
job_ask_read(struct store *st, void *ud, struct http_resp *resp)
{
    (void)resp;
    struct job_ask *q = ud;
    q->one = store_job_get(st, q->s.job, &q->j, NULL) == SF_OK;
}

static void
job_ask_finish(void *ud, struct http_resp *resp)
{
    struct job_ask *q = ud;
    resp->json = job_json(q->one ? &q->j : NULL, &q->s);
}

void
api_octoprint_state(void *ctx, const struct route_args *args, const struct http_req *req,
                    struct http_resp *resp)
{
    (void)args;
    const struct api_compat_env *env = ctx;
    struct api_octoprint_summary s;
    const char *printer = http_req_arg(req, "printer");
    if (!api_octoprint_summarize(env->farm, printer, &s)) {
        http_error(resp, 404, "printer '%.64s' (query 'printer') is not in the farm", printer);
        return;
    }
    if (strcmp(req->path, "/api/printer") == 0 || !s.job) {
        resp->json = strcmp(req->path, "/api/printer") == 0 ? printer_json(&s) : job_json(NULL, &s);
        return;
    }
    struct job_ask *q = mem_calloc(1, sizeof(*q));
    if (!q) {
        http_error(resp, 500, "out of memory");
        return;
    }
    q->s = s;
    api_read_run(env->reads, resp, job_ask_read, job_ask_finish, q, free);
}

void
api_octoprint_job_command(void *ctx, const struct route_args *args, const struct http_req *req,
                          struct http_resp *resp)
{
    (void)args;
    const struct api_compat_env *env = ctx;
    json_t *b = json_loadb(req->body, req->body_len, 0, NULL);
    const char *cmd = b ? json_string_value(json_object_get(b, "command")) : NULL;
    char c[33];
    snprintf(c, sizeof(c), "%s", cmd ? cmd : "");
    json_decref(b);
    if (!c[0]) {
        http_error(resp, 400, "body must be JSON with a \"command\"");
        return;
    }
    if (strcmp(c, "cancel") != 0) {
        http_error(resp, 409,
                   "command '%s': the farm starts and pauses its printers itself (POST "
                   "/api/printers/NAME/pause); only cancel is taken here",
                   c);
        return;
    }
    struct api_octoprint_summary s;
    api_octoprint_summarize(env->farm, NULL, &s);
    if (!s.job) {
        http_error(resp, 409,
                   "%zu jobs print: cancel takes effect only when exactly one does (POST "
                   "/api/jobs/ID/cancel cancels one)",
                   s.printing + s.paused);
        return;
    }
    struct sf_err err;
    int rc = jobctl_cancel(env->farm, env->store, s.job, &err);
    if (rc) {
        http_fail(resp, rc, err.msg);
        return;
    }
    resp->status = 204;
    if (env->changed)
        env->changed(env->ud);
}
