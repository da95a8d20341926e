/*
 * test_store.c - the SQLite job store on real files: schema and migrations,
 * content-addressed files, every job event with its history and log, crash
 * recovery, and a kill -9 test: a child process hammering the store is
 * SIGKILLed mid-transaction again and again, and each reopen must find a
 * consistent store with every acknowledged job present.
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
#include "../t.h"

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

T_CASE(store_open_creates_schema_in_wal_mode)
{
    struct sf_err err;
    const char *dir = fresh_dir("open");
    struct store *s = store_open(dir, NULL, &err);
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
    T_TRUE(store_open(dir, NULL, &err) == NULL);
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
    struct sf_err err;
    const char *dir = fresh_dir("migrate1");
    struct store *s = store_open(dir, NULL, &err);
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
    T_EQ_INT(sqlite3_exec(db,
                          "ALTER TABLE jobs DROP COLUMN prep_key; ALTER TABLE jobs DROP COLUMN "
                          "mesh_sha; ALTER TABLE jobs DROP COLUMN mesh_angle_deg;"
                          "ALTER TABLE printers DROP COLUMN bed_full;"
                          "ALTER TABLE jobs DROP COLUMN gcode_lines; PRAGMA user_version = 1",
                          NULL, NULL, NULL),
             SQLITE_OK);
    sqlite3_close(db);
    T_TRUE((s = store_open(dir, NULL, &err)) != NULL);
    T_OK(store_job_get(s, id, &j, &err), &err);
    T_EQ_INT(j.state, JOB_READY);
    T_EQ_STR(j.gcode_sha, sha);
    T_EQ_DBL(j.size_mm[1], 30, 0);
    T_EQ_INT(j.gcode_lines, 0);
    T_OK(store_check(s, &err), &err);
    /* prepared again (a new job here): the count is stored */
    int64_t id2 = add_job(s, "part 2", 1, &err);
    T_OK(store_job_event(s, id2, JOB_EV_PREPARE, NULL, NULL, &err), &err);
    a.gcode_lines = 7;
    T_OK(store_job_event(s, id2, JOB_EV_PREPARED, &a, NULL, &err), &err);
    T_OK(store_job_get(s, id2, &j, &err), &err);
    T_EQ_INT(j.gcode_lines, 7);
    store_close(s);
    T_EQ_INT(sqlite3_open(path, &db), SQLITE_OK);
    sqlite3_stmt *st;
    sqlite3_prepare_v2(db, "PRAGMA user_version", -1, &st, NULL);
    T_EQ_INT(sqlite3_step(st), SQLITE_ROW);
    T_EQ_INT(sqlite3_column_int(st, 0), store_schema_version());
    sqlite3_finalize(st);
    sqlite3_close(db);
}

T_CASE(store_files_are_content_addressed)
{
    struct sf_err err;
    struct store *s = store_open(fresh_dir("files"), NULL, &err);
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
    struct store *s = store_open(dir, NULL, &err);
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
    struct store *s = store_open(fresh_dir("life"), NULL, &err);
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
    struct store *s = store_open(fresh_dir("illegal"), NULL, &err);
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
    struct store *s = store_open(dir, NULL, &err);
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
    s = store_open(dir, &rec, &err);
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
    s = store_open(dir, &rec, &err);
    T_TRUE(s != NULL);
    T_EQ_INT(rec.interrupted, 1); /* the resumed one was printing again */
    T_EQ_INT(rec.requeued, 0);
    store_close(s);
}

/*
 * The child: add jobs and drive them through their lives forever, writing
 * each job id to fd after the transaction that created it committed.
 */
static void
hammer(const char *dir, int fd, unsigned seed)
{
    struct sf_err err;
    struct store *s = store_open(dir, NULL, &err);
    if (!s)
        _exit(3);
    for (unsigned i = 0;; i++) {
        char part[64];
        snprintf(part, sizeof(part), "part %u/%u", seed, i);
        int64_t id = add_job(s, part, 1 + (int)(i % 2), &err);
        if (!id)
            _exit(4);
        if (write(fd, &id, sizeof(id)) != sizeof(id))
            _exit(5);
        if (make_ready(s, id, &err))
            _exit(6);
        struct job_event_args start = { .printer = (i % 3) ? "a" : "b" };
        store_job_event(s, id, JOB_EV_START, &start, NULL, &err);
        store_job_progress(s, id, i, &err);
        store_printer_set(s, start.printer, PRINTER_PRINTING, &err);
        if (i % 4 == 0)
            continue; /* leave it printing: the next crash interrupts it */
        struct job_event_args done = { .lines_acked = 10 };
        store_job_event(s, id, i % 5 ? JOB_EV_PRINT_DONE : JOB_EV_PRINT_FAILED, &done, NULL, &err);
    }
}

T_CASE(store_survives_sigkill_mid_transaction)
{
    const char *dir = fresh_dir("crash");
    int64_t acked[4096];
    size_t n_acked = 0;
    struct timespec seed;
    clock_gettime(CLOCK_REALTIME, &seed);
    srand((unsigned)seed.tv_nsec);
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
           loaded the machine), then kill it a random 0..40 ms later: usually
           mid-transaction. */
        int64_t id;
        for (int k = 0; k < 2 && read(pfd[0], &id, sizeof(id)) == sizeof(id) && n_acked < 4096; k++)
            acked[n_acked++] = id;
        struct timespec ts = { 0, (rand() % 40) * 1000000L };
        nanosleep(&ts, NULL);
        kill(pid, SIGKILL);
        int status;
        waitpid(pid, &status, 0);
        T_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL);
        while (read(pfd[0], &id, sizeof(id)) == sizeof(id) && n_acked < 4096)
            acked[n_acked++] = id;
        close(pfd[0]);
        printf("    round %d: %zu jobs acknowledged so far\n", round, n_acked);

        struct sf_err err;
        struct store_recovery rec;
        struct store *s = store_open(dir, &rec, &err);
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

T_CASE(store_survives_allocation_failures)
{
    /* every allocation the store makes through mem.h, failed in turn */
    const char *dir = fresh_dir("oom");
    struct sf_err err;
    struct store *s = store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    T_TRUE(add_job(s, "seed", 1, &err) > 0);
    store_close(s);
    for (long n = 1; n < 40; n++) {
        mem_fail_after(n);
        s = store_open(dir, NULL, &err);
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
    s = store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    T_OK(store_check(s, &err), &err);
    store_close(s);
}

T_CASE(store_jobs_progress_saves_printing_jobs_in_one_go)
{
    struct sf_err err;
    struct store *s = store_open(fresh_dir("progress"), NULL, &err);
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
    struct store_progress p[] = { { a, 120, false }, { idle, 7, true }, { b, 45, false } };
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
    struct store *s = store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    T_TRUE(store_open(dir, NULL, &err) == NULL);
    T_EQ_INT(err.code, SF_EAGAIN);
    char want[700];
    snprintf(want, sizeof(want), "store: data dir '%s' is in use by another process (pid %ld)", dir,
             (long)getpid());
    T_TRUE(strstr(err.msg, want) != NULL);
    store_close(s);
    T_TRUE((s = store_open(dir, NULL, &err)) != NULL);
    store_close(s);
}
