/*
 * drv_moonraker.h - the Klipper driver, through Moonraker's HTTP API
 * (behind drv.h), and the parsers of Moonraker's replies it is built on.
 *
 * Most callers use drv_new() with kind "moonraker"; this header adds the
 * constructor drv.c calls, and the pure functions that read Moonraker's
 * JSON, so the tests can check them against bodies that follow Moonraker's
 * documentation field by field (tests/replay/moonraker/).
 *
 * The API as documented (Arksine/moonraker docs/external_api/ (server, printer, file_manager,
 * history) and
 * docs/printer_objects.md, v0.10.0-31): HTTP replies are {"result": ...},
 * except the upload's, which is the bare object; errors are
 * {"error": {"code", "message"}}.
 *
 * Thread: loop thread for the driver; the parsers are pure (any thread).
 */
#ifndef SF_DRIVERS_NET_DRV_MOONRAKER_H
#define SF_DRIVERS_NET_DRV_MOONRAKER_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../drv.h"
#include "netjob.h"

/* What one GET /printer/objects/query?webhooks&print_stats&... says. */
struct moonraker_status {
    char klippy[16];                  /* webhooks.state: ready, startup, shutdown, error */
    char klippy_message[160];         /* webhooks.state_message */
    char state[16];                   /* print_stats.state: standby, printing, paused, complete,
                                         cancelled, error ("" when absent) */
    char filename[256];               /* print_stats.filename, relative to the gcodes root */
    char message[160];                /* print_stats.message (the error of an "error" job) */
    double progress;                  /* virtual_sdcard.progress, 0..1 (by file position) */
    int64_t file_position;            /* virtual_sdcard.file_position, bytes */
    int64_t file_size;                /* virtual_sdcard.file_size, bytes (0: no file) */
    double print_duration_s;          /* print_stats.print_duration (pauses excluded) */
    double nozzle_c, nozzle_target_c; /* extruder.temperature, .target */
    double bed_c, bed_target_c;       /* heater_bed.temperature, .target */
};

/* What POST /server/files/upload answered (201). */
struct moonraker_upload {
    char path[256];     /* item.path, relative to the root */
    int64_t size;       /* item.size, bytes */
    bool print_started; /* the print began */
    bool print_queued;  /* Moonraker's job queue took it instead */
};

/*
 * Parse a /printer/objects/query reply into st.  Objects the printer lacks
 * are left zero (Moonraker omits them); webhooks and print_stats must be
 * there.  SF_EINVAL naming the field when the body is not the documented
 * shape.
 */
int drv_moonraker_parse_status(const char *body, size_t len, struct moonraker_status *st,
                               struct sf_err *err);

/* What GET /server/files/metadata?filename=NAME says of the file (file_manager.md). */
struct moonraker_meta {
    double modified;    /* result.modified: unix time the file was last written (uploaded) */
    int64_t size;       /* result.size, bytes */
    double estimated_s; /* result.estimated_time: the slicer's print time, s; -1 if absent */
};

/* Parse a metadata reply; modified and size are required.  SF_EINVAL naming the field. */
int drv_moonraker_parse_meta(const char *body, size_t len, struct moonraker_meta *m,
                             struct sf_err *err);

/* How the newest job of one file ended, from GET /server/history/list (history.md). */
struct moonraker_hist {
    bool found;        /* an entry for the file, started at or after `since` */
    char status[24];   /* its status: completed, cancelled, error, klippy_shutdown,
                          klippy_disconnect, interrupted, in_progress */
    double start_time; /* unix time */
    double end_time;   /* unix time; 0 if null */
    int64_t size;      /* metadata.size of the file then, bytes; -1 if not given */
};

/*
 * Parse a history list reply (newest first or not: the newest entry wins)
 * and find the newest job of filename that started at or after since
 * (unix time: the upload's).  SF_EINVAL naming the field for a reply not
 * of the documented shape (result.jobs[i].filename, .status, .start_time).
 */
int drv_moonraker_parse_history(const char *body, size_t len, const char *filename, double since,
                                struct moonraker_hist *h, struct sf_err *err);

/*
 * The time left of the job in st (s; -1 when it cannot be told), as
 * Mainsail tells it (src/store/printer/getters.ts): the slicer's estimate
 * (the file's metadata estimated_time, estimated_s; < 0 if unknown) less
 * print_stats.print_duration while that is still short of it, else
 * print_duration / progress - print_duration (Mainsail's "file"
 * estimate).  Moonraker itself reports no time left.  Pure.
 */
double drv_moonraker_time_left(const struct moonraker_status *st, double estimated_s);

/* Parse GET /server/info: result.klippy_state into state (n bytes).  SF_EINVAL. */
int drv_moonraker_parse_info(const char *body, size_t len, char *state, size_t n,
                             struct sf_err *err);

/* Parse the upload reply (bare, or wrapped in "result").  SF_EINVAL. */
int drv_moonraker_parse_upload(const char *body, size_t len, struct moonraker_upload *up,
                               struct sf_err *err);

/*
 * The printer's words in an error reply: error.message of
 * {"error": {...}}, else the body's first line (trimmed, at most n - 1
 * bytes), else "".  Never fails.
 */
void drv_moonraker_error_text(const char *body, size_t len, char *out, size_t n);

/*
 * Name st in netjob's words (klippy not ready first, then print_stats)
 * and say whether its job is job_name of job_size bytes (0: size not
 * compared).  o->file and o->message point into st.
 */
void drv_moonraker_observe(const struct moonraker_status *st, const char *job_name,
                           int64_t job_size, struct netjob_obs *o);

/* The constructor drv.c calls for kind "moonraker". */
struct drv *drv_moonraker_new(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event,
                              void *ud, struct sf_err *err);

#endif
