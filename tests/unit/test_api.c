/*
 * test_api.c - the REST API over real HTTP on loopback (libcurl client,
 * libmicrohttpd server on a thread of its own standing in for the loop),
 * with a real store in a scratch dir and a real farm whose two printers
 * run a small in-test driver.
 *
 * Keys (401/403), submission (multipart + options), malformed JSON (400),
 * oversized bodies (413), path traversal in file names, cancel, priority,
 * printer actions and the bed-clear gate, and Server-Sent Events (backlog
 * and live).
 */
#include <arpa/inet.h>
#include <curl/curl.h>
#include <dirent.h>
#include <fcntl.h>
#include <ftw.h>
#include <netinet/in.h>
#include <poll.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "../../src/api/api.h"
#include "../../src/base/buf.h"
#include "../../src/base/log.h"
#include "../../src/base/mem.h"
#include "../../src/base/ws.h"
#include "../../src/farm/farm.h"
#include "../../src/farm/sqldb.h"
#include "../../src/farm/store.h"
#include "../../src/farm/store_host.h"
#include "../../src/farm/store_int.h" /* store_log_event: an event without a job */
#include "../t.h"
#include "../tstore.h"

#define KEY_RW     "rw-key-0123456789abcdef"
#define KEY_RO     "ro-key-0123456789abcdef"
#define UPLOAD_MAX (64 << 10)

/*
 * The farm behind the API: two printers, "a" and "b", driven by a small
 * in-test driver that goes where it is told at once (the farm's own rules
 * are test_farm's), and a prepare hook writing a real G-code file of
 * GCODE_LINES commands.
 */
#define GCODE_LINES 2000

/* Test switches, set on the server thread: the driver says "not now" to a
   pause, as Moonraker's and PrusaLink's do while their upload runs; printer
   b's link is gone (it stays offline across reconnects). */
static atomic_bool adrv_busy, adrv_unplugged;
/* Jobs the in-test driver was given: the store says PRINTING before the farm's start check
   (on its io thread) hands the job to the driver. */
static atomic_int adrv_starts;
static struct drv *adrv_b; /* printer b's driver */

static int
adrv_open(struct drv *d, struct sf_err *err)
{
    if (d == adrv_b && atomic_load(&adrv_unplugged))
        return sf_err_set(err, SF_EIO, "adrv: no answer");
    d->status.state = DRV_IDLE;
    d->status.nozzle_c = d->status.nozzle_target_c = 215;
    d->on_event(d, DRV_EV_STATE, d->ud);
    return SF_OK;
}

static int
adrv_start(struct drv *d, const char *path, uint64_t first_line, const struct drv_job_scan *scan,
           struct sf_err *err)
{
    (void)path, (void)scan, (void)err;
    atomic_fetch_add(&adrv_starts, 1);
    d->status.state = DRV_PRINTING;
    d->status.lines_acked = first_line;
    d->on_event(d, DRV_EV_STATE, d->ud);
    return SF_OK;
}

static int
adrv_set(struct drv *d, enum drv_state st)
{
    d->status.state = st;
    d->on_event(d, DRV_EV_STATE, d->ud);
    return SF_OK;
}

static int
adrv_pause(struct drv *d, struct sf_err *err)
{
    if (atomic_load(&adrv_busy))
        return sf_err_set(err, SF_EAGAIN, "printer '%s': nothing to pause", d->name);
    return adrv_set(d, DRV_PAUSED);
}

static int
adrv_resume(struct drv *d, struct sf_err *err)
{
    (void)err;
    return adrv_set(d, DRV_PRINTING);
}

static int
adrv_cancel(struct drv *d, struct sf_err *err)
{
    (void)err;
    return adrv_set(d, DRV_IDLE);
}

static int
adrv_command(struct drv *d, const char *line, struct sf_err *err)
{
    (void)d, (void)line;
    return sf_err_set(err, SF_EUNSUPP, "adrv: no console");
}

static void
adrv_close(struct drv *d)
{
    (void)d;
}

static void
adrv_destroy(struct drv *d)
{
    free(d);
}

static const struct drv_ops adrv_ops = { DRV_OPS_VERSION, "adrv",       adrv_open,   adrv_start,
                                         adrv_pause,      adrv_resume,  adrv_cancel, adrv_command,
                                         adrv_close,      adrv_destroy, NULL,        NULL };

static struct drv *
adrv_new(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event, void *ud,
         struct sf_err *err)
{
    struct drv *d = calloc(1, sizeof(*d));
    if (!d) {
        sf_err_set(err, SF_ENOMEM, "adrv: out of memory");
        return NULL;
    }
    *d = (struct drv){ .ops = &adrv_ops, .loop = l, .on_event = on_event, .ud = ud };
    snprintf(d->name, sizeof(d->name), "%s", cfg->name);
    if (strcmp(cfg->name, "b") == 0)
        adrv_b = d;
    return d;
}

static int
api_prepare(const struct prepare_req *req, struct prepare_out *out, const atomic_bool *cancel,
            struct sf_err *err)
{
    (void)cancel;
    FILE *f = fopen(req->out_path, "w");
    if (!f)
        return sf_err_sys(err, "cannot write '%s'", req->out_path);
    fputs("G28\n", f);
    for (int i = 1; i < GCODE_LINES; i++)
        fputs("G1 X1\n", f);
    fclose(f);
    out->size_mm[0] = out->size_mm[1] = out->size_mm[2] = 10;
    out->nozzle_mm = req->printer.nozzle_mm;
    return SF_OK;
}

static const char farm_ini[] = "[printer a]\ndriver: marlin\nport: x\n"
                               "[printer b]\ndriver: marlin\nport: x\ngcode_models: *\n";

/* The server side: the farm and the api on a thread of their own (the loop's). */
static struct {
    struct farmcfg cfg;
    struct store *store;
    struct loop *l;
    struct pool *pool;
    struct farm *farm;
    struct api *api;
    pthread_t thread;
    atomic_bool stop;
    char base[64];
} srv;

/* A function to run on the server thread (the API is loop-thread only). */
static struct {
    pthread_mutex_t mu;
    pthread_cond_t cv;
    void (*fn)(void *arg);
    void *arg;
    bool done;
} oncall = { PTHREAD_MUTEX_INITIALIZER, PTHREAD_COND_INITIALIZER, NULL, NULL, false };

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
        poll(&pfd, 1, t < 0 || t > 5 ? 5 : (int)t);
        http_run(h);
        loop_run_once(srv.l, 0); /* the farm: its timers, printers, prepares */
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

static void stop(void);

/* Open the store in scratch dir name and build the farm on it (this thread, for now). */
static int
open_farm(const char *name, struct sf_err *err)
{
    char dir[512];
    snprintf(dir, sizeof(dir), "%s/%s", t_tmpdir(), name);
    farmcfg_init(&srv.cfg);
    struct farm_hooks hooks = { .driver = adrv_new, .prepare = api_prepare, .progress_ms = 50 };
    if (farmcfg_parse(&srv.cfg, farm_ini, strlen(farm_ini), "api.ini", err) ||
        !(srv.store = t_store_open(dir, NULL, err)) || !(srv.l = loop_new(err)) ||
        !(srv.pool = pool_new(srv.l, 1, err)) ||
        !(srv.farm = farm_new(srv.l, srv.store, srv.pool, &srv.cfg, &hooks, err)))
        return err->code ? err->code : SF_EIO;
    /* both printers connect on the first turns */
    for (int i = 0; i < 100; i++) {
        struct printer_info a, b;
        farm_printer_info(srv.farm, 0, &a);
        farm_printer_info(srv.farm, 1, &b);
        if (a.state != PRINTER_OFFLINE && b.state != PRINTER_OFFLINE)
            return SF_OK;
        loop_run_once(srv.l, 10);
    }
    return sf_err_set(err, SF_ETIMEDOUT, "the test printers did not connect");
}

/* Turn the farm's loop (before the server thread runs it) until job id is in state. */
static bool
wait_state(int64_t id, enum job_state state)
{
    struct job_row j;
    for (int i = 0; i < 3000; i++) {
        if (store_job_get(srv.store, id, &j, NULL) == SF_OK && j.state == state)
            return true;
        loop_run_once(srv.l, 10);
    }
    return false;
}

static int start_api(unsigned header_ms, struct sf_err *err);

/* A store with one job printing on printer "a", the farm and the API. */
static int
start(const char *name, struct sf_err *err)
{
    if (srv.api)
        stop(); /* a failed case returned early: its server must not run on */
    memset(&srv, 0, sizeof(srv));
    log_set_level(LOG_WARN);
    int rc = open_farm(name, err);
    if (rc)
        return rc;
    char sha[STORE_SHA_HEX];
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "seed.stl");
    int64_t id;
    if ((rc = store_file_put(srv.store, "solid x", 7, sha, err)) ||
        (rc = store_job_add(srv.store, &o, sha, &id, err)))
        return rc;
    int starts = atomic_load(&adrv_starts);
    farm_kick(srv.farm);
    if (!wait_state(id, JOB_PRINTING))
        return sf_err_set(err, SF_ETIMEDOUT, "job %lld never printed", (long long)id);
    /* the printer acts on it only once its driver has it (a pause before is "starting") */
    for (int i = 0; i < 3000 && atomic_load(&adrv_starts) == starts; i++)
        loop_run_once(srv.l, 10);
    if (atomic_load(&adrv_starts) == starts)
        return sf_err_set(err, SF_ETIMEDOUT, "job %lld never reached the driver", (long long)id);
    return start_api(0, err);
}

/* Start the API over srv's store and farm, on the server thread; a
   header deadline of header_ms if non-zero. */
static int
start_api(unsigned header_ms, struct sf_err *err)
{
    atomic_store(&srv.stop, false);
    struct farmcfg_key keys[2] = { { KEY_RW, false, false }, { KEY_RO, true, false } };
    struct api_config cfg = { .store = srv.store,
                              .farm = srv.farm,
                              .host = "127.0.0.1",
                              .port = 0,
                              .keys = keys,
                              .n_keys = 2,
                              .upload_max = UPLOAD_MAX,
                              .header_timeout_ms = header_ms,
                              .loop = srv.l };
    srv.api = api_new(&cfg, err);
    if (!srv.api)
        return err->code;
    snprintf(srv.base, sizeof(srv.base), "http://127.0.0.1:%d", http_port(api_http(srv.api)));
    pthread_create(&srv.thread, NULL, serve, NULL);
    return SF_OK;
}

/* Stop the server thread and tear down as the daemon does. */
static void
stop(void)
{
    if (srv.api) {
        atomic_store(&srv.stop, true);
        pthread_join(srv.thread, NULL);
    }
    api_free(srv.api);
    if (srv.pool) {
        farm_drop_pool(srv.farm);
        pool_free(srv.pool);
        loop_run_once(srv.l, 0);
    }
    farm_free(srv.farm);
    store_close(srv.store);
    loop_free(srv.l);
    farmcfg_release(&srv.cfg);
    memset(&srv, 0, sizeof(srv));
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
    /* as the CLI does: wait for the server's early refusal before sending a body (curl asks
       only for bodies over 1 MiB; a smaller one raced the refusal and its connection close:
       "Failed sending data to the peer", 2 runs in 200 at load ~18) */
    if (part_name || body)
        h = curl_slist_append(h, "Expect: 100-continue");
    curl_easy_setopt(c, CURLOPT_EXPECT_100_TIMEOUT_MS, 10000L);
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

/* How many jobs GET /api/jobs lists; -1 if it does not answer 200. */
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
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "plain.3mf", "PK\3\4", 4, NULL, &b), 201);
    T_EQ_STR(jstr(&b, "job", "copies"), "1");
    T_EQ_STR(jstr(&b, "job", "method"), "orient");
    T_EQ_INT(n_jobs(), 3);
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

/* Job id's queue_pos from GET /api/jobs/ID. */
static long long
queue_pos(int id, struct buf *b)
{
    char path[64];
    snprintf(path, sizeof(path), "/api/jobs/%d", id);
    if (get(path, KEY_RW, b) != 200 || strcmp(jstr(b, "job", "priority"), "0") != 0)
        return -1; /* a move within one priority changes none */
    return atoll(jstr(b, "job", "queue_pos"));
}

/* ▲ on the third of three waiting jobs of equal priority moves it one
   place, to second (a priority change jumped it to first: issue 31). */
T_CASE(api_move_a_waiting_job_one_place)
{
    struct sf_err err;
    T_OK(start("move", &err), &err);
    struct buf b;
    buf_init(&b, 0);
    const char part[] = "solid cube\nendsolid cube\n";
    for (int i = 0; i < 3; i++) /* jobs 2, 3, 4: a group no printer is in, so they wait */
        T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "w.stl", part, sizeof(part) - 1,
                      "{\"group\": \"big\"}", &b),
                 201);
    T_TRUE(0 < queue_pos(2, &b) && queue_pos(2, &b) < queue_pos(3, &b) &&
           queue_pos(3, &b) < queue_pos(4, &b));
    T_EQ_INT(call("POST", "/api/jobs/4/move", KEY_RW, "{\"by\": -1}", NULL, NULL, 0, NULL, &b),
             200);
    T_EQ_STR(jstr(&b, "job", "id"), "4");
    T_TRUE(0 < queue_pos(2, &b) && queue_pos(2, &b) < queue_pos(4, &b) &&
           queue_pos(4, &b) < queue_pos(3, &b));
    /* and back down */
    T_EQ_INT(call("POST", "/api/jobs/4/move", KEY_RW, "{\"by\": 1}", NULL, NULL, 0, NULL, &b), 200);
    T_TRUE(0 < queue_pos(3, &b) && queue_pos(3, &b) < queue_pos(4, &b));
    /* refusals, each naming why */
    T_EQ_INT(call("POST", "/api/jobs/2/move", KEY_RW, "{\"by\": -1}", NULL, NULL, 0, NULL, &b),
             409);
    T_EQ_STR(jstr(&b, NULL, "error"), "job 2 is already first of the waiting jobs");
    T_EQ_INT(call("POST", "/api/jobs/1/move", KEY_RW, "{\"by\": 1}", NULL, NULL, 0, NULL, &b), 409);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "job 1 is printing: only a waiting job") != NULL);
    T_EQ_INT(call("POST", "/api/jobs/2/move", KEY_RW, "{\"by\": 2}", NULL, NULL, 0, NULL, &b), 400);
    T_EQ_STR(jstr(&b, NULL, "error"), "by: 2 is not in -1..1");
    T_EQ_INT(call("POST", "/api/jobs/2/move", KEY_RW, "{\"by\": 0}", NULL, NULL, 0, NULL, &b), 400);
    T_EQ_INT(call("POST", "/api/jobs/2/move", KEY_RW, "{\"up\": 1}", NULL, NULL, 0, NULL, &b), 400);
    T_EQ_INT(call("POST", "/api/jobs/99/move", KEY_RW, "{\"by\": 1}", NULL, NULL, 0, NULL, &b),
             404);
    T_EQ_INT(call("POST", "/api/jobs/3/move", KEY_RO, "{\"by\": 1}", NULL, NULL, 0, NULL, &b), 403);
    buf_release(&b);
    stop();
}

/* An upload is judged by its content before it is queued, the reason
   naming the file (issue 31: a text file renamed .stl was queued). */
T_CASE(api_upload_content_is_checked)
{
    struct sf_err err;
    T_OK(start("content", &err), &err);
    struct buf b;
    buf_init(&b, 0);
    int before = n_jobs();
    static const struct {
        const char *name, *data, *says;
    } bad[] = {
        { "notes.stl", "shopping list:\nmilk\n", "not an STL: 'notes.stl' holds plain text" },
        { "cube.stl", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
          "not an STL: 'cube.stl' is a Wavefront OBJ by its content: name it .obj" },
        { "print.stl", "; sliced\nG28\nG1 X10 E1\n", "not an STL: 'print.stl' is G-code" },
        { "cut.stl", "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\n",
          "not an STL: stl 'cut.stl': line " },
        { "part.obj", "hello\n", "not an OBJ: 'part.obj' holds plain text" },
        { "part.3mf", "solid t\nendsolid t\n", "not a 3MF: 'part.3mf' is an ASCII STL" },
    };
    for (size_t i = 0; i < sizeof(bad) / sizeof(*bad); i++) {
        T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, bad[i].name, bad[i].data,
                      strlen(bad[i].data), NULL, &b),
                 400);
        T_TRUE(strstr(jstr(&b, NULL, "error"), bad[i].says) != NULL);
    }
    /* a binary STL of one triangle (its header begins "solid", as many do) */
    unsigned char stl[134] = "solid binary";
    uint32_t one = 1;
    memcpy(stl + 80, &one, 4);
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "bin.stl", stl, sizeof(stl), NULL, &b), 201);
    /* G-code through OctoPrint's route: a mesh is refused there too */
    T_EQ_INT(call("POST", "/api/files/local", KEY_RW, NULL, "x.gcode", stl, sizeof(stl), NULL, &b),
             400);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "not G-code: 'x.gcode' is a binary STL") != NULL);
    T_EQ_INT(n_jobs(), before + 1); /* only the good one */
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
    T_EQ_INT(n_jobs(), 1);
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
    /* a name over the limit is refused as too long, saying the limit */
    char long_name[200];
    memset(long_name, 'a', sizeof(long_name));
    memcpy(long_name + sizeof(long_name) - 5, ".stl", 5);
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, long_name, "x", 1, NULL, &b), 400);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "is 199 bytes: at most 127 bytes") != NULL);
    /* no file of theirs landed outside the data dir, and no job was added */
    T_EQ_INT(n_jobs(), 1);
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
    /* the daemon stops while job 1 prints; on restart it is interrupted */
    stop();
    T_OK(open_farm("restart", &err), &err);
    T_OK(start_api(0, &err), &err);
    T_EQ_INT(get("/api/jobs/1", KEY_RW, &b), 200);
    T_EQ_STR(jstr(&b, "job", "state"), "interrupted");
    T_EQ_STR(jstr(&b, "job", "printer"), "a");
    T_EQ_STR(jstr(&b, "job", "gcode_lines"), "2000"); /* the resume range's end */
    T_EQ_INT(call("POST", "/api/jobs/1/restart", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 200);
    T_EQ_STR(jstr(&b, "job", "state"), "ready");
    T_EQ_INT(call("POST", "/api/jobs/1/explode", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 404);
    T_EQ_INT(call("GET", "/api/jobs/1/restart", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 405);
    buf_release(&b);
    stop();
}

/* On the server thread: printer b's link goes and does not come back. */
static void
unplug_b(void *arg)
{
    (void)arg;
    atomic_store(&adrv_unplugged, true);
    snprintf(adrv_b->status.message, sizeof(adrv_b->status.message), "no answer");
    adrv_set(adrv_b, DRV_OFFLINE);
}

static void on_server(void (*fn)(void *), void *arg);

/* A printer that cannot do it now answers 409, whoever says so (the farm or
   its driver: it was 500 when the driver said it); one the farm holds
   offline answers 503, for actions, commands and the cancel of its job. */
T_CASE(api_busy_printer_is_409_unreachable_is_503)
{
    struct sf_err err;
    T_OK(start("busy", &err), &err);
    struct buf b;
    buf_init(&b, 0);
    atomic_store(&adrv_busy, true);
    T_EQ_INT(call("POST", "/api/printers/a/pause", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 409);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "printer 'a': nothing to pause") != NULL);
    atomic_store(&adrv_busy, false);
    T_EQ_INT(call("POST", "/api/printers/a/command", KEY_RW, "{\"command\": \"G28\"}", NULL, NULL,
                  0, NULL, &b),
             409);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "manual commands wait") != NULL);
    on_server(unplug_b, NULL);
    T_EQ_INT(get("/api/printers/b", KEY_RW, &b), 200);
    T_EQ_STR(jstr(&b, "printer", "state"), "offline");
    T_EQ_INT(call("POST", "/api/printers/b/command", KEY_RW, "{\"command\": \"G28\"}", NULL, NULL,
                  0, NULL, &b),
             503);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "printer b is offline") != NULL);
    T_EQ_INT(call("POST", "/api/printers/b/pause", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 503);
    T_EQ_INT(call("POST", "/api/printers/b/cleared", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 503);
    /* a wrong method on a known path says which would do */
    T_EQ_INT(call("POST", "/api/printers/b", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 405);
    T_EQ_STR(jstr(&b, NULL, "error"), "method POST is not allowed on /api/printers/b");
    atomic_store(&adrv_unplugged, false);
    buf_release(&b);
    stop();
}

/* On the server thread: a printer note for the farm's store queue (it waits under a lock). */
static void
queue_note(void *arg)
{
    (void)arg;
    storeq_printer_note(farm_storeq(srv.farm), "b", "printer-command", "queued under a lock");
}

/* A manual command while the store's queue cannot be written (another process holds its
   write lock) is 503, the store busy: whether the printer holds an interrupted job is not
   known yet.  It was 409, "not now", as if the printer's state refused it. */
T_CASE(api_command_while_the_store_is_busy_is_503)
{
    struct sf_err err;
    T_OK(start("cmdbusy", &err), &err);
    char dir[600];
    snprintf(dir, sizeof(dir), "%s/cmdbusy", t_tmpdir());
    struct sqldb *other = t_store_lock(dir);
    T_TRUE(other != NULL);
    on_server(queue_note, NULL);
    struct buf b;
    buf_init(&b, 0);
    T_EQ_INT(call("POST", "/api/printers/b/command", KEY_RW, "{\"command\": \"G28\"}", NULL, NULL,
                  0, NULL, &b),
             503);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "the store is busy") != NULL);
    t_store_unlock(other);
    /* the queue written: the command reaches the driver, which has no console */
    T_EQ_INT(call("POST", "/api/printers/b/command", KEY_RW, "{\"command\": \"G28\"}", NULL, NULL,
                  0, NULL, &b),
             501);
    buf_release(&b);
    stop();
}

/* On the server thread: the store queue's retries so far. */
static void
read_retries(void *arg)
{
    struct farm_health h;
    farm_health(srv.farm, &h);
    *(uint64_t *)arg = h.store.retries;
}

/* A part whose adoption cannot reach the database (PostgreSQL: the upload's own connection
   refused "not now") answers 503 at once, saying so, and holds no write behind it: the
   queue does not retry it (it waited out its 60 s, every farm write queued behind it). */
T_CASE(api_submit_whose_part_cannot_be_stored_is_503_at_once)
{
    if (!t_store_pg()) {
        t_skip("the part's own database connection is PostgreSQL's");
        return;
    }
    struct sf_err err;
    T_OK(start("adoptfail", &err), &err);
    char dir[600];
    snprintf(dir, sizeof(dir), "%s/adoptfail", t_tmpdir());
    /* from the server's postgres database: not the one it closes */
    const char *url = t_store_db(dir), *auth = strstr(url, "://") + 3; /* AUTH/NAME?QUERY */
    const char *name = auth + strcspn(auth, "/?") + 1;
    int name_len = (int)strcspn(name, "?");
    struct sqldb *db = sqldb_open(getenv("SLIMFARM_TEST_STORE"), 0, &err);
    T_TRUE(db != NULL);
    char sql[200];
    snprintf(sql, sizeof(sql), "ALTER DATABASE %.*s ALLOW_CONNECTIONS false", name_len, name);
    T_TRUE(sqldb_exec(db, sql) == SF_OK || !printf("%s: %s\n", sql, sqldb_errmsg(db)));
    uint64_t before = 0, after = 0;
    on_server(read_retries, &before);
    struct buf b;
    buf_init(&b, 0);
    const char part[] = "solid cube\nendsolid cube\n";
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "held.stl", part, sizeof(part) - 1, NULL, &b),
             503);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "the part could not be stored") != NULL);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "cannot connect") != NULL);
    on_server(read_retries, &after);
    T_EQ_INT(after - before, 0); /* answered on its first run */
    snprintf(sql, sizeof(sql), "ALTER DATABASE %.*s ALLOW_CONNECTIONS true", name_len, name);
    T_OK(sqldb_exec(db, sql), NULL);
    sqldb_close(db);
    T_EQ_INT(call("POST", "/api/jobs", KEY_RW, NULL, "held.stl", part, sizeof(part) - 1, NULL, &b),
             201);
    buf_release(&b);
    stop();
}

/* On the server thread: the statements the loop's own connection has sent (PostgreSQL). */
static void
read_loop_trips(void *arg)
{
    *(uint64_t *)arg = store_round_trips(srv.store);
}

/* On the server thread: the farm schedules nothing more (its passes read on the loop's
   connection, which is not what is measured here). */
static void
farm_quiet(void *arg)
{
    (void)arg;
    farm_drop_pool(srv.farm);
}

/* One write through the API, answered with want, that sends nothing on the loop's connection:
   the store's thread writes it and reads its answer.  Tried up to 3 times: a beat of the
   farm's host (its lease) may fall into one. */
static bool
write_off_loop(const char *method, const char *path, const char *body, const char *part_name,
               const char *part, long want, struct buf *b)
{
    for (int i = 0; i < 3; i++) {
        uint64_t before = 0, after = 0;
        on_server(read_loop_trips, &before);
        long got =
            call(method, path, KEY_RW, body, part_name, part, part ? strlen(part) : 0, NULL, b);
        on_server(read_loop_trips, &after);
        if (got != want) {
            printf("    %s %s: %ld, not %ld: %s\n", method, path, got, want,
                   b->data ? b->data : "");
            return false;
        }
        if (after == before)
            return true;
        printf("    %s %s: %llu statements on the loop's connection\n", method, path,
               (unsigned long long)(after - before));
    }
    return false;
}

/* The job writes, their answers and the slicers' uploads run on the store's thread: on
   PostgreSQL the loop's own connection sends nothing for them (issue 32: each was a round trip
   every printer waited for; a part's bytes went to the database on it). */
T_CASE(api_job_writes_send_nothing_on_the_loops_connection)
{
    if (!t_store_pg()) {
        t_skip("round trips are PostgreSQL's");
        return;
    }
    struct sf_err err;
    T_OK(start("offloop", &err), &err);
    on_server(farm_quiet, NULL);
    struct buf b;
    buf_init(&b, 0);
    const char part[] = "solid cube\nendsolid cube\n";
    T_TRUE(write_off_loop("POST", "/api/jobs", NULL, "cube.stl", part, 201, &b));
    T_EQ_STR(jstr(&b, "job", "name"), "cube.stl");
    T_EQ_STR(jstr(&b, "job", "state"), "queued");
    char path[64], id[24];
    snprintf(id, sizeof(id), "%s", jstr(&b, "job", "id"));
    snprintf(path, sizeof(path), "/api/jobs/%s", id);
    T_TRUE(write_off_loop("PATCH", path, "{\"priority\": 5}", NULL, NULL, 200, &b));
    T_EQ_STR(jstr(&b, "job", "priority"), "5");
    snprintf(path, sizeof(path), "/api/jobs/%s/cancel", id);
    T_TRUE(write_off_loop("POST", path, NULL, NULL, NULL, 200, &b));
    T_EQ_STR(jstr(&b, "job", "state"), "cancelled");
    snprintf(path, sizeof(path), "/api/jobs/%s/again", id);
    T_TRUE(write_off_loop("POST", path, NULL, NULL, NULL, 201, &b));
    T_EQ_STR(jstr(&b, "job", "state"), "queued");
    /* the job printing on printer a: its printer stops it */
    T_TRUE(write_off_loop("POST", "/api/jobs/1/cancel", NULL, NULL, NULL, 200, &b));
    T_EQ_STR(jstr(&b, "job", "id"), "1");
    /* the slicers' uploads (OctoPrint's, Moonraker's) */
    T_TRUE(write_off_loop("POST", "/api/files/local", NULL, "slicer.stl", part, 201, &b));
    T_TRUE(strstr(b.data, "\"job_id\"") != NULL);
    T_TRUE(write_off_loop("POST", "/api/files/local", NULL, "sliced.gcode",
                          "; sliced\nG28\nG1 X10 E1\n", 201, &b));
    T_TRUE(strstr(b.data, "sliced.gcode") != NULL);
    T_TRUE(write_off_loop("POST", "/server/files/upload", NULL, "moon.stl", part, 201, &b));
    T_TRUE(strstr(b.data, "\"modified\"") != NULL);
    buf_release(&b);
    stop();
}

/* A manual command reads whether its printer holds an interrupted job on the store's thread,
   and is sent when the answer comes: the loop's connection sends nothing for it (before:
   store_job_interrupted on the loop, printer_command's interrupted_here). */
T_CASE(api_command_reads_off_the_loops_connection)
{
    if (!t_store_pg()) {
        t_skip("round trips are PostgreSQL's");
        return;
    }
    struct sf_err err;
    T_OK(start("cmdoffloop", &err), &err);
    on_server(farm_quiet, NULL);
    struct buf b;
    buf_init(&b, 0);
    /* b is idle with a clear bed and no interrupted job: the read lets the command through to
       its driver, which has no console */
    T_TRUE(write_off_loop("POST", "/api/printers/b/command", "{\"command\": \"G28\"}", NULL, NULL,
                          501, &b));
    T_TRUE(strstr(jstr(&b, NULL, "error"), "no console") != NULL);
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
    /* printing: the farm refuses (409), naming why */
    T_EQ_INT(call("POST", "/api/jobs/1/resume", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 409);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "only an interrupted job") != NULL);
    /* stopped mid-print and restarted: interrupted at line 0 */
    stop();
    T_OK(open_farm("resume", &err), &err);
    T_OK(start_api(0, &err), &err);
    /* no body: the stored line, 0, which would run the job's own start */
    T_EQ_INT(call("POST", "/api/jobs/1/resume", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 409);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "line 0 is out of range: resume from 1..1999") != NULL);
    T_EQ_INT(call("POST", "/api/jobs/1/resume", KEY_RW, "{\"line\": -3}", NULL, NULL, 0, NULL, &b),
             400);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "line: -3 is negative") != NULL);
    T_EQ_INT(
        call("POST", "/api/jobs/1/resume", KEY_RW, "{\"line\": \"x\"}", NULL, NULL, 0, NULL, &b),
        400);
    T_TRUE(strstr(jstr(&b, NULL, "error"), "expected {\"line\": INTEGER}") != NULL);
    T_EQ_INT(call("POST", "/api/jobs/2/resume", KEY_RW, NULL, NULL, NULL, 0, NULL, &b), 404);
    T_EQ_INT(call("POST", "/api/jobs/1/resume", KEY_RO, NULL, NULL, NULL, 0, NULL, &b), 403);
    /* a line in range: the job prints again on its printer from there */
    T_EQ_INT(
        call("POST", "/api/jobs/1/resume", KEY_RW, "{\"line\": 1234}", NULL, NULL, 0, NULL, &b),
        200);
    T_EQ_STR(jstr(&b, "job", "state"), "printing");
    T_EQ_STR(jstr(&b, "job", "printer"), "a");
    T_EQ_STR(jstr(&b, "job", "lines_acked"), "1234");
    buf_release(&b);
    stop();
}

/* POST /api/jobs/ID/resume reads the job (and its G-code's path) on the store's thread and
   answers deferred: the loop's connection sends nothing for a refusal or a resume (before:
   farm_job_resume's store_job_get and store_file_path on the loop). */
T_CASE(api_resume_reads_off_the_loops_connection)
{
    if (!t_store_pg()) {
        t_skip("round trips are PostgreSQL's");
        return;
    }
    struct sf_err err;
    T_OK(start("resumeoff", &err), &err);
    stop(); /* stopped mid-print: job 1 interrupted on a */
    T_OK(open_farm("resumeoff", &err), &err);
    T_OK(start_api(0, &err), &err);
    on_server(farm_quiet, NULL);
    struct buf b;
    buf_init(&b, 0);
    T_TRUE(write_off_loop("POST", "/api/jobs/1/resume", NULL, NULL, NULL, 409, &b));
    T_TRUE(strstr(jstr(&b, NULL, "error"), "line 0 is out of range") != NULL);
    T_TRUE(write_off_loop("POST", "/api/jobs/1/resume", "{\"line\": 1234}", NULL, NULL, 200, &b));
    T_EQ_STR(jstr(&b, "job", "state"), "printing");
    T_EQ_STR(jstr(&b, "job", "lines_acked"), "1234");
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
    T_TRUE(strstr(s.got.data, "id: 1\nevent: ") != NULL); /* from the first */
    T_TRUE(strstr(s.got.data, "\nevent: job-add\ndata: {") != NULL);
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

/* start() with the seed job, and if non-zero a header deadline of header_ms. */
static int
start_calls(const char *name, unsigned header_ms, struct sf_err *err)
{
    int rc = start(name, err);
    if (rc)
        return rc;
    /* replace the API start() made with one configured here */
    atomic_store(&srv.stop, true);
    pthread_join(srv.thread, NULL);
    api_free(srv.api);
    srv.api = NULL;
    return start_api(header_ms, err);
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
    struct store *s = t_store_open(dir, NULL, &err);
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
    /* the whole log from its first event, the job's among them */
    T_TRUE(strstr(s.got.data, "id: 1\nevent: ") != NULL);
    T_TRUE(strstr(s.got.data, "event: job-add\ndata: {") != NULL);
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

/* ---- issue 32: the API's reads send nothing on the loop's own connection ---- */

/* Hold a stream open until its text has want (the server thread writes events meanwhile
   only when note is set: a second connection's event, logged once the stream is open). */
static bool
sse_until(const char *last_id, const char *want, struct store *note)
{
    char url[128];
    snprintf(url, sizeof(url), "%s/api/events", srv.base);
    struct curl_slist *h = curl_slist_append(NULL, "X-Api-Key: " KEY_RO);
    if (last_id)
        h = curl_slist_append(h, last_id);
    struct sse_client s = { .want = want };
    buf_init(&s.got, 0);
    CURLM *m = curl_multi_init();
    CURL *c = curl_easy_init();
    curl_easy_setopt(c, CURLOPT_URL, url);
    curl_easy_setopt(c, CURLOPT_HTTPHEADER, h);
    curl_easy_setopt(c, CURLOPT_WRITEFUNCTION, on_sse);
    curl_easy_setopt(c, CURLOPT_WRITEDATA, &s);
    curl_multi_add_handle(m, c);
    int running = 1;
    bool noted = !note;
    for (int i = 0; running && i < 1000; i++) { /* 20 s at most */
        curl_multi_perform(m, &running);
        curl_multi_poll(m, NULL, 0, 20, NULL);
        if (!noted && s.got.len) { /* the stream is open (a keepalive came): now the event */
            noted = true;
            struct sf_err err;
            if (store_log_event(note, 0, "a", "note-live", "{}", &err))
                printf("    log event: %s\n", err.msg);
        }
    }
    bool got = s.got.data && strstr(s.got.data, want);
    curl_multi_remove_handle(m, c);
    curl_easy_cleanup(c);
    curl_multi_cleanup(m);
    curl_slist_free_all(h);
    buf_release(&s.got);
    return got;
}

/* Issue 32: GET /api/printers (the beds) and the event stream (the newest id, each wake's
   events) read on the reader's connection: on PostgreSQL the loop's own connection, which
   every printer waits on, sends nothing for them (store_round_trips unchanged). */
T_CASE(api_reads_send_nothing_on_the_loops_connection)
{
    T_SKIP_UNLESS(t_store_pg(), "only a PostgreSQL connection counts its round trips");
    struct sf_err err;
    if (srv.api)
        stop();
    memset(&srv, 0, sizeof(srv));
    log_set_level(LOG_WARN);
    T_OK(open_farm("looptrips", &err), &err);
    struct store *w = store_open_writer(srv.store, &err); /* another host's events */
    T_TRUE(w != NULL);
    T_OK(store_log_event(w, 0, "a", "note-old", "{}", &err), &err);
    T_OK(start_api(0, &err), &err);
    struct buf b;
    buf_init(&b, 0);
    T_EQ_INT(get("/api/printers", KEY_RO, &b), 200); /* the first of each opens what it needs */
    uint64_t before = 0, after = 0, idle = 0;
    on_server(read_loop_trips, &before);
    T_EQ_INT(get("/api/printers", KEY_RO, &b), 200);
    T_TRUE(strstr(b.data, "\"name\":\"b\"") != NULL);
    T_EQ_INT(get("/api/printers/a", KEY_RO, &b), 200);
    T_TRUE(strstr(b.data, "\"printer\":{") != NULL);
    on_server(read_loop_trips, &after);
    T_EQ_INT(after - before, 0);
    /* the backlog from the start, and an event committed while the stream is open */
    T_TRUE(sse_until("Last-Event-ID: 0", "event: note-old", NULL));
    T_TRUE(sse_until(NULL, "event: note-live", w));
    on_server(read_loop_trips, &idle);
    T_EQ_INT(idle - after, 0);
    buf_release(&b);
    store_close(w);
    stop();
}

/* Issue 32: GET /api/job (OctoPrint's) reads the one job printing, and a select the job
   selected, on the API's reader: on PostgreSQL the loop's own connection sends nothing for
   them, while the job prints. */
T_CASE(api_octoprint_job_reads_off_the_loop)
{
    T_SKIP_UNLESS(t_store_pg(), "only a PostgreSQL connection counts its round trips");
    struct sf_err err;
    T_OK(start("octojob", &err), &err);
    struct buf b;
    buf_init(&b, 0);
    uint64_t before = 0, after = 0;
    on_server(read_loop_trips, &before);
    for (int i = 0; i < 5; i++) {
        T_EQ_INT(get("/api/job", KEY_RO, &b), 200);
        T_TRUE(strstr(b.data, "\"name\":\"seed.stl\"") != NULL);
    }
    /* a slicer's select of what it uploaded: the job is read, nothing written */
    T_EQ_INT(call("POST", "/api/files/local/job-1/seed.stl", KEY_RW, "{\"command\":\"select\"}",
                  NULL, NULL, 0, NULL, &b),
             204);
    T_EQ_INT(call("POST", "/api/files/local/job-99/x.gcode", KEY_RW, "{\"command\":\"select\"}",
                  NULL, NULL, 0, NULL, &b),
             404);
    on_server(read_loop_trips, &after);
    T_EQ_INT(after - before, 0);
    buf_release(&b);
    stop();
}

/* ---- OctoPrint's push socket (api_octopush.h) ---- */

/* A blocking websocket client of the server (its waits bounded): the socket and its frames. */
struct wsclient {
    int fd;
    struct ws_parser p;
};

/* Open path's websocket: true once the server answered 101 (w is wsclient_close's either way). */
static bool
wsclient_open(struct wsclient *w, const char *path)
{
    ws_parser_init(&w->p, false, 1 << 20);
    if ((w->fd = connect_from(NULL)) < 0)
        return false;
    char req[512];
    int n = snprintf(req, sizeof(req),
                     "GET %s HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                     "Sec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                     "\r\n",
                     path);
    if (send(w->fd, req, (size_t)n, MSG_NOSIGNAL) != n)
        return false;
    /* the answer's head byte by byte: what follows it is frames */
    char head[2048];
    size_t len = 0;
    struct pollfd pf = { .fd = w->fd, .events = POLLIN };
    while (len < sizeof(head) - 1 && poll(&pf, 1, 30000) == 1 &&
           recv(w->fd, head + len, 1, 0) == 1) {
        head[++len] = '\0';
        if (len >= 4 && memcmp(head + len - 4, "\r\n\r\n", 4) == 0)
            return strncmp(head, "HTTP/1.1 101", 12) == 0;
    }
    return false;
}

static void
wsclient_close(struct wsclient *w)
{
    if (w->fd >= 0)
        close(w->fd);
    ws_parser_release(&w->p);
}

/* Send text in a masked frame, as a client must. */
static bool
wsclient_send(struct wsclient *w, const char *text)
{
    static const uint8_t mask[4] = { 0x12, 0x34, 0x56, 0x78 };
    struct buf b;
    buf_init(&b, 0);
    bool ok = ws_frame(&b, WS_TEXT, text, strlen(text), mask) == SF_OK &&
              send(w->fd, b.data, b.len, MSG_NOSIGNAL) == (ssize_t)b.len;
    buf_release(&b);
    return ok;
}

/* The next text message into out within 30 s; false when the socket closed or nothing came. */
static bool
wsclient_next(struct wsclient *w, struct buf *out)
{
    for (int waits = 0; waits < 30;) {
        struct ws_msg m;
        int rc = ws_parser_next(&w->p, &m, NULL);
        if (rc < 0 || (rc == 1 && m.op == WS_CLOSE))
            return false;
        if (rc == 1 && m.op == WS_TEXT) {
            buf_reset(out);
            return buf_append(out, m.data, m.len) == SF_OK;
        }
        if (rc == 1)
            continue; /* a ping */
        struct pollfd pf = { .fd = w->fd, .events = POLLIN };
        if (poll(&pf, 1, 1000) != 1) {
            waits++;
            continue;
        }
        char chunk[4096];
        ssize_t n = recv(w->fd, chunk, sizeof(chunk), 0);
        if (n <= 0 || ws_parser_feed(&w->p, chunk, (size_t)n, NULL))
            return false;
    }
    return false;
}

/* Read messages (into out) until one holds both want and also (NULL: want alone); at most
   200 (the socket's `current`s come every half second). */
static bool
wsclient_until(struct wsclient *w, const char *want, const char *also, struct buf *out)
{
    for (int i = 0; i < 200 && wsclient_next(w, out);)
        if (strstr(out->data, want) && (!also || strstr(out->data, also)))
            return true;
        else
            i++;
    printf("    no message with %s%s%s (last: %.300s)\n", want, also ? " and " : "",
           also ? also : "", out->data ? out->data : "");
    return false;
}

/* Issue 32: the push socket's reads (the log's newest id when it opens, its events, each
   print event's job and printer, the job history and current show) are the API reader's:
   on PostgreSQL the loop's own connection sends nothing for a socket.  Both engines: the
   socket's messages, in order (history before anything else after the auth). */
T_CASE(api_octopush_reads_off_the_loop)
{
    struct sf_err err;
    T_OK(start("octopush", &err), &err);
    struct store *w = store_open_writer(srv.store, &err); /* another host's events */
    T_TRUE(w != NULL);
    struct buf b;
    buf_init(&b, 0);
    long st = call("POST", "/api/login?passive=true", KEY_RW, "{}", NULL, NULL, 0, NULL, &b);
    T_TRUE(st == 200 || !printf("    %ld: %s\n", st, b.data));
    char name[64], auth[160];
    snprintf(name, sizeof(name), "%s", jstr(&b, NULL, "name")); /* jstr's value is static */
    snprintf(auth, sizeof(auth), "{\"auth\":\"%s:%s\"}", name, jstr(&b, NULL, "session"));
    uint64_t before = 0, after = 0;
    on_server(read_loop_trips, &before);
    struct wsclient ws;
    T_TRUE(wsclient_open(&ws, "/sockjs/websocket"));
    T_TRUE(wsclient_next(&ws, &b) && strstr(b.data, "\"connected\"") != NULL);
    T_TRUE(wsclient_send(&ws, auth));
    T_TRUE(wsclient_next(&ws, &b));
    T_TRUE(strncmp(b.data, "{\"history\":", 11) == 0 || !printf("    %.300s\n", b.data));
    T_TRUE(strstr(b.data, "\"name\":\"seed.stl\"") != NULL);
    T_TRUE(wsclient_until(&ws, "{\"current\":", "\"name\":\"seed.stl\"", &b));
    /* a pause logged with its printer; a print's end without it (its last print's) */
    T_OK(store_log_event(w, 1, "a", "job-pause", "{}", &err), &err);
    T_TRUE(wsclient_until(&ws, "\"PrintPaused\"", "\"name\":\"seed.stl\"", &b));
    T_TRUE(strstr(b.data, "\"printer\":\"a\"") != NULL);
    T_OK(store_log_event(w, 1, NULL, "job-print-done", "{}", &err), &err);
    T_TRUE(wsclient_until(&ws, "\"PrintDone\"", "\"path\":\"job-1/seed.stl\"", &b));
    T_TRUE(strstr(b.data, "\"printer\":\"a\"") != NULL);
    T_TRUE(wsclient_until(&ws, "{\"current\":", "\"name\":\"seed.stl\"", &b));
    on_server(read_loop_trips, &after);
    if (t_store_pg())
        T_EQ_INT(after - before, 0);
    wsclient_close(&ws);
    buf_release(&b);
    store_close(w);
    stop();
}
