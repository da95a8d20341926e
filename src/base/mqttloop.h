/*
 * mqttloop.h - one MQTT 3.1.1 client over TLS (libmosquitto) driven by our
 * event loop: no mosquitto thread and no blocking call.
 *
 * Shared by the Bambu driver (the farm's side) and the Bambu simulator (the
 * printer's side), which both talk to a broker over TLS.
 *
 * How it joins the loop (libmosquitto 2.0.11, read from its source): the
 * connection starts with mosquitto_connect_async(), whose TCP connect is
 * non-blocking (EINPROGRESS) and whose TLS handshake is stepped by
 * mosquitto_loop_read() while the library's want_connect flag is up; the
 * CONNECT packet waits in its queue until the handshake is done.  So every
 * readiness of the socket runs loop_read (handshake or packets), then
 * loop_write when the library wants to write; a 1 s timer runs loop_misc
 * (keepalive pings).  After each call the socket is compared with the one
 * registered, because libmosquitto closes it by itself on a failed
 * handshake without telling anyone.  Host names are resolved by
 * getaddrinfo inside mosquitto_connect_async, so give an IP address (the
 * Bambu driver does; a name would block the loop for the lookup).
 *
 * TLS: the client builds its own SSL_CTX: trust ca_file, and when
 * tls_name is set require the peer certificate to carry that name (CN when
 * it has no SAN, as Bambu certificates do); the IP address connected to is
 * never checked.  tls_insecure skips verification entirely.  A failed
 * verification is reported with OpenSSL's reason and the certificate's
 * subject.
 *
 * Reconnecting is the owner's decision (on_down, then mqttloop_connect
 * again after its backoff).
 *
 * Thread: loop thread only.  Owns the mosquitto handle, its socket
 * registration and its timer; mqttloop_free releases all.  Callbacks must
 * not call mqttloop_free.
 */
#ifndef SF_BASE_MQTTLOOP_H
#define SF_BASE_MQTTLOOP_H

#include <stdbool.h>
#include <stddef.h>

#include "err.h"
#include "loop.h"

/* Connected and the broker accepted us (CONNACK 0). */
typedef void (*mqttloop_up_fn)(void *ud);
/*
 * The connection ended or never came up.  connack: the broker's refusal
 * code (4 bad user name or password, 5 not authorised) or 0; tls: the
 * failure was the TLS handshake or certificate; why: a sentence.
 */
typedef void (*mqttloop_down_fn)(void *ud, int connack, bool tls, const char *why);
typedef void (*mqttloop_msg_fn)(void *ud, const char *topic, const char *payload, size_t len);

struct mqttloop_config {
    const char *host;       /* IP address of the broker */
    int port;               /* 8883 on a printer */
    const char *client_id;  /* unique per broker */
    const char *user;       /* "bblp" */
    const char *password;   /* the access code */
    const char *ca_file;    /* PEM CA bundle to trust; NULL with tls_insecure */
    const char *tls_name;   /* name the peer certificate must carry; NULL: chain only */
    bool tls_insecure;      /* no verification at all (operator's choice) */
    bool tls12_only;        /* cap at TLS 1.2, as Bambu printers speak */
    int keepalive_s;        /* MQTT keepalive; 0: 30 */
    int connect_timeout_ms; /* TCP + TLS + CONNACK must finish within; 0: 10000 */
    mqttloop_up_fn on_up;
    mqttloop_down_fn on_down;
    mqttloop_msg_fn on_message;
    void *ud;
};

struct mqttloop;

/* A client, not yet connected.  NULL with err set (SF_EINVAL bad config, SF_ENOMEM). */
struct mqttloop *mqttloop_new(struct loop *l, const struct mqttloop_config *c, struct sf_err *err);
/*
 * Start connecting; the result comes as on_up or on_down.  SF_EIO when the
 * attempt fails at once (the message says why; no on_down follows).
 */
int mqttloop_connect(struct mqttloop *m, struct sf_err *err);
/* True between on_up and on_down. */
bool mqttloop_is_up(const struct mqttloop *m);
/* QoS 0.  SF_EAGAIN when not up. */
int mqttloop_subscribe(struct mqttloop *m, const char *topic, struct sf_err *err);
int mqttloop_publish(struct mqttloop *m, const char *topic, const void *payload, size_t len,
                     struct sf_err *err);
/* Close the connection now, without on_down. */
void mqttloop_close(struct mqttloop *m);
/* Close and free.  NULL is fine. */
void mqttloop_free(struct mqttloop *m);

#endif
