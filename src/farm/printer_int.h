/*
 * printer_int.h - internal to the printer module (printer.c, printer_attach.c,
 * printer_heat.c, printer_op.c), not a contract for anyone else: nothing outside
 * src/farm/printer*.c includes it; printer.h is the module's contract.
 *
 * What the parts share: the printer itself (struct printer), its moves on
 * job.h's machine with the bed they record, the job events it writes, the
 * owner's wake, and the heaters' watch (printer_heat.c) that the driver
 * events' delivery (printer.c) re-arms.
 *
 * Thread: as printer.h (the loop thread).
 */
#ifndef SF_FARM_PRINTER_INT_H
#define SF_FARM_PRINTER_INT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../../drivers/drv.h"
#include "farmcfg.h"
#include "job.h"
#include "printer.h"

/* One driver event as it happened. */
struct queued {
    enum drv_event ev;    /* what */
    struct drv_status st; /* the driver's status at that moment */
};

struct printer {
    struct printer_env env;     /* owner, store, loop */
    struct farmcfg_printer cfg; /* its config section */
    enum printer_state state;   /* job.h printer state: the one truth */
    struct drv *drv;            /* its driver; NULL without one */
    int64_t job_id;             /* job on it, 0 if none */
    int64_t lines_acked;        /* latest from the driver */
    struct filament fil;        /* the net E by line of the print started on it (filament.h) */
    int64_t lines_saved;        /* last value written to the store */
    char message[160];          /* why offline / error */
    uint64_t reconnect;         /* reconnect timer id, 0 if none */
    int attempts;               /* reconnects since the link was last up (drv_backoff_ms) */
    bool removed;               /* dropped from the config */
    bool bed_full;              /* the bed holds a part (store_printer_bed_get) */
    bool deaf;                  /* printer_stop: driver events are dropped */
    bool attach_tried;          /* this connection offered the driver its interrupted job */
    bool error_cleared;         /* an operator cleared the error before the driver saw the
                                   printer recover: leave it when the driver reports idle */
    struct queued *queue;       /* driver events not applied yet, n_queue of cap_queue */
    size_t n_queue, cap_queue;
    uint64_t deliver;      /* timer applying the queue, 0 if none */
    uint64_t hold;         /* after a refused start: timer until p takes jobs again, 0 if none */
    int refusals;          /* starts refused in a row (drive) */
    uint64_t attach_retry; /* timer offering the interrupted job again, 0 if none */
    int attach_waits;      /* attach() answers "not yet" on this connection */
    double est_s;          /* the job's print time estimate (printer_estimate_s), s; -1 unknown */
    uint64_t heat_timer;   /* hot with no print: timer turning the heaters off, 0 if none */
    uint64_t judging;      /* the start whose file is judged before the driver has it, 0 if none */
    uint64_t starts;       /* starts made: the next start's token */
    struct start_ticket *ticket;  /* the START queued for the store, not yet back; NULL if none */
    struct start_go *go;          /* a start judged before its START committed: its verdict */
    struct start_ticket *rticket; /* the RESUME queued for the store, not yet back; NULL if none */
    struct resume_go *rgo;        /* a resume read before its RESUME committed: its verdict */
    int64_t fence;                /* fence_job's fencing token (printer_set_fence), 0: none */
    int64_t fence_job;            /* the job it is for, 0: none */
    struct fence_watch *watches;  /* fenced job events on their way to the store */
    /* a print that ended whole here while this host was away from the store, its end refused
       as stale (the host was reaped meanwhile: the job is interrupted): recorded once the host
       joined again and holds the job (printer_settle_orphan); id 0: none */
    struct {
        int64_t id;
        int64_t lines_acked;
        enum job_event ev; /* how it ended: JOB_EV_PRINT_DONE, or JOB_EV_PRINT_FAILED (why) */
        char why[160];
    } orphan;
    /* a network print its driver runs on, which this host does not hold now: let go
       (printer_fenced_out: the host was reaped, or another host held the job), or adopted by
       the driver at a re-attach whose hold is not back yet.  p waits offline; the host holds
       it (printer_settle_orphan: at once, or at the next join) and p takes it back, or, once
       the driver saw its end, it is recorded as the orphan above; 0: none */
    int64_t away_id;
    /* the hold of the orphan's or the away job (env.hold_ask) on the store's thread, not yet
       back; NULL if none */
    struct hold_ticket *hticket;
    /* the hold was refused for want of a lease (SF_EAGAIN): no orphan read nor hold until the
       host joined (printer_attach_again) */
    bool hold_join;
    /* the interrupted job's read on the store's thread (printer_attach_offer), not yet back;
       NULL if none */
    struct attach_ticket *aticket;
    /* the orphan's read on the store's thread (printer_settle_orphan), not yet back; NULL if
       none */
    struct orphan_ticket *oticket;
    struct cmd_ticket *cmds;    /* manual commands waiting for the store (printer_command_then) */
    struct bed_ticket *bticket; /* its bed's read (printer_new), not yet back; NULL if none */
};

/*
 * Write job event ev for job id (a, not NULL, carrying p's fence for it) through the store's
 * queue, and let the job go (printer_fenced_out) if the store refuses it as stale.  SF_OK
 * or SF_ENOMEM (printer_op.c).
 */
int printer_fenced_event(struct printer *p, int64_t id, enum job_event ev,
                         const struct job_event_args *a);
/* p is freed: its fenced events, its orphan's read and its commands' come back to no one. */
void printer_fence_release(struct printer *p);

/*
 * The driver of p saw the end (ev: JOB_EV_PRINT_DONE, or JOB_EV_PRINT_FAILED with why) of the
 * network print p->away_id, which this host does not hold: it becomes the orphan, recorded
 * once the host holds the job again (printer_op.c).
 */
void printer_away_ended(struct printer *p, enum job_event ev, int64_t lines, const char *why);
/* Hold p->away_id (env.hold_ask) and take it back once held (printer_op.c): the driver has
   just adopted it (printer_attach.c). */
void printer_away_hold(struct printer *p);
/* The hold's answer, or the read's, asks again later (printer_attach.c: bounded, with the
   driver's "not yet"); false once the tries are spent. */
bool printer_attach_later(struct printer *p);

/* Tell p's owner it changed (printer_env.changed), if it listens. */
void printer_changed(struct printer *p);

/* Record whether p's bed holds a part (in the store: a crash keeps the bed gate). */
void printer_set_bed(struct printer *p, bool full);

/*
 * Move p by ev on job.h's machine, recording the bed and the state in the
 * store; false (logged) when the machine refuses the move.
 */
bool printer_move(struct printer *p, enum printer_event ev);

/*
 * Queue a job event for the store (env.q): the loop goes on, the event is
 * written after everything p queued before it, and a failure is logged
 * when it comes back (the job fails alone).  An event ending job id's
 * print records the filament it used (printer_filament_mm).  SF_OK, or
 * SF_ENOMEM (nothing queued).
 */
int printer_job_event(struct printer *p, int64_t id, enum job_event ev,
                      const struct job_event_args *a);
/* The filament job id's print on p used by command line `lines` (all of its file's when ev is
   JOB_EV_PRINT_DONE); 0 when p did not read the file (a resumed or re-attached print). */
double printer_filament_mm(const struct printer *p, int64_t id, enum job_event ev, int64_t lines);

/* Apply the driver's status now as a DRV_EV_STATE (printer.c). */
void printer_apply_status(struct printer *p);

/*
 * A network printer came up offline (its driver idle, printing or paused) and was not offered
 * its interrupted job on this connection: read the job on the store's thread and offer it to
 * the driver when the answer comes (printer_attach.c).  true: p waits offline (for its host's
 * lease, the read, or the driver's "not yet"); false: there is nothing to offer
 * (attach_tried set), p connects as its driver says.
 */
bool printer_attach_offer(struct printer *p);
/* p is freed: its read comes back to no one. */
void printer_attach_release(struct printer *p);
/* Offer p its interrupted job now if it waits offline for that (printer_attach_again without
   the orphan's settling: its read's answer). */
void printer_attach_wake(struct printer *p);

/*
 * Arm the heaters' timer when p is hot with no print on it (turned off
 * after cfg.hold_heat_min), disarm it when not; called after each batch of
 * driver events.
 */
void printer_heat_watch(struct printer *p);

#endif
