/*
 * sim_bambu_relay.h - the simulated Bambu printer's own MQTT port: a TCP
 * relay from a loopback port of its own to the broker the test started.
 *
 * On a printer the broker runs inside the printer, so when the printer's
 * MQTT service goes away, every client's connection drops with it.  The
 * tests' broker is a separate mosquitto, which the simulator reaches as a
 * client like any other; a client that connects through this relay
 * instead (sim_bambu_mqtt_port) sees what a printer's clients see when
 * the simulator drops its MQTT (fault mqtt-drop): its connection cut, and
 * refused until the service is back.  TLS and MQTT pass through untouched:
 * the certificate and the access code are still the broker's to show and
 * check.
 *
 * Thread: loop thread.  Owns its listening socket and every relayed pair
 * of sockets; sim_bambu_relay_free closes them all.
 */
#ifndef SF_SIM_BAMBU_SIM_BAMBU_RELAY_H
#define SF_SIM_BAMBU_SIM_BAMBU_RELAY_H

#include <stdbool.h>
#include <stddef.h>

#include "../../src/base/err.h"
#include "../../src/base/loop.h"

struct sim_bambu_relay;

/*
 * Listen on a free loopback port and relay each connection to
 * host:port (an IPv4 address).  NULL with err set (SF_EIO, SF_ENOMEM).
 */
struct sim_bambu_relay *sim_bambu_relay_new(struct loop *l, const char *host, int port,
                                            struct sf_err *err);
/* The port clients connect to. */
int sim_bambu_relay_port(const struct sim_bambu_relay *r);
/*
 * down: cut every relayed connection now (both sides) and refuse new ones
 * (accepted, then closed) until set up again.  Returns the connections cut.
 */
size_t sim_bambu_relay_set_down(struct sim_bambu_relay *r, bool down);
/* Connections relayed so far (accepted while up). */
size_t sim_bambu_relay_accepted(const struct sim_bambu_relay *r);
/* Close everything and free.  NULL is fine. */
void sim_bambu_relay_free(struct sim_bambu_relay *r);

#endif
