/*
 * farm_host.h - the farm as one of several hosts on one PostgreSQL store
 * (farm.ini `store: postgresql://...`; store_host.h has the rows).
 *
 * A host joins under its name (farm.ini `host`, default the machine's
 * hostname) with a lease of `host_lease_s` (default 30 s), owns the
 * printers of its config, renews the lease every third of it, and at the
 * same beat reaps every host whose lease ran out (store_host_reap: their
 * queued and preparing jobs go back to the queue, their printing ones
 * become interrupted).  A stop leaves: the lease ends at once and the host
 * reaps itself, so its waiting work moves on without waiting the lease out.
 *
 * Which host does what (the rule, simplest first): a host prepares only a
 * queued job its scheduler chose for a printer of its own, after claiming
 * it (store_job_claim_id: the claim's statement with SKIP LOCKED, so two
 * hosts never prepare one job), and starts only jobs on printers it owns:
 * its own prepared jobs, or a ready job no host holds (an uploaded G-code,
 * one a reaped host had prepared), taken first (store_job_take, one
 * statement).  A host's scheduler never sees another host's jobs
 * (store_job_live_host), and writes no wait reason on queued jobs (another
 * host may be about to take them).
 *
 * Wake-ups: a job added or changed through a host's API, a reap that moved
 * jobs and a host's leave NOTIFY the others; every host LISTENs on a
 * connection of its own, watched on the loop's epoll, and runs a
 * scheduling pass when one arrives (no polling of the queue).  A lost
 * listener is retried at each beat.
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
 * join, own f's printers, listen, start the beat.  A name whose earlier
 * lease still runs (a restart after a crash) is logged and joined at a
 * later beat, once that lease ran out.  SF_ENOMEM, SF_EINVAL (a bad host
 * name), SF_EIO (the listener's connection).
 */
int farm_host_start(struct farm *f, const struct farmcfg *cfg, struct sf_err *err);
/* Leave (see above) and free; after the farm's store thread wrote what it held. */
void farm_host_stop(struct farm *f);
/* f runs as one of several hosts. */
bool farm_host_on(const struct farm *f);
/* f is the farm's only host: a single host, or joined with no other live host at its last
   beat (what it says of a waiting job is then the whole farm's word). */
bool farm_host_alone(const struct farm *f);

/* Whose live jobs f's scheduler reads (on the store thread): name "" for a single host
   (store_job_live), the host's name for store_job_live_host; false before the host joined
   (none of the queue is its own then). */
bool farm_host_reader(const struct farm *f, char *name, size_t size);
/*
 * Claim queued job id for preparing (store_job_claim_id), its fencing token
 * into *fence: SF_OK, SF_ENOTFOUND (another host has it, or it moved on:
 * not logged), else logged.
 */
int farm_host_claim(struct farm *f, int64_t id, int64_t *fence);
/* May f start (or prepare again) ready job id?  Always without a shared store; with one,
   once f took it (store_job_take). */
bool farm_host_take(struct farm *f, int64_t id);
/* Wake the other hosts: something they may act on changed (a job added through the API). */
void farm_host_wake(struct farm *f);
/*
 * May f drive an interrupted job of its network printer (printer_env.hold)?
 * Without a shared store always (SF_OK); with one SF_EAGAIN until f joined
 * (a restarted host waits out its predecessor's lease, whose reap at the
 * join interrupts the predecessor's prints: a print re-attached before
 * would be interrupted under the printer that runs it), and then, for id
 * > 0, the job becomes f's under its lease (store_job_attach: a new fencing
 * token; SF_ESTALE if the lease is lost).
 */
int farm_host_hold(struct farm *f, int64_t id, struct sf_err *err);
/* f's printers changed (a reload): own them again. */
void farm_host_own(struct farm *f);

#endif
