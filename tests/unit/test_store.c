/*
 * test_store.c - the job store on real files: schema and migrations,
 * content-addressed files, every job event with its history and log, crash
 * recovery, and a kill -9 test: a child process hammering the store is
 * SIGKILLed mid-transaction again and again, and each reopen must find a
 * consistent store with every acknowledged job present.  I/O faults come
 * from a VFS that fails the Nth read (Debian's SQLite has no
 * sqlite3_test_control fault hooks): recovery and every listing must fail
 * or return all their rows, never part of them as success.  With
 * SLIMFARM_TEST_STORE (tstore.h) every case that does not read SQLite's
 * file itself runs on PostgreSQL.
 */
#include <signal.h>
#include <sqlite3.h>
#include <stdint.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "../../src/base/buf.h"
#include "../../src/base/mem.h"
#include "../../src/farm/store.h"
#include "../../src/farm/store_host.h"
#include "../t.h"
#include "../tstore.h"

/* Leave a case that reads or breaks SQLite's file itself when the run is on PostgreSQL. */
#define SQLITE_ONLY()                                                                              \
    do {                                                                                           \
        if (t_store_pg()) {                                                                        \
            t_skip("reads SQLite's file");                                                         \
            return;                                                                                \
        }                                                                                          \
    } while (0)

/* A fresh data dir per case, under the program's scratch dir. */
static const char *
fresh_dir(const char *name)
{
    static char path[512];
    snprintf(path, sizeof(path), "%s/%s", t_tmpdir(), name);
    return path;
}

static struct job_opts
opts(const char *name, int copies)
{
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "%s", name);
    o.copies = copies;
    return o;
}

/* Add a job for some part bytes and return its id (0 on failure). */
static int64_t
add_job(struct store *s, const char *part, int copies, struct sf_err *err)
{
    char sha[STORE_SHA_HEX];
    int64_t id = 0;
    struct job_opts o = opts("part.stl", copies);
    if (store_file_put(s, part, strlen(part), sha, err) || store_job_add(s, &o, sha, &id, err))
        return 0;
    return id;
}

/* Move a queued job to ready with some G-code. */
static int
make_ready(struct store *s, int64_t id, struct sf_err *err)
{
    char sha[STORE_SHA_HEX];
    int rc = store_job_event(s, id, JOB_EV_PREPARE, NULL, NULL, err);
    if (rc || (rc = store_file_put(s, "G28\nG1 X1\n", 10, sha, err)))
        return rc;
    struct job_event_args a = { .gcode_sha = sha, .size_mm = { 20, 30, 40 } };
    return store_job_event(s, id, JOB_EV_PREPARED, &a, NULL, err);
}

/* Either engine: the schema version is this program's, and a newer one is refused. */
T_CASE(store_schema_version_is_kept_and_a_newer_one_refused)
{
    struct sf_err err;
    const char *dir = fresh_dir("version");
    struct store *s = t_store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    store_close(s);
    const char *get = t_store_pg() ? "SELECT version FROM schema_version" : "PRAGMA user_version";
    T_EQ_INT(t_store_int(dir, get), store_schema_version());
    /* opened again: nothing to migrate, one version row */
    T_TRUE((s = t_store_open(dir, NULL, &err)) != NULL);
    store_close(s);
    T_EQ_INT(t_store_int(dir, get), store_schema_version());
    T_OK(t_store_exec(dir, t_store_pg() ? "UPDATE schema_version SET version = 99"
                                        : "PRAGMA user_version = 99"),
         NULL);
    T_TRUE(t_store_open(dir, NULL, &err) == NULL);
    T_EQ_INT(err.code, SF_EUNSUPP);
    T_TRUE(strstr(err.msg, "schema 99 is newer") != NULL);
    /* store_init (slimfarmd --init-store) refuses it too, and makes a new one */
    T_EQ_INT(store_init(t_store_pg() ? t_store_db(dir) : dir, NULL, &err), SF_EUNSUPP);
    const char *fresh = fresh_dir("version-init");
    int from = -1;
    T_OK(store_init(t_store_pg() ? t_store_db(fresh) : fresh, &from, &err), &err);
    T_EQ_INT(from, 0);
    T_EQ_INT(t_store_int(fresh, get), store_schema_version());
    T_OK(store_init(t_store_pg() ? t_store_db(fresh) : fresh, &from, &err), &err);
    T_EQ_INT(from, store_schema_version());
}

/* PostgreSQL: a second single-host daemon on the same database (another data dir, so no flock
   stops it) is refused, as its crash recovery would take the first one's printing jobs; hosts
   (store_open_host) share a database, but never with a single-host daemon. */
T_CASE(store_one_daemon_per_database)
{
    if (!t_store_pg()) {
        t_skip("PostgreSQL only: SQLite's database is in the data dir, under its flock");
        return;
    }
    struct sf_err err;
    struct store *a = t_store_open(fresh_dir("db-lock-a"), NULL, &err);
    T_TRUE(a != NULL);
    char url[1024];
    snprintf(url, sizeof(url), "%s", t_store_db(fresh_dir("db-lock-a")));
    struct store *b = store_open_db(fresh_dir("db-lock-b"), url, NULL, &err);
    T_TRUE(b == NULL);
    T_EQ_INT(err.code, SF_EAGAIN);
    T_TRUE(strstr(err.msg, "in use by another slimfarmd") != NULL);
    T_TRUE(store_open_host(fresh_dir("db-lock-b"), url, NULL, &err) == NULL);
    T_EQ_INT(err.code, SF_EAGAIN);
    T_TRUE(strstr(err.msg, "in use by a single-host slimfarmd") != NULL);
    store_close(a); /* its lock goes with its connection */
    /* two hosts at once; a single-host daemon is refused beside them */
    T_TRUE((a = store_open_host(fresh_dir("db-lock-a"), url, NULL, &err)) != NULL);
    T_TRUE((b = store_open_host(fresh_dir("db-lock-b"), url, NULL, &err)) != NULL);
    T_TRUE(store_open_db(fresh_dir("db-lock-c"), url, NULL, &err) == NULL);
    T_TRUE(strstr(err.msg, "in use by another slimfarmd") != NULL);
    store_close(a);
    store_close(b);
    T_TRUE((b = store_open_db(fresh_dir("db-lock-b"), url, NULL, &err)) != NULL);
    store_close(b);
}

T_CASE(store_open_creates_schema_in_wal_mode)
{
    SQLITE_ONLY();
    struct sf_err err;
    const char *dir = fresh_dir("open");
    struct store *s = t_store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    store_close(s);
    char path[600];
    snprintf(path, sizeof(path), "%s/slimfarm.db", dir);
    sqlite3 *db;
    T_EQ_INT(sqlite3_open(path, &db), SQLITE_OK);
    sqlite3_stmt *st;
    sqlite3_prepare_v2(db, "PRAGMA journal_mode", -1, &st, NULL);
    T_EQ_INT(sqlite3_step(st), SQLITE_ROW);
    T_EQ_STR((const char *)sqlite3_column_text(st, 0), "wal");
    sqlite3_finalize(st);
    sqlite3_prepare_v2(db, "PRAGMA user_version", -1, &st, NULL);
    T_EQ_INT(sqlite3_step(st), SQLITE_ROW);
    T_EQ_INT(sqlite3_column_int(st, 0), store_schema_version());
    sqlite3_finalize(st);
    /* a schema from the future is refused, not guessed at */
    sqlite3_exec(db, "PRAGMA user_version = 99", NULL, NULL, NULL);
    sqlite3_close(db);
    T_TRUE(t_store_open(dir, NULL, &err) == NULL);
    T_EQ_INT(err.code, SF_EUNSUPP);
    T_TRUE(strstr(err.msg, "schema 99 is newer") != NULL);
}

/*
 * Schema 2 keeps the G-code's command count with the job.  A schema-1
 * store (made here by dropping the column again) upgrades in place: its
 * ready job keeps everything, with the count 0 ("not known"), and the
 * next preparation stores one.
 */
T_CASE(store_migrates_schema_1_to_gcode_lines)
{
    SQLITE_ONLY();
    struct sf_err err;
    const char *dir = fresh_dir("migrate1");
    struct store *s = t_store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    int64_t id = add_job(s, "part", 1, &err);
    T_TRUE(id > 0);
    char sha[STORE_SHA_HEX];
    T_OK(store_job_event(s, id, JOB_EV_PREPARE, NULL, NULL, &err), &err);
    T_OK(store_file_put(s, "G28\nG1 X1\n", 10, sha, &err), &err);
    struct job_event_args a = { .gcode_sha = sha, .size_mm = { 20, 30, 40 }, .gcode_lines = 2 };
    T_OK(store_job_event(s, id, JOB_EV_PREPARED, &a, NULL, &err), &err);
    struct job_row j;
    T_OK(store_job_get(s, id, &j, &err), &err);
    T_EQ_INT(j.gcode_lines, 2);
    store_close(s);
    /* back to schema 1 */
    char path[600];
    snprintf(path, sizeof(path), "%s/slimfarm.db", dir);
    sqlite3 *db;
    T_EQ_INT(sqlite3_open(path, &db), SQLITE_OK);
    T_EQ_INT(sqlite3_exec(
                 db,
                 "DROP TABLE host_views; DROP TABLE host_printers; DROP TABLE hosts;"
                 "DROP INDEX jobs_claimed;"
                 "DROP INDEX jobs_claim_order; ALTER TABLE jobs DROP COLUMN claimed_by;"
                 "ALTER TABLE jobs DROP COLUMN fence;"
                 "ALTER TABLE jobs DROP COLUMN prep_key; ALTER TABLE jobs DROP COLUMN "
                 "mesh_sha; ALTER TABLE jobs DROP COLUMN mesh_angle_deg;"
                 "ALTER TABLE printers DROP COLUMN bed_full;"
                 "ALTER TABLE jobs DROP COLUMN gcode_lines;"
                 "ALTER TABLE jobs DROP COLUMN filament_g; ALTER TABLE jobs DROP COLUMN "
                 "support_g; ALTER TABLE jobs DROP COLUMN support_saved_g; ALTER TABLE "
                 "jobs DROP COLUMN prepare_ms; ALTER TABLE jobs DROP COLUMN slice_ms;"
                 "ALTER TABLE jobs DROP COLUMN ready_ms; ALTER TABLE prints DROP COLUMN "
                 "wait_ms; ALTER TABLE jobs DROP COLUMN mndr; ALTER TABLE jobs DROP "
                 "COLUMN andr; ALTER TABLE jobs DROP COLUMN shape_changed;"
                 "ALTER TABLE jobs DROP COLUMN est_s;"
                 "DROP INDEX jobs_live; DROP INDEX prints_printer; DROP INDEX prints_printer_id;"
                 "DROP INDEX jobs_queue_pos; ALTER TABLE jobs DROP COLUMN queue_pos;"
                 "DROP TABLE printer_cfgs; DROP TABLE file_chunks; DROP TABLE file_blobs;"
                 "ALTER TABLE prints DROP COLUMN gcode_sha; DROP TABLE commands;"
                 "PRAGMA user_version = 1",
                 NULL, NULL, NULL),
             SQLITE_OK);
    sqlite3_close(db);
    T_TRUE((s = t_store_open(dir, NULL, &err)) != NULL);
    T_OK(store_job_get(s, id, &j, &err), &err);
    T_EQ_INT(j.state, JOB_READY);
    T_EQ_STR(j.gcode_sha, sha);
    T_EQ_DBL(j.size_mm[1], 30, 0);
    T_EQ_INT(j.gcode_lines, 0);
    T_TRUE(!j.dev_measured && !j.shape_changed); /* schema 5: not measured before */
    T_TRUE(!j.est_known && j.est_s == -1);       /* schema 6: the printer reads the file */
    T_EQ_INT(j.queue_pos, id);                   /* schema 9: first come, first served */
    T_OK(store_check(s, &err), &err);
    /* prepared again (a new job here): the count and the deviation are stored */
    int64_t id2 = add_job(s, "part 2", 1, &err);
    T_OK(store_job_event(s, id2, JOB_EV_PREPARE, NULL, NULL, &err), &err);
    a.gcode_lines = 7;
    a.dev_measured = a.shape_changed = true;
    a.mndr = 0.02;
    a.andr = 0.005;
    a.est_known = true;
    a.est_s = 754;
    T_OK(store_job_event(s, id2, JOB_EV_PREPARED, &a, NULL, &err), &err);
    T_OK(store_job_get(s, id2, &j, &err), &err);
    T_EQ_INT(j.gcode_lines, 7);
    T_TRUE(j.est_known);
    T_EQ_DBL(j.est_s, 754, 0);
    T_TRUE(j.dev_measured && j.shape_changed);
    T_EQ_DBL(j.mndr, 0.02, 0);
    T_EQ_DBL(j.andr, 0.005, 0);
    store_close(s);
    T_EQ_INT(sqlite3_open(path, &db), SQLITE_OK);
    sqlite3_stmt *st;
    sqlite3_prepare_v2(db, "PRAGMA user_version", -1, &st, NULL);
    T_EQ_INT(sqlite3_step(st), SQLITE_ROW);
    T_EQ_INT(sqlite3_column_int(st, 0), store_schema_version());
    sqlite3_finalize(st);
    sqlite3_close(db);
}

/*
 * A shape method's deviation (MNDR / ANDR) is kept with the job: NULL in
 * the table, not measured in the row, for methods that do not reshape; a
 * re-slice of the saved part (no new mesh, nothing measured) keeps it.
 */
/*
 * Each print names the G-code it ran: a job of two copies is sliced again
 * for another printer after its first copy (the farm's reslice for an idle
 * printer of another kind), and the first print still names the file it
 * printed.  Before schema 13 only the job's (latest) G-code was known, so an
 * audit of what a printer executed compared its first copy with the wrong
 * file.
 */
T_CASE(store_print_names_the_gcode_it_ran)
{
    struct sf_err err;
    const char *dir = fresh_dir("gcode_of_print");
    struct store *s = t_store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    int64_t id = add_job(s, "solid a\nendsolid a\n", 2, &err);
    T_TRUE(id > 0);
    T_OK(make_ready(s, id, &err), &err);
    struct job_row j;
    T_OK(store_job_get(s, id, &j, &err), &err);
    char first[STORE_SHA_HEX];
    snprintf(first, sizeof(first), "%s", j.gcode_sha);
    struct job_event_args start = { .printer = "mk4" };
    struct job_event_args done = { .lines_acked = 2 };
    T_OK(store_job_event(s, id, JOB_EV_START, &start, NULL, &err), &err);
    T_OK(store_job_event(s, id, JOB_EV_PRINT_DONE, &done, NULL, &err), &err);
    char again[STORE_SHA_HEX];
    T_OK(store_file_put(s, "G28\nG1 X2\n", 10, again, &err), &err);
    struct job_event_args re = { .gcode_sha = again, .size_mm = { 20, 30, 40 } };
    T_OK(store_job_event(s, id, JOB_EV_PREPARED, &re, NULL, &err), &err);
    start.printer = "mini";
    T_OK(store_job_event(s, id, JOB_EV_START, &start, NULL, &err), &err);
    T_OK(store_job_event(s, id, JOB_EV_PRINT_DONE, &done, NULL, &err), &err);
    struct print_row *p;
    size_t n;
    T_OK(store_prints(s, id, &p, &n, &err), &err);
    T_EQ_INT(n, 2);
    T_EQ_STR(p[0].gcode_sha, first);
    T_EQ_STR(p[1].gcode_sha, again);
    T_TRUE(strcmp(first, again) != 0);
    free(p);
    store_close(s);
}

T_CASE(store_keeps_the_deviation_of_a_reshaped_part)
{
    struct sf_err err;
    const char *dir = fresh_dir("deviation");
    struct store *s = t_store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    char gc[STORE_SHA_HEX], mesh[STORE_SHA_HEX];
    T_OK(store_file_put(s, "G28\n", 4, gc, &err), &err);
    T_OK(store_file_put(s, "solid\n", 6, mesh, &err), &err);
    int64_t orient = add_job(s, "oriented", 1, &err), slim = add_job(s, "slimmed", 1, &err);
    /* orient: a new mesh, nothing measured */
    struct job_event_args a = { .gcode_sha = gc, .size_mm = { 1, 1, 1 }, .mesh_sha = mesh };
    T_OK(store_job_event(s, orient, JOB_EV_PREPARE, NULL, NULL, &err), &err);
    T_OK(store_job_event(s, orient, JOB_EV_PREPARED, &a, NULL, &err), &err);
    /* slim: measured */
    a.dev_measured = a.shape_changed = true;
    a.mndr = 0.031;
    a.andr = 0.0042;
    T_OK(store_job_event(s, slim, JOB_EV_PREPARE, NULL, NULL, &err), &err);
    T_OK(store_job_event(s, slim, JOB_EV_PREPARED, &a, NULL, &err), &err);
    struct job_row j;
    T_OK(store_job_get(s, orient, &j, &err), &err);
    T_TRUE(!j.dev_measured && !j.shape_changed);
    T_EQ_DBL(j.mndr, 0, 0);
    T_OK(store_job_get(s, slim, &j, &err), &err);
    T_TRUE(j.dev_measured && j.shape_changed);
    T_EQ_DBL(j.mndr, 0.031, 0);
    T_EQ_DBL(j.andr, 0.0042, 0);
    /* a re-slice of the saved part for another printer: kept */
    struct job_event_args re = { .gcode_sha = gc, .size_mm = { 1, 1, 1 } };
    T_OK(store_job_event(s, slim, JOB_EV_PREPARED, &re, NULL, &err), &err);
    T_OK(store_job_get(s, slim, &j, &err), &err);
    T_TRUE(j.dev_measured && j.shape_changed);
    T_EQ_DBL(j.mndr, 0.031, 0);
    /* on disk as NULL for the unmeasured job */
    store_close(s);
    char sql[128];
    snprintf(sql, sizeof(sql),
             "SELECT count(*) FROM jobs WHERE mndr IS NULL AND andr IS NULL"
             " AND id = %lld",
             (long long)orient);
    T_EQ_INT(t_store_int(dir, sql), 1);
    snprintf(sql, sizeof(sql), "SELECT count(*) FROM jobs WHERE andr = 0.0042 AND id = %lld",
             (long long)slim);
    T_EQ_INT(t_store_int(dir, sql), 1);
}

T_CASE(store_files_are_content_addressed)
{
    struct sf_err err;
    struct store *s = t_store_open(fresh_dir("files"), NULL, &err);
    T_TRUE(s != NULL);
    char a[STORE_SHA_HEX], b[STORE_SHA_HEX], path[1200];
    T_OK(store_file_put(s, "abc", 3, a, &err), &err);
    /* FIPS 180-2 test vector */
    T_EQ_STR(a, "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
    T_OK(store_file_put(s, "abc", 3, b, &err), &err);
    T_EQ_STR(a, b);
    /* streamed in pieces gives the same address */
    struct store_file *f = store_file_begin(s, &err);
    T_TRUE(f != NULL);
    T_OK(store_file_write(f, "a", 1, &err), &err);
    T_OK(store_file_write(f, "bc", 2, &err), &err);
    T_OK(store_file_commit(f, b, &err), &err);
    T_EQ_STR(a, b);
    T_OK(store_file_path(s, a, path, sizeof(path), &err), &err);
    struct buf buf;
    buf_init(&buf, 0);
    T_OK(buf_read_file(&buf, path, &err), &err);
    T_EQ_STR(buf.data, "abc");
    buf_release(&buf);
    T_ERR(store_file_path(s, "../../etc/passwd", path, sizeof(path), &err), SF_EINVAL, &err,
          "not a SHA-256");
    T_ERR(store_file_path(s, "0000000000000000000000000000000000000000000000000000000000000000",
                          path, sizeof(path), &err),
          SF_ENOTFOUND, &err, "no file");
    /* an aborted writer leaves nothing behind */
    f = store_file_begin(s, &err);
    T_OK(store_file_write(f, "junk", 4, &err), &err);
    store_file_abort(f);
    store_close(s);
}

/* A file made beside the store is adopted off the store's thread (moved, hashed, not copied) and
   recorded on it; until recorded it has no path. */
T_CASE(store_adopts_a_file_then_records_it)
{
    struct sf_err err;
    const char *dir = fresh_dir("adopt");
    struct store *s = t_store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    char made[600], sha[STORE_SHA_HEX], path[1200];
    snprintf(made, sizeof(made), "%s/files/job-1.gcode", dir);
    FILE *fp = fopen(made, "w");
    T_TRUE(fp != NULL);
    for (int i = 0; i < 20000; i++) /* several read chunks */
        fprintf(fp, "G1 X%d Y%d\n", i % 200, i / 200);
    fclose(fp);
    struct stat st;
    T_TRUE(stat(made, &st) == 0);
    int64_t size = -1;
    T_OK(store_file_adopt(s, made, sha, &size, &err), &err);
    T_EQ_INT(size, st.st_size);
    T_TRUE(access(made, F_OK) != 0); /* moved, not copied */
    T_ERR(store_file_path(s, sha, path, sizeof(path), &err), SF_ENOTFOUND, &err, "no file");
    T_OK(store_file_record(s, sha, size, &err), &err);
    T_OK(store_file_path(s, sha, path, sizeof(path), &err), &err);
    /* the same address the streaming writer gives the same bytes */
    struct buf buf;
    buf_init(&buf, 0);
    T_OK(buf_read_file(&buf, path, &err), &err);
    T_EQ_INT(buf.len, (size_t)size);
    char put[STORE_SHA_HEX];
    T_OK(store_file_put(s, buf.data, buf.len, put, &err), &err);
    T_EQ_STR(put, sha);
    buf_release(&buf);
    T_ERR(store_file_adopt(s, made, sha, &size, &err), SF_EIO, &err, "cannot read");
    T_ERR(store_file_record(s, "zz", 2, &err), SF_EINVAL, &err, "not a SHA-256");
    store_close(s);
}

T_CASE(store_job_lifecycle_with_copies_and_history)
{
    struct sf_err err;
    struct store *s = t_store_open(fresh_dir("life"), NULL, &err);
    T_TRUE(s != NULL);
    int64_t id = add_job(s, "solid part", 2, &err);
    T_TRUE(id > 0);
    struct job_row j;
    T_OK(store_job_get(s, id, &j, &err), &err);
    T_EQ_INT(j.state, JOB_QUEUED);
    T_EQ_INT(j.counts.copies, 2);
    T_EQ_STR(j.opts.name, "part.stl");
    T_OK(make_ready(s, id, &err), &err);
    T_OK(store_job_get(s, id, &j, &err), &err);
    T_EQ_INT(j.state, JOB_READY);
    T_EQ_DBL(j.size_mm[2], 40, 0);
    T_TRUE(j.gcode_sha[0] != '\0');
    for (int copy = 1; copy <= 2; copy++) {
        struct job_event_args start = { .printer = copy == 1 ? "mk3-a" : "mk3-b" };
        enum job_state to;
        T_OK(store_job_event(s, id, JOB_EV_START, &start, &to, &err), &err);
        T_EQ_INT(to, JOB_PRINTING);
        T_OK(store_job_progress(s, id, 100, &err), &err);
        T_OK(store_job_event(s, id, JOB_EV_PAUSE, NULL, NULL, &err), &err);
        T_OK(store_job_event(s, id, JOB_EV_RESUME, NULL, NULL, &err), &err);
        T_OK(store_check(s, &err), &err);
        struct job_event_args done = { .lines_acked = 500, .filament_mm = 1234.5 };
        T_OK(store_job_event(s, id, JOB_EV_PRINT_DONE, &done, &to, &err), &err);
        T_EQ_INT(to, copy == 1 ? JOB_READY : JOB_DONE);
    }
    struct print_row *p;
    size_t n;
    T_OK(store_prints(s, id, &p, &n, &err), &err);
    T_EQ_INT(n, 2);
    T_EQ_STR(p[0].printer, "mk3-a");
    T_EQ_STR(p[1].printer, "mk3-b");
    T_EQ_INT(p[1].copy, 2);
    T_EQ_STR(p[1].outcome, "done");
    T_EQ_INT(p[1].lines_acked, 500);
    T_EQ_DBL(p[1].filament_mm, 1234.5, 1e-9);
    T_TRUE(p[1].ended_ms >= p[1].started_ms);
    free(p);
    struct event_row *e;
    T_OK(store_events(s, 0, 100, &e, &n, &err), &err);
    T_EQ_INT(n, 11); /* add, prepare, prepared, 2 x (start, pause, resume, done) */
    T_EQ_STR(e[0].kind, "job-add");
    T_EQ_STR(e[n - 1].kind, "job-print-done");
    T_EQ_STR(e[n - 1].detail, "printing -> done");
    int64_t last = e[n - 1].id;
    free(e);
    T_OK(store_events(s, last, 100, &e, &n, &err), &err);
    T_EQ_INT(n, 0);
    free(e);
    T_OK(store_check(s, &err), &err);
    store_close(s);
}

T_CASE(store_illegal_event_changes_nothing)
{
    struct sf_err err;
    struct store *s = t_store_open(fresh_dir("illegal"), NULL, &err);
    T_TRUE(s != NULL);
    int64_t id = add_job(s, "x", 1, &err);
    T_TRUE(id > 0);
    struct job_event_args start = { .printer = "p1" };
    T_ERR(store_job_event(s, id, JOB_EV_START, &start, NULL, &err), SF_EINVAL, &err,
          "cannot start a queued job");
    T_TRUE(strstr(err.msg, "job 1") != NULL);
    T_ERR(store_job_event(s, 999, JOB_EV_CANCEL, NULL, NULL, &err), SF_ENOTFOUND, &err,
          "no such job");
    /* START without a printer is refused inside the transaction */
    T_OK(make_ready(s, id, &err), &err);
    T_ERR(store_job_event(s, id, JOB_EV_START, NULL, NULL, &err), SF_EINVAL, &err,
          "needs a printer");
    struct job_row j;
    T_OK(store_job_get(s, id, &j, &err), &err);
    T_EQ_INT(j.state, JOB_READY);
    struct event_row *e;
    size_t n;
    T_OK(store_events(s, 0, 100, &e, &n, &err), &err);
    T_EQ_INT(n, 3); /* add, prepare, prepared: the refusals logged nothing */
    free(e);
    /* a job without a stored part file, and bad options, are refused */
    struct job_opts o = opts("a.stl", 1);
    T_ERR(store_job_add(s, &o, "ff", NULL, &err), SF_ENOTFOUND, &err, "not stored");
    o.copies = -1;
    T_ERR(store_job_add(s, &o, j.file_sha, NULL, &err), SF_EINVAL, &err, "copies");
    T_ERR(store_job_set_priority(s, id, 2000000, &err), SF_EINVAL, &err, "priority");
    T_OK(store_job_set_priority(s, id, 7, &err), &err);
    T_OK(store_job_get(s, id, &j, &err), &err);
    T_EQ_INT(j.opts.priority, 7);
    T_OK(store_check(s, &err), &err);
    store_close(s);
}

T_CASE(store_reopen_recovers_interrupted_and_preparing)
{
    struct sf_err err;
    const char *dir = fresh_dir("recover");
    struct store *s = t_store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    int64_t printing = add_job(s, "a", 1, &err), preparing = add_job(s, "b", 1, &err),
            paused = add_job(s, "c", 1, &err), ready = add_job(s, "d", 1, &err);
    T_TRUE(printing && preparing && paused && ready);
    struct job_event_args start = { .printer = "mk3-a" };
    T_OK(make_ready(s, printing, &err), &err);
    T_OK(store_job_event(s, printing, JOB_EV_START, &start, NULL, &err), &err);
    T_OK(store_job_progress(s, printing, 4242, &err), &err);
    T_OK(store_job_event(s, preparing, JOB_EV_PREPARE, NULL, NULL, &err), &err);
    T_OK(make_ready(s, paused, &err), &err);
    start.printer = "mk3-b";
    T_OK(store_job_event(s, paused, JOB_EV_START, &start, NULL, &err), &err);
    T_OK(store_job_event(s, paused, JOB_EV_PAUSE, NULL, NULL, &err), &err);
    T_OK(make_ready(s, ready, &err), &err);
    T_OK(store_printer_set(s, "mk3-a", PRINTER_PRINTING, &err), &err);
    store_close(s); /* as if the daemon died here */

    struct store_recovery rec;
    s = t_store_open(dir, &rec, &err);
    T_TRUE(s != NULL);
    T_EQ_INT(rec.interrupted, 2);
    T_EQ_INT(rec.requeued, 1);
    struct job_row j;
    T_OK(store_job_get(s, printing, &j, &err), &err);
    T_EQ_INT(j.state, JOB_INTERRUPTED);
    T_EQ_INT(j.lines_acked, 4242);
    T_EQ_STR(j.printer, "mk3-a");
    T_TRUE(strstr(j.reason, "daemon stopped") != NULL);
    T_OK(store_job_get(s, preparing, &j, &err), &err);
    T_EQ_INT(j.state, JOB_QUEUED);
    T_OK(store_job_get(s, ready, &j, &err), &err);
    T_EQ_INT(j.state, JOB_READY);
    enum printer_state ps;
    T_OK(store_printer_get(s, "mk3-a", &ps, &err), &err);
    T_EQ_INT(ps, PRINTER_OFFLINE);
    T_OK(store_check(s, &err), &err);
    /* the operator resumes from the last line: a new print starts there */
    T_OK(store_job_event(s, printing, JOB_EV_RESUME, NULL, NULL, &err), &err);
    struct print_row *p;
    size_t n;
    T_OK(store_prints(s, printing, &p, &n, &err), &err);
    T_EQ_INT(n, 2);
    T_EQ_STR(p[0].outcome, "interrupted");
    T_EQ_INT(p[1].start_line, 4242);
    T_EQ_STR(p[1].printer, "mk3-a");
    free(p);
    T_OK(store_check(s, &err), &err);
    store_close(s);
    /* nothing left to recover */
    s = t_store_open(dir, &rec, &err);
    T_TRUE(s != NULL);
    T_EQ_INT(rec.interrupted, 1); /* the resumed one was printing again */
    T_EQ_INT(rec.requeued, 0);
    store_close(s);
}

/* The child's way out when a store call fails: the parent sees an exit, not its SIGKILL. */
static void
hammer_fail(int status, const char *what, const struct sf_err *err)
{
    fprintf(stderr, "    child: %s: %s\n", what, err->msg);
    _exit(status);
}

/*
 * The child: add jobs and drive them through their lives forever, writing
 * each job id to fd after the transaction that created it committed.  Every
 * call must succeed: a failure ends the child with its own status, which
 * fails the test.
 */
static void
hammer(const char *dir, int fd, unsigned seed)
{
    struct sf_err err;
    struct store *s = t_store_open(dir, NULL, &err);
    if (!s)
        hammer_fail(3, "open", &err);
    for (unsigned i = 0;; i++) {
        char part[64];
        snprintf(part, sizeof(part), "part %u/%u", seed, i);
        int64_t id = add_job(s, part, 1 + (int)(i % 2), &err);
        if (!id)
            hammer_fail(4, "add job", &err);
        if (write(fd, &id, sizeof(id)) != sizeof(id))
            _exit(5);
        if (make_ready(s, id, &err))
            hammer_fail(6, "prepare", &err);
        struct job_event_args start = { .printer = (i % 3) ? "a" : "b" };
        if (store_job_event(s, id, JOB_EV_START, &start, NULL, &err))
            hammer_fail(7, "start", &err);
        if (store_job_progress(s, id, i, &err))
            hammer_fail(8, "progress", &err);
        if (store_printer_set(s, start.printer, PRINTER_PRINTING, &err))
            hammer_fail(9, "printer state", &err);
        if (i % 4 == 0)
            continue; /* leave it printing: the next crash interrupts it */
        struct job_event_args done = { .lines_acked = 10 };
        if (store_job_event(s, id, i % 5 ? JOB_EV_PRINT_DONE : JOB_EV_PRINT_FAILED, &done, NULL,
                            &err))
            hammer_fail(10, "end of print", &err);
    }
}

T_CASE(store_survives_sigkill_mid_transaction)
{
    const char *dir = fresh_dir("crash");
    int64_t acked[4096];
    size_t n_acked = 0;
    /* A fixed seed: a failure replays with the same kill delays. */
    unsigned delay_seed = 20261201;
    for (int round = 0; round < 8; round++) {
        int pfd[2];
        T_TRUE(pipe(pfd) == 0);
        pid_t pid = fork();
        T_TRUE(pid >= 0);
        if (pid == 0) {
            close(pfd[0]);
            hammer(dir, pfd[1], (unsigned)round);
        }
        close(pfd[1]);
        /* Let the child acknowledge two jobs (so it is surely working, however
           loaded the machine), then kill it 0..39 ms later: usually
           mid-transaction. */
        int64_t id;
        for (int k = 0; k < 2 && n_acked < 4096; k++) {
            T_EQ_INT(read(pfd[0], &id, sizeof(id)), sizeof(id));
            acked[n_acked++] = id;
        }
        delay_seed = delay_seed * 1103515245u + 12345u;
        struct timespec ts = { 0, (long)(delay_seed >> 16) % 40 * 1000000L };
        nanosleep(&ts, NULL);
        T_EQ_INT(kill(pid, SIGKILL), 0);
        int status;
        T_EQ_INT(waitpid(pid, &status, 0), pid);
        if (!WIFSIGNALED(status) || WTERMSIG(status) != SIGKILL)
            t_fail(__FILE__, __LINE__, "round %d: the child ended by itself (status %d)", round,
                   WIFEXITED(status) ? WEXITSTATUS(status) : -1);
        ssize_t got;
        while ((got = read(pfd[0], &id, sizeof(id))) == sizeof(id) && n_acked < 4096)
            acked[n_acked++] = id;
        T_EQ_INT(got, 0); /* the pipe's end, never half an id */
        close(pfd[0]);
        printf("    round %d (kill after %ld ms): %zu jobs acknowledged so far\n", round,
               ts.tv_nsec / 1000000L, n_acked);

        struct sf_err err;
        struct store_recovery rec;
        struct store *s = t_store_open(dir, &rec, &err);
        T_TRUE(s != NULL);
        T_OK(store_check(s, &err), &err);
        /* every acknowledged job is there; none is left mid-flight */
        for (size_t i = 0; i < n_acked; i++) {
            struct job_row j;
            T_OK(store_job_get(s, acked[i], &j, &err), &err);
            T_TRUE(j.state != JOB_PRINTING && j.state != JOB_PAUSED && j.state != JOB_PREPARING);
        }
        struct job_row *rows;
        size_t n;
        T_OK(store_job_list(s, &rows, &n, &err), &err);
        /* at most one job per kill more than acknowledged: committed, killed
           before the child could write its id (each round may leave one) */
        T_TRUE(n >= n_acked && n <= n_acked + (size_t)round + 1);
        for (size_t i = 1; i < n; i++)
            T_TRUE(rows[i].id > rows[i - 1].id);
        free(rows);
        store_close(s);
    }
    T_TRUE(n_acked >= 16); /* the child got real work done */
}

/*
 * A VFS that fails reads on demand: it passes every call to the default VFS,
 * except that the read after fault_after more reads returns
 * SQLITE_IOERR_READ, once (a flaky disk, or the I/O error SQLite's own test
 * VFS injects).  iVersion 2: the WAL index needs the shm methods, and
 * without xFetch SQLite reads every page through xRead, never by mmap.
 */
struct fault_file {
    sqlite3_file base;  /* pMethods = &fault_io */
    sqlite3_file *real; /* the default VFS's file, right after this struct */
};

static sqlite3_vfs *real_vfs, fault_vfs;
static long fault_after = -1; /* reads to pass before the failing one; -1: none fails */
static long fault_fired;      /* reads failed so far */

static sqlite3_file *
real_file(sqlite3_file *f)
{
    return ((struct fault_file *)f)->real;
}

static int
ff_close(sqlite3_file *f)
{
    return real_file(f)->pMethods->xClose(real_file(f));
}

static int
ff_read(sqlite3_file *f, void *buf, int amt, sqlite3_int64 off)
{
    if (fault_after == 0) {
        fault_after = -1;
        fault_fired++;
        return SQLITE_IOERR_READ;
    }
    if (fault_after > 0)
        fault_after--;
    return real_file(f)->pMethods->xRead(real_file(f), buf, amt, off);
}

static int
ff_write(sqlite3_file *f, const void *buf, int amt, sqlite3_int64 off)
{
    return real_file(f)->pMethods->xWrite(real_file(f), buf, amt, off);
}

static int
ff_truncate(sqlite3_file *f, sqlite3_int64 size)
{
    return real_file(f)->pMethods->xTruncate(real_file(f), size);
}

static int
ff_sync(sqlite3_file *f, int flags)
{
    return real_file(f)->pMethods->xSync(real_file(f), flags);
}

static int
ff_file_size(sqlite3_file *f, sqlite3_int64 *size)
{
    return real_file(f)->pMethods->xFileSize(real_file(f), size);
}

static int
ff_lock(sqlite3_file *f, int level)
{
    return real_file(f)->pMethods->xLock(real_file(f), level);
}

static int
ff_unlock(sqlite3_file *f, int level)
{
    return real_file(f)->pMethods->xUnlock(real_file(f), level);
}

static int
ff_check_reserved(sqlite3_file *f, int *out)
{
    return real_file(f)->pMethods->xCheckReservedLock(real_file(f), out);
}

static int
ff_file_control(sqlite3_file *f, int op, void *arg)
{
    return real_file(f)->pMethods->xFileControl(real_file(f), op, arg);
}

static int
ff_sector_size(sqlite3_file *f)
{
    return real_file(f)->pMethods->xSectorSize(real_file(f));
}

static int
ff_device_chars(sqlite3_file *f)
{
    return real_file(f)->pMethods->xDeviceCharacteristics(real_file(f));
}

static int
ff_shm_map(sqlite3_file *f, int region, int size, int extend, void volatile **p)
{
    return real_file(f)->pMethods->xShmMap(real_file(f), region, size, extend, p);
}

static int
ff_shm_lock(sqlite3_file *f, int offset, int n, int flags)
{
    return real_file(f)->pMethods->xShmLock(real_file(f), offset, n, flags);
}

static void
ff_shm_barrier(sqlite3_file *f)
{
    real_file(f)->pMethods->xShmBarrier(real_file(f));
}

static int
ff_shm_unmap(sqlite3_file *f, int delete_flag)
{
    return real_file(f)->pMethods->xShmUnmap(real_file(f), delete_flag);
}

static const sqlite3_io_methods fault_io = {
    2,
    ff_close,
    ff_read,
    ff_write,
    ff_truncate,
    ff_sync,
    ff_file_size,
    ff_lock,
    ff_unlock,
    ff_check_reserved,
    ff_file_control,
    ff_sector_size,
    ff_device_chars,
    ff_shm_map,
    ff_shm_lock,
    ff_shm_barrier,
    ff_shm_unmap,
    NULL,
    NULL,
};

static int
fault_open(sqlite3_vfs *vfs, const char *name, sqlite3_file *f, int flags, int *out_flags)
{
    (void)vfs;
    struct fault_file *ff = (struct fault_file *)f;
    ff->real = (sqlite3_file *)(ff + 1);
    int rc = real_vfs->xOpen(real_vfs, name, ff->real, flags, out_flags);
    /* SQLite calls xClose only when pMethods is set, so mirror the real open */
    f->pMethods = ff->real->pMethods ? &fault_io : NULL;
    return rc;
}

/* Make the fault VFS the default for connections opened from now on. */
static bool
fault_vfs_install(void)
{
    if (!real_vfs) {
        real_vfs = sqlite3_vfs_find(NULL);
        if (!real_vfs)
            return false;
        fault_vfs = *real_vfs; /* its other methods serve us unchanged */
        fault_vfs.zName = "slimfarm-test-fault";
        fault_vfs.szOsFile = (int)sizeof(struct fault_file) + real_vfs->szOsFile;
        fault_vfs.xOpen = fault_open;
    }
    fault_after = -1;
    return sqlite3_vfs_register(&fault_vfs, 1) == SQLITE_OK;
}

static void
fault_vfs_remove(void)
{
    fault_after = -1;
    sqlite3_vfs_unregister(&fault_vfs);
}

static int
copy_file(const char *from, const char *to)
{
    FILE *in = fopen(from, "rb"), *out = fopen(to, "wb");
    char buf[1 << 14];
    size_t n;
    int rc = in && out ? 0 : -1;
    while (rc == 0 && (n = fread(buf, 1, sizeof(buf), in)) > 0)
        if (fwrite(buf, 1, n, out) != n)
            rc = -1;
    if (in && ferror(in))
        rc = -1;
    if (in)
        fclose(in);
    if (out && fclose(out) != 0)
        rc = -1;
    return rc;
}

/* Count the jobs in a state that crash recovery must leave no job in. */
static int
count_active(struct store *s, struct sf_err *err)
{
    struct job_row *rows;
    size_t n;
    if (store_job_list(s, &rows, &n, err))
        return -1;
    int active = 0;
    for (size_t i = 0; i < n; i++)
        active += rows[i].state == JOB_PRINTING || rows[i].state == JOB_PAUSED ||
                  rows[i].state == JOB_PREPARING;
    free(rows);
    return active;
}

/*
 * Crash recovery with each read of the open failing in turn.  The open either
 * fails with SF_EIO, and a clean open afterwards finishes the recovery, or
 * it succeeds having recovered every job: never success after a partial
 * read that left jobs "printing" for ever.
 */
T_CASE(store_recovery_never_succeeds_on_a_failed_read)
{
    SQLITE_ONLY();
    struct sf_err err;
    const char *dir = fresh_dir("recover-io");
    struct store *s = t_store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    enum { N_PRINTING = 4, N_PREPARING = 2 };
    for (int i = 0; i < N_PRINTING + N_PREPARING + 2; i++) {
        char part[32];
        snprintf(part, sizeof(part), "part %d", i);
        int64_t id = add_job(s, part, 1, &err);
        T_TRUE(id > 0);
        if (i < N_PRINTING) {
            struct job_event_args start = { .printer = i % 2 ? "a" : "b" };
            T_OK(make_ready(s, id, &err), &err);
            T_OK(store_job_event(s, id, JOB_EV_START, &start, NULL, &err), &err);
        } else if (i < N_PRINTING + N_PREPARING) {
            T_OK(store_job_event(s, id, JOB_EV_PREPARE, NULL, NULL, &err), &err);
        }
    }
    store_close(s); /* the last connection checkpoints: the database is one file */
    char db[600], saved[600], wal[600];
    snprintf(db, sizeof(db), "%s/slimfarm.db", dir);
    snprintf(saved, sizeof(saved), "%s/crashed.db", t_tmpdir());
    snprintf(wal, sizeof(wal), "%s-wal", db);
    T_TRUE(access(wal, F_OK) != 0);
    T_TRUE(copy_file(db, saved) == 0);
    T_TRUE(fault_vfs_install());
    int failed = 0;
    long k;
    for (k = 0; k < 2000; k++) {
        T_TRUE(copy_file(saved, db) == 0);
        long fired = fault_fired;
        fault_after = k;
        struct store_recovery rec = { -1, -1 };
        s = t_store_open(dir, &rec, &err);
        fault_after = -1;
        if (!s) {
            T_EQ_INT(err.code, SF_EIO);
            failed++;
            s = t_store_open(dir, &rec, &err); /* the next start finishes the work */
            T_TRUE(s != NULL);
        } else if (fault_fired == fired) {
            T_EQ_INT(rec.interrupted, N_PRINTING);
            T_EQ_INT(rec.requeued, N_PREPARING);
            T_EQ_INT(count_active(s, &err), 0);
            store_close(s);
            break; /* every read of the open has failed once */
        } else {
            if (rec.interrupted != N_PRINTING || rec.requeued != N_PREPARING)
                t_fail(__FILE__, __LINE__,
                       "read %ld failed, yet the open succeeded having recovered %d + %d jobs, "
                       "not %d + %d",
                       k, rec.interrupted, rec.requeued, N_PRINTING, N_PREPARING);
        }
        T_EQ_INT(count_active(s, &err), 0);
        T_OK(store_check(s, &err), &err);
        store_close(s);
    }
    fault_vfs_remove();
    printf("    %ld reads, %d opens failed\n", k, failed);
    T_TRUE(k < 2000);
    T_TRUE(failed > 0); /* the fault did reach the store */
}

/* Each listing with each of its reads failing in turn: an error, or every row. */
T_CASE(store_listings_report_a_failed_read)
{
    SQLITE_ONLY();
    struct sf_err err;
    const char *dir = fresh_dir("list-io");
    struct store *s = t_store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    int64_t id = add_job(s, "part", 3, &err);
    T_TRUE(id > 0);
    T_OK(make_ready(s, id, &err), &err);
    for (int c = 0; c < 3; c++) {
        struct job_event_args start = { .printer = "a" }, done = { .lines_acked = 2 };
        T_OK(store_job_event(s, id, JOB_EV_START, &start, NULL, &err), &err);
        T_OK(store_job_event(s, id, JOB_EV_PRINT_DONE, &done, NULL, &err), &err);
    }
    for (int i = 0; i < 40; i++) /* enough jobs and events to fill several pages */
        T_TRUE(add_job(s, "another part with a name long enough to fill pages", 1, &err) > 0);
    struct event_row *ev;
    size_t n_events;
    T_OK(store_events(s, 0, 100000, &ev, &n_events, &err), &err);
    free(ev);
    T_TRUE(n_events > 40);
    store_close(s);
    T_TRUE(fault_vfs_install());
    for (int which = 0; which < 3; which++) {
        static const char *const names[] = { "store_prints", "store_events", "store_job_list" };
        int failed = 0;
        long k;
        for (k = 0; k < 2000; k++) {
            s = t_store_open(dir, NULL, &err);
            T_TRUE(s != NULL);
            long fired = fault_fired;
            fault_after = k;
            void *rows = NULL;
            size_t n = 99, want = 0;
            int rc;
            if (which == 0) {
                rc = store_prints(s, id, (struct print_row **)&rows, &n, &err);
                want = 3;
            } else if (which == 1) {
                rc = store_events(s, 0, 100000, (struct event_row **)&rows, &n, &err);
                want = n_events;
            } else {
                rc = store_job_list(s, (struct job_row **)&rows, &n, &err);
                want = 41;
            }
            fault_after = -1;
            store_close(s);
            if (rc == SF_OK && n != want)
                t_fail(__FILE__, __LINE__, "%s: read %ld failed, yet it returned %zu of %zu rows",
                       names[which], k, n, want);
            free(rows);
            if (rc != SF_OK) {
                T_EQ_INT(rc, SF_EIO);
                T_TRUE(rows == NULL && n == 0);
                T_TRUE(strstr(err.msg, "I/O error") != NULL);
                failed++;
            } else if (fault_fired == fired) {
                break;
            }
        }
        printf("    %s: %ld reads, %d failed\n", names[which], k, failed);
        T_TRUE(k < 2000);
        T_TRUE(failed > 0);
    }
    fault_vfs_remove();
}

T_CASE(store_survives_allocation_failures)
{
    /* every allocation the store makes through mem.h, failed in turn */
    const char *dir = fresh_dir("oom");
    struct sf_err err;
    struct store *s = t_store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    T_TRUE(add_job(s, "seed", 1, &err) > 0);
    store_close(s);
    for (long n = 1; n < 40; n++) {
        mem_fail_after(n);
        s = t_store_open(dir, NULL, &err);
        if (s) {
            struct job_row *rows = NULL;
            size_t cnt;
            store_job_list(s, &rows, &cnt, &err);
            free(rows);
            add_job(s, "more", 1, &err);
            store_close(s);
        }
        mem_fail_after(0);
    }
    s = t_store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    T_OK(store_check(s, &err), &err);
    store_close(s);
}

T_CASE(store_jobs_progress_saves_printing_jobs_in_one_go)
{
    struct sf_err err;
    struct store *s = t_store_open(fresh_dir("progress"), NULL, &err);
    T_TRUE(s != NULL);
    int64_t a = add_job(s, "a", 1, &err), b = add_job(s, "b", 1, &err),
            idle = add_job(s, "c", 1, &err);
    T_TRUE(a && b && idle);
    struct job_event_args start = { .printer = "mk3-a" };
    T_OK(make_ready(s, a, &err), &err);
    T_OK(store_job_event(s, a, JOB_EV_START, &start, NULL, &err), &err);
    start.printer = "mk3-b";
    T_OK(make_ready(s, b, &err), &err);
    T_OK(store_job_event(s, b, JOB_EV_START, &start, NULL, &err), &err);
    T_OK(store_job_event(s, b, JOB_EV_PAUSE, NULL, NULL, &err), &err);
    T_OK(make_ready(s, idle, &err), &err);
    struct store_progress p[] = { { a, 120, false, 0 }, { idle, 7, true, 0 }, { b, 45, false, 0 } };
    T_EQ_INT(store_jobs_progress(s, p, 3, &err), 2);
    T_TRUE(p[0].saved && !p[1].saved && p[2].saved);
    struct job_row j;
    T_OK(store_job_get(s, a, &j, &err), &err);
    T_EQ_INT(j.lines_acked, 120);
    T_OK(store_job_get(s, b, &j, &err), &err);
    T_EQ_INT(j.lines_acked, 45);
    T_OK(store_job_get(s, idle, &j, &err), &err);
    T_EQ_INT(j.lines_acked, 0);
    /* Progress never goes backwards. */
    p[0].lines_acked = 100;
    T_EQ_INT(store_jobs_progress(s, p, 1, &err), 1);
    T_OK(store_job_get(s, a, &j, &err), &err);
    T_EQ_INT(j.lines_acked, 120);
    T_OK(store_check(s, &err), &err);
    store_close(s);
}

/*
 * One process per data dir (issue 16): crash recovery from `slimfarmd
 * --fsck`, or a second daemon, beside a live one turned its printing job
 * interrupted under the printer still printing it.  The second open is
 * refused naming the dir and the holder's pid; the lock goes with the store.
 */
T_CASE(store_open_refuses_a_data_dir_in_use)
{
    struct sf_err err;
    const char *dir = fresh_dir("locked");
    struct store *s = t_store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    T_TRUE(t_store_open(dir, NULL, &err) == NULL);
    T_EQ_INT(err.code, SF_EAGAIN);
    char want[700];
    snprintf(want, sizeof(want), "store: data dir '%s' is in use by another process (pid %ld)", dir,
             (long)getpid());
    T_TRUE(strstr(err.msg, want) != NULL);
    store_close(s);
    T_TRUE((s = t_store_open(dir, NULL, &err)) != NULL);
    store_close(s);
}

/* A store in a fresh dir named dir holding one job of copies (its id in *id). */
static struct store *
store_with_job(const char *dir, int copies, int64_t *id)
{
    struct sf_err err;
    struct store *s = t_store_open(fresh_dir(dir), NULL, &err);
    *id = s ? add_job(s, "solid part", copies, &err) : 0;
    return s;
}

/* An operator stops one copy: the print ends "cancelled", the job waits to
   print that copy again, and the printer's bed names it. */
T_CASE(store_cancel_copy_keeps_the_job_and_the_bed_names_it)
{
    struct sf_err err;
    int64_t id;
    struct store *s = store_with_job("copy", 3, &id);
    T_TRUE(s && id > 0);
    T_OK(make_ready(s, id, &err), &err);
    struct store_bed *beds;
    size_t n;
    T_OK(store_printer_set(s, "mk3", PRINTER_IDLE, &err), &err);
    T_OK(store_printer_set(s, "mini", PRINTER_IDLE, &err), &err);
    T_OK(store_beds(s, &beds, &n, &err), &err);
    T_TRUE(n == 2 && beds[0].last.id == 0 && beds[1].last.id == 0); /* nothing printed yet */
    free(beds);
    struct job_event_args start = { .printer = "mk3" };
    T_OK(store_job_event(s, id, JOB_EV_START, &start, NULL, &err), &err);
    struct job_event_args stop = { .lines_acked = 42, .reason = "copy cancelled" };
    enum job_state to;
    T_OK(store_job_event(s, id, JOB_EV_CANCEL_COPY, &stop, &to, &err), &err);
    T_EQ_INT(to, JOB_READY);
    struct job_row j;
    T_OK(store_job_get(s, id, &j, &err), &err);
    T_TRUE(j.counts.copies_done == 0 && j.counts.failures == 0);
    T_OK(store_printer_bed_set(s, "mk3", true, &err), &err);
    T_OK(store_beds(s, &beds, &n, &err), &err);
    T_EQ_INT(n, 2); /* by name: mini, mk3 */
    T_TRUE(beds[0].last.id == 0 && !beds[0].bed_full);
    T_EQ_STR(beds[1].printer, "mk3");
    T_TRUE(beds[1].bed_full && beds[1].interrupted_job == 0);
    struct print_row *last = &beds[1].last;
    T_TRUE(last->job_id == id && last->copy == 1 && last->lines_acked == 42);
    T_EQ_STR(last->outcome, "cancelled");
    T_EQ_STR(beds[1].job_name, "part.stl");
    T_EQ_INT(beds[1].copies, 3);
    free(beds);
    T_OK(store_check(s, &err), &err);
    store_close(s);
}

/* The scheduler's reason lands through the store thread, maybe after the
   job was cancelled: it must not replace the cancel's reason (the history
   page showed a cancelled job as "fits no printer"). */
T_CASE(store_waiting_reason_never_replaces_a_cancelled_jobs)
{
    struct sf_err err;
    int64_t id;
    struct store *s = store_with_job("late-reason", 1, &id);
    T_TRUE(s && id > 0);
    T_OK(store_job_set_reason(s, id, "fits no printer: mk3: material TPU not loaded", &err), &err);
    struct job_row j;
    T_OK(store_job_get(s, id, &j, &err), &err);
    T_EQ_STR(j.reason, "fits no printer: mk3: material TPU not loaded");
    struct job_event_args cancel = { .reason = "cancelled by an operator" };
    T_OK(store_job_event(s, id, JOB_EV_CANCEL, &cancel, NULL, &err), &err);
    T_OK(store_job_set_reason(s, id, "waits for a printer: mk3 is printing", &err), &err);
    T_OK(store_job_get(s, id, &j, &err), &err);
    T_EQ_STR(job_state_name(j.state), "cancelled");
    T_EQ_STR(j.reason, "cancelled by an operator");
    store_close(s);
}

/* A reason longer than a job row holds is cut at a word, with "...". */
T_CASE(store_long_reason_is_cut_at_a_word)
{
    struct sf_err err;
    int64_t id;
    struct store *s = store_with_job("reason", 1, &id);
    T_TRUE(s && id > 0);
    char why[300] = "waits for a printer: ";
    for (int i = 0; strlen(why) < 250; i++)
        snprintf(why + strlen(why), sizeof(why) - strlen(why), "%sprinter-%02d is printing",
                 i ? "; " : "", i);
    T_OK(store_job_set_reason(s, id, why, &err), &err);
    struct job_row j;
    T_OK(store_job_get(s, id, &j, &err), &err);
    size_t n = strlen(j.reason);
    T_TRUE(n > 100 && n < sizeof(j.reason));
    T_EQ_STR(j.reason + n - 3, "...");
    /* what is kept is the reason's start, ending where a word ends */
    T_TRUE(strncmp(j.reason, why, n - 3) == 0);
    T_TRUE(why[n - 3] == ';' || why[n - 3] == ' ');
    store_close(s);
}
