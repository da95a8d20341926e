/*
 * api_octoprint.h - what OctoPrint apps and OctoPrint-based farm managers
 * read to show slimfarmd online, beside the slicer uploads of
 * api_compat.h: the farm as one OctoPrint printer.
 *
 *   POST /api/login {"passive": true} (or ?passive=true with an empty body)
 *        the user of the request's key: name = the key's label
 *        (route_key_label, never the key), role admin (read-write key);
 *        a read-only key cannot POST (http.h: 403), so its clients read
 *        GET /api/currentuser only.  "session" is a new login session of
 *        the key (api_octopush.h): what the push socket's auth message
 *        must carry.
 *        {"user", "pass"}: 403 (no users here); neither: 400.
 *   GET  /api/currentuser   {"name", "permissions", "groups"} from the key's rights
 *   GET  /api/files, /api/files/local   the newest API_OCTOPRINT_FILES jobs,
 *        newest first, as machinecode files named job-ID/NAME (the path an
 *        upload's Location gives), read off the loop (api_read.h)
 *   GET  /api/printer       (?printer=NAME: that farm printer alone; 404 if
 *        there is none of that name) the farm as one printer: Printing if a printer
 *        prints, else Paused if one is paused, Offline when every printer is
 *        offline (or there are none), Error when all are in error or offline
 *        with one in error, else Operational; no temperatures ({}: a farm
 *        has no one temperature)
 *   GET  /api/job           the same state; progress.completion the mean of
 *        the printing (and paused) jobs' progress, in percent; the file and
 *        estimatedPrintTime of the job when exactly one prints, else null
 *   POST /api/job {"command": "cancel"}   cancels the job that prints when
 *        exactly one does (204); with none or several 409 naming them
 *        (cancel those with POST /api/jobs/ID/cancel); other commands 409
 *
 * Thread: the loop thread.
 */
#ifndef SF_API_API_OCTOPRINT_H
#define SF_API_API_OCTOPRINT_H

#include <jansson.h>
#include <stdbool.h>

#include "../farm/farm.h"
#include "../farm/store.h"
#include "http.h"
#include "route.h"

#define API_OCTOPRINT_FILES 100 /* jobs in GET /api/files, newest first */

/* The farm (or one printer of it) as one OctoPrint printer. */
struct api_octoprint_summary {
    const char *text; /* OctoPrint's state text */
    size_t n, printing, paused, offline, error;
    double progress; /* mean of the printing and paused printers', 0..1 */
    int64_t left_s;  /* the longest known time left; -1 if none */
    int64_t job;     /* the one job printing or paused, 0 if none or several */
};

/* Summarize farm f (NULL: no printers), or its printer named printer (NULL
   or "": all); false when printer names none. */
bool api_octoprint_summarize(struct farm *f, const char *printer, struct api_octoprint_summary *s);
/* {"text", "flags"} of OctoPrint's state (new reference). */
json_t *api_octoprint_state_json(const struct api_octoprint_summary *s);
/* GET /api/job's {"job", "progress", "state"} with s's one job j (NULL: none, or not read; the
   caller reads it off the loop, api_read.h) (new reference). */
json_t *api_octoprint_job_json(const struct job_row *j, const struct api_octoprint_summary *s);

/* Route handlers; ctx is the struct api_compat_env (api_compat.h). */
void api_octoprint_login(void *ctx, const struct route_args *args, const struct http_req *req,
                         struct http_resp *resp);
void api_octoprint_user(void *ctx, const struct route_args *args, const struct http_req *req,
                        struct http_resp *resp);
void api_octoprint_files(void *ctx, const struct route_args *args, const struct http_req *req,
                         struct http_resp *resp);
/* GET /api/printer and GET /api/job (by req->path). */
void api_octoprint_state(void *ctx, const struct route_args *args, const struct http_req *req,
                         struct http_resp *resp);
void api_octoprint_job_command(void *ctx, const struct route_args *args, const struct http_req *req,
                               struct http_resp *resp);

#endif
