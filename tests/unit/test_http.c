/*
 * test_http.c - the HTTP server's connection budgets and event stream
 * limits (http_budget.h, http.h), over real sockets: the budget's
 * accounting on socketpairs (a dropped connection reads end of stream),
 * and the server on loopback, run by a thread of its own standing in for
 * the loop, with raw-socket clients.
 */
#include <errno.h>
#include <netinet/in.h>
#include <poll.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <unistd.h>

#include "../../src/api/http.h"
#include "../../src/api/http_budget.h"
#include "../../src/base/log.h"
#include "../t.h"

#define KEY_A "key-a-0123456789abcdef"
#define KEY_B "key-b-0123456789abcdef"

/* ---- budget accounting ---- */

/* A budget with small caps and n slots, each on one end of a socketpair
   (peer[i] is the other end), from the addresses given. */
#define SLOTS_MAX 8
static struct {
    struct http_budget b;
    struct http_slot s[SLOTS_MAX];
    int peer[SLOTS_MAX];
    int n;
} fx;

static void
fx_open(int n, const uint32_t *addr)
{
    log_set_level(LOG_WARN); /* each drop is logged at info */
    struct http_budget_caps caps = {
        .max = { 4, 2, 2, 2 }, .pending_per_addr = 2, .keyless_per_addr = 1, .total = 12
    };
    http_budget_init(&fx.b, &caps);
    fx.n = n;
    for (int i = 0; i < n; i++) {
        int sv[2];
        socketpair(AF_UNIX, SOCK_STREAM, 0, sv);
        fx.s[i] = (struct http_slot){
            .fd = sv[0], .addr = addr[i], .cls = HTTP_CLASS_N, .deadline_ms = 1000 + i
        };
        fx.peer[i] = sv[1];
    }
}

/* Close every slot; true if the budget then counts none. */
static bool
fx_close(void)
{
    for (int i = 0; i < fx.n; i++) {
        http_budget_close(&fx.b, &fx.s[i]);
        close(fx.s[i].fd), close(fx.peer[i]);
    }
    unsigned left = 0;
    for (int c = 0; c < HTTP_CLASS_N; c++)
        left += fx.b.n[c];
    return left == 0;
}

/* The server shut slot i down: its peer reads end of stream at once. */
static bool
dropped(int i)
{
    struct pollfd p = { .fd = fx.peer[i], .events = POLLIN };
    char c;
    return poll(&p, 1, 0) == 1 && recv(fx.peer[i], &c, 1, MSG_DONTWAIT) == 0;
}

T_CASE(http_budget_pending_drops_the_oldest_of_its_address_first)
{
    const uint32_t addr[6] = { 1, 2, 1, 1, 3, 4 };
    fx_open(6, addr);
    struct http_budget *b = &fx.b;
    http_budget_accept(b, &fx.s[0]);
    http_budget_accept(b, &fx.s[1]);
    http_budget_accept(b, &fx.s[2]);
    T_TRUE(!dropped(0));
    http_budget_accept(b, &fx.s[3]); /* a third from address 1: its oldest goes */
    T_TRUE(dropped(0));
    T_TRUE(!dropped(1));
    T_EQ_INT(b->n[HTTP_CLASS_PENDING], 3);
    http_budget_accept(b, &fx.s[4]);
    http_budget_accept(b, &fx.s[5]); /* five pending, cap 4: the oldest of all goes */
    T_TRUE(dropped(1));
    T_EQ_INT(b->n[HTTP_CLASS_PENDING], 4);
    http_budget_expire(b, 1003); /* deadlines 1002 (s[2]) and 1003 (s[3]) passed */
    T_TRUE(dropped(2) && dropped(3));
    T_TRUE(!dropped(4) && !dropped(5));
    T_EQ_INT(http_budget_next_ms(b), 1004);
    T_TRUE(fx_close());
}

T_CASE(http_budget_classes_keep_their_own_slots)
{
    const uint32_t addr[7] = { 1, 1, 2, 3, 4, 5, 6 };
    fx_open(7, addr); /* as if accepted and already moved on */
    struct http_budget *b = &fx.b;
    struct http_slot *s = fx.s;
    T_TRUE(http_budget_enter(b, &s[0], HTTP_CLASS_KEYLESS));
    T_TRUE(!http_budget_enter(b, &s[1], HTTP_CLASS_KEYLESS)); /* one per address */
    T_TRUE(http_budget_enter(b, &s[2], HTTP_CLASS_KEYLESS));
    T_TRUE(!http_budget_enter(b, &s[3], HTTP_CLASS_KEYLESS)); /* the class is full */
    T_TRUE(http_budget_enter(b, &s[3], HTTP_CLASS_READ));
    T_TRUE(http_budget_enter(b, &s[4], HTTP_CLASS_READ));
    T_TRUE(!http_budget_enter(b, &s[5], HTTP_CLASS_READ));
    /* keyless and read full: the write class is untouched */
    T_TRUE(http_budget_enter(b, &s[5], HTTP_CLASS_WRITE));
    T_TRUE(http_budget_enter(b, &s[6], HTTP_CLASS_WRITE));
    /* a keep-alive connection asking as a full class is refused and
       counted nowhere (it is closed), which frees its keyless slot */
    T_TRUE(!http_budget_enter(b, &s[0], HTTP_CLASS_READ));
    T_EQ_INT(b->n[HTTP_CLASS_KEYLESS], 1);
    T_TRUE(http_budget_enter(b, &s[1], HTTP_CLASS_KEYLESS)); /* address 1 is free again */
    T_TRUE(fx_close());
}

/* ---- the server: event streams ---- */

static struct {
    struct http *h;
    pthread_t thread;
    atomic_bool stop;
} srv;

static ssize_t
ev_read(void *ud, char *buf, size_t max)
{
    int *sent = ud;
    if (*sent)
        return 0; /* nothing more: suspended until woken or expired */
    *sent = 1;
    return snprintf(buf, max, "data: hi\n\n");
}

/* An endless stream: whatever room MHD has, filled. */
static ssize_t
flood_read(void *ud, char *buf, size_t max)
{
    (void)ud;
    memset(buf, ':', max);
    return (ssize_t)max;
}

static atomic_bool flood_freed; /* the server let go of the /flood stream */

static void
flood_free(void *ud)
{
    (void)ud;
    atomic_store(&flood_freed, true);
}

/* /events: one event, then quiet; /flood: endless; anything else: {} */
static void
route(void *ud, const struct http_req *req, struct http_resp *resp)
{
    (void)ud;
    if (strcmp(req->path, "/events") == 0) {
        resp->stream = ev_read;
        resp->stream_ud = calloc(1, sizeof(int));
        resp->stream_free = free;
    } else if (strcmp(req->path, "/flood") == 0) {
        resp->stream = flood_read;
        resp->stream_free = flood_free;
    }
}

static void *
serve(void *arg)
{
    (void)arg;
    struct pollfd pfd = { .fd = http_fd(srv.h), .events = POLLIN };
    while (!atomic_load(&srv.stop)) {
        int64_t t = http_timeout_ms(srv.h);
        poll(&pfd, 1, t < 0 || t > 5 ? 5 : (int)t);
        http_run(srv.h);
    }
    return NULL;
}

static int
start(unsigned lifetime_ms, unsigned idle_s, struct sf_err *err)
{
    static const struct farmcfg_key keys[2] = { { KEY_A, false, false }, { KEY_B, true, false } };
    struct http_config cfg = { .route = route, .host = "127.0.0.1", .keys = keys, .n_keys = 2 };
    cfg.body_max = cfg.upload_max = 4096;
    cfg.stream_lifetime_ms = lifetime_ms;
    cfg.idle_s = idle_s;
    srv.h = http_new(&cfg, err);
    if (!srv.h)
        return err->code;
    atomic_store(&srv.stop, false);
    pthread_create(&srv.thread, NULL, serve, NULL);
    return SF_OK;
}

static void
stop(void)
{
    atomic_store(&srv.stop, true);
    pthread_join(srv.thread, NULL);
    http_free(srv.h);
    srv.h = NULL;
}

/* GET path with key on a new connection (a receive buffer of rcvbuf
   bytes if not 0); its socket, the response so far in out (the head at
   least). */
static int
open_get(const char *path, const char *key, int rcvbuf, char *out, size_t cap)
{
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    if (rcvbuf)
        setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof(rcvbuf));
    struct sockaddr_in sa = { .sin_family = AF_INET,
                              .sin_port = htons((uint16_t)http_port(srv.h)),
                              .sin_addr.s_addr = htonl(INADDR_LOOPBACK) };
    struct timeval tv = { .tv_sec = 20 };
    setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
    if (connect(fd, (struct sockaddr *)&sa, sizeof(sa))) {
        close(fd);
        return -1;
    }
    char req[256];
    int n = snprintf(req, sizeof(req), "GET %s HTTP/1.1\r\nHost: x\r\nX-Api-Key: %s\r\n\r\n", path,
                     key);
    send(fd, req, (size_t)n, 0);
    size_t len = 0;
    out[0] = '\0';
    while (!strstr(out, "\r\n\r\n") && len + 1 < cap) {
        ssize_t r = recv(fd, out + len, cap - 1 - len, 0);
        if (r <= 0)
            break;
        out[len += (size_t)r] = '\0';
    }
    return fd;
}

static int
open_stream(const char *key, char *out, size_t cap)
{
    return open_get("/events", key, 0, out, cap);
}

/* Read fd until the server closes it; false if it is still open after 20 s. */
static bool
read_to_close(int fd)
{
    char buf[65536];
    for (;;) {
        ssize_t r = recv(fd, buf, sizeof(buf), 0);
        if (r == 0 || (r < 0 && errno == ECONNRESET))
            return true;
        if (r < 0)
            return false; /* SO_RCVTIMEO: still open */
    }
}

T_CASE(http_event_stream_ends_after_its_lifetime_with_a_retry_hint)
{
    struct sf_err err;
    T_OK(start(300, 0, &err), &err);
    char buf[4096];
    int fd = open_stream(KEY_A, buf, sizeof(buf));
    T_TRUE(fd >= 0);
    /* read to the end of the chunked body, which only the lifetime brings */
    size_t len = strlen(buf);
    while (!strstr(buf, "\r\n0\r\n\r\n") && len + 1 < sizeof(buf)) {
        ssize_t r = recv(fd, buf + len, sizeof(buf) - 1 - len, 0);
        if (r <= 0)
            break;
        buf[len += (size_t)r] = '\0';
    }
    close(fd);
    stop();
    T_TRUE(strstr(buf, "HTTP/1.1 200") != NULL);
    T_TRUE(strstr(buf, "data: hi\n\n") != NULL);
    T_TRUE(strstr(buf, "retry: 1000\n\n") != NULL);
    T_TRUE(strstr(buf, "\r\n0\r\n\r\n") != NULL);
}

T_CASE(http_event_streams_per_key_are_capped)
{
    struct sf_err err;
    T_OK(start(0, 0, &err), &err);
    int fd[HTTP_STREAMS_PER_KEY + 2];
    char buf[4096];
    for (int i = 0; i < HTTP_STREAMS_PER_KEY; i++) {
        fd[i] = open_stream(KEY_B, buf, sizeof(buf));
        T_TRUE(strstr(buf, "HTTP/1.1 200") != NULL);
    }
    fd[HTTP_STREAMS_PER_KEY] = open_stream(KEY_B, buf, sizeof(buf));
    bool refused = strstr(buf, "HTTP/1.1 429") != NULL;
    /* another key's streams are its own */
    fd[HTTP_STREAMS_PER_KEY + 1] = open_stream(KEY_A, buf, sizeof(buf));
    bool other = strstr(buf, "HTTP/1.1 200") != NULL;
    for (int i = 0; i < HTTP_STREAMS_PER_KEY + 2; i++)
        close(fd[i]);
    stop();
    T_TRUE(refused);
    T_TRUE(other);
}

T_CASE(http_idle_keep_alive_connection_is_closed)
{
    struct sf_err err;
    T_OK(start(0, 1, &err), &err);
    char buf[4096];
    int fd = open_get("/ok", KEY_A, 0, buf, sizeof(buf));
    bool answered = strstr(buf, "HTTP/1.1 200") != NULL;
    bool closed = read_to_close(fd); /* idle past 1 s: the server ends it */
    close(fd);
    stop();
    T_TRUE(answered);
    T_TRUE(closed);
}

T_CASE(http_stream_whose_client_reads_nothing_is_closed)
{
    struct sf_err err;
    atomic_store(&flood_freed, false);
    T_OK(start(0, 1, &err), &err);
    char buf[4096];
    int fd = open_get("/flood", KEY_A, 4096, buf, sizeof(buf));
    bool answered = strstr(buf, "HTTP/1.1 200") != NULL;
    /* read nothing more: the socket fills, no byte can be written, and
       the idle limit (1 s) ends the stream */
    for (int i = 0; i < 2000 && !atomic_load(&flood_freed); i++)
        usleep(10000);
    bool freed = atomic_load(&flood_freed);
    close(fd);
    stop();
    T_TRUE(answered);
    T_TRUE(freed);
}
