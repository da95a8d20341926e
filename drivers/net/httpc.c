/*
 * httpc.c - libcurl's multi interface on our event loop (httpc.h).
 *
 * curl tells us which sockets to watch (socket_cb) and when it next wants
 * a turn (timer_cb); the loop calls back on_fd/on_timeout, which hand the
 * event to curl_multi_socket_action, then collect finished transfers with
 * curl_multi_info_read and call their done callbacks.
 *
 * Re-entrancy is the delicate part.  curl forbids removing or adding easy
 * handles from within its own callbacks (read, write, progress, socket,
 * timer), and our users may cancel or start requests from anywhere,
 * including their progress callbacks.  So while we are inside curl
 * (depth > 0) a cancel only marks the request (its progress and read
 * callbacks then abort the transfer) and a start only queues it; a
 * zero-delay loop timer (the "sweep") then removes the cancelled and adds
 * the queued, outside curl.  Finished transfers are first all taken off
 * the multi handle and moved to a done list, then their callbacks run one
 * by one, so a done callback may cancel another finished request (it is
 * then freed unreported) or start new ones.
 *
 * Thread: the loop thread; the shared-client registry has its own lock.
 */
#include "httpc.h"

#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>

#include "../../src/base/buf.h"
#include "../../src/base/log.h"
#include "../../src/base/mem.h"

struct httpc {
    struct loop *l;            /* the loop we run on */
    CURLM *multi;              /* the one multi handle */
    uint64_t timer;            /* curl's timeout as a loop timer, 0 if none */
    uint64_t sweep;            /* pending sweep timer, 0 if none */
    uint64_t kick;             /* FTP set-up kick timer (kick()), 0 if none */
    int depth;                 /* > 0 while inside a curl_multi_* call */
    bool nudging;              /* inside nudge(): its own REMOVEs ask for no other */
    struct httpc_req *reqs;    /* every live request (doubly linked) */
    struct httpc_req *done;    /* finished requests awaiting their callback (singly linked) */
    size_t n_active;           /* live requests not cancelled and not yet reported */
    int refs;                  /* shared client: references; 0 for a private one */
    struct httpc *next_shared; /* shared registry link */
};

/*
 * One multipart file part, read by us (curl_mime_data_cb) rather than by
 * curl (curl_mime_filedata) only to count how far curl read it: curl
 * rewinds a form body to send it again on a reused connection that died
 * (part_seek), so the most read in any attempt is what a server can have
 * had of it (httpc_result.body_read).
 */
struct part_file {
    struct httpc_req *r; /* the request, for its cancel flag and file error */
    FILE *fp;            /* the open file */
    char *path;          /* its path, for messages */
    uint64_t pos;        /* bytes handed to curl since the last rewind */
    uint64_t most;       /* the most pos has been */
};

struct httpc_req {
    struct httpc *h;               /* owner */
    CURL *easy;                    /* the transfer */
    struct httpc_req *prev, *next; /* in h->reqs */
    struct httpc_req *next_done;   /* in h->done */
    bool added;                    /* in the multi handle */
    bool cancelled;                /* httpc_cancel called: never report */
    bool finished;                 /* curl is done with it; on the done list */
    bool in_done;                  /* its done callback is running */
    bool nudge;                    /* curl dropped one of its sockets mid-transfer: see nudge() */
    bool ftp;                      /* ftp:// or ftps:// (kick()) */
    bool body_started;             /* read_cb has been asked for body bytes */
    CURLcode result;               /* curl's result once finished */
    struct curl_slist *hdrs;       /* request headers */
    curl_mime *mime;               /* multipart body, or NULL */
    char *body;                    /* copied memory body, or NULL */
    size_t body_len, body_off;     /* its size and how much was read (PUT from memory) */
    FILE *fp;                      /* streamed body file, or NULL */
    char *body_path;               /* its path, for messages */
    bool file_err;                 /* reading fp or a part's file failed */
    const char *err_path;          /* the file that failed (body_path or a part's) */
    uint64_t fp_read;              /* bytes of fp handed to curl (no seek callback: never
                                      rewound, so no attempt sent more) */
    struct part_file *files;       /* multipart file parts, streamed by part_read */
    size_t n_files;                /* their count */
    struct buf resp;               /* response body (capped) */
    struct buf hdr;                /* response headers (capped) */
    bool oversize;                 /* the body passed its cap */
    char method[16];               /* for messages */
    char *url;                     /* for messages */
    long timeout_ms;               /* for messages */
    httpc_done_fn done_fn;         /* completion */
    httpc_progress_fn progress_fn; /* upload progress */
    void *ud;                      /* their argument */
    uint64_t last_sent;            /* last progress reported */
    char errbuf[CURL_ERROR_SIZE];  /* curl's detail */
};

/* FTP set-up kick period (on_kick): a few round trips on a LAN, so a tenth of a second. */
#define FTP_KICK_MS 100

static pthread_once_t global_once = PTHREAD_ONCE_INIT;
static CURLcode global_rc = CURLE_OK;
static pthread_mutex_t shared_lock = PTHREAD_MUTEX_INITIALIZER;
static struct httpc *shared_list; /* shared clients, one per loop that asked */

static void
global_init(void)
{
    global_rc = curl_global_init(CURL_GLOBAL_DEFAULT);
}

static void sweep_soon(struct httpc *h);
static void collect(struct httpc *h);
static void on_kick(struct loop *l, void *ud);

/* ---- curl -> loop ---- */

static void
on_fd(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)l;
    struct httpc *h = ud;
    int mask = 0, running;
    if (events & LOOP_READ)
        mask |= CURL_CSELECT_IN;
    if (events & LOOP_WRITE)
        mask |= CURL_CSELECT_OUT;
    if (events & (LOOP_ERROR | LOOP_HUP))
        mask |= CURL_CSELECT_ERR;
    h->depth++;
    curl_multi_socket_action(h->multi, fd, mask, &running);
    h->depth--;
    collect(h);
}

static void
on_timeout(struct loop *l, void *ud)
{
    (void)l;
    struct httpc *h = ud;
    int running;
    h->timer = 0;
    h->depth++;
    curl_multi_socket_action(h->multi, CURL_SOCKET_TIMEOUT, 0, &running);
    h->depth--;
    collect(h);
}

static int
socket_cb(CURL *easy, curl_socket_t s, int what, void *userp, void *socketp)
{
    struct httpc *h = userp;
    if (what == CURL_POLL_REMOVE) {
        if (socketp)
            loop_del_fd(h->l, s);
        curl_multi_assign(h->multi, s, NULL);
        struct httpc_req *r = NULL;
        if (easy && !h->nudging &&
            curl_easy_getinfo(easy, CURLINFO_PRIVATE, (char **)&r) == CURLE_OK && r &&
            !r->finished && !r->cancelled) {
            r->nudge = true; /* it may have nothing left to wait on: see nudge() */
            sweep_soon(h);
        }
        return 0;
    }
    unsigned ev = 0;
    if (what & CURL_POLL_IN)
        ev |= LOOP_READ;
    if (what & CURL_POLL_OUT)
        ev |= LOOP_WRITE;
    struct sf_err err;
    if (socketp) {
        if (loop_mod_fd(h->l, s, ev, &err) < 0)
            log_warn("http", "%s", err.msg);
        return 0;
    }
    /* A socket curl closed without a REMOVE would leave a stale watch on a
       reused fd number: drop it first. */
    loop_del_fd(h->l, s);
    if (loop_add_fd(h->l, s, ev, on_fd, h, &err) < 0) {
        log_warn("http", "%s", err.msg);
        return -1;
    }
    curl_multi_assign(h->multi, s, h);
    return 0;
}

static int
timer_cb(CURLM *multi, long timeout_ms, void *userp)
{
    (void)multi;
    struct httpc *h = userp;
    if (h->timer)
        loop_timer_cancel(h->l, h->timer);
    h->timer = 0;
    if (timeout_ms >= 0)
        h->timer = loop_timer_add(h->l, timeout_ms, on_timeout, h);
    return 0;
}

/* ---- transfer callbacks (inside curl) ---- */

static size_t
write_cb(char *ptr, size_t size, size_t nmemb, void *ud)
{
    struct httpc_req *r = ud;
    size_t n = size * nmemb;
    if (r->cancelled)
        return 0;
    if (buf_append(&r->resp, ptr, n) < 0) {
        r->oversize = true;
        return 0;
    }
    return n;
}

static size_t
header_cb(char *ptr, size_t size, size_t nmemb, void *ud)
{
    struct httpc_req *r = ud;
    size_t n = size * nmemb;
    /* Each response (a 401 before digest, a 100 Continue) starts a new block. */
    if (n >= 5 && memcmp(ptr, "HTTP/", 5) == 0)
        buf_reset(&r->hdr);
    (void)buf_append(&r->hdr, ptr, n); /* past the cap, later headers are dropped */
    return n;
}

static size_t
read_cb(char *ptr, size_t size, size_t nmemb, void *ud)
{
    struct httpc_req *r = ud;
    size_t want = size * nmemb;
    r->body_started = true;
    if (r->cancelled)
        return CURL_READFUNC_ABORT;
    if (r->fp) {
        size_t got = fread(ptr, 1, want, r->fp);
        if (got < want && ferror(r->fp)) {
            r->file_err = true;
            r->err_path = r->body_path;
            return CURL_READFUNC_ABORT;
        }
        r->fp_read += got;
        return got;
    }
    size_t left = r->body_len - r->body_off;
    size_t n = left < want ? left : want;
    if (n)
        memcpy(ptr, r->body + r->body_off, n);
    r->body_off += n;
    return n;
}

static size_t
part_read(char *ptr, size_t size, size_t nmemb, void *ud)
{
    struct part_file *pf = ud;
    struct httpc_req *r = pf->r;
    r->body_started = true;
    if (r->cancelled)
        return CURL_READFUNC_ABORT;
    size_t want = size * nmemb;
    size_t got = fread(ptr, 1, want, pf->fp);
    if (got < want && ferror(pf->fp)) {
        r->file_err = true;
        r->err_path = pf->path;
        return CURL_READFUNC_ABORT;
    }
    pf->pos += got;
    if (pf->pos > pf->most)
        pf->most = pf->pos;
    return got;
}

static int
part_seek(void *ud, curl_off_t offset, int origin)
{
    struct part_file *pf = ud;
    if (origin != SEEK_SET || offset < 0 || fseeko(pf->fp, (off_t)offset, SEEK_SET) != 0)
        return CURL_SEEKFUNC_CANTSEEK;
    pf->pos = (uint64_t)offset;
    return CURL_SEEKFUNC_OK;
}

static int
xferinfo_cb(void *ud, curl_off_t dltotal, curl_off_t dlnow, curl_off_t ultotal, curl_off_t ulnow)
{
    (void)dltotal, (void)dlnow;
    struct httpc_req *r = ud;
    if (r->cancelled)
        return 1;
    if (r->progress_fn && (uint64_t)ulnow != r->last_sent) {
        r->last_sent = (uint64_t)ulnow;
        r->progress_fn(r, (uint64_t)ulnow, ultotal > 0 ? (uint64_t)ultotal : 0, r->ud);
    }
    return r->cancelled ? 1 : 0;
}

/* ---- request lifetime ---- */

static void
unlink_req(struct httpc_req *r)
{
    struct httpc *h = r->h;
    if (r->prev)
        r->prev->next = r->next;
    else
        h->reqs = r->next;
    if (r->next)
        r->next->prev = r->prev;
    r->prev = r->next = NULL;
}

/* Take r off the multi handle and free it.  Never inside curl. */
static void
free_req(struct httpc_req *r)
{
    struct httpc *h = r->h;
    if (r->added) {
        h->depth++;
        curl_multi_remove_handle(h->multi, r->easy);
        h->depth--;
        r->added = false;
    }
    unlink_req(r);
    curl_easy_cleanup(r->easy);
    curl_slist_free_all(r->hdrs);
    curl_mime_free(r->mime);
    for (size_t i = 0; i < r->n_files; i++) {
        if (r->files[i].fp)
            fclose(r->files[i].fp);
        free(r->files[i].path);
    }
    free(r->files);
    if (r->fp)
        fclose(r->fp);
    free(r->body_path);
    free(r->body);
    free(r->url);
    buf_release(&r->resp);
    buf_release(&r->hdr);
    free(r);
}

static int
add_to_multi(struct httpc_req *r, struct sf_err *err)
{
    struct httpc *h = r->h;
    h->depth++;
    CURLMcode mc = curl_multi_add_handle(h->multi, r->easy);
    h->depth--;
    if (mc != CURLM_OK)
        return sf_err_set(err, SF_ENOMEM, "%s %s: %s", r->method, r->url, curl_multi_strerror(mc));
    r->added = true;
    if (r->ftp && !h->kick)
        h->kick = loop_timer_add(h->l, FTP_KICK_MS, on_kick, h);
    return SF_OK;
}

/*
 * Make curl run r again.  libcurl before 8.4.0 (Debian 12 ships 7.88.1)
 * can leave a transfer with nothing to wait on: when an FTP server answers
 * PASV so fast that the DO phase ends within one call, the transfer moves
 * to DOING_MORE and waits for "socket activity" on the data connection it
 * has not opened yet (curl issue #12033, fixed by #12042).  With
 * curl_multi_perform something else runs it soon; with multi_socket
 * nothing does until its connect timeout: the FTPS upload stalled after
 * PASV.  Pausing and unpausing is libcurl's public way to say "get this
 * handle going again" (curl_easy_pause: Curl_expire(RUN_NOW) and a timer
 * callback), and leaves the transfer's state as it was.  Asked for when
 * curl drops a socket of a transfer that has not finished (socket_cb), so
 * it costs one extra turn of that transfer at most per dropped socket.
 */
static void
nudge(struct httpc_req *r)
{
    struct httpc *h = r->h;
    r->nudge = false;
    h->depth++;
    h->nudging = true;
    if (curl_easy_pause(r->easy, CURLPAUSE_ALL) == CURLE_OK)
        curl_easy_pause(r->easy, CURLPAUSE_CONT);
    h->nudging = false;
    h->depth--;
}

/*
 * Run every FTP transfer still setting up (its body not yet asked for)
 * every FTP_KICK_MS.  libcurl 7.88 connects an FTPS data connection's TCP
 * and TLS as one, and while the TLS is unfinished it polls only the data
 * socket; vsftpd (and an X1) start that TLS only after STOR, and the
 * replies to TYPE and STOR come on the control connection, which curl then
 * reads only when it runs for some other reason: an upload whose TYPE I
 * answer came a moment after curl looked waited for its connect timeout
 * ("SSL connection timeout", farmd_bambu_crash's second job).  Each kick
 * costs one non-blocking turn of the transfer; set-up lasts a few round
 * trips.
 */
static void
on_kick(struct loop *l, void *ud)
{
    struct httpc *h = ud;
    h->kick = 0;
    bool any = false;
    for (struct httpc_req *r = h->reqs; r; r = r->next) {
        if (r->ftp && r->added && !r->finished && !r->cancelled && !r->body_started) {
            nudge(r);
            any = true;
        }
    }
    if (any)
        h->kick = loop_timer_add(l, FTP_KICK_MS, on_kick, h);
}

static void
on_sweep(struct loop *l, void *ud)
{
    (void)l;
    struct httpc *h = ud;
    h->sweep = 0;
    struct httpc_req *next;
    for (struct httpc_req *r = h->reqs; r; r = next) {
        next = r->next;
        if (r->finished)
            continue;
        if (r->cancelled) {
            free_req(r);
        } else if (r->nudge && r->added) {
            nudge(r);
        } else if (!r->added) {
            struct sf_err err;
            if (add_to_multi(r, &err) < 0) {
                /* Report it as a failed request, like any other. */
                r->result = CURLE_OUT_OF_MEMORY;
                r->finished = true;
                r->next_done = h->done;
                h->done = r;
            }
        }
    }
    collect(h);
}

static void
sweep_soon(struct httpc *h)
{
    if (!h->sweep)
        h->sweep = loop_timer_add(h->l, 0, on_sweep, h);
}

static void
report(struct httpc_req *r)
{
    struct httpc_result res = { 0 };
    sf_err_clear(&res.err);
    curl_easy_getinfo(r->easy, CURLINFO_RESPONSE_CODE, &res.status);
    res.body = r->resp.data ? r->resp.data : "";
    res.body_len = r->resp.len;
    res.headers = r->hdr.data ? r->hdr.data : "";
    char *ip = NULL;
    res.peer_ip = curl_easy_getinfo(r->easy, CURLINFO_PRIMARY_IP, &ip) == CURLE_OK && ip ? ip : "";
    const char *detail = r->errbuf[0] ? r->errbuf : curl_easy_strerror(r->result);
    res.detail = r->result == CURLE_OK ? "" : detail;
    res.tls_peer = r->result == CURLE_PEER_FAILED_VERIFICATION;
    res.body_read = httpc_body_read(r);
    if (r->result == CURLE_OK) {
        res.code = SF_OK;
    } else if (r->oversize) {
        res.code = sf_err_set(&res.err, SF_ENOMEM, "%s %s: response body over the %zu-byte cap",
                              r->method, r->url, r->resp.max);
    } else if (r->file_err) {
        res.code = sf_err_set(&res.err, SF_EIO, "%s %s: reading '%s' failed", r->method, r->url,
                              r->err_path);
    } else if (r->result == CURLE_OPERATION_TIMEDOUT) {
        res.code =
            sf_err_set(&res.err, SF_ETIMEDOUT, "%s %s: timed out (%s)", r->method, r->url, detail);
    } else if (r->result == CURLE_OUT_OF_MEMORY) {
        res.code = sf_err_set(&res.err, SF_ENOMEM, "%s %s: out of memory", r->method, r->url);
    } else {
        res.code = sf_err_set(&res.err, SF_EIO, "%s %s: %s", r->method, r->url, detail);
    }
    r->in_done = true;
    r->h->n_active--;
    r->done_fn(r, &res, r->ud);
}

/* Move finished transfers to the done list, then report them one by one. */
static void
collect(struct httpc *h)
{
    CURLMsg *m;
    int left;
    while ((m = curl_multi_info_read(h->multi, &left))) {
        if (m->msg != CURLMSG_DONE)
            continue;
        struct httpc_req *r = NULL;
        curl_easy_getinfo(m->easy_handle, CURLINFO_PRIVATE, (char **)&r);
        if (!r || r->finished)
            continue;
        r->result = m->data.result;
        r->finished = true;
        r->next_done = h->done;
        h->done = r;
    }
    /* Take them off the multi handle now (outside curl), in finishing order. */
    struct httpc_req *list = NULL;
    while (h->done) {
        struct httpc_req *r = h->done;
        h->done = r->next_done;
        r->next_done = list;
        list = r;
    }
    for (struct httpc_req *r = list; r; r = r->next_done) {
        if (r->added) {
            h->depth++;
            curl_multi_remove_handle(h->multi, r->easy);
            h->depth--;
            r->added = false;
        }
    }
    while (list) {
        struct httpc_req *r = list;
        list = r->next_done;
        if (!r->cancelled)
            report(r);
        free_req(r);
    }
}

/* ---- public ---- */

struct httpc *
httpc_new(struct loop *l, struct sf_err *err)
{
    pthread_once(&global_once, global_init);
    if (global_rc != CURLE_OK) {
        sf_err_set(err, SF_EIO, "http: curl_global_init: %s", curl_easy_strerror(global_rc));
        return NULL;
    }
    struct httpc *h = mem_calloc(1, sizeof(*h));
    if (!h) {
        sf_err_set(err, SF_ENOMEM, "http: out of memory");
        return NULL;
    }
    h->l = l;
    h->multi = curl_multi_init();
    if (!h->multi) {
        free(h);
        sf_err_set(err, SF_ENOMEM, "http: curl_multi_init failed");
        return NULL;
    }
    curl_multi_setopt(h->multi, CURLMOPT_SOCKETFUNCTION, socket_cb);
    curl_multi_setopt(h->multi, CURLMOPT_SOCKETDATA, h);
    curl_multi_setopt(h->multi, CURLMOPT_TIMERFUNCTION, timer_cb);
    curl_multi_setopt(h->multi, CURLMOPT_TIMERDATA, h);
    /* A few kept-alive connections per printer host, plenty for polls plus an upload. */
    curl_multi_setopt(h->multi, CURLMOPT_MAX_HOST_CONNECTIONS, 4L);
    return h;
}

void
httpc_free(struct httpc *h)
{
    if (!h)
        return;
    while (h->reqs) {
        struct httpc_req *r = h->reqs;
        r->cancelled = true;
        free_req(r);
    }
    if (h->timer)
        loop_timer_cancel(h->l, h->timer);
    if (h->sweep)
        loop_timer_cancel(h->l, h->sweep);
    if (h->kick)
        loop_timer_cancel(h->l, h->kick);
    curl_multi_cleanup(h->multi);
    free(h);
}

struct httpc *
httpc_get(struct loop *l, struct sf_err *err)
{
    pthread_mutex_lock(&shared_lock);
    struct httpc *h = shared_list;
    while (h && h->l != l)
        h = h->next_shared;
    if (!h) {
        h = httpc_new(l, err);
        if (h) {
            h->next_shared = shared_list;
            shared_list = h;
        }
    }
    if (h)
        h->refs++;
    pthread_mutex_unlock(&shared_lock);
    return h;
}

void
httpc_put(struct httpc *h)
{
    if (!h)
        return;
    pthread_mutex_lock(&shared_lock);
    bool last = --h->refs == 0;
    if (last) {
        for (struct httpc **pp = &shared_list; *pp; pp = &(*pp)->next_shared)
            if (*pp == h) {
                *pp = h->next_shared;
                break;
            }
    }
    pthread_mutex_unlock(&shared_lock);
    if (last)
        httpc_free(h);
}

size_t
httpc_active(const struct httpc *h)
{
    return h->n_active;
}

#define SET(opt, val)                                                                              \
    do {                                                                                           \
        if (curl_easy_setopt(r->easy, opt, val) != CURLE_OK) {                                     \
            sf_err_set(err, SF_EINVAL, "%s %s: curl option " #opt " refused", r->method, r->url);  \
            goto fail;                                                                             \
        }                                                                                          \
    } while (0)

/* The transfer itself: callbacks, keepalive, timeouts, the stall limit and authentication. */
static int
setup_transfer(struct httpc_req *r, const struct httpc_opts *o, struct sf_err *err)
{
    SET(CURLOPT_PRIVATE, r);
    SET(CURLOPT_URL, o->url);
    SET(CURLOPT_NOSIGNAL, 1L);
    SET(CURLOPT_ERRORBUFFER, r->errbuf);
    SET(CURLOPT_WRITEFUNCTION, write_cb);
    SET(CURLOPT_WRITEDATA, r);
    SET(CURLOPT_HEADERFUNCTION, header_cb);
    SET(CURLOPT_HEADERDATA, r);
    SET(CURLOPT_NOPROGRESS, 0L);
    SET(CURLOPT_XFERINFOFUNCTION, xferinfo_cb);
    SET(CURLOPT_XFERINFODATA, r);
    SET(CURLOPT_TCP_KEEPALIVE, 1L);
    r->timeout_ms = o->timeout_ms ? o->timeout_ms : HTTPC_TIMEOUT_MS_DEFAULT;
    if (r->timeout_ms > 0)
        SET(CURLOPT_TIMEOUT_MS, r->timeout_ms);
    SET(CURLOPT_CONNECTTIMEOUT_MS,
        (long)(o->connect_timeout_ms ? o->connect_timeout_ms : HTTPC_CONNECT_TIMEOUT_MS_DEFAULT));
    if (o->stall_ms > 0) {
        SET(CURLOPT_LOW_SPEED_LIMIT, 1L);
        SET(CURLOPT_LOW_SPEED_TIME, (long)((o->stall_ms + 999) / 1000));
    }
    if (o->user) {
        SET(CURLOPT_USERNAME, o->user);
        SET(CURLOPT_PASSWORD, o->password ? o->password : "");
        SET(CURLOPT_HTTPAUTH, o->digest ? CURLAUTH_DIGEST : CURLAUTH_BASIC);
    }
    return SF_OK;
fail:
    return SF_EINVAL;
}

/* The caller's headers, and no "Expect: 100-continue". */
static int
setup_headers(struct httpc_req *r, const struct httpc_opts *o, struct sf_err *err)
{
    for (const char *const *hp = o->headers; hp && *hp; hp++) {
        struct curl_slist *s = curl_slist_append(r->hdrs, *hp);
        if (!s)
            return sf_err_set(err, SF_ENOMEM, "http: out of memory");
        r->hdrs = s;
    }
    /* No "Expect: 100-continue" round trip before large bodies: the servers
       we talk to read the body anyway, and some embedded ones never answer it. */
    struct curl_slist *s = curl_slist_append(r->hdrs, "Expect:");
    if (!s)
        return sf_err_set(err, SF_ENOMEM, "http: out of memory");
    r->hdrs = s;
    SET(CURLOPT_HTTPHEADER, r->hdrs);
    return SF_OK;
fail:
    return SF_EINVAL;
}

static int
build_mime(struct httpc_req *r, const struct httpc_opts *o, struct sf_err *err)
{
    r->mime = curl_mime_init(r->easy);
    r->files = mem_calloc(o->n_parts, sizeof(*r->files));
    if (!r->mime || !r->files)
        return sf_err_set(err, SF_ENOMEM, "%s %s: out of memory", r->method, r->url);
    for (size_t i = 0; i < o->n_parts; i++) {
        const struct httpc_part *p = &o->parts[i];
        if (!p->name || (!p->value == !p->file_path))
            return sf_err_set(err, SF_EINVAL,
                              "%s %s: part %zu needs a name and either a value or a file",
                              r->method, r->url, i);
        curl_mimepart *mp = curl_mime_addpart(r->mime);
        if (!mp || curl_mime_name(mp, p->name) != CURLE_OK)
            return sf_err_set(err, SF_ENOMEM, "%s %s: out of memory", r->method, r->url);
        if (p->value) {
            if (curl_mime_data(mp, p->value, CURL_ZERO_TERMINATED) != CURLE_OK)
                return sf_err_set(err, SF_ENOMEM, "%s %s: out of memory", r->method, r->url);
        } else {
            /* streamed from disk in chunks while sending, by part_read */
            struct part_file *pf = &r->files[r->n_files++];
            pf->r = r;
            pf->path = mem_strdup(p->file_path);
            if (!pf->path)
                return sf_err_set(err, SF_ENOMEM, "%s %s: out of memory", r->method, r->url);
            pf->fp = fopen(p->file_path, "rb");
            struct stat st;
            if (!pf->fp || fstat(fileno(pf->fp), &st) < 0 || !S_ISREG(st.st_mode))
                return sf_err_sys(err, "%s %s: part '%s': cannot read '%s'", r->method, r->url,
                                  p->name, p->file_path);
            const char *base = strrchr(p->file_path, '/');
            base = p->filename ? p->filename : base ? base + 1 : p->file_path;
            if (curl_mime_data_cb(mp, (curl_off_t)st.st_size, part_read, part_seek, NULL, pf) !=
                    CURLE_OK ||
                curl_mime_filename(mp, base) != CURLE_OK)
                return sf_err_set(err, SF_ENOMEM, "%s %s: out of memory", r->method, r->url);
        }
        if (p->type && curl_mime_type(mp, p->type) != CURLE_OK)
            return sf_err_set(err, SF_ENOMEM, "%s %s: out of memory", r->method, r->url);
    }
    return SF_OK;
}

/* The body (copied, a file read while sending, or multipart parts) and the method that sends it. */
static int
setup_body(struct httpc_req *r, const struct httpc_opts *o, struct sf_err *err)
{
    const char *method = r->method;
    bool put = strcmp(method, "PUT") == 0;
    curl_off_t body_size = 0;
    if (o->body) {
        r->body = mem_alloc(o->body_len ? o->body_len : 1);
        if (!r->body)
            return sf_err_set(err, SF_ENOMEM, "http: out of memory");
        memcpy(r->body, o->body, o->body_len);
        r->body_len = o->body_len;
        body_size = (curl_off_t)o->body_len;
    } else if (o->body_path) {
        r->body_path = mem_strdup(o->body_path);
        r->fp = fopen(o->body_path, "rb");
        struct stat st;
        if (!r->body_path || !r->fp || fstat(fileno(r->fp), &st) < 0)
            return sf_err_sys(err, "%s %s: cannot read '%s'", method, o->url, o->body_path);
        body_size = (curl_off_t)st.st_size;
    }
    if (o->n_parts) {
        if (build_mime(r, o, err) < 0)
            return SF_EINVAL;
        SET(CURLOPT_MIMEPOST, r->mime);
        if (strcmp(method, "POST") != 0)
            SET(CURLOPT_CUSTOMREQUEST, method);
    } else if (put) {
        SET(CURLOPT_UPLOAD, 1L);
        SET(CURLOPT_READFUNCTION, read_cb);
        SET(CURLOPT_READDATA, r);
        SET(CURLOPT_INFILESIZE_LARGE, body_size);
    } else if (strcmp(method, "POST") == 0 || r->body || r->fp) {
        SET(CURLOPT_POST, 1L);
        SET(CURLOPT_READFUNCTION, read_cb);
        SET(CURLOPT_READDATA, r);
        SET(CURLOPT_POSTFIELDSIZE_LARGE, body_size);
        if (strcmp(method, "POST") != 0)
            SET(CURLOPT_CUSTOMREQUEST, method);
    } else if (strcmp(method, "GET") == 0) {
        SET(CURLOPT_HTTPGET, 1L);
    } else if (strcmp(method, "HEAD") == 0) {
        SET(CURLOPT_NOBODY, 1L);
    } else {
        SET(CURLOPT_CUSTOMREQUEST, method);
    }
    return SF_OK;
fail:
    return SF_EINVAL;
}

struct httpc_req *
httpc_start(struct httpc *h, const struct httpc_opts *o, struct sf_err *err)
{
    if (!o || !o->url || !o->done) {
        sf_err_set(err, SF_EINVAL, "http: a request needs a url and a done callback");
        return NULL;
    }
    int n_bodies = (o->body != NULL) + (o->body_path != NULL) + (o->n_parts > 0);
    if (n_bodies > 1) {
        sf_err_set(err, SF_EINVAL, "http %s: give at most one of body, body_path and parts",
                   o->url);
        return NULL;
    }
    const char *method = o->method ? o->method : n_bodies ? "POST" : "GET";
    if (strlen(method) >= 16) {
        sf_err_set(err, SF_EINVAL, "http %s: method too long", o->url);
        return NULL;
    }
    struct httpc_req *r = mem_calloc(1, sizeof(*r));
    if (!r) {
        sf_err_set(err, SF_ENOMEM, "http: out of memory");
        return NULL;
    }
    r->h = h;
    snprintf(r->method, sizeof(r->method), "%s", method);
    buf_init(&r->resp, o->max_body ? o->max_body : HTTPC_BODY_MAX_DEFAULT);
    buf_init(&r->hdr, HTTPC_HEADERS_MAX);
    r->done_fn = o->done;
    r->progress_fn = o->progress;
    r->ud = o->ud;
    r->url = mem_strdup(o->url);
    r->ftp = strncmp(o->url, "ftp://", 6) == 0 || strncmp(o->url, "ftps://", 7) == 0;
    r->easy = curl_easy_init();
    /* Linked first, so that the failure path frees it like any request. */
    r->next = h->reqs;
    if (h->reqs)
        h->reqs->prev = r;
    h->reqs = r;
    if (!r->url || !r->easy) {
        sf_err_set(err, SF_ENOMEM, "http: out of memory");
        goto fail;
    }
    if (setup_transfer(r, o, err) < 0 || setup_headers(r, o, err) < 0 || setup_body(r, o, err) < 0)
        goto fail;
    if (o->setopt) {
        CURLcode cc = o->setopt(r->easy, o->setopt_ud);
        if (cc != CURLE_OK) {
            sf_err_set(err, SF_EINVAL, "%s %s: option hook: %s", method, o->url,
                       curl_easy_strerror(cc));
            goto fail;
        }
    }
    h->n_active++;
    if (h->depth > 0) {
        sweep_soon(h); /* inside curl: add it from the sweep */
    } else if (add_to_multi(r, err) < 0) {
        h->n_active--;
        goto fail;
    }
    return r;
fail:
    r->cancelled = true;
    free_req(r);
    return NULL;
}

uint64_t
httpc_body_read(const struct httpc_req *r)
{
    if (r->n_files) {
        uint64_t sum = 0;
        for (size_t i = 0; i < r->n_files; i++)
            sum += r->files[i].most;
        return sum;
    }
    return r->fp ? r->fp_read : UINT64_MAX;
}

void
httpc_cancel(struct httpc_req *r)
{
    if (!r || r->in_done || r->cancelled)
        return;
    struct httpc *h = r->h;
    r->cancelled = true;
    h->n_active--;
    if (r->finished)
        return; /* on the done list: collect frees it unreported */
    if (h->depth > 0) {
        sweep_soon(h); /* inside curl: its callbacks abort it, the sweep frees it */
        return;
    }
    free_req(r);
}

bool
httpc_header(const struct httpc_result *res, const char *name, char *out, size_t n)
{
    size_t nl = strlen(name);
    bool found = false;
    for (const char *p = res->headers; p && *p;) {
        const char *eol = strchr(p, '\n');
        size_t len = eol ? (size_t)(eol - p) : strlen(p);
        if (len > nl && p[nl] == ':' && strncasecmp(p, name, nl) == 0) {
            const char *v = p + nl + 1;
            const char *end = p + len;
            while (v < end && (*v == ' ' || *v == '\t'))
                v++;
            while (end > v && (end[-1] == '\r' || end[-1] == ' '))
                end--;
            if (n) {
                size_t k = (size_t)(end - v) < n - 1 ? (size_t)(end - v) : n - 1;
                memcpy(out, v, k);
                out[k] = 0;
            }
            found = true;
        }
        p = eol ? eol + 1 : p + len;
    }
    return found;
}
