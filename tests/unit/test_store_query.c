/*
 * test_store_query.c - the store's reads that must not grow with history
 * (store_query.c): the live jobs through their partial index, a printer's
 * interrupted job, pages walked by cursor while jobs are added, the
 * metrics' aggregates, and a read-only connection reading beside the
 * writer.  Real SQLite files.
 */
#include <sqlite3.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/farm/store.h"
#include "../t.h"
#include "../tstore.h"

static const char *
fresh_dir(const char *name)
{
    static char path[512];
    snprintf(path, sizeof(path), "%s/%s", t_tmpdir(), name);
    return path;
}

static int64_t
add_job(struct store *s, const char *part, struct sf_err *err)
{
    char sha[STORE_SHA_HEX];
    int64_t id = 0;
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "part.stl");
    if (store_file_put(s, part, strlen(part), sha, err) || store_job_add(s, &o, sha, &id, err))
        return 0;
    return id;
}

/* queued -> ready with some G-code -> printing on printer. */
static int
start_on(struct store *s, int64_t id, const char *printer, struct sf_err *err)
{
    char sha[STORE_SHA_HEX];
    int rc = store_job_event(s, id, JOB_EV_PREPARE, NULL, NULL, err);
    if (rc || (rc = store_file_put(s, "G28\nG1 X1\n", 10, sha, err)))
        return rc;
    struct job_event_args a = { .gcode_sha = sha, .size_mm = { 20, 30, 40 } };
    struct job_event_args st = { .printer = printer };
    if ((rc = store_job_event(s, id, JOB_EV_PREPARED, &a, NULL, err)))
        return rc;
    return store_job_event(s, id, JOB_EV_START, &st, NULL, err);
}

/* The query plan of sql on the store's database file, one line. */
static void
plan_of(const char *dir, const char *sql, char *out, size_t cap)
{
    char path[600], q[1024];
    snprintf(path, sizeof(path), "%s/slimfarm.db", dir);
    snprintf(q, sizeof(q), "EXPLAIN QUERY PLAN %s", sql);
    sqlite3 *db;
    sqlite3_stmt *st;
    out[0] = '\0';
    if (sqlite3_open_v2(path, &db, SQLITE_OPEN_READONLY, NULL) == SQLITE_OK &&
        sqlite3_prepare_v2(db, q, -1, &st, NULL) == SQLITE_OK) {
        size_t len = 0;
        while (sqlite3_step(st) == SQLITE_ROW && len < cap)
            len += (size_t)snprintf(out + len, cap - len, "%s; ", sqlite3_column_text(st, 3));
        sqlite3_finalize(st);
    }
    sqlite3_close(db);
}

T_CASE(store_live_jobs_come_from_their_index_not_history)
{
    struct sf_err err;
    const char *dir = fresh_dir("live");
    struct store *s = t_store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    int64_t ids[40];
    char part[16];
    for (int i = 0; i < 40; i++) {
        snprintf(part, sizeof(part), "p%d", i);
        T_TRUE((ids[i] = add_job(s, part, &err)) > 0);
    }
    /* history: 30 cancelled; live: 8 queued, one printing on a, one on b */
    struct job_event_args why = { .reason = "test" };
    for (int i = 0; i < 30; i++)
        T_OK(store_job_event(s, ids[i], JOB_EV_CANCEL, &why, NULL, &err), &err);
    T_OK(start_on(s, ids[35], "a", &err), &err);
    T_OK(start_on(s, ids[37], "b", &err), &err);
    struct job_row *rows;
    size_t n;
    T_OK(store_job_live(s, &rows, &n, &err), &err);
    T_EQ_INT((long long)n, 10);
    for (size_t i = 0; i < n; i++) {
        T_EQ_INT(rows[i].id, ids[30 + i]); /* oldest first */
        T_TRUE(rows[i].state != JOB_CANCELLED);
    }
    free(rows);
    /* nothing interrupted yet; after a crash, a's and b's are */
    struct job_row j;
    T_EQ_INT(store_job_interrupted(s, "a", &j, &err), SF_ENOTFOUND);
    store_close(s);
    T_TRUE((s = t_store_open(dir, NULL, &err)) != NULL);
    T_OK(store_job_interrupted(s, "a", &j, &err), &err);
    T_EQ_INT(j.id, ids[35]);
    T_EQ_INT(j.state, JOB_INTERRUPTED);
    T_OK(store_job_interrupted(s, "b", &j, &err), &err);
    T_EQ_INT(j.id, ids[37]);
    T_EQ_INT(store_job_interrupted(s, "c", &j, &err), SF_ENOTFOUND);
    T_OK(store_job_live(s, &rows, &n, &err), &err);
    T_EQ_INT((long long)n, 10);
    free(rows);
    store_close(s);
    if (t_store_pg())
        return; /* PostgreSQL's plans are its own (and a table this small is scanned) */
    /* SQLite reads the live jobs through the partial index, not the table */
    char plan[512];
    plan_of(dir,
            "SELECT id, state FROM jobs WHERE state NOT IN ('done','failed','cancelled')"
            " ORDER BY id",
            plan, sizeof(plan));
    T_TRUE(strstr(plan, "jobs_live") != NULL);
    T_TRUE(strstr(plan, "TEMP B-TREE") == NULL); /* and in id order: no sort */
    plan_of(dir, "SELECT id FROM jobs WHERE state = 'interrupted' AND printer = 'a'", plan,
            sizeof(plan));
    T_TRUE(strstr(plan, "USING INDEX") != NULL);
}

/* Walk every page of f with limit; each id seen into seen[id] (counted). */
static size_t
walk(struct store *s, struct store_job_filter f, size_t limit, int *seen, int64_t max_id,
     int64_t add_after_first, struct sf_err *err)
{
    size_t pages = 0;
    for (;;) {
        struct job_row *rows;
        size_t n;
        bool more;
        if (store_job_page(s, &f, limit, &rows, &n, &more, err))
            return 0;
        pages++;
        for (size_t i = 0; i < n; i++) {
            if (rows[i].id > 0 && rows[i].id <= max_id)
                seen[rows[i].id]++;
            if (i && (f.newest_first ? rows[i].id >= rows[i - 1].id : rows[i].id <= rows[i - 1].id))
                seen[0]++; /* out of order */
        }
        if (n)
            f.after_id = rows[n - 1].id;
        free(rows);
        if (pages == 1)
            for (int64_t k = 0; k < add_after_first; k++)
                add_job(s, "added", err); /* jobs arrive during the walk */
        if (!more)
            return pages;
    }
}

/* A fresh store named name with n queued jobs, job printing printing on mk3; NULL on failure. */
static struct store *
store_with_jobs(const char *name, int n, int64_t printing, struct sf_err *err)
{
    struct store *s = t_store_open(fresh_dir(name), NULL, err);
    for (int i = 0; s && i < n; i++)
        if (!add_job(s, name, err)) {
            store_close(s);
            return NULL;
        }
    if (s && start_on(s, printing, "mk3", err)) {
        store_close(s);
        return NULL;
    }
    return s;
}

T_CASE(store_pages_walk_every_job_once_while_jobs_are_added)
{
    struct sf_err err;
    struct store *s = store_with_jobs("pages", 53, 7, &err);
    T_TRUE(s != NULL);
    struct job_event_args why = { .reason = "test" };
    for (int64_t id = 10; id <= 20; id++)
        T_OK(store_job_event(s, id, JOB_EV_CANCEL, &why, NULL, &err), &err);
    static int seen[128];
    /* oldest first, 5 added after the first page: 58 jobs, each once, 6 pages of 10 */
    memset(seen, 0, sizeof(seen));
    struct store_job_filter f = { 0 };
    T_EQ_INT((long long)walk(s, f, 10, seen, 127, 5, &err), 6);
    T_EQ_INT(seen[0], 0);
    for (int id = 1; id <= 58; id++)
        T_EQ_INT(seen[id], 1);
    T_EQ_INT(seen[59], 0);
    /* newest first: the jobs there were when it began, each once */
    memset(seen, 0, sizeof(seen));
    f.newest_first = true;
    T_EQ_INT((long long)walk(s, f, 7, seen, 127, 3, &err), 9); /* 58 in pages of 7 */
    T_EQ_INT(seen[0], 0);
    for (int id = 1; id <= 58; id++)
        T_EQ_INT(seen[id], 1);
    /* by state: the 11 cancelled; by printer: the one that printed on mk3 */
    memset(seen, 0, sizeof(seen));
    f = (struct store_job_filter){ .states = 1u << JOB_CANCELLED };
    walk(s, f, 4, seen, 127, 0, &err);
    for (int id = 1; id <= 61; id++)
        T_EQ_INT(seen[id], id >= 10 && id <= 20);
    struct job_row *rows;
    size_t n;
    bool more;
    f = (struct store_job_filter){ .printer = "mk3" };
    T_OK(store_job_page(s, &f, 100, &rows, &n, &more, &err), &err);
    T_EQ_INT((long long)n, 1);
    T_EQ_INT(rows[0].id, 7);
    T_TRUE(!more);
    free(rows);
    /* by time: nothing changed in 2100 */
    f = (struct store_job_filter){ .since_ms = INT64_C(4102444800000) }; /* 2100 */
    T_OK(store_job_page(s, &f, 100, &rows, &n, &more, &err), &err);
    T_EQ_INT((long long)n, 0);
    free(rows);
    T_EQ_INT(store_job_page(s, &f, 0, &rows, &n, &more, &err), SF_EINVAL);
    T_EQ_INT(store_job_page(s, &f, STORE_PAGE_MAX + 1, &rows, &n, &more, &err), SF_EINVAL);
    store_close(s);
}

T_CASE(store_counts_and_a_reader_beside_the_writer)
{
    struct sf_err err;
    struct store *s = store_with_jobs("counts", 5, 2, &err);
    T_TRUE(s != NULL);
    struct job_event_args done = { .filament_mm = 10 };
    T_OK(store_job_event(s, 2, JOB_EV_PRINT_DONE, &done, NULL, &err), &err);
    struct store *r = store_open_reader(s, &err);
    T_TRUE(r != NULL);
    uint64_t by_state[JOB_STATE_COUNT];
    T_OK(store_job_counts(r, by_state, &err), &err);
    T_EQ_INT((long long)by_state[JOB_QUEUED], 4);
    T_EQ_INT((long long)by_state[JOB_DONE], 1);
    struct print_tally *t;
    size_t n;
    T_OK(store_print_tally(r, &t, &n, &err), &err);
    T_EQ_INT((long long)n, 1);
    T_EQ_STR(t[0].printer, "mk3");
    T_EQ_STR(t[0].outcome, "done");
    T_EQ_INT((long long)t[0].n, 1);
    free(t);
    static const double b[] = { 1e9 };
    struct store_hist_out h;
    T_OK(store_hist(r, STORE_HIST_PRINT, b, 1, &h, &err), &err);
    T_EQ_INT((long long)h.count, 1);
    T_EQ_INT((long long)h.le[0], 1);
    /* the reader sees what the writer commits after it opened, and cannot write */
    T_TRUE(add_job(s, "z", &err) > 0);
    T_OK(store_job_counts(r, by_state, &err), &err);
    T_EQ_INT((long long)by_state[JOB_QUEUED], 5);
    T_EQ_INT(store_job_set_priority(r, 1, 3, &err), SF_EIO);
    store_close(r);
    store_close(s);
}

/* A page's last printers are read for the page's jobs alone: a sparse page (jobs 1 and 6 of a
   filter) read every print of the jobs between them (review). */
T_CASE(store_last_printers_of_a_page_only)
{
    struct sf_err err;
    struct store *s = t_store_open(fresh_dir("lastpr"), NULL, &err);
    T_TRUE(s != NULL);
    int64_t ids[6];
    const char *printers[6] = { "a", "b", "c", "d", "e", "f" };
    for (int i = 0; i < 6; i++) {
        char part[32];
        snprintf(part, sizeof(part), "solid p%d", i);
        T_TRUE((ids[i] = add_job(s, part, &err)) > 0);
        T_OK(start_on(s, ids[i], printers[i], &err), &err);
    }
    int64_t page[2] = { ids[0], ids[5] };
    struct store_job_printer *rows = NULL;
    size_t n = 0;
    T_OK(store_last_printers(s, page, 2, &rows, &n, &err), &err);
    T_EQ_INT(n, 2);
    T_EQ_INT(rows[0].job_id, ids[0]);
    T_EQ_STR(rows[0].printer, "a");
    T_EQ_INT(rows[1].job_id, ids[5]);
    T_EQ_STR(rows[1].printer, "f");
    free(rows);
    store_close(s);
}

/* The waiting jobs in the scheduler's order (priority, queue_pos, id) into ids; their count. */
static int
cmp_queue(const void *a, const void *b)
{
    const struct job_row *x = a, *y = b;
    if (x->opts.priority != y->opts.priority)
        return x->opts.priority > y->opts.priority ? -1 : 1;
    if (x->queue_pos != y->queue_pos)
        return x->queue_pos < y->queue_pos ? -1 : 1;
    return (x->id > y->id) - (x->id < y->id);
}

static size_t
queue_of(struct store *s, int64_t *ids, struct sf_err *err)
{
    struct job_row *rows;
    size_t n, k = 0;
    if (store_job_live(s, &rows, &n, err))
        return 0;
    for (size_t i = 0; i < n; i++)
        if (rows[i].state == JOB_QUEUED || rows[i].state == JOB_READY)
            rows[k++] = rows[i];
    qsort(rows, k, sizeof(*rows), cmp_queue);
    for (size_t i = 0; i < k; i++)
        ids[i] = rows[i].id;
    free(rows);
    return k;
}

#define T_QUEUE(s, ...)                                                                            \
    do {                                                                                           \
        int64_t want_[] = { __VA_ARGS__ }, got_[16];                                               \
        T_EQ_INT((long long)queue_of(s, got_, &err), (long long)(sizeof(want_) / sizeof(*want_))); \
        for (size_t q_ = 0; q_ < sizeof(want_) / sizeof(*want_); q_++)                             \
            T_EQ_INT(got_[q_], want_[q_]);                                                         \
    } while (0)

/*
 * store_job_move: one place among the waiting jobs (issue 31: ▲ on the
 * third of three equal-priority jobs jumped it to first).  Within a
 * priority two jobs trade places; next to a job of another priority the
 * job takes that priority and lands just past it, no other job moving; a
 * new job still goes last; printing jobs do not move.
 */
T_CASE(store_move_a_waiting_job_one_place)
{
    struct sf_err err;
    struct store *s = store_open(fresh_dir("move"), NULL, &err);
    T_TRUE(s != NULL);
    int64_t a = add_job(s, "a", &err), b = add_job(s, "b", &err), c = add_job(s, "c", &err),
            d = add_job(s, "d", &err);
    T_QUEUE(s, a, b, c, d);
    T_OK(store_job_move(s, c, -1, &err), &err);
    T_QUEUE(s, a, c, b, d);
    T_ERR(store_job_move(s, a, -1, &err), SF_EAGAIN, &err, "already first");
    T_ERR(store_job_move(s, d, 1, &err), SF_EAGAIN, &err, "already last");
    T_ERR(store_job_move(s, d, 2, &err), SF_EINVAL, &err, "by: 2");
    T_ERR(store_job_move(s, 99, 1, &err), SF_ENOTFOUND, &err, "job 99");
    /* across a priority: d first at 5; a moves up past it, taking 5 */
    T_OK(store_job_set_priority(s, d, 5, &err), &err);
    T_QUEUE(s, d, a, c, b);
    T_OK(store_job_move(s, a, -1, &err), &err);
    T_QUEUE(s, a, d, c, b);
    struct job_row j;
    T_OK(store_job_get(s, a, &j, &err), &err);
    T_EQ_INT(j.opts.priority, 5);
    /* down twice: past d (same priority), then past c, taking 0 */
    T_OK(store_job_move(s, a, 1, &err), &err);
    T_OK(store_job_move(s, a, 1, &err), &err);
    T_QUEUE(s, d, c, a, b);
    T_OK(store_job_get(s, a, &j, &err), &err);
    T_EQ_INT(j.opts.priority, 0);
    /* b back up past a, then up past c: b before c, a after */
    T_OK(store_job_move(s, b, -1, &err), &err);
    T_OK(store_job_move(s, b, -1, &err), &err);
    T_QUEUE(s, d, b, c, a);
    /* a new job goes last; a printing job does not move */
    int64_t e = add_job(s, "e", &err);
    T_QUEUE(s, d, b, c, a, e);
    T_OK(start_on(s, c, "p", &err), &err);
    T_ERR(store_job_move(s, c, -1, &err), SF_EAGAIN, &err, "only a waiting job");
    T_QUEUE(s, d, b, a, e);
    T_OK(store_job_move(s, e, -1, &err), &err); /* the printing job is not a place */
    T_QUEUE(s, d, b, e, a);
    /* each move is in the event log */
    struct event_row *ev;
    size_t n, moves = 0;
    T_OK(store_events(s, 0, 200, &ev, &n, &err), &err);
    for (size_t i = 0; i < n; i++)
        moves += strcmp(ev[i].kind, "job-move") == 0;
    free(ev);
    T_EQ_INT((long long)moves, 7);
    T_OK(store_check(s, &err), &err);
    store_close(s);
}
