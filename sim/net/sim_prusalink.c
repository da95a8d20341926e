/*
 * sim_prusalink.c - PrusaLink's v1 HTTP API over a simulated machine
 * (sim_prusalink.h).
 *
 * The job lives in sim_netprinter; this face numbers jobs (ids from 100,
 * as a printer's counter would be past its first prints), names files as
 * the USB stick holds them (a long display name and an 8.3 short one), and
 * reports the machine's state in PrusaLink's words: IDLE, PRINTING,
 * PAUSED, FINISHED, STOPPED, ERROR.  A watch timer fires the
 * line-triggered faults.
 *
 * Beside v1 (spec/openapi.yaml), the legacy endpoints Buddy firmware and
 * Prusa-Link still serve and clients call (spec/openapi-legacy.yaml,
 * info.version 2.0.0, Prusa-Link-Web commit 337fabbd): GET /api/printer,
 * /api/job and /api/files, in their OctoPrint-like shapes; and from v1
 * also GET /api/v1/files/usb/NAME (the file's PrintFileInfo) and GET
 * /api/v1/storage (PrusaSlicer asks it before an upload).
 *
 * Thread: the loop thread.
 */
#include "sim_prusalink.h"

#include <ctype.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../../src/base/mem.h"
#include "sim_netbase.h"
#include "sim_netcli.h"

#define WATCH_MS  20
#define FILES_MAX 1024 /* files a list shows */

struct sim_prusalink {
    struct sim_netbase b; /* machine, HTTP server, watch timer; first (sim_netbase.h) */
    struct sim_prusalink_config cfg;
    int64_t job_id;                 /* id of the current (or last) job, 0 before the first */
    int64_t next_id;                /* the next job's id */
    long busy_left;                 /* uploads still to meet a busy printer */
    bool fired_error, fired_cancel; /* each fault once a job */
    int64_t m_timestamp;            /* upload time of the job's file, Unix seconds */
};

void
sim_prusalink_config_init(struct sim_prusalink_config *c)
{
    memset(c, 0, sizeof(*c));
    sim_netprinter_config_init(&c->machine);
}

int
sim_prusalink_fault_parse(struct sim_prusalink_config *c, const char *spec, struct sf_err *err)
{
    int rc = sim_http_fault_parse(&c->http, spec, err);
    if (rc != SF_EUNSUPP)
        return rc;
    const char *v;
    if ((v = sim_netbase_fault_arg(spec, "busy")))
        return sim_netbase_fault_count(spec, v, &c->busy_uploads, err);
    if ((v = sim_netbase_fault_arg(spec, "error")))
        return sim_netbase_fault_count(spec, v, &c->error_at, err);
    if ((v = sim_netbase_fault_arg(spec, "cancel")))
        return sim_netbase_fault_count(spec, v, &c->cancel_at, err);
    if ((v = sim_netbase_fault_arg(spec, "dismiss")))
        return sim_netbase_fault_count(spec, v, &c->dismiss, err);
    return faults_parse(&c->machine.faults, spec, err);
}

/* ---- replies ---- */

/* An error as the spec has it: the Error object if the client takes JSON, else plain text. */
static void
reply_err(struct sim_http_req *r, unsigned status, const char *title, const char *text)
{
    const char *accept = sim_http_header(r, "Accept");
    if (accept && strstr(accept, "application/json")) {
        char code[16];
        snprintf(code, sizeof(code), "10%03u", status);
        sim_http_reply_json(r, status,
                            json_pack("{s:s,s:s,s:s}", "code", code, "title", title, "text", text));
        return;
    }
    sim_http_reply(r, status, "text/plain", text, strlen(text));
}

static const char *
pl_state(const struct sim_np_status *st)
{
    switch (st->state) {
    case SIM_NP_IDLE:
        return "IDLE";
    case SIM_NP_PRINTING:
    case SIM_NP_CANCELLING:
        return "PRINTING";
    case SIM_NP_PAUSING:
    case SIM_NP_PAUSED:
        return "PAUSED";
    case SIM_NP_COMPLETE:
        return "FINISHED";
    case SIM_NP_CANCELLED:
        return "STOPPED";
    case SIM_NP_ERROR:
        return "ERROR";
    }
    return "IDLE";
}

/* The 8.3 name a FAT stick shows for a long one: "SF-3F2~1.GCO". */
static void
short_name(const char *name, char *out, size_t n)
{
    char base[8] = "", ext[4] = "";
    const char *dot = strrchr(name, '.');
    size_t k = 0;
    for (const char *c = name; *c && c != dot && k < 6; c++)
        if (isalnum((unsigned char)*c) || *c == '-' || *c == '_')
            base[k++] = (char)toupper((unsigned char)*c);
    base[k] = '\0';
    k = 0;
    for (const char *c = dot ? dot + 1 : ""; *c && k < 3; c++)
        ext[k++] = (char)toupper((unsigned char)*c);
    ext[k] = '\0';
    snprintf(out, n, "%s~1%s%s", base, ext[0] ? "." : "", ext);
}

static void
on_version(struct sim_http_req *r, void *ud)
{
    (void)ud;
    sim_http_reply_json(r, 200,
                        json_pack("{s:s,s:s,s:s,s:s,s:s,s:s,s:{s:b}}", "api", "2.0.0", "version",
                                  "2.1.2", "printer", "1.0.0", "text", "PrusaLink", "firmware",
                                  "6.1.3+slimfarm-sim", "sdk", "0.7.0", "capabilities",
                                  "upload-by-put", 1));
}

static void
on_info(struct sim_http_req *r, void *ud)
{
    (void)ud;
    sim_http_reply_json(r, 200,
                        json_pack("{s:f,s:b,s:s,s:s,s:i}", "nozzle_diameter", 0.4, "mmu", 0,
                                  "serial", "SIM-0000000001", "hostname", "slimfarm-sim",
                                  "min_extrusion_temp", 170));
}

/* The machine's status as the printer shows it: with dismiss=1 an ended job is gone. */
static void
shown(const struct sim_prusalink *s, struct sim_np_status *st)
{
    sim_netprinter_status(s->b.np, st);
    if (s->cfg.dismiss && (st->state == SIM_NP_COMPLETE || st->state == SIM_NP_CANCELLED))
        st->state = SIM_NP_IDLE;
}

/*
 * job.time_remaining as Prusa firmware gives it: the slicer's minutes left
 * from the file's last M73 R it ran (PrusaSlicer writes them), else its
 * own estimate from the progress; -1 when it has none.
 */
static json_int_t
time_left(const struct sim_np_status *st)
{
    if (st->m73_left_s >= 0)
        return (json_int_t)st->m73_left_s;
    return st->time_left_s >= 0 ? (json_int_t)st->time_left_s : -1;
}

static void
on_status(struct sim_http_req *r, void *ud)
{
    struct sim_prusalink *s = ud;
    struct sim_np_status st;
    shown(s, &st);
    bool err = st.state == SIM_NP_ERROR;
    json_t *printer =
        json_pack("{s:s,s:f,s:f,s:f,s:f,s:f,s:i,s:i,s:i,s:i,s:{s:b,s:s},s:{s:b,s:s}}", "state",
                  pl_state(&st), "temp_nozzle", st.nozzle_c, "target_nozzle", st.nozzle_target_c,
                  "temp_bed", st.bed_c, "target_bed", st.bed_target_c, "axis_z", 0.2, "flow", 100,
                  "speed", 100, "fan_hotend", 0, "fan_print", 0, "status_printer", "ok", !err,
                  "message", err ? st.message : "OK", "status_connect", "ok", 1, "message", "OK");
    json_t *body =
        json_pack("{s:o,s:{s:s,s:s,s:b,s:I}}", "printer", printer, "storage", "name", "usb", "path",
                  "/usb/", "read_only", 0, "free_space", (json_int_t)4000000000LL);
    if (st.state != SIM_NP_IDLE && s->job_id > 0) {
        json_t *job = json_pack("{s:I,s:f,s:I}", "id", (json_int_t)s->job_id, "progress",
                                st.progress * 100, "time_printing", (json_int_t)st.print_time_s);
        if (time_left(&st) >= 0)
            json_object_set_new(job, "time_remaining", json_integer(time_left(&st)));
        json_object_set_new(body, "job", job);
    }
    sim_http_reply_json(r, 200, body);
}

static void
on_job(struct sim_http_req *r, void *ud)
{
    struct sim_prusalink *s = ud;
    struct sim_np_status st;
    shown(s, &st);
    if (st.state == SIM_NP_IDLE || s->job_id == 0) {
        sim_http_reply_empty(r, 204);
        return;
    }
    char sn[16];
    short_name(st.file, sn, sizeof(sn));
    json_t *job = json_pack(
        "{s:I,s:s,s:f,s:I,s:b,s:{s:s,s:s,s:s,s:s,s:I,s:I}}", "id", (json_int_t)s->job_id, "state",
        strcmp(pl_state(&st), "ERROR") == 0 ? "ERROR" : pl_state(&st), "progress",
        st.progress * 100, "time_printing", (json_int_t)st.print_time_s, "inaccurate_estimates", 0,
        "file", "name", sn, "display_name", st.file, "path", "/usb", "display_path", "/usb", "size",
        (json_int_t)st.file_size, "m_timestamp", (json_int_t)s->m_timestamp);
    if (time_left(&st) >= 0)
        json_object_set_new(job, "time_remaining", json_integer(time_left(&st)));
    sim_http_reply_json(r, 200, job);
}

static bool
flag(struct sim_http_req *r, const char *name)
{
    const char *v = sim_http_header(r, name);
    return v && (strcmp(v, "?1") == 0 || strcmp(v, "1") == 0);
}

static int
start(struct sim_prusalink *s, const char *name, struct sf_err *err)
{
    int rc = sim_netprinter_start(s->b.np, name, err);
    if (rc == SF_OK) {
        s->job_id = s->next_id++;
        s->fired_error = s->fired_cancel = false;
        s->m_timestamp = (int64_t)time(NULL);
    }
    return rc;
}

static void
on_file_put(struct sim_http_req *r, void *ud)
{
    struct sim_prusalink *s = ud;
    const char *name = sim_http_rest(r);
    char path[1024];
    struct sf_err err;
    if (sim_netprinter_path(s->b.np, name, path, sizeof(path), &err)) {
        reply_err(r, 400, "BAD REQUEST", err.msg);
        return;
    }
    if (!sim_http_upload(r)) {
        reply_err(r, 400, "BAD REQUEST", "No file in the request body");
        return;
    }
    bool print = flag(r, "Print-After-Upload");
    struct sim_np_status st;
    sim_netprinter_status(s->b.np, &st);
    if (s->busy_left > 0) {
        s->busy_left--;
        reply_err(r, 409, "CONFLICT", "Printer is busy");
        return;
    }
    if (sim_netprinter_file_busy(s->b.np, name)) {
        reply_err(r, 409, "CONFLICT", "File is currently being printed");
        return;
    }
    if (sim_netprinter_file_size(s->b.np, name) >= 0 && !flag(r, "Overwrite")) {
        reply_err(r, 409, "CONFLICT", "File already exists");
        return;
    }
    if (print && (sim_np_running(&st) || st.state == SIM_NP_ERROR)) {
        reply_err(r, 409, "CONFLICT", "Printer is busy");
        return;
    }
    if (sim_http_keep_upload(r, path, &err)) {
        reply_err(r, 500, "INTERNAL SERVER ERROR", err.msg);
        return;
    }
    if (print && start(s, name, &err)) {
        reply_err(r, 409, "CONFLICT", err.msg);
        return;
    }
    sim_http_reply_empty(r, 201);
}

static void
on_file_other(struct sim_http_req *r, void *ud)
{
    struct sim_prusalink *s = ud;
    const char *name = sim_http_rest(r);
    const char *m = sim_http_method(r);
    struct sf_err err;
    if (sim_netprinter_file_size(s->b.np, name) < 0) {
        reply_err(r, 404, "NOT FOUND", "File not found");
        return;
    }
    bool busy = sim_netprinter_file_busy(s->b.np, name);
    if (strcmp(m, "HEAD") == 0) {
        sim_http_add_header(r, "Read-Only", "?0");
        sim_http_add_header(r, "Currently-Printed", busy ? "?1" : "?0");
        sim_http_reply_empty(r, 200);
    } else if (strcmp(m, "POST") == 0) { /* print it */
        if (start(s, name, &err))
            reply_err(r, 409, "CONFLICT", "Printer is busy");
        else
            sim_http_reply_empty(r, 204);
    } else { /* DELETE */
        char path[1024];
        if (busy) {
            reply_err(r, 409, "CONFLICT", "File is currently being printed");
        } else if (sim_netprinter_path(s->b.np, name, path, sizeof(path), &err) == SF_OK &&
                   remove(path) == 0) {
            sim_http_reply_empty(r, 204);
        } else {
            reply_err(r, 500, "INTERNAL SERVER ERROR", "could not delete the file");
        }
    }
}

/* PUT /api/v1/job/{id}/pause|resume|continue, DELETE /api/v1/job/{id}. */
static void
on_job_action(struct sim_http_req *r, void *ud)
{
    struct sim_prusalink *s = ud;
    const char *rest = sim_http_rest(r);
    char *end;
    errno = 0;
    long long id = strtoll(rest, &end, 10);
    const char *what = *end == '/' ? end + 1 : end;
    bool del = strcmp(sim_http_method(r), "DELETE") == 0;
    struct sim_np_status st;
    sim_netprinter_status(s->b.np, &st);
    if (errno || end == rest || id != s->job_id || s->job_id == 0 || st.state == SIM_NP_IDLE ||
        (del ? *what != '\0' : (strcmp(what, "pause") && strcmp(what, "resume")))) {
        reply_err(r, 404, "NOT FOUND", "Job not found");
        return;
    }
    int rc = del                          ? sim_netprinter_cancel(s->b.np, NULL)
             : strcmp(what, "pause") == 0 ? sim_netprinter_pause(s->b.np, NULL)
                                          : sim_netprinter_resume(s->b.np, NULL);
    if (rc) {
        reply_err(r, 409, "CONFLICT", "Job is not in a state that allows this");
        return;
    }
    sim_http_reply_empty(r, 204);
}

/* ---- the legacy API (Prusa-Link-Web spec/openapi-legacy.yaml, "2.0.0") ---- */

/* The OctoPrint-style state text the legacy API gives for a machine state. */
static const char *
legacy_text(const struct sim_np_status *st)
{
    switch (st->state) {
    case SIM_NP_PRINTING:
    case SIM_NP_CANCELLING:
        return "Printing";
    case SIM_NP_PAUSING:
        return "Pausing";
    case SIM_NP_PAUSED:
        return "Paused";
    case SIM_NP_ERROR:
        return "Error";
    default:
        return "Operational";
    }
}

/* GET /api/printer: temperature, sd, state {text, flags}, telemetry.  The telemetry
   carries the spec's names (temp_nozzle) and Buddy firmware's (temp-nozzle): clients
   read either. */
static void
on_legacy_printer(struct sim_http_req *r, void *ud)
{
    struct sim_prusalink *s = ud;
    struct sim_np_status st;
    shown(s, &st);
    bool err = st.state == SIM_NP_ERROR, run = sim_np_running(&st);
    json_t *temps = json_pack("{s:{s:f,s:f,s:f},s:{s:f,s:f,s:f}}", "tool0", "actual", st.nozzle_c,
                              "target", st.nozzle_target_c, "offset", 0.0, "bed", "actual",
                              st.bed_c, "target", st.bed_target_c, "offset", 0.0);
    json_t *fl = json_pack(
        "{s:b,s:b,s:b,s:b,s:b,s:b,s:b,s:b,s:b,s:b,s:b,s:b,s:s}", "operational", !err, "paused",
        st.state == SIM_NP_PAUSED || st.state == SIM_NP_PAUSING, "printing", run, "cancelling",
        st.state == SIM_NP_CANCELLING, "pausing", st.state == SIM_NP_PAUSING, "sdReady", false,
        "error", err, "ready", !err && !run, "closedOrError", err, "finished",
        st.state == SIM_NP_COMPLETE, "prepared", false, "busy", false, "link_state", pl_state(&st));
    json_t *tele =
        json_pack("{s:f,s:f,s:s,s:f,s:i,s:f,s:f,s:f}", "temp_bed", st.bed_c, "temp_nozzle",
                  st.nozzle_c, "material", "PLA", "z-height", 0.2, "print-speed", 100, "temp-bed",
                  st.bed_c, "temp-nozzle", st.nozzle_c, "axis_z", 0.2);
    sim_http_reply_json(r, 200,
                        json_pack("{s:o,s:{s:b},s:{s:s,s:o},s:o}", "temperature", temps, "sd",
                                  "ready", false, "state", "text", legacy_text(&st), "flags", fl,
                                  "telemetry", tele));
}

/* GET /api/job: job {file, estimatedPrintTime}, progress (completion as the spec's
   percentage), state; nulls without a job. */
static void
on_legacy_job(struct sim_http_req *r, void *ud)
{
    struct sim_prusalink *s = ud;
    struct sim_np_status st;
    shown(s, &st);
    bool has = st.state != SIM_NP_IDLE && s->job_id > 0;
    json_int_t left = has ? time_left(&st) : -1;
    char path[SIM_NP_NAME_MAX + 8];
    snprintf(path, sizeof(path), "/usb/%s", st.file);
    json_t *file = has ? json_pack("{s:s,s:s,s:s,s:s,s:I,s:I}", "name", st.file, "display", st.file,
                                   "path", path, "origin", "usb", "size", (json_int_t)st.file_size,
                                   "date", (json_int_t)s->m_timestamp)
                       : json_pack("{s:n,s:n,s:n,s:n,s:n,s:n}", "name", "display", "path", "origin",
                                   "size", "date");
    json_t *job =
        json_pack("{s:o,s:o,s:n,s:n,s:n,s:s}", "file", file, "estimatedPrintTime",
                  left >= 0 ? json_integer((json_int_t)st.print_time_s + left) : json_null(),
                  "averagePrintTime", "lastPrintTime", "filament", "user", "_api");
    json_t *progress = json_pack(
        "{s:o,s:o,s:o,s:o,s:s}", "completion", has ? json_real(st.progress * 100) : json_null(),
        "filepos", has ? json_integer((json_int_t)st.file_pos) : json_null(), "printTime",
        has ? json_integer((json_int_t)st.print_time_s) : json_null(), "printTimeLeft",
        left >= 0 ? json_integer(left) : json_null(), "printTimeLeftOrigin", "estimate");
    sim_http_reply_json(
        r, 200,
        json_pack("{s:o,s:o,s:s}", "job", job, "progress", progress, "state", legacy_text(&st)));
}

/* GET /api/files: the stick as one folder with its files as children. */
static void
on_legacy_files(struct sim_http_req *r, void *ud)
{
    struct sim_prusalink *s = ud;
    struct sim_np_file *list = mem_calloc(FILES_MAX, sizeof(*list));
    if (!list) {
        reply_err(r, 500, "INTERNAL SERVER ERROR", "out of memory");
        return;
    }
    int n = sim_netprinter_files(s->b.np, list, FILES_MAX);
    json_t *children = json_array();
    for (int i = 0; i < n; i++) {
        char path[SIM_NP_NAME_MAX + 8], res[SIM_NP_NAME_MAX + 32];
        snprintf(path, sizeof(path), "/usb/%s", list[i].name);
        snprintf(res, sizeof(res), "/api/files%s", path);
        json_array_append_new(
            children,
            json_pack("{s:s,s:s,s:s,s:s,s:s,s:[s,s],s:I,s:I,s:{s:s,s:s}}", "name", list[i].name,
                      "display", list[i].name, "path", path, "origin", "usb", "type", "machinecode",
                      "typePath", "machinecode", "gcode", "size", (json_int_t)list[i].size, "date",
                      (json_int_t)list[i].mtime_s, "refs", "resource", res, "download", path));
    }
    free(list);
    json_t *usb = json_pack("{s:s,s:s,s:s,s:s,s:s,s:[s],s:o}", "name", "usb", "display", "usb",
                            "path", "/usb", "origin", "usb", "type", "folder", "typePath", "folder",
                            "children", children);
    sim_http_reply_json(r, 200,
                        json_pack("{s:[o],s:I,s:I}", "files", usb, "free", (json_int_t)4000000000LL,
                                  "total", (json_int_t)8000000000LL));
}

/* GET /api/v1/files/usb/NAME: PrintFileInfo (openapi.yaml). */
static void
on_file_get(struct sim_http_req *r, void *ud)
{
    struct sim_prusalink *s = ud;
    const char *name = sim_http_rest(r);
    struct sim_np_file *list = mem_calloc(FILES_MAX, sizeof(*list));
    if (!list) {
        reply_err(r, 500, "INTERNAL SERVER ERROR", "out of memory");
        return;
    }
    int n = sim_netprinter_files(s->b.np, list, FILES_MAX), i = 0;
    while (i < n && strcmp(list[i].name, name) != 0)
        i++;
    if (i == n) {
        free(list);
        reply_err(r, 404, "NOT FOUND", "File not found");
        return;
    }
    char sn[16], dl[SIM_NP_NAME_MAX + 8];
    short_name(name, sn, sizeof(sn));
    snprintf(dl, sizeof(dl), "/usb/%s", name);
    sim_http_reply_json(r, 200,
                        json_pack("{s:s,s:s,s:b,s:I,s:s,s:I,s:{s:s},s:{}}", "name", sn,
                                  "display_name", name, "read_only", false, "size",
                                  (json_int_t)list[i].size, "type", "PRINT_FILE", "m_timestamp",
                                  (json_int_t)list[i].mtime_s, "refs", "download", dl, "meta"));
    free(list);
}

/* GET /api/v1/storage: {storage_list: [Storage]}, the one USB stick. */
static void
on_storage(struct sim_http_req *r, void *ud)
{
    (void)ud;
    sim_http_reply_json(r, 200,
                        json_pack("{s:[{s:s,s:s,s:s,s:I,s:I,s:b,s:b}]}", "storage_list", "name",
                                  "usb", "type", "USB", "path", "/usb", "free_space",
                                  (json_int_t)4000000000LL, "total_space", (json_int_t)8000000000LL,
                                  "available", true, "read_only", false));
}

static const struct sim_http_route routes[] = {
    { "GET", "/api/version", SIM_HTTP_BODY_MEM, false, on_version },
    { "GET", "/api/v1/info", SIM_HTTP_BODY_MEM, false, on_info },
    { "GET", "/api/v1/status", SIM_HTTP_BODY_MEM, false, on_status },
    { "GET", "/api/v1/job", SIM_HTTP_BODY_MEM, false, on_job },
    { "GET", "/api/v1/storage", SIM_HTTP_BODY_MEM, false, on_storage },
    { "GET", "/api/printer", SIM_HTTP_BODY_MEM, false, on_legacy_printer },
    { "GET", "/api/job", SIM_HTTP_BODY_MEM, false, on_legacy_job },
    { "GET", "/api/files", SIM_HTTP_BODY_MEM, false, on_legacy_files },
    { "GET", "/api/v1/files/usb/*", SIM_HTTP_BODY_MEM, false, on_file_get },
    { "PUT", "/api/v1/files/usb/*", SIM_HTTP_BODY_FILE, false, on_file_put },
    { "HEAD", "/api/v1/files/usb/*", SIM_HTTP_BODY_MEM, false, on_file_other },
    { "POST", "/api/v1/files/usb/*", SIM_HTTP_BODY_MEM, false, on_file_other },
    { "DELETE", "/api/v1/files/usb/*", SIM_HTTP_BODY_MEM, false, on_file_other },
    { "PUT", "/api/v1/job/*", SIM_HTTP_BODY_MEM, false, on_job_action },
    { "DELETE", "/api/v1/job/*", SIM_HTTP_BODY_MEM, false, on_job_action },
};

static void
on_watch(void *ud)
{
    struct sim_prusalink *s = ud;
    struct sim_np_status st;
    sim_netprinter_status(s->b.np, &st);
    sim_http_outage_watch(s->b.http, sim_np_running(&st), st.lines_done);
    if (st.state != SIM_NP_PRINTING)
        return;
    long done = (long)st.lines_done;
    if (s->cfg.error_at && !s->fired_error && done >= s->cfg.error_at) {
        s->fired_error = true;
        sim_netprinter_fail(s->b.np, "Thermal runaway: heater nozzle");
    } else if (s->cfg.cancel_at && !s->fired_cancel && done >= s->cfg.cancel_at) {
        s->fired_cancel = true;
        sim_netprinter_cancel(s->b.np, NULL); /* stopped on the printer's screen */
    }
}

struct sim_prusalink *
sim_prusalink_new(struct loop *l, const struct sim_prusalink_config *c, struct sf_err *err)
{
    struct sim_prusalink *s = sim_netbase_alloc(sizeof(*s), "prusalink", err);
    if (!s)
        return NULL;
    s->cfg = *c;
    s->next_id = 100;
    s->busy_left = c->busy_uploads;
    bool digest = c->user && c->user[0];
    struct sim_http_config hc = {
        .port = c->port,
        .routes = routes,
        .n_routes = sizeof(routes) / sizeof(routes[0]),
        .ud = s,
        .api_key = !digest && c->api_key && c->api_key[0] ? c->api_key : NULL,
        .key_header = "X-Api-Key",
        .auth_status = 401,
        .auth_body = "{\"title\": \"Unauthorized\", \"text\": \"Invalid API key\"}",
        .digest_user = digest ? c->user : NULL,
        .digest_password = digest ? (c->password ? c->password : "") : NULL,
        .realm = "Printer API",
        .faults = c->http,
    };
    if (sim_netbase_init(&s->b, l, &c->machine, &hc, WATCH_MS, on_watch, err))
        goto fail;
    return s;
fail:
    sim_prusalink_free(s);
    return NULL;
}

int
sim_prusalink_port(const struct sim_prusalink *s)
{
    return sim_netbase_port(&s->b);
}

void
sim_prusalink_status(const struct sim_prusalink *s, struct sim_np_status *out)
{
    sim_netbase_status(&s->b, out);
}

void
sim_prusalink_free(struct sim_prusalink *s)
{
    sim_netbase_free(s);
}

/* ---- slimfarm-sim prusalink (sim_netcli.h) ---- */

static void *
face_new(struct loop *l, const struct sim_net_opts *o, int index, struct sf_err *err)
{
    (void)index;
    struct sim_prusalink_config c;
    sim_prusalink_config_init(&c);
    c.port = o->port;
    c.api_key = o->api_key;
    c.user = o->user;
    c.password = o->password;
    sim_net_machine(o, &c.machine);
    for (int i = 0; i < o->n_faults; i++)
        if (sim_prusalink_fault_parse(&c, o->faults[i], err))
            return NULL;
    return sim_prusalink_new(l, &c, err);
}

int
sim_prusalink_main(int argc, char **argv)
{
    return sim_netbase_main(
        argc, argv,
        "faults: busy=N error=LINE cancel=LINE (the printer), and the HTTP and firmware\n"
        "        faults of every simulator; --user/--password: HTTP Digest instead of the key\n",
        face_new);
}
