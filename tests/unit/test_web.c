/*
 * test_web.c - the dashboard's side of the API over real HTTP (libcurl
 * client; the API, a store and a one-thread pool on a server thread that
 * stands in for the loop): static files without a key but nothing else,
 * their ETag/304, CSP and types; /api/whoami and its session cookie, which
 * authorizes GETs, and changes only with its CSRF token; a new tab's
 * session by its cookie, log out, and the per-key session quota; the part pictures (rendered on the
 * pool, cached, 304 by ETag) with the support model's grams in /report; G-code serving.
 */
#include <curl/curl.h>
#include <poll.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <strings.h>

#include "../../src/api/api.h"
#include "../../src/base/buf.h"
#include "../../src/base/log.h"
#include "../../src/farm/store.h"
#include "../../src/farm/store_host.h"
#include "../t.h"
#include "../tstore.h"

#define KEY_RW "rw-key-0123456789abcdef"
#define KEY_RO "ro-key-0123456789abcdef"

static struct {
    struct store *store;
    struct loop *l;
    struct pool *pool;
    struct api *api;
    pthread_t thread;
    atomic_bool stop;
    char base[64];
    int64_t job; /* a tetrahedron, queued */
} srv;

static void *
serve(void *arg)
{
    (void)arg;
    struct http *h = api_http(srv.api);
    struct pollfd pfd = { .fd = http_fd(h), .events = POLLIN };
    while (!atomic_load(&srv.stop)) {
        int64_t t = http_timeout_ms(h);
        poll(&pfd, 1, t < 0 || t > 5 ? 5 : (int)t);
        http_run(h);
        loop_run_once(srv.l, 0); /* the pool's done() calls: finished pictures */
    }
    return NULL;
}

static const char tetra[] = "solid t\n"
                            "facet normal 0 0 -1\nouter loop\nvertex 0 0 0\nvertex 0 20 0\n"
                            "vertex 20 0 0\nendloop\nendfacet\n"
                            "facet normal 0 -1 0\nouter loop\nvertex 0 0 0\nvertex 20 0 0\n"
                            "vertex 0 0 20\nendloop\nendfacet\n"
                            "facet normal -1 0 0\nouter loop\nvertex 0 0 0\nvertex 0 0 20\n"
                            "vertex 0 20 0\nendloop\nendfacet\n"
                            "facet normal 1 1 1\nouter loop\nvertex 20 0 0\nvertex 0 20 0\n"
                            "vertex 0 0 20\nendloop\nendfacet\nendsolid t\n";

static void stop(void);

static int
start(const char *name, struct sf_err *err)
{
    if (srv.api)
        stop(); /* a failed case returned early: its server must not run on */
    memset(&srv, 0, sizeof(srv));
    log_set_level(LOG_WARN);
    char dir[512];
    snprintf(dir, sizeof(dir), "%s/%s", t_tmpdir(), name);
    if (!(srv.store = t_store_open(dir, NULL, err)) || !(srv.l = loop_new(err)) ||
        !(srv.pool = pool_new(srv.l, 1, err)))
        return err->code ? err->code : SF_EIO;
    char sha[STORE_SHA_HEX];
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "tetra.stl");
    int rc;
    if ((rc = store_file_put(srv.store, tetra, sizeof(tetra) - 1, sha, err)) ||
        (rc = store_job_add(srv.store, &o, sha, &srv.job, err)))
        return rc;
    struct farmcfg_key keys[2] = { { .key = KEY_RW }, { .key = KEY_RO, .read_only = true } };
    struct api_config cfg = { .store = srv.store,
                              .pool = srv.pool,
                              .host = "127.0.0.1",
                              .port = 0,
                              .keys = keys,
                              .n_keys = 2,
                              .upload_max = 1 << 20,
                              .loop = srv.l }; /* reads on the reader's thread, as the daemon's */
    if (!(srv.api = api_new(&cfg, err)))
        return err->code;
    snprintf(srv.base, sizeof(srv.base), "http://127.0.0.1:%d", http_port(api_http(srv.api)));
    pthread_create(&srv.thread, NULL, serve, NULL);
    return SF_OK;
}

static void
stop(void)
{
    if (srv.api) {
        atomic_store(&srv.stop, true);
        pthread_join(srv.thread, NULL);
    }
    api_free(srv.api);
    if (srv.pool) {
        pool_free(srv.pool);
        loop_run_once(srv.l, 0);
    }
    store_close(srv.store);
    loop_free(srv.l);
    memset(&srv, 0, sizeof(srv));
}

static size_t
on_data(char *data, size_t size, size_t n, void *ud)
{
    buf_append(ud, data, size * n);
    return size * n;
}

/* One request: key and cookie ("sf_session=...") may be NULL, extra is
   one more header line or NULL; body and head (response headers) are
   filled; returns the status. */
static long
call(const char *method, const char *path, const char *key, const char *cookie, const char *extra,
     struct buf *body, struct buf *head)
{
    CURL *c = curl_easy_init();
    char url[256], hdr[160];
    snprintf(url, sizeof(url), "%s%s", srv.base, path);
    struct curl_slist *h = NULL;
    if (key) {
        snprintf(hdr, sizeof(hdr), "X-Api-Key: %s", key);
        h = curl_slist_append(h, hdr);
    }
    if (extra)
        h = curl_slist_append(h, extra);
    buf_reset(body);
    buf_reset(head);
    curl_easy_setopt(c, CURLOPT_URL, url);
    curl_easy_setopt(c, CURLOPT_CUSTOMREQUEST, method);
    if (strcmp(method, "POST") == 0)
        curl_easy_setopt(c, CURLOPT_POSTFIELDS, "");
    curl_easy_setopt(c, CURLOPT_HTTPHEADER, h);
    if (cookie)
        curl_easy_setopt(c, CURLOPT_COOKIE, cookie);
    curl_easy_setopt(c, CURLOPT_WRITEFUNCTION, on_data);
    curl_easy_setopt(c, CURLOPT_WRITEDATA, body);
    curl_easy_setopt(c, CURLOPT_HEADERFUNCTION, on_data);
    curl_easy_setopt(c, CURLOPT_HEADERDATA, head);
    curl_easy_setopt(c, CURLOPT_TIMEOUT, 120L);
    long status = 0;
    if (curl_easy_perform(c) == CURLE_OK)
        curl_easy_getinfo(c, CURLINFO_RESPONSE_CODE, &status);
    buf_append(body, "", 1); /* NUL-terminate */
    body->len--;
    buf_append(head, "", 1);
    head->len--;
    curl_slist_free_all(h);
    curl_easy_cleanup(c);
    return status;
}

/* The value of response header name (case-insensitive) into out, or "". */
static const char *
header(const struct buf *head, const char *name, char *out, size_t cap)
{
    out[0] = '\0';
    const char *p = head->data ? head->data : "";
    size_t n = strlen(name);
    while (*p) {
        if (strncasecmp(p, name, n) == 0 && p[n] == ':') {
            const char *v = p + n + 1;
            while (*v == ' ')
                v++;
            size_t l = strcspn(v, "\r\n");
            snprintf(out, cap, "%.*s", (int)(l < cap ? l : cap - 1), v);
            return out;
        }
        p += strcspn(p, "\n");
        if (*p)
            p++;
    }
    return out;
}

T_CASE(web_static_files_need_no_key_and_say_what_they_are)
{
    struct sf_err err;
    T_OK(start("static", &err), &err);
    struct buf b, h;
    buf_init(&b, 0);
    buf_init(&h, 0);
    char v[512], etag[128], inm[160];
    T_EQ_INT(call("GET", "/", NULL, NULL, NULL, &b, &h), 200);
    T_TRUE(strstr(b.data, "<script src=\"/app.js\"") != NULL);
    T_TRUE(strncmp(header(&h, "Content-Type", v, sizeof(v)), "text/html", 9) == 0);
    header(&h, "Content-Security-Policy", v, sizeof(v));
    T_TRUE(strstr(v, "script-src 'self'") != NULL);
    T_TRUE(strstr(v, "unsafe-inline") == NULL && strstr(v, "default-src 'none'") != NULL);
    T_EQ_STR(header(&h, "X-Content-Type-Options", v, sizeof(v)), "nosniff");
    header(&h, "ETag", etag, sizeof(etag));
    T_TRUE(etag[0] == '"');
    /* revalidation: 304 with no body */
    snprintf(inm, sizeof(inm), "If-None-Match: %s", etag);
    T_EQ_INT(call("GET", "/index.html", NULL, NULL, inm, &b, &h), 304);
    T_EQ_INT(b.len, 0);
    T_EQ_INT(call("GET", "/app.js", NULL, NULL, NULL, &b, &h), 200);
    T_TRUE(strncmp(header(&h, "Content-Type", v, sizeof(v)), "text/javascript", 15) == 0);
    T_TRUE(strstr(header(&h, "ETag", v, sizeof(v)), etag) == NULL); /* each file its own */
    T_EQ_INT(call("GET", "/style.css", NULL, NULL, NULL, &b, &h), 200);
    T_TRUE(strncmp(header(&h, "Content-Type", v, sizeof(v)), "text/css", 8) == 0);
    /* nothing else is public: the API and unknown paths still want a key */
    T_EQ_INT(call("GET", "/api/jobs", NULL, NULL, NULL, &b, &h), 401);
    T_EQ_INT(call("GET", "/secret.html", NULL, NULL, NULL, &b, &h), 401);
    T_EQ_INT(call("GET", "/../etc/passwd", NULL, NULL, NULL, &b, &h), 401);
    /* a static file takes GET/HEAD only, key or not */
    T_EQ_INT(call("POST", "/", NULL, NULL, NULL, &b, &h), 405);
    T_EQ_INT(call("POST", "/", KEY_RW, NULL, NULL, &b, &h), 405);
    buf_release(&b);
    buf_release(&h);
    stop();
}

/* "sf_session_ID=TOKEN" from a whoami reply's Set-Cookie into out. */
static const char *
session_of(const struct buf *head, char *out, size_t cap)
{
    char v[256];
    header(head, "Set-Cookie", v, sizeof(v));
    snprintf(out, cap, "%.*s", (int)strcspn(v, ";"), v);
    return v[0] ? out : NULL;
}

/* The "X-Csrf-Token: T" header line for the "csrf" of a whoami reply, into out. */
static const char *
csrf_of(const struct buf *body, char *out, size_t cap)
{
    const char *p = body->data ? strstr(body->data, "\"csrf\":\"") : NULL;
    out[0] = '\0';
    if (p)
        snprintf(out, cap, "X-Csrf-Token: %.*s", (int)strcspn(p + 8, "\""), p + 8);
    return out;
}

/* The start of a case: its server (named name) and its buffers. */
static int
begin(const char *name, struct buf *b, struct buf *h, struct sf_err *err)
{
    buf_init(b, 0);
    buf_init(h, 0);
    return start(name, err);
}

/* The end of a case: its buffers and its server. */
static void
finish(struct buf *b, struct buf *h)
{
    buf_release(b);
    buf_release(h);
    stop();
}

T_CASE(web_session_cookie_stands_for_its_key_and_changes_only_with_its_csrf)
{
    struct sf_err err;
    struct buf b, h;
    T_OK(begin("session", &b, &h, &err), &err);
    char v[256], rw[128], ro[128], csrf[96], bad[128];
    T_EQ_INT(call("GET", "/api/whoami", NULL, NULL, NULL, &b, &h), 401);
    T_EQ_INT(call("GET", "/api/whoami", KEY_RW, NULL, NULL, &b, &h), 200);
    T_TRUE(strstr(b.data, "\"read_only\":false") != NULL);
    csrf_of(&b, csrf, sizeof(csrf));
    T_EQ_INT(strlen(csrf), strlen("X-Csrf-Token: ") + 32);
    header(&h, "Set-Cookie", v, sizeof(v));
    T_TRUE(strstr(v, "HttpOnly") != NULL && strstr(v, "SameSite=Strict") != NULL);
    T_TRUE(strstr(v, "Path=/;") != NULL);
    T_TRUE(strncmp(v, "sf_session_", 11) == 0); /* named after this daemon */
    T_TRUE(strstr(v, KEY_RW) == NULL);          /* a token, not the key */
    T_TRUE(session_of(&h, rw, sizeof(rw)) != NULL);
    T_EQ_INT(call("GET", "/api/whoami", KEY_RO, NULL, NULL, &b, &h), 200);
    T_TRUE(strstr(b.data, "\"read_only\":true") != NULL);
    T_TRUE(session_of(&h, ro, sizeof(ro)) != NULL);
    /* the cookie alone reads, and knows which key it stands for */
    T_EQ_INT(call("GET", "/api/jobs", NULL, rw, NULL, &b, &h), 200);
    T_TRUE(strstr(b.data, "tetra.stl") != NULL);
    T_EQ_INT(call("GET", "/api/whoami", NULL, ro, NULL, &b, &h), 200);
    T_TRUE(strstr(b.data, "\"read_only\":true") != NULL);
    /* ...and changes things only with its CSRF token, which no other page can read */
    char path[64];
    snprintf(path, sizeof(path), "/api/jobs/%lld/cancel", (long long)srv.job);
    T_EQ_INT(call("POST", path, NULL, rw, NULL, &b, &h), 401);
    T_TRUE(strstr(b.data, "X-Csrf-Token") != NULL);
    T_EQ_INT(call("POST", path, NULL, rw, "X-Csrf-Token: 0123456789abcdef0123456789abcdef", &b, &h),
             401);
    T_EQ_INT(call("POST", path, NULL, ro, csrf, &b, &h), 401); /* another session's token */
    T_EQ_INT(call("POST", path, NULL, rw, csrf, &b, &h), 200);
    /* a token this daemon never made, under its cookie name */
    snprintf(bad, sizeof(bad), "%.*s=0123456789abcdef0123456789abcdef", (int)strcspn(rw, "="), rw);
    T_EQ_INT(call("GET", "/api/jobs", NULL, bad, NULL, &b, &h), 401);
    T_TRUE(strstr(b.data, "session expired") != NULL);
    /* the old name means nothing */
    T_EQ_INT(
        call("GET", "/api/jobs", NULL, "sf_session=0123456789abcdef0123456789abcdef", NULL, &b, &h),
        401);
    finish(&b, &h);
}

T_CASE(web_new_tab_gets_the_session_by_its_cookie_and_log_out_ends_it)
{
    struct sf_err err;
    struct buf b, h;
    T_OK(begin("logout", &b, &h, &err), &err);
    char v[256], rw[128], csrf[96], csrf2[96];
    T_EQ_INT(call("GET", "/api/whoami", KEY_RW, NULL, NULL, &b, &h), 200);
    T_TRUE(session_of(&h, rw, sizeof(rw)) != NULL);
    csrf_of(&b, csrf, sizeof(csrf));
    /* a new tab: the cookie alone, no key; the same session, no new cookie */
    T_EQ_INT(call("GET", "/api/whoami", NULL, rw, NULL, &b, &h), 200);
    T_EQ_STR(csrf_of(&b, csrf2, sizeof(csrf2)), csrf);
    T_EQ_STR(header(&h, "Set-Cookie", v, sizeof(v)), "");
    /* log out needs the CSRF token too (no other page may log us out) */
    T_EQ_INT(call("POST", "/api/logout", NULL, rw, NULL, &b, &h), 403);
    T_EQ_INT(call("GET", "/api/jobs", NULL, rw, NULL, &b, &h), 200);
    T_EQ_INT(call("POST", "/api/logout", NULL, rw, csrf, &b, &h), 200);
    T_TRUE(strstr(b.data, "\"ended\":true") != NULL);
    header(&h, "Set-Cookie", v, sizeof(v));
    T_TRUE(strstr(v, "Max-Age=0") != NULL); /* the browser drops it */
    /* the token is dead on the daemon, whoever still holds it */
    T_EQ_INT(call("GET", "/api/jobs", NULL, rw, NULL, &b, &h), 401);
    T_EQ_INT(call("GET", "/api/whoami", NULL, rw, NULL, &b, &h), 401);
    T_EQ_INT(call("POST", "/api/logout", NULL, rw, csrf, &b, &h), 200);
    T_TRUE(strstr(b.data, "\"ended\":false") != NULL);
    finish(&b, &h);
}

T_CASE(web_read_only_logins_never_evict_another_keys_session)
{
    struct sf_err err;
    struct buf b, h;
    T_OK(begin("evict", &b, &h, &err), &err);
    char rw[128], first_ro[128], last_ro[128];
    T_EQ_INT(call("GET", "/api/whoami", KEY_RW, NULL, NULL, &b, &h), 200);
    T_TRUE(session_of(&h, rw, sizeof(rw)) != NULL);
    /* 64 logins used to evict every session; a key now evicts only its own */
    for (int i = 0; i < 200; i++) {
        T_EQ_INT(call("GET", "/api/whoami", KEY_RO, NULL, NULL, &b, &h), 200);
        T_TRUE(session_of(&h, i ? last_ro : first_ro, sizeof(rw)) != NULL);
    }
    T_EQ_INT(call("GET", "/api/jobs", NULL, rw, NULL, &b, &h), 200);
    T_EQ_INT(call("GET", "/api/jobs", NULL, last_ro, NULL, &b, &h), 200);
    T_EQ_INT(call("GET", "/api/jobs", NULL, first_ro, NULL, &b, &h), 401); /* its own oldest */
    finish(&b, &h);
}

T_CASE(web_part_pictures_render_on_the_pool_and_revalidate)
{
    struct sf_err err;
    T_OK(start("picture", &err), &err);
    struct buf b, h;
    buf_init(&b, 0);
    buf_init(&h, 0);
    char path[96], rpath[64], v[128], inm[160];
    snprintf(path, sizeof(path), "/api/jobs/%lld/preview.png?stage=before", (long long)srv.job);
    snprintf(rpath, sizeof(rpath), "/api/jobs/%lld/report", (long long)srv.job);
    T_EQ_INT(call("GET", rpath, KEY_RO, NULL, NULL, &b, &h), 200);
    T_TRUE(strstr(b.data, "\"model_before\":null") != NULL);
    T_TRUE(strstr(b.data, "\"gcode\":null") != NULL); /* not sliced */
    T_EQ_INT(call("GET", path, KEY_RO, NULL, NULL, &b, &h), 200);
    T_TRUE(b.len > 1000 && memcmp(b.data, "\x89PNG\r\n\x1a\n", 8) == 0);
    T_EQ_STR(header(&h, "Content-Type", v, sizeof(v)), "image/png");
    snprintf(inm, sizeof(inm), "If-None-Match: %s", header(&h, "ETag", v, sizeof(v)));
    T_TRUE(v[0] == '"');
    T_EQ_INT(call("GET", path, KEY_RO, NULL, inm, &b, &h), 304);
    /* from the cache now, whole */
    T_EQ_INT(call("GET", path, KEY_RO, NULL, NULL, &b, &h), 200);
    T_TRUE(b.len > 1000 && memcmp(b.data, "\x89PNG", 4) == 0);
    /* the tetrahedron's slanted face needs no support, its bottom lies on
       the bed: the model's grams are there, and small */
    T_EQ_INT(call("GET", rpath, KEY_RO, NULL, NULL, &b, &h), 200);
    const char *m = strstr(b.data, "\"model_before\":{");
    T_TRUE(m != NULL);
    T_TRUE(strstr(m, "\"support_g\":") != NULL);
    snprintf(path, sizeof(path), "/api/jobs/%lld/preview.png?stage=sideways", (long long)srv.job);
    T_EQ_INT(call("GET", path, KEY_RO, NULL, NULL, &b, &h), 400);
    T_EQ_INT(call("GET", "/api/jobs/999/preview.png", KEY_RO, NULL, NULL, &b, &h), 404);
    snprintf(path, sizeof(path), "/api/jobs/%lld/gcode", (long long)srv.job);
    T_EQ_INT(call("GET", path, KEY_RO, NULL, NULL, &b, &h), 404);
    T_TRUE(strstr(b.data, "no G-code yet") != NULL);
    buf_release(&b);
    buf_release(&h);
    stop();
}

/* The loop's own connection's round trips so far (store_round_trips), read with the server
   thread (the loop) stopped. */
static int64_t
loop_trips(void)
{
    atomic_store(&srv.stop, true);
    pthread_join(srv.thread, NULL);
    int64_t n = store_round_trips(srv.store);
    atomic_store(&srv.stop, false);
    pthread_create(&srv.thread, NULL, serve, NULL);
    return n;
}

T_CASE(web_gcode_is_served_from_the_store)
{
    struct sf_err err;
    T_OK(start("gcode", &err), &err);
    struct buf b, h;
    buf_init(&b, 0);
    buf_init(&h, 0);
    /* prepare the job by hand: the store records its G-code */
    static const char gc[] = "; generated by slimfarm slicer\n; estimated printing time [s] = 754\n"
                             "; filament used [g] = 3.25\n; support material used [g] = 0.50\n"
                             "; total layers = 12\nG28\n;LAYER_CHANGE\n;Z:0.2\nG1 X1 Y1 E1\n";
    char sha[STORE_SHA_HEX], path[64], v[128];
    T_OK(store_file_put(srv.store, gc, sizeof(gc) - 1, sha, &err), &err);
    /* the store is the server thread's: stop it while we write */
    atomic_store(&srv.stop, true);
    pthread_join(srv.thread, NULL);
    struct job_event_args a = { .gcode_sha = sha, .gcode_lines = 2, .nozzle_mm = 0.4 };
    T_OK(store_job_event(srv.store, srv.job, JOB_EV_PREPARE, NULL, NULL, &err), &err);
    T_OK(store_job_event(srv.store, srv.job, JOB_EV_PREPARED, &a, NULL, &err), &err);
    atomic_store(&srv.stop, false);
    pthread_create(&srv.thread, NULL, serve, NULL);
    int64_t trips = loop_trips();
    snprintf(path, sizeof(path), "/api/jobs/%lld/gcode", (long long)srv.job);
    T_EQ_INT(call("GET", path, KEY_RO, NULL, NULL, &b, &h), 200);
    T_EQ_INT(b.len, sizeof(gc) - 1);
    T_TRUE(memcmp(b.data, gc, b.len) == 0);
    T_TRUE(strncmp(header(&h, "Content-Type", v, sizeof(v)), "text/plain", 10) == 0);
    snprintf(path, sizeof(path), "/api/jobs/%lld/report", (long long)srv.job);
    T_EQ_INT(call("GET", path, KEY_RO, NULL, NULL, &b, &h), 200);
    T_TRUE(strstr(b.data, "\"time_s\":754") != NULL);
    T_TRUE(strstr(b.data, "\"filament_g\":3.25") != NULL);
    T_TRUE(strstr(b.data, "\"support_g\":0.5") != NULL);
    T_TRUE(strstr(b.data, "\"layers\":12") != NULL);
    /* an orient job's deviation is not measured: null, in the report and the job */
    T_TRUE(strstr(b.data, "\"mndr\":null") != NULL && strstr(b.data, "\"andr\":null") != NULL);
    snprintf(path, sizeof(path), "/api/jobs/%lld", (long long)srv.job);
    T_EQ_INT(call("GET", path, KEY_RO, NULL, NULL, &b, &h), 200);
    T_TRUE(strstr(b.data, "\"mndr\":null") != NULL && strstr(b.data, "\"andr\":null") != NULL);
    /* issue 32: the job, its G-code file (which may come whole from the database) and its
       report's numbers were read on the API's reader: the loop's connection sent nothing */
    T_EQ_INT(loop_trips() - trips, 0);
    /* a slim job's is: the fractions of the diagonal the farm recorded */
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "slim.stl");
    snprintf(o.method, sizeof(o.method), "slim");
    char part[STORE_SHA_HEX];
    int64_t slim;
    atomic_store(&srv.stop, true);
    pthread_join(srv.thread, NULL);
    T_OK(store_file_put(srv.store, tetra, sizeof(tetra) - 1, part, &err), &err);
    T_OK(store_job_add(srv.store, &o, part, &slim, &err), &err);
    a.dev_measured = a.shape_changed = true;
    a.mndr = 0.0125;
    a.andr = 0.0025;
    T_OK(store_job_event(srv.store, slim, JOB_EV_PREPARE, NULL, NULL, &err), &err);
    T_OK(store_job_event(srv.store, slim, JOB_EV_PREPARED, &a, NULL, &err), &err);
    atomic_store(&srv.stop, false);
    pthread_create(&srv.thread, NULL, serve, NULL);
    snprintf(path, sizeof(path), "/api/jobs/%lld", (long long)slim);
    T_EQ_INT(call("GET", path, KEY_RO, NULL, NULL, &b, &h), 200);
    T_TRUE(strstr(b.data, "\"mndr\":0.0125") != NULL);
    T_TRUE(strstr(b.data, "\"andr\":0.0025") != NULL);
    T_TRUE(strstr(b.data, "\"shape_changed\":true") != NULL);
    snprintf(path, sizeof(path), "/api/jobs/%lld/report", (long long)slim);
    T_EQ_INT(call("GET", path, KEY_RO, NULL, NULL, &b, &h), 200);
    T_TRUE(strstr(b.data, "\"mndr\":0.0125") != NULL);
    T_TRUE(strstr(b.data, "\"andr\":0.0025") != NULL);
    buf_release(&b);
    buf_release(&h);
    stop();
}

/* Issue 32: a picture's render looks its part up on the worker's own reader (a part this
   host's cache lacks comes whole from the database first): the loop's connection sends
   nothing for a picture, rendered or kept. */
T_CASE(web_picture_looks_its_part_up_off_the_loop)
{
    struct sf_err err;
    T_OK(start("picture-trips", &err), &err);
    struct buf b, h;
    buf_init(&b, 0);
    buf_init(&h, 0);
    char path[96];
    snprintf(path, sizeof(path), "/api/jobs/%lld/preview.png?stage=before", (long long)srv.job);
    int64_t trips = loop_trips();
    T_EQ_INT(call("GET", path, KEY_RO, NULL, NULL, &b, &h), 200); /* rendered */
    T_TRUE(b.len > 1000 && memcmp(b.data, "\x89PNG\r\n\x1a\n", 8) == 0);
    T_EQ_INT(call("GET", path, KEY_RO, NULL, NULL, &b, &h), 200); /* kept */
    T_TRUE(b.len > 1000 && memcmp(b.data, "\x89PNG", 4) == 0);
    T_EQ_INT(loop_trips() - trips, 0);
    buf_release(&b);
    buf_release(&h);
    stop();
}
