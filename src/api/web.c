/*
 * web.c - the dashboard's static files, sessions, pictures and G-code.
 *
 * Why apart from api.c: api.c maps the REST API, which scripts and the CLI
 * use; this file is what only a browser needs (files, a cookie, pictures),
 * so each can change without the other.
 *
 * Pictures: a render is slow (load, ray grid, cairo: a second or more), so
 * it runs on the worker pool and the request waits as a suspended stream
 * (http.c's SSE machinery) that the render's done() wakes.  Rendered PNGs
 * are kept by content (file sha and overhang angle) in a small LRU, and
 * their ETag says the same, so a page reload costs a 304.  A task owns
 * its own data; web_free cuts its link to us, and done() of a task whose
 * web is gone only frees it.
 *
 * Thread: the loop thread; render_work() on a pool worker.
 */
#include "web.h"

#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/random.h>
#include <sys/stat.h>
#include <unistd.h>

#include "../../slicer/preview.h"
#include "../base/buf.h"
#include "../base/log.h"
#include "../base/mem.h"
#include "../geom/supmodel.h"
#include "../mesh/mesh.h"

/* The Content-Security-Policy of every static file: scripts and styles
   from this origin only, no inline script, nothing framed or embedded. */
#define WEB_CSP                                                                                    \
    "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; "              \
    "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"

enum render_state { R_FREE, R_PENDING, R_READY, R_FAILED };

/* One picture, cached by what it shows. */
struct render {
    enum render_state state;
    char key[96];       /* "SHA@ANGLE" */
    unsigned char *png; /* R_READY */
    size_t len;
    uint64_t used;            /* LRU stamp */
    char why[SF_ERR_MSG_MAX]; /* R_FAILED */
    double support_g;         /* R_READY: the support model's grams for it, -1 if it failed */
    double support_s;         /* and seconds */
};

/* A render on the pool: its own copies of everything. */
struct task {
    struct web *w; /* NULL once web_free ran */
    char key[96];
    char path[1100]; /* the stored part */
    double angle_deg;
    unsigned char *png;
    size_t len;
    double support_g, support_s; /* supmodel_of_mesh, PrusaSlicer's rules; -1 if it failed */
    struct sf_err err;
    struct task *next; /* in w->tasks */
};

struct session {
    char token[33];                /* 32 hex digits; "" if unused */
    char key[FARMCFG_KEY_MAX + 1]; /* the API key it stands for */
    uint64_t made;                 /* order of making: the oldest goes first */
};

struct web {
    struct web_config cfg;
    struct session sessions[WEB_SESSIONS_MAX];
    uint64_t n_made;
    struct render renders[WEB_PREVIEWS_MAX];
    uint64_t stamp;
    struct task *tasks;
};

/* A request waiting for (or sending) a picture. */
struct pstream {
    struct web *w;
    char key[96];
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
web_session_key(struct web *w, const char *token)
{
    if (strlen(token) != 32)
        return NULL;
    for (size_t i = 0; i < WEB_SESSIONS_MAX; i++)
        if (w->sessions[i].token[0] && strcmp(w->sessions[i].token, token) == 0)
            return w->sessions[i].key;
    return NULL;
}

/* A new session for key, in the free or the oldest slot; SF_EIO if the
   kernel has no random bytes for its token. */
static int
session_new(struct web *w, const char *key, char token[33])
{
    unsigned char rnd[16];
    if (getrandom(rnd, sizeof(rnd), 0) != (ssize_t)sizeof(rnd))
        return SF_EIO;
    struct session *s = &w->sessions[0];
    for (size_t i = 0; i < WEB_SESSIONS_MAX; i++) {
        if (!w->sessions[i].token[0]) {
            s = &w->sessions[i];
            break;
        }
        if (w->sessions[i].made < s->made)
            s = &w->sessions[i];
    }
    for (size_t i = 0; i < sizeof(rnd); i++)
        snprintf(s->token + 2 * i, 3, "%02x", rnd[i]);
    snprintf(s->key, sizeof(s->key), "%s", key);
    s->made = ++w->n_made;
    memcpy(token, s->token, 33);
    return SF_OK;
}

static void
whoami(struct web *w, const struct http_req *req, struct http_resp *resp)
{
    char token[33];
    if (session_new(w, req->key, token)) {
        http_error(resp, 500, "no random bytes for a session token");
        return;
    }
    http_resp_header(resp, "Set-Cookie", "%s=%s; Path=/; HttpOnly; SameSite=Strict",
                     HTTP_SESSION_COOKIE, token);
    http_resp_header(resp, "Cache-Control", "no-store");
    resp->json = json_pack("{sb}", "read_only", req->read_only);
}

/* ---- pictures ---- */

static struct render *
render_find(struct web *w, const char *key)
{
    for (size_t i = 0; i < WEB_PREVIEWS_MAX; i++)
        if (w->renders[i].state != R_FREE && strcmp(w->renders[i].key, key) == 0)
            return &w->renders[i];
    return NULL;
}

/* A slot for a new render: a free one, else the least recently used
   finished one; NULL when every slot is rendering. */
static struct render *
render_slot(struct web *w)
{
    struct render *best = NULL;
    for (size_t i = 0; i < WEB_PREVIEWS_MAX; i++) {
        struct render *r = &w->renders[i];
        if (r->state == R_FREE)
            return r;
        if (r->state != R_PENDING && (!best || r->used < best->used))
            best = r;
    }
    if (best) {
        free(best->png);
        memset(best, 0, sizeof(*best));
    }
    return best;
}

static int
render_work(void *ud, const atomic_bool *cancel)
{
    struct task *t = ud;
    struct mesh m;
    mesh_init(&m);
    char png[64] = "";
    int rc = mesh_load(t->path, &m, NULL, &t->err);
    if (rc == SF_OK && atomic_load(cancel))
        rc = sf_err_set(&t->err, SF_ECANCELED, "cancelled");
    if (rc == SF_OK) {
        const char *dir = getenv("TMPDIR");
        snprintf(png, sizeof(png), "%.40s/sfpreview.XXXXXX", dir && *dir ? dir : "/tmp");
        int fd = mkstemp(png);
        if (fd < 0) {
            rc = sf_err_sys(&t->err, "preview: temporary file in %s", png);
            png[0] = '\0';
        } else {
            close(fd);
        }
    }
    if (rc == SF_OK) {
        struct preview_opts po;
        preview_opts_default(&po);
        po.width_px = WEB_PREVIEW_W;
        po.height_px = WEB_PREVIEW_H;
        po.angle_deg = t->angle_deg;
        rc = preview_part(&m, &po, png, &t->err);
    }
    if (rc == SF_OK) {
        struct buf b;
        buf_init(&b, 64 << 20);
        rc = buf_read_file(&b, png, &t->err);
        if (rc == SF_OK)
            t->png = (unsigned char *)buf_take(&b, &t->len);
        buf_release(&b);
    }
    if (png[0])
        unlink(png);
    /* what this part needs in support, as it stands on the bed (+z): the
       same model orientation and slimming rank by (supmodel.h) */
    t->support_g = t->support_s = -1;
    struct supmodel_params sp;
    struct supmodel_result sr;
    struct sf_err serr;
    supmodel_params_steer(&sp, t->angle_deg);
    if (rc == SF_OK && !atomic_load(cancel) &&
        supmodel_of_mesh(&m, (struct vec3){ 0, 0, 1 }, &sp, &sr, &serr) == SF_OK) {
        t->support_g = sr.grams;
        t->support_s = sr.time_s;
    }
    mesh_release(&m);
    return rc;
}

static void
render_done(struct loop *l, void *ud, int rc)
{
    (void)l;
    struct task *t = ud;
    struct web *w = t->w;
    if (w) {
        for (struct task **pp = &w->tasks; *pp; pp = &(*pp)->next)
            if (*pp == t) {
                *pp = t->next;
                break;
            }
        struct render *r = render_find(w, t->key);
        if (r && r->state == R_PENDING) {
            if (rc == SF_OK && t->png) {
                r->state = R_READY;
                r->png = t->png;
                r->len = t->len;
                r->support_g = t->support_g;
                r->support_s = t->support_s;
                t->png = NULL;
            } else {
                r->state = R_FAILED;
                snprintf(r->why, sizeof(r->why), "%s",
                         rc == SF_ECANCELED ? "cancelled" : t->err.msg);
                log_warn("web", "preview %s: %s", t->key, r->why);
            }
        }
        if (w->cfg.wake)
            w->cfg.wake(w->cfg.ud);
    }
    free(t->png);
    free(t);
}

static double
render_angle(const struct job_row *j)
{
    return j->opts.overhang_deg > 0 ? j->opts.overhang_deg : 45;
}

/* The cache key of a job's picture: what it shows (after: the part as it
   prints, oriented and shaped; a job that kept its part, or is not
   prepared yet, shows the upload) and the angle its risky faces are for. */
static void
render_key(const struct job_row *j, bool after, char *key, size_t cap)
{
    const char *sha = after && j->mesh_sha[0] ? j->mesh_sha : j->file_sha;
    snprintf(key, cap, "%.64s@%g", sha, render_angle(j));
}

static ssize_t
pstream_read(void *ud, char *buf, size_t max)
{
    struct pstream *s = ud;
    if (!s->png) {
        struct render *r = render_find(s->w, s->key);
        if (r && r->state == R_PENDING)
            return 0; /* still rendering: suspended until a render ends */
        if (!r || r->state != R_READY || !(s->png = mem_alloc(r->len)))
            return -1; /* failed (logged): the picture ends empty */
        memcpy(s->png, r->png, r->len);
        s->len = r->len;
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

static void
preview(struct web *w, const struct job_row *j, const struct http_req *req, struct http_resp *resp)
{
    const char *stage = http_req_arg(req, "stage");
    bool after = stage && strcmp(stage, "after") == 0;
    if (stage && !after && strcmp(stage, "before") != 0) {
        http_error(resp, 400, "stage: '%.16s' is not 'before' or 'after'", stage);
        return;
    }
    const char *sha = after && j->mesh_sha[0] ? j->mesh_sha : j->file_sha;
    double angle = render_angle(j);
    char key[96], etag[112];
    render_key(j, after, key, sizeof(key));
    snprintf(etag, sizeof(etag), "\"%.24s-%g\"", sha, angle);
    http_resp_header(resp, "ETag", "%s", etag);
    http_resp_header(resp, "Cache-Control", "private, no-cache");
    resp->content_type = "image/png";
    if (etag_matches(req, etag)) {
        resp->status = 304;
        return;
    }
    struct render *r = render_find(w, key);
    if (r && r->state == R_FAILED) {
        resp->content_type = NULL;
        http_error(resp, 422, "job %lld: no picture of its part: %s", (long long)j->id, r->why);
        r->state = R_FREE; /* the next request tries again */
        return;
    }
    if (!r) {
        struct sf_err err;
        struct task *t = w->cfg.pool ? mem_calloc(1, sizeof(*t)) : NULL;
        if (!t || store_file_path(w->cfg.store, sha, t->path, sizeof(t->path), &err)) {
            resp->content_type = NULL;
            http_error(resp, t ? 500 : 503, "job %lld: %s", (long long)j->id,
                       t ? err.msg : "no worker pool for pictures");
            free(t);
            return;
        }
        if (!(r = render_slot(w))) {
            free(t);
            resp->content_type = NULL;
            http_resp_header(resp, "Retry-After", "2");
            http_error(resp, 503, "every picture slot is rendering; try again");
            return;
        }
        t->w = w;
        snprintf(t->key, sizeof(t->key), "%s", key);
        t->angle_deg = angle;
        if (!pool_submit(w->cfg.pool, render_work, render_done, t, &err)) {
            free(t);
            resp->content_type = NULL;
            http_error(resp, 500, "%s", err.msg);
            return;
        }
        t->next = w->tasks;
        w->tasks = t;
        r->state = R_PENDING;
        snprintf(r->key, sizeof(r->key), "%s", key);
    }
    r->used = ++w->stamp;
    if (r->state == R_READY) {
        /* MHD may send it after the cache evicted it: a copy it frees */
        void *copy = mem_alloc(r->len);
        if (!copy) {
            resp->content_type = NULL;
            http_error(resp, 500, "out of memory");
            return;
        }
        memcpy(copy, r->png, r->len);
        resp->body = copy;
        resp->body_len = r->len;
        resp->body_free = free;
        return;
    }
    struct pstream *s = mem_calloc(1, sizeof(*s));
    if (!s) {
        resp->content_type = NULL;
        http_error(resp, 500, "out of memory");
        return;
    }
    s->w = w;
    snprintf(s->key, sizeof(s->key), "%s", key);
    resp->stream = pstream_read;
    resp->stream_ud = s;
    resp->stream_free = pstream_free;
}

/* ---- G-code ---- */

static void
gcode(struct web *w, const struct job_row *j, struct http_resp *resp)
{
    struct sf_err err;
    char path[1100];
    if (!j->gcode_sha[0]) {
        http_error(resp, 404, "job %lld has no G-code yet (%s)", (long long)j->id,
                   job_state_name(j->state));
        return;
    }
    if (store_file_path(w->cfg.store, j->gcode_sha, path, sizeof(path), &err)) {
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
    char key[96];
    render_key(j, after, key, sizeof(key));
    struct render *r = render_find(w, key);
    if (!r || r->state != R_READY || r->support_g < 0)
        return json_null();
    return json_pack("{sf sf}", "support_g", r->support_g, "support_s", r->support_s);
}

static void
report(struct web *w, const struct job_row *j, struct http_resp *resp)
{
    json_t *g = json_null();
    char path[1100], head[WEB_GCODE_HEAD_MAX + 1];
    struct sf_err err;
    if (j->gcode_sha[0] &&
        store_file_path(w->cfg.store, j->gcode_sha, path, sizeof(path), &err) == SF_OK) {
        int fd = open(path, O_RDONLY | O_CLOEXEC);
        ssize_t n = fd >= 0 ? read(fd, head + 1, sizeof(head) - 2) : -1;
        if (fd >= 0)
            close(fd);
        if (n > 0) {
            head[0] = '\n';
            head[n + 1] = '\0';
            g = json_pack("{sf sf sf sf sf}", "time_s",
                          head_num(head, "estimated printing time [s]"), "filament_g",
                          head_num(head, "filament used [g]"), "support_g",
                          head_num(head, "support material used [g]"), "layers",
                          head_num(head, "total layers"), "filament_mm",
                          head_num(head, "filament used [mm]"));
        }
    }
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

/* GET /api/jobs/ID/preview.png, /gcode or /report. */
static void
job_route(void *ctx, const struct route_args *args, const struct http_req *req,
          struct http_resp *resp)
{
    struct web *w = ctx;
    struct job_row j;
    struct sf_err err;
    int rc = store_job_get(w->cfg.store, args->id, &j, &err);
    if (rc) {
        http_fail(resp, rc, err.msg);
        return;
    }
    const char *what = strrchr(req->path, '/') + 1;
    if (strcmp(what, "gcode") == 0)
        gcode(w, &j, resp);
    else if (strcmp(what, "report") == 0)
        report(w, &j, resp);
    else
        preview(w, &j, req, resp);
}

#define GET_HEAD (ROUTE_GET | ROUTE_HEAD)

static const struct route rows[] = {
    /* methods, pattern, match, body, scope, handler, 405 message */
    { GET_HEAD, NULL, web_is_public, HTTP_BODY_NONE, ROUTE_PUBLIC, asset, "use GET" },
    { GET_HEAD, "/api/whoami", NULL, HTTP_BODY_NONE, ROUTE_READ, whoami_route, "use GET" },
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
    return w;
}

void
web_free(struct web *w)
{
    if (!w)
        return;
    for (struct task *t = w->tasks; t; t = t->next)
        t->w = NULL; /* its done() frees it alone */
    for (size_t i = 0; i < WEB_PREVIEWS_MAX; i++)
        free(w->renders[i].png);
    free(w);
}
