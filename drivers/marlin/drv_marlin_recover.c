/*
 * drv_marlin_recover.c - what the Marlin driver makes of acknowledgements
 * and of their absence (drv_marlin_int.h).
 *
 * What: counts acknowledged job lines (and lines a silence only assumed
 * handled), rewinds on a Resend and waits for the stale replies to settle,
 * asks for a barrier (a numbered M105 probe) when a reply does not add up,
 * and acts on a deadline: the silence longer than what is in flight can
 * take, after which the window resyncs or a probe goes out.
 *
 * Thread: loop thread.
 */
#include "drv_marlin_int.h"

#include <stdint.h>

#include "../../src/base/log.h"

#define PROBES_MAX     5     /* deadlines in a row without a reply before the job may fail */
#define SILENCE_MS     30000 /* ... and no byte at all for this long */
#define GARBLED_MAX    40    /* deadlines in a row with only unreadable replies: fail */
#define PLANNER_BLOCKS 16    /* Marlin's BLOCK_BUFFER_SIZE: moves acknowledged, not yet run */
#define KEEPALIVE_MS   3000  /* busy/wait reports come at least this often once seen */
#define CLIMB_LINES    16    /* clean lines per step back up after a rewind */
#define UNMATCHED_MAX  8     /* probes answered by oks not theirs, no job line confirmed: fail */
#define STALL_MS       (30 * 60 * 1000) /* no job line confirmed for this long: fail */

/*
 * When the printer's next reply is overdue, ms: after the last reply, or
 * the end of the moves it has planned, the lines in flight and the margin.
 * How long the printer may legitimately take:
 * the lines in flight, and the moves acknowledged before them that may
 * still wait in the planner (an ok leaves once a move is planned, and the
 * next line waits for a free block): busy_until_ms follows them, each
 * acknowledged move starting when the one before it ends at the latest.  A firmware that has shown
 * it reports while it blocks (busy, M109's temperatures) gets only the report interval for a
 * blocking command: those reports count as replies.
 */
int64_t
marlin_deadline_ms(const struct marlin *m)
{
    int32_t cap = m->keepalive_seen ? KEEPALIVE_MS : INT32_MAX;
    int32_t heat_cap = m->keepalive_seen || m->heat_reports_seen ? KEEPALIVE_MS : INT32_MAX;
    int64_t from = m->busy_until_ms > m->progress_ms ? m->busy_until_ms : m->progress_ms;
    return from + linewin_cost(&m->win, m->win.acked + 1, m->win.next - 1, cap, heat_cap) +
           m->margin_ms;
}

/*
 * Something did not add up (an unreadable reply, an ok for a line that
 * cannot be, an error without its Resend): ask for a barrier.  The probe is
 * a numbered M105 in the stream, inside the window like any line: Marlin
 * checks its number and checksum, so garbled on the wire it is refused
 * (Resend), never run as another command; M105 runs in order and answers
 * "ok T:..." itself, so its answer means every line before it was handled.
 */
void
marlin_want_probe(struct marlin *m)
{
    if (m->probe_wanted || marlin_m105_in_flight(m) || m->phase != PH_READY)
        return;
    m->st.probes++;
    if (m->win.window == 1 && m->win.in_flight > 0 && m->win.next > m->win.high &&
        !marlin_renumber_pending(m)) {
        /* In ping-pong the garbled reply was the one line's: nothing else
           will come, so the probe goes now, past the window. */
        struct sf_err err;
        if (marlin_push_host(m, "M105", TAG_M105, &err) > 0) {
            m->st.host_lines++;
            linewin_force(&m->win);
            marlin_pump(m);
        }
        return;
    }
    m->probe_wanted = true;
    marlin_inject_front(m, "M105");
}

/* The job lines among window lines from+1..to were run: lines_acked follows. */
void
marlin_report_acked(struct marlin *m, long from, long to)
{
    for (long n = from + 1; n <= to; n++) {
        long tag = linewin_tag(&m->win, n);
        if (tag >= 0 && (uint64_t)(tag + 1) > m->base.status.lines_acked)
            m->base.status.lines_acked = (uint64_t)(tag + 1);
    }
}

/*
 * A silence made the window count lines from+1..to as handled
 * (linewin_resync, linewin_rewind): the stream goes on, and the printer
 * refuses with a Resend what it did not have.  But nothing says they ran,
 * so they are not progress (lines_acked, where a resume starts) until a
 * reply acknowledges a line after them (credit), or a Resend says where
 * the printer is.  A printer that hung stays at the last line it answered.
 */
static void
provisional(struct marlin *m, long from, long to)
{
    if (to <= from)
        return;
    if (!m->unconfirmed_to)
        m->unconfirmed_from = from;
    if (to > m->unconfirmed_to)
        m->unconfirmed_to = to;
}

/* A reply acknowledged window lines from+1..to (and so every line before them). */
void
marlin_credit(struct marlin *m, long from, long to)
{
    if (to > from && m->unconfirmed_to) {
        marlin_report_acked(m, m->unconfirmed_from,
                            m->unconfirmed_to < to ? m->unconfirmed_to : to);
        m->unconfirmed_to = 0;
    }
    if (to > from && m->win.window < m->full_window) {
        /* Climb back from ping-pong one line per CLIMB_LINES clean lines. */
        m->clean += (int)(to - from);
        while (m->clean >= CLIMB_LINES && m->win.window < m->full_window) {
            m->clean -= CLIMB_LINES;
            m->win.window++;
        }
    }
    int64_t now = loop_now_ms(m->base.loop);
    if (to > from) {
        /* The planner holds PLANNER_BLOCKS moves at most: the bound never
           runs further ahead than the last ones acknowledged. */
        int planner = m->max_p + 1 > PLANNER_BLOCKS ? m->max_p + 1 : PLANNER_BLOCKS;
        /* Only moves run on after their ok: a wait's (M109, M190, G28, G4)
           ends with it.  Counting a heat-up's half-hour bound here left a
           line lost right after an M109 unprobed for that long. */
        if (m->busy_until_ms < now)
            m->busy_until_ms = now;
        m->busy_until_ms += linewin_cost_after_ok(&m->win, from + 1, to, INT32_MAX);
        int64_t cap = now + linewin_cost_after_ok(&m->win, to - planner + 1, to, INT32_MAX);
        if (m->busy_until_ms > cap)
            m->busy_until_ms = cap;
    }
    marlin_report_acked(m, from, to);
}

/*
 * Settling ends when no reply came for settle_ms: every line that was in
 * flight behind the bad one has been answered or eaten by Marlin's RX
 * flush, so the rewound line cannot be flushed with them.  Then it goes
 * out in ping-pong, and the window climbs back as lines pass clean: with
 * one line in flight an error leaves nothing behind it to be flushed or
 * cut into fragments.
 */
static void
on_settle(struct loop *l, void *ud)
{
    struct marlin *m = ud;
    m->settle_timer = 0;
    int64_t quiet = loop_now_ms(l) - m->last_reply_ms;
    if (quiet < m->settle_ms && m->win.stale > 0) {
        m->settle_timer = loop_timer_add(l, m->settle_ms - quiet, on_settle, m);
        return;
    }
    m->settling = false;
    m->win.stale = 0;
    m->win.swallow = 0; /* a rejection's ok follows its Resend at once, or was lost */
    marlin_pump(m);
}

static void
start_settling(struct marlin *m)
{
    m->win.window = 1;
    m->clean = 0;
    if (m->settling)
        return;
    m->settling = true;
    m->settle_timer = loop_timer_add(m->base.loop, m->settle_ms, on_settle, m);
}

/* An M105's "ok T:": a barrier at the oldest numbered M105 in flight. */
void
marlin_on_m105_answer(struct marlin *m)
{
    m->m105_answered = true;
    for (long n = m->win.acked + 1; n < m->win.next; n++) {
        if (linewin_tag(&m->win, n) == TAG_M105) {
            long before = m->win.acked;
            linewin_barrier(&m->win, n);
            marlin_credit(m, before, m->win.acked);
            return;
        }
    }
}

void
marlin_on_resend(struct marlin *m, long k)
{
    if (m->renumber_n && k == m->renumber_to + 1 && m->win.next > m->renumber_n) {
        /* The printer counts from the renumbering: it ran it (its ok was
           lost, or this refuses a copy of it sent after a silence). */
        marlin_renumber_check(m, true);
        m->win.swallow = 1; /* the refusal's ok */
        return;
    }
    long before = m->win.acked;
    int rc = linewin_on_resend(&m->win, k);
    if (rc == SF_OK) {
        /* It wants k: lines from k on were never run, whatever a silence said. */
        if (m->unconfirmed_to > m->win.acked)
            m->unconfirmed_to = m->win.acked > m->unconfirmed_from ? m->win.acked : 0;
        m->st.rewinds++;
        m->bad_resend = 0;
        m->bad_resend_count = 0;
        start_settling(m);
        return;
    }
    (void)before;
    if (rc == 2 || (rc == SF_ENOTFOUND && k != 1))
        marlin_want_probe(m); /* garbled, or the printer is ahead: ask where it is */
    if (rc == SF_ENOTFOUND && k == 1) {
        /* A printer that reset without our seeing its banner counts from 0
           again and asks for line 1 after every line; three such requests
           running (a garbled number does not repeat) end the job. */
        if (m->bad_resend == k && ++m->bad_resend_count >= 3) {
            log_printer(LOG_WARN, m->base.name, "printer asks for line %ld; we hold %ld-%ld", k,
                        m->win.high - m->win.cap + 1, m->win.high);
            m->bad_resend = 0;
            marlin_job_fail(m, DRV_CONNECTING, "printer lost its line count (reset?)");
            marlin_hello(m);
        } else if (m->bad_resend != k) {
            m->bad_resend = k;
            m->bad_resend_count = 1;
        }
    }
}

/*
 * Nothing came back for longer than what is in flight can take, plus the
 * margin: an ok or a Resend was lost.  With lines still to send (after a
 * rewind) the quiet says the printer handled what it had, so the window
 * resyncs and the next line tells (Marlin refuses a line it had with a
 * Resend for the one it wants).  Otherwise a numbered M105 goes out past
 * the full window: refused with a Resend if the printer misses a line,
 * else answered after everything before it.  The job fails only when the
 * printer truly says nothing: PROBES_MAX deadlines in a row and no byte at
 * all for SILENCE_MS (offline: the link is dropped), or only unreadable
 * bytes for GARBLED_MAX deadlines (in error: the link is dropped and opened
 * again, marlin_relink).
 */
/*
 * A stream that stops moving fails, never crawls (issue 29).  The printer
 * keeps answering but no job line is confirmed: oks that are not the
 * lines' (M105 answered with a plain "ok", so the host counts one ok short
 * for ever: each probe gets an ok but never its own answer), or only
 * "busy:" keepalives of a command that never ends (a probing that hangs),
 * echo lines, replies just slower than each deadline.  Two bounds, both
 * counted from the last confirmed job line: UNMATCHED_MAX probes answered
 * by oks that are not theirs, and STALL_MS of wall time whatever came.
 * Neither restarts on a deadline that sent no probe (a resync after a
 * Resend) or heard no ok: only a confirmed job line, a probe answered as
 * one ("ok T:"), or a pause does.  The wall time is long enough for a
 * blocking command of a real print (a bed heat-up, a mesh probing: the
 * firmware's own watchdogs end a heat-up that does not climb) and does not
 * run while the printer says it waits for a person ("busy: paused for
 * user": an attended printer's M600).
 */
bool
marlin_stall_check(struct marlin *m, int64_t now)
{
    if (m->mode != J_RUN || m->waits_for_user || m->base.status.lines_acked != m->stall_acked) {
        m->stall_acked = m->base.status.lines_acked;
        m->stall_ms = now;
        m->unmatched = 0;
        return false;
    }
    char why[200];
    if (m->unmatched >= UNMATCHED_MAX)
        snprintf(why, sizeof(why),
                 "stream stalled: %d probes (M105) answered only by '%s', no temperature "
                 "report: acknowledgements do not match lines",
                 m->unmatched, m->last_ok);
    else if (now - m->stall_ms >= STALL_MS)
        snprintf(why, sizeof(why),
                 "stream stalled: no line confirmed for %lld min, the printer answering '%s'",
                 (long long)((now - m->stall_ms) / 60000), m->last_reply);
    else
        return false;
    m->unmatched = 0;
    marlin_job_fail(m, DRV_ERROR, why);
    return true;
}

/* A deadline: count a probe answered by oks that are not its own. */
static bool
stalled(struct marlin *m, int64_t now)
{
    if (m->mode == J_RUN && m->probe_sent && m->ok_since && !m->m105_answered)
        m->unmatched++;
    else if (m->m105_answered)
        m->unmatched = 0;
    m->probe_sent = m->m105_answered = m->ok_since = false;
    return marlin_stall_check(m, now);
}

void
marlin_deadline(struct marlin *m, int64_t now)
{
    if (stalled(m, now))
        return;
    m->probes++;
    bool silent = now - m->last_rx_ms >= SILENCE_MS;
    if ((m->probes >= PROBES_MAX && silent) || m->probes >= GARBLED_MAX) {
        m->probes = 0;
        if (silent) {
            marlin_job_fail(m, DRV_OFFLINE, "printer stopped answering");
            m->t_dead = m->t;
            m->t = NULL;
            m->phase = PH_OFF;
            return;
        }
        /* It talks (temperature reports) but takes no line: the job fails
           in error, for an operator's look (offline would count it ejected
           with auto_eject), and the link is dropped and opened again, a new
           handshake: probing on, one more M105 in flight each time, wedged
           the printer in error with no way back (opening a USB port again
           resets most boards).  A handshake that fails leaves it offline,
           and the farm connects it again. */
        marlin_job_fail(m, DRV_ERROR, "printer stopped answering: it talks, but takes no line");
        marlin_relink(m);
        return;
    }
    /* Which side stopped: bytes still waiting to be written (the link
       takes nothing), or the printer's last words and when (it talks, but
       not of these lines). */
    log_printer(LOG_INFO, m->base.name,
                "no reply for %lld ms (lines %ld-%ld in flight, window %d, high %ld, tag %ld, "
                "swallow %d stale %ld settling %d, %zu bytes unsent, last byte %lld ms ago, "
                "last reply '%s'): probing",
                (long long)(now - m->progress_ms), m->win.acked + 1, m->win.next - 1, m->win.window,
                m->win.high, linewin_tag(&m->win, m->win.acked + 1), m->win.swallow, m->win.stale,
                m->settling, transport_pending(m->t), (long long)(now - m->last_rx_ms),
                m->last_reply);
    m->st.deadlines++;
    m->st.lost_ms += m->margin_ms; /* what the wait cost past the printer's own time */
    m->progress_ms = now;
    m->st.probes++;
    m->win.stale = 0;
    m->win.swallow = 0;
    /* Every M105 in flight is overdue: each lost its answer (or was
       refused, and the Resend was lost).  The next probe's answer stands
       for them all, and must not be taken for one of theirs, or each probe
       would only answer the one before.  Not only the oldest line: when
       the oks of the lines before a probe were lost too, the probe is not
       the oldest line in flight, and a burst that swallowed k probes'
       answers cost k more deadlines, each answer acknowledging the probe
       before it (10 oks lost from a job's third line: 13 deadlines, not 7;
       test_marlin, marlin_probe_answer_stands_for_lost_ones). */
    for (long n = m->win.acked + 1; n < m->win.next; n++)
        if (linewin_tag(&m->win, n) == TAG_M105)
            linewin_set_tag(&m->win, n, TAG_HOST);
    if (m->renumber_n && m->win.next > m->renumber_n) {
        /* The renumbering's ok is overdue: send it again.  Run already,
           the copy is refused with "Resend: m + 1" (on_resend); lost, it
           runs now. */
        long before = m->win.acked;
        linewin_rewind(&m->win, m->renumber_n);
        provisional(m, before, m->win.acked);
    } else if (m->win.next <= m->win.high) {
        long before = m->win.acked;
        linewin_resync(&m->win);
        provisional(m, before, m->win.acked);
    } else if (!marlin_renumber_pending(m)) {
        struct sf_err err;
        long n = marlin_push_host(m, "M105", TAG_M105, &err);
        if (n > 0) {
            m->st.host_lines++;
            m->probe_sent = true;
            linewin_force(&m->win);
        }
    } else {
        linewin_force(&m->win); /* the renumbering goes out as the probe */
    }
    marlin_pump(m);
}
