/*
 * sim_netprinter.h - the machine behind every simulated network printer
 * (OctoPrint, Moonraker, PrusaLink, Bambu): a simulated Marlin (sim_marlin.h)
 * on a socketpair, plus the host that a real network printer runs in front
 * of its firmware, which streams an uploaded file to it.
 *
 * This is what OctoPrint is in front of a real Marlin: it numbers and
 * checksums each line, sends one line and waits for its "ok" (OctoPrint's
 * default ping-pong), answers "Resend: N" by sending line N again, treats
 * "echo:busy" as a sign of life, interleaves manual commands between job
 * lines, and ends a job with M400 so "complete" means executed (so the
 * simulated printer's executed-command log holds every line of a finished
 * job).  A printer-side error ("Error:" other than line/checksum trouble, a
 * halt, a firmware reset mid-job) moves the job to SIM_NP_ERROR.  Cancel
 * stops streaming and sends the cancel script (M104 S0, M140 S0, M107,
 * M84), OctoPrint's default afterPrintCancelled with the heaters first.
 *
 * Each API simulator (sim_octoprint.c, sim_moonraker.c, sim_prusalink.c,
 * sim_bambu.c) is a thin HTTP/MQTT face over this: it stores uploads in
 * the uploads directory, starts/pauses/resumes/cancels the job, queues
 * manual commands, and reports sim_netprinter_status() in its own words.
 *
 * Time: progress and time left are in simulated seconds (loop time times
 * the speed factor).
 *
 * Thread: the loop thread.  Owns its socketpair, its sim_marlin, its open
 * job file and, when it made it, its uploads directory (removed with its
 * files by sim_netprinter_free).
 */
#ifndef SF_SIM_NET_SIM_NETPRINTER_H
#define SF_SIM_NET_SIM_NETPRINTER_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../../src/base/err.h"
#include "../../src/base/loop.h"
#include "../marlin/faults.h"

/* Longest file name the uploads directory takes (no '/', no leading '.'). */
#define SIM_NP_NAME_MAX 128

/* The job's state, the one vocabulary every API face translates. */
enum sim_np_state {
    SIM_NP_IDLE = 0,   /* no job yet (or after sim_netprinter_reset) */
    SIM_NP_PRINTING,   /* streaming lines */
    SIM_NP_PAUSING,    /* pause asked, the line in flight not yet acknowledged */
    SIM_NP_PAUSED,     /* paused: nothing sent */
    SIM_NP_CANCELLING, /* cancel asked: waiting for the line in flight, then the cancel script */
    SIM_NP_CANCELLED,  /* the last job was cancelled (idle again: a new job may start) */
    SIM_NP_COMPLETE,   /* the last job finished, every line executed (idle again) */
    SIM_NP_ERROR,      /* the printer failed (message says why); sim_netprinter_reset clears */
};

struct sim_netprinter_config {
    double speed;            /* simulated time runs this much faster; 0: 1 */
    int baud;                /* the firmware link's pacing, bits/s; 0: 1000000 */
    const char *log_path;    /* every executed command, one per line (sim_marlin's), or NULL */
    const char *uploads_dir; /* where uploads live; NULL: a fresh temporary directory, removed
                                with its files by sim_netprinter_free */
    struct faults faults;    /* firmware/link faults (faults.h); faults_init() for none */
};

struct sim_np_status {
    enum sim_np_state state;
    char file[SIM_NP_NAME_MAX + 1]; /* the job's file name ("" before the first job) */
    int64_t file_size;              /* its bytes */
    int64_t file_pos;               /* bytes of it acknowledged by the firmware */
    uint64_t lines_total;           /* command lines in it */
    uint64_t lines_done;            /* of those, acknowledged */
    double progress;                /* file_pos / file_size, 0..1 (1 when complete) */
    double print_time_s;            /* simulated seconds since the job started (pauses
                                       included), frozen when it ends */
    double time_left_s;             /* estimate from progress, -1 when unknown */
    double m73_left_s; /* the job's last M73 R the firmware ran (the slicer's minutes left), in
                          s, while a job is on; -1 if the file has none (yet) */
    double nozzle_c, nozzle_target_c, bed_c, bed_target_c; /* from the firmware */
    char message[160]; /* why ERROR (or the last notice), "" if none */
};

struct sim_netprinter;

/* Defaults: speed 1, baud 1000000, temporary uploads directory, no faults. */
void sim_netprinter_config_init(struct sim_netprinter_config *c);

/* Start the machine on loop l (firmware booted, host connected).  NULL with err set. */
struct sim_netprinter *sim_netprinter_new(struct loop *l, const struct sim_netprinter_config *c,
                                          struct sf_err *err);
/* Stop, flush the log, close, free (and remove a temporary uploads directory).  NULL is fine. */
void sim_netprinter_free(struct sim_netprinter *np);

/* The uploads directory. */
const char *sim_netprinter_uploads(const struct sim_netprinter *np);

/*
 * Check an upload's file name (SF_EINVAL: empty, over SIM_NP_NAME_MAX,
 * holding '/', a control byte or starting with '.') and write its path in
 * the uploads directory into out (n bytes).
 */
int sim_netprinter_path(const struct sim_netprinter *np, const char *name, char *out, size_t n,
                        struct sf_err *err);
/* Size of uploaded file name, or -1 if there is none. */
int64_t sim_netprinter_file_size(const struct sim_netprinter *np, const char *name);
/* One uploaded file, as sim_netprinter_files lists it. */
struct sim_np_file {
    char name[SIM_NP_NAME_MAX + 1];
    int64_t size;    /* bytes */
    int64_t mtime_s; /* last change, Unix seconds */
};

/*
 * List up to max uploaded files (regular files, not dot files: those are
 * uploads still arriving) into out, sorted by name; returns how many (0 when
 * the directory cannot be read).
 */
int sim_netprinter_files(const struct sim_netprinter *np, struct sim_np_file *out, int max);
/* True while name is the file of a job that is not over (it may not be replaced). */
bool sim_netprinter_file_busy(const struct sim_netprinter *np, const char *name);

/*
 * Start printing uploaded file name.  SF_EAGAIN when a job is running
 * (printing, pausing, paused, cancelling) or the printer is in ERROR;
 * SF_ENOTFOUND when there is no such file; SF_EIO when it cannot be read.
 */
int sim_netprinter_start(struct sim_netprinter *np, const char *name, struct sf_err *err);
/* Pause / resume / cancel the job: SF_EAGAIN when its state does not allow it. */
int sim_netprinter_pause(struct sim_netprinter *np, struct sf_err *err);
int sim_netprinter_resume(struct sim_netprinter *np, struct sf_err *err);
int sim_netprinter_cancel(struct sim_netprinter *np, struct sf_err *err);
/*
 * Queue one manual command line (sent between job lines, or at once when
 * idle).  SF_EINVAL for an empty or over-long line, SF_EAGAIN in ERROR.
 */
int sim_netprinter_command(struct sim_netprinter *np, const char *line, struct sf_err *err);

/* Fault injection: the printer fails now (a job in progress stops) with message. */
void sim_netprinter_fail(struct sim_netprinter *np, const char *message);
/* Leave ERROR (or a finished state) for IDLE, as reconnecting OctoPrint would.  */
void sim_netprinter_reset(struct sim_netprinter *np);

void sim_netprinter_status(const struct sim_netprinter *np, struct sim_np_status *out);
/* "idle", "printing", ..., never NULL. */
const char *sim_np_state_name(enum sim_np_state s);
/* A job is on the machine: printing, pausing, paused or cancelling. */
bool sim_np_running(const struct sim_np_status *st);

#endif
