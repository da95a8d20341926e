/*
 * test_store_file.c - files shared between hosts through a PostgreSQL
 * store's database (store_blob.c), and the blobs under them (sqldb.h).
 * Each case opens real stores on the run's engine (tests/tstore.h); a
 * second host is a second store, with a data dir of its own, on the first
 * one's database.  Faults come from the database itself: a chunk damaged
 * with SQL, a trigger that refuses an insert mid-upload.  The cases that
 * need a second host or the database's copy skip on SQLite, where the data
 * dir is the store (tests/integ/store_pg.sh runs them on PostgreSQL).
 */
#include <dirent.h>
#include <fcntl.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "../../src/base/buf.h"
#include "../../src/base/limits.h"
#include "../../src/base/mem.h"
#include "../../src/farm/sqldb.h"
#include "../../src/farm/store.h"
#include "../t.h"
#include "../tstore.h"

#define MIB (1 << 20)

/* A fresh data dir per case and host, under the program's scratch dir (kept per name). */
static const char *
host_dir(const char *name)
{
    static char paths[4][512];
    static int next;
    char *p = paths[next++ % 4];
    snprintf(p, sizeof(paths[0]), "%s/%s", t_tmpdir(), name);
    mkdir(p, 0700);
    return p;
}

/* n bytes that do not repeat in any chunk (xorshift), so a chunk mixed up shows. */
static unsigned char *
bytes(size_t n, uint32_t seed)
{
    unsigned char *b = mem_alloc(n ? n : 1);
    uint32_t x = seed | 1;
    for (size_t i = 0; b && i < n; i++) {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        b[i] = (unsigned char)x;
    }
    return b;
}

/* Whether the file at path holds exactly data[0..n). */
static bool
holds(const char *path, const unsigned char *data, size_t n)
{
    struct buf b;
    buf_init(&b, 0);
    bool same =
        buf_read_file(&b, path, NULL) == SF_OK && b.len == n && memcmp(b.data, data, n) == 0;
    buf_release(&b);
    return same;
}

/* Files named tmp-* left in dir/files (a fetch's temporaries). */
static int
temporaries(const char *dir)
{
    char path[600];
    snprintf(path, sizeof(path), "%s/files", dir);
    DIR *d = opendir(path);
    int n = 0;
    for (struct dirent *e; d && (e = readdir(d));)
        n += strncmp(e->d_name, "tmp-", 4) == 0;
    if (d)
        closedir(d);
    return n;
}

/* Open host b's store on host a's database (t_store_db names a's). */
static struct store *
open_other_host(const char *a, const char *b, struct sf_err *err)
{
    return store_open_db(b, t_store_db(a), NULL, err);
}

/* A case's first host: skip on SQLite (the data dir is the store: nothing is shared) unless
   both engines, else its store in a fresh data dir named name, s NULL on failure. */
#define FIRST_HOST(s, dir, name, both)                                                             \
    if (!(both) && !t_store_pg()) {                                                                \
        t_skip("on SQLite the data dir is the store: nothing is shared");                          \
        return;                                                                                    \
    }                                                                                              \
    struct sf_err err;                                                                             \
    const char *dir = host_dir(name);                                                              \
    struct store *s = t_store_open(dir, NULL, &err);                                               \
    T_TRUE(s != NULL)

T_CASE(sqldb_blobs_round_trip_every_byte)
{
    const char *dir = host_dir("blobs");
    struct sqldb *db = t_store_sqldb(dir);
    T_TRUE(db != NULL);
    T_OK(sqldb_exec(db, t_store_pg() ? "CREATE TABLE b(k BIGINT, v BYTEA, t TEXT)"
                                     : "CREATE TABLE b(k INTEGER, v BLOB, t TEXT)"),
         NULL);
    unsigned char all[256 * 3];
    for (size_t i = 0; i < sizeof(all); i++)
        all[i] = (unsigned char)i; /* NULs, quotes, backslashes, high bytes */
    struct sqldb_stmt *st;
    T_OK(sqldb_prepare(db, "INSERT INTO b(k, v, t) VALUES(?, ?, ?)", &st), NULL);
    sqldb_bind_int64(st, 1, 1);
    sqldb_bind_blob(st, 2, all, sizeof(all));
    sqldb_bind_text(st, 3, "x");
    T_EQ_INT(sqldb_step(st), SQLDB_DONE);
    sqldb_reset(st); /* the same slot: text after a blob, then an empty blob */
    sqldb_bind_int64(st, 1, 2);
    sqldb_bind_text(st, 2, "");
    sqldb_bind_blob(st, 2, "", 0);
    sqldb_bind_text(st, 3, "y");
    T_EQ_INT(sqldb_step(st), SQLDB_DONE);
    sqldb_reset(st);
    sqldb_bind_int64(st, 1, 3);
    sqldb_bind_null(st, 2);
    T_EQ_INT(sqldb_step(st), SQLDB_DONE);
    sqldb_finalize(st);
    T_OK(sqldb_prepare(db, "SELECT v, t FROM b ORDER BY k", &st), NULL);
    size_t len = 99;
    T_EQ_INT(sqldb_step(st), SQLDB_ROW);
    const unsigned char *v = sqldb_column_blob(st, 0, &len);
    T_TRUE(v != NULL);
    T_EQ_INT(len, sizeof(all));
    T_TRUE(memcmp(v, all, sizeof(all)) == 0);
    T_EQ_STR(sqldb_column_text(st, 1), "x");
    T_EQ_INT(sqldb_step(st), SQLDB_ROW);
    T_TRUE(sqldb_column_blob(st, 0, &len) != NULL); /* empty, not NULL */
    T_EQ_INT(len, 0);
    T_EQ_INT(sqldb_step(st), SQLDB_ROW);
    T_TRUE(sqldb_column_blob(st, 0, &len) == NULL);
    T_EQ_INT(len, 0);
    T_EQ_INT(sqldb_step(st), SQLDB_DONE);
    sqldb_finalize(st);
    sqldb_close(db);
}

T_CASE(store_file_put_on_one_host_is_read_on_another)
{
    FIRST_HOST(s, a, "share-a", false);
    const char *b = host_dir("share-b");
    /* 2.5 MiB + 1 (three chunks, the last short), exactly 1 MiB, and nothing */
    size_t sizes[3] = { 5 * MIB / 2 + 1, MIB, 0 };
    unsigned char *data[3];
    char sha[3][STORE_SHA_HEX], path[1200];
    for (int i = 0; i < 3; i++) {
        data[i] = bytes(sizes[i], 7 + (uint32_t)i);
        T_OK(store_file_put(s, data[i], sizes[i], sha[i], &err), &err);
    }
    /* a file the slicer made beside the store: adopted on a worker, then recorded */
    char made[600], adopted[STORE_SHA_HEX];
    snprintf(made, sizeof(made), "%s/files/job-1.gcode", a);
    unsigned char *gcode = bytes(MIB + 5, 99);
    FILE *fp = fopen(made, "w");
    T_TRUE(fp && fwrite(gcode, 1, MIB + 5, fp) == MIB + 5);
    fclose(fp);
    int64_t size;
    T_OK(store_file_adopt(s, made, adopted, &size, &err), &err);
    T_OK(store_file_record(s, adopted, size, &err), &err);
    store_close(s); /* one daemon per database until hosts hold leases (issue 32) */
    T_EQ_INT(t_store_int(a, "SELECT count(*) FROM file_chunks"), 3 + 1 + 1 + 2);

    s = open_other_host(a, b, &err);
    T_TRUE(s != NULL);
    for (int i = 0; i < 3; i++) {
        T_OK(store_file_path(s, sha[i], path, sizeof(path), &err), &err);
        T_TRUE(strncmp(path, b, strlen(b)) == 0); /* B's cache, not A's dir */
        T_TRUE(holds(path, data[i], sizes[i]));
        T_OK(store_file_path(s, sha[i], path, sizeof(path), &err), &err); /* cached now */
        T_TRUE(holds(path, data[i], sizes[i]));
        free(data[i]);
    }
    T_OK(store_file_path(s, adopted, path, sizeof(path), &err), &err);
    T_TRUE(holds(path, gcode, MIB + 5));
    /* a file B stores again, that the database has, is not sent again: nothing changes */
    T_OK(store_file_put(s, gcode, MIB + 5, adopted, &err), &err);
    T_EQ_INT(temporaries(b), 0);
    free(gcode);
    store_close(s);
}

T_CASE(store_file_corrupt_chunk_is_refused_not_cached)
{
    FIRST_HOST(s, a, "corrupt-a", false);
    const char *b = host_dir("corrupt-b");
    size_t n = 2 * MIB + 100;
    unsigned char *data = bytes(n, 3);
    char sha[STORE_SHA_HEX], path[1200];
    T_OK(store_file_put(s, data, n, sha, &err), &err);
    store_close(s);
    T_OK(t_store_exec(a, "UPDATE file_chunks SET data = set_byte(data, 7, (get_byte(data, 7) + 1)"
                         " % 256) WHERE seq = 1"),
         NULL);
    s = open_other_host(a, b, &err);
    T_TRUE(s != NULL);
    T_ERR(store_file_path(s, sha, path, sizeof(path), &err), SF_EIO, &err, "corrupt, not kept");
    T_TRUE(access(path, F_OK) != 0);
    T_EQ_INT(temporaries(b), 0);
    /* a chunk cut short, a chunk gone, a size no store wrote */
    T_OK(t_store_exec(a,
                      "UPDATE file_chunks SET data = substring(data from 1 for 10) WHERE seq = 1"),
         NULL);
    T_ERR(store_file_path(s, sha, path, sizeof(path), &err), SF_EIO, &err,
          "chunk 1 is 10 bytes, not 1048576");
    T_OK(t_store_exec(a, "DELETE FROM file_chunks WHERE seq = 2"), NULL);
    T_ERR(store_file_path(s, sha, path, sizeof(path), &err), SF_EIO, &err,
          "chunk 1 is 10 bytes"); /* the first damage still found first */
    T_OK(t_store_exec(a, "DELETE FROM file_chunks WHERE seq = 1"), NULL);
    T_ERR(store_file_path(s, sha, path, sizeof(path), &err), SF_EIO, &err,
          "chunk 1 of 3 is not in the database");
    T_OK(t_store_exec(a, "UPDATE file_blobs SET size = 5000000000000"), NULL);
    T_ERR(store_file_path(s, sha, path, sizeof(path), &err), SF_EIO, &err,
          "not a file this store wrote");
    T_TRUE(access(path, F_OK) != 0);
    T_EQ_INT(temporaries(b), 0);
    /* a file recorded but not in the database (before files were shared) */
    T_OK(t_store_exec(a, "DELETE FROM file_blobs"), NULL);
    T_EQ_INT(t_store_int(a, "SELECT count(*) FROM file_chunks"), 0); /* cascaded */
    T_ERR(store_file_path(s, sha, path, sizeof(path), &err), SF_ENOTFOUND, &err,
          "is not in the database, only in the data dir of the host that stored it");
    /* the host that has it sends it again when it stores it again */
    store_close(s);
    s = t_store_open(a, NULL, &err);
    T_TRUE(s != NULL);
    T_OK(store_file_put(s, data, n, sha, &err), &err);
    store_close(s);
    s = open_other_host(a, b, &err);
    T_TRUE(s != NULL);
    T_OK(store_file_path(s, sha, path, sizeof(path), &err), &err);
    T_TRUE(holds(path, data, n));
    store_close(s);
    free(data);
}

/* A trigger that fails every insert into table (when, an SQL condition on NEW) with msg. */
static int
refuse_inserts(const char *dir, const char *table, const char *when, const char *msg)
{
    char sql[1024];
    if (t_store_pg())
        snprintf(sql, sizeof(sql),
                 "CREATE OR REPLACE FUNCTION refuse_%s() RETURNS trigger LANGUAGE plpgsql AS "
                 "$$BEGIN IF %s THEN RAISE EXCEPTION '%s'; END IF; RETURN NEW; END$$;"
                 "CREATE TRIGGER refuse_%s BEFORE INSERT ON %s FOR EACH ROW "
                 "EXECUTE FUNCTION refuse_%s();",
                 table, when, msg, table, table, table);
    else
        snprintf(sql, sizeof(sql),
                 "CREATE TRIGGER refuse_%s BEFORE INSERT ON %s WHEN %s BEGIN "
                 "SELECT RAISE(ABORT, '%s'); END;",
                 table, table, when, msg);
    return t_store_exec(dir, sql);
}

T_CASE(store_file_put_again_sends_nothing)
{
    FIRST_HOST(s, dir, "reput", true);
    size_t n = MIB + 3;
    unsigned char *data = bytes(n, 5);
    char sha[STORE_SHA_HEX], again[STORE_SHA_HEX];
    T_OK(store_file_put(s, data, n, sha, &err), &err);
    int64_t chunks = t_store_int(dir, "SELECT count(*) FROM file_chunks");
    T_EQ_INT(chunks, t_store_pg() ? 2 : 0);
    /* any byte sent again now fails the put */
    T_OK(refuse_inserts(dir, "file_chunks", "true", "sent again"), NULL);
    T_OK(refuse_inserts(dir, "file_blobs", "true", "claimed again"), NULL);
    T_OK(store_file_put(s, data, n, again, &err), &err);
    T_EQ_STR(again, sha);
    T_EQ_INT(t_store_int(dir, "SELECT count(*) FROM file_chunks"), chunks);
    T_EQ_INT(t_store_int(dir, "SELECT count(*) FROM files"), 1);
    free(data);
    store_close(s);
}

T_CASE(store_file_partial_upload_leaves_no_claim)
{
    FIRST_HOST(s, dir, "partial", false);
    size_t n = 7 * MIB / 2;
    unsigned char *data = bytes(n, 11);
    char sha[STORE_SHA_HEX], path[1200];
    /* the database fails the third chunk, as a full disk or a dropped connection would */
    T_OK(refuse_inserts(dir, "file_chunks", "NEW.seq = 2", "disk full (test)"), NULL);
    T_ERR(store_file_put(s, data, n, sha, &err), SF_EIO, &err, "chunk 2: disk full (test)");
    T_EQ_INT(t_store_int(dir, "SELECT count(*) FROM file_blobs"), 0);
    T_EQ_INT(t_store_int(dir, "SELECT count(*) FROM file_chunks"), 0);
    T_EQ_INT(t_store_int(dir, "SELECT count(*) FROM files"), 0);
    /* the store's connection is usable, and the put, once the fault is gone, completes */
    T_OK(t_store_exec(dir, "DROP TRIGGER refuse_file_chunks ON file_chunks"), NULL);
    T_OK(store_file_put(s, data, n, sha, &err), &err);
    T_EQ_INT(t_store_int(dir, "SELECT count(*) FROM file_chunks"), 4);
    T_OK(store_file_path(s, sha, path, sizeof(path), &err), &err);
    free(data);
    store_close(s);
}

T_CASE(store_file_over_the_size_limit_is_refused)
{
    FIRST_HOST(s, dir, "huge", false);
    /* a sparse file at an address: the limit is checked before a byte is read */
    const char *sha = "00ff00ff00ff00ff00ff00ff00ff00ff00ff00ff00ff00ff00ff00ff00ff00ff";
    char sub[600], path[700];
    snprintf(sub, sizeof(sub), "%s/files/00", dir);
    mkdir(sub, 0700);
    snprintf(path, sizeof(path), "%s/%s", sub, sha);
    int fd = open(path, O_CREAT | O_WRONLY, 0600);
    T_TRUE(fd >= 0 && ftruncate(fd, SF_STORE_BLOB_MAX + 1) == 0);
    close(fd);
    T_ERR(store_file_record(s, sha, SF_STORE_BLOB_MAX + 1, &err), SF_EINVAL, &err,
          "over the 4294967296 a file shared through the database may have");
    T_EQ_INT(t_store_int(dir, "SELECT count(*) FROM files"), 0);
    unlink(path);
    store_close(s);
}

/* A database that does not answer whether a file is stored (here its table is gone, as a lost
   connection or a busy server would leave it) gives its error, not "no such file": a job was
   failed as missing its part, a file sent again, for a failure that may pass. */
T_CASE(store_file_lookup_failure_is_not_a_missing_file)
{
    FIRST_HOST(s, dir, "lookup", true);
    char sha[STORE_SHA_HEX], path[1200];
    T_OK(store_file_put(s, "solid x", 7, sha, &err), &err);
    T_OK(t_store_exec(dir, "ALTER TABLE files RENAME TO files_away"), NULL);
    T_ERR(store_file_path(s, sha, path, sizeof(path), &err), SF_EIO, &err, "files");
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "part.stl");
    int64_t id = 0;
    T_ERR(store_job_add(s, &o, sha, &id, &err), SF_EIO, &err, "files");
    struct job_event_args g = { .prep_key = "any", .nozzle_mm = 0.4 };
    T_ERR(store_job_add_gcode(s, &o, sha, &g, &id, &err), SF_EIO, &err, "files");
    T_OK(t_store_exec(dir, "ALTER TABLE files_away RENAME TO files"), NULL);
    T_OK(store_file_path(s, sha, path, sizeof(path), &err), &err);
    T_OK(store_job_add(s, &o, sha, &id, &err), &err);
    T_TRUE(id > 0);
    store_close(s);
}
