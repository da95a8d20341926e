/*
 * test_farm_view.c - a host's view of its printers for the other hosts
 * (farm_view.h) on a real PostgreSQL (store_pg.sh; skipped on SQLite, as a
 * farm of several hosts needs a store URL): a text looked at again and
 * again is written once, and a burst of changes is written as at most its
 * first and its last (never a write per look: the store gets no write per
 * temperature sample); writes counted by a trigger the test adds.
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/base/clock.h"
#include "../../src/base/loop.h"
#include "../../src/base/pool.h"
#include "../../src/farm/farm.h"
#include "../../src/farm/farm_view.h"
#include "../../src/farm/farmcfg.h"
#include "../../src/farm/sqldb.h"
#include "../t.h"
#include "../tstore.h"

#define WAIT_LIMIT_MS 60000

static int
no_prepare(const struct prepare_req *req, struct prepare_out *out, const atomic_bool *cancel,
           struct sf_err *err)
{
    (void)req, (void)out, (void)cancel;
    return sf_err_set(err, SF_EUNSUPP, "test: no preparing here");
}

/* One text column or number of url's database, as text ("(none)" without a row). */
static void
db_text(const char *url, const char *sql, char *out, size_t cap)
{
    struct sf_err err;
    struct sqldb *db = sqldb_open(url, 0, &err);
    struct sqldb_stmt *st;
    snprintf(out, cap, "(none)");
    if (db && sqldb_prepare(db, sql, &st) == SF_OK) {
        if (sqldb_step(st) == SQLDB_ROW)
            snprintf(out, cap, "%s", sqldb_column_text(st, 0));
        sqldb_finalize(st);
    }
    sqldb_close(db);
}

/* Turn l until b's stored view is want, then until the farm's store queue is empty. */
static bool
wait_view(struct loop *l, struct farm *f, const char *url, const char *want)
{
    char got[256] = "";
    struct sf_err err;
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; clock_mono_ms() < end;) {
        loop_run_once(l, 20);
        db_text(url, "SELECT view FROM host_views WHERE host = 'b'", got, sizeof(got));
        if (strcmp(got, want) == 0)
            return farm_sync(f, -1, &err) == SF_OK;
    }
    return false;
}

/* The writes of host_views counted so far (the test's trigger). */
static int
writes(const char *url)
{
    char n[32];
    db_text(url, "SELECT n FROM view_writes", n, sizeof(n));
    return (int)strtol(n, NULL, 10);
}

T_CASE(host_writes_its_view_once_per_change_and_a_burst_as_its_last)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char dir[512], url[1024], ini[1400];
    snprintf(dir, sizeof(dir), "%s/view", t_tmpdir());
    snprintf(url, sizeof(url), "%s", t_store_db(dir));
    snprintf(ini, sizeof(ini), "[farm]\nstore: %s\nhost: b\nhost_lease_s: 600\n", url);
    struct farmcfg cfg;
    farmcfg_init(&cfg);
    T_OK(farmcfg_parse(&cfg, ini, strlen(ini), "farm.ini", &err), &err);
    struct loop *l = loop_new(&err);
    struct store *s = store_open_host(dir, url, NULL, &err);
    T_TRUE(l && s);
    struct pool *pool = pool_new(l, 1, &err);
    struct farm_hooks hooks = { .prepare = no_prepare, .progress_ms = 50 };
    struct farm *f = farm_new(l, s, pool, &cfg, &hooks, &err);
    T_TRUE(f != NULL);
    /* count every write of a view (a trigger: exact, in the writing transaction) */
    struct sqldb *db = sqldb_open(url, 0, &err);
    T_TRUE(db != NULL);
    T_OK(sqldb_exec(db, "CREATE TABLE view_writes(n INTEGER NOT NULL)"), NULL);
    T_OK(sqldb_exec(db, "INSERT INTO view_writes VALUES(0)"), NULL);
    T_OK(sqldb_exec(db, "CREATE FUNCTION count_view() RETURNS trigger LANGUAGE plpgsql AS"
                        " $$BEGIN UPDATE view_writes SET n = n + 1; RETURN NEW; END$$"),
         NULL);
    T_OK(sqldb_exec(db, "CREATE TRIGGER count_view AFTER INSERT OR UPDATE ON host_views"
                        " FOR EACH ROW EXECUTE FUNCTION count_view()"),
         NULL);
    sqldb_close(db);
    /* the same text at every look: one write */
    const char *a = "{\"p\":{\"temps\":{\"nozzle_c\":20}}}";
    for (int i = 0; i < 5; i++) {
        farm_view_publish(f, a);
        loop_run_once(l, 0);
    }
    T_TRUE(wait_view(l, f, url, a));
    for (int i = 0; i < 5; i++) {
        farm_view_publish(f, a);
        loop_run_once(l, 0);
    }
    T_OK(farm_sync(f, -1, &err), &err);
    T_EQ_INT(writes(url), 1);
    /* ten changes in a burst (a heating nozzle looked at ten times): its last is written, and
       at most one before it (the first, when FARM_VIEW_MIN_MS had passed already) */
    char text[64];
    for (int c = 21; c <= 30; c++) {
        snprintf(text, sizeof(text), "{\"p\":{\"temps\":{\"nozzle_c\":%d}}}", c);
        farm_view_publish(f, text);
        loop_run_once(l, 0);
    }
    T_TRUE(wait_view(l, f, url, text));
    int n = writes(url);
    T_TRUE(n >= 2 && n <= 3);
    farm_drop_pool(f);
    pool_free(pool);
    loop_run_once(l, 0);
    farm_free(f);
    store_close(s);
    loop_free(l);
    farmcfg_release(&cfg);
}
