/*
 * test_history.c - the farm's history as an operator reads it: finished
 * jobs found by a piece of their name (store_job_page's name filter and
 * GET /api/jobs's name=), exported as CSV (api_csv.c: columns, quoting,
 * a formula defused, the rows cap and the cursor to go on), and "print
 * again" (jobctl_again: a new job from the same file and options, uploaded
 * G-code ready at once), and each printer's statistics over a window of
 * days (store_print_stats, GET /api/stats's JSON).  Real SQLite files, or
 * PostgreSQL with SLIMFARM_TEST_STORE (tstore.h).
 */
#include <jansson.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/api/api_csv.h"
#include "../../src/api/api_page.h"
#include "../../src/api/api_stats.h"
#include "../../src/farm/jobctl.h"
#include "../../src/farm/store.h"
#include "../t.h"
#include "../tstore.h"

static struct store *
fresh(const char *name, struct sf_err *err)
{
    char path[512];
    snprintf(path, sizeof(path), "%s/%s", t_tmpdir(), name);
    return t_store_open(path, NULL, err);
}

/* A job called name, printed on printer to done (filament 2.5 g a copy). */
static int64_t
done_job(struct store *s, const char *name, const char *printer, struct sf_err *err)
{
    char sha[STORE_SHA_HEX], gsha[STORE_SHA_HEX];
    int64_t id = 0;
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "%s", name);
    snprintf(o.material, sizeof(o.material), "PETG");
    o.priority = 3;
    struct job_event_args p = {
        .gcode_sha = gsha, .size_mm = { 20, 30, 40 }, .filament_g = 2.5, .saved_g = 1
    };
    struct job_event_args st = { .printer = printer }, end = { .filament_mm = 10 };
    if (store_file_put(s, "solid x\n", 8, sha, err) || store_job_add(s, &o, sha, &id, err) ||
        store_file_put(s, "G28\n", 4, gsha, err) ||
        store_job_event(s, id, JOB_EV_PREPARE, NULL, NULL, err) ||
        store_job_event(s, id, JOB_EV_PREPARED, &p, NULL, err) ||
        store_job_event(s, id, JOB_EV_START, &st, NULL, err) ||
        store_job_event(s, id, JOB_EV_PRINT_DONE, &end, NULL, err))
        return 0;
    return id;
}

T_CASE(history_name_search)
{
    struct sf_err err;
    struct store *s = fresh("search", &err);
    T_TRUE(s != NULL);
    T_TRUE(done_job(s, "Bracket-left.stl", "mk3", &err) > 0);
    T_TRUE(done_job(s, "hook.stl", "mk3", &err) > 0);
    T_TRUE(done_job(s, "bracket_100%.stl", "mini", &err) > 0);
    struct api_page_query q;
    T_OK(api_page_parse("name=BRACKET&state=done", &q, &err), &err);
    struct job_row *rows;
    size_t n;
    bool more;
    T_OK(store_job_page(s, &q.f, 100, &rows, &n, &more, &err), &err);
    T_EQ_INT((long long)n, 2); /* case aside */
    T_EQ_INT(rows[0].id, 1);
    T_EQ_INT(rows[1].id, 3);
    free(rows);
    /* '%' and '_' are plain text, not LIKE's wildcards */
    T_OK(api_page_parse("name=_100%25", &q, &err), &err);
    T_OK(store_job_page(s, &q.f, 100, &rows, &n, &more, &err), &err);
    T_EQ_INT((long long)n, 1);
    T_EQ_INT(rows[0].id, 3);
    free(rows);
    T_OK(api_page_parse("name=t_l", &q, &err), &err); /* LIKE would take Bracket-left */
    T_OK(store_job_page(s, &q.f, 100, &rows, &n, &more, &err), &err);
    T_EQ_INT((long long)n, 0);
    free(rows);
    T_EQ_INT(api_page_parse("format=xml", &q, &err), SF_EINVAL);
    T_EQ_STR(err.msg, "parameter 'format' ('xml'): expected json or csv");
    store_close(s);
}

T_CASE(history_csv_export)
{
    struct sf_err err;
    struct store *s = fresh("csv", &err);
    T_TRUE(s != NULL);
    T_TRUE(done_job(s, "a, \"quoted\".stl", "mk3", &err) > 0);
    T_TRUE(done_job(s, "=cmd.stl", "mini", &err) > 0);
    T_TRUE(done_job(s, "plain.stl", "mk3", &err) > 0);
    struct api_page_query q;
    T_OK(api_page_parse("format=csv", &q, &err), &err);
    T_TRUE(q.csv);
    size_t len;
    char next[24];
    char *csv = api_csv_render(s, &q, &len, next, &err);
    T_TRUE(csv != NULL);
    T_EQ_INT(len, strlen(csv));
    T_TRUE(strncmp(csv,
                   "id,name,state,created,finished,print_s,printer,material,copies,"
                   "copies_done,filament_g,support_saved_g,reason\r\n",
                   100) == 0);
    T_TRUE(strstr(csv, "\r\n1,\"a, \"\"quoted\"\".stl\",done,") != NULL);
    T_TRUE(strstr(csv, "\r\n2,\"'=cmd.stl\",done,") != NULL);
    T_TRUE(strstr(csv, ",mk3,PETG,1,1,2.5,1.0,\r\n") != NULL);
    T_EQ_STR(next, "");
    free(csv);
    /* capped rows: the cursor goes on where they stopped */
    T_OK(api_page_parse("format=csv&limit=2", &q, &err), &err);
    csv = api_csv_render(s, &q, &len, next, &err);
    T_TRUE(csv && strstr(csv, "\r\n3,") == NULL && strstr(csv, "\r\n2,") != NULL);
    T_EQ_STR(next, "a2");
    free(csv);
    T_OK(api_page_parse("format=csv&cursor=a2", &q, &err), &err);
    csv = api_csv_render(s, &q, &len, next, &err);
    T_TRUE(csv && strstr(csv, "\r\n3,plain.stl,") != NULL && strstr(csv, "\r\n2,") == NULL);
    free(csv);
    store_close(s);
}

T_CASE(history_print_again)
{
    struct sf_err err;
    struct store *s = fresh("again", &err);
    T_TRUE(s != NULL);
    int64_t id = done_job(s, "bracket.stl", "mk3", &err), again;
    T_TRUE(id > 0);
    T_OK(jobctl_again(s, id, &again, &err), &err);
    T_TRUE(again > id);
    struct job_row a, b;
    T_OK(store_job_get(s, id, &a, &err), &err);
    T_OK(store_job_get(s, again, &b, &err), &err);
    T_EQ_INT(b.state, JOB_QUEUED);
    T_EQ_STR(b.opts.name, "bracket.stl");
    T_EQ_STR(b.opts.material, "PETG");
    T_EQ_INT(b.opts.priority, 3);
    T_EQ_STR(b.file_sha, a.file_sha);
    T_EQ_INT(b.counts.copies_done, 0);
    T_EQ_INT(jobctl_again(s, 999, &again, &err), SF_ENOTFOUND);
    /* uploaded G-code: ready at once with what its upload found */
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "x.gcode");
    char sha[STORE_SHA_HEX];
    T_OK(store_file_put(s, "G28\nG1 X5\n", 10, sha, &err), &err);
    struct job_event_args g = { .prep_key = "gcode:mk3|0.4", .nozzle_mm = 0.4, .gcode_lines = 2 };
    int64_t gid;
    T_OK(store_job_add_gcode(s, &o, sha, &g, &gid, &err), &err);
    T_OK(jobctl_again(s, gid, &again, &err), &err);
    T_OK(store_job_get(s, again, &b, &err), &err);
    T_EQ_INT(b.state, JOB_READY);
    T_EQ_STR(b.prep_key, "gcode:mk3|0.4");
    T_EQ_STR(b.gcode_sha, sha);
    T_EQ_INT(b.gcode_lines, 2);
    store_close(s);
}

/* Run sql on the store's database in dir, beside the store's own connection. */
static void
db_exec(const char *dir, const char *sql)
{
    T_OK(t_store_exec(dir, sql), NULL);
}

/* Set print id's times (ended 0: still running, outcome ""). */
static void
set_print(const char *dir, int64_t id, int64_t start_ms, int64_t end_ms)
{
    char sql[256];
    snprintf(sql, sizeof(sql),
             "UPDATE prints SET started_ms = %lld, ended_ms = %lld%s WHERE id = %lld",
             (long long)start_ms, (long long)end_ms, end_ms ? "" : ", outcome = ''", (long long)id);
    db_exec(dir, sql);
}

T_CASE(history_stats_per_printer_and_day)
{
    struct sf_err err;
    char dir[512];
    snprintf(dir, sizeof(dir), "%s/stats", t_tmpdir());
    struct store *s = t_store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    T_TRUE(done_job(s, "a.stl", "mk3", &err) > 0);
    T_TRUE(done_job(s, "b.stl", "mk3", &err) > 0);
    T_TRUE(done_job(s, "c.stl", "mk3", &err) > 0);
    T_TRUE(done_job(s, "d.stl", "mini", &err) > 0);
    T_TRUE(done_job(s, "old.stl", "mini", &err) > 0);
    const int64_t H = 3600000, day = 24 * H, today = INT64_C(1796428800000); /* 2026-12-05 */
    set_print(dir, 1, today - H, today + H);     /* done across midnight: 1 h each day */
    set_print(dir, 2, today + H, today + 2 * H); /* made failed below */
    set_print(dir, 3, today + 2 * H, 0);         /* still printing */
    set_print(dir, 4, today - 2 * H, today - H); /* yesterday */
    set_print(dir, 5, today - 3 * day, today - 3 * day + H); /* before the window */
    db_exec(dir, "UPDATE prints SET outcome = 'failed' WHERE id = 2;"
                 "UPDATE prints SET outcome = 'cancelled' WHERE id = 4");
    struct store_printer_stats *r;
    size_t n;
    int64_t now = today + 4 * H;
    T_OK(store_print_stats(s, now, 2, &r, &n, &err), &err);
    T_EQ_INT((long long)n, 2);
    T_EQ_STR(r[0].printer, "mini");
    T_EQ_INT(r[0].cancelled, 1);
    T_EQ_INT(r[0].done, 0); /* old.stl ended before the window */
    T_EQ_DBL(r[0].day_s[0], 3600, 1e-6);
    T_EQ_STR(r[1].printer, "mk3");
    T_EQ_INT(r[1].done, 1);
    T_EQ_INT(r[1].failed, 1);
    T_EQ_DBL(r[1].day_s[0], 3600, 1e-6);     /* the hour before midnight */
    T_EQ_DBL(r[1].day_s[1], 3600 * 4, 1e-6); /* 1 + 1 + the running 2 */
    T_EQ_DBL(r[1].print_s, 3600 * 5, 1e-6);
    json_t *o = api_stats_json(r, n, 2, now);
    json_t *mk3 = json_array_get(json_object_get(o, "printers"), 1);
    T_EQ_DBL(json_real_value(json_object_get(mk3, "success_rate")), 0.5, 1e-9);
    T_EQ_DBL(json_real_value(json_object_get(mk3, "hours_printing")), 5, 1e-9);
    json_t *use = json_object_get(mk3, "utilisation");
    T_EQ_DBL(json_real_value(json_array_get(use, 0)), 0.041667, 1e-9); /* 1 h of 24 */
    T_EQ_DBL(json_real_value(json_array_get(use, 1)), 1.0, 1e-9);      /* 4 h of the 4 so far */
    T_EQ_STR(json_string_value(json_object_get(o, "since")), "2026-12-04T00:00:00Z");
    json_decref(o);
    free(r);
    int days;
    T_EQ_INT(api_stats_parse("days=91", &days, &err), SF_EINVAL);
    T_EQ_STR(err.msg, "parameter 'days': expected a number from 1 to 90");
    T_OK(api_stats_parse(NULL, &days, &err), &err);
    T_EQ_INT(days, 7);
    store_close(s);
}
