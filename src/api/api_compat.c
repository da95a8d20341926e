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
#include "../base/mem.h"
#include "api_octoprint.h"
#include "api_octopush.h"
#include "api_read.h"
#include "metrics.h"
#include "partcheck.h"

bool
api_compat_is_gcode(const char *name)
{
    const char *dot = strrchr(name, '.');
    return dot && (strcasecmp(dot, ".gcode") == 0 || strcasecmp(dot, ".gco") == 0 ||
                   strcasecmp(dot, ".g") == 0);
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

/* ---- uploads ---- */

void
api_compat_base_url(const struct http_req *req, char *out, size_t cap)
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

void
api_compat_url_escape(const char *name, char *out, size_t cap)
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

enum flavor { OCTOPRINT, MOONRAKER };

/* The answer to an upload that made job id, j (NULL: not read) as it is. */
static void
answer(enum flavor fl, const char *base, const char *name, int64_t id, struct http_resp *resp,
       const struct job_row *j)
{
    char esc[3 * JOB_NAME_MAX + 1], shown[JOB_NAME_MAX + 32], clean[JOB_NAME_MAX + 4];
    api_compat_url_escape(name, esc, sizeof(esc));
    snprintf(shown, sizeof(shown), "job-%lld/%s", (long long)id, name);
    http_text_clean(shown, sizeof(shown), shown);
    http_text_clean(clean, sizeof(clean), name);
    resp->status = 201;
    if (fl == MOONRAKER) {
        http_resp_header(resp, "Location", "%s/server/files/gcodes/job-%lld/%s", base,
                         (long long)id, esc);
        double modified = j ? j->created_ms / 1000.0 : 0;
        /* queued, never started at once: the farm starts it when a printer is free */
        resp->json = json_pack("{s{s{ss ss sf ss} sb sb ss}}", "result", "item", "path", shown,
                               "root", "gcodes", "modified", modified, "permissions", "rw",
                               "print_started", 0, "print_queued", 1, "action", "create_file");
        return;
    }
    char location[512];
    snprintf(location, sizeof(location), "%s/api/files/local/job-%lld/%s", base, (long long)id,
             esc);
    http_resp_header(resp, "Location", "%s", location);
    char download[64 + 256];
    snprintf(download, sizeof(download), "%s/api/jobs/%lld", base, (long long)id);
    /* The farm queues every upload: it is selected and will print when a
       printer can take it, so both flags are true whatever was asked. */
    resp->json = json_pack("{s{s{ss ss ss s{ss ss}}} sb sb sb s{sI}}", "files", "local", "name",
                           clean, "path", shown, "origin", "local", "refs", "resource", location,
                           "download", download, "done", 1, "effectiveSelect", 1, "effectivePrint",
                           1, "slimfarm", "job_id", (json_int_t)id);
}

/* An upload under check on the farm's io thread (G-code), then written on its store thread. */
struct pending {
    const struct api_compat_env *env; /* valid while d is alive (api_free ends both) */
    struct http_defer *d;             /* the waiting request; NULL if deferring failed */
    enum flavor fl;
    struct job_opts o;
    char base[256];      /* scheme and host for Location, "" for a relative one */
    struct farm_add add; /* the job's write (farm.h); the store thread's until added() */
};

/* The upload's job is written (store thread, farm_add_post): answer with it, or refuse. */
static void
added(void *ud, const struct storeq_result *r)
{
    struct pending *p = ud;
    struct http_defer *d = p->d;
    struct http_resp resp = { .status = 200 };
    if (http_defer_alive(d)) {
        const struct api_compat_env *env = p->env;
        int rc = r->rc;
        const char *msg = r->err->msg;
        if (rc && p->add.adopted && p->add.adopt_rc) { /* the file was not stored */
            rc = p->add.adopt_rc;
            msg = p->add.adopt_err.msg;
        }
        if (rc) {
            /* a file the job names that is not stored: the upload's fault */
            http_fail(&resp, rc == SF_ENOTFOUND ? SF_EINVAL : rc, msg);
        } else {
            log_info("api", "job %lld: '%s' uploaded through the %s API", (long long)p->add.id,
                     p->o.name, p->fl == MOONRAKER ? "Moonraker" : "OctoPrint");
            answer(p->fl, p->base, p->o.name, p->add.id, &resp, &p->add.j);
            if (env->changed)
                env->changed(env->ud);
        }
    }
    http_defer_answer(d, &resp); /* frees the answer if the client left */
    free(p);
}

/* The check is done (loop thread): store the file and queue it, or refuse. */
static void
checked(void *ud, int rc, const struct farm_gcode *g, const char *msg)
{
    struct pending *p = ud;
    struct http_defer *d = p->d;
    struct http_resp resp = { .status = 200 };
    if (!d || !http_defer_alive(d)) { /* the client left, or the server stopped */
        if (d)
            http_defer_answer(d, &resp);
        free(p);
        return;
    }
    const struct api_compat_env *env = p->env;
    struct sf_err err;
    if (rc) {
        http_fail(&resp, rc, msg); /* SF_ECANCELED: the daemon is stopping, 503 */
    } else {
        /* stored and queued on the store's thread (its bytes, on PostgreSQL, too): answered
           by added() */
        p->add.o = p->o;
        snprintf(p->add.tmp, sizeof(p->add.tmp), "%s", env->upload_path(http_defer_upload(d)));
        if ((rc = farm_gcode_add(env->farm, &p->add, g, added, p, &err)) == SF_OK)
            return;
        http_fail(&resp, rc, err.msg);
    }
    http_defer_answer(d, &resp);
    free(p);
}

/* Both uploads: the file part, its fields, then the job (a part now, G-code
   after its check). */
static void
upload(const struct api_compat_env *env, enum flavor fl, const struct http_req *req,
       struct http_resp *resp)
{
    struct sf_err err;
    if (!req->upload_name || !req->upload) {
        http_error(resp, 400, "multipart field 'file' (the G-code or part) is required");
        return;
    }
    bool b;
    const char *names[] = { "print", "select" };
    for (size_t i = 0; i < 2; i++)
        if (boolean(http_req_field(req, names[i]), &b)) {
            http_error(resp, 400, "form field '%s' must be true or false", names[i]);
            return;
        }
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "%s", req->upload_name);
    char base[256];
    api_compat_base_url(req, base, sizeof(base));
    if (partcheck_file(env->upload_path(req->upload), o.name, &err)) {
        http_fail(resp, err.code, err.msg); /* what it holds is not what its name says */
        return;
    }
    if (api_compat_is_gcode(o.name)) {
        if (!env->farm) {
            http_error(resp, 400, "'%s': this daemon runs no farm to print G-code", o.name);
            return;
        }
        struct pending *p = mem_calloc(1, sizeof(*p));
        if (!p) {
            http_error(resp, 500, "out of memory");
            return;
        }
        *p = (struct pending){ .env = env, .fl = fl, .o = o };
        snprintf(p->base, sizeof(p->base), "%s", base);
        /* checked before it is stored: a refused file leaves nothing */
        if (farm_gcode_check(env->farm, env->upload_path(req->upload), &o, checked, p, &err)) {
            free(p);
            http_error(resp, 500, "%s", err.msg);
            return;
        }
        p->d = http_defer(resp);
        if (!p->d)
            http_error(resp, 500, "out of memory"); /* checked() then only frees p */
        return;
    }
    char sha[STORE_SHA_HEX];
    int64_t id;
    int rc;
    if ((rc = job_opts_validate(&o, &err))) {
        http_fail(resp, rc, err.msg);
        return;
    }
    /* With a farm: stored and queued on its store thread while the request waits (added) */
    struct pending *p = env->farm ? mem_calloc(1, sizeof(*p)) : NULL;
    if (p && (p->d = http_defer(resp))) {
        *p = (struct pending){ .env = env, .d = p->d, .fl = fl, .o = o };
        snprintf(p->base, sizeof(p->base), "%s", base);
        p->add.o = o;
        snprintf(p->add.tmp, sizeof(p->add.tmp), "%s", env->upload_path(req->upload));
        if (farm_add_post(env->farm, &p->add, added, p, &err) == SF_OK)
            return;
        free(resp->defer); /* not queued: written now (http_defer's handle is a plain
                              allocation until the route returns) */
        resp->defer = NULL;
    }
    free(p);
    struct job_row j;
    if ((rc = env->upload_commit(req->upload, sha, &err)) ||
        (rc = store_job_add(env->store, &o, sha, &id, &err))) {
        /* a file the job names that is not stored: the upload's fault */
        http_fail(resp, rc == SF_ENOTFOUND ? SF_EINVAL : rc, err.msg);
        return;
    }
    log_info("api", "job %lld: '%s' uploaded through the %s API", (long long)id, o.name,
             fl == MOONRAKER ? "Moonraker" : "OctoPrint");
    answer(fl, base, o.name, id, resp,
           store_job_get(env->store, id, &j, NULL) == SF_OK ? &j : NULL);
    if (env->changed)
        env->changed(env->ud);
}

static void
moon_upload(void *ctx, const struct route_args *args, const struct http_req *req,
            struct http_resp *resp)
{
    (void)args;
    const struct api_compat_env *env = ctx;
    const char *root = http_req_field(req, "root");
    if (root && root[0] && strcmp(root, "gcodes") != 0) {
        http_error(resp, 400, "root '%.32s': the farm takes uploads only to 'gcodes'", root);
        return;
    }
    upload(env, MOONRAKER, req, resp);
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
   it is queued already.  A job already done did what the select asks for
   (a slicer's select can arrive after a fast printer finished the upload);
   one that failed or was cancelled can no longer print: 409. */
/* A select on its way: the job read on the API's reader, which answers it too. */
struct select_ask {
    int64_t id;
    bool moonraker;
};

static void
select_read(struct store *s, void *ud, struct http_resp *resp)
{
    const struct select_ask *q = ud;
    struct job_row j;
    struct sf_err err;
    int rc = q->id ? store_job_get(s, q->id, &j, &err) : SF_ENOTFOUND;
    if (rc == SF_ENOTFOUND) {
        http_error(resp, 404, "no uploaded file there (paths are job-ID/NAME, as uploads answer)");
        return;
    }
    if (rc) {
        http_fail(resp, rc, err.msg);
        return;
    }
    if (job_state_terminal(j.state) && j.state != JOB_DONE) {
        http_error(resp, 409, "job %lld is %s; upload it again to print it again", (long long)q->id,
                   job_state_name(j.state));
        return;
    }
    if (q->moonraker)
        resp->json = json_pack("{ss}", "result", "ok");
    else
        resp->status = 204;
}

static void
select_job(const struct api_compat_env *env, int64_t id, struct http_resp *resp, bool moonraker)
{
    struct select_ask *q = mem_calloc(1, sizeof(*q));
    if (!q) {
        http_error(resp, 500, "out of memory");
        return;
    }
    *q = (struct select_ask){ id, moonraker };
    api_read_run(env->reads, resp, select_read, NULL, q, free);
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
moon_start(void *ctx, const struct route_args *args, const struct http_req *req,
           struct http_resp *resp)
{
    (void)args;
    const struct api_compat_env *env = ctx;
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

/* /metrics: the printers taken on the loop, the store counted on the reader thread. */
struct scrape {
    struct metrics_printer *printers;
    size_t n;
    struct farm_health h; /* when has_h */
    bool has_h;
};

static void
scrape_read(struct store *s, void *ud, struct http_resp *resp)
{
    struct scrape *sc = ud;
    struct sf_err err;
    char *text = metrics_render(s, sc->printers, sc->n, sc->has_h ? &sc->h : NULL, &err);
    if (!text) {
        http_fail(resp, err.code, err.msg);
        return;
    }
    resp->body = text;
    resp->body_len = strlen(text);
    resp->body_free = free;
    resp->content_type = METRICS_CONTENT_TYPE;
}

static void
scrape_free(void *ud)
{
    struct scrape *sc = ud;
    free(sc->printers);
    free(sc);
}

static void
metrics(void *ctx, const struct route_args *args, const struct http_req *req,
        struct http_resp *resp)
{
    (void)args, (void)req;
    const struct api_compat_env *env = ctx;
    struct scrape *sc = mem_calloc(1, sizeof(*sc));
    if (!sc || metrics_printers(env->farm, &sc->printers, &sc->n)) {
        free(sc);
        http_error(resp, 500, "out of memory");
        return;
    }
    if ((sc->has_h = env->farm != NULL))
        farm_health(env->farm, &sc->h);
    api_read_run(env->reads, resp, scrape_read, NULL, sc, scrape_free);
}

static void
octo_upload(void *ctx, const struct route_args *args, const struct http_req *req,
            struct http_resp *resp)
{
    (void)args;
    upload(ctx, OCTOPRINT, req, resp);
}

static void
sdcard(void *ctx, const struct route_args *args, const struct http_req *req, struct http_resp *resp)
{
    (void)ctx, (void)args, (void)req;
    http_error(resp, 400, "the farm has no SD card: upload to /api/files/local");
}

static void
octo_select(void *ctx, const struct route_args *args, const struct http_req *req,
            struct http_resp *resp)
{
    octo_command(ctx, req, args->rest, resp);
}

static void
info(void *ctx, const struct route_args *args, const struct http_req *req, struct http_resp *resp)
{
    (void)ctx, (void)args;
    if (!octo_get(req->path, resp))
        moon_get(req->path, resp);
}

#define UPLOAD_405 "use POST with a multipart/form-data upload"

/* Rows of the route table (route.h); the read-only answers are unknown to
   other methods (404). */
static const struct route rows[] = {
    /* methods, pattern, match, body, scope, handler, 405 message */
    { ROUTE_GET, "/metrics", NULL, HTTP_BODY_NONE, ROUTE_READ, metrics, "use GET" },
    { ROUTE_POST, "/api/files/local", NULL, HTTP_BODY_UPLOAD, ROUTE_WRITE, octo_upload,
      UPLOAD_405 },
    { ROUTE_GET, "/api/files/local", NULL, HTTP_BODY_NONE, ROUTE_READ, api_octoprint_files,
      UPLOAD_405 },
    { ROUTE_POST, "/server/files/upload", NULL, HTTP_BODY_UPLOAD, ROUTE_WRITE, moon_upload,
      UPLOAD_405 },
    { ROUTE_ANY, "/api/files/sdcard", NULL, HTTP_BODY_NONE, ROUTE_READ, sdcard, NULL },
    { ROUTE_POST, "/api/files/local/{*}", NULL, HTTP_BODY_JSON, ROUTE_WRITE, octo_select,
      "use POST with {\"command\": \"select\"}" },
    { ROUTE_POST, "/printer/print/start", NULL, HTTP_BODY_JSON, ROUTE_WRITE, moon_start,
      "use POST" },
    { ROUTE_GET, "/api/version", NULL, HTTP_BODY_NONE, ROUTE_READ, info, NULL },
    { ROUTE_GET, "/api/server", NULL, HTTP_BODY_NONE, ROUTE_READ, info, NULL },
    { ROUTE_GET, "/api/settings", NULL, HTTP_BODY_NONE, ROUTE_READ, info, NULL },
    { ROUTE_GET, "/api/printerprofiles", NULL, HTTP_BODY_NONE, ROUTE_READ, info, NULL },
    { ROUTE_GET, "/api/printer", NULL, HTTP_BODY_NONE, ROUTE_READ, api_octoprint_state, NULL },
    { ROUTE_GET, "/api/job", NULL, HTTP_BODY_NONE, ROUTE_READ, api_octoprint_state, NULL },
    { ROUTE_POST, "/api/job", NULL, HTTP_BODY_JSON, ROUTE_WRITE, api_octoprint_job_command, NULL },
    { ROUTE_POST, "/api/login", NULL, HTTP_BODY_JSON, ROUTE_READ, api_octoprint_login, NULL },
    { ROUTE_GET, "/api/currentuser", NULL, HTTP_BODY_NONE, ROUTE_READ, api_octoprint_user, NULL },
    { ROUTE_GET, "/api/files", NULL, HTTP_BODY_NONE, ROUTE_READ, api_octoprint_files, NULL },
    { ROUTE_GET, "/api/connection", NULL, HTTP_BODY_NONE, ROUTE_READ, info, NULL },
    { ROUTE_GET, "/server/info", NULL, HTTP_BODY_NONE, ROUTE_READ, info, NULL },
    { ROUTE_GET, "/server/files/roots", NULL, HTTP_BODY_NONE, ROUTE_READ, info, NULL },
    { ROUTE_GET, "/printer/info", NULL, HTTP_BODY_NONE, ROUTE_READ, info, NULL },
    { ROUTE_GET, "/sockjs/info", NULL, HTTP_BODY_NONE, ROUTE_PUBLIC, api_octopush_route, NULL },
    { ROUTE_GET, "/sockjs/{*}", NULL, HTTP_BODY_NONE, ROUTE_PUBLIC, api_octopush_route, NULL },
};

const struct route *
api_compat_routes(size_t *n)
{
    *n = sizeof(rows) / sizeof(rows[0]);
    return rows;
}
