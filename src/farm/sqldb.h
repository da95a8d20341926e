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
 * Errors: functions return SF_OK or a code that says what a caller may do
 * (SF_ENOMEM for memory), and leave the engine's message on the handle
 * (sqldb_errmsg), as sqlite3 does; the store wraps both into its sf_err
 * (sqldb_errcode):
 *   SF_EBUSY     busy: SQLite's lock, PostgreSQL's serialization failure,
 *                deadlock, lock not available, insufficient resources, a
 *                cancelled statement.  Nothing was applied (a transaction that
 *                met it is rolled back): try it again, whole, later.
 *   SF_EUNREACH  the connection is lost or not back yet ("connection lost",
 *                "database unreachable (retrying)") and nothing was applied:
 *                the statement was not sent, or its transaction did not commit.
 *   SF_EINDOUBT  the connection was lost while a COMMIT (or a write outside a
 *                transaction) ran: it may have been applied.  Not to be retried
 *                blindly: ask sqldb_commit_outcome, or make the write idempotent.
 *   SF_EIO       anything else: a constraint, invalid input (a byte sequence
 *                the database's encoding refuses), SQL the engine rejects, a
 *                damaged file.  Trying again gives the same answer.
 *
 * A PostgreSQL connection can be lost (the server restarts, the network
 * parts); sqldb_on_reconnect below says what then.  LISTEN/NOTIFY, which
 * wakes the other hosts on one database, is sqldb_listen and its friends.
 *
 * Thread: a connection and its statements are used by one thread at a
 * time.  Calls block until the engine answers (for PostgreSQL: the
 * network, bounded as sqldb_on_reconnect says); nothing here is for a
 * loop that must not wait.
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
#define SQLDB_NOWAIT   2u /* PostgreSQL: a reconnect never waits (the loop's connection) */

/* Whether target names a PostgreSQL server ("postgresql://..." or "postgres://...")
   rather than an SQLite file. */
bool sqldb_is_url(const char *target);

/*
 * Connect to target: a PostgreSQL URL (sqldb_is_url) or an SQLite file
 * path.  SQLite files are created if missing and switched to WAL, with
 * foreign keys on, synchronous FULL and a 5 s busy timeout (a read-only
 * connection: the timeout alone); PostgreSQL connections get a quiet
 * notice channel, and default_transaction_read_only if read-only.  NULL with err
 * set on failure, naming the target (the password part of a URL left out):
 * SF_EUNREACH when the server cannot be reached or says "not now" (starting,
 * stopping, no connection slot left: try again later), SF_EIO when it
 * refuses (a password, an unknown role or database) or the file cannot be
 * opened.  Free with sqldb_close.
 */
struct sqldb *sqldb_open(const char *target, unsigned flags, struct sf_err *err);
void sqldb_close(struct sqldb *db);
enum sqldb_engine sqldb_engine(const struct sqldb *db);
/* The engine's message for the last failure on db ("" if none). */
const char *sqldb_errmsg(const struct sqldb *db);
/* The code of the last call's failure (above); SF_EIO when that call did not fail (a caller
   that found something else wrong, an unexpected row). */
int sqldb_errcode(const struct sqldb *db);

/* Run sql, one or more statements without parameters or rows. */
int sqldb_exec(struct sqldb *db, const char *sql);
/* BEGIN (SQLite: IMMEDIATE, taking the write lock now), COMMIT, ROLLBACK.  A COMMIT that
   fails is rolled back; ROLLBACK outside a transaction does nothing (it never reconnects). */
int sqldb_begin(struct sqldb *db);
int sqldb_commit(struct sqldb *db);
void sqldb_rollback(struct sqldb *db);
/*
 * After a write failed with SF_EINDOUBT: whether it was applied.  1: the
 * transaction committed; 0: it did not (nothing applied: run it again);
 * < 0, message on db: still unknown (SF_EINDOUBT; the server cannot be
 * asked now, or the write ran outside a transaction and left nothing to
 * look up): ask again later, as long as the caller's patience lasts.
 * PostgreSQL: BEGIN takes the transaction's id (txid_current(), in the same
 * round trip); this asks txid_status() on a new session, first ending this
 * handle's last session if the server still runs it (pg_terminate_backend
 * of that pid and start time: its transaction is then settled, and its
 * session locks freed).  SQLite: always 0 (a local commit is never in doubt).
 */
int sqldb_commit_outcome(struct sqldb *db);
/*
 * Whether later commits wait for the disk (the default) or may return
 * before it (SQLite synchronous=NORMAL in WAL, PostgreSQL
 * synchronous_commit=off): such a commit survives the process being killed
 * but may be lost, whole, with the machine.
 */
int sqldb_set_durable(struct sqldb *db, bool durable);
/* Rows the last INSERT, UPDATE or DELETE on db changed. */
int64_t sqldb_changes(const struct sqldb *db);

/*
 * Lost connections (PostgreSQL only: an SQLite file is never lost).  The
 * call that finds the connection gone fails with SF_EIO and "connection
 * lost: " and the server's message.  The next call outside a transaction
 * connects again (libpq's PQreset: same URL, a new server session); if
 * that fails, attempts are spaced 0.2 s after the first failure, doubling
 * to 5 s, and every call in between fails at once with "database
 * unreachable (retrying): " and the last attempt's message, so a caller
 * that keeps calling neither waits nor hammers the server.  One attempt
 * waits at most connect_timeout (5 s unless the URL sets it); TCP
 * keepalives (10 s idle, then 3 probes 5 s apart) and tcp_user_timeout
 * (10 s) find a silent network partition, unless the URL sets them.  The
 * server's side of each session gets the same keepalives and user timeout
 * (SET per session), so a backend whose client vanished in a partition
 * ends within about 25 s and frees its session's advisory locks, instead
 * of after the kernel's two hours.  A writing session (not SQLDB_READONLY)
 * also gets idle_in_transaction_session_timeout and lock_timeout of 5 s:
 * one cut off inside a transaction (a partition whose packets are still
 * answered) is ended by the server after 5 s, freeing its locks (the event
 * log's lock, which every event's transaction takes); a statement that
 * waits 5 s for a lock fails SF_EBUSY ("lock timeout"), to be tried again.
 *
 * SQLDB_NOWAIT (a connection on the loop): no call waits for a connect.
 * The call that finds the loss starts one (PQresetStart) and it and every
 * later call until the new session is up fail at once with "database
 * unreachable (retrying): connecting ...", each advancing the connect as
 * far as it goes without waiting (PQresetPoll on a ready socket); an
 * attempt not up within connect_timeout is dropped and the back-off above
 * applies.  Once connected, restoring the session takes a few round trips
 * on the new connection.
 *
 * Inside a transaction (sqldb_begin until sqldb_commit or sqldb_rollback)
 * nothing reconnects: every later statement and the COMMIT fail, so a
 * transaction is never half applied nor silently run again; the caller
 * rolls back and retries it whole.  A connection lost while its COMMIT
 * runs leaves the outcome unknown to the client (the message says so): a
 * caller that must know reads back.  Statements hold no server state (no
 * server-side prepared statements), so one prepared before a loss runs
 * after it.
 *
 * After a reconnect the session is restored before any other statement:
 * the last session is ended if the server still runs it (pg_terminate_backend
 * of its pid and start time: its locks are freed, its transaction settled),
 * durability (sqldb_set_durable), read-only mode and every LISTEN; then fn
 * (if set) runs, so the caller re-takes what its session held (the
 * store's advisory lock).  fn may run statements on db; an error from it
 * (SF_*, message in err) fails the reconnect like a server that did not
 * answer: the new session is dropped and the next attempt waits its turn.
 * One fn per connection; NULL removes it.
 */
typedef int (*sqldb_reconnect_fn)(struct sqldb *db, void *arg, struct sf_err *err);
void sqldb_on_reconnect(struct sqldb *db, sqldb_reconnect_fn fn, void *arg);
/* Successful reconnects of db so far (0 on SQLite). */
int64_t sqldb_reconnects(const struct sqldb *db);
/* Round trips to the server on db so far (statements sent, a session's restoring included;
   0 on SQLite, whose statements never leave the process): what a caller waited on the
   network for. */
int64_t sqldb_round_trips(const struct sqldb *db);
/*
 * The time on the database's clock, in ms since the epoch: leases that hosts compare must
 * be on one clock, not each host's own (a host whose clock ran ahead reaped the others
 * early).  PostgreSQL: this process's wall clock plus the offset to the server's
 * (clock_timestamp()), measured when each session starts (half its round trip's error);
 * SQLite: this process's wall clock, its only host's.  SLIMFARM_TEST_CLOCK_SKEW_MS, read at
 * open, shifts the process's clock as a host's wrong clock would (tests only).
 */
int64_t sqldb_clock_ms(const struct sqldb *db);

/*
 * LISTEN/NOTIFY.  A channel name is a-z, 0-9 and _, starting with a letter
 * or _, at most 63 bytes: the identifiers PostgreSQL reads the same quoted
 * or not, so LISTEN and pg_notify name one channel; any other is SF_EINVAL
 * with the name in the message.  A payload is at most SQLDB_PAYLOAD_MAX
 * bytes (the server's cap), else SF_EINVAL.
 *
 * On SQLite all four are valid no-ops (nothing is ever delivered, the fd is
 * -1): one SQLite database has one daemon (the data dir's flock), so there
 * is no other host to wake, and the process that wrote knows already.
 *
 * sqldb_listen: LISTEN on channel, at most SQLDB_LISTEN_MAX channels a
 * connection (again is a no-op); re-issued after every reconnect.
 * sqldb_notify: pg_notify(channel, payload) (NULL payload: empty); in a
 * transaction it is delivered at COMMIT, and not at all on ROLLBACK.
 * sqldb_notify_fd: the socket to watch for readability (epoll), or -1 (no
 * connection now, or SQLite).  It may change at any reconnect: read it
 * again after each call that may have reconnected (sqldb_reconnects
 * tells).
 * sqldb_notifications: read what the socket holds and hand each
 * notification to fn, oldest first; returns how many (>= 0) or SF_EIO when
 * the connection is lost -- it then reconnects as any call does (the
 * back-off allowing), so a listener that only ever drains comes back: call
 * it again from a timer until it returns >= 0.  Notifications that arrive
 * while another call runs on db are kept, but do not wake the fd: drain
 * after other calls on a listening connection too (or give the listener a
 * connection of its own).
 */
#define SQLDB_LISTEN_MAX  16   /* channels a connection listens on: a few per farm */
#define SQLDB_CHANNEL_MAX 63   /* PostgreSQL's NAMEDATALEN - 1 */
#define SQLDB_PAYLOAD_MAX 7999 /* PostgreSQL refuses 8000 bytes and more */
typedef void (*sqldb_notify_fn)(void *arg, const char *channel, const char *payload);
int sqldb_listen(struct sqldb *db, const char *channel);
int sqldb_notify(struct sqldb *db, const char *channel, const char *payload);
int sqldb_notify_fd(struct sqldb *db);
int sqldb_notifications(struct sqldb *db, sqldb_notify_fn fn, void *arg);

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
