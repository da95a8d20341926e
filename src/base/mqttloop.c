/*
 * mqttloop.c - libmosquitto on the event loop (mqttloop.h).
 *
 * Why: the farm daemon has one loop that owns every socket (STYLE.md,
 * "Threads"); libmosquitto's own thread (mosquitto_loop_start) would need
 * locks around every printer's state, and its blocking connect would stall
 * the loop.  libmosquitto exposes just enough to be driven from outside:
 * mosquitto_socket, mosquitto_want_write and loop_read/write/misc.
 *
 * Design: three states (down, connecting, up).  Everything libmosquitto
 * reports through its callbacks (CONNACK, disconnect) only sets flags;
 * after each call into the library, settle() compares the flags, the return
 * code and the socket with what is registered and moves the state, so the
 * owner's callbacks run outside libmosquitto's (where a publish would only
 * be queued).  The TLS context is ours (MOSQ_OPT_SSL_CTX, no defaults), so
 * the expected name is the printer's serial rather than the IP address
 * connected to, and a verify callback keeps OpenSSL's reason for the
 * message.
 *
 * Thread: loop thread.
 */
#include "mqttloop.h"

#include <errno.h>
#include <mosquitto.h>
#include <openssl/err.h>
#include <openssl/ssl.h>
#include <openssl/x509v3.h>
#include <pthread.h>
#include <stdio.h>
#include <string.h>
#include <sys/socket.h>

#include "log.h"
#include "mem.h"

enum mstate { M_DOWN, M_CONNECTING, M_UP };

struct mqttloop {
    struct loop *loop;
    struct mosquitto *mosq;
    SSL_CTX *ctx;             /* ours; libmosquitto holds a reference too */
    struct mqttloop_config c; /* strings below are our copies */
    char *host, *client_id, *user, *password, *ca_file, *tls_name;
    enum mstate state;
    int fd;                 /* socket registered with the loop, -1 none */
    unsigned fd_events;     /* LOOP_READ / LOOP_WRITE registered */
    uint64_t misc_timer;    /* 1 s keepalive tick while connecting or up */
    uint64_t timeout_timer; /* connect deadline */
    uint64_t fail_timer;    /* reports an immediate connect failure */
    bool got_connack;       /* CONNACK seen since connect */
    int connack;            /* its code */
    bool lib_down;          /* libmosquitto's on_disconnect ran */
    char verify_err[160];   /* certificate verification failure, if any */
    char lib_err[160];      /* last error libmosquitto logged */
    int fail_rc;            /* libmosquitto code of a pending immediate failure */
    int fail_errno;         /* its errno when that was MOSQ_ERR_ERRNO */
};

static pthread_once_t lib_once = PTHREAD_ONCE_INIT;

static void
lib_init(void)
{
    mosquitto_lib_init();
}

static void
on_lib_connect(struct mosquitto *mosq, void *ud, int rc)
{
    (void)mosq;
    struct mqttloop *m = ud;
    m->got_connack = true;
    m->connack = rc;
}

static void
on_lib_disconnect(struct mosquitto *mosq, void *ud, int rc)
{
    (void)mosq;
    (void)rc;
    struct mqttloop *m = ud;
    m->lib_down = true;
}

static void
on_lib_message(struct mosquitto *mosq, void *ud, const struct mosquitto_message *msg)
{
    (void)mosq;
    struct mqttloop *m = ud;
    if (m->c.on_message && msg->topic)
        m->c.on_message(m->c.ud, msg->topic, msg->payload ? msg->payload : "",
                        (size_t)(msg->payloadlen > 0 ? msg->payloadlen : 0));
}

static void
on_lib_log(struct mosquitto *mosq, void *ud, int level, const char *str)
{
    (void)mosq;
    struct mqttloop *m = ud;
    if (level == MOSQ_LOG_ERR && str)
        snprintf(m->lib_err, sizeof(m->lib_err), "%s", str);
}

static int
verify_cb(int ok, X509_STORE_CTX *sctx)
{
    if (ok)
        return ok;
    SSL *ssl = X509_STORE_CTX_get_ex_data(sctx, SSL_get_ex_data_X509_STORE_CTX_idx());
    struct mqttloop *m = ssl ? SSL_CTX_get_app_data(SSL_get_SSL_CTX(ssl)) : NULL;
    if (m && !m->verify_err[0]) {
        char subj[96] = "?";
        X509 *cert = X509_STORE_CTX_get_current_cert(sctx);
        if (cert)
            X509_NAME_oneline(X509_get_subject_name(cert), subj, sizeof(subj));
        int e = X509_STORE_CTX_get_error(sctx);
        snprintf(m->verify_err, sizeof(m->verify_err), "%s (certificate %s)",
                 X509_verify_cert_error_string(e), subj);
    }
    return ok;
}

static int
make_ctx(struct mqttloop *m, struct sf_err *err)
{
    m->ctx = SSL_CTX_new(TLS_client_method());
    if (!m->ctx)
        return sf_err_set(err, SF_ENOMEM, "mqtt: cannot create a TLS context");
    SSL_CTX_set_min_proto_version(m->ctx, TLS1_2_VERSION);
    if (m->c.tls12_only)
        SSL_CTX_set_max_proto_version(m->ctx, TLS1_2_VERSION);
    SSL_CTX_set_app_data(m->ctx, m);
    if (m->c.tls_insecure) {
        SSL_CTX_set_verify(m->ctx, SSL_VERIFY_NONE, NULL);
        return SF_OK;
    }
    if (!m->ca_file)
        return sf_err_set(err, SF_EINVAL, "mqtt: no CA file to verify the broker with");
    if (SSL_CTX_load_verify_locations(m->ctx, m->ca_file, NULL) != 1) {
        char e[120];
        ERR_error_string_n(ERR_get_error(), e, sizeof(e));
        return sf_err_set(err, SF_EINVAL, "mqtt: CA file '%s' cannot be loaded: %s", m->ca_file, e);
    }
    SSL_CTX_set_verify(m->ctx, SSL_VERIFY_PEER, verify_cb);
    if (m->tls_name) {
        X509_VERIFY_PARAM *p = SSL_CTX_get0_param(m->ctx);
        X509_VERIFY_PARAM_set_hostflags(p, X509_CHECK_FLAG_NO_PARTIAL_WILDCARDS);
        if (X509_VERIFY_PARAM_set1_host(p, m->tls_name, 0) != 1)
            return sf_err_set(err, SF_EINVAL, "mqtt: bad certificate name '%s'", m->tls_name);
    }
    return SF_OK;
}

static void fd_event(struct loop *l, int fd, unsigned events, void *ud);

/* Register the library's current socket with the interest it needs now. */
static void
sync_fd(struct mqttloop *m)
{
    int s = m->state == M_DOWN ? -1 : mosquitto_socket(m->mosq);
    if (s != m->fd && m->fd >= 0) {
        loop_del_fd(m->loop, m->fd);
        m->fd = -1;
    }
    if (s < 0)
        return;
    unsigned ev = LOOP_READ;
    if (m->state == M_CONNECTING || mosquitto_want_write(m->mosq))
        ev |= LOOP_WRITE;
    if (m->fd < 0) {
        struct sf_err e;
        if (loop_add_fd(m->loop, s, ev, fd_event, m, &e) == SF_OK) {
            m->fd = s;
            m->fd_events = ev;
        }
    } else if (ev != m->fd_events) {
        loop_mod_fd(m->loop, m->fd, ev, NULL);
        m->fd_events = ev;
    }
}

static void
stop_timers(struct mqttloop *m)
{
    loop_timer_cancel(m->loop, m->misc_timer);
    loop_timer_cancel(m->loop, m->timeout_timer);
    m->misc_timer = m->timeout_timer = 0;
}

/* Drop the connection (no callback). */
static void
drop(struct mqttloop *m)
{
    stop_timers(m);
    int s = mosquitto_socket(m->mosq);
    if (s >= 0)
        shutdown(s, SHUT_RDWR); /* libmosquitto closes it on the next connect or destroy */
    m->state = M_DOWN;
    sync_fd(m);
}

/* Did OpenSSL report a handshake the peer ended (EOF, reset) rather than one
   it refused?  OpenSSL 3's reason strings, as libmosquitto logs them. */
static bool
handshake_cut(const char *lib_err)
{
    return strstr(lib_err, "unexpected eof") || strstr(lib_err, "Connection reset") ||
           strstr(lib_err, "Broken pipe");
}

/* Why the connection ended (or never came up), from rc and what the callbacks saw. */
static void
describe(struct mqttloop *m, int rc, bool was_up, char *why, size_t n, bool *tls, int *connack)
{
    *tls = false;
    *connack = 0;
    if (m->got_connack && m->connack != 0) {
        *connack = m->connack;
        snprintf(why, n, "broker refused the connection: %s (CONNACK %d)",
                 mosquitto_connack_string(m->connack), m->connack);
    } else if (rc == MOSQ_ERR_TLS && !m->verify_err[0] && handshake_cut(m->lib_err)) {
        /* the peer closed or reset the connection mid-handshake: a port coming
           back up (a printer's MQTT restarting), not a certificate to reject */
        snprintf(why, n, "TLS handshake cut short: %s", m->lib_err);
    } else if (rc == MOSQ_ERR_TLS || m->verify_err[0]) {
        *tls = true;
        if (m->verify_err[0])
            snprintf(why, n, "TLS: certificate rejected: %s", m->verify_err);
        else
            snprintf(why, n, "TLS handshake failed: %s",
                     m->lib_err[0] ? m->lib_err : mosquitto_strerror(rc));
    } else if (rc == MOSQ_ERR_ERRNO) {
        snprintf(why, n, "cannot connect to %s:%d: %s", m->host, m->c.port,
                 strerror(m->fail_errno ? m->fail_errno : errno));
    } else {
        snprintf(why, n, "%s%s", was_up ? "connection lost: " : "",
                 rc ? mosquitto_strerror(rc) : "connection closed");
    }
}

static void
go_down(struct mqttloop *m, int rc, const char *why_override)
{
    bool was_up = m->state == M_UP;
    drop(m);
    char why[300];
    bool tls = false;
    int connack = 0;
    if (why_override)
        snprintf(why, sizeof(why), "%s", why_override);
    else
        describe(m, rc, was_up, why, sizeof(why), &tls, &connack);
    if (m->c.on_down)
        m->c.on_down(m->c.ud, connack, tls, why);
}

/* After a call into libmosquitto: move the state as its results say. */
static void
settle(struct mqttloop *m, int rc)
{
    if (m->state == M_DOWN)
        return;
    if (rc != MOSQ_ERR_SUCCESS || m->lib_down || mosquitto_socket(m->mosq) < 0 ||
        (m->got_connack && m->connack != 0)) {
        go_down(m, rc, NULL);
        return;
    }
    if (m->state == M_CONNECTING && m->got_connack) {
        m->state = M_UP;
        loop_timer_cancel(m->loop, m->timeout_timer);
        m->timeout_timer = 0;
        sync_fd(m);
        if (m->c.on_up)
            m->c.on_up(m->c.ud);
        return;
    }
    sync_fd(m);
}

static void
fd_event(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)l;
    (void)fd;
    struct mqttloop *m = ud;
    if (m->state == M_CONNECTING && (events & (LOOP_HUP | LOOP_ERROR))) {
        /* Refused or reset before the session was up.  SO_ERROR may already have been
           taken by a write of the handshake; either way the attempt is over (epoll would
           report the hang-up on every turn). */
        int soerr = 0;
        socklen_t len = sizeof(soerr);
        getsockopt(m->fd, SOL_SOCKET, SO_ERROR, &soerr, &len);
        char why[160];
        snprintf(why, sizeof(why), "cannot connect to %s:%d: %s", m->host, m->c.port,
                 soerr ? strerror(soerr) : "connection closed");
        go_down(m, MOSQ_ERR_ERRNO, why);
        return;
    }
    /* loop_read also steps the TLS handshake, which may wait on either direction. */
    int rc = mosquitto_loop_read(m->mosq, 1);
    if (rc == MOSQ_ERR_SUCCESS && m->state != M_DOWN && mosquitto_socket(m->mosq) >= 0 &&
        mosquitto_want_write(m->mosq))
        rc = mosquitto_loop_write(m->mosq, 1);
    settle(m, rc);
}

static void
misc_tick(struct loop *l, void *ud)
{
    struct mqttloop *m = ud;
    m->misc_timer = 0;
    if (m->state == M_DOWN)
        return;
    int rc = m->state == M_UP ? mosquitto_loop_misc(m->mosq) : MOSQ_ERR_SUCCESS;
    if (rc == MOSQ_ERR_SUCCESS && m->state == M_UP && mosquitto_want_write(m->mosq))
        rc = mosquitto_loop_write(m->mosq, 1);
    m->misc_timer = loop_timer_add(l, 1000, misc_tick, m);
    settle(m, rc);
}

static void
connect_timeout(struct loop *l, void *ud)
{
    (void)l;
    struct mqttloop *m = ud;
    m->timeout_timer = 0;
    if (m->state != M_CONNECTING)
        return;
    char why[160];
    snprintf(why, sizeof(why), "no answer from %s:%d within %d ms%s%s", m->host, m->c.port,
             m->c.connect_timeout_ms, m->verify_err[0] ? "; " : "", m->verify_err);
    go_down(m, MOSQ_ERR_NO_CONN, why);
}

static void
report_failure(struct loop *l, void *ud)
{
    (void)l;
    struct mqttloop *m = ud;
    m->fail_timer = 0;
    char why[300];
    bool tls;
    int connack;
    describe(m, m->fail_rc, false, why, sizeof(why), &tls, &connack);
    if (m->c.on_down)
        m->c.on_down(m->c.ud, connack, tls, why);
}

static char *
dup_opt(const char *s, bool *oom)
{
    if (!s)
        return NULL;
    char *d = mem_strdup(s);
    if (!d)
        *oom = true;
    return d;
}

struct mqttloop *
mqttloop_new(struct loop *l, const struct mqttloop_config *c, struct sf_err *err)
{
    if (!c->host || !c->client_id || c->port <= 0 || c->port > 65535) {
        sf_err_set(err, SF_EINVAL, "mqtt: host, port and client id are required");
        return NULL;
    }
    pthread_once(&lib_once, lib_init);
    struct mqttloop *m = mem_calloc(1, sizeof(*m));
    if (!m) {
        sf_err_set(err, SF_ENOMEM, "mqtt: out of memory");
        return NULL;
    }
    m->loop = l;
    m->fd = -1;
    m->c = *c;
    if (!m->c.keepalive_s)
        m->c.keepalive_s = 30;
    if (!m->c.connect_timeout_ms)
        m->c.connect_timeout_ms = 10000;
    bool oom = false;
    m->host = dup_opt(c->host, &oom);
    m->client_id = dup_opt(c->client_id, &oom);
    m->user = dup_opt(c->user, &oom);
    m->password = dup_opt(c->password, &oom);
    m->ca_file = dup_opt(c->ca_file, &oom);
    m->tls_name = dup_opt(c->tls_name, &oom);
    if (oom) {
        sf_err_set(err, SF_ENOMEM, "mqtt: out of memory");
        goto fail;
    }
    m->mosq = mosquitto_new(m->client_id, true, m);
    if (!m->mosq) {
        sf_err_set(err, SF_ENOMEM, "mqtt: cannot create a client");
        goto fail;
    }
    if (make_ctx(m, err) < 0)
        goto fail;
    mosquitto_int_option(m->mosq, MOSQ_OPT_PROTOCOL_VERSION, MQTT_PROTOCOL_V311);
    /* Our context as it is: with the defaults on, libmosquitto insists on its own cafile. */
    mosquitto_int_option(m->mosq, MOSQ_OPT_SSL_CTX_WITH_DEFAULTS, 0);
    if (mosquitto_void_option(m->mosq, MOSQ_OPT_SSL_CTX, m->ctx) != MOSQ_ERR_SUCCESS ||
        (m->user && mosquitto_username_pw_set(m->mosq, m->user, m->password))) {
        sf_err_set(err, SF_EINVAL, "mqtt: the client refused its TLS or login settings");
        goto fail;
    }
    mosquitto_connect_callback_set(m->mosq, on_lib_connect);
    mosquitto_disconnect_callback_set(m->mosq, on_lib_disconnect);
    mosquitto_message_callback_set(m->mosq, on_lib_message);
    mosquitto_log_callback_set(m->mosq, on_lib_log);
    return m;
fail:
    mqttloop_free(m);
    return NULL;
}

int
mqttloop_connect(struct mqttloop *m, struct sf_err *err)
{
    (void)err;
    if (m->state != M_DOWN)
        mqttloop_close(m);
    m->got_connack = false;
    m->connack = 0;
    m->lib_down = false;
    m->verify_err[0] = m->lib_err[0] = '\0';
    m->fail_rc = m->fail_errno = 0;
    ERR_clear_error();
    m->state = M_CONNECTING;
    int rc = mosquitto_connect_async(m->mosq, m->host, m->c.port, m->c.keepalive_s);
    if (rc != MOSQ_ERR_SUCCESS) {
        /* Refused at once (a loopback port with no listener, or a TLS handshake that
           finished inside the call): reported through on_down like every other failure,
           on the next turn. */
        m->fail_rc = rc;
        if (rc == MOSQ_ERR_ERRNO)
            m->fail_errno = errno;
        drop(m);
        loop_timer_cancel(m->loop, m->fail_timer);
        m->fail_timer = loop_timer_add(m->loop, 0, report_failure, m);
        return SF_OK;
    }
    m->timeout_timer = loop_timer_add(m->loop, m->c.connect_timeout_ms, connect_timeout, m);
    m->misc_timer = loop_timer_add(m->loop, 1000, misc_tick, m);
    sync_fd(m);
    return SF_OK;
}

bool
mqttloop_is_up(const struct mqttloop *m)
{
    return m && m->state == M_UP;
}

int
mqttloop_subscribe(struct mqttloop *m, const char *topic, struct sf_err *err)
{
    if (m->state != M_UP)
        return sf_err_set(err, SF_EAGAIN, "mqtt: not connected");
    int rc = mosquitto_subscribe(m->mosq, NULL, topic, 0);
    if (rc != MOSQ_ERR_SUCCESS) {
        sf_err_set(err, SF_EIO, "mqtt: subscribe '%s': %s", topic, mosquitto_strerror(rc));
        settle(m, rc);
        return SF_EIO;
    }
    settle(m, rc);
    return SF_OK;
}

int
mqttloop_publish(struct mqttloop *m, const char *topic, const void *payload, size_t len,
                 struct sf_err *err)
{
    if (m->state != M_UP)
        return sf_err_set(err, SF_EAGAIN, "mqtt: not connected");
    if (len > (size_t)1 << 27)
        return sf_err_set(err, SF_EINVAL, "mqtt: message too large");
    int rc = mosquitto_publish(m->mosq, NULL, topic, (int)len, payload, 0, false);
    if (rc != MOSQ_ERR_SUCCESS) {
        sf_err_set(err, SF_EIO, "mqtt: publish '%s': %s", topic, mosquitto_strerror(rc));
        settle(m, rc);
        return SF_EIO;
    }
    settle(m, rc);
    return SF_OK;
}

void
mqttloop_close(struct mqttloop *m)
{
    if (!m)
        return;
    loop_timer_cancel(m->loop, m->fail_timer);
    m->fail_timer = 0;
    if (m->state == M_UP) {
        mosquitto_disconnect(m->mosq);
        if (mosquitto_want_write(m->mosq))
            mosquitto_loop_write(m->mosq, 1);
    }
    drop(m);
}

void
mqttloop_free(struct mqttloop *m)
{
    if (!m)
        return;
    if (m->mosq) {
        mqttloop_close(m);
        mosquitto_destroy(m->mosq);
    }
    SSL_CTX_free(m->ctx);
    free(m->host);
    free(m->client_id);
    free(m->user);
    free(m->password);
    free(m->ca_file);
    free(m->tls_name);
    free(m);
}
