/*
 * test_farm_host.c - what a host's scheduler reads and claims on a shared
 * store (farm_host.h over store_host.h): a claim of one chosen queued job
 * is taken once (a second host, or the same job again, gets SF_ENOTFOUND);
 * a claim among a pass's chosen jobs takes the first free (a held row is
 * passed over, never lost), and a host whose first choice another host's
 * claim holds prepares the next;
 * a ready job no host holds is taken by one host only; each host's live
 * jobs leave out the other hosts' claims but keep a job on a printer it
 * owns; a reaped host's jobs come back for the others.  A farm as one of
 * several hosts (PostgreSQL only, as farm.ini's store is a URL; hdrv, a
 * small in-test driver, stands in for its printers) leaves alone a
 * printer of its config that another live host owns, listens again after
 * its connection is cut, and gives back a claim whose COMMIT's answer was
 * lost (SLIMFARM_TEST_PROXY, tests/tools/tcpproxy, and SLIMFARM_TEST_PG_PORT,
 * the server's TCP port, cut the network: store_pg.sh sets them), and lets
 * go of a print another host has attached (its fencing token is stale), and
 * takes a ready job again after the database refused its take, and names
 * its printers with its host (/metrics) before it joined.  With
 * SLIMFARM_TEST_STORE (tstore.h) on PostgreSQL, the second host a store of
 * its own on the same database; on SQLite a second connection.
 */
#include <poll.h>
#include <pthread.h>
#include <spawn.h>
#include <stdint.h>
#include <stdlib.h>
#include <sys/wait.h>
#include <unistd.h>

#include "../../src/api/metrics.h"
#include "../../src/base/clock.h"
#include "../../src/base/log.h"
#include "../../src/base/mem.h"
#include "../../src/farm/farm.h"
#include "../../src/farm/farm_host.h"
#include "../../src/farm/farm_remote.h"
#include "../../src/farm/farmcfg.h"
#include "../../src/farm/store_command.h"
#include "../../src/farm/store_host.h"
#include "../t.h"
#include "../tproxy.h"
#include "../tstore.h"

#define LEASE_MS (600 * 1000)

/* Two hosts on one database (tstore.h), joined as "a" and "b". */
static bool
pair_open(struct t_pair *p, const char *name, struct sf_err *err)
{
    char dir[512];
    snprintf(dir, sizeof(dir), "%s/%s", t_tmpdir(), name);
    return t_pair_open(p, dir, err) && store_host_join(p->a, "a", LEASE_MS, &p->ta, err) == SF_OK &&
           store_host_join(p->b, "b", LEASE_MS, &p->tb, err) == SF_OK;
}

static int
add_job(struct store *s, int64_t *id, struct sf_err *err)
{
    char sha[STORE_SHA_HEX];
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "part.stl");
    int rc = store_file_put(s, "solid part\n", 11, sha, err);
    return rc ? rc : store_job_add(s, &o, sha, id, err);
}

static int
add_ready(struct store *s, int64_t *id, struct sf_err *err)
{
    char sha[STORE_SHA_HEX];
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "part.gcode");
    struct job_event_args g = { .prep_key = "k", .gcode_lines = 2 };
    int rc = store_file_put(s, "G28\nG1 X1\n", 10, sha, err);
    return rc ? rc : store_job_add_gcode(s, &o, sha, &g, id, err);
}

/* Is job id among rows? */
static bool
has(const struct job_row *rows, size_t n, int64_t id)
{
    for (size_t i = 0; i < n; i++)
        if (rows[i].id == id)
            return true;
    return false;
}

T_CASE(claim_of_a_chosen_job_is_taken_once)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "claim", &err));
    int64_t first, second, fence = 0;
    T_OK(add_job(p.a, &first, &err), &err);
    T_OK(add_job(p.a, &second, &err), &err);
    struct job_row j;
    /* the second job, not the queue's head: the scheduler chose it */
    T_OK(store_job_claim_id(p.b, "b", p.tb, second, &j, &fence, &err), &err);
    T_EQ_INT(j.id, second);
    T_EQ_INT(j.state, JOB_PREPARING);
    T_TRUE(fence > 0);
    T_EQ_INT(store_job_claim_id(p.a, "a", p.ta, second, &j, NULL, &err), SF_ENOTFOUND);
    T_EQ_INT(store_job_claim_id(p.b, "b", p.tb, second, &j, NULL, &err), SF_ENOTFOUND);
    T_OK(store_job_claim_id(p.a, "a", p.ta, first, &j, NULL, &err), &err);
    T_EQ_INT(j.id, first);
    /* a host whose lease is lost claims nothing */
    int64_t third;
    T_OK(add_job(p.a, &third, &err), &err);
    T_ERR(store_job_claim_id(p.a, "a", p.ta + 7, third, &j, NULL, &err), SF_ESTALE, &err, "");
    t_pair_close(&p);
}

/* A connection of its own to url's database with a transaction open (held idle as long as
   the test needs: no idle timeout), NULL if not. */
static struct sqldb *
open_tx(const char *url)
{
    struct sf_err err;
    struct sqldb *db = sqldb_open(url, 0, &err);
    if (db && (sqldb_exec(db, "SET idle_in_transaction_session_timeout = 0") || sqldb_begin(db))) {
        sqldb_close(db);
        return NULL;
    }
    return db;
}

/* Run sql (its %lld job id) in db's open transaction. */
static int
exec_id(struct sqldb *db, const char *sql, int64_t id)
{
    char q[256];
    snprintf(q, sizeof(q), sql, (long long)id);
    return sqldb_exec(db, q);
}

/*
 * A chosen job whose row another transaction holds is busy, not gone (issue 32, a flake of
 * farmd_hosts.sh: a host's claim skipped the row while another host wrote the job's waiting
 * reason, took it for claimed elsewhere, and nothing woke it again: the job stayed queued
 * for good).  Held by a write that leaves it queued, the claim passes once it commits; held
 * by another host's claim, the job is gone once that commits.  PostgreSQL's row locks.
 */
T_CASE(claim_of_a_chosen_job_another_write_holds_is_busy)
{
    T_SKIP_UNLESS(t_store_pg(), "row locks of other transactions: PostgreSQL (store_pg.sh)");
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "claimheld", &err));
    int64_t reasoned, claimed;
    T_OK(add_job(p.a, &reasoned, &err), &err);
    T_OK(add_job(p.a, &claimed, &err), &err);
    struct job_row j;
    struct sqldb *other = open_tx(p.url);
    T_TRUE(other != NULL);
    T_OK(exec_id(other, "UPDATE jobs SET reason = 'fits no printer' WHERE id = %lld", reasoned),
         NULL);
    T_ERR(store_job_claim_id(p.b, "b", p.tb, reasoned, &j, NULL, &err), SF_EBUSY, &err,
          "is held by another transaction");
    T_OK(sqldb_commit(other), NULL);
    T_OK(store_job_claim_id(p.b, "b", p.tb, reasoned, &j, NULL, &err), &err);
    T_EQ_INT(j.id, reasoned);
    /* a's claim, not committed yet */
    T_OK(sqldb_begin(other), NULL);
    T_OK(exec_id(other,
                 "UPDATE jobs SET state = 'preparing', claimed_by = 'a', fence = fence + 1"
                 " WHERE id = %lld",
                 claimed),
         NULL);
    T_EQ_INT(store_job_claim_id(p.b, "b", p.tb, claimed, &j, NULL, &err), SF_EBUSY);
    T_OK(sqldb_commit(other), NULL);
    T_EQ_INT(store_job_claim_id(p.b, "b", p.tb, claimed, &j, NULL, &err), SF_ENOTFOUND);
    sqldb_close(other);
    t_pair_close(&p);
}

/*
 * A claim among a pass's chosen jobs takes the first still queued, in the order given (the
 * scheduler's, not the queue's), and names the job it tried (a claim in doubt is read back by
 * it).  On PostgreSQL the first whose row another transaction holds is passed over for the
 * next (hosts whose passes chose the same jobs: each loser read the whole queue again,
 * bench_hosts), but never lost: with none other free the claim is busy (try again), not gone,
 * whether the row is held by a write that leaves the job queued (flake32) or by another
 * host's claim.
 */
T_CASE(claim_among_chosen_jobs_takes_the_first_free)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "claimfirst", &err));
    int64_t ids[5], tried = -1, fence = 0;
    for (int k = 0; k < 5; k++)
        T_OK(add_job(p.a, &ids[k], &err), &err);
    struct job_row j;
    int64_t order[] = { ids[2], ids[0] };
    T_OK(store_job_claim_first(p.b, "b", p.tb, order, 2, &tried, &j, &fence, &err), &err);
    T_EQ_INT(j.id, ids[2]);
    T_EQ_INT(tried, ids[2]);
    T_EQ_INT(j.state, JOB_PREPARING);
    T_TRUE(fence > 0);
    T_OK(store_job_claim_first(p.a, "a", p.ta, order, 2, &tried, &j, NULL, &err), &err);
    T_EQ_INT(j.id, ids[0]);
    T_EQ_INT(store_job_claim_first(p.b, "b", p.tb, order, 2, &tried, &j, NULL, &err), SF_ENOTFOUND);
    T_EQ_INT(tried, 0);
    T_ERR(store_job_claim_first(p.b, "b", p.tb, order, 0, &tried, &j, NULL, &err), SF_EINVAL, &err,
          "jobs to choose from");
    T_ERR(store_job_claim_first(p.b, "b", p.tb + 7, &ids[1], 1, &tried, &j, NULL, &err), SF_ESTALE,
          &err, "");
    if (t_store_pg()) { /* row locks of other transactions */
        int64_t held[] = { ids[3], ids[4] };
        struct sqldb *other = open_tx(p.url);
        T_TRUE(other != NULL);
        T_OK(exec_id(other, "UPDATE jobs SET reason = 'fits no printer' WHERE id = %lld", ids[3]),
             NULL);
        T_ERR(store_job_claim_first(p.b, "b", p.tb, held, 1, &tried, &j, NULL, &err), SF_EBUSY,
              &err, "is held by another transaction");
        T_OK(store_job_claim_first(p.b, "b", p.tb, held, 2, &tried, &j, NULL, &err), &err);
        T_EQ_INT(j.id, ids[4]); /* the held one passed over, not lost: */
        T_EQ_INT(store_job_claim_first(p.b, "b", p.tb, held, 2, &tried, &j, NULL, &err), SF_EBUSY);
        T_OK(sqldb_commit(other), NULL);
        T_OK(store_job_claim_first(p.b, "b", p.tb, held, 2, &tried, &j, NULL, &err), &err);
        T_EQ_INT(j.id, ids[3]);
        /* held by another host's claim: busy until it commits, then gone */
        T_OK(add_job(p.a, &ids[0], &err), &err);
        T_OK(sqldb_begin(other), NULL);
        T_OK(exec_id(other,
                     "UPDATE jobs SET state = 'preparing', claimed_by = 'a', fence = fence + 1"
                     " WHERE id = %lld",
                     ids[0]),
             NULL);
        T_EQ_INT(store_job_claim_first(p.b, "b", p.tb, ids, 1, &tried, &j, NULL, &err), SF_EBUSY);
        T_OK(sqldb_commit(other), NULL);
        T_EQ_INT(store_job_claim_first(p.b, "b", p.tb, ids, 1, &tried, &j, NULL, &err),
                 SF_ENOTFOUND);
        sqldb_close(other);
    }
    t_pair_close(&p);
}

T_CASE(ready_job_no_host_holds_is_taken_by_one)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "take", &err));
    int64_t id, queued, fa = 0, fb = 0;
    T_OK(add_ready(p.a, &id, &err), &err);
    T_OK(store_job_take(p.b, "b", p.tb, id, &fb, &err), &err);
    T_TRUE(fb > 0);
    T_EQ_INT(store_job_take(p.a, "a", p.ta, id, &fa, &err), SF_ENOTFOUND);
    /* b again: already its own, a new fencing token */
    T_OK(store_job_take(p.b, "b", p.tb, id, &fa, &err), &err);
    T_TRUE(fa > fb);
    /* only a ready job */
    T_OK(add_job(p.a, &queued, &err), &err);
    T_EQ_INT(store_job_take(p.a, "a", p.ta, queued, NULL, &err), SF_ENOTFOUND);
    t_pair_close(&p);
}

T_CASE(live_jobs_of_a_host_leave_out_the_others_claims)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "live", &err));
    const char *pa[] = { "pa" };
    T_OK(store_host_own(p.a, "a", p.ta, pa, 1, NULL, &err), &err);
    int64_t free_q, by_a, by_b, ready_free;
    T_OK(add_job(p.a, &free_q, &err), &err);
    T_OK(add_job(p.a, &by_a, &err), &err);
    T_OK(add_job(p.a, &by_b, &err), &err);
    T_OK(add_ready(p.a, &ready_free, &err), &err);
    struct job_row j;
    T_OK(store_job_claim_id(p.a, "a", p.ta, by_a, &j, NULL, &err), &err);
    T_OK(store_job_claim_id(p.b, "b", p.tb, by_b, &j, NULL, &err), &err);
    struct job_row *rows;
    size_t n;
    T_OK(store_job_live_host(p.a, "a", &rows, &n, &err), &err);
    T_TRUE(has(rows, n, free_q) && has(rows, n, by_a) && has(rows, n, ready_free));
    T_TRUE(!has(rows, n, by_b));
    free(rows);
    T_OK(store_job_live_host(p.b, "b", &rows, &n, &err), &err);
    T_TRUE(has(rows, n, free_q) && has(rows, n, by_b) && !has(rows, n, by_a));
    free(rows);
    /* b's lease runs out and a reaps it: its claimed job is queued again, a sees it */
    T_OK(store_host_beat(p.b, "b", p.tb, 1, &err), &err);
    T_EQ_INT(store_host_reap(p.a, clock_wall_ms() + 1000, NULL, &err), 1);
    T_OK(store_job_live_host(p.a, "a", &rows, &n, &err), &err);
    T_TRUE(has(rows, n, by_b));
    free(rows);
    T_OK(store_job_claim_id(p.a, "a", p.ta, by_b, &j, NULL, &err), &err);
    t_pair_close(&p);
}

T_CASE(store_url_password_is_never_shown)
{
    char out[256];
    farmcfg_store_shown("postgresql://farm:s3cret@db.lan/farm", out, sizeof(out));
    T_EQ_STR(out, "postgresql://farm:***@db.lan/farm");
    farmcfg_store_shown("postgresql:///farm?host=/run/pg&password=s3cret&user=x", out, sizeof(out));
    T_EQ_STR(out, "postgresql:///farm?host=/run/pg&password=***&user=x");
    farmcfg_store_shown("postgresql:///farm?password=p", out, sizeof(out));
    T_EQ_STR(out, "postgresql:///farm?password=***");
    farmcfg_store_shown("postgresql:///farm?host=/run/pg", out, sizeof(out));
    T_EQ_STR(out, "postgresql:///farm?host=/run/pg");
}

T_CASE(farm_ini_selects_a_shared_store)
{
    struct farmcfg c;
    struct sf_err err;
    farmcfg_init(&c);
    const char *ok = "[farm]\nstore: postgresql://farm:pw@db/farm\nhost: rack-2\nhost_lease_s: 5\n";
    T_OK(farmcfg_parse(&c, ok, strlen(ok), "farm.ini", &err), &err);
    T_EQ_STR(c.store, "postgresql://farm:pw@db/farm");
    T_EQ_STR(c.host, "rack-2");
    T_TRUE(c.host_lease_s == 5);
    farmcfg_release(&c);
    T_EQ_STR(c.store, "");
    T_TRUE(c.host_lease_s == 30);
    const char *bad = "[farm]\nstore: mysql://farm:topsecret@db/farm\n";
    T_ERR(farmcfg_parse(&c, bad, strlen(bad), "farm.ini", &err), SF_EINVAL, &err,
          "farm.ini:2: option 'store' in section 'farm': not a postgresql:// URL");
    T_TRUE(!strstr(err.msg, "topsecret"));
    farmcfg_init(&c);
    const char *host = "[farm]\nhost: a b\n";
    T_ERR(farmcfg_parse(&c, host, strlen(host), "farm.ini", &err), SF_EINVAL, &err, "host");
    farmcfg_init(&c);
    const char *lease = "[farm]\nhost_lease_s: 1\n";
    T_ERR(farmcfg_parse(&c, lease, strlen(lease), "farm.ini", &err), SF_EINVAL, &err,
          "host_lease_s");
}

/* ---- a farm as one host (PostgreSQL: farm.ini's store is a URL) ---- */

#include "../tfarmhost.h"

/* A case's store of several hosts (PostgreSQL): dir, TMP/NAME (host b's farm, host_farm), url,
   the store's database (t_store_db), and host a's store in dir-a (store_close); NULL with err
   set if that did not open. */
static struct store *
host_a_open(const char *name, char *dir, size_t dir_cap, char *url, size_t url_cap,
            struct sf_err *err)
{
    char dir_a[600];
    snprintf(dir, dir_cap, "%s/%s", t_tmpdir(), name);
    snprintf(dir_a, sizeof(dir_a), "%s-a", dir);
    snprintf(url, url_cap, "%s", t_store_db(dir));
    return store_open_host(dir_a, url, NULL, err);
}

T_CASE(host_leaves_alone_a_printer_another_live_host_owns)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char dir[512], url[1024], text[64];
    /* host a, live, owns printer x; b's config lists an x too, and a y */
    struct store *a = host_a_open("foreign", dir, sizeof(dir), url, sizeof(url), &err);
    T_TRUE(a != NULL);
    int64_t ta, jx, jy;
    T_OK(store_host_join(a, "a", LEASE_MS, &ta, &err), &err);
    const char *xs[] = { "x" };
    T_OK(store_host_own(a, "a", ta, xs, 1, NULL, &err), &err);
    T_OK(add_ready_for(a, "x", &jx, &err), &err);
    T_OK(add_ready_for(a, "y", &jy, &err), &err);
    T_OK(host_farm(dir, url, "b",
                   "[printer x]\ndriver: marlin\nport: pty:/dev/null\ngcode_models: *\n"
                   "[printer y]\ndriver: marlin\nport: pty:/dev/null\ngcode_models: *\n",
                   &err),
         &err);
    /* y's job prints on b; x's, seen in the same scheduling pass, is left to a */
    T_TRUE(wait_state(url, jy, "printing"));
    db_text(url, "SELECT state FROM jobs WHERE id = ?1", jx, text, sizeof(text));
    T_EQ_STR(text, "ready");
    db_text(url, "SELECT 'by ' || claimed_by FROM jobs WHERE id = ?1", jx, text, sizeof(text));
    T_EQ_STR(text, "by ");
    T_TRUE(hdrv_named("x") && hdrv_named("x")->starts == 0);
    T_TRUE(was_logged("printer 'x' belongs to live host 'a'"));
    db_text(url, "SELECT host FROM host_printers WHERE printer = 'x' AND ?1 = 0", 0, text,
            sizeof(text));
    T_EQ_STR(text, "a");
    db_text(url, "SELECT host FROM host_printers WHERE printer = 'y' AND ?1 = 0", 0, text,
            sizeof(text));
    T_EQ_STR(text, "b");
    /* the whole farm's printers (/metrics) list x once, as a's: b's copy of it is not one */
    struct metrics_printer *mp = NULL;
    size_t n_mp = 0;
    int x_rows = 0;
    bool from_a = false;
    for (int64_t end = clock_mono_ms() + 60000; clock_mono_ms() < end && !from_a;) {
        loop_run_once(hx.l, 50);
        free(mp);
        T_OK(metrics_printers(hx.f, &mp, &n_mp), NULL);
        x_rows = 0;
        for (size_t i = 0; i < n_mp; i++)
            if (strcmp(mp[i].name, "x") == 0) {
                x_rows++;
                from_a = from_a || strcmp(mp[i].host, "a") == 0;
            }
    }
    free(mp);
    T_TRUE(from_a);
    T_EQ_INT(x_rows, 1);
    host_farm_free();
    store_close(a);
}

/*
 * A host that has not joined yet (a restart waits out its predecessor's lease) names its own
 * printers with its host already, as once it joined: /metrics' series of them keep their
 * labels across the join.  Fails without it: host "" until the join, then "b" (to Prometheus
 * another series, its counters starting again).
 */
T_CASE(host_names_its_printers_before_it_joined)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char dir[512], dir_p[600], url[1024];
    snprintf(dir, sizeof(dir), "%s/prejoin", t_tmpdir());
    snprintf(dir_p, sizeof(dir_p), "%s-p", dir);
    snprintf(url, sizeof(url), "%s", t_store_db(dir));
    /* b's predecessor (killed): its lease still runs */
    struct store *p = store_open_host(dir_p, url, NULL, &err);
    T_TRUE(p != NULL);
    int64_t tp;
    T_OK(store_host_join(p, "b", LEASE_MS, &tp, &err), &err);
    T_OK(host_farm(dir, url, "b", "[printer y]\ndriver: marlin\nport: pty:/dev/null\n", &err),
         &err);
    for (int64_t end = clock_mono_ms() + 60000;
         clock_mono_ms() < end && !was_logged("b: cannot join yet");)
        loop_run_once(hx.l, 50);
    T_TRUE(was_logged("b: cannot join yet"));
    struct metrics_printer *mp = NULL;
    size_t n_mp = 0;
    T_OK(metrics_printers(hx.f, &mp, &n_mp), NULL);
    T_EQ_INT(n_mp, 1);
    T_EQ_STR(n_mp ? mp[0].host : "(none)", "b");
    free(mp);
    host_farm_free();
    store_close(p);
}

/*
 * A take the database did not answer (busy, or away as at an outage) is tried again: the
 * job stayed ready, this host's printer idle, and nothing else came to wake the host (issue
 * 32's acceptance run: after PostgreSQL's restart a host's four printers stood idle beside
 * the job it had prepared, for good).  Here a trigger ends the take's own session (the
 * database gone under it) while hold_takes has a row; fails without the retry: the job
 * stays ready.
 */
T_CASE(host_takes_a_ready_job_again_after_the_database_refused)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char dir[512], url[1024];
    struct store *a =
        host_a_open("retake", dir, sizeof(dir), url, sizeof(url), &err); /* the schema, the job */
    T_TRUE(a != NULL);
    struct sqldb *direct = sqldb_open(url, 0, &err);
    T_TRUE(direct != NULL);
    T_OK(sqldb_exec(direct, "CREATE TABLE hold_takes(x INTEGER); INSERT INTO hold_takes VALUES(1);"
                            " CREATE FUNCTION hold_take() RETURNS trigger LANGUAGE plpgsql AS $$"
                            " BEGIN IF EXISTS (SELECT 1 FROM hold_takes) THEN"
                            " PERFORM pg_terminate_backend(pg_backend_pid()); PERFORM pg_sleep(5);"
                            " END IF; RETURN NEW; END $$;"
                            " CREATE TRIGGER hold_take BEFORE UPDATE ON jobs FOR EACH ROW"
                            " WHEN (OLD.state = 'ready' AND NEW.fence <> OLD.fence)"
                            " EXECUTE FUNCTION hold_take()"),
         NULL);
    int64_t id;
    T_OK(add_ready_for(a, "p", &id, &err), &err);
    T_OK(host_farm(dir, url, "b",
                   "[printer p]\ndriver: marlin\nport: pty:/dev/null\ngcode_models: *\n", &err),
         &err);
    bool refused = false;
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; !refused && clock_mono_ms() < end;) {
        loop_run_once(hx.l, 20);
        refused = was_logged("take job");
    }
    T_TRUE(refused);
    T_OK(sqldb_exec(direct, "DELETE FROM hold_takes"), NULL);
    sqldb_close(direct);
    T_TRUE(wait_state(url, id, "printing"));
    host_farm_free();
    store_close(a);
}

T_CASE(host_listens_again_after_its_connection_is_cut)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char dir[512], dir_a[600], url[1024], sql[256];
    snprintf(dir, sizeof(dir), "%s/relisten", t_tmpdir());
    snprintf(dir_a, sizeof(dir_a), "%s-a", dir);
    snprintf(url, sizeof(url), "%s", t_store_db(dir));
    char db[64];
    db_text(url, "SELECT current_database() WHERE ?1 = 0", 0, db, sizeof(db));
    /* a, a host without printers, adds jobs for b's printers and wakes b (a NOTIFY) */
    struct store *a = store_open_host(dir_a, url, NULL, &err);
    T_TRUE(a != NULL);
    T_OK(host_farm(dir, url, "b",
                   "[printer p1]\ndriver: marlin\nport: pty:/dev/null\ngcode_models: *\n"
                   "[printer p2]\ndriver: marlin\nport: pty:/dev/null\ngcode_models: *\n"
                   "[printer p3]\ndriver: marlin\nport: pty:/dev/null\ngcode_models: *\n",
                   &err),
         &err);
    int64_t ids[3];
    T_OK(add_ready_for(a, "p1", &ids[0], &err), &err);
    T_OK(store_host_wake(a, &err), &err);
    T_TRUE(wait_state(url, ids[0], "printing"));
    /* the listener's session is cut by the server, and no new one is let in for now (both
       from the server's own database: a database cannot shut itself) */
    struct sqldb *cut = sqldb_open(getenv("SLIMFARM_TEST_STORE"), 0, &err);
    T_TRUE(cut != NULL);
    snprintf(sql, sizeof(sql), "ALTER DATABASE %s ALLOW_CONNECTIONS false", db);
    T_OK(sqldb_exec(cut, sql), NULL);
    snprintf(sql, sizeof(sql),
             "SELECT count(pg_terminate_backend(pid)) FROM pg_stat_activity"
             " WHERE datname = '%s' AND query = 'LISTEN \"%s\"'",
             db, STORE_HOST_CHANNEL); /* (not the commands' listener, farm_remote.c) */
    struct sqldb_stmt *st;
    T_OK(sqldb_prepare(cut, sql, &st), NULL);
    T_EQ_INT(sqldb_step(st), SQLDB_ROW);
    T_EQ_INT(sqldb_column_int(st, 0), 1);
    sqldb_finalize(st);
    T_TRUE(wait_logged("b: the wake-up connection is lost"));
    /* a job queued (its NOTIFY lost to b) while the listener is away */
    T_OK(add_ready_for(a, "p2", &ids[1], &err), &err);
    T_OK(store_host_wake(a, &err), &err);
    snprintf(sql, sizeof(sql), "ALTER DATABASE %s ALLOW_CONNECTIONS true", db);
    T_OK(sqldb_exec(cut, sql), NULL);
    sqldb_close(cut);
    /* back: the pass it runs then starts what came meanwhile, and a NOTIFY wakes it again */
    T_TRUE(wait_logged("b: the wake-up connection is back"));
    T_TRUE(wait_state(url, ids[1], "printing"));
    T_OK(add_ready_for(a, "p3", &ids[2], &err), &err);
    T_OK(store_host_wake(a, &err), &err);
    T_TRUE(wait_state(url, ids[2], "printing"));
    host_farm_free();
    store_close(a);
}

/* A remote command's answer (farm_remote_send), on b's loop. */
static int remote_rc = 1;
static void
on_remote(void *ud, const struct farm_remote_result *r)
{
    (void)ud;
    remote_rc = r->rc;
}

/* b asks a (a store here) for a pause; the owner's answer comes while b's commands listener
   is cut, its NOTIFY lost: once the listener is back, b reads it then, not at the deadline. */
T_CASE(host_reads_an_answer_that_came_while_its_listener_was_away)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char dir[512], dir_a[600], url[1024], sql[320], db[64], text[64];
    snprintf(dir, sizeof(dir), "%s/reread", t_tmpdir());
    snprintf(dir_a, sizeof(dir_a), "%s-a", dir);
    snprintf(url, sizeof(url), "%s", t_store_db(dir));
    db_text(url, "SELECT current_database() WHERE ?1 = 0", 0, db, sizeof(db));
    struct store *a = store_open_host(dir_a, url, NULL, &err);
    T_TRUE(a != NULL);
    int64_t ta;
    const char *xs[] = { "x" };
    T_OK(store_host_join(a, "a", LEASE_MS, &ta, &err), &err);
    T_OK(store_host_own(a, "a", ta, xs, 1, NULL, &err), &err);
    T_OK(host_farm(dir, url, "b", "[printer y]\ndriver: marlin\nport: pty:/dev/null\n", &err),
         &err);
    T_TRUE(wait_logged("b joined")); /* the join comes back from the beat's thread */
    remote_rc = 1;
    int64_t t0 = clock_mono_ms();
    T_OK(farm_remote_send(hx.f, "x", "pause", NULL, "ops", on_remote, NULL, &err), &err);
    for (int64_t end = t0 + WAIT_LIMIT_MS; clock_mono_ms() < end;) {
        db_text(url, "SELECT state FROM commands WHERE ?1 = 0", 0, text, sizeof(text));
        if (strcmp(text, "pending") == 0)
            break;
        loop_run_once(hx.l, 20);
    }
    T_EQ_STR(text, "pending");
    /* b's commands listener is cut (its last LISTEN is one of the channels store_command_listen
       names: not the jobs' listener's), and no new session let in for now */
    struct sqldb *cut = sqldb_open(getenv("SLIMFARM_TEST_STORE"), 0, &err);
    T_TRUE(cut != NULL);
    snprintf(sql, sizeof(sql), "ALTER DATABASE %s ALLOW_CONNECTIONS false", db);
    T_OK(sqldb_exec(cut, sql), NULL);
    snprintf(sql, sizeof(sql),
             "SELECT count(pg_terminate_backend(pid)) FROM pg_stat_activity WHERE datname = '%s'"
             " AND query LIKE 'LISTEN%%' AND query NOT LIKE '%%" STORE_HOST_CHANNEL "%%'",
             db);
    struct sqldb_stmt *st;
    T_OK(sqldb_prepare(cut, sql, &st), NULL);
    T_EQ_INT(sqldb_step(st), SQLDB_ROW);
    T_EQ_INT(sqldb_column_int(st, 0), 1);
    sqldb_finalize(st);
    T_TRUE(wait_logged("the commands' wake-up connection is lost"));
    /* the owner answers meanwhile: its NOTIFY to b is lost */
    struct store_command *rows;
    size_t n;
    T_OK(store_command_take(a, "a", &rows, &n, &err), &err);
    T_EQ_INT(n, 1);
    T_OK(store_command_finish(a, rows[0].id, SF_OK, NULL, "paused", &err), &err);
    free(rows);
    snprintf(sql, sizeof(sql), "ALTER DATABASE %s ALLOW_CONNECTIONS true", db);
    T_OK(sqldb_exec(cut, sql), NULL);
    sqldb_close(cut);
    for (int64_t end = t0 + WAIT_LIMIT_MS; remote_rc == 1 && clock_mono_ms() < end;)
        loop_run_once(hx.l, 20);
    T_EQ_INT(remote_rc, SF_OK);
    /* read at the listener's return: its deadline (the withdrawal reads it too) not reached */
    T_TRUE(clock_mono_ms() - t0 < FARM_REMOTE_WAIT_MS);
    host_farm_free();
    store_close(a);
}

/* A host stopping at once after it started: the take its start queued (a command another
   host asked while it was away) must leave no row running that nobody runs.  Whether the
   take comes back before the stop's queue drain depends on the store thread's timing. */
T_CASE(host_stopping_leaves_no_command_running)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char dir[512], dir_b[600], url[1024], text[64];
    /* b's last process owned x and died; a asked it for a pause meanwhile */
    struct store *a = host_a_open("stopcmd", dir, sizeof(dir), url, sizeof(url), &err), *pb = NULL;
    T_TRUE(a != NULL);
    snprintf(dir_b, sizeof(dir_b), "%s-b", dir);
    T_TRUE((pb = store_open_host(dir_b, url, NULL, &err)) != NULL);
    int64_t ta, tb;
    const char *xs[] = { "x" };
    struct store_command c;
    T_OK(store_host_join(a, "a", LEASE_MS, &ta, &err), &err);
    T_OK(store_host_join(pb, "b", LEASE_MS, &tb, &err), &err);
    T_OK(store_host_own(pb, "b", tb, xs, 1, NULL, &err), &err);
    T_OK(store_command_add(a, "a", "x", "pause", NULL, "ops", clock_wall_ms(), WAIT_LIMIT_MS, &c,
                           &err),
         &err);
    T_OK(store_host_beat(pb, "b", tb, 1, &err), &err);
    store_close(pb);
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS, gone = clock_wall_ms() + 5;
         clock_wall_ms() <= gone && clock_mono_ms() < end;)
        (void)poll(NULL, 0, 2); /* a bound, not a sleep: its lease is past */
    /* b starts again (its start queues a take) and stops before its loop turns */
    T_OK(host_farm(dir, url, "b", "[printer x]\ndriver: marlin\nport: pty:/dev/null\n", &err),
         &err);
    farm_drop_pool(hx.f);
    farm_free(hx.f);
    pool_free(hx.pool);
    store_close(hx.s);
    loop_free(hx.l);
    farmcfg_release(&hx.cfg);
    log_set_sink(NULL, NULL);
    db_text(url, "SELECT state || ' ' || rc FROM commands WHERE id = ?1", c.id, text, sizeof(text));
    /* answered (SF_ECANCELED if taken at the stop; b's refusal if it ran before), or left
       pending for its deadline: never running with nobody to run it */
    T_TRUE(strncmp(text, "done ", 5) == 0 || strcmp(text, "pending 0") == 0);
    store_close(a);
}

/* ---- a network cut (tests/tools/tcpproxy) ---- */

/* A prepare that writes a tiny G-code for the job's printer. */
static int
gcode_prepare(const struct prepare_req *req, struct prepare_out *out, const atomic_bool *cancel,
              struct sf_err *err)
{
    (void)cancel;
    FILE *f = fopen(req->out_path, "w");
    if (!f)
        return sf_err_sys(err, "cannot write '%s'", req->out_path);
    fprintf(f, "; for %s\nG28\nG1 X10 Y10 Z10\n", req->printer.name);
    fclose(f);
    for (int i = 0; i < 3; i++)
        out->size_mm[i] = 10;
    out->nozzle_mm = req->printer.nozzle_mm;
    return SF_OK;
}

/* The first column of sql's first row on db as an integer; -1 on any failure. */
static int64_t
db_int(struct sqldb *db, const char *sql)
{
    struct sqldb_stmt *st;
    int64_t v = -1;
    if (sqldb_prepare(db, sql, &st) == SF_OK) {
        if (sqldb_step(st) == SQLDB_ROW)
            v = sqldb_column_int64(st, 0);
        sqldb_finalize(st);
    }
    return v;
}

/* Cuts the claim's COMMIT off while the server holds it (the test's trigger sleeps at
   COMMIT while hold_claims has a row), then lets the server commit it and heals. */
struct cutter {
    const char *url; /* the database, directly */
    struct proxy *px;
    bool ok; /* every step was taken */
};

static void *
cut_held_commit(void *arg)
{
    struct cutter *c = arg;
    struct sf_err err;
    struct sqldb *db = sqldb_open(c->url, 0, &err);
    int64_t pid = 0;
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; db && clock_mono_ms() < end && pid <= 0;
         usleep(20 * 1000))
        pid = db_int(db, "SELECT coalesce(min(pid), 0) FROM pg_stat_activity WHERE"
                         " datname = current_database() AND query = 'COMMIT' AND"
                         " wait_event = 'PgSleep'");
    if (pid > 0 && proxy_cmd(c->px, "drop") && sqldb_exec(db, "DELETE FROM hold_claims") == 0) {
        char sql[128];
        snprintf(sql, sizeof(sql), "SELECT count(*) FROM pg_stat_activity WHERE pid = %lld",
                 (long long)pid);
        int64_t end = clock_mono_ms() + WAIT_LIMIT_MS;
        while (db_int(db, sql) != 0 && clock_mono_ms() < end)
            usleep(20 * 1000); /* its COMMIT done on the server, the answer nowhere to go */
        c->ok = db_int(db, sql) == 0 && proxy_cmd(c->px, "heal");
    }
    sqldb_close(db);
    return NULL;
}

T_CASE(host_claim_in_doubt_is_given_back_not_stranded)
{
    T_SKIP_UNLESS(t_store_pg() && getenv("SLIMFARM_TEST_PROXY") && getenv("SLIMFARM_TEST_PG_PORT"),
                  "needs PostgreSQL on a TCP port and tests/tools/tcpproxy (store_pg.sh)");
    struct sf_err err;
    char dir[512], dir_a[600], url[1024], purl[256], db[64];
    snprintf(dir, sizeof(dir), "%s/doubt", t_tmpdir());
    snprintf(dir_a, sizeof(dir_a), "%s-a", dir);
    snprintf(url, sizeof(url), "%s", t_store_db(dir));
    db_text(url, "SELECT current_database() WHERE ?1 = 0", 0, db, sizeof(db));
    struct store *a = store_open_host(dir_a, url, NULL, &err); /* the schema, the job */
    T_TRUE(a != NULL);
    /* a claim's COMMIT (the job to preparing) waits in a deferred trigger while
       hold_claims has a row */
    struct sqldb *direct = sqldb_open(url, 0, &err);
    T_TRUE(direct != NULL);
    T_OK(sqldb_exec(direct,
                    "CREATE TABLE hold_claims(x INTEGER); INSERT INTO hold_claims VALUES(1);"
                    " CREATE FUNCTION hold_claim() RETURNS trigger LANGUAGE plpgsql AS $$"
                    " BEGIN WHILE EXISTS (SELECT 1 FROM hold_claims) LOOP"
                    " PERFORM pg_sleep(0.02); END LOOP; RETURN NULL; END $$;"
                    " CREATE CONSTRAINT TRIGGER hold_claim AFTER UPDATE ON jobs"
                    " DEFERRABLE INITIALLY DEFERRED FOR EACH ROW"
                    " WHEN (NEW.state = 'preparing') EXECUTE FUNCTION hold_claim()"),
         NULL);
    sqldb_close(direct);
    char sha[STORE_SHA_HEX];
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "part.stl");
    snprintf(o.method, sizeof(o.method), "none");
    int64_t id;
    T_OK(store_file_put(a, "solid part\n", 11, sha, &err), &err);
    T_OK(store_job_add(a, &o, sha, &id, &err), &err);
    /* host b reaches the database through the proxy */
    struct proxy px;
    T_TRUE(proxy_start(&px, getenv("SLIMFARM_TEST_PROXY"), getenv("SLIMFARM_TEST_PG_PORT")));
    snprintf(purl, sizeof(purl), "postgresql://postgres@127.0.0.1:%d/%s", px.port, db);
    struct cutter c = { .url = url, .px = &px };
    pthread_t t;
    T_EQ_INT(pthread_create(&t, NULL, cut_held_commit, &c), 0);
    host_prepare = gcode_prepare;
    T_OK(host_farm(dir, purl, "b", "[printer p]\ndriver: marlin\nport: pty:/dev/null\n", &err),
         &err);
    /* b's claim committed, its answer lost: read back, given back, claimed again, printed */
    bool printing = wait_state(url, id, "printing");
    pthread_join(t, NULL);
    if (!printing) { /* what happened instead */
        char ev[2048];
        db_text(url,
                "SELECT string_agg(kind || ': ' || detail, E'\\n' ORDER BY id) FROM events"
                " WHERE job_id = ?1",
                id, ev, sizeof(ev));
        fprintf(stderr, "host b logged:\n%sjob %lld's events:\n%s\n", logged, (long long)id, ev);
    }
    T_TRUE(c.ok);
    T_TRUE(printing);
    T_EQ_INT(t_store_int(dir, "SELECT count(*) FROM events WHERE kind = 'job-defer' AND"
                              " detail LIKE '%its commit was in doubt'"),
             1);
    T_TRUE(was_logged("had committed: given back to the queue"));
    host_farm_free();
    store_close(a);
    proxy_stop(&px);
}

T_CASE(host_lets_go_of_a_print_another_host_attached)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char dir[512], url[1024], text[64];
    struct store *a = host_a_open("fenced", dir, sizeof(dir), url, sizeof(url), &err);
    T_TRUE(a != NULL);
    int64_t ta, id, fa;
    T_OK(store_host_join(a, "a", LEASE_MS, &ta, &err), &err);
    T_OK(host_farm(dir, url, "b",
                   "[printer p]\ndriver: marlin\nport: pty:/dev/null\ngcode_models: *\n", &err),
         &err);
    T_OK(add_ready_for(a, "p", &id, &err), &err);
    T_OK(store_host_wake(a, &err), &err);
    T_TRUE(wait_state(url, id, "printing"));
    /* b is cut off from the database until its lease ran out (p is b's: while b lives, a may
       not attach its print), and host a attaches the job: b's fencing token is stale */
    char sql[128];
    snprintf(sql, sizeof(sql), "UPDATE hosts SET lease_until_ms = %lld WHERE name = 'b'",
             (long long)(clock_wall_ms() - 1000));
    T_OK(t_store_exec(dir, sql), NULL);
    T_OK(store_job_attach(a, "a", ta, id, &fa, &err), &err);
    /* b's printer pauses by itself (a runout): b's PAUSE is refused, and b lets the job go */
    struct hdrv *d = hdrv_named("p");
    T_TRUE(d != NULL);
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; !d->starts && clock_mono_ms() < end;)
        loop_run_once(hx.l, 20); /* the driver has the job (its file judged) */
    T_EQ_INT(d->starts, 1);
    d->base.status.state = DRV_PAUSED;
    loop_timer_add(hx.l, 0, h_deliver, &d->base);
    bool let_go = wait_logged("another host holds it now");
    if (!let_go) {
        char ev[2048];
        db_text(url,
                "SELECT string_agg(kind || ': ' || detail, E'\\n' ORDER BY id) FROM events"
                " WHERE job_id = ?1",
                id, ev, sizeof(ev));
        fprintf(stderr, "host b logged:\n%sjob %lld's events:\n%s\n", logged, (long long)id, ev);
    }
    T_TRUE(let_go);
    farm_sync(hx.f, -1, NULL);
    db_text(url, "SELECT state || ' ' || claimed_by FROM jobs WHERE id = ?1", id, text,
            sizeof(text));
    T_EQ_STR(text, "printing a");
    T_EQ_INT(t_store_int(dir, "SELECT count(*) FROM events WHERE kind = 'job-pause'"), 0);
    T_EQ_INT(d->cancels, 1); /* streamed from b: b stops streaming it */
    struct printer_info info;
    farm_printer_info(hx.f, 0, &info);
    T_EQ_INT(info.job_id, 0);
    host_farm_free();
    store_close(a);
}

/* A reaped host's print: host b prints job *id on its Marlin q (driver *d) for a, its loop
   standing still (a partition, as far as the database can tell) until its lease ran out and a's
   reap interrupted the print.  False if any step did not come. */
static bool reaped_print_on(const char *name, const char *section, const char *printer, char *url,
                            size_t url_cap, struct store **a, int64_t *id, struct hdrv **d);

static bool
reaped_print(const char *name, char *url, size_t url_cap, struct store **a, int64_t *id,
             struct hdrv **d)
{
    return reaped_print_on(name,
                           "[printer q]\ndriver: marlin\nport: pty:/dev/null\ngcode_models: *\n",
                           "q", url, url_cap, a, id, d);
}

/* The same on printer `printer`, the [printer] section `section` of b's farm.ini. */
static bool
reaped_print_on(const char *name, const char *section, const char *printer, char *url,
                size_t url_cap, struct store **a, int64_t *id, struct hdrv **d)
{
    struct sf_err err;
    char dir[512], text[64];
    if (!(*a = host_a_open(name, dir, sizeof(dir), url, url_cap, &err)))
        return false;
    host_lease_s = 5;
    if (host_farm(dir, url, "b", section, &err) || add_ready_for(*a, printer, id, &err) ||
        store_host_wake(*a, &err) || !wait_state(url, *id, "printing"))
        return false;
    if (!(*d = hdrv_named(printer))) /* not p: a printer's repeated log line is held back */
        return false;
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; !(*d)->starts && clock_mono_ms() < end;)
        loop_run_once(hx.l, 20); /* the driver has the job (its file judged) */
    int reaped = 0;
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS;
         (*d)->starts == 1 && reaped <= 0 && clock_mono_ms() < end; usleep(50 * 1000))
        reaped = store_host_reap(*a, clock_wall_ms(), NULL, &err);
    db_text(url, "SELECT state FROM jobs WHERE id = ?1", *id, text, sizeof(text));
    return reaped == 1 && strcmp(text, "interrupted") == 0;
}

T_CASE(host_reaped_while_away_lets_go_of_its_prints)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    char url[1024], text[64];
    struct store *a = NULL;
    int64_t id = 0;
    struct hdrv *d = NULL;
    T_TRUE(reaped_print("reaped", url, sizeof(url), &a, &id, &d));
    T_TRUE(d != NULL);
    /* back: its next beat finds the lease lost, and the printer stops streaming the print */
    bool let_go = wait_logged("another host holds it now");
    if (!let_go)
        fprintf(stderr, "host b logged:\n%s", logged);
    T_TRUE(let_go);
    T_EQ_INT(d ? d->cancels : -1, 1);
    struct printer_info info;
    farm_printer_info(hx.f, 0, &info);
    T_EQ_INT(info.job_id, 0);
    farm_sync(hx.f, -1, NULL);
    db_text(url, "SELECT state FROM jobs WHERE id = ?1", id, text, sizeof(text));
    T_EQ_STR(text, "interrupted");
    host_farm_free();
    store_close(a);
}

/* A print that ran to its end while its host was away from the database: its end, written
   late, is refused as stale (the host was reaped: the job interrupted), and an operator would
   print it again.  Once the host joined again it holds the job and records it done. */
T_CASE(host_records_a_print_that_ended_while_it_was_away)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    char url[1024];
    struct store *a = NULL;
    int64_t id = 0;
    struct hdrv *d = NULL;
    T_TRUE(reaped_print("orphan", url, sizeof(url), &a, &id, &d));
    T_TRUE(d != NULL);
    if (d) { /* meanwhile the printer ran it to its end: b hears it once its loop runs again */
        d->base.status.state = DRV_IDLE;
        d->base.status.lines_acked = 2;
        d->base.on_event(&d->base, DRV_EV_JOB_DONE, d->base.ud);
    }
    T_TRUE(wait_state(url, id, "done"));
    host_farm_free();
    store_close(a);
}

/*
 * A print that ended whole on b while another host holds its job (b's end refused as stale):
 * b reads the job back (printer_settle_orphan) on the store's thread, not on its loop's
 * connection, and leaves the job to the host that holds it.  Before, the read was a
 * store_job_get on the loop.
 */
T_CASE(host_reads_a_refused_end_back_off_the_loop)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char dir[512], url[1024], text[64], sql[128];
    struct store *a = host_a_open("endback", dir, sizeof(dir), url, sizeof(url), &err);
    T_TRUE(a != NULL);
    int64_t ta, id, fa;
    T_OK(store_host_join(a, "a", LEASE_MS, &ta, &err), &err);
    T_OK(host_farm(dir, url, "b",
                   "[printer q]\ndriver: marlin\nport: pty:/dev/null\ngcode_models: *\n", &err),
         &err);
    T_OK(add_ready_for(a, "q", &id, &err), &err);
    T_OK(store_host_wake(a, &err), &err);
    T_TRUE(wait_state(url, id, "printing"));
    struct hdrv *d = hdrv_named("q");
    T_TRUE(d != NULL);
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; d && !d->starts && clock_mono_ms() < end;)
        loop_run_once(hx.l, 20); /* the driver has the job (its file judged) */
    /* b's lease runs out (as in a partition) and a attaches the job: b's token is stale */
    snprintf(sql, sizeof(sql), "UPDATE hosts SET lease_until_ms = %lld WHERE name = 'b'",
             (long long)(clock_wall_ms() - 1000));
    T_OK(t_store_exec(dir, sql), NULL);
    T_OK(store_job_attach(a, "a", ta, id, &fa, &err), &err);
    int64_t sent = store_round_trips(hx.s);
    if (d) { /* the print ends on b's printer: b's PRINT_DONE is refused, then read back */
        d->base.status.state = DRV_IDLE;
        d->base.status.lines_acked = 2;
        d->base.on_event(&d->base, DRV_EV_JOB_DONE, d->base.ud);
    }
    /* the refusal's answer reads the job back (before: at once, on the loop's connection) */
    T_TRUE(wait_logged("is stale: host 'a' holds the job now"));
    struct farm_health h = { 0 };
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; clock_mono_ms() < end;) {
        farm_health(hx.f, &h);
        if (h.store.depth == 0 && h.store.done == h.store.posted)
            break;
        loop_run_once(hx.l, 20);
    }
    T_EQ_INT(h.store.depth, 0);
    T_TRUE(h.has_beat && h.beat.done > 0); /* the beat's own queue, for /metrics */
    loop_run_once(hx.l, 20);               /* the read's answer, if still on its way to the loop */
    T_EQ_INT(store_round_trips(hx.s) - sent, 0);
    db_text(url, "SELECT state || ' ' || claimed_by FROM jobs WHERE id = ?1", id, text,
            sizeof(text));
    T_EQ_STR(text, "printing a"); /* a's now: b records nothing for it */
    host_farm_free();
    store_close(a);
}

/*
 * The farmd_hosts.sh flake (issue 32): a job for host b's printer, queued through another
 * host's API, stayed queued for good.  b's claim, woken by the NOTIFY, found the job's row
 * held by another host's write that leaves it queued (its waiting reason) and took the job
 * for claimed elsewhere; that write's commit wakes nobody.  Here the write is held open
 * while b claims, and committed after; b must claim the job then, with nothing more to wake
 * it.  Fails without the fix: the job stays queued.
 */
T_CASE(host_claims_a_job_another_write_held_at_its_claim)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char dir[512], url[1024], text[64];
    struct store *a = host_a_open("heldrow", dir, sizeof(dir), url, sizeof(url), &err);
    T_TRUE(a != NULL);
    host_prepare = gcode_prepare;
    T_OK(host_farm(dir, url, "b", "[printer p]\ndriver: marlin\nport: pty:/dev/null\n", &err),
         &err);
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; clock_mono_ms() < end;) {
        farm_sync(hx.f, -1, NULL);
        db_text(url, "SELECT state FROM printers WHERE name = 'p' AND ?1 = 0", 0, text,
                sizeof(text));
        if (strcmp(text, "idle") == 0)
            break;
        loop_run_once(hx.l, 20);
    }
    T_EQ_STR(text, "idle");
    int64_t id;
    char sha[STORE_SHA_HEX];
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "part.stl");
    snprintf(o.method, sizeof(o.method), "none");
    snprintf(o.printer, sizeof(o.printer), "p");
    T_OK(store_file_put(a, "solid part\n", 11, sha, &err), &err);
    T_OK(store_job_add(a, &o, sha, &id, &err), &err);
    struct sqldb *other = open_tx(url);
    T_TRUE(other != NULL);
    T_OK(exec_id(other, "UPDATE jobs SET reason = 'fits no printer' WHERE id = %lld", id), NULL);
    T_OK(store_host_wake(a, &err), &err);
    T_TRUE(wait_logged("trying again")); /* b's claim met the held row */
    db_text(url, "SELECT state FROM jobs WHERE id = ?1", id, text, sizeof(text));
    T_EQ_STR(text, "queued");
    T_OK(sqldb_commit(other), NULL); /* no NOTIFY */
    sqldb_close(other);
    T_TRUE(wait_state(url, id, "printing"));
    T_TRUE(was_logged("b claimed job"));
    host_farm_free();
    store_close(a);
}

/*
 * A host whose pass chose a job another host's claim holds (every host's pass reads the same
 * queue and chooses the same first job) claims the next job its pass would prepare, in the
 * same claim: no pass again, no read of the whole queue again (bench_hosts: with 10 hosts on
 * 10,000 jobs five passes a claim, 2.6 claims/s).  Here a's claim of the first job is held
 * open while b's passes run (b's pool has one place); b must prepare the second meanwhile (it
 * prints once the first is a's: till then the first holds b's printer, sched.h).  Failed
 * before: b's claim of the first was busy, tried again and again until a's claim ended.
 */
T_CASE(host_claims_the_next_job_while_another_hosts_claim_holds_the_first)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char dir[512], url[1024], text[64];
    struct store *a = host_a_open("nextfree", dir, sizeof(dir), url, sizeof(url), &err);
    T_TRUE(a != NULL);
    int64_t first, second;
    char sha[STORE_SHA_HEX];
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "part.stl");
    snprintf(o.method, sizeof(o.method), "none");
    T_OK(store_file_put(a, "solid part\n", 11, sha, &err), &err);
    T_OK(store_job_add(a, &o, sha, &first, &err), &err);
    T_OK(store_job_add(a, &o, sha, &second, &err), &err);
    /* a's claim of the first, on its way (b reads the job queued) */
    struct sqldb *other = open_tx(url);
    T_TRUE(other != NULL);
    T_OK(exec_id(other,
                 "UPDATE jobs SET state = 'preparing', claimed_by = 'a', fence = fence + 1"
                 " WHERE id = %lld",
                 first),
         NULL);
    host_prepare = gcode_prepare;
    T_OK(host_farm(dir, url, "b", "[printer p]\ndriver: marlin\nport: pty:/dev/null\n", &err),
         &err);
    /* prepared (claimed) while a's claim holds the first: it prints once the first is a's */
    bool claimed = wait_state(url, second, "ready");
    if (!claimed)
        fprintf(stderr, "host b logged:\n%.2000s", logged);
    T_TRUE(claimed);
    db_text(url, "SELECT state || ' ' || claimed_by FROM jobs WHERE id = ?1", first, text,
            sizeof(text));
    T_EQ_STR(text, "queued "); /* as committed: a's claim is still on its way */
    T_OK(sqldb_commit(other), NULL);
    sqldb_close(other);
    T_TRUE(wait_state(url, second, "printing"));
    db_text(url, "SELECT claimed_by FROM jobs WHERE id = ?1", second, text, sizeof(text));
    T_EQ_STR(text, "b");
    db_text(url, "SELECT state || ' ' || claimed_by FROM jobs WHERE id = ?1", first, text,
            sizeof(text));
    T_EQ_STR(text, "preparing a"); /* a's: b did not claim it too */
    host_farm_free();
    store_close(a);
}

/* ---- the scheduling pass's claims and takes on the store thread (farm_ask.c) ---- */

/* A gate on url's database: a claim or take (the fence of a queued or ready job moves on)
   waits on the server while gate has a row (60 s at most: a loop that made it itself, and so
   cannot open the gate, would hang for good otherwise).  Empty at first. */
static bool
gate_make(struct sqldb *db)
{
    return sqldb_exec(db, "CREATE TABLE gate(x INTEGER);"
                          " CREATE FUNCTION gate_wait() RETURNS trigger LANGUAGE plpgsql AS $$"
                          " BEGIN FOR i IN 1..3000 LOOP EXIT WHEN NOT EXISTS (SELECT 1 FROM gate);"
                          " PERFORM pg_sleep(0.02); END LOOP; RETURN NEW; END $$;"
                          " CREATE TRIGGER gate_wait BEFORE UPDATE ON jobs FOR EACH ROW"
                          " WHEN (OLD.state IN ('queued', 'ready') AND NEW.fence <> OLD.fence)"
                          " EXECUTE FUNCTION gate_wait()") == 0;
}

/* Turn hx's loop until a claim or take waits at the gate (on the store thread: the loop
   turns meanwhile); false after WAIT_LIMIT_MS. */
static bool
gate_waited(struct sqldb *db)
{
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; clock_mono_ms() < end;) {
        if (db_int(db, "SELECT count(*) FROM pg_stat_activity WHERE datname = current_database()"
                       " AND wait_event = 'PgSleep' AND query LIKE 'UPDATE jobs SET %'") > 0)
            return true;
        loop_run_once(hx.l, 10);
    }
    return false;
}

/* Host b with printers p and q, printing a G-code job on p (so it joined, and its passes
   have run); the gate made, closed.  *direct: a connection to the database. */
static bool
gated_host(const char *name, char *url, size_t cap, struct store **a, struct sqldb **direct)
{
    struct sf_err err;
    char dir[512];
    int64_t warm;
    host_prepare = gcode_prepare;
    return (*a = host_a_open(name, dir, sizeof(dir), url, cap, &err)) != NULL &&
           (*direct = sqldb_open(url, 0, &err)) != NULL && gate_make(*direct) &&
           host_farm(dir, url, "b",
                     "[printer p]\ndriver: marlin\nport: pty:/dev/null\ngcode_models: *\n"
                     "[printer q]\ndriver: marlin\nport: pty:/dev/null\ngcode_models: *\n",
                     &err) == SF_OK &&
           add_ready_for(*a, "p", &warm, &err) == SF_OK && store_host_wake(*a, &err) == SF_OK &&
           wait_state(url, warm, "printing") &&
           sqldb_exec(*direct, "INSERT INTO gate VALUES(1)") == 0;
}

/* The pass that claims a queued job sends nothing on the loop's connection: the claim runs on
   the store thread (the loop turns while it waits at the gate), and the job is prepared and
   printed once it is back.  (The preparation's file lookups are the worker's: not measured
   here.)  Failed before: the claim was the loop's own statement, and the loop stood still. */
T_CASE(host_claims_a_job_on_the_store_thread)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char url[1024], sha[STORE_SHA_HEX];
    struct store *a = NULL;
    struct sqldb *direct = NULL;
    T_TRUE(gated_host("claimgate", url, sizeof(url), &a, &direct));
    int64_t rt = store_round_trips(hx.s), id;
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "part.stl");
    snprintf(o.printer, sizeof(o.printer), "q");
    T_OK(store_file_put(a, "solid part\n", 11, sha, &err), &err);
    T_OK(store_job_add(a, &o, sha, &id, &err), &err);
    T_OK(store_host_wake(a, &err), &err);
    T_TRUE(gate_waited(direct));
    T_EQ_INT(store_round_trips(hx.s), rt);
    T_OK(sqldb_exec(direct, "DELETE FROM gate"), NULL);
    T_TRUE(wait_state(url, id, "printing"));
    sqldb_close(direct);
    host_farm_free();
    store_close(a);
}

/* The pass that takes a ready job for a printer sends nothing on the loop's connection, and
   while the take is out a later pass gives that printer no other job; the job starts once
   the take is back. */
T_CASE(host_takes_a_ready_job_on_the_store_thread)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char url[1024];
    struct store *a = NULL;
    struct sqldb *direct = NULL;
    T_TRUE(gated_host("takegate", url, sizeof(url), &a, &direct));
    int64_t rt = store_round_trips(hx.s), id, other;
    T_OK(add_ready_for(a, "q", &id, &err), &err);
    T_OK(store_host_wake(a, &err), &err);
    T_TRUE(gate_waited(direct));
    T_EQ_INT(store_round_trips(hx.s), rt);
    /* another job for q meanwhile: q is taken (by the take on its way), so no pass takes it */
    T_OK(add_ready_for(a, "q", &other, &err), &err);
    farm_kick(hx.f);
    for (int i = 0; i < 20; i++)
        loop_run_once(hx.l, 10);
    T_EQ_INT(db_int(direct, "SELECT count(*) FROM pg_stat_activity WHERE"
                            " datname = current_database() AND wait_event = 'PgSleep'"),
             1);
    T_OK(sqldb_exec(direct, "DELETE FROM gate"), NULL);
    T_TRUE(wait_state(url, id, "printing"));
    char text[64];
    db_text(url, "SELECT state || ' by ' || claimed_by FROM jobs WHERE id = ?1", other, text,
            sizeof(text));
    T_EQ_STR(text, "ready by ");
    sqldb_close(direct);
    host_farm_free();
    store_close(a);
}

/* A printer disabled while the take of its job is out: the job is not started on it but
   given back, ready for any host (b may take it again for another printer). */
T_CASE(host_starts_nothing_on_a_printer_disabled_while_its_take_was_out)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char url[1024], text[64];
    struct store *a = NULL;
    struct sqldb *direct = NULL;
    T_TRUE(gated_host("disablegate", url, sizeof(url), &a, &direct));
    int64_t id;
    T_OK(add_ready_for(a, "q", &id, &err), &err);
    T_OK(store_host_wake(a, &err), &err);
    T_TRUE(gate_waited(direct));
    T_OK(farm_printer_disable(hx.f, "q", "test", &err), &err);
    T_OK(sqldb_exec(direct, "DELETE FROM gate"), NULL);
    T_TRUE(wait_logged("b gave job"));
    T_TRUE(was_logged("printer q was disabled meanwhile"));
    farm_sync(hx.f, -1, NULL);
    db_text(url, "SELECT state || ' by ' || claimed_by FROM jobs WHERE id = ?1", id, text,
            sizeof(text));
    T_EQ_STR(text, "ready by ");
    struct printer_info info;
    farm_printer_info(hx.f, 1, &info);
    T_EQ_STR(info.cfg->name, "q");
    T_EQ_INT(info.job_id, 0);
    sqldb_close(direct);
    host_farm_free();
    store_close(a);
}

/* The same for a printer removed while the take of its job was out. */
T_CASE(host_starts_nothing_on_a_printer_removed_while_its_take_was_out)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char url[1024], text[64];
    struct store *a = NULL;
    struct sqldb *direct = NULL;
    T_TRUE(gated_host("removegate", url, sizeof(url), &a, &direct));
    int64_t id;
    T_OK(add_ready_for(a, "q", &id, &err), &err);
    T_OK(store_host_wake(a, &err), &err);
    T_TRUE(gate_waited(direct));
    T_OK(farm_printer_remove(hx.f, "q", &err), &err);
    T_OK(sqldb_exec(direct, "DELETE FROM gate"), NULL);
    T_TRUE(wait_logged("b gave job"));
    T_TRUE(was_logged("printer q was removed meanwhile"));
    farm_sync(hx.f, -1, NULL);
    db_text(url, "SELECT state || ' by ' || claimed_by FROM jobs WHERE id = ?1", id, text,
            sizeof(text));
    T_EQ_STR(text, "ready by ");
    sqldb_close(direct);
    host_farm_free();
    store_close(a);
}

/* ---- a network print re-attached: held on the store thread, its end recorded ---- */

/* Host b's network printer NAME (hdrv re-attaches it).  A name of each test's own: a
   printer's repeated log line is held back. */
#define NET_PRINTER(name)                                                                          \
    "[printer " name "]\ndriver: octoprint\nurl: http://127.0.0.1:9\napi_key: k\n"                 \
    "gcode_models: *\n"

/* A gate on db's database: a hold of an interrupted job (its fence moves on) waits on the
   server while gate has a row (30 s at most).  Closed at first. */
static bool
gate_interrupted(struct sqldb *db)
{
    return sqldb_exec(db, "CREATE TABLE gate(x INTEGER); INSERT INTO gate VALUES(1);"
                          " CREATE FUNCTION gate_wait() RETURNS trigger LANGUAGE plpgsql AS $$"
                          " BEGIN FOR i IN 1..1500 LOOP EXIT WHEN NOT EXISTS (SELECT 1 FROM gate);"
                          " PERFORM pg_sleep(0.02); END LOOP; RETURN NEW; END $$;"
                          " CREATE TRIGGER gate_wait BEFORE UPDATE ON jobs FOR EACH ROW"
                          " WHEN (OLD.state = 'interrupted' AND NEW.fence <> OLD.fence)"
                          " EXECUTE FUNCTION gate_wait()") == 0;
}

/* d's print ended: the driver says idle, then reports the end (a network driver's order:
   netjob_report). */
static void
net_print_ends(struct hdrv *d)
{
    d->base.status.state = DRV_IDLE;
    d->base.status.lines_acked = 2;
    d->base.on_event(&d->base, DRV_EV_STATE, d->base.ud);
    d->base.on_event(&d->base, DRV_EV_JOB_DONE, d->base.ud);
}

/* Turn hx's loop until its printer 0 is in state want with no job; false after
   WAIT_LIMIT_MS. */
static bool
wait_printer_free(enum printer_state want)
{
    struct printer_info info = { 0 };
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; clock_mono_ms() < end;) {
        farm_printer_info(hx.f, 0, &info);
        if (info.state == want && info.job_id == 0)
            return true;
        loop_run_once(hx.l, 20);
    }
    fprintf(stderr, "printer: %s, job %lld: %s\n", printer_state_name(info.state),
            (long long)info.job_id, info.message ? info.message : "");
    return false;
}

/* An operator's resume's answer (farm_job_resume_then): its rc, once it came. */
struct resumed {
    bool came;
    int rc;
    char msg[256];
};

static void
on_resumed(void *ud, const struct storeq_result *r)
{
    struct resumed *x = ud;
    x->came = true;
    x->rc = r->rc;
    snprintf(x->msg, sizeof(x->msg), "%s", r->rc && r->err ? r->err->msg : "");
}

/*
 * An operator's resume on one of several hosts holds the job (its new fencing token) on the
 * store's thread (farm_host_hold_ask), not on the loop's connection, and answers once the hold
 * and its RESUME came back: the print goes on on its printer under this host's token.  Before,
 * printer_resume_commit held it with farm_host_hold: farm_sync and store_job_attach on the
 * loop's connection.
 */
T_CASE(host_holds_an_operators_resume_off_the_loop)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    char url[1024], text[64];
    struct store *a = NULL;
    int64_t id = 0;
    struct hdrv *d = NULL;
    struct sf_err err;
    T_TRUE(reaped_print("resumehold", url, sizeof(url), &a, &id, &d));
    T_TRUE(d != NULL);
    T_TRUE(wait_logged("another host holds it now")); /* b let it go, and joins again */
    if (d) /* its driver stopped the print (the cancel): its part is left on the bed */
        d->base.on_event(&d->base, DRV_EV_JOB_CANCELLED, d->base.ud);
    struct printer_info info = { 0 };
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; clock_mono_ms() < end;) {
        farm_printer_info(hx.f, 0, &info);
        if (info.job_id == 0 && info.state != PRINTER_PRINTING && info.state != PRINTER_OFFLINE)
            break;
        loop_run_once(hx.l, 20);
    }
    if (info.state == PRINTER_AWAITING_CLEAR) /* the operator cleared what was left */
        T_OK(farm_printer_action(hx.f, "q", PRINTER_ACT_CLEARED, &err), &err);
    T_TRUE(wait_printer_free(PRINTER_IDLE));
    char reader[64];
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS;
         !farm_host_reader(hx.f, reader, sizeof(reader)) && clock_mono_ms() < end;)
        loop_run_once(hx.l, 20); /* b joined again: it may hold */
    farm_sync(hx.f, -1, NULL);
    int64_t fence_before = 0, fence_after = 0;
    db_text(url, "SELECT fence FROM jobs WHERE id = ?1", id, text, sizeof(text));
    fence_before = atoll(text);
    int starts = d ? d->starts : -1;
    int64_t rt = store_round_trips(hx.s);
    struct resumed x = { 0 };
    T_OK(farm_job_resume_then(hx.f, id, 1, on_resumed, &x, &err), &err);
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; !x.came && clock_mono_ms() < end;)
        loop_run_once(hx.l, 20);
    T_TRUE(x.came);
    if (x.rc)
        fprintf(stderr, "resume: %s\n", x.msg);
    T_EQ_INT(x.rc, SF_OK);
    T_EQ_INT(store_round_trips(hx.s) - rt, 0);
    T_TRUE(wait_state(url, id, "printing"));
    db_text(url, "SELECT fence FROM jobs WHERE id = ?1", id, text, sizeof(text));
    fence_after = atoll(text);
    T_TRUE(fence_after > fence_before); /* held: the token moved on */
    farm_printer_info(hx.f, 0, &info);
    T_EQ_INT(info.state, PRINTER_PRINTING);
    T_EQ_INT(info.job_id, id);
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS;
         d && d->starts == starts && clock_mono_ms() < end;)
        loop_run_once(hx.l, 20); /* its driver has it again */
    T_EQ_INT(d ? d->starts : -1, starts + 1);
    host_farm_free();
    store_close(a);
}

/*
 * Issue 32 (farmd_hosts_chaos part 2, b_pl): host b, cut off from the database while its
 * network printer prints, is reaped (the job interrupted); when b is back its beat finds the
 * lease lost and lets the job go (the printer prints on), and b joins again.  b then holds
 * the job again and takes the print back.  Failed before: the printer, offered its
 * interrupted job once on this connection already, was never offered it again: the job
 * stayed interrupted while the printer printed it, and its end was refused ("cannot finish
 * a printer that is idle").
 */
T_CASE(host_takes_back_a_network_print_it_let_go)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    char url[1024], text[64];
    struct store *a = NULL;
    int64_t id = 0;
    struct hdrv *d = NULL;
    T_TRUE(reaped_print_on("netback", NET_PRINTER("n1") "auto_eject: true\n", "n1", url,
                           sizeof(url), &a, &id, &d));
    T_TRUE(d != NULL);
    /* back: lost, let go, joined again, held again: printing on n for b */
    T_TRUE(wait_state(url, id, "printing"));
    T_TRUE(was_logged("another host holds it now"));
    db_text(url, "SELECT claimed_by FROM jobs WHERE id = ?1", id, text, sizeof(text));
    T_EQ_STR(text, "b");
    if (d) {
        T_EQ_INT(d->starts, 1);
        T_EQ_INT(d->attaches, 0); /* the driver had it all along: not offered again */
        net_print_ends(d);
    }
    T_TRUE(wait_state(url, id, "done"));
    T_TRUE(wait_printer_free(PRINTER_IDLE));
    db_text(url, "SELECT count(*) FROM prints WHERE job_id = ?1 AND outcome = 'done'", id, text,
            sizeof(text));
    T_EQ_STR(text, "1");
    T_TRUE(!was_logged("cannot finish"));
    host_farm_free();
    store_close(a);
}

/*
 * The same, but the print ends while b's hold of the job is on its way (held here at a gate
 * on the server; the print's end reaches b's driver only after b joined again): the end is
 * recorded once the hold is back, the job done once, and the printer, which keeps its part
 * (no auto_eject), awaits its clear: it waited offline for the job, not idle with a part on
 * its bed.  Failed before as above (nothing held the job again: the gate never saw a hold).
 */
T_CASE(host_records_a_network_print_that_ended_after_it_joined_again)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char url[1024], text[64];
    struct store *a = NULL;
    int64_t id = 0;
    struct hdrv *d = NULL;
    T_TRUE(reaped_print_on("netend", NET_PRINTER("n2"), "n2", url, sizeof(url), &a, &id, &d));
    struct sqldb *direct = sqldb_open(url, 0, &err);
    T_TRUE(direct != NULL && gate_interrupted(direct));
    /* b's loop runs again: its beat finds the lease lost, lets the job go, joins, holds it */
    T_TRUE(gate_waited(direct));
    bool let_go = was_logged("another host holds it now");
    if (!let_go)
        fprintf(stderr, "host b logged:\n%s", logged);
    T_TRUE(let_go);
    if (d)
        net_print_ends(d);
    for (int i = 0; i < 10; i++) /* its end reaches the printer while the hold waits */
        loop_run_once(hx.l, 10);
    T_OK(sqldb_exec(direct, "DELETE FROM gate"), NULL);
    T_TRUE(wait_state(url, id, "done"));
    T_TRUE(wait_printer_free(PRINTER_AWAITING_CLEAR));
    db_text(url, "SELECT count(*) FROM prints WHERE job_id = ?1 AND outcome = 'done'", id, text,
            sizeof(text));
    T_EQ_STR(text, "1");
    T_EQ_INT(d ? d->starts : -1, 1);
    T_TRUE(!was_logged("cannot finish"));
    sqldb_close(direct);
    host_farm_free();
    store_close(a);
}

/* Host b's farm (host_farm in dir) with network printer `printer` (auto_eject), printing job
   *id that a added ready for it; *d, its driver, once that has the job (or the wait for it
   ran out).  SF_ETIMEDOUT if the job never printed, SF_ENOTFOUND if the printer has no
   driver, else host_farm's, add_ready_for's or store_host_wake's status; err says which. */
static int
net_printing(struct store *a, const char *dir, const char *url, const char *printer, int64_t *id,
             struct hdrv **d, struct sf_err *err)
{
    char section[256];
    snprintf(section, sizeof(section), NET_PRINTER("%s") "auto_eject: true\n", printer);
    int rc;
    if ((rc = host_farm(dir, url, "b", section, err)) < 0 ||
        (rc = add_ready_for(a, printer, id, err)) < 0 || (rc = store_host_wake(a, err)) < 0)
        return rc;
    if (!wait_state(url, *id, "printing"))
        return sf_err_set(err, SF_ETIMEDOUT, "job %lld never printing", (long long)*id);
    if (!(*d = hdrv_named(printer)))
        return sf_err_set(err, SF_ENOTFOUND, "printer %s has no driver", printer);
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; !(*d)->starts && clock_mono_ms() < end;)
        loop_run_once(hx.l, 20); /* the driver has the job */
    return SF_OK;
}

/*
 * A network printer whose link dropped while printing comes back still printing its job (now
 * interrupted): the host holds the job (store_job_attach, its new fencing token) on the farm's
 * store thread, and nothing on the loop's connection; the loop turns while the hold waits
 * (here at a gate on the server), and the printer takes the job back once it is held.  Before,
 * the hold waited on the loop for the store's queue (farm_sync, 250 ms: a busy queue gave the
 * re-attach up for good, the job left interrupted under a printer that printed it) and then
 * ran on the loop's connection, the loop standing still meanwhile.
 */
T_CASE(host_holds_a_reattached_print_off_the_loop)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char dir[512], url[1024], text[64];
    struct store *a = host_a_open("netgate", dir, sizeof(dir), url, sizeof(url), &err);
    T_TRUE(a != NULL);
    int64_t id;
    struct hdrv *d = NULL;
    T_OK(net_printing(a, dir, url, "n3", &id, &d, &err), &err);
    struct sqldb *direct = sqldb_open(url, 0, &err);
    T_TRUE(direct != NULL && gate_interrupted(direct));
    int64_t rt = store_round_trips(hx.s);
    if (d) { /* the link drops; the printer prints on, and the driver connects again */
        d->base.status.state = DRV_OFFLINE;
        snprintf(d->base.status.message, sizeof(d->base.status.message), "timed out");
        d->base.on_event(&d->base, DRV_EV_STATE, d->base.ud);
        d->base.status.state = DRV_PRINTING;
        d->base.status.message[0] = '\0';
    }
    T_TRUE(gate_waited(direct)); /* the hold, on the store thread; the loop turns */
    T_EQ_INT(d ? d->attaches : -1, 1);
    T_EQ_INT(store_round_trips(hx.s) - rt, 0);
    db_text(url, "SELECT state FROM jobs WHERE id = ?1", id, text, sizeof(text));
    T_EQ_STR(text, "interrupted");
    T_OK(sqldb_exec(direct, "DELETE FROM gate"), NULL);
    T_TRUE(wait_state(url, id, "printing"));
    struct printer_info info;
    farm_printer_info(hx.f, 0, &info);
    T_EQ_INT(info.state, PRINTER_PRINTING);
    T_EQ_INT(info.job_id, id);
    if (d)
        net_print_ends(d);
    T_TRUE(wait_state(url, id, "done"));
    T_EQ_INT(d ? d->starts : -1, 1);
    sqldb_close(direct);
    host_farm_free();
    store_close(a);
}

/*
 * The re-attach of a network printer while the farm's store queue is busy (here: the
 * printer's own state write waits at a gate on the server): the printer takes its job back
 * at once in the loop's view, and the store has it once the queue moves.  Failed before: the
 * hold waited for the queue on the loop (farm_sync, 250 ms), found it busy (SF_EBUSY), and
 * that was final: the job stayed interrupted while the printer printed it.
 */
T_CASE(host_reattaches_while_its_store_queue_is_busy)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char dir[512], url[1024];
    struct store *a = host_a_open("netbusy", dir, sizeof(dir), url, sizeof(url), &err);
    T_TRUE(a != NULL);
    int64_t id;
    struct hdrv *d = NULL;
    T_OK(net_printing(a, dir, url, "n4", &id, &d, &err), &err);
    /* the gate: the printer's move from offline to idle waits on the server (30 s at most) */
    struct sqldb *direct = sqldb_open(url, 0, &err);
    T_TRUE(direct != NULL);
    T_EQ_INT(sqldb_exec(direct,
                        "CREATE TABLE gate(x INTEGER); INSERT INTO gate VALUES(1);"
                        " CREATE FUNCTION gate_wait() RETURNS trigger LANGUAGE plpgsql AS $$"
                        " BEGIN FOR i IN 1..1500 LOOP EXIT WHEN NOT EXISTS (SELECT 1 FROM gate);"
                        " PERFORM pg_sleep(0.02); END LOOP; RETURN NEW; END $$;"
                        " CREATE TRIGGER gate_wait BEFORE UPDATE ON printers FOR EACH ROW"
                        " WHEN (OLD.state = 'offline' AND NEW.state = 'idle')"
                        " EXECUTE FUNCTION gate_wait()"),
             0);
    if (d) { /* the link drops; the printer prints on, and the driver connects again */
        d->base.status.state = DRV_OFFLINE;
        snprintf(d->base.status.message, sizeof(d->base.status.message), "timed out");
        d->base.on_event(&d->base, DRV_EV_STATE, d->base.ud);
        d->base.status.state = DRV_PRINTING;
        d->base.status.message[0] = '\0';
    }
    /* the printer prints its job again while its state write waits at the gate */
    struct printer_info info = { 0 };
    bool gated = false;
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; clock_mono_ms() < end;) {
        farm_printer_info(hx.f, 0, &info);
        gated = gated || db_int(direct, "SELECT count(*) FROM pg_stat_activity WHERE datname ="
                                        " current_database() AND wait_event = 'PgSleep' AND"
                                        " query LIKE 'INSERT INTO printers%'") > 0;
        if (gated && info.state == PRINTER_PRINTING && info.job_id == id)
            break;
        loop_run_once(hx.l, 10);
    }
    T_TRUE(gated);
    T_EQ_INT(info.state, PRINTER_PRINTING);
    T_EQ_INT(info.job_id, id);
    T_OK(sqldb_exec(direct, "DELETE FROM gate"), NULL);
    T_TRUE(wait_state(url, id, "printing"));
    if (d)
        net_print_ends(d);
    T_TRUE(wait_state(url, id, "done"));
    T_EQ_INT(d ? d->starts : -1, 1);
    T_EQ_INT(d ? d->attaches : -1, 1);
    sqldb_close(direct);
    host_farm_free();
    store_close(a);
}

/*
 * A network printer whose link dropped while printing comes back idle: the print ended while
 * the farm was away, and the driver, adopting the job, reports its end at once (no change of
 * state to report).  The end is recorded once the host holds the job, and the printer, which
 * waited offline for that, connects: idle (auto_eject), taking the next job.
 */
T_CASE(host_records_a_reattached_print_that_ended_while_away)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char dir[512], url[1024], text[64];
    struct store *a = host_a_open("netgone", dir, sizeof(dir), url, sizeof(url), &err);
    T_TRUE(a != NULL);
    int64_t id;
    struct hdrv *d = NULL;
    T_OK(net_printing(a, dir, url, "n5", &id, &d, &err), &err);
    if (d) { /* the link drops; the print ends meanwhile; the driver connects again, idle */
        d->base.status.state = DRV_OFFLINE;
        snprintf(d->base.status.message, sizeof(d->base.status.message), "timed out");
        d->base.on_event(&d->base, DRV_EV_STATE, d->base.ud);
        d->base.status.state = DRV_IDLE;
        d->base.status.message[0] = '\0';
        d->base.status.lines_acked = 2;
        d->ended = true;
    }
    T_TRUE(wait_state(url, id, "done"));
    T_TRUE(wait_printer_free(PRINTER_IDLE));
    T_EQ_INT(d ? d->attaches : -1, 1);
    T_EQ_INT(d ? d->starts : -1, 1);
    db_text(url, "SELECT count(*) FROM prints WHERE job_id = ?1 AND outcome = 'done'", id, text,
            sizeof(text));
    T_EQ_STR(text, "1");
    host_farm_free();
    store_close(a);
}

/*
 * A network printer (no auto_eject) whose link dropped while printing comes back still
 * printing its job, but an operator restarted the job (interrupted -> ready) after the
 * re-attach read it and before the hold (here: the restart's transaction holds the job's row
 * while the hold waits for it).  The hold checks "interrupted, on this printer" in its own
 * transaction, so the ready job is not held by this host; and the print the printer finishes
 * leaves its part on the bed: the printer awaits a clear, not offered the ready job on top of
 * it.  Failed before: the hold took the ready job (store_job_attach accepts ready), RESUME was
 * refused, and the job was left held by b; and a dropped away job left the bed "clear".
 */
T_CASE(host_does_not_hold_an_away_job_restarted_before_its_hold)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char dir[512], url[1024], text[64], sql[160];
    struct store *a = host_a_open("netrestart", dir, sizeof(dir), url, sizeof(url), &err);
    T_TRUE(a != NULL);
    int64_t id;
    T_OK(host_farm(dir, url, "b", NET_PRINTER("n6"), &err), &err);
    T_OK(add_ready_for(a, "n6", &id, &err), &err);
    T_OK(store_host_wake(a, &err), &err);
    T_TRUE(wait_state(url, id, "printing"));
    struct hdrv *d = hdrv_named("n6");
    T_TRUE(d != NULL);
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; d && !d->starts && clock_mono_ms() < end;)
        loop_run_once(hx.l, 20); /* the driver has the job */
    if (d) {                     /* the link drops; the printer prints on */
        d->base.status.state = DRV_OFFLINE;
        snprintf(d->base.status.message, sizeof(d->base.status.message), "timed out");
        d->base.on_event(&d->base, DRV_EV_STATE, d->base.ud);
    }
    T_TRUE(wait_state(url, id, "interrupted"));
    farm_sync(hx.f, -1, NULL);
    /* the operator's restart, its transaction open: reads see the job interrupted still */
    struct sqldb *direct = sqldb_open(url, 0, &err);
    T_TRUE(direct != NULL);
    snprintf(sql, sizeof(sql),
             "BEGIN; UPDATE jobs SET state = 'ready', claimed_by = '' WHERE id = %lld",
             (long long)id);
    T_OK(sqldb_exec(direct, sql), NULL);
    if (d) { /* the driver connects again, printing */
        d->base.status.state = DRV_PRINTING;
        d->base.status.message[0] = '\0';
        d->base.on_event(&d->base, DRV_EV_STATE, d->base.ud);
    }
    struct sqldb *watch = sqldb_open(url, 0, &err);
    T_TRUE(watch != NULL);
    bool waited = false; /* the hold waits for the restart's row lock */
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; !waited && clock_mono_ms() < end;) {
        waited = db_int(watch, "SELECT count(*) FROM pg_stat_activity WHERE datname ="
                               " current_database() AND wait_event_type = 'Lock' AND"
                               " query LIKE 'UPDATE jobs SET claimed_by%'") > 0;
        loop_run_once(hx.l, 10);
    }
    T_TRUE(waited);
    T_OK(sqldb_exec(direct, "COMMIT"), NULL);
    /* refused (the hold's answer, on the loop, then p's bed written through the queue) */
    bool full = false;
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; !full && clock_mono_ms() < end;) {
        farm_sync(hx.f, -1, NULL);
        full =
            db_int(watch, "SELECT count(*) FROM printers WHERE name = 'n6' AND bed_full = 1") == 1;
        loop_run_once(hx.l, 20);
    }
    db_text(url, "SELECT state || ' by ' || claimed_by FROM jobs WHERE id = ?1", id, text,
            sizeof(text));
    T_EQ_STR(text, "ready by ");
    T_TRUE(full); /* its part stays on the bed once the print ends */
    T_EQ_INT(d ? d->starts : -1, 1);
    sqldb_close(watch);
    sqldb_close(direct);
    host_farm_free();
    store_close(a);
}

/*
 * Spare cores (issue 32: "any host with spare cores may prepare any queued job"): host a,
 * with no printers, prepares a job for host b's printer with b's settings as b published
 * them (store_host_publish), on the store thread and workers (none of it on the loop's own
 * connection), and gives the prepared job up in the same commit: no host holds it, so b
 * takes it (store_job_take) and prints it.  Fails without the rule: no host prepares the job
 * (a prepared only for a printer of its own, and b here has no preparation of its own).
 */
T_CASE(host_with_spare_cores_prepares_for_another_hosts_printer)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char dir[512], dir_b[600], url[1024], text[256];
    snprintf(dir, sizeof(dir), "%s/spare", t_tmpdir());
    snprintf(dir_b, sizeof(dir_b), "%s-b", dir);
    snprintf(url, sizeof(url), "%s", t_store_db(dir));
    /* b: live, owns pb (PETG, a 0.6 mm nozzle, a big bed) and published it */
    struct store *b = store_open_host(dir_b, url, NULL, &err);
    T_TRUE(b != NULL);
    int64_t tb, id, fence = 0;
    T_OK(store_host_join(b, "b", LEASE_MS, &tb, &err), &err);
    const char *pbs[] = { "pb", "pc" };
    T_OK(store_host_own(b, "b", tb, pbs, 2, NULL, &err), &err);
    struct store_printer_prep pb = { .name = "pb",
                                     .profile = "generic-marlin",
                                     .material = "PETG",
                                     .nozzle_mm = 0.6,
                                     .bed_mm = { 300, 300, 300 },
                                     .overhang_deg = 50,
                                     .enabled = true };
    T_OK(store_host_publish(b, "b", tb, &pb, 1, &err), &err);
    /* and pc, with settings farm.ini would refuse (a profile that is a path): never prepared for */
    struct store_printer_prep pc = pb;
    snprintf(pc.name, sizeof(pc.name), "pc");
    snprintf(pc.profile, sizeof(pc.profile), "../../etc/x");
    T_OK(store_host_publish(b, "b", tb, &pc, 1, &err), &err);
    /* a PETG job: a's printer has PLA */
    char sha[STORE_SHA_HEX];
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "part.stl");
    snprintf(o.method, sizeof(o.method), "none");
    snprintf(o.material, sizeof(o.material), "PETG");
    T_OK(store_file_put(b, "solid part\n", 11, sha, &err), &err);
    T_OK(store_job_add(b, &o, sha, &id, &err), &err);
    T_OK(store_host_wake(b, &err), &err);
    host_prepare = gcode_prepare;
    T_OK(host_farm(dir, url, "a", "", &err), &err);
    T_TRUE(wait_logged("a joined"));         /* (its join checks the loop's connection once) */
    int64_t trips = store_round_trips(hx.s); /* the loop's own connection */
    bool ready = wait_state(url, id, "ready");
    if (!ready)
        fprintf(stderr, "host a logged:\n%s\n", logged);
    T_TRUE(ready);
    farm_sync(hx.f, -1, NULL);
    /* prepared for pb's key, and no host's: a gave it up in the same commit */
    db_text(url, "SELECT prep_key || ' by ' || claimed_by FROM jobs WHERE id = ?1", id, text,
            sizeof(text));
    T_EQ_STR(text, "generic-marlin/PETG/n0.6/bed300x300x300/a50 by ");
    T_EQ_INT(t_store_int(dir, "SELECT count(*) FROM events WHERE kind = 'job-hand-over' AND"
                              " detail LIKE '%host ''a'' prepared it%'"),
             1);
    T_TRUE(was_logged("a claimed job"));
    T_TRUE(was_logged("host b's printer pc: bad profile: skipped"));
    /* b's printers read, the claim, the preparation's files and PREPARED: none on the loop's
       connection */
    T_EQ_INT(store_round_trips(hx.s), trips);
    /* b takes it as any ready job no host holds, and prints it */
    T_OK(store_job_take(b, "b", tb, id, &fence, &err), &err);
    struct job_event_args st = { .printer = "pb", .fence = fence };
    T_OK(store_job_event(b, id, JOB_EV_START, &st, NULL, &err), &err);
    db_text(url, "SELECT state || ' on ' || printer FROM jobs WHERE id = ?1", id, text,
            sizeof(text));
    T_EQ_STR(text, "printing on pb");
    host_farm_free();
    store_close(b);
}

/* A printer with an empty profile (farm.ini takes `profile:` empty) is owned and scheduled: its
   publish failed the beat's own, so the host never learnt it owned its printers. */
T_CASE(host_with_a_printer_with_no_profile_owns_and_prints)
{
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    char dir[512], url[1024];
    struct store *a = host_a_open("noprofile", dir, sizeof(dir), url, sizeof(url),
                                  &err); /* the schema, the job */
    T_TRUE(a != NULL);
    int64_t id;
    T_OK(add_ready_for(a, "p", &id, &err), &err);
    T_OK(host_farm(dir, url, "b",
                   "[printer p]\ndriver: marlin\nport: pty:/dev/null\nprofile:\ngcode_models: *\n",
                   &err),
         &err);
    bool printing = wait_state(url, id, "printing");
    if (!printing)
        fprintf(stderr, "host b logged:\n%s\n", logged);
    T_TRUE(printing);
    T_TRUE(!was_logged("publish"));
    host_farm_free();
    store_close(a);
}
