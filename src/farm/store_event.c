/*
 * store_event.c - the store's event log (store.h): the append every
 * mutator makes in its own transaction, and the reads the API's event
 * stream pages through.
 *
 * Thread: the store's.
 */
#include "store.h"

#include <sqlite3.h>
#include <stdint.h>

#include "../base/clock.h"
#include "store_int.h"

int
store_log_event(struct store *s, int64_t job_id, const char *printer, const char *kind,
                const char *detail, struct sf_err *err)
{
    sqlite3_stmt *st;
    int rc = store_prepare(s, &st,
                           "INSERT INTO events(at_ms, job_id, printer, kind, detail)"
                           " VALUES(?, ?, ?, ?, ?)",
                           err);
    if (rc)
        return rc;
    sqlite3_bind_int64(st, 1, clock_wall_ms());
    if (job_id > 0)
        sqlite3_bind_int64(st, 2, job_id);
    else
        sqlite3_bind_null(st, 2);
    sqlite3_bind_text(st, 3, printer ? printer : "", -1, SQLITE_TRANSIENT);
    sqlite3_bind_text(st, 4, kind, -1, SQLITE_TRANSIENT);
    sqlite3_bind_text(st, 5, detail, -1, SQLITE_TRANSIENT);
    return store_step_done(s, st, err, "log event");
}

static void
read_event(sqlite3_stmt *st, void *row)
{
    struct event_row *e = row;
    e->id = sqlite3_column_int64(st, 0);
    e->at_ms = sqlite3_column_int64(st, 1);
    e->job_id = sqlite3_column_int64(st, 2);
    store_copy_text(e->printer, sizeof(e->printer), st, 3);
    store_copy_text(e->kind, sizeof(e->kind), st, 4);
    store_copy_text(e->detail, sizeof(e->detail), st, 5);
}

int
store_events(struct store *s, int64_t after_id, size_t max, struct event_row **rows, size_t *n,
             struct sf_err *err)
{
    sqlite3_stmt *st;
    int rc = store_select(s, &st,
                          "SELECT id, at_ms, coalesce(job_id, 0), printer, kind, detail FROM events"
                          " WHERE id > ? ORDER BY id LIMIT ?",
                          (void **)rows, n, err);
    if (rc)
        return rc;
    sqlite3_bind_int64(st, 1, after_id);
    sqlite3_bind_int64(st, 2, (sqlite3_int64)(max > INT64_MAX ? INT64_MAX : max));
    return store_read_rows(s, st, sizeof(**rows), read_event, (void **)rows, n, "list events", err);
}

int64_t
store_event_last(struct store *s)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(s->db, "SELECT coalesce(max(id), 0) FROM events", -1, &st, NULL))
        return 0;
    int64_t id = sqlite3_step(st) == SQLITE_ROW ? sqlite3_column_int64(st, 0) : 0;
    sqlite3_finalize(st);
    return id;
}
