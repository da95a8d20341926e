/*
 * printer.h - one printer of the farm, its one owner: the printer state
 * machine (job.h rules), its driver (no other module calls drv.h for it),
 * the job printing on it, the bed gate (kept in the store across restarts)
 * and reconnects with drv_backoff_ms.
 *
 * Driver events arrive through the loop: the driver's callback only queues
 * the event with a copy of the driver's status, and a zero-delay timer
 * applies the queue on a later loop turn.  So nothing here runs inside a
 * call into the driver (printer_action -> pause -> event -> printer), and
 * an action's own move is applied once, by the action.
 *
 * Every change follows the farm's rule: commit to the store, then act on
 * the device.  What starts a print (its START, a RESUME) and an operator's
 * action commit before the printer is told; what follows the device
 * (progress, the printer's state, its bed, notes, the end of a print) is
 * queued on the store's thread (env.q, storeq.h) and written in the order
 * it happened, so the loop never waits for it; the bed is recorded before
 * the job that leaves a part on it.
 * The owner (farm.c) is told after each change (env.changed) to schedule
 * and to wake event streams.
 *
 * Thread: the loop thread.
 */
#ifndef SF_FARM_PRINTER_H
#define SF_FARM_PRINTER_H

#include <stdbool.h>
#include <stdint.h>

#include "../../drivers/drv.h"
#include "../base/err.h"
#include "../base/loop.h"
#include "farmcfg.h"
#include "filament.h"
#include "job.h"
#include "store.h"
#include "storeq.h"

/* drv_new's shape: slimfarmd hands drv_new in; tests may hand in their own. */
typedef struct drv *(*printer_driver_fn)(struct loop *l, const struct drv_config *cfg,
                                         drv_event_fn on_event, void *ud, struct sf_err *err);

/* A hold's answer on the loop (printer_env.hold_ask): rc SF_OK with the job's new fencing
   token, or the store's refusal or failure in err. */
typedef void (*printer_held_fn)(void *ud, int rc, int64_t fence, const struct sf_err *err);

/* What a printer needs from its owner; copied by printer_new. */
struct printer_env {
    struct loop *l;            /* the loop */
    struct store *s;           /* the job store: reads, and writes whose result is needed */
    struct storeq *q;          /* its queue (storeq.h): the writes nothing waits for */
    printer_driver_fn driver;  /* NULL: the printer stays offline (prepare-only tests) */
    void (*changed)(void *ud); /* a job or the printer moved: schedule, wake streams */
    void *ud;                  /* their argument */
    bool bed_known;            /* bed_full is this printer's bed (it replaces one of the same
                                  name, farm_apply): not read from the store */
    bool bed_full;
    /* One of several hosts (farm_host_hold): hold job_id for this printer (store_job_attach)
       before a resume takes it, its fencing token into *fence (printer_set_fence); job_id 0:
       only whether the host holds a lease at all.  SF_EAGAIN while it has none (a restarted
       host waits out its predecessor's: printer_attach_again once it joined), SF_ESTALE or
       another code, err set, when it may not.  NULL: nothing to hold (one host). */
    int (*hold)(void *ud, int64_t job_id, int64_t *fence, struct sf_err *err);
    /* The same hold on the store's thread (farm_host_hold_ask), after what was queued before
       it: the loop does not wait; only while job_id is interrupted on printer, in the hold's
       transaction (store_job_reattach: SF_ENOTFOUND when not).  SF_OK with *posted: done(dud, ...)
       comes on the loop; SF_OK without: nothing to hold (one host), fence 0; SF_EAGAIN while the
       host has no lease, SF_ENOMEM (err set, done not called).  NULL: as hold. */
    int (*hold_ask)(void *ud, int64_t job_id, const char *printer, bool *posted,
                    printer_held_fn done, void *dud, struct sf_err *err);
};

/* What an operator may ask of a printer (the API's ACTION). */
enum printer_action {
    PRINTER_ACT_PAUSE = 0,   /* pause the job on it */
    PRINTER_ACT_RESUME,      /* resume it */
    PRINTER_ACT_CANCEL,      /* cancel it (the part stays on the bed) */
    PRINTER_ACT_CLEARED,     /* the bed is clear (or the error acknowledged: the printer
                                leaves the error when its driver reports it ready) */
    PRINTER_ACT_CANCEL_COPY, /* stop the copy on it (the part stays on the bed); the job
                                goes on and prints that copy again (JOB_EV_CANCEL_COPY) */
};
#define PRINTER_ACTION_COUNT 5

/* "pause", "resume", "cancel", "cleared", "cancel-copy"; false if s is none of them. */
bool printer_action_parse(const char *s, enum printer_action *out);
/* a's name, as printer_action_parse reads it ("?" if none). */
const char *printer_action_name(enum printer_action a);

/* A printer as the API shows it (valid until the loop turns or the config reloads). */
struct printer_info {
    const struct farmcfg_printer *cfg;                     /* its config */
    enum printer_state state;                              /* current state */
    int64_t job_id;                                        /* job on it, 0 if none */
    double progress;                                       /* 0..1 */
    double nozzle_c, nozzle_target_c, bed_c, bed_target_c; /* deg C, 0 if unknown */
    const char *message;        /* why offline/error, "" if nothing to say */
    int64_t time_left_s;        /* the job's time left, s; -1 when not known */
    const char *time_left_from; /* whose estimate: "printer" (its own, drv_status.time_left_s),
                                   "farm" (the G-code's print time less the progress made), or
                                   "" (none) */
};

struct printer;

/* Create the printer and start connecting; NULL only when out of memory. */
struct printer *printer_new(const struct printer_env *env, const struct farmcfg_printer *cfg);
/* Disconnect and free; what the driver says while closing is not heard. */
void printer_free(struct printer *p);
/*
 * The daemon stops: the job on p (if any) is left interrupted at its last
 * acknowledged line, exactly as crash recovery would leave it, and p hears
 * its driver no more (printer_free follows).
 */
void printer_stop(struct printer *p);
/* The host holds its lease now (env.hold): offer the job the store holds as interrupted
   on p again if p waited for that (a restarted host waits out its predecessor's lease). */
void printer_attach_again(struct printer *p);

const struct farmcfg_printer *printer_cfg(const struct printer *p);
/* Take a new config whose link (driver, its link options, enabled) is p's own. */
void printer_set_cfg(struct printer *p, const struct farmcfg_printer *cfg);
enum printer_state printer_state(const struct printer *p);
int64_t printer_job(const struct printer *p);
/* Has a driver that is up and idle, and is not holding off after a refused start. */
bool printer_connected(const struct printer *p);
void printer_info(const struct printer *p, struct printer_info *out);

/*
 * Connected with no print on it and a heater set: holding its heat for a
 * print to resume (hold_heat_min, printer_heat.c).  Its driver must not be
 * closed then (disabled, removed or reconnected): the heaters would stay on
 * with nothing left to turn them off.
 */
bool printer_hot_idle(const struct printer *p);

/* Dropped from the config: not scheduled, freed by the farm once idle. */
void printer_set_removed(struct printer *p, bool removed);
bool printer_removed(const struct printer *p);
/* Does p's bed hold a part (what the farm knows; the store keeps it for a restart)? */
bool printer_bed_full(const struct printer *p);
/* Whether p's bed is known (false while printer_new's read of it is on its way: bed_full is
   true until then). */
bool printer_bed_known(const struct printer *p);

/*
 * Start job j (ready; its G-code at path) from line 0, in two steps like a
 * resume: printer_start makes j p's job and queues its START for the store
 * (env.q; SF_OK, or SF_ENOMEM with nothing changed), then
 * printer_start_go hands it to the driver once the farm has judged the
 * file by p's policy off the loop (rc, why: the verdict) and the START has
 * committed, whichever comes last, unless the job left p meanwhile.  A
 * START the store refuses (logged) leaves p idle again with nothing sent.  scan (NULL: the driver
 * counts the lines) is the job's; fil (NULL: not read) its net E by line, from which each end of
 * this print records the filament it used.  A driver refusing with SF_EAGAIN (not idle: "not now")
 * sends the job back to ready without spending a retry (JOB_EV_REFUSED) and p takes no job for
 * drv_backoff_ms(refusals in a row); any other refusal fails the print (the retry policy applies).
 * rc != SF_OK (the file breaks p's policy, or cannot be read) fails the job with why, not retried:
 * nothing was sent, p is idle again with its bed as it was.
 */
int printer_start(struct printer *p, const struct job_row *j, const char *path);
/*
 * One of several hosts: p holds job id by fencing token fence (store_host.h:
 * the owner's take, or the hold of a resume).  Every job event and progress
 * p writes for id carries it, so once another host holds the job the store
 * refuses them (SF_ESTALE), and p lets the job go (printer_fenced_out).
 * 0: none (one host: nothing is checked).
 */
void printer_set_fence(struct printer *p, int64_t id, int64_t fence);
/* The fencing token p holds job id by (printer_set_fence), 0 if none. */
int64_t printer_fence(const struct printer *p, int64_t id);
/*
 * Another host holds job id now (the store refused a write of p's for it as stale, or this
 * host was reaped).  p forgets its fence for id and, if it still has the job, lets it go:
 * a printer whose job is streamed from here (no attach) is told to stop, a network printer
 * (which prints on for the other host) is left to it, offline here; nothing more is written
 * for the job.
 */
void printer_fenced_out(struct printer *p, int64_t id);
/*
 * A print that ended whole on p while its host was away from the store had its end refused
 * as stale (the host was reaped: the job interrupted).  Once the host joined again: if the
 * job is still interrupted on p, hold it (env.hold) and record the end, so it is not printed
 * a second time.  On the loop; reads the store.
 */
void printer_settle_orphan(struct printer *p);
/* The start printer_start just made (its check is stale once p starts anything else, even the
   same job again after a copy was cancelled). */
uint64_t printer_start_token(const struct printer *p);
void printer_start_go(struct printer *p, int64_t id, uint64_t token, const char *path,
                      const struct drv_job_scan *scan, const struct filament *fil, int rc,
                      const char *why);

/*
 * Resume interrupted job id on p (idle, connected) from command `line`:
 * printer_resume_commit queues its RESUME on the store's thread and p
 * takes the job at once (SF_OK, or SF_ENOMEM with nothing changed); a
 * RESUME the store refuses (logged) leaves p idle again with nothing sent.
 * printer_resume_go starts the driver once the resume point is read
 * (scan) and the RESUME has committed, whichever comes last, unless the
 * job left p meanwhile, with the job's time estimate est_s
 * (printer_estimate_s); rc != SF_OK (the read failed) fails the print
 * with why.
 */
int printer_resume_commit(struct printer *p, int64_t id, int64_t line, struct sf_err *err);
/* printer_resume_commit with the job held already under fence (0: one host), the hold done
   on the store's thread (printer_env.hold_ask: an operator's resume, farm_resume.c; the
   re-attach, printer_op.c): p takes job id at line. */
int printer_resume_fenced(struct printer *p, int64_t id, int64_t line, int64_t fence,
                          struct sf_err *err);
void printer_resume_go(struct printer *p, int64_t id, const char *path, uint64_t line,
                       const struct drv_job_scan *scan, double est_s, int rc, const char *why);

/*
 * Job j's print time estimate, s (-1 if none), what the farm's own time
 * left starts from: the one kept with the job (store.h est_s), or for a
 * job stored before it was kept, the head of its G-code at path
 * (gcjob_estimate_s).
 */
double printer_estimate_s(const struct job_row *j, const char *path);

/*
 * Act on p.  SF_EINVAL when not legal now ("cannot pause a printer that is
 * idle", "printer a has no job to cancel"); driver errors as they come.
 */
int printer_action(struct printer *p, enum printer_action a, struct sf_err *err);
/*
 * printer_action, answered once it is written: the printer and its driver
 * act now; what it records in the store (the job's pause, resume or
 * cancel, the printer's state and bed) is queued (storeq), and done(ud, r)
 * runs on the loop once that has committed, r->rc the store's verdict
 * (SF_OK, or its error: the printer has acted all the same).  Refused now
 * (non-zero, err set): done is not called.  done NULL: a store failure is
 * logged.
 */
int printer_action_then(struct printer *p, enum printer_action a, storeq_event_fn done, void *ud,
                        struct sf_err *err);

/*
 * Send p a manual command (one G-code line) from who (the sender's label,
 * for the log): its driver queues it (the console; the executed command
 * shows in the printer's log), logged on its own line with who.  Only on
 * an idle printer with a clear bed that holds no interrupted job:
 * SF_EAGAIN otherwise ("printer a is awaiting-clear: ..."), and while p is
 * offline, prints or the driver cannot take it now; SF_EUNSUPP when the
 * driver has no way to send one (PrusaLink: its API has no console
 * endpoint); SF_EINVAL for a line that is not one command; the store's
 * error (SF_EBUSY: its queue is not written yet) when whether p holds an
 * interrupted job is not known.
 */
int printer_command(struct printer *p, const char *line, const char *who, struct sf_err *err);
/*
 * The same, without the loop's connection: whether p holds an interrupted job is read on the
 * store's thread, and the command sent (p as it is then) when the answer comes; done(ud, r)
 * on the loop with r->rc and r->err as printer_command's.  A refusal now (done not called) as
 * printer_command's, or SF_ENOMEM.
 */
int printer_command_then(struct printer *p, const char *line, const char *who, storeq_event_fn done,
                         void *ud, struct sf_err *err);

/*
 * An operator's (who's) emergency stop: the driver's own (drv.h estop;
 * a kind without one cancels the job), then p is in error with its bed
 * marked full, and the job on it fails with no retry.  SF_EUNREACH when p
 * is offline; driver errors as they come.
 */
int printer_estop(struct printer *p, const char *who, struct sf_err *err);

/*
 * Progress persistence, batched by the owner: printer_progress gives the
 * job on p and its last acknowledged line when that is not saved yet
 * (false otherwise); printer_progress_saved records that it was.
 */
bool printer_progress(const struct printer *p, int64_t *job_id, int64_t *lines);
void printer_progress_saved(struct printer *p, int64_t lines);

#endif
