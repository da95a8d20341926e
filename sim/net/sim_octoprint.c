/*
 * sim_octoprint.c - a simulated OctoPrint (sim_octoprint.h): the REST API
 * over sim_http, the printer over sim_netprinter.
 *
 * Replies follow docs.octoprint.org (api/version, api/job, api/printer,
 * api/files, api/connection; 1.10.0 and 1.11.x read side by side) field by
 * field where a client could read them; fields no client of ours reads
 * (history, sd card details, refs.download) are kept minimal but present.
 * State texts are OctoPrint's: Operational, Printing, Pausing, Paused,
 * Cancelling, Finishing, Error.  A job that ran to its end shows Finishing
 * (flags.finishing, still printing) for FINISH_TICKS watch turns, as
 * OctoPrint does while it runs the end of a print, then Operational; after
 * it /api/job keeps its file and final progress, as OctoPrint does.
 *
 * What clients call beside the job (issue 35; OctoPrint 1.11.8's
 * server/api modules and util/flask.py): POST /api/login with passive (the
 * user of the API key, or the anonymous user's needs), GET /api/currentuser,
 * GET /api/files and /api/files/local (the uploads as machinecode files,
 * with free and total), /api/settings, /api/printerprofiles and
 * /api/system/info (minimal but real shapes), POST /api/printer/printhead
 * (jog, home, feedrate) and /api/printer/bed (target, offset) with
 * OctoPrint's checks and G-code.
 *
 * Thread: the loop thread.
 */
#include "sim_octoprint.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/base/mem.h"
#include "sim_http.h"
#include "sim_netcli.h"
#include "sim_netprinter.h"
#include "sim_octoprint_int.h"

/* A print that ran to its end is Finishing from that moment on: the watch turn that starts
   the count may come after a client's request, which must not see Operational first (a farm
   that starts its next job then is refused: "already printing"). */
static bool
finishing(const struct octo_sim *o, const struct sim_np_status *st)
{
    return o->finishing > 0 || (o->was_running && st->state == SIM_NP_COMPLETE);
}

const char *
sim_octoprint_state_text(const struct octo_sim *o, const struct sim_np_status *st)
{
    if (finishing(o, st))
        return "Finishing";
    switch (st->state) {
    case SIM_NP_PRINTING:
        return "Printing";
    case SIM_NP_PAUSING:
        return "Pausing";
    case SIM_NP_PAUSED:
        return "Paused";
    case SIM_NP_CANCELLING:
        return "Cancelling";
    case SIM_NP_ERROR:
        return "Error";
    default:
        return "Operational";
    }
}

bool
sim_octoprint_active(const struct sim_np_status *st)
{
    return st->state == SIM_NP_PRINTING || st->state == SIM_NP_PAUSING ||
           st->state == SIM_NP_PAUSED || st->state == SIM_NP_CANCELLING;
}

/* Not free for a new job: the busy fault, or the end of a print still Finishing. */
static bool
busy(const struct octo_sim *o, const struct sim_np_status *st)
{
    return o->busy || finishing(o, st);
}

json_t *
sim_octoprint_flags(const struct octo_sim *o, const struct sim_np_status *st)
{
    bool err = st->state == SIM_NP_ERROR;
    bool printing = st->state == SIM_NP_PRINTING || st->state == SIM_NP_PAUSING ||
                    st->state == SIM_NP_CANCELLING;
    bool held = busy(o, st);
    return json_pack("{s:b,s:b,s:b,s:b,s:b,s:b,s:b,s:b,s:b,s:b}", "operational", !err, "paused",
                     st->state == SIM_NP_PAUSED, "printing", printing || held, "pausing",
                     st->state == SIM_NP_PAUSING, "cancelling", st->state == SIM_NP_CANCELLING,
                     "sdReady", false, "error", err, "ready",
                     !err && !sim_octoprint_active(st) && !held, "closedOrError", err, "finishing",
                     finishing(o, st));
}

/* ---- handlers ---- */

static void
h_version(struct sim_http_req *r, void *ud)
{
    (void)ud;
    sim_http_reply_json(
        r, 200,
        json_pack("{s:s,s:s,s:s}", "api", "0.1", "server", "1.10.0", "text", "OctoPrint 1.10.0"));
}

static void
h_server(struct sim_http_req *r, void *ud)
{
    (void)ud;
    sim_http_reply_json(r, 200, json_pack("{s:s,s:n}", "version", "1.10.0", "safemode"));
}

static void
h_connection(struct sim_http_req *r, void *ud)
{
    struct octo_sim *o = ud;
    struct sim_np_status st;
    sim_netprinter_status(o->np, &st);
    sim_http_reply_json(
        r, 200,
        json_pack("{s:{s:s,s:s,s:i,s:s},s:{s:[s],s:[i],s:[{s:s,s:s}],s:s,s:i,s:s}}", "current",
                  "state", sim_octoprint_state_text(o, &st), "port", "VIRTUAL", "baudrate", 250000,
                  "printerProfile", "_default", "options", "ports", "VIRTUAL", "baudrates", 250000,
                  "printerProfiles", "id", "_default", "name", "Default", "portPreference",
                  "VIRTUAL", "baudratePreference", 250000, "printerProfilePreference", "_default"));
}

/* The request's JSON body (json_decref), or NULL after a 400 that says what is wrong with it. */
static json_t *
body_json(struct sim_http_req *r)
{
    struct sf_err err;
    json_t *j = sim_http_json(r, &err);
    if (!j)
        sim_http_reply_error(r, 400, err.msg);
    return j;
}

/* POST /api/connection: "connect" brings a printer out of Error, as reconnecting does. */
static void
h_connect(struct sim_http_req *r, void *ud)
{
    struct octo_sim *o = ud;
    json_t *j = body_json(r);
    if (!j)
        return;
    const char *cmd = json_string_value(json_object_get(j, "command"));
    if (cmd && strcmp(cmd, "connect") == 0) {
        sim_netprinter_reset(o->np);
        sim_http_reply_empty(r, 204);
    } else {
        sim_http_reply_error(r, 400, "Unknown command");
    }
    json_decref(j);
}

static json_t *
null_or_real(bool known, double v)
{
    return known ? json_real(v) : json_null();
}

json_t *
sim_octoprint_job(const struct octo_sim *o, const struct sim_np_status *stp)
{
    struct sim_np_status st = *stp;
    bool has = st.file[0] != 0;
    json_t *file = has ? json_pack("{s:s,s:s,s:s,s:s,s:I,s:I}", "name", st.file, "path", st.file,
                                   "display", st.file, "origin", "local", "size",
                                   (json_int_t)st.file_size, "date", (json_int_t)1700000000)
                       : json_pack("{s:n,s:n,s:n,s:n,s:n}", "name", "path", "display", "origin",
                                   "size", "date");
    /* OctoPrint's comes from its G-code analysis: here the time so far plus the time left. */
    bool est = has && st.time_left_s >= 0;
    json_t *job = json_pack("{s:o,s:o,s:n,s:n,s:n,s:s}", "file", file, "estimatedPrintTime",
                            null_or_real(est, st.print_time_s + st.time_left_s), "lastPrintTime",
                            "filament", "averagePrintTime", "user", "slimfarm");
    json_t *progress = json_pack(
        "{s:o,s:o,s:o,s:o,s:s}", "completion", null_or_real(has, st.progress * 100.0), "filepos",
        has ? json_integer((json_int_t)st.file_pos) : json_null(), "printTime",
        has ? json_integer((json_int_t)st.print_time_s) : json_null(), "printTimeLeft",
        has && st.time_left_s >= 0 ? json_integer((json_int_t)st.time_left_s) : json_null(),
        "printTimeLeftOrigin", "linear");
    json_t *reply = json_pack(
        "{s:o,s:o,s:s}", "job", job, "progress", progress, "state",
        o->busy && !sim_octoprint_active(&st) ? "Printing" : sim_octoprint_state_text(o, &st));
    if (st.state == SIM_NP_ERROR)
        json_object_set_new(reply, "error", json_string(st.message));
    return reply;
}

static void
h_job(struct sim_http_req *r, void *ud)
{
    struct octo_sim *o = ud;
    struct sim_np_status st;
    sim_netprinter_status(o->np, &st);
    sim_http_reply_json(r, 200, sim_octoprint_job(o, &st));
}

static void
h_printer(struct sim_http_req *r, void *ud)
{
    struct octo_sim *o = ud;
    struct sim_np_status st;
    sim_netprinter_status(o->np, &st);
    if (st.state == SIM_NP_ERROR) {
        sim_http_reply_error(r, 409, "Printer is not operational");
        return;
    }
    json_t *temps = json_pack("{s:{s:f,s:f,s:i},s:{s:f,s:f,s:f}}", "tool0", "actual", st.nozzle_c,
                              "target", st.nozzle_target_c, "offset", 0, "bed", "actual", st.bed_c,
                              "target", st.bed_target_c, "offset", o->bed_offset_c);
    sim_http_reply_json(r, 200,
                        json_pack("{s:o,s:{s:b},s:{s:s,s:o}}", "temperature", temps, "sd", "ready",
                                  false, "state", "text",
                                  o->busy && !sim_octoprint_active(&st)
                                      ? "Printing"
                                      : sim_octoprint_state_text(o, &st),
                                  "flags", sim_octoprint_flags(o, &st)));
}

static void
file_json_reply(struct sim_http_req *r, unsigned status, const char *name, bool done,
                bool eff_select, bool eff_print, const char *base)
{
    char res[512];
    snprintf(res, sizeof(res), "%s/api/files/local/%s", base, name);
    char dl[512];
    snprintf(dl, sizeof(dl), "%s/downloads/files/local/%s", base, name);
    sim_http_add_header(r, "Location", res);
    sim_http_reply_json(r, status,
                        json_pack("{s:{s:{s:s,s:s,s:s,s:{s:s,s:s}}},s:b,s:b,s:b}", "files", "local",
                                  "name", name, "path", name, "origin", "local", "refs", "resource",
                                  res, "download", dl, "done", done, "effectiveSelect", eff_select,
                                  "effectivePrint", eff_print));
}

static bool
truthy(const char *v)
{
    return v && (strcmp(v, "true") == 0 || strcmp(v, "1") == 0 || strcmp(v, "yes") == 0);
}

static void
start_job(struct octo_sim *o, const char *name)
{
    o->fired = false;
    o->jobs++;
    (void)sim_netprinter_start(o->np, name, NULL);
}

static void
h_upload(struct sim_http_req *r, void *ud)
{
    struct octo_sim *o = ud;
    const struct sim_http_file *f = sim_http_upload(r);
    if (!f || !f->filename[0]) {
        sim_http_reply_error(r, 400, "No file to upload and no folder to create");
        return;
    }
    const char *name = strrchr(f->filename, '/');
    name = name ? name + 1 : f->filename;
    size_t n = strlen(name);
    if (n < 6 || (strcmp(name + n - 6, ".gcode") != 0 && strcmp(name + n - 4, ".gco") != 0 &&
                  strcmp(name + n - 2, ".g") != 0)) {
        sim_http_reply_error(r, 415, "Could not upload the file, invalid type");
        return;
    }
    char path[1024];
    struct sf_err err;
    if (sim_netprinter_path(o->np, name, path, sizeof(path), &err) < 0) {
        sim_http_reply_error(r, 400, err.msg);
        return;
    }
    if (sim_netprinter_file_busy(o->np, name)) {
        sim_http_reply_error(r, 409, "Trying to overwrite file that is currently being printed");
        return;
    }
    if (sim_http_keep_upload(r, path, &err) < 0) {
        sim_http_reply_error(r, 500, err.msg);
        return;
    }
    o->uploads++;
    bool want_print = truthy(sim_http_field(r, "print"));
    bool want_select = want_print || truthy(sim_http_field(r, "select"));
    struct sim_np_status st;
    sim_netprinter_status(o->np, &st);
    /* Not operational, or busy: select and print are silently dropped, as OctoPrint does. */
    bool can = !sim_octoprint_active(&st) && st.state != SIM_NP_ERROR && !busy(o, &st);
    bool printing = false;
    if (want_print && can) {
        start_job(o, name);
        printing = true;
    }
    char base[64];
    snprintf(base, sizeof(base), "%s", o->address);
    file_json_reply(r, 201, name, true, want_select && can, printing, base);
}

static void
h_file(struct sim_http_req *r, void *ud)
{
    struct octo_sim *o = ud;
    const char *name = sim_http_rest(r);
    int64_t size = sim_netprinter_file_size(o->np, name);
    if (size < 0) {
        sim_http_reply_error(r, 404, "File not found");
        return;
    }
    const char *m = sim_http_method(r);
    if (strcmp(m, "GET") == 0) {
        sim_http_reply_json(r, 200,
                            json_pack("{s:s,s:s,s:s,s:s,s:I,s:I}", "name", name, "path", name,
                                      "display", name, "origin", "local", "size", (json_int_t)size,
                                      "date", (json_int_t)1700000000));
        return;
    }
    if (strcmp(m, "DELETE") == 0) {
        char path[1024];
        if (sim_netprinter_file_busy(o->np, name)) {
            sim_http_reply_error(r, 409, "Trying to delete a file that is currently in use");
            return;
        }
        if (sim_netprinter_path(o->np, name, path, sizeof(path), NULL) == 0)
            remove(path);
        sim_http_reply_empty(r, 204);
        return;
    }
    json_t *j = body_json(r);
    if (!j)
        return;
    const char *cmd = json_string_value(json_object_get(j, "command"));
    bool print = json_is_true(json_object_get(j, "print"));
    struct sim_np_status st;
    sim_netprinter_status(o->np, &st);
    if (!cmd || strcmp(cmd, "select") != 0) {
        sim_http_reply_error(r, 400, "Unknown command");
    } else if (sim_octoprint_active(&st) || busy(o, &st)) {
        sim_http_reply_error(r, 409, "Printer is already printing, cannot select a new file");
    } else if (print && st.state == SIM_NP_ERROR) {
        sim_http_reply_error(r, 409, "Printer is not operational, cannot directly start printing");
    } else {
        if (print)
            start_job(o, name);
        sim_http_reply_empty(r, 204);
    }
    json_decref(j);
}

static void
h_job_command(struct sim_http_req *r, void *ud)
{
    struct octo_sim *o = ud;
    struct sf_err err;
    json_t *j = body_json(r);
    if (!j)
        return;
    const char *cmd = json_string_value(json_object_get(j, "command"));
    const char *action = json_string_value(json_object_get(j, "action"));
    struct sim_np_status st;
    sim_netprinter_status(o->np, &st);
    int rc = SF_OK;
    if (!cmd) {
        sim_http_reply_error(r, 400, "Expected a command");
        json_decref(j);
        return;
    }
    if (strcmp(cmd, "start") == 0) {
        if (sim_octoprint_active(&st) || busy(o, &st) || !st.file[0]) {
            sim_http_reply_error(r, 409, "Printer is not operational or already printing");
            rc = SF_EAGAIN;
        } else {
            start_job(o, st.file);
        }
    } else if (strcmp(cmd, "cancel") == 0) {
        rc = sim_netprinter_cancel(o->np, &err);
        if (rc)
            sim_http_reply_error(r, 409, "Printer is neither printing nor paused");
    } else if (strcmp(cmd, "pause") == 0) {
        if (!action || strcmp(action, "toggle") == 0)
            action = st.state == SIM_NP_PAUSED ? "resume" : "pause";
        if (!sim_octoprint_active(&st)) {
            sim_http_reply_error(r, 409, "Printer is neither printing nor paused");
            rc = SF_EAGAIN;
        } else if (strcmp(action, "pause") == 0) {
            if (st.state == SIM_NP_PRINTING)
                sim_netprinter_pause(o->np, NULL); /* already paused: nothing to do */
        } else if (strcmp(action, "resume") == 0) {
            if (st.state == SIM_NP_PAUSED || st.state == SIM_NP_PAUSING)
                sim_netprinter_resume(o->np, NULL);
        } else {
            sim_http_reply_error(r, 400, "Unknown action");
            rc = SF_EINVAL;
        }
    } else if (strcmp(cmd, "restart") == 0) {
        if (st.state != SIM_NP_PAUSED) {
            sim_http_reply_error(r, 409, "Printer is not paused");
            rc = SF_EAGAIN;
        } else {
            sim_netprinter_cancel(o->np, NULL);
        }
    } else {
        sim_http_reply_error(r, 400, "Unknown command");
        rc = SF_EINVAL;
    }
    if (rc == SF_OK)
        sim_http_reply_empty(r, 204);
    json_decref(j);
}

static void
h_command(struct sim_http_req *r, void *ud)
{
    struct octo_sim *o = ud;
    struct sf_err err;
    json_t *j = body_json(r);
    if (!j)
        return;
    struct sim_np_status st;
    sim_netprinter_status(o->np, &st);
    if (st.state == SIM_NP_ERROR) {
        sim_http_reply_error(r, 409, "Printer is not operational");
        json_decref(j);
        return;
    }
    json_t *one = json_object_get(j, "command");
    json_t *many = json_object_get(j, "commands");
    size_t i;
    json_t *c;
    int rc = SF_OK;
    if (json_is_string(one))
        rc = sim_netprinter_command(o->np, json_string_value(one), &err);
    else if (json_is_array(many))
        json_array_foreach(many, i, c)
        {
            if (rc == SF_OK && json_is_string(c))
                rc = sim_netprinter_command(o->np, json_string_value(c), &err);
        }
    else
        rc = sf_err_set(&err, SF_EINVAL, "Expected command or commands");
    if (rc)
        sim_http_reply_error(r, rc == SF_EAGAIN ? 409 : 400, err.msg);
    else
        sim_http_reply_empty(r, 204);
    json_decref(j);
}

/* ---- the user, the files, the settings (what clients read beside the job) ---- */

/* The key the request carries (X-Api-Key, or Authorization: Bearer), NULL if none. */
static const char *
request_key(const struct sim_http_req *r)
{
    const char *k = sim_http_header(r, "X-Api-Key");
    const char *a = sim_http_header(r, "Authorization");
    if (!k && a && strncmp(a, "Bearer ", 7) == 0)
        k = a + 7;
    return k;
}

/* The permissions and groups of the key's user (an admin) or of the anonymous user. */
static json_t *
user_permissions(bool user)
{
    return user ? json_pack("[s,s,s,s,s,s,s,s,s,s,s]", "ADMIN", "STATUS", "CONNECTION", "CONTROL",
                            "FILES_LIST", "FILES_UPLOAD", "FILES_DOWNLOAD", "FILES_DELETE",
                            "FILES_SELECT", "PRINT", "SYSTEM")
                : json_array();
}

static json_t *
user_groups(bool user)
{
    return user ? json_pack("[s,s]", "admins", "users") : json_pack("[s]", "guests");
}

/*
 * POST /api/login: with user and pass (no users here) 403; with passive
 * (in the JSON body, or in the query when the body is no JSON object or
 * an empty one: OctoPrint reads request.values unless request.json) the
 * user of a valid key (User.as_dict plus session) or, without a key, the
 * anonymous user's needs; a wrong key 403 (OctoPrint refuses it before the
 * handler); neither 400.
 */
static void
h_login(struct sim_http_req *r, void *ud)
{
    struct octo_sim *o = ud;
    struct sf_err err;
    json_t *j = sim_http_json(r, &err);
    const char *key = request_key(r);
    bool user = !o->api_key || (key && strcmp(key, o->api_key) == 0);
    if (key && !user)
        sim_http_reply_error(r, 403, "Invalid API key");
    else if (j && json_object_get(j, "user") && json_object_get(j, "pass"))
        sim_http_reply_error(r, 403, "User unknown or password incorrect");
    else if (!(json_object_size(j) ? json_object_get(j, "passive") != NULL
                                   : sim_http_query(r, "passive") != NULL))
        sim_http_reply_error(r, 400, "Neither user and pass attributes nor passive flag present");
    else if (!user || !key)
        sim_http_reply_json(r, 200,
                            json_pack("{s:{s:[],s:[s]},s:b,s:b}", "needs", "role", "group",
                                      "guests", "_is_external_client", false, "_credentials_seen",
                                      false));
    else
        sim_http_reply_json(
            r, 200,
            json_pack("{s:s,s:b,s:o,s:o,s:{s:[s,s,s],s:[s,s]},s:s,s:{},s:b,s:b,s:[s,s],s:s,s:b,"
                      "s:s,s:b}",
                      "name", "slimfarm", "active", true, "permissions", user_permissions(true),
                      "groups", user_groups(true), "needs", "role", "admin", "status", "print",
                      "group", "admins", "users", "apikey", key, "settings", "admin", true, "user",
                      true, "roles", "user", "admin", "session", SIM_OCTO_SESSION,
                      "_is_external_client", false, "_login_mechanism", "apikey",
                      "_credentials_seen", false));
    json_decref(j);
}

/* GET /api/currentuser: name (null when anonymous), permissions, groups. */
static void
h_currentuser(struct sim_http_req *r, void *ud)
{
    struct octo_sim *o = ud;
    const char *key = request_key(r);
    bool user = !o->api_key || (key && strcmp(key, o->api_key) == 0);
    sim_http_reply_json(r, 200,
                        json_pack("{s:o,s:o,s:o}", "name",
                                  user ? json_string("slimfarm") : json_null(), "permissions",
                                  user_permissions(user), "groups", user_groups(user)));
}

/* One local file as OctoPrint's file list gives it (server/api/files.py _getFileList). */
static json_t *
file_entry(const struct octo_sim *o, const struct sim_np_file *f)
{
    char res[512], dl[512];
    snprintf(res, sizeof(res), "%s/api/files/local/%s", o->address, f->name);
    snprintf(dl, sizeof(dl), "%s/downloads/files/local/%s", o->address, f->name);
    return json_pack("{s:s,s:s,s:s,s:s,s:[s,s],s:s,s:{s:s,s:s},s:I,s:I}", "name", f->name,
                     "display", f->name, "path", f->name, "type", "machinecode", "typePath",
                     "machinecode", "gcode", "origin", "local", "refs", "resource", res, "download",
                     dl, "size", (json_int_t)f->size, "date", (json_int_t)f->mtime_s);
}

/* GET /api/files and /api/files/local: {files, free, total}. */
static void
h_files(struct sim_http_req *r, void *ud)
{
    struct octo_sim *o = ud;
    struct sim_np_file *list = mem_calloc(FILES_MAX, sizeof(*list));
    if (!list) {
        sim_http_reply_error(r, 500, "out of memory");
        return;
    }
    int n = sim_netprinter_files(o->np, list, FILES_MAX);
    json_t *files = json_array();
    for (int i = 0; i < n; i++)
        json_array_append_new(files, file_entry(o, &list[i]));
    free(list);
    sim_http_reply_json(r, 200,
                        json_pack("{s:o,s:I,s:I}", "files", files, "free", (json_int_t)4000000000LL,
                                  "total", (json_int_t)8000000000LL));
}

/* GET /api/settings: the sections clients read (appearance, feature, serial,
   temperature, webcam), OctoPrint's defaults. */
static void
h_settings(struct sim_http_req *r, void *ud)
{
    (void)ud;
    json_t *temp = json_pack("{s:[{s:s,s:i,s:i,s:i},{s:s,s:i,s:i,s:i}],s:i,s:b,s:i}", "profiles",
                             "name", "ABS", "extruder", 210, "bed", 100, "chamber", 0, "name",
                             "PLA", "extruder", 180, "bed", 60, "chamber", 0, "cutoff", 30,
                             "sendAutomatically", false, "sendAutomaticallyAfter", 1);
    json_t *webcam = json_pack("{s:b,s:b,s:s,s:s,s:b,s:b,s:b}", "webcamEnabled", false,
                               "timelapseEnabled", false, "streamUrl", "", "snapshotUrl", "",
                               "flipH", false, "flipV", false, "rotate90", false);
    sim_http_reply_json(
        r, 200,
        json_pack("{s:{s:b},s:{s:s,s:s,s:b},s:{s:b,s:b,s:b},s:{s:s,s:i,s:b},s:o,s:o,s:{}}", "api",
                  "allowCrossOrigin", false, "appearance", "name", "", "color", "default",
                  "colorTransparent", false, "feature", "temperatureGraph", true, "sdSupport",
                  false, "keyboardControl", true, "serial", "port", "VIRTUAL", "baudrate", 250000,
                  "autoconnect", true, "temperature", temp, "webcam", webcam, "plugins"));
}

static json_t *
axis(int speed)
{
    return json_pack("{s:i,s:b}", "speed", speed, "inverted", false);
}

/* GET /api/printerprofiles: the one default profile. */
static void
h_profiles(struct sim_http_req *r, void *ud)
{
    struct octo_sim *o = ud;
    char res[256];
    snprintf(res, sizeof(res), "%s/api/printerprofiles/_default", o->address);
    json_t *p = json_pack(
        "{s:s,s:s,s:s,s:s,s:b,s:b,s:s,s:{s:s,s:s,s:i,s:i,s:i,s:b},s:b,s:b,"
        "s:{s:o,s:o,s:o,s:o},s:{s:i,s:[[i,i]],s:f,s:b,s:i}}",
        "id", "_default", "name", "Default", "model", "Generic RepRap Printer", "color", "default",
        "current", true, "default", true, "resource", res, "volume", "formFactor", "rectangular",
        "origin", "lowerleft", "width", 200, "depth", 200, "height", 200, "custom_box", false,
        "heatedBed", true, "heatedChamber", false, "axes", "x", axis(6000), "y", axis(6000), "z",
        axis(200), "e", axis(300), "extruder", "count", 1, "offsets", 0, 0, "nozzleDiameter", 0.4,
        "sharedNozzle", false, "defaultExtrusionLength", 5);
    sim_http_reply_json(r, 200, json_pack("{s:{s:o}}", "profiles", "_default", p));
}

/* GET /api/system/info: {systeminfo: flat keys}. */
static void
h_sysinfo(struct sim_http_req *r, void *ud)
{
    (void)ud;
    sim_http_reply_json(r, 200,
                        json_pack("{s:{s:s,s:b,s:s,s:s,s:i,s:b,s:s}}", "systeminfo",
                                  "octoprint.version", "1.10.0", "octoprint.safe_mode", false,
                                  "env.os.platform", "linux", "env.python.version", "3.11.2",
                                  "env.hardware.cores", 4, "connectivity.online", false,
                                  "printer.firmware", "slimfarm-sim"));
}

/* The body's command (get_json_command_from_request) and the machine's status into st:
   NULL after a 400 reply. */
static json_t *
command_body(struct octo_sim *o, struct sim_http_req *r, const char **cmd, struct sim_np_status *st)
{
    sim_netprinter_status(o->np, st);
    struct sf_err err;
    json_t *j = sim_http_json(r, &err);
    *cmd = j ? json_string_value(json_object_get(j, "command")) : NULL;
    if (!*cmd) {
        sim_http_reply_error(r, 400, j ? "Expected a command" : err.msg);
        json_decref(j);
        return NULL;
    }
    return j;
}

/* Queue G-code lines, OctoPrint's for a printhead or bed command; 409 if refused. */
static bool
send_lines(struct octo_sim *o, struct sim_http_req *r, const char *const *lines, int n)
{
    struct sf_err err;
    for (int i = 0; i < n; i++)
        if (sim_netprinter_command(o->np, lines[i], &err) < 0) {
            sim_http_reply_error(r, 409, err.msg);
            return false;
        }
    return true;
}

/* jog: G91, one G1 with the axes given (and F speed), G90 (absolute: G1 only). */
static bool
jog(struct octo_sim *o, struct sim_http_req *r, json_t *j)
{
    char g1[160] = "G1";
    size_t len = 2;
    static const char *const axes[] = { "x", "y", "z" };
    for (int i = 0; i < 3; i++) {
        json_t *v = json_object_get(j, axes[i]);
        if (!v)
            continue;
        if (!json_is_number(v)) {
            sim_http_reply_error(r, 400, "axis value is invalid");
            return false;
        }
        len +=
            (size_t)snprintf(g1 + len, sizeof(g1) - len, " %c%.4g", 'X' + i, json_number_value(v));
    }
    json_t *speed = json_object_get(j, "speed");
    if (json_is_number(speed))
        snprintf(g1 + len, sizeof(g1) - len, " F%.0f", json_number_value(speed));
    if (json_is_true(json_object_get(j, "absolute"))) {
        return send_lines(o, r, (const char *[]){ g1 }, 1);
    }
    const char *rel[] = { "G91", g1, "G90" };
    return send_lines(o, r, rel, 3);
}

/* home: G28 with the axes given (x, y, z only). */
static bool
home(struct octo_sim *o, struct sim_http_req *r, json_t *j)
{
    json_t *list = json_object_get(j, "axes");
    char g28[32] = "G28";
    size_t len = 3, i;
    json_t *a;
    if (!json_is_array(list)) {
        sim_http_reply_error(r, 400, "Mandatory parameter axes missing for command home");
        return false;
    }
    json_array_foreach(list, i, a)
    {
        const char *s = json_string_value(a);
        if (!s || (strcmp(s, "x") && strcmp(s, "y") && strcmp(s, "z")) || len + 4 > sizeof(g28)) {
            sim_http_reply_error(r, 400, "axis is invalid");
            return false;
        }
        len += (size_t)snprintf(g28 + len, sizeof(g28) - len, " %c0", s[0] - 'a' + 'A');
    }
    return send_lines(o, r, (const char *[]){ g28 }, 1);
}

/* printhead: jog, home, feedrate; 409 when not operational or printing (feedrate
   excepted).  True when the command went (the caller answers 204). */
static bool
printhead(struct octo_sim *o, struct sim_http_req *r, json_t *j, const char *cmd,
          const struct sim_np_status *st)
{
    bool feed = strcmp(cmd, "feedrate") == 0;
    bool ok = false;
    if (!feed && strcmp(cmd, "jog") != 0 && strcmp(cmd, "home") != 0)
        sim_http_reply_error(r, 400, "command is invalid");
    else if (st->state == SIM_NP_ERROR || (!feed && (sim_octoprint_active(st) || busy(o, st))))
        sim_http_reply_error(r, 409, "Printer is not operational or currently printing");
    else if (feed && !json_is_number(json_object_get(j, "factor")))
        sim_http_reply_error(r, 400, "factor is invalid");
    else if (feed) {
        char m220[32];
        double f = json_number_value(json_object_get(j, "factor"));
        snprintf(m220, sizeof(m220), "M220 S%.0f", f <= 2.0 ? f * 100.0 : f);
        ok = send_lines(o, r, (const char *[]){ m220 }, 1);
    } else
        ok = strcmp(cmd, "jog") == 0 ? jog(o, r, j) : home(o, r, j);
    return ok;
}

/* bed: target (M140) and offset (-50..50, kept); 409 when not operational. */
static bool
bed(struct octo_sim *o, struct sim_http_req *r, json_t *j, const char *cmd,
    const struct sim_np_status *st)
{
    json_t *target = json_object_get(j, "target");
    json_t *offset = json_object_get(j, "offset");
    bool ok = false;
    if (st->state == SIM_NP_ERROR)
        sim_http_reply_error(r, 409, "Printer is not operational");
    else if (strcmp(cmd, "target") == 0 && !json_is_number(target))
        sim_http_reply_error(r, 400, "target is invalid");
    else if (strcmp(cmd, "target") == 0) {
        char m140[32];
        snprintf(m140, sizeof(m140), "M140 S%.0f", json_number_value(target));
        ok = send_lines(o, r, (const char *[]){ m140 }, 1);
    } else if (strcmp(cmd, "offset") == 0 &&
               (!json_is_number(offset) || fabs(json_number_value(offset)) > 50))
        sim_http_reply_error(r, 400, "offset is invalid");
    else if (strcmp(cmd, "offset") == 0) {
        o->bed_offset_c = json_number_value(offset);
        ok = true;
    } else
        sim_http_reply_error(r, 400, "command is invalid");
    return ok;
}

/* POST /api/printer/printhead and /api/printer/bed: OctoPrint's command checks, then 204. */
static void
h_printer_command(struct sim_http_req *r, void *ud)
{
    struct octo_sim *o = ud;
    const char *cmd;
    struct sim_np_status st;
    json_t *j = command_body(o, r, &cmd, &st);
    if (!j)
        return;
    bool is_bed = strcmp(sim_http_path(r), "/api/printer/bed") == 0;
    if (is_bed ? bed(o, r, j, cmd, &st) : printhead(o, r, j, cmd, &st))
        sim_http_reply_empty(r, 204);
    json_decref(j);
}

static const struct sim_http_route routes[] = {
    { "GET", "/api/version", SIM_HTTP_BODY_MEM, false, h_version },
    { "POST", "/api/login", SIM_HTTP_BODY_MEM, true, h_login },
    { "GET", "/api/currentuser", SIM_HTTP_BODY_MEM, true, h_currentuser },
    { "GET", "/api/files", SIM_HTTP_BODY_MEM, false, h_files },
    { "GET", "/api/files/local", SIM_HTTP_BODY_MEM, false, h_files },
    { "GET", "/api/settings", SIM_HTTP_BODY_MEM, false, h_settings },
    { "GET", "/api/printerprofiles", SIM_HTTP_BODY_MEM, false, h_profiles },
    { "GET", "/api/system/info", SIM_HTTP_BODY_MEM, false, h_sysinfo },
    { "POST", "/api/printer/printhead", SIM_HTTP_BODY_MEM, false, h_printer_command },
    { "POST", "/api/printer/bed", SIM_HTTP_BODY_MEM, false, h_printer_command },
    { "GET", "/api/server", SIM_HTTP_BODY_MEM, false, h_server },
    { "GET", "/api/connection", SIM_HTTP_BODY_MEM, false, h_connection },
    { "POST", "/api/connection", SIM_HTTP_BODY_MEM, false, h_connect },
    { "GET", "/api/job", SIM_HTTP_BODY_MEM, false, h_job },
    { "POST", "/api/job", SIM_HTTP_BODY_MEM, false, h_job_command },
    { "GET", "/api/printer", SIM_HTTP_BODY_MEM, false, h_printer },
    { "POST", "/api/printer/command", SIM_HTTP_BODY_MEM, false, h_command },
    { "POST", "/api/files/local", SIM_HTTP_BODY_FORM, false, h_upload },
    { "GET", "/api/files/local/*", SIM_HTTP_BODY_MEM, false, h_file },
    { "POST", "/api/files/local/*", SIM_HTTP_BODY_MEM, false, h_file },
    { "DELETE", "/api/files/local/*", SIM_HTTP_BODY_MEM, false, h_file },
    /* the push socket: open, as a browser cannot send the key; the socket's auth message
       carries the user instead */
    { "GET", "/sockjs/info", SIM_HTTP_BODY_MEM, true, sim_octoprint_on_sockjs_info },
    { "GET", "/sockjs/*", SIM_HTTP_BODY_MEM, true, sim_octoprint_on_sockjs },
};

/* ---- faults on the job ---- */

static void
on_tick(struct loop *l, void *ud)
{
    struct octo_sim *o = ud;
    struct sim_np_status st;
    sim_netprinter_status(o->np, &st);
    sim_http_outage_watch(o->http, sim_np_running(&st), st.lines_done);
    if (o->finishing > 0)
        o->finishing--;
    if (o->was_running && st.state == SIM_NP_COMPLETE)
        o->finishing = FINISH_TICKS;
    o->was_running = sim_octoprint_active(&st);
    sim_octoprint_push_watch(o, &st);
    if (!o->fired && (st.state == SIM_NP_PRINTING || st.state == SIM_NP_PAUSED)) {
        if (o->error_at && !o->err_fired && st.lines_done >= (uint64_t)o->error_at) {
            o->err_fired = true;
            sim_netprinter_fail(o->np, "Printer halted: heater failure (simulated)");
        } else if (o->cancel_at && st.lines_done >= (uint64_t)o->cancel_at) {
            o->fired = true;
            sim_netprinter_cancel(o->np, NULL);
        }
    }
    o->tick = loop_timer_add(l, 10, on_tick, o);
}

static int
octo_fault(struct octo_sim *o, const char *spec, struct sf_err *err)
{
    long *dst = NULL;
    const char *v = NULL;
    if (strncmp(spec, "error-at=", 9) == 0)
        dst = &o->error_at, v = spec + 9;
    else if (strncmp(spec, "cancel-at=", 10) == 0)
        dst = &o->cancel_at, v = spec + 10;
    else if (strcmp(spec, "busy=1") == 0) {
        o->busy = true;
        return SF_OK;
    } else
        return SF_EUNSUPP;
    char *end;
    errno = 0;
    long n = strtol(v, &end, 10);
    if (errno || end == v || *end || n < 1)
        return sf_err_set(err, SF_EINVAL, "fault '%s': expected a line count above 0", spec);
    *dst = n;
    return SF_OK;
}

/* ---- the face for sim_netcli ---- */

static void
destroy(void *sim)
{
    struct octo_sim *o = sim;
    if (!o)
        return;
    if (o->tick)
        loop_timer_cancel(o->l, o->tick);
    sim_ws_hub_free(o->hub); /* its sockets came through the server: before it */
    sim_http_free(o->http);
    sim_netprinter_free(o->np);
    free(o);
}

static void *
create(struct loop *l, const struct sim_net_opts *opt, int index, struct sf_err *err)
{
    (void)index;
    struct octo_sim *o = mem_calloc(1, sizeof(*o));
    if (!o) {
        sf_err_set(err, SF_ENOMEM, "out of memory");
        return NULL;
    }
    o->l = l;
    o->api_key = opt->api_key;
    o->hub = sim_octoprint_push_hub(o);
    if (!o->hub) {
        sf_err_set(err, SF_ENOMEM, "out of memory");
        destroy(o);
        return NULL;
    }
    struct sim_netprinter_config nc;
    sim_netprinter_config_init(&nc);
    nc.speed = opt->speed;
    nc.log_path = opt->log_path;
    nc.uploads_dir = opt->uploads_dir;
    struct sim_http_config hc = { 0 };
    hc.port = opt->port;
    hc.routes = routes;
    hc.n_routes = sizeof(routes) / sizeof(routes[0]);
    hc.ud = o;
    hc.api_key = opt->api_key;
    hc.auth_status = 403;
    hc.auth_body = "{\"error\":\"You don't have the permission to access the requested "
                   "resource. It is either read-protected or not readable by the server.\"}";
    for (int i = 0; i < opt->n_faults; i++) {
        int rc = octo_fault(o, opt->faults[i], err);
        if (rc == SF_EUNSUPP)
            rc = sim_http_fault_parse(&hc.faults, opt->faults[i], err);
        if (rc == SF_EUNSUPP)
            rc = faults_parse(&nc.faults, opt->faults[i], err);
        if (rc < 0) {
            destroy(o);
            return NULL;
        }
    }
    o->np = sim_netprinter_new(l, &nc, err);
    if (!o->np) {
        destroy(o);
        return NULL;
    }
    hc.upload_dir = sim_netprinter_uploads(o->np);
    o->http = sim_http_new(l, &hc, err);
    if (!o->http) {
        destroy(o);
        return NULL;
    }
    snprintf(o->address, sizeof(o->address), "http://127.0.0.1:%d", sim_http_port(o->http));
    o->tick = loop_timer_add(l, 10, on_tick, o);
    return o;
}

static const char *
address(void *sim)
{
    return ((struct octo_sim *)sim)->address;
}

static void
stats(void *sim, char *out, size_t n)
{
    struct octo_sim *o = sim;
    struct sim_np_status st;
    sim_netprinter_status(o->np, &st);
    snprintf(out, n, "requests=%llu pushed=%llu uploads=%llu jobs=%llu state=%s lines=%llu/%llu",
             (unsigned long long)sim_http_served(o->http),
             (unsigned long long)sim_ws_hub_sent(o->hub), (unsigned long long)o->uploads,
             (unsigned long long)o->jobs, sim_np_state_name(st.state),
             (unsigned long long)st.lines_done, (unsigned long long)st.lines_total);
}

int
sim_octoprint_main(int argc, char **argv)
{
    struct sim_net_opts o;
    int rc =
        sim_net_parse(argc, argv, &o, "octoprint faults: error-at=LINES cancel-at=LINES busy=1\n");
    if (rc >= 0)
        return rc;
    static const struct sim_net_face face = {
        .create = create, .address = address, .stats = stats, .destroy = destroy
    };
    return sim_net_serve(&o, &face);
}
