/*
 * drv_marlin_rx.c - the Marlin driver's reply handling (drv_marlin_int.h).
 *
 * What: splits replies whose newline was garbled, classifies each
 * (marlin_reply.c) and acts on it: the handshake's oks and capabilities,
 * oks and Resends for the window, errors, resets, temperatures, host
 * actions; learns the window from ADVANCED_OK.
 *
 * Thread: loop thread.
 */
#include "drv_marlin_int.h"

#include <stdio.h>
#include <string.h>

#include "../../src/base/log.h"
#include "marlin_reply.h"

/* The window for this firmware: BUFSIZE lines (ADVANCED_OK's B + 1 once seen twice). */
void
marlin_set_full_window(struct marlin *m)
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
        marlin_set_full_window(m);
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
    marlin_emit_event(m, DRV_EV_TEMPS);
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

/* What any reply says of the link: progress, keepalives, temperatures. */
static void
note_reply(struct marlin *m, const struct mreply *r)
{
    int64_t now = loop_now_ms(m->base.loop);
    m->last_reply_ms = now;
    bool protocol = r->kind == MR_OK || r->kind == MR_RESEND || r->kind == MR_BUSY ||
                    r->kind == MR_ERROR || (r->kind == MR_TEMP && r->temp_wait);
    if (protocol) {
        m->progress_ms = now;
        m->probes = 0;
    }
    /* M109's reports say nothing of a G4 or a G28 on a firmware with its
       host keepalive off: they shorten only the heat-ups' allowance. */
    if (r->kind == MR_BUSY)
        m->keepalive_seen = true;
    if (r->kind == MR_TEMP && r->temp_wait)
        m->heat_reports_seen = true;
    if (r->has_temps)
        on_temps(m, r);
}

/* A reply during the handshake: oks for the hellos, M115's report. */
static void
on_hello_reply(struct marlin *m, const struct mreply *r)
{
    switch (r->kind) {
    case MR_OK:
        if (r->has_n && r->b >= 0)
            learn_window(m, r->b, r->p);
        /* Done when every hello sent has its two oks: a hello the
           printer had taken before its "start" (or before a retry)
           runs after the others, and its M110 N0 would reset the
           count under the job's first lines (the printer then asks
           for line 1 again).  A hello lost whole is the timer's. */
        m->hello_ok_ms = loop_now_ms(m->base.loop);
        if (++m->hello_oks >= 2 * m->hello_out)
            marlin_handshake_done(m);
        break;
    case MR_FIRMWARE:
        snprintf(m->base.caps.firmware, sizeof(m->base.caps.firmware), "%s", r->name);
        break;
    case MR_CAP:
        if (strcmp(r->name, "AUTOREPORT_TEMP") == 0)
            m->base.caps.autoreport_temp = r->cap_value;
        else if (strcmp(r->name, "HOST_ACTION_COMMANDS") == 0)
            m->base.caps.host_actions = r->cap_value;
        else if (strcmp(r->name, "ADVANCED_OK") == 0)
            m->base.caps.advanced_ok = r->cap_value;
        break;
    case MR_START:
    case MR_RESEND:
        marlin_hello(m); /* rebooted, or the M110 was garbled: start over */
        break;
    default:
        break;
    }
}

/*
 * Marlin follows a line error with "Resend: L+1" and "ok" at once.  If
 * what comes next is not that Resend (garbled, or lost), the error's own
 * "Last Line: L" says what the printer wants.  True when r was the
 * rejection's ok or the garbled Resend, and there is nothing more to it.
 */
static bool
after_line_error(struct marlin *m, struct mreply *r)
{
    long wants = m->error_wants;
    m->error_wants = 0;
    if (wants > 0 && r->kind != MR_RESEND) {
        marlin_on_resend(m, wants);
        if ((r->kind == MR_OK && !r->has_temps && !r->has_n) || r->kind == MR_OTHER) {
            /* the rejection's ok, or the garbled Resend (its ok still to come) */
            if (r->kind == MR_OK && m->win.swallow > 0)
                m->win.swallow--;
            return true;
        }
    }
    if (wants > 0 && r->kind == MR_RESEND && r->resend != wants) {
        /* One of the two numbers is garbled: the one in the window wins. */
        bool k_ok = r->resend > m->win.acked && r->resend <= m->win.next;
        bool w_ok = wants > m->win.acked && wants <= m->win.next;
        if (w_ok && !k_ok)
            r->resend = wants;
    }
    return false;
}

static void
on_ok(struct marlin *m, const struct mreply *r, const char *line, size_t len)
{
    /* Only a whole ADVANCED_OK reply teaches the window. */
    if (r->has_n && r->p >= 0 && r->b >= 0 && !r->has_temps)
        learn_window(m, r->b, r->p);
    m->ok_since = true;
    snprintf(m->last_ok, sizeof(m->last_ok), "%.*s", (int)(len < 39 ? len : 39), line);
    if (!r->has_n && (r->has_temps || (len > 6 && looks_like_m105(line, len)))) {
        marlin_on_m105_answer(m);
    } else {
        long before = m->win.acked;
        if (linewin_on_ok(&m->win, r->has_n, r->n, TAG_M105) < 0)
            marlin_want_probe(m);
        marlin_credit(m, before, m->win.acked);
    }
}

static void
on_error(struct marlin *m, const struct mreply *r)
{
    if (r->err == MR_ERR_FATAL) {
        if (m->base.status.state != DRV_ERROR) {
            char why[120];
            snprintf(why, sizeof(why), "printer halted: %.80s", r->name);
            marlin_job_fail(m, DRV_ERROR, why);
        }
    } else if (r->err == MR_ERR_LINE && !r->resend_follows && r->last_line >= 0 &&
               strstr(r->name, "No Line Number")) {
        /* Our line lost its N on the wire: Marlin 1.1 drops it, saying
           where it is, with no Resend and no ok (2.x runs it instead). */
        marlin_on_resend(m, r->last_line + 1);
        if (m->win.swallow > 0)
            m->win.swallow--;
    } else if (r->err == MR_ERR_LINE && r->resend_follows && r->last_line >= 0) {
        m->error_wants = r->last_line + 1;
    } else if (r->err == MR_ERR_LINE && !r->resend_follows) {
        marlin_want_probe(m); /* the error text itself is garbled: ask */
    } else if (r->err == MR_ERR_OTHER) {
        log_printer(LOG_WARN, m->base.name, "printer error: %s", r->name);
    }
}

static void
on_action(struct marlin *m, const struct mreply *r)
{
    log_printer(LOG_INFO, m->base.name, "host action: %s", r->name);
    if (strcmp(r->name, "pause") == 0 || strcmp(r->name, "paused") == 0) {
        if (m->base.status.state == DRV_PRINTING)
            marlin_do_pause(m);
    } else if (strcmp(r->name, "resume") == 0 || strcmp(r->name, "resumed") == 0) {
        if (m->base.status.state == DRV_PAUSED)
            marlin_do_resume(m);
    } else if (strcmp(r->name, "cancel") == 0) {
        if (m->mode == J_RUN || m->mode == J_PAUSED)
            marlin_do_cancel(m);
    }
}

static void
on_reply(struct marlin *m, const char *line, size_t len)
{
    struct mreply r;
    mreply_parse(line, len, &r);
    note_reply(m, &r);
    snprintf(m->last_reply, sizeof(m->last_reply), "%.*s", (int)(len < 39 ? len : 39), line);
    if (r.kind == MR_BUSY || r.kind == MR_OK)
        m->waits_for_user = r.kind == MR_BUSY && memmem(line, len, "paused for", 10);
    if (m->phase == PH_HELLO) {
        on_hello_reply(m, &r);
        return;
    }
    if (m->phase != PH_READY)
        return;
    if (after_line_error(m, &r)) {
        marlin_check_job_progress(m);
        return;
    }
    switch (r.kind) {
    case MR_OK:
        on_ok(m, &r, line, len);
        break;
    case MR_OTHER:
        /* Not a Marlin line: a garbled ok, Resend or error.  Right after a
           Resend it was the rejection's ok; otherwise the window may be off
           by that reply, and a barrier puts it right. */
        if (m->win.swallow > 0)
            m->win.swallow--;
        else if (m->win.in_flight > 0)
            marlin_want_probe(m);
        break;
    case MR_RESEND:
        marlin_on_resend(m, r.resend);
        if (r.tail && m->win.swallow > 0)
            m->win.swallow--; /* its ok was merged into this line */
        break;
    case MR_ERROR:
        on_error(m, &r);
        break;
    case MR_START:
        if (m->mode != J_NONE)
            marlin_job_fail(m, DRV_CONNECTING, "printer reset");
        else
            marlin_set_state(m, DRV_CONNECTING);
        marlin_hello(m);
        return;
    case MR_WAIT:
        /* Marlin's queue is empty and nothing is arriving: whatever we think
           is in flight was handled or lost. */
        if (m->win.in_flight > 0)
            marlin_want_probe(m);
        break;
    case MR_ACTION:
        on_action(m, &r);
        break;
    default:
        break;
    }
    marlin_renumber_check(m, false);
    marlin_check_job_progress(m);
}

/* One reply line; two if a garbled newline merged them. */
void
marlin_on_line(struct marlin *m, const char *line, size_t len)
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
