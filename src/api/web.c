/*
 * web.c - the dashboard's static files, sessions, pictures and G-code.
 *
 * Why apart from api.c: api.c maps the REST API, which scripts and the CLI
 * use; this file is what only a browser needs (files, a cookie, pictures),
 * so each can change without the other.
 *
 * Pictures: the farm makes them (pictures.h); a render is slow, so the
 * request waits as a suspended stream (http.c's SSE machinery) that the
 * render's end wakes.  Their ETag says what they show (file sha and
 * overhang angle), so a page reload costs a 304.
 *
 * Thread: the loop thread.
 */
#include "web.h"

#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/random.h>
#include <sys/stat.h>
#include <unistd.h>

#include "../base/clock.h"
#include "../base/mem.h"
#include "session.h"

/* The Content-Security-Policy of every static file: scripts and styles
   from this origin only, no inline script, nothing framed or embedded. */
#define WEB_CSP                                                                                    \
    "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; "              \
    "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"

struct web {
    struct web_config cfg;
    struct sessions *sessions; /* the browsers logged in */
    char cookie[64];           /* the session cookie's name: sf_session_INSTANCE */
    struct pictures *pictures; /* the jobs' pictures, from the farm */
};

/* A request waiting for (or sending) a picture. */
struct pstream {
    struct web *w;
    char key[PICTURES_KEY_MAX];
    unsigned char *png; /* our copy, once ready */
    size_t len, off;
};

/* ---- static files ---- */

static const struct web_asset *
asset_find(const char *path)
{
    if (strcmp(path, "/") == 0)
        path = "/index.html";
    size_t n;
    const struct web_asset *a = web_assets(&n);
    for (size_t i = 0; i < n; i++)
        if (strcmp(a[i].path, path) == 0)
            return &a[i];
    return NULL;
}

bool
web_is_public(const char *path)
{
    return asset_find(path) != NULL;
}

static bool
etag_matches(const struct http_req *req, const char *etag)
{
    const char *inm = http_req_header(req, "If-None-Match");
    return inm && (strstr(inm, etag) != NULL || strcmp(inm, "*") == 0);
}

static void
serve_asset(const struct web_asset *a, const struct http_req *req, struct http_resp *resp)
{
    resp->content_type = a->content_type;
    http_resp_header(resp, "ETag", "%s", a->etag);
    http_resp_header(resp, "Cache-Control", "no-cache");
    http_resp_header(resp, "Content-Security-Policy", "%s", WEB_CSP);
    http_resp_header(resp, "X-Content-Type-Options", "nosniff");
    http_resp_header(resp, "Referrer-Policy", "no-referrer");
    if (etag_matches(req, a->etag)) {
        resp->status = 304;
        return;
    }
    resp->body = a->data;
    resp->body_len = a->len;
}

/* ---- sessions ---- */

const char *
web_session_key(struct web *w, const char *token, const char *csrf)
{
    return sessions_key(w->sessions, token, csrf, clock_mono_ms());
}

const char *
web_cookie_name(const struct web *w)
{
    return w->cookie;
}

bool
web_needs_no_key(const char *path)
{
    return web_is_public(path) || strcmp(path, "/api/logout") == 0;
}

size_t
web_keys_changed(struct web *w, const struct farmcfg_key *keys, size_t n_keys)
{
    return sessions_keep_keys(w->sessions, keys, n_keys);
}

/* The value of cookie name in the request's Cookie header into out; false if none. */
static bool
cookie_get(const struct http_req *req, const char *name, char *out, size_t cap)
{
    const char *p = http_req_header(req, "Cookie");
    size_t n = strlen(name);
    while (p && *p) {
        p += strspn(p, " ;");
        size_t len = strcspn(p, ";");
        if (len > n && strncmp(p, name, n) == 0 && p[n] == '=') {
            size_t v = len - n - 1;
            if (v >= cap)
                return false;
            memcpy(out, p + n + 1, v);
            out[v] = '\0';
            return true;
        }
        p += len;
    }
    return false;
}

/* The request came with its key in a header (a log in), not by its cookie. */
static bool
has_key_header(const struct http_req *req)
{
    return http_req_header(req, "X-Api-Key") || http_req_header(req, "Authorization");
}

/*
 * GET /api/whoami.  With the key in a header: log in (a new session; the
 * browser's old one, if its cookie came along, ends).  By the cookie alone
 * (a new tab of a logged-in browser): the session it has.  Either way the
 * page learns the CSRF token its changes must carry.
 */
static void
whoami(struct web *w, const struct http_req *req, struct http_resp *resp)
{
    char token[SESSION_TOKEN_LEN + 1], csrf[SESSION_TOKEN_LEN + 1], old[SESSION_TOKEN_LEN + 2];
    int64_t now = clock_mono_ms();
    bool had = cookie_get(req, w->cookie, old, sizeof(old));
    const char *csrf_now =
        !has_key_header(req) && had ? sessions_csrf(w->sessions, old, now) : NULL;
    if (csrf_now) {
        snprintf(csrf, sizeof(csrf), "%s", csrf_now);
    } else {
        struct sf_err err;
        int rc = sessions_make(w->sessions, req->key, now, token, csrf, &err);
        if (rc) {
            http_fail(resp, rc, err.msg);
            return;
        }
        if (had)
            sessions_revoke(w->sessions, old);
        http_resp_header(resp, "Set-Cookie", "%s=%s; Path=/; HttpOnly; SameSite=Strict", w->cookie,
                         token);
    }
    http_resp_header(resp, "Cache-Control", "no-store");
    resp->json = json_pack("{sb ss}", "read_only", req->read_only, "csrf", csrf);
}

/* POST /api/logout (no key: the cookie and its CSRF token are the proof):
   the session ends here, and the cookie in the browser. */
static void
logout(struct web *w, const struct http_req *req, struct http_resp *resp)
{
    char token[SESSION_TOKEN_LEN + 2];
    const char *csrf = http_req_header(req, HTTP_CSRF_HEADER);
    bool ended = false;
    if (cookie_get(req, w->cookie, token, sizeof(token))) {
        int64_t now = clock_mono_ms();
        if (!csrf || !sessions_key(w->sessions, token, csrf, now)) {
            if (sessions_csrf(w->sessions, token, now)) {
                http_error(resp, 403, "log out needs the session's %s header", HTTP_CSRF_HEADER);
                return;
            }
        } else {
            ended = sessions_revoke(w->sessions, token);
        }
    }
    http_resp_header(resp, "Set-Cookie", "%s=; Path=/; HttpOnly; SameSite=Strict; Max-Age=0",
                     w->cookie);
    http_resp_header(resp, "Cache-Control", "no-store");
    resp->json = json_pack("{sb}", "ended", ended);
}

/* ---- pictures ---- */

static ssize_t
pstream_read(void *ud, char *buf, size_t max)
{
    struct pstream *s = ud;
    if (!s->png) {
        enum pictures_state st = pictures_take(s->w->pictures, s->key, &s->png, &s->len);
        if (st == PICTURES_PENDING)
            return 0; /* still rendering: suspended until a render ends */
        if (st != PICTURES_READY)
            return -1; /* failed (logged): the picture ends empty */
    }
    size_t n = s->len - s->off < max ? s->len - s->off : max;
    if (n == 0)
        return -1;
    memcpy(buf, s->png + s->off, n);
    s->off += n;
    return (ssize_t)n;
}

static void
pstream_free(void *ud)
{
    struct pstream *s = ud;
    free(s->png);
    free(s);
}

/* A picture the farm could not give now, as an error answer. */
static void
preview_refused(const struct job_row *j, enum pictures_state st, const struct sf_err *err,
                struct http_resp *resp)
{
    resp->content_type = NULL;
    if (st == PICTURES_FAILED) {
        http_error(resp, 422, "job %lld: no picture of its part: %s", (long long)j->id, err->msg);
    } else if (st == PICTURES_NONE) {
        http_error(resp, 503, "job %lld: no worker pool for pictures", (long long)j->id);
    } else {
        http_resp_header(resp, "Retry-After", "2");
        http_error(resp, 503, "every picture slot is rendering; try again");
    }
}

/* Job j's picture (after: of the part as optimized); inm: the request's If-None-Match or "". */
static void
preview(struct web *w, const struct job_row *j, bool after, const char *inm, struct http_resp *resp)
{
    const char *sha;
    double angle;
    char etag[112];
    pictures_what(j, after, &sha, &angle);
    snprintf(etag, sizeof(etag), "\"%.24s-%g\"", sha, angle);
    http_resp_header(resp, "ETag", "%s", etag);
    http_resp_header(resp, "Cache-Control", "private, no-cache");
    resp->content_type = "image/png";
    if (inm[0] && (strstr(inm, etag) != NULL || strcmp(inm, "*") == 0)) {
        resp->status = 304;
        return;
    }
    enum pictures_state st;
    unsigned char *png = NULL;
    size_t len = 0;
    struct sf_err err;
    int rc = pictures_get(w->pictures, j, after, &st, &png, &len, &err);
    if (rc) {
        resp->content_type = NULL;
        http_error(resp, 500, "%s", err.msg);
        return;
    }
    if (st == PICTURES_READY) {
        /* MHD may send it after the cache evicted it: a copy it frees */
        resp->body = png;
        resp->body_len = len;
        resp->body_free = free;
        return;
    }
    if (st != PICTURES_PENDING) {
        preview_refused(j, st, &err, resp);
        return;
    }
    struct pstream *s = mem_calloc(1, sizeof(*s));
    if (!s) {
        resp->content_type = NULL;
        http_error(resp, 500, "out of memory");
        return;
    }
    s->w = w;
    pictures_key(j, after, s->key);
    resp->stream = pstream_read;
    resp->stream_ud = s;
    resp->stream_free = pstream_free;
}

/* ---- G-code ---- */

/* Job j's G-code from store s as an open file (the reader's thread: the file may come
   whole from the database first). */
static void
gcode(struct store *s, const struct job_row *j, struct http_resp *resp)
{
    struct sf_err err;
    char path[1100];
    if (!j->gcode_sha[0]) {
        http_error(resp, 404, "job %lld has no G-code yet (%s)", (long long)j->id,
                   job_state_name(j->state));
        return;
    }
    if (store_file_path(s, j->gcode_sha, path, sizeof(path), &err)) {
        http_error(resp, 500, "%s", err.msg);
        return;
    }
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    struct stat st;
    if (fd < 0 || fstat(fd, &st) != 0) {
        if (fd >= 0)
            close(fd);
        http_error(resp, 500, "job %lld: cannot read its G-code", (long long)j->id);
        return;
    }
    resp->fd = fd;
    resp->fd_size = (uint64_t)st.st_size;
    resp->content_type = "text/plain; charset=utf-8";
    http_resp_header(resp, "ETag", "\"%.24s\"", j->gcode_sha);
    http_resp_header(resp, "Cache-Control", "private, no-cache");
}

/* The number after "; NAME = " in the header text, or -1. */
static double
head_num(const char *text, const char *name)
{
    char pat[80];
    snprintf(pat, sizeof(pat), "\n; %s = ", name);
    const char *p = strstr(text, pat);
    if (!p)
        return -1;
    char *end;
    double v = strtod(p + strlen(pat), &end);
    return end == p + strlen(pat) ? -1 : v;
}

/* The support model's numbers for a stage, once its picture was rendered
   (the render computes them); null before that. */
static json_t *
model_json(struct web *w, const struct job_row *j, bool after)
{
    double g, sec;
    if (!pictures_support(w->pictures, j, after, &g, &sec))
        return json_null();
    return json_pack("{sf sf}", "support_g", g, "support_s", sec);
}

/* The numbers of job j's G-code header from store s (the reader's thread), or null. */
static json_t *
report_gcode(struct store *s, const struct job_row *j)
{
    json_t *g = json_null();
    char path[1100], head[WEB_GCODE_HEAD_MAX + 1];
    struct sf_err err;
    if (j->gcode_sha[0] && store_file_path(s, j->gcode_sha, path, sizeof(path), &err) == SF_OK) {
        int fd = open(path, O_RDONLY | O_CLOEXEC);
        ssize_t n = fd >= 0 ? read(fd, head + 1, sizeof(head) - 2) : -1;
        if (fd >= 0)
            close(fd);
        if (n > 0) {
            head[0] = '\n';
            head[n + 1] = '\0';
            json_decref(g);
            g = json_pack("{sf sf sf sf sf}", "time_s",
                          head_num(head, "estimated printing time [s]"), "filament_g",
                          head_num(head, "filament used [g]"), "support_g",
                          head_num(head, "support material used [g]"), "layers",
                          head_num(head, "total layers"), "filament_mm",
                          head_num(head, "filament used [mm]"));
        }
    }
    return g;
}

/* On the loop: job j's report, with g (report_gcode's; taken). */
static void
report(struct web *w, const struct job_row *j, json_t *g, struct http_resp *resp)
{
    resp->json =
        json_pack("{sI ss sb so so so so so sb sf}", "job_id", (json_int_t)j->id, "method",
                  j->opts.method, "optimized", j->mesh_sha[0] != '\0', "gcode", g, "model_before",
                  model_json(w, j, false), "model_after", model_json(w, j, true), "mndr",
                  j->dev_measured ? json_real(j->mndr) : json_null(), "andr",
                  j->dev_measured ? json_real(j->andr) : json_null(), "shape_changed",
                  j->shape_changed, "deviation_mm", j->opts.deviation_mm);
}

/* ---- dispatch ---- */

static void
asset(void *ctx, const struct route_args *args, const struct http_req *req, struct http_resp *resp)
{
    (void)ctx, (void)args;
    serve_asset(asset_find(req->path), req, resp);
}

static void
whoami_route(void *ctx, const struct route_args *args, const struct http_req *req,
             struct http_resp *resp)
{
    (void)args;
    whoami(ctx, req, resp);
}

static void
logout_route(void *ctx, const struct route_args *args, const struct http_req *req,
             struct http_resp *resp)
{
    (void)args;
    logout(ctx, req, resp);
}

/* A GET /api/jobs/ID/preview.png, /gcode or /report on its way: the job (and the G-code's
   file) read on the API's reader, the picture and the report's models added on the loop. */
struct job_ask {
    struct web *w;
    int64_t id;
    char what;      /* 'g' gcode, 'r' report, 'p' preview */
    char stage[24]; /* preview's ?stage= ("" none) */
    bool has_stage;
    char inm[512];    /* its If-None-Match ("" none) */
    int rc;           /* the reader's: the job's read */
    struct job_row j; /* the job */
    json_t *g;        /* report's G-code numbers */
};

static void
job_ask_read(struct store *s, void *ud, struct http_resp *resp)
{
    struct job_ask *q = ud;
    struct sf_err err;
    if ((q->rc = store_job_get(s, q->id, &q->j, &err))) {
        http_fail(resp, q->rc, err.msg);
        return;
    }
    if (q->what == 'g')
        gcode(s, &q->j, resp);
    else if (q->what == 'r')
        q->g = report_gcode(s, &q->j);
}

static void
job_ask_finish(void *ud, struct http_resp *resp)
{
    struct job_ask *q = ud;
    if (q->rc || q->what == 'g')
        return;
    if (q->what == 'r') {
        report(q->w, &q->j, q->g, resp);
        q->g = NULL;
        return;
    }
    bool after = q->has_stage && strcmp(q->stage, "after") == 0;
    if (q->has_stage && !after && strcmp(q->stage, "before") != 0)
        http_error(resp, 400, "stage: '%.16s' is not 'before' or 'after'", q->stage);
    else
        preview(q->w, &q->j, after, q->inm, resp);
}

static void
job_ask_free(void *ud)
{
    struct job_ask *q = ud;
    json_decref(q->g);
    free(q);
}

static void
job_route(void *ctx, const struct route_args *args, const struct http_req *req,
          struct http_resp *resp)
{
    struct job_ask *q = mem_calloc(1, sizeof(*q));
    if (!q) {
        http_error(resp, 500, "out of memory");
        return;
    }
    q->w = ctx;
    q->id = args->id;
    const char *what = strrchr(req->path, '/') + 1;
    q->what = strcmp(what, "gcode") == 0 ? 'g' : strcmp(what, "report") == 0 ? 'r' : 'p';
    const char *stage = http_req_arg(req, "stage"), *inm = http_req_header(req, "If-None-Match");
    q->has_stage = stage != NULL;
    snprintf(q->stage, sizeof(q->stage), "%s", stage ? stage : "");
    snprintf(q->inm, sizeof(q->inm), "%s", inm ? inm : "");
    api_read_run(q->w->cfg.reads, resp, job_ask_read, job_ask_finish, q, job_ask_free);
}

#define GET_HEAD (ROUTE_GET | ROUTE_HEAD)

static const struct route rows[] = {
    /* methods, pattern, match, body, scope, handler, 405 message */
    { GET_HEAD, NULL, web_is_public, HTTP_BODY_NONE, ROUTE_PUBLIC, asset, "use GET" },
    { GET_HEAD, "/api/whoami", NULL, HTTP_BODY_NONE, ROUTE_READ, whoami_route, "use GET" },
    { ROUTE_POST, "/api/logout", NULL, HTTP_BODY_NONE, ROUTE_PUBLIC, logout_route, "use POST" },
    { GET_HEAD, "/api/jobs/{id}/preview.png", NULL, HTTP_BODY_NONE, ROUTE_READ, job_route,
      "use GET" },
    { GET_HEAD, "/api/jobs/{id}/gcode", NULL, HTTP_BODY_NONE, ROUTE_READ, job_route, "use GET" },
    { GET_HEAD, "/api/jobs/{id}/report", NULL, HTTP_BODY_NONE, ROUTE_READ, job_route, "use GET" },
};

const struct route *
web_routes(size_t *n)
{
    *n = sizeof(rows) / sizeof(rows[0]);
    return rows;
}

struct web *
web_new(const struct web_config *cfg, struct sf_err *err)
{
    struct web *w = mem_calloc(1, sizeof(*w));
    if (!w) {
        sf_err_set(err, SF_ENOMEM, "web: out of memory");
        return NULL;
    }
    w->cfg = *cfg;
    unsigned char rnd[8];
    char id[2 * sizeof(rnd) + 1] = "";
    if (!cfg->instance && getrandom(rnd, sizeof(rnd), 0) == sizeof(rnd)) /* this process's own */
        for (size_t i = 0; i < sizeof(rnd); i++)
            snprintf(id + 2 * i, 3, "%02x", rnd[i]);
    snprintf(w->cookie, sizeof(w->cookie), "%s_%.40s", HTTP_SESSION_COOKIE,
             cfg->instance ? cfg->instance : id);
    if (!(w->sessions = sessions_new(cfg->session_idle_ms, cfg->session_max_ms, err))) {
        free(w);
        return NULL;
    }
    struct pictures_config pc = {
        .store = cfg->store, .pool = cfg->pool, .ready = cfg->wake, .ud = cfg->ud
    };
    if (!(w->pictures = pictures_new(&pc, err))) {
        sessions_free(w->sessions);
        free(w);
        return NULL;
    }
    return w;
}

void
web_free(struct web *w)
{
    if (!w)
        return;
    pictures_free(w->pictures); /* renders in flight finish unseen */
    sessions_free(w->sessions);
    free(w);
}
