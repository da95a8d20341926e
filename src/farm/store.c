/*
 * store.c - the job store (SQLite, or PostgreSQL: store_open_db) and the
 * content-addressed file directory.
 *
 * Why SQLite: a farm must survive kill -9 and power cuts with every job
 * where it was, and SQLite's WAL mode gives atomic, durable transactions
 * with one file and no server.  Design: every public mutator is a single
 * BEGIN IMMEDIATE ... COMMIT that changes the job row, its print history
 * and the event log together, with the job.h state machine deciding what
 * is legal.  synchronous=FULL, because state changes are rare (progress is
 * written on a timer) and "committed" must mean "on disk".  The schema
 * version lives in PRAGMA user_version; migrations[] upgrades one version
 * per transaction, and a newer database is refused rather than guessed at.
 * On PostgreSQL the same versions live in the schema_version table, and
 * the same migrations run translated to its types (store_pg.c).
 *
 * This file opens the store (data dir lock, migrations, crash recovery),
 * checks it, and holds the statement helpers the other parts share
 * (store_int.h), written over sqldb.h so one SQL text serves both engines.  The rest of the
 * interface lives by subject: store_file.c (the content-addressed files), store_job.c (jobs, their
 * copies and print history), store_printer.c, store_event.c.
 *
 * Thread: one connection per store, used by one thread at a time.
 */
#include "store.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <ftw.h>
#include <limits.h>
#include <stdio.h>
#include <string.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "../base/log.h"
#include "../base/mem.h"
#include "store_host.h"
#include "store_int.h"

/*
 * One process per data dir: crash recovery run beside a live daemon (its
 * --fsck, or a second daemon) turned a printing job interrupted under a
 * printer still printing it.  An flock, not a pid file: the kernel drops it
 * when the holder dies, even by kill -9.  The file holds the holder's pid
 * for the message.
 */
static int
lock_dir(struct store *s, struct sf_err *err)
{
    char path[STORE_PATH_MAX + 16];
    snprintf(path, sizeof(path), "%s/lock", s->dir);
    s->lock_fd = open(path, O_RDWR | O_CREAT | O_CLOEXEC, 0600);
    if (s->lock_fd < 0)
        return sf_err_sys(err, "store: cannot open '%s'", path);
    if (flock(s->lock_fd, LOCK_EX | LOCK_NB) != 0) {
        if (errno != EWOULDBLOCK)
            return sf_err_sys(err, "store: cannot lock '%s'", path);
        char pid[24] = "";
        ssize_t n = pread(s->lock_fd, pid, sizeof(pid) - 1, 0);
        pid[n > 0 ? n : 0] = '\0';
        pid[strcspn(pid, "\n")] = '\0';
        return sf_err_set(err, SF_EAGAIN,
                          "store: data dir '%s' is in use by another process (pid %s): stop it "
                          "first, or give this one another data_dir",
                          s->dir, pid[0] ? pid : "unknown");
    }
    char pid[24];
    int len = snprintf(pid, sizeof(pid), "%ld\n", (long)getpid());
    if (ftruncate(s->lock_fd, 0) != 0 || pwrite(s->lock_fd, pid, (size_t)len, 0) != len)
        return sf_err_sys(err, "store: cannot write '%s'", path);
    return SF_OK;
}

/* Schema migrations; index i upgrades user_version i to i + 1.  PostgreSQL
   runs the same text with its type names (store_pg.c): write SQL both
   engines read (make check-pg runs the store's tests on both). */
static const char *const migrations[] = {
    /* 1: the first schema */
    "CREATE TABLE files("
    "  sha256 TEXT PRIMARY KEY CHECK(length(sha256) = 64),"
    "  size INTEGER NOT NULL CHECK(size >= 0),"
    "  created_ms INTEGER NOT NULL);"
    "CREATE TABLE jobs("
    "  id INTEGER PRIMARY KEY AUTOINCREMENT,"
    "  name TEXT NOT NULL,"
    "  file_sha TEXT NOT NULL REFERENCES files(sha256),"
    "  gcode_sha TEXT REFERENCES files(sha256),"
    "  state TEXT NOT NULL CHECK(state IN ('queued','preparing','ready','printing','paused',"
    "    'done','failed','cancelled','interrupted')),"
    "  method TEXT NOT NULL,"
    "  deviation_mm REAL NOT NULL,"
    "  overhang_deg REAL NOT NULL,"
    "  copies INTEGER NOT NULL CHECK(copies >= 1),"
    "  copies_done INTEGER NOT NULL DEFAULT 0 CHECK(copies_done <= copies),"
    "  failures INTEGER NOT NULL DEFAULT 0,"
    "  max_retries INTEGER NOT NULL,"
    "  material TEXT NOT NULL,"
    "  target_printer TEXT NOT NULL,"
    "  target_group TEXT NOT NULL,"
    "  priority INTEGER NOT NULL,"
    "  size_x REAL NOT NULL DEFAULT 0, size_y REAL NOT NULL DEFAULT 0,"
    "  size_z REAL NOT NULL DEFAULT 0,"
    "  nozzle_mm REAL NOT NULL DEFAULT 0,"
    "  printer TEXT NOT NULL DEFAULT '',"
    "  lines_acked INTEGER NOT NULL DEFAULT 0,"
    "  reason TEXT NOT NULL DEFAULT '',"
    "  created_ms INTEGER NOT NULL,"
    "  updated_ms INTEGER NOT NULL);"
    "CREATE INDEX jobs_state ON jobs(state);"
    "CREATE TABLE printers("
    "  name TEXT PRIMARY KEY,"
    "  state TEXT NOT NULL,"
    "  updated_ms INTEGER NOT NULL);"
    "CREATE TABLE prints("
    "  id INTEGER PRIMARY KEY AUTOINCREMENT,"
    "  job_id INTEGER NOT NULL REFERENCES jobs(id),"
    "  copy INTEGER NOT NULL,"
    "  printer TEXT NOT NULL,"
    "  material TEXT NOT NULL,"
    "  start_line INTEGER NOT NULL,"
    "  lines_acked INTEGER NOT NULL DEFAULT 0,"
    "  filament_mm REAL NOT NULL DEFAULT 0,"
    "  started_ms INTEGER NOT NULL,"
    "  ended_ms INTEGER NOT NULL DEFAULT 0,"
    "  outcome TEXT NOT NULL DEFAULT '');"
    "CREATE INDEX prints_job ON prints(job_id);"
    "CREATE TABLE events("
    "  id INTEGER PRIMARY KEY AUTOINCREMENT,"
    "  at_ms INTEGER NOT NULL,"
    "  job_id INTEGER REFERENCES jobs(id),"
    "  printer TEXT NOT NULL DEFAULT '',"
    "  kind TEXT NOT NULL,"
    "  detail TEXT NOT NULL);",
    /* 2: the G-code's command line count, scanned once when it is prepared
       (drv_job_scan), so starting a job need not read the file; 0 for
       G-code prepared before (the driver then counts it itself) */
    "ALTER TABLE jobs ADD COLUMN gcode_lines INTEGER NOT NULL DEFAULT 0 CHECK(gcode_lines >= 0);",
    /* 3: what the G-code was prepared for (sched_key), so it starts only on
       printers of that key; and the optimized part, so preparing it again
       for another printer does not repeat the optimization.  G-code
       prepared before has no key and is prepared again before it prints. */
    "ALTER TABLE jobs ADD COLUMN prep_key TEXT NOT NULL DEFAULT '';"
    "ALTER TABLE jobs ADD COLUMN mesh_sha TEXT NOT NULL DEFAULT '';"
    "ALTER TABLE jobs ADD COLUMN mesh_angle_deg REAL NOT NULL DEFAULT 0;"
    /* and whether a printer's bed holds a part, which no restart forgets */
    "ALTER TABLE printers ADD COLUMN bed_full INTEGER NOT NULL DEFAULT 0;",
    /* 4: the estimates of the G-code (filament, support, and the support
       the optimization saved, grams), how long preparing and slicing took,
       when the job last became ready, and each print's wait for a printer
       since then: what /metrics reports.  0 for jobs and prints before. */
    "ALTER TABLE jobs ADD COLUMN filament_g REAL NOT NULL DEFAULT 0;"
    "ALTER TABLE jobs ADD COLUMN support_g REAL NOT NULL DEFAULT 0;"
    "ALTER TABLE jobs ADD COLUMN support_saved_g REAL NOT NULL DEFAULT 0;"
    "ALTER TABLE jobs ADD COLUMN prepare_ms INTEGER NOT NULL DEFAULT 0;"
    "ALTER TABLE jobs ADD COLUMN slice_ms INTEGER NOT NULL DEFAULT 0;"
    "ALTER TABLE jobs ADD COLUMN ready_ms INTEGER NOT NULL DEFAULT 0;"
    "ALTER TABLE prints ADD COLUMN wait_ms INTEGER NOT NULL DEFAULT 0;",
    /* 5: how far a shape method moved the part (MNDR / ANDR over the
       bounding-box diagonal, measure.h) and whether it prints reshaped;
       NULL when not measured (methods none, orient, and jobs before) */
    "ALTER TABLE jobs ADD COLUMN mndr REAL CHECK(mndr IS NULL OR mndr >= 0);"
    "ALTER TABLE jobs ADD COLUMN andr REAL CHECK(andr IS NULL OR andr >= 0);"
    "ALTER TABLE jobs ADD COLUMN shape_changed INTEGER NOT NULL DEFAULT 0;",
    /* 6: the G-code's print time estimate (gcjob_estimate_s: -1 when it
       states none), read once when the G-code is made or checked, so a
       start need not read the file; NULL for G-code before (the printer
       then reads the file's head) */
    "ALTER TABLE jobs ADD COLUMN est_s REAL CHECK(est_s IS NULL OR est_s >= -1);",
    /* 7: reads that stay small as history grows: the live jobs (what the
       scheduler reads at each change, store_job_live) as a partial index,
       so 10,000 finished jobs cost it nothing; and prints by printer, for
       GET /api/jobs?printer= (store_job_page) */
    "CREATE INDEX jobs_live ON jobs(id) WHERE state NOT IN ('done','failed','cancelled');"
    "CREATE INDEX prints_printer ON prints(printer, job_id);",
    /* 8: a printer's newest print (store_beds, on the loop for GET
       /api/printers) in one index step: max(id) over (printer, job_id)
       walked every print of the printer */
    "CREATE INDEX prints_printer_id ON prints(printer, id);",
    /* 9: each job's place in the queue within its priority, lower first
       (issue 31: ▲/▼ move a job one place among the waiting jobs, where a
       priority change jumped it past every job of its priority); jobs
       before keep their order, first come first served, by taking their
       id; a new job takes the largest + 1, which the index finds in a step */
    "ALTER TABLE jobs ADD COLUMN queue_pos INTEGER NOT NULL DEFAULT 0;"
    "UPDATE jobs SET queue_pos = id;"
    "CREATE INDEX jobs_queue_pos ON jobs(queue_pos);",
    /* 10: printers managed at run time (store_printer_cfg.c) */
    STORE_PRINTER_CFG_SCHEMA,
    /* 11: several hosts on one database (store_host.c) */
    STORE_HOST_SCHEMA,
    /* 12: files shared between hosts through the database (store_blob.c; store_int.h's
       STORE_BLOB_VERSION names this number: renumber both together) */
    STORE_BLOB_SCHEMA,
    /* 13: the G-code each print ran (a job's changes when it is sliced again for another
       printer between two copies) */
    "ALTER TABLE prints ADD COLUMN gcode_sha TEXT NOT NULL DEFAULT '';",
    /* 14: an action on a printer another host owns, carried through the database
       (store_command.c) */
    STORE_COMMAND_SCHEMA,
    /* 15: each host's view of its own printers, for the others (store_view.c) */
    STORE_VIEW_SCHEMA,
    /* 16: what preparing for each host's printers needs, for the hosts with spare cores
       (store_spare.c) */
    STORE_SPARE_SCHEMA,
};
#define N_MIGRATIONS ((int)(sizeof(migrations) / sizeof(migrations[0])))

int
store_schema_version(void)
{
    return N_MIGRATIONS;
}

int
store_db_fail(struct store *s, struct sf_err *err, const char *what)
{
    return sf_err_set(err, sqldb_errcode(s->db), "store: %s: %s", what, sqldb_errmsg(s->db));
}

int
store_exec(struct store *s, const char *sql, struct sf_err *err)
{
    if (sqldb_exec(s->db, sql) != SF_OK)
        return sf_err_set(err, sqldb_errcode(s->db), "store: %.60s: %s", sql, sqldb_errmsg(s->db));
    return SF_OK;
}

int
store_prepare(struct store *s, struct sqldb_stmt **st, const char *sql, struct sf_err *err)
{
    if (sqldb_prepare(s->db, sql, st) != SF_OK)
        return store_db_fail(s, err, "prepare");
    return SF_OK;
}

int
store_step_done(struct store *s, struct sqldb_stmt *st, struct sf_err *err, const char *what)
{
    int rc = sqldb_step(st);
    int out = rc == SQLDB_DONE ? SF_OK : store_db_fail(s, err, what);
    sqldb_finalize(st);
    return out;
}

int
store_begin(struct store *s, struct sf_err *err)
{
    if (sqldb_begin(s->db) != SF_OK)
        return sf_err_set(err, sqldb_errcode(s->db), "store: begin: %s", sqldb_errmsg(s->db));
    return SF_OK;
}

int
store_commit(struct store *s, struct sf_err *err)
{
    if (sqldb_commit(s->db) != SF_OK) /* rolled back */
        return sf_err_set(err, sqldb_errcode(s->db), "store: commit: %s", sqldb_errmsg(s->db));
    return SF_OK;
}

int
store_commit_outcome(struct store *s, struct sf_err *err)
{
    int rc = sqldb_commit_outcome(s->db);
    if (rc < 0)
        return sf_err_set(err, rc, "store: %s", sqldb_errmsg(s->db));
    return rc;
}

void
store_rollback(struct store *s)
{
    sqldb_rollback(s->db);
}

int
store_write_begin(struct store *s, struct sqldb_stmt **st, const char *sql, struct sf_err *err)
{
    int rc = store_begin(s, err);
    if (rc == SF_OK && (rc = store_prepare(s, st, sql, err)))
        store_rollback(s);
    return rc;
}

int
store_write_end(struct store *s, struct sqldb_stmt *st, const char *what, int64_t job_id,
                const char *printer, const char *kind, const char *detail, struct sf_err *err)
{
    int rc;
    if ((rc = store_step_done(s, st, err, what)) ||
        (rc = store_log_event(s, job_id, printer, kind, detail, err)) ||
        (rc = store_commit(s, err)))
        store_rollback(s);
    return rc;
}

int
store_select(struct store *s, struct sqldb_stmt **st, const char *sql, void **rows, size_t *n,
             struct sf_err *err)
{
    *rows = NULL;
    *n = 0;
    return store_prepare(s, st, sql, err);
}

void
store_copy_text(char *dst, size_t cap, struct sqldb_stmt *st, int col)
{
    const char *t = sqldb_column_text(st, col);
    snprintf(dst, cap, "%s", t ? (const char *)t : "");
}

int
store_read_rows(struct store *s, struct sqldb_stmt *st, size_t elem_size, store_row_fn read,
                void **rows, size_t *n, const char *what, struct sf_err *err)
{
    size_t cap = 0;
    int step, rc = SF_OK;
    *rows = NULL;
    *n = 0;
    while ((step = sqldb_step(st)) == SQLDB_ROW) {
        if (!mem_grow(rows, &cap, *n + 1, elem_size)) {
            rc = sf_err_set(err, SF_ENOMEM, "store: %s: out of memory", what);
            break;
        }
        read(st, (char *)*rows + *n * elem_size);
        (*n)++;
    }
    if (rc == SF_OK && step != SQLDB_DONE)
        rc = store_db_fail(s, err, what);
    sqldb_finalize(st);
    if (rc != SF_OK) {
        free(*rows);
        *rows = NULL;
        *n = 0;
    }
    return rc;
}

/* Whether the pragma sql answers want in its first row: *ok, or an error preparing it. */
static int
pragma_is(struct store *s, const char *sql, const char *want, bool *ok, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st, sql, err);
    if (rc)
        return rc;
    *ok = sqldb_step(st) == SQLDB_ROW && strcmp(sqldb_column_text(st, 0), want) == 0;
    sqldb_finalize(st);
    return SF_OK;
}

/* The schema version (SQLite: user_version; PostgreSQL: the schema_version row, 0
   if none), read in the caller's transaction. */
static int
read_version(struct store *s, int *version, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st,
                           sqldb_engine(s->db) == SQLDB_SQLITE
                               ? "PRAGMA user_version"
                               : "SELECT coalesce(max(version), 0) FROM schema_version",
                           err);
    if (rc)
        return rc;
    *version = sqldb_step(st) == SQLDB_ROW ? sqldb_column_int(st, 0) : -1;
    sqldb_finalize(st);
    return *version < 0 ? store_db_fail(s, err, "read schema version") : SF_OK;
}

/* Migration v + 1 and the version it records, in the caller's transaction. */
static int
migrate_one(struct store *s, int v, struct sf_err *err)
{
    bool pg = sqldb_engine(s->db) == SQLDB_PG;
    char set[96];
    snprintf(set, sizeof(set),
             pg ? "DELETE FROM schema_version; INSERT INTO schema_version VALUES(%d)"
                : "PRAGMA user_version = %d",
             v + 1);
    char *sql = pg ? store_pg_migration(v, migrations[v]) : NULL;
    if (pg && !sql)
        return sf_err_set(err, SF_ENOMEM, "store: out of memory");
    int rc = store_exec(s, pg ? sql : migrations[v], err);
    free(sql);
    return rc ? rc : store_exec(s, set, err);
}

/*
 * Bring the schema to this program's version, one version per transaction,
 * each reading the version again inside it: hosts that migrate one
 * PostgreSQL database at once (PostgreSQL's LOCK, SQLite's BEGIN
 * IMMEDIATE) apply each migration once.  *from (may be NULL): the version
 * found.
 */
static int
migrate(struct store *s, int *from, struct sf_err *err)
{
    bool pg = sqldb_engine(s->db) == SQLDB_PG;
    int rc;
    if (pg && (rc = store_exec(
                   s, "CREATE TABLE IF NOT EXISTS schema_version(version INTEGER NOT NULL)", err)))
        return rc;
    for (bool first = true;; first = false) {
        int version;
        if ((rc = store_begin(s, err)))
            return rc;
        if ((rc = pg ? store_exec(s, "LOCK TABLE schema_version IN EXCLUSIVE MODE", err) : SF_OK) ||
            (rc = read_version(s, &version, err)))
            goto fail;
        if (first && from)
            *from = version;
        if (version > N_MIGRATIONS) {
            rc = sf_err_set(err, SF_EUNSUPP,
                            "store: database schema %d is newer than this slimfarm (%d)", version,
                            N_MIGRATIONS);
            goto fail;
        }
        if (version == N_MIGRATIONS)
            return store_commit(s, err);
        if (s->no_migrate) {
            rc = sf_err_set(err, SF_EUNSUPP,
                            "store: database schema %d is older than this slimfarm's (%d): a "
                            "check changes nothing (hosts that run the older version share "
                            "it); migrate it with slimfarmd --init-store",
                            version, N_MIGRATIONS);
            goto fail;
        }
        if ((rc = migrate_one(s, version, err))) {
            sf_err_prefix(err, "store: migration to schema %d", version + 1);
            goto fail;
        }
        if ((rc = store_commit(s, err)))
            return rc;
    }
fail:
    store_rollback(s);
    return rc;
}

void
store_read_id(struct sqldb_stmt *st, void *row)
{
    *(int64_t *)row = sqldb_column_int64(st, 0);
}

/*
 * Crash recovery (see the header).  Each job moves in its own transaction
 * through store_job_event, so a crash during recovery leaves every job
 * either moved or not, and the next open finishes the work.
 */
static int
recover(struct store *s, struct store_recovery *rec, struct sf_err *err)
{
    struct store_recovery r = { 0, 0 };
    struct sqldb_stmt *st;
    int64_t *ids;
    size_t n;
    int rc = store_prepare(s, &st,
                           "SELECT id FROM jobs WHERE state IN ('printing','paused','preparing')"
                           " ORDER BY id",
                           err);
    if (rc)
        return rc;
    /* a failed read must fail the open: jobs it missed would stay "printing" for ever */
    if ((rc = store_read_rows(s, st, sizeof(*ids), store_read_id, (void **)&ids, &n,
                              "recovery: list jobs", err)))
        return rc;
    for (size_t i = 0; i < n; i++) {
        enum job_state to;
        struct job_event_args a = { .reason = "the daemon stopped while this job was active" };
        if ((rc = store_job_event(s, ids[i], JOB_EV_CRASHED, &a, &to, err)))
            goto out;
        if (to == JOB_INTERRUPTED)
            r.interrupted++;
        else
            r.requeued++;
    }
    /* Connections died with the process; drivers report again when they reconnect. */
    rc = store_exec(s, "UPDATE printers SET state = 'offline' WHERE state != 'offline'", err);
    if (rec)
        *rec = r;
out:
    free(ids);
    return rc;
}

static int
mkdir_p(const char *path, struct sf_err *err)
{
    char tmp[STORE_PATH_MAX];
    snprintf(tmp, sizeof(tmp), "%s", path);
    for (char *p = tmp + 1;; p++) {
        if (*p == '/' || *p == '\0') {
            char c = *p;
            *p = '\0';
            if (mkdir(tmp, 0700) != 0 && errno != EEXIST)
                return sf_err_sys(err, "store: cannot create '%s'", tmp);
            *p = c;
            if (!c)
                break;
        }
    }
    return SF_OK;
}

/* nftw's callback can take no argument: the count of fix_modes' walk. */
static int n_fixed;

static int
fix_one(const char *path, const struct stat *st, int flag, struct FTW *ftw)
{
    (void)ftw;
    if ((flag == FTW_F || flag == FTW_D) && (st->st_mode & 077) &&
        chmod(path, (st->st_mode & 0700) | (flag == FTW_D ? 0700 : 0600)) == 0)
        n_fixed++;
    return 0;
}

/* The data dir and everything in it for its owner alone (0700 folders,
   0600 files: jobs, G-code, the database and its WAL say what the farm
   prints and hold no one else's business); a dir made before this rule,
   or by hand, is fixed here and the log says so. */
static void
fix_modes(const char *data_dir)
{
    n_fixed = 0;
    nftw(data_dir, fix_one, 16, FTW_PHYS);
    if (n_fixed)
        log_warn("store",
                 "data dir '%s': %d files and folders were open to other users; now "
                 "0600 files, 0700 folders",
                 data_dir, n_fixed);
}

/* Create the database file 0600 before SQLite does (0644 by default); its
   WAL and SHM files take its mode. */
static int
create_private(const char *path, struct sf_err *err)
{
    int fd = open(path, O_RDWR | O_CREAT | O_CLOEXEC, 0600);
    if (fd < 0)
        return sf_err_sys(err, "store: cannot create '%s'", path);
    close(fd);
    return SF_OK;
}

/* Remove the temporaries of uploads a killed daemon never finished (the
   caller holds the data dir: no writer of this process is open yet). */
static void
sweep_tmp(const char *files_dir)
{
    DIR *d = opendir(files_dir);
    if (!d)
        return;
    struct dirent *e;
    char path[STORE_PATH_MAX + 320];
    int n = 0;
    while ((e = readdir(d)))
        if (strncmp(e->d_name, "tmp-", 4) == 0) {
            snprintf(path, sizeof(path), "%s/%s", files_dir, e->d_name);
            n += unlink(path) == 0;
        }
    closedir(d);
    if (n)
        log_info("store", "removed %d unfinished upload%s from '%s'", n, n == 1 ? "" : "s",
                 files_dir);
}

/* Connect s to its database (s->target) with sqldb_open's flags and bring its schema up
   to date. */
static int
connect(struct store *s, unsigned flags, int *from, struct sf_err *err)
{
    int rc = sqldb_is_url(s->target) ? SF_OK : create_private(s->target, err);
    if (rc == SF_OK && !(s->db = sqldb_open(s->target, flags, err)))
        rc = err ? err->code : SF_EIO; /* SF_EUNREACH: try again later */
    return rc ? rc : migrate(s, from, err);
}

/*
 * PostgreSQL: one single-host daemon per database, since its crash recovery
 * takes every printing job in the database as its own; or any number of
 * hosts (store_open_host), each recovering only its own work (store_host.c:
 * one process per host name, by a lease and a lock of the name).  A session
 * advisory lock on one key, exclusive for the single host, shared by the
 * hosts, so neither kind starts beside the other.  The server drops it when
 * the connection ends (a killed daemon's too); a connection closed a moment
 * ago may still hold it while its server process exits, hence the tries
 * over about 5 s.
 */
#define STORE_DB_LOCK_KEY 0x736c696d6661726dLL /* "slimfarm" in ASCII */
static int
lock_db(struct store *s, int n_tries, struct sf_err *err)
{
    if (sqldb_engine(s->db) != SQLDB_PG)
        return SF_OK; /* SQLite: the data dir's flock covers its file (lock_dir) */
    bool shared = s->host;
    for (int tries = 0; tries < n_tries; tries++) {
        struct sqldb_stmt *st;
        int rc =
            store_prepare(s, &st,
                          shared ? "SELECT CASE WHEN pg_try_advisory_lock_shared(?1) THEN 1 "
                                   "ELSE 0 END"
                                 : "SELECT CASE WHEN pg_try_advisory_lock(?1) THEN 1 ELSE 0 END",
                          err);
        if (rc)
            return rc;
        sqldb_bind_int64(st, 1, STORE_DB_LOCK_KEY);
        rc = sqldb_step(st);
        bool got = rc == SQLDB_ROW && sqldb_column_int(st, 0) == 1;
        sqldb_finalize(st);
        if (rc != SQLDB_ROW)
            return store_db_fail(s, err, "lock the database");
        if (got)
            return SF_OK;
        nanosleep(&(struct timespec){ .tv_nsec = 100 * 1000 * 1000 }, NULL);
    }
    if (shared)
        return sf_err_set(err, SF_EAGAIN,
                          "store: the database of data dir '%s' is in use by a single-host "
                          "slimfarmd, whose crash recovery takes every job in it: stop it first",
                          s->dir);
    return sf_err_set(err, SF_EAGAIN,
                      "store: the database of data dir '%s' is in use by another slimfarmd "
                      "(one single-host daemon per database; several share one only as hosts): "
                      "stop it first, or give this one another database",
                      s->dir);
}

/* A new session after a lost connection (sqldb_on_reconnect) holds no lock: take it
   again, once (a refusal fails the reconnect, which is tried again later). */
static int
relock(struct sqldb *db, void *arg, struct sf_err *err)
{
    (void)db;
    int rc = lock_db(arg, 1, err);
    return rc ? rc : store_host_relock(arg, err);
}

/* A new store for data_dir (NULL: none, a database alone) and db (as store_open_db). */
static struct store *
store_new(const char *data_dir, const char *db, struct sf_err *err)
{
    if (data_dir && (!data_dir[0] || strlen(data_dir) >= STORE_PATH_MAX - 80)) {
        sf_err_set(err, SF_EINVAL, "store: data dir '%.80s' is empty or too long", data_dir);
        return NULL;
    }
    if (db && db[0] && (!sqldb_is_url(db) || strlen(db) >= STORE_PATH_MAX)) {
        sf_err_set(err, SF_EINVAL, "store: '%.80s' is not a postgresql:// URL", db);
        return NULL;
    }
    struct store *s = mem_calloc(1, sizeof(*s));
    if (!s) {
        sf_err_set(err, SF_ENOMEM, "store: out of memory");
        return NULL;
    }
    snprintf(s->dir, sizeof(s->dir), "%s", data_dir ? data_dir : "");
    if (db && db[0])
        snprintf(s->target, sizeof(s->target), "%s", db);
    else
        snprintf(s->target, sizeof(s->target), "%s/slimfarm.db", s->dir);
    s->lock_fd = -1;
    return s;
}

struct store *
store_open(const char *data_dir, struct store_recovery *rec, struct sf_err *err)
{
    return store_open_db(data_dir, NULL, rec, err);
}

/* store_open_db, or as one of several hosts (store_open_host): a shared database lock, and
   on PostgreSQL no crash recovery at open (each host recovers its own work). */
static struct store *
open_store(const char *data_dir, const char *db, bool host, bool no_migrate,
           struct store_recovery *rec, struct sf_err *err)
{
    if (rec)
        *rec = (struct store_recovery){ 0, 0 };
    struct store *s = store_new(data_dir, db, err);
    if (!s)
        return NULL;
    s->host = host;
    s->no_migrate = no_migrate;
    char path[STORE_PATH_MAX + 32];
    snprintf(path, sizeof(path), "%s/files", data_dir);
    if (mkdir_p(path, err) || lock_dir(s, err))
        goto fail;
    fix_modes(data_dir);
    sweep_tmp(path);
    /* the loop's connection: a reconnect never waits for the network (sqldb.h) */
    if (connect(s, SQLDB_NOWAIT, NULL, err) || lock_db(s, 50, err))
        goto fail;
    /* SQLite's file is this data dir's alone (its flock): every job in it is this host's */
    if ((!host || sqldb_engine(s->db) == SQLDB_SQLITE) && recover(s, rec, err))
        goto fail;
    sqldb_on_reconnect(s->db, relock, s);
    return s;
fail:
    store_close(s);
    return NULL;
}

struct store *
store_open_db(const char *data_dir, const char *db, struct store_recovery *rec, struct sf_err *err)
{
    return open_store(data_dir, db, false, false, rec, err);
}

struct store *
store_open_host(const char *data_dir, const char *db, struct store_recovery *rec,
                struct sf_err *err)
{
    return open_store(data_dir, db, true, false, rec, err);
}

struct store *
store_open_check(const char *data_dir, const char *db, struct sf_err *err)
{
    return open_store(data_dir, db, true, true, NULL, err);
}

int
store_init(const char *target, int *from, struct sf_err *err)
{
    bool url = sqldb_is_url(target);
    struct store *s = store_new(url ? NULL : target, url ? target : NULL, err);
    if (!s)
        return err ? err->code : SF_EINVAL;
    int rc = url ? SF_OK : mkdir_p(target, err);
    if (rc == SF_OK && !url && (rc = lock_dir(s, err)) == SF_OK)
        fix_modes(target);
    if (rc == SF_OK)
        rc = connect(s, 0, from, err);
    store_close(s);
    return rc;
}

void
store_close(struct store *s)
{
    if (!s)
        return;
    sqldb_close(s->db);
    if (s->lock_fd >= 0)
        close(s->lock_fd); /* releases the flock */
    free(s);
}

/* Run a query whose first row, if any, is a violation described by column 0. */
static int
check_none(struct store *s, const char *sql, const char *what, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st, sql, err);
    if (rc)
        return rc;
    rc = sqldb_step(st);
    if (rc == SQLDB_ROW) {
        const char *t = sqldb_column_text(st, 0);
        sf_err_set(err, SF_EBUG, "store check: %s: %s", what, t ? (const char *)t : "?");
    }
    sqldb_finalize(st);
    if (rc == SQLDB_ROW)
        return SF_EBUG;
    return rc == SQLDB_DONE ? SF_OK : store_db_fail(s, err, what);
}

int
store_check(struct store *s, struct sf_err *err)
{
    /* SQLite checks its file and, on request, foreign keys; PostgreSQL
       enforces foreign keys always and checks its pages itself */
    bool lite = sqldb_engine(s->db) == SQLDB_SQLITE, ok = true;
    int rc = lite ? pragma_is(s, "PRAGMA integrity_check", "ok", &ok, err) : SF_OK;
    if (rc)
        return rc;
    if (!ok)
        return sf_err_set(err, SF_EBUG, "store check: integrity_check failed");
    static const struct {
        const char *what, *sql;
    } checks[] = {
        { "foreign key", /* first: SQLite only */
          "SELECT \"table\" || ' row ' || rowid FROM pragma_foreign_key_check" },
        { "job on a printer without printer name",
          "SELECT 'job ' || id FROM jobs WHERE state IN ('printing','paused') AND printer = ''" },
        { "job on a printer without exactly one open print",
          "SELECT 'job ' || id FROM jobs j WHERE state IN ('printing','paused') AND"
          " (SELECT count(*) FROM prints p WHERE p.job_id = j.id AND outcome = '') != 1" },
        { "open print of a job not on a printer",
          "SELECT 'print ' || p.id FROM prints p JOIN jobs j ON j.id = p.job_id"
          " WHERE p.outcome = '' AND j.state NOT IN ('printing','paused')" },
        { "ready or later job without G-code",
          "SELECT 'job ' || id FROM jobs WHERE gcode_sha IS NULL AND state IN"
          " ('ready','printing','paused','done','interrupted')" },
        { "copies", "SELECT 'job ' || id FROM jobs WHERE copies_done > copies OR"
                    " (state = 'done') != (copies_done = copies)" },
        { "more done prints than copies",
          "SELECT 'job ' || j.id FROM jobs j WHERE (SELECT count(*) FROM prints p"
          " WHERE p.job_id = j.id AND outcome = 'done') != j.copies_done" },
    };
    for (size_t i = lite ? 0 : 1; i < sizeof(checks) / sizeof(checks[0]); i++)
        if ((rc = check_none(s, checks[i].sql, checks[i].what, err)))
            return rc;
    return SF_OK;
}
