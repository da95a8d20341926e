/*
 * store_view.c - each host's published view of its printers (store_view.h).
 *
 * Thread: any, one store handle per thread (store.h).
 */
#include "store_view.h"

#include "../base/clock.h"
#include "sqldb.h"
#include "store_int.h"

/* The upsert, only under host's current token; a row back when written. */
#define VIEW_UPSERT                                                                                \
    "INSERT INTO host_views(host, token, view, updated_ms)"                                        \
    " SELECT CAST(?1 AS TEXT), CAST(?2 AS BIGINT), CAST(?3 AS TEXT), CAST(?4 AS BIGINT)"           \
    " WHERE EXISTS (SELECT 1 FROM hosts WHERE name = ?1 AND token = ?2 AND reaped_ms = 0)"         \
    " ON CONFLICT(host) DO UPDATE SET token = excluded.token, view = excluded.view,"               \
    " updated_ms = excluded.updated_ms RETURNING host"

int
store_view_publish(struct store *s, const char *host, int64_t token, const char *view,
                   struct sf_err *err)
{
    struct sqldb_stmt *st;
    /* on PostgreSQL the NOTIFY rides in the same statement, sent only when written */
    int rc = store_prepare(s, &st,
                           sqldb_engine(s->db) == SQLDB_PG
                               ? "WITH u AS (" VIEW_UPSERT ")"
                                 " SELECT pg_notify('" STORE_VIEW_CHANNEL "', host) FROM u"
                               : VIEW_UPSERT,
                           err);
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, host);
    sqldb_bind_int64(st, 2, token);
    sqldb_bind_text(st, 3, view);
    sqldb_bind_int64(st, 4, clock_wall_ms());
    rc = sqldb_step(st);
    bool written = rc == SQLDB_ROW;
    while (rc == SQLDB_ROW)
        rc = sqldb_step(st);
    sqldb_finalize(st);
    if (rc != SQLDB_DONE)
        return store_db_fail(s, err, "publish the host's view");
    if (!written)
        return sf_err_set(err, SF_ESTALE,
                          "host '%s': its view not written: token %lld is no longer the name's",
                          host, (long long)token);
    return SF_OK;
}
