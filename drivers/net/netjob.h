/*
 * netjob.h - what a network printer's own report means for the job the
 * farm sent it: the one table from a remote print state to drv_state and
 * the job events, shared by the Moonraker and PrusaLink drivers.
 *
 * A network printer runs the job itself (Klipper's virtual SD card,
 * PrusaLink's firmware); the driver only sees its state on each poll.  Each
 * driver first names what its printer said in this vocabulary (klippy
 * "shutdown" and PrusaLink "ERROR" are both NETJOB_R_HALTED), then asks
 * netjob_judge() what that means for the job it holds: which drv_state to
 * report, and whether the job has ended and how.  Keeping the rule in one
 * pure function lets the tests walk every row without a printer.
 *
 * Thread: any; pure.
 */
#ifndef SF_DRIVERS_NET_NETJOB_H
#define SF_DRIVERS_NET_NETJOB_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../drv.h"

/* What the printer says it is doing, in the drivers' common words. */
enum netjob_remote {
    NETJOB_R_IDLE,      /* ready, no job loaded */
    NETJOB_R_BUSY,      /* ready but doing something that is not a print (calibrating) */
    NETJOB_R_PRINTING,  /* a job is running */
    NETJOB_R_PAUSED,    /* a job is paused, or waits for someone at the printer */
    NETJOB_R_DONE,      /* the last job completed */
    NETJOB_R_CANCELLED, /* the last job was cancelled or stopped */
    NETJOB_R_FAILED,    /* the last job ended with an error; the printer can take another */
    NETJOB_R_STARTING,  /* the printer's host is starting (klippy startup) */
    NETJOB_R_HALTED,    /* the printer is halted and needs a person (klippy shutdown) */
};

/* Where the driver's own job is. */
enum netjob_phase {
    NETJOB_NONE,       /* no job of ours on the printer */
    NETJOB_RUNNING,    /* our job was started and has not ended */
    NETJOB_CANCELLING, /* we asked the printer to cancel it */
};

/* One observation: the remote state and whether its job is ours. */
struct netjob_obs {
    enum netjob_remote remote;
    bool ours;           /* the job the printer reports is the file we sent (name and size) */
    const char *file;    /* the printer's job file name, for messages ("" or NULL: none) */
    const char *message; /* the printer's own words for its state (klippy's state_message,
                            print_stats.message), or NULL */
};

/* What the observation means. */
struct netjob_verdict {
    enum drv_state state; /* report this */
    bool ends;            /* the driver's job has ended: report ev, phase becomes NONE */
    enum drv_event ev;    /* when ends: DRV_EV_JOB_DONE, _FAILED or _CANCELLED */
    char message[160];    /* status.message to show ("" clears it) */
    bool has_lines;       /* the driver counted the job's lines done itself (netdrv lines) */
    uint64_t lines;       /* ... that many (else progress times lines_total) */
};

/*
 * Judge observation o for a driver whose job is in phase.  Pure.  The rules
 * (tests/unit/test_netjob.c walks them all):
 *  - NONE: idle, done, cancelled and failed are DRV_IDLE (the printer keeps
 *    the last job's state until the next, which is not ours to judge);
 *    printing and paused (someone else's job) and busy are DRV_PRINTING or
 *    DRV_PAUSED with a message, so nothing is sent to it; starting is
 *    DRV_CONNECTING; halted is DRV_ERROR with the printer's message.
 *  - RUNNING: our job printing or paused is DRV_PRINTING or DRV_PAUSED;
 *    done ends it with JOB_DONE; cancelled ends it with JOB_FAILED
 *    ("cancelled at the printer": nobody here asked); failed, gone (idle,
 *    or another file) and a host restart end it with JOB_FAILED and the
 *    printer's message; halted ends it with JOB_FAILED and DRV_ERROR;
 *    busy keeps DRV_PRINTING (a printer busy between its job's steps).
 *  - CANCELLING: any state but our job still printing or paused ends it
 *    with JOB_CANCELLED (halted: DRV_ERROR; starting: DRV_CONNECTING).
 */
void netjob_judge(enum netjob_phase phase, const struct netjob_obs *o, struct netjob_verdict *v);

/* The job a network driver holds. */
struct netjob {
    enum netjob_phase phase;
    char name[160];       /* its file name on the printer (netjob_name) */
    int64_t size;         /* its bytes */
    uint64_t lines_total; /* its command lines (drv_job_scan), for lines_acked */
};

/*
 * Fill j for the job file gcode_path: phase NETJOB_RUNNING, the name it
 * goes by on the printer (drv_remote_name, the same in every daemon run),
 * its size and its command lines (scan's, or drv_job_scan's when scan is
 * NULL), and copy the path into path (n bytes).  SF_EIO when the file
 * cannot be read, SF_EINVAL for a path over n or a bad file.
 */
int netjob_prepare(struct netjob *j, const char *gcode_path, const struct drv_job_scan *scan,
                   char *path, size_t n, struct sf_err *err);

/*
 * Report verdict v on driver d, whose job is j: status.state, .message,
 * .progress and .lines_acked (progress times j->lines_total), then the
 * events in the order the farm needs them: DRV_EV_PROGRESS if lines_acked
 * moved, DRV_EV_STATE if the state changed (a printer error reaches the
 * farm with its message before the job's failure), then the job's end if
 * v->ends (j->phase becomes NETJOB_NONE).  Loop thread.
 */
void netjob_report(struct drv *d, struct netjob *j, const struct netjob_verdict *v,
                   double progress);

/* Set d's state and message (printf-style, NULL keeps it), DRV_EV_STATE if the state changed. */
void netjob_state(struct drv *d, enum drv_state s, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

/* Record temperatures; DRV_EV_TEMPS when one changed. */
void netjob_temps(struct drv *d, double nozzle_c, double nozzle_target_c, double bed_c,
                  double bed_target_c);

/* Short name of a remote state ("printing"), for logs and tests. */
const char *netjob_remote_name(enum netjob_remote r);

#endif
