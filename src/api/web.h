/*
 * web.h - the operator's dashboard on slimfarmd: its static files (HTML,
 * CSS, JS from src/api/web/, embedded in the binary at build time), the
 * browser's session, and the JSON and pictures only the dashboard needs.
 *
 *   GET /, /index.html, /app.js, ...   static files (no key: they hold no
 *                                      data); ETag, Cache-Control: no-cache
 *                                      (revalidated, 304), a strict CSP
 *   GET /api/whoami                    {"read_only": B}; sets the session
 *                                      cookie (HttpOnly, SameSite=Strict)
 *                                      that stands for the request's key on
 *                                      later GETs (EventSource, <img>)
 *   GET /api/jobs/ID/preview.png?stage=before|after
 *                                      the part as uploaded / as it prints,
 *                                      risky faces red, as the farm gives
 *                                      it (farm/pictures.h)
 *   GET /api/jobs/ID/gcode             the job's G-code (text/plain)
 *   GET /api/jobs/ID/report            what the G-code's header says: time,
 *                                      filament and support grams, layers
 *
 * Sessions: WEB_SESSIONS_MAX random tokens, each mapped to the API key it
 * was made with, the oldest dropped first; they live in memory only (a
 * restarted daemon forgets them and the page logs in again with the key
 * it keeps in sessionStorage).  A token for a key removed on reload
 * authorizes nothing (http.c checks the key it maps to).
 *
 * Thread: the loop thread; renders run on the pool, delivered on the loop.
 */
#ifndef SF_API_WEB_H
#define SF_API_WEB_H

#include <stdbool.h>
#include <stddef.h>

#include "../base/err.h"
#include "../base/pool.h"
#include "../farm/pictures.h"
#include "../farm/store.h"
#include "http.h"
#include "route.h"

#define WEB_SESSIONS_MAX   64   /* browser sessions: a farm has few operators */
#define WEB_GCODE_HEAD_MAX 4096 /* bytes of G-code header read for /report */

/* One embedded static file (build/gen/web_assets.c, from src/api/web/). */
struct web_asset {
    const char *path;         /* "/app.js" */
    const char *content_type; /* "text/javascript; charset=utf-8" */
    const char *etag;         /* "\"sha256 prefix\"" */
    const unsigned char *data;
    size_t len;
};

/* The embedded files; *n their count. */
const struct web_asset *web_assets(size_t *n);

struct web_config {
    struct store *store;    /* jobs and files (not owned) */
    struct pool *pool;      /* renders (not owned); NULL: previews answer 503 */
    void (*wake)(void *ud); /* a render finished: wake the streams waiting for it */
    void *ud;
};

struct web;

/* NULL with err set (SF_ENOMEM). */
struct web *web_new(const struct web_config *cfg, struct sf_err *err);
/* Renders in flight finish unseen (their results are dropped). */
void web_free(struct web *w);

/* GET/HEAD of path is one of the static files (http.c lets it in without a key). */
bool web_is_public(const char *path);

/* The API key a session token stands for, or NULL. */
const char *web_session_key(struct web *w, const char *token);

/* The routes above as rows of the route table; their handlers take the
   struct web as ctx.  *n their count. */
const struct route *web_routes(size_t *n);

#endif
