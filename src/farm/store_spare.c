/*
 * store_spare.c - a host with spare cores prepares for another host's
 * printer (store_host.h; farm_spare.c decides when): each host publishes
 * what preparing for its printers needs on their host_printers rows
 * (schema 16), another host reads the live hosts' published printers, and
 * the job it prepared for one of them is recorded ready and given up in one
 * transaction, so the printer's own host takes it as it takes any ready job
 * no host holds.
 *
 * Thread: any, one store handle per thread (store.h).
 */
#include "store.h"
#include "store_host.h"
#include "store_int.h"

#include <stdio.h>
#include <string.h>

#include "../base/clock.h"

/* Write p onto name's row of its printer, in the caller's transaction.  A printer with no
   profile (farmcfg accepts an empty one) is written as is: store_host_printers_prep leaves it
   out, and the publish of the others goes on. */
static int
publish_one(struct store *s, const char *name, const struct store_printer_prep *p,
            struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st,
                           "UPDATE host_printers SET profile = ?3, material = ?4, nozzle_mm = ?5,"
                           " bed_x = ?6, bed_y = ?7, bed_z = ?8, overhang_deg = ?9,"
                           " printer_group = ?10, gcode_models = ?11, attended = ?12,"
                           " allow_gcode = ?13, enabled = ?14 WHERE printer = ?1 AND host = ?2",
                           err);
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, p->name);
    sqldb_bind_text(st, 2, name);
    sqldb_bind_text(st, 3, p->profile);
    sqldb_bind_text(st, 4, p->material);
    sqldb_bind_double(st, 5, p->nozzle_mm);
    for (int i = 0; i < 3; i++)
        sqldb_bind_double(st, 6 + i, p->bed_mm[i]);
    sqldb_bind_double(st, 9, p->overhang_deg);
    sqldb_bind_text(st, 10, p->group);
    sqldb_bind_text(st, 11, p->gcode_models);
    sqldb_bind_int64(st, 12, p->attended);
    sqldb_bind_text(st, 13, p->allow_gcode);
    sqldb_bind_int64(st, 14, p->enabled);
    return store_step_done(s, st, err, "publish a printer");
}

int
store_host_publish(struct store *s, const char *name, int64_t token,
                   const struct store_printer_prep *p, size_t n, struct sf_err *err)
{
    int rc = store_begin(s, err);
    if (rc)
        return rc;
    rc = store_host_hold(s, name, token, store_clock_ms(s), err);
    for (size_t i = 0; rc == SF_OK && i < n; i++)
        rc = publish_one(s, name, &p[i], err);
    return store_end_tx(s, rc, err);
}

static void
read_prep(struct sqldb_stmt *st, void *row)
{
    struct store_printer_prep *p = row;
    memset(p, 0, sizeof(*p));
    store_copy_text(p->name, sizeof(p->name), st, 0);
    store_copy_text(p->host, sizeof(p->host), st, 1);
    store_copy_text(p->profile, sizeof(p->profile), st, 2);
    store_copy_text(p->material, sizeof(p->material), st, 3);
    p->nozzle_mm = sqldb_column_double(st, 4);
    for (int i = 0; i < 3; i++)
        p->bed_mm[i] = sqldb_column_double(st, 5 + i);
    p->overhang_deg = sqldb_column_double(st, 8);
    store_copy_text(p->group, sizeof(p->group), st, 9);
    store_copy_text(p->gcode_models, sizeof(p->gcode_models), st, 10);
    p->attended = sqldb_column_int64(st, 11) != 0;
    store_copy_text(p->allow_gcode, sizeof(p->allow_gcode), st, 12);
    p->enabled = sqldb_column_int64(st, 13) != 0;
}

int
store_host_printers_prep(struct store *s, const char *name, int64_t now_ms,
                         struct store_printer_prep **rows, size_t *n, struct sf_err *err)
{
    now_ms += store_clock_ms(s) - clock_wall_ms(); /* onto the database's clock */
    struct sqldb_stmt *st;
    int rc = store_select(s, &st,
                          "SELECT hp.printer, hp.host, hp.profile, hp.material, hp.nozzle_mm,"
                          " hp.bed_x, hp.bed_y, hp.bed_z, hp.overhang_deg, hp.printer_group,"
                          " hp.gcode_models, hp.attended, hp.allow_gcode, hp.enabled"
                          " FROM host_printers hp JOIN hosts h ON h.name = hp.host"
                          " WHERE hp.host != ?1 AND h.reaped_ms = 0 AND h.lease_until_ms > ?2"
                          " AND hp.profile != '' ORDER BY hp.printer",
                          (void **)rows, n, err);
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, name);
    sqldb_bind_int64(st, 2, now_ms);
    return store_read_rows(s, st, sizeof(**rows), read_prep, (void **)rows, n,
                           "read the other hosts' printers", err);
}

/* The release of store_job_prepared_release, in the caller's transaction after the
   PREPARED: the job is ready under fence. */
static int
release_tx(struct store *s, int64_t id, int64_t fence, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st, "SELECT claimed_by FROM jobs WHERE id = ?1", err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, id);
    char host[STORE_HOST_NAME_MAX] = "";
    rc = sqldb_step(st);
    if (rc == SQLDB_ROW)
        store_copy_text(host, sizeof(host), st, 0);
    sqldb_finalize(st);
    if (rc != SQLDB_ROW)
        return store_db_fail(s, err, "read a job's holder");
    if ((rc = store_prepare(s, &st,
                            "UPDATE jobs SET claimed_by = '', fence = fence + 1, updated_ms = ?1"
                            " WHERE id = ?2 AND fence = ?3 AND state = 'ready'",
                            err)))
        return rc;
    sqldb_bind_int64(st, 1, store_clock_ms(s)); /* the claims' clock */
    sqldb_bind_int64(st, 2, id);
    sqldb_bind_int64(st, 3, fence);
    if ((rc = store_step_done(s, st, err, "hand a job over")))
        return rc;
    if (sqldb_changes(s->db) != 1)
        return sf_err_set(err, SF_ESTALE,
                          "job %lld: not handed over: not ready under fencing token %lld",
                          (long long)id, (long long)fence);
    char detail[160];
    snprintf(detail, sizeof(detail),
             "ready: host '%s' prepared it for another host's printer: no host holds it", host);
    if ((rc = store_log_event(s, id, NULL, "job-hand-over", detail, err)))
        return rc;
    return store_is_pg(s) ? store_host_wake(s, err) : SF_OK; /* at the commit */
}

int
store_job_prepared_release(struct store *s, int64_t id, const struct job_event_args *a,
                           enum job_state *to, struct sf_err *err)
{
    int rc = store_begin(s, err);
    if (rc)
        return rc;
    rc = store_job_event_in(s, id, JOB_EV_PREPARED, a, to, err);
    if (rc == SF_OK)
        rc = release_tx(s, id, a->fence, err);
    return store_end_tx(s, rc, err);
}
