/*
 * store_int.h - internal to the store module (store.c, store_file.c,
 * store_blob.c, store_job.c, store_printer.c, store_event.c, store_query.c);
 * nothing outside src/farm/store*.c includes it.
 *
 * What the parts share: the connection and data dir (struct store), the
 * statement helpers every part writes through (store.c, over sqldb.h, so
 * one SQL text serves SQLite and PostgreSQL), the event log append
 * (store_event.c), the file-table checks and hashing (store_file.c) and
 * the database's copy of the files (store_blob.c).  Each
 * helper's errors are SF_EIO from the engine with its message, set in err
 * like the public functions'.
 *
 * Thread: as store.h (the store's thread).
 */
#ifndef SF_FARM_STORE_INT_H
#define SF_FARM_STORE_INT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"
#include "sqldb.h"
#include "store.h"

#define STORE_PATH_MAX 1024 /* data dir paths; deeper trees are a config error */

struct store {
    struct sqldb *db;            /* the connection (SQLite: WAL mode, foreign keys on) */
    char dir[STORE_PATH_MAX];    /* data directory */
    char target[STORE_PATH_MAX]; /* what db connects to: the SQLite file or a URL */
    int lock_fd;                 /* DATA_DIR/lock, flock()ed exclusively; -1 if not open */
    bool host;                   /* one of several hosts (store_open_host): the database's
                                    lock is shared */
    char host_name[64];          /* the name store_host_join locked on this connection ("" if
                                    none): locked again after a reconnect (store_host_relock) */
    int64_t host_token;          /* its token */
    bool name_lost;              /* another process took the name while the connection was
                                    away: the lease is lost (store_host_beat refuses) */
    bool no_migrate;             /* a check (store_open_check): an older schema is refused,
                                    not migrated */
};

/* After a reconnect (store.c's hook): lock s's host name again, if it joined one.  SF_OK
   (also when another process has joined under the name since: name_lost is set), or
   SF_EAGAIN while the name's lock is held with this process's token still current (the lost
   session, not yet ended), so the reconnect is tried again. */
int store_host_relock(struct store *s, struct sf_err *err);

/*
 * Migration 10 (store_printer_cfg.c): a printer the API added, edited,
 * disabled or removed.  name: the printer; cfg: its [printer NAME]
 * section's body ("key: value" lines), NULL when farm.ini's section is
 * the one in force; disabled: the operator's reason, NULL when not
 * disabled; removed: 1 hides farm.ini's printer of that name.  id orders
 * the printers farm.ini does not name.
 */
#define STORE_PRINTER_CFG_SCHEMA                                                                   \
    "CREATE TABLE printer_cfgs("                                                                   \
    "  id INTEGER PRIMARY KEY AUTOINCREMENT,"                                                      \
    "  name TEXT NOT NULL UNIQUE,"                                                                 \
    "  cfg TEXT,"                                                                                  \
    "  disabled TEXT,"                                                                             \
    "  removed INTEGER NOT NULL DEFAULT 0 CHECK(removed IN (0, 1)),"                               \
    "  updated_ms INTEGER NOT NULL);"

/*
 * Migration 11 (store_host.c): several hosts on one database.  hosts: one
 * row per host name: token, bumped at each join (a process's claim on the
 * name); pid and version (the schema its program writes) of that process;
 * started_ms, heartbeat_ms (its last beat) and lease_until_ms, wall clock;
 * reaped_ms: when store_host_reap released its work (0: not reaped).
 * host_printers: which host owns a printer (its own config's).  jobs:
 * claimed_by, the host that claimed (prepares) or attached (prints) it, ''
 * for none; fence, the job's fencing token, bumped at every claim and
 * attach.  jobs_claim_order is the claim's order (the scheduler's) over the
 * queued jobs alone, so a claim is one index step however long the queue.
 */
#define STORE_HOST_SCHEMA                                                                          \
    "CREATE TABLE hosts("                                                                          \
    "  name TEXT PRIMARY KEY,"                                                                     \
    "  token INTEGER NOT NULL CHECK(token >= 1),"                                                  \
    "  pid INTEGER NOT NULL,"                                                                      \
    "  version INTEGER NOT NULL,"                                                                  \
    "  started_ms INTEGER NOT NULL,"                                                               \
    "  heartbeat_ms INTEGER NOT NULL,"                                                             \
    "  lease_until_ms INTEGER NOT NULL,"                                                           \
    "  reaped_ms INTEGER NOT NULL DEFAULT 0);"                                                     \
    "CREATE TABLE host_printers("                                                                  \
    "  printer TEXT PRIMARY KEY,"                                                                  \
    "  host TEXT NOT NULL REFERENCES hosts(name),"                                                 \
    "  since_ms INTEGER NOT NULL);"                                                                \
    "CREATE INDEX host_printers_host ON host_printers(host);"                                      \
    "ALTER TABLE jobs ADD COLUMN claimed_by TEXT NOT NULL DEFAULT '';"                             \
    "ALTER TABLE jobs ADD COLUMN fence INTEGER NOT NULL DEFAULT 0;"                                \
    "CREATE INDEX jobs_claimed ON jobs(claimed_by) WHERE claimed_by != '';"                        \
    "CREATE INDEX jobs_claim_order ON jobs(priority DESC, queue_pos, id) WHERE state = 'queued';"

/*
 * Migration STORE_BLOB_VERSION (store_blob.c): files shared between hosts through the
 * database.  file_blobs says the database holds a file's bytes, all of
 * them: its row is written in the one transaction that writes every chunk,
 * so no row ever names a part-sent file.  file_chunks holds the bytes cut
 * into chunk_bytes pieces, seq from 0, the last one shorter.  Only a
 * PostgreSQL store fills them; on SQLite (one host) the data dir is the
 * store and they stay empty.
 */
#define STORE_BLOB_VERSION 12 /* the schema version STORE_BLOB_SCHEMA upgrades to */
#define STORE_BLOB_SCHEMA                                                                          \
    "CREATE TABLE file_blobs("                                                                     \
    "  sha256 TEXT PRIMARY KEY CHECK(length(sha256) = 64),"                                        \
    "  size INTEGER NOT NULL CHECK(size >= 0),"                                                    \
    "  chunk_bytes INTEGER NOT NULL CHECK(chunk_bytes > 0),"                                       \
    "  created_ms INTEGER NOT NULL);"                                                              \
    "CREATE TABLE file_chunks("                                                                    \
    "  sha256 TEXT NOT NULL REFERENCES file_blobs(sha256) ON DELETE CASCADE,"                      \
    "  seq INTEGER NOT NULL CHECK(seq >= 0),"                                                      \
    "  data BLOB NOT NULL,"                                                                        \
    "  PRIMARY KEY(sha256, seq));"

/*
 * Migration 14 (store_command.c): commands, an operator's action on a
 * printer another host owns.  host: the printer's owner, who runs it;
 * from_host: who asked; kind: a printer action, "cancel-job" (line: the
 * job's id), "command" (line: the G-code) or "emergency-stop"; who: the
 * operator; state: pending (written),
 * running (the owner took it), done (rc, message and the printer's state
 * after written), expired (withdrawn at its deadline: never run).
 * commands_pending finds a host's pending rows in one index step.
 */
#define STORE_COMMAND_SCHEMA                                                                       \
    "CREATE TABLE commands("                                                                       \
    "  id INTEGER PRIMARY KEY AUTOINCREMENT,"                                                      \
    "  printer TEXT NOT NULL,"                                                                     \
    "  host TEXT NOT NULL,"                                                                        \
    "  from_host TEXT NOT NULL,"                                                                   \
    "  kind TEXT NOT NULL,"                                                                        \
    "  line TEXT NOT NULL DEFAULT '',"                                                             \
    "  who TEXT NOT NULL DEFAULT '',"                                                              \
    "  state TEXT NOT NULL CHECK(state IN ('pending','running','done','expired')),"                \
    "  rc INTEGER NOT NULL DEFAULT 0,"                                                             \
    "  message TEXT NOT NULL DEFAULT '',"                                                          \
    "  printer_state TEXT NOT NULL DEFAULT '',"                                                    \
    "  created_ms INTEGER NOT NULL,"                                                               \
    "  deadline_ms INTEGER NOT NULL);"                                                             \
    "CREATE INDEX commands_pending ON commands(host) WHERE state = 'pending';"                     \
    "CREATE INDEX commands_created ON commands(created_ms);"

/*
 * Migration 15 (store_view.c): each host's view of its own printers, as the
 * other hosts show them (store_view.h).  host: the publisher; token: its
 * join's (a view is read only while it is the host's current token); view:
 * a JSON object, printer name -> the printer as the host's API shows it.
 */
#define STORE_VIEW_SCHEMA                                                                          \
    "CREATE TABLE host_views("                                                                     \
    "  host TEXT PRIMARY KEY REFERENCES hosts(name),"                                              \
    "  token INTEGER NOT NULL,"                                                                    \
    "  view TEXT NOT NULL,"                                                                        \
    "  updated_ms INTEGER NOT NULL);"

/*
 * Migration 16 (store_spare.c): what preparing a job for a printer needs, as its owner
 * publishes it beside its claim on the printer (host_printers), so a host with spare cores
 * may prepare for another host's printer (farm_spare.c).  profile '' until the owner
 * published it (a host of an older program): not prepared for by others.
 */
#define STORE_SPARE_SCHEMA                                                                         \
    "ALTER TABLE host_printers ADD COLUMN profile TEXT NOT NULL DEFAULT '';"                       \
    "ALTER TABLE host_printers ADD COLUMN material TEXT NOT NULL DEFAULT '';"                      \
    "ALTER TABLE host_printers ADD COLUMN nozzle_mm REAL NOT NULL DEFAULT 0;"                      \
    "ALTER TABLE host_printers ADD COLUMN bed_x REAL NOT NULL DEFAULT 0;"                          \
    "ALTER TABLE host_printers ADD COLUMN bed_y REAL NOT NULL DEFAULT 0;"                          \
    "ALTER TABLE host_printers ADD COLUMN bed_z REAL NOT NULL DEFAULT 0;"                          \
    "ALTER TABLE host_printers ADD COLUMN overhang_deg REAL NOT NULL DEFAULT 0;"                   \
    "ALTER TABLE host_printers ADD COLUMN printer_group TEXT NOT NULL DEFAULT '';"                 \
    "ALTER TABLE host_printers ADD COLUMN gcode_models TEXT NOT NULL DEFAULT '';"                  \
    "ALTER TABLE host_printers ADD COLUMN attended INTEGER NOT NULL DEFAULT 0;"                    \
    "ALTER TABLE host_printers ADD COLUMN allow_gcode TEXT NOT NULL DEFAULT '';"                   \
    "ALTER TABLE host_printers ADD COLUMN enabled INTEGER NOT NULL DEFAULT 0;"

/* SF_EIO with what and SQLite's message. */
int store_db_fail(struct store *s, struct sf_err *err, const char *what);
/* Run sql (no rows, no parameters). */
int store_exec(struct store *s, const char *sql, struct sf_err *err);
/* Prepare sql into *st (sqldb_finalize it). */
int store_prepare(struct store *s, struct sqldb_stmt **st, const char *sql, struct sf_err *err);
/* Step a statement that returns no rows, then finalize it. */
int store_step_done(struct store *s, struct sqldb_stmt *st, struct sf_err *err, const char *what);
/* BEGIN (SQLite: IMMEDIATE); COMMIT (rolled back if it fails); ROLLBACK. */
int store_begin(struct store *s, struct sf_err *err);
int store_commit(struct store *s, struct sf_err *err);
void store_rollback(struct store *s);
/*
 * A write that logs an event, in one transaction: store_write_begin opens it
 * and prepares sql into *st (on failure nothing is left open); the caller
 * binds; store_write_end steps st (what names it in errors), appends the
 * event (as store_log_event) and commits, or rolls back and returns the
 * error.  st is finalized either way.
 */
int store_write_begin(struct store *s, struct sqldb_stmt **st, const char *sql, struct sf_err *err);
int store_write_end(struct store *s, struct sqldb_stmt *st, const char *what, int64_t job_id,
                    const char *printer, const char *kind, const char *detail, struct sf_err *err);
/* Prepare the SELECT sql into *st for store_read_rows, *rows NULL and *n 0 until it runs. */
int store_select(struct store *s, struct sqldb_stmt **st, const char *sql, void **rows, size_t *n,
                 struct sf_err *err);
/* Column col of st's row as text into dst (cap bytes, cut to fit; NULL is ""). */
void store_copy_text(char *dst, size_t cap, struct sqldb_stmt *st, int col);

/* Fill one element of a result array from the statement's current row. */
typedef void (*store_row_fn)(struct sqldb_stmt *st, void *row);
/*
 * Step st to its end, appending one element of elem_size bytes per row to
 * *rows (filled by read), then finalize st.  A step that ends in anything
 * but SQLDB_DONE (busy, I/O error, corruption) is an error and nothing is
 * returned: a caller never takes part of a result for all of it.  *rows is
 * freed by the caller (NULL when there are no rows or on error).
 */
int store_read_rows(struct store *s, struct sqldb_stmt *st, size_t elem_size, store_row_fn read,
                    void **rows, size_t *n, const char *what, struct sf_err *err);

/* A store_row_fn: column 0 as an int64_t (an id). */
void store_read_id(struct sqldb_stmt *st, void *row);

/* The columns store_read_job reads, in its order. */
#define STORE_JOB_COLS                                                                             \
    "id, name, file_sha, coalesce(gcode_sha, ''), state, method, deviation_mm, overhang_deg,"      \
    " copies, copies_done, failures, max_retries, material, target_printer, target_group,"         \
    " priority, size_x, size_y, size_z, printer, lines_acked, reason, created_ms, updated_ms,"     \
    " nozzle_mm, gcode_lines, prep_key, mesh_sha, mesh_angle_deg, filament_g, support_g,"          \
    " support_saved_g, prepare_ms, slice_ms, ready_ms, mndr, andr, shape_changed, est_s,"          \
    " queue_pos"
/* A store_row_fn: a struct job_row from a row of STORE_JOB_COLS. */
void store_read_job(struct sqldb_stmt *st, void *row);
/* Step st (a SELECT of STORE_JOB_COLS) once and finalize it: its row into *out, or
   SF_ENOTFOUND (err not set: the caller says what was not found), or SF_EIO naming what. */
int store_job_one(struct store *s, struct sqldb_stmt *st, struct job_row *out, const char *what,
                  struct sf_err *err);

/* store_job_event in the caller's transaction (store_host_reap moves many jobs in one). */
int store_job_event_in(struct store *s, int64_t id, enum job_event ev,
                       const struct job_event_args *a, enum job_state *to, struct sf_err *err);

/* PostgreSQL's text of store.c's SQLite migration v (0-based: to schema v + 1), sql,
   in PostgreSQL's types (store_pg.c); free() it.  NULL when out of memory. */
char *store_pg_migration(int v, const char *sql);

/* Append to the event log (job_id 0 and printer NULL: none), in the caller's transaction. */
int store_log_event(struct store *s, int64_t job_id, const char *printer, const char *kind,
                    const char *detail, struct sf_err *err);

/* Whether sha is 64 lowercase hex digits. */
bool store_sha_valid(const char *sha);

/* A running SHA-256 (store_file.c, over libcrypto): new, update with the bytes, final into
   hex (SF_EBUG if the library fails), free (NULL allowed).  new: NULL with err set. */
struct store_sha;
struct store_sha *store_sha_new(struct sf_err *err);
int store_sha_update(struct store_sha *h, const void *data, size_t len, struct sf_err *err);
int store_sha_final(struct store_sha *h, char sha[STORE_SHA_HEX], struct sf_err *err);
void store_sha_free(struct store_sha *h);
/*
 * Make the file at from (open as fd) durable and move it to sha's address
 * under dir/files (store_file.c).  The file system only: any thread.
 */
int store_file_place(const char *dir, int fd, const char *from, const char *sha,
                     struct sf_err *err);
/*
 * store_file_begin into data dir dir (which must outlive it), for a file that
 * is not recorded (a fetched copy, store_blob_fetch): written with
 * store_file_write, then store_file_keep_as places it at sha's address if its
 * SHA-256 is sha (SF_EIO naming both if not, the temporary file removed);
 * keep_as always frees f.
 */
struct store_file *store_file_begin_in(const char *dir, struct sf_err *err);
int store_file_keep_as(struct store_file *f, const char *sha, struct sf_err *err);

/*
 * The database's copy of the files (store_blob.c; PostgreSQL stores only).
 * Each takes the connection to use, so a worker may send on one of its own
 * (store_file_adopt) while the store's thread works on the store's.
 *
 * store_blob_upload: send the file at path, which must hash to sha, to db
 * chunk by chunk and mark it complete, in one transaction; nothing is sent
 * when db has it already (or another host is sending it: that upload's
 * commit is waited for).  SF_EINVAL for a file over SF_STORE_BLOB_MAX,
 * SF_EIO for the file, the database, or bytes that do not hash to sha;
 * on error nothing is left in db.  Not inside a transaction of db's.
 * The database's failures keep its code (sqldb_errcode): SF_EBUSY (a lock
 * not had within the lock timeout), SF_EUNREACH, SF_EINDOUBT are of the
 * moment, and the callers try again rather than fail the file's job.
 *
 * store_blob_fetch: copy sha from db into dir's files, at its address:
 * streamed into a temporary file, SHA-256 checked, then renamed, so a torn
 * or corrupt copy is never taken for the file.  SF_ENOTFOUND when db does
 * not hold sha's bytes, SF_EIO for a missing or damaged chunk, bytes that
 * do not hash to sha, or the file system; the database's own failures as
 * store_blob_upload's.
 */
int store_blob_upload(struct sqldb *db, const char *path, const char *sha, struct sf_err *err);
int store_blob_fetch(struct sqldb *db, const char *dir, const char *sha, struct sf_err *err);

/* store_host.c, shared with store_claim.c: the engine is PostgreSQL; end the transaction a
   body ran in (commit on SF_OK, else roll back); in the caller's transaction, hold host
   name's lease row, refused (SF_ESTALE) unless token's lease runs at now_ms. */
bool store_is_pg(const struct store *s);
int store_end_tx(struct store *s, int rc, struct sf_err *err);
int store_host_hold(struct store *s, const char *name, int64_t token, int64_t now_ms,
                    struct sf_err *err);

#endif
