/*
 * sqldb.c - the engine-neutral half of sqldb.h: picks a driver by the
 * target's form and dispatches each call through its table.
 *
 * Thread: as sqldb.h.
 */
#include "sqldb.h"

#include <stdio.h>
#include <string.h>

#include "sqldb_int.h"

bool
sqldb_is_url(const char *target)
{
    return strncmp(target, "postgresql://", 13) == 0 || strncmp(target, "postgres://", 11) == 0;
}

struct sqldb *
sqldb_open(const char *target, unsigned flags, struct sf_err *err)
{
    return sqldb_is_url(target) ? sqldb_pg_open(target, flags, err)
                                : sqldb_sqlite_open(target, flags, err);
}

int
sqldb_fail(struct sqldb *db, const char *msg)
{
    snprintf(db->msg, sizeof(db->msg), "%s", msg ? msg : "unknown error");
    size_t n = strlen(db->msg);
    while (n > 0 && (db->msg[n - 1] == '\n' || db->msg[n - 1] == ' '))
        db->msg[--n] = '\0';
    return SF_EIO;
}

void
sqldb_close(struct sqldb *db)
{
    if (db)
        db->ops->close(db);
}

enum sqldb_engine
sqldb_engine(const struct sqldb *db)
{
    return db->ops->engine;
}

const char *
sqldb_errmsg(const struct sqldb *db)
{
    return db->msg;
}

int
sqldb_exec(struct sqldb *db, const char *sql)
{
    return db->ops->exec(db, sql);
}

int
sqldb_begin(struct sqldb *db)
{
    return db->ops->exec(db, db->ops->begin_sql);
}

int
sqldb_commit(struct sqldb *db)
{
    int rc = db->ops->exec(db, "COMMIT");
    if (rc != SF_OK) {
        char msg[SQLDB_MSG_MAX];
        snprintf(msg, sizeof(msg), "%s", db->msg); /* the commit's, not the rollback's */
        sqldb_rollback(db);
        snprintf(db->msg, sizeof(db->msg), "%s", msg);
    }
    return rc;
}

void
sqldb_rollback(struct sqldb *db)
{
    char msg[SQLDB_MSG_MAX];
    snprintf(msg, sizeof(msg), "%s", db->msg); /* keep the failure that led here */
    db->ops->exec(db, "ROLLBACK");
    snprintf(db->msg, sizeof(db->msg), "%s", msg);
}

int
sqldb_set_durable(struct sqldb *db, bool durable)
{
    return db->ops->set_durable(db, durable);
}

int64_t
sqldb_changes(const struct sqldb *db)
{
    return db->changes;
}

int
sqldb_prepare(struct sqldb *db, const char *sql, struct sqldb_stmt **st)
{
    *st = NULL;
    return db->ops->prepare(db, sql, st);
}

void
sqldb_bind_int64(struct sqldb_stmt *st, int i, int64_t v)
{
    st->db->ops->bind_int64(st, i, v);
}

void
sqldb_bind_double(struct sqldb_stmt *st, int i, double v)
{
    st->db->ops->bind_double(st, i, v);
}

void
sqldb_bind_text(struct sqldb_stmt *st, int i, const char *text)
{
    if (text)
        st->db->ops->bind_text(st, i, text);
    else
        st->db->ops->bind_null(st, i);
}

void
sqldb_bind_null(struct sqldb_stmt *st, int i)
{
    st->db->ops->bind_null(st, i);
}

void
sqldb_bind_blob(struct sqldb_stmt *st, int i, const void *data, size_t len)
{
    st->db->ops->bind_blob(st, i, data, len);
}

int
sqldb_step(struct sqldb_stmt *st)
{
    return st->db->ops->step(st);
}

int64_t
sqldb_column_int64(struct sqldb_stmt *st, int col)
{
    return st->db->ops->column_int64(st, col);
}

int
sqldb_column_int(struct sqldb_stmt *st, int col)
{
    return (int)st->db->ops->column_int64(st, col);
}

double
sqldb_column_double(struct sqldb_stmt *st, int col)
{
    return st->db->ops->column_double(st, col);
}

const char *
sqldb_column_text(struct sqldb_stmt *st, int col)
{
    return st->db->ops->column_text(st, col);
}

bool
sqldb_column_null(struct sqldb_stmt *st, int col)
{
    return st->db->ops->column_null(st, col);
}

const void *
sqldb_column_blob(struct sqldb_stmt *st, int col, size_t *len)
{
    return st->db->ops->column_blob(st, col, len);
}

void
sqldb_reset(struct sqldb_stmt *st)
{
    st->db->ops->reset(st);
}

void
sqldb_finalize(struct sqldb_stmt *st)
{
    if (st)
        st->db->ops->finalize(st);
}
