/*
 * sim_http.c - libmicrohttpd on our loop for the simulated network
 * printers (sim_http.h).
 *
 * MHD runs in external epoll mode: its epoll fd is watched for reading and
 * its timeout is a loop timer, exactly as src/api/http_loop.c does for the
 * daemon (sim/ may use only src/base, so the dozen lines are repeated
 * here).  Each request gets a struct sim_http_req on MHD's first call,
 * where the route, the key and the 5xx faults are checked; body chunks go
 * to memory, MHD's post processor (multipart) or a temporary file; the
 * last call runs the handler and queues its reply, or, with the slow
 * fault, suspends the connection and queues it from a timer.
 *
 * Thread: the loop thread.
 */
#include "sim_http.h"

#include <errno.h>
#include <fcntl.h>
#include <microhttpd.h>
#include <netinet/in.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/random.h>
#include <unistd.h>

#include "../../src/base/buf.h"
#include "../../src/base/mem.h"

#define FIELDS_MAX         16 /* text fields kept per form */
#define OUT_HEADERS_MAX    8  /* reply headers a handler may add */
#define UPLOAD_MAX_DEFAULT ((uint64_t)1 << 30)

struct sim_http {
    struct loop *l;
    struct sim_http_config cfg;
    struct MHD_Daemon *d;
    int epfd;       /* MHD's epoll fd */
    uint64_t timer; /* MHD's timeout */
    int port;
    uint64_t served; /* replies queued */
    long n_requests; /* requests begun (faults count these) */
    long n_uploads;  /* uploads begun */
    char digest_random[32];
    struct sim_http_req *slow; /* requests suspended by the slow fault */
    bool outage_fired;         /* the outage fault began (once a run) */
    bool down;                 /* ... and every request answers 503 */
    bool outage_over;          /* ... and the job has ended since */
    long outage_refused;       /* requests refused in the outage */
};

struct field {
    char *name;
    struct buf value;
};

struct sim_http_req {
    struct sim_http *h;
    struct MHD_Connection *c;
    const struct sim_http_route *route;
    const char *method, *path, *rest;
    struct buf body;              /* SIM_HTTP_BODY_MEM */
    bool too_big;                 /* the body passed its cap */
    struct MHD_PostProcessor *pp; /* SIM_HTTP_BODY_FORM */
    struct field fields[FIELDS_MAX];
    size_t n_fields;
    int fd;             /* upload temporary file, -1 if none */
    char tmp_path[640]; /* its path ("" when kept or none) */
    char file_field[64], filename[256];
    struct sim_http_file file;
    bool have_file;
    bool write_failed;
    uint64_t received; /* body bytes so far */
    uint64_t drop_at;  /* > 0: cut the connection past this many bytes */
    char *out_hdr[OUT_HEADERS_MAX][2];
    size_t n_out_hdr;
    struct MHD_Response *resp; /* the reply, once made */
    unsigned status;
    bool replied;
    bool suspended; /* waiting for the slow fault's timer */
    long upload_n;  /* an upload: its number (1-based), for the upload faults */
    bool resumed;   /* the timer fired: queue resp now */
    uint64_t slow_timer;
    struct sim_http_req *slow_next; /* in h->slow */
    sim_http_upgrade_fn up_fn;      /* sim_http_reply_upgrade: who takes the socket */
    void *up_ud;
    int up_tag;
};

static void
slow_unlink(struct sim_http_req *r)
{
    for (struct sim_http_req **pp = &r->h->slow; *pp; pp = &(*pp)->slow_next)
        if (*pp == r) {
            *pp = r->slow_next;
            return;
        }
}

/* ---- faults ---------------------------------------------------------- */

static int
parse_num(const char *v, long lo, long hi, long *out)
{
    char *end;
    errno = 0;
    long n = strtol(v, &end, 10);
    if (errno || end == v || n < lo || n > hi)
        return -1;
    *out = n;
    return (int)(end - v);
}

int
sim_http_fault_parse(struct sim_http_faults *f, const char *spec, struct sf_err *err)
{
    const char *eq = strchr(spec, '=');
    if (!eq)
        return sf_err_set(err, SF_EINVAL, "fault '%s': expected NAME=VALUE", spec);
    size_t nl = (size_t)(eq - spec);
    const char *v = eq + 1;
    long n, k = 0;
    int used;
    if (nl == 3 && strncmp(spec, "5xx", 3) == 0) {
        if ((used = parse_num(v, 1, 1000000, &n)) < 0 ||
            (v[used] && (v[used] != '@' || parse_num(v + used + 1, 0, 1000000000, &k) < 0)))
            return sf_err_set(err, SF_EINVAL, "fault '%s': expected 5xx=N or 5xx=N@K", spec);
        f->err5xx_count = n;
        f->err5xx_after = k;
        return SF_OK;
    }
    if (nl == 11 && strncmp(spec, "slow-upload", 11) == 0) {
        if ((used = parse_num(v, 1, 600000, &n)) < 0 ||
            (v[used] && (v[used] != '@' || parse_num(v + used + 1, 1, 1000000000, &k) < 0)))
            return sf_err_set(err, SF_EINVAL,
                              "fault '%s': expected slow-upload=MS or slow-upload=MS@N", spec);
        f->slow_upload_ms = (int)n;
        f->slow_uploads = k;
        return SF_OK;
    }
    const char *names[] = { "slow", "drop-upload", "drop", "outage" };
    for (int i = 0; i < 4; i++) {
        if (strlen(names[i]) != nl || strncmp(spec, names[i], nl) != 0)
            continue;
        if ((used = parse_num(v, 1, 1000000000, &n)) < 0 || v[used])
            return sf_err_set(err, SF_EINVAL, "fault '%s': expected a whole number above 0", spec);
        if (i == 0)
            f->slow_ms = (int)(n > 600000 ? 600000 : n);
        else if (i == 1)
            f->drop_upload = n;
        else if (i == 2)
            f->drop_request = n;
        else
            f->outage_line = n;
        return SF_OK;
    }
    return sf_err_set(err, SF_EUNSUPP, "fault '%s' is not an HTTP fault", spec);
}

/* ---- the loop -------------------------------------------------------- */

static void on_timer(struct loop *l, void *ud);

static void
kick(struct sim_http *h)
{
    MHD_run(h->d);
    if (h->timer)
        loop_timer_cancel(h->l, h->timer);
    h->timer = 0;
    MHD_UNSIGNED_LONG_LONG ms;
    if (MHD_get_timeout(h->d, &ms) == MHD_YES)
        h->timer = loop_timer_add(h->l, (int64_t)(ms > 60000 ? 60000 : ms), on_timer, h);
}

static void
on_timer(struct loop *l, void *ud)
{
    (void)l;
    struct sim_http *h = ud;
    h->timer = 0;
    kick(h);
}

static void
on_fd(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)l, (void)fd, (void)events;
    kick(ud);
}

/* ---- replies --------------------------------------------------------- */

static void
make_reply(struct sim_http_req *r, unsigned status, const char *type, void *body, size_t len,
           enum MHD_ResponseMemoryMode mode)
{
    if (r->replied) {
        if (mode == MHD_RESPMEM_MUST_FREE)
            free(body);
        return;
    }
    r->replied = true;
    r->status = status;
    r->resp = MHD_create_response_from_buffer(len, body, mode);
    if (!r->resp)
        return;
    if (type)
        MHD_add_response_header(r->resp, "Content-Type", type);
    for (size_t i = 0; i < r->n_out_hdr; i++)
        MHD_add_response_header(r->resp, r->out_hdr[i][0], r->out_hdr[i][1]);
}

void
sim_http_add_header(struct sim_http_req *r, const char *name, const char *value)
{
    if (r->n_out_hdr == OUT_HEADERS_MAX)
        return;
    r->out_hdr[r->n_out_hdr][0] = mem_strdup(name);
    r->out_hdr[r->n_out_hdr][1] = mem_strdup(value);
    r->n_out_hdr++;
}

void
sim_http_reply(struct sim_http_req *r, unsigned status, const char *type, const char *body,
               size_t len)
{
    make_reply(r, status, type, (void *)body, len, MHD_RESPMEM_MUST_COPY);
}

void
sim_http_reply_json(struct sim_http_req *r, unsigned status, json_t *value)
{
    char *text = value ? json_dumps(value, JSON_COMPACT) : NULL;
    json_decref(value);
    if (!text) {
        make_reply(r, status, NULL, (void *)"", 0, MHD_RESPMEM_PERSISTENT);
        return;
    }
    make_reply(r, status, "application/json", text, strlen(text), MHD_RESPMEM_MUST_FREE);
}

void
sim_http_reply_empty(struct sim_http_req *r, unsigned status)
{
    make_reply(r, status, NULL, (void *)"", 0, MHD_RESPMEM_PERSISTENT);
}

void
sim_http_reply_error(struct sim_http_req *r, unsigned status, const char *text)
{
    sim_http_reply_json(r, status, json_pack("{s:s}", "error", text));
}

/* MHD sent the 101: hand the socket on (con_cls is still our request). */
static void
on_upgraded(void *cls, struct MHD_Connection *c, void *con_cls, const char *extra_in,
            size_t extra_in_size, MHD_socket sock, struct MHD_UpgradeResponseHandle *urh)
{
    (void)cls, (void)c;
    struct sim_http_req *r = con_cls;
    int fl = fcntl(sock, F_GETFL);
    if (fl >= 0)
        fcntl(sock, F_SETFL, fl | O_NONBLOCK);
    r->up_fn((struct sim_http_upgraded *)urh, sock, extra_in, extra_in_size, r->up_ud, r->up_tag);
}

void
sim_http_reply_upgrade(struct sim_http_req *r, sim_http_upgrade_fn fn, void *ud, int tag)
{
    if (r->replied)
        return;
    r->replied = true;
    r->status = MHD_HTTP_SWITCHING_PROTOCOLS;
    r->up_fn = fn;
    r->up_ud = ud;
    r->up_tag = tag;
    r->resp = MHD_create_response_for_upgrade(on_upgraded, r->h);
    if (!r->resp)
        return;
    for (size_t i = 0; i < r->n_out_hdr; i++)
        MHD_add_response_header(r->resp, r->out_hdr[i][0], r->out_hdr[i][1]);
}

void
sim_http_upgraded_close(struct sim_http_upgraded *u)
{
    MHD_upgrade_action((struct MHD_UpgradeResponseHandle *)u, MHD_UPGRADE_ACTION_CLOSE);
}

static enum MHD_Result
queue(struct sim_http_req *r)
{
    if (!r->resp)
        return MHD_NO;
    enum MHD_Result ret = MHD_queue_response(r->c, r->status, r->resp);
    MHD_destroy_response(r->resp);
    r->resp = NULL;
    r->h->served++;
    return ret;
}

/* ---- request accessors ----------------------------------------------- */

const char *
sim_http_method(const struct sim_http_req *r)
{
    return r->method;
}

const char *
sim_http_path(const struct sim_http_req *r)
{
    return r->path;
}

const char *
sim_http_rest(const struct sim_http_req *r)
{
    return r->rest ? r->rest : "";
}

const char *
sim_http_query(const struct sim_http_req *r, const char *name)
{
    return MHD_lookup_connection_value(r->c, MHD_GET_ARGUMENT_KIND, name);
}

const char *
sim_http_header(const struct sim_http_req *r, const char *name)
{
    return MHD_lookup_connection_value(r->c, MHD_HEADER_KIND, name);
}

const char *
sim_http_field(const struct sim_http_req *r, const char *name)
{
    for (size_t i = 0; i < r->n_fields; i++)
        if (strcmp(r->fields[i].name, name) == 0)
            return r->fields[i].value.data ? r->fields[i].value.data : "";
    return NULL;
}

const char *
sim_http_body(const struct sim_http_req *r, size_t *len)
{
    if (len)
        *len = r->body.len;
    return r->body.data ? r->body.data : "";
}

json_t *
sim_http_json(const struct sim_http_req *r, struct sf_err *err)
{
    json_error_t je;
    json_t *v = json_loadb(r->body.data ? r->body.data : "", r->body.len, 0, &je);
    if (!v) {
        sf_err_set(err, SF_EINVAL, "body is not JSON: %s", je.text);
        return NULL;
    }
    if (!json_is_object(v)) {
        json_decref(v);
        sf_err_set(err, SF_EINVAL, "body is not a JSON object");
        return NULL;
    }
    return v;
}

const struct sim_http_file *
sim_http_upload(const struct sim_http_req *r)
{
    return r->have_file && !r->write_failed ? &r->file : NULL;
}

int
sim_http_keep_upload(struct sim_http_req *r, const char *path, struct sf_err *err)
{
    if (!r->have_file || !r->tmp_path[0])
        return sf_err_set(err, SF_EINVAL, "no upload to keep");
    if (r->fd >= 0) {
        close(r->fd);
        r->fd = -1;
    }
    if (rename(r->tmp_path, path) < 0)
        return sf_err_sys(err, "keep upload as '%s'", path);
    r->tmp_path[0] = 0;
    return SF_OK;
}

/* ---- request intake -------------------------------------------------- */

static int
open_upload(struct sim_http_req *r)
{
    snprintf(r->tmp_path, sizeof(r->tmp_path), "%s/.upload-XXXXXX",
             r->h->cfg.upload_dir ? r->h->cfg.upload_dir : "/tmp");
    r->fd = mkstemp(r->tmp_path);
    if (r->fd < 0) {
        r->tmp_path[0] = 0;
        r->write_failed = true;
        return -1;
    }
    r->have_file = true;
    r->file.field = r->file_field;
    r->file.filename = r->filename;
    r->file.path = r->tmp_path;
    return 0;
}

static void
write_upload(struct sim_http_req *r, const char *data, size_t size)
{
    uint64_t max = r->h->cfg.upload_max ? r->h->cfg.upload_max : UPLOAD_MAX_DEFAULT;
    if (r->fd < 0 || r->write_failed)
        return;
    if (r->file.size + size > max) {
        r->too_big = true;
        return;
    }
    while (size) {
        ssize_t k = write(r->fd, data, size);
        if (k < 0 && errno == EINTR)
            continue;
        if (k <= 0) {
            r->write_failed = true;
            return;
        }
        data += k;
        size -= (size_t)k;
        r->file.size += (uint64_t)k;
    }
}

static enum MHD_Result
post_iter(void *cls, enum MHD_ValueKind kind, const char *key, const char *filename,
          const char *content_type, const char *transfer_encoding, const char *data, uint64_t off,
          size_t size)
{
    (void)kind, (void)content_type, (void)transfer_encoding, (void)off;
    struct sim_http_req *r = cls;
    if (!key)
        return MHD_YES;
    if (filename) {
        if (!r->have_file && !r->write_failed) {
            snprintf(r->file_field, sizeof(r->file_field), "%s", key);
            snprintf(r->filename, sizeof(r->filename), "%s", filename);
            open_upload(r);
        }
        if (r->have_file && strcmp(key, r->file_field) == 0)
            write_upload(r, data, size);
        return MHD_YES;
    }
    struct field *f = NULL;
    for (size_t i = 0; i < r->n_fields; i++)
        if (strcmp(r->fields[i].name, key) == 0)
            f = &r->fields[i];
    if (!f && r->n_fields < FIELDS_MAX) {
        f = &r->fields[r->n_fields];
        f->name = mem_strdup(key);
        if (!f->name)
            return MHD_YES;
        buf_init(&f->value, SIM_HTTP_FIELD_MAX);
        r->n_fields++;
    }
    if (f && size && buf_append(&f->value, data, size) < 0)
        r->too_big = true;
    return MHD_YES;
}

static const struct sim_http_route *
find_route(const struct sim_http *h, const char *method, const char *path, bool *path_known,
           const char **rest)
{
    *path_known = false;
    for (size_t i = 0; i < h->cfg.n_routes; i++) {
        const struct sim_http_route *rt = &h->cfg.routes[i];
        size_t n = strlen(rt->path);
        bool match;
        if (n && rt->path[n - 1] == '*') {
            match = strncmp(path, rt->path, n - 1) == 0;
            if (match)
                *rest = path + n - 1;
        } else {
            match = strcmp(path, rt->path) == 0;
            *rest = NULL;
        }
        if (!match)
            continue;
        *path_known = true;
        if (strcmp(method, rt->method) == 0)
            return rt;
    }
    return NULL;
}

/* The first call: route, faults, key.  False when a reply is already made. */
static bool
admit(struct sim_http_req *r)
{
    struct sim_http *h = r->h;
    const struct sim_http_faults *f = &h->cfg.faults;
    long k = h->n_requests;
    if (h->down) {
        if (++h->outage_refused >= SIM_HTTP_OUTAGE_MIN && h->outage_over)
            h->down = false;
        sim_http_reply_error(r, 503, "Service Unavailable (simulated outage)");
        return false;
    }
    if (f->err5xx_count && k > f->err5xx_after && k <= f->err5xx_after + f->err5xx_count) {
        sim_http_reply_error(r, 503, "Service Unavailable (simulated fault)");
        return false;
    }
    bool known;
    r->route = find_route(h, r->method, r->path, &known, &r->rest);
    if (!r->route) {
        sim_http_reply_error(r, known ? 405 : 404, known ? "Method Not Allowed" : "Not Found");
        return false;
    }
    if (!r->route->open && h->cfg.api_key) {
        const char *got = MHD_lookup_connection_value(
            r->c, MHD_HEADER_KIND, h->cfg.key_header ? h->cfg.key_header : "X-Api-Key");
        if (!got || strcmp(got, h->cfg.api_key) != 0) {
            const char *body =
                h->cfg.auth_body ? h->cfg.auth_body : "{\"error\":\"Invalid API key\"}";
            sim_http_reply(r, h->cfg.auth_status ? (unsigned)h->cfg.auth_status : 403,
                           "application/json", body, strlen(body));
            return false;
        }
    }
    if (!r->route->open && h->cfg.digest_user) {
        const char *realm = h->cfg.realm ? h->cfg.realm : "Printer API";
        char *user = MHD_digest_auth_get_username(r->c);
        int ok = user && strcmp(user, h->cfg.digest_user) == 0 &&
                 MHD_digest_auth_check(r->c, realm, h->cfg.digest_user,
                                       h->cfg.digest_password ? h->cfg.digest_password : "",
                                       300) == MHD_YES;
        MHD_free(user);
        if (!ok) {
            static const char denied[] = "{\"error\":\"Unauthorized\"}";
            struct MHD_Response *resp = MHD_create_response_from_buffer(
                sizeof(denied) - 1, (void *)denied, MHD_RESPMEM_PERSISTENT);
            MHD_add_response_header(resp, "Content-Type", "application/json");
            MHD_queue_auth_fail_response(r->c, realm, "slimfarm-sim", resp, MHD_NO);
            MHD_destroy_response(resp);
            r->replied = true;
            h->served++;
            return false;
        }
    }
    bool upload = r->route->body != SIM_HTTP_BODY_MEM;
    if (upload) {
        r->upload_n = ++h->n_uploads;
        if (f->drop_upload && h->n_uploads <= f->drop_upload) {
            const char *cl = MHD_lookup_connection_value(r->c, MHD_HEADER_KIND, "Content-Length");
            uint64_t len = cl ? strtoull(cl, NULL, 10) : 0;
            r->drop_at = len && len / 2 < 65536 ? len / 2 : 65536;
            if (!r->drop_at)
                r->drop_at = 1;
        }
    }
    if (r->route->body == SIM_HTTP_BODY_FORM)
        r->pp = MHD_create_post_processor(r->c, 65536, post_iter, r);
    else if (r->route->body == SIM_HTTP_BODY_FILE)
        open_upload(r);
    return true;
}

static void
on_slow(struct loop *l, void *ud)
{
    (void)l;
    struct sim_http_req *r = ud;
    r->slow_timer = 0;
    r->resumed = true;
    slow_unlink(r);
    MHD_resume_connection(r->c);
    kick(r->h);
}

static enum MHD_Result
on_request(void *cls, struct MHD_Connection *c, const char *url, const char *method,
           const char *version, const char *data, size_t *size, void **con_cls)
{
    (void)version;
    struct sim_http *h = cls;
    struct sim_http_req *r = *con_cls;
    if (!r) {
        r = mem_calloc(1, sizeof(*r));
        if (!r)
            return MHD_NO;
        *con_cls = r;
        r->h = h;
        r->c = c;
        r->method = method;
        r->path = url;
        r->fd = -1;
        buf_init(&r->body, SIM_HTTP_BODY_MAX);
        h->n_requests++;
        if (h->cfg.faults.drop_request && h->n_requests == h->cfg.faults.drop_request)
            return MHD_NO; /* cut, unanswered */
        if (!admit(r))
            return r->resp ? queue(r) : MHD_YES;
        return MHD_YES;
    }
    if (*size) {
        if (r->replied) { /* an early reply: the body is not wanted */
            *size = 0;
            return MHD_YES;
        }
        if (r->drop_at && r->received + *size >= r->drop_at)
            return MHD_NO; /* the connection drops half-way through the upload */
        r->received += *size;
        if (r->route->body == SIM_HTTP_BODY_MEM) {
            if (buf_append(&r->body, data, *size) < 0)
                r->too_big = true;
        } else if (r->pp) {
            MHD_post_process(r->pp, data, *size);
        } else if (r->route->body == SIM_HTTP_BODY_FILE) {
            write_upload(r, data, *size);
        }
        *size = 0;
        return MHD_YES;
    }
    if (r->resumed)
        return queue(r);
    if (r->suspended || r->replied)
        return MHD_YES;
    if (r->fd >= 0) {
        close(r->fd);
        r->fd = -1;
    }
    if (r->too_big)
        sim_http_reply_error(r, 413, "Request body too large");
    else if (r->write_failed)
        sim_http_reply_error(r, 500, "Could not store the upload");
    else
        r->route->fn(r, h->cfg.ud);
    if (!r->replied)
        sim_http_reply_error(r, 500, "handler did not reply");
    int late = h->cfg.faults.slow_ms;
    if (r->route->body != SIM_HTTP_BODY_MEM && r->upload_n > 0 &&
        (!h->cfg.faults.slow_uploads || r->upload_n <= h->cfg.faults.slow_uploads) &&
        h->cfg.faults.slow_upload_ms > late)
        late = h->cfg.faults.slow_upload_ms; /* the handler ran: a print it started is on */
    if (late > 0) {
        r->suspended = true;
        MHD_suspend_connection(c);
        r->slow_timer = loop_timer_add(h->l, late, on_slow, r);
        r->slow_next = h->slow;
        h->slow = r;
        return MHD_YES;
    }
    return queue(r);
}

static void
on_completed(void *cls, struct MHD_Connection *c, void **con_cls,
             enum MHD_RequestTerminationCode toe)
{
    (void)c, (void)toe;
    struct sim_http *h = cls;
    struct sim_http_req *r = *con_cls;
    if (!r)
        return;
    *con_cls = NULL;
    if (r->slow_timer)
        loop_timer_cancel(h->l, r->slow_timer);
    if (r->suspended && !r->resumed)
        slow_unlink(r);
    if (r->pp)
        MHD_destroy_post_processor(r->pp);
    if (r->fd >= 0)
        close(r->fd);
    if (r->tmp_path[0])
        unlink(r->tmp_path);
    if (r->resp)
        MHD_destroy_response(r->resp);
    for (size_t i = 0; i < r->n_fields; i++) {
        free(r->fields[i].name);
        buf_release(&r->fields[i].value);
    }
    for (size_t i = 0; i < r->n_out_hdr; i++) {
        free(r->out_hdr[i][0]);
        free(r->out_hdr[i][1]);
    }
    buf_release(&r->body);
    free(r);
}

/* ---- lifecycle ------------------------------------------------------- */

struct sim_http *
sim_http_new(struct loop *l, const struct sim_http_config *c, struct sf_err *err)
{
    struct sim_http *h = mem_calloc(1, sizeof(*h));
    if (!h) {
        sf_err_set(err, SF_ENOMEM, "sim: out of memory");
        return NULL;
    }
    h->l = l;
    h->cfg = *c;
    if (getrandom(h->digest_random, sizeof(h->digest_random), 0) < 0)
        memset(h->digest_random, 0x5a, sizeof(h->digest_random));
    struct sockaddr_in sa = { .sin_family = AF_INET,
                              .sin_port = htons((uint16_t)c->port),
                              .sin_addr.s_addr = htonl(INADDR_LOOPBACK) };
    h->d = MHD_start_daemon(
        MHD_USE_EPOLL | MHD_ALLOW_SUSPEND_RESUME | MHD_ALLOW_UPGRADE, (uint16_t)c->port, NULL, NULL,
        on_request, h, MHD_OPTION_NOTIFY_COMPLETED, on_completed, h, MHD_OPTION_SOCK_ADDR, &sa,
        MHD_OPTION_CONNECTION_TIMEOUT, 120u, MHD_OPTION_DIGEST_AUTH_RANDOM,
        sizeof(h->digest_random), h->digest_random, MHD_OPTION_NONCE_NC_SIZE, 256u, MHD_OPTION_END);
    if (!h->d) {
        sf_err_set(err, SF_EIO, "sim: cannot listen on 127.0.0.1:%d", c->port);
        free(h);
        return NULL;
    }
    const union MHD_DaemonInfo *pi = MHD_get_daemon_info(h->d, MHD_DAEMON_INFO_BIND_PORT);
    const union MHD_DaemonInfo *ei = MHD_get_daemon_info(h->d, MHD_DAEMON_INFO_EPOLL_FD);
    h->port = pi ? pi->port : c->port;
    h->epfd = ei ? ei->epoll_fd : -1;
    if (h->epfd < 0 || loop_add_fd(l, h->epfd, LOOP_READ, on_fd, h, err) < 0) {
        if (h->epfd < 0)
            sf_err_set(err, SF_EIO, "sim: http server has no epoll fd");
        MHD_stop_daemon(h->d);
        free(h);
        return NULL;
    }
    kick(h);
    return h;
}

void
sim_http_free(struct sim_http *h)
{
    if (!h)
        return;
    loop_del_fd(h->l, h->epfd);
    if (h->timer)
        loop_timer_cancel(h->l, h->timer);
    /* MHD cannot stop with suspended connections: let them go first. */
    while (h->slow) {
        struct sim_http_req *r = h->slow;
        h->slow = r->slow_next;
        loop_timer_cancel(h->l, r->slow_timer);
        r->slow_timer = 0;
        r->resumed = true;
        MHD_resume_connection(r->c);
    }
    MHD_run(h->d);
    MHD_stop_daemon(h->d); /* runs on_completed for every open request */
    free(h);
}

void
sim_http_outage_watch(struct sim_http *h, bool running, uint64_t lines_done)
{
    if (!h->cfg.faults.outage_line)
        return;
    if (!h->outage_fired && running && lines_done >= (uint64_t)h->cfg.faults.outage_line) {
        h->outage_fired = h->down = true;
    } else if (h->down && !running) {
        h->outage_over = true;
        if (h->outage_refused >= SIM_HTTP_OUTAGE_MIN)
            h->down = false;
    }
}

bool
sim_http_refusing(const struct sim_http *h)
{
    const struct sim_http_faults *f = &h->cfg.faults;
    long k = h->n_requests;
    return h->down ||
           (f->err5xx_count && k > f->err5xx_after && k < f->err5xx_after + f->err5xx_count);
}

int
sim_http_port(const struct sim_http *h)
{
    return h->port;
}

uint64_t
sim_http_served(const struct sim_http *h)
{
    return h->served;
}
