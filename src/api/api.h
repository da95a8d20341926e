/*
 * api.h - the REST API of slimfarmd (routes over http.h, data from the
 * store, printers through farm.h, what operators ask of jobs and printers
 * through jobctl.h).
 *
 *   GET    /api/jobs                      a page of jobs (api_page.h: limit, cursor,
 *                                         state, printer, since, until, order)
 *   POST   /api/jobs                      multipart: "file" (the part) and
 *                                         optional "options" (JSON) -> 201
 *   GET    /api/jobs/ID                   one job with its print history
 *   PATCH  /api/jobs/ID                   {"priority": N}
 *   POST   /api/jobs/ID/cancel            cancel (through the printer if printing)
 *   POST   /api/jobs/ID/restart           interrupted job: print its copy again from the start
 *   POST   /api/jobs/ID/resume            interrupted job: continue on its printer from the
 *                                         last acknowledged line, or {"line": N}
 *   GET    /api/printers                  list printers with state, temperatures
 *   GET    /api/printers/NAME             one printer
 *   POST   /api/printers/NAME/ACTION      pause | resume | cancel | cleared
 *   POST /api/printers, PUT/PATCH/DELETE /api/printers/NAME, .../disable, .../enable:
 *                                         printers managed at run time (api_printers.h)
 *   GET    /api/events                    Server-Sent Events: the event log (id: N,
 *                                         event: KIND; Last-Event-ID resumes) and
 *                                         every API_TICK_MS a "progress" snapshot
 *   GET    /metrics, OctoPrint and Moonraker upload routes: api_compat.h
 *
 * G-code goes to POST /api/files/local (api_compat.h: printed as is);
 * POST /api/jobs takes parts.
 *
 * and the dashboard's (web.h): GET / and its static files, /api/whoami
 * (and the session cookie), /api/jobs/ID/preview.png, /gcode, /report.
 *
 * Errors are {"error": "message"}: 400 bad input (a multipart upload
 * anywhere but POST /api/jobs, a body cut before its closing boundary, an
 * empty file), 401/403 keys (a read-only key may send no body), 404
 * unknown, 405 wrong method (Allow says which would do), 409 not legal in
 * the current state or busy now, 413 too large, 501 not possible on that
 * kind of printer, 503 the printer is offline, 500 server trouble: the
 * status of a failure code is http_status_of()'s, for every route.  Text a
 * client sent is echoed as valid UTF-8.
 *
 * Reads of the store a client asks for (GET /api/jobs, /api/jobs/ID and
 * /metrics) run on a reader thread (api_read.h), never on the loop that
 * feeds the printers; writes, and the event streams' small indexed reads,
 * stay on the loop.
 *
 * Thread: the loop thread (the one driving api_http()).
 */
#ifndef SF_API_API_H
#define SF_API_API_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"
#include "../base/pool.h"
#include "../farm/farm.h"
#include "../farm/farmcfg.h"
#include "../farm/job.h"
#include "../farm/store.h"
#include "http.h"

#define API_BODY_MAX (64 << 10) /* JSON bodies: a priority or options object */

struct api_config {
    struct store *store;            /* jobs and events (not owned) */
    struct farm *farm;              /* printers and resumes (not owned); NULL: none */
    const char *host;               /* listen address */
    int port;                       /* 0: any free port */
    const struct farmcfg_key *keys; /* API keys (copied) */
    size_t n_keys;
    size_t upload_max;           /* largest upload, bytes */
    unsigned header_timeout_ms;  /* 0: HTTP_HEADER_TIMEOUT_MS (tests shorten it) */
    struct pool *pool;           /* renders the dashboard's pictures (not owned); NULL: none */
    struct loop *loop;           /* the loop thread's, for the store reads off it (api_read.h);
                                    NULL: reads run on the caller's thread */
    void (*on_change)(void *ud); /* a job was added or changed (run the scheduler) */
    void *ud;                    /* its argument */
    const char *instance;        /* this daemon's id, names the session cookie; NULL: random */
    int64_t session_idle_ms;     /* dashboard sessions (session.h); <= 0: the defaults */
    int64_t session_max_ms;
};

struct api;

/* Listen; NULL with err set. */
struct api *api_new(const struct api_config *cfg, struct sf_err *err);
void api_free(struct api *a);

/*
 * SIGHUP: apply what the API reads from the farm config.  API keys are
 * replaced (event streams opened with a key that is gone end), upload_max
 * applies to requests that start after this; listen_host/port need a
 * restart (logged as a warning when they differ from old, which may be
 * NULL).  SF_ENOMEM leaves everything as it was.
 */
int api_reload(struct api *a, const struct farmcfg *old, const struct farmcfg *next,
               struct sf_err *err);

/* The server, to drive (http_fd / http_run). */
struct http *api_http(struct api *a);

/* The event log grew: wake the event streams. */
void api_notify(struct api *a);

/*
 * Call every API_TICK_MS: each event stream then sends a "progress" event
 * (printers with a job: name, job_id, state, progress) or a keepalive.
 */
#define API_TICK_MS 5000
void api_tick(struct api *a);

#endif
