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
 * A lost connection (sqldb.h) is found by the call that meets it: libpq
 * marks the connection bad, or the server's error says so (SQLSTATE class
 * 08, or 57P01-57P03: shut down, crashed, starting).  A server that closed
 * an idle connection (a restart) is seen before the next statement is
 * sent, by a poll of the socket, so that statement runs on a new session
 * instead of failing.  The connection is then marked lost and ready()
 * decides: fail inside a transaction, else reconnect (PQreset; on an
 * SQLDB_NOWAIT connection PQresetStart, then PQresetPoll a step at each
 * later call, never waiting) when the back-off allows, restoring the
 * session (session(): the lost session ended if the server still runs it,
 * server-side keepalives, read-only, durability, LISTENs) and calling the
 * caller's hook.  The back-off lives here, not in the caller, so every
 * caller of the store gets it.
 *
 * Codes (sqldb.h): a loss is SF_EUNREACH when nothing can have been
 * applied (inside a transaction, a read, before sending), SF_EINDOUBT
 * during a COMMIT or a write outside a transaction; the server's SQLSTATE
 * sorts the rest (code_of).  A writer's BEGIN also reads txid_current() in
 * its round trip, so a COMMIT in doubt is looked up later by txid_status()
 * (pg_commit_outcome).
 *
 * Thread: as sqldb.h.  Every call blocks on the server.
 */
#include "sqldb.h"

#include <libpq-fe.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "../base/clock.h"
#include "../base/mem.h"
#include "sqldb_int.h"

#define PG_PARAMS_MAX 999 /* as SQLite's default; the store's widest statement binds 27 */
#define PG_TEXT_OID   25  /* pg_type's oid of text (catalog/pg_type_d.h, a server header) */

#define PG_BACKOFF_MIN_MS 200  /* the wait after a first failed reconnect */
#define PG_BACKOFF_MAX_MS 5000 /* the longest: a server back is used within 5 s */
/* A writing session's bounds (session()), as SQL literals: a transaction idle that long has
   lost its client (the store's transactions send their statements back to back), and a lock
   not had in that long is busy (retried by the caller) rather than waited for, so a host
   partitioned while holding the event log's lock holds up the others 5 s, not ~25 s. */
#define PG_IDLE_TX_MS   "5000"
#define PG_LOCK_WAIT_MS "5000"

struct pg {
    struct sqldb base;
    PGconn *conn;
    unsigned flags;                 /* sqldb_open's: SQLDB_READONLY is restored */
    bool async_commit;              /* sqldb_set_durable(false) in force: restored */
    bool lost;                      /* the connection is gone: reconnect before use */
    bool reconnecting;              /* restoring a session: a loss now fails, no recursion */
    bool connecting;                /* SQLDB_NOWAIT: a PQresetStart is under way */
    PostgresPollingStatusType poll; /* its last PQresetPoll (what its socket waits for) */
    int64_t connect_ms;             /* clock_mono_ms when it started */
    int64_t connect_timeout_ms;     /* the connection's connect_timeout (0: none) */
    int64_t xid;                    /* the open transaction's id (txid_current), 0 if none */
    bool doubt;                     /* the last write's outcome is unknown (SF_EINDOUBT) */
    int64_t doubt_xid;              /* its transaction's id; 0: it ran outside one */
    int pid;                        /* the server process of this session (pg_backend_pid) */
    char started[64];               /* and its backend_start, as text: together, this session */
    int old_pid;                    /* a lost session the server may still run; 0 if none */
    char old_started[64];
    int backoff_ms;               /* the wait after the next failed attempt; 0: none yet */
    int64_t retry_ms;             /* clock_mono_ms of the next attempt allowed */
    char lost_msg[SQLDB_MSG_MAX]; /* why the connection is away (the server's message) */
    int n_listens;                /* channels LISTENed, re-issued by session() */
    char listens[SQLDB_LISTEN_MAX][SQLDB_CHANNEL_MAX + 1];
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

static int ready(struct pg *p);

static void
pg_close(struct sqldb *db)
{
    PQfinish(conn(db));
    free(db);
}

/* Whether sql only reads, or only touches the session (which a lost connection ends): a
   loss while it ran applied nothing. */
static bool
reads_only(const char *sql)
{
    while (*sql == ' ' || *sql == '\n' || *sql == '(')
        sql++;
    return strncasecmp(sql, "SELECT", 6) == 0 || strncasecmp(sql, "SHOW", 4) == 0 ||
           strncasecmp(sql, "BEGIN", 5) == 0 || strncasecmp(sql, "LISTEN", 6) == 0 ||
           strncasecmp(sql, "SET", 3) == 0 || strncasecmp(sql, "ROLLBACK", 8) == 0;
}

/* The code of a failure the server reported on a live connection (sqldb.h): busy, or not. */
static int
code_of(const PGresult *res)
{
    const char *c = res ? PQresultErrorField(res, PG_DIAG_SQLSTATE) : NULL;
    if (!c)
        return SF_EIO;
    /* serialization failure, deadlock, lock not available, insufficient resources (disk
       full, too many connections), a cancelled statement: the transaction is rolled back
       and a later try may pass */
    if (strcmp(c, "40001") == 0 || strcmp(c, "40P01") == 0 || strcmp(c, "55P03") == 0 ||
        strncmp(c, "53", 2) == 0 || strcmp(c, "57014") == 0)
        return SF_EBUSY;
    return SF_EIO;
}

/* Whether the failure res reports (NULL: none) means the connection is gone. */
static bool
lost_by(struct sqldb *db, const PGresult *res)
{
    if (PQstatus(conn(db)) != CONNECTION_OK)
        return true;
    const char *code = res ? PQresultErrorField(res, PG_DIAG_SQLSTATE) : NULL;
    return code && (strncmp(code, "08", 2) == 0 || strcmp(code, "57P01") == 0 ||
                    strcmp(code, "57P02") == 0 || strcmp(code, "57P03") == 0);
}

/* db's last failure from res (or the connection's message when res has none) while sql ran,
   with its code (sqldb.h); a lost connection is marked so, for ready() to reconnect. */
static int
fail_res(struct sqldb *db, const PGresult *res, const char *sql)
{
    const char *m = res ? PQresultErrorField(res, PG_DIAG_MESSAGE_PRIMARY) : NULL;
    sqldb_fail(db, m ? m : PQerrorMessage(conn(db)));
    if (!lost_by(db, res)) {
        db->code = code_of(res);
        return db->code;
    }
    struct pg *p = (struct pg *)db;
    p->lost = true;
    snprintf(p->lost_msg, sizeof(p->lost_msg), "%s", db->msg);
    if (strcmp(sql, "COMMIT") == 0) { /* sent, perhaps committed: nobody knows */
        p->doubt = true;
        p->doubt_xid = p->xid;
        return sqldb_failf(db, SF_EINDOUBT,
                           "connection lost during COMMIT, whose outcome is unknown: %s",
                           p->lost_msg);
    }
    if (db->in_tx || reads_only(sql)) /* the transaction ends uncommitted with its session */
        return sqldb_failf(db, SF_EUNREACH, "connection lost: %s", p->lost_msg);
    p->doubt = true;
    p->doubt_xid = 0;
    return sqldb_failf(db, SF_EINDOUBT,
                       "connection lost: %s (while a write ran outside a transaction: it may "
                       "have been applied)",
                       p->lost_msg);
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
    struct pg *p = (struct pg *)db;
    int rc = ready(p);
    if (rc)
        return rc;
    /* a writer's transaction learns its id in BEGIN's round trip: a COMMIT lost on the way
       can then be looked up (pg_commit_outcome) */
    bool begin = strcmp(sql, "BEGIN") == 0 && !(p->flags & SQLDB_READONLY);
    db->round_trips++;
    PGresult *res = PQexec(conn(db), begin ? "BEGIN; SELECT txid_current()" : sql);
    ExecStatusType es = PQresultStatus(res);
    if (es != PGRES_COMMAND_OK && es != PGRES_TUPLES_OK) {
        rc = fail_res(db, res, sql);
    } else if (strcmp(sql, "COMMIT") == 0 && strcmp(PQcmdStatus(res), "ROLLBACK") == 0) {
        /* a COMMIT of a transaction a failed statement aborted "succeeds" as a rollback */
        rc = sqldb_fail(db, "the transaction was aborted by an earlier error and rolled back");
    } else {
        count_changes(db, res);
        if (begin)
            p->xid = PQntuples(res) == 1 ? strtoll(PQgetvalue(res, 0, 0), NULL, 10) : 0;
    }
    if (strcmp(sql, "COMMIT") == 0 || strcmp(sql, "ROLLBACK") == 0)
        p->xid = 0;
    PQclear(res);
    return rc;
}

static int
pg_set_durable(struct sqldb *db, bool durable)
{
    /* off: the commit returns before its WAL is flushed; a server crash may
       lose it, whole, never half (PostgreSQL's asynchronous commit) */
    int rc = pg_exec(db, durable ? "SET synchronous_commit = on" : "SET synchronous_commit = off");
    if (rc == SF_OK)
        ((struct pg *)db)->async_commit = !durable;
    return rc;
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
        int rc = ready((struct pg *)base->db);
        if (rc)
            return rc;
        base->db->round_trips++;
        st->res = PQexecParams(conn(base->db), st->sql, st->n_params, st->types,
                               (const char *const *)st->vals, st->lens, st->fmts, 0);
        ExecStatusType es = PQresultStatus(st->res);
        if (es != PGRES_COMMAND_OK && es != PGRES_TUPLES_OK) {
            rc = fail_res(base->db, st->res, st->sql);
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

/* The server's NOTICEs ("relation already exists, skipping") are not the daemon's log. */
static void
quiet(void *arg, const char *message)
{
    (void)arg;
    (void)message;
}

/* Whether p's connection is gone: libpq knows it, or the server closed it while it was
   idle (a restart's "terminating connection" and end of file), seen without a round
   trip.  Reading here also takes in notifications that arrived (PQnotifies). */
static bool
gone(struct pg *p)
{
    for (int i = 0; i < 4 && !p->lost && PQstatus(p->conn) == CONNECTION_OK; i++) {
        struct pollfd pfd = { .fd = PQsocket(p->conn), .events = POLLIN };
        if (poll(&pfd, 1, 0) <= 0)
            return false;
        if (!PQconsumeInput(p->conn))
            break;
    }
    if (!p->lost && PQstatus(p->conn) != CONNECTION_OK) {
        p->lost = true;
        sqldb_fail(&p->base, PQerrorMessage(p->conn));
        snprintf(p->lost_msg, sizeof(p->lost_msg), "%s", p->base.msg);
    }
    return p->lost;
}

/* LISTEN on channel (checked by sqldb.c; quoted, so a keyword is a channel too). */
static int
run_listen(struct pg *p, const char *channel)
{
    char sql[SQLDB_CHANNEL_MAX + 16];
    snprintf(sql, sizeof(sql), "LISTEN \"%s\"", channel);
    return pg_exec(&p->base, sql);
}

/* The first column of sql's one row (n text parameters) as text into out ("" if none);
   SF_OK, or the failure (on the connection). */
static int
one_text(struct pg *p, const char *sql, int n, const char *const *params, char *out, size_t cap)
{
    p->base.round_trips++;
    PGresult *res = PQexecParams(p->conn, sql, n, NULL, params, NULL, NULL, 0);
    int rc = SF_OK;
    if (PQresultStatus(res) != PGRES_TUPLES_OK)
        rc = fail_res(&p->base, res, sql);
    else
        snprintf(out, cap, "%s",
                 PQntuples(res) == 1 && PQnfields(res) >= 1 ? PQgetvalue(res, 0, 0) : "");
    PQclear(res);
    return rc;
}

/* End the session this handle lost, if the server still runs it: a backend whose client
   vanished in a partition keeps its locks and its open transaction until the server's
   keepalives find it; its pid and start time name it, so no other session is touched.
   Without a wait on SQLDB_NOWAIT (the loop): a lock it held may then be free only at the
   next attempt. */
static int
end_old_session(struct pg *p)
{
    if (!p->old_pid)
        return SF_OK;
    char sql[256], pid[16], out[16];
    snprintf(pid, sizeof(pid), "%d", p->old_pid);
    /* OFFSET 0 keeps the subquery whole: only the row that is that session is signalled */
    snprintf(sql, sizeof(sql),
             "SELECT count(pg_terminate_backend(pid%s)) FROM (SELECT pid FROM pg_stat_activity"
             " WHERE pid = $1::int AND backend_start::text = $2 OFFSET 0) a",
             PQserverVersion(p->conn) >= 140000 && !(p->flags & SQLDB_NOWAIT) ? ", 2000" : "");
    const char *params[2] = { pid, p->old_started };
    int rc = one_text(p, sql, 2, params, out, sizeof(out));
    if (rc == SF_EUNREACH || rc == SF_EINDOUBT)
        return rc;  /* lost again: the next session tries */
    p->old_pid = 0; /* ended, gone already, or not ours to end (the server's keepalives will) */
    return SF_OK;
}

/* Set up a new session as the caller left the last: the last one ended, keepalives on the
   server's side, read-only, durability, LISTENs, then the caller's hook
   (sqldb_on_reconnect).  SF_OK, or the failure with the message. */
static int
session(struct pg *p)
{
    struct sqldb *db = &p->base;
    PQsetNoticeProcessor(p->conn, quiet, NULL);
    p->lost = false;
    p->reconnecting = true;
    p->xid = 0;
    /* the server's side of the keepalives (sqldb.h): an orphaned backend ends in ~25 s
       (ignored on a Unix socket).  Not idle_session_timeout: that would end healthy idle
       sessions (a listener, the loop's between passes) and their locks with them. */
    int rc = pg_exec(db, PQserverVersion(p->conn) >= 120000
                             ? "SET tcp_keepalives_idle = 10; SET tcp_keepalives_interval = 5;"
                               " SET tcp_keepalives_count = 3; SET tcp_user_timeout = 10000"
                             : "SET tcp_keepalives_idle = 10; SET tcp_keepalives_interval = 5;"
                               " SET tcp_keepalives_count = 3");
    char ident[128] = "";
    int64_t sent = clock_wall_ms();
    if (rc == SF_OK)
        rc = one_text(p,
                      "SELECT pg_backend_pid() || ' ' || CAST(extract(epoch FROM"
                      " clock_timestamp()) * 1000 AS BIGINT) || ' ' || backend_start::text"
                      " FROM pg_stat_activity WHERE pid = pg_backend_pid()",
                      0, NULL, ident, sizeof(ident));
    /* the server's clock, read halfway through the round trip (sqldb_clock_ms) */
    char *at = strchr(ident, ' ');
    if (rc == SF_OK && at)
        db->clock_offset_ms =
            strtoll(at + 1, NULL, 10) - (sent + clock_wall_ms()) / 2 - db->clock_skew_ms;
    if (rc == SF_OK)
        rc = end_old_session(p);
    if (rc == SF_OK && p->flags & SQLDB_READONLY)
        rc = pg_exec(db, "SET default_transaction_read_only = on");
    /* A writer cut off inside a transaction (a partition: no close reaches the server, and
       its keepalives are answered) held its locks, the event log's among them, for as long
       as the partition lasted: the server now ends it after PG_IDLE_TX_MS, and a writer
       waits PG_LOCK_WAIT_MS for a lock before failing busy (retried: sqldb.h). */
    if (rc == SF_OK && !(p->flags & SQLDB_READONLY))
        rc = pg_exec(db, "SET lock_timeout = " PG_LOCK_WAIT_MS ";"
                         " SET idle_in_transaction_session_timeout = " PG_IDLE_TX_MS);
    if (rc == SF_OK && p->async_commit)
        rc = pg_exec(db, "SET synchronous_commit = off");
    for (int i = 0; rc == SF_OK && i < p->n_listens; i++)
        rc = run_listen(p, p->listens[i]);
    if (rc == SF_OK && db->on_reconnect) {
        struct sf_err err = { 0 };
        if (db->on_reconnect(db, db->on_reconnect_arg, &err) != SF_OK)
            rc = sqldb_failf(db, SF_EUNREACH, "%s", err.msg[0] ? err.msg : "reconnect hook failed");
    }
    char *sp = at ? strchr(at + 1, ' ') : NULL;
    if (rc == SF_OK && sp) { /* this session, to end should it be lost */
        p->pid = (int)strtol(ident, NULL, 10);
        snprintf(p->started, sizeof(p->started), "%s", sp + 1);
    }
    p->reconnecting = false;
    return rc;
}

/* connect_timeout of p's connection in ms (0: none), as libpq reads it (sqldb_pg_open). */
static int64_t
connect_timeout_ms(PGconn *c)
{
    int64_t ms = 0;
    PQconninfoOption *o = PQconninfo(c);
    for (PQconninfoOption *i = o; i && i->keyword; i++)
        if (strcmp(i->keyword, "connect_timeout") == 0 && i->val)
            ms = strtoll(i->val, NULL, 10) * 1000;
    PQconninfoFree(o);
    return ms;
}

/* SQLDB_NOWAIT: start a connect, or take the one under way as far as its socket allows
   without waiting.  1 when connected, 0 when still under way, SF_EIO with the message when
   this attempt failed. */
static int
connect_step(struct pg *p)
{
    struct sqldb *db = &p->base;
    if (!p->connecting) {
        if (!PQresetStart(p->conn))
            return sqldb_fail(db, PQerrorMessage(p->conn));
        p->connecting = true;
        p->poll = PGRES_POLLING_WRITING; /* libpq: as if the last poll said so */
        p->connect_ms = clock_mono_ms();
    }
    for (int i = 0; i < 64 && p->poll != PGRES_POLLING_OK && p->poll != PGRES_POLLING_FAILED; i++) {
        struct pollfd pfd = { .fd = PQsocket(p->conn),
                              .events = p->poll == PGRES_POLLING_READING ? POLLIN : POLLOUT };
        if (pfd.fd < 0 || poll(&pfd, 1, 0) == 0)
            break;
        p->poll = PQresetPoll(p->conn);
    }
    if (p->poll == PGRES_POLLING_OK) {
        p->connecting = false;
        return 1;
    }
    if (p->poll != PGRES_POLLING_FAILED && p->connect_timeout_ms > 0 &&
        clock_mono_ms() - p->connect_ms >= p->connect_timeout_ms) {
        p->connecting = false;
        return sqldb_failf(db, SF_EIO, "connection to server timed out: timeout expired");
    }
    if (p->poll == PGRES_POLLING_FAILED) {
        p->connecting = false;
        return sqldb_fail(db, PQerrorMessage(p->conn));
    }
    return 0;
}

/* A new session for a lost connection, if the back-off allows one now. */
static int
reconnect(struct pg *p)
{
    struct sqldb *db = &p->base;
    if (!p->connecting && clock_mono_ms() < p->retry_ms)
        return sqldb_failf(db, SF_EUNREACH, "database unreachable (retrying): %s", p->lost_msg);
    if (!p->old_pid && p->pid) { /* the session lost: ended at the next one's start */
        p->old_pid = p->pid;
        snprintf(p->old_started, sizeof(p->old_started), "%s", p->started);
        p->pid = 0;
    }
    int rc;
    if (p->flags & SQLDB_NOWAIT) {
        rc = connect_step(p);
        if (rc == 0)
            return sqldb_failf(db, SF_EUNREACH, "database unreachable (retrying): connecting: %s",
                               p->lost_msg);
        rc = rc == 1 ? session(p) : rc;
    } else {
        PQreset(p->conn); /* blocks at most connect_timeout (sqldb_pg_open) */
        rc = PQstatus(p->conn) == CONNECTION_OK ? session(p)
                                                : sqldb_fail(db, PQerrorMessage(p->conn));
    }
    if (rc == SF_OK) {
        p->backoff_ms = 0;
        p->retry_ms = 0;
        db->reconnects++;
        return SF_OK;
    }
    p->lost = true; /* also when the hook refused: the next attempt starts a new session */
    snprintf(p->lost_msg, sizeof(p->lost_msg), "%s", db->msg);
    p->backoff_ms = p->backoff_ms ? p->backoff_ms * 2 : PG_BACKOFF_MIN_MS;
    if (p->backoff_ms > PG_BACKOFF_MAX_MS)
        p->backoff_ms = PG_BACKOFF_MAX_MS;
    p->retry_ms = clock_mono_ms() + p->backoff_ms;
    return sqldb_failf(db, SF_EUNREACH, "database unreachable (retrying): %s", p->lost_msg);
}

/* SF_OK when p's connection can take a statement: as it is, or connected again outside a
   transaction (sqldb.h); else SF_EUNREACH with why. */
static int
ready(struct pg *p)
{
    if (!p->connecting && !gone(p))
        return SF_OK;
    if (p->base.in_tx)
        return sqldb_failf(&p->base, SF_EUNREACH,
                           "connection lost in a transaction, which did not commit: %s",
                           p->lost_msg);
    if (p->reconnecting)
        return sqldb_failf(&p->base, SF_EUNREACH, "connection lost: %s", p->lost_msg);
    return reconnect(p);
}

/* sqldb_commit_outcome (sqldb.h). */
static int
pg_commit_outcome(struct sqldb *db)
{
    struct pg *p = (struct pg *)db;
    if (!p->doubt)
        return 0;
    if (!p->doubt_xid)
        return sqldb_failf(db, SF_EINDOUBT,
                           "the outcome of a write outside a transaction cannot be looked up");
    int rc = ready(p); /* a new session, the lost one ended (session()) */
    char xid[24], st[32];
    snprintf(xid, sizeof(xid), "%lld", (long long)p->doubt_xid);
    if (rc == SF_OK)
        rc = one_text(p, "SELECT coalesce(txid_status($1::bigint), 'unknown')", 1,
                      (const char *const[]){ xid }, st, sizeof(st));
    if (rc)
        return sqldb_failf(db, SF_EINDOUBT, "a commit's outcome is unknown for now: %s", db->msg);
    if (strcmp(st, "committed") == 0 || strcmp(st, "aborted") == 0) {
        p->doubt = false;
        return st[0] == 'c';
    }
    return sqldb_failf(db, SF_EINDOUBT, "transaction %s is %s on the server", xid, st);
}

static int
pg_listen(struct sqldb *db, const char *channel)
{
    struct pg *p = (struct pg *)db;
    for (int i = 0; i < p->n_listens; i++)
        if (strcmp(p->listens[i], channel) == 0)
            return SF_OK;
    if (p->n_listens == SQLDB_LISTEN_MAX)
        return sqldb_failf(db, SF_EINVAL, "listen '%s': already on %d channels", channel,
                           SQLDB_LISTEN_MAX);
    int rc = run_listen(p, channel);
    if (rc == SF_OK)
        snprintf(p->listens[p->n_listens++], sizeof(p->listens[0]), "%s", channel);
    return rc;
}

static int
pg_notify(struct sqldb *db, const char *channel, const char *payload)
{
    int rc = ready((struct pg *)db);
    if (rc)
        return rc;
    const char *vals[2] = { channel, payload };
    db->round_trips++;
    PGresult *res =
        PQexecParams(conn(db), "SELECT pg_notify($1, $2)", 2, NULL, vals, NULL, NULL, 0);
    rc = PQresultStatus(res) == PGRES_TUPLES_OK ? SF_OK : fail_res(db, res, "SELECT pg_notify");
    PQclear(res);
    return rc;
}

static int
pg_notify_fd(struct sqldb *db)
{
    struct pg *p = (struct pg *)db;
    return p->lost ? -1 : PQsocket(p->conn);
}

static int
pg_notifications(struct sqldb *db, sqldb_notify_fn fn, void *arg)
{
    int rc = ready((struct pg *)db); /* reads the socket, and reconnects a lost connection */
    if (rc)
        return rc;
    int n = 0;
    for (PGnotify *nt; (nt = PQnotifies(conn(db))); PQfreemem(nt), n++)
        fn(arg, nt->relname, nt->extra);
    return n;
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
    .listen = pg_listen,
    .notify = pg_notify,
    .notify_fd = pg_notify_fd,
    .notifications = pg_notifications,
    .commit_outcome = pg_commit_outcome,
};

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

/* A failed connect's code: SF_EIO when the server answered and refused (a password, a role
   or database that does not exist: libpq's "FATAL:"), which trying again does not mend;
   SF_EUNREACH when it could not be reached (refused, timed out, no socket, no host) or said
   "not now" (starting up, shutting down, out of connection slots, the database closed to
   connections for an operator's maintenance: ALLOW_CONNECTIONS false). */
static int
connect_code(const char *msg)
{
    static const char *const passing[] = {
        "starting up", "shutting down",        "in recovery",
        "too many",    "connection slots are", "not currently accepting connections"
    };
    if (!strstr(msg, "FATAL:"))
        return SF_EUNREACH;
    for (size_t i = 0; i < sizeof(passing) / sizeof(passing[0]); i++)
        if (strstr(msg, passing[i]))
            return SF_EUNREACH;
    return SF_EIO;
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
    p->flags = flags;
    p->base.clock_skew_ms = sqldb_test_skew_ms(); /* before the session reads the server's */
    /* Bounds on waiting for the network (sqldb.h), before the URL so that its own
       settings win (libpq: later keywords override earlier; dbname expands the URL).
       keepalives and tcp_user_timeout apply to TCP only. */
    static const char *const keys[] = { "connect_timeout",
                                        "keepalives_idle",
                                        "keepalives_interval",
                                        "keepalives_count",
                                        "tcp_user_timeout",
                                        "dbname",
                                        NULL };
    const char *vals[] = { "5", "10", "5", "3", "10000", url, NULL };
    p->conn = PQconnectdbParams(keys, vals, 1);
    if (!p->conn || PQstatus(p->conn) != CONNECTION_OK) {
        sqldb_fail(&p->base, p->conn ? PQerrorMessage(p->conn) : "out of memory");
        sf_err_set(err, p->conn ? connect_code(p->base.msg) : SF_ENOMEM,
                   "store: cannot connect to '%s': %s", shown, p->base.msg);
        pg_close(&p->base);
        return NULL;
    }
    p->connect_timeout_ms = connect_timeout_ms(p->conn);
    int rc = session(p);
    if (rc) {
        sf_err_set(err, rc, "store: '%s': %s", shown, p->base.msg);
        pg_close(&p->base);
        return NULL;
    }
    return &p->base;
}
