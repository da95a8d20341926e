/*
 * api_read.h - the API's reads of the store, off the loop thread: a
 * read-only connection to the database (store_open_reader) used by one
 * worker thread of its own, while the request waits, deferred
 * (http_defer), and its answer is given on the loop.
 *
 * Why: the loop that answers HTTP also feeds the printers their next line;
 * a client listing jobs in a loop once held it long enough to stretch a
 * print from 26 s to 47 s (issue 30).  SQLite's WAL lets the reader read
 * while the loop writes, and neither waits for the other; one thread
 * (not the prepare pool, whose slices take seconds) keeps the reads in
 * order and leaves the other cores to the printers and the workers.
 *
 * Thread: api_read_new, api_read_free and api_read_run on the loop thread;
 * a read function on the reader's thread, with the reader's connection
 * only (nothing of the farm, printers or the loop's store); a finish
 * function back on the loop thread.  Owns the reader thread and its
 * connection.
 */
#ifndef SF_API_API_READ_H
#define SF_API_API_READ_H

#include "../base/err.h"
#include "../base/loop.h"
#include "../farm/store.h"
#include "http.h"

struct api_read;

/*
 * A reader of store s (its thread and connection).  l NULL: no thread,
 * every read runs at once on the caller's thread with s itself (a test
 * without a loop).  The server runs again after each deferred answer
 * (http_set_wake).  NULL with err set.  Free with api_read_free() before s; reads still queued are
 * answered 503.
 */
struct api_read *api_read_new(struct loop *l, struct store *s, struct sf_err *err);
void api_read_free(struct api_read *r);

/* Fills resp (json or a body, or an error) from the store s given (the reader's). */
typedef void (*api_read_fn)(struct store *s, void *ud, struct http_resp *resp);
/* On the loop, after the read, while the client still waits: add what only the loop reads. */
typedef void (*api_read_finish_fn)(void *ud, struct http_resp *resp);

/*
 * Answer the request resp belongs to with read(ud) on the reader's thread,
 * then finish(ud) (may be NULL) on the loop; ud_free(ud) (may be NULL)
 * runs after, whatever happened (the client left, the daemon stopped).
 * When the request cannot be deferred (out of memory) the read runs now,
 * on the loop, with the loop's store.
 */
void api_read_run(struct api_read *r, struct http_resp *resp, api_read_fn read,
                  api_read_finish_fn finish, void *ud, void (*ud_free)(void *ud));

/* A read of the reader's store s into ud (the reader's thread). */
typedef void (*api_read_job_fn)(struct store *s, void *ud);
/* On the loop after it: ran false when the read never ran (the daemon stopping). */
typedef void (*api_read_done_fn)(void *ud, bool ran);

/*
 * A read that answers no request of its own (an event stream's next
 * events): read(ud) on the reader's thread, in order with the other
 * reads, then done(ud, ran) on the loop, exactly once; done owns ud
 * (what ud stands for may be gone meanwhile: done must check, as
 * nothing else tells it).  Without a reader thread both run now, on the
 * caller's thread with the loop's store.  false (out of memory):
 * neither runs.  A read in flight when api_read_free runs calls done
 * later on the loop (pool.h): ud must not point into what the caller
 * frees after api_read_free.
 */
bool api_read_post(struct api_read *r, api_read_job_fn read, api_read_done_fn done, void *ud);

#endif
