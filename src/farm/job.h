/*
 * job.h - the farm's state vocabulary: job states, printer states and the
 * legal moves between them, as pure functions over plain values.
 *
 * A job goes queued -> preparing (orient, shape, slice) -> ready ->
 * printing -> done | failed | cancelled; paused is reachable from printing;
 * interrupted marks a job that was printing when the daemon died and waits
 * for the operator (resume from its last line, start over, or cancel).
 * Copies print one after another: a finished copy with more to go sends the
 * job back to ready, so the scheduler can place the next copy on any
 * printer.  A failed print is retried (back to ready) until the job's retry
 * budget is spent.
 *
 * A printer is offline, idle, printing, paused, in error, or awaiting bed
 * clear (a finished print must be removed before the next starts, unless the
 * printer has an automatic ejector).
 *
 * The store (store.h) applies these rules inside its transactions; the
 * scheduler and the API ask them before acting.  No state, no I/O:
 * callable from any thread.
 */
#ifndef SF_FARM_JOB_H
#define SF_FARM_JOB_H

#include <stdbool.h>
#include <stdint.h>

#include "../base/err.h"

enum job_state {
    JOB_QUEUED = 0,  /* waiting to be prepared */
    JOB_PREPARING,   /* orient / shape / slice running on the pool */
    JOB_READY,       /* G-code ready, waiting for a printer */
    JOB_PRINTING,    /* a copy is printing */
    JOB_PAUSED,      /* the printing copy is paused */
    JOB_DONE,        /* every copy printed */
    JOB_FAILED,      /* preparation failed or retries spent */
    JOB_CANCELLED,   /* cancelled by an operator */
    JOB_INTERRUPTED, /* was printing when the daemon died; operator decides */
};
#define JOB_STATE_COUNT 9

enum job_event {
    JOB_EV_PREPARE = 0,    /* queued -> preparing: a worker picked it up */
    JOB_EV_PREPARED,       /* preparing -> ready: G-code stored; ready -> ready: G-code
                              prepared again for a printer of another key */
    JOB_EV_PREPARE_FAILED, /* preparing -> failed */
    JOB_EV_START,          /* ready -> printing: sent to a printer */
    JOB_EV_PAUSE,          /* printing -> paused */
    JOB_EV_RESUME,         /* paused -> printing; interrupted -> printing (from last line) */
    JOB_EV_PRINT_DONE,     /* printing -> ready (copies left) | done */
    JOB_EV_PRINT_FAILED,   /* printing|paused -> ready (retry left) | failed */
    JOB_EV_CANCEL,         /* any live state -> cancelled */
    JOB_EV_CRASHED,        /* on restart or stop: printing|paused -> interrupted,
                              preparing -> queued */
    JOB_EV_RESTART,        /* interrupted -> ready: print the copy again from the start */
    JOB_EV_DEFER,          /* preparing -> queued: a stage is unavailable now; try later */
    JOB_EV_REFUSED,        /* printing -> ready: the printer refused the start ("not idle");
                              nothing printed, so no retry is spent (the printer holds off) */
    JOB_EV_CANCEL_COPY,    /* printing|paused -> ready: an operator stopped this copy; it is
                              printed again (no counter moves), the job goes on */
};
#define JOB_EVENT_COUNT 14

/* The counters a transition reads and updates. */
struct job_counts {
    int copies;      /* prints wanted, >= 1 */
    int copies_done; /* prints finished successfully */
    int failures;    /* failed prints of the current copy */
    int max_retries; /* failed prints tolerated per copy before the job fails */
};

/*
 * Apply ev to a job in state from with counters c: on success set *to,
 * update c (copies_done, failures) and return SF_OK.  An event that is not
 * legal in from returns SF_EINVAL with "cannot EVENT a STATE job" in err,
 * leaving c unchanged.
 */
int job_next(enum job_state from, enum job_event ev, struct job_counts *c, enum job_state *to,
             struct sf_err *err);

/* True when some event leads from `from` to `to`. */
bool job_can_transition(enum job_state from, enum job_state to);

/*
 * Does ev end the claim of the host that held the job (store_host.h's
 * claimed_by)?  DEFER (preparing -> queued: it gives the job back),
 * PREPARE_FAILED (preparing -> failed: nothing left to hold) and RESTART
 * (interrupted -> ready: the operator prints the copy again, on any host's
 * printer; the host that held it may be gone).  A host keeps its claim
 * through every other event.
 */
bool job_event_releases_claim(enum job_event ev);

/* done, failed, cancelled: nothing more happens to the job. */
bool job_state_terminal(enum job_state s);

/* A copy occupies a printer: printing or paused. */
bool job_state_on_printer(enum job_state s);

/* "queued" ...; "?" for an out-of-range value. */
const char *job_state_name(enum job_state s);
const char *job_event_name(enum job_event ev);

/* Parse a state name; false if unknown. */
bool job_state_parse(const char *s, enum job_state *out);

/* Caps on job options (each with its reason). */
#define JOB_NAME_MAX     128     /* part file names: longer ones are not names but payloads */
#define JOB_COPIES_MAX   1000    /* a farm batch; beyond this it is a typo */
#define JOB_RETRIES_MAX  10      /* a print that failed 10 times needs a human */
#define JOB_PRIORITY_MAX 1000000 /* |priority| bound, keeps arithmetic safe */

/* What the operator asked for when submitting a job (plain data). */
struct job_opts {
    char name[JOB_NAME_MAX]; /* part file name as uploaded: no '/', no "..", printable */
    char method[16];         /* "none" | "orient" | "slim" | "surface" (default "orient") */
    double deviation_mm;     /* shape optimization's deviation budget, 0..10 mm (default 0.5) */
    double overhang_deg;     /* overhang threshold; 0 = the target printer's own (default 0) */
    int copies;              /* prints wanted, 1..JOB_COPIES_MAX (default 1) */
    int max_retries;         /* failed prints tolerated per copy, 0..10 (default 1) */
    char material[32];       /* "PLA", ...; "" = whatever the printer has loaded */
    char printer[64];        /* target printer name; "" = any */
    char group[64];          /* target printer group; "" = any */
    int priority;            /* higher first; |priority| <= JOB_PRIORITY_MAX (default 0) */
};

/* Fill o with the defaults above (empty name). */
void job_opts_init(struct job_opts *o);

/*
 * Check every field of o; SF_EINVAL naming the field ("copies: 0 is not in
 * 1..1000", "name: '../x.stl' must not contain '/'") on the first bad one.
 */
int job_opts_validate(const struct job_opts *o, struct sf_err *err);

/* True when s is a safe single path component to show or store as a name:
   valid UTF-8, no '/', '\\', ".." or control characters, 1..JOB_NAME_MAX-1 bytes. */
bool job_name_valid(const char *s);

enum printer_state {
    PRINTER_OFFLINE = 0,    /* not connected */
    PRINTER_IDLE,           /* connected, bed clear, ready for a job */
    PRINTER_PRINTING,       /* streaming a job */
    PRINTER_PAUSED,         /* job paused */
    PRINTER_ERROR,          /* halted; needs an operator */
    PRINTER_AWAITING_CLEAR, /* print finished; waits for "bed cleared" */
};
#define PRINTER_STATE_COUNT 6

enum printer_event {
    PRINTER_EV_CONNECTED = 0, /* link up and handshake done */
    PRINTER_EV_DISCONNECTED,  /* link lost */
    PRINTER_EV_START,         /* job sent */
    PRINTER_EV_PAUSE,
    PRINTER_EV_RESUME,
    PRINTER_EV_FINISHED, /* job ended (done, failed or cancelled) with the part on the bed */
    PRINTER_EV_FAULT,    /* firmware halted or reported an error */
    PRINTER_EV_CLEARED,  /* operator confirmed the bed is clear (or error acknowledged) */
    PRINTER_EV_REFUSED,  /* its driver refused the job just sent: idle again, bed untouched */
};
#define PRINTER_EVENT_COUNT 9

/*
 * Apply ev to a printer in state from; auto_eject makes FINISHED lead to
 * idle instead of awaiting bed clear.  SF_EINVAL with a message when ev is
 * not legal in from.
 */
int printer_next(enum printer_state from, enum printer_event ev, bool auto_eject,
                 enum printer_state *to, struct sf_err *err);

const char *printer_state_name(enum printer_state s);
const char *printer_event_name(enum printer_event ev);
bool printer_state_parse(const char *s, enum printer_state *out);

#endif
