/*
 * store_event.c - the store's event log (store.h): the append every
 * mutator makes in its own transaction, and the reads the API's event
 * stream pages through.
 *
 * Thread: the store's.
 */
#include "store.h"

#include <stdint.h>
#include <stdio.h>

#include "../base/clock.h"
#include "store_int.h"
#include "store_view.h"

/*
 * Event ids commit in their order, so a reader paging `WHERE id > last` never
 * passes one that commits later.  SQLite has one writer at a time.  On
 * PostgreSQL an id is taken at the INSERT and two connections (the loop's and
 * the store thread's; other hosts) commit in any order: the INSERT first takes
 * a transaction-level advisory lock (in the same statement: a CTE the INSERT
 * reads before its id is drawn), held to COMMIT, so the next event's id is
 * drawn only once this one is visible.  Chosen over readers stopping at the
 * oldest open transaction, which would need each row's transaction id and a
 * cursor of (xid, id) in every reader (the API's stream, notify.c).  Cost:
 * transactions that log events commit one after another (no group commit
 * between them); measured in tests/bench/bench_store.sh's claims.  The same
 * statement NOTIFYs STORE_EVENT_CHANNEL (store_view.h): the other hosts'
 * event streams wake when it commits (PostgreSQL sends one per transaction).
 */
#define STORE_EVENT_LOCK_KEY 0x736c696d6576656eLL /* "slimeven" in ASCII */

int
store_log_event(struct store *s, int64_t job_id, const char *printer, const char *kind,
                const char *detail, struct sf_err *err)
{
    struct sqldb_stmt *st;
    char pg_sql[512];
    snprintf(pg_sql, sizeof(pg_sql),
             "WITH l AS (SELECT pg_advisory_xact_lock(%lld)),"
             " n AS (SELECT pg_notify('" STORE_EVENT_CHANNEL "', ''))"
             " INSERT INTO events(at_ms, job_id, printer, kind, detail)"
             " SELECT CAST(?1 AS BIGINT), CAST(?2 AS BIGINT), CAST(?3 AS TEXT), CAST(?4 AS TEXT),"
             " CAST(?5 AS TEXT) FROM l, n",
             (long long)STORE_EVENT_LOCK_KEY);
    int rc = store_prepare(s, &st,
                           sqldb_engine(s->db) == SQLDB_PG
                               ? pg_sql
                               : "INSERT INTO events(at_ms, job_id, printer, kind, detail)"
                                 " VALUES(?, ?, ?, ?, ?)",
                           err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, clock_wall_ms());
    if (job_id > 0)
        sqldb_bind_int64(st, 2, job_id);
    else
        sqldb_bind_null(st, 2);
    sqldb_bind_text(st, 3, printer ? printer : "");
    sqldb_bind_text(st, 4, kind);
    sqldb_bind_text(st, 5, detail);
    return store_step_done(s, st, err, "log event");
}

static void
read_event(struct sqldb_stmt *st, void *row)
{
    struct event_row *e = row;
    e->id = sqldb_column_int64(st, 0);
    e->at_ms = sqldb_column_int64(st, 1);
    e->job_id = sqldb_column_int64(st, 2);
    store_copy_text(e->printer, sizeof(e->printer), st, 3);
    store_copy_text(e->kind, sizeof(e->kind), st, 4);
    store_copy_text(e->detail, sizeof(e->detail), st, 5);
}

int
store_events(struct store *s, int64_t after_id, size_t max, struct event_row **rows, size_t *n,
             struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_select(s, &st,
                          "SELECT id, at_ms, coalesce(job_id, 0), printer, kind, detail FROM events"
                          " WHERE id > ? ORDER BY id LIMIT ?",
                          (void **)rows, n, err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, after_id);
    sqldb_bind_int64(st, 2, (int64_t)(max > INT64_MAX ? INT64_MAX : max));
    return store_read_rows(s, st, sizeof(**rows), read_event, (void **)rows, n, "list events", err);
}

int64_t
store_event_last(struct store *s)
{
    struct sqldb_stmt *st;
    if (sqldb_prepare(s->db, "SELECT coalesce(max(id), 0) FROM events", &st))
        return 0;
    int64_t id = sqldb_step(st) == SQLDB_ROW ? sqldb_column_int64(st, 0) : 0;
    sqldb_finalize(st);
    return id;
}
