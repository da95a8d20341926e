/*
 * sqldb_sqlite.c - sqldb.h's SQLite driver: a thin layer over sqlite3,
 * whose API sqldb.h copies, plus the connection set-up the store relies
 * on (WAL, foreign keys, synchronous FULL, a busy timeout).
 *
 * Thread: as sqldb.h.
 */
#include "sqldb.h"

#include <sqlite3.h>
#include <stdio.h>
#include <string.h>

#include "../base/mem.h"
#include "sqldb_int.h"

struct lite {
    struct sqldb base;
    sqlite3 *db;
};

struct lite_stmt {
    struct sqldb_stmt base;
    sqlite3_stmt *st;
};

static sqlite3 *
conn(struct sqldb *db)
{
    return ((struct lite *)db)->db;
}

static sqlite3_stmt *
stmt(struct sqldb_stmt *st)
{
    return ((struct lite_stmt *)st)->st;
}

/* db's last failure from SQLite: msg (NULL: SQLite's own), its code per sqldb.h (busy or
   locked: SF_EBUSY, nothing applied; anything else SF_EIO). */
static int
lite_fail(struct sqldb *db, const char *msg)
{
    int ec = sqlite3_errcode(conn(db)) & 0xff;
    return sqldb_failf(db, ec == SQLITE_BUSY || ec == SQLITE_LOCKED ? SF_EBUSY : SF_EIO, "%s",
                       msg ? msg : sqlite3_errmsg(conn(db)));
}

static void
lite_close(struct sqldb *db)
{
    sqlite3_close(conn(db));
    free(db);
}

static int
lite_exec(struct sqldb *db, const char *sql)
{
    char *msg = NULL;
    if (sqlite3_exec(conn(db), sql, NULL, NULL, &msg) != SQLITE_OK) {
        int rc = lite_fail(db, msg);
        sqlite3_free(msg);
        return rc;
    }
    db->changes = sqlite3_changes(conn(db));
    return SF_OK;
}

static int
lite_set_durable(struct sqldb *db, bool durable)
{
    /* WAL with synchronous=NORMAL: a commit survives a kill -9, and the next
       FULL commit's fsync carries it to disk */
    return lite_exec(db, durable ? "PRAGMA synchronous = FULL" : "PRAGMA synchronous = NORMAL");
}

static int
lite_prepare(struct sqldb *db, const char *sql, struct sqldb_stmt **out)
{
    struct lite_stmt *st = mem_calloc(1, sizeof(*st));
    if (!st)
        return SF_ENOMEM;
    st->base.db = db;
    if (sqlite3_prepare_v2(conn(db), sql, -1, &st->st, NULL) != SQLITE_OK) {
        int rc = lite_fail(db, NULL);
        sqlite3_finalize(st->st);
        free(st);
        return rc;
    }
    *out = &st->base;
    return SF_OK;
}

static void
lite_bind_int64(struct sqldb_stmt *st, int i, int64_t v)
{
    sqlite3_bind_int64(stmt(st), i, v);
}

static void
lite_bind_double(struct sqldb_stmt *st, int i, double v)
{
    sqlite3_bind_double(stmt(st), i, v);
}

static void
lite_bind_text(struct sqldb_stmt *st, int i, const char *text)
{
    sqlite3_bind_text(stmt(st), i, text, -1, SQLITE_TRANSIENT);
}

static void
lite_bind_null(struct sqldb_stmt *st, int i)
{
    sqlite3_bind_null(stmt(st), i);
}

static void
lite_bind_blob(struct sqldb_stmt *st, int i, const void *data, size_t len)
{
    /* zeroblob for none: sqlite3_bind_blob binds NULL for a NULL pointer */
    if (len == 0)
        sqlite3_bind_zeroblob(stmt(st), i, 0);
    else
        sqlite3_bind_blob64(stmt(st), i, data, len, SQLITE_TRANSIENT);
}

static int
lite_step(struct sqldb_stmt *st)
{
    int rc = sqlite3_step(stmt(st));
    if (rc == SQLITE_ROW)
        return SQLDB_ROW;
    if (rc == SQLITE_DONE) {
        st->db->changes = sqlite3_changes(conn(st->db));
        return SQLDB_DONE;
    }
    return lite_fail(st->db, NULL);
}

static int64_t
lite_column_int64(struct sqldb_stmt *st, int col)
{
    return sqlite3_column_int64(stmt(st), col);
}

static double
lite_column_double(struct sqldb_stmt *st, int col)
{
    return sqlite3_column_double(stmt(st), col);
}

static const char *
lite_column_text(struct sqldb_stmt *st, int col)
{
    return (const char *)sqlite3_column_text(stmt(st), col);
}

static bool
lite_column_null(struct sqldb_stmt *st, int col)
{
    return sqlite3_column_type(stmt(st), col) == SQLITE_NULL;
}

static const void *
lite_column_blob(struct sqldb_stmt *st, int col, size_t *len)
{
    *len = 0;
    if (sqlite3_column_type(stmt(st), col) == SQLITE_NULL)
        return NULL;
    const void *p = sqlite3_column_blob(stmt(st), col);
    *len = (size_t)sqlite3_column_bytes(stmt(st), col);
    return p ? p : ""; /* an empty blob reads as NULL in sqlite3 */
}

static void
lite_reset(struct sqldb_stmt *st)
{
    sqlite3_reset(stmt(st));
}

static void
lite_finalize(struct sqldb_stmt *st)
{
    sqlite3_finalize(stmt(st));
    free(st);
}

static const struct sqldb_ops lite_ops = {
    .engine = SQLDB_SQLITE,
    .close = lite_close,
    .exec = lite_exec,
    .begin_sql = "BEGIN IMMEDIATE",
    .set_durable = lite_set_durable,
    .prepare = lite_prepare,
    .bind_int64 = lite_bind_int64,
    .bind_double = lite_bind_double,
    .bind_text = lite_bind_text,
    .bind_null = lite_bind_null,
    .bind_blob = lite_bind_blob,
    .step = lite_step,
    .column_int64 = lite_column_int64,
    .column_double = lite_column_double,
    .column_text = lite_column_text,
    .column_null = lite_column_null,
    .column_blob = lite_column_blob,
    .reset = lite_reset,
    .finalize = lite_finalize,
};

/* Switch a new writer to WAL: readers (store_open_reader) then never wait for it. */
static int
wal_on(struct sqldb *db, const char *path, struct sf_err *err)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(conn(db), "PRAGMA journal_mode = WAL", -1, &st, NULL) != SQLITE_OK)
        return sf_err_set(err, SF_EIO, "sqlite '%s': %s", path, sqlite3_errmsg(conn(db)));
    bool ok = sqlite3_step(st) == SQLITE_ROW &&
              strcmp((const char *)sqlite3_column_text(st, 0), "wal") == 0;
    sqlite3_finalize(st);
    return ok ? SF_OK : sf_err_set(err, SF_EIO, "store: '%s': cannot switch to WAL mode", path);
}

struct sqldb *
sqldb_sqlite_open(const char *path, unsigned flags, struct sf_err *err)
{
    struct lite *l = mem_calloc(1, sizeof(*l));
    if (!l) {
        sf_err_set(err, SF_ENOMEM, "sqlite: out of memory");
        return NULL;
    }
    l->base.ops = &lite_ops;
    int oflags =
        flags & SQLDB_READONLY ? SQLITE_OPEN_READONLY : SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE;
    if (sqlite3_open_v2(path, &l->db, oflags, NULL) != SQLITE_OK) {
        sf_err_set(err, SF_EIO, "store: cannot open '%s': %s", path,
                   l->db ? sqlite3_errmsg(l->db) : "out of memory");
        lite_close(&l->base);
        return NULL;
    }
    /* a checkpoint may hold the WAL index for a moment; wait rather than fail */
    sqlite3_busy_timeout(l->db, 5000);
    if (!(flags & SQLDB_READONLY)) {
        int rc = wal_on(&l->base, path, err);
        if (rc == SF_OK &&
            lite_exec(&l->base, "PRAGMA foreign_keys = ON; PRAGMA synchronous = FULL;"))
            rc = sf_err_set(err, SF_EIO, "store: '%s': %s", path, l->base.msg);
        if (rc) {
            lite_close(&l->base);
            return NULL;
        }
    }
    return &l->base;
}
