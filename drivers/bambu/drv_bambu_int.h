/*
 * drv_bambu_int.h - internal to the Bambu driver (drv_bambu.c and
 * drv_bambu_upload.c), not for other modules: the driver's state and the
 * few helpers the two files share.  drv_bambu.c follows the printer over
 * MQTT (reports, state, job control); drv_bambu_upload.c packs the job's
 * .gcode.3mf, uploads it by FTPS and starts it with project_file.
 *
 * Thread: loop thread.
 */
#ifndef SF_DRIVERS_BAMBU_DRV_BAMBU_INT_H
#define SF_DRIVERS_BAMBU_DRV_BAMBU_INT_H

#include <jansson.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../../src/base/mqttloop.h"
#include "../net/httpc.h"
#include "drv_bambu.h"
#include "gcode3mf.h"

enum jphase {
    J_NONE,      /* no job of ours */
    J_PACKING,   /* writing the .gcode.3mf */
    J_UPLOADING, /* FTPS transfer running */
    J_SENT,      /* project_file published; waiting for a report that shows it running */
    J_ACTIVE,    /* the printer runs our job */
};

struct bambu {
    struct drv d; /* first: drivers are cast from struct drv */
    char host[128];
    int mqtt_port, ftps_port;
    char serial[64];
    char code[64];
    char ca_file[512];
    bool insecure;
    struct curl_slist *resolve; /* "SERIAL:FTPS_PORT:HOST" for CURLOPT_RESOLVE */
    char topic_report[96], topic_request[96];
    struct mqttloop *mqtt;
    struct httpc *http;
    bool open;               /* between open() and close() */
    json_t *print;           /* merged "print" object of every report */
    int64_t last_pushall_ms; /* loop time of the last pushall, 0 never */
    uint64_t pushall_timer;
    unsigned seq; /* request sequence ids */
    struct drv_bambu_stats stats;
    bool refused; /* unsigned commands refused: Developer Mode is off */
    /* the job */
    enum jphase phase;
    bool cancelling;    /* stop sent for our job */
    char subtask[96];   /* our job's name on the printer */
    char file[128];     /* its package's name on the printer's storage */
    char pkg_path[600]; /* the package on our disk, while it exists */
    char pkg_md5[33];
    struct gcode3mf *pack;
    uint64_t pack_timer;
    struct httpc_req *upload;
    char project_seq[16]; /* sequence_id of our project_file */
    int last_percent;
};

/* Tell the owner ev (drv.h on_event). */
void drv_bambu_emit(struct bambu *b, enum drv_event ev);

/* Publish {key: body} (body taken, a sequence_id added; its text into seq_out[16] if not NULL);
   SF_EAGAIN when not connected, SF_ENOMEM, or mqttloop_publish's error. */
int drv_bambu_request(struct bambu *b, const char *key, json_t *body, char *seq_out,
                      struct sf_err *err);

/* Our job ended with ev: DRV_IDLE, message msg (NULL keeps it), the events. */
void drv_bambu_job_end(struct bambu *b, enum drv_event ev, const char *msg);

/* A certificate check that failed on link ("MQTT", "FTPS upload"), in the operator's words. */
void drv_bambu_tls_message(struct bambu *b, const char *link, const char *detail, char *out,
                           size_t n);

/* Loop timer: pack the next part of the .gcode.3mf; once whole, upload it, then start it. */
void drv_bambu_pack_step(struct loop *l, void *ud);

/* Stop packing and delete the package from our disk. */
void drv_bambu_drop_package(struct bambu *b);

#endif
