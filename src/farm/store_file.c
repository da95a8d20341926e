/*
 * store_file.c - the store's content-addressed file directory (store.h).
 *
 * Files are named by their SHA-256 (OpenSSL's libcrypto EVP interface, the
 * most widely reviewed implementation on the system): a writer hashes while
 * it streams into a temporary file, fsyncs, and renames it to
 * files/ab/abcdef...; a crash leaves at worst an orphan temporary or an
 * unreferenced file, never a row pointing at a missing or partial file.
 * The files table records which addresses are complete.
 *
 * On PostgreSQL (several hosts, one database) the data dir is each host's
 * cache and the database holds every file's bytes (store_blob.c): a file
 * recorded here is sent there first, and a path asked for a file the cache
 * lacks is fetched from there.  On SQLite the data dir is the store.
 *
 * Thread: the store's, except store_file_adopt (any: the file system, and
 * on PostgreSQL a connection of its own).
 */
#include "store.h"

#include <errno.h>
#include <fcntl.h>
#include <openssl/evp.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "../base/clock.h"
#include "../base/mem.h"
#include "store_int.h"

struct store_file {
    struct store *s;               /* owner; NULL for store_file_begin_in's */
    const char *dir;               /* the data dir it goes into (s's, or the caller's) */
    int fd;                        /* temporary file being written */
    char tmp[STORE_PATH_MAX + 64]; /* its path */
    struct store_sha *md;          /* running SHA-256 */
    int64_t size;                  /* bytes written */
};

/* ---- files ---- */

bool
store_sha_valid(const char *sha)
{
    if (strlen(sha) != 64)
        return false;
    for (const char *p = sha; *p; p++)
        if (!((*p >= '0' && *p <= '9') || (*p >= 'a' && *p <= 'f')))
            return false;
    return true;
}

struct store_file *
store_file_begin_in(const char *dir, struct sf_err *err)
{
    struct store_file *f = mem_calloc(1, sizeof(*f));
    if (!f) {
        sf_err_set(err, SF_ENOMEM, "store: out of memory");
        return NULL;
    }
    f->dir = dir;
    snprintf(f->tmp, sizeof(f->tmp), "%s/files/tmp-XXXXXX", dir);
    f->fd = mkstemp(f->tmp);
    if (f->fd < 0) {
        sf_err_sys(err, "store: cannot create a file in '%s/files'", dir);
        free(f);
        return NULL;
    }
    if (!(f->md = store_sha_new(err))) {
        store_file_abort(f);
        return NULL;
    }
    return f;
}

struct store_file *
store_file_begin(struct store *s, struct sf_err *err)
{
    struct store_file *f = store_file_begin_in(s->dir, err);
    if (f)
        f->s = s;
    return f;
}

int
store_file_write(struct store_file *f, const void *data, size_t len, struct sf_err *err)
{
    const char *p = data;
    int rc = store_sha_update(f->md, data, len, err);
    if (rc)
        return rc;
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
    store_sha_free(f->md);
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

/* struct store_sha is libcrypto's context under a name of the store's (store_int.h). */
struct store_sha *
store_sha_new(struct sf_err *err)
{
    EVP_MD_CTX *md = EVP_MD_CTX_new();
    if (!md || EVP_DigestInit_ex(md, EVP_sha256(), NULL) != 1) {
        EVP_MD_CTX_free(md);
        sf_err_set(err, SF_ENOMEM, "store: cannot start SHA-256");
        return NULL;
    }
    return (struct store_sha *)md;
}

int
store_sha_update(struct store_sha *h, const void *data, size_t len, struct sf_err *err)
{
    if (EVP_DigestUpdate((EVP_MD_CTX *)h, data, len) != 1)
        return sf_err_set(err, SF_EBUG, "store: SHA-256 update failed");
    return SF_OK;
}

int
store_sha_final(struct store_sha *h, char sha[STORE_SHA_HEX], struct sf_err *err)
{
    unsigned char d[EVP_MAX_MD_SIZE];
    unsigned int n = 0;
    if (EVP_DigestFinal_ex((EVP_MD_CTX *)h, d, &n) != 1 || n != 32)
        return sf_err_set(err, SF_EBUG, "store: SHA-256 final failed");
    for (int i = 0; i < 32; i++)
        snprintf(sha + 2 * i, 3, "%02x", d[i]);
    return SF_OK;
}

void
store_sha_free(struct store_sha *h)
{
    EVP_MD_CTX_free((EVP_MD_CTX *)h);
}

int
store_file_place(const char *data_dir, int fd, const char *from, const char *sha,
                 struct sf_err *err)
{
    if (fsync(fd) != 0)
        return sf_err_sys(err, "store: fsync '%s'", from);
    char dir[STORE_PATH_MAX + 16], path[STORE_PATH_MAX + 96];
    snprintf(dir, sizeof(dir), "%s/files/%.2s", data_dir, sha);
    snprintf(path, sizeof(path), "%s/%s", dir, sha);
    if (mkdir(dir, 0700) != 0 && errno != EEXIST)
        return sf_err_sys(err, "store: cannot create '%s'", dir);
    if (rename(from, path) != 0)
        return sf_err_sys(err, "store: cannot move '%s' to '%s'", from, path);
    fsync_dir(dir);
    return SF_OK;
}

/* The path of sha in data_dir's files into path (STORE_PATH_MAX + 96 bytes). */
static void
local_path(const char *data_dir, const char *sha, char *path)
{
    snprintf(path, STORE_PATH_MAX + 96, "%s/files/%.2s/%s", data_dir, sha, sha);
}

int
store_file_record(struct store *s, const char *sha, int64_t size, struct sf_err *err)
{
    if (!store_sha_valid(sha))
        return sf_err_set(err, SF_EINVAL, "store: '%.80s' is not a SHA-256 in hex", sha);
    struct sqldb_stmt *st;
    char path[STORE_PATH_MAX + 96];
    local_path(s->dir, sha, path);
    /* the database's copy first: a recorded file is one every host can read */
    int rc = sqldb_engine(s->db) == SQLDB_PG ? store_blob_upload(s->db, path, sha, err) : SF_OK;
    if (rc == SF_OK)
        rc = store_prepare(
            s, &st,
            "INSERT INTO files(sha256, size, created_ms) VALUES(?,?,?) ON CONFLICT DO NOTHING",
            err);
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, sha); /* store_sha_valid: 64 digits */
    sqldb_bind_int64(st, 2, size);
    sqldb_bind_int64(st, 3, clock_wall_ms());
    return store_step_done(s, st, err, "record file");
}

int
store_file_keep_as(struct store_file *f, const char *sha, struct sf_err *err)
{
    char got[STORE_SHA_HEX];
    int rc = store_sha_final(f->md, got, err);
    if (rc == SF_OK && strcmp(got, sha) != 0)
        rc = sf_err_set(err, SF_EIO, "store: file %s arrived with SHA-256 %s: corrupt, not kept",
                        sha, got);
    if (rc == SF_OK && (rc = store_file_place(f->dir, f->fd, f->tmp, sha, err)) == SF_OK) {
        close(f->fd);
        f->fd = -1;
    }
    store_file_abort(f);
    return rc;
}

int
store_file_commit(struct store_file *f, char sha[STORE_SHA_HEX], struct sf_err *err)
{
    int rc = store_sha_final(f->md, sha, err);
    if (rc == SF_OK && (rc = store_file_place(f->dir, f->fd, f->tmp, sha, err)) == SF_OK) {
        close(f->fd);
        f->fd = -1;
        rc = store_file_record(f->s, sha, f->size, err);
    }
    store_file_abort(f);
    return rc;
}

/* On PostgreSQL, send an adopted file to the database on a connection of this thread's own,
   so the heavy part of recording it stays off the store's thread; record then finds it there. */
static int
adopt_upload(const struct store *s, const char *sha, struct sf_err *err)
{
    if (!sqldb_is_url(s->target))
        return SF_OK;
    struct sqldb *db = sqldb_open(s->target, 0, err);
    if (!db)
        return err ? err->code : SF_EIO;
    char path[STORE_PATH_MAX + 96];
    local_path(s->dir, sha, path);
    int rc = store_blob_upload(db, path, sha, err);
    sqldb_close(db);
    return rc;
}

int
store_file_adopt(const struct store *s, const char *path, char sha[STORE_SHA_HEX], int64_t *size,
                 struct sf_err *err)
{
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0)
        return sf_err_sys(err, "store: cannot read '%s'", path);
    struct store_sha *md = store_sha_new(err);
    int rc = md ? SF_OK : SF_ENOMEM;
    char buf[1 << 16];
    ssize_t n;
    *size = 0;
    while (rc == SF_OK && (n = read(fd, buf, sizeof(buf))) != 0) {
        if (n < 0 && errno == EINTR)
            continue;
        if (n < 0)
            rc = sf_err_sys(err, "store: reading '%s'", path);
        else if ((rc = store_sha_update(md, buf, (size_t)n, err)) == SF_OK)
            *size += n;
    }
    if (rc == SF_OK && (rc = store_sha_final(md, sha, err)) == SF_OK)
        rc = store_file_place(s->dir, fd, path, sha, err);
    store_sha_free(md);
    close(fd);
    return rc == SF_OK ? adopt_upload(s, sha, err) : rc;
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

int
store_file_known(struct store *s, const char *sha, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st, "SELECT 1 FROM files WHERE sha256 = ?", err);
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, sha);
    rc = sqldb_step(st);
    if (rc < 0) /* before the finalize, which would take the message with it */
        rc = store_db_fail(s, err, "look up file");
    sqldb_finalize(st);
    return rc == SQLDB_ROW ? 1 : rc;
}

int
store_file_path(struct store *s, const char *sha, char *path, size_t cap, struct sf_err *err)
{
    if (!store_sha_valid(sha))
        return sf_err_set(err, SF_EINVAL, "store: '%.80s' is not a SHA-256 in hex", sha);
    int rc = store_file_known(s, sha, err);
    if (rc < 0)
        return rc; /* not known now (busy, unreachable): not "no file" */
    if (!rc)
        return sf_err_set(err, SF_ENOTFOUND, "store: no file %s", sha);
    if ((size_t)snprintf(path, cap, "%s/files/%.2s/%s", s->dir, sha, sha) >= cap)
        return sf_err_set(err, SF_ENOMEM, "store: path of file %s is too long", sha);
    /* a host's cache lacks what another host stored: fetch it */
    if (sqldb_engine(s->db) == SQLDB_PG && access(path, F_OK) != 0)
        return store_blob_fetch(s->db, s->dir, sha, err);
    return SF_OK;
}

const char *
store_file_tmp_path(const struct store_file *f)
{
    return f->tmp;
}
