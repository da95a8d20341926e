/*
 * farm.h - the running farm: the printers of the config (printer.h, each
 * owning its driver), the prepare stage on the worker pool (prepare.h) and
 * the scheduler (sched.h), over the job store (store.h), on the loop.
 *
 * Flow: a queued job is prepared for a printer that could take it (an idle
 * one first); a ready job starts only on an idle printer of the key it was
 * prepared for, and one that waits for a busy printer while another idles
 * is prepared again for that one (reusing the optimized part).  Printers
 * report through the loop; nothing here waits, so one slow or dead printer
 * never holds up the others; the store writes that follow the printers
 * (progress, their states, the end of prints) go to a store thread of the
 * farm's own (storeq.h), so a busy database holds up no printer either.
 * farm_reload() applies a new config (SIGHUP)
 * without disturbing running prints; farm_free() leaves printing jobs
 * interrupted at their last line, as a crash would.
 *
 * Thread: the loop thread.  The pool must be drained (farm_drop_pool,
 * pool_free, then one loop iteration) before farm_free, since prepare
 * completions use the farm.
 */
#ifndef SF_FARM_FARM_H
#define SF_FARM_FARM_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"
#include "../base/loop.h"
#include "../base/pool.h"
#include "farmcfg.h"
#include "gcjob.h"
#include "job.h"
#include "prepare.h"
#include "printer.h"
#include "sched.h"
#include "store.h"
#include "storeq.h"

/* Persist lines acknowledged this often: what a resume after a crash may
   print twice (one UPDATE a second for all printing printers together). */
#define FARM_PROGRESS_MS 1000

/* What the farm is built with. */
struct farm_hooks {
    printer_driver_fn driver; /* drv_new, a test's, or NULL: printers stay offline */
    prepare_fn prepare;       /* prepare_part, or a test's */
    void (*notify)(void *ud); /* the event log grew (wake event streams) */
    int64_t progress_ms;      /* persist progress this often (0: FARM_PROGRESS_MS) */
    void *notify_ud;
};

struct farm;

/*
 * Build the farm on loop l over store s, preparing on pool; the printers
 * start connecting; the farm's store thread opens its own connection to
 * s's database (storeq_new).  NULL with err set (SF_ENOMEM; SF_EIO from
 * that connection).  Free with farm_free, which owns nothing it was given
 * and writes what its store thread still holds before it returns.
 */
struct farm *farm_new(struct loop *l, struct store *s, struct pool *pool, const struct farmcfg *cfg,
                      const struct farm_hooks *hooks, struct sf_err *err);
void farm_free(struct farm *f);
/* The pool is about to be freed: schedule and prepare nothing more (the
   drain's loop iteration would otherwise run the scheduler on a freed pool). */
void farm_drop_pool(struct farm *f);

/* Apply a new config; running prints keep their printer until they end. */
int farm_reload(struct farm *f, const struct farmcfg *cfg, struct sf_err *err);

/*
 * Run-time printers (farm_printers.c): printers an operator adds, edits,
 * disables and removes through the API, kept in the store (store.h
 * store_printer_cfg_*) and applied as a reload applies farm.ini's.  At
 * start and at each reload the printers in force are farm.ini's with the
 * store's rows over them: a printer the API edited runs on the API's
 * config, farm.ini's section of that name no longer counts; one the API
 * disabled stays disabled whatever farm.ini says; one the API removed
 * stays removed; the API's own printers come after farm.ini's.
 *
 * text is a [printer NAME] section's body, "key: value" lines, checked by
 * farmcfg_printer_parse (SF_EINVAL naming the option).  SF_ENOTFOUND no
 * such printer; SF_EAGAIN (409) not now: a name in use (add), a printing
 * printer's link (edit: driver, enabled or a connection option), a
 * printer that holds a job (disable, remove) or a part on its bed or an
 * interrupted job (remove); SF_EIO the store.  Each change is committed
 * to the store before the printer is touched.
 */
int farm_printer_add(struct farm *f, const char *name, const char *text, struct sf_err *err);
int farm_printer_edit(struct farm *f, const char *name, const char *text, struct sf_err *err);
/* Disabled: no job starts on it and the farm lets go of its link (enabled false). */
int farm_printer_disable(struct farm *f, const char *name, const char *reason, struct sf_err *err);
int farm_printer_enable(struct farm *f, const char *name, struct sf_err *err);
int farm_printer_remove(struct farm *f, const char *name, struct sf_err *err);
/*
 * Printer name's config as an edit starts from, into *out: the store's
 * when the API edited or added it (*stored true), else farm.ini's; an
 * operator's disable not applied.  SF_ENOTFOUND, SF_EIO.
 */
int farm_printer_base(struct farm *f, const char *name, struct farmcfg_printer *out, bool *stored,
                      struct sf_err *err);

/* Something changed (job submitted, bed cleared): prepare and schedule soon. */
void farm_kick(struct farm *f);

/*
 * Return once every store write the farm queued (storeq.h) is committed,
 * waiting up to max_ms (< 0: as long as it takes; tests): for a direct
 * store call that must see them (a job's cancel).  SF_EBUSY (the store
 * is busy, err says so) when they were not.  NULL is SF_OK.
 */
int farm_sync(struct farm *f, int64_t max_ms, struct sf_err *err);
/* How the farm's loop and its store thread fare, for /metrics. */
struct farm_health {
    int64_t loop_turn_max_ms;  /* loop_turn_max_ms of the farm's loop */
    int64_t loop_round_trips;  /* statements the loop's own store connection sent to a server */
    struct storeq_stats store; /* the store thread's counters (storeq_stats) */
    bool has_beat;             /* one of several hosts: ... */
    struct storeq_stats beat;  /* ... its beat's own store thread's (farm_host_beat_stats) */
};
void farm_health(struct farm *f, struct farm_health *out);

/* Printers in config order (a removed one stays until its print ends). */
size_t farm_printer_count(const struct farm *f);
/* Printer i (0 .. count-1, config order), as printer.h's printer_info. */
void farm_printer_info(const struct farm *f, size_t i, struct printer_info *out);

/*
 * Act on printer name (printer.h: pause, resume, cancel the job on it,
 * cleared).  SF_ENOTFOUND unknown printer, SF_EINVAL not legal now; err
 * says why.
 */
int farm_printer_action(struct farm *f, const char *name, enum printer_action act,
                        struct sf_err *err);
/* The farm's store queue (storeq.h): writes the loop does not wait for, in order with the
   farm's own.  NULL f: NULL. */
struct storeq *farm_storeq(struct farm *f);

/* The same, done(ud, r) once its writes commit (printer.h printer_action_then). */
int farm_printer_action_then(struct farm *f, const char *name, enum printer_action act,
                             storeq_event_fn done, void *ud, struct sf_err *err);

/*
 * A manual command for printer name from who (the sender's label, logged
 * with it; printer_command): SF_ENOTFOUND unknown printer, else
 * printer_command's codes.
 */
int farm_printer_command(struct farm *f, const char *name, const char *line, const char *who,
                         struct sf_err *err);
/* The same, done(ud, r) once sent or refused (printer.h printer_command_then). */
int farm_printer_command_then(struct farm *f, const char *name, const char *line, const char *who,
                              storeq_event_fn done, void *ud, struct sf_err *err);

/* An operator's emergency stop of printer name (printer_estop), as above. */
int farm_printer_estop(struct farm *f, const char *name, const char *who, struct sf_err *err);

/*
 * Resume interrupted job id on the printer its part is on, from command
 * line `line` (0-based; -1: the last acknowledged line the store holds).
 * The printer must be idle.  SF_ENOTFOUND no such job; SF_EINVAL not
 * interrupted, printer not idle, or line outside 1..lines-1 (err says
 * which and the range).
 */
int farm_job_resume(struct farm *f, int64_t id, int64_t line, struct sf_err *err);
/* The same without the loop's connection: the job is read on the store's thread, resumed when
   it comes back, and done(ud, r) answers once its RESUME committed, or with the refusal.  SF_OK
   (done called later) or SF_ENOMEM. */
int farm_job_resume_then(struct farm *f, int64_t id, int64_t line, storeq_event_fn done, void *ud,
                         struct sf_err *err);

/* What farm_gcode_check learnt of an uploaded G-code file. */
struct farm_gcode {
    struct gcjob_info info;  /* what its slicer wrote */
    char key[SCHED_KEY_MAX]; /* gcjob_key */
    int64_t lines;           /* command lines (drv_job_scan) */
    double est_s;            /* print time estimate (gcjob_estimate_s), -1 if none */
};

/* The end of a check: rc SF_OK with g, or an error with msg (g NULL). */
typedef void (*farm_gcode_fn)(void *ud, int rc, const struct farm_gcode *g, const char *msg);

/*
 * Check uploaded G-code at path (a temporary file, before it is stored)
 * for the job o describes, off the loop thread (the farm's io thread: a
 * 50 MB file is ~1 s of reading, which must not stall the printers'
 * streams): every line (drv_job_scan), what its slicer wrote
 * (gcjob_read); then, on the loop thread, that some configured printer
 * could run it (its target printer or group, gcode_models, nozzle; not
 * its material, which an operator may load).  done(ud, ...) runs once on
 * the loop thread, also when the farm is freed first (SF_ECANCELED).
 * Errors to done: SF_EINVAL naming o->name (a bad line, a foreign flavor,
 * no command at all, no printer: each printer and why), SF_EIO.  Returns
 * SF_ENOMEM (done is then never called).
 */
int farm_gcode_check(struct farm *f, const char *path, const struct job_opts *o, farm_gcode_fn done,
                     void *ud, struct sf_err *err);

/*
 * A new job from an upload, written on the farm's store thread
 * (farm_add_post) while the upload's request waits: its temporary file
 * adopted into the store (store_file_adopt: on PostgreSQL its bytes sent
 * on a connection of the thread's own, not the loop's), recorded, the job
 * added, and the job read back for the answer.  Each half once: a retry
 * of the queue (the store busy) goes on from what is done.
 */
struct farm_add {
    char tmp[1200];    /* the upload's temporary file (the caller's) */
    struct job_opts o; /* the job */
    bool gcode;        /* G-code printed as is, g what its check found (farm_gcode_add) */
    struct farm_gcode g;
    /* the store thread's, read by done */
    const struct store *store; /* whose data dir (read only) */
    bool adopted, added;
    int adopt_rc; /* the adoption's failure (not retried: its temporary has moved) */
    struct sf_err adopt_err;
    char sha[STORE_SHA_HEX];
    int64_t size;
    int64_t id;       /* the new job */
    struct job_row j; /* as read back after its commit */
};

/*
 * Write a's job on the farm's store thread, then done(ud, r) on the loop:
 * r->rc SF_OK (a->id, a->j the new job), or the failure in r->err; a
 * failed adoption (a->adopted with a->adopt_rc) is reported as
 * SF_ECANCELED with the adoption's error (the part was not stored).  a is
 * the caller's again once done runs.  SF_OK, or SF_ENOMEM (done is not
 * called).
 */
int farm_add_post(struct farm *f, struct farm_add *a, storeq_event_fn done, void *ud,
                  struct sf_err *err);

/*
 * farm_add_post for an uploaded G-code file, checked by farm_gcode_check
 * into g: a job printed as is (store_job_add_gcode), ready at once, its
 * material the file's unless a->o names one.
 */
int farm_gcode_add(struct farm *f, struct farm_add *a, const struct farm_gcode *g,
                   storeq_event_fn done, void *ud, struct sf_err *err);

#endif
