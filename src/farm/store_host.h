/*
 * store_host.h - several slimfarmd hosts on one database (issue 32): who
 * they are, how long each is trusted (a lease it renews), which printers
 * each owns, and which host holds each job.
 *
 * A host joins under a name and gets a token; it renews its lease with
 * store_host_beat before lease_ms passes.  A host whose lease ran out is
 * reaped by any host (store_host_reap): its queued and preparing work goes
 * back to the queue for the others, its printing jobs become interrupted
 * (a print cannot move to another host's USB port).  Work moves between
 * hosts only through the database: store_job_claim hands the next queued
 * job to exactly one host, and store_job_attach gives a ready, printing or
 * interrupted job to a host for its printer.  Both bump the job's fencing
 * token; an event that carries an older one (job_event_args.fence) is
 * refused, so a host that comes back after a partition cannot start or
 * continue a print another host has taken.
 *
 * Times are each host's wall clock (ms since the epoch): hosts keep their
 * clocks in step (NTP), and leases are seconds, far above their skew.
 *
 * Errors: SF_EINVAL for a bad name or argument (the message names it),
 * SF_ESTALE when the caller's token or lease is no longer current,
 * SF_EAGAIN when another live host holds what was asked for, SF_EIO from
 * the engine.  Thread: the store's, as store.h.
 */
#ifndef SF_FARM_STORE_HOST_H
#define SF_FARM_STORE_HOST_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"
#include "store.h"

#define STORE_HOST_NAME_MAX 64 /* a host name: letters, digits, '.', '-', '_' (a DNS label's) */
#define STORE_LEASE_MAX_MS  (24 * 3600 * 1000LL) /* a day: longer is no lease at all */

/*
 * As store_open_db, as one of several hosts on the database: on PostgreSQL
 * it takes the database's lock shared with the other hosts (a single-host
 * store_open_db refuses to start beside them, and they beside it: SF_EAGAIN)
 * and runs no crash recovery, since the database's active jobs are the
 * other hosts' too; each host's own are recovered when it joins or when it
 * is reaped.  On SQLite, whose file one process holds, it is store_open_db.
 */
struct store *store_open_host(const char *data_dir, const char *db, struct store_recovery *rec,
                              struct sf_err *err);
/* As store_open_host for a check of a shared store (slimfarmd --fsck): a schema older than
   this program's is refused (SF_EUNSUPP, naming --init-store), not migrated under the hosts
   that run on it. */
struct store *store_open_check(const char *data_dir, const char *db, struct sf_err *err);

/*
 * A second connection to s's database that may write, for another thread
 * of s's process (a preparation worker claiming jobs): no lock, migration
 * or recovery (s did them).  A host's (store_open_host) is a host's too: a
 * holder's job event without a fencing token is refused there as on s
 * (store_open_writer's alike).  Open and close it on s's thread; use it on one
 * thread at a time.  NULL with err set.  Free with store_close().
 */
struct store *store_open_peer(const struct store *s, struct sf_err *err);

/*
 * As store_open_peer, for the loop thread's wake-ups (store_host_listen): a
 * reconnect never waits for the network (sqldb.h's SQLDB_NOWAIT), so each
 * store_host_drain after a loss advances the new connection as far as it
 * goes without waiting, until its session is up with its LISTENs again.
 */
struct store *store_open_listener(const struct store *s, struct sf_err *err);

/*
 * A read-only connection to the store at target (a PostgreSQL URL, or a data
 * dir whose SQLite file is opened beside its daemon), for tools such as
 * `slimfarm hosts`: no lock, migration or recovery.  NULL with err set
 * (SF_EIO naming target).  Free with store_close().
 */
struct store *store_open_view(const char *target, struct sf_err *err);

/*
 * Join as host name with a lease of lease_ms (1 .. STORE_LEASE_MAX_MS) from
 * now: *token receives this process's token, larger than any before under
 * that name.  A name whose lease another process holds (not run out, or, on
 * PostgreSQL, a live connection holding the name) is refused with SF_EAGAIN,
 * the message naming it, its pid and its lease's age.  The name's earlier
 * holder, if its lease ran out unreaped, is reaped first (store_host_reap).
 * On PostgreSQL the name stays locked to this connection until it closes:
 * one process per host name.
 */
int store_host_join(struct store *s, const char *name, int64_t lease_ms, int64_t *token,
                    struct sf_err *err);

/*
 * Renew host name's lease to lease_ms from now.  SF_ESTALE when the lease is
 * lost: another process joined under the name (token is not its), or the
 * lease ran out and a host reaped it (its work has moved on; join again).
 * A lease that ran out but was not reaped yet is renewed.
 */
int store_host_beat(struct store *s, const char *name, int64_t token, int64_t lease_ms,
                    struct sf_err *err);

/* What store_host_own found for one printer (plain data). */
struct store_host_owned {
    bool owned;                      /* the caller owns it now */
    char other[STORE_HOST_NAME_MAX]; /* else the live host that owns it */
};

/*
 * Record the printers of host name's config (n names, each 1..63 bytes) as
 * its own, replacing what it owned before.  A printer belongs to one
 * config: one that another unreaped host owns stays that host's (even if its
 * lease ran out: it may renew after an outage; the printer moves once it is
 * reaped).  With out (n
 * entries) each printer's outcome goes there (out[i].owned false and
 * out[i].other naming the live owner for such a printer; the rest are
 * owned) and the call succeeds; with out NULL such a printer refuses the
 * whole call (SF_EAGAIN naming both hosts, nothing recorded).  SF_ESTALE
 * when name's lease is lost.
 */
int store_host_own(struct store *s, const char *name, int64_t token, const char *const *printers,
                   size_t n, struct store_host_owned *out, struct sf_err *err);

/*
 * Reap every host whose lease ran out by now_ms, in one transaction: its
 * claims on queued, preparing and ready jobs are released (preparing jobs
 * go back to queued), its printing and paused jobs (claimed by it, or
 * unclaimed on a printer it owns) become interrupted, each with an event
 * whose reason is "host NAME lost its lease", plus one "host-reaped" event
 * per host.  Idempotent: a reaped host is not reaped again.  Returns the
 * number of hosts reaped; *moved (may be NULL) the jobs requeued and
 * interrupted.
 */
int store_host_reap(struct store *s, int64_t now_ms, struct store_recovery *moved,
                    struct sf_err *err);

/*
 * Host name leaves (its process, token, stops): its lease ends now and it is
 * reaped as store_host_reap reaps, in one transaction, so its waiting work
 * moves on at once.  Only this host: the others' leases are the reap's (a
 * host that reaped every lease about to end would undo the reap's grace
 * after an outage).  Nothing to do (SF_OK, nothing moved) if it was reaped
 * already or the name is another process's.
 */
int store_host_leave(struct store *s, const char *name, int64_t token, struct store_recovery *moved,
                     struct sf_err *err);

/* A host as `slimfarm hosts` shows it (plain data). */
struct store_host_row {
    char name[STORE_HOST_NAME_MAX];
    int64_t token;          /* its current process's token */
    int64_t pid;            /* that process */
    int version;            /* the schema its program writes */
    int64_t started_ms;     /* when it joined */
    int64_t heartbeat_ms;   /* its last beat */
    int64_t lease_until_ms; /* when its lease runs out */
    bool live;              /* the lease runs at now_ms and was not reaped */
    int n_printers;         /* printers it owns, */
    char printers[256];     /* their names, comma-separated (cut with "..." past 255 bytes) */
    int n_claimed;          /* jobs it holds: preparing, ready, printing, paused, interrupted */
};

/*
 * Which host tells the operator of an event (notify.h) about job job_id (0:
 * none) and printer (NULL or "": none), as of now_ms, into host (cap
 * bytes): the job's holder, if live; else the live owner of the printer
 * (the event's, else the job's); else the live host first by name; "" if
 * no host is live.  Every host reads every event of the shared log, and
 * each event is told once per farm, by that host.
 */
int store_host_teller(struct store *s, int64_t job_id, const char *printer, int64_t now_ms,
                      char *host, size_t cap, struct sf_err *err);

/* How many hosts other than name hold a lease running at now_ms (*n). */
int store_host_peers(struct store *s, const char *name, int64_t now_ms, int *n, struct sf_err *err);
/* One trivial statement: whether s's connection answers.  On the loop's connection (a
   reconnect never waits: store_open_host) a lost one advances its reconnect and fails
   (SF_EUNREACH) until it is back, without waiting. */
int store_ping(struct store *s, struct sf_err *err);
/* Every host, by name, as of now_ms, into *rows (free() it). */
int store_host_list(struct store *s, int64_t now_ms, struct store_host_row **rows, size_t *n,
                    struct sf_err *err);

/*
 * Claim the next queued job for host (token: its join's) in the scheduler's
 * order (priority, higher first; queue_pos; id), moving it to preparing (the
 * PREPARE event, job.c's rule) with its claim, a new fencing token and a
 * "job-prepare" event, in one statement that no other host can interleave
 * (PostgreSQL: FOR UPDATE SKIP LOCKED, so claimers never wait on each other;
 * SQLite: its one writer).  methods: the preparation methods host runs,
 * comma-separated ("orient,slim"); NULL or "" for all.  The job into *out,
 * its fencing token into *fence (may be NULL).  SF_ENOTFOUND (err not set)
 * when no queued job fits; SF_ESTALE when host's lease is lost or run out;
 * SF_EINVAL for an unknown method.
 */
int store_job_claim(struct store *s, const char *host, int64_t token, const char *methods,
                    struct job_row *out, int64_t *fence, struct sf_err *err);

/*
 * As store_job_claim, for queued job id only (the one a host's scheduler
 * chose for a printer of its own), in the same statement: SF_ENOTFOUND (err
 * not set) when id is not queued (another host claimed it, or it moved on);
 * SF_EBUSY when another transaction holds its row (PostgreSQL: another
 * host's claim not yet committed, or another write to the job such as a
 * waiting reason): whether it stays queued is not known yet, so try again
 * (a write that leaves it queued wakes no host when it commits).
 */
int store_job_claim_id(struct store *s, const char *host, int64_t token, int64_t id,
                       struct job_row *out, int64_t *fence, struct sf_err *err);

/*
 * As store_job_claim_id, for the first of queued jobs ids[0..n) (n at most
 * STORE_CLAIM_IDS_MAX, in the order given: a host's scheduler's choices for
 * one printer, the best first) that is still queued and whose row no other
 * transaction holds (PostgreSQL: SKIP LOCKED, so hosts whose passes chose
 * the same jobs each claim the next one instead of failing on the first).
 * *tried: the job whose claim was made (0 if none; the one to read back,
 * store_job_claim_settle, when the claim is in doubt).  SF_ENOTFOUND (err
 * not set) when none of them is queued; SF_EBUSY when none was free but
 * one is still queued as far as committed writes say (its row held by a
 * write that may leave it queued, or another host's claim on its way: try
 * again; such a write wakes no host when it commits); SF_EINVAL when n is 0
 * or too many.
 */
#define STORE_CLAIM_IDS_MAX 16 /* the jobs a claim chooses from: more than hosts race for one */
int store_job_claim_first(struct store *s, const char *host, int64_t token, const int64_t *ids,
                          size_t n, int64_t *tried, struct job_row *out, int64_t *fence,
                          struct sf_err *err);

/*
 * Settle host's claim of job id whose COMMIT's answer was lost
 * (store_job_claim_id failed with SF_EINDOUBT: it may have committed).  If
 * it did (the job is preparing and host's), the claim is given back: the
 * DEFER event with the claim's fencing token, so the job is queued again
 * and no host's, and the other hosts are woken (*released true); if it did
 * not (the job is as it was), nothing is written (*released false).  Both
 * are SF_OK, and running it again is harmless.  SF_EBUSY while the claim's
 * own transaction still holds the job's row (its session not ended yet:
 * ask again), else the store's failure.  Call it before host claims job id
 * again: a claim of host's made after would be given back too.
 */
int store_job_claim_settle(struct store *s, const char *host, int64_t id, bool *released,
                           struct sf_err *err);

/*
 * Take ready job id for host, for a printer of its own, if no other host
 * holds it (unclaimed, or host's already: an uploaded G-code job, or one a
 * reaped host had prepared): its claim and a new fencing token (*fence, may
 * be NULL).  SF_ENOTFOUND (err not set) when id is not ready or another host
 * holds it; SF_ESTALE when host's lease is lost.  One statement, so two
 * hosts never both take a job.
 */
int store_job_take(struct store *s, const char *host, int64_t token, int64_t id, int64_t *fence,
                   struct sf_err *err);

/*
 * Give back a ready job host took (store_job_take) under fencing token
 * fence but cannot start (its G-code cannot be fetched here, why): no host
 * holds it any more, its token moves on, a "job-give-back" event says why,
 * and the other hosts are woken (a NOTIFY at the commit) to take it.
 * SF_ESTALE when host no longer holds it so.
 */
int store_job_give_back(struct store *s, const char *host, int64_t id, int64_t fence,
                        const char *why, struct sf_err *err);

/*
 * The live jobs host's scheduler works from (store_job_live's order): those
 * no host holds, host's own, and any on a printer host owns (a part on its
 * bed).  *rows: free() it.
 */
int store_job_live_host(struct store *s, const char *host, struct job_row **rows, size_t *n,
                        struct sf_err *err);

/*
 * Wake-ups between hosts (sqldb.h's LISTEN/NOTIFY on STORE_HOST_CHANNEL;
 * no-ops on SQLite): store_host_listen once on a connection kept for it,
 * store_host_wake after a change other hosts may act on (a job queued,
 * released or reaped; at COMMIT inside a transaction), store_host_notify_fd
 * the socket to watch (-1 when none; it may change at a reconnect),
 * store_host_drain reads what arrived: how many (>= 0), or SF_EIO when the
 * connection is lost (call it again later: it reconnects).
 */
#define STORE_HOST_CHANNEL "slimfarm_jobs"
int store_host_listen(struct store *s, struct sf_err *err);
int store_host_wake(struct store *s, struct sf_err *err);
int store_host_notify_fd(struct store *s);
int store_host_drain(struct store *s);
/* How often s's connection came back after a loss (0 on SQLite): its socket is a new one
   each time, perhaps under the old one's number, so a watcher of the old one adds it again. */
int64_t store_host_reconnects(struct store *s);
/* The time on s's database's clock (sqldb_clock_ms): every lease, reap and liveness test
   of the store runs on it; a now_ms a caller passes to a store_host or store_command
   function is its own wall clock (clock_wall_ms), moved onto the database's inside. */
int64_t store_clock_ms(const struct store *s);
/* Round trips s's connection made to the server so far (sqldb_round_trips; 0 on SQLite). */
int64_t store_round_trips(const struct store *s);

/*
 * Give job id (ready, printing, paused or interrupted) to host for its
 * printer: its claim and a new fencing token (*fence), logged as
 * "job-attach"; whoever held the job before holds a stale token.
 * SF_ENOTFOUND: no such job; SF_EAGAIN: not in one of those states, or on
 * a printer a live host other than host owns (store_host_own: the owner
 * drives its prints while it lives; another host attaches them only once
 * the owner's lease ran out); SF_ESTALE: host's lease is lost or run out.
 */
int store_job_attach(struct store *s, const char *host, int64_t token, int64_t id, int64_t *fence,
                     struct sf_err *err);

/*
 * store_job_attach of job id only while it is interrupted on printer, checked in the same
 * transaction (a job an operator restarted, or another printer took on, since the caller read
 * it is not held): SF_ENOTFOUND, err naming its state and printer, when it is not.
 */
int store_job_reattach(struct store *s, const char *host, int64_t token, int64_t id,
                       const char *printer, int64_t *fence, struct sf_err *err);

/*
 * Whether fence is job id's current fencing token, in the caller's
 * transaction (PostgreSQL: the job's row stays locked to it): SF_OK, or
 * SF_ESTALE naming the host that holds the job now, SF_ENOTFOUND.
 * store_job_event checks it for events that carry a fence.
 */
int store_job_fence(struct store *s, int64_t id, int64_t fence, struct sf_err *err);

/*
 * store_printer_set from host (its token): only while host's lease is
 * current and host owns printer (store_host_own), else SF_ESTALE naming
 * why, nothing written; so a host back from a partition cannot overwrite
 * the state of a printer another host has taken over.
 */
int store_host_printer_set(struct store *s, const char *host, int64_t token, const char *printer,
                           enum printer_state state, struct sf_err *err);

/*
 * What preparing a job for a printer needs (prepare.h's req.printer, sched.h's key and
 * compatibility), as the host that owns the printer publishes it (store_spare.c): so a
 * host with spare cores prepares a queued job for another host's printer (farm_spare.c).
 * Plain data.
 */
struct store_printer_prep {
    char name[64];                  /* the printer */
    char host[STORE_HOST_NAME_MAX]; /* its owner */
    char profile[64];               /* slicing profile */
    char material[32];              /* loaded material */
    double nozzle_mm;
    double bed_mm[3];
    double overhang_deg;
    char group[64];
    char gcode_models[256];
    bool attended;
    char allow_gcode[256];
    bool enabled;
};

/*
 * Publish what preparing for host name's printers needs (n entries, each a printer it owns,
 * store_host_own): written on their host_printers rows in one transaction; a printer name
 * owns no longer is left alone, one with an empty profile written as is (the read leaves it
 * out).  SF_ESTALE when name's lease is lost.
 */
int store_host_publish(struct store *s, const char *name, int64_t token,
                       const struct store_printer_prep *p, size_t n, struct sf_err *err);

/*
 * The printers other live hosts than name (lease running at now_ms, not reaped) own and
 * published (store_host_publish), by printer, into *rows (free() it).
 */
int store_host_printers_prep(struct store *s, const char *name, int64_t now_ms,
                             struct store_printer_prep **rows, size_t *n, struct sf_err *err);

/*
 * A job a host prepared for another host's printer (a spare-cores preparation): its PREPARED
 * event (a, with the claim's fencing token) and, in the same transaction, the claim given
 * up (no host holds it, its token moves on, a "job-hand-over" event naming the host that
 * prepared it), so the printer's own host takes it (store_job_take) as it takes a ready job
 * no host holds; the others are woken at the commit.  Never left held by the host that
 * prepared it.  *to: the job's state after.
 * store_job_event's errors (SF_ESTALE for a stale token).
 */
int store_job_prepared_release(struct store *s, int64_t id, const struct job_event_args *a,
                               enum job_state *to, struct sf_err *err);

#endif
