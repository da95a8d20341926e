/*
 * sqldb.h - one small SQL interface over the two engines the store runs
 * on: SQLite (a file, embedded; the default) and PostgreSQL (a server,
 * through libpq).  Shaped as the subset of the sqlite3 API the store uses
 * (prepare, bind, step, column, finalize, exec, changes), so a store
 * function keeps its structure and its one SQL text on both engines.
 *
 *     struct sqldb *db = sqldb_open("postgresql:///farm?host=/run/pg", 0, &err);
 *     struct sqldb_stmt *st;
 *     if (sqldb_prepare(db, "SELECT id FROM jobs WHERE state = ?", &st) == SF_OK) {
 *         sqldb_bind_text(st, 1, "queued");
 *         while (sqldb_step(st) == SQLDB_ROW) use(sqldb_column_int64(st, 0));
 *         sqldb_finalize(st);
 *     }
 *
 * SQL is written once, in the dialect both engines share: placeholders `?`
 * or `?N` (the PostgreSQL driver rewrites them to `$N`), INSERT ...
 * RETURNING instead of a last insert id, ON CONFLICT, CASE and coalesce
 * rather than SQLite's two-argument max() or total(); a parameter whose
 * type nothing in the statement fixes (`? || 'x'`) takes a CAST, as
 * PostgreSQL infers parameter types from their use (so a `?N` used twice
 * is used as one type).  What only one
 * engine has (PRAGMAs, json_each, INDEXED BY) the caller picks by
 * sqldb_engine(); connection set-up (SQLite's WAL and busy timeout) lives
 * in the drivers.
 *
 * Errors: functions return SF_OK or SF_EIO (SF_ENOMEM for memory) and
 * leave the engine's message on the handle (sqldb_errmsg), as sqlite3
 * does; the store wraps it into its sf_err.
 *
 * Thread: a connection and its statements are used by one thread at a
 * time.  Calls block until the engine answers (for PostgreSQL: the
 * network); nothing here is for a loop that must not wait.
 */
#ifndef SF_FARM_SQLDB_H
#define SF_FARM_SQLDB_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"

struct sqldb;
struct sqldb_stmt;

enum sqldb_engine {
    SQLDB_SQLITE,
    SQLDB_PG,
};

/* sqldb_step's answers besides an error (SF_EIO). */
enum {
    SQLDB_DONE = 0, /* no (more) rows: the statement has run */
    SQLDB_ROW = 1,  /* a row is ready for the column functions */
};

/* sqldb_open flags */
#define SQLDB_READONLY 1u /* reads only: a write fails */

/* Whether target names a PostgreSQL server ("postgresql://..." or "postgres://...")
   rather than an SQLite file. */
bool sqldb_is_url(const char *target);

/*
 * Connect to target: a PostgreSQL URL (sqldb_is_url) or an SQLite file
 * path.  SQLite files are created if missing and switched to WAL, with
 * foreign keys on, synchronous FULL and a 5 s busy timeout (a read-only
 * connection: the timeout alone); PostgreSQL connections get a quiet
 * notice channel, and default_transaction_read_only if read-only.  NULL with err
 * set (SF_EIO naming the target, the password part of a URL left out) on
 * failure.  Free with sqldb_close.
 */
struct sqldb *sqldb_open(const char *target, unsigned flags, struct sf_err *err);
void sqldb_close(struct sqldb *db);
enum sqldb_engine sqldb_engine(const struct sqldb *db);
/* The engine's message for the last failure on db ("" if none). */
const char *sqldb_errmsg(const struct sqldb *db);

/* Run sql, one or more statements without parameters or rows. */
int sqldb_exec(struct sqldb *db, const char *sql);
/* BEGIN (SQLite: IMMEDIATE, taking the write lock now), COMMIT, ROLLBACK. */
int sqldb_begin(struct sqldb *db);
int sqldb_commit(struct sqldb *db);
void sqldb_rollback(struct sqldb *db);
/*
 * Whether later commits wait for the disk (the default) or may return
 * before it (SQLite synchronous=NORMAL in WAL, PostgreSQL
 * synchronous_commit=off): such a commit survives the process being killed
 * but may be lost, whole, with the machine.
 */
int sqldb_set_durable(struct sqldb *db, bool durable);
/* Rows the last INSERT, UPDATE or DELETE on db changed. */
int64_t sqldb_changes(const struct sqldb *db);

/* Prepare one statement of sql into *st (free with sqldb_finalize). */
int sqldb_prepare(struct sqldb *db, const char *sql, struct sqldb_stmt **st);
/* Bind parameter i (1-based, as `?N`); text is copied.  Binding an index the statement
   does not have is ignored, as in SQLite. */
void sqldb_bind_int64(struct sqldb_stmt *st, int i, int64_t v);
void sqldb_bind_double(struct sqldb_stmt *st, int i, double v);
void sqldb_bind_text(struct sqldb_stmt *st, int i, const char *text);
void sqldb_bind_null(struct sqldb_stmt *st, int i);
/* Bind len bytes at data as a blob (PostgreSQL: a bytea, sent in binary, not escaped); the
   bytes are copied. */
void sqldb_bind_blob(struct sqldb_stmt *st, int i, const void *data, size_t len);
/* Run or advance st: SQLDB_ROW, SQLDB_DONE, or SF_EIO (message on the connection). */
int sqldb_step(struct sqldb_stmt *st);
/* Column col of the current row (0-based).  NULL reads as 0 and as a NULL text;
   a PostgreSQL boolean reads as 1 or 0.  Text stays valid until the next step. */
int64_t sqldb_column_int64(struct sqldb_stmt *st, int col);
int sqldb_column_int(struct sqldb_stmt *st, int col);
double sqldb_column_double(struct sqldb_stmt *st, int col);
const char *sqldb_column_text(struct sqldb_stmt *st, int col);
bool sqldb_column_null(struct sqldb_stmt *st, int col);
/* Column col of the current row as bytes (a blob; PostgreSQL: a bytea), *len their count;
   NULL (and *len 0) for SQL NULL, or for PostgreSQL out of memory.  Valid until the next
   step or column_blob call on st. */
const void *sqldb_column_blob(struct sqldb_stmt *st, int col, size_t *len);
/* Make st ready to run again; bindings are kept. */
void sqldb_reset(struct sqldb_stmt *st);
void sqldb_finalize(struct sqldb_stmt *st);

#endif
