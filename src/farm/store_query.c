/*
 * store_query.c - the store's reads whose cost must not grow with history
 * (store.h): the live jobs the scheduler works from, the targeted lookup
 * of a printer's interrupted job, pages of jobs for the API, the metrics'
 * aggregates, and read-only connections for a thread off the loop.
 *
 * Why: a farm keeps every job it ever printed.  The scheduler, the
 * printers and /metrics once read them all at each change or scrape, on
 * the loop that feeds the printers; 5,700 jobs were 3.7 MB of JSON and a
 * print stretched from 26 s to 47 s under one client listing jobs
 * (issue 30).  Each query here goes through an index (schema 7) or an
 * SQL aggregate, and a page has a hard bound.
 *
 * Thread: the store's (a reader's: the one thread that uses it).
 */
#include "store.h"

#include <stdio.h>
#include <string.h>

#include "../base/buf.h"
#include "../base/mem.h"
#include "store_int.h"

int
store_job_live(struct store *s, struct job_row **rows, size_t *n, struct sf_err *err)
{
    /* the WHERE is the partial index's own, word for word, so SQLite reads jobs_live */
    struct sqldb_stmt *st;
    int rc = store_select(s, &st,
                          "SELECT " STORE_JOB_COLS " FROM jobs"
                          " WHERE state NOT IN ('done','failed','cancelled') ORDER BY id",
                          (void **)rows, n, err);
    if (rc)
        return rc;
    return store_read_rows(s, st, sizeof(**rows), store_read_job, (void **)rows, n,
                           "list live jobs", err);
}

int
store_job_interrupted(struct store *s, const char *printer, struct job_row *out, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st,
                           "SELECT " STORE_JOB_COLS " FROM jobs"
                           " WHERE state = 'interrupted' AND printer = ?"
                           " ORDER BY updated_ms DESC, id DESC LIMIT 1",
                           err);
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, printer);
    rc = store_job_one(s, st, out, "interrupted job", err);
    if (rc == SF_ENOTFOUND)
        return sf_err_set(err, SF_ENOTFOUND, "printer %s holds no interrupted job", printer);
    return rc;
}

/* The WHERE and ORDER of a page for f (states from job.h's fixed names, the rest bound). */
static void
page_sql(const struct store_job_filter *f, char *sql, size_t cap)
{
    size_t len = (size_t)snprintf(sql, cap, "SELECT " STORE_JOB_COLS " FROM jobs WHERE %s",
                                  f->newest_first ? "id < ?1" : "id > ?1");
    if (f->states) {
        len += (size_t)snprintf(sql + len, cap - len, " AND state IN (");
        const char *sep = "";
        for (int i = 0; i < JOB_STATE_COUNT; i++)
            if (f->states & (1u << i)) {
                len += (size_t)snprintf(sql + len, cap - len, "%s'%s'", sep,
                                        job_state_name((enum job_state)i));
                sep = ",";
            }
        len += (size_t)snprintf(sql + len, cap - len, ")");
    }
    if (f->printer && f->printer[0])
        len += (size_t)snprintf(sql + len, cap - len,
                                " AND (printer = ?2 OR id IN"
                                " (SELECT job_id FROM prints WHERE printer = ?2))");
    if (f->since_ms > 0)
        len += (size_t)snprintf(sql + len, cap - len, " AND updated_ms >= ?3");
    if (f->until_ms > 0)
        len += (size_t)snprintf(sql + len, cap - len, " AND updated_ms < ?4");
    if (f->name && f->name[0]) /* instr, not LIKE: '%' and '_' in a name are plain text */
        len += (size_t)snprintf(sql + len, cap - len, " AND instr(lower(name), lower(?6)) > 0");
    snprintf(sql + len, cap - len, " ORDER BY id %s LIMIT ?5", f->newest_first ? "DESC" : "ASC");
}

int
store_job_page(struct store *s, const struct store_job_filter *f, size_t limit,
               struct job_row **rows, size_t *n, bool *more, struct sf_err *err)
{
    *rows = NULL;
    *n = 0;
    if (more)
        *more = false;
    if (limit < 1 || limit > STORE_PAGE_MAX)
        return sf_err_set(err, SF_EINVAL, "store: page limit %zu is not 1 to %d", limit,
                          STORE_PAGE_MAX);
    char sql[sizeof(STORE_JOB_COLS) + 512];
    page_sql(f, sql, sizeof(sql));
    struct sqldb_stmt *st;
    int rc = store_select(s, &st, sql, (void **)rows, n, err);
    if (rc)
        return rc;
    int64_t after = f->after_id > 0 ? f->after_id : (f->newest_first ? INT64_MAX : 0);
    sqldb_bind_int64(st, 1, after);
    if (f->printer && f->printer[0])
        sqldb_bind_text(st, 2, f->printer);
    if (f->since_ms > 0)
        sqldb_bind_int64(st, 3, f->since_ms);
    if (f->until_ms > 0)
        sqldb_bind_int64(st, 4, f->until_ms);
    sqldb_bind_int64(st, 5, (int64_t)limit + 1); /* one more: is there a next page */
    if (f->name && f->name[0])
        sqldb_bind_text(st, 6, f->name);
    rc = store_read_rows(s, st, sizeof(**rows), store_read_job, (void **)rows, n, "page of jobs",
                         err);
    if (rc == SF_OK && *n > limit) {
        *n = limit;
        if (more)
            *more = true;
    }
    return rc;
}

int
store_job_counts(struct store *s, uint64_t by_state[JOB_STATE_COUNT], struct sf_err *err)
{
    memset(by_state, 0, sizeof(uint64_t) * JOB_STATE_COUNT);
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st, "SELECT state, count(*) FROM jobs GROUP BY state", err);
    if (rc)
        return rc;
    while ((rc = sqldb_step(st)) == SQLDB_ROW) {
        enum job_state js;
        const char *t = sqldb_column_text(st, 0);
        if (t && job_state_parse((const char *)t, &js))
            by_state[js] = (uint64_t)sqldb_column_int64(st, 1);
    }
    sqldb_finalize(st);
    return rc == SQLDB_DONE ? SF_OK : store_db_fail(s, err, "count jobs");
}

static void
read_job_printer(struct sqldb_stmt *st, void *row)
{
    struct store_job_printer *p = row;
    p->job_id = sqldb_column_int64(st, 0);
    store_copy_text(p->printer, sizeof(p->printer), st, 1);
}

int
store_last_printers(struct store *s, const int64_t *ids, size_t n_ids,
                    struct store_job_printer **rows, size_t *n, struct sf_err *err)
{
    /* the page's ids as one array parameter (at most STORE_PAGE_MAX of
       them: SQLite's JSON [1,2], PostgreSQL's bigint[] {1,2}); the newest
       print of each job is its highest id, through the prints_job index */
    bool lite = sqldb_engine(s->db) == SQLDB_SQLITE;
    struct buf list;
    buf_init(&list, 0);
    int rc = buf_printf(&list, lite ? "[" : "{");
    for (size_t i = 0; i < n_ids && rc == SF_OK; i++)
        rc = buf_printf(&list, "%s%lld", i ? "," : "", (long long)ids[i]);
    if (rc == SF_OK)
        rc = buf_printf(&list, lite ? "]" : "}");
    if (rc) {
        buf_release(&list);
        return sf_err_set(err, SF_ENOMEM, "store: out of memory listing a page's jobs");
    }
    char sql[256];
    snprintf(sql, sizeof(sql),
             "SELECT job_id, printer FROM prints WHERE id IN (SELECT (SELECT max(id)"
             " FROM prints WHERE job_id = ids.value) FROM %s) ORDER BY job_id",
             lite ? "json_each(?1) AS ids" : "unnest(CAST(?1 AS bigint[])) AS ids(value)");
    struct sqldb_stmt *st;
    rc = store_select(s, &st, sql, (void **)rows, n, err);
    if (rc == SF_OK) {
        sqldb_bind_text(st, 1, list.data);
        rc = store_read_rows(s, st, sizeof(**rows), read_job_printer, (void **)rows, n,
                             "last printers", err);
    }
    buf_release(&list);
    return rc;
}

static void
read_tally(struct sqldb_stmt *st, void *row)
{
    struct print_tally *t = row;
    memset(t, 0, sizeof(*t));
    store_copy_text(t->printer, sizeof(t->printer), st, 0);
    store_copy_text(t->outcome, sizeof(t->outcome), st, 1);
    t->n = (uint64_t)sqldb_column_int64(st, 2);
    t->filament_g = sqldb_column_double(st, 3);
    t->saved_g = sqldb_column_double(st, 4);
}

int
store_print_tally(struct store *s, struct print_tally **rows, size_t *n, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_select(
        s, &st,
        "SELECT p.printer, p.outcome, count(*), coalesce(sum(j.filament_g), 0),"
        " coalesce(sum(j.support_saved_g), 0) FROM prints p JOIN jobs j ON j.id = p.job_id"
        " WHERE p.outcome != '' GROUP BY p.printer, p.outcome ORDER BY min(p.id)",
        (void **)rows, n, err);
    if (rc)
        return rc;
    return store_read_rows(s, st, sizeof(**rows), read_tally, (void **)rows, n, "tally prints",
                           err);
}

int
store_hist(struct store *s, enum store_hist which, const double *bounds_s, size_t n,
           struct store_hist_out *out, struct sf_err *err)
{
    static const char *const from[] = {
        [STORE_HIST_PREPARE] = "prepare_ms / 1000.0 AS v FROM jobs WHERE prepare_ms > 0",
        [STORE_HIST_SLICE] = "slice_ms / 1000.0 AS v FROM jobs WHERE slice_ms > 0",
        [STORE_HIST_PRINT] = "(ended_ms - started_ms) / 1000.0 AS v FROM prints"
                             " WHERE outcome = 'done' AND ended_ms >= started_ms",
        [STORE_HIST_WAIT] = "wait_ms / 1000.0 AS v FROM prints WHERE outcome != '' AND wait_ms > 0",
    };
    memset(out, 0, sizeof(*out));
    if (n > STORE_HIST_BOUNDS_MAX || (unsigned)which >= sizeof(from) / sizeof(from[0]))
        return sf_err_set(err, SF_EINVAL, "store: histogram of %zu bounds", n);
    char sql[1024];
    size_t len = (size_t)snprintf(sql, sizeof(sql), "SELECT count(*), coalesce(sum(v), 0)");
    for (size_t i = 0; i < n; i++)
        len += (size_t)snprintf(sql + len, sizeof(sql) - len,
                                ", coalesce(sum(CASE WHEN v <= ?%zu THEN 1 ELSE 0 END), 0)", i + 1);
    snprintf(sql + len, sizeof(sql) - len, " FROM (SELECT %s) AS t", from[which]);
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st, sql, err);
    if (rc)
        return rc;
    for (size_t i = 0; i < n; i++)
        sqldb_bind_double(st, (int)i + 1, bounds_s[i]);
    rc = sqldb_step(st);
    if (rc == SQLDB_ROW) {
        out->count = (uint64_t)sqldb_column_int64(st, 0);
        out->sum_s = sqldb_column_double(st, 1);
        for (size_t i = 0; i < n; i++)
            out->le[i] = (uint64_t)sqldb_column_double(st, (int)i + 2);
    }
    sqldb_finalize(st);
    return rc == SQLDB_ROW ? SF_OK : store_db_fail(s, err, "histogram");
}

/* A writer's new session after a lost connection holds no lock: take the host name it joined
   again, if any (store_host_relock; a refusal fails the reconnect, tried again later). */
static int
relock_name(struct sqldb *db, void *arg, struct sf_err *err)
{
    (void)db;
    return store_host_relock(arg, err);
}

/* A second connection to s's database: read-only (flags SQLDB_READONLY) or a writer. */
static struct store *
open_peer(const struct store *s, unsigned flags, struct sf_err *err)
{
    struct store *r = mem_calloc(1, sizeof(*r));
    if (!r) {
        sf_err_set(err, SF_ENOMEM, "store: out of memory");
        return NULL;
    }
    snprintf(r->dir, sizeof(r->dir), "%s", s->dir);
    snprintf(r->target, sizeof(r->target), "%s", s->target);
    r->lock_fd = -1;   /* the writer holds the data dir */
    r->host = s->host; /* one of several hosts: a holder's events without a fence are refused */
    if (!(r->db = sqldb_open(r->target, flags, err))) {
        store_close(r);
        return NULL;
    }
    if (!(flags & SQLDB_READONLY))
        sqldb_on_reconnect(r->db, relock_name, r);
    return r;
}

struct store *
store_open_reader(const struct store *s, struct sf_err *err)
{
    return open_peer(s, SQLDB_READONLY, err);
}

struct store *
store_open_writer(const struct store *s, struct sf_err *err)
{
    return open_peer(s, 0, err);
}
