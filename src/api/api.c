/*
 * api.c - the REST routes: jobs from the store, printers through farm.h,
 * the event log as Server-Sent Events.
 *
 * Why this split: http.c knows HTTP (keys, caps, multipart, streams) and
 * nothing of jobs; api_json.c knows JSON shapes; route.c dispatches the
 * route table, whose rows are this file's, api_compat.c's and web.c's; the
 * farm (jobctl.h) decides what a cancel or an action does.  This file only
 * maps URLs to store and farm calls and their codes to statuses
 * (http_status_of), so each route is a few lines.
 * Uploads stream straight into a temporary file of the store (never whole
 * in memory); the route commits it to its content address only once the
 * options are valid, and the job row is added right after, so a refused
 * or broken upload leaves neither a file nor a job.  A client file name is
 * only ever a label: it must be a plain name (job_name_valid) and a part
 * format we load, and it never becomes a path; text a client sent is
 * echoed in errors cut on a character boundary (route_clip()).
 *
 * Thread: the loop thread, like the store it uses.
 */
#include "api.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <strings.h>

#include "../base/buf.h"
#include "../base/clock.h"
#include "../base/limits.h"
#include "../base/log.h"
#include "../base/mem.h"
#include "../farm/farm_host.h"
#include "../farm/farm_view.h"
#include "../farm/jobctl.h"
#include "api_compat.h"
#include "api_csv.h"
#include "api_json.h"
#include "api_octopush.h"
#include "api_page.h"
#include "api_printers.h"
#include "api_read.h"
#include "api_remote.h"
#include "api_sse.h"
#include "api_stats.h"
#include "api_writes.h"
#include "partcheck.h"
#include "route.h"
#include "temps.h"
#include "web.h"

#define API_GROUPS 5 /* route groups: api_compat's, web's, api_printers', api_writes', api.c's */

struct api {
    struct api_config cfg;                 /* as given */
    struct api_compat_env slicers;         /* the slicer-upload routes' view (api_compat.h) */
    struct http *http;                     /* the server */
    struct web *web;                       /* the dashboard's files, sessions and pictures */
    struct api_read *reads;                /* store reads off the loop (api_read.h) */
    struct api_octopush *push;             /* OctoPrint's push sockets (api_octopush.h) */
    struct api_sse_env sse;                /* the event streams' view (api_sse.h) */
    struct temps *temps;                   /* each printer's last hour of temperatures (temps.h) */
    struct route_group groups[API_GROUPS]; /* the route table: api_compat's, web's, ours */
    struct api_writes writes; /* job writes and printer actions answered once committed */
};

/* ---- upload sink ---- */

static bool
part_ext_ok(const char *name)
{
    const char *dot = strrchr(name, '.');
    return (dot && (strcasecmp(dot, ".stl") == 0 || strcasecmp(dot, ".obj") == 0 ||
                    strcasecmp(dot, ".3mf") == 0)) ||
           api_compat_is_gcode(name);
}

static void *
up_begin(void *ud, const char *filename, struct sf_err *err)
{
    struct api *a = ud;
    char name[81];
    route_clip(name, sizeof(name), filename);
    if (strlen(filename) >= JOB_NAME_MAX) {
        sf_err_set(err, SF_EINVAL, "file name '%s...' is %zu bytes: at most %d bytes (UTF-8)", name,
                   strlen(filename), JOB_NAME_MAX - 1);
        return NULL;
    }
    if (!job_name_valid(filename)) {
        sf_err_set(err, SF_EINVAL,
                   "file name '%s' is not a plain file name (valid UTF-8; no paths, '..' or "
                   "control characters)",
                   name);
        return NULL;
    }
    if (!part_ext_ok(filename)) {
        sf_err_set(err, SF_EINVAL, "file name '%s' does not end in .stl, .obj, .3mf or .gcode",
                   name);
        return NULL;
    }
    struct upload *u = mem_calloc(1, sizeof(*u));
    if (!u) {
        sf_err_set(err, SF_ENOMEM, "out of memory");
        return NULL;
    }
    route_clip(u->name, sizeof(u->name), filename);
    u->f = store_file_begin(a->cfg.store, err);
    if (!u->f) {
        free(u);
        return NULL;
    }
    return u;
}

static int
up_write(void *ctx, const char *data, size_t len, struct sf_err *err)
{
    struct upload *u = ctx;
    u->size += len;
    return store_file_write(u->f, data, len, err);
}

/* The body is complete: refuse an empty part now rather than at prepare. */
static int
up_finish(void *ctx, struct sf_err *err)
{
    struct upload *u = ctx;
    if (u->size == 0)
        return sf_err_set(err, SF_EINVAL, "file '%s' is empty", u->name);
    return SF_OK;
}

static void
up_discard(void *ctx)
{
    struct upload *u = ctx;
    store_file_abort(u->f);
    free(u);
}

static const struct http_upload_sink sink = { up_begin, up_write, up_finish, up_discard };

static const char *
up_path(void *ctx)
{
    return store_file_tmp_path(((struct upload *)ctx)->f);
}

static int
up_commit(void *ctx, char sha[STORE_SHA_HEX], struct sf_err *err)
{
    struct upload *u = ctx;
    int rc = store_file_commit(u->f, sha, err);
    u->f = NULL; /* commit frees the writer either way */
    return rc;
}

/* ---- helpers ---- */

static void
changed(struct api *a)
{
    http_wake_streams(a->http);
    if (a->cfg.on_change)
        a->cfg.on_change(a->cfg.ud);
}

static void
compat_changed(void *ud)
{
    changed(ud);
}

/* ---- jobs ---- */

/* GET /api/jobs: a page (api_page.h), read on the reader's thread. */
static void
read_page(struct store *s, void *ud, struct http_resp *resp)
{
    struct sf_err err;
    size_t len;
    const struct api_page_query *q = ud;
    char next[24] = "";
    char *text =
        q->csv ? api_csv_render(s, q, &len, next, &err) : api_page_render(s, q, &len, &err);
    if (!text) {
        http_fail(resp, err.code, err.msg);
        return;
    }
    resp->body = text;
    resp->body_len = len;
    resp->body_free = free;
    resp->content_type = q->csv ? "text/csv; charset=utf-8" : "application/json";
    if (q->csv)
        http_resp_header(resp, "Content-Disposition", "attachment; filename=\"jobs.csv\"");
    if (next[0]) /* more jobs pass: the same query with cursor=next goes on */
        http_resp_header(resp, "X-Next-Cursor", "%s", next);
}

static void
jobs_list(void *ctx, const struct route_args *args, const struct http_req *req,
          struct http_resp *resp)
{
    (void)args;
    struct api *a = ctx;
    struct sf_err err;
    struct api_page_query *q = mem_calloc(1, sizeof(*q));
    if (!q) {
        http_error(resp, 500, "out of memory");
        return;
    }
    if (api_page_parse(req->query, q, &err)) {
        http_error(resp, 400, "%s", err.msg);
        free(q);
        return;
    }
    q->f.printer = q->printer; /* q moved to the heap: point into it */
    q->f.name = q->name[0] ? q->name : NULL;
    api_read_run(a->reads, resp, read_page, NULL, q, free);
}

/* Job id with its print history from s, or the failure (any thread with its s). */
static void
job_read(struct store *s, int64_t id, struct http_resp *resp)
{
    struct sf_err err;
    struct job_row j;
    struct print_row *p;
    size_t n;
    int rc = store_job_get(s, id, &j, &err);
    if (rc || (rc = store_prints(s, id, &p, &n, &err))) {
        http_fail(resp, rc, err.msg);
        return;
    }
    json_t *prints = json_array();
    for (size_t i = 0; prints && i < n; i++)
        json_array_append_new(prints, api_print_json(&p[i]));
    free(p);
    resp->json = json_pack("{soso}", "job", api_job_json(&j), "prints", prints);
}

/* On the loop: the time left of the job in resp if it is on a printer, as GET
   /api/printers gives it. */
static void
job_time_left(struct api *a, int64_t id, struct http_resp *resp)
{
    json_t *job = json_object_get(resp->json, "job");
    size_t np = a->cfg.farm && job ? farm_printer_count(a->cfg.farm) : 0;
    for (size_t i = 0; i < np; i++) {
        struct printer_info pi;
        farm_printer_info(a->cfg.farm, i, &pi);
        if (pi.job_id == id) {
            api_time_left_json(job, &pi);
            break;
        }
    }
}

/* A GET /api/jobs/ID on its way: the reader reads, the loop adds the printer's part. */
struct job_ask {
    struct api *a;
    int64_t id;
};

static void
job_ask_read(struct store *s, void *ud, struct http_resp *resp)
{
    job_read(s, ((struct job_ask *)ud)->id, resp);
}

static void
job_ask_finish(void *ud, struct http_resp *resp)
{
    struct job_ask *q = ud;
    job_time_left(q->a, q->id, resp);
}

static void
job_get(void *ctx, const struct route_args *args, const struct http_req *req,
        struct http_resp *resp)
{
    (void)req;
    struct api *a = ctx;
    struct job_ask *q = mem_calloc(1, sizeof(*q));
    if (!q) {
        http_error(resp, 500, "out of memory");
        return;
    }
    *q = (struct job_ask){ a, args->id };
    api_read_run(a->reads, resp, job_ask_read, job_ask_finish, q, free);
}

/* The job id with its prints and its time left, as the loop's connection reads it now (the
   answer to a write: api_writes.h). */
static void
job_answer(void *ud, int64_t id, struct http_resp *resp)
{
    struct api *a = ud;
    job_read(a->cfg.store, id, resp);
    job_time_left(a, id, resp);
}

/* The loop's part of a job's answer to a write, read on the store's thread (api_writes.h). */
static void
job_answer_more(void *ud, int64_t id, struct http_resp *resp)
{
    job_time_left(ud, id, resp);
}

static void
api_changed(void *ud)
{
    changed(ud);
}

/* GET /api/stats?days=N (api_stats.h), read on the reader's thread. */
static void
stats_get(void *ctx, const struct route_args *args, const struct http_req *req,
          struct http_resp *resp)
{
    (void)args;
    struct api *a = ctx;
    struct sf_err err;
    int *days = mem_calloc(1, sizeof(*days));
    if (!days) {
        http_error(resp, 500, "out of memory");
        return;
    }
    if (api_stats_parse(req->query, days, &err)) {
        http_error(resp, 400, "%s", err.msg);
        free(days);
        return;
    }
    api_read_run(a->reads, resp, api_stats_read, NULL, days, free);
}

/* ---- printers ---- */

/* The job's time left, s, and whose estimate it is ("printer" or "farm"); nulls if none. */

/*
 * What is on a printer's bed (b from store_beds, NULL: the store has not
 * seen it), for a dashboard card: "bed_full" (a part waits to be taken
 * off), "interrupted_job" (a job the daemon left interrupted there, null if
 * none: the printer is blocked until it is resumed, restarted or
 * cancelled) and "last_print" (the newest print there with its job's name,
 * copies and line count, null if none).
 */
static void
bed_json(json_t *o, const struct store_bed *b)
{
    if (!o)
        return;
    json_object_set_new(o, "bed_full", json_boolean(b && b->bed_full));
    json_object_set_new(o, "interrupted_job",
                        b && b->interrupted_job ? json_integer(b->interrupted_job) : json_null());
    json_t *l = b && b->last.id ? api_print_json(&b->last) : NULL;
    if (l)
        json_object_update_new(l, json_pack("{sI ss si sI}", "job_id", (json_int_t)b->last.job_id,
                                            "job_name", b->job_name, "copies", b->copies,
                                            "gcode_lines", (json_int_t)b->gcode_lines));
    json_object_set_new(o, "last_print", l ? l : json_null());
}

static json_t *
printer_json(const struct store_bed *beds, size_t n_beds, const struct printer_info *p)
{
    const struct farmcfg_printer *c = p->cfg;
    json_t *o = json_pack("{ss ss sb ss sf s[fff] ss s{sfsfsfsf} sI sf ss}", "name", c->name,
                          "state", printer_state_name(p->state), "enabled", c->enabled, "material",
                          c->material, "nozzle_mm", c->nozzle_mm, "bed_mm", c->bed_mm[0],
                          c->bed_mm[1], c->bed_mm[2], "group", c->group, "temps", "nozzle_c",
                          p->nozzle_c, "nozzle_target_c", p->nozzle_target_c, "bed_c", p->bed_c,
                          "bed_target_c", p->bed_target_c, "job_id", (json_int_t)p->job_id,
                          "progress", p->progress, "message", p->message ? p->message : "");
    if (o) {
        api_time_left_json(o, p);
        json_object_set_new(o, "disabled_reason", /* farm.h: an operator's, with why */
                            c->disabled[0] ? json_string(c->disabled) : json_null());
    }
    const struct store_bed *b = NULL;
    for (size_t i = 0; i < n_beds && !b; i++)
        if (strcmp(beds[i].printer, c->name) == 0)
            b = &beds[i];
    bed_json(o, b);
    return o;
}

/* Round o[key], a number, to the nearest multiple of step (what a published view keeps). */
static void
round_key(json_t *o, const char *key, double step)
{
    json_t *v = json_object_get(o, key);
    if (json_is_number(v))
        json_object_set_new(o, key, json_real(floor(json_number_value(v) / step + 0.5) * step));
}

/*
 * One of several hosts: this host's printers as the others show them
 * (farm_view.h), each as GET /api/printers shows it, less its bed (the
 * store's) and with what moves by the sample rounded (temperatures to a
 * degree, progress to a percent, time left to a minute), so the text
 * changes, and is written, only when the dashboard would show a change.
 */
static void
view_publish(struct api *a)
{
    struct farm *f = a->cfg.farm;
    if (!f || !farm_host_on(f))
        return;
    json_t *all = json_object();
    size_t n = farm_printer_count(f);
    for (size_t i = 0; all && i < n; i++) {
        struct printer_info p;
        farm_printer_info(f, i, &p);
        json_t *o = printer_json(NULL, 0, &p);
        if (!o)
            continue;
        json_t *t = json_object_get(o, "temps");
        const char *keys[] = { "nozzle_c", "nozzle_target_c", "bed_c", "bed_target_c" };
        for (size_t k = 0; k < sizeof(keys) / sizeof(keys[0]); k++)
            round_key(t, keys[k], 1);
        round_key(o, "progress", 0.01);
        json_t *left = json_object_get(o, "time_left_s");
        if (json_is_integer(left))
            json_object_set_new(o, "time_left_s", json_integer(json_integer_value(left) / 60 * 60));
        const char *drop[] = { "name", "bed_full", "interrupted_job", "last_print" };
        for (size_t k = 0; k < sizeof(drop) / sizeof(drop[0]); k++)
            json_object_del(o, drop[k]);
        json_object_set_new(all, p.cfg->name, o);
    }
    char *text = all ? json_dumps(all, JSON_COMPACT | JSON_SORT_KEYS) : NULL;
    json_decref(all);
    if (text)
        farm_view_publish(f, text);
    free(text);
}

/* Every printer, or the one called name (NULL: all), with the beds' state beds[n_beds]. */
static void
printers_json(struct api *a, const char *name, const struct store_bed *beds, size_t n_beds,
              struct http_resp *resp)
{
    json_t *arr = json_array();
    size_t n = a->cfg.farm ? farm_printer_count(a->cfg.farm) : 0;
    for (size_t i = 0; arr && i < n; i++) {
        struct printer_info p;
        farm_printer_info(a->cfg.farm, i, &p);
        if (!name) {
            json_array_append_new(arr, printer_json(beds, n_beds, &p));
        } else if (strcmp(p.cfg->name, name) == 0) {
            json_decref(arr);
            resp->json = json_pack("{so}", "printer", printer_json(beds, n_beds, &p));
            return;
        }
    }
    if (name) {
        json_decref(arr);
        http_error(resp, 404, "no printer '%.64s'", name);
        return;
    }
    resp->json = json_pack("{so}", "printers", arr);
}

/* As printers_json, the beds read now with the loop's store (a write's answer). */
static void
printers_answer(struct api *a, const char *name, struct http_resp *resp)
{
    size_t n = a->cfg.farm ? farm_printer_count(a->cfg.farm) : 0;
    struct store_bed *beds = NULL;
    size_t n_beds = 0;
    struct sf_err err;
    if (n && store_beds(a->cfg.store, &beds, &n_beds, &err)) /* the cards go without */
        log_warn("api", "printers: %s", err.msg);
    printers_json(a, name, beds, n_beds, resp);
    free(beds);
}

static void
printer_answer(void *ud, const char *name, struct http_resp *resp)
{
    printers_answer(ud, name, resp);
}

static void
printer_local(void *ud, const char *name, const struct store_bed *beds, size_t n_beds,
              struct http_resp *resp)
{
    printers_json(ud, name, beds, n_beds, resp);
}

/* A GET /api/printers on its way: the reader reads the beds, the loop adds the printers. */
struct printers_ask {
    struct api *a;
    char name[64]; /* "": all */
    struct store_bed *beds;
    size_t n_beds;
    int rc;
    struct sf_err err;
};

static void
printers_ask_read(struct store *s, void *ud, struct http_resp *resp)
{
    (void)resp;
    struct printers_ask *q = ud;
    q->rc = store_beds(s, &q->beds, &q->n_beds, &q->err);
}

static void
printers_ask_finish(void *ud, struct http_resp *resp)
{
    struct printers_ask *q = ud;
    if (q->rc) /* the cards go without */
        log_warn("api", "printers: %s", q->err.msg);
    printers_json(q->a, q->name[0] ? q->name : NULL, q->beds, q->n_beds, resp);
}

static void
printers_ask_free(void *ud)
{
    struct printers_ask *q = ud;
    free(q->beds);
    free(q);
}

/* GET /api/printers (args->name ""), or /api/printers/NAME. */
static void
printers_get(void *ctx, const struct route_args *args, const struct http_req *req,
             struct http_resp *resp)
{
    (void)req;
    struct api *a = ctx;
    const char *name = args->name[0] ? args->name : NULL;
    /* one of several hosts: the other hosts' printers too, read off the loop */
    if (api_remote_printers(a->reads, a->cfg.farm, name, printer_local, a, resp))
        return;
    if (!a->cfg.farm || !farm_printer_count(a->cfg.farm)) { /* no printers: nothing to read */
        printers_json(a, name, NULL, 0, resp);
        return;
    }
    struct printers_ask *q = mem_calloc(1, sizeof(*q));
    if (!q) {
        http_error(resp, 500, "out of memory");
        return;
    }
    q->a = a;
    snprintf(q->name, sizeof(q->name), "%s", name ? name : "");
    api_read_run(a->reads, resp, printers_ask_read, printers_ask_finish, q, printers_ask_free);
}

/* The end of an action on printer name: its refusal (rc, err), or the printer as it is now. */
static void
printer_acted(struct api *a, const char *name, int rc, const struct sf_err *err,
              struct http_resp *resp)
{
    if (rc) {
        http_fail(resp, rc, err->msg);
        return;
    }
    printers_answer(a, name, resp);
    changed(a);
}

/* GET /api/printers/NAME/temps: its last hour (temps.h), from memory. */
static void
printer_temps(void *ctx, const struct route_args *args, const struct http_req *req,
              struct http_resp *resp)
{
    (void)req;
    struct api *a = ctx;
    json_t *o = temps_json(a->temps, args->name, API_TICK_MS);
    if (o) {
        resp->json = o;
        return;
    }
    bool known = false;
    size_t np = a->cfg.farm ? farm_printer_count(a->cfg.farm) : 0;
    for (size_t i = 0; i < np && !known; i++) {
        struct printer_info pi;
        farm_printer_info(a->cfg.farm, i, &pi);
        known = strcmp(pi.cfg->name, args->name) == 0;
    }
    if (!known) {
        http_error(resp, 404, "no printer '%.64s'", args->name);
        return;
    }
    resp->json = json_pack("{ss si s[]}", "printer", args->name, "interval_ms", API_TICK_MS,
                           "samples"); /* not sampled yet */
}

static void
printer_act(void *ctx, const struct route_args *args, const struct http_req *req,
            struct http_resp *resp)
{
    struct api *a = ctx;
    enum printer_action act;
    char who[16];
    if (!printer_action_parse(args->action, &act)) {
        http_error(resp, 404,
                   "no printer action '%.32s' (pause, resume, cancel, cancel-copy, cleared)",
                   args->action);
        return;
    }
    route_key_label(req, who, sizeof(who));
    api_writes_printer_act(&a->writes, args->name, act, who, resp);
}

/*
 * POST /api/printers/NAME/command {"command": "G28"}: one manual G-code
 * line for an idle printer with a clear bed.  400 a bad body or a refused
 * command (M110, M111, control bytes), 404 no such printer, 409 the
 * printer cannot take one now (printing, busy, awaiting clear, in error,
 * holding an interrupted job: SF_EAGAIN), 503 it is offline or the store
 * is busy (whether it holds an interrupted job is not known), 501 its kind
 * has no way to send one (PrusaLink); 200 with the printer.
 */
static void
printer_cmd(void *ctx, const struct route_args *args, const struct http_req *req,
            struct http_resp *resp)
{
    struct api *a = ctx;
    struct sf_err err;
    char line[SF_COMMAND_MAX + 1], who[16];
    if (api_command_parse(req->body, req->body_len, line, sizeof(line), &err)) {
        http_error(resp, 400, "%s", err.msg);
        return;
    }
    route_key_label(req, who, sizeof(who));
    if (api_remote_try(a->cfg.farm, args->name, "command", line, who, resp))
        return; /* another host's printer: carried to it */
    api_writes_printer_cmd(&a->writes, args->name, line, who, resp);
}

/*
 * POST /api/printers/NAME/emergency-stop: the printer's own emergency stop
 * (not a G-code line), the printer then in error and the job on it failed
 * without retry.  404 no such printer, 503 offline; 200 with the printer.
 */
static void
printer_estop_route(void *ctx, const struct route_args *args, const struct http_req *req,
                    struct http_resp *resp)
{
    struct api *a = ctx;
    struct sf_err err;
    char who[16];
    route_key_label(req, who, sizeof(who));
    if (api_remote_try(a->cfg.farm, args->name, "emergency-stop", NULL, who, resp))
        return;
    int rc = jobctl_printer_estop(a->cfg.farm, args->name, who, &err);
    printer_acted(a, args->name, rc, &err, resp);
}

/* ---- events ---- */

static void
events_stream(void *ctx, const struct route_args *args, const struct http_req *req,
              struct http_resp *resp)
{
    (void)args;
    struct api *a = ctx;
    api_sse_open(&a->sse, req, resp);
}

/* ---- dispatch ---- */

/* api.c's rows of the route table (route.h); api_compat's and web's come first. */
static const struct route rows[] = {
    /* methods, pattern, match, body, scope, handler, 405 message */
    { ROUTE_GET, "/api/jobs", NULL, HTTP_BODY_NONE, ROUTE_READ, jobs_list, ROUTE_405 },
    { ROUTE_GET, "/api/jobs/{id}", NULL, HTTP_BODY_NONE, ROUTE_READ, job_get, ROUTE_405 },
    { ROUTE_GET, "/api/stats", NULL, HTTP_BODY_NONE, ROUTE_READ, stats_get, ROUTE_405 },
    { ROUTE_GET, "/api/printers", NULL, HTTP_BODY_NONE, ROUTE_READ, printers_get, "use GET" },
    { ROUTE_GET, "/api/printers/{name}", NULL, HTTP_BODY_NONE, ROUTE_READ, printers_get,
      "use GET" },
    { ROUTE_GET, "/api/printers/{name}/temps", NULL, HTTP_BODY_NONE, ROUTE_READ, printer_temps,
      ROUTE_405 },
    { ROUTE_POST, "/api/printers/{name}/command", NULL, HTTP_BODY_JSON, ROUTE_WRITE, printer_cmd,
      ROUTE_405 },
    { ROUTE_POST, "/api/printers/{name}/emergency-stop", NULL, HTTP_BODY_NONE, ROUTE_WRITE,
      printer_estop_route, ROUTE_405 },
    { ROUTE_POST, "/api/printers/{name}/{action}", NULL, HTTP_BODY_NONE, ROUTE_WRITE, printer_act,
      ROUTE_405 },
    { ROUTE_GET, "/api/events", NULL, HTTP_BODY_NONE, ROUTE_READ, events_stream, ROUTE_405 },
};

static void
route(void *ud, const struct http_req *req, struct http_resp *resp)
{
    struct api *a = ud;
    route_dispatch(a->groups, API_GROUPS, req, resp);
}

/* Which body a request may carry, from its head (http.c refuses a
   multipart upload anywhere else before reading a byte of it). */
static enum http_body
body_kind(void *ud, const char *method, const char *path)
{
    struct api *a = ud;
    return route_body(a->groups, API_GROUPS, method, path);
}

static bool
is_public(void *ud, const char *path)
{
    (void)ud;
    return web_needs_no_key(path) || api_octopush_public(path);
}

static const char *
session_key(void *ud, const char *token, const char *csrf)
{
    struct api *a = ud;
    return web_session_key(a->web, token, csrf);
}

static void
web_wake(void *ud)
{
    struct api *a = ud;
    http_wake_streams(a->http);
}

struct api *
api_new(const struct api_config *cfg, struct sf_err *err)
{
    struct api *a = mem_calloc(1, sizeof(*a));
    if (!a) {
        sf_err_set(err, SF_ENOMEM, "api: out of memory");
        return NULL;
    }
    a->cfg = *cfg;
    a->slicers = (struct api_compat_env){ .store = cfg->store,
                                          .farm = cfg->farm,
                                          .upload_path = up_path,
                                          .upload_commit = up_commit,
                                          .changed = compat_changed,
                                          .ud = a };
    struct http_config hc = { .host = cfg->host,
                              .port = cfg->port,
                              .keys = cfg->keys,
                              .n_keys = cfg->n_keys,
                              .body_max = API_BODY_MAX,
                              .upload_max = cfg->upload_max,
                              .header_timeout_ms = cfg->header_timeout_ms,
                              .route = route,
                              .body_kind = body_kind,
                              .ud = a,
                              .sink = &sink,
                              .is_public = is_public,
                              .session_key = session_key };
    struct web_config wc = { .store = cfg->store,
                             .pool = cfg->pool,
                             .wake = web_wake,
                             .ud = a,
                             .instance = cfg->instance,
                             .session_idle_ms = cfg->session_idle_ms,
                             .session_max_ms = cfg->session_max_ms };
    a->reads = api_read_new(cfg->loop, cfg->store, err);
    a->slicers.reads = a->reads;
    wc.reads = a->reads;
    a->push = a->reads ? api_octopush_new(cfg->loop, a->reads, cfg->farm, cfg->session_idle_ms,
                                          cfg->session_max_ms, err)
                       : NULL;
    a->slicers.push = a->push;
    a->web = a->push ? web_new(&wc, err) : NULL;
    hc.session_cookie = a->web ? web_cookie_name(a->web) : NULL;
    size_t n_compat, n_web, n_printers;
    const struct route *compat = api_compat_routes(&n_compat), *web = web_routes(&n_web),
                       *printers = api_printers_routes(&n_printers);
    a->groups[0] = (struct route_group){ compat, n_compat, &a->slicers };
    a->groups[1] = (struct route_group){ web, n_web, a->web };
    a->groups[2] = (struct route_group){ printers, n_printers, cfg->farm };
    a->writes = (struct api_writes){ .store = cfg->store,
                                     .farm = cfg->farm,
                                     .job = job_answer,
                                     .job_more = job_answer_more,
                                     .printer = printer_answer,
                                     .changed = api_changed,
                                     .ud = a };
    size_t n_writes;
    const struct route *writes = api_writes_routes(&n_writes);
    a->groups[3] = (struct route_group){ writes, n_writes, &a->writes };
    a->groups[4] = (struct route_group){ rows, sizeof(rows) / sizeof(rows[0]), a };
    a->temps = temps_new();
    a->http = a->web && a->temps ? http_new(&hc, err) : NULL;
    a->sse = (struct api_sse_env){ .reads = a->reads, .http = a->http, .farm = cfg->farm };
    if (!a->http) {
        if (!a->temps)
            sf_err_set(err, SF_ENOMEM, "api: out of memory");
        temps_free(a->temps);
        web_free(a->web);
        api_octopush_free(a->push);
        api_read_free(a->reads);
        free(a);
        return NULL;
    }
    return a;
}

void
api_free(struct api *a)
{
    if (!a)
        return;
    api_octopush_free(a->push); /* its sockets close before the server they came through */
    http_free(a->http);         /* ends the picture streams before the renders they wait for */
    web_free(a->web);
    api_read_free(a->reads);       /* reads still queued: their requests went with the server */
    api_writes_orphan(&a->writes); /* answered to no one (the farm's queue calls back later) */
    temps_free(a->temps);
    free(a);
}

int
api_reload(struct api *a, const struct farmcfg *old, const struct farmcfg *next, struct sf_err *err)
{
    size_t closed = 0;
    if (http_set_keys(a->http, next->keys, next->n_keys, &closed))
        return sf_err_set(err, SF_ENOMEM, "api: out of memory for %zu API keys", next->n_keys);
    if (closed)
        log_info("api", "reload: closed %zu event streams of revoked API keys", closed);
    size_t ended = web_keys_changed(a->web, next->keys, next->n_keys);
    if (ended)
        log_info("api", "reload: ended %zu dashboard sessions of revoked API keys", ended);
    ended = api_octopush_keys_changed(a->push, next->keys, next->n_keys);
    if (ended)
        log_info("api", "reload: ended %zu OctoPrint login sessions of revoked API keys", ended);
    if (next->upload_max_bytes != a->cfg.upload_max) {
        log_info("api", "reload: upload_max %zu -> %zu bytes", a->cfg.upload_max,
                 next->upload_max_bytes);
        a->cfg.upload_max = next->upload_max_bytes;
        http_set_upload_max(a->http, next->upload_max_bytes);
    }
    if (old &&
        (strcmp(old->listen_host, next->listen_host) != 0 || old->listen_port != next->listen_port))
        log_warn("api", "reload: listen %s:%d -> %s:%d needs a restart (still on the old one)",
                 old->listen_host, old->listen_port, next->listen_host, next->listen_port);
    return SF_OK;
}

struct http *
api_http(struct api *a)
{
    return a->http;
}

void
api_notify(struct api *a)
{
    http_wake_streams(a->http);
    view_publish(a); /* a printer's state may have changed: the other hosts see it */
}

void
api_tick(struct api *a)
{
    a->sse.tick++;
    http_wake_streams(a->http);
    view_publish(a);
    /* a sample a printer each tick: the chart's history (temps.h) */
    size_t np = a->cfg.farm ? farm_printer_count(a->cfg.farm) : 0;
    int64_t now = clock_wall_ms();
    for (size_t i = 0; i < np; i++) {
        struct printer_info pi;
        farm_printer_info(a->cfg.farm, i, &pi);
        const double c[4] = { pi.nozzle_c, pi.nozzle_target_c, pi.bed_c, pi.bed_target_c };
        temps_add(a->temps, pi.cfg->name, now, pi.state != PRINTER_OFFLINE, c);
    }
}
