/*
 * sim_moonraker.c - Moonraker's HTTP API over a simulated machine
 * (sim_moonraker.h).
 *
 * Klippy's state (ready, startup, shutdown) lives here; the job lives in
 * sim_netprinter and is reported in Klipper's words: print_stats.state
 * standby, printing, paused, complete, cancelled or error, and the
 * virtual_sdcard's file position.  A watch timer fires the line-triggered
 * faults (shutdown, error, cancel at the printer) when the job gets there,
 * and samples the temperature store.  The server side clients read beside
 * the printer (file lists, roots, temperature store, config, HTTP
 * subscribe, the [octoprint_compat] emulation) is sim_moonraker_srv.c.
 *
 * Thread: the loop thread.
 */
#include "sim_moonraker.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <time.h>

#include "../../src/base/mem.h"
#include "../../src/base/ws.h"
#include "sim_moonraker_int.h"
#include "sim_netbase.h"
#include "sim_netcli.h"

#define WATCH_MS   20  /* how often line-triggered faults are checked */
#define RESTART_MS 300 /* a firmware_restart's "startup" phase */

static const char shutdown_text[] =
    "MCU 'mcu' shutdown: Timer too close\nThis often indicates the host computer is "
    "overloaded. Check\nfor other processes consuming excessive CPU time, high swap\nusage, "
    "disk errors, overheating, unstable voltage, or\nsimilar system problems on the host "
    "computer.\nOnce the underlying issue is corrected, use the\n\"FIRMWARE_RESTART\" command "
    "to reset the firmware, reload the\nconfig, and restart the host software.\nPrinter is "
    "shutdown";

void
sim_moonraker_config_init(struct sim_moonraker_config *c)
{
    memset(c, 0, sizeof(*c));
    sim_netprinter_config_init(&c->machine);
}

int
sim_moonraker_fault_parse(struct sim_moonraker_config *c, const char *spec, struct sf_err *err)
{
    int rc = sim_http_fault_parse(&c->http, spec, err);
    if (rc != SF_EUNSUPP)
        return rc;
    const char *v;
    if ((v = sim_netbase_fault_arg(spec, "shutdown")))
        return sim_netbase_fault_count(spec, v, &c->shutdown_at, err);
    if ((v = sim_netbase_fault_arg(spec, "error")))
        return sim_netbase_fault_count(spec, v, &c->error_at, err);
    if ((v = sim_netbase_fault_arg(spec, "cancel")))
        return sim_netbase_fault_count(spec, v, &c->cancel_at, err);
    if ((v = sim_netbase_fault_arg(spec, "miss-ready")))
        return sim_netbase_fault_count(spec, v, &c->miss_ready, err);
    if ((v = sim_netbase_fault_arg(spec, "startup"))) {
        long ms;
        if ((rc = sim_netbase_fault_count(spec, v, &ms, err)))
            return rc;
        c->startup_ms = (int)(ms > 3600000 ? 3600000 : ms);
        return SF_OK;
    }
    return faults_parse(&c->machine.faults, spec, err);
}

/* ---- replies ---- */

void
sim_moonraker_result(struct sim_http_req *r, json_t *result)
{
    sim_http_reply_json(r, 200, json_pack("{s:o}", "result", result ? result : json_null()));
}

static void
reply_ok(struct sim_http_req *r)
{
    sim_moonraker_result(r, json_string("ok"));
}

void
sim_moonraker_error(struct sim_http_req *r, unsigned status, const char *message)
{
    sim_http_reply_json(
        r, status, json_pack("{s:{s:i,s:s}}", "error", "code", (int)status, "message", message));
}

static const char *
klippy_name(enum klippy k)
{
    return k == K_READY ? "ready" : k == K_STARTUP ? "startup" : "shutdown";
}

bool
sim_moonraker_klippy_up(struct sim_moonraker *s, struct sim_http_req *r)
{
    if (s->klippy != K_STARTUP)
        return true;
    sim_moonraker_error(r, 503, "Klippy Host not connected");
    return false;
}

/* Klippy must be ready for gcode and print requests; else the error Klipper gives. */
static bool
need_ready(struct sim_moonraker *s, struct sim_http_req *r)
{
    if (s->klippy == K_READY)
        return true;
    sim_moonraker_error(r, s->klippy == K_STARTUP ? 503 : 400,
                        s->klippy == K_STARTUP ? "Klippy Host not connected"
                                               : "Printer is shutdown");
    return false;
}

/* A request argument from the JSON body, else the query string; NULL if neither. */
static const char *
arg(struct sim_http_req *r, const char *name, json_t **hold)
{
    size_t len = 0;
    sim_http_body(r, &len);
    if (len > 0) {
        json_t *b = sim_http_json(r, NULL);
        json_t *v = b ? json_object_get(b, name) : NULL;
        if (v && json_is_string(v)) {
            *hold = b;
            return json_string_value(v);
        }
        json_decref(b);
    }
    return sim_http_query(r, name);
}

/* ---- status in Klipper's words ---- */

static const char *
ps_state(const struct sim_np_status *st)
{
    switch (st->state) {
    case SIM_NP_IDLE:
        return "standby";
    case SIM_NP_PRINTING:
    case SIM_NP_CANCELLING:
        return "printing";
    case SIM_NP_PAUSING:
    case SIM_NP_PAUSED:
        return "paused";
    case SIM_NP_CANCELLED:
        return "cancelled";
    case SIM_NP_COMPLETE:
        return "complete";
    case SIM_NP_ERROR:
        return "error";
    }
    return "standby";
}

/* The object called name, or NULL if this printer has none. */
static json_t *
object(struct sim_moonraker *s, const char *name, const struct sim_np_status *st)
{
    bool loaded = st->state != SIM_NP_IDLE;
    if (strcmp(name, "webhooks") == 0)
        return json_pack("{s:s,s:s}", "state", klippy_name(s->klippy), "state_message",
                         s->klippy_msg);
    if (strcmp(name, "print_stats") == 0)
        return json_pack("{s:s,s:f,s:f,s:f,s:s,s:s,s:{s:n,s:n}}", "filename",
                         loaded ? st->file : "", "total_duration", st->print_time_s,
                         "print_duration", st->print_time_s, "filament_used", 0.0, "state",
                         ps_state(st), "message", st->state == SIM_NP_ERROR ? st->message : "",
                         "info", "total_layer", "current_layer");
    if (strcmp(name, "virtual_sdcard") == 0) {
        char path[1024];
        json_t *fp = json_null();
        if (loaded && sim_netprinter_path(s->b.np, st->file, path, sizeof(path), NULL) == SF_OK)
            fp = json_string(path);
        return json_pack("{s:o,s:f,s:b,s:I,s:I}", "file_path", fp, "progress", st->progress,
                         "is_active", st->state == SIM_NP_PRINTING, "file_position",
                         (json_int_t)(loaded ? st->file_pos : 0), "file_size",
                         (json_int_t)(loaded ? st->file_size : 0));
    }
    if (strcmp(name, "extruder") == 0)
        return json_pack("{s:f,s:f,s:f,s:b,s:f,s:f,s:n}", "temperature", st->nozzle_c, "target",
                         st->nozzle_target_c, "power", st->nozzle_target_c > 0 ? 0.4 : 0.0,
                         "can_extrude", st->nozzle_c >= 170, "pressure_advance", 0.0, "smooth_time",
                         0.04, "motion_queue");
    if (strcmp(name, "heater_bed") == 0)
        return json_pack("{s:f,s:f,s:f}", "temperature", st->bed_c, "target", st->bed_target_c,
                         "power", st->bed_target_c > 0 ? 0.3 : 0.0);
    if (strcmp(name, "display_status") == 0)
        return json_pack("{s:s,s:f}", "message", "", "progress", st->progress);
    return NULL;
}

static const char *const all_objects[] = { "webhooks", "print_stats", "virtual_sdcard",
                                           "extruder", "heater_bed",  "display_status" };

json_t *
sim_moonraker_pick(struct sim_moonraker *s, json_t *want, const struct sim_np_status *st)
{
    json_t *status = json_object();
    if (!want) {
        for (size_t i = 0; i < sizeof(all_objects) / sizeof(all_objects[0]); i++)
            json_object_set_new(status, all_objects[i], object(s, all_objects[i], st));
        return status;
    }
    const char *name;
    json_t *attrs;
    json_object_foreach(want, name, attrs)
    {
        json_t *o = object(s, name, st);
        if (!o)
            continue;               /* the docs: an object the printer lacks is left out */
        if (json_is_array(attrs)) { /* keep only the attributes asked for */
            json_t *pick = json_object();
            size_t i;
            json_t *a;
            json_array_foreach(attrs, i, a)
            {
                json_t *v = json_is_string(a) ? json_object_get(o, json_string_value(a)) : NULL;
                if (v)
                    json_object_set(pick, json_string_value(a), v);
            }
            json_decref(o);
            o = pick;
        }
        json_object_set_new(status, name, o);
    }
    return status;
}

double
sim_moonraker_eventtime(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec / 1e9;
}

static void
on_query(struct sim_http_req *r, void *ud)
{
    struct sim_moonraker *s = ud;
    if (s->klippy == K_STARTUP) {
        sim_moonraker_error(r, 503, "Klippy Host not connected");
        return;
    }
    s->n_queries++;
    struct sim_np_status st;
    sim_netprinter_status(s->b.np, &st);
    json_t *b = NULL, *want = NULL;
    size_t len = 0;
    sim_http_body(r, &len);
    if (strcmp(sim_http_method(r), "POST") == 0 && len > 0) {
        struct sf_err err;
        b = sim_http_json(r, &err);
        want = b ? json_object_get(b, "objects") : NULL;
        if (!want || !json_is_object(want)) {
            json_decref(b);
            sim_moonraker_error(r, 400, "Invalid argument 'objects'");
            return;
        }
    } /* else GET ?webhooks&print_stats...: the sim answers with every object it has */
    json_t *status = sim_moonraker_pick(s, want, &st);
    json_decref(b);
    sim_moonraker_result(
        r, json_pack("{s:f,s:o}", "eventtime", sim_moonraker_eventtime(), "status", status));
}

/* GET /printer/objects/list: the objects this printer has (Klippy's objects/list). */
static void
on_objects_list(struct sim_http_req *r, void *ud)
{
    if (!sim_moonraker_klippy_up(ud, r))
        return;
    sim_moonraker_result(r, sim_moonraker_objects_list());
}

json_t *
sim_moonraker_objects_list(void)
{
    json_t *list = json_array();
    for (size_t i = 0; i < sizeof(all_objects) / sizeof(all_objects[0]); i++)
        json_array_append_new(list, json_string(all_objects[i]));
    return json_pack("{s:o}", "objects", list);
}

json_t *
sim_moonraker_server_info(struct sim_moonraker *s)
{
    return json_pack("{s:b,s:s,s:[sssss],s:[],s:[ss],s:[],s:i,s:s,s:[iii],s:s}", "klippy_connected",
                     1, "klippy_state", klippy_name(s->klippy), "components", "database",
                     "file_manager", "klippy_apis", "machine", "history", "failed_components",
                     "registered_directories", "config", "gcodes", "warnings", "websocket_count",
                     (int)sim_ws_hub_count(s->b.hub), "moonraker_version", "v0.10.0-slimfarm-sim",
                     "api_version", 1, 5, 0, "api_version_string", "1.5.0");
}

json_t *
sim_moonraker_printer_info(struct sim_moonraker *s)
{
    return json_pack("{s:s,s:s,s:s,s:s}", "state", klippy_name(s->klippy), "state_message",
                     s->klippy_msg, "hostname", "slimfarm-sim", "software_version",
                     "v0.12.0-slimfarm-sim");
}

static void
on_server_info(struct sim_http_req *r, void *ud)
{
    sim_moonraker_result(r, sim_moonraker_server_info(ud));
}

static void
on_printer_info(struct sim_http_req *r, void *ud)
{
    struct sim_moonraker *s = ud;
    if (s->klippy == K_STARTUP) {
        sim_moonraker_error(r, 503, "Klippy Host not connected");
        return;
    }
    sim_moonraker_result(r, sim_moonraker_printer_info(s));
}

/* ---- file metadata and job history ---- */

static double
unix_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec / 1e9;
}

/* PrusaSlicer's "1d 2h 3m 4s" after key in text, in s; -1 if absent. */
static double
find_estimate(const char *text, const char *key)
{
    const char *p = strstr(text, key);
    if (!p)
        return -1;
    p += strlen(key);
    double total = 0;
    bool any = false;
    for (;;) {
        while (*p == ' ')
            p++;
        char *end;
        long v = strtol(p, &end, 10);
        if (end == p || v < 0)
            break;
        int mul = *end == 'd' ? 86400 : *end == 'h' ? 3600 : *end == 'm' ? 60 : *end == 's' ? 1 : 0;
        if (!mul)
            break;
        total += (double)v * mul;
        any = true;
        p = end + 1;
    }
    return any ? total : -1;
}

/*
 * The slicer's print time as Moonraker's metadata parser finds it: for
 * PrusaSlicer-style files the "; estimated printing time (normal mode) ="
 * comment, read in the file's head and tail; -1 if absent.
 */
static double
file_estimate(const char *path)
{
    static const char key[] = "; estimated printing time (normal mode) =";
    FILE *f = fopen(path, "rb");
    if (!f)
        return -1;
    enum { CHUNK = 64 * 1024 };
    char *buf = mem_alloc(CHUNK + 1);
    double est = -1;
    for (int pass = 0; buf && pass < 2 && est < 0; pass++) {
        if (pass == 1 && fseeko(f, -(off_t)CHUNK, SEEK_END) != 0)
            rewind(f);
        size_t n = fread(buf, 1, CHUNK, f);
        buf[n] = '\0';
        est = find_estimate(buf, key);
    }
    free(buf);
    fclose(f);
    return est;
}

/* The uploaded file name's modification time (unix) and size; false if it is not there. */
static bool
file_stat(struct sim_moonraker *s, const char *name, double *mtime, int64_t *size)
{
    char path[1024];
    struct stat sb;
    if (sim_netprinter_path(s->b.np, name, path, sizeof(path), NULL) || stat(path, &sb) != 0)
        return false;
    *mtime = (double)sb.st_mtim.tv_sec + (double)sb.st_mtim.tv_nsec / 1e9;
    *size = (int64_t)sb.st_size;
    return true;
}

/* The newest history entry, if it is still in progress, takes the end st shows. */
static void
hist_settle(struct sim_moonraker *s, const struct sim_np_status *st, const char *otherwise)
{
    struct hist_job *h = s->n_hist ? &s->hist[s->n_hist - 1] : NULL;
    if (!h || strcmp(h->status, "in_progress") != 0)
        return;
    const char *end = st->state == SIM_NP_COMPLETE    ? "completed"
                      : st->state == SIM_NP_CANCELLED ? "cancelled"
                      : st->state == SIM_NP_ERROR
                          ? (s->klippy == K_SHUTDOWN ? "klippy_shutdown" : "error")
                          : otherwise;
    if (!end)
        return;
    snprintf(h->status, sizeof(h->status), "%s", end);
    h->end = unix_now();
    h->print_s = st->print_time_s;
}

/* A print of name started: a new history entry (the oldest goes when full). */
static void
hist_add(struct sim_moonraker *s, const char *name)
{
    if (s->n_hist == HISTORY_MAX) {
        memmove(s->hist, s->hist + 1, sizeof(s->hist[0]) * (HISTORY_MAX - 1));
        s->n_hist--;
    }
    struct hist_job *h = &s->hist[s->n_hist++];
    memset(h, 0, sizeof(*h));
    snprintf(h->id, sizeof(h->id), "%06X", ++s->hist_ids & 0xffffff);
    snprintf(h->file, sizeof(h->file), "%s", name);
    snprintf(h->status, sizeof(h->status), "in_progress");
    h->start = unix_now();
    h->estimated_s = -1;
    char path[1024];
    if (file_stat(s, name, &h->modified, &h->size) &&
        sim_netprinter_path(s->b.np, name, path, sizeof(path), NULL) == SF_OK)
        h->estimated_s = file_estimate(path);
}

/* Start file name as SDCARD_PRINT_FILE would; replies on failure, true on success. */
static bool
start_print(struct sim_moonraker *s, struct sim_http_req *r, const char *name)
{
    struct sim_np_status st;
    sim_netprinter_status(s->b.np, &st);
    hist_settle(s, &st, NULL);
    if (st.state == SIM_NP_ERROR)
        sim_netprinter_reset(s->b.np); /* an errored print is over; Klipper prints again */
    struct sf_err err;
    int rc = sim_netprinter_start(s->b.np, name, &err);
    if (rc == SF_OK) {
        s->fired_shutdown = s->fired_error = s->fired_cancel = false;
        hist_add(s, name);
        return true;
    }
    if (r)
        sim_moonraker_error(r, 400, rc == SF_EAGAIN ? "SD busy" : "Unable to open file");
    return false;
}

static void
on_upload(struct sim_http_req *r, void *ud)
{
    struct sim_moonraker *s = ud;
    const struct sim_http_file *f = sim_http_upload(r);
    if (!f || !f->filename[0]) {
        sim_moonraker_error(r, 400, "Multipart filename omitted");
        return;
    }
    const char *root = sim_http_field(r, "root");
    const char *sub = sim_http_field(r, "path");
    const char *print = sim_http_field(r, "print");
    if (root && strcmp(root, "gcodes") != 0) {
        sim_moonraker_error(r, 400,
                            "Invalid root request"); /* config uploads: not a printer's job */
        return;
    }
    if (sub && sub[0]) {
        sim_moonraker_error(r, 400, "slimfarm-sim: upload sub-folders are not simulated");
        return;
    }
    char path[1024];
    struct sf_err err;
    if (sim_netprinter_path(s->b.np, f->filename, path, sizeof(path), &err)) {
        sim_moonraker_error(r, 400, err.msg);
        return;
    }
    if (sim_netprinter_file_busy(s->b.np, f->filename)) {
        sim_moonraker_error(r, 403, "File is loaded, upload not permitted");
        return;
    }
    if (sim_http_keep_upload(r, path, &err)) {
        sim_moonraker_error(r, 500, err.msg);
        return;
    }
    bool started = false;
    if (print && strcmp(print, "true") == 0 && s->klippy == K_READY)
        started = start_print(s, NULL, f->filename);
    char loc[1200];
    snprintf(loc, sizeof(loc), "http://127.0.0.1:%d/server/files/gcodes/%s",
             sim_http_port(s->b.http), f->filename);
    sim_http_add_header(r, "Location", loc);
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    sim_http_reply_json(r, 201,
                        json_pack("{s:{s:s,s:s,s:f,s:I,s:s},s:b,s:b,s:s}", "item", "path",
                                  f->filename, "root", "gcodes", "modified",
                                  (double)ts.tv_sec + (double)ts.tv_nsec / 1e9, "size",
                                  (json_int_t)f->size, "permissions", "rw", "print_started",
                                  started, "print_queued", 0, "action", "create_file"));
}

static void
on_metadata(struct sim_http_req *r, void *ud)
{
    struct sim_moonraker *s = ud;
    const char *name = sim_http_query(r, "filename");
    double mtime;
    int64_t size;
    char path[1024];
    if (!name || !file_stat(s, name, &mtime, &size) ||
        sim_netprinter_path(s->b.np, name, path, sizeof(path), NULL)) {
        char msg[300];
        snprintf(msg, sizeof(msg), "Metadata not available for <%s>", name ? name : "");
        sim_moonraker_error(r, 404, msg);
        return;
    }
    json_t *md = json_pack("{s:I,s:f,s:s,s:n,s:s}", "size", (json_int_t)size, "modified", mtime,
                           "filename", name, "job_id", "uuid", "00000000-sim");
    double est = file_estimate(path);
    if (est >= 0) { /* as Moonraker's parser reports a PrusaSlicer-style file */
        json_object_set_new(md, "slicer", json_string("PrusaSlicer"));
        json_object_set_new(md, "estimated_time", json_real(est));
    }
    sim_moonraker_result(r, md);
}

/* A query argument as a number, or dflt when absent; false (replied 400) when not a number. */
static bool
num_arg(struct sim_http_req *r, const char *name, double dflt, double *out)
{
    const char *v = sim_http_query(r, name);
    *out = dflt;
    if (!v)
        return true;
    char *end;
    errno = 0;
    *out = strtod(v, &end);
    if (errno || end == v || *end) {
        char msg[120];
        snprintf(msg, sizeof(msg), "Unable to convert argument '%s' to float", name);
        sim_moonraker_error(r, 400, msg);
        return false;
    }
    return true;
}

/* GET /server/history/list?limit&start&since&before&order (history.md). */
static void
on_history_list(struct sim_http_req *r, void *ud)
{
    struct sim_moonraker *s = ud;
    double limit, start, since, before;
    if (!num_arg(r, "limit", 50, &limit) || !num_arg(r, "start", 0, &start) ||
        !num_arg(r, "since", -1, &since) || !num_arg(r, "before", -1, &before))
        return;
    const char *order = sim_http_query(r, "order");
    if (order && strcmp(order, "asc") != 0 && strcmp(order, "desc") != 0) {
        char msg[200];
        snprintf(msg, sizeof(msg), "Invalid `order` value '%.64s'. Must be 'asc' or 'desc'", order);
        sim_moonraker_error(r, 400, msg);
        return;
    }
    bool asc = order && strcmp(order, "asc") == 0;
    struct sim_np_status st;
    sim_netprinter_status(s->b.np, &st);
    json_t *jobs = json_array();
    long skipped = 0;
    for (int k = 0; k < s->n_hist && json_array_size(jobs) < (size_t)limit; k++) {
        const struct hist_job *h = &s->hist[asc ? k : s->n_hist - 1 - k];
        if ((since >= 0 && h->start <= since) || (before >= 0 && h->start >= before))
            continue;
        if (skipped++ < (long)start)
            continue;
        bool live = strcmp(h->status, "in_progress") == 0;
        double mtime = 0;
        int64_t size = -1;
        bool exists = file_stat(s, h->file, &mtime, &size) && mtime == h->modified;
        json_t *md = json_pack("{s:I,s:f,s:s}", "size", (json_int_t)h->size, "modified",
                               h->modified, "filename", h->file);
        if (h->estimated_s >= 0)
            json_object_set_new(md, "estimated_time", json_real(h->estimated_s));
        double dur = live ? st.print_time_s : h->print_s;
        json_array_append_new(jobs,
                              json_pack("{s:s,s:n,s:s,s:b,s:s,s:f,s:o,s:f,s:f,s:f,s:o,s:[]}",
                                        "job_id", h->id, "user", "filename", h->file, "exists",
                                        exists, "status", h->status, "start_time", h->start,
                                        "end_time", live ? json_null() : json_real(h->end),
                                        "print_duration", dur, "total_duration", dur,
                                        "filament_used", 0.0, "metadata", md, "auxiliary_data"));
    }
    sim_moonraker_result(
        r, json_pack("{s:I,s:o}", "count", (json_int_t)json_array_size(jobs), "jobs", jobs));
}

static void
on_print_start(struct sim_http_req *r, void *ud)
{
    struct sim_moonraker *s = ud;
    json_t *hold = NULL;
    const char *name = arg(r, "filename", &hold);
    if (!name) {
        sim_moonraker_error(r, 400, "No data for argument: filename");
    } else if (need_ready(s, r) && start_print(s, r, name)) {
        reply_ok(r);
    }
    json_decref(hold);
}

static void
on_pause(struct sim_http_req *r, void *ud)
{
    struct sim_moonraker *s = ud;
    if (!need_ready(s, r))
        return;
    sim_netprinter_pause(s->b.np, NULL); /* "Print already paused" is not an error */
    reply_ok(r);
}

static void
on_resume(struct sim_http_req *r, void *ud)
{
    struct sim_moonraker *s = ud;
    if (!need_ready(s, r))
        return;
    sim_netprinter_resume(s->b.np, NULL);
    reply_ok(r);
}

static void
on_cancel(struct sim_http_req *r, void *ud)
{
    struct sim_moonraker *s = ud;
    if (!need_ready(s, r))
        return;
    sim_netprinter_cancel(s->b.np, NULL);
    reply_ok(r);
}

/* The text after a RESPOND's MSG= or an M118 (quotes dropped), or NULL: the line says nothing. */
static const char *
echo_text(const char *line, char *out, size_t cap)
{
    const char *m = NULL;
    if (strncasecmp(line, "M118", 4) == 0 && (line[4] == ' ' || !line[4]))
        m = line[4] ? line + 5 : "";
    else if (strncasecmp(line, "RESPOND", 7) == 0 && (line[7] == ' ' || !line[7]))
        m = strcasestr(line, "MSG=") ? strcasestr(line, "MSG=") + 4 : "";
    if (!m)
        return NULL;
    size_t n = strlen(m);
    if (n >= 2 && m[0] == '"' && m[n - 1] == '"')
        m++, n -= 2;
    snprintf(out, cap, "echo: %.*s", (int)n, m);
    return out;
}

int
sim_moonraker_script(struct sim_moonraker *s, const char *script, struct sf_err *err)
{
    /* several commands separated by newlines, each queued in turn */
    char line[256], said[300];
    const char *p = script;
    int rc = SF_OK;
    while (*p && rc == SF_OK) {
        size_t n = strcspn(p, "\n");
        if (n > 0 && n < sizeof(line)) {
            memcpy(line, p, n);
            line[n] = '\0';
            rc = sim_netprinter_command(s->b.np, line, err);
            if (rc == SF_OK && echo_text(line, said, sizeof(said)))
                sim_moonraker_ws_gcode_response(s, said);
        } else if (n >= sizeof(line)) {
            rc = sf_err_set(err, SF_EINVAL, "command too long");
        }
        p += n + (p[n] == '\n');
    }
    if (rc) {
        snprintf(said, sizeof(said), "!! %s", err->msg);
        sim_moonraker_ws_gcode_response(s, said);
    }
    return rc;
}

static void
on_script(struct sim_http_req *r, void *ud)
{
    struct sim_moonraker *s = ud;
    json_t *hold = NULL;
    const char *script = arg(r, "script", &hold);
    struct sf_err err;
    if (!script) {
        sim_moonraker_error(r, 400, "No data for argument: script");
    } else if (need_ready(s, r)) {
        if (sim_moonraker_script(s, script, &err))
            sim_moonraker_error(r, 400, err.msg);
        else
            reply_ok(r);
    }
    json_decref(hold);
}

static void
shut_down(struct sim_moonraker *s, const char *why)
{
    s->klippy = K_SHUTDOWN;
    snprintf(s->klippy_msg, sizeof(s->klippy_msg), "%s", why);
    sim_netprinter_fail(s->b.np, "Printer is shutdown");
}

static void
on_estop(struct sim_http_req *r, void *ud)
{
    struct sim_moonraker *s = ud;
    shut_down(s, "Shutdown due to webhooks request\nPrinter is shutdown");
    reply_ok(r);
}

void
sim_moonraker_firmware_restart(struct sim_moonraker *s)
{
    struct sim_np_status st;
    sim_netprinter_status(s->b.np, &st);
    hist_settle(s, &st, "klippy_disconnect"); /* a print cut short by the restart */
    sim_netprinter_reset(s->b.np);
    s->klippy = K_STARTUP;
    snprintf(s->klippy_msg, sizeof(s->klippy_msg), "Printer is not ready");
    s->ready_at_ms = loop_now_ms(s->b.l) + RESTART_MS;
    sim_moonraker_ws_klippy_lost(s);
}

static void
on_firmware_restart(struct sim_http_req *r, void *ud)
{
    sim_moonraker_firmware_restart(ud);
    reply_ok(r);
}

int
sim_moonraker_ws_opened(const struct sim_moonraker *s)
{
    return s->ws_ids;
}

static const struct sim_http_route routes[] = {
    { "GET", "/server/info", SIM_HTTP_BODY_MEM, false, on_server_info },
    { "GET", "/printer/info", SIM_HTTP_BODY_MEM, false, on_printer_info },
    { "GET", "/printer/objects/list", SIM_HTTP_BODY_MEM, false, on_objects_list },
    { "GET", "/printer/objects/query", SIM_HTTP_BODY_MEM, false, on_query },
    { "POST", "/printer/objects/query", SIM_HTTP_BODY_MEM, false, on_query },
    { "POST", "/server/files/upload", SIM_HTTP_BODY_FORM, false, on_upload },
    { "GET", "/server/files/metadata", SIM_HTTP_BODY_MEM, false, on_metadata },
    { "GET", "/server/history/list", SIM_HTTP_BODY_MEM, false, on_history_list },
    { "POST", "/printer/print/start", SIM_HTTP_BODY_MEM, false, on_print_start },
    { "POST", "/printer/print/pause", SIM_HTTP_BODY_MEM, false, on_pause },
    { "POST", "/printer/print/resume", SIM_HTTP_BODY_MEM, false, on_resume },
    { "POST", "/printer/print/cancel", SIM_HTTP_BODY_MEM, false, on_cancel },
    { "POST", "/printer/gcode/script", SIM_HTTP_BODY_MEM, false, on_script },
    { "POST", "/printer/emergency_stop", SIM_HTTP_BODY_MEM, false, on_estop },
    { "POST", "/printer/firmware_restart", SIM_HTTP_BODY_MEM, false, on_firmware_restart },
    { "GET", "/printer/objects/subscribe", SIM_HTTP_BODY_MEM, false, sim_moonraker_on_subscribe },
    { "POST", "/printer/objects/subscribe", SIM_HTTP_BODY_MEM, false, sim_moonraker_on_subscribe },
    { "GET", "/server/files/list", SIM_HTTP_BODY_MEM, false, sim_moonraker_on_files_list },
    { "GET", "/server/files/roots", SIM_HTTP_BODY_MEM, false, sim_moonraker_on_roots },
    { "GET", "/server/temperature_store", SIM_HTTP_BODY_MEM, false,
      sim_moonraker_on_temperature_store },
    { "GET", "/server/config", SIM_HTTP_BODY_MEM, false, sim_moonraker_on_config },
    { "GET", "/api/version", SIM_HTTP_BODY_MEM, false, sim_moonraker_on_octo_version },
    { "GET", "/api/server", SIM_HTTP_BODY_MEM, false, sim_moonraker_on_octo_server },
    { "POST", "/api/login", SIM_HTTP_BODY_MEM, false, sim_moonraker_on_octo_login },
    /* open: a browser cannot set X-Api-Key on a websocket; the socket asks it (identify) */
    { "GET", "/websocket", SIM_HTTP_BODY_MEM, true, sim_moonraker_on_websocket },
};

/* ---- faults on the job's way ---- */

static void
on_watch(void *ud)
{
    struct sim_moonraker *s = ud;
    if (s->klippy == K_STARTUP && loop_now_ms(s->b.l) >= s->ready_at_ms) {
        s->klippy = K_READY;
        snprintf(s->klippy_msg, sizeof(s->klippy_msg), "Printer is ready");
    }
    struct sim_np_status st;
    sim_netprinter_status(s->b.np, &st);
    hist_settle(s, &st, NULL);
    sim_moonraker_temps_sample(s, &st);
    sim_moonraker_ws_watch(s, &st);
    sim_http_outage_watch(s->b.http, sim_np_running(&st), st.lines_done);
    if (st.state != SIM_NP_PRINTING || s->klippy != K_READY)
        return;
    long done = (long)st.lines_done;
    if (s->cfg.shutdown_at && !s->fired_shutdown && done >= s->cfg.shutdown_at) {
        s->fired_shutdown = true;
        shut_down(s, shutdown_text);
    } else if (s->cfg.error_at && !s->fired_error && done >= s->cfg.error_at) {
        s->fired_error = true;
        sim_netprinter_fail(s->b.np, "Move out of range: 260.000 10.000 0.300 [1203.442]");
    } else if (s->cfg.cancel_at && !s->fired_cancel && done >= s->cfg.cancel_at) {
        s->fired_cancel = true;
        sim_netprinter_cancel(s->b.np, NULL); /* someone pressed cancel on the printer */
    }
}

/* ---- lifecycle ---- */

struct sim_moonraker *
sim_moonraker_new(struct loop *l, const struct sim_moonraker_config *c, struct sf_err *err)
{
    struct sim_moonraker *s = sim_netbase_alloc(sizeof(*s), "moonraker", err);
    if (!s)
        return NULL;
    s->cfg = *c;
    struct sim_http_config hc = {
        .port = c->port,
        .routes = routes,
        .n_routes = sizeof(routes) / sizeof(routes[0]),
        .ud = s,
        .api_key = c->api_key && c->api_key[0] ? c->api_key : NULL,
        .key_header = "X-Api-Key",
        .auth_status = 401,
        .auth_body = "{\"error\": {\"code\": 401, \"message\": \"Unauthorized\"}}",
        .faults = c->http,
    };
    if (sim_netbase_init(&s->b, l, &c->machine, &hc, WATCH_MS, on_watch, err))
        goto fail;
    s->b.hub = sim_moonraker_ws_hub(s);
    if (!s->b.hub) {
        sf_err_set(err, SF_ENOMEM, "moonraker sim: out of memory");
        goto fail;
    }
    s->klippy = c->startup_ms > 0 ? K_STARTUP : K_READY;
    s->ws_klippy = s->klippy;
    snprintf(s->klippy_msg, sizeof(s->klippy_msg), "%s",
             s->klippy == K_READY ? "Printer is ready" : "Printer is not ready");
    s->ready_at_ms = loop_now_ms(l) + c->startup_ms;
    return s;
fail:
    sim_moonraker_free(s);
    return NULL;
}

int
sim_moonraker_port(const struct sim_moonraker *s)
{
    return sim_netbase_port(&s->b);
}

void
sim_moonraker_status(const struct sim_moonraker *s, struct sim_np_status *out)
{
    sim_netbase_status(&s->b, out);
}

uint64_t
sim_moonraker_queries(const struct sim_moonraker *s)
{
    return s->n_queries;
}

void
sim_moonraker_drop_sockets(struct sim_moonraker *s)
{
    sim_ws_hub_close_all(s->b.hub, WS_CLOSE_AWAY, "dropped");
}

void
sim_moonraker_free(struct sim_moonraker *s)
{
    sim_netbase_free(s);
}

/* ---- slimfarm-sim moonraker (sim_netcli.h) ---- */

static void *
face_new(struct loop *l, const struct sim_net_opts *o, int index, struct sf_err *err)
{
    (void)index;
    struct sim_moonraker_config c;
    sim_moonraker_config_init(&c);
    c.port = o->port;
    c.api_key = o->api_key;
    sim_net_machine(o, &c.machine);
    for (int i = 0; i < o->n_faults; i++)
        if (sim_moonraker_fault_parse(&c, o->faults[i], err))
            return NULL;
    return sim_moonraker_new(l, &c, err);
}

int
sim_moonraker_main(int argc, char **argv)
{
    return sim_netbase_main(
        argc, argv,
        "faults: shutdown=LINE error=LINE cancel=LINE startup=MS miss-ready=N (Klipper), and\n"
        "        the HTTP and firmware faults of every simulator\n",
        face_new);
}
