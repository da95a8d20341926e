/*
 * drv.h - the printer driver interface: one vtable for every kind of
 * printer (Marlin over serial/pty/TCP, OctoPrint, Moonraker, Bambu LAN), so
 * the daemon never knows which protocol it talks.
 *
 * Shaped like SQLite's VFS: struct drv_ops holds a version and the
 * operations; each driver embeds struct drv as its first member and casts.
 * Drivers run on the loop thread (loop.h), never block and never own
 * threads: they register their fds and timers with the loop and report
 * through the on_event callback.
 *
 * Lifecycle: drv_new() parses the config and creates the driver without
 * touching the device; ops->open() starts connecting (result arrives as a
 * DRV_EV_STATE event); start_job/pause/resume/cancel act on the job;
 * ops->close() disconnects; drv_free() destroys.  A driver whose link drops
 * reports DRV_OFFLINE; the owner decides when to open() again (backoff).
 */
#ifndef SF_DRIVERS_DRV_H
#define SF_DRIVERS_DRV_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../src/base/err.h"
#include "../src/base/loop.h"
#include "gcheck.h"

/* 2: attach (network printers re-attach after a daemon restart); drv_kind.auth, schemes.
   3: estop (an operator's emergency stop). */
#define DRV_OPS_VERSION 3

enum drv_state {
    DRV_OFFLINE = 0, /* not connected */
    DRV_CONNECTING,  /* link up, handshake in progress */
    DRV_IDLE,        /* ready for a job */
    DRV_PRINTING,    /* streaming a job */
    DRV_PAUSED,      /* job paused (by us or by the printer) */
    DRV_ERROR,       /* printer halted or reported a fatal error; needs attention */
};

enum drv_event {
    DRV_EV_STATE,         /* status.state changed */
    DRV_EV_PROGRESS,      /* lines acknowledged moved on (rate-limited by the driver) */
    DRV_EV_TEMPS,         /* new temperature report */
    DRV_EV_JOB_DONE,      /* the job's last line was acknowledged and executed */
    DRV_EV_JOB_FAILED,    /* the job stopped; status.message says why, lines_acked where */
    DRV_EV_JOB_CANCELLED, /* cancel() finished: end sequence acknowledged (added for issue 6) */
};

struct drv_status {
    enum drv_state state;
    double nozzle_c, nozzle_target_c; /* last reported temperatures, deg C */
    double bed_c, bed_target_c;
    uint64_t lines_total;   /* command lines in the running job */
    uint64_t lines_acked;   /* of those, acknowledged by the printer */
    double progress;        /* 0..1 */
    bool has_time_left;     /* the printer gave its own estimate of the time left */
    int64_t time_left_s;    /* that estimate, seconds */
    int64_t job_started_ms; /* loop time the job started */
    char message[160];      /* last error or notice, for operators */
};

struct drv_caps {
    char firmware[64];    /* FIRMWARE_NAME from M115, or the server's name */
    bool advanced_ok;     /* replies carry ok N P B */
    bool autoreport_temp; /* M155 supported */
    bool host_actions;    /* // action: commands understood */
    int buffer_lines;     /* command lines the firmware can queue (BUFSIZE) */
};

/*
 * How to reach a printer.  From the farm config, each field is filled by the
 * link option whose row names it (the kinds' tables in drv.c, drv_link.h);
 * a new field needs its row there and nothing else in the farm.  Text
 * fields may be NULL or "" for "not given" (timeout_ms has no option).
 */
struct drv_config {
    const char *name;     /* printer name, for logs */
    const char *kind;     /* "marlin", "octoprint", "moonraker", "bambu" */
    const char *port;     /* marlin: /dev/ttyUSB0 | pty:/dev/pts/N | tcp://host:port */
    int baud;             /* serial baud rate (0: 115200) */
    const char *url;      /* network printers: base URL (http://host[:port][/prefix]) */
    const char *api_key;  /* network printers: key or access code ("" or NULL: none) */
    const char *user;     /* network printers: HTTP digest user (PrusaLink), or NULL */
    const char *password; /* its password */
    int poll_ms;          /* network printers: status poll period while a job runs or the
                             printer works (0: the driver's, 1000) */
    int poll_idle_ms;     /* ... while it waits: idle, finished, halted (0: 5000; never below
                             poll_ms) */
    bool poll_only;       /* OctoPrint, Moonraker: no push socket, status by polls alone */
    int timeout_ms;       /* marlin: margin past the expected execution time of the lines in
                             flight before a probe (0: 1000) */
    int buffer_lines;     /* marlin: the firmware's BUFSIZE, most lines in flight (0: 4;
                             ADVANCED_OK's B when it says more; 1: ping-pong) */
    int rx_buffer;        /* marlin: the firmware's RX ring, bytes (0: 128) */
    const char *serial;   /* bambu: the printer's serial, its device id and certificate CN */
    const char *ca_file;  /* bambu: CA bundle the printer's certificate must chain to */
    bool tls_insecure;    /* bambu: no certificate check at all (operator's choice; warned) */
    int ftps_port;        /* bambu: implicit FTPS port (0: 990) */
};

/* The machine state a job's commands leave behind: what a resume restores. */
struct drv_machine {
    bool rel_xyz, rel_e; /* G91 / M83 */
    double pos[4];       /* X Y Z E, mm */
    double feed_mm_min;  /* last F */
    double noz_c, bed_c; /* last targets */
    double fan;          /* M106 S, 0 off */
};

/*
 * What drv_job_scan() learns from a job file, for start_job.  Keep it with
 * the job: it holds as long as the file does not change (the farm's files
 * are content-addressed, so they never do).  drv_job_scan_to() adds a
 * resume point.
 */
struct drv_job_scan {
    uint64_t lines_total; /* command lines (comments and blank lines not counted) */
    uint64_t resume_line; /* > 0: command resume_line starts at byte resume_at, */
    int64_t resume_at;    /* and the commands before it leave machine */
    struct drv_machine machine;
};

struct drv;
typedef void (*drv_event_fn)(struct drv *d, enum drv_event ev, void *ud);

struct drv_ops {
    int version;      /* DRV_OPS_VERSION */
    const char *kind; /* "marlin" */
    int (*open)(struct drv *d, struct sf_err *err);
    /*
     * Stream gcode_path from its command first_line (0-based, comments and
     * blank lines not counted).  first_line > 0 resumes a job the printer
     * lost (daemon or printer restarted): the driver first brings the
     * machine back to the state the job's earlier lines left (heat, home
     * X/Y only, Z set where those lines left it, E, fan, feed) and reports
     * lines_acked = first_line.  SF_EINVAL when first_line is not below the
     * job's command count; SF_EAGAIN when the printer is not idle.
     *
     * scan: what drv_job_scan() found in this very file, made off the loop
     * thread; the driver trusts it and does not read the whole file (a job
     * start only opens it; a resume reads up to first_line, unless the scan
     * holds that line's resume point, drv_job_scan_to).  NULL: the
     * driver counts and checks the whole file itself, on the loop thread
     * (fine for small files and one-off tools; a 150 MB job stalls ~2.5 s).
     */
    int (*start_job)(struct drv *d, const char *gcode_path, uint64_t first_line,
                     const struct drv_job_scan *scan, struct sf_err *err);
    int (*pause)(struct drv *d, struct sf_err *err);
    int (*resume)(struct drv *d, struct sf_err *err);
    int (*cancel)(struct drv *d, struct sf_err *err);
    /* Queue one manual command (console); SF_EAGAIN while printing. */
    int (*command)(struct drv *d, const char *line, struct sf_err *err);
    void (*close)(struct drv *d);
    void (*destroy)(struct drv *d);
    /* Version 2 on (appended, as SQLite's VFS grows): */
    /*
     * Re-attach (NULL for drivers whose job dies with the host, Marlin):
     * a network printer keeps printing when the daemon dies.  After a
     * restart, once the driver has connected (status.state left
     * DRV_CONNECTING), the owner offers it the job it last gave this
     * printer, gcode_path (scan as for start_job, or NULL).  If the
     * printer is printing or paused on that job's upload (the name
     * drv_remote_name() gives, with the file's size), or ended it since
     * (complete or cancelled at the printer), the driver adopts it without
     * sending anything and reports on it as on a job it started: progress,
     * then DRV_EV_JOB_DONE / FAILED / CANCELLED (possibly at once).
     * SF_ENOTFOUND when the printer knows nothing of it (the owner marks
     * the job interrupted, as for Marlin); SF_EAGAIN while not connected.
     */
    int (*attach)(struct drv *d, const char *gcode_path, const struct drv_job_scan *scan,
                  struct sf_err *err);
    /* Version 3 on: */
    /*
     * An operator's emergency stop (NULL: the kind has none; the owner
     * cancels the job instead): halt the printer now, past anything queued
     * (Marlin: M112 straight to the wire, which its emergency parser runs
     * on arrival), fail the job, if any, and report DRV_ERROR.  Any state
     * but offline; SF_EAGAIN when offline.
     */
    int (*estop)(struct drv *d, struct sf_err *err);
};

struct drv {
    const struct drv_ops *ops;
    struct loop *loop;
    char name[64];         /* printer name, for logs */
    drv_event_fn on_event; /* owner's callback (loop thread) */
    void *ud;              /* its argument */
    struct drv_status status;
    struct drv_caps caps;
};

/* What a network kind needs to authenticate (farmcfg checks the config by it). */
enum drv_auth {
    DRV_AUTH_NONE = 0,      /* nothing (serial) */
    DRV_AUTH_KEY,           /* api_key required (OctoPrint) */
    DRV_AUTH_KEY_OPTIONAL,  /* api_key if the server asks for one (Moonraker) */
    DRV_AUTH_KEY_OR_DIGEST, /* api_key, or user and password for HTTP digest (PrusaLink) */
};

struct drv_option; /* drv_link.h */

/*
 * One kind of printer driver: a row of drv.c's registry, the one list of
 * kinds.  The row says everything the rest of the farm needs to know of the
 * kind: how to create it, its link options (each with its type, default,
 * check, drv_config field, secrecy and whether a reload may change it live:
 * drv_link.h), its own rules over them, and which G-code rules its jobs
 * must pass.
 */
struct drv_kind {
    const char *name;    /* the config's "driver:" value, e.g. "marlin" */
    bool url;            /* reached by URL (network) rather than by port (serial, pty, TCP) */
    enum drv_auth auth;  /* url kinds: the credentials the config must give */
    const char *schemes; /* url kinds: accepted URL schemes, space-separated ("http https") */
    struct drv *(*create)(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event,
                          void *ud, struct sf_err *err);
    /* its link options: tables (each ended by a row with a NULL name, shared between kinds
       where the options are), NULL after the last */
    const struct drv_option *options[4];
    /* its own rules over a whole link (NULL: none): 0 when cfg is fine, else -1 with why set
       to what the config must change ("options 'serial' and 'access_code' are required by
       driver bambu"); cfg is drv_link_config's */
    int (*check)(const struct drv_config *cfg, char *why, size_t n);
    enum gcheck_rules gcode; /* the rules its job files must pass (gcheck.h) */
};

/*
 * The rules drv_job_scan applies: every kind's row names these today (a unit
 * test holds them equal), so a file checked before its printer is known
 * fits whichever printer takes it.
 */
#define DRV_JOB_RULES GCHECK_MARLIN

/* The kind called name, or NULL. */
const struct drv_kind *drv_kind_find(const char *name);
/* Kind i (0, 1, ...), NULL past the last: for listing them in messages. */
const struct drv_kind *drv_kind_at(size_t i);

/*
 * Create the driver for cfg->kind on loop l.  Nothing is opened yet.
 * SF_EINVAL / SF_EUNSUPP with a message for a bad or unknown config.
 */
struct drv *drv_new(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event, void *ud,
                    struct sf_err *err);
/* close() if open, then destroy.  NULL is fine. */
void drv_free(struct drv *d);

const char *drv_state_name(enum drv_state s);

/*
 * The name under which network drivers upload gcode_path, the same for
 * every driver and every daemon run (so a restarted daemon recognises its
 * job on the printer): "sf-" and the file's base name (the farm's files are
 * named by their SHA-256, so the name says which content it holds), kept
 * to [A-Za-z0-9._-] and 64 bytes, ending in ".gcode".  out holds n >= 74.
 */
void drv_remote_name(const char *gcode_path, char *out, size_t n);

/*
 * Read and check a whole job file once, so that a job never fails half-way
 * on a bad line and start_job need not read it: gcheck_scan by
 * DRV_JOB_RULES.  Counts its command lines, and refuses a line longer than
 * SF_GCODE_LINE_MAX or a command no driver could send (SF_EINVAL, the
 * message naming 'path':line).  SF_EIO when the
 * file cannot be read.  Pure: any thread (the farm runs it on a prepare
 * worker); it reads a 150 MB file in about as long as start_job used to
 * stall the loop.
 */
int drv_job_scan(const char *path, struct drv_job_scan *scan, struct sf_err *err);

/*
 * gcheck_scan_to by DRV_JOB_RULES: add to scan (whose lines_total the
 * caller knows) the resume point of command first_line (1 .. lines_total -
 * 1): where it starts and the machine state the commands before it leave,
 * reading the file only up to it.  start_job given this scan and first_line reads nothing before it
 * streams.  SF_EINVAL if the file holds no such command, SF_EIO.  Pure:
 * any thread (a resume from 2/3 of a 112 MB job reads for ~0.5 s).
 */
int drv_job_scan_to(const char *path, uint64_t first_line, struct drv_job_scan *scan,
                    struct sf_err *err);

/*
 * Delay before reconnect attempt number `attempt` (0, 1, ...): 500 ms
 * doubling up to 30 s.  The one reconnect policy: the farm re-open()s a
 * driver gone OFFLINE after this long.
 */
int drv_backoff_ms(int attempt);

#endif
