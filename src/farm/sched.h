/*
 * sched.h - the scheduler: which ready job goes to which idle printer.
 *
 * Pure logic over caller arrays (no store, no loop), so every rule is unit
 * tested and the daemon calls it whenever a job becomes ready or a printer
 * idle.  Rules, in order:
 *  - only enabled, idle printers take jobs (a printer awaiting bed clear is
 *    not idle: the operator, or auto-eject, must free it first);
 *  - ready jobs go by priority (higher first), then their order (the
 *    operator's ▲/▼, else FIFO), then lower id: first come first served: a job still queued or
 * being prepared holds the idle printer it would take, so a later job that prepared faster does not
 * start before it (unless it is stalled: it would hold the printer idle for nothing);
 *  - a job goes only to a printer it targets (by name or group), whose
 *    loaded material matches the job's (if it names one), and whose bed
 *    holds the part (x/y may swap: the part can turn 90 degrees on the bed);
 *  - a ready job's G-code starts only on a printer with the key it was
 *    prepared for (sched_key: profile, material, nozzle, bed, overhang
 *    angle), so a part centred for one bed, or one machine's start G-code,
 *    never runs on another; uploaded G-code (a gcjob.h key) only on a
 *    printer whose gcode_models and nozzle take it, and it is never
 *    prepared again;
 *  - a ready job left waiting while an idle printer of another key could
 *    take it is assigned to that printer with `reslice` set: the caller
 *    prepares it again for that printer (the printer counts as taken);
 *  - among the printers that qualify, a job that names no material takes
 *    one that no other waiting job naming a material could use (it once
 *    took the only PETG printer while a PETG job waited), and is sliced
 *    again for such a printer rather than start on a needed one; then the
 *    smallest bed wins (best fit keeps big printers free for big parts),
 *    then the order given;
 *  - retry policy: a printer that just failed the job is avoided while
 *    another qualifying printer exists;
 *  - copies print one after another (job.h), so a job takes one printer.
 * A job that no enabled printer could ever take gets a reason saying why
 * for each printer; one that only waits for a busy printer says so too.
 *
 * Thread: any; no state.
 */
#ifndef SF_FARM_SCHED_H
#define SF_FARM_SCHED_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "job.h"

#define SCHED_REASON_MAX 256 /* one reason line; longer lists end in "..." */

/* A printer as the scheduler sees it. */
struct sched_printer {
    const char *name;         /* unique */
    enum printer_state state; /* only PRINTER_IDLE takes jobs */
    bool enabled;             /* false: never scheduled */
    const char *material;     /* loaded material, e.g. "PLA" */
    double nozzle_mm;         /* nozzle diameter */
    double bed_mm[3];         /* build volume x, y, z */
    const char *group;        /* group name, "" for none */
    const char *profile;      /* slicing profile name */
    double overhang_deg;      /* the printer's overhang angle */
    const char *gcode_models; /* uploaded G-code it runs (gcjob.h); NULL or "": none */
};

/* A job as the scheduler sees it. */
struct sched_job {
    int64_t id;           /* FIFO order: lower first */
    enum job_state state; /* only JOB_READY is placed; others only get reasons */
    int priority;         /* higher first */
    const char *material; /* "" = any */
    const char *printer;  /* target printer, "" = any */
    const char *group;    /* target group, "" = any */
    const char *key;      /* sched_key it was prepared for, or an uploaded G-code's
                             gcjob_key; "" or NULL = not prepared */
    double size_mm[3];    /* part bounding box as it will print; 0s = not known yet */
    const char *avoid;    /* printer that failed it last, "" or NULL for none */
    double overhang_deg;  /* the job's overhang angle; 0 = the printer's */
    bool stalled;         /* cannot be prepared now (the pool is full, or, ready, it is being
                             sliced again or a slicing of it failed): it holds no printer and
                             gives up none to be sliced again */
    int64_t order;        /* within a priority, lower first (the store's queue_pos: the
                             operator's ▲/▼, else FIFO); then lower id */
};

/* One decision: jobs[job] starts on printers[printer]. */
struct sched_assign {
    size_t job;     /* index into the jobs array */
    size_t printer; /* index into the printers array */
    bool reslice;   /* prepare the job again for this printer before it can start */
};

/*
 * Plan: fill out (room for min(n_jobs, n_printers) entries) with the
 * assignments to make now, in priority order, and return how many.  If
 * reasons is not NULL it has n_jobs entries; each job not assigned gets a
 * line saying why (empty for assigned jobs and for jobs not queued or
 * ready): "fits no printer: mk3-a: material PETG not loaded (has PLA); ..."
 * or "waits for a printer: mk3-a is printing".
 */
size_t sched_plan(const struct sched_job *jobs, size_t n_jobs, const struct sched_printer *printers,
                  size_t n_printers, struct sched_assign *out, char (*reasons)[SCHED_REASON_MAX]);

/*
 * Which printer to prepare queued jobs[job] for: one that could take it, an
 * idle one first, then (for a job that names no material) one no other
 * waiting job needs, then the order given.  Returns n_printers if none.
 */
size_t sched_prepare_for(const struct sched_job *jobs, size_t n_jobs, size_t job,
                         const struct sched_printer *printers, size_t n_printers);

/*
 * Could printer p ever take job j (ignoring its state)?  If not and why is
 * not NULL, write the reason ("material PETG not loaded (has PLA)").
 */
bool sched_compatible(const struct sched_job *j, const struct sched_printer *p, char *why,
                      size_t why_cap);

#define SCHED_KEY_MAX 192 /* a key: profile and material names are at most 63 bytes */

/*
 * The key of G-code prepared for printer p with overhang angle angle_deg
 * (the job's; 0: the printer's): everything that shapes the G-code a
 * printer may run, "PROFILE/MATERIAL/n0.4/bed250x210x210/a45".  Two
 * printers with equal keys can run each other's G-code.
 */
void sched_key(const struct sched_printer *p, double angle_deg, char key[SCHED_KEY_MAX]);

/* True when ready job j may start on printer p now that it is idle: same key. */
bool sched_runs_on(const struct sched_job *j, const struct sched_printer *p);

/* True when a part of size s fits a bed b, turning it 90 degrees if needed. */
bool sched_fits_bed(const double s[3], const double b[3]);

#endif
