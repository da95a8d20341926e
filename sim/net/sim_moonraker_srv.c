/*
 * sim_moonraker_srv.c - the server side of the Moonraker simulator
 * (sim_moonraker_int.h): what clients read beside the printer objects.
 *
 * Follows Arksine/moonraker v0.10.0-31-gd5ee171 (docs/external_api/
 * server.md, file_manager.md, printer.md, integrations.md; read with
 * components/file_manager, klippy_connection.py, application.py and
 * octoprint_compat.py):
 *   GET /server/files/list    [{path, modified, size, permissions}] of a root
 *                             (gcodes: the uploads; config: empty here; any
 *                             other root 400)
 *   GET /server/files/roots   [{name, path, permissions}] (config, logs, gcodes)
 *   GET /server/temperature_store  {extruder, heater_bed: {temperatures,
 *                             targets, powers}}, a sample a second, 1200 kept
 *   GET /server/config        {config, orig, files} of a minimal moonraker.conf
 *   POST /printer/objects/subscribe  over HTTP Moonraker ties a subscription
 *                             to the websocket named by connection_id; with no
 *                             such websocket (this simulator has none) it
 *                             answers 400 "No connection associated with
 *                             subscription request", as here
 *   [octoprint_compat]: GET /api/version, GET /api/server, POST /api/login,
 *                             replies not wrapped in "result"
 *
 * Thread: the loop thread.
 */
#include "sim_moonraker_int.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/base/mem.h"

#define SAMPLE_MS 1000 /* Moonraker samples temperatures once a second */
#define FILES_MAX 1024 /* files a list shows */

void
sim_moonraker_temps_sample(struct sim_moonraker *s, const struct sim_np_status *st)
{
    struct temp_store *t = &s->temps;
    int64_t now = loop_now_ms(s->b.l);
    if (now < t->next_ms)
        return;
    t->next_ms = now + SAMPLE_MS;
    int i = (t->head + t->n) % TEMP_STORE_MAX;
    if (t->n == TEMP_STORE_MAX)
        t->head = (t->head + 1) % TEMP_STORE_MAX;
    else
        t->n++;
    t->temp[0][i] = (float)st->nozzle_c;
    t->target[0][i] = (float)st->nozzle_target_c;
    t->power[0][i] = st->nozzle_target_c > 0 ? 0.4f : 0.0f;
    t->temp[1][i] = (float)st->bed_c;
    t->target[1][i] = (float)st->bed_target_c;
    t->power[1][i] = st->bed_target_c > 0 ? 0.3f : 0.0f;
}

/* One sensor's history, rounded as Moonraker stores it (2 places). */
static json_t *
sensor(const struct temp_store *t, int k)
{
    json_t *temps = json_array(), *targets = json_array(), *powers = json_array();
    for (int n = 0; n < t->n; n++) {
        int i = (t->head + n) % TEMP_STORE_MAX;
        json_array_append_new(temps, json_real((double)(int)(t->temp[k][i] * 100.0f) / 100.0));
        json_array_append_new(targets, json_real(t->target[k][i]));
        json_array_append_new(powers, json_real(t->power[k][i]));
    }
    return json_pack("{s:o,s:o,s:o}", "temperatures", temps, "targets", targets, "powers", powers);
}

void
sim_moonraker_on_temperature_store(struct sim_http_req *r, void *ud)
{
    struct sim_moonraker *s = ud;
    sim_moonraker_result(r, json_pack("{s:o,s:o}", "extruder", sensor(&s->temps, 0), "heater_bed",
                                      sensor(&s->temps, 1)));
}

void
sim_moonraker_on_subscribe(struct sim_http_req *r, void *ud)
{
    if (sim_moonraker_klippy_up(ud, r))
        sim_moonraker_error(r, 400, "No connection associated with subscription request");
}

void
sim_moonraker_on_files_list(struct sim_http_req *r, void *ud)
{
    struct sim_moonraker *s = ud;
    const char *root = sim_http_query(r, "root");
    if (!root || !root[0])
        root = "gcodes";
    if (strcmp(root, "config") == 0) {
        sim_moonraker_result(r, json_array());
        return;
    }
    if (strcmp(root, "gcodes") != 0) {
        char msg[256];
        snprintf(msg, sizeof(msg), "Failed to build file list, invalid path: %.64s: None", root);
        sim_moonraker_error(r, 400, msg);
        return;
    }
    struct sim_np_file *list = mem_calloc(FILES_MAX, sizeof(*list));
    if (!list) {
        sim_moonraker_error(r, 500, "out of memory");
        return;
    }
    int n = sim_netprinter_files(s->b.np, list, FILES_MAX);
    json_t *out = json_array();
    for (int i = 0; i < n; i++)
        json_array_append_new(out, json_pack("{s:s,s:f,s:I,s:s}", "path", list[i].name, "modified",
                                             (double)list[i].mtime_s, "size",
                                             (json_int_t)list[i].size, "permissions", "rw"));
    free(list);
    sim_moonraker_result(r, out);
}

void
sim_moonraker_on_roots(struct sim_http_req *r, void *ud)
{
    struct sim_moonraker *s = ud;
    const char *gcodes = sim_netprinter_uploads(s->b.np);
    sim_moonraker_result(r, json_pack("[{s:s,s:s,s:s},{s:s,s:s,s:s},{s:s,s:s,s:s}]", "name",
                                      "config", "path", "/home/pi/printer_data/config",
                                      "permissions", "rw", "name", "logs", "path",
                                      "/home/pi/printer_data/logs", "permissions", "r", "name",
                                      "gcodes", "path", gcodes, "permissions", "rw"));
}

void
sim_moonraker_on_config(struct sim_http_req *r, void *ud)
{
    (void)ud;
    json_t *config = json_pack(
        "{s:{s:s,s:i,s:i,s:s,s:i},s:{s:b,s:b},s:{s:i,s:i},s:{},s:{},s:{s:b,s:b,s:b,s:b}}", "server",
        "host", "0.0.0.0", "port", 7125, "ssl_port", 7130, "klippy_uds_address", "/tmp/klippy_uds",
        "max_upload_size", 1024, "file_manager", "queue_gcode_uploads", false,
        "enable_object_processing", false, "data_store", "temperature_store_size", TEMP_STORE_MAX,
        "gcode_store_size", 1000, "authorization", "history", "octoprint_compat", "enable_ufp",
        true, "flip_h", false, "flip_v", false, "webcam_enabled", false);
    json_t *orig = json_pack("{s:{},s:{},s:{},s:{},s:{}}", "DEFAULT", "server", "authorization",
                             "history", "octoprint_compat");
    json_t *files = json_pack("[{s:s,s:[s,s,s,s]}]", "filename", "moonraker.conf", "sections",
                              "server", "authorization", "history", "octoprint_compat");
    sim_moonraker_result(
        r, json_pack("{s:o,s:o,s:o}", "config", config, "orig", orig, "files", files));
}

/* ---- [octoprint_compat]: OctoPrint's shapes, not wrapped in "result" ---- */

void
sim_moonraker_on_octo_version(struct sim_http_req *r, void *ud)
{
    (void)ud;
    sim_http_reply_json(r, 200,
                        json_pack("{s:s,s:s,s:s}", "server", "1.5.0", "api", "0.1", "text",
                                  "OctoPrint (Moonraker v0.10.0-slimfarm-sim)"));
}

void
sim_moonraker_on_octo_server(struct sim_http_req *r, void *ud)
{
    struct sim_moonraker *s = ud;
    sim_http_reply_json(r, 200,
                        json_pack("{s:s,s:o}", "server", "1.5.0", "safemode",
                                  s->klippy == K_READY ? json_null() : json_string("settings")));
}

void
sim_moonraker_on_octo_login(struct sim_http_req *r, void *ud)
{
    (void)ud;
    sim_http_reply_json(r, 200,
                        json_pack("{s:b,s:s,s:s,s:b,s:b,s:b,s:n,s:[],s:[s,s]}",
                                  "_is_external_client", false, "_login_mechanism", "apikey",
                                  "name", "_api", "active", true, "user", true, "admin", true,
                                  "apikey", "permissions", "groups", "admins", "users"));
}
