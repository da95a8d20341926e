/*
 * job.c - job and printer state machines as tables.
 *
 * Why: every component that moves a job (the store's transactions, the
 * scheduler, the API, crash recovery) must agree on what is legal, so the
 * rules live in one place as data.  Each event has a small table of
 * (from -> to) rows; the only events that need more than a table are
 * PRINT_DONE (more copies to go?) and PRINT_FAILED (retries left?), which
 * read and update struct job_counts.  Printer moves work the same way, with
 * auto-eject deciding where a finished print leads.
 *
 * Pure functions, no state: any thread.
 */
#include "job.h"

#include <stdio.h>
#include <string.h>

#include "../base/utf8.h"

static const char *const job_names[JOB_STATE_COUNT] = {
    "queued", "preparing", "ready",     "printing",    "paused",
    "done",   "failed",    "cancelled", "interrupted",
};

static const char *const job_event_names[JOB_EVENT_COUNT] = {
    "prepare",      "prepared", "prepare-failed", "start",   "pause", "resume",  "print-done",
    "print-failed", "cancel",   "crashed",        "restart", "defer", "refused", "cancel-copy",
};

/* One legal move: in state `from`, the event leads to `to`. */
struct move {
    signed char from; /* enum job_state / printer_state, -1 ends a list */
    signed char to;   /* where it leads */
};

/* Per event, its legal moves (at most 6), ended by from = -1. */
static const struct move job_moves[JOB_EVENT_COUNT][7] = {
    [JOB_EV_PREPARE] = { { JOB_QUEUED, JOB_PREPARING }, { -1, 0 } },
    /* ready -> ready: prepared again for a printer of another key (farm.c) */
    [JOB_EV_PREPARED] = { { JOB_PREPARING, JOB_READY }, { JOB_READY, JOB_READY }, { -1, 0 } },
    [JOB_EV_PREPARE_FAILED] = { { JOB_PREPARING, JOB_FAILED }, { -1, 0 } },
    [JOB_EV_START] = { { JOB_READY, JOB_PRINTING }, { -1, 0 } },
    [JOB_EV_PAUSE] = { { JOB_PRINTING, JOB_PAUSED }, { -1, 0 } },
    [JOB_EV_RESUME] = { { JOB_PAUSED, JOB_PRINTING },
                        { JOB_INTERRUPTED, JOB_PRINTING },
                        { -1, 0 } },
    /* `to` of the two below is the "more to go" outcome; job_next decides. */
    /* paused -> done: a pause that reached the printer as the print ended */
    [JOB_EV_PRINT_DONE] = { { JOB_PRINTING, JOB_READY }, { JOB_PAUSED, JOB_READY }, { -1, 0 } },
    [JOB_EV_PRINT_FAILED] = { { JOB_PRINTING, JOB_READY },
                              { JOB_PAUSED, JOB_READY },
                              { JOB_INTERRUPTED, JOB_READY },
                              { -1, 0 } },
    [JOB_EV_CANCEL] = { { JOB_QUEUED, JOB_CANCELLED },
                        { JOB_PREPARING, JOB_CANCELLED },
                        { JOB_READY, JOB_CANCELLED },
                        { JOB_PRINTING, JOB_CANCELLED },
                        { JOB_PAUSED, JOB_CANCELLED },
                        { JOB_INTERRUPTED, JOB_CANCELLED },
                        { -1, 0 } },
    [JOB_EV_CRASHED] = { { JOB_PRINTING, JOB_INTERRUPTED },
                         { JOB_PAUSED, JOB_INTERRUPTED },
                         { JOB_PREPARING, JOB_QUEUED },
                         { -1, 0 } },
    [JOB_EV_RESTART] = { { JOB_INTERRUPTED, JOB_READY }, { -1, 0 } },
    [JOB_EV_DEFER] = { { JOB_PREPARING, JOB_QUEUED }, { -1, 0 } },
    /* no counter moves: the printer said "not now", the print never began */
    [JOB_EV_REFUSED] = { { JOB_PRINTING, JOB_READY }, { -1, 0 } },
    /* no counter moves: the operator stopped the copy, not the printer failing it */
    [JOB_EV_CANCEL_COPY] = { { JOB_PRINTING, JOB_READY }, { JOB_PAUSED, JOB_READY }, { -1, 0 } },
};

static int
find_move(const struct move *m, int from)
{
    for (; m->from >= 0; m++)
        if (m->from == from)
            return m->to;
    return -1;
}

int
job_next(enum job_state from, enum job_event ev, struct job_counts *c, enum job_state *to,
         struct sf_err *err)
{
    if ((unsigned)ev >= JOB_EVENT_COUNT || (unsigned)from >= JOB_STATE_COUNT)
        return sf_err_set(err, SF_EBUG, "job: event %d or state %d out of range", (int)ev,
                          (int)from);
    int t = find_move(job_moves[ev], from);
    if (t < 0)
        return sf_err_set(err, SF_EINVAL, "cannot %s a %s job", job_event_names[ev],
                          job_names[from]);
    if (ev == JOB_EV_PRINT_DONE) {
        if (c->copies_done + 1 >= c->copies)
            t = JOB_DONE;
        c->copies_done++;
        c->failures = 0;
    } else if (ev == JOB_EV_PRINT_FAILED) {
        if (c->failures >= c->max_retries)
            t = JOB_FAILED;
        c->failures++;
    }
    /* RESTART (the operator prints an interrupted copy again) does not
       spend the retry budget: the daemon died, not the print. */
    *to = (enum job_state)t;
    return SF_OK;
}

bool
job_can_transition(enum job_state from, enum job_state to)
{
    for (int ev = 0; ev < JOB_EVENT_COUNT; ev++) {
        int t = find_move(job_moves[ev], from);
        if (t < 0)
            continue;
        if (t == (int)to)
            return true;
        if (ev == JOB_EV_PRINT_DONE && to == JOB_DONE)
            return true;
        if (ev == JOB_EV_PRINT_FAILED && to == JOB_FAILED)
            return true;
    }
    return false;
}

bool
job_event_releases_claim(enum job_event ev)
{
    return ev == JOB_EV_DEFER || ev == JOB_EV_PREPARE_FAILED || ev == JOB_EV_RESTART;
}

bool
job_state_terminal(enum job_state s)
{
    return s == JOB_DONE || s == JOB_FAILED || s == JOB_CANCELLED;
}

bool
job_state_on_printer(enum job_state s)
{
    return s == JOB_PRINTING || s == JOB_PAUSED;
}

const char *
job_state_name(enum job_state s)
{
    return (unsigned)s < JOB_STATE_COUNT ? job_names[s] : "?";
}

const char *
job_event_name(enum job_event ev)
{
    return (unsigned)ev < JOB_EVENT_COUNT ? job_event_names[ev] : "?";
}

bool
job_state_parse(const char *s, enum job_state *out)
{
    for (int i = 0; i < JOB_STATE_COUNT; i++)
        if (strcmp(s, job_names[i]) == 0) {
            *out = (enum job_state)i;
            return true;
        }
    return false;
}

static const char *const printer_names[PRINTER_STATE_COUNT] = {
    "offline", "idle", "printing", "paused", "error", "awaiting-clear",
};

static const char *const printer_event_names[PRINTER_EVENT_COUNT] = {
    "connect", "disconnect", "start", "pause", "resume", "finish", "fault", "clear", "refuse",
};

/* DISCONNECTED and FAULT are legal from every state but their own target. */
static const struct move printer_moves[PRINTER_EVENT_COUNT][7] = {
    [PRINTER_EV_CONNECTED] = { { PRINTER_OFFLINE, PRINTER_IDLE }, { -1, 0 } },
    [PRINTER_EV_DISCONNECTED] = { { PRINTER_IDLE, PRINTER_OFFLINE },
                                  { PRINTER_PRINTING, PRINTER_OFFLINE },
                                  { PRINTER_PAUSED, PRINTER_OFFLINE },
                                  { PRINTER_ERROR, PRINTER_OFFLINE },
                                  { PRINTER_AWAITING_CLEAR, PRINTER_OFFLINE },
                                  { -1, 0 } },
    [PRINTER_EV_START] = { { PRINTER_IDLE, PRINTER_PRINTING }, { -1, 0 } },
    [PRINTER_EV_PAUSE] = { { PRINTER_PRINTING, PRINTER_PAUSED }, { -1, 0 } },
    [PRINTER_EV_RESUME] = { { PRINTER_PAUSED, PRINTER_PRINTING }, { -1, 0 } },
    /* `to` is for a printer without auto-eject; printer_next adjusts. */
    [PRINTER_EV_FINISHED] = { { PRINTER_PRINTING, PRINTER_AWAITING_CLEAR },
                              { PRINTER_PAUSED, PRINTER_AWAITING_CLEAR },
                              { -1, 0 } },
    [PRINTER_EV_FAULT] = { { PRINTER_IDLE, PRINTER_ERROR },
                           { PRINTER_PRINTING, PRINTER_ERROR },
                           { PRINTER_PAUSED, PRINTER_ERROR },
                           { PRINTER_AWAITING_CLEAR, PRINTER_ERROR },
                           { -1, 0 } },
    /* After an error the operator inspects the bed too, so clearing an
       error also means "bed clear". */
    [PRINTER_EV_CLEARED] = { { PRINTER_AWAITING_CLEAR, PRINTER_IDLE },
                             { PRINTER_ERROR, PRINTER_IDLE },
                             { -1, 0 } },
    [PRINTER_EV_REFUSED] = { { PRINTER_PRINTING, PRINTER_IDLE }, { -1, 0 } },
};

int
printer_next(enum printer_state from, enum printer_event ev, bool auto_eject,
             enum printer_state *to, struct sf_err *err)
{
    if ((unsigned)ev >= PRINTER_EVENT_COUNT || (unsigned)from >= PRINTER_STATE_COUNT)
        return sf_err_set(err, SF_EBUG, "printer: event %d or state %d out of range", (int)ev,
                          (int)from);
    int t = find_move(printer_moves[ev], from);
    if (t < 0)
        return sf_err_set(err, SF_EINVAL, "cannot %s a printer that is %s", printer_event_names[ev],
                          printer_names[from]);
    if (ev == PRINTER_EV_FINISHED && auto_eject)
        t = PRINTER_IDLE;
    *to = (enum printer_state)t;
    return SF_OK;
}

const char *
printer_state_name(enum printer_state s)
{
    return (unsigned)s < PRINTER_STATE_COUNT ? printer_names[s] : "?";
}

const char *
printer_event_name(enum printer_event ev)
{
    return (unsigned)ev < PRINTER_EVENT_COUNT ? printer_event_names[ev] : "?";
}

bool
printer_state_parse(const char *s, enum printer_state *out)
{
    for (int i = 0; i < PRINTER_STATE_COUNT; i++)
        if (strcmp(s, printer_names[i]) == 0) {
            *out = (enum printer_state)i;
            return true;
        }
    return false;
}

void
job_opts_init(struct job_opts *o)
{
    memset(o, 0, sizeof(*o));
    snprintf(o->method, sizeof(o->method), "orient");
    o->deviation_mm = 0.5;
    o->copies = 1;
    o->max_retries = 1;
}

bool
job_name_valid(const char *s)
{
    size_t n = strlen(s);
    if (n == 0 || n >= JOB_NAME_MAX || strcmp(s, ".") == 0 || strstr(s, ".."))
        return false;
    for (const unsigned char *p = (const unsigned char *)s; *p;) {
        if (*p < 0x20 || *p == 0x7f || *p == '/' || *p == '\\')
            return false;
        int len = utf8_seq(p);
        if (len <= 0)
            return false;
        p += len;
    }
    return true;
}

/* Names of printers, groups and materials: letters, digits, "-_." only. */
static bool
ident_valid(const char *s)
{
    for (; *s; s++)
        if (!((*s >= 'a' && *s <= 'z') || (*s >= 'A' && *s <= 'Z') || (*s >= '0' && *s <= '9') ||
              *s == '-' || *s == '_' || *s == '.'))
            return false;
    return true;
}

int
job_opts_validate(const struct job_opts *o, struct sf_err *err)
{
    static const char *const methods[] = { "none", "orient", "slim", "surface" };
    if (!job_name_valid(o->name))
        return sf_err_set(err, SF_EINVAL,
                          "name: '%s' is not a plain file name (no '/', '\\', '..' or control "
                          "characters, 1..%d bytes)",
                          o->name, JOB_NAME_MAX - 1);
    bool known = false;
    for (size_t i = 0; i < sizeof(methods) / sizeof(methods[0]); i++)
        known |= strcmp(o->method, methods[i]) == 0;
    if (!known)
        return sf_err_set(err, SF_EINVAL, "method: '%s' is not one of none, orient, slim, surface",
                          o->method);
    if (!(o->deviation_mm >= 0 && o->deviation_mm <= 10))
        return sf_err_set(err, SF_EINVAL, "deviation_mm: %g is not in 0..10", o->deviation_mm);
    if (!(o->overhang_deg >= 0 && o->overhang_deg <= 89))
        return sf_err_set(err, SF_EINVAL, "overhang_deg: %g is not in 0..89", o->overhang_deg);
    if (o->copies < 1 || o->copies > JOB_COPIES_MAX)
        return sf_err_set(err, SF_EINVAL, "copies: %d is not in 1..%d", o->copies, JOB_COPIES_MAX);
    if (o->max_retries < 0 || o->max_retries > JOB_RETRIES_MAX)
        return sf_err_set(err, SF_EINVAL, "max_retries: %d is not in 0..%d", o->max_retries,
                          JOB_RETRIES_MAX);
    if (o->priority < -JOB_PRIORITY_MAX || o->priority > JOB_PRIORITY_MAX)
        return sf_err_set(err, SF_EINVAL, "priority: %d is not in -%d..%d", o->priority,
                          JOB_PRIORITY_MAX, JOB_PRIORITY_MAX);
    if (!ident_valid(o->material))
        return sf_err_set(err, SF_EINVAL, "material: '%s' may hold only letters, digits, -_.",
                          o->material);
    if (!ident_valid(o->printer))
        return sf_err_set(err, SF_EINVAL, "printer: '%s' may hold only letters, digits, -_.",
                          o->printer);
    if (!ident_valid(o->group))
        return sf_err_set(err, SF_EINVAL, "group: '%s' may hold only letters, digits, -_.",
                          o->group);
    if (o->printer[0] && o->group[0])
        return sf_err_set(err, SF_EINVAL, "printer and group: give one target, not both");
    return SF_OK;
}
