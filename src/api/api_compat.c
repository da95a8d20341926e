/*
 * api_compat.c - OctoPrint- and Moonraker-compatible routes for slicer
 * uploads, and /metrics (see api_compat.h).
 *
 * Why emulate and not ask slicers for a farm plugin: PrusaSlicer, Orca and
 * Cura already ship OctoPrint clients, and what they call is small (their
 * sources, read for this: PrusaSlicer and Orca src/slic3r/Utils/
 * OctoPrint.cpp test GET api/version, whose "text" must start "OctoPrint"
 * and which must hold "api", then POST api/files/local with fields print,
 * path, file and look only at the status; Cura's OctoPrintOutputDevice.py
 * reads api/settings, api/version, api/printerprofiles, polls api/printer
 * and api/job, uploads path, file[, select, print] and, when it queues or
 * waits, splits the 201's Location at "api/" and POSTs {"command":
 * "select"} to it).  Design: each upload is one farm job, named in its
 * Location as job-ID/NAME, so the select that follows finds it by id.
 * What the farm is not (one printer with a temperature, an SD card) is
 * answered with the neutral values those clients accept.
 *
 * Thread: the loop thread.
 */
#include "api_compat.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <time.h>

#include "../base/log.h"
#include "metrics.h"

bool
api_compat_is_gcode(const char *name)
{
    const char *dot = strrchr(name, '.');
    return dot && (strcasecmp(dot, ".gcode") == 0 || strcasecmp(dot, ".gco") == 0 ||
                   strcasecmp(dot, ".g") == 0);
}

static const char *
field(const struct http_req *req, const char *name)
{
    for (size_t i = 0; i < req->n_fields; i++)
        if (strcmp(req->field_name[i], name) == 0)
            return req->field_value[i];
    return NULL;
}

/* OctoPrint's and Moonraker's booleans: "true"/"false" (any case), "1"/"0". */
static int
boolean(const char *v, bool *out)
{
    if (!v || !v[0] || strcasecmp(v, "false") == 0 || strcmp(v, "0") == 0) {
        *out = false;
        return SF_OK;
    }
    if (strcasecmp(v, "true") == 0 || strcmp(v, "1") == 0) {
        *out = true;
        return SF_OK;
    }
    return SF_EINVAL;
}

int
api_compat_submit(const struct api_compat_env *env, const struct job_opts *o, void *upload,
                  int64_t *id, struct sf_err *err)
{
    char sha[STORE_SHA_HEX];
    int rc;
    if (api_compat_is_gcode(o->name)) {
        if (!env->farm)
            return sf_err_set(err, SF_EINVAL, "'%s': this daemon runs no farm to print G-code",
                              o->name);
        /* checked before it is stored: a refused file leaves nothing */
        struct farm_gcode g;
        if ((rc = farm_gcode_check(env->farm, env->upload_path(upload), o, &g, err)) ||
            (rc = env->upload_commit(upload, sha, err)))
            return rc;
        rc = farm_gcode_add(env->farm, o, sha, &g, id, err);
    } else {
        if ((rc = job_opts_validate(o, err)) || (rc = env->upload_commit(upload, sha, err)))
            return rc;
        rc = store_job_add(env->store, o, sha, id, err);
    }
    if (rc == SF_OK && env->changed)
        env->changed(env->ud);
    return rc;
}

/* ---- uploads ---- */

/* The scheme-and-host prefix of an absolute URL from the Host header, or
   "" when it holds anything but a host name, address and port. */
static void
base_url(const struct http_req *req, char *out, size_t cap)
{
    out[0] = '\0';
    const char *h = req->host;
    if (!h || !h[0] || strlen(h) > 200)
        return;
    for (const char *p = h; *p; p++)
        if (!((*p >= 'a' && *p <= 'z') || (*p >= 'A' && *p <= 'Z') || (*p >= '0' && *p <= '9') ||
              strchr(".-:[]", *p)))
            return;
    snprintf(out, cap, "http://%s", h);
}

/* name percent-encoded for a URL path segment (RFC 3986 unreserved kept). */
static void
url_escape(const char *name, char *out, size_t cap)
{
    size_t o = 0;
    for (const unsigned char *p = (const unsigned char *)name; *p && o + 4 < cap; p++) {
        if ((*p >= 'a' && *p <= 'z') || (*p >= 'A' && *p <= 'Z') || (*p >= '0' && *p <= '9') ||
            strchr("-._~", *p))
            out[o++] = (char)*p;
        else
            o += (size_t)snprintf(out + o, cap - o, "%%%02X", *p);
    }
    out[o] = '\0';
}

/* Common to both uploads: the file part, options, the job.  0 or an HTTP status. */
static int
upload(const struct api_compat_env *env, const struct http_req *req, struct http_resp *resp,
       int64_t *id)
{
    struct sf_err err;
    if (!req->upload_name || !req->upload) {
        http_error(resp, 400, "multipart field 'file' (the G-code or part) is required");
        return 400;
    }
    bool b;
    const char *names[] = { "print", "select" };
    for (size_t i = 0; i < 2; i++)
        if (boolean(field(req, names[i]), &b)) {
            http_error(resp, 400, "form field '%s' must be true or false", names[i]);
            return 400;
        }
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "%s", req->upload_name);
    int rc = api_compat_submit(env, &o, req->upload, id, &err);
    if (rc) {
        http_error(resp, rc == SF_EINVAL || rc == SF_ENOTFOUND ? 400 : 500, "%s", err.msg);
        return resp->status;
    }
    log_info("api", "job %lld: '%s' uploaded through the slicer API", (long long)*id, o.name);
    return 0;
}

static void
octo_upload(const struct api_compat_env *env, const struct http_req *req, struct http_resp *resp)
{
    int64_t id;
    if (upload(env, req, resp, &id))
        return;
    char base[256], esc[3 * JOB_NAME_MAX + 1], path[3 * JOB_NAME_MAX + 32];
    base_url(req, base, sizeof(base));
    url_escape(req->upload_name, esc, sizeof(esc));
    snprintf(path, sizeof(path), "job-%lld/%s", (long long)id, esc);
    snprintf(resp->location, sizeof(resp->location), "%s/api/files/local/%s", base, path);
    char download[sizeof(resp->location) + 32];
    snprintf(download, sizeof(download), "%s/api/jobs/%lld", base, (long long)id);
    char shown[JOB_NAME_MAX + 32];
    snprintf(shown, sizeof(shown), "job-%lld/%s", (long long)id, req->upload_name);
    char name[JOB_NAME_MAX + 4];
    http_text_clean(name, sizeof(name), req->upload_name);
    http_text_clean(shown, sizeof(shown), shown);
    resp->status = 201;
    /* The farm queues every upload: it is selected and will print when a
       printer can take it, so both flags are true whatever was asked. */
    resp->json = json_pack("{s{s{ss ss ss s{ss ss}}} sb sb sb s{sI}}", "files", "local", "name",
                           name, "path", shown, "origin", "local", "refs", "resource",
                           resp->location, "download", download, "done", 1, "effectiveSelect", 1,
                           "effectivePrint", 1, "slimfarm", "job_id", (json_int_t)id);
}

static void
moon_upload(const struct api_compat_env *env, const struct http_req *req, struct http_resp *resp)
{
    const char *root = field(req, "root");
    if (root && root[0] && strcmp(root, "gcodes") != 0) {
        http_error(resp, 400, "root '%.32s': the farm takes uploads only to 'gcodes'", root);
        return;
    }
    int64_t id;
    if (upload(env, req, resp, &id))
        return;
    char base[256], esc[3 * JOB_NAME_MAX + 1];
    base_url(req, base, sizeof(base));
    url_escape(req->upload_name, esc, sizeof(esc));
    snprintf(resp->location, sizeof(resp->location), "%s/server/files/gcodes/job-%lld/%s", base,
             (long long)id, esc);
    char item[JOB_NAME_MAX + 32];
    snprintf(item, sizeof(item), "job-%lld/%s", (long long)id, req->upload_name);
    http_text_clean(item, sizeof(item), item);
    struct job_row j;
    struct sf_err err;
    double modified = store_job_get(env->store, id, &j, &err) == SF_OK ? j.created_ms / 1000.0 : 0;
    resp->status = 201;
    resp->json = json_pack("{s{s{ss ss sf ss} sb sb ss}}", "result", "item", "path", item, "root",
                           "gcodes", "modified", modified, "permissions", "rw", "print_started", 0,
                           "print_queued", 1, "action", "create_file");
}

/* "job-ID/..." (an upload's path, as its Location named it) -> ID. */
static int64_t
job_of(const char *p)
{
    while (*p == '/')
        p++;
    if (strncmp(p, "job-", 4) != 0)
        return 0;
    char *end;
    long long id = strtoll(p + 4, &end, 10);
    return end != p + 4 && (*end == '/' || !*end) && id > 0 ? id : 0;
}

/* The select (OctoPrint) or print start (Moonraker) of an uploaded job:
   it is queued already; a job that can no longer print is 409. */
static void
select_job(const struct api_compat_env *env, int64_t id, struct http_resp *resp, bool moonraker)
{
    struct job_row j;
    struct sf_err err;
    int rc = id ? store_job_get(env->store, id, &j, &err) : SF_ENOTFOUND;
    if (rc == SF_ENOTFOUND) {
        http_error(resp, 404, "no uploaded file there (paths are job-ID/NAME, as uploads answer)");
        return;
    }
    if (rc) {
        http_error(resp, 500, "%s", err.msg);
        return;
    }
    if (job_state_terminal(j.state)) {
        http_error(resp, 409, "job %lld is %s; upload it again to print it again", (long long)id,
                   job_state_name(j.state));
        return;
    }
    if (moonraker)
        resp->json = json_pack("{ss}", "result", "ok");
    else
        resp->status = 204;
}

static void
octo_command(const struct api_compat_env *env, const struct http_req *req, const char *rest,
             struct http_resp *resp)
{
    json_error_t je;
    json_t *body = json_loadb(req->body, req->body_len, 0, &je);
    const char *cmd = body ? json_string_value(json_object_get(body, "command")) : NULL;
    if (!cmd) {
        json_decref(body);
        http_error(resp, 400, "body must be JSON with a \"command\"");
        return;
    }
    if (strcmp(cmd, "select") != 0) {
        http_error(resp, 400, "command '%.32s' is not supported here (only select)", cmd);
        json_decref(body);
        return;
    }
    json_decref(body);
    select_job(env, job_of(rest), resp, false);
}

/* ---- read-only answers ---- */

static json_t *
octo_state(void)
{
    return json_pack("{ss s{sb sb sb sb sb sb sb sb sb sb}}", "text", "Operational", "flags",
                     "operational", 1, "ready", 1, "printing", 0, "paused", 0, "pausing", 0,
                     "cancelling", 0, "error", 0, "closedOrError", 0, "sdReady", 0, "finishing", 0);
}

static bool
octo_get(const char *path, struct http_resp *resp)
{
    if (strcmp(path, "/api/version") == 0)
        resp->json = json_pack("{ss ss ss}", "api", "0.1", "server", API_COMPAT_OCTOPRINT, "text",
                               "OctoPrint " API_COMPAT_OCTOPRINT " (slimfarm)");
    else if (strcmp(path, "/api/server") == 0)
        resp->json = json_pack("{ss sn}", "version", API_COMPAT_OCTOPRINT, "safemode");
    else if (strcmp(path, "/api/settings") == 0)
        resp->json = json_pack("{s{sb} s{ss} s{} s{sb} s{ss}}", "feature", "sdSupport", 0,
                               "gcodeAnalysis", "runAt", "never", "plugins", "webcam",
                               "webcamEnabled", 0, "appearance", "name", "slimfarm");
    else if (strcmp(path, "/api/printerprofiles") == 0)
        resp->json =
            json_pack("{s{s{ss ss ss sb sb}}}", "profiles", "_default", "id", "_default", "name",
                      "slimfarm", "model", "slimfarm print farm", "current", 1, "default", 1);
    else if (strcmp(path, "/api/printer") == 0)
        resp->json =
            json_pack("{so s{} s{sb}}", "state", octo_state(), "temperature", "sd", "ready", 0);
    else if (strcmp(path, "/api/job") == 0)
        resp->json = json_pack("{s{s{sn ss}} s{sn sn sn} ss}", "job", "file", "name", "origin",
                               "local", "progress", "completion", "printTime", "printTimeLeft",
                               "state", "Operational");
    else if (strcmp(path, "/api/connection") == 0)
        resp->json = json_pack("{s{ss ss sn}}", "current", "state", "Operational", "port",
                               "slimfarm", "baudrate");
    else
        return false;
    return true;
}

static bool
moon_get(const char *path, struct http_resp *resp)
{
    if (strcmp(path, "/server/info") == 0)
        resp->json =
            json_pack("{s{sb ss s[s] s[] s[s] s[] ss s[iii] ss}}", "result", "klippy_connected", 1,
                      "klippy_state", "ready", "components", "file_manager", "failed_components",
                      "registered_directories", "gcodes", "warnings", "moonraker_version",
                      "slimfarm", "api_version", 1, 5, 0, "api_version_string", "1.5.0");
    else if (strcmp(path, "/server/files/roots") == 0)
        resp->json = json_pack("{s[{ss ss ss}]}", "result", "name", "gcodes", "path", "",
                               "permissions", "rw");
    else if (strcmp(path, "/printer/info") == 0)
        resp->json = json_pack("{s{ss ss ss ss}}", "result", "state", "ready", "state_message",
                               "slimfarm: uploads join the farm queue", "hostname", "slimfarm",
                               "software_version", "slimfarm");
    else
        return false;
    return true;
}

/* Moonraker's print start names the file in the query or a JSON body. */
static void
moon_start(const struct api_compat_env *env, const struct http_req *req, struct http_resp *resp)
{
    char name[512] = "";
    const char *q = req->query;
    while (q && *q) {
        size_t n = strcspn(q, "&");
        if (n > 9 && strncmp(q, "filename=", 9) == 0 && n - 9 < sizeof(name)) {
            memcpy(name, q + 9, n - 9);
            name[n - 9] = '\0';
        }
        q += n + (q[n] == '&');
    }
    if (!name[0] && req->body_len) {
        json_t *b = json_loadb(req->body, req->body_len, 0, NULL);
        const char *f = b ? json_string_value(json_object_get(b, "filename")) : NULL;
        if (f)
            snprintf(name, sizeof(name), "%s", f);
        json_decref(b);
    }
    if (!name[0]) {
        http_error(resp, 400, "filename is required");
        return;
    }
    select_job(env, job_of(name), resp, true);
}

bool
api_compat_body(const char *method, const char *path, enum http_body *kind)
{
    bool post = strcmp(method, "POST") == 0;
    if (strcmp(path, "/api/files/local") == 0 || strcmp(path, "/server/files/upload") == 0) {
        *kind = post ? HTTP_BODY_UPLOAD : HTTP_BODY_NONE;
        return true;
    }
    if (strncmp(path, "/api/files/local/", 17) == 0 || strcmp(path, "/printer/print/start") == 0) {
        *kind = post ? HTTP_BODY_JSON : HTTP_BODY_NONE;
        return true;
    }
    return false;
}

bool
api_compat_route(const struct api_compat_env *env, const struct http_req *req,
                 struct http_resp *resp)
{
    const char *path = req->path;
    bool get = strcmp(req->method, "GET") == 0, post = strcmp(req->method, "POST") == 0;
    if (strcmp(path, "/metrics") == 0) {
        struct sf_err err;
        if (!get)
            http_error(resp, 405, "use GET");
        else if (!(resp->text = metrics_render(env->store, env->farm, &err)))
            http_error(resp, 500, "%s", err.msg);
        else
            resp->content_type = METRICS_CONTENT_TYPE;
        return true;
    }
    if (strcmp(path, "/api/files/local") == 0 || strcmp(path, "/server/files/upload") == 0) {
        if (!post)
            http_error(resp, 405, "use POST with a multipart/form-data upload");
        else if (path[1] == 'a')
            octo_upload(env, req, resp);
        else
            moon_upload(env, req, resp);
        return true;
    }
    if (strcmp(path, "/api/files/sdcard") == 0) {
        http_error(resp, 400, "the farm has no SD card: upload to /api/files/local");
        return true;
    }
    if (strncmp(path, "/api/files/local/", 17) == 0) {
        if (post)
            octo_command(env, req, path + 17, resp);
        else
            http_error(resp, 405, "use POST with {\"command\": \"select\"}");
        return true;
    }
    if (strcmp(path, "/printer/print/start") == 0) {
        if (post)
            moon_start(env, req, resp);
        else
            http_error(resp, 405, "use POST");
        return true;
    }
    if (get && (octo_get(path, resp) || moon_get(path, resp)))
        return true;
    return false;
}
