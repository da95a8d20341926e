/*
 * store_printer_cfg.c - the printers an operator manages at run time
 * (store.h store_printer_cfg_*; farm_printers.c decides what they mean):
 * one row a printer the API added, edited, disabled or removed, in table
 * printer_cfgs (migration 10, STORE_PRINTER_CFG_SCHEMA in store_int.h).
 *
 * Why a row holds the section's text and not a column an option: the
 * option set belongs to farmcfg.c and the driver kinds (drivers/drv.c),
 * and grows with them; the text is what farm.ini would hold, parsed by the
 * same code at each start, so a stored printer and a file's are checked
 * alike and no migration follows a new option.  Each write is one
 * transaction that logs a "printer-config" event (the dashboard's cue).
 *
 * Thread: the store's.
 */
#include "store.h"

#include <stdio.h>

#include "../base/clock.h"
#include "store_int.h"

static void
read_row(struct sqldb_stmt *st, void *row)
{
    struct store_printer_cfg *r = row;
    r->id = sqldb_column_int64(st, 0);
    store_copy_text(r->name, sizeof(r->name), st, 1);
    r->has_cfg = !sqldb_column_null(st, 2);
    store_copy_text(r->cfg, sizeof(r->cfg), st, 2);
    r->disabled = !sqldb_column_null(st, 3);
    store_copy_text(r->reason, sizeof(r->reason), st, 3);
    r->removed = sqldb_column_int(st, 4) != 0;
}

int
store_printer_cfg_list(struct store *s, struct store_printer_cfg **rows, size_t *n,
                       struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_select(s, &st,
                          "SELECT id, name, cfg, disabled, removed FROM printer_cfgs ORDER BY id",
                          (void **)rows, n, err);
    if (rc)
        return rc;
    return store_read_rows(s, st, sizeof(**rows), read_row, (void **)rows, n,
                           "list printer configs", err);
}

int
store_printer_cfg_put(struct store *s, const struct store_printer_cfg *r, const char *detail,
                      struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_write_begin(
        s, &st,
        "INSERT INTO printer_cfgs(name, cfg, disabled, removed, updated_ms)"
        " VALUES(?1, ?2, ?3, ?4, ?5) ON CONFLICT(name) DO UPDATE SET cfg = ?2, disabled = ?3,"
        " removed = ?4, updated_ms = ?5",
        err);
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, r->name);
    if (r->has_cfg)
        sqldb_bind_text(st, 2, r->cfg);
    else
        sqldb_bind_null(st, 2);
    if (r->disabled)
        sqldb_bind_text(st, 3, r->reason);
    else
        sqldb_bind_null(st, 3);
    sqldb_bind_int64(st, 4, r->removed);
    sqldb_bind_int64(st, 5, clock_wall_ms());
    return store_write_end(s, st, "put printer config", 0, r->name, "printer-config", detail, err);
}

int
store_printer_cfg_drop(struct store *s, const char *name, const char *detail, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_write_begin(s, &st, "DELETE FROM printer_cfgs WHERE name = ?1", err);
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, name);
    return store_write_end(s, st, "drop printer config", 0, name, "printer-config", detail, err);
}
