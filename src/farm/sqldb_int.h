/*
 * sqldb_int.h - internal to the sqldb module (sqldb.c and its drivers
 * sqldb_sqlite.c, sqldb_pg.c): the driver table sqldb.c dispatches
 * through, after SQLite's own VFS table.  A driver's connection and
 * statement structs begin with struct sqldb and struct sqldb_stmt.
 *
 * Thread: as sqldb.h.
 */
#ifndef SF_FARM_SQLDB_INT_H
#define SF_FARM_SQLDB_INT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"
#include "sqldb.h"

#define SQLDB_MSG_MAX 256

struct sqldb_ops {
    enum sqldb_engine engine;
    void (*close)(struct sqldb *db);
    int (*exec)(struct sqldb *db, const char *sql);
    const char *begin_sql; /* what sqldb_begin runs */
    int (*set_durable)(struct sqldb *db, bool durable);
    int (*prepare)(struct sqldb *db, const char *sql, struct sqldb_stmt **st);
    void (*bind_int64)(struct sqldb_stmt *st, int i, int64_t v);
    void (*bind_double)(struct sqldb_stmt *st, int i, double v);
    void (*bind_text)(struct sqldb_stmt *st, int i, const char *text);
    void (*bind_null)(struct sqldb_stmt *st, int i);
    void (*bind_blob)(struct sqldb_stmt *st, int i, const void *data, size_t len);
    int (*step)(struct sqldb_stmt *st);
    int64_t (*column_int64)(struct sqldb_stmt *st, int col);
    double (*column_double)(struct sqldb_stmt *st, int col);
    const char *(*column_text)(struct sqldb_stmt *st, int col);
    bool (*column_null)(struct sqldb_stmt *st, int col);
    const void *(*column_blob)(struct sqldb_stmt *st, int col, size_t *len);
    void (*reset)(struct sqldb_stmt *st);
    void (*finalize)(struct sqldb_stmt *st);
    /* LISTEN/NOTIFY (sqldb.h), the channel checked already; NULL: a no-op (SQLite) */
    int (*listen)(struct sqldb *db, const char *channel);
    int (*notify)(struct sqldb *db, const char *channel, const char *payload);
    int (*notify_fd)(struct sqldb *db);
    int (*notifications)(struct sqldb *db, sqldb_notify_fn fn, void *arg);
    /* sqldb_commit_outcome; NULL: nothing is ever in doubt (SQLite) */
    int (*commit_outcome)(struct sqldb *db);
};

struct sqldb {
    const struct sqldb_ops *ops;
    char msg[SQLDB_MSG_MAX];         /* the last failure's message */
    int code;                        /* the last call's failure (sqldb_errcode), SF_OK if none */
    int64_t changes;                 /* rows the last write changed */
    bool in_tx;                      /* between a sqldb_begin and its commit or rollback */
    int64_t reconnects;              /* successful reconnects (sqldb_reconnects) */
    int64_t round_trips;             /* statements sent to a server (sqldb_round_trips) */
    int64_t clock_offset_ms;         /* the server's clock less this process's (sqldb_clock_ms) */
    int64_t clock_skew_ms;           /* SLIMFARM_TEST_CLOCK_SKEW_MS at open: tests only */
    sqldb_reconnect_fn on_reconnect; /* sqldb_on_reconnect's; NULL if none */
    void *on_reconnect_arg;
};

struct sqldb_stmt {
    struct sqldb *db;
};

/* SLIMFARM_TEST_CLOCK_SKEW_MS (0 unset): a connection's clock_skew_ms (sqldb_clock_ms). */
int64_t sqldb_test_skew_ms(void);

/* The drivers' open functions (sqldb_open picks one); NULL with err set. */
struct sqldb *sqldb_sqlite_open(const char *path, unsigned flags, struct sf_err *err);
struct sqldb *sqldb_pg_open(const char *url, unsigned flags, struct sf_err *err);
/* Keep msg (cut to fit, without a trailing newline) as db's last failure, code SF_EIO;
   returns SF_EIO. */
int sqldb_fail(struct sqldb *db, const char *msg);
/* As sqldb_fail with a format and code (kept for sqldb_errcode); returns code. */
int sqldb_failf(struct sqldb *db, int code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

#endif
