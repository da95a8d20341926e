/*
 * test_store_command.c - command rows (store_command.h): an action asked of
 * a printer another host owns is taken by its owner once, answered into
 * the row, and read back by the asker; a row withdrawn at its deadline, or
 * whose deadline passed before the owner came, is never taken (never runs
 * late); a row the owner took is not withdrawn; a printer whose host is
 * down, or that no host owns, is refused with a clear error; the owner's
 * listener hears the row's NOTIFY (PostgreSQL).  Each host's published view
 * of its printers (store_view.h) is what the others list with them, only
 * under the publisher's current token, and wakes them, as every event does.  With
 * SLIMFARM_TEST_STORE (tstore.h, tests/integ/store_pg.sh) on PostgreSQL, the second host a store of
 * its own on the same database; on SQLite a second connection.
 */
#include <poll.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/base/clock.h"
#include "../../src/farm/store_command.h"
#include "../t.h"
#include "../tstore.h"

#define LEASE_MS (600 * 1000)
#define WAIT_MS  10000

/* Two hosts on one database: a owns printer "p1", b asks. */
static bool
pair_open(struct t_pair *p, const char *name, struct sf_err *err)
{
    char dir[512];
    snprintf(dir, sizeof(dir), "%s/%s", t_tmpdir(), name);
    const char *mine[] = { "p1" }, *theirs[] = { "p2" };
    return t_pair_open(p, dir, err) && store_host_join(p->a, "a", LEASE_MS, &p->ta, err) == SF_OK &&
           store_host_join(p->b, "b", LEASE_MS, &p->tb, err) == SF_OK &&
           store_host_own(p->a, "a", p->ta, mine, 1, NULL, err) == SF_OK &&
           store_host_own(p->b, "b", p->tb, theirs, 1, NULL, err) == SF_OK;
}

T_CASE(command_is_taken_once_and_answered)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "once", &err));
    int64_t now = clock_wall_ms();
    struct store_command c, got, *rows;
    size_t n;
    T_OK(store_command_add(p.b, "b", "p1", "pause", NULL, "ops", now, WAIT_MS, &c, &err), &err);
    T_TRUE(c.id > 0);
    T_EQ_STR(c.host, "a");
    T_EQ_STR(c.from, "b");
    T_EQ_INT(c.state, STORE_CMD_PENDING);
    /* b owns no such command: nothing for it */
    T_OK(store_command_take(p.b, "b", &rows, &n, &err), &err);
    T_EQ_INT(n, 0);
    free(rows);
    T_OK(store_command_take(p.a, "a", &rows, &n, &err), &err);
    T_EQ_INT(n, 1);
    T_EQ_INT(rows[0].id, c.id);
    T_EQ_STR(rows[0].kind, "pause");
    T_EQ_STR(rows[0].who, "ops");
    T_EQ_INT(rows[0].state, STORE_CMD_RUNNING);
    free(rows);
    /* taken once */
    T_OK(store_command_take(p.a, "a", &rows, &n, &err), &err);
    T_EQ_INT(n, 0);
    free(rows);
    /* taken: the asker's withdrawal comes too late, and says so */
    T_OK(store_command_expire(p.b, c.id, &got, &err), &err);
    T_EQ_INT(got.state, STORE_CMD_RUNNING);
    T_OK(store_command_finish(p.a, c.id, SF_EAGAIN, "no job to pause", "idle", &err), &err);
    T_OK(store_command_get(p.b, c.id, &got, &err), &err);
    T_EQ_INT(got.state, STORE_CMD_DONE);
    T_EQ_INT(got.rc, SF_EAGAIN);
    T_EQ_STR(got.message, "no job to pause");
    T_EQ_STR(got.printer_state, "idle");
    /* answered once */
    T_ERR(store_command_finish(p.a, c.id, SF_OK, NULL, NULL, &err), SF_ENOTFOUND, &err,
          "not running");
    T_ERR(store_command_get(p.b, c.id + 100, &got, &err), SF_ENOTFOUND, &err, "no command");
    t_pair_close(&p);
}

T_CASE(command_past_its_deadline_never_runs)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "late", &err));
    int64_t now = clock_wall_ms();
    struct store_command c, d, got, *rows;
    size_t n;
    /* withdrawn by the asker: never taken */
    T_OK(store_command_add(p.b, "b", "p1", "resume", NULL, NULL, now, WAIT_MS, &c, &err), &err);
    T_OK(store_command_expire(p.b, c.id, &got, &err), &err);
    T_EQ_INT(got.state, STORE_CMD_EXPIRED);
    /* not withdrawn, but the owner comes after its deadline (the database's clock; the test's
       is the same machine's): not taken, expired */
    T_OK(store_command_add(p.b, "b", "p1", "cancel", NULL, NULL, now, 1, &d, &err), &err);
    T_EQ_INT(d.deadline_ms - d.created_ms, 1);
    for (int64_t end = clock_mono_ms() + WAIT_MS;
         clock_wall_ms() <= d.deadline_ms + 1 && clock_mono_ms() < end;)
        (void)poll(NULL, 0, 5); /* a bound, not a sleep: ends once the deadline is past */
    T_OK(store_command_take(p.a, "a", &rows, &n, &err), &err);
    T_EQ_INT(n, 0);
    free(rows);
    T_OK(store_command_get(p.b, d.id, &got, &err), &err);
    T_EQ_INT(got.state, STORE_CMD_EXPIRED);
    T_ERR(store_command_finish(p.a, d.id, SF_OK, NULL, NULL, &err), SF_ENOTFOUND, &err, "");
    /* a later command is taken alone, in order with nothing stale before it */
    T_OK(store_command_add(p.b, "b", "p1", "command", "G28", "ops", now, WAIT_MS, &c, &err), &err);
    T_OK(store_command_take(p.a, "a", &rows, &n, &err), &err);
    T_EQ_INT(n, 1);
    T_EQ_INT(rows[0].id, c.id);
    T_EQ_STR(rows[0].line, "G28");
    free(rows);
    t_pair_close(&p);
}

/* The deadline is the database's clock's: an asker whose clock runs a minute behind (or
   ahead) asks for WAIT_MS, and the owner takes it with that much left. */
T_CASE(command_deadline_is_the_databases_clock)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "clock", &err));
    struct store_command c, *rows;
    size_t n;
    int64_t before = clock_wall_ms();
    T_OK(store_command_add(p.b, "b", "p1", "pause", NULL, NULL, before - 60000, WAIT_MS, &c, &err),
         &err);
    T_EQ_INT(c.deadline_ms - c.created_ms, WAIT_MS);
    /* the database runs on this machine here: its clock is this one's */
    T_TRUE(c.created_ms >= before - 1000 && c.created_ms <= clock_wall_ms() + 1000);
    T_OK(store_command_add(p.b, "b", "p1", "resume", NULL, NULL, before + 60000, WAIT_MS, &c, &err),
         &err);
    T_OK(store_command_take(p.a, "a", &rows, &n, &err), &err);
    T_EQ_INT(n, 2);
    for (size_t i = 0; i < n; i++)
        T_TRUE(rows[i].left_ms > 0 && rows[i].left_ms <= WAIT_MS);
    free(rows);
    t_pair_close(&p);
}

T_CASE(command_to_a_host_down_or_no_printer_is_refused)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "down", &err));
    int64_t now = clock_wall_ms();
    struct store_command c, *rows;
    size_t n;
    T_ERR(store_command_add(p.b, "b", "nope", "pause", NULL, NULL, now, WAIT_MS, &c, &err),
          SF_ENOTFOUND, &err, "no printer 'nope' on any host");
    T_ERR(store_command_add(p.b, "b", "p2", "pause", NULL, NULL, now, WAIT_MS, &c, &err), SF_EINVAL,
          &err, "host b's own");
    /* a manual line as long as the API takes (SF_COMMAND_MAX) is carried; one more is named */
    char line[SF_COMMAND_MAX + 2];
    memset(line, 'M', SF_COMMAND_MAX);
    line[SF_COMMAND_MAX] = '\0';
    T_OK(store_command_add(p.b, "b", "p1", "command", line, NULL, now, WAIT_MS, &c, &err), &err);
    T_EQ_INT(strlen(c.line), SF_COMMAND_MAX);
    T_OK(store_command_expire(p.b, c.id, &c, &err), &err); /* not for the take below */
    line[SF_COMMAND_MAX] = 'M';
    line[SF_COMMAND_MAX + 1] = '\0';
    T_ERR(store_command_add(p.b, "b", "p1", "command", line, NULL, now, WAIT_MS, &c, &err),
          SF_EINVAL, &err, "line is longer than 256 bytes");
    T_ERR(store_command_add(p.b, "b", "p1", "pause", NULL, NULL, now, 0, &c, &err), SF_EINVAL, &err,
          "not after now");
    /* a's lease runs out: its printer is offline to the others, nothing is written */
    T_OK(store_host_beat(p.a, "a", p.ta, 1, &err), &err);
    int64_t later = clock_wall_ms() + 5000;
    T_ERR(store_command_add(p.b, "b", "p1", "pause", NULL, NULL, later, WAIT_MS, &c, &err),
          SF_ESTALE, &err, "its host a is down");
    T_OK(store_command_take(p.a, "a", &rows, &n, &err), &err);
    T_EQ_INT(n, 0);
    free(rows);
    t_pair_close(&p);
}

/* What a listener heard: every payload, and how many were want (the host it waits for). */
struct heard {
    const char *want;
    const char *channel; /* the channel heard (NULL: STORE_COMMAND_CHANNEL) */
    int n, wanted;
};

static void
on_heard(void *ud, const char *channel, const char *host)
{
    struct heard *h = ud;
    if (strcmp(channel, h->channel ? h->channel : STORE_COMMAND_CHANNEL) != 0)
        return; /* the events' and views' wake-ups (store_view.h) */
    h->n++;
    h->wanted += strcmp(host, h->want) == 0;
}

/* Drain l until want is heard, for up to WAIT_MS (each listener hears every host's); false
   when a drain fails (the connection lost: the case fails, it does not spin). */
static bool
hear(struct store *l, struct heard *h)
{
    for (int64_t end = clock_mono_ms() + WAIT_MS; !h->wanted && clock_mono_ms() < end;) {
        struct pollfd pfd = { .fd = store_command_notify_fd(l), .events = POLLIN };
        int n = store_command_drain(l, on_heard, h);
        if (n < 0)
            return false;
        if (n == 0)
            (void)poll(&pfd, 1, 100); /* a bound, not a sleep: the NOTIFY ends it */
    }
    return true;
}

T_CASE(owner_and_asker_hear_the_command)
{
    T_SKIP_UNLESS(t_store_pg(), "NOTIFY is PostgreSQL's (SQLite has one host)");
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "hear", &err));
    struct store *la = store_open_peer(p.a, &err), *lb = store_open_peer(p.b, &err);
    T_TRUE(la && lb);
    T_OK(store_command_listen(la, &err), &err);
    T_OK(store_command_listen(lb, &err), &err);
    T_TRUE(store_command_notify_fd(la) >= 0);
    int64_t now = clock_wall_ms();
    struct store_command c, *rows;
    size_t n;
    T_OK(store_command_add(p.b, "b", "p1", "pause", NULL, NULL, now, WAIT_MS, &c, &err), &err);
    struct heard ha = { .want = "a" }, hb = { .want = "b" };
    T_TRUE(hear(la, &ha));
    T_EQ_INT(ha.n, 1);
    T_EQ_INT(ha.wanted, 1); /* the owner's name: a runs it */
    T_OK(store_command_take(p.a, "a", &rows, &n, &err), &err);
    free(rows);
    T_OK(store_command_finish(p.a, c.id, SF_OK, NULL, "paused", &err), &err);
    T_TRUE(hear(lb, &hb));
    T_EQ_INT(hb.wanted, 1); /* the asker's: b reads the answer */
    store_close(la);
    store_close(lb);
    t_pair_close(&p);
}

T_CASE(each_host_lists_the_printers_the_others_own)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "list", &err));
    struct store_command_printer *rows;
    size_t n;
    T_OK(store_printer_set(p.a, "p1", PRINTER_PAUSED, &err), &err);
    T_OK(store_command_printers(p.b, "b", clock_wall_ms(), &rows, &n, &err), &err);
    T_EQ_INT(n, 1);
    T_EQ_STR(rows[0].name, "p1");
    T_EQ_STR(rows[0].host, "a");
    T_EQ_STR(rows[0].state, "paused");
    T_TRUE(rows[0].live);
    T_EQ_INT(rows[0].job_id, 0);
    free(rows);
    T_OK(store_command_printers(p.a, "a", clock_wall_ms(), &rows, &n, &err), &err);
    T_EQ_INT(n, 1);
    T_EQ_STR(rows[0].name, "p2");
    T_EQ_STR(rows[0].state, ""); /* b never wrote its state */
    free(rows);
    /* a's lease runs out: its printer is listed, not live, with how long ago */
    T_OK(store_host_beat(p.a, "a", p.ta, 1, &err), &err);
    T_OK(store_command_printers(p.b, "b", clock_wall_ms() + 5000, &rows, &n, &err), &err);
    T_EQ_INT(n, 1);
    T_TRUE(!rows[0].live);
    T_TRUE(rows[0].down_ms >= 4000);
    free(rows);
    t_pair_close(&p);
}

/* The view b lists a's printer p1 with ("" when none). */
static void
view_of_p1(struct t_pair *p, char *out, size_t cap)
{
    struct sf_err err;
    struct store_command_printer *rows;
    size_t n;
    out[0] = '\0';
    if (store_command_printers(p->b, "b", clock_wall_ms(), &rows, &n, &err) == SF_OK && n == 1)
        snprintf(out, cap, "%s", rows[0].view);
    free(rows);
}

T_CASE(each_host_lists_the_others_printers_as_they_published_them)
{
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "view", &err));
    char v[STORE_VIEW_MAX];
    view_of_p1(&p, v, sizeof(v));
    T_EQ_STR(v, ""); /* never published */
    T_OK(store_view_publish(p.a, "a", p.ta,
                            "{\"p1\":{\"enabled\":false,\"temps\":{\"nozzle_c\":211}},"
                            "\"p9\":{\"enabled\":true}}",
                            &err),
         &err);
    view_of_p1(&p, v, sizeof(v));
    /* p1's object alone (the engines space JSON differently) */
    T_TRUE(strstr(v, "\"enabled\"") && strstr(v, "false") && strstr(v, "211"));
    T_TRUE(!strstr(v, "p9"));
    /* a stale token (another process holds the name, or a was reaped) writes nothing */
    T_EQ_INT(store_view_publish(p.a, "a", p.ta + 1, "{\"p1\":{\"enabled\":true}}", &err),
             SF_ESTALE);
    T_TRUE(strstr(err.msg, "no longer"));
    view_of_p1(&p, v, sizeof(v));
    T_TRUE(strstr(v, "211"));
    /* a newer view replaces it */
    T_OK(store_view_publish(p.a, "a", p.ta, "{\"p1\":{\"enabled\":true}}", &err), &err);
    view_of_p1(&p, v, sizeof(v));
    T_TRUE(strstr(v, "true") && !strstr(v, "211"));
    /* a view that is not an object (another version's) lists its printers without one */
    T_OK(store_view_publish(p.a, "a", p.ta, "[{\"p1\":1}]", &err), &err);
    view_of_p1(&p, v, sizeof(v));
    T_EQ_STR(v, "");
    t_pair_close(&p);
}

T_CASE(hosts_hear_a_view_published_and_an_event_logged)
{
    T_SKIP_UNLESS(t_store_pg(), "NOTIFY is PostgreSQL's (SQLite has one host)");
    struct sf_err err;
    struct t_pair p;
    T_TRUE(pair_open(&p, "hearview", &err));
    struct store *lb = store_open_peer(p.b, &err);
    T_TRUE(lb != NULL);
    T_OK(store_command_listen(lb, &err), &err);
    T_OK(store_view_publish(p.a, "a", p.ta, "{}", &err), &err);
    struct heard hv = { .want = "a", .channel = STORE_VIEW_CHANNEL };
    T_TRUE(hear(lb, &hv));
    T_EQ_INT(hv.wanted, 1);                                       /* the publisher's name */
    T_OK(store_printer_set(p.a, "p1", PRINTER_IDLE, &err), &err); /* logs printer-state */
    struct heard he = { .want = "", .channel = STORE_EVENT_CHANNEL };
    T_TRUE(hear(lb, &he));
    T_EQ_INT(he.wanted, 1);
    store_close(lb);
    t_pair_close(&p);
}
