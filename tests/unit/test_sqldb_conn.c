/*
 * test_sqldb_conn.c - sqldb's PostgreSQL connection when the server or the
 * network goes away (sqldb.h: reconnect, transactions, LISTEN/NOTIFY),
 * against a real server: tests/integ/sqldb_conn.sh starts one with a
 * loopback port (lib/pg.sh), and names it and its tools in the environment:
 *   SQLDB_CONN_DB     a database's name on it, SQLDB_CONN_URL its Unix-socket URL
 *   SQLDB_CONN_PORT   the server's TCP port, reached through tests/tools/tcpproxy
 *                     (SQLDB_CONN_PROXY) to cut the network
 *   SQLDB_CONN_PGCTL  a command taking "stop -m fast" or "start" for the server
 *   SQLDB_CONN_OUTAGE_S  how long the server stays stopped (default 30)
 * Without them every case skips (the suite's plain run of this program).
 * Waits are for conditions with generous deadlines; the one bound asserted
 * on time is the one under test, that no call hangs (here: 3 x connect_timeout).
 */
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <spawn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "../../src/base/clock.h"
#include "../../src/farm/sqldb.h"
#include "../../src/farm/store.h"
#include "../../src/farm/store_host.h"
#include "../../src/farm/storeq.h"
#include "../t.h"
#include "../tproxy.h"

#define DEADLINE_MS 60000 /* a condition that must come: generous for a loaded machine */

/* expr must fail with code and a message holding substr. */
#define T_DB_ERR(expr, db, code, substr)                                                           \
    do {                                                                                           \
        int t_r_ = (expr);                                                                         \
        if (t_r_ != (code) || !strstr(sqldb_errmsg(db), (substr))) {                               \
            t_fail(__FILE__, __LINE__, "%s = %d (%s), not %d with \"%s\"", #expr, t_r_,            \
                   sqldb_errmsg(db), (code), (substr));                                            \
            return;                                                                                \
        }                                                                                          \
    } while (0)

/* expr must be SF_OK, else fail with db's message. */
#define T_DB_OK(expr, db) T_DB_ERR(expr, db, SF_OK, "")

static bool
have_server(void)
{
    return getenv("SQLDB_CONN_URL") && getenv("SQLDB_CONN_PORT") && getenv("SQLDB_CONN_DB") &&
           getenv("SQLDB_CONN_PROXY") && getenv("SQLDB_CONN_PGCTL");
}

static void
nap_ms(int ms)
{
    nanosleep(&(struct timespec){ .tv_sec = ms / 1000, .tv_nsec = (ms % 1000) * 1000000L }, NULL);
}

/* A proxy to the test server's port (tproxy.h). */
static bool
conn_proxy(struct proxy *p)
{
    return proxy_start(p, getenv("SQLDB_CONN_PROXY"), getenv("SQLDB_CONN_PORT"));
}

/* The test database through the proxy. */
static const char *
proxy_url(const struct proxy *p)
{
    static char url[256];
    snprintf(url, sizeof(url), "postgresql://postgres@127.0.0.1:%d/%s", p->port,
             getenv("SQLDB_CONN_DB"));
    return url;
}

static struct sqldb *
open_url(const char *url)
{
    struct sf_err err;
    struct sqldb *db = sqldb_open(url, 0, &err);
    if (!db)
        fprintf(stderr, "open %s: %s\n", url, err.msg);
    return db;
}

/* A proxy, a connection through it and one direct; false if any fails. */
static bool
cut_setup(struct proxy *px, struct sqldb **via, struct sqldb **direct)
{
    if (!conn_proxy(px))
        return false;
    *via = open_url(proxy_url(px));
    *direct = open_url(getenv("SQLDB_CONN_URL"));
    return *via && *direct;
}

/* Run sql with one integer parameter; SF_OK or the failure. */
static int
run1(struct sqldb *db, const char *sql, int64_t v)
{
    struct sqldb_stmt *st;
    int rc = sqldb_prepare(db, sql, &st);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, v);
    rc = sqldb_step(st);
    sqldb_finalize(st);
    return rc < 0 ? rc : SF_OK;
}

/* The first column of sql's first row; -1 on failure. */
static int64_t
one(struct sqldb *db, const char *sql)
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

static int
pgctl(const char *args)
{
    char cmd[1024];
    snprintf(cmd, sizeof(cmd), "%s %s > /dev/null", getenv("SQLDB_CONN_PGCTL"), args);
    return system(cmd);
}

/* (a) The server stops for ~30 s while a writer keeps calling. */
T_CASE(sqldb_pg_survives_a_server_restart)
{
    T_SKIP_UNLESS(have_server(), "no server (tests/integ/sqldb_conn.sh runs this)");
    const char *o = getenv("SQLDB_CONN_OUTAGE_S");
    int64_t outage_ms = (o ? strtol(o, NULL, 10) : 30) * 1000;
    struct sqldb *db = open_url(getenv("SQLDB_CONN_URL"));
    T_TRUE(db != NULL);
    T_DB_OK(sqldb_exec(db, "CREATE TABLE rows_a(k BIGINT PRIMARY KEY)"), db);
    const char *ins = "INSERT INTO rows_a(k) VALUES(?)";
    int64_t k = 0, ok[4096];
    int n_ok = 0;
    while (n_ok < 20) {
        T_DB_OK(run1(db, ins, ++k), db);
        ok[n_ok++] = k;
    }
    T_EQ_INT(pgctl("stop -m fast"), 0);
    int64_t t_stop = clock_mono_ms(), worst_ms = 0;
    int n_fail = 0, n_fast = 0;
    while (clock_mono_ms() - t_stop < outage_ms) {
        int64_t t0 = clock_mono_ms();
        int rc = run1(db, ins, ++k);
        int64_t dt = clock_mono_ms() - t0;
        worst_ms = dt > worst_ms ? dt : worst_ms;
        /* the server is down: nothing can succeed, and nothing was applied (or, for the
           insert that met the loss, nobody knows) */
        n_fail += rc == SF_EUNREACH || rc == SF_EINDOUBT;
        n_fast += strstr(sqldb_errmsg(db), "database unreachable (retrying): ") != NULL;
        if (!strstr(sqldb_errmsg(db), "unreachable") && !strstr(sqldb_errmsg(db), "lost"))
            printf("# unclear failure: %s\n", sqldb_errmsg(db));
        nap_ms(20);
    }
    int n_calls = (int)(k - ok[n_ok - 1]);
    T_EQ_INT(pgctl("start"), 0); /* first, so the cases after this one have their server */
    int64_t t_up = clock_mono_ms();
    printf("# %d calls failed while the server was down, %d at once (back-off), the longest "
           "%lld ms\n",
           n_fail, n_fast, (long long)worst_ms);
    T_EQ_INT(n_fail, n_calls);
    T_EQ_INT(n_fast, n_calls); /* each with the clear message */
    T_TRUE(worst_ms < 15000);  /* one attempt waits at most connect_timeout, 5 s */
    int rc;
    while ((rc = run1(db, ins, ++k)) != SF_OK && clock_mono_ms() - t_up < DEADLINE_MS)
        nap_ms(10);
    T_DB_OK(rc, db); /* the same handle works again */
    printf("# the first call succeeded %lld ms after the server was back\n",
           (long long)(clock_mono_ms() - t_up));
    ok[n_ok++] = k;
    for (int i = 0; i < 5; i++) {
        T_DB_OK(run1(db, ins, ++k), db);
        ok[n_ok++] = k;
    }
    T_EQ_INT(sqldb_reconnects(db), 1);
    /* no committed row lost; none of the failed calls wrote one */
    T_EQ_INT(one(db, "SELECT count(*) FROM rows_a"), n_ok);
    struct sqldb_stmt *st;
    T_DB_OK(sqldb_prepare(db, "SELECT k FROM rows_a ORDER BY k", &st), db);
    for (int i = 0; i < n_ok && sqldb_step(st) == SQLDB_ROW; i++)
        T_EQ_INT(sqldb_column_int64(st, 0), ok[i]);
    sqldb_finalize(st);
    sqldb_close(db);
}

static int n_hook;

/* A reconnect hook that uses the new session, as the store's lock re-take does. */
static int
hook(struct sqldb *db, void *arg, struct sf_err *err)
{
    (void)arg;
    n_hook++;
    return one(db, "SELECT 7") == 7 ? SF_OK : sf_err_set(err, SF_EIO, "hook: no answer");
}

/* (b) The network parts in the middle of a transaction. */
T_CASE(sqldb_pg_cut_fails_the_whole_transaction)
{
    T_SKIP_UNLESS(have_server(), "no server (tests/integ/sqldb_conn.sh runs this)");
    struct proxy px;
    struct sqldb *db, *direct;
    T_TRUE(cut_setup(&px, &db, &direct));
    sqldb_on_reconnect(db, hook, NULL);
    T_DB_OK(sqldb_exec(direct, "CREATE TABLE rows_b(k BIGINT PRIMARY KEY)"), direct);
    const char *ins = "INSERT INTO rows_b(k) VALUES(?)";
    T_DB_OK(sqldb_begin(db), db);
    T_DB_OK(run1(db, ins, 1), db);
    T_DB_OK(run1(db, ins, 2), db);
    T_TRUE(proxy_cmd(&px, "drop"));
    T_DB_ERR(run1(db, ins, 3), db, SF_EUNREACH, "connection lost");
    T_TRUE(proxy_cmd(&px, "heal"));
    /* the network is back, but this transaction is gone: nothing runs in its name */
    T_DB_ERR(run1(db, ins, 4), db, SF_EUNREACH, "connection lost in a transaction");
    T_DB_ERR(sqldb_commit(db), db, SF_EUNREACH, "connection lost in a transaction");
    T_EQ_INT(one(direct, "SELECT count(*) FROM rows_b"), 0);
    T_EQ_INT(n_hook, 0);
    /* outside a transaction the next call connects again */
    T_DB_OK(run1(db, ins, 5), db);
    T_EQ_INT(sqldb_reconnects(db), 1);
    T_EQ_INT(n_hook, 1);
    T_EQ_INT(one(direct, "SELECT count(*) FROM rows_b WHERE k = 5"), 1);
    /* a refused reconnect: the call that finds the loss fails (the end of the connection
       seen before sending, then the reconnect refused: "unreachable"; or, were the end to
       come late, sending: "lost"), the next ones fail at once (back-off), and after the
       heal a call gets through */
    T_TRUE(proxy_cmd(&px, "drop"));
    int rc6 = run1(db, ins, 6);
    T_TRUE(rc6 == SF_EUNREACH || rc6 == SF_EINDOUBT);
    T_TRUE(strstr(sqldb_errmsg(db), "unreachable") || strstr(sqldb_errmsg(db), "lost"));
    T_DB_ERR(run1(db, ins, 7), db, SF_EUNREACH, "database unreachable (retrying): ");
    T_DB_ERR(run1(db, ins, 8), db, SF_EUNREACH, "database unreachable (retrying): ");
    T_TRUE(proxy_cmd(&px, "heal"));
    int64_t t0 = clock_mono_ms();
    int rc;
    while ((rc = run1(db, ins, 9)) != SF_OK && clock_mono_ms() - t0 < DEADLINE_MS)
        nap_ms(20);
    T_DB_OK(rc, db);
    T_EQ_INT(sqldb_reconnects(db), 2);
    T_EQ_INT(one(direct, "SELECT count(*) FROM rows_b"), 2); /* 5 and 9 */
    sqldb_close(db);
    sqldb_close(direct);
    proxy_stop(&px);
}

struct got {
    int n;
    char last[64];
};

static void
on_note(void *arg, const char *channel, const char *payload)
{
    struct got *g = arg;
    if (strcmp(channel, "jobs") == 0) {
        g->n++;
        snprintf(g->last, sizeof(g->last), "%s", payload);
    }
}

/* Wait until db's notification fd is readable and drain it, until g's last payload is want. */
static bool
await_note(struct sqldb *db, struct got *g, const char *want)
{
    int64_t t0 = clock_mono_ms();
    while (strcmp(g->last, want) != 0 && clock_mono_ms() - t0 < DEADLINE_MS) {
        struct pollfd pfd = { .fd = sqldb_notify_fd(db), .events = POLLIN };
        if (poll(&pfd, 1, 1000) > 0 && sqldb_notifications(db, on_note, g) < 0)
            return false;
    }
    return strcmp(g->last, want) == 0;
}

/* (c) LISTEN on one connection, NOTIFY from another; a cut and a heal keep the LISTEN. */
T_CASE(sqldb_pg_listen_survives_a_cut)
{
    T_SKIP_UNLESS(have_server(), "no server (tests/integ/sqldb_conn.sh runs this)");
    struct proxy px;
    struct sqldb *l, *n;
    T_TRUE(cut_setup(&px, &l, &n));
    T_DB_OK(sqldb_listen(l, "jobs"), l);
    struct got g = { 0 };
    T_DB_OK(sqldb_notify(n, "jobs", "queued 1"), n);
    T_TRUE(await_note(l, &g, "queued 1"));
    T_TRUE(proxy_cmd(&px, "drop"));
    /* the fd reads the end of the connection; draining finds it lost, and the proxy
       refuses the reconnect */
    struct pollfd pfd = { .fd = sqldb_notify_fd(l), .events = POLLIN };
    T_TRUE(poll(&pfd, 1, DEADLINE_MS) == 1);
    T_DB_ERR(sqldb_notifications(l, on_note, &g), l, SF_EUNREACH, "unreachable");
    T_EQ_INT(sqldb_notify_fd(l), -1);
    T_TRUE(proxy_cmd(&px, "heal"));
    int64_t t0 = clock_mono_ms();
    int rc;
    while ((rc = sqldb_notifications(l, on_note, &g)) < 0 && clock_mono_ms() - t0 < DEADLINE_MS)
        nap_ms(20);
    T_TRUE(rc >= 0);
    T_EQ_INT(sqldb_reconnects(l), 1);
    T_TRUE(sqldb_notify_fd(l) >= 0);
    T_DB_OK(sqldb_notify(n, "jobs", "queued 2"), n);
    T_TRUE(await_note(l, &g, "queued 2")); /* the LISTEN was issued again */
    T_EQ_INT(g.n, 2);
    sqldb_close(l);
    sqldb_close(n);
    proxy_stop(&px);
}

/* The first column of sql's first row as text, into out. */
static const char *
text1(struct sqldb *db, const char *sql, char *out, size_t cap)
{
    struct sqldb_stmt *st;
    snprintf(out, cap, "(failed)");
    if (sqldb_prepare(db, sql, &st) == SF_OK) {
        if (sqldb_step(st) == SQLDB_ROW)
            snprintf(out, cap, "%s", sqldb_column_text(st, 0));
        sqldb_finalize(st);
    }
    return out;
}

/* A silent network: a reconnect waits connect_timeout, no longer; the session comes back
   as it was (read-only, asynchronous commit). */
T_CASE(sqldb_pg_reconnect_is_bounded_and_keeps_the_session)
{
    T_SKIP_UNLESS(have_server(), "no server (tests/integ/sqldb_conn.sh runs this)");
    struct proxy px;
    T_TRUE(conn_proxy(&px));
    struct sf_err err;
    struct sqldb *db = sqldb_open(proxy_url(&px), SQLDB_READONLY, &err);
    T_OK(db ? SF_OK : err.code, &err);
    T_DB_OK(sqldb_set_durable(db, false), db);
    T_TRUE(proxy_cmd(&px, "blackhole"));
    int64_t t0 = clock_mono_ms();
    T_DB_ERR(sqldb_exec(db, "SELECT 1"), db, SF_EUNREACH, "database unreachable (retrying): ");
    int64_t took_ms = clock_mono_ms() - t0;
    printf("# a reconnect into a silent network gave up after %lld ms: %s\n", (long long)took_ms,
           sqldb_errmsg(db));
    T_TRUE(strstr(sqldb_errmsg(db), "timeout") != NULL);
    T_TRUE(took_ms < 15000); /* connect_timeout is 5 s */
    T_TRUE(proxy_cmd(&px, "heal"));
    t0 = clock_mono_ms();
    int rc;
    while ((rc = sqldb_exec(db, "SELECT 1")) != SF_OK && clock_mono_ms() - t0 < DEADLINE_MS)
        nap_ms(20);
    T_DB_OK(rc, db);
    char v[64];
    T_EQ_STR(text1(db, "SHOW synchronous_commit", v, sizeof(v)), "off");
    T_EQ_STR(text1(db, "SHOW default_transaction_read_only", v, sizeof(v)), "on");
    /* the server's keepalives are the session's too (an orphaned backend ends) */
    T_EQ_STR(text1(db, "SHOW tcp_keepalives_idle", v, sizeof(v)), "10");
    T_EQ_STR(text1(db, "SHOW tcp_user_timeout", v, sizeof(v)), "10000");
    T_DB_ERR(sqldb_exec(db, "CREATE TABLE t_ro(k INTEGER)"), db, SF_EIO, "read-only");
    sqldb_close(db);
    proxy_stop(&px);
}

/* The store's reconnect hook takes its database lock again (store.c relock). */
T_CASE(sqldb_pg_store_holds_its_lock_after_a_cut)
{
    T_SKIP_UNLESS(have_server(), "no server (tests/integ/sqldb_conn.sh runs this)");
    struct proxy px;
    T_TRUE(conn_proxy(&px));
    struct sqldb *direct = open_url(getenv("SQLDB_CONN_URL"));
    T_TRUE(direct != NULL);
    char dir[512], dir2[512];
    snprintf(dir, sizeof(dir), "%s/store", t_tmpdir());
    snprintf(dir2, sizeof(dir2), "%s/store2", t_tmpdir());
    struct sf_err err;
    struct store *s = store_open_db(dir, proxy_url(&px), NULL, &err);
    T_OK(s ? SF_OK : err.code, &err);
    const char *held = "SELECT count(*) FROM pg_locks WHERE locktype = 'advisory' AND granted";
    T_EQ_INT(one(direct, held), 1);
    T_TRUE(proxy_cmd(&px, "drop"));
    T_TRUE(proxy_cmd(&px, "heal"));
    /* the server ends the cut session, and its lock, once it sees the end */
    int64_t t0 = clock_mono_ms();
    while (one(direct, held) != 0 && clock_mono_ms() - t0 < DEADLINE_MS)
        nap_ms(20);
    T_EQ_INT(one(direct, held), 0);
    /* a store call fails (the call that finds the loss), the next reconnects and relocks */
    t0 = clock_mono_ms();
    int rc;
    while ((rc = store_printer_set(s, "p1", PRINTER_IDLE, &err)) != SF_OK &&
           clock_mono_ms() - t0 < DEADLINE_MS)
        nap_ms(20);
    T_OK(rc, &err);
    T_EQ_INT(one(direct, held), 1);
    struct store *s2 = store_open_db(dir2, getenv("SQLDB_CONN_URL"), NULL, &err);
    T_TRUE(s2 == NULL);
    T_TRUE(strstr(err.msg, "in use by another slimfarmd") != NULL);
    store_close(s);
    sqldb_close(direct);
    proxy_stop(&px);
}

/* The loop's connection (SQLDB_NOWAIT) in a silent network: no call waits for a connect.
   A blocking reconnect (PQreset) takes connect_timeout (5 s) a call here, so the calls made
   in 7 s count them: a handful at most with it, hundreds without. */
T_CASE(sqldb_pg_nowait_reconnect_never_waits_on_connect)
{
    T_SKIP_UNLESS(have_server(), "no server (tests/integ/sqldb_conn.sh runs this)");
    struct proxy px;
    T_TRUE(conn_proxy(&px));
    struct sf_err err;
    struct sqldb *db = sqldb_open(proxy_url(&px), SQLDB_NOWAIT, &err);
    T_OK(db ? SF_OK : err.code, &err);
    T_DB_OK(sqldb_set_durable(db, false), db);
    T_TRUE(proxy_cmd(&px, "blackhole"));
    int n_calls = 0, n_connecting = 0;
    int64_t t0 = clock_mono_ms(), worst_ms = 0;
    while (clock_mono_ms() - t0 < 7000) {
        int64_t t1 = clock_mono_ms();
        T_DB_ERR(sqldb_exec(db, "SELECT 1"), db, SF_EUNREACH, "database unreachable (retrying): ");
        int64_t dt = clock_mono_ms() - t1;
        worst_ms = dt > worst_ms ? dt : worst_ms;
        n_calls++;
        n_connecting += strstr(sqldb_errmsg(db), "connecting") != NULL;
        nap_ms(10);
    }
    printf("# %d calls in a silent network for 7 s, %d while a connect was under way; the "
           "longest %lld ms\n",
           n_calls, n_connecting, (long long)worst_ms);
    T_TRUE(n_calls >= 20);
    T_TRUE(n_connecting >= 10);
    T_TRUE(worst_ms < 2000); /* generous: a call never waits on the connect (5 s) */
    T_TRUE(proxy_cmd(&px, "heal"));
    t0 = clock_mono_ms();
    int rc;
    while ((rc = sqldb_exec(db, "SELECT 1")) != SF_OK && clock_mono_ms() - t0 < DEADLINE_MS)
        nap_ms(20);
    T_DB_OK(rc, db);
    T_EQ_INT(sqldb_reconnects(db), 1);
    char v[64];
    T_EQ_STR(text1(db, "SHOW synchronous_commit", v, sizeof(v)), "off");
    sqldb_close(db);
    proxy_stop(&px);
}

/* A COMMIT sent on another thread (it waits on the server). */
struct committer {
    struct sqldb *db;
    int rc;
};

static void *
commit_bg(void *arg)
{
    struct committer *c = arg;
    c->rc = sqldb_commit(c->db);
    return NULL;
}

/* Wait until sql's count on db is at least 1. */
static bool
await_count(struct sqldb *db, const char *sql)
{
    for (int64_t t0 = clock_mono_ms(); clock_mono_ms() - t0 < DEADLINE_MS; nap_ms(20))
        if (one(db, sql) > 0)
            return true;
    return false;
}

/* A COMMIT whose answer the network lost: SF_EINDOUBT, then read back.  Its transaction
   waits at COMMIT on another's (a deferred unique key both inserted), so the cut lands
   while the server holds it; the read-back ends the lost session, whose transaction is
   then rolled back: "not committed", and no row. */
T_CASE(sqldb_pg_commit_in_doubt_is_read_back)
{
    T_SKIP_UNLESS(have_server(), "no server (tests/integ/sqldb_conn.sh runs this)");
    struct proxy px;
    struct sqldb *db, *direct;
    T_TRUE(cut_setup(&px, &db, &direct));
    struct sqldb *other = open_url(getenv("SQLDB_CONN_URL"));
    T_TRUE(other != NULL);
    T_DB_OK(sqldb_exec(direct, "CREATE TABLE rows_d(k BIGINT UNIQUE DEFERRABLE INITIALLY"
                               " DEFERRED)"),
            direct);
    T_EQ_INT(sqldb_commit_outcome(db), 0); /* nothing in doubt */
    T_DB_OK(sqldb_begin(other), other);
    T_DB_OK(run1(other, "INSERT INTO rows_d(k) VALUES(?)", 1), other);
    T_DB_OK(sqldb_begin(db), db);
    T_DB_OK(run1(db, "INSERT INTO rows_d(k) VALUES(?)", 1), db);
    struct committer c = { db, 0 };
    pthread_t t;
    T_EQ_INT(pthread_create(&t, NULL, commit_bg, &c), 0);
    /* its COMMIT checks the key and waits for other's transaction */
    T_TRUE(await_count(direct, "SELECT count(*) FROM pg_locks WHERE NOT granted AND"
                               " locktype = 'transactionid'"));
    T_TRUE(proxy_cmd(&px, "drop"));
    pthread_join(t, NULL);
    T_EQ_INT(c.rc, SF_EINDOUBT);
    T_TRUE(strstr(sqldb_errmsg(db), "outcome is unknown") != NULL);
    /* unknown while the network is away */
    T_EQ_INT(sqldb_commit_outcome(db), SF_EINDOUBT);
    T_TRUE(proxy_cmd(&px, "heal"));
    int o;
    int64_t t0 = clock_mono_ms();
    while ((o = sqldb_commit_outcome(db)) < 0 && clock_mono_ms() - t0 < DEADLINE_MS)
        nap_ms(20);
    T_EQ_INT(o, 0); /* its session ended (by the read-back), its transaction rolled back */
    sqldb_rollback(other);
    T_EQ_INT(one(direct, "SELECT count(*) FROM rows_d"), 0);
    T_EQ_INT(sqldb_commit_outcome(db), 0); /* settled */
    sqldb_close(other);
    sqldb_close(db);
    sqldb_close(direct);
    proxy_stop(&px);
}

struct started {
    int calls, rc;
    enum job_state to;
};

static void
on_started(void *ud, const struct storeq_result *r)
{
    struct started *s = ud;
    s->calls++;
    s->rc = r->rc;
    s->to = r->to;
}

/* A START whose COMMIT's answer is lost is read back, not run again (where its own first
   write would refuse it: "job is printing").  The COMMIT is held on the server by a
   synchronous standby that does not exist (committed locally, not yet visible), the cut
   made there; the read-back ends the lost session, which then commits. */
T_CASE(storeq_start_in_doubt_is_read_back_not_refused)
{
    T_SKIP_UNLESS(have_server(), "no server (tests/integ/sqldb_conn.sh runs this)");
    struct proxy px;
    T_TRUE(conn_proxy(&px));
    struct sqldb *direct = open_url(getenv("SQLDB_CONN_URL"));
    T_TRUE(direct != NULL);
    char dir[512];
    snprintf(dir, sizeof(dir), "%s/started", t_tmpdir());
    struct sf_err err;
    struct loop *l = loop_new(&err);
    T_TRUE(l != NULL);
    struct store *s = store_open_db(dir, proxy_url(&px), NULL, &err);
    T_OK(s ? SF_OK : err.code, &err);
    struct storeq *q = storeq_new(l, s, &err);
    T_OK(q ? SF_OK : err.code, &err);
    char sha[STORE_SHA_HEX];
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "part.gcode");
    struct job_event_args g = { .prep_key = "k", .gcode_lines = 2 };
    int64_t id;
    T_OK(store_file_put(s, "G28\nG1 X1\n", 10, sha, &err), &err);
    T_OK(store_job_add_gcode(s, &o, sha, &g, &id, &err), &err);
    T_DB_OK(sqldb_exec(direct, "ALTER SYSTEM SET synchronous_standby_names = 'nobody'"), direct);
    T_EQ_INT(one(direct, "SELECT count(*) FROM (SELECT pg_reload_conf()) r"), 1);
    T_TRUE(await_count(direct, "SELECT count(*) FROM pg_settings WHERE"
                               " name = 'synchronous_standby_names' AND setting = 'nobody'"));
    struct started st = { 0 };
    struct job_event_args sa = { .printer = "mk3" };
    T_OK(storeq_job_event(q, id, JOB_EV_START, &sa, "mk3", on_started, &st), NULL);
    T_TRUE(await_count(direct, "SELECT count(*) FROM pg_stat_activity WHERE"
                               " wait_event = 'SyncRep'"));
    T_TRUE(proxy_cmd(&px, "drop"));
    T_TRUE(proxy_cmd(&px, "heal"));
    for (int64_t t0 = clock_mono_ms(); !st.calls && clock_mono_ms() - t0 < DEADLINE_MS;)
        loop_run_once(l, 20);
    T_DB_OK(sqldb_exec(direct, "ALTER SYSTEM RESET synchronous_standby_names"), direct);
    T_EQ_INT(one(direct, "SELECT count(*) FROM (SELECT pg_reload_conf()) r"), 1);
    T_EQ_INT(st.calls, 1);
    T_EQ_INT(st.rc, SF_OK);
    T_EQ_INT(st.to, JOB_PRINTING);
    struct storeq_stats qs;
    storeq_stats(q, &qs);
    T_EQ_INT(qs.failed, 0);
    storeq_free(q);
    int rc;
    struct job_row j;
    for (int64_t t0 = clock_mono_ms();
         (rc = store_job_get(s, id, &j, &err)) != SF_OK && clock_mono_ms() - t0 < DEADLINE_MS;)
        nap_ms(20);
    T_OK(rc, &err);
    T_EQ_INT(j.state, JOB_PRINTING);
    T_EQ_STR(j.printer, "mk3");
    store_close(s);
    loop_free(l);
    sqldb_close(direct);
    proxy_stop(&px);
}

/* Cut host store s's connection through px and let it through again, then beat host name's
   lease (token) until a beat succeeds or DEADLINE_MS pass: the last beat's status, or SF_EIO
   if the proxy did not cut or heal. */
static int
beat_after_a_cut(struct proxy *px, struct store *s, const char *name, int64_t token,
                 struct sf_err *err)
{
    if (!proxy_cmd(px, "drop") || !proxy_cmd(px, "heal"))
        return sf_err_set(err, SF_EIO, "the proxy did not cut and heal the connection");
    int rc;
    for (int64_t t0 = clock_mono_ms();
         (rc = store_host_beat(s, name, token, 600 * 1000, err)) != SF_OK &&
         clock_mono_ms() - t0 < DEADLINE_MS;)
        nap_ms(20);
    return rc;
}

/* A host's name is its connection's lock: after a cut the reconnect takes it again, so a
   second process cannot join under the name once the lease is gone. */
T_CASE(sqldb_pg_host_name_lock_is_taken_again_after_a_cut)
{
    T_SKIP_UNLESS(have_server(), "no server (tests/integ/sqldb_conn.sh runs this)");
    struct proxy px;
    T_TRUE(conn_proxy(&px));
    struct sqldb *direct = open_url(getenv("SQLDB_CONN_URL"));
    T_TRUE(direct != NULL);
    char dir[512], dir2[512];
    snprintf(dir, sizeof(dir), "%s/hosta", t_tmpdir());
    snprintf(dir2, sizeof(dir2), "%s/hostb", t_tmpdir());
    struct sf_err err;
    struct store *s = store_open_host(dir, proxy_url(&px), NULL, &err);
    T_OK(s ? SF_OK : err.code, &err);
    int64_t token, t2;
    T_OK(store_host_join(s, "h1", 600 * 1000, &token, &err), &err);
    T_OK(beat_after_a_cut(&px, s, "h1", token, &err), &err);
    /* the lease gone, only the lock holds the name */
    T_DB_OK(sqldb_exec(direct, "UPDATE hosts SET lease_until_ms = 1"), direct);
    struct store *s2 = store_open_host(dir2, getenv("SQLDB_CONN_URL"), NULL, &err);
    T_OK(s2 ? SF_OK : err.code, &err);
    T_ERR(store_host_join(s2, "h1", 600 * 1000, &t2, &err), SF_EAGAIN, &err,
          "its connection holds the name");
    store_close(s2);
    store_close(s);
    sqldb_close(direct);
    proxy_stop(&px);
}

/* The same on a writer (store_open_writer): the connection a host's beat thread joins on
   (farm_host.c) takes its name again after a cut, as the loop's connection does. */
T_CASE(sqldb_pg_host_name_lock_on_a_writer_is_taken_again_after_a_cut)
{
    T_SKIP_UNLESS(have_server(), "no server (tests/integ/sqldb_conn.sh runs this)");
    struct proxy px;
    T_TRUE(conn_proxy(&px));
    struct sqldb *direct = open_url(getenv("SQLDB_CONN_URL"));
    T_TRUE(direct != NULL);
    char dir[512], dir2[512];
    snprintf(dir, sizeof(dir), "%s/hostw", t_tmpdir());
    snprintf(dir2, sizeof(dir2), "%s/hostw2", t_tmpdir());
    struct sf_err err;
    struct store *s = store_open_host(dir, proxy_url(&px), NULL, &err);
    T_OK(s ? SF_OK : err.code, &err);
    struct store *w = store_open_writer(s, &err);
    T_OK(w ? SF_OK : err.code, &err);
    int64_t token, t2;
    T_OK(store_host_join(w, "h2", 600 * 1000, &token, &err), &err);
    T_OK(beat_after_a_cut(&px, w, "h2", token, &err), &err);
    T_DB_OK(sqldb_exec(direct, "UPDATE hosts SET lease_until_ms = 1 WHERE name = 'h2'"), direct);
    struct store *s2 = store_open_host(dir2, getenv("SQLDB_CONN_URL"), NULL, &err);
    T_OK(s2 ? SF_OK : err.code, &err);
    T_ERR(store_host_join(s2, "h2", 600 * 1000, &t2, &err), SF_EAGAIN, &err,
          "its connection holds the name");
    store_close(s2);
    store_close(w);
    store_close(s);
    sqldb_close(direct);
    proxy_stop(&px);
}

/* A job add on the store thread, as the API posts one (storeq_call). */
struct adder {
    const char *sha;
    int64_t id; /* the new job's, as store_job_add gives it */
    int runs;
};

static int
add_fn(struct store *s, void *arg, struct sf_err *err)
{
    struct adder *a = arg;
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "doubt.stl");
    a->runs++;
    return store_job_add(s, &o, a->sha, &a->id, err);
}

/* A job add whose COMMIT's answer is lost, read back as committed, gives the job's id: it
   was 0 (set only after a COMMIT that answered), so the caller lost the job it had added
   (or, run again, would add it twice).  The COMMIT held on the server as above. */
T_CASE(storeq_job_add_in_doubt_keeps_its_id)
{
    T_SKIP_UNLESS(have_server(), "no server (tests/integ/sqldb_conn.sh runs this)");
    struct proxy px;
    T_TRUE(conn_proxy(&px));
    struct sqldb *direct = open_url(getenv("SQLDB_CONN_URL"));
    T_TRUE(direct != NULL);
    char dir[512];
    snprintf(dir, sizeof(dir), "%s/added", t_tmpdir());
    struct sf_err err;
    struct loop *l = loop_new(&err);
    T_TRUE(l != NULL);
    struct store *s = store_open_db(dir, proxy_url(&px), NULL, &err);
    T_OK(s ? SF_OK : err.code, &err);
    struct storeq *q = storeq_new(l, s, &err);
    T_OK(q ? SF_OK : err.code, &err);
    char sha[STORE_SHA_HEX];
    T_OK(store_file_put(s, "solid doubt", 11, sha, &err), &err);
    T_DB_OK(sqldb_exec(direct, "ALTER SYSTEM SET synchronous_standby_names = 'nobody'"), direct);
    T_EQ_INT(one(direct, "SELECT count(*) FROM (SELECT pg_reload_conf()) r"), 1);
    T_TRUE(await_count(direct, "SELECT count(*) FROM pg_settings WHERE"
                               " name = 'synchronous_standby_names' AND setting = 'nobody'"));
    struct started st = { 0 };
    struct adder a = { .sha = sha };
    T_OK(storeq_call(q, add_fn, &a, NULL, on_started, &st), NULL);
    T_TRUE(await_count(direct, "SELECT count(*) FROM pg_stat_activity WHERE"
                               " wait_event = 'SyncRep'"));
    T_TRUE(proxy_cmd(&px, "drop"));
    T_TRUE(proxy_cmd(&px, "heal"));
    for (int64_t t0 = clock_mono_ms(); !st.calls && clock_mono_ms() - t0 < DEADLINE_MS;)
        loop_run_once(l, 20);
    T_DB_OK(sqldb_exec(direct, "ALTER SYSTEM RESET synchronous_standby_names"), direct);
    T_EQ_INT(one(direct, "SELECT count(*) FROM (SELECT pg_reload_conf()) r"), 1);
    T_EQ_INT(st.calls, 1);
    T_EQ_INT(st.rc, SF_OK);
    T_EQ_INT(a.runs, 1); /* read back, not run again */
    storeq_free(q);
    struct job_row j;
    int rc;
    for (int64_t t0 = clock_mono_ms(); (rc = store_job_get(s, a.id, &j, &err)) == SF_EUNREACH &&
                                       clock_mono_ms() - t0 < DEADLINE_MS;)
        nap_ms(20);
    T_OK(rc, &err); /* the id names the job added */
    T_EQ_STR(j.opts.name, "doubt.stl");
    T_EQ_INT(one(direct, "SELECT count(*) FROM jobs WHERE name = 'doubt.stl'"), 1); /* once */
    store_close(s);
    loop_free(l);
    sqldb_close(direct);
    proxy_stop(&px);
}

/* The event log's lock (store_event.c: every transaction that logs an event takes it). */
#define EVENT_LOCK_KEY 0x736c696d6576656eLL

/* A host cut off from the database while it holds the event log's lock holds up no one for
   long: the partition answers nothing but closes nothing (the proxy's freeze), the server
   ends the session once its transaction has idled past idle_in_transaction_session_timeout,
   and another writer, failing busy on lock_timeout meanwhile, takes the lock.  It was held
   for as long as the partition lasted (the proxy's socket answers the server's keepalives). */
T_CASE(sqldb_pg_partitioned_event_lock_is_cut_by_the_server)
{
    T_SKIP_UNLESS(have_server(), "no server (tests/integ/sqldb_conn.sh runs this)");
    struct proxy px;
    T_TRUE(conn_proxy(&px));
    struct sf_err err;
    struct sqldb *held = sqldb_open(proxy_url(&px), 0, &err);
    T_OK(held ? SF_OK : err.code, &err);
    struct sqldb *other = open_url(getenv("SQLDB_CONN_URL"));
    T_TRUE(other != NULL);
    char v[64];
    T_EQ_STR(text1(other, "SHOW lock_timeout", v, sizeof(v)), "5s");
    T_EQ_STR(text1(other, "SHOW idle_in_transaction_session_timeout", v, sizeof(v)), "5s");
    /* a guard for a run without the server's cut: a wait ends, failing, after 20 s */
    T_DB_OK(sqldb_exec(other, "SET statement_timeout = 20000"), other);
    int64_t pid = one(held, "SELECT pg_backend_pid()");
    T_TRUE(pid > 0);
    T_DB_OK(sqldb_begin(held), held);
    T_DB_OK(run1(held, "SELECT pg_advisory_xact_lock(?)", EVENT_LOCK_KEY), held);
    T_TRUE(proxy_cmd(&px, "freeze"));
    int rc = SF_EBUSY, busy = 0;
    int64_t t0 = clock_mono_ms();
    while (rc == SF_EBUSY && clock_mono_ms() - t0 < DEADLINE_MS) {
        T_DB_OK(sqldb_begin(other), other);
        rc = run1(other, "SELECT pg_advisory_xact_lock(?)", EVENT_LOCK_KEY);
        busy += rc == SF_EBUSY && strstr(sqldb_errmsg(other), "lock timeout") != NULL;
        if (rc == SF_OK)
            rc = sqldb_commit(other);
        else
            sqldb_rollback(other);
    }
    printf("# a writer waited %lld ms for a partitioned holder of the event lock (%d lock "
           "timeouts)\n",
           (long long)(clock_mono_ms() - t0), busy);
    T_DB_OK(rc, other);
    /* the holder's session was ended by the server (its lock went with it; its entry goes
       as the process exits) */
    char sql[128];
    snprintf(sql, sizeof(sql),
             "SELECT CASE WHEN count(*) = 0 THEN 1 ELSE 0 END FROM pg_stat_activity"
             " WHERE pid = %lld",
             (long long)pid);
    T_TRUE(await_count(other, sql));
    T_TRUE(proxy_cmd(&px, "heal"));
    T_TRUE(sqldb_exec(held, "SELECT 1") != SF_OK); /* its transaction is gone, not resumed */
    sqldb_rollback(held);
    sqldb_close(held);
    sqldb_close(other);
    proxy_stop(&px);
}
