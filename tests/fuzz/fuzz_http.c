/*
 * fuzz_http.c - the HTTP server's request handling (http.c over
 * libmicrohttpd: request head, keys, body caps, multipart post processor,
 * upload sink) on arbitrary bytes.  Each input is what one client sends on
 * one connection (a socketpair handed to the server, which listens
 * nowhere); the harness runs the server until the connection closes.
 */
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include "../../src/api/http.h"
#include "../../src/base/log.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

#define FUZZ_KEY_RW "rw-key-0123456789abcdef"
#define FUZZ_KEY_RO "ro-key-0123456789abcdef"

/* An upload sink that keeps only a byte count. */
struct fake_upload {
    size_t n;
};

static void *
fz_begin(void *ud, const char *filename, struct sf_err *err)
{
    (void)ud;
    if (!filename[0]) {
        sf_err_set(err, SF_EINVAL, "empty file name");
        return NULL;
    }
    struct fake_upload *u = calloc(1, sizeof(*u));
    if (!u)
        sf_err_set(err, SF_ENOMEM, "out of memory");
    return u;
}

static int
fz_write(void *ctx, const char *data, size_t len, struct sf_err *err)
{
    (void)data, (void)err;
    ((struct fake_upload *)ctx)->n += len;
    return SF_OK;
}

static int
fz_finish(void *ctx, struct sf_err *err)
{
    return ((struct fake_upload *)ctx)->n ? SF_OK : sf_err_set(err, SF_EINVAL, "empty file");
}

static void
fz_discard(void *ctx)
{
    free(ctx);
}

static const struct http_upload_sink fz_sink = { fz_begin, fz_write, fz_finish, fz_discard };

static enum http_body
fz_body(void *ud, const char *method, const char *path)
{
    (void)ud;
    if (strcmp(method, "POST") == 0 && strcmp(path, "/api/jobs") == 0)
        return HTTP_BODY_UPLOAD;
    return strcmp(method, "PATCH") == 0 ? HTTP_BODY_JSON : HTTP_BODY_NONE;
}

/* Echo what the route saw, as the API's errors echo client text. */
static void
fz_route(void *ud, const struct http_req *req, struct http_resp *resp)
{
    (void)ud;
    if (req->n_fields)
        http_error(resp, 400, "field '%.64s' = '%.80s'", req->field_name[0], req->field_value[0]);
    else if (req->upload_name)
        http_error(resp, 201, "file '%.80s'", req->upload_name);
    else
        http_error(resp, 404, "no such resource: %.100s (%zu bytes)", req->path, req->body_len);
}

static struct http *server;

static struct http *
server_get(void)
{
    if (server)
        return server;
    log_set_level(LOG_WARN); /* MHD's notes on every closed socket */
    static const struct farmcfg_key keys[2] = { { FUZZ_KEY_RW, false, false },
                                                { FUZZ_KEY_RO, true, false } };
    struct http_config cfg = { .host = "127.0.0.1",
                               .port = -1,
                               .keys = keys,
                               .n_keys = 2,
                               .body_max = 4096,
                               .upload_max = 32768,
                               .route = fz_route,
                               .body_kind = fz_body,
                               .sink = &fz_sink };
    server = http_new(&cfg, NULL);
    return server;
}

int
LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct http *h = server_get();
    int sv[2];
    if (!h || socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, sv) != 0)
        return 0;
    fcntl(sv[0], F_SETFL, O_NONBLOCK);
    if (http_add_connection(h, sv[1]) != SF_OK) {
        close(sv[0]);
        return 0;
    }
    size_t off = 0;
    bool eof = false;
    char sink[8192];
    /* Feed the input, run the server, read what it answers; the client
       half-closes once everything is sent.  The server is left once it
       closes, or once it is idle (its epoll fd not readable, no work queued
       for now, nothing answered) after the client has sent everything: it
       then waits for bytes that never come, which only its connection
       time-out would end.  Spinning on such a connection for the whole turn
       budget cost 2000 recv+epoll_wait pairs an input (74 exec/s). */
    int idle = 0;
    for (int turn = 0; turn < 2000 && !eof && idle < 2; turn++) {
        if (off < size) {
            ssize_t w = send(sv[0], data + off, size - off, MSG_NOSIGNAL);
            if (w > 0)
                off += (size_t)w;
            else if (w < 0 && errno != EAGAIN)
                off = size;
            if (off == size)
                shutdown(sv[0], SHUT_WR);
        } else if (size == 0 && turn == 0) {
            shutdown(sv[0], SHUT_WR);
        }
        http_run(h);
        ssize_t r;
        bool answered = false;
        while ((r = recv(sv[0], sink, sizeof(sink), 0)) > 0) {
            answered = true;
            if (getenv("FUZZ_HTTP_ECHO"))
                fwrite(sink, 1, (size_t)r, stderr);
        }
        eof = r == 0;
        struct pollfd pfd = { .fd = http_fd(h), .events = POLLIN };
        bool quiet = off == size && !answered && http_timeout_ms(h) != 0 && poll(&pfd, 1, 0) == 0;
        idle = quiet ? idle + 1 : 0;
    }
    close(sv[0]);
    for (int turn = 0; turn < 4; turn++)
        http_run(h); /* let the server see the close */
    return 0;
}
