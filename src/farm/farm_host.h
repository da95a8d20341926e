/*
 * farm_host.h - the farm as one of several hosts on one PostgreSQL store
 * (farm.ini `store: postgresql://...`; store_host.h has the rows).
 *
 * A host joins under its name (farm.ini `host`, default the machine's
 * hostname) with a lease of `host_lease_s` (default 30 s), owns the
 * printers of its config, renews the lease every third of it, and at the
 * same beat reaps every host whose lease ran out (store_host_reap: their
 * queued and preparing jobs go back to the queue, their printing ones
 * become interrupted), once it has itself renewed without a break for a
 * whole lease (farm_host.c: after a database outage every lease ran out,
 * and the first host back must not reap the others).  A claim, take or
 * hold that finds its own lease run out makes the host beat at once: a
 * lease nobody reaped is renewed and the host carries on, its prints
 * untouched; only a host really reaped lets go of them and joins again.  A stop leaves: the lease
 * ends at once and the host reaps itself, so its waiting work moves on without waiting the lease
 * out.
 *
 * Which host does what (the rule, simplest first): a host prepares only a
 * queued job its scheduler chose for a printer of its own, or, with a free
 * place in its pool, one that fits only another live host's printer and has
 * waited (farm_spare.c), after claiming it (store_job_claim_first: the claim's
 * statement with SKIP LOCKED, so two hosts never prepare one job); a job it
 * prepared for another host's printer is ready and no host's at once
 * (store_job_prepared_release).  It starts only jobs on printers it owns:
 * its own prepared jobs, or a ready job no host holds (an uploaded G-code,
 * one a reaped host or a host with spare cores prepared), taken first
 * (store_job_take, one statement).  A host's scheduler never sees another host's jobs
 * (store_job_live_host), and writes no wait reason on queued jobs (another
 * host may be about to take them).  A printer of its config that another
 * live host owns (both configs list that name) stays that host's: this
 * host schedules nothing on it, says so once with both names, and tries to
 * own it again at each beat (it is free once that host is gone).
 *
 * Fencing: every write the host makes for a job it holds (the PREPARED of
 * its claim, a printer's events and progress, a DEFER) carries the fencing
 * token of its claim, take, or hold (a resume attaches the job first), so
 * once another host holds the job the store refuses them (SF_ESTALE) and
 * the printer lets the job go (printer.h printer_set_fence).
 *
 * Wake-ups: a job added or changed through a host's API, a reap that moved
 * jobs and a host's leave NOTIFY the others; every host LISTENs on a
 * connection of its own, watched on the loop's epoll, and runs a
 * scheduling pass when one arrives (no polling of the queue).  A lost
 * listener (the server restarted, the network cut) is tried again every
 * 200 ms without the loop waiting on its connect, and watched again once
 * its new session LISTENs, followed by a scheduling pass for what arrived
 * while it was away.
 *
 * The beat, its join and reap, and the printers' own run on a thread and
 * connection of the beat's own, never on the loop's (farm_host.c says why
 * not on the farm's store thread either).
 *
 * Every call here is a no-op (or store.h's single-host call) when the farm
 * has no shared store.  Thread: the loop thread.
 */
#ifndef SF_FARM_FARM_HOST_H
#define SF_FARM_FARM_HOST_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"
#include "farmcfg.h"
#include "store.h"

struct farm;
struct farm_host;

/* The beat: a third of the lease (a beat late, two more before the others reap). */
#define FARM_HOST_BEATS_PER_LEASE 3

/*
 * Join f's store as a host when cfg names a shared store (else nothing):
 * listen, start the beat, whose first round joins and owns f's printers on
 * the beat's own thread and connection (farm_host.c), so the host has
 * joined once that comes back, on a later loop turn ("NAME joined" is
 * logged; until then farm_host_reader is false and farm_host_hold says
 * SF_EAGAIN).  A name whose earlier lease still runs (a restart after a
 * crash) is logged and joined at a later beat, once that lease ran out.
 * SF_ENOMEM, SF_EINVAL (a bad host name), SF_EIO (the listener's or the
 * beat's connection).
 */
int farm_host_start(struct farm *f, const struct farmcfg *cfg, struct sf_err *err);
/* Leave (see above) and free; after the farm's store thread wrote what it held. */
void farm_host_stop(struct farm *f);
/* f runs as one of several hosts. */
bool farm_host_on(const struct farm *f);
/* f is the farm's only host: a single host, or joined with no other live host at its last
   beat (what it says of a waiting job is then the whole farm's word). */
bool farm_host_alone(const struct farm *f);

/* This host's name (farm.ini host, default the machine's), "" for a single host. */
const char *farm_host_name(const struct farm *f);

/* Whose live jobs f's scheduler reads (on the store thread): name "" for a single host
   (store_job_live), the host's name for store_job_live_host; false before the host joined
   (none of the queue is its own then). */
bool farm_host_reader(const struct farm *f, char *name, size_t size);
/* f's join's token (its claim on its host name), 0 before it joined or without a shared store. */
int64_t farm_host_token(const struct farm *f);
/* The answer of a claim, take or give-back posted on the store thread, on the loop: rc as
   below, fence the claim's or take's fencing token (rc SF_OK; else 0), job the job as claimed
   (a claim's, rc SF_OK; else NULL).  Called at the stop too (storeq_free delivers what is in
   flight): the farm is stopping then. */
typedef void (*farm_host_answer_fn)(void *ud, int rc, int64_t fence, const struct job_row *job);
/*
 * Claim for preparing the first free of queued jobs ids[0..n) (the pass's choices for one
 * printer, best first; those past STORE_CLAIM_IDS_MAX are left out), on the store thread
 * (store_job_claim_first), after what the farm queued before; done(ud, ...) on the loop with
 * its answer (job: the one claimed): SF_OK, SF_ENOTFOUND (other hosts have them, or they moved
 * on: not logged), else logged: SF_EBUSY, SF_EUNREACH (passing: not
 * retried on the thread), SF_ESTALE (the lease not current: the host beats at once).  A claim
 * whose COMMIT's answer was lost (SF_EINDOUBT) is read back on the store thread
 * (store_job_claim_settle): one that committed is given back to the queue, so the job is never
 * left this host's and prepared by no one; until then that job is not claimed again (left out
 * of the ids).  SF_OK (posted), SF_ENOTFOUND (the last claim of every one is in doubt still) or
 * SF_ENOMEM: done is not called then.
 */
int farm_host_claim(struct farm *f, const int64_t *ids, size_t n, farm_host_answer_fn done,
                    void *ud);
/* Take ready job id for a printer of f's (store_job_take) on the store thread; done(ud, ...)
   on the loop with its answer: SF_OK with its fencing token (what f writes for the job carries
   it: printer_set_fence), SF_ENOTFOUND (another host holds it, or it is no longer ready), or
   another error (the database away or busy, in doubt: passing, try again later; SF_ESTALE as
   a claim's), logged.  SF_OK (posted), SF_ENOTFOUND (f gave it back lately: the other hosts
   first), SF_ENOMEM: done not called.  One of several hosts only (else nothing to take). */
int farm_host_take(struct farm *f, int64_t id, farm_host_answer_fn done, void *ud);
/* f took ready job id (under fencing token fence) but cannot start it (why: its G-code cannot
   be fetched here): give it back for the other hosts (store_job_give_back on the store thread,
   which wakes them); f does not take it again for a lease.  Logged.  Nothing without a shared
   store. */
void farm_host_give_back(struct farm *f, int64_t id, int64_t fence, const char *why);
/* The same for a job f took for a printer that changed before the take's answer came (why):
   f may take it again at once, for another printer.  done(ud, rc, 0, NULL) once the store
   answered (rc SF_OK, or its failure, logged).  SF_OK or SF_ENOMEM (done not called). */
int farm_host_release(struct farm *f, int64_t id, int64_t fence, const char *why,
                      farm_host_answer_fn done, void *ud);
/*
 * printer_env.hold: before a printer of f resumes job id (an operator's resume, a network
 * printer found still printing it), f holds the job: store_job_attach, its new fencing
 * token into *fence, so a host that held it before is fenced off.  Without a shared store
 * *fence is 0 and it is always SF_OK.  SF_EAGAIN until f joined (a restarted host waits out
 * its predecessor's lease, whose reap at the join interrupts the predecessor's prints: a
 * print re-attached before would be interrupted under the printer that runs it); id 0 asks
 * only that.  SF_ESTALE (f's lease is lost), SF_EAGAIN (the job is in no state to attach),
 * the store's failure; err set.
 */
int farm_host_hold(void *f, int64_t id, int64_t *fence, struct sf_err *err);
/*
 * printer_env.hold_ask: farm_host_hold of id, only while it is interrupted on printer (checked
 * in the hold's transaction: store_job_reattach, SF_ENOTFOUND when not), on the farm's store thread
 * (storeq_call, after what the farm queued before it: the job's CRASHED, say; SF_EBUSY and
 * SF_EUNREACH tried again there), so the loop waits neither for the queue nor for the statement;
 * done(ud, rc, fence, err) on the loop with its outcome (SF_ESTALE makes the host beat at once, as
 * farm_host_hold). SF_OK with *posted true: done comes; SF_OK with *posted false: nothing to hold
 * (no shared store, or id 0); SF_EAGAIN until f joined, SF_ENOMEM: err set, done not called.
 */
int farm_host_hold_ask(void *f, int64_t id, const char *printer, bool *posted,
                       void (*done)(void *ud, int rc, int64_t fence, const struct sf_err *err),
                       void *ud, struct sf_err *err);
/* Wake the other hosts: something they may act on changed (a job added through the API). */
void farm_host_wake(struct farm *f);
/* f's printers changed (a reload): own them again (on the beat's thread: until that comes
   back, a printer new to f is not scheduled on here). */
void farm_host_own(struct farm *f);
/* May f schedule on its printer named printer?  Always without a shared store; with one,
   unless another live host owns a printer of that name (its config lists it too): then the
   job and the printer are that host's (logged once, when found; tried again at each beat). */
bool farm_host_owns(const struct farm *f, const char *printer);
/* The beat's own store queue's counters (storeq_stats, for /metrics) into out; false when f is
   not one of several hosts, or its host stopped (out untouched). */
struct storeq_stats;
bool farm_host_beat_stats(const struct farm *f, struct storeq_stats *out);

#endif
