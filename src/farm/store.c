/*
 * store.c - the SQLite job store and the content-addressed file directory.
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
 *
 * Files are named by their SHA-256 (OpenSSL's libcrypto EVP interface, the
 * most widely reviewed implementation on the system): a writer hashes while
 * it streams into a temporary file, fsyncs, and renames it to
 * files/ab/abcdef...; a crash leaves at worst an orphan temporary or an
 * unreferenced file, never a row pointing at a missing or partial file.
 *
 * Thread: one connection per store, used by one thread at a time.
 */
#include "store.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <openssl/evp.h>
#include <sqlite3.h>
#include <stdio.h>
#include <string.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "../base/log.h"
#include "../base/mem.h"

#define STORE_PATH_MAX 1024 /* data dir paths; deeper trees are a config error */

struct store {
    sqlite3 *db;              /* the connection, WAL mode, foreign keys on */
    char dir[STORE_PATH_MAX]; /* data directory */
    int lock_fd;              /* DATA_DIR/lock, flock()ed exclusively; -1 if not open */
};

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

struct store_file {
    struct store *s;               /* owner */
    int fd;                        /* temporary file being written */
    char tmp[STORE_PATH_MAX + 64]; /* its path */
    EVP_MD_CTX *md;                /* running SHA-256 */
    int64_t size;                  /* bytes written */
};

/* Schema migrations; index i upgrades user_version i to i + 1. */
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
};
#define N_MIGRATIONS ((int)(sizeof(migrations) / sizeof(migrations[0])))

static const char JOB_COLS[] =
    "id, name, file_sha, coalesce(gcode_sha, ''), state, method, deviation_mm, overhang_deg,"
    " copies, copies_done, failures, max_retries, material, target_printer, target_group,"
    " priority, size_x, size_y, size_z, printer, lines_acked, reason, created_ms, updated_ms,"
    " nozzle_mm, gcode_lines, prep_key, mesh_sha, mesh_angle_deg, filament_g, support_g,"
    " support_saved_g, prepare_ms, slice_ms, ready_ms, mndr, andr, shape_changed";

int
store_schema_version(void)
{
    return N_MIGRATIONS;
}

static int64_t
now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (int64_t)ts.tv_sec * 1000 + ts.tv_nsec / 1000000;
}

static int
db_fail(struct store *s, struct sf_err *err, const char *what)
{
    return sf_err_set(err, SF_EIO, "store: %s: %s", what, sqlite3_errmsg(s->db));
}

static int
exec(struct store *s, const char *sql, struct sf_err *err)
{
    char *msg = NULL;
    if (sqlite3_exec(s->db, sql, NULL, NULL, &msg) != SQLITE_OK) {
        int rc = sf_err_set(err, SF_EIO, "store: %.60s: %s", sql, msg ? msg : "?");
        sqlite3_free(msg);
        return rc;
    }
    return SF_OK;
}

static int
prepare(struct store *s, sqlite3_stmt **st, const char *sql, struct sf_err *err)
{
    if (sqlite3_prepare_v2(s->db, sql, -1, st, NULL) != SQLITE_OK)
        return db_fail(s, err, "prepare");
    return SF_OK;
}

/* Step a statement that returns no rows, then finalize it. */
static int
step_done(struct store *s, sqlite3_stmt *st, struct sf_err *err, const char *what)
{
    int rc = sqlite3_step(st);
    int out = rc == SQLITE_DONE ? SF_OK : db_fail(s, err, what);
    sqlite3_finalize(st);
    return out;
}

static int
begin(struct store *s, struct sf_err *err)
{
    return exec(s, "BEGIN IMMEDIATE", err);
}

static int
commit(struct store *s, struct sf_err *err)
{
    int rc = exec(s, "COMMIT", err);
    if (rc != SF_OK)
        sqlite3_exec(s->db, "ROLLBACK", NULL, NULL, NULL);
    return rc;
}

static void
rollback(struct store *s)
{
    sqlite3_exec(s->db, "ROLLBACK", NULL, NULL, NULL);
}

static void
copy_text(char *dst, size_t cap, sqlite3_stmt *st, int col)
{
    const unsigned char *t = sqlite3_column_text(st, col);
    snprintf(dst, cap, "%s", t ? (const char *)t : "");
}

/* Fill one element of a result array from the statement's current row. */
typedef void (*row_fn)(sqlite3_stmt *st, void *row);

/*
 * Step st to its end, appending one element of elem_size bytes per row to
 * *rows (filled by read), then finalize st.  A step that ends in anything
 * but SQLITE_DONE (busy, I/O error, corruption) is an error and nothing is
 * returned: a caller never takes part of a result for all of it.  *rows is
 * freed by the caller (NULL when there are no rows or on error).
 */
static int
read_rows(struct store *s, sqlite3_stmt *st, size_t elem_size, row_fn read, void **rows, size_t *n,
          const char *what, struct sf_err *err)
{
    size_t cap = 0;
    int step, rc = SF_OK;
    *rows = NULL;
    *n = 0;
    while ((step = sqlite3_step(st)) == SQLITE_ROW) {
        if (!mem_grow(rows, &cap, *n + 1, elem_size)) {
            rc = sf_err_set(err, SF_ENOMEM, "store: %s: out of memory", what);
            break;
        }
        read(st, (char *)*rows + *n * elem_size);
        (*n)++;
    }
    if (rc == SF_OK && step != SQLITE_DONE)
        rc = db_fail(s, err, what);
    sqlite3_finalize(st);
    if (rc != SF_OK) {
        free(*rows);
        *rows = NULL;
        *n = 0;
    }
    return rc;
}

static int
log_event(struct store *s, int64_t job_id, const char *printer, const char *kind,
          const char *detail, struct sf_err *err)
{
    sqlite3_stmt *st;
    int rc = prepare(s, &st,
                     "INSERT INTO events(at_ms, job_id, printer, kind, detail)"
                     " VALUES(?, ?, ?, ?, ?)",
                     err);
    if (rc)
        return rc;
    sqlite3_bind_int64(st, 1, now_ms());
    if (job_id > 0)
        sqlite3_bind_int64(st, 2, job_id);
    else
        sqlite3_bind_null(st, 2);
    sqlite3_bind_text(st, 3, printer ? printer : "", -1, SQLITE_TRANSIENT);
    sqlite3_bind_text(st, 4, kind, -1, SQLITE_TRANSIENT);
    sqlite3_bind_text(st, 5, detail, -1, SQLITE_TRANSIENT);
    return step_done(s, st, err, "log event");
}

static int
migrate(struct store *s, struct sf_err *err)
{
    sqlite3_stmt *st;
    int rc = prepare(s, &st, "PRAGMA user_version", err);
    if (rc)
        return rc;
    int version = sqlite3_step(st) == SQLITE_ROW ? sqlite3_column_int(st, 0) : -1;
    sqlite3_finalize(st);
    if (version < 0)
        return db_fail(s, err, "read schema version");
    if (version > N_MIGRATIONS)
        return sf_err_set(err, SF_EUNSUPP,
                          "store: database schema %d is newer than this slimfarm (%d)", version,
                          N_MIGRATIONS);
    for (int v = version; v < N_MIGRATIONS; v++) {
        char pragma[48];
        snprintf(pragma, sizeof(pragma), "PRAGMA user_version = %d", v + 1);
        if ((rc = begin(s, err)))
            return rc;
        if ((rc = exec(s, migrations[v], err)) || (rc = exec(s, pragma, err))) {
            rollback(s);
            return sf_err_prefix(err, "store: migration to schema %d", v + 1);
        }
        if ((rc = commit(s, err)))
            return rc;
    }
    return SF_OK;
}

static void
read_id(sqlite3_stmt *st, void *row)
{
    *(int64_t *)row = sqlite3_column_int64(st, 0);
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
    sqlite3_stmt *st;
    int64_t *ids;
    size_t n;
    int rc = prepare(s, &st,
                     "SELECT id FROM jobs WHERE state IN ('printing','paused','preparing')"
                     " ORDER BY id",
                     err);
    if (rc)
        return rc;
    /* a failed read must fail the open: jobs it missed would stay "printing" for ever */
    if ((rc = read_rows(s, st, sizeof(*ids), read_id, (void **)&ids, &n, "recovery: list jobs",
                        err)))
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
    rc = exec(s, "UPDATE printers SET state = 'offline' WHERE state != 'offline'", err);
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
            if (mkdir(tmp, 0755) != 0 && errno != EEXIST)
                return sf_err_sys(err, "store: cannot create '%s'", tmp);
            *p = c;
            if (!c)
                break;
        }
    }
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

struct store *
store_open(const char *data_dir, struct store_recovery *rec, struct sf_err *err)
{
    if (rec)
        *rec = (struct store_recovery){ 0, 0 };
    if (!data_dir[0] || strlen(data_dir) >= STORE_PATH_MAX - 80) {
        sf_err_set(err, SF_EINVAL, "store: data dir '%.80s' is empty or too long", data_dir);
        return NULL;
    }
    struct store *s = mem_calloc(1, sizeof(*s));
    if (!s) {
        sf_err_set(err, SF_ENOMEM, "store: out of memory");
        return NULL;
    }
    snprintf(s->dir, sizeof(s->dir), "%s", data_dir);
    s->lock_fd = -1;
    char path[STORE_PATH_MAX + 32];
    snprintf(path, sizeof(path), "%s/files", data_dir);
    if (mkdir_p(path, err) || lock_dir(s, err))
        goto fail;
    sweep_tmp(path);
    snprintf(path, sizeof(path), "%s/slimfarm.db", data_dir);
    if (sqlite3_open_v2(path, &s->db, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE, NULL) !=
        SQLITE_OK) {
        sf_err_set(err, SF_EIO, "store: cannot open '%s': %s", path,
                   s->db ? sqlite3_errmsg(s->db) : "out of memory");
        goto fail;
    }
    sqlite3_busy_timeout(s->db, 5000);
    sqlite3_stmt *st;
    if (prepare(s, &st, "PRAGMA journal_mode = WAL", err))
        goto fail;
    int ok = sqlite3_step(st) == SQLITE_ROW &&
             strcmp((const char *)sqlite3_column_text(st, 0), "wal") == 0;
    sqlite3_finalize(st);
    if (!ok) {
        sf_err_set(err, SF_EIO, "store: '%s': cannot switch to WAL mode", path);
        goto fail;
    }
    if (exec(s, "PRAGMA foreign_keys = ON; PRAGMA synchronous = FULL;", err) || migrate(s, err) ||
        recover(s, rec, err))
        goto fail;
    return s;
fail:
    store_close(s);
    return NULL;
}

void
store_close(struct store *s)
{
    if (!s)
        return;
    sqlite3_close(s->db);
    if (s->lock_fd >= 0)
        close(s->lock_fd); /* releases the flock */
    free(s);
}

/* ---- files ---- */

static bool
sha_valid(const char *sha)
{
    if (strlen(sha) != 64)
        return false;
    for (const char *p = sha; *p; p++)
        if (!((*p >= '0' && *p <= '9') || (*p >= 'a' && *p <= 'f')))
            return false;
    return true;
}

struct store_file *
store_file_begin(struct store *s, struct sf_err *err)
{
    struct store_file *f = mem_calloc(1, sizeof(*f));
    if (!f) {
        sf_err_set(err, SF_ENOMEM, "store: out of memory");
        return NULL;
    }
    f->s = s;
    snprintf(f->tmp, sizeof(f->tmp), "%s/files/tmp-XXXXXX", s->dir);
    f->fd = mkstemp(f->tmp);
    if (f->fd < 0) {
        sf_err_sys(err, "store: cannot create a file in '%s/files'", s->dir);
        free(f);
        return NULL;
    }
    f->md = EVP_MD_CTX_new();
    if (!f->md || EVP_DigestInit_ex(f->md, EVP_sha256(), NULL) != 1) {
        sf_err_set(err, SF_ENOMEM, "store: cannot start SHA-256");
        store_file_abort(f);
        return NULL;
    }
    return f;
}

int
store_file_write(struct store_file *f, const void *data, size_t len, struct sf_err *err)
{
    const char *p = data;
    if (EVP_DigestUpdate(f->md, data, len) != 1)
        return sf_err_set(err, SF_EBUG, "store: SHA-256 update failed");
    while (len > 0) {
        ssize_t w = write(f->fd, p, len);
        if (w < 0 && errno == EINTR)
            continue;
        if (w < 0)
            return sf_err_sys(err, "store: writing '%s'", f->tmp);
        p += w;
        len -= (size_t)w;
        f->size += w;
    }
    return SF_OK;
}

void
store_file_abort(struct store_file *f)
{
    if (!f)
        return;
    if (f->fd >= 0) {
        close(f->fd);
        unlink(f->tmp);
    }
    EVP_MD_CTX_free(f->md);
    free(f);
}

static void
fsync_dir(const char *path)
{
    int fd = open(path, O_RDONLY | O_DIRECTORY);
    if (fd >= 0) {
        fsync(fd);
        close(fd);
    }
}

/* The hex digest of md into sha. */
static int
sha_hex(EVP_MD_CTX *md, char sha[STORE_SHA_HEX], struct sf_err *err)
{
    unsigned char d[EVP_MAX_MD_SIZE];
    unsigned int n = 0;
    if (EVP_DigestFinal_ex(md, d, &n) != 1 || n != 32)
        return sf_err_set(err, SF_EBUG, "store: SHA-256 final failed");
    for (int i = 0; i < 32; i++)
        snprintf(sha + 2 * i, 3, "%02x", d[i]);
    return SF_OK;
}

/* Make the file at from (open as fd) durable and move it to sha's address.  Touches the file
   system only: s->dir is fixed at open, so this may run on any thread. */
static int
place_file(const struct store *s, int fd, const char *from, const char *sha, struct sf_err *err)
{
    if (fsync(fd) != 0)
        return sf_err_sys(err, "store: fsync '%s'", from);
    char dir[STORE_PATH_MAX + 16], path[STORE_PATH_MAX + 96];
    snprintf(dir, sizeof(dir), "%s/files/%.2s", s->dir, sha);
    snprintf(path, sizeof(path), "%s/%s", dir, sha);
    if (mkdir(dir, 0755) != 0 && errno != EEXIST)
        return sf_err_sys(err, "store: cannot create '%s'", dir);
    if (rename(from, path) != 0)
        return sf_err_sys(err, "store: cannot move '%s' to '%s'", from, path);
    fsync_dir(dir);
    return SF_OK;
}

int
store_file_record(struct store *s, const char *sha, int64_t size, struct sf_err *err)
{
    if (!sha_valid(sha))
        return sf_err_set(err, SF_EINVAL, "store: '%.80s' is not a SHA-256 in hex", sha);
    sqlite3_stmt *st;
    int rc =
        prepare(s, &st, "INSERT OR IGNORE INTO files(sha256, size, created_ms) VALUES(?,?,?)", err);
    if (rc)
        return rc;
    sqlite3_bind_text(st, 1, sha, 64, SQLITE_TRANSIENT);
    sqlite3_bind_int64(st, 2, size);
    sqlite3_bind_int64(st, 3, now_ms());
    return step_done(s, st, err, "record file");
}

int
store_file_commit(struct store_file *f, char sha[STORE_SHA_HEX], struct sf_err *err)
{
    int rc = sha_hex(f->md, sha, err);
    if (rc == SF_OK && (rc = place_file(f->s, f->fd, f->tmp, sha, err)) == SF_OK) {
        close(f->fd);
        f->fd = -1;
        rc = store_file_record(f->s, sha, f->size, err);
    }
    store_file_abort(f);
    return rc;
}

int
store_file_adopt(const struct store *s, const char *path, char sha[STORE_SHA_HEX], int64_t *size,
                 struct sf_err *err)
{
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0)
        return sf_err_sys(err, "store: cannot read '%s'", path);
    EVP_MD_CTX *md = EVP_MD_CTX_new();
    int rc = md && EVP_DigestInit_ex(md, EVP_sha256(), NULL) == 1
                 ? SF_OK
                 : sf_err_set(err, SF_ENOMEM, "store: cannot start SHA-256");
    char buf[1 << 16];
    ssize_t n;
    *size = 0;
    while (rc == SF_OK && (n = read(fd, buf, sizeof(buf))) != 0) {
        if (n < 0 && errno == EINTR)
            continue;
        if (n < 0)
            rc = sf_err_sys(err, "store: reading '%s'", path);
        else if (EVP_DigestUpdate(md, buf, (size_t)n) != 1)
            rc = sf_err_set(err, SF_EBUG, "store: SHA-256 update failed");
        else
            *size += n;
    }
    if (rc == SF_OK && (rc = sha_hex(md, sha, err)) == SF_OK)
        rc = place_file(s, fd, path, sha, err);
    EVP_MD_CTX_free(md);
    close(fd);
    return rc;
}

int
store_file_put(struct store *s, const void *data, size_t len, char sha[STORE_SHA_HEX],
               struct sf_err *err)
{
    struct store_file *f = store_file_begin(s, err);
    if (!f)
        return err ? err->code : SF_EIO;
    int rc = store_file_write(f, data, len, err);
    if (rc) {
        store_file_abort(f);
        return rc;
    }
    return store_file_commit(f, sha, err);
}

static bool
file_known(struct store *s, const char *sha)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(s->db, "SELECT 1 FROM files WHERE sha256 = ?", -1, &st, NULL))
        return false;
    sqlite3_bind_text(st, 1, sha, -1, SQLITE_TRANSIENT);
    bool found = sqlite3_step(st) == SQLITE_ROW;
    sqlite3_finalize(st);
    return found;
}

int
store_file_path(struct store *s, const char *sha, char *path, size_t cap, struct sf_err *err)
{
    if (!sha_valid(sha))
        return sf_err_set(err, SF_EINVAL, "store: '%.80s' is not a SHA-256 in hex", sha);
    if (!file_known(s, sha))
        return sf_err_set(err, SF_ENOTFOUND, "store: no file %s", sha);
    if ((size_t)snprintf(path, cap, "%s/files/%.2s/%s", s->dir, sha, sha) >= cap)
        return sf_err_set(err, SF_ENOMEM, "store: path of file %s is too long", sha);
    return SF_OK;
}

/* ---- jobs ---- */

static void
read_job(sqlite3_stmt *st, struct job_row *j)
{
    memset(j, 0, sizeof(*j));
    j->id = sqlite3_column_int64(st, 0);
    copy_text(j->opts.name, sizeof(j->opts.name), st, 1);
    copy_text(j->file_sha, sizeof(j->file_sha), st, 2);
    copy_text(j->gcode_sha, sizeof(j->gcode_sha), st, 3);
    char state[16];
    copy_text(state, sizeof(state), st, 4);
    if (!job_state_parse(state, &j->state))
        j->state = JOB_FAILED; /* the CHECK constraint makes this unreachable */
    copy_text(j->opts.method, sizeof(j->opts.method), st, 5);
    j->opts.deviation_mm = sqlite3_column_double(st, 6);
    j->opts.overhang_deg = sqlite3_column_double(st, 7);
    j->opts.copies = j->counts.copies = sqlite3_column_int(st, 8);
    j->counts.copies_done = sqlite3_column_int(st, 9);
    j->counts.failures = sqlite3_column_int(st, 10);
    j->opts.max_retries = j->counts.max_retries = sqlite3_column_int(st, 11);
    copy_text(j->opts.material, sizeof(j->opts.material), st, 12);
    copy_text(j->opts.printer, sizeof(j->opts.printer), st, 13);
    copy_text(j->opts.group, sizeof(j->opts.group), st, 14);
    j->opts.priority = sqlite3_column_int(st, 15);
    for (int i = 0; i < 3; i++)
        j->size_mm[i] = sqlite3_column_double(st, 16 + i);
    copy_text(j->printer, sizeof(j->printer), st, 19);
    j->lines_acked = sqlite3_column_int64(st, 20);
    copy_text(j->reason, sizeof(j->reason), st, 21);
    j->created_ms = sqlite3_column_int64(st, 22);
    j->updated_ms = sqlite3_column_int64(st, 23);
    j->nozzle_mm = sqlite3_column_double(st, 24);
    j->gcode_lines = sqlite3_column_int64(st, 25);
    copy_text(j->prep_key, sizeof(j->prep_key), st, 26);
    copy_text(j->mesh_sha, sizeof(j->mesh_sha), st, 27);
    j->mesh_angle_deg = sqlite3_column_double(st, 28);
    j->filament_g = sqlite3_column_double(st, 29);
    j->support_g = sqlite3_column_double(st, 30);
    j->support_saved_g = sqlite3_column_double(st, 31);
    j->prepare_ms = sqlite3_column_int64(st, 32);
    j->slice_ms = sqlite3_column_int64(st, 33);
    j->ready_ms = sqlite3_column_int64(st, 34);
    j->dev_measured = sqlite3_column_type(st, 35) != SQLITE_NULL;
    j->mndr = sqlite3_column_double(st, 35);
    j->andr = sqlite3_column_double(st, 36);
    j->shape_changed = sqlite3_column_int(st, 37) != 0;
}

static void
read_job_row(sqlite3_stmt *st, void *row)
{
    read_job(st, row);
}

const char *
store_file_tmp_path(const struct store_file *f)
{
    return f->tmp;
}

int
store_job_add(struct store *s, const struct job_opts *o, const char *file_sha, int64_t *id,
              struct sf_err *err)
{
    int rc = job_opts_validate(o, err);
    if (rc)
        return rc;
    if (!sha_valid(file_sha) || !file_known(s, file_sha))
        return sf_err_set(err, SF_ENOTFOUND, "store: part file '%.80s' is not stored", file_sha);
    if ((rc = begin(s, err)))
        return rc;
    sqlite3_stmt *st;
    if ((rc = prepare(s, &st,
                      "INSERT INTO jobs(name, file_sha, state, method, deviation_mm, overhang_deg,"
                      " copies, max_retries, material, target_printer, target_group, priority,"
                      " created_ms, updated_ms) VALUES(?,?,'queued',?,?,?,?,?,?,?,?,?,?,?)",
                      err)))
        goto fail;
    int64_t t = now_ms();
    sqlite3_bind_text(st, 1, o->name, -1, SQLITE_TRANSIENT);
    sqlite3_bind_text(st, 2, file_sha, -1, SQLITE_TRANSIENT);
    sqlite3_bind_text(st, 3, o->method, -1, SQLITE_TRANSIENT);
    sqlite3_bind_double(st, 4, o->deviation_mm);
    sqlite3_bind_double(st, 5, o->overhang_deg);
    sqlite3_bind_int(st, 6, o->copies);
    sqlite3_bind_int(st, 7, o->max_retries);
    sqlite3_bind_text(st, 8, o->material, -1, SQLITE_TRANSIENT);
    sqlite3_bind_text(st, 9, o->printer, -1, SQLITE_TRANSIENT);
    sqlite3_bind_text(st, 10, o->group, -1, SQLITE_TRANSIENT);
    sqlite3_bind_int(st, 11, o->priority);
    sqlite3_bind_int64(st, 12, t);
    sqlite3_bind_int64(st, 13, t);
    if ((rc = step_done(s, st, err, "add job")))
        goto fail;
    int64_t new_id = sqlite3_last_insert_rowid(s->db);
    char detail[192];
    snprintf(detail, sizeof(detail), "queued '%s' x%d", o->name, o->copies);
    if ((rc = log_event(s, new_id, NULL, "job-add", detail, err)) || (rc = commit(s, err)))
        goto fail;
    if (id)
        *id = new_id;
    return SF_OK;
fail:
    rollback(s);
    return rc;
}

int
store_job_add_gcode(struct store *s, const struct job_opts *o, const char *sha,
                    const struct job_event_args *g, int64_t *id, struct sf_err *err)
{
    struct job_opts v = *o;
    snprintf(v.method, sizeof(v.method), "none"); /* validate the rest as any job's */
    int rc = job_opts_validate(&v, err);
    if (rc)
        return rc;
    if (!sha_valid(sha) || !file_known(s, sha))
        return sf_err_set(err, SF_ENOTFOUND, "store: G-code file '%.80s' is not stored", sha);
    if (!g->prep_key || !g->prep_key[0])
        return sf_err_set(err, SF_EINVAL, "store: G-code job '%s' has no key", o->name);
    if ((rc = begin(s, err)))
        return rc;
    sqlite3_stmt *st;
    if ((rc = prepare(s, &st,
                      "INSERT INTO jobs(name, file_sha, gcode_sha, state, method, deviation_mm,"
                      " overhang_deg, copies, max_retries, material, target_printer, target_group,"
                      " priority, created_ms, updated_ms, nozzle_mm, gcode_lines, prep_key,"
                      " filament_g, support_g, ready_ms)"
                      " VALUES(?,?,?,'ready','gcode',0,0,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                      err)))
        goto fail;
    int64_t t = now_ms();
    sqlite3_bind_text(st, 1, o->name, -1, SQLITE_TRANSIENT);
    sqlite3_bind_text(st, 2, sha, -1, SQLITE_TRANSIENT);
    sqlite3_bind_text(st, 3, sha, -1, SQLITE_TRANSIENT);
    sqlite3_bind_int(st, 4, o->copies);
    sqlite3_bind_int(st, 5, o->max_retries);
    sqlite3_bind_text(st, 6, o->material, -1, SQLITE_TRANSIENT);
    sqlite3_bind_text(st, 7, o->printer, -1, SQLITE_TRANSIENT);
    sqlite3_bind_text(st, 8, o->group, -1, SQLITE_TRANSIENT);
    sqlite3_bind_int(st, 9, o->priority);
    sqlite3_bind_int64(st, 10, t);
    sqlite3_bind_int64(st, 11, t);
    sqlite3_bind_double(st, 12, g->nozzle_mm);
    sqlite3_bind_int64(st, 13, g->gcode_lines > 0 ? g->gcode_lines : 0);
    sqlite3_bind_text(st, 14, g->prep_key, -1, SQLITE_TRANSIENT);
    sqlite3_bind_double(st, 15, g->filament_g);
    sqlite3_bind_double(st, 16, g->support_g);
    sqlite3_bind_int64(st, 17, t);
    if ((rc = step_done(s, st, err, "add G-code job")))
        goto fail;
    int64_t new_id = sqlite3_last_insert_rowid(s->db);
    char detail[192];
    snprintf(detail, sizeof(detail), "ready '%s' x%d (G-code as uploaded, for %s)", o->name,
             o->copies, g->prep_key);
    if ((rc = log_event(s, new_id, NULL, "job-add", detail, err)) || (rc = commit(s, err)))
        goto fail;
    if (id)
        *id = new_id;
    return SF_OK;
fail:
    rollback(s);
    return rc;
}

static void
read_print_stat(sqlite3_stmt *st, void *row)
{
    struct print_stat *p = row;
    memset(p, 0, sizeof(*p));
    copy_text(p->printer, sizeof(p->printer), st, 0);
    copy_text(p->outcome, sizeof(p->outcome), st, 1);
    p->started_ms = sqlite3_column_int64(st, 2);
    p->ended_ms = sqlite3_column_int64(st, 3);
    p->wait_ms = sqlite3_column_int64(st, 4);
    p->filament_g = sqlite3_column_double(st, 5);
    p->support_saved_g = sqlite3_column_double(st, 6);
}

int
store_print_stats(struct store *s, struct print_stat **rows, size_t *n, struct sf_err *err)
{
    sqlite3_stmt *st;
    *rows = NULL;
    *n = 0;
    int rc = prepare(s, &st,
                     "SELECT p.printer, p.outcome, p.started_ms, p.ended_ms, p.wait_ms,"
                     " j.filament_g, j.support_saved_g FROM prints p JOIN jobs j ON j.id = p.job_id"
                     " ORDER BY p.id",
                     err);
    if (rc)
        return rc;
    return read_rows(s, st, sizeof(**rows), read_print_stat, (void **)rows, n, "print stats", err);
}

int
store_job_get(struct store *s, int64_t id, struct job_row *out, struct sf_err *err)
{
    char sql[sizeof(JOB_COLS) + 48];
    snprintf(sql, sizeof(sql), "SELECT %s FROM jobs WHERE id = ?", JOB_COLS);
    sqlite3_stmt *st;
    int rc = prepare(s, &st, sql, err);
    if (rc)
        return rc;
    sqlite3_bind_int64(st, 1, id);
    rc = sqlite3_step(st);
    if (rc == SQLITE_ROW)
        read_job(st, out);
    sqlite3_finalize(st);
    if (rc == SQLITE_ROW)
        return SF_OK;
    if (rc == SQLITE_DONE)
        return sf_err_set(err, SF_ENOTFOUND, "job %lld: no such job", (long long)id);
    return db_fail(s, err, "get job");
}

int
store_job_list(struct store *s, struct job_row **rows, size_t *n, struct sf_err *err)
{
    char sql[sizeof(JOB_COLS) + 48];
    snprintf(sql, sizeof(sql), "SELECT %s FROM jobs ORDER BY id", JOB_COLS);
    sqlite3_stmt *st;
    *rows = NULL;
    *n = 0;
    int rc = prepare(s, &st, sql, err);
    if (rc)
        return rc;
    return read_rows(s, st, sizeof(**rows), read_job_row, (void **)rows, n, "list jobs", err);
}

/* Close the job's open print with an outcome. */
static int
close_print(struct store *s, int64_t job_id, const char *outcome, int64_t lines_acked,
            double filament_mm, struct sf_err *err)
{
    sqlite3_stmt *st;
    int rc = prepare(s, &st,
                     "UPDATE prints SET ended_ms = ?, outcome = ?, lines_acked = ?,"
                     " filament_mm = ? WHERE job_id = ? AND outcome = ''",
                     err);
    if (rc)
        return rc;
    sqlite3_bind_int64(st, 1, now_ms());
    sqlite3_bind_text(st, 2, outcome, -1, SQLITE_STATIC);
    sqlite3_bind_int64(st, 3, lines_acked);
    sqlite3_bind_double(st, 4, filament_mm);
    sqlite3_bind_int64(st, 5, job_id);
    return step_done(s, st, err, "close print");
}

static int
open_print(struct store *s, const struct job_row *j, const char *printer, int64_t start_line,
           struct sf_err *err)
{
    sqlite3_stmt *st;
    int rc = prepare(s, &st,
                     "INSERT INTO prints(job_id, copy, printer, material, start_line,"
                     " lines_acked, started_ms, wait_ms) VALUES(?,?,?,?,?,?,?,?)",
                     err);
    if (rc)
        return rc;
    sqlite3_bind_int64(st, 1, j->id);
    sqlite3_bind_int(st, 2, j->counts.copies_done + 1);
    sqlite3_bind_text(st, 3, printer, -1, SQLITE_TRANSIENT);
    sqlite3_bind_text(st, 4, j->opts.material, -1, SQLITE_TRANSIENT);
    sqlite3_bind_int64(st, 5, start_line);
    sqlite3_bind_int64(st, 6, start_line);
    int64_t t = now_ms();
    sqlite3_bind_int64(st, 7, t);
    /* a resume of an interrupted print waited for the operator, not in the queue */
    sqlite3_bind_int64(
        st, 8, j->state == JOB_READY && j->ready_ms > 0 && t > j->ready_ms ? t - j->ready_ms : 0);
    return step_done(s, st, err, "open print");
}

/* Fill in j (already read) for the move from j->state to `to` by ev. */
static int
apply_event(struct store *s, struct job_row *j, enum job_event ev, const struct job_event_args *a,
            enum job_state to, struct sf_err *err)
{
    enum job_state from = j->state;
    int rc = SF_OK;
    char printer[sizeof(j->printer)]; /* a copy: j->printer is overwritten below */
    snprintf(printer, sizeof(printer), "%s", a->printer && a->printer[0] ? a->printer : j->printer);
    switch (ev) {
    case JOB_EV_PREPARED:
        if (!a->gcode_sha || !sha_valid(a->gcode_sha) || !file_known(s, a->gcode_sha))
            return sf_err_set(err, SF_EINVAL, "job %lld: prepared without stored G-code",
                              (long long)j->id);
        snprintf(j->gcode_sha, sizeof(j->gcode_sha), "%s", a->gcode_sha);
        for (int i = 0; i < 3; i++)
            j->size_mm[i] = a->size_mm[i];
        j->nozzle_mm = a->nozzle_mm;
        j->gcode_lines = a->gcode_lines > 0 ? a->gcode_lines : 0;
        snprintf(j->prep_key, sizeof(j->prep_key), "%s", a->prep_key ? a->prep_key : "");
        if (a->mesh_sha && a->mesh_sha[0]) {
            if (!sha_valid(a->mesh_sha) || !file_known(s, a->mesh_sha))
                return sf_err_set(err, SF_EINVAL, "job %lld: optimized part is not stored",
                                  (long long)j->id);
            snprintf(j->mesh_sha, sizeof(j->mesh_sha), "%s", a->mesh_sha);
            j->mesh_angle_deg = a->mesh_angle_deg;
        }
        j->filament_g = a->filament_g;
        j->support_g = a->support_g;
        j->support_saved_g = a->saved_g;
        j->prepare_ms = a->prepare_ms;
        j->slice_ms = a->slice_ms;
        if (a->dev_measured || (a->mesh_sha && a->mesh_sha[0])) {
            j->dev_measured = a->dev_measured; /* a fresh preparation: measured or not */
            j->shape_changed = a->dev_measured && a->shape_changed;
            j->mndr = a->dev_measured && a->mndr > 0 ? a->mndr : 0;
            j->andr = a->dev_measured && a->andr > 0 ? a->andr : 0;
        }
        j->reason[0] = '\0';
        break;
    case JOB_EV_START:
    case JOB_EV_RESUME:
        if (ev == JOB_EV_RESUME && from == JOB_PAUSED)
            break;
        if (!printer[0])
            return sf_err_set(err, SF_EINVAL, "job %lld: %s needs a printer", (long long)j->id,
                              job_event_name(ev));
        if (ev == JOB_EV_START)
            j->lines_acked = 0;
        else if (a->lines_acked > 0)
            j->lines_acked = a->lines_acked; /* the operator chose where to resume */
        rc = open_print(s, j, printer, j->lines_acked, err);
        snprintf(j->printer, sizeof(j->printer), "%s", printer);
        j->reason[0] = '\0';
        break;
    case JOB_EV_PAUSE:
        if (a->lines_acked > j->lines_acked)
            j->lines_acked = a->lines_acked;
        break;
    case JOB_EV_PRINT_DONE:
    case JOB_EV_PRINT_FAILED:
    case JOB_EV_CANCEL:
    case JOB_EV_REFUSED:
        if (a->lines_acked > j->lines_acked)
            j->lines_acked = a->lines_acked;
        if (job_state_on_printer(from))
            rc = close_print(s, j->id,
                             ev == JOB_EV_PRINT_DONE     ? "done"
                             : ev == JOB_EV_PRINT_FAILED ? "failed"
                             : ev == JOB_EV_REFUSED      ? "refused"
                                                         : "cancelled",
                             j->lines_acked, a->filament_mm, err);
        j->printer[0] = '\0';
        j->lines_acked = 0;
        snprintf(j->reason, sizeof(j->reason), "%s", a->reason ? a->reason : "");
        break;
    case JOB_EV_CRASHED:
        if (job_state_on_printer(from))
            rc = close_print(s, j->id, "interrupted", j->lines_acked, 0, err);
        snprintf(j->reason, sizeof(j->reason), "%s", a->reason ? a->reason : "");
        break;
    case JOB_EV_RESTART:
        j->printer[0] = '\0';
        j->lines_acked = 0;
        j->reason[0] = '\0';
        break;
    case JOB_EV_PREPARE_FAILED:
    case JOB_EV_DEFER:
        snprintf(j->reason, sizeof(j->reason), "%s", a->reason ? a->reason : "");
        break;
    case JOB_EV_PREPARE:
        break;
    }
    if (to == JOB_READY && from != JOB_READY)
        j->ready_ms = now_ms(); /* a print's queue wait starts here */
    j->state = to;
    return rc;
}

int
store_job_event(struct store *s, int64_t id, enum job_event ev, const struct job_event_args *a,
                enum job_state *to, struct sf_err *err)
{
    static const struct job_event_args none;
    if (!a)
        a = &none;
    int rc = begin(s, err);
    if (rc)
        return rc;
    struct job_row j;
    if ((rc = store_job_get(s, id, &j, err)))
        goto fail;
    enum job_state from = j.state, next;
    struct job_counts c = j.counts;
    if ((rc = job_next(from, ev, &c, &next, err))) {
        sf_err_prefix(err, "job %lld", (long long)id);
        goto fail;
    }
    j.counts = c;
    if ((rc = apply_event(s, &j, ev, a, next, err)))
        goto fail;
    sqlite3_stmt *st;
    if ((rc = prepare(s, &st,
                      "UPDATE jobs SET state = ?, copies_done = ?, failures = ?, gcode_sha = ?,"
                      " size_x = ?, size_y = ?, size_z = ?, printer = ?, lines_acked = ?,"
                      " reason = ?, updated_ms = ?, nozzle_mm = ?, gcode_lines = ?, prep_key = ?,"
                      " mesh_sha = ?, mesh_angle_deg = ?, filament_g = ?, support_g = ?,"
                      " support_saved_g = ?, prepare_ms = ?, slice_ms = ?, ready_ms = ?,"
                      " mndr = ?, andr = ?, shape_changed = ? WHERE id = ?",
                      err)))
        goto fail;
    sqlite3_bind_text(st, 1, job_state_name(j.state), -1, SQLITE_STATIC);
    sqlite3_bind_int(st, 2, j.counts.copies_done);
    sqlite3_bind_int(st, 3, j.counts.failures);
    if (j.gcode_sha[0])
        sqlite3_bind_text(st, 4, j.gcode_sha, -1, SQLITE_TRANSIENT);
    else
        sqlite3_bind_null(st, 4);
    for (int i = 0; i < 3; i++)
        sqlite3_bind_double(st, 5 + i, j.size_mm[i]);
    sqlite3_bind_text(st, 8, j.printer, -1, SQLITE_TRANSIENT);
    sqlite3_bind_int64(st, 9, j.lines_acked);
    sqlite3_bind_text(st, 10, j.reason, -1, SQLITE_TRANSIENT);
    sqlite3_bind_int64(st, 11, now_ms());
    sqlite3_bind_double(st, 12, j.nozzle_mm);
    sqlite3_bind_int64(st, 13, j.gcode_lines);
    sqlite3_bind_text(st, 14, j.prep_key, -1, SQLITE_TRANSIENT);
    sqlite3_bind_text(st, 15, j.mesh_sha, -1, SQLITE_TRANSIENT);
    sqlite3_bind_double(st, 16, j.mesh_angle_deg);
    sqlite3_bind_double(st, 17, j.filament_g);
    sqlite3_bind_double(st, 18, j.support_g);
    sqlite3_bind_double(st, 19, j.support_saved_g);
    sqlite3_bind_int64(st, 20, j.prepare_ms);
    sqlite3_bind_int64(st, 21, j.slice_ms);
    sqlite3_bind_int64(st, 22, j.ready_ms);
    if (j.dev_measured) {
        sqlite3_bind_double(st, 23, j.mndr);
        sqlite3_bind_double(st, 24, j.andr);
    } else {
        sqlite3_bind_null(st, 23);
        sqlite3_bind_null(st, 24);
    }
    sqlite3_bind_int(st, 25, j.shape_changed);
    sqlite3_bind_int64(st, 26, id);
    if ((rc = step_done(s, st, err, "update job")))
        goto fail;
    char kind[24], detail[192];
    const char *why = j.reason[0] ? j.reason : ev == JOB_EV_PREPARED && a->note ? a->note : "";
    snprintf(kind, sizeof(kind), "job-%s", job_event_name(ev));
    snprintf(detail, sizeof(detail), "%s -> %s%s%s", job_state_name(from), job_state_name(j.state),
             why[0] ? ": " : "", why);
    if ((rc = log_event(s, id, j.printer, kind, detail, err)) || (rc = commit(s, err)))
        goto fail;
    if (to)
        *to = j.state;
    return SF_OK;
fail:
    rollback(s);
    return rc;
}

static int
update_job_field(struct store *s, int64_t id, const char *sql, sqlite3_int64 ival, const char *tval,
                 struct sf_err *err)
{
    sqlite3_stmt *st;
    int rc = prepare(s, &st, sql, err);
    if (rc)
        return rc;
    if (tval)
        sqlite3_bind_text(st, 1, tval, -1, SQLITE_TRANSIENT);
    else
        sqlite3_bind_int64(st, 1, ival);
    sqlite3_bind_int64(st, 2, now_ms());
    sqlite3_bind_int64(st, 3, id);
    rc = sqlite3_step(st);
    sqlite3_finalize(st);
    if (rc != SQLITE_DONE)
        return db_fail(s, err, "update job");
    if (sqlite3_changes(s->db) == 0)
        return sf_err_set(err, SF_ENOTFOUND, "job %lld: no such job", (long long)id);
    return SF_OK;
}

int
store_job_progress(struct store *s, int64_t id, int64_t lines_acked, struct sf_err *err)
{
    int rc = update_job_field(s, id,
                              "UPDATE jobs SET lines_acked = max(lines_acked, ?), updated_ms = ?"
                              " WHERE id = ? AND state IN ('printing', 'paused')",
                              lines_acked, NULL, err);
    if (rc == SF_ENOTFOUND)
        return sf_err_set(err, SF_EINVAL, "job %lld: not printing", (long long)id);
    return rc;
}

static int store_jobs_progress_tx(struct store *s, struct store_progress *p, size_t n,
                                  struct sf_err *err);

int
store_jobs_progress(struct store *s, struct store_progress *p, size_t n, struct sf_err *err)
{
    /* Progress commits do not fsync (WAL with synchronous=NORMAL: they
       survive a kill -9, and the next state change's fsync carries them to
       disk); state changes stay FULL. */
    sqlite3_exec(s->db, "PRAGMA synchronous = NORMAL", NULL, NULL, NULL);
    int rc = store_jobs_progress_tx(s, p, n, err);
    sqlite3_exec(s->db, "PRAGMA synchronous = FULL", NULL, NULL, NULL);
    return rc;
}

static int
store_jobs_progress_tx(struct store *s, struct store_progress *p, size_t n, struct sf_err *err)
{
    int rc = begin(s, err);
    if (rc)
        return rc;
    int saved = 0;
    for (size_t i = 0; i < n; i++) {
        rc = update_job_field(s, p[i].job_id,
                              "UPDATE jobs SET lines_acked = max(lines_acked, ?), updated_ms = ?"
                              " WHERE id = ? AND state IN ('printing', 'paused')",
                              p[i].lines_acked, NULL, err);
        if (rc && rc != SF_ENOTFOUND) {
            rollback(s);
            return rc;
        }
        p[i].saved = rc == SF_OK;
        saved += p[i].saved;
    }
    if ((rc = commit(s, err))) {
        rollback(s);
        for (size_t i = 0; i < n; i++)
            p[i].saved = false;
        return rc;
    }
    return saved;
}

int
store_job_set_priority(struct store *s, int64_t id, int priority, struct sf_err *err)
{
    if (priority < -JOB_PRIORITY_MAX || priority > JOB_PRIORITY_MAX)
        return sf_err_set(err, SF_EINVAL, "priority: %d is not in -%d..%d", priority,
                          JOB_PRIORITY_MAX, JOB_PRIORITY_MAX);
    int rc = begin(s, err);
    if (rc)
        return rc;
    char detail[64];
    snprintf(detail, sizeof(detail), "priority %d", priority);
    if ((rc = update_job_field(s, id, "UPDATE jobs SET priority = ?, updated_ms = ? WHERE id = ?",
                               priority, NULL, err)) ||
        (rc = log_event(s, id, NULL, "job-priority", detail, err)) || (rc = commit(s, err))) {
        rollback(s);
        return rc;
    }
    return SF_OK;
}

int
store_job_set_reason(struct store *s, int64_t id, const char *reason, struct sf_err *err)
{
    int rc = update_job_field(s, id,
                              "UPDATE jobs SET reason = ?1, updated_ms = ?2"
                              " WHERE id = ?3 AND reason != ?1",
                              0, reason, err);
    return rc == SF_ENOTFOUND ? SF_OK : rc; /* unchanged, or gone: nothing to write */
}

/* ---- printers ---- */

int
store_printer_set(struct store *s, const char *name, enum printer_state state, struct sf_err *err)
{
    int rc = begin(s, err);
    if (rc)
        return rc;
    sqlite3_stmt *st;
    if ((rc = prepare(s, &st,
                      "INSERT INTO printers(name, state, updated_ms) VALUES(?1, ?2, ?3)"
                      " ON CONFLICT(name) DO UPDATE SET state = ?2, updated_ms = ?3",
                      err)))
        goto fail;
    sqlite3_bind_text(st, 1, name, -1, SQLITE_TRANSIENT);
    sqlite3_bind_text(st, 2, printer_state_name(state), -1, SQLITE_STATIC);
    sqlite3_bind_int64(st, 3, now_ms());
    if ((rc = step_done(s, st, err, "set printer")) ||
        (rc = log_event(s, 0, name, "printer-state", printer_state_name(state), err)) ||
        (rc = commit(s, err)))
        goto fail;
    return SF_OK;
fail:
    rollback(s);
    return rc;
}

int
store_printer_get(struct store *s, const char *name, enum printer_state *state, struct sf_err *err)
{
    sqlite3_stmt *st;
    int rc = prepare(s, &st, "SELECT state FROM printers WHERE name = ?", err);
    if (rc)
        return rc;
    sqlite3_bind_text(st, 1, name, -1, SQLITE_TRANSIENT);
    rc = sqlite3_step(st);
    bool ok = false;
    if (rc == SQLITE_ROW)
        ok = printer_state_parse((const char *)sqlite3_column_text(st, 0), state);
    sqlite3_finalize(st);
    if (rc == SQLITE_ROW)
        return ok ? SF_OK : sf_err_set(err, SF_EBUG, "printer '%s': unknown state", name);
    if (rc == SQLITE_DONE)
        return sf_err_set(err, SF_ENOTFOUND, "printer '%s': never seen", name);
    return db_fail(s, err, "get printer");
}

int
store_printer_bed_set(struct store *s, const char *name, bool full, struct sf_err *err)
{
    int rc = begin(s, err);
    if (rc)
        return rc;
    sqlite3_stmt *st;
    if ((rc =
             prepare(s, &st,
                     "INSERT INTO printers(name, state, updated_ms, bed_full) VALUES(?1, 'offline',"
                     " ?2, ?3) ON CONFLICT(name) DO UPDATE SET bed_full = ?3, updated_ms = ?2",
                     err)))
        goto fail;
    sqlite3_bind_text(st, 1, name, -1, SQLITE_TRANSIENT);
    sqlite3_bind_int64(st, 2, now_ms());
    sqlite3_bind_int(st, 3, full);
    if ((rc = step_done(s, st, err, "set printer bed")) ||
        (rc = log_event(s, 0, name, "printer-bed", full ? "holds a part" : "cleared", err)) ||
        (rc = commit(s, err)))
        goto fail;
    return SF_OK;
fail:
    rollback(s);
    return rc;
}

int
store_printer_bed_get(struct store *s, const char *name, bool *full, struct sf_err *err)
{
    sqlite3_stmt *st;
    int rc = prepare(s, &st, "SELECT bed_full FROM printers WHERE name = ?", err);
    if (rc)
        return rc;
    sqlite3_bind_text(st, 1, name, -1, SQLITE_TRANSIENT);
    rc = sqlite3_step(st);
    *full = rc == SQLITE_ROW && sqlite3_column_int(st, 0) != 0;
    sqlite3_finalize(st);
    if (rc == SQLITE_ROW || rc == SQLITE_DONE)
        return SF_OK;
    return db_fail(s, err, "get printer bed");
}

/* ---- history, events, checks ---- */

static void
read_print(sqlite3_stmt *st, void *row)
{
    struct print_row *p = row;
    p->id = sqlite3_column_int64(st, 0);
    p->job_id = sqlite3_column_int64(st, 1);
    p->copy = sqlite3_column_int(st, 2);
    copy_text(p->printer, sizeof(p->printer), st, 3);
    copy_text(p->material, sizeof(p->material), st, 4);
    p->start_line = sqlite3_column_int64(st, 5);
    p->lines_acked = sqlite3_column_int64(st, 6);
    p->filament_mm = sqlite3_column_double(st, 7);
    p->started_ms = sqlite3_column_int64(st, 8);
    p->ended_ms = sqlite3_column_int64(st, 9);
    copy_text(p->outcome, sizeof(p->outcome), st, 10);
}

int
store_prints(struct store *s, int64_t job_id, struct print_row **rows, size_t *n,
             struct sf_err *err)
{
    sqlite3_stmt *st;
    *rows = NULL;
    *n = 0;
    int rc = prepare(s, &st,
                     "SELECT id, job_id, copy, printer, material, start_line, lines_acked,"
                     " filament_mm, started_ms, ended_ms, outcome FROM prints WHERE job_id = ?"
                     " ORDER BY id",
                     err);
    if (rc)
        return rc;
    sqlite3_bind_int64(st, 1, job_id);
    return read_rows(s, st, sizeof(**rows), read_print, (void **)rows, n, "list prints", err);
}

static void
read_event(sqlite3_stmt *st, void *row)
{
    struct event_row *e = row;
    e->id = sqlite3_column_int64(st, 0);
    e->at_ms = sqlite3_column_int64(st, 1);
    e->job_id = sqlite3_column_int64(st, 2);
    copy_text(e->printer, sizeof(e->printer), st, 3);
    copy_text(e->kind, sizeof(e->kind), st, 4);
    copy_text(e->detail, sizeof(e->detail), st, 5);
}

int
store_events(struct store *s, int64_t after_id, size_t max, struct event_row **rows, size_t *n,
             struct sf_err *err)
{
    sqlite3_stmt *st;
    *rows = NULL;
    *n = 0;
    int rc = prepare(s, &st,
                     "SELECT id, at_ms, coalesce(job_id, 0), printer, kind, detail FROM events"
                     " WHERE id > ? ORDER BY id LIMIT ?",
                     err);
    if (rc)
        return rc;
    sqlite3_bind_int64(st, 1, after_id);
    sqlite3_bind_int64(st, 2, (sqlite3_int64)(max > INT64_MAX ? INT64_MAX : max));
    return read_rows(s, st, sizeof(**rows), read_event, (void **)rows, n, "list events", err);
}

int64_t
store_event_last(struct store *s)
{
    sqlite3_stmt *st;
    if (sqlite3_prepare_v2(s->db, "SELECT coalesce(max(id), 0) FROM events", -1, &st, NULL))
        return 0;
    int64_t id = sqlite3_step(st) == SQLITE_ROW ? sqlite3_column_int64(st, 0) : 0;
    sqlite3_finalize(st);
    return id;
}

/* Run a query whose first row, if any, is a violation described by column 0. */
static int
check_none(struct store *s, const char *sql, const char *what, struct sf_err *err)
{
    sqlite3_stmt *st;
    int rc = prepare(s, &st, sql, err);
    if (rc)
        return rc;
    rc = sqlite3_step(st);
    if (rc == SQLITE_ROW) {
        const unsigned char *t = sqlite3_column_text(st, 0);
        sf_err_set(err, SF_EBUG, "store check: %s: %s", what, t ? (const char *)t : "?");
    }
    sqlite3_finalize(st);
    if (rc == SQLITE_ROW)
        return SF_EBUG;
    return rc == SQLITE_DONE ? SF_OK : db_fail(s, err, what);
}

int
store_check(struct store *s, struct sf_err *err)
{
    sqlite3_stmt *st;
    int rc = prepare(s, &st, "PRAGMA integrity_check", err);
    if (rc)
        return rc;
    bool ok = sqlite3_step(st) == SQLITE_ROW &&
              strcmp((const char *)sqlite3_column_text(st, 0), "ok") == 0;
    sqlite3_finalize(st);
    if (!ok)
        return sf_err_set(err, SF_EBUG, "store check: integrity_check failed");
    static const struct {
        const char *what, *sql;
    } checks[] = {
        { "foreign key", "SELECT \"table\" || ' row ' || rowid FROM pragma_foreign_key_check" },
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
    for (size_t i = 0; i < sizeof(checks) / sizeof(checks[0]); i++)
        if ((rc = check_none(s, checks[i].sql, checks[i].what, err)))
            return rc;
    return SF_OK;
}
