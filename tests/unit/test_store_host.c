/*
 * test_store_host.c - several hosts on one store (store_host.h): two
 * connections claiming 500 jobs from two threads at once never get the same
 * job and together get all; a host whose lease ran out is reaped (its
 * claims back in the queue, its printing job interrupted with the reason)
 * once however often the reap runs; a stale fencing token is refused at
 * START; a host name another process holds is refused with its lease's
 * age.  With SLIMFARM_TEST_STORE (tstore.h, tests/integ/store_pg.sh) every
 * case runs on PostgreSQL, the second host then a store of its own on the
 * same database; on SQLite it is a second connection of the same process
 * (store_open_peer), as the data dir's flock allows one process.
 */
#include <poll.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../../src/base/clock.h"
#include "../../src/farm/store_host.h"
#include "../t.h"
#include "../tstore.h"

#define LEASE_MS (600 * 1000) /* far above any stall of a loaded machine: no case waits on it */

static const char *
fresh_dir(const char *name)
{
    static char path[512];
    snprintf(path, sizeof(path), "%s/%s", t_tmpdir(), name);
    return path;
}

/* Two hosts' stores on one database (see the top comment), in a fresh dir. */
static bool
pair_open(struct t_pair *p, const char *name, struct sf_err *err)
{
    return t_pair_open(p, fresh_dir(name), err);
}

/* n queued jobs of one part, into ids (may be NULL). */
static int
add_jobs(struct store *s, int n, int64_t *ids, struct sf_err *err)
{
    char sha[STORE_SHA_HEX];
    int rc = store_file_put(s, "solid part\n", 11, sha, err);
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "part.stl");
    for (int i = 0; i < n && rc == SF_OK; i++) {
        int64_t id;
        rc = store_job_add(s, &o, sha, &id, err);
        if (ids)
            ids[i] = id;
    }
    return rc;
}

/* A job ready at once: G-code to print as it is (store_job_add_gcode), its id into *id. */
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

#define N_CLAIM 500

/* One claimer: claims until the queue is empty, keeping what it got. */
struct claimer {
    struct store *s;
    const char *host;
    int64_t token;
    int64_t ids[N_CLAIM];
    int n;
    int rc; /* SF_OK, or the first error */
    struct sf_err err;
};

static void *
claim_all(void *arg)
{
    struct claimer *c = arg;
    for (;;) {
        struct job_row j;
        int64_t fence;
        int rc = store_job_claim(c->s, c->host, c->token, NULL, &j, &fence, &c->err);
        if (rc == SF_ENOTFOUND)
            return NULL;
        /* SQLite: the other thread kept the one writer lock past the busy timeout (a loaded
           machine); the claim did nothing, so try again */
        if (rc == SF_EBUSY && strstr(c->err.msg, "database is locked"))
            continue;
        if (rc || c->n == N_CLAIM || j.state != JOB_PREPARING || fence < 1) {
            c->rc = rc ? rc : SF_EBUG;
            return NULL;
        }
        c->ids[c->n++] = j.id;
    }
}

static int
cmp_id(const void *a, const void *b)
{
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

T_CASE(hosts_claim_500_jobs_from_two_threads_never_twice)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "claims", &err));
    static struct claimer c[2];
    c[0] = (struct claimer){ .s = p.a, .host = "a" };
    c[1] = (struct claimer){ .s = p.b, .host = "b" };
    T_OK(store_host_join(p.a, "a", LEASE_MS, &c[0].token, &err), &err);
    T_OK(store_host_join(p.b, "b", LEASE_MS, &c[1].token, &err), &err);
    T_OK(add_jobs(p.a, N_CLAIM, NULL, &err), &err);
    pthread_t th[2];
    for (int i = 0; i < 2; i++)
        T_EQ_INT(pthread_create(&th[i], NULL, claim_all, &c[i]), 0);
    for (int i = 0; i < 2; i++)
        pthread_join(th[i], NULL);
    T_OK(c[0].rc, &c[0].err);
    T_OK(c[1].rc, &c[1].err);
    /* together all 500, none twice */
    T_EQ_INT(c[0].n + c[1].n, N_CLAIM);
    static int64_t all[N_CLAIM];
    memcpy(all, c[0].ids, sizeof(int64_t) * (size_t)c[0].n);
    memcpy(all + c[0].n, c[1].ids, sizeof(int64_t) * (size_t)c[1].n);
    qsort(all, N_CLAIM, sizeof(all[0]), cmp_id);
    for (int i = 1; i < N_CLAIM; i++)
        T_TRUE(all[i] != all[i - 1]);
    /* and the store says the same: each preparing, held by the host that got it */
    T_EQ_INT(t_store_int(p.dir, "SELECT count(*) FROM jobs WHERE state = 'preparing'"), N_CLAIM);
    char sql[160];
    snprintf(sql, sizeof(sql), "SELECT count(*) FROM jobs WHERE claimed_by = 'a'");
    T_EQ_INT(t_store_int(p.dir, sql), c[0].n);
    T_EQ_INT(t_store_int(p.dir, "SELECT count(*) FROM events WHERE kind = 'job-prepare'"), N_CLAIM);
    t_pair_close(&p);
}

/* The claim takes the scheduler's order and only the methods the host runs. */
T_CASE(hosts_claim_follows_queue_order_and_methods)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "claim-order", &err));
    int64_t ids[3], token, fence = 0;
    struct job_row j;
    T_OK(store_host_join(p.a, "a", LEASE_MS, &token, &err), &err);
    T_OK(add_jobs(p.a, 3, ids, &err), &err);
    T_OK(store_job_set_priority(p.a, ids[2], 5, &err), &err);
    T_OK(t_store_exec(p.dir, "UPDATE jobs SET method = 'slim' WHERE id IN (SELECT max(id) FROM "
                             "jobs)"),
         NULL);
    T_ERR(store_job_claim(p.a, "a", token, "orient,bogus", &j, &fence, &err), SF_EINVAL, &err,
          "'bogus' is not one of");
    /* the priority-5 job is slim: a host that only orients takes the first of the rest */
    T_OK(store_job_claim(p.a, "a", token, "orient", &j, &fence, &err), &err);
    T_EQ_INT(j.id, ids[0]);
    T_EQ_INT(fence, 1);
    T_OK(store_job_claim(p.a, "a", token, "none,slim", &j, &fence, &err), &err);
    T_EQ_INT(j.id, ids[2]);
    T_OK(store_job_claim(p.a, "a", token, NULL, &j, &fence, &err), &err);
    T_EQ_INT(j.id, ids[1]);
    T_EQ_INT(store_job_claim(p.a, "a", token, NULL, &j, &fence, &err), SF_ENOTFOUND);
    t_pair_close(&p);
}

T_CASE(hosts_expired_host_is_reaped_once)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "reap", &err));
    int64_t ids[3], ta, tb, fence;
    struct job_row j;
    /* a: lease 1 min, b: 10 min; the reap below runs "2 min later" (its now) */
    T_OK(store_host_join(p.a, "a", 60 * 1000, &ta, &err), &err);
    T_OK(store_host_join(p.b, "b", LEASE_MS, &tb, &err), &err);
    const char *mine[] = { "p1" };
    T_OK(store_host_own(p.a, "a", ta, mine, 1, NULL, &err), &err);
    const char *theirs[] = { "p1" };
    T_ERR(store_host_own(p.b, "b", tb, theirs, 1, NULL, &err), SF_EAGAIN, &err,
          "belongs to live host 'a'");
    /* asked per printer: a's stays a's, said so, and b owns the rest */
    const char *both[] = { "p1", "p9" };
    struct store_host_owned owned[2];
    T_OK(store_host_own(p.b, "b", tb, both, 2, owned, &err), &err);
    T_TRUE(!owned[0].owned && owned[1].owned);
    T_EQ_STR(owned[0].other, "a");
    T_EQ_INT(t_store_int(p.dir, "SELECT count(*) FROM host_printers WHERE host = 'a'"
                                " AND printer = 'p1'"),
             1);
    T_OK(add_jobs(p.a, 1, &ids[0], &err), &err);
    T_OK(add_jobs(p.a, 1, &ids[2], &err), &err);
    /* ids[0] is claimed (preparing) by a; ids[1] prints on a's p1; ids[2] waits unclaimed */
    T_OK(store_job_claim(p.a, "a", ta, NULL, &j, &fence, &err), &err);
    T_EQ_INT(j.id, ids[0]);
    T_OK(add_ready(p.a, &ids[1], &err), &err);
    T_OK(store_job_attach(p.a, "a", ta, ids[1], &fence, &err), &err);
    struct job_event_args start = { .printer = "p1", .fence = fence };
    T_OK(store_job_event(p.a, ids[1], JOB_EV_START, &start, NULL, &err), &err);
    int64_t later = clock_wall_ms() + 120 * 1000;
    struct store_recovery moved;
    T_EQ_INT(store_host_reap(p.b, later, &moved, &err), 1);
    T_EQ_INT(moved.requeued, 1);
    T_EQ_INT(moved.interrupted, 1);
    T_OK(store_job_get(p.b, ids[0], &j, &err), &err);
    T_EQ_INT(j.state, JOB_QUEUED);
    T_OK(store_job_get(p.b, ids[1], &j, &err), &err);
    T_EQ_INT(j.state, JOB_INTERRUPTED);
    T_EQ_STR(j.reason, "host a lost its lease");
    T_EQ_STR(j.printer, "p1");
    T_EQ_INT(t_store_int(p.dir, "SELECT count(*) FROM jobs WHERE claimed_by = 'a'"
                                " AND state != 'interrupted'"),
             0);
    T_EQ_INT(t_store_int(p.dir, "SELECT count(*) FROM events WHERE kind = 'job-crashed'"
                                " AND detail = 'printing -> interrupted: host a lost its lease'"),
             1);
    int64_t events = t_store_int(p.dir, "SELECT count(*) FROM events");
    /* again: nothing more to do, nothing logged */
    T_EQ_INT(store_host_reap(p.b, later + 1000, &moved, &err), 0);
    T_EQ_INT(moved.requeued + moved.interrupted, 0);
    T_EQ_INT(t_store_int(p.dir, "SELECT count(*) FROM events"), events);
    /* a's lease is lost: no beat, no claim; b takes the requeued job */
    T_ERR(store_host_beat(p.a, "a", ta, 60 * 1000, &err), SF_ESTALE, &err, "reaped");
    T_ERR(store_job_claim(p.a, "a", ta, NULL, &j, &fence, &err), SF_ESTALE, &err, "reaped");
    T_OK(store_job_claim(p.b, "b", tb, NULL, &j, &fence, &err), &err);
    T_EQ_INT(j.id, ids[0]);
    T_OK(store_check(p.b, &err), &err);
    t_pair_close(&p);
}

T_CASE(hosts_stale_fencing_token_refused_at_start)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "fence", &err));
    int64_t id, ta, tb, fa, fb;
    T_OK(store_host_join(p.a, "a", LEASE_MS, &ta, &err), &err);
    T_OK(store_host_join(p.b, "b", LEASE_MS, &tb, &err), &err);
    T_OK(add_ready(p.a, &id, &err), &err);
    T_ERR(store_job_attach(p.a, "a", ta + 1, id, &fa, &err), SF_ESTALE, &err, "another process");
    T_OK(store_job_attach(p.a, "a", ta, id, &fa, &err), &err);
    /* b takes the job over (a was cut off): a's token is stale from now on */
    T_OK(store_job_attach(p.b, "b", tb, id, &fb, &err), &err);
    T_TRUE(fb > fa);
    struct job_event_args start = { .printer = "net1", .fence = fa };
    T_ERR(store_job_event(p.a, id, JOB_EV_START, &start, NULL, &err), SF_ESTALE, &err,
          "host 'b' holds the job");
    struct job_row j;
    T_OK(store_job_get(p.a, id, &j, &err), &err);
    T_EQ_INT(j.state, JOB_READY);
    start.fence = fb;
    T_OK(store_job_event(p.b, id, JOB_EV_START, &start, NULL, &err), &err);
    T_OK(
        store_job_event(p.b, id, JOB_EV_PAUSE, &(struct job_event_args){ .fence = fb }, NULL, &err),
        &err);
    /* a comes back and would continue the print: refused, b's print stays paused */
    T_ERR(store_job_event(p.a, id, JOB_EV_RESUME, &(struct job_event_args){ .fence = fa }, NULL,
                          &err),
          SF_ESTALE, &err, "is stale");
    T_OK(store_job_get(p.a, id, &j, &err), &err);
    T_EQ_INT(j.state, JOB_PAUSED);
    T_EQ_INT(store_job_fence(p.a, id + 100, fb, &err), SF_ENOTFOUND);
    t_pair_close(&p);
}

T_CASE(hosts_join_refused_while_another_lease_holds_the_name)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "join", &err));
    int64_t t1, t2;
    T_ERR(store_host_join(p.a, "a b", LEASE_MS, &t1, &err), SF_EINVAL, &err, "not a host name");
    T_ERR(store_host_join(p.a, "a", 0, &t1, &err), SF_EINVAL, &err, "lease_ms");
    if (t_store_pg()) {
        /* PostgreSQL: another host's store takes the name first */
        T_OK(store_host_join(p.b, "a", LEASE_MS, &t1, &err), &err);
    } else {
        /* SQLite has one process per file: another's lease, as a process of an earlier
           life of this data dir left it */
        char sql[256];
        int64_t now = clock_wall_ms();
        snprintf(sql, sizeof(sql),
                 "INSERT INTO hosts VALUES('a', 1, 424242, 11, %lld, %lld, %lld, 0)",
                 (long long)now - 5000, (long long)now - 2000, (long long)now + LEASE_MS);
        T_OK(t_store_exec(p.dir, sql), NULL);
        t1 = 1;
    }
    T_ERR(store_host_join(p.a, "a", LEASE_MS, &t2, &err), SF_EAGAIN, &err, "host 'a' is");
    T_TRUE(strstr(err.msg, t_store_pg() ? "its connection holds the name" : "pid 424242") ||
           strstr(err.msg, "renewed"));
    /* the holder's lease runs out (and on PostgreSQL its connection goes): the name is free */
    if (t_store_pg()) {
        store_close(p.b);
        p.b = NULL;
        /* its connection gone, its lease still holds the name */
        T_ERR(store_host_join(p.a, "a", LEASE_MS, &t2, &err), SF_EAGAIN, &err, "renewed");
    }
    T_OK(t_store_exec(p.dir, "UPDATE hosts SET lease_until_ms = 1"), NULL);
    if (t_store_pg()) {
        /* the refused join kept no hold on the name: a third store takes it, then a's is
           refused by that one's connection */
        char dir_c[600];
        snprintf(dir_c, sizeof(dir_c), "%s-c", p.dir);
        struct store *c = store_open_host(dir_c, p.url, NULL, &err);
        T_TRUE(c != NULL);
        T_OK(store_host_join(c, "a", LEASE_MS, &t2, &err), &err);
        T_EQ_INT(t2, t1 + 1);
        store_close(c);
        T_OK(t_store_exec(p.dir, "UPDATE hosts SET lease_until_ms = 1"), NULL);
        t1 = t2;
    }
    T_OK(store_host_join(p.a, "a", LEASE_MS, &t2, &err), &err);
    T_EQ_INT(t2, t1 + 1);
    T_ERR(store_host_beat(p.a, "a", t1, LEASE_MS, &err), SF_ESTALE, &err, "another process");
    T_OK(store_host_beat(p.a, "a", t2, LEASE_MS, &err), &err);
    t_pair_close(&p);
}

T_CASE(hosts_list_shows_lease_printers_and_claims)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "list", &err));
    int64_t ta, tb, fence;
    T_OK(store_host_join(p.a, "a", LEASE_MS, &ta, &err), &err);
    T_OK(store_host_join(p.b, "b", 60 * 1000, &tb, &err), &err);
    const char *mine[] = { "m2", "m1" };
    T_OK(store_host_own(p.a, "a", ta, mine, 2, NULL, &err), &err);
    T_OK(add_jobs(p.a, 2, NULL, &err), &err);
    struct job_row j;
    T_OK(store_job_claim(p.a, "a", ta, NULL, &j, &fence, &err), &err);
    struct store_host_row *rows;
    size_t n;
    T_OK(store_host_list(p.a, clock_wall_ms() + 120 * 1000, &rows, &n, &err), &err);
    T_EQ_INT(n, 2);
    T_EQ_STR(rows[0].name, "a");
    T_TRUE(rows[0].live);
    T_EQ_INT(rows[0].n_printers, 2);
    T_EQ_STR(rows[0].printers, "m1,m2");
    T_EQ_INT(rows[0].n_claimed, 1);
    T_EQ_INT(rows[0].token, ta);
    T_EQ_STR(rows[1].name, "b");
    T_TRUE(!rows[1].live); /* 2 min on, its 1-min lease has run out */
    T_EQ_INT(rows[1].n_claimed, 0);
    free(rows);
    t_pair_close(&p);
}

/* A store call on another thread: a note logged (an event in its own transaction), or the
   reap of every host. */
struct bg {
    struct store *s;
    bool reap;
    int rc;
    struct sf_err err;
    volatile int done;
};

static void *
bg_run(void *arg)
{
    struct bg *b = arg;
    b->rc = b->reap ? store_host_reap(b->s, clock_wall_ms() + 120 * 1000, NULL, &b->err)
                    : store_printer_note(b->s, "mk3", "printer-note", "from the second writer",
                                         &b->err);
    __atomic_store_n(&b->done, 1, __ATOMIC_SEQ_CST);
    return NULL;
}

/* Wait until sql (a count on the database) is at least 1, or done is set; false at the
   deadline. */
static bool
wait_for(struct sqldb *db, const char *sql, volatile int *done)
{
    for (int64_t end = clock_mono_ms() + 60000; clock_mono_ms() < end;) {
        if (done && __atomic_load_n(done, __ATOMIC_SEQ_CST))
            return true;
        struct sqldb_stmt *st;
        int64_t v = 0;
        if (sqldb_prepare(db, sql, &st) == SF_OK) {
            if (sqldb_step(st) == SQLDB_ROW)
                v = sqldb_column_int64(st, 0);
            sqldb_finalize(st);
        }
        if (v > 0)
            return true;
        nanosleep(&(struct timespec){ .tv_nsec = 10 * 1000 * 1000 }, NULL);
    }
    return false;
}

/* Events read from after_id on, as the API's stream pages them: the count read, the last id
   into *last. */
static size_t
page_events(struct store *s, int64_t *last)
{
    struct event_row *ev;
    size_t n = 0, total = 0;
    while (store_events(s, *last, 100, &ev, &n, NULL) == SF_OK && n > 0) {
        *last = ev[n - 1].id;
        total += n;
        free(ev);
    }
    return total;
}

/* Two connections write events; the one whose id is lower commits later.  A reader paging
   `id > last` must still read every event (store_event.c's lock): here the reap holds its
   first job's event uncommitted (its second job's row is locked by a third connection)
   while another connection logs a note. */
T_CASE(hosts_events_commit_in_id_order_across_connections)
{
    if (!t_store_pg()) {
        t_skip("SQLite has one writer at a time: its ids commit in order");
        return;
    }
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "evorder", &err));
    int64_t ta, tb, fence;
    T_OK(store_host_join(p.a, "a", 60 * 1000, &ta, &err), &err);
    T_OK(store_host_join(p.b, "b", LEASE_MS, &tb, &err), &err);
    T_OK(add_jobs(p.a, 2, NULL, &err), &err);
    struct job_row j1, j2;
    T_OK(store_job_claim(p.a, "a", ta, NULL, &j1, &fence, &err), &err);
    T_OK(store_job_claim(p.a, "a", ta, NULL, &j2, &fence, &err), &err);
    struct store *w = store_open_peer(p.a, &err);
    T_TRUE(w != NULL);
    struct sqldb *lock = sqldb_open(p.url, 0, &err), *look = sqldb_open(p.url, 0, &err);
    T_TRUE(lock && look);
    int64_t last = 0;
    page_events(p.a, &last);
    int64_t before = last;
    /* the second job's row locked: the reap logs the first job's event, then waits */
    T_OK(sqldb_begin(lock), NULL);
    char sql[128];
    snprintf(sql, sizeof(sql), "SELECT id FROM jobs WHERE id = %lld FOR UPDATE",
             (long long)(j1.id > j2.id ? j1.id : j2.id));
    T_OK(sqldb_exec(lock, sql), NULL);
    struct bg reap = { .s = p.b, .reap = true }, note = { .s = w };
    pthread_t tr, tn;
    T_EQ_INT(pthread_create(&tr, NULL, bg_run, &reap), 0);
    T_TRUE(wait_for(look,
                    "SELECT count(*) FROM pg_locks WHERE NOT granted AND locktype IN"
                    " ('transactionid', 'tuple')",
                    NULL));
    /* the note: it commits at once (ids out of order) or waits for the reap's commit */
    T_EQ_INT(pthread_create(&tn, NULL, bg_run, &note), 0);
    T_TRUE(wait_for(look,
                    "SELECT count(*) FROM pg_locks WHERE NOT granted AND"
                    " locktype = 'advisory'",
                    &note.done));
    size_t n = page_events(p.a, &last);
    sqldb_rollback(lock);
    pthread_join(tr, NULL);
    pthread_join(tn, NULL);
    T_EQ_INT(reap.rc, 1);
    T_OK(note.rc, &note.err);
    n += page_events(p.a, &last);
    snprintf(sql, sizeof(sql), "SELECT count(*) FROM events WHERE id > %lld", (long long)before);
    int64_t all = t_store_int(p.dir, sql);
    T_EQ_INT(all, 4);          /* two jobs back in the queue, the reap, the note */
    T_EQ_INT((int64_t)n, all); /* none passed over */
    sqldb_close(lock);
    sqldb_close(look);
    store_close(w);
    t_pair_close(&p);
}

/* Fencing cannot be bypassed: a reap makes the reaped host's tokens stale (its RESUME of the
   interrupted print, its PREPARED of a requeued job), a host-mode write without a token is
   refused once a host holds the job, and progress carries the token. */
T_CASE(hosts_reap_bumps_fences_and_unfenced_writes_are_refused)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "fence2", &err));
    int64_t ta, tb, fa, fc, id, q;
    struct job_row j;
    T_OK(store_host_join(p.a, "a", 60 * 1000, &ta, &err), &err);
    T_OK(store_host_join(p.b, "b", LEASE_MS, &tb, &err), &err);
    const char *mine[] = { "p1" };
    T_OK(store_host_own(p.a, "a", ta, mine, 1, NULL, &err), &err);
    T_OK(add_ready(p.a, &id, &err), &err);
    T_OK(store_job_attach(p.a, "a", ta, id, &fa, &err), &err);
    T_ERR(store_job_event(p.a, id, JOB_EV_START, &(struct job_event_args){ .printer = "p1" }, NULL,
                          &err),
          SF_ESTALE, &err, "without a fencing token");
    T_OK(store_job_event(p.a, id, JOB_EV_START,
                         &(struct job_event_args){ .printer = "p1", .fence = fa }, NULL, &err),
         &err);
    T_OK(store_job_progress_fenced(p.a, id, 100, fa, &err), &err);
    T_OK(store_host_printer_set(p.a, "a", ta, "p1", PRINTER_PRINTING, &err), &err);
    T_ERR(store_host_printer_set(p.b, "b", tb, "p1", PRINTER_IDLE, &err), SF_ESTALE, &err,
          "belongs to host 'a', not 'b'");
    T_ERR(store_job_progress_fenced(p.a, id, 200, fa + 1, &err), SF_ESTALE, &err, "is stale");
    T_OK(add_jobs(p.a, 1, &q, &err), &err);
    T_OK(store_job_claim(p.a, "a", ta, NULL, &j, &fc, &err), &err);
    T_EQ_INT(j.id, q);
    /* a is cut off; its lease runs out and b reaps it */
    T_EQ_INT(store_host_reap(p.b, clock_wall_ms() + 120 * 1000, NULL, &err), 1);
    T_OK(store_job_get(p.b, id, &j, &err), &err);
    T_EQ_INT(j.state, JOB_INTERRUPTED);
    T_EQ_INT(j.lines_acked, 100);
    /* a comes back with its old tokens: refused, nothing changes */
    T_ERR(store_job_event(p.a, id, JOB_EV_RESUME, &(struct job_event_args){ .fence = fa }, NULL,
                          &err),
          SF_ESTALE, &err, "is stale");
    T_ERR(store_job_progress_fenced(p.a, id, 300, fa, &err), SF_ESTALE, &err, "is stale");
    T_ERR(store_host_printer_set(p.a, "a", ta, "p1", PRINTER_PRINTING, &err), SF_ESTALE, &err,
          "reaped");
    struct job_event_args done = { .gcode_sha = j.gcode_sha, .prep_key = "k", .fence = fc };
    T_ERR(store_job_event(p.a, q, JOB_EV_PREPARED, &done, NULL, &err), SF_ESTALE, &err, "is stale");
    T_OK(store_job_get(p.b, id, &j, &err), &err);
    T_EQ_INT(j.state, JOB_INTERRUPTED);
    T_EQ_INT(j.lines_acked, 100);
    T_OK(store_job_get(p.b, q, &j, &err), &err);
    T_EQ_INT(j.state, JOB_QUEUED);
    /* the operator's events need no token */
    T_OK(store_job_event(p.a, q, JOB_EV_CANCEL, NULL, NULL, &err), &err);
    t_pair_close(&p);
}

/* Whether rows (n) hold job id. */
static bool
has_job(const struct job_row *rows, size_t n, int64_t id)
{
    for (size_t i = 0; i < n; i++)
        if (rows[i].id == id)
            return true;
    return false;
}

/* Does b's scheduler see job id (store_job_live_host)?  -1 on an error. */
static int
b_sees(struct t_pair *p, int64_t id)
{
    struct job_row *rows;
    size_t n;
    struct sf_err err;
    if (store_job_live_host(p->b, "b", &rows, &n, &err))
        return -1;
    int yes = has_job(rows, n, id);
    free(rows);
    return yes;
}

T_CASE(hosts_defer_prepare_failed_and_restart_release_the_claim)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "release", &err));
    int64_t ta, tb, ids[2], ready, fence;
    T_OK(store_host_join(p.a, "a", 60 * 1000, &ta, &err), &err);
    T_OK(store_host_join(p.b, "b", LEASE_MS, &tb, &err), &err);
    T_OK(add_jobs(p.a, 2, ids, &err), &err);
    struct job_row j;
    /* a defers the job it claimed: back in the queue, no host's, so b's scheduler sees it */
    T_OK(store_job_claim_id(p.a, "a", ta, ids[0], &j, &fence, &err), &err);
    T_EQ_INT(b_sees(&p, ids[0]), 0);
    struct job_event_args defer = { .reason = "the pool is full", .fence = fence };
    T_OK(store_job_event(p.a, ids[0], JOB_EV_DEFER, &defer, NULL, &err), &err);
    T_EQ_INT(t_store_int(p.dir, "SELECT count(*) FROM jobs WHERE claimed_by != ''"), 0);
    T_EQ_INT(b_sees(&p, ids[0]), 1);
    T_OK(store_job_claim_id(p.b, "b", tb, ids[0], &j, NULL, &err), &err);
    /* a's preparation fails: the failed job is held by no host */
    T_OK(store_job_claim_id(p.a, "a", ta, ids[1], &j, &fence, &err), &err);
    struct job_event_args failed = { .reason = "no slicer", .fence = fence };
    T_OK(store_job_event(p.a, ids[1], JOB_EV_PREPARE_FAILED, &failed, NULL, &err), &err);
    T_EQ_INT(t_store_int(p.dir, "SELECT count(*) FROM jobs WHERE claimed_by = 'a'"), 0);
    /* a prints a job and is reaped: interrupted, still a's (its part is on a's printer);
       the operator's restart gives it to any host, and b takes it */
    const char *mine[] = { "pa" };
    T_OK(store_host_own(p.a, "a", ta, mine, 1, NULL, &err), &err);
    T_OK(add_ready(p.a, &ready, &err), &err);
    T_OK(store_job_take(p.a, "a", ta, ready, &fence, &err), &err);
    struct job_event_args start = { .printer = "pa", .fence = fence };
    T_OK(store_job_event(p.a, ready, JOB_EV_START, &start, NULL, &err), &err);
    T_EQ_INT(store_host_reap(p.b, clock_wall_ms() + 120 * 1000, NULL, &err), 1);
    T_OK(store_job_get(p.b, ready, &j, &err), &err);
    T_EQ_INT(j.state, JOB_INTERRUPTED);
    T_EQ_INT(store_job_take(p.b, "b", tb, ready, NULL, &err), SF_ENOTFOUND);
    T_OK(store_job_event(p.b, ready, JOB_EV_RESTART, NULL, NULL, &err), &err);
    T_EQ_INT(b_sees(&p, ready), 1);
    T_OK(store_job_take(p.b, "b", tb, ready, &fence, &err), &err);
    T_OK(store_check(p.b, &err), &err);
    t_pair_close(&p);
}

T_CASE(hosts_claim_in_doubt_is_settled_by_reading_it_back)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "settle", &err));
    int64_t ta, tb, ids[2], fence;
    T_OK(store_host_join(p.a, "a", LEASE_MS, &ta, &err), &err);
    T_OK(store_host_join(p.b, "b", LEASE_MS, &tb, &err), &err);
    T_OK(add_jobs(p.a, 2, ids, &err), &err);
    struct job_row j;
    /* a's claim committed (its answer lost): given back, no host's, b's scheduler sees it */
    T_OK(store_job_claim_id(p.a, "a", ta, ids[0], &j, &fence, &err), &err);
    bool released = false;
    T_OK(store_job_claim_settle(p.a, "a", ids[0], &released, &err), &err);
    T_TRUE(released);
    T_OK(store_job_get(p.a, ids[0], &j, &err), &err);
    T_EQ_INT(j.state, JOB_QUEUED);
    T_EQ_INT(b_sees(&p, ids[0]), 1);
    T_EQ_INT(t_store_int(p.dir, "SELECT count(*) FROM events WHERE kind = 'job-defer' AND"
                                " detail LIKE '%its commit was in doubt'"),
             1);
    /* read back again: nothing more */
    T_OK(store_job_claim_settle(p.a, "a", ids[0], &released, &err), &err);
    T_TRUE(!released);
    /* a claim that did not commit: the job stays queued, another host's claim stays its */
    T_OK(store_job_claim_settle(p.a, "a", ids[1], &released, &err), &err);
    T_TRUE(!released);
    T_OK(store_job_claim_id(p.b, "b", tb, ids[1], &j, NULL, &err), &err);
    T_OK(store_job_claim_settle(p.a, "a", ids[1], &released, &err), &err);
    T_TRUE(!released);
    T_OK(store_job_get(p.a, ids[1], &j, &err), &err);
    T_EQ_INT(j.state, JOB_PREPARING);
    T_OK(store_check(p.a, &err), &err);
    t_pair_close(&p);
}

T_CASE(hosts_progress_of_a_job_another_host_holds_is_not_written)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "progress", &err));
    int64_t ta, tb, ids[2], fa[2], fb;
    T_OK(store_host_join(p.a, "a", LEASE_MS, &ta, &err), &err);
    T_OK(store_host_join(p.b, "b", LEASE_MS, &tb, &err), &err);
    for (int i = 0; i < 2; i++) {
        T_OK(add_ready(p.a, &ids[i], &err), &err);
        T_OK(store_job_take(p.a, "a", ta, ids[i], &fa[i], &err), &err);
        struct job_event_args start = { .printer = i ? "p2" : "p1", .fence = fa[i] };
        T_OK(store_job_event(p.a, ids[i], JOB_EV_START, &start, NULL, &err), &err);
    }
    /* b attaches the first: a's progress for it is stale, its other job's still counts */
    T_OK(store_job_attach(p.b, "b", tb, ids[0], &fb, &err), &err);
    struct store_progress batch[] = { { ids[0], 5, false, fa[0] }, { ids[1], 6, false, fa[1] } };
    T_EQ_INT(store_jobs_progress(p.a, batch, 2, &err), 1);
    T_TRUE(!batch[0].saved && batch[1].saved);
    struct job_row j;
    T_OK(store_job_get(p.a, ids[0], &j, &err), &err);
    T_EQ_INT(j.lines_acked, 0);
    T_OK(store_job_get(p.a, ids[1], &j, &err), &err);
    T_EQ_INT(j.lines_acked, 6);
    /* a stale event is refused, naming the holder */
    struct job_event_args pause = { .lines_acked = 5, .fence = fa[0] };
    T_ERR(store_job_event(p.a, ids[0], JOB_EV_PAUSE, &pause, NULL, &err), SF_ESTALE, &err,
          "host 'b' holds the job now");
    t_pair_close(&p);
}

/* Both configs may list one network printer: while its owner lives, only the owner attaches
   the job on it; once the owner's lease ran out, another host may (issue 32). */
T_CASE(hosts_attach_on_a_printer_its_live_owner_holds_is_refused)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "owner", &err));
    int64_t ta, tb, id, fa, fb;
    T_OK(store_host_join(p.a, "a", LEASE_MS, &ta, &err), &err);
    T_OK(store_host_join(p.b, "b", LEASE_MS, &tb, &err), &err);
    const char *net[] = { "net1" };
    T_OK(store_host_own(p.a, "a", ta, net, 1, NULL, &err), &err);
    T_OK(add_ready(p.a, &id, &err), &err);
    T_OK(store_job_take(p.a, "a", ta, id, &fa, &err), &err);
    struct job_event_args start = { .printer = "net1", .fence = fa };
    T_OK(store_job_event(p.a, id, JOB_EV_START, &start, NULL, &err), &err);
    T_ERR(store_job_attach(p.b, "b", tb, id, &fb, &err), SF_EAGAIN, &err,
          "which live host 'a' owns");
    T_EQ_INT(t_store_int(p.dir, "SELECT count(*) FROM jobs WHERE claimed_by = 'a'"), 1);
    /* the owner attaches its own print again; a's lease runs out: b may take it over */
    T_OK(store_job_attach(p.a, "a", ta, id, &fa, &err), &err);
    T_OK(store_host_beat(p.a, "a", ta, 1, &err), &err);
    for (int64_t end = clock_mono_ms() + 60000, gone = clock_wall_ms() + 5;
         clock_wall_ms() <= gone && clock_mono_ms() < end;)
        (void)poll(NULL, 0, 2); /* a bound, not a sleep: a's lease is past */
    T_OK(store_job_attach(p.b, "b", tb, id, &fb, &err), &err);
    T_TRUE(fb > fa);
    t_pair_close(&p);
}

/* A printer has one owner: after an outage of the database longer than the lease every lease
   ran out, and the first host back must not take the printers of an owner that nobody reaped
   (it renews and carries on); once that owner is reaped, the printer is free (issue 32). */
T_CASE(hosts_own_no_printer_of_an_owner_whose_lease_only_ran_out)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "lapse", &err));
    int64_t ta, tb;
    T_OK(store_host_join(p.a, "a", LEASE_MS, &ta, &err), &err);
    T_OK(store_host_join(p.b, "b", LEASE_MS, &tb, &err), &err);
    const char *net[] = { "net1" };
    T_OK(store_host_own(p.a, "a", ta, net, 1, NULL, &err), &err);
    T_OK(store_host_beat(p.a, "a", ta, 1, &err), &err);
    for (int64_t end = clock_mono_ms() + 60000, gone = clock_wall_ms() + 5;
         clock_wall_ms() <= gone && clock_mono_ms() < end;)
        (void)poll(NULL, 0, 2); /* a bound, not a sleep: a's lease is past */
    T_ERR(store_host_own(p.b, "b", tb, net, 1, NULL, &err), SF_EAGAIN, &err,
          "belongs to live host 'a'");
    /* a renews (the database is back): net1 is still a's alone */
    T_OK(store_host_beat(p.a, "a", ta, LEASE_MS, &err), &err);
    T_EQ_INT(t_store_int(p.dir, "SELECT count(*) FROM host_printers WHERE printer = 'net1'"
                                " AND host = 'a'"),
             1);
    /* a's lease runs out again, and b reaps it: now b may own net1 */
    T_OK(store_host_beat(p.a, "a", ta, 1, &err), &err);
    struct store_recovery moved;
    T_EQ_INT(store_host_reap(p.b, clock_wall_ms() + 60 * 1000, &moved, &err), 1);
    T_OK(store_host_own(p.b, "b", tb, net, 1, NULL, &err), &err);
    T_EQ_INT(t_store_int(p.dir, "SELECT count(*) FROM host_printers WHERE printer = 'net1'"
                                " AND host = 'b'"),
             1);
    t_pair_close(&p);
}

/* A check of a shared store (slimfarmd --fsck) migrates nothing: a schema older than this
   program's is refused, naming --init-store, and left as it was, since hosts of the older
   version run on it (it was migrated, as a host's start would). */
T_CASE(hosts_check_refuses_an_older_schema_and_leaves_it)
{
    struct sf_err err;
    char dir[512];
    snprintf(dir, sizeof(dir), "%s/checkold", t_tmpdir());
    const char *db = t_store_db(dir);
    char target[1100];
    snprintf(target, sizeof(target), "%s", db ? db : dir);
    T_OK(store_init(target, NULL, &err), &err);
    int v = store_schema_version();
    char back[128];
    snprintf(back, sizeof(back),
             t_store_pg() ? "UPDATE schema_version SET version = %d" : "PRAGMA user_version = %d",
             v - 1);
    T_OK(t_store_exec(dir, back), NULL);
    const char *read = t_store_pg() ? "SELECT version FROM schema_version" : "PRAGMA user_version";
    T_TRUE(store_open_check(dir, t_store_db(dir), &err) == NULL);
    T_EQ_INT(err.code, SF_EUNSUPP);
    T_TRUE(strstr(err.msg, "older") && strstr(err.msg, "--init-store"));
    T_EQ_INT(t_store_int(dir, read), v - 1);
    /* the same store at this program's schema is checked */
    snprintf(back, sizeof(back),
             t_store_pg() ? "UPDATE schema_version SET version = %d" : "PRAGMA user_version = %d",
             v);
    T_OK(t_store_exec(dir, back), NULL);
    struct store *s = store_open_check(dir, t_store_db(dir), &err);
    T_TRUE(s != NULL);
    T_OK(store_check(s, &err), &err);
    store_close(s);
}

/* Leases run on the database's clock, not each host's: a host whose clock runs a minute
   ahead (SLIMFARM_TEST_CLOCK_SKEW_MS) reaps no live host, and one whose clock runs a minute
   behind is not reaped as it joins.  Before, a's lease came out a minute short or long on
   its peers' clocks, and the fast host reaped a peer within its 10 s lease. */
T_CASE(hosts_leases_hold_across_hosts_whose_clocks_differ)
{
    T_SKIP_UNLESS(t_store_pg(), "hosts with clocks of their own share a PostgreSQL store");
    struct sf_err err;
    const char *dir = fresh_dir("skew");
    char url[1024], dir_fast[600], dir_slow[600];
    snprintf(url, sizeof(url), "%s", t_store_db(dir));
    snprintf(dir_fast, sizeof(dir_fast), "%s-fast", dir);
    snprintf(dir_slow, sizeof(dir_slow), "%s-slow", dir);
    struct store *b = store_open_host(dir, url, NULL, &err);
    T_TRUE(b != NULL);
    setenv("SLIMFARM_TEST_CLOCK_SKEW_MS", "60000", 1);
    struct store *fast = store_open_host(dir_fast, url, NULL, &err);
    setenv("SLIMFARM_TEST_CLOCK_SKEW_MS", "-60000", 1);
    struct store *slow = store_open_host(dir_slow, url, NULL, &err);
    unsetenv("SLIMFARM_TEST_CLOCK_SKEW_MS");
    T_TRUE(fast != NULL && slow != NULL);
    int64_t tb, tf, ts;
    T_OK(store_host_join(b, "b", 10000, &tb, &err), &err);
    T_OK(store_host_join(fast, "fast", 10000, &tf, &err), &err);
    struct store_recovery moved;
    T_EQ_INT(store_host_reap(fast, clock_wall_ms(), &moved, &err), 0); /* b lives */
    T_OK(store_host_join(slow, "slow", 10000, &ts, &err), &err);
    T_EQ_INT(store_host_reap(b, clock_wall_ms(), &moved, &err), 0); /* slow lives */
    int peers = -1;
    T_OK(store_host_peers(fast, "fast", clock_wall_ms(), &peers, &err), &err);
    T_EQ_INT(peers, 2);
    T_OK(store_host_beat(slow, "slow", ts, 10000, &err), &err);
    T_OK(store_host_beat(b, "b", tb, 10000, &err), &err);
    store_close(slow);
    store_close(fast);
    store_close(b);
}

/* A printer with an empty profile (farm.ini takes `profile:` empty) does not fail the publish
   of its host's others (it failed the whole beat's own: the host scheduled nothing); the
   other hosts' read leaves it out. */
T_CASE(hosts_publish_a_printer_with_no_profile)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "publish", &err));
    int64_t ta, tb;
    T_OK(store_host_join(p.a, "a", LEASE_MS, &ta, &err), &err);
    T_OK(store_host_join(p.b, "b", LEASE_MS, &tb, &err), &err);
    const char *names[] = { "bare", "full" };
    T_OK(store_host_own(p.a, "a", ta, names, 2, NULL, &err), &err);
    struct store_printer_prep preps[2] = {
        { .name = "bare", .material = "PLA", .nozzle_mm = 0.4, .bed_mm = { 220, 220, 250 } },
        { .name = "full",
          .profile = "generic-marlin",
          .material = "PLA",
          .nozzle_mm = 0.4,
          .bed_mm = { 220, 220, 250 } },
    };
    T_OK(store_host_publish(p.a, "a", ta, preps, 2, &err), &err);
    struct store_printer_prep *rows = NULL;
    size_t n = 0;
    T_OK(store_host_printers_prep(p.b, "b", clock_wall_ms(), &rows, &n, &err), &err);
    T_EQ_INT(n, 1);
    T_EQ_STR(rows[0].name, "full");
    free(rows);
    t_pair_close(&p);
}

/* A claim among chosen jobs refuses a job id that is no id, as a claim of one does. */
T_CASE(hosts_claim_among_chosen_jobs_refuses_a_bad_id)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "badid", &err));
    int64_t tb, ids[] = { 0 }, tried = 0;
    T_OK(store_host_join(p.b, "b", LEASE_MS, &tb, &err), &err);
    struct job_row j;
    T_ERR(store_job_claim_first(p.b, "b", tb, ids, 1, &tried, &j, NULL, &err), SF_EINVAL, &err,
          "job id 0");
    t_pair_close(&p);
}
