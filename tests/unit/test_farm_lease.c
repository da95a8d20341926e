/*
 * test_farm_lease.c - a host's lease through a database outage (farm_host.h,
 * PostgreSQL only: farm.ini's store is a URL; tests/tfarmhost.h runs the
 * farm).  A host whose lease ran out while nobody reaped it renews it and
 * carries on, its prints untouched, when a claim or take finds it lapsed
 * (it used to join again, reaping itself); the first host back after an
 * outage longer than the leases waits a lease before it reaps the others,
 * so the hosts that come back as it did are not reaped, and reaps a host
 * that did not.  A ready job a host took but whose G-code it cannot fetch is
 * given back for the others (not taken there again at once), and a DEFER
 * wakes the other hosts.  With SLIMFARM_TEST_STORE (tstore.h; store_pg.sh sets it).
 */
#include <poll.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdlib.h>
#include <unistd.h>

#include "../../src/base/clock.h"
#include "../../src/farm/farm.h"
#include "../../src/farm/farm_host.h"
#include "../../src/farm/farm_remote.h"
#include "../../src/farm/store_host.h"
#include "../t.h"
#include "../tfarmhost.h"
#include "../tstore.h"

#define SKIP_UNLESS_PG()                                                                           \
    T_SKIP_UNLESS(t_store_pg(), "a farm of several hosts runs on PostgreSQL (store_pg.sh)")

/* The first column of sql (its ?1 bound to id) on url's database, as an integer (-1: none). */
static int64_t
db_int(const char *url, const char *sql, int64_t id)
{
    char text[64];
    db_text(url, sql, id, text, sizeof(text));
    return strcmp(text, "(no row)") == 0 ? -1 : strtoll(text, NULL, 10);
}

/* Run sql on url's database; SF_OK or the engine's failure. */
static int
db_exec(const char *url, const char *sql)
{
    struct sf_err err;
    struct sqldb *db = sqldb_open(url, 0, &err);
    int rc = db ? sqldb_exec(db, sql) : SF_EIO;
    sqldb_close(db);
    return rc;
}

T_CASE(host_renews_a_lease_that_ran_out_unreaped_and_prints_on)
{
    SKIP_UNLESS_PG();
    struct sf_err err;
    char dir[512], dir_a[600], url[1024], text[64], sql[256];
    snprintf(dir, sizeof(dir), "%s/renew", t_tmpdir());
    snprintf(dir_a, sizeof(dir_a), "%s-a", dir);
    snprintf(url, sizeof(url), "%s", t_store_db(dir));
    struct store *a = store_open_host(dir_a, url, NULL, &err); /* adds the jobs */
    T_TRUE(a != NULL);
    T_OK(host_farm(dir, url, "b",
                   "[printer q]\ndriver: marlin\nport: pty:/dev/null\ngcode_models: *\n"
                   "[printer r]\ndriver: marlin\nport: pty:/dev/null\ngcode_models: *\n",
                   &err),
         &err);
    int64_t first, second;
    T_OK(add_ready_for(a, "q", &first, &err), &err);
    T_OK(store_host_wake(a, &err), &err);
    T_TRUE(wait_state(url, first, "printing"));
    struct hdrv *d = hdrv_named("q");
    T_TRUE(d != NULL);
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; !d->starts && clock_mono_ms() < end;)
        loop_run_once(hx.l, 20);
    T_EQ_INT(d->starts, 1);
    int64_t fence = db_int(url, "SELECT fence FROM jobs WHERE id = ?1", first);
    int64_t token = db_int(url, "SELECT token FROM hosts WHERE name = 'b' AND ?1 = 0", 0);
    T_TRUE(fence > 0 && token > 0);
    /* b's lease ran out, as after the database was away longer than it (b's beat, a third of
       a 600 s lease, is far off), and nobody reaped b */
    snprintf(sql, sizeof(sql), "UPDATE hosts SET lease_until_ms = %lld WHERE name = 'b'",
             (long long)(clock_wall_ms() - 1000));
    T_OK(db_exec(url, sql), NULL);
    /* the next take finds the lease lapsed: b renews it and takes the job */
    T_OK(add_ready_for(a, "r", &second, &err), &err);
    T_OK(store_host_wake(a, &err), &err);
    bool printing = wait_state(url, second, "printing");
    if (!printing)
        fprintf(stderr, "host b logged:\n%s", logged);
    T_TRUE(printing);
    T_TRUE(was_logged("its lease ran out")); /* the take did find it lapsed */
    /* the first print is untouched: the same host process, fencing token and printer */
    T_EQ_INT(db_int(url, "SELECT token FROM hosts WHERE name = 'b' AND ?1 = 0", 0), token);
    T_EQ_INT(db_int(url, "SELECT fence FROM jobs WHERE id = ?1", first), fence);
    db_text(url, "SELECT state || ' ' || claimed_by FROM jobs WHERE id = ?1", first, text,
            sizeof(text));
    T_EQ_STR(text, "printing b");
    T_EQ_INT(t_store_int(dir, "SELECT count(*) FROM events WHERE kind = 'host-reaped'"), 0);
    T_EQ_INT(d->cancels, 0);
    struct printer_info info;
    farm_printer_info(hx.f, 0, &info);
    T_EQ_INT(info.job_id, first);
    host_farm_free();
    store_close(a);
}

/* Turn hx's loop (and beat host a's lease every few turns, if ta) until the wall clock
   passes until_ms. */
static void
turn_until(int64_t until_ms, struct store *a, int64_t ta, int *a_rc)
{
    struct sf_err err;
    for (int i = 0; clock_wall_ms() < until_ms; i++) {
        loop_run_once(hx.l, 20);
        if (ta && i % 10 == 0) {
            int rc = store_host_beat(a, "a", ta, 3000, &err);
            if (rc && *a_rc == SF_OK)
                *a_rc = rc;
        }
    }
}

T_CASE(host_back_from_an_outage_reaps_no_host_that_came_back_too)
{
    SKIP_UNLESS_PG();
    struct sf_err err;
    char dir[512], dir_a[600], url[1024], db[64], sql[256], text[64];
    snprintf(dir, sizeof(dir), "%s/outage", t_tmpdir());
    snprintf(dir_a, sizeof(dir_a), "%s-a", dir);
    snprintf(url, sizeof(url), "%s", t_store_db(dir));
    db_text(url, "SELECT current_database() WHERE ?1 = 0", 0, db, sizeof(db));
    /* host a (a store here, beating from the test) prints job id on its printer x */
    struct store *a = store_open_host(dir_a, url, NULL, &err);
    T_TRUE(a != NULL);
    int64_t ta, id, fence;
    const char *xs[] = { "x" };
    T_OK(store_host_join(a, "a", 3000, &ta, &err), &err);
    T_OK(store_host_own(a, "a", ta, xs, 1, NULL, &err), &err);
    T_OK(add_ready_for(a, "x", &id, &err), &err);
    T_OK(store_job_take(a, "a", ta, id, &fence, &err), &err);
    snprintf(sql, sizeof(sql), "UPDATE jobs SET state = 'printing' WHERE id = %lld", (long long)id);
    T_OK(db_exec(url, sql), NULL);
    /* host b, a farm with a 2 s lease, runs a while beside a: a stays live */
    host_lease_s = 2;
    T_OK(host_farm(dir, url, "b", "[printer y]\ndriver: marlin\nport: pty:/dev/null\n", &err),
         &err);
    T_TRUE(wait_logged("b joined"));
    int a_rc = SF_OK;
    turn_until(clock_wall_ms() + 2500, a, ta, &a_rc);
    T_OK(a_rc, NULL);
    /* the database goes away for longer than both leases: every session of the farm's
       database is cut and no new one let in (from the server's own database) */
    struct sqldb *cut = sqldb_open(getenv("SLIMFARM_TEST_STORE"), 0, &err);
    T_TRUE(cut != NULL);
    snprintf(sql, sizeof(sql), "ALTER DATABASE %s ALLOW_CONNECTIONS false", db);
    T_OK(sqldb_exec(cut, sql), NULL);
    snprintf(sql, sizeof(sql),
             "SELECT count(pg_terminate_backend(pid)) FROM pg_stat_activity WHERE datname = '%s'",
             db);
    T_OK(sqldb_exec(cut, sql), NULL);
    int64_t cut_ms = clock_wall_ms();
    turn_until(cut_ms + 3500, NULL, 0, &a_rc);
    snprintf(sql, sizeof(sql), "ALTER DATABASE %s ALLOW_CONNECTIONS true", db);
    T_OK(sqldb_exec(cut, sql), NULL);
    sqldb_close(cut);
    /* back: b renews first (its beat), then a; b must not have reaped a meanwhile */
    bool renewed = false;
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; !renewed && clock_mono_ms() < end;) {
        loop_run_once(hx.l, 20);
        renewed =
            db_int(url, "SELECT heartbeat_ms FROM hosts WHERE name = 'b' AND ?1 = 0", 0) > cut_ms;
    }
    T_TRUE(renewed);
    int rc = SF_EUNREACH; /* a's connection comes back after its reconnect's back-off */
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; rc == SF_EUNREACH && clock_mono_ms() < end;)
        if ((rc = store_host_beat(a, "a", ta, 3000, &err)) == SF_EUNREACH)
            loop_run_once(hx.l, 20);
    T_OK(rc, &err);
    /* a lease later, with both renewing, a and its print are still live */
    turn_until(clock_wall_ms() + 3000, a, ta, &a_rc);
    T_OK(a_rc, NULL);
    db_text(url, "SELECT state || ' ' || claimed_by FROM jobs WHERE id = ?1", id, text,
            sizeof(text));
    T_EQ_STR(text, "printing a");
    T_EQ_INT(t_store_int(dir, "SELECT count(*) FROM events WHERE kind = 'host-reaped'"), 0);
    /* a host that does not come back is still reaped: a stops renewing */
    bool reaped = wait_state(url, id, "interrupted");
    if (!reaped)
        fprintf(stderr, "host b logged:\n%s", logged);
    T_TRUE(reaped);
    T_EQ_INT(store_host_beat(a, "a", ta, 3000, &err), SF_ESTALE);
    host_farm_free();
    store_close(a);
}

T_CASE(host_gives_back_a_ready_job_whose_gcode_it_cannot_fetch)
{
    SKIP_UNLESS_PG();
    struct sf_err err;
    char dir[512], dir_a[600], url[1024], text[96], sql[256];
    snprintf(dir, sizeof(dir), "%s/giveback", t_tmpdir());
    snprintf(dir_a, sizeof(dir_a), "%s-a", dir);
    snprintf(url, sizeof(url), "%s", t_store_db(dir));
    /* host a stored the job's G-code in its own data dir before files were shared: the
       database knows the file but has none of its bytes; a has it, b cannot fetch it */
    struct store *a = store_open_host(dir_a, url, NULL, &err);
    T_TRUE(a != NULL);
    int64_t ta, id, fence = 0;
    T_OK(store_host_join(a, "a", 600000, &ta, &err), &err);
    T_OK(host_farm(dir, url, "b",
                   "[printer q]\ndriver: marlin\nport: pty:/dev/null\ngcode_models: *\n", &err),
         &err);
    T_OK(add_ready_for(a, "q", &id, &err), &err);
    snprintf(sql, sizeof(sql),
             "DELETE FROM file_blobs WHERE sha256 = (SELECT gcode_sha FROM jobs WHERE id = %lld)",
             (long long)id);
    T_OK(db_exec(url, sql), NULL);
    T_OK(store_host_wake(a, &err), &err);
    /* b takes it, cannot start it, and gives it back: a takes it */
    bool back = false;
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; !back && clock_mono_ms() < end;) {
        loop_run_once(hx.l, 20);
        back =
            db_int(url, "SELECT count(*) FROM events WHERE job_id = ?1 AND kind = 'job-give-back'",
                   id) == 1;
    }
    if (!back)
        fprintf(stderr, "host b logged:\n%s", logged);
    T_TRUE(back);
    db_text(url, "SELECT state || ' by ' || claimed_by FROM jobs WHERE id = ?1", id, text,
            sizeof(text));
    T_EQ_STR(text, "ready by ");
    T_TRUE(wait_logged("b gave job")); /* the give-back's answer comes to the loop after */
    /* b leaves it to the others for now, however often it is woken */
    for (int i = 0; i < 5; i++) {
        T_OK(store_host_wake(a, &err), &err);
        for (int k = 0; k < 10; k++)
            loop_run_once(hx.l, 10);
    }
    T_EQ_INT(
        db_int(url, "SELECT count(*) FROM events WHERE job_id = ?1 AND kind = 'job-give-back'", id),
        1);
    T_OK(store_job_take(a, "a", ta, id, &fence, &err), &err);
    host_farm_free();
    store_close(a);
}

/* Two jobs given back one after the other are each taken here again in their time: the kick
   at the first one's time comes again for the second (it used to come once, and the second
   sat ready for good while nothing else woke the host). */
T_CASE(host_takes_again_every_job_it_gave_back)
{
    SKIP_UNLESS_PG();
    struct sf_err err;
    char dir[512], dir_a[600], url[1024], sql[256];
    snprintf(dir, sizeof(dir), "%s/givetwo", t_tmpdir());
    snprintf(dir_a, sizeof(dir_a), "%s-a", dir);
    snprintf(url, sizeof(url), "%s", t_store_db(dir));
    struct store *a = store_open_host(dir_a, url, NULL, &err);
    T_TRUE(a != NULL);
    int64_t ta, ids[2], fence = 0;
    T_OK(store_host_join(a, "a", 600000, &ta, &err), &err);
    /* both G-codes only in a's data dir (one file): b gives each back when it takes it */
    T_OK(add_ready_for(a, "q", &ids[0], &err), &err);
    T_OK(add_ready_for(a, "q", &ids[1], &err), &err);
    snprintf(sql, sizeof(sql),
             "DELETE FROM file_blobs WHERE sha256 = (SELECT gcode_sha FROM jobs WHERE id = %lld)",
             (long long)ids[0]);
    T_OK(db_exec(url, sql), NULL);
    host_lease_s = 2; /* b takes them again 2 s after it gave them back */
    T_OK(host_farm(dir, url, "b",
                   "[printer q]\ndriver: marlin\nport: pty:/dev/null\ngcode_models: *\n", &err),
         &err);
    const char *given = "SELECT count(*) FROM events WHERE kind = 'job-give-back' AND ?1 = 0";
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS;
         db_int(url, given, 0) < 2 && clock_mono_ms() < end;)
        loop_run_once(hx.l, 20);
    T_EQ_INT(db_int(url, given, 0), 2);
    /* a takes the first one given back; b takes the second again in its time, unwoken */
    int64_t first = db_int(url,
                           "SELECT job_id FROM events WHERE kind = 'job-give-back' AND ?1 = 0"
                           " ORDER BY id LIMIT 1",
                           0);
    int64_t second = first == ids[0] ? ids[1] : ids[0];
    T_OK(store_job_take(a, "a", ta, first, &fence, &err), &err);
    const char *again = "SELECT count(*) FROM events WHERE kind = 'job-give-back' AND job_id = ?1";
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS;
         db_int(url, again, second) < 2 && clock_mono_ms() < end;)
        loop_run_once(hx.l, 20);
    T_EQ_INT(db_int(url, again, second), 2);
    host_farm_free();
    store_close(a);
}

/* A G-code file whose bytes in the database are damaged (a chunk gone) can be had by no host:
   the start fails the job, naming the file, rather than passing it between hosts for good. */
T_CASE(host_fails_a_ready_job_whose_gcode_the_store_lost)
{
    SKIP_UNLESS_PG();
    struct sf_err err;
    char dir[512], dir_a[600], url[1024], text[256], sql[256], sha[STORE_SHA_HEX];
    snprintf(dir, sizeof(dir), "%s/lostchunk", t_tmpdir());
    snprintf(dir_a, sizeof(dir_a), "%s-a", dir);
    snprintf(url, sizeof(url), "%s", t_store_db(dir));
    struct store *a = store_open_host(dir_a, url, NULL, &err);
    T_TRUE(a != NULL);
    T_OK(host_farm(dir, url, "b",
                   "[printer q]\ndriver: marlin\nport: pty:/dev/null\ngcode_models: *\n", &err),
         &err);
    int64_t id;
    T_OK(add_ready_for(a, "q", &id, &err), &err);
    db_text(url, "SELECT gcode_sha FROM jobs WHERE id = ?1", id, sha, sizeof(sha));
    snprintf(sql, sizeof(sql), "DELETE FROM file_chunks WHERE sha256 = '%s'", sha);
    T_OK(db_exec(url, sql), NULL);
    T_OK(store_host_wake(a, &err), &err);
    bool failed = wait_state(url, id, "failed");
    if (!failed)
        fprintf(stderr, "host b logged:\n%s", logged);
    T_TRUE(failed);
    db_text(url, "SELECT reason FROM jobs WHERE id = ?1", id, text, sizeof(text));
    T_TRUE(strstr(text, sha) != NULL);
    T_EQ_INT(
        db_int(url, "SELECT count(*) FROM events WHERE job_id = ?1 AND kind = 'job-give-back'", id),
        0);
    host_farm_free();
    store_close(a);
}

/* A host that stops leaves by its own name: a peer whose lease ran out (back from an outage,
   not renewed yet) is the reap's, after its grace, not reaped by the leave. */
T_CASE(host_leaving_reaps_itself_only)
{
    SKIP_UNLESS_PG();
    struct sf_err err;
    char dir[512], dir_a[600], url[1024], sql[256];
    snprintf(dir, sizeof(dir), "%s/leave", t_tmpdir());
    snprintf(dir_a, sizeof(dir_a), "%s-a", dir);
    snprintf(url, sizeof(url), "%s", t_store_db(dir));
    struct store *a = store_open_host(dir_a, url, NULL, &err);
    T_TRUE(a != NULL);
    int64_t ta;
    T_OK(store_host_join(a, "a", 600000, &ta, &err), &err);
    T_OK(host_farm(dir, url, "b",
                   "[printer q]\ndriver: marlin\nport: pty:/dev/null\ngcode_models: *\n", &err),
         &err);
    snprintf(sql, sizeof(sql), "UPDATE hosts SET lease_until_ms = %lld WHERE name = 'a'",
             (long long)(clock_wall_ms() - 1000));
    T_OK(db_exec(url, sql), NULL);
    host_farm_free();
    T_EQ_INT(db_int(url,
                    "SELECT count(*) FROM hosts WHERE reaped_ms = 0 AND name = 'a'"
                    " AND ?1 = 0",
                    0),
             1);
    T_EQ_INT(db_int(url,
                    "SELECT count(*) FROM hosts WHERE reaped_ms > 0 AND name = 'b'"
                    " AND ?1 = 0",
                    0),
             1);
    T_OK(store_host_beat(a, "a", ta, 600000, &err), &err); /* a renews and carries on */
    store_close(a);
}

T_CASE(defer_wakes_the_other_hosts)
{
    SKIP_UNLESS_PG();
    struct sf_err err;
    char dir[512];
    snprintf(dir, sizeof(dir), "%s/defer", t_tmpdir());
    struct t_pair p;
    T_TRUE(t_pair_open(&p, dir, &err));
    T_OK(store_host_join(p.a, "a", 600000, &p.ta, &err), &err);
    struct store *ls = store_open_listener(p.b, &err);
    T_TRUE(ls != NULL);
    T_OK(store_host_listen(ls, &err), &err);
    char sha[STORE_SHA_HEX];
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "part.stl");
    int64_t id, fence = 0;
    struct job_row j;
    T_OK(store_file_put(p.a, "solid part\n", 11, sha, &err), &err);
    T_OK(store_job_add(p.a, &o, sha, &id, &err), &err);
    T_OK(store_job_claim_id(p.a, "a", p.ta, id, &j, &fence, &err), &err);
    while (store_host_drain(ls) > 0) /* what came before */
        ;
    /* a gives its claim back (a stage unavailable): b hears of it */
    struct job_event_args d = { .reason = "slicer busy", .fence = fence };
    enum job_state to;
    T_OK(store_job_event(p.a, id, JOB_EV_DEFER, &d, &to, &err), &err);
    T_EQ_INT(to, JOB_QUEUED);
    int heard = 0;
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; heard <= 0 && clock_mono_ms() < end;) {
        struct pollfd pfd = { .fd = store_host_notify_fd(ls), .events = POLLIN };
        (void)poll(&pfd, 1, 100);
        heard = store_host_drain(ls);
    }
    T_TRUE(heard > 0);
    store_close(ls);
    t_pair_close(&p);
}

/* Both configs list printer x, and live host a owns it: an action on x at b is a's to carry
   out (routed to it as a command), not b's on its copy; y is b's own. */
T_CASE(host_routes_an_action_on_a_printer_its_live_owner_holds)
{
    SKIP_UNLESS_PG();
    struct sf_err err;
    char dir[512], dir_a[600], url[1024];
    snprintf(dir, sizeof(dir), "%s/route", t_tmpdir());
    snprintf(dir_a, sizeof(dir_a), "%s-a", dir);
    snprintf(url, sizeof(url), "%s", t_store_db(dir));
    struct store *a = store_open_host(dir_a, url, NULL, &err);
    T_TRUE(a != NULL);
    int64_t ta;
    const char *xs[] = { "x" };
    T_OK(store_host_join(a, "a", 600000, &ta, &err), &err);
    T_OK(store_host_own(a, "a", ta, xs, 1, NULL, &err), &err);
    T_OK(host_farm(dir, url, "b",
                   "[printer x]\ndriver: marlin\nport: pty:/dev/null\n"
                   "[printer y]\ndriver: marlin\nport: pty:/dev/null\n",
                   &err),
         &err);
    T_TRUE(wait_logged("printer 'x' belongs to live host 'a'"));
    T_TRUE(farm_remote_is(hx.f, "x"));
    T_TRUE(!farm_remote_is(hx.f, "y"));
    T_TRUE(farm_remote_is(hx.f, "z")); /* in no config of b's */
    host_farm_free();
    store_close(a);
}

/* The farm's store thread, held by hold_queue until *arg is set. */
static int
hold_queue(struct store *s, void *arg, struct sf_err *err)
{
    (void)s, (void)err;
    atomic_bool *release = arg;
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; !atomic_load(release);)
        if (clock_mono_ms() > end || poll(NULL, 0, 10) < 0)
            break;
    return SF_OK;
}

/* b's renewal, as the database has it (its heartbeat, wall ms). */
static int64_t
b_heartbeat(const char *url)
{
    return db_int(url, "SELECT heartbeat_ms FROM hosts WHERE name = 'b' AND ?1 = 0", 0);
}

/* Turn hx's loop until b renews its lease after since_ms; false if it did not in
   WAIT_LIMIT_MS. */
static bool
wait_renewed(const char *url, int64_t since_ms)
{
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; clock_mono_ms() < end;) {
        if (b_heartbeat(url) > since_ms)
            return true;
        loop_run_once(hx.l, 20);
    }
    return false;
}

/* The beat (its join, renewals, the reap of a dead peer, the own of that peer's printer)
   sends nothing on the loop's connection, so a slow or silent database never holds the
   printers' loop; and it runs beside the farm's store thread, not behind it, so writes
   queued for a slow database do not hold the lease either. */
T_CASE(host_beats_reaps_and_owns_off_the_loops_connection)
{
    SKIP_UNLESS_PG();
    struct sf_err err;
    char dir[512], dir_a[600], url[1024];
    snprintf(dir, sizeof(dir), "%s/beatconn", t_tmpdir());
    snprintf(dir_a, sizeof(dir_a), "%s-a", dir);
    snprintf(url, sizeof(url), "%s", t_store_db(dir));
    /* host c owns printer r, and dies: its 1 s lease runs out, renewed by nobody */
    struct store *a = store_open_host(dir_a, url, NULL, &err);
    T_TRUE(a != NULL);
    int64_t tc;
    const char *rs[] = { "r" };
    T_OK(store_host_join(a, "c", 1000, &tc, &err), &err);
    T_OK(store_host_own(a, "c", tc, rs, 1, NULL, &err), &err);
    host_lease_s = 3; /* a beat a second; b reaps after renewing for 3 s */
    T_OK(host_farm(dir, url, "b",
                   "[printer q]\ndriver: marlin\nport: pty:/dev/null\n"
                   "[printer r]\ndriver: marlin\nport: pty:/dev/null\n",
                   &err),
         &err);
    T_TRUE(wait_logged("b joined"));
    T_TRUE(wait_logged("printer 'r' belongs to live host 'c'"));
    T_TRUE(!farm_host_owns(hx.f, "r"));
    int64_t rt = store_round_trips(hx.s);
    /* b renews, reaps c once its grace is over, and owns r at its next beat */
    T_TRUE(wait_logged("reaped 1 hosts"));
    T_TRUE(wait_logged("printer 'r' is its own now"));
    T_TRUE(farm_host_owns(hx.f, "r"));
    T_TRUE(wait_renewed(url, b_heartbeat(url)));
    T_TRUE(db_int(url, "SELECT reaped_ms FROM hosts WHERE name = 'c' AND ?1 = 0", 0) > 0);
    T_EQ_INT(store_round_trips(hx.s), rt);
    /* the farm's store thread held (as by a slow database): b renews all the same */
    atomic_bool release = false;
    T_OK(storeq_call(farm_storeq(hx.f), hold_queue, &release, NULL, NULL, NULL), NULL);
    int64_t held_ms = clock_wall_ms();
    T_TRUE(wait_renewed(url, held_ms));
    T_TRUE(wait_renewed(url, b_heartbeat(url)));
    T_TRUE(storeq_depth(farm_storeq(hx.f)) > 0); /* still held */
    atomic_store(&release, true);
    T_EQ_INT(store_round_trips(hx.s), rt);
    host_farm_free();
    store_close(a);
}
