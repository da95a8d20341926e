/*
 * store_event.c - the store's event log (store.h): the append every
 * mutator makes in its own transaction, and the reads the API's event
 * stream pages through.
 *
 * Thread: the store's.
 */
#include "store.h"

#include <stdint.h>

#include "../base/clock.h"
#include "store_int.h"

int
store_log_event(struct store *s, int64_t job_id, const char *printer, const char *kind,
                const char *detail, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st,
                           "INSERT INTO events(at_ms, job_id, printer, kind, detail)"
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
