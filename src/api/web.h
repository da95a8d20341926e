/*
 * web.h - the operator's dashboard on slimfarmd: its static files (HTML,
 * CSS, JS from src/api/web/, embedded in the binary at build time), the
 * browser's session, and the JSON and pictures only the dashboard needs.
 *
 *   GET /, /index.html, /app.js, ...   static files (no key: they hold no
 *                                      data); ETag, Cache-Control: no-cache
 *                                      (revalidated, 304), a strict CSP
 *   GET /api/whoami                    {"read_only": B, "csrf": T}; with
 *                                      the key in a header: logs in (sets
 *                                      the session cookie); by the cookie:
 *                                      the session's CSRF token again
 *   POST /api/logout                   no key: ends the session of the
 *                                      cookie (with its X-Csrf-Token) and
 *                                      clears the cookie
 *   GET /api/jobs/ID/preview.png?stage=before|after
 *                                      the part as uploaded / as it prints,
 *                                      risky faces red, as the farm gives
 *                                      it (farm/pictures.h)
 *   GET /api/jobs/ID/gcode             the job's G-code (text/plain)
 *   GET /api/jobs/ID/report            what the G-code's header says: time,
 *                                      filament and support grams, layers
 *
 * Sessions (session.h): server-side, with an idle and an absolute expiry,
 * a quota per key, ended by log out and by a reload that removes their key;
 * in memory only (a restarted daemon forgets them: the page asks for the
 * key again).  The cookie is HttpOnly, SameSite=Strict, Path=/, and named
 * sf_session_INSTANCE after this daemon's instance id, so a browser keeps
 * the cookies of two daemons on one host (ports share cookies) apart; a
 * token is random and known only to the daemon that made it.  The cookie
 * authorizes GETs, and changes with the session's CSRF token in
 * X-Csrf-Token (http.h), so the page never keeps the key.
 *
 * Thread: the loop thread; renders run on the pool, delivered on the loop.
 */
#ifndef SF_API_WEB_H
#define SF_API_WEB_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"
#include "../base/pool.h"
#include "../farm/pictures.h"
#include "../farm/store.h"
#include "api_read.h"
#include "http.h"
#include "route.h"

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
    struct api_read *reads; /* the job routes' reads (api_read.h; not owned) */
    struct pool *pool;      /* renders (not owned); NULL: previews answer 503 */
    void (*wake)(void *ud); /* a render finished: wake the streams waiting for it */
    void *ud;
    const char *instance;    /* this daemon's id (hex, the data dir's); NULL: a random one */
    int64_t session_idle_ms; /* <= 0: SESSION_IDLE_S */
    int64_t session_max_ms;  /* <= 0: SESSION_MAX_S */
};

struct web;

/* NULL with err set (SF_ENOMEM). */
struct web *web_new(const struct web_config *cfg, struct sf_err *err);
/* Renders in flight finish unseen (their results are dropped). */
void web_free(struct web *w);

/* GET/HEAD of path is one of the static files. */
bool web_is_public(const char *path);
/* path needs no key: a static file, or log out (http.c lets it in). */
bool web_needs_no_key(const char *path);

/* The API key a session token stands for, or NULL (http.h's session_key:
   csrf NULL for GET/HEAD, else it must be the session's). */
const char *web_session_key(struct web *w, const char *token, const char *csrf);
/* The session cookie's name, sf_session_INSTANCE (lives as long as w). */
const char *web_cookie_name(const struct web *w);
/* A reload: end the sessions of keys that are gone; returns how many. */
size_t web_keys_changed(struct web *w, const struct farmcfg_key *keys, size_t n_keys);

/* The routes above as rows of the route table; their handlers take the
   struct web as ctx.  *n their count. */
const struct route *web_routes(size_t *n);

#endif
