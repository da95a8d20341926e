/*
 * tstore.h - the database a unit test's store runs on.  Unset, a store
 * is SQLite in its data dir, as the daemon's; with SLIMFARM_TEST_STORE a
 * PostgreSQL URL (tests/integ/lib/pg.sh starts a server and sets it), each
 * data dir gets a fresh database of its own on that server, so the same
 * cases run on both engines (tests/integ/store_pg.sh, make check-pg).
 *
 *     struct store *s = t_store_open(dir, NULL, &err);
 *
 * Header-only: tests/t.c stays free of the store.  One thread.
 */
#ifndef SF_TESTS_TSTORE_H
#define SF_TESTS_TSTORE_H

#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../src/farm/sqldb.h"
#include "../src/farm/store.h"
#include "../src/farm/store_host.h"

/* Whether the stores of this run are PostgreSQL. */
static inline bool
t_store_pg(void)
{
    const char *u = getenv("SLIMFARM_TEST_STORE");
    return u && u[0];
}

/*
 * The database for data dir dir: NULL for SQLite, else the URL of a
 * database named for dir on SLIMFARM_TEST_STORE's server, created on
 * first use (a forked child finds its parent's).  Valid until the next
 * call.  Exits the program when the server cannot make it: no case may
 * pass on the wrong engine.
 */
static inline const char *
t_store_db(const char *dir)
{
    static char url[1024], last[512]; /* the last dir's: made already, nothing to allocate
                                         (store_survives_allocation_failures fails mem.h) */
    const char *base = getenv("SLIMFARM_TEST_STORE");
    if (!base || !base[0])
        return NULL;
    uint64_t h = 1469598103934665603u; /* FNV-1a of the dir: unique per mktemp'd dir */
    for (const char *p = dir; *p; p++)
        h = (h ^ (unsigned char)*p) * 1099511628211u;
    char name[32];
    snprintf(name, sizeof(name), "sft_%016llx", (unsigned long long)h);
    /* postgresql://AUTH[/DB][?QUERY] -> postgresql://AUTH/name[?QUERY] */
    const char *auth = strstr(base, "://");
    auth = auth ? auth + 3 : base;
    size_t a = strcspn(auth, "/?");
    const char *query = strchr(auth + a, '?');
    snprintf(url, sizeof(url), "%.*s/%s%s", (int)(auth + a - base), base, name, query ? query : "");
    if (strcmp(last, dir) == 0)
        return url;
    struct sf_err err;
    struct sqldb *db = sqldb_open(base, 0, &err);
    char sql[64];
    snprintf(sql, sizeof(sql), "CREATE DATABASE %s", name);
    if (!db || (sqldb_exec(db, sql) && !strstr(sqldb_errmsg(db), "already exists"))) {
        fprintf(stderr, "tstore: cannot create database %s on %s: %s\n", name, base,
                db ? sqldb_errmsg(db) : err.msg);
        exit(2);
    }
    sqldb_close(db);
    snprintf(last, sizeof(last), "%s", dir);
    return url;
}

/* store_open for a test: on the run's engine (t_store_db). */
static inline struct store *
t_store_open(const char *dir, struct store_recovery *rec, struct sf_err *err)
{
    return store_open_db(dir, t_store_db(dir), rec, err);
}

/* A connection to the database of dir's store, either engine (sqldb_close it). */
static inline struct sqldb *
t_store_sqldb(const char *dir)
{
    char path[1100];
    const char *db = t_store_db(dir);
    snprintf(path, sizeof(path), "%s/slimfarm.db", dir);
    struct sf_err err;
    return sqldb_open(db ? db : path, 0, &err);
}

/* The first column of sql's first row on dir's store as an integer; -1 on any failure. */
static inline int64_t
t_store_int(const char *dir, const char *sql)
{
    struct sqldb *db = t_store_sqldb(dir);
    struct sqldb_stmt *st;
    int64_t v = -1;
    if (db && sqldb_prepare(db, sql, &st) == SF_OK) {
        if (sqldb_step(st) == SQLDB_ROW)
            v = sqldb_column_int64(st, 0);
        sqldb_finalize(st);
    }
    sqldb_close(db);
    return v;
}

/* Run sql on dir's store; SF_OK or SF_EIO. */
static inline int
t_store_exec(const char *dir, const char *sql)
{
    struct sqldb *db = t_store_sqldb(dir);
    int rc = db ? sqldb_exec(db, sql) : SF_EIO;
    sqldb_close(db);
    return rc;
}

/*
 * Another process's hold on dir's store, either engine: a second connection with its write
 * lock taken (NULL when it cannot).  SQLite: BEGIN IMMEDIATE on the file.  PostgreSQL: every
 * table of the store locked EXCLUSIVE in one transaction, as SQLite's write lock holds the
 * whole file: reads go on, a write waits out the store's lock_timeout and fails busy.
 * t_store_unlock lets it go.
 */
static inline struct sqldb *
t_store_lock(const char *dir)
{
    struct sqldb *db = t_store_sqldb(dir);
    /* (held idle: the store's sessions end an idle transaction after 5 s, sqldb_pg.c) */
    if (db && ((t_store_pg() && sqldb_exec(db, "SET idle_in_transaction_session_timeout = 0")) ||
               sqldb_begin(db) ||
               (t_store_pg() &&
                sqldb_exec(db, "DO $$ DECLARE t text; BEGIN"
                               " FOR t IN SELECT tablename FROM pg_tables WHERE schemaname ="
                               " current_schema() LOOP"
                               " EXECUTE format('LOCK TABLE %I IN EXCLUSIVE MODE', t);"
                               " END LOOP; END $$")))) {
        fprintf(stderr, "tstore: cannot lock %s: %s\n", dir, sqldb_errmsg(db));
        sqldb_close(db);
        return NULL;
    }
    return db;
}

static inline void
t_store_unlock(struct sqldb *db)
{
    if (!db)
        return;
    sqldb_rollback(db);
    sqldb_close(db);
}

/* Two hosts' stores on one database: a on dir, b on dir-b (on SQLite b is a peer of a: one
   process holds the data dir).  ta, tb: their join tokens, for the tests that join. */
struct t_pair {
    char dir[512], dir_b[512], url[1024];
    struct store *a, *b;
    int64_t ta, tb;
};

/* Open p's two stores on dir (its database: t_store_db); false with err set if not. */
static inline bool
t_pair_open(struct t_pair *p, const char *dir, struct sf_err *err)
{
    snprintf(p->dir, sizeof(p->dir), "%s", dir);
    snprintf(p->dir_b, sizeof(p->dir_b), "%.500s-b", p->dir);
    const char *db = t_store_db(p->dir);
    snprintf(p->url, sizeof(p->url), "%s", db ? db : "");
    p->a = store_open_host(p->dir, db, NULL, err);
    p->b = !p->a ? NULL
           : db  ? store_open_host(p->dir_b, p->url, NULL, err)
                 : store_open_peer(p->a, err);
    return p->a && p->b;
}

static inline void
t_pair_close(struct t_pair *p)
{
    store_close(p->b);
    store_close(p->a);
}

#endif
