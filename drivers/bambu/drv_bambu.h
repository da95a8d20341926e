/*
 * drv_bambu.h - the Bambu Lab LAN-mode driver (behind drv.h): X1, P1, A1
 * and H2 printers over MQTT/TLS (status and commands) and implicit FTPS
 * (the job, a .gcode.3mf).
 *
 * Config (drv_config): url = the printer's IP address, or
 * "mqtts://IP[:PORT]" (PORT default 8883); api_key = the LAN access code;
 * serial = the device id (the MQTT topics and the certificate's CN);
 * ca_file = the CA the printer's certificate must chain to (Bambu's "BBL
 * CA"), checked with the serial as the expected name; tls_insecure skips
 * every certificate check (logged as a warning); ftps_port (default 990).
 *
 * Printing needs LAN Only mode with Developer Mode on (firmware since 2025
 * refuses unsigned control commands otherwise); without it the driver
 * still reads status and reports the refusal as an error saying what to
 * switch on.
 *
 * Thread: loop thread.
 */
#ifndef SF_DRIVERS_BAMBU_DRV_BAMBU_H
#define SF_DRIVERS_BAMBU_DRV_BAMBU_H

#include <stdint.h>

#include "../drv.h"

struct drv_bambu_stats {
    uint64_t reports;       /* report messages merged */
    uint64_t pushalls;      /* pushall requests sent */
    int64_t pushall_gap_ms; /* shortest time between two of them (loop clock), -1 until two */
    uint64_t requests;      /* other requests sent */
    uint64_t connects;      /* MQTT sessions that came up */
    uint64_t uploads;       /* packages uploaded */
    int upload_pct;         /* the last upload's progress as shown ("uploading N %"), -1 none */
    uint64_t upload_steps;  /* percentages shown strictly between 0 and 100, every upload */
    char gcode_state[16];   /* the printer's last gcode_state */
    int mc_percent;         /* and progress */
    int remaining_min;      /* mc_remaining_time */
    int layer_num, total_layer_num;
};

struct drv *drv_bambu_new(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event,
                          void *ud, struct sf_err *err);

/* Counters and the cached report; false if d is not a Bambu driver. */
bool drv_bambu_stats(const struct drv *d, struct drv_bambu_stats *out);

#endif
