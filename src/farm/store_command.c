/*
 * store_command.c - command rows: an action on a printer another host
 * owns, carried through the database (store_command.h).
 *
 * Why rows and not a NOTIFY payload alone: a notification is lost when the
 * owner's listener is away, and carries no answer; a row is there until it
 * is taken, withdrawn or answered, and its state says which, so the asker
 * and the owner agree on whether it ran.  The NOTIFY only wakes.
 *
 * Thread: any, one store handle per thread (store.h).
 */
#include "store_command.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/clock.h"

#include "store_host.h"
#include "store_int.h"

static const char *const state_names[] = { "pending", "running", "done", "expired" };

const char *
store_command_state_name(enum store_command_state s)
{
    return (unsigned)s < sizeof(state_names) / sizeof(state_names[0]) ? state_names[s] : "?";
}

static enum store_command_state
state_parse(const char *s)
{
    for (unsigned i = 0; i < sizeof(state_names) / sizeof(state_names[0]); i++)
        if (strcmp(s, state_names[i]) == 0)
            return (enum store_command_state)i;
    return STORE_CMD_EXPIRED; /* a state this program does not know: never run */
}

#define COLS                                                                                       \
    "id, printer, host, from_host, kind, line, who, state, rc, message, printer_state,"            \
    " created_ms, deadline_ms"

/*
 * The database's clock in ms since the epoch, as an SQL expression: a
 * command's deadline is set and judged by it alone.  Why not the hosts'
 * clocks: the asker set the deadline from its own and the owner compared
 * it with its own, so two hosts' clocks a few seconds apart ran a command
 * late or expired it at once.  PostgreSQL's clock_timestamp() is the time
 * of the call (now() is the transaction's start); SQLite is one host.
 */
#define PG_NOW    "CAST(extract(epoch FROM clock_timestamp()) * 1000 AS BIGINT)"
#define LITE_NOW  "CAST((julianday('now') - 2440587.5) * 86400000 AS INTEGER)"
#define DB_NOW(s) (store_is_pg(s) ? PG_NOW : LITE_NOW)

/* A store_row_fn: a struct store_command from a row of COLS. */
static void
read_row(struct sqldb_stmt *st, void *row)
{
    struct store_command *c = row;
    char state[16];
    memset(c, 0, sizeof(*c));
    c->id = sqldb_column_int64(st, 0);
    store_copy_text(c->printer, sizeof(c->printer), st, 1);
    store_copy_text(c->host, sizeof(c->host), st, 2);
    store_copy_text(c->from, sizeof(c->from), st, 3);
    store_copy_text(c->kind, sizeof(c->kind), st, 4);
    store_copy_text(c->line, sizeof(c->line), st, 5);
    store_copy_text(c->who, sizeof(c->who), st, 6);
    store_copy_text(state, sizeof(state), st, 7);
    c->state = state_parse(state);
    c->rc = sqldb_column_int(st, 8);
    store_copy_text(c->message, sizeof(c->message), st, 9);
    store_copy_text(c->printer_state, sizeof(c->printer_state), st, 10);
    c->created_ms = sqldb_column_int64(st, 11);
    c->deadline_ms = sqldb_column_int64(st, 12);
}

/* A store_row_fn: read_row, then how long its deadline is away (the take's last column). */
static void
read_taken(struct sqldb_stmt *st, void *row)
{
    struct store_command *c = row;
    read_row(st, row);
    c->left_ms = sqldb_column_int64(st, 13);
}

/* One row of st (a statement returning COLS) into *out, st finalized: SF_ENOTFOUND (err not set).
 */
static int
one_row(struct store *s, struct sqldb_stmt *st, struct store_command *out, const char *what,
        struct sf_err *err)
{
    int rc = sqldb_step(st);
    if (rc == SQLDB_ROW)
        read_row(st, out);
    sqldb_finalize(st);
    if (rc == SQLDB_ROW)
        return SF_OK;
    return rc == SQLDB_DONE ? SF_ENOTFOUND : store_db_fail(s, err, what);
}

static int
check_text(const char *field, const char *v, size_t cap, bool required, struct sf_err *err)
{
    if (required && (!v || !v[0]))
        return sf_err_set(err, SF_EINVAL, "command: %s is required", field);
    if (v && strlen(v) >= cap)
        return sf_err_set(err, SF_EINVAL, "command: %s is longer than %zu bytes", field, cap - 1);
    return SF_OK;
}

/* printer's owner into owner, whether its lease runs at now_ms into *live and since when it ran
   out into *down_ms; SF_ENOTFOUND (err set) when no host owns printer. */
static int
owner_of(struct store *s, const char *printer, int64_t now_ms, char *owner, bool *live,
         int64_t *down_ms, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st,
                           "SELECT hp.host, h.lease_until_ms, h.reaped_ms FROM host_printers hp"
                           " JOIN hosts h ON h.name = hp.host WHERE hp.printer = ?1",
                           err);
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, printer);
    rc = sqldb_step(st);
    if (rc == SQLDB_ROW) {
        store_copy_text(owner, STORE_HOST_NAME_MAX, st, 0);
        int64_t until = sqldb_column_int64(st, 1), reaped = sqldb_column_int64(st, 2);
        *live = until > now_ms && reaped == 0;
        *down_ms = now_ms - until;
    }
    sqldb_finalize(st);
    if (rc == SQLDB_DONE)
        return sf_err_set(err, SF_ENOTFOUND, "no printer '%.64s' on any host", printer);
    return rc == SQLDB_ROW ? SF_OK : store_db_fail(s, err, "command: printer's owner");
}

/* store_command_add in the caller's transaction. */
static int
add_tx(struct store *s, const char *from, const char *printer, const char *kind, const char *line,
       const char *who, int64_t now_ms, int64_t wait_ms, struct store_command *out,
       struct sf_err *err)
{
    char owner[STORE_HOST_NAME_MAX] = "";
    bool live = false;
    int64_t down_ms = 0;
    int rc = owner_of(s, printer, now_ms, owner, &live, &down_ms, err);
    if (rc)
        return rc;
    if (strcmp(owner, from) == 0)
        return sf_err_set(err, SF_EINVAL, "printer '%.64s' is host %s's own: not sent to itself",
                          printer, from);
    if (!live)
        return sf_err_set(err, SF_ESTALE,
                          "printer '%.64s' is offline: its host %s is down (its lease ran out "
                          "%.0f s ago); nothing was sent",
                          printer, owner, (double)(down_ms > 0 ? down_ms : 0) / 1000);
    struct sqldb_stmt *st;
    char sql[512];
    snprintf(sql, sizeof(sql), "DELETE FROM commands WHERE created_ms < %s - ?1", DB_NOW(s));
    if ((rc = store_prepare(s, &st, sql, err)))
        return rc;
    sqldb_bind_int64(st, 1, STORE_COMMAND_KEEP_MS);
    if ((rc = store_step_done(s, st, err, "command: delete old rows")))
        return rc;
    snprintf(sql, sizeof(sql),
             "INSERT INTO commands(printer, host, from_host, kind, line, who, state, created_ms,"
             " deadline_ms) VALUES(?1, ?2, ?3, ?4, ?5, ?6, 'pending', %s, %s + ?7) RETURNING " COLS,
             DB_NOW(s), DB_NOW(s));
    if ((rc = store_prepare(s, &st, sql, err)))
        return rc;
    sqldb_bind_text(st, 1, printer);
    sqldb_bind_text(st, 2, owner);
    sqldb_bind_text(st, 3, from);
    sqldb_bind_text(st, 4, kind);
    sqldb_bind_text(st, 5, line ? line : "");
    sqldb_bind_text(st, 6, who ? who : "");
    sqldb_bind_int64(st, 7, wait_ms);
    if ((rc = one_row(s, st, out, "command: add", err)))
        return rc == SF_ENOTFOUND ? store_db_fail(s, err, "command: add") : rc;
    return sqldb_notify(s->db, STORE_COMMAND_CHANNEL, owner) ? store_db_fail(s, err, "notify")
                                                             : SF_OK;
}

int
store_command_add(struct store *s, const char *from, const char *printer, const char *kind,
                  const char *line, const char *who, int64_t now_ms, int64_t wait_ms,
                  struct store_command *out, struct sf_err *err)
{
    int rc = check_text("from", from, STORE_HOST_NAME_MAX, true, err);
    if (rc || (rc = check_text("printer", printer, sizeof(out->printer), true, err)) ||
        (rc = check_text("kind", kind, sizeof(out->kind), true, err)) ||
        (rc = check_text("line", line, sizeof(out->line), false, err)) ||
        (rc = check_text("who", who, sizeof(out->who), false, err)))
        return rc;
    if (wait_ms <= 0)
        return sf_err_set(err, SF_EINVAL, "command: wait %lld ms is not after now",
                          (long long)wait_ms);
    now_ms += store_clock_ms(s) - clock_wall_ms(); /* onto the database's clock */
    if ((rc = store_begin(s, err)))
        return rc;
    rc = add_tx(s, from, printer, kind, line, who, now_ms, wait_ms, out, err);
    return store_end_tx(s, rc, err);
}

static int
by_id(const void *a, const void *b)
{
    int64_t x = ((const struct store_command *)a)->id, y = ((const struct store_command *)b)->id;
    return (x > y) - (x < y);
}

int
store_command_take(struct store *s, const char *host, struct store_command **rows, size_t *n,
                   struct sf_err *err)
{
    *rows = NULL;
    *n = 0;
    int rc = check_text("host", host, STORE_HOST_NAME_MAX, true, err);
    struct sqldb_stmt *st;
    char sql[512];
    if (rc || (rc = store_begin(s, err)))
        return rc;
    /* the overdue ones first: they never run, and their askers read why */
    snprintf(sql, sizeof(sql),
             "UPDATE commands SET state = 'expired' WHERE host = ?1 AND state = 'pending'"
             " AND deadline_ms <= %s",
             DB_NOW(s));
    if ((rc = store_prepare(s, &st, sql, err)) == SF_OK) {
        sqldb_bind_text(st, 1, host);
        rc = store_step_done(s, st, err, "command: expire overdue");
    }
    void *out = NULL;
    snprintf(sql, sizeof(sql),
             "UPDATE commands SET state = 'running' WHERE host = ?1 AND state = 'pending'"
             " AND deadline_ms > %s RETURNING " COLS ", deadline_ms - %s",
             DB_NOW(s), DB_NOW(s));
    if (rc == SF_OK && (rc = store_prepare(s, &st, sql, err)) == SF_OK) {
        sqldb_bind_text(st, 1, host);
        rc = store_read_rows(s, st, sizeof(struct store_command), read_taken, &out, n,
                             "command: take", err);
    }
    if ((rc = store_end_tx(s, rc, err))) {
        free(out);
        *n = 0;
        return rc;
    }
    *rows = out;
    if (*n > 1)
        qsort(*rows, *n, sizeof(**rows), by_id);
    return SF_OK;
}

int
store_command_finish(struct store *s, int64_t id, int rc_run, const char *message,
                     const char *printer_state, struct sf_err *err)
{
    struct sqldb_stmt *st;
    struct store_command c;
    int rc = store_begin(s, err);
    if (rc)
        return rc;
    if ((rc = store_prepare(s, &st,
                            "UPDATE commands SET state = 'done', rc = ?2, message = ?3,"
                            " printer_state = ?4 WHERE id = ?1 AND state = 'running'"
                            " RETURNING " COLS,
                            err)))
        return store_end_tx(s, rc, err);
    sqldb_bind_int64(st, 1, id);
    sqldb_bind_int64(st, 2, rc_run);
    sqldb_bind_text(st, 3, message ? message : "");
    sqldb_bind_text(st, 4, printer_state ? printer_state : "");
    rc = one_row(s, st, &c, "command: finish", err);
    if (rc == SF_ENOTFOUND)
        sf_err_set(err, SF_ENOTFOUND, "command %lld is not running: its result not written",
                   (long long)id);
    if (rc == SF_OK && sqldb_notify(s->db, STORE_COMMAND_CHANNEL, c.from))
        rc = store_db_fail(s, err, "notify");
    return store_end_tx(s, rc, err);
}

int
store_command_get(struct store *s, int64_t id, struct store_command *out, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st, "SELECT " COLS " FROM commands WHERE id = ?1", err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, id);
    rc = one_row(s, st, out, "command: read", err);
    return rc == SF_ENOTFOUND ? sf_err_set(err, SF_ENOTFOUND, "no command %lld", (long long)id)
                              : rc;
}

int
store_command_expire(struct store *s, int64_t id, struct store_command *out, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st,
                           "UPDATE commands SET state = 'expired' WHERE id = ?1"
                           " AND state = 'pending'",
                           err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, id);
    if ((rc = store_step_done(s, st, err, "command: expire")))
        return rc;
    return store_command_get(s, id, out, err);
}

static void
read_printer(struct sqldb_stmt *st, void *row)
{
    struct store_command_printer *p = row;
    memset(p, 0, sizeof(*p));
    store_copy_text(p->name, sizeof(p->name), st, 0);
    store_copy_text(p->host, sizeof(p->host), st, 1);
    store_copy_text(p->state, sizeof(p->state), st, 2);
    p->live = sqldb_column_int(st, 3) != 0;
    p->down_ms = sqldb_column_int64(st, 4);
    p->bed_full = sqldb_column_int(st, 5) != 0;
    p->job_id = sqldb_column_int64(st, 6);
    p->lines_acked = sqldb_column_int64(st, 7);
    p->gcode_lines = sqldb_column_int64(st, 8);
    store_copy_text(p->view, sizeof(p->view), st, 9);
}

/* Each other host's view (a JSON object by printer name) split into one row a printer, if its
   current process published it: each view is parsed once, not once for each of its printers (a
   host of n printers made n parses of its whole view: 10 hosts of 100 printers, 0.76-0.90 s a
   read on PostgreSQL, 17-24 ms now).  MATERIALIZED: left to itself, PostgreSQL's planner
   re-ran the split for every printer's row.  One engine's json_each each; a view that is not
   an object splits into nothing. */
#define VIEWS_PG                                                                                   \
    "SELECT v.host, v.token, e.key, CAST(e.value AS TEXT) AS view FROM host_views v,"              \
    " json_each(CASE WHEN json_typeof(CAST(v.view AS json)) = 'object'"                            \
    " THEN CAST(v.view AS json) ELSE CAST('{}' AS json) END) e WHERE v.host != ?1"
#define VIEWS_SQL                                                                                  \
    "SELECT v.host, v.token, e.key, e.value AS view FROM host_views v,"                            \
    " json_each(CASE WHEN json_valid(v.view) AND json_type(v.view) = 'object'"                     \
    " THEN v.view ELSE '{}' END) e WHERE v.host != ?1"
#define PRINTERS_SQL(VIEWS)                                                                        \
    "WITH pv AS MATERIALIZED (" VIEWS ")"                                                          \
    " SELECT hp.printer, hp.host, coalesce(p.state, ''),"                                          \
    " CASE WHEN h.reaped_ms = 0 AND h.lease_until_ms > ?2 THEN 1 ELSE 0 END,"                      \
    " ?2 - h.lease_until_ms, coalesce(p.bed_full, 0), coalesce(j.id, 0),"                          \
    " coalesce(j.lines_acked, 0), coalesce(j.gcode_lines, 0), coalesce(pv.view, '')"               \
    " FROM host_printers hp JOIN hosts h ON h.name = hp.host"                                      \
    " LEFT JOIN printers p ON p.name = hp.printer"                                                 \
    " LEFT JOIN pv ON pv.host = hp.host AND pv.token = h.token AND pv.key = hp.printer"            \
    " LEFT JOIN jobs j ON j.id = (SELECT max(id) FROM jobs WHERE printer = hp.printer"             \
    " AND state IN ('printing','paused'))"                                                         \
    " WHERE hp.host != ?1 ORDER BY hp.printer"

int
store_command_printers(struct store *s, const char *me, int64_t now_ms,
                       struct store_command_printer **rows, size_t *n, struct sf_err *err)
{
    now_ms += store_clock_ms(s) - clock_wall_ms(); /* onto the database's clock */
    struct sqldb_stmt *st;
    void *out = NULL;
    int rc = store_select(
        s, &st, sqldb_engine(s->db) == SQLDB_PG ? PRINTERS_SQL(VIEWS_PG) : PRINTERS_SQL(VIEWS_SQL),
        &out, n, err);
    *rows = NULL;
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, me);
    sqldb_bind_int64(st, 2, now_ms);
    rc = store_read_rows(s, st, sizeof(struct store_command_printer), read_printer, &out, n,
                         "other hosts' printers", err);
    *rows = out;
    return rc;
}

int
store_command_listen(struct store *s, struct sf_err *err)
{
    if (sqldb_listen(s->db, STORE_COMMAND_CHANNEL) || sqldb_listen(s->db, STORE_VIEW_CHANNEL) ||
        sqldb_listen(s->db, STORE_EVENT_CHANNEL))
        return store_db_fail(s, err, "listen");
    return SF_OK;
}

struct drain {
    store_command_note_fn fn;
    void *ud;
};

static void
on_note(void *arg, const char *channel, const char *payload)
{
    const struct drain *d = arg;
    if (d->fn)
        d->fn(d->ud, channel, payload ? payload : "");
}

int
store_command_drain(struct store *s, store_command_note_fn fn, void *ud)
{
    struct drain d = { fn, ud };
    return sqldb_notifications(s->db, on_note, &d);
}

int
store_command_notify_fd(struct store *s)
{
    return sqldb_notify_fd(s->db);
}
