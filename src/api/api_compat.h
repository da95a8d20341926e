/*
 * api_compat.h - what slicers call to send a job: enough of OctoPrint's
 * REST API (PrusaSlicer's and OrcaSlicer's "OctoPrint" host type, Cura's
 * OctoPrint plugin) and of Moonraker's (its upload, server info and print
 * start) for their uploads to land in the farm queue; and GET /metrics
 * (metrics.h).
 *
 *   GET  /api/version            {"api": "0.1", "server": ..., "text": "OctoPrint ... (slimfarm)"}
 *   GET  /api/server             {"version": ..., "safemode": null}
 *   GET  /api/settings           no SD card, no webcam, no G-code analysis to wait for
 *   GET  /api/printerprofiles    one profile, the farm
 *   GET  /api/connection         the farm as one operational printer
 *   /api/login, /api/currentuser, GET /api/files[/local], /api/printer,
 *   /api/job: the farm as one OctoPrint printer (api_octoprint.h)
 *   GET  /sockjs/info, /sockjs/websocket, /sockjs/SERVER/SESSION/websocket:
 *                                its push socket (api_octopush.h)
 *   POST /api/files/local        multipart file (+ path, select, print, userdata):
 *                                201, Location: .../api/files/local/job-ID/NAME
 *   POST /api/files/local/job-ID/NAME   {"command": "select"[, "print": true]} -> 204
 *   GET  /server/info, /server/files/roots, /printer/info   Moonraker's connection test
 *   POST /server/files/upload    multipart file (+ root=gcodes, path, print, checksum):
 *                                201 {"result": {"item", "print_started", "print_queued",
 *                                "action"}}
 *   POST /printer/print/start    ?filename=job-ID/NAME or {"filename": ...} -> {"result": "ok"}
 *   GET  /metrics                Prometheus text format 0.0.4
 *
 * Every upload becomes a farm job whatever select/print say: G-code runs
 * as is on a printer that can take it (checked by farm_gcode_check off the
 * loop thread while the request waits, http_defer), a part (.stl,
 * .obj, .3mf) goes through the pipeline with the default options.  The
 * farm is a queue: a busy farm queues, never answers 409, and print=false
 * queues too (effectivePrint and print_queued say so).  A refused upload
 * (no file part, a bad G-code line, no printer for it, too large, a
 * read-only key) leaves neither a job nor a stored file.
 *
 * Thread: the loop thread.
 */
#ifndef SF_API_API_COMPAT_H
#define SF_API_API_COMPAT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../farm/farm.h"
#include "../farm/store.h"
#include "http.h"
#include "route.h"

#define API_COMPAT_OCTOPRINT "1.10.0" /* the OctoPrint version reported */

/* What the compatible routes use of the API (api.c owns it). */
struct api_read;
struct api_octopush;

struct api_compat_env {
    struct store *store;       /* jobs */
    struct farm *farm;         /* printers; NULL: none (G-code is then refused) */
    struct api_read *reads;    /* where /metrics reads the store (api_read.h) */
    struct api_octopush *push; /* the push sockets and login sessions (api_octopush.h) */
    /* The temporary file of an upload (http.h sink context), to check it. */
    const char *(*upload_path)(void *upload);
    /* Store the upload at its content address (once). */
    int (*upload_commit)(void *upload, char sha[STORE_SHA_HEX], struct sf_err *err);
    void (*changed)(void *ud); /* a job was added */
    void *ud;
};

/* The routes above as rows of the route table; their handlers take the
   struct api_compat_env as ctx.  *n their count. */
const struct route *api_compat_routes(size_t *n);

/* The scheme-and-host prefix of an absolute URL from req's Host header, or
   "" when it holds anything but a host name, address and port. */
void api_compat_base_url(const struct http_req *req, char *out, size_t cap);
/* name percent-encoded for a URL path segment (RFC 3986 unreserved kept). */
void api_compat_url_escape(const char *name, char *out, size_t cap);

/* True for a G-code file name (.gcode, .gco, .g). */
bool api_compat_is_gcode(const char *name);

#endif
