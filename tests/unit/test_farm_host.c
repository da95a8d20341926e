/*
 * test_farm_host.c - what a host's scheduler reads and claims on a shared
 * store (farm_host.h over store_host.h): a claim of one chosen queued job
 * is taken once (a second host, or the same job again, gets SF_ENOTFOUND);
 * a ready job no host holds is taken by one host only; each host's live
 * jobs leave out the other hosts' claims but keep a job on a printer it
 * owns; a reaped host's jobs come back for the others.  With
 * SLIMFARM_TEST_STORE (tstore.h) on PostgreSQL, the second host a store of
 * its own on the same database; on SQLite a second connection.
 */
#include <stdint.h>
#include <stdlib.h>

#include "../../src/base/clock.h"
#include "../../src/farm/farmcfg.h"
#include "../../src/farm/store_host.h"
#include "../t.h"
#include "../tstore.h"

#define LEASE_MS (600 * 1000)

struct pair {
    char dir[512], dir_b[512], url[1024];
    struct store *a, *b;
    int64_t ta, tb;
};

static bool
pair_open(struct pair *p, const char *name, struct sf_err *err)
{
    snprintf(p->dir, sizeof(p->dir), "%s/%s", t_tmpdir(), name);
    snprintf(p->dir_b, sizeof(p->dir_b), "%s-b", p->dir);
    const char *db = t_store_db(p->dir);
    snprintf(p->url, sizeof(p->url), "%s", db ? db : "");
    p->a = store_open_host(p->dir, db, NULL, err);
    p->b = !p->a ? NULL
           : db  ? store_open_host(p->dir_b, p->url, NULL, err)
                 : store_open_peer(p->a, err);
    return p->a && p->b && store_host_join(p->a, "a", LEASE_MS, &p->ta, err) == SF_OK &&
           store_host_join(p->b, "b", LEASE_MS, &p->tb, err) == SF_OK;
}

static void
pair_close(struct pair *p)
{
    store_close(p->b);
    store_close(p->a);
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
    struct pair p;
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
    pair_close(&p);
}

T_CASE(ready_job_no_host_holds_is_taken_by_one)
{
    struct sf_err err;
    struct pair p;
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
    pair_close(&p);
}

T_CASE(live_jobs_of_a_host_leave_out_the_others_claims)
{
    struct sf_err err;
    struct pair p;
    T_TRUE(pair_open(&p, "live", &err));
    const char *pa[] = { "pa" };
    T_OK(store_host_own(p.a, "a", p.ta, pa, 1, &err), &err);
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
    pair_close(&p);
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
