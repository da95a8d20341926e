/*
 * sqldb_pg.c - sqldb.h's PostgreSQL driver, on libpq.
 *
 * A statement keeps its SQL with the `?`/`?N` placeholders rewritten to
 * PostgreSQL's `$N` (outside quoted strings and names; a bare `?` takes
 * the next number after the highest so far, as SQLite numbers it) and its
 * parameters as text, but for blobs, sent in binary (a bytea's text form
 * would double it).  The first step runs it (PQexecParams, text out) and
 * holds the whole result; later steps walk its rows.  Parameters
 * the SQL never names are sent typed as text, so a statement whose
 * optional clauses are left out (store_job_page) still binds by the same
 * numbers.  No server-side prepared statements: the store prepares each
 * statement once per call, and a round trip is what they would save.
 *
 * Thread: as sqldb.h.  Every call blocks on the server.
 */
#include "sqldb.h"

#include <libpq-fe.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"
#include "sqldb_int.h"

#define PG_PARAMS_MAX 999 /* as SQLite's default; the store's widest statement binds 27 */
#define PG_TEXT_OID   25  /* pg_type's oid of text (catalog/pg_type_d.h, a server header) */

struct pg {
    struct sqldb base;
    PGconn *conn;
};

struct pg_stmt {
    struct sqldb_stmt base;
    char *sql;       /* with $N placeholders */
    int n_params;    /* the highest N */
    char **vals;     /* n_params texts, NULL for SQL NULL; owned */
    Oid *types;      /* 0: the server infers it; text for one the SQL never names */
    int *lens;       /* n_params byte counts, NULL until a blob is bound (pg_bind_blob) */
    int *fmts;       /* n_params formats (1: binary, a blob's; 0: text), NULL as lens */
    void *blob;      /* the last column_blob's bytes (PQunescapeBytea's: PQfreemem) */
    bool oom;        /* a bind ran out of memory: the step fails */
    PGresult *res;   /* once run */
    int row, n_rows; /* the current row of res */
};

static PGconn *
conn(struct sqldb *db)
{
    return ((struct pg *)db)->conn;
}

static void
pg_close(struct sqldb *db)
{
    PQfinish(conn(db));
    free(db);
}

/* db's last failure from res (or the connection's message when res has none). */
static int
fail_res(struct sqldb *db, const PGresult *res)
{
    const char *m = res ? PQresultErrorField(res, PG_DIAG_MESSAGE_PRIMARY) : NULL;
    return sqldb_fail(db, m ? m : PQerrorMessage(conn(db)));
}

/* Rows a finished command changed: INSERT, UPDATE and DELETE only, as SQLite counts. */
static void
count_changes(struct sqldb *db, PGresult *res)
{
    const char *cmd = PQcmdStatus(res);
    if (strncmp(cmd, "INSERT", 6) == 0 || strncmp(cmd, "UPDATE", 6) == 0 ||
        strncmp(cmd, "DELETE", 6) == 0)
        db->changes = strtoll(PQcmdTuples(res), NULL, 10);
}

static int
pg_exec(struct sqldb *db, const char *sql)
{
    PGresult *res = PQexec(conn(db), sql);
    ExecStatusType es = PQresultStatus(res);
    int rc = SF_OK;
    if (es != PGRES_COMMAND_OK && es != PGRES_TUPLES_OK)
        rc = fail_res(db, res);
    else if (strcmp(sql, "COMMIT") == 0 && strcmp(PQcmdStatus(res), "ROLLBACK") == 0)
        /* a COMMIT of a transaction a failed statement aborted "succeeds" as a rollback */
        rc = sqldb_fail(db, "the transaction was aborted by an earlier error and rolled back");
    else
        count_changes(db, res);
    PQclear(res);
    return rc;
}

static int
pg_set_durable(struct sqldb *db, bool durable)
{
    /* off: the commit returns before its WAL is flushed; a server crash may
       lose it, whole, never half (PostgreSQL's asynchronous commit) */
    return pg_exec(db, durable ? "SET synchronous_commit = on" : "SET synchronous_commit = off");
}

/* Copy the quoted run at sql (quote q) to *out; returns the length copied. */
static size_t
copy_quoted(const char *sql, char **out)
{
    char q = sql[0];
    size_t i = 1;
    while (sql[i] && sql[i] != q)
        i++;
    if (sql[i])
        i++;
    memcpy(*out, sql, i);
    *out += i;
    return i;
}

/* Rewrite sql's ?/?N to $N into st; NULL sql in st when out of memory, SF_EINVAL
   for a number out of range. */
static int
translate(struct pg_stmt *st, const char *sql, bool *named)
{
    size_t len = strlen(sql), n_q = 0;
    for (size_t i = 0; i < len; i++)
        n_q += sql[i] == '?';
    if (!(st->sql = mem_alloc(len + n_q * 4 + 1)))
        return SF_ENOMEM;
    char *o = st->sql;
    int top = 0;
    for (size_t i = 0; i < len;) {
        if (sql[i] == '\'' || sql[i] == '"') {
            i += copy_quoted(sql + i, &o);
            continue;
        }
        if (sql[i] != '?') {
            *o++ = sql[i++];
            continue;
        }
        int n = 0;
        size_t j = i + 1;
        while (sql[j] >= '0' && sql[j] <= '9' && n <= PG_PARAMS_MAX)
            n = n * 10 + (sql[j++] - '0');
        if (j == i + 1)
            n = top + 1;
        if (n < 1 || n > PG_PARAMS_MAX)
            return SF_EINVAL;
        named[n] = true;
        top = n > top ? n : top;
        o += snprintf(o, 5, "$%d", n); /* "$999": room for 3 more bytes than each ? */
        i = j;
    }
    *o = '\0';
    st->n_params = top;
    return SF_OK;
}

static void pg_finalize(struct sqldb_stmt *st);

static int
pg_prepare(struct sqldb *db, const char *sql, struct sqldb_stmt **out)
{
    struct pg_stmt *st = mem_calloc(1, sizeof(*st));
    bool *named = mem_calloc(PG_PARAMS_MAX + 1, sizeof(*named));
    if (!st || !named) {
        free(st);
        free(named);
        return SF_ENOMEM;
    }
    st->base.db = db;
    int rc = translate(st, sql, named);
    if (rc == SF_OK && st->n_params > 0) {
        st->vals = mem_calloc((size_t)st->n_params, sizeof(*st->vals));
        st->types = mem_calloc((size_t)st->n_params, sizeof(*st->types));
        if (!st->vals || !st->types)
            rc = SF_ENOMEM;
        for (int i = 0; rc == SF_OK && i < st->n_params; i++)
            st->types[i] = named[i + 1] ? 0 : PG_TEXT_OID;
    }
    free(named);
    if (rc) {
        sqldb_fail(db, rc == SF_EINVAL ? "parameter number out of range" : "out of memory");
        pg_finalize(&st->base);
        return rc;
    }
    *out = &st->base;
    return SF_OK;
}

static void
bind_owned(struct sqldb_stmt *base, int i, char *val, bool want)
{
    struct pg_stmt *st = (struct pg_stmt *)base;
    if (i < 1 || i > st->n_params) {
        free(val); /* as SQLite: an index the statement lacks is ignored */
        return;
    }
    free(st->vals[i - 1]);
    st->vals[i - 1] = val;
    if (st->fmts)
        st->fmts[i - 1] = 0; /* text, until pg_bind_blob says otherwise */
    if (want && !val)
        st->oom = true;
}

static void
pg_bind_int64(struct sqldb_stmt *st, int i, int64_t v)
{
    char buf[24];
    snprintf(buf, sizeof(buf), "%lld", (long long)v);
    bind_owned(st, i, mem_strdup(buf), true);
}

static void
pg_bind_double(struct sqldb_stmt *st, int i, double v)
{
    char buf[32];
    snprintf(buf, sizeof(buf), "%.17g", v); /* round-trips every double */
    bind_owned(st, i, mem_strdup(buf), true);
}

static void
pg_bind_text(struct sqldb_stmt *st, int i, const char *text)
{
    bind_owned(st, i, mem_strdup(text), true);
}

static void
pg_bind_null(struct sqldb_stmt *st, int i)
{
    bind_owned(st, i, NULL, false);
}

static void
pg_bind_blob(struct sqldb_stmt *base, int i, const void *data, size_t len)
{
    struct pg_stmt *st = (struct pg_stmt *)base;
    if (i < 1 || i > st->n_params)
        return;
    if (len > INT32_MAX) { /* libpq's lengths are int; a bytea holds at most 1 GB anyway */
        st->oom = true;
        return;
    }
    if (!st->lens)
        st->lens = mem_calloc((size_t)st->n_params, sizeof(*st->lens));
    if (!st->fmts)
        st->fmts = mem_calloc((size_t)st->n_params, sizeof(*st->fmts));
    if (!st->lens || !st->fmts) {
        st->oom = true;
        return;
    }
    char *copy = mem_alloc(len ? len : 1);
    if (copy && len)
        memcpy(copy, data, len);
    bind_owned(base, i, copy, true);
    st->lens[i - 1] = (int)len;
    st->fmts[i - 1] = 1;
}

static int
pg_step(struct sqldb_stmt *base)
{
    struct pg_stmt *st = (struct pg_stmt *)base;
    if (!st->res) {
        if (st->oom)
            return sqldb_fail(base->db, "out of memory binding a parameter");
        st->res = PQexecParams(conn(base->db), st->sql, st->n_params, st->types,
                               (const char *const *)st->vals, st->lens, st->fmts, 0);
        ExecStatusType es = PQresultStatus(st->res);
        if (es != PGRES_COMMAND_OK && es != PGRES_TUPLES_OK) {
            int rc = fail_res(base->db, st->res);
            PQclear(st->res);
            st->res = NULL;
            return rc;
        }
        count_changes(base->db, st->res);
        st->n_rows = PQntuples(st->res);
        st->row = -1;
    }
    if (st->row + 1 < st->n_rows) {
        st->row++;
        return SQLDB_ROW;
    }
    st->row = st->n_rows;
    return SQLDB_DONE;
}

/* The current row's col as text; NULL for SQL NULL or no such row or column. */
static const char *
value(struct sqldb_stmt *base, int col)
{
    struct pg_stmt *st = (struct pg_stmt *)base;
    if (!st->res || st->row < 0 || st->row >= st->n_rows || col < 0 || col >= PQnfields(st->res) ||
        PQgetisnull(st->res, st->row, col))
        return NULL;
    return PQgetvalue(st->res, st->row, col);
}

static int64_t
pg_column_int64(struct sqldb_stmt *st, int col)
{
    const char *v = value(st, col);
    if (!v)
        return 0;
    if ((v[0] == 't' || v[0] == 'f') && !v[1]) /* a boolean */
        return v[0] == 't';
    /* a numeric ("2.0", a sum) reads as its integer part, as SQLite converts a real */
    return strchr(v, '.') || strchr(v, 'e') ? (int64_t)strtod(v, NULL) : strtoll(v, NULL, 10);
}

static double
pg_column_double(struct sqldb_stmt *st, int col)
{
    const char *v = value(st, col);
    if (!v)
        return 0;
    if ((v[0] == 't' || v[0] == 'f') && !v[1])
        return v[0] == 't';
    return strtod(v, NULL);
}

static const char *
pg_column_text(struct sqldb_stmt *st, int col)
{
    return value(st, col);
}

static bool
pg_column_null(struct sqldb_stmt *st, int col)
{
    return value(st, col) == NULL;
}

static const void *
pg_column_blob(struct sqldb_stmt *base, int col, size_t *len)
{
    struct pg_stmt *st = (struct pg_stmt *)base;
    *len = 0;
    PQfreemem(st->blob);
    st->blob = NULL;
    const char *v = value(base, col);
    /* results come as text: a bytea in its escaped form (hex by default), which libpq decodes */
    if (v)
        st->blob = PQunescapeBytea((const unsigned char *)v, len);
    return st->blob;
}

static void
pg_reset(struct sqldb_stmt *base)
{
    struct pg_stmt *st = (struct pg_stmt *)base;
    PQclear(st->res);
    st->res = NULL;
}

static void
pg_finalize(struct sqldb_stmt *base)
{
    struct pg_stmt *st = (struct pg_stmt *)base;
    PQclear(st->res);
    for (int i = 0; st->vals && i < st->n_params; i++)
        free(st->vals[i]);
    free(st->vals);
    free(st->types);
    free(st->lens);
    free(st->fmts);
    PQfreemem(st->blob);
    free(st->sql);
    free(st);
}

static const struct sqldb_ops pg_ops = {
    .engine = SQLDB_PG,
    .close = pg_close,
    .exec = pg_exec,
    .begin_sql = "BEGIN",
    .set_durable = pg_set_durable,
    .prepare = pg_prepare,
    .bind_int64 = pg_bind_int64,
    .bind_double = pg_bind_double,
    .bind_text = pg_bind_text,
    .bind_null = pg_bind_null,
    .bind_blob = pg_bind_blob,
    .step = pg_step,
    .column_int64 = pg_column_int64,
    .column_double = pg_column_double,
    .column_text = pg_column_text,
    .column_null = pg_column_null,
    .column_blob = pg_column_blob,
    .reset = pg_reset,
    .finalize = pg_finalize,
};

/* The server's NOTICEs ("relation already exists, skipping") are not the daemon's log. */
static void
quiet(void *arg, const char *message)
{
    (void)arg;
    (void)message;
}

/* url for messages: a password in it (postgresql://user:secret@host, ?password=secret or a
   conninfo's password=secret) shown as "***" or "*". */
static void
show_url(const char *url, char *out, size_t cap)
{
    const char *auth = strstr(url, "://");
    auth = auth ? auth + 3 : url;
    const char *at = strchr(auth, '@'), *colon = strchr(auth, ':');
    if (at && colon && colon < at && !memchr(auth, '/', (size_t)(at - auth)))
        snprintf(out, cap, "%.*s***%s", (int)(colon + 1 - url), url, at);
    else
        snprintf(out, cap, "%s", url);
    /* a password= value: its first byte kept as '*', the rest dropped (shortens, never grows) */
    for (char *pw = strstr(out, "password="); pw; pw = strstr(pw, "password=")) {
        pw += strlen("password=");
        size_t n = strcspn(pw, "& ");
        if (n) {
            *pw = '*';
            memmove(pw + 1, pw + n, strlen(pw + n) + 1);
        }
    }
}

struct sqldb *
sqldb_pg_open(const char *url, unsigned flags, struct sf_err *err)
{
    char shown[256];
    show_url(url, shown, sizeof(shown));
    struct pg *p = mem_calloc(1, sizeof(*p));
    if (!p) {
        sf_err_set(err, SF_ENOMEM, "postgresql: out of memory");
        return NULL;
    }
    p->base.ops = &pg_ops;
    p->conn = PQconnectdb(url);
    if (!p->conn || PQstatus(p->conn) != CONNECTION_OK) {
        sqldb_fail(&p->base, p->conn ? PQerrorMessage(p->conn) : "out of memory");
        sf_err_set(err, SF_EIO, "store: cannot connect to '%s': %s", shown, p->base.msg);
        pg_close(&p->base);
        return NULL;
    }
    PQsetNoticeProcessor(p->conn, quiet, NULL);
    if (flags & SQLDB_READONLY && pg_exec(&p->base, "SET default_transaction_read_only = on")) {
        sf_err_set(err, SF_EIO, "store: '%s': %s", shown, p->base.msg);
        pg_close(&p->base);
        return NULL;
    }
    return &p->base;
}
