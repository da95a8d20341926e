/*
 * transport.h - byte transports beneath the printer protocols: a serial
 * device through libserialport, a plain fd for pseudo-terminals (which
 * libserialport cannot open), and TCP for serial bridges (ser2net, ESP3D).
 *
 * Spec strings: "/dev/ttyUSB0" (serial; a path resolving into /dev/pts is
 * opened as a pty), "pty:/dev/pts/3", "tcp://host:port", "fd:N" (a copy of
 * the caller's connected stream socket N, e.g. a socketpair end to a
 * simulator on the same loop: simulated-time runs, sim/ and tests).  A TCP host name
 * is resolved on a lookup thread, never on the loop; closing the transport
 * cancels the lookup.  Everything is
 * non-blocking and on the loop: received bytes go to on_data as they come;
 * writes are queued (capped) and flushed when the fd is writable; a hang-up
 * or error calls on_close once, after which the transport is inert until
 * transport_free().
 *
 * Thread: loop thread (transport_set_resolver and transport_lookups_alive:
 * any).  Owns its fd, port handle and host name lookup.
 */
#ifndef SF_DRIVERS_MARLIN_TRANSPORT_H
#define SF_DRIVERS_MARLIN_TRANSPORT_H

#include <stdbool.h>
#include <stddef.h>

#include "../../src/base/err.h"
#include "../../src/base/loop.h"

struct transport;
struct addrinfo;

typedef void (*transport_data_fn)(void *ud, const char *data, size_t n);
/* The link is gone; why says so ("read: Input/output error", "connection closed"). */
typedef void (*transport_close_fn)(void *ud, const char *why);

/*
 * Open spec at baud (serial only; 0 = 115200).  TCP resolves a host name
 * and connects in the background: a failure arrives through on_close
 * ("cannot resolve host 'name': Name or service not known"), and bytes
 * written meanwhile wait in the queue.  NULL with err
 * set: SF_EINVAL for a bad spec or baud, SF_EIO when the device cannot be
 * opened, SF_EAGAIN when SF_RESOLVER_THREADS_MAX lookups are in flight.
 */
struct transport *transport_open(struct loop *l, const char *spec, int baud,
                                 transport_data_fn on_data, transport_close_fn on_close, void *ud,
                                 struct sf_err *err);

/* Queue n bytes.  SF_ENOMEM when the write queue cap is hit, SF_EIO when closed. */
int transport_write(struct transport *t, const void *data, size_t n);

/* Bytes queued but not yet handed to the OS. */
size_t transport_pending(const struct transport *t);

/* Drop anything the device has buffered for us (stale bytes from before open). */
void transport_flush_input(struct transport *t);

/* Close and free (a host name lookup in flight is abandoned).  NULL is fine.
   on_close is not called. */
void transport_free(struct transport *t);

/* getaddrinfo's signature: what TCP host name lookups call. */
typedef int (*transport_resolve_fn)(const char *host, const char *service,
                                    const struct addrinfo *hints, struct addrinfo **res);
/*
 * Test hook: resolve host names with fn (NULL: getaddrinfo again), e.g. one
 * that never answers.  fn runs on a lookup thread; its result is freed with
 * freeaddrinfo(), so it must come from getaddrinfo().  Set it before
 * opening transports; lookups already started keep their resolver.
 */
void transport_set_resolver(transport_resolve_fn fn);
/* Lookup threads still running (abandoned ones included). */
int transport_lookups_alive(void);

struct transport_port {
    char name[128];        /* /dev/ttyACM0 */
    char description[128]; /* product string */
    int vid, pid;          /* USB ids, -1 when not USB */
    char serial[64];       /* USB serial number or "" */
};

/* List serial ports; *out is freed with free().  SF_EIO on failure. */
int transport_list_ports(struct transport_port **out, size_t *n, struct sf_err *err);

#endif
