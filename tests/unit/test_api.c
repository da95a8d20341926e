/*
 * test_api.c - the REST API over real HTTP on loopback (libcurl client,
 * libmicrohttpd server on a thread of its own standing in for the loop),
 * with a real store in a scratch dir and a small printer registry driven
 * by job.h's printer state machine.
 *
 * Keys (401/403), submission (multipart + options), malformed JSON (400),
 * oversized bodies (413), path traversal in file names, cancel, priority,
 * printer actions and the bed-clear gate, and Server-Sent Events (backlog
 * and live).
 */
#include <curl/curl.h>
#include <poll.h>
#include <pthread.h>
#include <stdatomic.h>
#include <time.h>

#include "../../src/api/api.h"
#include "../../src/base/buf.h"
#include "../../src/base/log.h"
#include "../../src/farm/store.h"
#include "../t.h"

#define KEY_RW     "rw-key-0123456789abcdef"
#define KEY_RO     "ro-key-0123456789abcdef"
#define UPLOAD_MAX (64 << 10)

/* The test's printer registry: two printers moved by printer_next(). */
struct farm {
    struct store *store;
    struct api_printer_info p[2];
    int64_t job[2]; /* job printing on each, 0 if none */
};

static size_t
reg_count(void *ud)
{
    (void)ud;
    return 2;
}

static void
reg_get(void *ud, size_t i, struct api_printer_info *out)
{
    struct farm *f = ud;
    *out = f->p[i];
    out->job_id = f->job[i];
}

static int
reg_action(void *ud, const char *name, const char *action, struct sf_err *err)
{
    struct farm *f = ud;
    for (size_t i = 0; i < 2; i++) {
        if (strcmp(f->p[i].name, name) != 0)
            continue;
        enum printer_event ev = strcmp(action, "pause") == 0    ? PRINTER_EV_PAUSE
                                : strcmp(action, "resume") == 0 ? PRINTER_EV_RESUME
                                : strcmp(action, "cancel") == 0 ? PRINTER_EV_FINISHED
                                                                : PRINTER_EV_CLEARED;
        enum printer_state to;
        int rc = printer_next(f->p[i].state, ev, false, &to, err);
        if (rc)
            return rc;
        if (f->job[i] && ev != PRINTER_EV_CLEARED) {
            enum job_event jev = ev == PRINTER_EV_PAUSE    ? JOB_EV_PAUSE
                                 : ev == PRINTER_EV_RESUME ? JOB_EV_RESUME
                                                           : JOB_EV_CANCEL;
            if ((rc = store_job_event(f->store, f->job[i], jev, NULL, NULL, err)))
                return rc;
            if (jev == JOB_EV_CANCEL)
                f->job[i] = 0;
        }
        f->p[i].state = to;
        return SF_OK;
    }
    return sf_err_set(err, SF_ENOTFOUND, "no printer '%s'", name);
}

/* resume_job: record what the API passed on (the farm's rules are test_farm's and integ's). */
static int64_t resumed_id, resumed_line;

static int
reg_resume_job(void *ud, int64_t id, int64_t line, struct sf_err *err)
{
    (void)ud;
    if (id == 2)
        return sf_err_set(err, SF_EINVAL,
                          "job 2 is queued: only an interrupted job can be resumed");
    resumed_id = id;
    resumed_line = line;
    return SF_OK;
}

static const struct api_printer_ops reg_ops = { reg_count, reg_get, reg_action, reg_resume_job };

/* The server side: api + its thread. */
static struct {
    struct farm farm;
    struct api *api;
    pthread_t thread;
    atomic_bool stop;
    char base[64];
} srv;

static void *
serve(void *arg)
{
    (void)arg;
    struct http *h = api_http(srv.api);
    /* Poll MHD's epoll fd for readability, as the loop does; never
       epoll_wait on it, which would steal MHD's own events. */
    struct pollfd pfd = { .fd = http_fd(h), .events = POLLIN };
    for (unsigned turn = 0; !atomic_load(&srv.stop); turn++) {
        if (turn % 10 == 9)
            api_tick(srv.api); /* the daemon's API_TICK_MS, faster */
        int64_t t = http_timeout_ms(h);
        poll(&pfd, 1, t < 0 || t > 10 ? 10 : (int)t);
        http_run(h);
    }
    return NULL;
}

static int start_api(struct sf_err *err);

/* Open a store with one printing job (on printer "a") and start the API. */
static void stop(void);

static int
start(const char *name, struct sf_err *err)
{
    char dir[512];
    snprintf(dir, sizeof(dir), "%s/%s", t_tmpdir(), name);
    if (srv.api)
        stop(); /* a failed case returned early: its server must not run on */
    memset(&srv, 0, sizeof(srv));
    log_set_level(LOG_WARN);
    struct farm *f = &srv.farm;
    f->store = store_open(dir, NULL, err);
    if (!f->store)
        return SF_EIO;
    f->p[0] = (struct api_printer_info){ .name = "a",
                                         .state = PRINTER_PRINTING,
                                         .enabled = true,
                                         .material = "PLA",
                                         .nozzle_mm = 0.4,
                                         .bed_mm = { 220, 220, 250 },
                                         .group = "",
                                         .nozzle_c = 215,
                                         .nozzle_target_c = 215 };
    f->p[1] = f->p[0];
    f->p[1].name = "b";
    f->p[1].state = PRINTER_IDLE;
    /* job 1 prints on "a" */
    char sha[STORE_SHA_HEX], gsha[STORE_SHA_HEX];
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "seed.stl");
    int64_t id;
    int rc;
    if ((rc = store_file_put(f->store, "solid x", 7, sha, err)) ||
        (rc = store_job_add(f->store, &o, sha, &id, err)) ||
        (rc = store_job_event(f->store, id, JOB_EV_PREPARE, NULL, NULL, err)) ||
        (rc = store_file_put(f->store, "G28\n", 4, gsha, err)))
        return rc;
    struct job_event_args prep = { .gcode_sha = gsha, .gcode_lines = 1 }, go = { .printer = "a" };
    if ((rc = store_job_event(f->store, id, JOB_EV_PREPARED, &prep, NULL, err)) ||
        (rc = store_job_event(f->store, id, JOB_EV_START, &go, NULL, err)))
        return rc;
    f->job[0] = id;
    return start_api(err);
}

/* Start the API on srv.farm's store. */
static int
start_api(struct sf_err *err)
{
    struct farm *f = &srv.farm;
    atomic_store(&srv.stop, false);
    struct farmcfg_key keys[2] = { { KEY_RW, false }, { KEY_RO, true } };
    struct api_config cfg = { .store = f->store,
                              .printers = &reg_ops,
                              .printers_ud = f,
                              .host = "127.0.0.1",
                              .port = 0,
                              .keys = keys,
                              .n_keys = 2,
                              .upload_max = UPLOAD_MAX };
    srv.api = api_new(&cfg, err);
    if (!srv.api)
        return err->code;
    snprintf(srv.base, sizeof(srv.base), "http://127.0.0.1:%d", http_port(api_http(srv.api)));
    pthread_create(&srv.thread, NULL, serve, NULL);
    return SF_OK;
}

static void
stop(void)
{
    atomic_store(&srv.stop, true);
    pthread_join(srv.thread, NULL);
    api_free(srv.api);
    store_close(srv.farm.store);
    srv.api = NULL;
    srv.farm.store = NULL;
}

static size_t
on_body(char *data, size_t size, size_t n, void *ud)
{
    buf_append(ud, data, size * n);
    return size * n;
}

/* A client call.  part/opts non-NULL make it multipart; returns the status. */
static long
call(const char *method, const char *path, const char *key, const char *body, const char *part_name,
     const void *part, size_t part_len, const char *opts, struct buf *out)
{
    CURL *c = curl_easy_init();
    char url[256], hdr[128];
    snprintf(url, sizeof(url), "%s%s", srv.base, path);
    struct curl_slist *h = NULL;
    if (key) {
        snprintf(hdr, sizeof(hdr), "X-Api-Key: %s", key);
        h = curl_slist_append(h, hdr);
    }
    curl_mime *mime = NULL;
    if (part_name) {
        mime = curl_mime_init(c);
        curl_mimepart *mp = curl_mime_addpart(mime);
        curl_mime_name(mp, "file");
        curl_mime_filename(mp, part_name);
        curl_mime_data(mp, part, part_len);
        if (opts) {
            mp = curl_mime_addpart(mime);
            curl_mime_name(mp, "options");
            curl_mime_data(mp, opts, CURL_ZERO_TERMINATED);
        }
        curl_easy_setopt(c, CURLOPT_MIMEPOST, mime);
    } else if (body) {
        h = curl_slist_append(h, "Content-Type: application/json");
        curl_easy_setopt(c, CURLOPT_POSTFIELDS, body);
    } else if (strcmp(method, "POST") == 0) {
        curl_easy_setopt(c, CURLOPT_POSTFIELDS, "");
    }
    curl_easy_setopt(c, CURLOPT_URL, url);
    curl_easy_setopt(c, CURLOPT_CUSTOMREQUEST, method);
    curl_easy_setopt(c, CURLOPT_HTTPHEADER, h);
    curl_easy_setopt(c, CURLOPT_WRITEFUNCTION, on_body);
    curl_easy_setopt(c, CURLOPT_WRITEDATA, out);
    curl_easy_setopt(c, CURLOPT_TIMEOUT, 10L);
    curl_easy_setopt(c, CURLOPT_EXPECT_100_TIMEOUT_MS, 10000L); /* as the CLI does */
    buf_reset(out);
    long status = 0;
    CURLcode rc = curl_easy_perform(c);
    if (rc == CURLE_OK)
        curl_easy_getinfo(c, CURLINFO_RESPONSE_CODE, &status);
    else
        printf("    curl: %s %s: %s\n", method, path, curl_easy_strerror(rc));
    curl_mime_free(mime);
    curl_slist_free_all(h);
    curl_easy_cleanup(c);
    return status;
}

static long
get(const char *path, const char *key, struct buf *out)
{
    return call("GET", path, key, NULL, NULL, NULL, 0, NULL, out);
}

/* Field of the JSON object at "job"/"printer" etc. in a reply, as text. */
static const char *
jstr(struct buf *b, const char *outer, const char *name)
{
    static char val[256];
    json_t *root = json_loads(b->data ? b->data : "", 0, NULL);
    json_t *o = outer ? json_object_get(root, outer) : root;
    json_t *v = json_object_get(o, name);
    if (json_is_string(v))
        snprintf(val, sizeof(val), "%s", json_string_value(v));
    else if (json_is_integer(v))
        snprintf(val, sizeof(val), "%lld", (long long)json_integer_value(v));
    else
        snprintf(val, sizeof(val), "(missing)");
    json_decref(root);
    return val;
}

T_CASE(api_keys_are_required)
{
    struct sf_err err;
    T_OK(start("keys", &err), &err);
    struct buf b;
    buf_init(&b, 0);
    T_EQ_INT(get("/api/jobs", NULL, &b), 401);
    T_EQ_STR(jstr(&b, NULL, "error"), "missing X-Api-Key header");
    T_EQ_INT(get("/api/jobs", "wrong-key-0123456789", &b), 401);
    T_EQ_STR(jstr(&b, NULL, "error"), "unknown API key");
    T_EQ_INT(get("/api/jobs", KEY_RO, &b), 200);
    T_EQ_INT(get("/api/printers", KEY_RO, &b), 200);
    /* read-only keys may not change anything */
    T_EQ_INT(call("POST", "/api/jobs/1/cancel", KEY_RO, NULL, NULL, NULL, 0, NULL, &b), 403);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "read-only API key") != NULL);
    T_EQ_INT(call("PATCH", "/api/jobs/1", KEY_RO, "{\"priority\":3}", NULL, NULL, 0, NULL, &b),
             403);
    T_EQ_INT(call("POST", "/api/jobs", KEY_RO, NULL, "a.stl", "x", 1, NULL, &b), 403);
    T_EQ_INT(get("/api/jobs/1", KEY_RW, &b), 200);
    T_EQ_STR(jstr(&b, "job", "state"), "printing");
    buf_release(&b);
    stop();
}

T_CASE(api_submit_get_list_and_reprioritize)
{
    struct sf_err err;
    T_OK(start("submit", &err), &err);
    struct buf b;
    buf_init(&b, 0);
    const char part[] = "solid cube\nendsolid cube\n";
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "bracket v2.stl", part, sizeof(part) - 1,
                  "{\"copies\": 3, \"material\": \"PETG\", \"method\": \"slim\", "
                  "\"deviation_mm\": 0.8, \"group\": \"big\", \"priority\": 2}",
                  &b),
             201);
    T_EQ_STR(jstr(&b, "job", "name"), "bracket v2.stl");
    T_EQ_STR(jstr(&b, "job", "state"), "queued");
    T_EQ_STR(jstr(&b, "job", "copies"), "3");
    T_EQ_STR(jstr(&b, "job", "material"), "PETG");
    T_EQ_STR(jstr(&b, "job", "target_group"), "big");
    T_EQ_STR(jstr(&b, "job", "method"), "slim");
    char id[32];
    snprintf(id, sizeof(id), "%s", jstr(&b, "job", "id"));
    T_EQ_STR(id, "2");
    /* defaults when no options are sent */
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "plain.3mf", "PK", 2, NULL, &b), 201);
    T_EQ_STR(jstr(&b, "job", "copies"), "1");
    T_EQ_STR(jstr(&b, "job", "method"), "orient");
    T_EQ_INT(get("/api/jobs", KEY_RW, &b), 200);
    json_t *root = json_loads(b.data, 0, NULL);
    T_EQ_INT(json_array_size(json_object_get(root, "jobs")), 3);
    json_decref(root);
    T_EQ_INT(get("/api/jobs/2", KEY_RW, &b), 200);
    T_EQ_STR(jstr(&b, "job", "priority"), "2");
    T_EQ_INT(call("PATCH", "/api/jobs/2", KEY_RW, "{\"priority\": -5}", NULL, NULL, 0, NULL, &b),
             200);
    T_EQ_STR(jstr(&b, "job", "priority"), "-5");
    T_EQ_INT(get("/api/jobs/99", KEY_RW, &b), 404);
    T_EQ_INT(get("/api/jobs/x1", KEY_RW, &b), 404);
    T_EQ_INT(get("/api/nothing", KEY_RW, &b), 404);
    T_EQ_INT(call("DELETE", "/api/jobs", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 405);
    buf_release(&b);
    stop();
}

T_CASE(api_malformed_json_is_400_with_message)
{
    struct sf_err err;
    T_OK(start("json", &err), &err);
    struct buf b;
    buf_init(&b, 0);
    T_EQ_INT(call("PATCH", "/api/jobs/1", KEY_RW, "{\"priority\": ", NULL, NULL, 0, NULL, &b), 400);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "malformed JSON at line 1") != NULL);
    T_EQ_INT(call("PATCH", "/api/jobs/1", KEY_RW, "[1]", NULL, NULL, 0, NULL, &b), 400);
    T_EQ_INT(
        call("PATCH", "/api/jobs/1", KEY_RW, "{\"priority\": \"high\"}", NULL, NULL, 0, NULL, &b),
        400);
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "a.stl", "x", 1, "{copies: 2}", &b), 400);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "options: malformed JSON") != NULL);
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "a.stl", "x", 1, "{\"copies\": \"2\"}", &b),
             400);
    T_EQ_STR(jstr(&b, NULL, "error"), "options: field 'copies': expected an integer");
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "a.stl", "x", 1, "{\"colour\": \"red\"}", &b),
             400);
    T_EQ_STR(jstr(&b, NULL, "error"), "options: unknown field 'colour'");
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "a.stl", "x", 1, "{\"copies\": 0}", &b), 400);
    T_EQ_STR(jstr(&b, NULL, "error"), "options: copies: 0 is not in 1..1000");
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "a.stl", "x", 1,
                  "{\"copies\": 1, \"copies\": 2}", &b),
             400);
    /* nothing was added by the refusals */
    T_EQ_INT(get("/api/jobs", KEY_RW, &b), 200);
    json_t *root = json_loads(b.data, 0, NULL);
    T_EQ_INT(json_array_size(json_object_get(root, "jobs")), 1);
    json_decref(root);
    buf_release(&b);
    stop();
}

T_CASE(api_oversized_bodies_are_413)
{
    struct sf_err err;
    T_OK(start("big", &err), &err);
    struct buf b;
    buf_init(&b, 0);
    size_t n = UPLOAD_MAX * 3;
    char *big = malloc(n + 1);
    memset(big, 'x', n);
    big[n] = '\0';
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "huge.stl", big, n, NULL, &b), 413);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "over the limit") != NULL);
    big[API_BODY_MAX + 10] = '\0';
    T_EQ_INT(call("PATCH", "/api/jobs/1", KEY_RW, big, NULL, NULL, 0, NULL, &b), 413);
    free(big);
    /* just under the limit is fine */
    char *ok = calloc(1, UPLOAD_MAX - 1024);
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "ok.stl", ok, UPLOAD_MAX - 1024, NULL, &b),
             201);
    free(ok);
    buf_release(&b);
    stop();
}

/* Reads `left` bytes of 'x' for a chunked upload. */
static size_t
read_x(char *buf, size_t size, size_t n, void *ud)
{
    size_t *left = ud, k = size * n < *left ? size * n : *left;
    memset(buf, 'x', k);
    *left -= k;
    return k;
}

T_CASE(api_chunked_body_over_the_cap_is_413)
{
    /* No Content-Length to refuse early: the cap holds while streaming. */
    struct sf_err err;
    T_OK(start("chunked", &err), &err);
    struct buf b;
    buf_init(&b, 0);
    CURL *c = curl_easy_init();
    char url[128];
    snprintf(url, sizeof(url), "%s/api/jobs/1", srv.base);
    struct curl_slist *h = curl_slist_append(NULL, "X-Api-Key: " KEY_RW);
    h = curl_slist_append(h, "Transfer-Encoding: chunked");
    h = curl_slist_append(h, "Content-Type: application/json");
    size_t left = API_BODY_MAX * 4;
    curl_easy_setopt(c, CURLOPT_URL, url);
    curl_easy_setopt(c, CURLOPT_UPLOAD, 1L);
    curl_easy_setopt(c, CURLOPT_CUSTOMREQUEST, "PATCH");
    curl_easy_setopt(c, CURLOPT_HTTPHEADER, h);
    curl_easy_setopt(c, CURLOPT_READFUNCTION, read_x);
    curl_easy_setopt(c, CURLOPT_READDATA, &left);
    curl_easy_setopt(c, CURLOPT_WRITEFUNCTION, on_body);
    curl_easy_setopt(c, CURLOPT_WRITEDATA, &b);
    curl_easy_setopt(c, CURLOPT_TIMEOUT, 10L);
    T_EQ_INT(curl_easy_perform(c), CURLE_OK);
    long status = 0;
    curl_easy_getinfo(c, CURLINFO_RESPONSE_CODE, &status);
    curl_slist_free_all(h);
    curl_easy_cleanup(c);
    T_EQ_INT(status, 413);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "over the limit") != NULL);
    buf_release(&b);
    stop();
}

T_CASE(api_path_traversal_in_file_names_is_refused)
{
    struct sf_err err;
    T_OK(start("traversal", &err), &err);
    struct buf b;
    buf_init(&b, 0);
    static const char *const bad[] = { "../../etc/passwd.stl",
                                       "..\\..\\boot.ini.stl",
                                       "/etc/x.stl",
                                       "a/../../b.stl",
                                       "..",
                                       "part.exe" };
    for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
        long st = call("POST", "/api/jobs", KEY_RW, NULL, bad[i], "x", 1, NULL, &b);
        if (st != 400) {
            t_fail(__FILE__, __LINE__, "'%s': status %ld, want 400 (%s)", bad[i], st,
                   b.data ? b.data : "");
            break;
        }
        T_TRUE(strstr(jstr(&b, NULL, "error"), "file name") != NULL);
    }
    /* no file of theirs landed outside the data dir, and no job was added */
    T_EQ_INT(get("/api/jobs", KEY_RW, &b), 200);
    json_t *root = json_loads(b.data, 0, NULL);
    T_EQ_INT(json_array_size(json_object_get(root, "jobs")), 1);
    json_decref(root);
    buf_release(&b);
    stop();
}

T_CASE(api_cancel_and_printer_actions)
{
    struct sf_err err;
    T_OK(start("actions", &err), &err);
    struct buf b;
    buf_init(&b, 0);
    T_EQ_INT(get("/api/printers/a", KEY_RW, &b), 200);
    T_EQ_STR(jstr(&b, "printer", "state"), "printing");
    T_EQ_STR(jstr(&b, "printer", "job_id"), "1");
    T_EQ_INT(get("/api/printers/zz", KEY_RW, &b), 404);
    T_EQ_INT(call("POST", "/api/printers/b/pause", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 409);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "cannot pause a printer that is idle") != NULL);
    T_EQ_INT(call("POST", "/api/printers/a/explode", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 404);
    T_EQ_INT(call("POST", "/api/printers/a/pause", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 200);
    T_EQ_STR(jstr(&b, "printer", "state"), "paused");
    T_EQ_INT(get("/api/jobs/1", KEY_RW, &b), 200);
    T_EQ_STR(jstr(&b, "job", "state"), "paused");
    T_EQ_INT(call("POST", "/api/printers/a/resume", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 200);
    /* cancelling the job stops its printer, which then waits for the bed */
    T_EQ_INT(call("POST", "/api/jobs/1/cancel", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 200);
    T_EQ_STR(jstr(&b, "job", "state"), "cancelled");
    T_EQ_INT(get("/api/printers/a", KEY_RW, &b), 200);
    T_EQ_STR(jstr(&b, "printer", "state"), "awaiting-clear");
    T_EQ_INT(call("POST", "/api/jobs/1/cancel", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 409);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "cannot cancel a cancelled job") != NULL);
    T_EQ_INT(call("POST", "/api/printers/a/cleared", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 200);
    T_EQ_STR(jstr(&b, "printer", "state"), "idle");
    /* a queued job is cancelled in the store directly */
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "q.obj", "v 0 0 0", 7, NULL, &b), 201);
    T_EQ_INT(call("POST", "/api/jobs/2/cancel", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 200);
    T_EQ_STR(jstr(&b, "job", "state"), "cancelled");
    T_EQ_STR(jstr(&b, "job", "reason"), "cancelled by an operator");
    buf_release(&b);
    stop();
}

T_CASE(api_restart_interrupted_job)
{
    struct sf_err err;
    T_OK(start("restart", &err), &err);
    struct buf b;
    buf_init(&b, 0);
    T_EQ_INT(call("POST", "/api/jobs/1/restart", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 409);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "cannot restart a printing job") != NULL);
    /* the daemon dies while job 1 prints; on restart it is interrupted */
    char dir[512];
    snprintf(dir, sizeof(dir), "%s/restart", t_tmpdir());
    stop();
    struct store_recovery rec;
    srv.farm.store = store_open(dir, &rec, &err);
    T_TRUE(srv.farm.store != NULL);
    T_EQ_INT(rec.interrupted, 1);
    srv.farm.job[0] = 0;
    srv.farm.p[0].state = PRINTER_OFFLINE;
    T_OK(start_api(&err), &err);
    T_EQ_INT(get("/api/jobs/1", KEY_RW, &b), 200);
    T_EQ_STR(jstr(&b, "job", "state"), "interrupted");
    T_EQ_STR(jstr(&b, "job", "printer"), "a");
    T_EQ_STR(jstr(&b, "job", "gcode_lines"), "1"); /* the resume range's end */
    T_EQ_INT(call("POST", "/api/jobs/1/restart", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 200);
    T_EQ_STR(jstr(&b, "job", "state"), "ready");
    T_EQ_INT(call("POST", "/api/jobs/1/explode", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 404);
    T_EQ_INT(call("GET", "/api/jobs/1/restart", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 405);
    buf_release(&b);
    stop();
}

/* POST /api/jobs/ID/resume: an optional {"line": N}, checked; refusals are 409. */
T_CASE(api_resume_job_body_and_refusal)
{
    struct sf_err err;
    T_OK(start("resume", &err), &err);
    struct buf b;
    buf_init(&b, 0);
    T_EQ_INT(call("POST", "/api/jobs/1/resume", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 200);
    T_EQ_INT(resumed_id, 1);
    T_EQ_INT(resumed_line, -1); /* no body: the stored line */
    T_EQ_INT(
        call("POST", "/api/jobs/1/resume", KEY_RW, "{\"line\": 1234}", NULL, NULL, 0, NULL, &b),
        200);
    T_EQ_INT(resumed_line, 1234);
    T_EQ_INT(call("POST", "/api/jobs/1/resume", KEY_RW, "{\"line\": -3}", NULL, NULL, 0, NULL, &b),
             400);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "line: -3 is negative") != NULL);
    T_EQ_INT(
        call("POST", "/api/jobs/1/resume", KEY_RW, "{\"line\": \"x\"}", NULL, NULL, 0, NULL, &b),
        400);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "expected {\"line\": INTEGER}") != NULL);
    T_EQ_INT(call("POST", "/api/jobs/2/resume", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 409);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "only an interrupted job") != NULL);
    T_EQ_INT(call("POST", "/api/jobs/1/resume", KEY_RO, NULL, NULL, NULL, 0, NULL, &b), 403);
    buf_release(&b);
    stop();
}

/* SSE client: collect until `want` (and `want2`, if set) appear, then stop. */
struct sse_client {
    struct buf got;
    const char *want, *want2;
};

static size_t
on_sse(char *data, size_t size, size_t n, void *ud)
{
    struct sse_client *s = ud;
    buf_append(&s->got, data, size * n);
    bool all = strstr(s->got.data, s->want) && (!s->want2 || strstr(s->got.data, s->want2));
    return all ? 0 : size * n; /* 0 ends the transfer */
}

T_CASE(api_events_stream_backlog_and_live)
{
    struct sf_err err;
    T_OK(start("events", &err), &err);
    char url[128];
    snprintf(url, sizeof(url), "%s/api/events", srv.base);
    struct curl_slist *h = curl_slist_append(NULL, "X-Api-Key: " KEY_RO);
    /* backlog: from event 0, the seed job's history arrives at once */
    struct sse_client s = { .want = "event: job-start" };
    buf_init(&s.got, 0);
    struct curl_slist *h0 =
        curl_slist_append(curl_slist_append(NULL, "X-Api-Key: " KEY_RO), "Last-Event-ID: 0");
    CURL *c = curl_easy_init();
    curl_easy_setopt(c, CURLOPT_URL, url);
    curl_easy_setopt(c, CURLOPT_HTTPHEADER, h0);
    curl_easy_setopt(c, CURLOPT_WRITEFUNCTION, on_sse);
    curl_easy_setopt(c, CURLOPT_WRITEDATA, &s);
    curl_easy_setopt(c, CURLOPT_TIMEOUT, 5L);
    T_EQ_INT(curl_easy_perform(c), CURLE_WRITE_ERROR); /* we stopped it */
    curl_easy_cleanup(c);
    T_TRUE(strstr(s.got.data, "id: 1\nevent: job-add\ndata: {") != NULL);
    buf_release(&s.got);
    curl_slist_free_all(h0);

    /* live: a stream opened now sees progress snapshots, then a cancel */
    s.want = "event: job-cancel";
    s.want2 = "event: progress\ndata: [{\"printer\":\"a\",\"job_id\":1,\"state\":\"printing\"";
    buf_init(&s.got, 0);
    CURLM *m = curl_multi_init();
    c = curl_easy_init();
    curl_easy_setopt(c, CURLOPT_URL, url);
    curl_easy_setopt(c, CURLOPT_HTTPHEADER, h);
    curl_easy_setopt(c, CURLOPT_WRITEFUNCTION, on_sse);
    curl_easy_setopt(c, CURLOPT_WRITEDATA, &s);
    curl_multi_add_handle(m, c);
    int running = 1;
    bool cancelled = false;
    struct timespec t0, t;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    struct buf b;
    buf_init(&b, 0);
    while (running) {
        curl_multi_perform(m, &running);
        curl_multi_poll(m, NULL, 0, 20, NULL);
        clock_gettime(CLOCK_MONOTONIC, &t);
        double ms = (t.tv_sec - t0.tv_sec) * 1e3 + (t.tv_nsec - t0.tv_nsec) / 1e6;
        if (!cancelled && s.got.data && strstr(s.got.data, "event: progress")) {
            T_EQ_INT(call("POST", "/api/jobs/1/cancel", KEY_RW, NULL, NULL, NULL, 0, NULL, &b),
                     200);
            cancelled = true;
        }
        if (ms > 5000)
            break;
    }
    curl_multi_remove_handle(m, c);
    curl_easy_cleanup(c);
    curl_multi_cleanup(m);
    curl_slist_free_all(h);
    buf_release(&b);
    T_TRUE(s.got.data && strstr(s.got.data, "event: job-cancel\ndata: {") != NULL);
    /* only live events: the backlog was not replayed */
    T_TRUE(strstr(s.got.data, "event: job-add") == NULL);
    buf_release(&s.got);
    stop();
}

/* ---- hardening (issue 16): a server whose loop thread runs test code too ---- */

#include <arpa/inet.h>
#include <dirent.h>
#include <fcntl.h>
#include <ftw.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include "../../src/base/mem.h"

/* A function to run on the server thread (the API is loop-thread only). */
static struct {
    pthread_mutex_t mu;
    pthread_cond_t cv;
    void (*fn)(void *arg);
    void *arg;
    bool done;
} oncall = { PTHREAD_MUTEX_INITIALIZER, PTHREAD_COND_INITIALIZER, NULL, NULL, false };

static void *
serve_calls(void *arg)
{
    (void)arg;
    struct http *h = api_http(srv.api);
    struct pollfd pfd = { .fd = http_fd(h), .events = POLLIN };
    for (unsigned turn = 0; !atomic_load(&srv.stop); turn++) {
        if (turn % 10 == 9)
            api_tick(srv.api);
        int64_t t = http_timeout_ms(h);
        poll(&pfd, 1, t < 0 || t > 10 ? 10 : (int)t);
        http_run(h);
        pthread_mutex_lock(&oncall.mu);
        if (oncall.fn) {
            oncall.fn(oncall.arg);
            oncall.fn = NULL;
            oncall.done = true;
            pthread_cond_broadcast(&oncall.cv);
        }
        pthread_mutex_unlock(&oncall.mu);
    }
    return NULL;
}

/* Run fn(arg) on the server thread and wait for it. */
static void
on_server(void (*fn)(void *), void *arg)
{
    pthread_mutex_lock(&oncall.mu);
    oncall.fn = fn;
    oncall.arg = arg;
    oncall.done = false;
    while (!oncall.done)
        pthread_cond_wait(&oncall.cv, &oncall.mu);
    pthread_mutex_unlock(&oncall.mu);
}

/* start() with the seed job, but served by serve_calls and, if non-zero, a
   header deadline of header_ms. */
static int
start_calls(const char *name, unsigned header_ms, struct sf_err *err)
{
    int rc = start(name, err);
    if (rc)
        return rc;
    /* replace the server start() made with one configured here */
    atomic_store(&srv.stop, true);
    pthread_join(srv.thread, NULL);
    api_free(srv.api);
    atomic_store(&srv.stop, false);
    struct farmcfg_key keys[2] = { { KEY_RW, false }, { KEY_RO, true } };
    struct api_config cfg = { .store = srv.farm.store,
                              .printers = &reg_ops,
                              .printers_ud = &srv.farm,
                              .host = "127.0.0.1",
                              .port = 0,
                              .keys = keys,
                              .n_keys = 2,
                              .upload_max = UPLOAD_MAX,
                              .header_timeout_ms = header_ms };
    srv.api = api_new(&cfg, err);
    if (!srv.api)
        return err->code;
    snprintf(srv.base, sizeof(srv.base), "http://127.0.0.1:%d", http_port(api_http(srv.api)));
    pthread_create(&srv.thread, NULL, serve_calls, NULL);
    return SF_OK;
}

/* Files (stored, temporary) under the store's files/ dir. */
static int n_files_seen;

static int
count_one(const char *path, const struct stat *st, int flag, struct FTW *ftw)
{
    (void)path, (void)st, (void)ftw;
    n_files_seen += flag == FTW_F;
    return 0;
}

static int
store_files(const char *name)
{
    char dir[512];
    snprintf(dir, sizeof(dir), "%s/%s/files", t_tmpdir(), name);
    n_files_seen = 0;
    nftw(dir, count_one, 16, FTW_PHYS);
    return n_files_seen;
}

static int
n_jobs(void)
{
    struct buf b;
    buf_init(&b, 0);
    int n = -1;
    if (get("/api/jobs", KEY_RW, &b) == 200) {
        json_t *root = json_loads(b.data, 0, NULL);
        n = (int)json_array_size(json_object_get(root, "jobs"));
        json_decref(root);
    }
    buf_release(&b);
    return n;
}

static int
srv_port(void)
{
    return http_port(api_http(srv.api));
}

/* A socket connected to the server from local address `from` (127.x.y.z; NULL: any). */
static int
connect_from(const char *from)
{
    int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0)
        return -1;
    if (from) {
        struct sockaddr_in me = { .sin_family = AF_INET };
        inet_pton(AF_INET, from, &me.sin_addr);
        if (bind(fd, (struct sockaddr *)&me, sizeof(me)) != 0) {
            close(fd);
            return -1;
        }
    }
    struct sockaddr_in sa = { .sin_family = AF_INET, .sin_port = htons((uint16_t)srv_port()) };
    inet_pton(AF_INET, "127.0.0.1", &sa.sin_addr);
    if (connect(fd, (struct sockaddr *)&sa, sizeof(sa)) != 0) {
        close(fd);
        return -1;
    }
    return fd;
}

/* Send a raw request and read the answer until the server closes or 10 s
   pass; returns the status (0: none) and the reply in out. */
static long
raw(const char *req, size_t len, struct buf *out)
{
    buf_reset(out);
    int fd = connect_from(NULL);
    if (fd < 0)
        return 0;
    for (size_t off = 0; off < len;) {
        ssize_t w = send(fd, req + off, len - off, MSG_NOSIGNAL);
        if (w <= 0)
            break;
        off += (size_t)w;
    }
    struct pollfd p = { .fd = fd, .events = POLLIN };
    char chunk[4096];
    while (poll(&p, 1, 10000) == 1) {
        ssize_t r = recv(fd, chunk, sizeof(chunk), 0);
        if (r <= 0)
            break;
        buf_append(out, chunk, (size_t)r);
        const char *end = strstr(out->data, "\r\n\r\n");
        const char *cl = strcasestr(out->data, "content-length: ");
        if (end && cl && cl < end &&
            out->len >= (size_t)(end + 4 - out->data) + strtoul(cl + 16, NULL, 10))
            break; /* the whole reply */
    }
    close(fd);
    long status = 0;
    if (out->data && strncmp(out->data, "HTTP/1.1 ", 9) == 0)
        status = strtol(out->data + 9, NULL, 10);
    return status;
}

/* The JSON body of a raw reply's "error", or "(none)". */
static const char *
raw_error(struct buf *b)
{
    const char *body = b->data ? strstr(b->data, "\r\n\r\n") : NULL;
    static char val[512];
    snprintf(val, sizeof(val), "(none)");
    json_t *root = body ? json_loads(body + 4, 0, NULL) : NULL;
    if (json_is_string(json_object_get(root, "error")))
        snprintf(val, sizeof(val), "%s", json_string_value(json_object_get(root, "error")));
    json_decref(root);
    return val;
}

/* Item 5: authorisation (key, method, route) comes before the body. */
T_CASE(api_read_only_key_multipart_stores_nothing)
{
    struct sf_err err;
    T_OK(start("robody", &err), &err);
    struct buf b;
    buf_init(&b, 0);
    int before = store_files("robody");
    static char part[32 << 10];
    memset(part, 'x', sizeof(part));
    T_EQ_INT(call("GET", "/api/jobs", KEY_RO, NULL, "big.stl", part, sizeof(part), NULL, &b), 403);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "read-only API key") != NULL);
    T_EQ_INT(call("GET", "/api/nothing", KEY_RO, NULL, "big.stl", part, sizeof(part), NULL, &b),
             403);
    /* a read-write key's upload goes only where a route takes one */
    T_EQ_INT(call("GET", "/api/jobs", KEY_RW, NULL, "big.stl", part, sizeof(part), NULL, &b), 400);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "takes no multipart") != NULL);
    T_EQ_INT(
        call("POST", "/api/jobs/1/cancel", KEY_RW, NULL, "big.stl", part, sizeof(part), NULL, &b),
        400);
    T_EQ_INT(call("PATCH", "/api/jobs/1", KEY_RW, NULL, "big.stl", part, sizeof(part), NULL, &b),
             400);
    T_EQ_INT(store_files("robody"), before);
    T_EQ_INT(n_jobs(), 1);
    T_EQ_INT(get("/api/jobs/1", KEY_RW, &b), 200);
    T_EQ_STR(jstr(&b, "job", "state"), "printing"); /* the cancel never ran */
    buf_release(&b);
    stop();
}

/* A multipart body for POST /api/jobs: the file, then `tail` (closing
   boundary or not). */
static size_t
multipart(char *out, size_t cap, const char *file, const char *tail)
{
    char body[4096];
    int n = snprintf(body, sizeof(body),
                     "--XyZ\r\nContent-Disposition: form-data; name=\"file\"; "
                     "filename=\"two.obj\"\r\nContent-Type: application/octet-stream\r\n\r\n"
                     "%s%s",
                     file, tail);
    return (size_t)snprintf(out, cap,
                            "POST /api/jobs HTTP/1.1\r\nHost: x\r\nX-Api-Key: " KEY_RW
                            "\r\nContent-Type: multipart/form-data; boundary=XyZ\r\n"
                            "Content-Length: %d\r\nConnection: close\r\n\r\n%s",
                            n, body);
}

/* Item 8: a body without its closing boundary is refused, nothing stored. */
T_CASE(api_truncated_multipart_is_400)
{
    struct sf_err err;
    T_OK(start("trunc", &err), &err);
    struct buf b;
    buf_init(&b, 0);
    int before = store_files("trunc");
    const char *cube = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
    char req[8192];
    size_t n = multipart(req, sizeof(req), cube, "");
    T_EQ_INT(raw(req, n, &b), 400);
    T_TRUE(strstr(raw_error(&b), "incomplete") != NULL);
    n = multipart(req, sizeof(req), cube, "\r\n--XyZ\r\nContent-Disposition: form-da");
    T_EQ_INT(raw(req, n, &b), 400);
    T_EQ_INT(store_files("trunc"), before);
    T_EQ_INT(n_jobs(), 1);
    /* the same body with its closing boundary is taken */
    n = multipart(req, sizeof(req), cube, "\r\n--XyZ--\r\n");
    T_EQ_INT(raw(req, n, &b), 201);
    T_EQ_INT(n_jobs(), 2);
    buf_release(&b);
    stop();
}

/* Item 10: a refused submission leaves no file and no row; temporaries of
   a killed daemon are removed when the store opens. */
T_CASE(api_refused_options_leave_no_file)
{
    struct sf_err err;
    T_OK(start("refused", &err), &err);
    struct buf b;
    buf_init(&b, 0);
    int before = store_files("refused");
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "a.stl", "solid a", 7, "{\"copies\": 0}", &b),
             400);
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "a.stl", "solid b", 7, "{\"copies\": 2,", &b),
             400);
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "a.stl", "solid c", 7,
                  "{\"material\": \"no such!\"}", &b),
             400);
    T_EQ_INT(store_files("refused"), before);
    T_EQ_INT(n_jobs(), 1);
    stop();
    /* a temporary left by a kill -9 mid-upload */
    char tmp[600];
    snprintf(tmp, sizeof(tmp), "%s/refused/files/tmp-AbC123", t_tmpdir());
    int fd = open(tmp, O_CREAT | O_WRONLY, 0644);
    T_TRUE(fd >= 0);
    T_TRUE(write(fd, "half a part", 11) == 11);
    close(fd);
    T_EQ_INT(store_files("refused"), before + 1);
    char dir[600];
    snprintf(dir, sizeof(dir), "%s/refused", t_tmpdir());
    struct store *s = store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    store_close(s);
    T_EQ_INT(store_files("refused"), before);
    T_TRUE(access(tmp, F_OK) != 0);
    buf_release(&b);
}

/* Item 11: echoed client text never breaks the JSON of an error. */
T_CASE(api_invalid_utf8_in_echoed_text)
{
    struct sf_err err;
    T_OK(start("utf8", &err), &err);
    struct buf b;
    buf_init(&b, 0);
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "bad\xff\xfe name.stl", "x", 1, NULL, &b),
             400);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "is not a plain file name") != NULL);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "\xef\xbf\xbd") != NULL); /* U+FFFD */
    /* 2-byte characters across the 80-byte cut of the message */
    char name[200] = "a";
    for (int i = 0; i < 60; i++)
        memcpy(name + 1 + 2 * i, "\xc3\xa9", 2);
    memcpy(name + 121, ".txt", 5);
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, name, "x", 1, NULL, &b), 400);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "does not end in .stl") != NULL);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "\xef\xbf\xbd") == NULL); /* cut between characters */
    /* a URL path with invalid UTF-8, echoed by the 404 */
    T_EQ_INT(get("/api/%FF%FEx", KEY_RW, &b), 404);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "no such resource") != NULL);
    char path[400] = "/api/";
    for (int i = 0; i < 60; i++)
        memcpy(path + 5 + 6 * i, "%C3%A9", 7);
    T_EQ_INT(get(path, KEY_RW, &b), 404);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "no such resource") != NULL);
    buf_release(&b);
    stop();
}

/* Item 12: a Last-Event-ID above the newest event (another log) replays this one. */
T_CASE(api_events_last_id_above_newest_replays)
{
    struct sf_err err;
    T_OK(start("evreset", &err), &err);
    char url[128];
    snprintf(url, sizeof(url), "%s/api/events", srv.base);
    struct curl_slist *h =
        curl_slist_append(curl_slist_append(NULL, "X-Api-Key: " KEY_RO), "Last-Event-ID: 999999");
    struct sse_client s = { .want = "event: job-start" };
    buf_init(&s.got, 0);
    CURL *c = curl_easy_init();
    curl_easy_setopt(c, CURLOPT_URL, url);
    curl_easy_setopt(c, CURLOPT_HTTPHEADER, h);
    curl_easy_setopt(c, CURLOPT_WRITEFUNCTION, on_sse);
    curl_easy_setopt(c, CURLOPT_WRITEDATA, &s);
    curl_easy_setopt(c, CURLOPT_TIMEOUT, 5L);
    curl_easy_perform(c);
    curl_easy_cleanup(c);
    curl_slist_free_all(h);
    T_TRUE(s.got.data != NULL);
    T_TRUE(strstr(s.got.data, "event: reset\ndata: {") != NULL);
    T_TRUE(strstr(s.got.data, "id: 1\nevent: job-add\ndata: {") != NULL);
    buf_release(&s.got);
    stop();
}

/* Item 13: reload applies upload_max and closes the streams of revoked keys. */
static void
reload_keys_rw_only(void *arg)
{
    (void)arg;
    struct farmcfg next;
    farmcfg_init(&next);
    next.keys = mem_calloc(1, sizeof(*next.keys));
    snprintf(next.keys[0].key, sizeof(next.keys[0].key), "%s", KEY_RW);
    next.n_keys = 1;
    next.upload_max_bytes = 1024;
    struct sf_err err;
    api_reload(srv.api, NULL, &next, &err);
    farmcfg_release(&next);
}

T_CASE(api_reload_applies_upload_max_and_revokes_streams)
{
    struct sf_err err;
    T_OK(start_calls("reload", 0, &err), &err);
    struct buf b;
    buf_init(&b, 0);
    char url[128];
    snprintf(url, sizeof(url), "%s/api/events", srv.base);
    struct curl_slist *h =
        curl_slist_append(curl_slist_append(NULL, "X-Api-Key: " KEY_RO), "Last-Event-ID: 0");
    struct sse_client s = { .want = "never sent" };
    buf_init(&s.got, 0);
    CURLM *m = curl_multi_init();
    CURL *c = curl_easy_init();
    curl_easy_setopt(c, CURLOPT_URL, url);
    curl_easy_setopt(c, CURLOPT_HTTPHEADER, h);
    curl_easy_setopt(c, CURLOPT_WRITEFUNCTION, on_sse);
    curl_easy_setopt(c, CURLOPT_WRITEDATA, &s);
    curl_easy_setopt(c, CURLOPT_TIMEOUT, 20L);
    curl_multi_add_handle(m, c);
    int running = 1;
    bool reloaded = false;
    while (running) {
        curl_multi_perform(m, &running);
        curl_multi_poll(m, NULL, 0, 20, NULL);
        if (!reloaded && s.got.data && strstr(s.got.data, "event: job-start")) {
            on_server(reload_keys_rw_only, NULL); /* the stream has its backlog: revoke */
            reloaded = true;
        }
    }
    CURLMsg *msg;
    int left;
    CURLcode done = CURLE_RECV_ERROR; /* unless curl reports */
    while ((msg = curl_multi_info_read(m, &left)))
        if (msg->msg == CURLMSG_DONE)
            done = msg->data.result;
    curl_multi_remove_handle(m, c);
    curl_easy_cleanup(c);
    curl_multi_cleanup(m);
    curl_slist_free_all(h);
    buf_release(&s.got);
    T_TRUE(reloaded);
    T_EQ_INT(done, CURLE_OK); /* the server ended it, well before the 20 s timeout */
    T_EQ_INT(get("/api/jobs", KEY_RO, &b), 401);
    static char part[4096];
    memset(part, 'x', sizeof(part));
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "big.stl", part, sizeof(part), NULL, &b), 413);
    buf_release(&b);
    stop();
}

/* Minor: %00 in a URL, conflicting Content-Length, an empty file part. */
T_CASE(api_nul_in_url_double_length_empty_file)
{
    struct sf_err err;
    T_OK(start("minor", &err), &err);
    struct buf b;
    buf_init(&b, 0);
    const char nul[] = "GET /api/jobs%00/1 HTTP/1.1\r\nHost: x\r\nX-Api-Key: " KEY_RW "\r\n\r\n";
    T_EQ_INT(raw(nul, sizeof(nul) - 1, &b), 400);
    T_TRUE(strstr(raw_error(&b), "%00") != NULL);
    const char twocl[] = "PATCH /api/jobs/1 HTTP/1.1\r\nHost: x\r\nX-Api-Key: " KEY_RW
                         "\r\nContent-Type: application/json\r\nContent-Length: 15\r\n"
                         "Content-Length: 16\r\n\r\n{\"priority\": 3}";
    T_EQ_INT(raw(twocl, sizeof(twocl) - 1, &b), 400);
    T_TRUE(strstr(raw_error(&b), "Content-Length") != NULL);
    int before = store_files("minor");
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "empty.stl", "", 0, NULL, &b), 400);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "'empty.stl' is empty") != NULL);
    T_EQ_INT(store_files("minor"), before);
    T_EQ_INT(n_jobs(), 1);
    buf_release(&b);
    stop();
}

/* Item 6: 300 clients with no key that never finish their request head
   (from ten loopback addresses, 30 each) do not keep an authenticated
   client out.  Asserts that its requests are answered, not how fast. */
T_CASE(api_slow_clients_do_not_lock_out_a_key)
{
    struct sf_err err;
    T_OK(start("slow", &err), &err);
    enum { N_SLOW = 300 };
    int fds[N_SLOW];
    int n = 0;
    for (int i = 0; i < N_SLOW; i++) {
        char from[32];
        snprintf(from, sizeof(from), "127.0.0.%d", 2 + i % 10);
        int fd = connect_from(from);
        if (fd < 0)
            break;
        const char head[] = "GET /api/jobs HTTP/1.1\r\nHost: x\r\n";
        if (send(fd, head, sizeof(head) - 1, MSG_NOSIGNAL) < 0) {
            close(fd);
            break;
        }
        fds[n++] = fd;
    }
    T_EQ_INT(n, N_SLOW);
    /* one more header line each: they are not idle */
    for (int i = 0; i < n; i++)
        send(fds[i], "X-Slow: 1\r\n", 11, MSG_NOSIGNAL);
    struct buf b;
    buf_init(&b, 0);
    int answered = 0;
    for (int i = 0; i < 5; i++)
        answered += get("/api/jobs", KEY_RW, &b) == 200; /* curl's 10 s timeout each */
    for (int i = 0; i < n; i++)
        close(fds[i]);
    buf_release(&b);
    T_EQ_INT(answered, 5);
    stop();
}

/* Item 6: a client trickling header lines is cut at the header deadline
   (it never goes idle, so the idle timeout alone would keep it). */
T_CASE(api_header_deadline_closes_a_trickling_client)
{
    struct sf_err err;
    T_OK(start_calls("trickle", 300, &err), &err);
    int fd = connect_from(NULL);
    T_TRUE(fd >= 0);
    send(fd, "GET /api/jobs HTTP/1.1\r\n", 24, MSG_NOSIGNAL);
    bool closed = false;
    /* up to 30 s of a line every 100 ms; the deadline is 0.3 s */
    for (int i = 0; i < 300 && !closed; i++) {
        struct pollfd p = { .fd = fd, .events = POLLIN };
        if (poll(&p, 1, 100) == 1) {
            char c[256];
            closed = recv(fd, c, sizeof(c), 0) <= 0;
        }
        if (!closed && send(fd, "X-Slow: 1\r\n", 11, MSG_NOSIGNAL) < 0)
            closed = true;
    }
    close(fd);
    T_TRUE(closed);
    struct buf b;
    buf_init(&b, 0);
    T_EQ_INT(get("/api/jobs", KEY_RW, &b), 200);
    buf_release(&b);
    stop();
}

/* Found by fuzz_http: a multipart part without a name reached strcmp(NULL). */
T_CASE(api_multipart_part_without_name_is_400)
{
    struct sf_err err;
    T_OK(start("noname", &err), &err);
    struct buf b;
    buf_init(&b, 0);
    const char body[] = "--XyZ\r\nContent-Disposition: form-data; filename=\"a.stl\"\r\n\r\n"
                        "solid a\r\n--XyZ--\r\n";
    char req[1024];
    int n = snprintf(req, sizeof(req),
                     "POST /api/jobs HTTP/1.1\r\nHost: x\r\nX-Api-Key: " KEY_RW
                     "\r\nContent-Type: multipart/form-data; boundary=XyZ\r\n"
                     "Content-Length: %zu\r\n\r\n%s",
                     sizeof(body) - 1, body);
    T_EQ_INT(raw(req, (size_t)n, &b), 400);
    T_TRUE(strstr(raw_error(&b), "has no name") != NULL);
    T_EQ_INT(n_jobs(), 1);
    buf_release(&b);
    stop();
}
