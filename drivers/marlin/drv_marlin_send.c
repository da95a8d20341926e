/*
 * drv_marlin_send.c - the Marlin driver's sending side (drv_marlin_int.h).
 *
 * What: feeds the window of numbered lines (linewin.c) from the resends,
 * the host lines (park, resume, end sequences, probes) and the job file,
 * and writes what may go out.  Keeps line numbers away from the emergency
 * parser's commands with a renumbering M0110 (renumber_pending).
 *
 * Thread: loop thread; never blocks.
 */
#include "drv_marlin_int.h"

#include <stdio.h>
#include <string.h>

#include "../../src/base/log.h"
#include "marlin_exec.h"

bool
marlin_m105_in_flight(const struct marlin *m)
{
    for (long n = m->win.acked + 1; n < m->win.next; n++)
        if (linewin_tag(&m->win, n) == TAG_M105)
            return true;
    return false;
}

/* Host line at the head of the inject queue (it goes next). */
void
marlin_inject_front(struct marlin *m, const char *cmd)
{
    if (m->inj_len == INJECT_MAX)
        return;
    m->inj_head = (m->inj_head + INJECT_MAX - 1) % INJECT_MAX;
    snprintf(m->inject[m->inj_head], LINEWIN_LINE_MAX, "%s", cmd);
    m->inj_len++;
}

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
bool
marlin_renumber_pending(struct marlin *m)
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

/* The renumbering M110 was handled: number on from its target. */
void
marlin_renumber_check(struct marlin *m, bool took)
{
    if (!m->renumber_n || (!took && m->win.acked < m->renumber_n))
        return;
    if (m->unconfirmed_to) { /* it ran, so did every line before it */
        marlin_report_acked(m, m->unconfirmed_from, m->unconfirmed_to);
        m->unconfirmed_to = 0;
    }
    linewin_reset(&m->win, m->renumber_to);
    m->renumber_n = 0;
}

/* Push a host line (cmd as the driver wrote it) in its safe form. */
long
marlin_push_host(struct marlin *m, const char *cmd, long tag, struct sf_err *err)
{
    char form[LINEWIN_LINE_MAX];
    linewin_ep_safe_form(m->win.high + 1, cmd, form, sizeof(form));
    return linewin_push(&m->win, form, tag, err);
}

/* Lines that may go out now: resends first, then host lines, then the job. */
void
marlin_pump(struct marlin *m)
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
            if (marlin_send_raw(m, line) < 0)
                return;
            continue;
        }
        if (m->win.next <= m->win.high)
            return; /* the window is full */
        if (m->win.in_flight >= m->win.window)
            return;
        if (m->renumber_n)
            return; /* a barrier: nothing follows it until its ok */
        if (marlin_renumber_pending(m))
            continue;
        struct sf_err err;
        if (m->inj_len > 0) {
            const char *cmd = m->inject[m->inj_head];
            long tag = strcmp(cmd, "M105") == 0 ? TAG_M105 : TAG_HOST;
            long rc = marlin_push_host(m, cmd, tag, &err);
            if (rc == SF_EAGAIN)
                return;
            if (rc < 0) {
                log_printer(LOG_WARN, m->base.name, "dropping host line: %s", err.msg);
            } else {
                m->st.host_lines++;
                linewin_set_cost(&m->win, rc, marlin_exec_ms(&m->est, cmd),
                                 marlin_exec_is_move(cmd), marlin_exec_heats(cmd));
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
                marlin_inject(m, "M400");
                marlin_inject(m, "M105");
                continue;
            }
            return;
        }
        char cmd[LINEWIN_LINE_MAX];
        /* Leave room for "N<number> " and "*<checksum>". */
        int rc = marlin_next_job_command(m, cmd, LINEWIN_LINE_MAX - 18);
        if (rc < 0) {
            /* Only a file that changed after its scan gets here; say what was wrong. */
            char why[sizeof(m->base.status.message)];
            snprintf(why, sizeof(why), "%s", m->base.status.message);
            marlin_job_fail(m, DRV_IDLE, why);
            return;
        }
        if (rc == 0) {
            m->job_eof = true;
            continue;
        }
        marlin_exec_track(&m->mo, cmd, strlen(cmd));
        long n = linewin_push(&m->win, cmd, m->job_index, &err);
        if (n < 0) {
            marlin_message(m, "job '%s': %s", m->job_path, err.msg);
            marlin_job_fail(m, DRV_IDLE, "bad G-code");
            return;
        }
        linewin_set_cost(&m->win, n, marlin_exec_ms(&m->est, cmd), marlin_exec_is_move(cmd),
                         marlin_exec_heats(cmd));
        m->job_index++;
    }
}
