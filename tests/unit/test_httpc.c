/*
 * test_httpc.c - the loop-driven HTTP client against a real loopback HTTP
 * server (libmicrohttpd, a thread per connection, in this process): GET and
 * POST, a 6 MB file streamed as a raw PUT body and as a multipart part
 * whose bytes arrive intact, a timeout, a refused connection, an oversize
 * response, cancel mid-upload from the progress callback, cancel of a
 * finished request from another's done callback, digest auth, and 60
 * concurrent requests on one loop sharing its client.
 */
#include <arpa/inet.h>
#include <microhttpd.h>
#include <netinet/in.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "../../drivers/net/httpc.h"
#include "../../src/base/buf.h"
#include "../../src/base/mem.h"
#include "../t.h"

/* ---- the server ---- */

struct upload {
    struct buf body; /* what arrived */
    uint64_t sunk;   /* bytes that arrived at /sink, counted and dropped */
};

static pthread_mutex_t srv_lock = PTHREAD_MUTEX_INITIALIZER;
static struct buf last_body; /* the last complete request body (under srv_lock) */
static atomic_int slow_release;

static enum MHD_Result
reply(struct MHD_Connection *c, unsigned status, const char *text)
{
    struct MHD_Response *r =
        MHD_create_response_from_buffer(strlen(text), (void *)text, MHD_RESPMEM_MUST_COPY);
    MHD_add_response_header(r, "X-Test", "yes");
    MHD_add_response_header(r, "Location", "http://example/api/files/local/a.gcode");
    enum MHD_Result ret = MHD_queue_response(c, status, r);
    MHD_destroy_response(r);
    return ret;
}

static enum MHD_Result
handler(void *cls, struct MHD_Connection *c, const char *url, const char *method,
        const char *version, const char *data, size_t *size, void **con_cls)
{
    (void)cls, (void)version;
    struct upload *u = *con_cls;
    if (!u) {
        u = calloc(1, sizeof(*u));
        buf_init(&u->body, 0);
        *con_cls = u;
        return MHD_YES;
    }
    if (*size && strcmp(url, "/sink") == 0) {
        u->sunk += *size;
        *size = 0;
        return MHD_YES;
    }
    if (*size) {
        buf_append(&u->body, data, *size);
        *size = 0;
        return MHD_YES;
    }
    pthread_mutex_lock(&srv_lock);
    buf_reset(&last_body);
    buf_append(&last_body, u->body.data ? u->body.data : "", u->body.len);
    pthread_mutex_unlock(&srv_lock);
    char text[256];
    if (strcmp(url, "/hello") == 0)
        return reply(c, 200, "hello world");
    if (strcmp(url, "/echo") == 0) {
        snprintf(text, sizeof(text), "%s %zu", method, u->body.len);
        return reply(c, 201, text);
    }
    if (strcmp(url, "/sink") == 0) {
        snprintf(text, sizeof(text), "%s %llu", method, (unsigned long long)u->sunk);
        return reply(c, 201, text);
    }
    if (strcmp(url, "/status/503") == 0)
        return reply(c, 503, "busy");
    if (strcmp(url, "/big") == 0) {
        char *big = malloc(100000);
        memset(big, 'x', 100000);
        struct MHD_Response *r =
            MHD_create_response_from_buffer(100000, big, MHD_RESPMEM_MUST_FREE);
        enum MHD_Result ret = MHD_queue_response(c, 200, r);
        MHD_destroy_response(r);
        return ret;
    }
    if (strcmp(url, "/slow") == 0) {
        for (int i = 0; i < 100 && !atomic_load(&slow_release); i++)
            usleep(50000);
        return reply(c, 200, "late");
    }
    if (strcmp(url, "/n") == 0) {
        const char *q = MHD_lookup_connection_value(c, MHD_GET_ARGUMENT_KIND, "i");
        snprintf(text, sizeof(text), "n=%s", q ? q : "?");
        return reply(c, 200, text);
    }
    if (strcmp(url, "/digest") == 0) {
        char *user = MHD_digest_auth_get_username(c);
        int ok = user && strcmp(user, "maker") == 0 &&
                 MHD_digest_auth_check(c, "test", "maker", "secret", 300) == MHD_YES;
        MHD_free(user);
        if (ok)
            return reply(c, 200, "welcome");
        struct MHD_Response *r =
            MHD_create_response_from_buffer(6, (void *)"denied", MHD_RESPMEM_PERSISTENT);
        enum MHD_Result ret = MHD_queue_auth_fail_response(c, "test", "opaque0", r, MHD_NO);
        MHD_destroy_response(r);
        return ret;
    }
    return reply(c, 404, "no such thing");
}

static void
completed(void *cls, struct MHD_Connection *c, void **con_cls, enum MHD_RequestTerminationCode t)
{
    (void)cls, (void)c, (void)t;
    struct upload *u = *con_cls;
    if (u) {
        buf_release(&u->body);
        free(u);
    }
    *con_cls = NULL;
}

static struct MHD_Daemon *srv;
static char digest_random[32] = "slimfarm test digest randomness";
static int srv_port;

static void
server_up(void)
{
    if (srv)
        return;
    buf_init(&last_body, 0);
    srv = MHD_start_daemon(MHD_USE_THREAD_PER_CONNECTION | MHD_USE_INTERNAL_POLLING_THREAD, 0, NULL,
                           NULL, handler, NULL, MHD_OPTION_NOTIFY_COMPLETED, completed, NULL,
                           MHD_OPTION_DIGEST_AUTH_RANDOM, sizeof(digest_random), digest_random,
                           MHD_OPTION_NONCE_NC_SIZE, 64, MHD_OPTION_END);
    const union MHD_DaemonInfo *di =
        srv ? MHD_get_daemon_info(srv, MHD_DAEMON_INFO_BIND_PORT) : NULL;
    srv_port = di ? di->port : 0;
}

static void
url(char *out, size_t n, const char *path)
{
    snprintf(out, n, "http://127.0.0.1:%d%s", srv_port, path);
}

/* ---- the client side ---- */

struct got {
    int calls;
    int code;
    long status;
    char body[256];
    size_t body_len;
    char location[128];
    char msg[256];
    uint64_t body_read;
};

static void
on_done(struct httpc_req *r, const struct httpc_result *res, void *ud)
{
    (void)r;
    struct got *g = ud;
    g->calls++;
    g->code = res->code;
    g->status = res->status;
    g->body_len = res->body_len;
    g->body_read = res->body_read;
    snprintf(g->body, sizeof(g->body), "%s", res->body);
    if (!httpc_header(res, "location", g->location, sizeof(g->location)))
        g->location[0] = 0;
    snprintf(g->msg, sizeof(g->msg), "%s", res->err.msg);
}

static double
wall_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec / 1e9;
}

/* Turn the loop until *flag (or all of n flags) is set; bounded by the wall clock. */
static void
run_until(struct loop *l, const int *calls, int want)
{
    double end = wall_s() + 60;
    while (*calls < want && wall_s() < end)
        loop_run_once(l, 100);
}

static struct httpc *
client(struct loop **l)
{
    server_up();
    struct sf_err err;
    *l = loop_new(&err);
    return *l ? httpc_new(*l, &err) : NULL;
}

T_CASE(get_and_post)
{
    struct loop *l;
    struct httpc *h = client(&l);
    T_TRUE(h && srv_port > 0);
    char u[128];
    struct got g = { 0 };
    struct sf_err err;
    url(u, sizeof(u), "/hello");
    struct httpc_opts o = { .url = u, .done = on_done, .ud = &g };
    T_TRUE(httpc_start(h, &o, &err) != NULL);
    T_EQ_INT(g.calls, 0); /* never from within httpc_start */
    run_until(l, &g.calls, 1);
    T_EQ_INT(g.calls, 1);
    T_EQ_INT(g.code, SF_OK);
    T_EQ_INT(g.status, 200);
    T_EQ_STR(g.body, "hello world");
    T_EQ_STR(g.location, "http://example/api/files/local/a.gcode");

    struct got p = { 0 };
    url(u, sizeof(u), "/echo");
    const char *hdrs[] = { "Content-Type: application/json", "X-Api-Key: k", NULL };
    struct httpc_opts po = { .url = u,
                             .headers = hdrs,
                             .body = "{\"command\":\"pause\"}",
                             .body_len = 19,
                             .done = on_done,
                             .ud = &p };
    T_TRUE(httpc_start(h, &po, &err) != NULL);
    run_until(l, &p.calls, 1);
    T_EQ_INT(p.status, 201);
    T_EQ_STR(p.body, "POST 19");

    struct got s = { 0 };
    url(u, sizeof(u), "/status/503");
    struct httpc_opts so = { .url = u, .done = on_done, .ud = &s };
    T_TRUE(httpc_start(h, &so, &err) != NULL);
    run_until(l, &s.calls, 1);
    T_EQ_INT(s.code, SF_OK); /* a response, whatever its status */
    T_EQ_INT(s.status, 503);
    T_EQ_INT(httpc_active(h), 0);
    httpc_free(h);
    loop_free(l);
}

/* A file of n pseudo-random bytes. */
static char *
make_file(const char *name, size_t n)
{
    static char path[512];
    snprintf(path, sizeof(path), "%s/%s", t_tmpdir(), name);
    FILE *f = fopen(path, "wb");
    uint32_t x = 12345;
    for (size_t i = 0; i < n; i++) {
        x = x * 1103515245u + 12345u;
        fputc((int)(x >> 16) & 0xff, f);
    }
    fclose(f);
    return path;
}

static bool
body_matches_file(const char *path, bool exact)
{
    struct buf fb;
    buf_init(&fb, 0);
    struct sf_err err;
    if (buf_read_file(&fb, path, &err) < 0)
        return false;
    pthread_mutex_lock(&srv_lock);
    bool ok = exact ? last_body.len == fb.len && memcmp(last_body.data, fb.data, fb.len) == 0
                    : last_body.len > fb.len &&
                          memmem(last_body.data, last_body.len, fb.data, fb.len) != NULL;
    pthread_mutex_unlock(&srv_lock);
    buf_release(&fb);
    return ok;
}

struct prog {
    uint64_t sent, total;
    int calls;
};

/* An upload's outcome and progress; done gets &g, which is the struct's address. */
struct upl {
    struct got g;
    struct prog p;
};

static void
on_progress(struct httpc_req *r, uint64_t sent, uint64_t total, void *ud)
{
    struct prog *p = &((struct upl *)ud)->p;
    (void)r;
    p->sent = sent;
    p->total = total;
    p->calls++;
}

/* Send path to u and run the loop until it is done: as a PUT body, or, with n_parts parts (one
   of them the file), as a multipart POST.  Outcome and progress in *up; false if it did not
   start. */
static bool
upload(struct loop *l, struct httpc *h, const char *u, const char *path,
       const struct httpc_part *parts, size_t n_parts, struct upl *up)
{
    struct sf_err err;
    struct httpc_opts o = { .method = n_parts ? NULL : "PUT",
                            .url = u,
                            .body_path = n_parts ? NULL : path,
                            .parts = parts,
                            .n_parts = n_parts,
                            .done = on_done,
                            .progress = on_progress,
                            .ud = up };
    if (!httpc_start(h, &o, &err)) {
        fprintf(stderr, "upload: %s\n", err.msg);
        return false;
    }
    run_until(l, &up->g.calls, 1);
    return true;
}

T_CASE(streamed_file_upload_arrives_intact)
{
    struct loop *l;
    struct httpc *h = client(&l);
    T_TRUE(h != NULL);
    const char *path = make_file("up.bin", 6u << 20);
    char u[128];
    struct sf_err err;
    url(u, sizeof(u), "/echo");
    struct upl a = { 0 };
    T_TRUE(upload(l, h, u, path, NULL, 0, &a));
    T_EQ_INT(a.g.code, SF_OK);
    T_EQ_STR(a.g.body, "PUT 6291456");
    T_TRUE(body_matches_file(path, true));
    T_EQ_INT(a.p.sent, 6u << 20);
    T_TRUE(a.p.calls >= 1);
    T_EQ_INT(a.g.body_read, 6u << 20);

    /* The same file as the 'file' part of a multipart POST, beside text fields. */
    struct upl m = { 0 };
    struct httpc_part parts[] = {
        { .name = "select", .value = "true" },
        { .name = "file", .file_path = path, .filename = "job 1.gcode" },
    };
    T_TRUE(upload(l, h, u, path, parts, 2, &m));
    T_EQ_INT(m.g.status, 201);
    T_TRUE(body_matches_file(path, false));
    pthread_mutex_lock(&srv_lock);
    T_TRUE(memmem(last_body.data, last_body.len, "filename=\"job 1.gcode\"", 22) != NULL);
    T_TRUE(memmem(last_body.data, last_body.len, "name=\"select\"", 13) != NULL);
    pthread_mutex_unlock(&srv_lock);
    T_TRUE(m.p.total > 6u << 20);
    T_EQ_INT(m.g.body_read, 6u << 20); /* the file part's bytes, not the form's */

    /* A body file that does not exist fails at start, naming it. */
    struct httpc_opts bad = {
        .method = "PUT", .url = u, .body_path = "/nonexistent/x.gcode", .done = on_done, .ud = &m.g
    };
    T_TRUE(httpc_start(h, &bad, &err) == NULL);
    T_TRUE(strstr(err.msg, "/nonexistent/x.gcode") != NULL);
    /* ... and so does a file part's */
    struct httpc_part gone[] = { { .name = "file", .file_path = "/nonexistent/y.gcode" } };
    struct httpc_opts bad_part = {
        .url = u, .parts = gone, .n_parts = 1, .done = on_done, .ud = &m.g
    };
    T_TRUE(httpc_start(h, &bad_part, &err) == NULL);
    T_TRUE(strstr(err.msg, "/nonexistent/y.gcode") != NULL);
    httpc_free(h);
    loop_free(l);
}

T_CASE(timeout_refused_oversize)
{
    struct loop *l;
    struct httpc *h = client(&l);
    T_TRUE(h != NULL);
    char u[128];
    struct sf_err err;
    struct got t = { 0 };
    atomic_store(&slow_release, 0);
    url(u, sizeof(u), "/slow");
    struct httpc_opts o = { .url = u, .timeout_ms = 300, .done = on_done, .ud = &t };
    T_TRUE(httpc_start(h, &o, &err) != NULL);
    run_until(l, &t.calls, 1);
    atomic_store(&slow_release, 1);
    T_EQ_INT(t.code, SF_ETIMEDOUT);
    T_TRUE(strstr(t.msg, "/slow") != NULL);

    /* A port nobody listens on: bind one, close it. */
    int s = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in a = { .sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK) };
    socklen_t al = sizeof(a);
    bind(s, (struct sockaddr *)&a, sizeof(a));
    getsockname(s, (struct sockaddr *)&a, &al);
    close(s);
    snprintf(u, sizeof(u), "http://127.0.0.1:%d/api/version", ntohs(a.sin_port));
    struct got r = { 0 };
    struct httpc_opts ro = { .url = u, .done = on_done, .ud = &r };
    T_TRUE(httpc_start(h, &ro, &err) != NULL);
    run_until(l, &r.calls, 1);
    T_EQ_INT(r.code, SF_EIO);
    T_EQ_INT(r.status, 0);
    T_TRUE(strstr(r.msg, "/api/version") != NULL);

    struct got b = { 0 };
    url(u, sizeof(u), "/big");
    struct httpc_opts bo = { .url = u, .max_body = 1024, .done = on_done, .ud = &b };
    T_TRUE(httpc_start(h, &bo, &err) != NULL);
    run_until(l, &b.calls, 1);
    T_EQ_INT(b.code, SF_ENOMEM);
    T_TRUE(strstr(b.msg, "1024-byte cap") != NULL);
    httpc_free(h);
    loop_free(l);
}

struct canceller {
    struct got g;
    struct httpc_req *self;
    int progress_calls;
};

static void
cancel_in_progress(struct httpc_req *r, uint64_t sent, uint64_t total, void *ud)
{
    (void)sent, (void)total;
    struct canceller *c = ud;
    c->progress_calls++;
    if (c->progress_calls == 1)
        httpc_cancel(r);
}

struct pair {
    struct got a;
    struct httpc_req *ra, *rb;
};

/* The first to finish cancels the other (finished too, or still in flight). */
static void
done_cancels_other(struct httpc_req *r, const struct httpc_result *res, void *ud)
{
    struct pair *p = ud;
    on_done(r, res, &p->a);
    httpc_cancel(r == p->ra ? p->rb : p->ra);
    httpc_cancel(r); /* its own, from its done: a no-op */
}

T_CASE(cancel_mid_transfer_and_from_callbacks)
{
    struct loop *l;
    struct httpc *h = client(&l);
    T_TRUE(h != NULL);
    const char *path = make_file("cancel.bin", 8u << 20);
    char u[128];
    struct sf_err err;
    url(u, sizeof(u), "/echo");
    struct canceller c = { 0 };
    struct httpc_opts o = { .method = "PUT",
                            .url = u,
                            .body_path = path,
                            .done = on_done,
                            .progress = cancel_in_progress,
                            .ud = &c };
    c.self = httpc_start(h, &o, &err);
    T_TRUE(c.self != NULL);
    double end = wall_s() + 30;
    while (httpc_active(h) && wall_s() < end)
        loop_run_once(l, 50);
    /* The sweep frees it; turn a little more so it does. */
    for (int i = 0; i < 20; i++)
        loop_run_once(l, 10);
    T_EQ_INT(c.g.calls, 0);
    T_TRUE(c.progress_calls >= 1);
    T_EQ_INT(httpc_active(h), 0);

    /* Cancel outside any callback, mid-wait. */
    struct got w = { 0 };
    atomic_store(&slow_release, 0);
    url(u, sizeof(u), "/slow");
    struct httpc_opts wo = { .url = u, .done = on_done, .ud = &w };
    struct httpc_req *wr = httpc_start(h, &wo, &err);
    for (int i = 0; i < 5; i++)
        loop_run_once(l, 20);
    httpc_cancel(wr);
    atomic_store(&slow_release, 1);

    /* Two requests; whichever finishes first cancels the other from its done. */
    struct pair p = { 0 };
    url(u, sizeof(u), "/hello");
    struct httpc_opts ao = { .url = u, .done = done_cancels_other, .ud = &p };
    p.ra = httpc_start(h, &ao, &err);
    p.rb = httpc_start(h, &ao, &err);
    T_TRUE(p.ra && p.rb);
    end = wall_s() + 30;
    while (httpc_active(h) && wall_s() < end)
        loop_run_once(l, 50);
    T_EQ_INT(p.a.calls, 1);
    T_EQ_INT(w.calls, 0);

    /* The client still works after all that. */
    struct got g = { 0 };
    struct httpc_opts go = { .url = u, .done = on_done, .ud = &g };
    T_TRUE(httpc_start(h, &go, &err) != NULL);
    run_until(l, &g.calls, 1);
    T_EQ_STR(g.body, "hello world");
    httpc_free(h);
    loop_free(l);
}

T_CASE(digest_auth)
{
    struct loop *l;
    struct httpc *h = client(&l);
    T_TRUE(h != NULL);
    char u[128];
    struct sf_err err;
    url(u, sizeof(u), "/digest");
    struct got ok = { 0 }, bad = { 0 };
    struct httpc_opts o = {
        .url = u, .user = "maker", .password = "secret", .digest = true, .done = on_done, .ud = &ok
    };
    T_TRUE(httpc_start(h, &o, &err) != NULL);
    run_until(l, &ok.calls, 1);
    struct httpc_opts b = {
        .url = u, .user = "maker", .password = "wrong", .digest = true, .done = on_done, .ud = &bad
    };
    T_TRUE(httpc_start(h, &b, &err) != NULL);
    run_until(l, &bad.calls, 1);
    T_EQ_INT(ok.status, 200);
    T_EQ_STR(ok.body, "welcome");
    T_EQ_INT(bad.status, 401);
    httpc_free(h);
    loop_free(l);
}

T_CASE(many_concurrent_on_one_shared_client)
{
    server_up();
    struct sf_err err;
    struct loop *l = loop_new(&err);
    struct httpc *h = httpc_get(l, &err);
    struct httpc *h2 = httpc_get(l, &err);
    T_TRUE(h && h == h2); /* one client per loop */
    httpc_put(h2);
    enum { N = 60 };
    static struct got g[N];
    memset(g, 0, sizeof(g));
    char u[128];
    for (int i = 0; i < N; i++) {
        snprintf(u, sizeof(u), "http://127.0.0.1:%d/n?i=%d", srv_port, i);
        struct httpc_opts o = { .url = u, .done = on_done, .ud = &g[i] };
        T_TRUE(httpc_start(h, &o, &err) != NULL);
    }
    T_EQ_INT(httpc_active(h), N);
    double end = wall_s() + 60;
    while (httpc_active(h) && wall_s() < end)
        loop_run_once(l, 100);
    int right = 0;
    for (int i = 0; i < N; i++) {
        char want[32];
        snprintf(want, sizeof(want), "n=%d", i);
        right += g[i].calls == 1 && g[i].status == 200 && strcmp(g[i].body, want) == 0;
    }
    T_EQ_INT(right, N);
    httpc_put(h);
    loop_free(l);
}

/* The process's peak resident set, kB (VmHWM), or -1. */
static long
peak_rss_kb(void)
{
    FILE *f = fopen("/proc/self/status", "r");
    char line[256];
    long kb = -1;
    while (f && fgets(line, sizeof(line), f))
        if (strncmp(line, "VmHWM:", 6) == 0)
            kb = strtol(line + 6, NULL, 10);
    if (f)
        fclose(f);
    return kb;
}

T_CASE(a_100_mb_upload_never_sits_in_memory)
{
    /* a job file of 100 MB streamed as a PUT body and as a multipart part:
       the peak resident set grows by a small part of it (curl reads it in
       buffers from disk); the server here counts the bytes and drops them */
    struct loop *l;
    struct httpc *h = client(&l);
    T_TRUE(h != NULL);
    char path[512];
    snprintf(path, sizeof(path), "%s/big.gcode", t_tmpdir());
    FILE *f = fopen(path, "wb");
    T_TRUE(f != NULL);
    T_TRUE(ftruncate(fileno(f), (off_t)100 << 20) == 0); /* sparse: no disk, no memory */
    fclose(f);
    FILE *c = fopen("/proc/self/clear_refs", "w"); /* reset VmHWM where the kernel lets us */
    if (c) {
        fputs("5", c);
        fclose(c);
    }
    long before = peak_rss_kb();
    T_TRUE(before > 0);
    char u[128];
    url(u, sizeof(u), "/sink");
    struct upl a = { 0 };
    T_TRUE(upload(l, h, u, path, NULL, 0, &a));
    T_EQ_INT(a.g.code, SF_OK);
    T_EQ_STR(a.g.body, "PUT 104857600");
    T_EQ_INT(a.p.sent, (uint64_t)100 << 20);
    struct upl m = { 0 };
    struct httpc_part parts[] = { { .name = "file", .file_path = path, .filename = "big.gcode" } };
    T_TRUE(upload(l, h, u, path, parts, 1, &m));
    T_EQ_INT(m.g.status, 201);
    T_TRUE(m.p.total > (uint64_t)100 << 20);
    long grew = peak_rss_kb() - before;
    if (grew > 32 * 1024)
        t_fail(__FILE__, __LINE__, "peak RSS grew by %ld kB over a 100 MB upload", grew);
    httpc_free(h);
    loop_free(l);
    remove(path);
}
