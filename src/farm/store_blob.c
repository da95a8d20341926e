/*
 * store_blob.c - the files' copy in a PostgreSQL store's database, which
 * every host reads (store_int.h: store_blob_upload, store_blob_fetch).
 *
 * Several hosts on one database share parts and G-code by SHA-256 through
 * that database, each keeping its data dir's files/ as a cache, rather
 * than through a shared directory: hosts in another room have no shared
 * file system, and the database is the one thing every host reaches
 * already.  A file's bytes go into file_chunks in STORE_CHUNK_BYTES
 * pieces (bytea, sent in binary), and its file_blobs row, written in the
 * same transaction, says they are all there.  Both ways stream: one chunk
 * in memory at a time (two on a fetch: the escaped text libpq receives,
 * and its bytes), whatever the file's size.
 *
 * Uploads are idempotent and safe to race: a file whose row is there is
 * not sent again, and of two hosts sending the same file the second waits
 * on the first's row (INSERT ... ON CONFLICT DO NOTHING) and then sends
 * nothing.  A fetch lands in a temporary file under files/, and is renamed
 * to its address only once its SHA-256 is the one asked for.
 *
 * Thread: the connection's (store_file_adopt uploads on a worker's own).
 */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "../base/clock.h"
#include "../base/limits.h"
#include "../base/mem.h"
#include "store_int.h"

/* 1 MiB: big enough that a round trip per chunk costs little (100 per 100 MB), small enough
   that a chunk in memory (twice that as the hex text a fetch receives) is nothing to a host. */
#define STORE_CHUNK_BYTES (1 << 20)

/* Read up to cap bytes from fd into buf, short only at the end of the file; -1 on error. */
static ssize_t
read_full(int fd, unsigned char *buf, size_t cap)
{
    size_t n = 0;
    while (n < cap) {
        ssize_t r = read(fd, buf + n, cap - n);
        if (r < 0 && errno == EINTR)
            continue;
        if (r < 0)
            return -1;
        if (r == 0)
            break;
        n += (size_t)r;
    }
    return (ssize_t)n;
}

/* Whether db holds sha's bytes (file_blobs), with their size and chunk size; SF_OK or the
   database's failure (sqldb_errcode). */
static int
blob_find(struct sqldb *db, const char *sha, bool *found, int64_t *size, int64_t *chunk,
          struct sf_err *err)
{
    struct sqldb_stmt *st;
    *found = false;
    if (sqldb_prepare(db, "SELECT size, chunk_bytes FROM file_blobs WHERE sha256 = ?", &st))
        return sf_err_set(err, sqldb_errcode(db), "store: file %s: %s", sha, sqldb_errmsg(db));
    sqldb_bind_text(st, 1, sha);
    int rc = sqldb_step(st);
    if (rc == SQLDB_ROW) {
        *found = true;
        *size = sqldb_column_int64(st, 0);
        *chunk = sqldb_column_int64(st, 1);
    }
    sqldb_finalize(st);
    return rc < 0 ? sf_err_set(err, sqldb_errcode(db), "store: file %s: %s", sha, sqldb_errmsg(db))
                  : SF_OK;
}

/* Claim sha for this upload: its file_blobs row, in the open transaction; *mine false when
   another's upload has it (committed, after waiting for it if it was under way).  SF_EIO
   with the message on db. */
static int
blob_claim(struct sqldb *db, const char *sha, int64_t size, bool *mine)
{
    struct sqldb_stmt *st;
    if (sqldb_prepare(db,
                      "INSERT INTO file_blobs(sha256, size, chunk_bytes, created_ms)"
                      " VALUES(?,?,?,?) ON CONFLICT DO NOTHING",
                      &st))
        return SF_EIO;
    sqldb_bind_text(st, 1, sha);
    sqldb_bind_int64(st, 2, size);
    sqldb_bind_int64(st, 3, STORE_CHUNK_BYTES);
    sqldb_bind_int64(st, 4, clock_wall_ms());
    int rc = sqldb_step(st);
    sqldb_finalize(st);
    *mine = sqldb_changes(db) == 1;
    return rc < 0 ? rc : SF_OK;
}

/* Send fd's bytes (size of them) as sha's chunks in the open transaction, hashing them into
   got; SF_EIO with err set for the file, the database (the message left on db: the caller
   words it) or a size that changed. */
static int
send_chunks(struct sqldb *db, int fd, const char *path, const char *sha, int64_t size,
            char got[STORE_SHA_HEX], struct sf_err *err)
{
    unsigned char *buf = mem_alloc(STORE_CHUNK_BYTES);
    struct store_sha *md = store_sha_new(err);
    struct sqldb_stmt *st = NULL;
    int rc = buf && md ? SF_OK : sf_err_set(err, SF_ENOMEM, "store: out of memory");
    if (rc == SF_OK &&
        sqldb_prepare(db, "INSERT INTO file_chunks(sha256, seq, data) VALUES(?,?,?)", &st))
        rc =
            sf_err_set(err, sqldb_errcode(db), "store: sending file %s: %s", sha, sqldb_errmsg(db));
    int64_t sent = 0;
    for (int64_t seq = 0; rc == SF_OK; seq++) {
        ssize_t n = read_full(fd, buf, STORE_CHUNK_BYTES);
        if (n < 0)
            rc = sf_err_sys(err, "store: reading '%s'", path);
        else if (n == 0 && seq > 0)
            break;
        else if ((rc = store_sha_update(md, buf, (size_t)n, err)) == SF_OK) {
            sqldb_reset(st);
            sqldb_bind_text(st, 1, sha);
            sqldb_bind_int64(st, 2, seq);
            sqldb_bind_blob(st, 3, buf, (size_t)n);
            if (sqldb_step(st) < 0)
                rc = sf_err_set(err, sqldb_errcode(db), "store: sending file %s, chunk %lld: %s",
                                sha, (long long)seq, sqldb_errmsg(db));
            sent += n;
            if (n < STORE_CHUNK_BYTES)
                break;
        }
    }
    if (rc == SF_OK && sent != size)
        rc = sf_err_set(err, SF_EIO, "store: '%s' changed while it was sent (%lld bytes, not %lld)",
                        path, (long long)sent, (long long)size);
    if (rc == SF_OK)
        rc = store_sha_final(md, got, err);
    sqldb_finalize(st);
    store_sha_free(md);
    free(buf);
    return rc;
}

int
store_blob_upload(struct sqldb *db, const char *path, const char *sha, struct sf_err *err)
{
    bool found, mine = false;
    int64_t size = 0, chunk;
    char got[STORE_SHA_HEX] = "";
    int rc = blob_find(db, sha, &found, &size, &chunk, err);
    if (rc || found)
        return rc;
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0)
        return sf_err_sys(err, "store: cannot read '%s' to send it to the database", path);
    struct stat sb;
    if (fstat(fd, &sb) != 0) {
        rc = sf_err_sys(err, "store: cannot stat '%s'", path);
        goto out_close;
    }
    size = sb.st_size;
    if (size > SF_STORE_BLOB_MAX) {
        rc = sf_err_set(err, SF_EINVAL,
                        "store: file %s is %lld bytes, over the %lld a file shared through the "
                        "database may have",
                        sha, (long long)size, (long long)SF_STORE_BLOB_MAX);
        goto out_close;
    }
    if (sqldb_begin(db) || blob_claim(db, sha, size, &mine)) {
        rc =
            sf_err_set(err, sqldb_errcode(db), "store: sending file %s: %s", sha, sqldb_errmsg(db));
        goto out_rollback;
    }
    if (mine && (rc = send_chunks(db, fd, path, sha, size, got, err)) == SF_OK &&
        strcmp(got, sha) != 0)
        rc =
            sf_err_set(err, SF_EIO, "store: '%s' has SHA-256 %s, not %s: not sent", path, got, sha);
    if (rc == SF_OK && sqldb_commit(db))
        rc =
            sf_err_set(err, sqldb_errcode(db), "store: sending file %s: %s", sha, sqldb_errmsg(db));
    if (rc == SF_OK)
        goto out_close;
out_rollback:
    sqldb_rollback(db);
out_close:
    close(fd);
    return rc;
}

/* Fetch sha's chunks (size bytes, chunk bytes each but the last) from db into f. */
static int
recv_chunks(struct sqldb *db, struct store_file *f, const char *sha, int64_t size, int64_t chunk,
            struct sf_err *err)
{
    struct sqldb_stmt *st = NULL;
    int rc = SF_OK;
    if (sqldb_prepare(db, "SELECT data FROM file_chunks WHERE sha256 = ? AND seq = ?", &st))
        rc = sf_err_set(err, sqldb_errcode(db), "store: fetching file %s: %s", sha,
                        sqldb_errmsg(db));
    int64_t n_chunks = size == 0 ? 1 : (size + chunk - 1) / chunk;
    for (int64_t seq = 0; rc == SF_OK && seq < n_chunks; seq++) {
        int64_t want = seq + 1 < n_chunks ? chunk : size - seq * chunk;
        size_t len = 0;
        const unsigned char *data = NULL;
        sqldb_reset(st);
        sqldb_bind_text(st, 1, sha);
        sqldb_bind_int64(st, 2, seq);
        int r = sqldb_step(st);
        if (r == SQLDB_ROW)
            data = sqldb_column_blob(st, 0, &len);
        if (r < 0)
            rc = sf_err_set(err, sqldb_errcode(db), "store: fetching file %s, chunk %lld: %s", sha,
                            (long long)seq, sqldb_errmsg(db));
        else if (r != SQLDB_ROW)
            rc =
                sf_err_set(err, SF_EIO, "store: file %s: chunk %lld of %lld is not in the database",
                           sha, (long long)seq, (long long)n_chunks);
        else if (!data)
            rc = sf_err_set(err, SF_ENOMEM, "store: fetching file %s: out of memory", sha);
        else if ((int64_t)len != want)
            rc = sf_err_set(err, SF_EIO, "store: file %s: chunk %lld is %zu bytes, not %lld", sha,
                            (long long)seq, len, (long long)want);
        else
            rc = store_file_write(f, data, len, err);
    }
    sqldb_finalize(st);
    return rc;
}

int
store_blob_fetch(struct sqldb *db, const char *dir, const char *sha, struct sf_err *err)
{
    bool found;
    int64_t size = 0, chunk = 0;
    int rc = blob_find(db, sha, &found, &size, &chunk, err);
    if (rc)
        return rc;
    if (!found)
        return sf_err_set(err, SF_ENOTFOUND,
                          "store: file %s is not in the database, only in the data dir of the "
                          "host that stored it (before files were shared): store it again there",
                          sha);
    if (size < 0 || size > SF_STORE_BLOB_MAX || chunk <= 0 || chunk > SF_STORE_BLOB_MAX)
        return sf_err_set(err, SF_EIO,
                          "store: file %s: the database gives %lld bytes in chunks "
                          "of %lld: not a file this store wrote",
                          sha, (long long)size, (long long)chunk);
    /* a temporary file, hashed as it is written, placed only if its SHA-256 is sha */
    struct store_file *f = store_file_begin_in(dir, err);
    if (!f)
        return err ? err->code : SF_EIO;
    if ((rc = recv_chunks(db, f, sha, size, chunk, err))) {
        store_file_abort(f);
        return rc;
    }
    return store_file_keep_as(f, sha, err);
}
