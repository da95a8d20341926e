/*
 * farm_host_int.h - internal to farm_host.c (the join, the beat, the reap,
 * the listener) and farm_host_ask.c (the scheduling pass's claims, takes and
 * give-backs on the farm's store thread): the host's state they share.
 * farm_host.h is the module's contract.
 *
 * Thread: the loop thread.
 */
#ifndef SF_FARM_FARM_HOST_INT_H
#define SF_FARM_FARM_HOST_INT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "farm_host.h"
#include "store_host.h"

struct farm_host {
    struct farm *f;
    struct store *ls; /* the listener's connection */
    char name[STORE_HOST_NAME_MAX];
    int64_t token;     /* this process's, once joined */
    bool joined;       /* the lease is ours */
    bool waiting;      /* a join was refused: say so once, retry at each beat */
    int64_t lease_ms;  /* host_lease_s */
    uint64_t timer;    /* the beat */
    int fd;            /* the listener's socket on the loop, -1 if none */
    int64_t fd_gen;    /* the listener's reconnects (store_host_reconnects) when fd was added */
    uint64_t relisten; /* the listener is lost: timer of its next try, 0 if none */
    bool listen_lost;  /* said so (once until it is back) */
    /* printers of f's config that another live host owns (store_host_own): the scheduler
       leaves them alone; tried again at each beat, taken once that host is gone */
    char (*foreign)[STORE_HOST_NAME_MAX];
    size_t n_foreign;
    /* claims whose COMMIT's answer was lost (SF_EINDOUBT): not claimed again until their
       read-back (store_job_claim_settle, on the store thread) settled them */
    struct doubt *doubts;
    uint64_t resettle; /* a read-back failed: timer of the next round, 0 if none */
    int peers;         /* other live hosts at the last join or beat; -1 if not known */
    /* the reap's grace (renewed): when this host's current run of renewals began (monotonic
       ms; 0: not renewing, as after a failed beat), its last renewal, and the beat
       connection's reconnects then; the beat in flight carries them and brings them back */
    int64_t renewing_since, renewed_at, renew_gen;
    bool doubted;      /* a claim, take or hold found the lease not current: the beat decides */
    struct storeq *bq; /* the beat's own store thread and connection (see the top) */
    bool beating;      /* a beat is on bq: its answer applies it (on_beat_done) */
    bool beat_due;     /* a beat was asked for while one was in flight: beat at its answer */
    bool stopping;     /* farm_host_stop: an answer still in flight only records the lease */
    bool reown;        /* the printers changed (a reload): the next beat owns them again */
    bool republish;    /* the last publish failed: the next beat publishes again */
    bool owning;       /* ... and until its answer, only those in mine are scheduled on */
    /* the printers this host owns, as of the last own that came back */
    char (*mine)[STORE_HOST_NAME_MAX];
    size_t n_mine;
    /* ready jobs this host gave back (farm_host_give_back): not taken here again until
       their time (monotonic ms), so the other hosts have them first */
    struct given {
        int64_t id, until;
    } * given;
    size_t n_given, cap_given;
    uint64_t given_timer; /* a kick when the first of them may be taken here again */
};

/* A claim in doubt, on its way to the store thread's read-back or waiting for another. */
struct doubt {
    struct farm_host *h;
    struct doubt *next;             /* in h->doubts */
    char host[STORE_HOST_NAME_MAX]; /* h's name, for the store thread */
    int64_t id;                     /* the job */
    bool posted;                    /* its read-back is on the store thread */
    bool released;                  /* the claim had committed and was given back */
};

/* A claim, take or hold found this host's lease not current (SF_ESTALE): beat now, and let
   the beat decide (farm_host.c). */
void farm_host_lease_doubted(struct farm_host *h);
/* Stop the claims' side at farm_host_stop: its timers, and the claims still in doubt
   (farm_host_ask.c). */
void farm_host_ask_stop(struct farm_host *h);

#endif
