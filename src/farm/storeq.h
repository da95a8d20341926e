/*
 * storeq.h - the store's own thread: writes the loop does not wait for.
 *
 * The loop feeds printers; a store write that waits (SQLite's lock held by
 * another process, up to its 5 s busy timeout; PostgreSQL's network) must
 * not stop them.  A storeq owns a second connection to the store's
 * database (store_open_writer) on a thread of its own.  The loop posts
 * requests (their data copied: nothing points into loop state) to a FIFO;
 * the thread runs them one at a time, in the order posted, and hands each
 * back to the loop with its result (an eventfd on the loop).
 *
 * Order: every request runs after every request posted before it, so a
 * read or write posted later sees them.  The loop's own connection does
 * not: before a direct store call that must see what was queued, call
 * storeq_sync.
 *
 * Failures: a request that fails with nothing applied (SF_EBUSY: busy;
 * SF_EUNREACH: the server gone) is tried again, backing off to 1 s, for up
 * to STOREQ_RETRY_MS; one whose commit's outcome is unknown (SF_EINDOUBT)
 * is read back (store_commit_outcome) and run again only if it did not
 * commit (a write that only sets values is run again at once); other
 * failures and the last one are reported on the loop: logged, counted in
 * storeq_stats, and given to the request's callback if it has one.  Once a
 * request has run out of time during storeq_free, the ones after it fail at
 * once.
 * Progress is folded: a newer count for a job whose older one still waits
 * replaces it, so a long wait queues one progress per job, not one per 16
 * lines.
 *
 * Thread: every function on the loop's thread.  The store passed to
 * storeq_new is only read there (its target); the queue's connection is its
 * own.
 */
#ifndef SF_FARM_STOREQ_H
#define SF_FARM_STOREQ_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"
#include "../base/loop.h"
#include "job.h"
#include "store.h"

/* How long a request that fails with nothing applied is tried again: a PostgreSQL restart, an
   SQLite lock an operator's tool holds for a while.  At shutdown: STOREQ_STOP_MS. */
#define STOREQ_RETRY_MS 60000
#define STOREQ_STOP_MS  10000
/* How long the loop waits for the queue before a write it acts on (storeq_sync): the
   queue empties in milliseconds unless the database is held busy, and then the
   printers must not wait with it. */
#define STOREQ_SYNC_MS 250

struct storeq;

/* What a job event came back with. */
struct storeq_result {
    int64_t id;        /* the job */
    enum job_event ev; /* the event */
    int rc;            /* SF_OK, or the store's error in err */
    enum job_state to; /* the job's state after (rc SF_OK) */
    const struct sf_err *err;
};
typedef void (*storeq_event_fn)(void *ud, const struct storeq_result *r);
/* Called on the loop after requests that logged an event committed (a batch: once). */
typedef void (*storeq_commit_fn)(void *ud);

/* What the queue has done since storeq_new. */
struct storeq_stats {
    uint64_t posted;     /* requests posted (folded progress counts once) */
    uint64_t done;       /* requests run to the end, failed or not */
    uint64_t failed;     /* of which failed (after their retries) */
    uint64_t retries;    /* failures tried again (or read back) */
    size_t depth;        /* requests waiting or running now */
    size_t depth_max;    /* the most there were */
    int64_t wait_max_ms; /* the longest a request waited from post to its end */
};

/*
 * A queue on s's database (its own connection) delivering to loop l.
 * NULL with err set (the connection's error, SF_EIO; SF_ENOMEM).  Free with
 * storeq_free.
 */
struct storeq *storeq_new(struct loop *l, const struct store *s, struct sf_err *err);
/*
 * Run every request still queued (retrying as above, STOREQ_STOP_MS at
 * most), deliver their results on this thread, stop the thread and close
 * the connection.  NULL is ignored.
 */
void storeq_free(struct storeq *q);

/* How long a request that fails with nothing applied is tried again from now on (default
   STOREQ_RETRY_MS): tests that must see the retries run out in seconds shorten it. */
void storeq_set_retry_ms(struct storeq *q, int64_t ms);

/* Call fn(ud) after requests that log an event commit (the farm's wake); NULL: none. */
void storeq_set_commit(struct storeq *q, storeq_commit_fn fn, void *ud);

/*
 * Writes the loop does not wait for (store.h's functions of the same
 * names, their arguments copied).  SF_OK, or SF_ENOMEM (nothing queued,
 * counted as failed).
 */
int storeq_jobs_progress(struct storeq *q, const struct store_progress *p, size_t n);
int storeq_job_set_reason(struct storeq *q, int64_t id, const char *reason);
int storeq_printer_set(struct storeq *q, const char *name, enum printer_state st);
int storeq_printer_note(struct storeq *q, const char *name, const char *kind, const char *detail);
int storeq_printer_bed_set(struct storeq *q, const char *name, bool full);
/*
 * Apply job event ev to job id (store_job_event), a's strings copied (a
 * reason or note is cut at 511 bytes, as the store would cut it anyway);
 * done(ud, result) on the loop once it ran (NULL: a failure is logged, with
 * who (a printer name, or NULL) in front).  SF_OK or SF_ENOMEM (done is
 * not called).
 */
int storeq_job_event(struct storeq *q, int64_t id, enum job_event ev,
                     const struct job_event_args *a, const char *who, storeq_event_fn done,
                     void *ud);

/*
 * Wait (blocking the loop) until every request posted so far has run, for
 * up to max_ms (< 0: as long as it takes): then the loop's own connection
 * sees what they wrote.  Their results are delivered on a later loop turn,
 * as always.  SF_EBUSY when the queue did not empty in time ("the store is
 * busy: N writes wait for the database"; not SF_EAGAIN, the job rules'
 * refusal): the caller tries again later (the API answers 503), and the
 * commit callback (storeq_set_commit) runs once the queue has emptied.
 */
int storeq_sync(struct storeq *q, int64_t max_ms, struct sf_err *err);

/*
 * Run fn(s, arg, err) on the queue's thread with its connection s, after
 * every request posted before it (retried while it fails with SF_EBUSY or
 * SF_EUNREACH, read back on SF_EINDOUBT, as any request: fn must leave
 * nothing behind when it fails, one store transaction), then done(ud, r) on the loop with r->rc and
 * r->err (r->id 0; NULL done: a failure is logged with who in front).  arg is the caller's until
 * done runs: the thread reads and writes it, the loop must not touch it meanwhile.  A successful
 * call wakes the farm as an event does (storeq_set_commit).  SF_OK, or SF_ENOMEM (done is not
 * called).
 */
typedef int (*storeq_call_fn)(struct store *s, void *arg, struct sf_err *err);
int storeq_call(struct storeq *q, storeq_call_fn fn, void *arg, const char *who,
                storeq_event_fn done, void *ud);
/*
 * storeq_call for a read (fn writes nothing): the same, except that it
 * wakes no one (storeq_set_commit's callback), so a reader that runs on
 * every wake-up does not wake itself.
 */
int storeq_read(struct storeq *q, storeq_call_fn fn, void *arg, storeq_event_fn done, void *ud);
/*
 * done(ud, r) on the loop (r->rc SF_OK) once every request posted before
 * it has run, failed or not: an answer that must follow what was written
 * before it (an operator's action whose writes are queued).  SF_OK or
 * SF_ENOMEM (done is not called).
 */
int storeq_barrier(struct storeq *q, storeq_event_fn done, void *ud);

/* Requests waiting or running. */
size_t storeq_depth(struct storeq *q);
void storeq_stats(struct storeq *q, struct storeq_stats *out);

#endif
