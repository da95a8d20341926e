/*
 * test_job.c - job and printer state machines: every legal path, every
 * illegal event refused with a message, copies and retries counted.
 */
#include "../../src/farm/job.h"
#include "../../src/farm/printer.h"
#include "../t.h"

/* Drive a job through events; returns the final state or -1 on refusal. */
static int
run(enum job_state s, struct job_counts *c, const enum job_event *evs, int n)
{
    for (int i = 0; i < n; i++) {
        enum job_state to;
        if (job_next(s, evs[i], c, &to, NULL) != SF_OK)
            return -1;
        s = to;
    }
    return (int)s;
}

T_CASE(job_happy_path)
{
    struct job_counts c = { 1, 0, 0, 0 };
    enum job_event evs[] = { JOB_EV_PREPARE, JOB_EV_PREPARED, JOB_EV_START,
                             JOB_EV_PAUSE,   JOB_EV_RESUME,   JOB_EV_PRINT_DONE };
    T_EQ_INT(run(JOB_QUEUED, &c, evs, 6), JOB_DONE);
    T_EQ_INT(c.copies_done, 1);
}

T_CASE(job_copies_go_back_to_ready)
{
    struct job_counts c = { 3, 0, 0, 0 };
    enum job_state to;
    T_OK(job_next(JOB_PRINTING, JOB_EV_PRINT_DONE, &c, &to, NULL), NULL);
    T_EQ_INT(to, JOB_READY);
    T_OK(job_next(JOB_PRINTING, JOB_EV_PRINT_DONE, &c, &to, NULL), NULL);
    T_EQ_INT(to, JOB_READY);
    T_OK(job_next(JOB_PRINTING, JOB_EV_PRINT_DONE, &c, &to, NULL), NULL);
    T_EQ_INT(to, JOB_DONE);
    T_EQ_INT(c.copies_done, 3);
}

/* A pause that reaches the printer as its print ends: the printer says
   done and the job is done (farmd_net saw it stuck paused, "cannot
   print-done a paused job", while its printer took the next job). */
T_CASE(job_done_while_paused_is_done)
{
    struct job_counts c = { 1, 0, 0, 0 };
    enum job_state to;
    T_OK(job_next(JOB_PAUSED, JOB_EV_PRINT_DONE, &c, &to, NULL), NULL);
    T_EQ_INT(to, JOB_DONE);
    T_EQ_INT(c.copies_done, 1);
}

T_CASE(job_retries_then_fails)
{
    struct job_counts c = { 2, 0, 0, 2 };
    enum job_state to;
    T_OK(job_next(JOB_PRINTING, JOB_EV_PRINT_FAILED, &c, &to, NULL), NULL);
    T_EQ_INT(to, JOB_READY);
    T_OK(job_next(JOB_PAUSED, JOB_EV_PRINT_FAILED, &c, &to, NULL), NULL);
    T_EQ_INT(to, JOB_READY);
    T_EQ_INT(c.failures, 2);
    /* a success resets the budget for the next copy */
    T_OK(job_next(JOB_PRINTING, JOB_EV_PRINT_DONE, &c, &to, NULL), NULL);
    T_EQ_INT(c.failures, 0);
    T_EQ_INT(to, JOB_READY);
    for (int i = 0; i < 2; i++) {
        T_OK(job_next(JOB_PRINTING, JOB_EV_PRINT_FAILED, &c, &to, NULL), NULL);
        T_EQ_INT(to, JOB_READY);
    }
    T_OK(job_next(JOB_PRINTING, JOB_EV_PRINT_FAILED, &c, &to, NULL), NULL);
    T_EQ_INT(to, JOB_FAILED);
}

/* A start the printer refused ("not idle") waits again without spending a retry. */
T_CASE(job_refused_start_spends_no_retry)
{
    struct job_counts c = { 1, 0, 0, 0 };
    enum job_state to;
    for (int i = 0; i < 3; i++) {
        T_OK(job_next(JOB_PRINTING, JOB_EV_REFUSED, &c, &to, NULL), NULL);
        T_EQ_INT(to, JOB_READY);
    }
    T_EQ_INT(c.failures, 0);
    T_EQ_INT(c.copies_done, 0);
    T_EQ_INT(job_next(JOB_PAUSED, JOB_EV_REFUSED, &c, &to, NULL), SF_EINVAL);
    enum printer_state ps;
    T_OK(printer_next(PRINTER_PRINTING, PRINTER_EV_REFUSED, false, &ps, NULL), NULL);
    T_EQ_INT(ps, PRINTER_IDLE);
}

/* An operator's stop of one copy: the job prints it again, no counter moves. */
T_CASE(job_cancel_copy_prints_the_copy_again)
{
    static const enum job_state on_printer[] = { JOB_PRINTING, JOB_PAUSED },
                                elsewhere[] = { JOB_READY, JOB_DONE };
    for (size_t i = 0; i < 2; i++) {
        struct job_counts c = { 3, 1, 0, 1 };
        enum job_state to = JOB_DONE;
        T_OK(job_next(on_printer[i], JOB_EV_CANCEL_COPY, &c, &to, NULL), NULL);
        T_TRUE(to == JOB_READY && c.copies_done == 1 && c.failures == 0);
        T_EQ_INT(job_next(elsewhere[i], JOB_EV_CANCEL_COPY, &c, &to, NULL), SF_EINVAL);
    }
    T_EQ_STR(job_event_name(JOB_EV_CANCEL_COPY), "cancel-copy");
    enum printer_action a;
    T_TRUE(printer_action_parse("cancel-copy", &a) && a == PRINTER_ACT_CANCEL_COPY);
}

T_CASE(job_illegal_events_refused)
{
    struct job_counts c = { 1, 0, 0, 0 };
    struct sf_err err;
    enum job_state to = JOB_QUEUED;
    T_ERR(job_next(JOB_QUEUED, JOB_EV_START, &c, &to, &err), SF_EINVAL, &err,
          "cannot start a queued job");
    T_ERR(job_next(JOB_DONE, JOB_EV_CANCEL, &c, &to, &err), SF_EINVAL, &err,
          "cannot cancel a done job");
    T_ERR(job_next(JOB_READY, JOB_EV_PAUSE, &c, &to, &err), SF_EINVAL, &err, "pause");
    T_ERR(job_next(JOB_INTERRUPTED, JOB_EV_PRINT_DONE, &c, &to, &err), SF_EINVAL, &err,
          "interrupted");
    T_EQ_INT(c.copies_done, 0);
    T_EQ_INT(job_next(JOB_QUEUED, (enum job_event)99, &c, &to, &err), SF_EBUG);
}

T_CASE(job_terminal_states_have_no_exit)
{
    enum job_state term[] = { JOB_DONE, JOB_FAILED, JOB_CANCELLED };
    for (int i = 0; i < 3; i++) {
        T_TRUE(job_state_terminal(term[i]));
        for (int ev = 0; ev < JOB_EVENT_COUNT; ev++) {
            struct job_counts c = { 1, 0, 0, 5 };
            enum job_state to;
            T_EQ_INT(job_next(term[i], (enum job_event)ev, &c, &to, NULL), SF_EINVAL);
        }
    }
    T_TRUE(!job_state_terminal(JOB_INTERRUPTED));
}

T_CASE(job_crash_recovery_moves)
{
    struct job_counts c = { 1, 0, 0, 0 };
    enum job_state to;
    T_OK(job_next(JOB_PRINTING, JOB_EV_CRASHED, &c, &to, NULL), NULL);
    T_EQ_INT(to, JOB_INTERRUPTED);
    T_OK(job_next(JOB_PAUSED, JOB_EV_CRASHED, &c, &to, NULL), NULL);
    T_EQ_INT(to, JOB_INTERRUPTED);
    T_OK(job_next(JOB_PREPARING, JOB_EV_CRASHED, &c, &to, NULL), NULL);
    T_EQ_INT(to, JOB_QUEUED);
    T_EQ_INT(job_next(JOB_READY, JOB_EV_CRASHED, &c, &to, NULL), SF_EINVAL);
    T_OK(job_next(JOB_PREPARING, JOB_EV_DEFER, &c, &to, NULL), NULL);
    T_EQ_INT(to, JOB_QUEUED);
    /* the operator's three choices */
    T_OK(job_next(JOB_INTERRUPTED, JOB_EV_RESUME, &c, &to, NULL), NULL);
    T_EQ_INT(to, JOB_PRINTING);
    T_OK(job_next(JOB_INTERRUPTED, JOB_EV_RESTART, &c, &to, NULL), NULL);
    T_EQ_INT(to, JOB_READY);
    T_OK(job_next(JOB_INTERRUPTED, JOB_EV_CANCEL, &c, &to, NULL), NULL);
    T_EQ_INT(to, JOB_CANCELLED);
    T_EQ_INT(c.failures, 0);
}

T_CASE(job_can_transition_matches_next)
{
    T_TRUE(job_can_transition(JOB_QUEUED, JOB_PREPARING));
    T_TRUE(job_can_transition(JOB_PRINTING, JOB_DONE));
    T_TRUE(job_can_transition(JOB_PRINTING, JOB_FAILED));
    T_TRUE(job_can_transition(JOB_PAUSED, JOB_PRINTING));
    T_TRUE(!job_can_transition(JOB_QUEUED, JOB_PRINTING));
    T_TRUE(!job_can_transition(JOB_DONE, JOB_QUEUED));
    T_TRUE(!job_can_transition(JOB_READY, JOB_PAUSED));
}

T_CASE(job_names_round_trip)
{
    for (int i = 0; i < JOB_STATE_COUNT; i++) {
        enum job_state s;
        T_TRUE(job_state_parse(job_state_name((enum job_state)i), &s));
        T_EQ_INT(s, i);
    }
    enum job_state s;
    T_TRUE(!job_state_parse("bogus", &s));
    T_EQ_STR(job_state_name((enum job_state)42), "?");
    for (int i = 0; i < PRINTER_STATE_COUNT; i++) {
        enum printer_state p;
        T_TRUE(printer_state_parse(printer_state_name((enum printer_state)i), &p));
        T_EQ_INT(p, i);
    }
}

T_CASE(printer_bed_clear_gate)
{
    enum printer_state s;
    struct sf_err err;
    T_OK(printer_next(PRINTER_OFFLINE, PRINTER_EV_CONNECTED, false, &s, &err), &err);
    T_EQ_INT(s, PRINTER_IDLE);
    T_OK(printer_next(s, PRINTER_EV_START, false, &s, &err), &err);
    T_OK(printer_next(s, PRINTER_EV_PAUSE, false, &s, &err), &err);
    T_EQ_INT(s, PRINTER_PAUSED);
    T_OK(printer_next(s, PRINTER_EV_RESUME, false, &s, &err), &err);
    T_OK(printer_next(s, PRINTER_EV_FINISHED, false, &s, &err), &err);
    T_EQ_INT(s, PRINTER_AWAITING_CLEAR);
    T_ERR(printer_next(s, PRINTER_EV_START, false, &s, &err), SF_EINVAL, &err,
          "cannot start a printer that is awaiting-clear");
    T_OK(printer_next(s, PRINTER_EV_CLEARED, false, &s, &err), &err);
    T_EQ_INT(s, PRINTER_IDLE);
    /* auto-eject skips the gate */
    T_OK(printer_next(PRINTER_PRINTING, PRINTER_EV_FINISHED, true, &s, &err), &err);
    T_EQ_INT(s, PRINTER_IDLE);
}

T_CASE(printer_faults_and_drops)
{
    enum printer_state s;
    struct sf_err err;
    for (int st = 0; st < PRINTER_STATE_COUNT; st++) {
        int rc = printer_next((enum printer_state)st, PRINTER_EV_DISCONNECTED, false, &s, &err);
        if (st == PRINTER_OFFLINE) {
            T_EQ_INT(rc, SF_EINVAL);
        } else {
            T_OK(rc, &err);
            T_EQ_INT(s, PRINTER_OFFLINE);
        }
    }
    T_OK(printer_next(PRINTER_PRINTING, PRINTER_EV_FAULT, false, &s, &err), &err);
    T_EQ_INT(s, PRINTER_ERROR);
    T_ERR(printer_next(s, PRINTER_EV_CONNECTED, false, &s, &err), SF_EINVAL, &err, "error");
    T_OK(printer_next(PRINTER_ERROR, PRINTER_EV_CLEARED, false, &s, &err), &err);
    T_EQ_INT(s, PRINTER_IDLE);
    T_ERR(printer_next(PRINTER_IDLE, PRINTER_EV_CLEARED, false, &s, &err), SF_EINVAL, &err,
          "cannot clear a printer that is idle");
}

T_CASE(job_opts_defaults_valid_and_fields_checked)
{
    struct job_opts o;
    struct sf_err err;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "bracket.stl");
    T_OK(job_opts_validate(&o, &err), &err);
    o.copies = 0;
    T_ERR(job_opts_validate(&o, &err), SF_EINVAL, &err, "copies: 0");
    o.copies = 2;
    snprintf(o.method, sizeof(o.method), "magic");
    T_ERR(job_opts_validate(&o, &err), SF_EINVAL, &err, "method: 'magic'");
    snprintf(o.method, sizeof(o.method), "slim");
    o.deviation_mm = -1;
    T_ERR(job_opts_validate(&o, &err), SF_EINVAL, &err, "deviation_mm");
    o.deviation_mm = 0.0 / 0.0;
    T_ERR(job_opts_validate(&o, &err), SF_EINVAL, &err, "deviation_mm");
    o.deviation_mm = 1;
    snprintf(o.printer, sizeof(o.printer), "mk3");
    snprintf(o.group, sizeof(o.group), "big");
    T_ERR(job_opts_validate(&o, &err), SF_EINVAL, &err, "one target");
    o.group[0] = '\0';
    snprintf(o.material, sizeof(o.material), "PLA; drop");
    T_ERR(job_opts_validate(&o, &err), SF_EINVAL, &err, "material");
}

T_CASE(job_names_reject_traversal)
{
    T_TRUE(job_name_valid("part v2.stl"));
    T_TRUE(!job_name_valid("../etc/passwd"));
    T_TRUE(!job_name_valid("a/b.stl"));
    T_TRUE(!job_name_valid("a\\b.stl"));
    T_TRUE(!job_name_valid(".."));
    T_TRUE(!job_name_valid("."));
    T_TRUE(!job_name_valid(""));
    T_TRUE(!job_name_valid("a\nb"));
    T_TRUE(job_name_valid("st\xc3\xbctze.stl")); /* UTF-8 u-umlaut */
    T_TRUE(!job_name_valid("bad\xc3.stl"));
    T_TRUE(!job_name_valid("over\xc0\xaf.stl")); /* overlong '/' */
}

T_CASE(job_defer_prepare_failed_and_restart_end_a_hosts_claim)
{
    int n = 0;
    for (int ev = 0; ev < JOB_EVENT_COUNT; ev++)
        n += job_event_releases_claim((enum job_event)ev);
    T_EQ_INT(n, 3);
    T_TRUE(job_event_releases_claim(JOB_EV_DEFER));
    T_TRUE(job_event_releases_claim(JOB_EV_PREPARE_FAILED));
    T_TRUE(job_event_releases_claim(JOB_EV_RESTART));
    /* a host holds its job through a print and its copies */
    T_TRUE(!job_event_releases_claim(JOB_EV_PREPARED));
    T_TRUE(!job_event_releases_claim(JOB_EV_PRINT_DONE));
}
