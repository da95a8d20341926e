/*
 * jobctl.h - what an operator asks of the farm's jobs and printers: cancel
 * a job (through its printer when it is on one), restart or resume an
 * interrupted one, act on a printer (pause, resume, cancel, cleared), send
 * it a manual command.  The farm decides by state and touches the store
 * and the printer; the API only maps the status codes to HTTP:
 *
 *   SF_ENOTFOUND  no such job or printer
 *   SF_EINVAL     bad input (a command that is not one line)
 *   SF_EAGAIN     not now: the job or the printer is not in a state for it
 *                 (the job and printer rules refuse, or the driver is busy:
 *                 "nothing to pause" while a network printer's upload runs,
 *                 "another action is still on its way")
 *   SF_EUNREACH   the printer does not answer: the farm holds it offline
 *                 (PRINTER_OFFLINE: its driver has lost contact, or never
 *                 had it: a network printer that does not answer, a serial
 *                 port that is gone), so nothing can be asked of it
 *   SF_EUNSUPP    its kind cannot do it (a PrusaLink console command)
 *   other         the store or the system failed
 *
 * f may be NULL (an API over a store alone): what needs a printer is then
 * refused as not now, or a printer is not found.
 *
 * Thread: the loop thread (the farm's and the store's); the functions
 * taking only a store (restart, again, jobctl_cancel_stored) any thread
 * with its own store (the farm's store queue runs them for the API).
 */
#ifndef SF_FARM_JOBCTL_H
#define SF_FARM_JOBCTL_H

#include <stdint.h>

#include "../base/err.h"
#include "farm.h"
#include "printer.h"
#include "store.h"

/*
 * Cancel job id: a job on a printer is cancelled by stopping the printer
 * (its registry records the cancel), any other in the store directly.
 */
int jobctl_cancel(struct farm *f, struct store *s, int64_t id, struct sf_err *err);

/*
 * The store's half of a cancel, on any thread with its store s (the
 * farm's store queue, storeq_call): job id cancelled unless it is on a
 * printer (SF_EAGAIN: its printer stops it, jobctl_printer_action).
 */
int jobctl_cancel_stored(struct store *s, int64_t id, struct sf_err *err);
/* As jobctl_cancel_stored; when the job is on a printer (SF_EAGAIN), that printer's name into
   printer (n bytes; NULL: not wanted): another host's, whose owner must stop it. */
int jobctl_cancel_stored_on(struct store *s, int64_t id, char *printer, size_t n,
                            struct sf_err *err);
/*
 * Cancel job id on printer name, answered as jobctl_printer_action_then:
 * only while id is the printer's job (another host asked by the job's id,
 * and by the time its command runs here the printer may print another
 * job): SF_EAGAIN, nothing done, when the printer holds no job or another.
 */
int jobctl_cancel_job_on(struct farm *f, const char *name, int64_t id, storeq_event_fn done,
                         void *ud, struct sf_err *err);
/* The printer of f that holds job id now (its name, f's), or NULL. */
const char *jobctl_printer_of(struct farm *f, int64_t id);

/* Interrupted job id prints its copy again from the start. */
int jobctl_restart(struct store *s, int64_t id, struct sf_err *err);

/*
 * "Print again": a new job from job id's file and options (copies,
 * material, target, priority, method ...), queued as a new submission
 * would be; uploaded G-code is ready at once, as when it was uploaded.
 * Any state: a job done, failed or cancelled as well as one still in
 * the queue.  The new job's id in *new_id.
 */
int jobctl_again(struct store *s, int64_t id, int64_t *new_id, struct sf_err *err);

/*
 * Interrupted job id continues on its printer from command line `line`
 * (-1: the last acknowledged one); farm_job_resume, whose refusals (not
 * interrupted, printer not idle, line out of range) are SF_EAGAIN here.
 * Its RESUME is queued (printer_resume_commit): a storeq_barrier posted
 * after SF_OK answers once it committed.
 */
int jobctl_resume(struct farm *f, int64_t id, int64_t line, struct sf_err *err);
/* The same, the job read on the store's thread (farm_job_resume_then): SF_OK, then done(ud, r)
   once its RESUME committed or with the refusal (SF_EINVAL for what is SF_EAGAIN above); a
   refusal now (done not called). */
int jobctl_resume_then(struct farm *f, int64_t id, int64_t line, storeq_event_fn done, void *ud,
                       struct sf_err *err);

/* Act on printer name (farm_printer_action). */
int jobctl_printer_action(struct farm *f, const char *name, enum printer_action act,
                          struct sf_err *err);
/*
 * The same, answered once what it wrote has committed (printer.h
 * printer_action_then): SF_OK, then done(ud, r) on the loop later; a
 * refusal now as above (done not called).
 */
int jobctl_printer_action_then(struct farm *f, const char *name, enum printer_action act,
                               storeq_event_fn done, void *ud, struct sf_err *err);

/*
 * One manual G-code line for printer name from who (the sending key's
 * label, logged with the command): farm_printer_command, which judges
 * the line by the printer's G-code policy (SF_EINVAL for what it refuses)
 * and takes it only on an idle printer with a clear bed and no
 * interrupted job (SF_EAGAIN otherwise).
 */
int jobctl_printer_command(struct farm *f, const char *name, const char *line, const char *who,
                           struct sf_err *err);
/* The same, answered once sent or refused (farm_printer_command_then): SF_OK, then done(ud, r)
   on the loop later; a refusal now as above (done not called). */
int jobctl_printer_command_then(struct farm *f, const char *name, const char *line, const char *who,
                                storeq_event_fn done, void *ud, struct sf_err *err);

/* An operator's (who's) emergency stop of printer name (farm_printer_estop). */
int jobctl_printer_estop(struct farm *f, const char *name, const char *who, struct sf_err *err);

#endif
