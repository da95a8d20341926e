/*
 * sqldb.c - the engine-neutral half of sqldb.h: picks a driver by the
 * target's form and dispatches each call through its table.
 *
 * Thread: as sqldb.h.
 */
#include "sqldb.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/clock.h"
#include "sqldb_int.h"

bool
sqldb_is_url(const char *target)
{
    return strncmp(target, "postgresql://", 13) == 0 || strncmp(target, "postgres://", 11) == 0;
}

int64_t
sqldb_test_skew_ms(void)
{
    const char *skew = getenv("SLIMFARM_TEST_CLOCK_SKEW_MS");
    return skew ? strtoll(skew, NULL, 10) : 0;
}

struct sqldb *
sqldb_open(const char *target, unsigned flags, struct sf_err *err)
{
    if (sqldb_is_url(target))
        return sqldb_pg_open(target, flags, err);
    struct sqldb *db = sqldb_sqlite_open(target, flags, err);
    if (db)
        db->clock_skew_ms = sqldb_test_skew_ms();
    return db;
}

/* One line: libpq's messages span several ("...failed: No such file\n\tIs the server
   running...?\n"), and a log line must not.  Whitespace runs become one space. */
static void
one_line(char *m)
{
    char *o = m;
    for (const char *i = m; *i; i++) {
        bool ws = *i == '\n' || *i == '\t' || *i == ' ' || *i == '\r';
        if (!ws)
            *o++ = *i;
        else if (o > m && o[-1] != ' ')
            *o++ = ' ';
    }
    while (o > m && o[-1] == ' ')
        o--;
    *o = '\0';
}

int
sqldb_fail(struct sqldb *db, const char *msg)
{
    snprintf(db->msg, sizeof(db->msg), "%s", msg ? msg : "unknown error");
    one_line(db->msg);
    db->code = SF_EIO;
    return SF_EIO;
}

int
sqldb_failf(struct sqldb *db, int code, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(db->msg, sizeof(db->msg), fmt, ap);
    va_end(ap);
    one_line(db->msg);
    db->code = code;
    return code;
}

void
sqldb_close(struct sqldb *db)
{
    if (db)
        db->ops->close(db);
}

enum sqldb_engine
sqldb_engine(const struct sqldb *db)
{
    return db->ops->engine;
}

const char *
sqldb_errmsg(const struct sqldb *db)
{
    return db->msg;
}

int
sqldb_errcode(const struct sqldb *db)
{
    return db->code < 0 ? db->code : SF_EIO;
}

int
sqldb_exec(struct sqldb *db, const char *sql)
{
    db->code = SF_OK;
    return db->ops->exec(db, sql);
}

int
sqldb_begin(struct sqldb *db)
{
    db->code = SF_OK;
    int rc = db->ops->exec(db, db->ops->begin_sql);
    db->in_tx = rc == SF_OK;
    return rc;
}

int
sqldb_commit(struct sqldb *db)
{
    db->code = SF_OK;
    int rc = db->ops->exec(db, "COMMIT");
    if (rc != SF_OK)
        sqldb_rollback(db); /* still in the transaction: a lost connection is not retried */
    db->in_tx = false;
    return rc;
}

void
sqldb_rollback(struct sqldb *db)
{
    /* outside a transaction there is nothing to undo, and a call could reconnect (a failed
       COMMIT rolls back itself: the caller's rollback after it must not wait on the network) */
    if (!db->in_tx)
        return;
    char msg[SQLDB_MSG_MAX];
    snprintf(msg, sizeof(msg), "%s", db->msg); /* keep the failure that led here */
    int code = db->code;
    db->ops->exec(db, "ROLLBACK");
    db->in_tx = false;
    snprintf(db->msg, sizeof(db->msg), "%s", msg);
    db->code = code;
}

int
sqldb_commit_outcome(struct sqldb *db)
{
    db->code = SF_OK;
    return db->ops->commit_outcome ? db->ops->commit_outcome(db) : 0;
}

int
sqldb_set_durable(struct sqldb *db, bool durable)
{
    return db->ops->set_durable(db, durable);
}

int64_t
sqldb_changes(const struct sqldb *db)
{
    return db->changes;
}

int
sqldb_prepare(struct sqldb *db, const char *sql, struct sqldb_stmt **st)
{
    *st = NULL;
    db->code = SF_OK;
    return db->ops->prepare(db, sql, st);
}

void
sqldb_bind_int64(struct sqldb_stmt *st, int i, int64_t v)
{
    st->db->ops->bind_int64(st, i, v);
}

void
sqldb_bind_double(struct sqldb_stmt *st, int i, double v)
{
    st->db->ops->bind_double(st, i, v);
}

void
sqldb_bind_text(struct sqldb_stmt *st, int i, const char *text)
{
    if (text)
        st->db->ops->bind_text(st, i, text);
    else
        st->db->ops->bind_null(st, i);
}

void
sqldb_bind_null(struct sqldb_stmt *st, int i)
{
    st->db->ops->bind_null(st, i);
}

void
sqldb_bind_blob(struct sqldb_stmt *st, int i, const void *data, size_t len)
{
    st->db->ops->bind_blob(st, i, data, len);
}

int
sqldb_step(struct sqldb_stmt *st)
{
    st->db->code = SF_OK;
    return st->db->ops->step(st);
}

int64_t
sqldb_column_int64(struct sqldb_stmt *st, int col)
{
    return st->db->ops->column_int64(st, col);
}

int
sqldb_column_int(struct sqldb_stmt *st, int col)
{
    return (int)st->db->ops->column_int64(st, col);
}

double
sqldb_column_double(struct sqldb_stmt *st, int col)
{
    return st->db->ops->column_double(st, col);
}

const char *
sqldb_column_text(struct sqldb_stmt *st, int col)
{
    return st->db->ops->column_text(st, col);
}

bool
sqldb_column_null(struct sqldb_stmt *st, int col)
{
    return st->db->ops->column_null(st, col);
}

const void *
sqldb_column_blob(struct sqldb_stmt *st, int col, size_t *len)
{
    return st->db->ops->column_blob(st, col, len);
}

void
sqldb_reset(struct sqldb_stmt *st)
{
    st->db->ops->reset(st);
}

void
sqldb_finalize(struct sqldb_stmt *st)
{
    if (st)
        st->db->ops->finalize(st);
}

void
sqldb_on_reconnect(struct sqldb *db, sqldb_reconnect_fn fn, void *arg)
{
    db->on_reconnect = fn;
    db->on_reconnect_arg = arg;
}

int64_t
sqldb_reconnects(const struct sqldb *db)
{
    return db->reconnects;
}

int64_t
sqldb_round_trips(const struct sqldb *db)
{
    return db->round_trips;
}

int64_t
sqldb_clock_ms(const struct sqldb *db)
{
    return clock_wall_ms() + db->clock_skew_ms + db->clock_offset_ms;
}

/* SF_OK if channel is a name LISTEN and pg_notify read alike (sqldb.h), else SF_EINVAL. */
static int
check_channel(struct sqldb *db, const char *channel)
{
    size_t n = channel ? strlen(channel) : 0;
    bool ok = n > 0 && n <= SQLDB_CHANNEL_MAX && !(channel[0] >= '0' && channel[0] <= '9');
    for (size_t i = 0; ok && i < n; i++)
        ok = (channel[i] >= 'a' && channel[i] <= 'z') || (channel[i] >= '0' && channel[i] <= '9') ||
             channel[i] == '_';
    if (ok)
        return SF_OK;
    return sqldb_failf(db, SF_EINVAL,
                       "channel '%.80s': not a valid name (a-z, 0-9 and _, starting with a "
                       "letter or _, 1 to %d bytes)",
                       channel ? channel : "(null)", SQLDB_CHANNEL_MAX);
}

int
sqldb_listen(struct sqldb *db, const char *channel)
{
    db->code = SF_OK;
    int rc = check_channel(db, channel);
    return rc || !db->ops->listen ? rc : db->ops->listen(db, channel);
}

int
sqldb_notify(struct sqldb *db, const char *channel, const char *payload)
{
    db->code = SF_OK;
    int rc = check_channel(db, channel);
    if (rc)
        return rc;
    size_t n = payload ? strlen(payload) : 0;
    if (n > SQLDB_PAYLOAD_MAX)
        return sqldb_failf(db, SF_EINVAL, "notify '%s': payload of %zu bytes is over %d", channel,
                           n, SQLDB_PAYLOAD_MAX);
    return db->ops->notify ? db->ops->notify(db, channel, payload ? payload : "") : SF_OK;
}

int
sqldb_notify_fd(struct sqldb *db)
{
    return db->ops->notify_fd ? db->ops->notify_fd(db) : -1;
}

int
sqldb_notifications(struct sqldb *db, sqldb_notify_fn fn, void *arg)
{
    db->code = SF_OK;
    return db->ops->notifications ? db->ops->notifications(db, fn, arg) : 0;
}
