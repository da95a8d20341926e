/*
 * sim_moonraker_int.h - internal to the Moonraker simulator: the state
 * sim_moonraker.c (Klippy, the job, the history) and sim_moonraker_srv.c
 * (the server side clients read beside the printer: file lists, roots,
 * temperature store, config, the OctoPrint emulation) share, and the reply
 * helpers.  Not for other modules.
 *
 * Thread: the loop thread.
 */
#ifndef SF_SIM_NET_SIM_MOONRAKER_INT_H
#define SF_SIM_NET_SIM_MOONRAKER_INT_H

#include <jansson.h>
#include <stdbool.h>
#include <stdint.h>

#include "sim_http.h"
#include "sim_moonraker.h"
#include "sim_netbase.h"

#define HISTORY_MAX 256 /* job history entries kept (Moonraker keeps them all; tests need few) */

enum klippy { K_READY, K_STARTUP, K_SHUTDOWN };

/* One entry of Moonraker's job history (history.md, "Job History"). */
struct hist_job {
    char id[8];                     /* job_id: "000001", ... */
    char file[SIM_NP_NAME_MAX + 1]; /* filename */
    char status[24];                /* in_progress, completed, cancelled, error, ... */
    double start, end;              /* unix times; end 0 while in progress */
    double print_s;                 /* print_duration */
    int64_t size;                   /* metadata.size */
    double modified;                /* metadata.modified */
    double estimated_s;             /* metadata.estimated_time, -1 if none */
};

/* Samples the temperature store keeps: Moonraker's default temperature_store_size. */
#define TEMP_STORE_MAX 1200
#define TEMP_SENSORS   2 /* extruder, heater_bed */

/* server.temperature_store: one sample a second per heater, oldest first (a ring). */
struct temp_store {
    float temp[TEMP_SENSORS][TEMP_STORE_MAX];
    float target[TEMP_SENSORS][TEMP_STORE_MAX];
    float power[TEMP_SENSORS][TEMP_STORE_MAX];
    int n, head;     /* samples held, the oldest's index */
    int64_t next_ms; /* loop time of the next sample */
};

struct sim_moonraker {
    struct sim_netbase b; /* machine, HTTP server, watch timer; first (sim_netbase.h) */
    struct sim_moonraker_config cfg;
    enum klippy klippy;
    char klippy_msg[512];                           /* webhooks.state_message */
    int64_t ready_at_ms;                            /* startup ends at this loop time */
    bool fired_shutdown, fired_error, fired_cancel; /* each fault once a job */
    char fired_for[SIM_NP_NAME_MAX + 1];            /* ... the job they fired for */
    int64_t fired_started;                          /* its start (print_time_s of 0) */
    double file_mtime;                              /* upload time of the current file */
    struct hist_job hist[HISTORY_MAX];              /* the job history, oldest first */
    int n_hist;
    int hist_ids; /* job_ids handed out */
    struct temp_store temps;
    int ws_ids;            /* websocket connection ids handed out */
    enum klippy ws_klippy; /* Klippy's state the sockets were last told */
    long ready_missed;     /* notify_klippy_ready not sent (miss-ready) */
    int64_t next_push_ms;  /* loop time of the next notify_status_update round */
    uint64_t n_queries;    /* /printer/objects/query answered over HTTP */
};

/* Reply 200 with {"result": result} (stolen; NULL: null). */
void sim_moonraker_result(struct sim_http_req *r, json_t *result);
/* Reply status with Moonraker's {"error": {"code", "message"}}. */
void sim_moonraker_error(struct sim_http_req *r, unsigned status, const char *message);

/* False, after answering 503 "Klippy Host not connected", while Klippy starts up. */
bool sim_moonraker_klippy_up(struct sim_moonraker *s, struct sim_http_req *r);

/* Take a temperature sample if a second has passed (the watch calls it). */
void sim_moonraker_temps_sample(struct sim_moonraker *s, const struct sim_np_status *st);

/* The status objects want asks for ({"name": null or [attrs]}; NULL: all of them, whole). */
json_t *sim_moonraker_pick(struct sim_moonraker *s, json_t *want, const struct sim_np_status *st);
/* Klipper's eventtime: monotonic seconds. */
double sim_moonraker_eventtime(void);
/* The results of server.info, printer.info and printer.objects.list. */
json_t *sim_moonraker_server_info(struct sim_moonraker *s);
json_t *sim_moonraker_printer_info(struct sim_moonraker *s);
json_t *sim_moonraker_objects_list(void);

/* sim_moonraker_ws.c: the /websocket route's handler, the sockets' hub (NULL if out of memory),
   and the watch's turn (Klippy's state changes, status updates every SIM_MR_PUSH_MS). */
#define SIM_MR_PUSH_MS 250 /* Klipper batches subscription updates every 250 ms */
void sim_moonraker_on_websocket(struct sim_http_req *r, void *ud);
struct sim_ws_hub *sim_moonraker_ws_hub(struct sim_moonraker *s);
void sim_moonraker_ws_watch(struct sim_moonraker *s, const struct sim_np_status *st);
/* Klippy's connection is gone (a restart): every socket's subscription is dropped, as
   klippy_connection.py's _on_connection_closed does, and notify_klippy_disconnected sent. */
void sim_moonraker_ws_klippy_lost(struct sim_moonraker *s);
/* notify_gcode_response with one line of G-code output, to every authorized socket. */
void sim_moonraker_ws_gcode_response(struct sim_moonraker *s, const char *line);
/* Run a G-code script (lines split by newlines; RESPOND and M118 answer "echo: ...", an
   error "!! ..." on every socket, as Klipper's gcode.py writes them): SF_OK, or the first
   failure (queue full, printer in error) with err set; what came before it ran. */
int sim_moonraker_script(struct sim_moonraker *s, const char *script, struct sf_err *err);

/* Handlers of sim_moonraker_srv.c (ud: the simulator). */
void sim_moonraker_on_subscribe(struct sim_http_req *r, void *ud);
void sim_moonraker_on_files_list(struct sim_http_req *r, void *ud);
void sim_moonraker_on_roots(struct sim_http_req *r, void *ud);
void sim_moonraker_on_temperature_store(struct sim_http_req *r, void *ud);
void sim_moonraker_on_config(struct sim_http_req *r, void *ud);
void sim_moonraker_on_octo_version(struct sim_http_req *r, void *ud);
void sim_moonraker_on_octo_server(struct sim_http_req *r, void *ud);
void sim_moonraker_on_octo_login(struct sim_http_req *r, void *ud);

#endif
