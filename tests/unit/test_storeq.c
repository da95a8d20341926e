/*
 * test_storeq.c - the store's thread (storeq.h) on a real store and a real
 * loop: requests are written in the order posted, each job event's
 * callback runs once, on the loop, with the store's answer; storeq_free
 * writes what is still queued; a failure is logged and counted; a write
 * that finds the database locked by another connection waits and lands
 * once the lock goes, the loop never waiting for it; progress posted
 * meanwhile is folded into one write, and a caller that must see the queue
 * written is told "busy" at once and woken when it is.
 */
#include <pthread.h>
#include <stdlib.h>

#include "../../src/base/clock.h"
#include "../../src/base/log.h"
#include "../../src/farm/sqldb.h"
#include "../../src/farm/storeq.h"
#include "../t.h"
#include "../tstore.h"

#define WAIT_LIMIT_MS 120000 /* a loaded machine under the sanitizers */

static pthread_t loop_thread;

/* One job event's answers. */
struct answer {
    int calls;         /* how often the callback ran */
    bool on_loop;      /* it ran on the loop's thread */
    int rc;            /* the store's answer */
    enum job_state to; /* the job's state after */
    char msg[SF_ERR_MSG_MAX];
};

static void
on_event(void *ud, const struct storeq_result *r)
{
    struct answer *a = ud;
    a->calls++;
    a->on_loop = pthread_equal(pthread_self(), loop_thread);
    a->rc = r->rc;
    a->to = r->to;
    snprintf(a->msg, sizeof(a->msg), "%s", r->rc ? r->err->msg : "");
}

/* A job whose stored G-code prints as is: ready at once. */
static int64_t
gcode_job(struct store *s, struct sf_err *err)
{
    char sha[STORE_SHA_HEX];
    int64_t id = 0;
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "cube.gcode");
    struct job_event_args g = { .prep_key = "any", .nozzle_mm = 0.4, .gcode_lines = 1000 };
    if (store_file_put(s, "G28\nG1 X1\n", 10, sha, err) ||
        store_job_add_gcode(s, &o, sha, &g, &id, err))
        return 0;
    return id;
}

/* Turn the loop until a's callback ran (or the limit passed). */
static bool
answered(struct loop *l, const struct answer *a)
{
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; !a->calls && clock_mono_ms() < end;)
        loop_run_once(l, 10);
    return a->calls > 0;
}

struct fixture {
    struct loop *l;
    struct store *s;
    struct storeq *q;
    int64_t id; /* a ready job (gcode_job) */
    char dir[512];
};

static int
setup(struct fixture *fx, const char *name, struct sf_err *err)
{
    loop_thread = pthread_self();
    snprintf(fx->dir, sizeof(fx->dir), "%s/%s", t_tmpdir(), name);
    if (!(fx->l = loop_new(err)) || !(fx->s = t_store_open(fx->dir, NULL, err)) ||
        !(fx->q = storeq_new(fx->l, fx->s, err)) || !(fx->id = gcode_job(fx->s, err)))
        return SF_EIO;
    return SF_OK;
}

static void
teardown(struct fixture *fx)
{
    storeq_free(fx->q);
    store_close(fx->s);
    loop_free(fx->l);
}

/* The details of the events of kind, in the log's order, joined by ','. */
static void
details(struct store *s, const char *kind, char *out, size_t cap)
{
    struct event_row *ev;
    size_t n;
    out[0] = '\0';
    if (store_events(s, 0, 1000, &ev, &n, NULL))
        return;
    for (size_t i = 0; i < n; i++)
        if (strcmp(ev[i].kind, kind) == 0) {
            size_t len = strlen(out);
            snprintf(out + len, cap - len, "%s%s", len ? "," : "", ev[i].detail);
        }
    free(ev);
}

T_CASE(storeq_writes_in_the_order_posted)
{
    struct sf_err err;
    struct fixture fx;
    T_OK(setup(&fx, "order", &err), &err);
    int64_t id = fx.id;
    /* a printer's print as the printer module posts it: nothing waits in between */
    struct answer start = { 0 }, pause = { 0 };
    struct job_event_args sa = { .printer = "mk3" };
    T_OK(storeq_printer_set(fx.q, "mk3", PRINTER_IDLE), NULL);
    T_OK(storeq_job_event(fx.q, id, JOB_EV_START, &sa, "mk3", on_event, &start), NULL);
    T_OK(storeq_printer_set(fx.q, "mk3", PRINTER_PRINTING), NULL);
    for (int i = 1; i <= 30; i++) {
        char what[16];
        snprintf(what, sizeof(what), "n%d", i);
        T_OK(storeq_printer_note(fx.q, "mk3", "printer-command", what), NULL);
        struct store_progress p = { id, i * 10, false, 0 };
        T_OK(storeq_jobs_progress(fx.q, &p, 1), NULL);
    }
    /* legal only after the START: it is written after it */
    struct job_event_args pa = { .lines_acked = 305 };
    T_OK(storeq_job_event(fx.q, id, JOB_EV_PAUSE, &pa, "mk3", on_event, &pause), NULL);
    T_OK(storeq_printer_bed_set(fx.q, "mk3", true), NULL);
    T_OK(storeq_printer_bed_set(fx.q, "mk3", false), NULL);
    T_OK(storeq_printer_bed_set(fx.q, "mk3", true), NULL);
    T_OK(storeq_sync(fx.q, -1, &err), &err);
    T_EQ_INT(storeq_depth(fx.q), 0);
    struct job_row j;
    T_OK(store_job_get(fx.s, id, &j, &err), &err);
    T_EQ_INT(j.state, JOB_PAUSED);
    T_EQ_INT(j.lines_acked, 305);
    bool full = false;
    T_OK(store_printer_bed_get(fx.s, "mk3", &full, &err), &err);
    T_TRUE(full);
    char got[1024], want[1024] = "";
    details(fx.s, "printer-command", got, sizeof(got));
    for (int i = 1; i <= 30; i++) {
        size_t len = strlen(want);
        snprintf(want + len, sizeof(want) - len, "%sn%d", i > 1 ? "," : "", i);
    }
    T_EQ_STR(got, want);
    T_TRUE(answered(fx.l, &pause));
    T_EQ_INT(start.calls, 1);
    T_EQ_INT(start.rc, SF_OK);
    T_EQ_INT(start.to, JOB_PRINTING);
    T_EQ_INT(pause.rc, SF_OK);
    T_EQ_INT(pause.to, JOB_PAUSED);
    T_TRUE(start.on_loop && pause.on_loop);
    T_OK(store_check(fx.s, &err), &err);
    teardown(&fx);
}

static int n_logged;
static char logged[SF_ERR_MSG_MAX];

static void
sink(void *ud, enum log_level level, const char *subsys, const char *printer, const char *msg)
{
    (void)ud;
    (void)subsys;
    if (level == LOG_ERROR && printer && strcmp(printer, "mk3") == 0) {
        n_logged++;
        snprintf(logged, sizeof(logged), "%s", msg);
    }
}

T_CASE(storeq_reports_each_failure_once_on_the_loop)
{
    struct sf_err err;
    struct fixture fx;
    T_OK(setup(&fx, "fail", &err), &err);
    int64_t id = fx.id;
    struct answer twice = { 0 }, missing = { 0 };
    /* not legal from ready: the store's message comes back, once */
    T_OK(storeq_job_event(fx.q, id, JOB_EV_PAUSE, NULL, "mk3", on_event, &twice), NULL);
    struct job_event_args sa = { .printer = "mk3" };
    T_OK(storeq_job_event(fx.q, id + 100, JOB_EV_START, &sa, "mk3", on_event, &missing), NULL);
    T_TRUE(answered(fx.l, &twice) && answered(fx.l, &missing));
    T_EQ_INT(twice.rc, SF_EINVAL);
    T_TRUE(strstr(twice.msg, "pause") != NULL);
    T_EQ_INT(missing.rc, SF_ENOTFOUND);
    /* with no callback: logged for the printer named, and counted */
    n_logged = 0;
    log_set_sink(sink, NULL);
    struct answer after = { 0 };
    T_OK(storeq_job_event(fx.q, id, JOB_EV_RESUME, NULL, "mk3", NULL, NULL), NULL);
    T_OK(storeq_job_event(fx.q, id, JOB_EV_START, &sa, "mk3", on_event, &after), NULL);
    T_TRUE(answered(fx.l, &after));
    log_set_sink(NULL, NULL);
    T_EQ_INT(n_logged, 1);
    T_TRUE(strstr(logged, "resume") != NULL);
    for (int i = 0; i < 5; i++)
        loop_run_once(fx.l, 0); /* nothing more comes */
    T_EQ_INT(twice.calls, 1);
    T_EQ_INT(missing.calls, 1);
    T_EQ_INT(after.calls, 1);
    T_EQ_INT(after.rc, SF_OK);
    struct storeq_stats st;
    storeq_stats(fx.q, &st);
    T_EQ_INT(st.posted, 4);
    T_EQ_INT(st.done, 4);
    T_EQ_INT(st.failed, 3); /* the pause, the unknown job, the resume: the start is legal */
    T_EQ_INT(st.retries, 0);
    teardown(&fx);
}

T_CASE(storeq_free_writes_what_is_queued)
{
    struct sf_err err;
    struct fixture fx;
    T_OK(setup(&fx, "drain", &err), &err);
    int64_t id = fx.id;
    struct answer start = { 0 };
    struct job_event_args sa = { .printer = "mk3" };
    T_OK(storeq_job_event(fx.q, id, JOB_EV_START, &sa, "mk3", on_event, &start), NULL);
    for (int i = 0; i < 200; i++)
        T_OK(storeq_printer_note(fx.q, "mk3", "printer-heat", "off"), NULL);
    struct store_progress p = { id, 777, false, 0 };
    T_OK(storeq_jobs_progress(fx.q, &p, 1), NULL);
    struct job_event_args ca = { .reason = "the daemon stopped" };
    T_OK(storeq_job_event(fx.q, id, JOB_EV_CRASHED, &ca, "mk3", NULL, NULL), NULL);
    storeq_free(fx.q); /* at once: no loop turn in between */
    fx.q = NULL;
    T_EQ_INT(start.calls, 1); /* delivered by the free */
    T_EQ_INT(start.rc, SF_OK);
    struct job_row j;
    T_OK(store_job_get(fx.s, id, &j, &err), &err);
    T_EQ_INT(j.state, JOB_INTERRUPTED);
    T_EQ_INT(j.lines_acked, 777);
    char got[4096];
    details(fx.s, "printer-heat", got, sizeof(got));
    T_EQ_INT(strlen(got), 200 * 4 - 1); /* "off" 200 times, joined */
    teardown(&fx);
}

static void
count_commit(void *ud)
{
    ++*(int *)ud;
}

T_CASE(storeq_waits_out_a_locked_database_without_the_loop)
{
    struct sf_err err;
    struct fixture fx;
    T_OK(setup(&fx, "locked", &err), &err);
    int64_t id = fx.id;
    struct job_event_args sa = { .printer = "mk3" };
    T_OK(store_job_event(fx.s, id, JOB_EV_START, &sa, NULL, &err), &err);
    /* another process's tool holds the write lock */
    struct sqldb *other = t_store_lock(fx.dir);
    T_TRUE(other != NULL);
    struct answer note = { 0 };
    struct job_event_args pa = { .lines_acked = 5 };
    /* posts return at once: the first write now waits for the lock on the thread */
    for (int i = 1; i <= 500; i++) {
        struct store_progress p = { id, i, false, 0 };
        T_OK(storeq_jobs_progress(fx.q, &p, 1), NULL);
    }
    struct storeq_stats st;
    storeq_stats(fx.q, &st);
    T_TRUE(st.posted <= 2); /* progress folded into one or two writes */
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; clock_mono_ms() < end;) {
        storeq_stats(fx.q, &st);
        if (st.retries > 0)
            break;
        loop_run_once(fx.l, 10);
    }
    T_TRUE(st.retries > 0); /* it failed busy and waits to try again */
    T_TRUE(st.depth > 0);
    /* a caller that must see the queue written is told "busy", not held */
    int commits = 0;
    storeq_set_commit(fx.q, count_commit, &commits);
    T_EQ_INT(storeq_sync(fx.q, 50, &err), SF_EBUSY); /* busy: try again (503), not a refusal */
    T_TRUE(strstr(err.msg, "the store is busy") != NULL);
    t_store_unlock(other);
    /* woken once the queue is written, though progress alone logs no event */
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; !commits && clock_mono_ms() < end;)
        loop_run_once(fx.l, 10);
    T_EQ_INT(commits, 1);
    T_OK(storeq_printer_note(fx.q, "mk3", "printer-command", "after the lock"), NULL);
    T_OK(storeq_job_event(fx.q, id, JOB_EV_PAUSE, &pa, "mk3", on_event, &note), NULL);
    T_TRUE(answered(fx.l, &note));
    T_EQ_INT(note.rc, SF_OK);
    storeq_stats(fx.q, &st);
    T_EQ_INT(st.failed, 0);
    T_EQ_INT(st.depth, 0);
    struct job_row j;
    T_OK(store_job_get(fx.s, id, &j, &err), &err);
    T_EQ_INT(j.state, JOB_PAUSED);
    T_EQ_INT(j.lines_acked, 500); /* the last progress posted, folded into one write */
    char got[256];
    details(fx.s, "printer-command", got, sizeof(got));
    T_EQ_STR(got, "after the lock");
    teardown(&fx);
}

/* A write the database refuses for good (here a trigger's error, as a constraint or a byte
   sequence the encoding refuses would be) is reported at once: not retried, not holding
   the writes behind it for STOREQ_RETRY_MS. */
T_CASE(storeq_reports_a_permanent_failure_at_once)
{
    struct sf_err err;
    struct fixture fx;
    T_OK(setup(&fx, "poison", &err), &err);
    const char *trigger =
        t_store_pg()
            ? "CREATE FUNCTION poison() RETURNS trigger AS $$ BEGIN IF NEW.detail = 'poison'"
              " THEN RAISE EXCEPTION 'poisoned note' USING ERRCODE = 'check_violation'; END IF;"
              " RETURN NEW; END $$ LANGUAGE plpgsql;"
              " CREATE TRIGGER poison BEFORE INSERT ON events FOR EACH ROW EXECUTE FUNCTION"
              " poison()"
            : "CREATE TRIGGER poison BEFORE INSERT ON events WHEN NEW.detail = 'poison'"
              " BEGIN SELECT RAISE(ABORT, 'poisoned note'); END";
    T_OK(t_store_exec(fx.dir, trigger), NULL);
    n_logged = 0;
    log_set_sink(sink, NULL);
    struct answer after = { 0 };
    T_OK(storeq_printer_note(fx.q, "mk3", "printer-command", "poison"), NULL);
    T_OK(storeq_printer_note(fx.q, "mk3", "printer-command", "after it"), NULL);
    struct job_event_args pa = { .printer = "mk3" };
    T_OK(storeq_job_event(fx.q, fx.id, JOB_EV_START, &pa, "mk3", on_event, &after), NULL);
    T_TRUE(answered(fx.l, &after));
    log_set_sink(NULL, NULL);
    T_EQ_INT(after.rc, SF_OK);
    T_EQ_INT(n_logged, 1);
    T_TRUE(strstr(logged, "poisoned note") != NULL);
    struct storeq_stats st;
    storeq_stats(fx.q, &st);
    T_EQ_INT(st.failed, 1);
    T_EQ_INT(st.retries, 0);
    char got[256];
    details(fx.s, "printer-command", got, sizeof(got));
    T_EQ_STR(got, "after it");
    teardown(&fx);
}

/* Shutdown with the database held busy: the first write waits out storeq_free's window, the
   ones after it fail at once (each used to wait out its own busy timeout, 5 s apiece). */
T_CASE(storeq_free_gives_up_once_on_a_locked_database)
{
    struct sf_err err;
    struct fixture fx;
    T_OK(setup(&fx, "stuck", &err), &err);
    struct sqldb *other = t_store_lock(fx.dir);
    T_TRUE(other != NULL);
    struct answer a[4] = { { 0 } };
    struct job_event_args sa = { .printer = "mk3" };
    for (int i = 0; i < 4; i++)
        T_OK(storeq_job_event(fx.q, fx.id, JOB_EV_START, &sa, "mk3", on_event, &a[i]), NULL);
    storeq_free(fx.q);
    fx.q = NULL;
    t_store_unlock(other);
    T_EQ_INT(a[0].calls, 1);
    T_EQ_INT(a[0].rc, SF_EBUSY);
    /* SQLite's "database is locked", PostgreSQL's "lock timeout" */
    T_TRUE(strstr(a[0].msg, "lock") != NULL || !printf("    busy: %s\n", a[0].msg));
    for (int i = 1; i < 4; i++) {
        T_EQ_INT(a[i].calls, 1);
        T_EQ_INT(a[i].rc, SF_EUNREACH);
        T_TRUE(strstr(a[i].msg, "through shutdown") != NULL);
    }
    teardown(&fx);
}

/* A caller's call on the thread: the job's state it finds, then a reason written with it. */
struct call_arg {
    int64_t id;
    bool on_thread; /* it ran off the loop's thread */
    enum job_state saw;
    int runs;
};

static int
call_fn(struct store *s, void *ud, struct sf_err *err)
{
    struct call_arg *c = ud;
    c->runs++;
    c->on_thread = !pthread_equal(pthread_self(), loop_thread);
    struct job_row j;
    int rc = store_job_get(s, c->id, &j, err);
    if (rc)
        return rc;
    c->saw = j.state;
    return store_printer_bed_set(s, "mk3", true, err);
}

static int
refuse_fn(struct store *s, void *ud, struct sf_err *err)
{
    (void)s;
    (void)ud;
    return sf_err_set(err, SF_EINVAL, "refused by the call");
}

/*
 * storeq_call runs the caller's function on the thread with its connection,
 * after what was posted before it (it sees the START), and answers once on
 * the loop with its result; a barrier answers after every request before it
 * has run, and a call's refusal comes back to its callback, not retried.
 */
T_CASE(storeq_call_and_barrier_answer_in_order_on_the_loop)
{
    struct sf_err err;
    struct fixture fx;
    T_OK(setup(&fx, "call", &err), &err);
    struct answer start = { 0 }, call = { 0 }, refused = { 0 }, barrier = { 0 };
    struct call_arg c = { .id = fx.id, .saw = (enum job_state) - 1 };
    struct job_event_args sa = { .printer = "mk3" };
    T_OK(storeq_job_event(fx.q, fx.id, JOB_EV_START, &sa, "mk3", on_event, &start), NULL);
    T_OK(storeq_call(fx.q, call_fn, &c, "mk3", on_event, &call), NULL);
    T_OK(storeq_call(fx.q, refuse_fn, NULL, "mk3", on_event, &refused), NULL);
    T_OK(storeq_printer_set(fx.q, "mk3", PRINTER_PRINTING), NULL);
    T_OK(storeq_barrier(fx.q, on_event, &barrier), NULL);
    T_TRUE(answered(fx.l, &barrier));
    /* delivered in the order posted: all before the barrier's */
    T_EQ_INT(start.calls, 1);
    T_EQ_INT(call.calls, 1);
    T_EQ_INT(refused.calls, 1);
    T_EQ_INT(barrier.calls, 1);
    T_TRUE(call.on_loop && barrier.on_loop);
    T_EQ_INT(call.rc, SF_OK);
    T_TRUE(c.on_thread);
    T_EQ_INT(c.runs, 1);
    T_EQ_INT(c.saw, JOB_PRINTING); /* the START before it was written */
    T_EQ_INT(refused.rc, SF_EINVAL);
    T_EQ_STR(refused.msg, "refused by the call");
    T_EQ_INT(barrier.rc, SF_OK);
    bool full = false;
    T_OK(store_printer_bed_get(fx.s, "mk3", &full, &err), &err);
    T_TRUE(full); /* the call's write */
    struct storeq_stats st;
    storeq_stats(fx.q, &st);
    T_EQ_INT(st.failed, 1); /* the refusal, counted */
    T_EQ_INT(st.retries, 0);
    teardown(&fx);
}
