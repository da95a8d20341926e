/*
 * drv_marlin.c - the Marlin host protocol over a byte transport (drv.h).
 *
 * What: connects (M110 N0 + M115 handshake, capabilities), streams a G-code
 * file as numbered, checksummed lines, keeps temperatures current (M155
 * auto-report, else M105 polling), and pauses (park), resumes (restore
 * position, temperatures, extrusion mode) and cancels (end sequence).
 *
 * Why this way: Marlin executes a numbered line only if it follows the
 * last one and its checksum matches, so exact-once delivery rests on the
 * printer; the host's job is to stay live.  Lines stream in a window of
 * the firmware's BUFSIZE lines whose bytes behind the oldest fit its RX
 * ring, dropping to ping-pong after a Resend and climbing back.  linewin.c does the bookkeeping;
 * this file reads replies (marlin_reply.c), feeds the window and the transport, and reports.
 * Replies carry no checksum: an unreadable reply, or one that cannot be
 * right, sends a numbered M105 probe, whose answer is a barrier (every line
 * before it was handled) and which Marlin refuses, never misreads, when it
 * is garbled.  A reply overdue by more than the execution time of what is
 * in flight plus a margin sends one too; the job fails only when the
 * printer stays silent (drivers/README.md has the whole protocol).
 *
 * Thread: loop thread; never blocks (the job file is read a line at a
 * time as the window opens; start_job reads it whole only when the owner
 * brings no drv_job_scan).  drv_marlin_scan and drv_marlin_scan_to: any
 * thread.
 */
#include "drv_marlin.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/base/gcode.h"
#include "../../src/base/limits.h"
#include "../../src/base/log.h"
#include "../../src/base/mem.h"
#include "linewin.h"
#include "marlin_reply.h"
#include "transport.h"

#define RING_LINES      512    /* numbered lines kept for resends */
#define WINDOW_MAX      32     /* most lines in flight however large B claims */
#define BUFSIZE_DEFAULT 4      /* Marlin's BUFSIZE in its default configuration */
#define RX_DEFAULT      128    /* Marlin's RX_BUFFER_SIZE in its default configuration */
#define INJECT_MAX      32     /* host lines waiting (park, resume, end sequences) */
#define HELLO_TRIES     5      /* handshake attempts before giving up */
#define PROBES_MAX      5      /* deadlines in a row without a reply before the job may fail */
#define SILENCE_MS      30000  /* ... and no byte at all for this long */
#define GARBLED_MAX     40     /* deadlines in a row with only unreadable replies: fail */
#define MARGIN_MS       1000   /* default margin beyond the expected execution time */
#define PLANNER_BLOCKS  16     /* Marlin's BLOCK_BUFFER_SIZE: moves acknowledged, not yet run */
#define ACCEL_MM_S2     1500.0 /* execution time bounds: below most printers' print accel */
#define KEEPALIVE_MS    3000   /* busy/wait reports come at least this often once seen */
#define POLL_MS         2000   /* M105 polling / M155 interval */
#define PROGRESS_MS     250    /* progress events at most this often, */
#define PROGRESS_LINES  16     /* or once this many more lines are acknowledged */
#define CLIMB_LINES     16     /* clean lines per step back up after a rewind */
#define TAG_HOST        (-1)   /* a line the driver added */
#define TAG_M105        (-2)   /* a numbered M105 (poll or probe): its answer is a barrier */
#define PARK_X_MM       0.0    /* where a paused head waits */
#define PARK_Y_MM       0.0
#define PARK_LIFT_MM    10.0
#define RETRACT_MM      2.0
#define RESUME_LIFT_MM  2.0 /* Marlin's POWER_LOSS_ZRAISE: off the part before homing X/Y */
#define RESUME_PRIME_MM 2.0 /* refill what the nozzle oozed while it cooled and reheated */

enum phase { PH_OFF, PH_HELLO, PH_READY };
enum jobmode { J_NONE, J_RUN, J_PAUSED, J_CANCELLING };

struct marlin {
    struct drv base; /* first: drv.h casts */
    char port[256];  /* transport spec */
    int baud;
    int margin_ms;            /* beyond the expected execution time before a probe */
    int cfg_lines;            /* the firmware's BUFSIZE (lines in flight at most) */
    int cfg_rx;               /* the firmware's RX ring, bytes (0: no byte limit) */
    struct transport *t;      /* NULL when offline */
    struct transport *t_dead; /* closed inside its callback; freed on the next tick */
    uint64_t timer;           /* periodic housekeeping */
    enum phase phase;
    int hello_tries, hello_oks;
    int hello_out;                    /* hellos sent in this handshake (2 oks each) */
    int64_t hello_ms;                 /* last hello sent */
    int64_t hello_ok_ms;              /* last ok of the handshake */
    char rx[SF_PRINTER_LINE_MAX + 1]; /* partial reply line */
    size_t rx_len;
    bool rx_skip; /* dropping an over-long line */
    struct linewin win;
    int max_b;                  /* largest ADVANCED_OK B seen twice */
    int b_seen[WINDOW_MAX + 1]; /* how often each B value was seen */
    int max_p;                  /* largest ADVANCED_OK P seen: the planner's depth */
    int full_window;            /* window when the link is clean */
    int clean;                  /* lines acknowledged since the last rewind */
    long unconfirmed_from;      /* a silence counted lines after this one as handled, with no */
    long unconfirmed_to;        /* reply, up to this one (0: none): not progress until one comes */
    bool settling;              /* after a Resend: wait for the stale replies to stop */
    int settle_ms;              /* quiet time that ends settling (3 line times) */
    int64_t last_reply_ms;      /* last complete reply line */
    uint64_t settle_timer;      /* pending settle check */
    uint64_t line_timer;        /* pending check of a reply line without its newline */
    int64_t progress_ms;        /* last protocol progress (ok, resend, busy...) */
    int64_t last_rx_ms;         /* last byte of any kind */
    int probes;                 /* deadlines in a row with no protocol reply */
    bool probe_wanted;          /* a probe waits in the inject queue */
    bool keepalive_seen;        /* the firmware sends "busy:" while any command blocks */
    bool heat_reports_seen;     /* it reports temperatures while M109/M190 wait */
    int64_t busy_until_ms;      /* when the moves acknowledged so far end at the latest */
    int64_t poll_ms;            /* next M105 poll (no auto-report) */
    long error_wants;           /* "Error:... Last Line: L" just came: L + 1, until its Resend */
    long renumber_n;            /* the renumbering M110 in the window, its ok awaited (0: none) */
    long renumber_to;           /* ... and the number it sets (the next line is one more) */
    long bad_resend;            /* resend target out of range */
    int bad_resend_count;       /* times in a row it was asked for */
    char inject[INJECT_MAX][LINEWIN_LINE_MAX];
    int inj_head, inj_len;
    /* job */
    enum jobmode mode;
    FILE *job;
    char job_path[256];
    long job_index; /* next job line (0-based command index) to push */
    bool job_eof;
    bool final_pushed;            /* M400 after the last line */
    long last_tag;                /* highest job index acknowledged + 1 */
    int64_t progress_ev_ms;       /* last DRV_EV_PROGRESS */
    uint64_t progress_ev_lines;   /* lines_acked it reported */
    struct drv_machine mo, saved; /* tracked from the lines pushed (for pause and resume) */
    struct drv_machine est;       /* position for execution time bounds (all lines pushed) */
    struct drv_marlin_stats st;
};

static const struct drv_ops marlin_ops;

static struct marlin *
M(struct drv *d)
{
    return (struct marlin *)d;
}

static void
emit_event(struct marlin *m, enum drv_event ev)
{
    if (m->base.on_event)
        m->base.on_event(&m->base, ev, m->base.ud);
}

static void
set_state(struct marlin *m, enum drv_state s)
{
    if (m->base.status.state == s)
        return;
    log_printer(LOG_INFO, m->base.name, "%s -> %s", drv_state_name(m->base.status.state),
                drv_state_name(s));
    m->base.status.state = s;
    emit_event(m, DRV_EV_STATE);
}

static void message(struct marlin *m, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

static void
message(struct marlin *m, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(m->base.status.message, sizeof(m->base.status.message), fmt, ap);
    va_end(ap);
}

static void
job_close(struct marlin *m)
{
    if (m->job)
        fclose(m->job);
    m->job = NULL;
    m->mode = J_NONE;
    m->inj_len = 0;
}

/* End the job with ev (DONE, FAILED, CANCELLED); the state is the caller's. */
static void
job_end(struct marlin *m, enum drv_event ev)
{
    if (m->mode == J_NONE)
        return;
    job_close(m);
    m->base.status.progress = m->base.status.lines_total ? (double)m->base.status.lines_acked /
                                                               (double)m->base.status.lines_total
                                                         : 1.0;
    emit_event(m, ev);
}

static void
job_fail(struct marlin *m, enum drv_state next, const char *why)
{
    message(m, "%s at line %llu of %llu", why, (unsigned long long)m->base.status.lines_acked,
            (unsigned long long)m->base.status.lines_total);
    log_printer(LOG_WARN, m->base.name, "job failed: %s", m->base.status.message);
    if (m->mode != J_NONE) {
        set_state(m, next);
        job_end(m, DRV_EV_JOB_FAILED);
    } else {
        set_state(m, next);
    }
}

/* ---- writing ------------------------------------------------------------ */

static int
send_raw(struct marlin *m, const char *text)
{
    if (!m->t)
        return SF_EIO;
    size_t n = strlen(text);
    m->st.bytes_sent += n;
    return transport_write(m->t, text, n);
}

static bool inject(struct marlin *m, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

static bool
inject(struct marlin *m, const char *fmt, ...)
{
    if (m->inj_len == INJECT_MAX)
        return false;
    char *slot = m->inject[(m->inj_head + m->inj_len) % INJECT_MAX];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(slot, LINEWIN_LINE_MAX, fmt, ap);
    va_end(ap);
    m->inj_len++;
    return true;
}

/* Follow the state a job line leaves behind, so resume can restore it. */
static void
track(struct drv_machine *mo, const char *cmd, size_t len)
{
    struct gcode_line g;
    if (gcode_parse(cmd, len, &g, NULL) < 0)
        return;
    static const char axes[4] = { 'X', 'Y', 'Z', 'E' };
    double v;
    if (g.letter == 'G' && g.code <= 3) {
        for (int a = 0; a < 4; a++)
            if (gcode_get(&g, axes[a], &v) && !isnan(v))
                mo->pos[a] = (a < 3 ? mo->rel_xyz : mo->rel_e) ? mo->pos[a] + v : v;
        if (gcode_get(&g, 'F', &v) && v > 0)
            mo->feed_mm_min = v;
    } else if (gcode_is(&g, 'G', 90) || gcode_is(&g, 'G', 91)) {
        mo->rel_xyz = mo->rel_e = g.code == 91;
    } else if (gcode_is(&g, 'M', 82) || gcode_is(&g, 'M', 83)) {
        mo->rel_e = g.code == 83;
    } else if (gcode_is(&g, 'G', 92)) {
        for (int a = 0; a < 4; a++)
            if (gcode_get(&g, axes[a], &v))
                mo->pos[a] = isnan(v) ? 0 : v;
    } else if (gcode_is(&g, 'G', 28)) {
        bool any = false;
        for (int a = 0; a < 3; a++)
            any |= gcode_get(&g, axes[a], NULL);
        for (int a = 0; a < 3; a++)
            if (!any || gcode_get(&g, axes[a], NULL))
                mo->pos[a] = 0;
    } else if ((gcode_is(&g, 'M', 104) || gcode_is(&g, 'M', 109)) && gcode_get(&g, 'S', &v) &&
               !isnan(v)) {
        mo->noz_c = v;
    } else if ((gcode_is(&g, 'M', 140) || gcode_is(&g, 'M', 190)) && gcode_get(&g, 'S', &v) &&
               !isnan(v)) {
        mo->bed_c = v;
    } else if (gcode_is(&g, 'M', 106)) {
        mo->fan = gcode_get(&g, 'S', &v) && !isnan(v) ? v : 255;
    } else if (gcode_is(&g, 'M', 107)) {
        mo->fan = 0;
    }
}

/*
 * Read the next command of the job file into out.  1: got one, 0: end of
 * file, <0: a bad line (message set).
 */
static int
next_job_command(struct marlin *m, char *out, size_t cap)
{
    char raw[SF_GCODE_LINE_MAX + 2];
    while (fgets(raw, sizeof(raw), m->job)) {
        size_t len = strlen(raw);
        if (len == sizeof(raw) - 1 && raw[len - 1] != '\n') {
            message(m, "job '%s': a line is longer than %d bytes", m->job_path, SF_GCODE_LINE_MAX);
            return SF_EINVAL;
        }
        bool too_long;
        size_t n = gcode_strip(raw, len, out, cap, &too_long);
        if (too_long) {
            message(m, "job '%s': command %ld is too long for Marlin", m->job_path,
                    m->job_index + 1);
            return SF_EINVAL;
        }
        if (n > 0)
            return 1;
    }
    if (ferror(m->job)) {
        message(m, "job '%s': read error", m->job_path);
        return SF_EIO;
    }
    return 0;
}

/* ---- execution time bounds ---------------------------------------------- */

/*
 * An upper bound on how long the printer takes to run cmd, ms, from the
 * machine state before it (advanced past it).  Moves: the trapezoid the
 * estimator's planner uses for a block (slicer/estimate.c), started and
 * ended at rest, at a low acceleration, so never less than the firmware
 * needs.  Commands that block (homing, probing, heating, dwell) get their
 * own allowances; heating and homing keep the host informed with busy and
 * temperature lines, which count as replies (see expect_ms).
 */
static int32_t
exec_ms(struct drv_machine *mo, const char *cmd)
{
    struct gcode_line g;
    if (gcode_parse(cmd, strlen(cmd), &g, NULL) < 0)
        return 0;
    double v;
    if (g.letter == 'G' && g.code <= 3) {
        static const char axes[4] = { 'X', 'Y', 'Z', 'E' };
        double d2 = 0, de = 0;
        for (int a = 0; a < 4; a++) {
            if (!gcode_get(&g, axes[a], &v) || isnan(v))
                continue;
            double to = (a < 3 ? mo->rel_xyz : mo->rel_e) ? mo->pos[a] + v : v;
            double dd = to - mo->pos[a];
            if (a < 3)
                d2 += dd * dd;
            else
                de = fabs(dd);
        }
        double d = d2 > 0 ? sqrt(d2) : de;
        if (g.code >= 2 && d > 0)
            d *= 3.2; /* an arc may sweep up to a full turn around its chord */
        double f = mo->feed_mm_min;
        if (gcode_get(&g, 'F', &v) && v > 0)
            f = v;
        track(mo, cmd, strlen(cmd));
        double vs = f / 60.0 < 0.5 ? 0.5 : f / 60.0;
        double t =
            d >= vs * vs / ACCEL_MM_S2 ? d / vs + vs / ACCEL_MM_S2 : 2 * sqrt(d / ACCEL_MM_S2);
        return t * 1000 > 600000 ? 600000 : (int32_t)(t * 1000) + 1;
    }
    track(mo, cmd, strlen(cmd));
    if (gcode_is(&g, 'G', 4)) {
        double ms = 0;
        if (gcode_get(&g, 'P', &v) && !isnan(v))
            ms = v;
        else if (gcode_get(&g, 'S', &v) && !isnan(v))
            ms = v * 1000;
        return ms < 0 ? 0 : ms > 3600000 ? 3600000 : (int32_t)ms;
    }
    if (gcode_is(&g, 'G', 28))
        return 60000;
    if (gcode_is(&g, 'G', 29) || gcode_is(&g, 'G', 34) || gcode_is(&g, 'M', 48))
        return 600000;
    if (gcode_is(&g, 'M', 109) || gcode_is(&g, 'M', 190) || gcode_is(&g, 'M', 191) ||
        gcode_is(&g, 'M', 303) || gcode_is(&g, 'M', 0) || gcode_is(&g, 'M', 1) ||
        gcode_is(&g, 'M', 600))
        return 1800000;
    return 0;
}

/* A move (G0-G3): planned, acknowledged, then run. */
static bool
is_move(const char *cmd)
{
    struct gcode_line g;
    return gcode_parse(cmd, strlen(cmd), &g, NULL) == 0 && g.letter == 'G' && g.code <= 3;
}

/* A heat-up wait: Marlin reports temperatures while it runs. */
static bool
heats(const char *cmd)
{
    struct gcode_line g;
    return gcode_parse(cmd, strlen(cmd), &g, NULL) == 0 &&
           (gcode_is(&g, 'M', 109) || gcode_is(&g, 'M', 190) || gcode_is(&g, 'M', 191));
}

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
static int64_t
deadline_ms(const struct marlin *m)
{
    int32_t cap = m->keepalive_seen ? KEEPALIVE_MS : INT32_MAX;
    int32_t heat_cap = m->keepalive_seen || m->heat_reports_seen ? KEEPALIVE_MS : INT32_MAX;
    int64_t from = m->busy_until_ms > m->progress_ms ? m->busy_until_ms : m->progress_ms;
    return from + linewin_cost(&m->win, m->win.acked + 1, m->win.next - 1, cap, heat_cap) +
           m->margin_ms;
}

/* ---- writing the window ------------------------------------------------- */

static bool
m105_in_flight(const struct marlin *m)
{
    for (long n = m->win.acked + 1; n < m->win.next; n++)
        if (linewin_tag(&m->win, n) == TAG_M105)
            return true;
    return false;
}

/* Host line at the head of the inject queue (it goes next). */
static void
inject_front(struct marlin *m, const char *cmd)
{
    if (m->inj_len == INJECT_MAX)
        return;
    m->inj_head = (m->inj_head + INJECT_MAX - 1) % INJECT_MAX;
    snprintf(m->inject[m->inj_head], LINEWIN_LINE_MAX, "%s", cmd);
    m->inj_len++;
}

static void pump(struct marlin *m);

/*
 * Line numbers near the emergency parser's commands.  Marlin's parser acts
 * on M108/M112/M410 at a line's start or after its N and digits, before
 * the checksum is checked, so "N2112 G1..." is one garbled byte from
 * "NM112 G1..." (kill), and "N1120 G1..." from "M1120 G1...".  No line
 * goes out under such a number: the line before one is
 * "N<n> M0110 N<m>", which makes the next line m + 1, the first of two
 * safe numbers.  "M0110", not "M110": the parser stops at the 0 where
 * "M110" is one byte from "M112"; Marlin reads the code as 110 but, not
 * finding "M110" in the text, checks its N like any line's (n is the one
 * it expects).  It is a barrier: Marlin sets the count when it runs the
 * line, so nothing follows it until its ok.  Host lines take the form of
 * their command that no one garbled byte turns into one of the three
 * (linewin_ep_safe_form: "M105" is one byte from "M108", "M00105" none).
 * Returns true when a renumbering is in the window (nothing may be pushed).
 */
static bool
renumber_pending(struct marlin *m)
{
    if (m->renumber_n)
        return true;
    long n = m->win.high + 1;
    if (linewin_number_ok(n + 1))
        return false;
    long q = n + 2;
    while (!linewin_number_ok(q) || !linewin_number_ok(q + 1))
        q++;
    char cmd[32], form[LINEWIN_LINE_MAX];
    snprintf(cmd, sizeof(cmd), "M0110 N%ld", q - 1);
    linewin_ep_safe_form(n, cmd, form, sizeof(form));
    struct sf_err err;
    if (linewin_push(&m->win, form, TAG_HOST, &err) != n)
        return true; /* the ring is full: the caller waits */
    m->renumber_n = n;
    m->renumber_to = q - 1;
    m->st.renumbers++;
    m->st.host_lines++;
    return true;
}

static void report_acked(struct marlin *m, long from, long to);

/* The renumbering M110 was handled: number on from its target. */
static void
renumber_check(struct marlin *m, bool took)
{
    if (!m->renumber_n || (!took && m->win.acked < m->renumber_n))
        return;
    if (m->unconfirmed_to) { /* it ran, so did every line before it */
        report_acked(m, m->unconfirmed_from, m->unconfirmed_to);
        m->unconfirmed_to = 0;
    }
    linewin_reset(&m->win, m->renumber_to);
    m->renumber_n = 0;
}

/* Push a host line (cmd as the driver wrote it) in its safe form. */
static long
push_host(struct marlin *m, const char *cmd, long tag, struct sf_err *err)
{
    char form[LINEWIN_LINE_MAX];
    linewin_ep_safe_form(m->win.high + 1, cmd, form, sizeof(form));
    return linewin_push(&m->win, form, tag, err);
}

/*
 * Something did not add up (an unreadable reply, an ok for a line that
 * cannot be, an error without its Resend): ask for a barrier.  The probe is
 * a numbered M105 in the stream, inside the window like any line: Marlin
 * checks its number and checksum, so garbled on the wire it is refused
 * (Resend), never run as another command; M105 runs in order and answers
 * "ok T:..." itself, so its answer means every line before it was handled.
 */
static void
want_probe(struct marlin *m)
{
    if (m->probe_wanted || m105_in_flight(m) || m->phase != PH_READY)
        return;
    m->st.probes++;
    if (m->win.window == 1 && m->win.in_flight > 0 && m->win.next > m->win.high &&
        !renumber_pending(m)) {
        /* In ping-pong the garbled reply was the one line's: nothing else
           will come, so the probe goes now, past the window. */
        struct sf_err err;
        if (push_host(m, "M105", TAG_M105, &err) > 0) {
            m->st.host_lines++;
            linewin_force(&m->win);
            pump(m);
        }
        return;
    }
    m->probe_wanted = true;
    inject_front(m, "M105");
}

/* Lines that may go out now: resends first, then host lines, then the job. */
static void
pump(struct marlin *m)
{
    if (m->phase != PH_READY || m->settling)
        return;
    for (int guard = 0; guard < 256 && m->t; guard++) {
        const struct linewin_entry *e = linewin_peek(&m->win);
        if (e) {
            /* With one line in flight nothing follows to end a line whose
               newline was garbled; "\r\n" ends it twice (Marlin skips the
               empty line).  Streaming, the next line does that job. */
            char line[LINEWIN_LINE_MAX + 2];
            memcpy(line, e->text, e->len);
            size_t k = e->len;
            if (m->win.window == 1)
                line[k++] = '\r';
            line[k++] = '\n';
            line[k] = '\0';
            if (m->win.in_flight == 0)
                m->progress_ms = loop_now_ms(m->base.loop); /* the clock starts now */
            linewin_sent(&m->win);
            m->st.lines_sent++;
            if (send_raw(m, line) < 0)
                return;
            continue;
        }
        if (m->win.next <= m->win.high)
            return; /* the window is full */
        if (m->win.in_flight >= m->win.window)
            return;
        if (m->renumber_n)
            return; /* a barrier: nothing follows it until its ok */
        if (renumber_pending(m))
            continue;
        struct sf_err err;
        if (m->inj_len > 0) {
            const char *cmd = m->inject[m->inj_head];
            long tag = strcmp(cmd, "M105") == 0 ? TAG_M105 : TAG_HOST;
            long rc = push_host(m, cmd, tag, &err);
            if (rc == SF_EAGAIN)
                return;
            if (rc < 0) {
                log_printer(LOG_WARN, m->base.name, "dropping host line: %s", err.msg);
            } else {
                m->st.host_lines++;
                linewin_set_cost(&m->win, rc, exec_ms(&m->est, cmd), is_move(cmd), heats(cmd));
            }
            if (tag == TAG_M105)
                m->probe_wanted = false;
            m->inj_head = (m->inj_head + 1) % INJECT_MAX;
            m->inj_len--;
            continue;
        }
        if (m->mode != J_RUN || m->base.status.state != DRV_PRINTING)
            return;
        if (m->job_eof) {
            if (!m->final_pushed) {
                /* Done means executed: M400 waits for the last move, and the
                   M105 after it answers only then, whatever became of the
                   plain oks on the way. */
                m->final_pushed = true;
                inject(m, "M400");
                inject(m, "M105");
                continue;
            }
            return;
        }
        char cmd[LINEWIN_LINE_MAX];
        /* Leave room for "N<number> " and "*<checksum>". */
        int rc = next_job_command(m, cmd, LINEWIN_LINE_MAX - 18);
        if (rc < 0) {
            /* Only a file that changed after its scan gets here; say what was wrong. */
            char why[sizeof(m->base.status.message)];
            snprintf(why, sizeof(why), "%s", m->base.status.message);
            job_fail(m, DRV_IDLE, why);
            return;
        }
        if (rc == 0) {
            m->job_eof = true;
            continue;
        }
        track(&m->mo, cmd, strlen(cmd));
        long n = linewin_push(&m->win, cmd, m->job_index, &err);
        if (n < 0) {
            message(m, "job '%s': %s", m->job_path, err.msg);
            job_fail(m, DRV_IDLE, "bad G-code");
            return;
        }
        linewin_set_cost(&m->win, n, exec_ms(&m->est, cmd), is_move(cmd), heats(cmd));
        m->job_index++;
    }
}

/* ---- replies ------------------------------------------------------------ */

/* The job lines among window lines from+1..to were run: lines_acked follows. */
static void
report_acked(struct marlin *m, long from, long to)
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
static void
credit(struct marlin *m, long from, long to)
{
    if (to > from && m->unconfirmed_to) {
        report_acked(m, m->unconfirmed_from, m->unconfirmed_to < to ? m->unconfirmed_to : to);
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
    report_acked(m, from, to);
}

static void
check_job_progress(struct marlin *m)
{
    struct drv_status *st = &m->base.status;
    if (st->lines_total)
        st->progress = (double)st->lines_acked / (double)st->lines_total;
    int64_t now = loop_now_ms(m->base.loop);
    if (m->mode != J_NONE && (now - m->progress_ev_ms >= PROGRESS_MS ||
                              st->lines_acked >= m->progress_ev_lines + PROGRESS_LINES ||
                              st->lines_acked < m->progress_ev_lines)) {
        m->progress_ev_ms = now;
        m->progress_ev_lines = st->lines_acked;
        emit_event(m, DRV_EV_PROGRESS);
    }
    if (m->inj_len > 0 || !linewin_idle(&m->win))
        return;
    if (m->mode == J_RUN && m->job_eof && m->final_pushed) {
        st->lines_acked = st->lines_total;
        message(m, "done: %llu lines", (unsigned long long)st->lines_total);
        set_state(m, DRV_IDLE);
        job_end(m, DRV_EV_JOB_DONE);
    } else if (m->mode == J_CANCELLING) {
        message(m, "cancelled at line %llu of %llu", (unsigned long long)st->lines_acked,
                (unsigned long long)st->lines_total);
        set_state(m, DRV_IDLE);
        job_end(m, DRV_EV_JOB_CANCELLED);
    }
}

/* The window for this firmware: BUFSIZE lines (ADVANCED_OK's B + 1 once seen twice). */
static void
set_full_window(struct marlin *m)
{
    int w = m->cfg_lines;
    if (m->win.advanced && m->max_b > 0)
        w = m->max_b + 1;
    m->full_window = w < 1 ? 1 : w > WINDOW_MAX ? WINDOW_MAX : w;
    if (m->win.window > m->full_window || m->clean == 0)
        m->win.window = m->full_window;
}

static void
learn_window(struct marlin *m, int b, int p)
{
    if (!m->win.advanced) {
        m->win.advanced = true;
        log_printer(LOG_INFO, m->base.name, "ADVANCED_OK: acknowledgements by line number");
    }
    if (p > m->max_p && p < 1024)
        m->max_p = p;
    /* One garbled digit must not widen the window: a value counts once seen twice. */
    if (b < 0 || b > WINDOW_MAX - 1 || m->cfg_lines == 1)
        return;
    if (++m->b_seen[b] >= 2 && b > m->max_b) {
        m->max_b = b;
        set_full_window(m);
    }
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
    pump(m);
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

static void hello(struct marlin *m);
static void do_pause(struct marlin *m);
static void do_resume(struct marlin *m);
static void do_cancel(struct marlin *m);

static void
handshake_done(struct marlin *m)
{
    m->phase = PH_READY;
    m->hello_tries = 0;
    linewin_reset(&m->win, 0);
    m->unconfirmed_to = 0;
    m->renumber_n = 0;
    if (m->settle_timer)
        loop_timer_cancel(m->base.loop, m->settle_timer);
    m->settle_timer = 0;
    m->settling = false;
    m->clean = 0;
    set_full_window(m);
    m->win.window = m->full_window;
    m->probe_wanted = false;
    m->probes = 0;
    m->bad_resend = 0;
    m->inj_len = 0;
    if (m->base.caps.autoreport_temp)
        inject(m, "M155 S%d", POLL_MS / 1000);
    log_printer(LOG_INFO, m->base.name, "connected: %s, window %d lines, %d bytes",
                m->base.caps.firmware[0] ? m->base.caps.firmware : "unknown firmware",
                m->win.window, m->win.rx_bytes);
    set_state(m, DRV_IDLE);
}

/* An M105's "ok T:": a barrier at the oldest numbered M105 in flight. */
static void
on_m105_answer(struct marlin *m)
{
    for (long n = m->win.acked + 1; n < m->win.next; n++) {
        if (linewin_tag(&m->win, n) == TAG_M105) {
            long before = m->win.acked;
            linewin_barrier(&m->win, n);
            credit(m, before, m->win.acked);
            return;
        }
    }
}

static void
on_resend(struct marlin *m, long k)
{
    if (m->renumber_n && k == m->renumber_to + 1 && m->win.next > m->renumber_n) {
        /* The printer counts from the renumbering: it ran it (its ok was
           lost, or this refuses a copy of it sent after a silence). */
        renumber_check(m, true);
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
        want_probe(m); /* garbled, or the printer is ahead: ask where it is */
    if (rc == SF_ENOTFOUND && k == 1) {
        /* A printer that reset without our seeing its banner counts from 0
           again and asks for line 1 after every line; three such requests
           running (a garbled number does not repeat) end the job. */
        if (m->bad_resend == k && ++m->bad_resend_count >= 3) {
            log_printer(LOG_WARN, m->base.name, "printer asks for line %ld; we hold %ld-%ld", k,
                        m->win.high - m->win.cap + 1, m->win.high);
            m->bad_resend = 0;
            job_fail(m, DRV_CONNECTING, "printer lost its line count (reset?)");
            hello(m);
        } else if (m->bad_resend != k) {
            m->bad_resend = k;
            m->bad_resend_count = 1;
        }
    }
}

static void
on_temps(struct marlin *m, const struct mreply *r)
{
    struct drv_status *st = &m->base.status;
    st->nozzle_c = r->t;
    st->nozzle_target_c = r->t_target;
    if (r->has_bed) {
        st->bed_c = r->bed;
        st->bed_target_c = r->bed_target;
    }
    emit_event(m, DRV_EV_TEMPS);
}

/* An N-less ok that reads like a temperature report whose "T:" was garbled. */
static bool
looks_like_m105(const char *line, size_t len)
{
    return memmem(line, len, "@:", 2) != NULL || memmem(line, len, " /", 2) != NULL;
}

/* Where a second reply starts inside line (its newline was garbled), or 0. */
static size_t
merged_at(const char *line, size_t len)
{
    static const char *const starts[] = { "ok T:", "ok N", "Resend:", "Error:", "echo:" };
    for (size_t i = 1; i + 4 <= len; i++)
        for (size_t k = 0; k < sizeof(starts) / sizeof(starts[0]); k++) {
            size_t n = strlen(starts[k]);
            if (i + n <= len && memcmp(line + i, starts[k], n) == 0)
                return i;
        }
    return 0;
}

static void on_reply(struct marlin *m, const char *line, size_t len);

/* One reply line; two if a garbled newline merged them. */
static void
on_line(struct marlin *m, const char *line, size_t len)
{
    size_t at = merged_at(line, len);
    if (at > 0) {
        on_reply(m, line, at);
        if (m->t && m->phase == PH_READY)
            on_reply(m, line + at, len - at);
        return;
    }
    on_reply(m, line, len);
}

static void
on_reply(struct marlin *m, const char *line, size_t len)
{
    struct mreply r;
    mreply_parse(line, len, &r);
    int64_t now = loop_now_ms(m->base.loop);
    m->last_reply_ms = now;
    bool protocol = r.kind == MR_OK || r.kind == MR_RESEND || r.kind == MR_BUSY ||
                    r.kind == MR_ERROR || (r.kind == MR_TEMP && r.temp_wait);
    if (protocol) {
        m->progress_ms = now;
        m->probes = 0;
    }
    /* M109's reports say nothing of a G4 or a G28 on a firmware with its
       host keepalive off: they shorten only the heat-ups' allowance. */
    if (r.kind == MR_BUSY)
        m->keepalive_seen = true;
    if (r.kind == MR_TEMP && r.temp_wait)
        m->heat_reports_seen = true;
    if (r.has_temps)
        on_temps(m, &r);

    if (m->phase == PH_HELLO) {
        switch (r.kind) {
        case MR_OK:
            if (r.has_n && r.b >= 0)
                learn_window(m, r.b, r.p);
            /* Done when every hello sent has its two oks: a hello the
               printer had taken before its "start" (or before a retry)
               runs after the others, and its M110 N0 would reset the
               count under the job's first lines (the printer then asks
               for line 1 again).  A hello lost whole is the timer's. */
            m->hello_ok_ms = loop_now_ms(m->base.loop);
            if (++m->hello_oks >= 2 * m->hello_out)
                handshake_done(m);
            break;
        case MR_FIRMWARE:
            snprintf(m->base.caps.firmware, sizeof(m->base.caps.firmware), "%s", r.name);
            break;
        case MR_CAP:
            if (strcmp(r.name, "AUTOREPORT_TEMP") == 0)
                m->base.caps.autoreport_temp = r.cap_value;
            else if (strcmp(r.name, "HOST_ACTION_COMMANDS") == 0)
                m->base.caps.host_actions = r.cap_value;
            else if (strcmp(r.name, "ADVANCED_OK") == 0)
                m->base.caps.advanced_ok = r.cap_value;
            break;
        case MR_START:
        case MR_RESEND:
            hello(m); /* rebooted, or the M110 was garbled: start over */
            break;
        default:
            break;
        }
        return;
    }
    if (m->phase != PH_READY)
        return;

    /* Marlin follows a line error with "Resend: L+1" and "ok" at once.  If
       what comes next is not that Resend (garbled, or lost), the error's
       own "Last Line: L" says what the printer wants. */
    long wants = m->error_wants;
    m->error_wants = 0;
    if (wants > 0 && r.kind != MR_RESEND) {
        on_resend(m, wants);
        if ((r.kind == MR_OK && !r.has_temps && !r.has_n) || r.kind == MR_OTHER) {
            /* the rejection's ok, or the garbled Resend (its ok still to come) */
            if (r.kind == MR_OK && m->win.swallow > 0)
                m->win.swallow--;
            check_job_progress(m);
            return;
        }
    }
    if (wants > 0 && r.kind == MR_RESEND && r.resend != wants) {
        /* One of the two numbers is garbled: the one in the window wins. */
        bool k_ok = r.resend > m->win.acked && r.resend <= m->win.next;
        bool w_ok = wants > m->win.acked && wants <= m->win.next;
        if (w_ok && !k_ok)
            r.resend = wants;
    }

    switch (r.kind) {
    case MR_OK: {
        /* Only a whole ADVANCED_OK reply teaches the window. */
        if (r.has_n && r.p >= 0 && r.b >= 0 && !r.has_temps)
            learn_window(m, r.b, r.p);
        if (!r.has_n && (r.has_temps || (len > 6 && looks_like_m105(line, len)))) {
            on_m105_answer(m);
        } else {
            long before = m->win.acked;
            if (linewin_on_ok(&m->win, r.has_n, r.n, TAG_M105) < 0)
                want_probe(m);
            credit(m, before, m->win.acked);
        }
        break;
    }
    case MR_OTHER:
        /* Not a Marlin line: a garbled ok, Resend or error.  Right after a
           Resend it was the rejection's ok; otherwise the window may be off
           by that reply, and a barrier puts it right. */
        if (m->win.swallow > 0)
            m->win.swallow--;
        else if (m->win.in_flight > 0)
            want_probe(m);
        break;
    case MR_RESEND:
        on_resend(m, r.resend);
        if (r.tail && m->win.swallow > 0)
            m->win.swallow--; /* its ok was merged into this line */
        break;
    case MR_ERROR:
        if (r.err == MR_ERR_FATAL) {
            if (m->base.status.state != DRV_ERROR) {
                char why[120];
                snprintf(why, sizeof(why), "printer halted: %.80s", r.name);
                job_fail(m, DRV_ERROR, why);
            }
        } else if (r.err == MR_ERR_LINE && !r.resend_follows && r.last_line >= 0 &&
                   strstr(r.name, "No Line Number")) {
            /* Our line lost its N on the wire: Marlin 1.1 drops it, saying
               where it is, with no Resend and no ok (2.x runs it instead). */
            on_resend(m, r.last_line + 1);
            if (m->win.swallow > 0)
                m->win.swallow--;
        } else if (r.err == MR_ERR_LINE && r.resend_follows && r.last_line >= 0) {
            m->error_wants = r.last_line + 1;
        } else if (r.err == MR_ERR_LINE && !r.resend_follows) {
            want_probe(m); /* the error text itself is garbled: ask */
        } else if (r.err == MR_ERR_OTHER) {
            log_printer(LOG_WARN, m->base.name, "printer error: %s", r.name);
        }
        break;
    case MR_START:
        if (m->mode != J_NONE)
            job_fail(m, DRV_CONNECTING, "printer reset");
        else
            set_state(m, DRV_CONNECTING);
        hello(m);
        return;
    case MR_WAIT:
        /* Marlin's queue is empty and nothing is arriving: whatever we think
           is in flight was handled or lost. */
        if (m->win.in_flight > 0)
            want_probe(m);
        break;
    case MR_ACTION:
        log_printer(LOG_INFO, m->base.name, "host action: %s", r.name);
        if (strcmp(r.name, "pause") == 0 || strcmp(r.name, "paused") == 0) {
            if (m->base.status.state == DRV_PRINTING)
                do_pause(m);
        } else if (strcmp(r.name, "resume") == 0 || strcmp(r.name, "resumed") == 0) {
            if (m->base.status.state == DRV_PAUSED)
                do_resume(m);
        } else if (strcmp(r.name, "cancel") == 0) {
            if (m->mode == J_RUN || m->mode == J_PAUSED)
                do_cancel(m);
        }
        break;
    default:
        break;
    }
    renumber_check(m, false);
    check_job_progress(m);
}

/*
 * A reply line that stopped short for settle_ms lost its newline on the
 * wire (replies carry no checksum): take it as it is rather than wait for
 * a line that may never come.
 */
static void
on_line_idle(struct loop *l, void *ud)
{
    struct marlin *m = ud;
    m->line_timer = 0;
    if (!m->t || m->rx_len == 0 || m->rx_skip)
        return;
    if (loop_now_ms(l) - m->last_rx_ms < m->settle_ms) {
        m->line_timer = loop_timer_add(l, m->settle_ms, on_line_idle, m);
        return;
    }
    size_t len = m->rx_len;
    m->rx_len = 0;
    on_line(m, m->rx, len);
    pump(m);
}

static void
on_data(void *ud, const char *data, size_t n)
{
    struct marlin *m = ud;
    m->last_rx_ms = loop_now_ms(m->base.loop);
    for (size_t i = 0; i < n && m->t; i++) {
        char c = data[i];
        if (c == '\n' || c == '\r') {
            if (!m->rx_skip && m->rx_len > 0)
                on_line(m, m->rx, m->rx_len);
            m->rx_len = 0;
            m->rx_skip = false;
            continue;
        }
        if (m->rx_len == SF_PRINTER_LINE_MAX) {
            m->rx_skip = true; /* garbage without newlines: drop, never grow */
            m->rx_len = 0;
        }
        if (!m->rx_skip)
            m->rx[m->rx_len++] = c;
    }
    if (m->t && m->rx_len > 0 && !m->line_timer)
        m->line_timer = loop_timer_add(m->base.loop, m->settle_ms, on_line_idle, m);
    pump(m);
}

static void
drop_link(struct marlin *m, const char *why)
{
    if (m->t) {
        m->t_dead = m->t;
        m->t = NULL;
    }
    m->phase = PH_OFF;
    char msg[120];
    snprintf(msg, sizeof(msg), "link lost (%.80s)", why);
    if (m->mode != J_NONE)
        job_fail(m, DRV_OFFLINE, msg);
    else {
        message(m, "%s", msg);
        set_state(m, DRV_OFFLINE);
    }
}

static void
on_close(void *ud, const char *why)
{
    drop_link(ud, why);
}

/* ---- timers --------------------------------------------------------------- */

static void
hello(struct marlin *m)
{
    /* The one line left one garbled byte from an emergency command
       ("M110" -> "M112"): Marlin takes an M110's number without the
       sequence check only when its text holds "M110", and the count it
       had is unknown here.  It goes before any job runs. */
    char m110[32];
    gcode_number_line(0, "M110 N0", m110, sizeof(m110));
    if (m->phase != PH_HELLO) {
        m->hello_out = 0;
        m->hello_oks = 0;
    }
    m->phase = PH_HELLO;
    m->hello_out++;
    m->hello_tries++;
    m->hello_ms = loop_now_ms(m->base.loop);
    char text[64];
    snprintf(text, sizeof(text), "%s\nM115\n", m110);
    send_raw(m, text);
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
 * all for SILENCE_MS, or only unreadable bytes for GARBLED_MAX deadlines.
 */
static void
deadline(struct marlin *m, int64_t now)
{
    m->probes++;
    bool silent = now - m->last_rx_ms >= SILENCE_MS;
    if ((m->probes >= PROBES_MAX && silent) || m->probes >= GARBLED_MAX) {
        job_fail(m, silent ? DRV_OFFLINE : DRV_ERROR, "printer stopped answering");
        if (silent) {
            m->t_dead = m->t;
            m->t = NULL;
            m->phase = PH_OFF;
        }
        m->probes = 0;
        return;
    }
    log_printer(LOG_INFO, m->base.name,
                "no reply for %lld ms (lines %ld-%ld in flight, window %d, high %ld, tag %ld, "
                "swallow %d stale %ld settling %d): probing",
                (long long)(now - m->progress_ms), m->win.acked + 1, m->win.next - 1, m->win.window,
                m->win.high, linewin_tag(&m->win, m->win.acked + 1), m->win.swallow, m->win.stale,
                m->settling);
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
    } else if (!renumber_pending(m)) {
        struct sf_err err;
        long n = push_host(m, "M105", TAG_M105, &err);
        if (n > 0) {
            m->st.host_lines++;
            linewin_force(&m->win);
        }
    } else {
        linewin_force(&m->win); /* the renumbering goes out as the probe */
    }
    pump(m);
}

static void
on_timer(struct loop *l, void *ud)
{
    struct marlin *m = ud;
    int64_t now = loop_now_ms(l);
    int period = m->margin_ms / 4 < 100 ? m->margin_ms / 4 : 100;
    m->timer = loop_timer_add(l, period > 5 ? period : 5, on_timer, m);
    if (m->t_dead) {
        transport_free(m->t_dead);
        m->t_dead = NULL;
    }
    if (!m->t)
        return;
    if (m->phase == PH_HELLO) {
        int interval = m->margin_ms * 2 < 2000 ? m->margin_ms * 2 : 2000;
        int64_t since = m->hello_ok_ms > m->hello_ms ? m->hello_ok_ms : m->hello_ms;
        if (now - since >= interval) {
            /* Quiet: what the printer took it has answered.  Two oks or
               more: the hellos still owed were lost (sent into the
               bootloader); none: ask again. */
            if (m->hello_oks >= 2) {
                handshake_done(m);
                return;
            }
            if (m->hello_tries >= HELLO_TRIES) {
                message(m, "no reply from '%s' (is it a Marlin printer at %d baud?)", m->port,
                        m->baud);
                m->t_dead = m->t;
                m->t = NULL;
                m->phase = PH_OFF;
                set_state(m, DRV_OFFLINE);
                return;
            }
            hello(m);
        }
        return;
    }
    if (m->phase != PH_READY)
        return;
    if (!m->base.caps.autoreport_temp && now >= m->poll_ms && m->inj_len == 0) {
        inject(m, "M105");
        m->poll_ms = now + POLL_MS;
    }
    if (m->win.in_flight > 0 && !m->settling && now >= deadline_ms(m))
        deadline(m, now);
    if (!m->t)
        return;
    pump(m);
    check_job_progress(m);
}

/* ---- operations ----------------------------------------------------------- */

static int
m_open(struct drv *d, struct sf_err *err)
{
    struct marlin *m = M(d);
    if (m->t)
        return sf_err_set(err, SF_EINVAL, "printer '%s': already open", d->name);
    m->t = transport_open(d->loop, m->port, m->baud, on_data, on_close, m, err);
    if (!m->t) {
        message(m, "%s", err ? err->msg : "cannot open port");
        return err ? err->code : SF_EIO;
    }
    transport_flush_input(m->t);
    m->rx_len = 0;
    m->rx_skip = false;
    m->max_b = m->max_p = 0;
    memset(m->b_seen, 0, sizeof(m->b_seen));
    m->keepalive_seen = false;
    m->heat_reports_seen = false;
    m->win.advanced = false;
    m->clean = 0;
    set_full_window(m);
    m->win.window = m->full_window;
    m->win.rx_bytes = m->cfg_rx;
    m->settling = false;
    memset(&d->caps, 0, sizeof(d->caps));
    d->status.message[0] = '\0';
    m->hello_tries = 0;
    m->progress_ms = m->last_rx_ms = loop_now_ms(d->loop);
    set_state(m, DRV_CONNECTING);
    hello(m);
    if (!m->timer)
        m->timer = loop_timer_add(d->loop, 10, on_timer, m);
    return SF_OK;
}

/*
 * Bring a printer that lost the job back to where the job's lines before
 * first_line left it, then stream on from first_line.  Modelled on Marlin
 * 2.1's power-loss recovery (powerloss.cpp, PrintJobRecovery::resume):
 * the printer was reset (a USB Marlin resets when the port is reopened),
 * so heaters are off and no axis is homed, but the nozzle still stands
 * where the last executed move left it, on or just above the part.
 *   1. start bed and nozzle heating; wait for the bed (a cold nozzle sits
 *      on the part: heating it there would melt a mark into the top layer);
 *   2. G92 Z = the Z the job's earlier lines commanded (trust the nozzle
 *      stayed put, as powerloss.cpp's G92.9 does), lift RESUME_LIFT_MM off
 *      the part, home X and Y only: homing Z would drive the nozzle down
 *      into the part;
 *   3. wait for the nozzle, prime what the cooling nozzle oozed, travel
 *      back over the point where line first_line starts, lower to Z;
 *   4. restore E mode and position, positioning mode, feedrate and fan;
 *   5. continue with line first_line: its move starts where line
 *      first_line - 1 ended, which is exactly where step 3 put the head,
 *      so the line runs whole, as sliced.
 * Why first_line is the first line *not acknowledged*: Marlin acknowledges
 * a line once it is parsed and planned, so every acknowledged line was
 * printed (the planner drains on its own); an unacknowledged line may or
 * may not have run, and running it twice costs a blob at worst, where
 * skipping it leaves a gap.  The owner may hold an older count than the
 * printer reached (progress is persisted periodically): the lines in
 * between are printed again over themselves, within the same layer when
 * the period is short.
 */
static void
inject_resume(struct marlin *m, const struct drv_machine *s)
{
    if (s->bed_c > 0)
        inject(m, "M140 S%.0f", s->bed_c);
    if (s->noz_c > 0)
        inject(m, "M104 S%.0f", s->noz_c);
    if (s->bed_c > 0)
        inject(m, "M190 S%.0f", s->bed_c);
    inject(m, "G92 Z%.3f", s->pos[2]);
    inject(m, "G91");
    inject(m, "G1 Z%.2f F600", RESUME_LIFT_MM);
    inject(m, "G90");
    inject(m, "G28 X Y");
    if (s->noz_c > 0)
        inject(m, "M109 S%.0f", s->noz_c);
    inject(m, "M83");
    inject(m, "G1 E%.2f F300", RESUME_PRIME_MM);
    inject(m, "G1 X%.3f Y%.3f F6000", s->pos[0], s->pos[1]);
    inject(m, "G1 Z%.3f F600", s->pos[2]);
    if (!s->rel_e) {
        inject(m, "M82");
        inject(m, "G92 E%.5f", s->pos[3]);
    }
    if (s->rel_xyz)
        inject(m, "G91");
    inject(m, "G1 F%.0f", s->feed_mm_min);
    if (s->fan > 0)
        inject(m, "M106 S%.0f", s->fan);
    else
        inject(m, "M107");
}

/*
 * Read f from its start: count the commands (lines_total) and refuse a bad
 * line (a job must not fail half-way on one).  For first_line > 0 also
 * follow the machine state up to first_line and, if the file has that
 * command, set its resume point (resume_line = first_line, resume_at,
 * machine); with stop_at_first (the count is already known) reading ends
 * there, and lines_total counts only the commands before it.  Pure:
 * touches only f and out, so it may run on any thread.
 */
static int
scan_job(FILE *f, const char *path, uint64_t first_line, bool stop_at_first,
         struct drv_job_scan *out, struct sf_err *err)
{
    char raw[SF_GCODE_LINE_MAX + 2], cmd[LINEWIN_LINE_MAX];
    uint64_t total = 0;
    long lineno = 0, offset = 0;
    *out = (struct drv_job_scan){ .machine = { .feed_mm_min = 1500 } };
    while (fgets(raw, sizeof(raw), f)) {
        size_t len = strlen(raw);
        long at = offset;
        offset += (long)len;
        lineno++;
        bool too_long;
        if (len == sizeof(raw) - 1 && raw[len - 1] != '\n')
            return sf_err_set(err, SF_EINVAL, "job '%s':%ld: line longer than %d bytes", path,
                              lineno, SF_GCODE_LINE_MAX);
        size_t n = gcode_strip(raw, len, cmd, LINEWIN_LINE_MAX - 18, &too_long);
        if (too_long)
            return sf_err_set(err, SF_EINVAL,
                              "job '%s':%ld: command too long for Marlin (%d bytes)", path, lineno,
                              LINEWIN_LINE_MAX - 19);
        if (n == 0)
            continue;
        if (first_line > 0 && total == first_line) {
            out->resume_line = first_line;
            out->resume_at = at;
            if (stop_at_first)
                break;
        }
        if (total < first_line)
            track(&out->machine, cmd, n);
        total++;
    }
    if (ferror(f))
        return sf_err_sys(err, "job '%s': read", path);
    out->lines_total = total;
    return SF_OK;
}

int
drv_marlin_scan(const char *path, struct drv_job_scan *out, struct sf_err *err)
{
    FILE *f = fopen(path, "r");
    if (!f)
        return sf_err_sys(err, "job '%s'", path);
    struct drv_job_scan sc;
    int rc = scan_job(f, path, 0, false, &sc, err);
    fclose(f);
    if (rc == SF_OK)
        *out = sc;
    return rc;
}

int
drv_marlin_scan_to(const char *path, uint64_t first_line, struct drv_job_scan *scan,
                   struct sf_err *err)
{
    if (first_line == 0)
        return sf_err_set(err, SF_EINVAL, "job '%s': a resume starts at line 1 or later", path);
    FILE *f = fopen(path, "r");
    if (!f)
        return sf_err_sys(err, "job '%s'", path);
    struct drv_job_scan sc;
    int rc = scan_job(f, path, first_line, true, &sc, err);
    fclose(f);
    if (rc)
        return rc;
    if (sc.resume_line != first_line)
        return sf_err_set(err, SF_EINVAL, "job '%s': no command line %llu to resume from", path,
                          (unsigned long long)first_line);
    scan->resume_line = sc.resume_line;
    scan->resume_at = sc.resume_at;
    scan->machine = sc.machine;
    return SF_OK;
}

static int
m_start_job(struct drv *d, const char *path, uint64_t first_line, const struct drv_job_scan *scan,
            struct sf_err *err)
{
    struct marlin *m = M(d);
    if (d->status.state != DRV_IDLE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is %s, not idle", d->name,
                          drv_state_name(d->status.state));
    FILE *f = fopen(path, "r");
    if (!f)
        return sf_err_sys(err, "job '%s'", path);
    /* With the owner's scan a start reads nothing here and a resume reads
       only up to first_line (nothing if the scan has its resume point);
       without one, the whole file is read now. */
    struct drv_job_scan sc = { .machine = { .feed_mm_min = 1500 } };
    uint64_t total = scan ? scan->lines_total : 0;
    bool resume_ok = !scan || first_line < total;
    if (resume_ok && scan && first_line > 0 && scan->resume_line == first_line) {
        sc = *scan;
    } else if (resume_ok && (!scan || first_line > 0)) {
        int rc = scan_job(f, path, first_line, scan != NULL, &sc, err);
        if (rc) {
            fclose(f);
            return rc;
        }
        if (!scan)
            total = sc.lines_total;
        /* no such command: past the end, or a file shorter than its scan said */
        resume_ok = first_line == 0 || sc.resume_line == first_line;
    }
    if (first_line > 0 && !resume_ok) {
        fclose(f);
        return sf_err_set(err, SF_EINVAL,
                          "job '%s': cannot resume from line %llu: the job has %llu command "
                          "lines (0..%llu)",
                          path, (unsigned long long)first_line, (unsigned long long)total,
                          (unsigned long long)(total ? total - 1 : 0));
    }
    if (fseek(f, (long)sc.resume_at, SEEK_SET) != 0) {
        fclose(f);
        return sf_err_sys(err, "job '%s': seek", path);
    }
    m->job = f;
    snprintf(m->job_path, sizeof(m->job_path), "%s", path);
    m->job_index = (long)first_line;
    m->job_eof = false;
    m->final_pushed = false;
    m->mo = sc.machine;
    d->status.lines_total = total;
    d->status.lines_acked = first_line;
    m->unconfirmed_to = 0; /* a silence before this job says nothing of its lines */
    d->status.progress = total ? (double)first_line / (double)total : 0;
    d->status.job_started_ms = loop_now_ms(d->loop);
    if (first_line > 0) {
        inject_resume(m, &sc.machine);
        message(m, "resuming '%s' at line %llu of %llu", path, (unsigned long long)first_line,
                (unsigned long long)total);
    } else {
        message(m, "printing '%s'", path);
    }
    m->mode = J_RUN;
    set_state(m, DRV_PRINTING);
    pump(m);
    return SF_OK;
}

static void
do_pause(struct marlin *m)
{
    m->saved = m->mo;
    m->mode = J_PAUSED;
    inject(m, "M400");
    inject(m, "M83");
    inject(m, "G1 E-%.2f F2400", RETRACT_MM);
    inject(m, "G91");
    inject(m, "G1 Z%.2f F600", PARK_LIFT_MM);
    inject(m, "G90");
    inject(m, "G1 X%.2f Y%.2f F6000", PARK_X_MM, PARK_Y_MM);
    message(m, "paused at line %llu", (unsigned long long)m->base.status.lines_acked);
    set_state(m, DRV_PAUSED);
    pump(m);
}

static void
do_resume(struct marlin *m)
{
    const struct drv_machine *s = &m->saved;
    if (s->bed_c > 0)
        inject(m, "M190 S%.0f", s->bed_c);
    if (s->noz_c > 0)
        inject(m, "M109 S%.0f", s->noz_c);
    inject(m, "G90");
    inject(m, "G1 X%.3f Y%.3f F6000", s->pos[0], s->pos[1]);
    inject(m, "G1 Z%.3f F600", s->pos[2]);
    inject(m, "M83");
    inject(m, "G1 E%.2f F2400", RETRACT_MM);
    inject(m, "%s", s->rel_e ? "M83" : "M82");
    if (!s->rel_e)
        inject(m, "G92 E%.5f", s->pos[3]);
    inject(m, "%s", s->rel_xyz ? "G91" : "G90");
    inject(m, "G1 F%.0f", s->feed_mm_min);
    if (s->fan > 0)
        inject(m, "M106 S%.0f", s->fan);
    m->mo = m->saved;
    m->mode = J_RUN;
    message(m, "resumed");
    set_state(m, DRV_PRINTING);
    pump(m);
}

static void
do_cancel(struct marlin *m)
{
    bool was_paused = m->mode == J_PAUSED;
    m->mode = J_CANCELLING;
    m->inj_len = 0;
    send_raw(m, "M108\n"); /* break an M109/M190 wait at once (emergency parser) */
    inject(m, "M104 S0");
    inject(m, "M140 S0");
    inject(m, "M107");
    if (!was_paused) {
        inject(m, "M83");
        inject(m, "G1 E-%.2f F2400", RETRACT_MM);
        inject(m, "G91");
        inject(m, "G1 Z%.2f F600", PARK_LIFT_MM);
        inject(m, "G90");
    }
    inject(m, "M84");
    set_state(m, DRV_PRINTING); /* until the end sequence is acknowledged */
    pump(m);
}

static int
m_pause(struct drv *d, struct sf_err *err)
{
    struct marlin *m = M(d);
    if (d->status.state != DRV_PRINTING || m->mode != J_RUN)
        return sf_err_set(err, SF_EINVAL, "printer '%s' is %s: nothing to pause", d->name,
                          drv_state_name(d->status.state));
    do_pause(m);
    return SF_OK;
}

static int
m_resume(struct drv *d, struct sf_err *err)
{
    struct marlin *m = M(d);
    if (d->status.state != DRV_PAUSED || m->mode != J_PAUSED)
        return sf_err_set(err, SF_EINVAL, "printer '%s' is %s: nothing to resume", d->name,
                          drv_state_name(d->status.state));
    do_resume(m);
    return SF_OK;
}

static int
m_cancel(struct drv *d, struct sf_err *err)
{
    struct marlin *m = M(d);
    if (m->mode != J_RUN && m->mode != J_PAUSED)
        return sf_err_set(err, SF_EINVAL, "printer '%s': no job to cancel", d->name);
    do_cancel(m);
    return SF_OK;
}

static int
m_command(struct drv *d, const char *line, struct sf_err *err)
{
    struct marlin *m = M(d);
    char cmd[LINEWIN_LINE_MAX];
    bool too_long;
    size_t n = gcode_strip(line, strlen(line), cmd, LINEWIN_LINE_MAX - 18, &too_long);
    if (too_long)
        return sf_err_set(err, SF_EINVAL, "command too long for Marlin");
    if (n == 0)
        return sf_err_set(err, SF_EINVAL, "empty command");
    if (m->phase != PH_READY)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is %s", d->name,
                          drv_state_name(d->status.state));
    if (strncmp(cmd, "M112", 4) == 0 && (cmd[4] == '\0' || cmd[4] == ' ')) {
        /* Emergency stop: straight to the wire, past the queue. */
        send_raw(m, "M112\n");
        job_fail(m, DRV_ERROR, "emergency stop (M112)");
        return SF_OK;
    }
    if (d->status.state == DRV_PRINTING)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is printing", d->name);
    if (!inject(m, "%s", cmd))
        return sf_err_set(err, SF_EAGAIN, "printer '%s': command queue full", d->name);
    pump(m);
    return SF_OK;
}

static void
m_close(struct drv *d)
{
    struct marlin *m = M(d);
    if (m->mode != J_NONE)
        job_fail(m, DRV_OFFLINE, "disconnected by host");
    transport_free(m->t);
    m->t = NULL;
    transport_free(m->t_dead);
    m->t_dead = NULL;
    m->phase = PH_OFF;
    if (m->timer)
        loop_timer_cancel(d->loop, m->timer);
    m->timer = 0;
    if (m->settle_timer)
        loop_timer_cancel(d->loop, m->settle_timer);
    m->settle_timer = 0;
    if (m->line_timer)
        loop_timer_cancel(d->loop, m->line_timer);
    m->line_timer = 0;
    m->settling = false;
    set_state(m, DRV_OFFLINE);
}

static void
m_destroy(struct drv *d)
{
    struct marlin *m = M(d);
    job_close(m);
    linewin_release(&m->win);
    free(m);
}

static const struct drv_ops marlin_ops = {
    .version = DRV_OPS_VERSION,
    .kind = "marlin",
    .open = m_open,
    .start_job = m_start_job,
    .pause = m_pause,
    .resume = m_resume,
    .cancel = m_cancel,
    .command = m_command,
    .close = m_close,
    .destroy = m_destroy,
};

struct drv *
drv_marlin_new(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event, void *ud,
               struct sf_err *err)
{
    const char *name = cfg->name ? cfg->name : "marlin";
    if (!cfg->port || !*cfg->port) {
        sf_err_set(err, SF_EINVAL, "printer '%s': no port given", name);
        return NULL;
    }
    if (strlen(cfg->port) >= sizeof(((struct marlin *)0)->port)) {
        sf_err_set(err, SF_EINVAL, "printer '%s': port name too long", name);
        return NULL;
    }
    if (cfg->baud != 0 && (cfg->baud < 300 || cfg->baud > 4000000)) {
        sf_err_set(err, SF_EINVAL, "printer '%s': baud %d out of range 300-4000000", name,
                   cfg->baud);
        return NULL;
    }
    if (cfg->rx_buffer < 0 || (cfg->rx_buffer > 0 && cfg->rx_buffer < 64) ||
        cfg->rx_buffer > 65536) {
        sf_err_set(err, SF_EINVAL, "printer '%s': rx_buffer %d out of range 64-65536", name,
                   cfg->rx_buffer);
        return NULL;
    }
    if (cfg->timeout_ms < 0 || cfg->timeout_ms > 600000) {
        sf_err_set(err, SF_EINVAL, "printer '%s': timeout %d ms out of range 0-600000", name,
                   cfg->timeout_ms);
        return NULL;
    }
    if (cfg->buffer_lines < 0 || cfg->buffer_lines > WINDOW_MAX) {
        sf_err_set(err, SF_EINVAL, "printer '%s': buffer_lines %d out of range 0-%d", name,
                   cfg->buffer_lines, WINDOW_MAX);
        return NULL;
    }
    struct marlin *m = mem_calloc(1, sizeof(*m));
    if (!m || linewin_init(&m->win, RING_LINES, BUFSIZE_DEFAULT) < 0) {
        free(m);
        sf_err_set(err, SF_ENOMEM, "printer '%s': out of memory", name);
        return NULL;
    }
    m->base.ops = &marlin_ops;
    m->base.loop = l;
    snprintf(m->base.name, sizeof(m->base.name), "%s", name);
    m->base.on_event = on_event;
    m->base.ud = ud;
    snprintf(m->port, sizeof(m->port), "%s", cfg->port);
    m->baud = cfg->baud ? cfg->baud : 115200;
    m->margin_ms = cfg->timeout_ms ? cfg->timeout_ms : MARGIN_MS;
    m->cfg_lines = cfg->buffer_lines ? cfg->buffer_lines : BUFSIZE_DEFAULT;
    m->cfg_rx = cfg->rx_buffer ? cfg->rx_buffer : RX_DEFAULT;
    /* Three of Marlin's longest lines on the wire, at least 5 ms. */
    m->settle_ms = 3 * LINEWIN_LINE_MAX * 10 * 1000 / m->baud;
    if (m->settle_ms < 5)
        m->settle_ms = 5;
    return &m->base;
}

bool
drv_marlin_stats(const struct drv *d, struct drv_marlin_stats *out)
{
    if (!d || d->ops != &marlin_ops)
        return false;
    const struct marlin *m = (const struct marlin *)d;
    *out = m->st;
    out->rewinds = m->win.rewinds;
    out->window = m->win.window;
    return true;
}
