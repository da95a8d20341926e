/*
 * store_printer.c - printers in the store (store.h): their last state and
 * whether their bed holds a part, each change logged as an event.
 *
 * Thread: the store's.
 */
#include "store.h"

#include "../base/clock.h"
#include "store_int.h"

int
store_printer_set(struct store *s, const char *name, enum printer_state state, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_write_begin(s, &st,
                               "INSERT INTO printers(name, state, updated_ms) VALUES(?1, ?2, ?3)"
                               " ON CONFLICT(name) DO UPDATE SET state = ?2, updated_ms = ?3",
                               err);
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, name);
    sqldb_bind_text(st, 2, printer_state_name(state));
    sqldb_bind_int64(st, 3, clock_wall_ms());
    return store_write_end(s, st, "set printer", 0, name, "printer-state",
                           printer_state_name(state), err);
}

int
store_printer_get(struct store *s, const char *name, enum printer_state *state, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st, "SELECT state FROM printers WHERE name = ?", err);
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, name);
    rc = sqldb_step(st);
    bool ok = false;
    if (rc == SQLDB_ROW)
        ok = printer_state_parse(sqldb_column_text(st, 0), state);
    sqldb_finalize(st);
    if (rc == SQLDB_ROW)
        return ok ? SF_OK : sf_err_set(err, SF_EBUG, "printer '%s': unknown state", name);
    if (rc == SQLDB_DONE)
        return sf_err_set(err, SF_ENOTFOUND, "printer '%s': never seen", name);
    return store_db_fail(s, err, "get printer");
}

int
store_printer_bed_set(struct store *s, const char *name, bool full, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_write_begin(
        s, &st,
        "INSERT INTO printers(name, state, updated_ms, bed_full) VALUES(?1, 'offline',"
        " ?2, ?3) ON CONFLICT(name) DO UPDATE SET bed_full = ?3, updated_ms = ?2",
        err);
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, name);
    sqldb_bind_int64(st, 2, clock_wall_ms());
    sqldb_bind_int64(st, 3, full);
    return store_write_end(s, st, "set printer bed", 0, name, "printer-bed",
                           full ? "holds a part" : "cleared", err);
}

int
store_printer_bed_get(struct store *s, const char *name, bool *full, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st, "SELECT bed_full FROM printers WHERE name = ?", err);
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, name);
    rc = sqldb_step(st);
    *full = rc == SQLDB_ROW && sqldb_column_int(st, 0) != 0;
    sqldb_finalize(st);
    if (rc == SQLDB_ROW || rc == SQLDB_DONE)
        return SF_OK;
    return store_db_fail(s, err, "get printer bed");
}

int
store_printer_note(struct store *s, const char *name, const char *kind, const char *detail,
                   struct sf_err *err)
{
    int rc = store_begin(s, err);
    if (rc)
        return rc;
    if ((rc = store_log_event(s, 0, name, kind, detail, err))) {
        store_rollback(s);
        return rc;
    }
    return store_commit(s, err);
}
