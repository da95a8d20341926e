/*
 * netdrv.h - the core the Moonraker, PrusaLink and OctoPrint drivers share: a
 * network printer that runs the job file itself and is watched by polling.
 *
 * All talk the same way (drv_moonraker.c, drv_prusalink.c and drv_octoprint.c say what
 * differs): one request at a time per printer; polls on a timer; an
 * action (upload, pause, resume, cancel, a manual command) takes the slot
 * as soon as it is free, cancelling a poll under way, so that no poll begun
 * before an action reports the printer as it was before it.  An upload
 * whose answer was lost is settled by the next poll (the printer runs our
 * file, or it is sent again, at most upload_tries times, or the job fails
 * with the reason).  Losing contact (5xx, timeout, refused): without a job
 * the printer goes DRV_OFFLINE and the farm reconnects with its backoff;
 * with one the driver rides out job_tries - 1 failed contacts (backoff 0.5,
 * 1, 2 s: the printer prints on without us; a failed upload is not one,
 * it counts against upload_tries), then goes offline too and
 * lets go of the job, which the farm marks interrupted and offers back
 * through attach() when the printer answers; unless the job's upload was
 * cut short and not yet sent again: the printer cannot have that file, so
 * the job fails with the reason (the farm's retry policy).
 *
 * OctoPrint's driver uses the core with job_tries and upload_tries 1: a
 * failed contact takes it offline at once, and a failed upload fails the
 * job (the farm's retry policy sends it again).
 *
 * A driver embeds struct netdrv first (which embeds struct drv first),
 * fills a struct netdrv_ops with its requests and replies, and points its
 * drv_ops at the netdrv_* operations it does not do itself.
 *
 * Thread: the loop thread.
 */
#ifndef SF_DRIVERS_NET_NETDRV_H
#define SF_DRIVERS_NET_NETDRV_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <jansson.h>

#include "../drv.h"
#include "httpc.h"
#include "netjob.h"

/* The poll period while the printer waits, when the config gives none (poll_idle_ms). */
#define NETDRV_IDLE_MS 5000

/* Kinds of request; a driver numbers its own from NETDRV_RQ_OWN. */
enum netdrv_rq {
    NETDRV_RQ_NONE = 0,
    NETDRV_RQ_POLL,   /* the status poll */
    NETDRV_RQ_INFO,   /* a connection check in place of a poll (Moonraker's /server/info) */
    NETDRV_RQ_UPLOAD, /* the job's file, streamed from disk */
    NETDRV_RQ_PAUSE,
    NETDRV_RQ_RESUME,
    NETDRV_RQ_CANCEL,
    NETDRV_RQ_OWN,
};

/* What a finished request amounts to. */
enum netdrv_outcome {
    NETDRV_OK,      /* 2xx */
    NETDRV_DOWN,    /* no answer, a timeout, or 5xx: contact lost */
    NETDRV_AUTH,    /* 401/403: "authentication failed" */
    NETDRV_REFUSED, /* another 4xx (409 "Printer is busy"): the printer's reason */
};

struct netdrv;

/* What a driver adds to the core. */
struct netdrv_ops {
    const char *product;  /* "Moonraker", for messages */
    const char *key_hint; /* what to check when the printer refuses us ("check api_key") */
    int poll_ms;          /* the poll period when the config gives none */
    int job_tries;        /* failed contacts in a row a job rides out before going offline
                             (polls and actions; a failed upload counts in upload_tries) */
    int upload_tries;     /* uploads of one job at the most */
    int timeout_ms;       /* a poll or an action */
    int upload_stall_ms;  /* an upload that moves nothing this long has failed */
    bool upload_403;      /* 403 to an upload is a refusal (Moonraker: the file is loaded) */
    int start_rq;         /* the driver's request that starts the uploaded file (OctoPrint's
                             select+print), or 0: on its way, the job is still starting, as
                             during the upload (cancel stops it, pause waits) */
    /* Start request kind in the free slot with netdrv_request; false (logged) if it could not. */
    bool (*start)(struct netdrv *n, int kind);
    /* The timer fired with the slot free: start the next poll; false if it could not. */
    bool (*poll)(struct netdrv *n);
    /* The reply to kind (the slot is free again). */
    void (*reply)(struct netdrv *n, int kind, const struct httpc_result *res);
    /* Send what waits (n->want, the driver's own), if anything; after every reply. */
    void (*kick)(struct netdrv *n);
    /* The printer's words in an error body, one line. */
    void (*error_text)(const char *body, size_t len, char *out, size_t n);
    /* Optional: forget the state of the job that ended or starts (PrusaLink's job id). */
    void (*forget)(struct netdrv *n);
    /* Optional: contact was lost; open() and close() too (connection state to reset). */
    void (*lost)(struct netdrv *n);
    /* Optional: read a reply in the driver's own words (OctoPrint names the request and
       "answered HTTP 503"); netdrv_judge's rule otherwise. */
    enum netdrv_outcome (*judge)(struct netdrv *n, int kind, const struct httpc_result *res,
                                 char *why, size_t len);
    /* Optional: the job's command lines done at progress (OctoPrint: those wholly before its
       file position); progress times lines_total otherwise. */
    uint64_t (*lines)(struct netdrv *n, double progress);
    /* Optional: a request of the driver's own that an action cuts short as it does a poll (one
       it asks again later: OctoPrint's push socket login). */
    int side_rq;
    /* Optional: the second request of the driver's status poll (OctoPrint's GET /api/printer),
       cut short by an action as the poll is: the next poll asks it again.  Left running, it
       held the slot an upload needs, and a job handed over then was refused ("the upload
       could not start"). */
    int poll_rq;
};

struct netdrv {
    struct drv base;
    const struct netdrv_ops *nops;
    struct httpc *http;    /* the loop's shared client (httpc_get) */
    char url[256];         /* base URL, no trailing '/' */
    char key_hdr[200];     /* "X-Api-Key: ...", or "" */
    bool open;             /* open() and not closed or gone offline */
    bool have_last;        /* a poll has answered since open() (attach reads it) */
    struct httpc_req *req; /* the request in flight, or NULL */
    int rq;                /* its kind (enum netdrv_rq or the driver's) */
    uint64_t timer;        /* the next poll, 0 if none */
    bool poll_now;         /* ... asked "at once" (netdrv_schedule 0: after an action), not the
                              period's (a driver with a push socket polls only then) */
    int fails;             /* contacts failed in a row */
    int poll_ms;           /* the poll period while a job runs or the printer works */
    int poll_idle_ms;      /* ... while it waits (>= poll_ms): netdrv_period */
    bool poll_only;        /* no push socket (drv_config.poll_only) */
    struct netjob job;     /* the job on the printer */
    char path[1024];       /* its file on disk (for a second upload) */
    int uploads;           /* upload attempts for it */
    bool verify;           /* the upload's fate is unknown: the next poll settles it */
    char upload_err[128];  /* why it is unknown */
    bool upload_cut;       /* ... and less than the file was sent (httpc_result.body_read):
                              the printer cannot run it */
    int want;              /* NETDRV_RQ_PAUSE/RESUME/CANCEL to send when the slot frees */
    char lost_name[160];   /* the job let go of at the last loss of contact, or "" */
};

/*
 * Set up n (zeroed by the caller) for cfg: check the url (http:// or
 * https://), copy it without trailing '/', the X-Api-Key header if a key
 * is given, the poll period, the shared HTTP client.  SF_EINVAL naming the
 * printer, or httpc_get's error.
 */
int netdrv_init(struct netdrv *n, struct loop *l, const struct drv_config *cfg,
                const struct drv_ops *ops, const struct netdrv_ops *nops, drv_event_fn on_event,
                void *ud, struct sf_err *err);

/*
 * Start a request of kind with o (done, ud and timeouts are filled here;
 * an upload gets no whole-request timeout but the stall limit, progress
 * reports, and counts in n->uploads).  False (logged) if it could not.
 */
bool netdrv_request(struct netdrv *n, int kind, struct httpc_opts *o);

/* Ask again (the timer) after ms. */
void netdrv_schedule(struct netdrv *n, int64_t ms);

/*
 * The period of the next poll, as the printer's state sets it: poll_ms
 * while a job of ours is on it or it prints, pauses or is busy (progress
 * and an end must be seen soon); poll_idle_ms while it waits (idle,
 * finished, halted): nothing there changes without us but a person at
 * the printer.
 */
int netdrv_period(const struct netdrv *n);

/* The reply res to request kind: what it amounts to, and why (the printer's words). */
enum netdrv_outcome netdrv_judge(struct netdrv *n, int kind, const struct httpc_result *res,
                                 char *why, size_t len);

/* The printer did not answer usefully (why): ride it out with a job, else offline. */
void netdrv_contact_lost(struct netdrv *n, const char *why);

/* The job ends here (not from a poll): report it with state st and message msg. */
void netdrv_end_job(struct netdrv *n, enum drv_state st, enum drv_event ev, const char *msg);

/*
 * The upload's reply: NETDRV_OK when it arrived (the driver goes on);
 * anything else is handled here (auth: the job fails and contact is lost;
 * refused: the job fails with the printer's reason; down: the next poll
 * settles whether it arrived), as it is when the job is no longer ours.
 */
enum netdrv_outcome netdrv_upload_reply(struct netdrv *n, const struct httpc_result *res);

/*
 * A poll's observation ob while an upload's fate is unknown: true when it
 * was settled here (sent again, or the job failed); false when the caller
 * judges ob as usual (it is ours, or the printer is busy, halted, ...).
 */
bool netdrv_settle(struct netdrv *n, const struct netjob_obs *ob);

/*
 * The printer's own estimate of the time left (secs; < 0: it gave none)
 * into status.has_time_left / time_left_s, kept only while the job on the
 * printer is ours (ob); call before netdrv_report.
 */
void netdrv_time_left(struct netdrv *n, const struct netjob_obs *ob, double secs);

/* Judge ob for the job and report it (netjob_judge, netjob_report), progress 0..1. */
void netdrv_report(struct netdrv *n, const struct netjob_obs *ob, double progress);

/* Judge the reply to an action (netdrv_judge); when it is NETDRV_OK, poll at once. */
enum netdrv_outcome netdrv_answered(struct netdrv *n, int kind, const struct httpc_result *res,
                                    char *why, size_t len);

/* The reply to pause, resume or cancel (kind): a refusal is the printer's reason. */
void netdrv_action_reply(struct netdrv *n, int kind, const struct httpc_result *res);

/* Names for logs: "pause", the driver's own kinds by its names[] from NETDRV_RQ_OWN. */
const char *netdrv_rq_name(int kind, const char *const *own, size_t n_own);

/*
 * attach()'s first half: SF_EAGAIN while not connected or busy with a
 * job, else netjob_prepare into j.
 */
int netdrv_attach_prepare(struct netdrv *n, const char *gcode_path, const struct drv_job_scan *scan,
                          struct netjob *j, struct sf_err *err);

/* attach()'s second half: take j as the running job, judged by ob at progress. */
void netdrv_adopt(struct netdrv *n, const struct netjob *j, const struct netjob_obs *ob,
                  double progress);

/* drv_ops shared as they are. */
int netdrv_open(struct drv *d, struct sf_err *err);
int netdrv_start_job(struct drv *d, const char *gcode_path, uint64_t first_line,
                     const struct drv_job_scan *scan, struct sf_err *err);
int netdrv_pause(struct drv *d, struct sf_err *err);
int netdrv_resume(struct drv *d, struct sf_err *err);
int netdrv_cancel(struct drv *d, struct sf_err *err);
void netdrv_close(struct drv *d);
void netdrv_destroy(struct drv *d);

/* Cancel a poll under way so an action goes first (the poll is asked again after it). */
void netdrv_preempt_poll(struct netdrv *n);

/*
 * kick()'s first step: when the slot is free, start the action that waits
 * (n->want).  True when the slot is still free for the driver's own
 * requests; false when it is taken or the printer is not open.
 */
bool netdrv_send_want(struct netdrv *n);

/*
 * Reading the printers' JSON with messages that name the field: "who
 * where.key: missing" ("prusalink job.id: missing").  Pure.
 */
/* body as JSON (an object if object), or NULL with err set ("who what: not JSON: ..."). */
json_t *netdrv_json_load(const char *who, const char *body, size_t len, const char *what,
                         bool object, struct sf_err *err);
/* obj.key, a string, into out (n bytes; "" when absent, which is an error if required). */
int netdrv_json_str(const char *who, json_t *obj, const char *key, const char *where, char *out,
                    size_t n, bool required, struct sf_err *err);
/* obj.key, a number, into *out (left as it is when absent, an error if required). */
int netdrv_json_num(const char *who, json_t *obj, const char *key, const char *where, double *out,
                    bool required, struct sf_err *err);
/* obj.key, a whole number 0 .. 9e15, into *out (as netdrv_json_num). */
int netdrv_json_int(const char *who, json_t *obj, const char *key, const char *where, int64_t *out,
                    bool required, struct sf_err *err);
/* obj.key, an object or null or absent, into *out (NULL unless an object). */
int netdrv_json_obj(const char *who, json_t *obj, const char *key, const char *where, json_t **out,
                    struct sf_err *err);
/* The first non-blank line of a body that is not the documented error shape (a proxy's page). */
void netdrv_first_line(const char *body, size_t len, char *out, size_t n);

#endif
