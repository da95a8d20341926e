/*
 * store_stats.c - per-printer statistics over a window of days (store.h,
 * store_print_stats): success, hours printing and each day's use, for
 * GET /api/stats and the history page's plot.
 *
 * Why in C rather than one SQL aggregate: a print that runs across
 * midnight counts on both days, and a running one up to now; SQLite has
 * no day series to join with, and a recursive one costs more than the
 * walk.  The walk reads only the prints that overlap the window
 * (started before now, ended after its start or still running), one row
 * at a time, never holding them all.
 *
 * Thread: the store's (the API's reader).
 */
#include "store.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"
#include "store_int.h"

#define DAY_MS INT64_C(86400000)

int64_t
store_stats_since_ms(int64_t now_ms, int n_days)
{
    return (now_ms / DAY_MS - (n_days - 1)) * DAY_MS;
}

/* The row for printer in *rows (added, zeroed, when new); NULL when out of memory. */
static struct store_printer_stats *
slot(struct store_printer_stats **rows, size_t *n, size_t *cap, const char *printer)
{
    for (size_t i = 0; i < *n; i++)
        if (strcmp((*rows)[i].printer, printer) == 0)
            return &(*rows)[i];
    if (!mem_grow((void **)rows, cap, *n + 1, sizeof(**rows)))
        return NULL;
    struct store_printer_stats *r = &(*rows)[(*n)++];
    memset(r, 0, sizeof(*r));
    snprintf(r->printer, sizeof(r->printer), "%s", printer);
    return r;
}

/* Add the part of [a, b) inside the window to r, day by day. */
static void
add_time(struct store_printer_stats *r, int64_t a, int64_t b, int64_t since, int n_days)
{
    if (a < since)
        a = since;
    while (a < b) {
        int64_t day = (a - since) / DAY_MS;
        if (day >= n_days)
            break;
        int64_t end = since + (day + 1) * DAY_MS;
        int64_t upto = b < end ? b : end;
        r->day_s[day] += (double)(upto - a) / 1000;
        r->print_s += (double)(upto - a) / 1000;
        a = upto;
    }
}

static int
by_name(const void *x, const void *y)
{
    return strcmp(((const struct store_printer_stats *)x)->printer,
                  ((const struct store_printer_stats *)y)->printer);
}

int
store_print_stats(struct store *s, int64_t now_ms, int n_days, struct store_printer_stats **rows,
                  size_t *n, struct sf_err *err)
{
    *rows = NULL;
    *n = 0;
    if (n_days < 1 || n_days > STORE_STATS_DAYS_MAX)
        return sf_err_set(err, SF_EINVAL, "store: statistics over %d days (1 to %d)", n_days,
                          STORE_STATS_DAYS_MAX);
    int64_t since = store_stats_since_ms(now_ms, n_days);
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st,
                           "SELECT printer, outcome, started_ms, ended_ms FROM prints"
                           " WHERE started_ms < ?1 AND (outcome = '' OR ended_ms >= ?2)",
                           err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, now_ms);
    sqldb_bind_int64(st, 2, since);
    size_t cap = 0;
    while ((rc = sqldb_step(st)) == SQLDB_ROW) {
        const char *printer = sqldb_column_text(st, 0);
        const char *outcome = sqldb_column_text(st, 1);
        struct store_printer_stats *r = slot(rows, n, &cap, printer ? printer : "");
        if (!r) {
            sqldb_finalize(st);
            free(*rows);
            *rows = NULL;
            *n = 0;
            return sf_err_set(err, SF_ENOMEM, "store: out of memory");
        }
        outcome = outcome ? outcome : "";
        int64_t a = sqldb_column_int64(st, 2), b = sqldb_column_int64(st, 3);
        bool running = !outcome[0];
        add_time(r, a, running || b > now_ms ? now_ms : b, since, n_days);
        if (running)
            continue;
        if (strcmp(outcome, "done") == 0)
            r->done++;
        else if (strcmp(outcome, "failed") == 0)
            r->failed++;
        else if (strcmp(outcome, "cancelled") == 0)
            r->cancelled++;
        else
            r->other++;
    }
    sqldb_finalize(st);
    if (rc != SQLDB_DONE) {
        free(*rows);
        *rows = NULL;
        *n = 0;
        return store_db_fail(s, err, "print statistics");
    }
    if (*n > 1)
        qsort(*rows, *n, sizeof(**rows), by_name);
    return SF_OK;
}
