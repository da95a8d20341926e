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
 * the driver reads replies (marlin_reply.c), feeds the window and the transport, and reports.
 * Replies carry no checksum: an unreadable reply, or one that cannot be
 * right, sends a numbered M105 probe, whose answer is a barrier (every line
 * before it was handled) and which Marlin refuses, never misreads, when it
 * is garbled.  A reply overdue by more than the execution time of what is
 * in flight plus a margin sends one too; the job fails only when the
 * printer stays silent (drivers/README.md has the whole protocol).
 *
 * This file holds the lifecycle (open, close, the operations table), the
 * handshake, the reply byte stream and the housekeeping timer; the rest is
 * drv_marlin_send.c (the window's feed), drv_marlin_rx.c (replies),
 * drv_marlin_recover.c (acknowledgements, resends, probes, deadlines) and
 * drv_marlin_job.c (the job stream), sharing drv_marlin_int.h, with
 * marlin_exec.c for the machine state and execution time of a command.
 *
 * Thread: loop thread; never blocks (the job file is read a line at a
 * time as the window opens; start_job reads it whole only when the owner
 * brings no drv_job_scan).  drv_marlin_scan and drv_marlin_scan_to: any
 * thread.
 */
#include "drv_marlin.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/base/gcode.h"
#include "../../src/base/log.h"
#include "../../src/base/mem.h"
#include "../gpolicy.h"
#include "drv_marlin_int.h"

#define RING_LINES      512  /* numbered lines kept for resends */
#define BUFSIZE_DEFAULT 4    /* Marlin's BUFSIZE in its default configuration */
#define RX_DEFAULT      128  /* Marlin's RX_BUFFER_SIZE in its default configuration */
#define HELLO_TRIES     5    /* handshake attempts before giving up */
#define MARGIN_MS       1000 /* default margin beyond the expected execution time */
#define POLL_MS         2000 /* M105 polling / M155 interval */
#define RELINK_MS       1000 /* port closed this long before marlin_relink opens it again */

void
marlin_emit_event(struct marlin *m, enum drv_event ev)
{
    if (m->base.on_event)
        m->base.on_event(&m->base, ev, m->base.ud);
}

void
marlin_set_state(struct marlin *m, enum drv_state s)
{
    if (m->base.status.state == s)
        return;
    log_printer(LOG_INFO, m->base.name, "%s -> %s", drv_state_name(m->base.status.state),
                drv_state_name(s));
    m->base.status.state = s;
    marlin_emit_event(m, DRV_EV_STATE);
}

void
marlin_message(struct marlin *m, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(m->base.status.message, sizeof(m->base.status.message), fmt, ap);
    va_end(ap);
}

int
marlin_send_raw(struct marlin *m, const char *text)
{
    if (!m->t)
        return SF_EIO;
    size_t n = strlen(text);
    m->st.bytes_sent += n;
    return transport_write(m->t, text, n);
}

bool
marlin_inject(struct marlin *m, const char *fmt, ...)
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

void
marlin_handshake_done(struct marlin *m)
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
    marlin_set_full_window(m);
    m->win.window = m->full_window;
    m->probe_wanted = false;
    m->probes = 0;
    m->bad_resend = 0;
    m->inj_len = 0;
    if (m->base.caps.autoreport_temp)
        marlin_inject(m, "M155 S%d", POLL_MS / 1000);
    log_printer(LOG_INFO, m->base.name, "connected: %s, window %d lines, %d bytes",
                m->base.caps.firmware[0] ? m->base.caps.firmware : "unknown firmware",
                m->win.window, m->win.rx_bytes);
    marlin_set_state(m, DRV_IDLE);
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
    marlin_on_line(m, m->rx, len);
    marlin_pump(m);
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
                marlin_on_line(m, m->rx, m->rx_len);
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
    marlin_pump(m);
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
        marlin_job_fail(m, DRV_OFFLINE, msg);
    else {
        marlin_message(m, "%s", msg);
        marlin_set_state(m, DRV_OFFLINE);
    }
}

static void
on_close(void *ud, const char *why)
{
    drop_link(ud, why);
}

void
marlin_hello(struct marlin *m)
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
    marlin_send_raw(m, text);
}

static void relink(struct marlin *m);

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
    if (!m->t && m->relink_ms && now >= m->relink_ms && m->base.status.state != DRV_OFFLINE)
        relink(m);
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
                marlin_handshake_done(m);
                return;
            }
            if (m->hello_tries >= HELLO_TRIES) {
                marlin_message(m, "no reply from '%s' (is it a Marlin printer at %d baud?)",
                               m->port, m->baud);
                m->t_dead = m->t;
                m->t = NULL;
                m->phase = PH_OFF;
                marlin_set_state(m, DRV_OFFLINE);
                return;
            }
            marlin_hello(m);
        }
        return;
    }
    if (m->phase != PH_READY)
        return;
    if (!m->base.caps.autoreport_temp && now >= m->poll_ms && m->inj_len == 0) {
        marlin_inject(m, "M105");
        m->poll_ms = now + POLL_MS;
    }
    if (m->win.in_flight > 0 && !m->settling && now >= marlin_deadline_ms(m))
        marlin_deadline(m, now);
    if (!m->t)
        return;
    marlin_pump(m);
    marlin_check_job_progress(m);
}

/* Open the port and start the handshake; the state is the caller's. */
static int
link_open(struct marlin *m, struct sf_err *err)
{
    struct drv *d = &m->base;
    m->t = transport_open(d->loop, m->port, m->baud, on_data, on_close, m, err);
    if (!m->t) {
        marlin_message(m, "%s", err ? err->msg : "cannot open port");
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
    marlin_set_full_window(m);
    m->win.window = m->full_window;
    m->win.rx_bytes = m->cfg_rx;
    m->settling = false;
    memset(&d->caps, 0, sizeof(d->caps));
    m->hello_tries = 0;
    m->progress_ms = m->last_rx_ms = loop_now_ms(d->loop);
    return SF_OK;
}

static int
m_open(struct drv *d, struct sf_err *err)
{
    struct marlin *m = marlin_of(d);
    if (m->t)
        return sf_err_set(err, SF_EINVAL, "printer '%s': already open", d->name);
    m->relink_ms = 0;
    int rc = link_open(m, err);
    if (rc)
        return rc;
    d->status.message[0] = '\0';
    marlin_set_state(m, DRV_CONNECTING);
    marlin_hello(m);
    if (!m->timer)
        m->timer = loop_timer_add(d->loop, 10, on_timer, m);
    return SF_OK;
}

void
marlin_relink(struct marlin *m)
{
    if (m->t) {
        m->t_dead = m->t;
        m->t = NULL;
    }
    m->phase = PH_OFF;
    m->relink_ms = loop_now_ms(m->base.loop) + RELINK_MS;
}

/* marlin_relink's second half, once the old link has been closed a while. */
static void
relink(struct marlin *m)
{
    m->relink_ms = 0;
    struct sf_err err;
    char why[sizeof(m->base.status.message)];
    snprintf(why, sizeof(why), "%s", m->base.status.message);
    if (link_open(m, &err)) {
        marlin_message(m, "%.120s; reconnect: %.120s", why, err.msg);
        marlin_set_state(m, DRV_OFFLINE);
        return;
    }
    snprintf(m->base.status.message, sizeof(m->base.status.message), "%s", why);
    log_printer(LOG_INFO, m->base.name, "link dropped and opened again: a new handshake");
    marlin_hello(m);
}

/* Emergency stop: straight to the wire, past the queue (drv.h estop). */
static int
m_estop(struct drv *d, struct sf_err *err)
{
    struct marlin *m = marlin_of(d);
    if (!m->t)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is offline", d->name);
    marlin_send_raw(m, "M112\n");
    marlin_job_fail(m, DRV_ERROR, "emergency stop (M112)");
    return SF_OK;
}

static int
m_command(struct drv *d, const char *line, struct sf_err *err)
{
    struct marlin *m = marlin_of(d);
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
    if (strncmp(cmd, "M112", 4) == 0 && (cmd[4] == '\0' || cmd[4] == ' '))
        return m_estop(d, err);
    /* The link's protocol is the driver's own (issue 29): whatever a
       printer's config allows, the policy's protocol rows (M110, M111, text
       that reads as a reply) never come from the console.  The farm judged
       the line already; this guards every other caller of the driver. */
    struct gpolicy pol;
    struct gpolicy_verdict v;
    gpolicy_all(&pol);
    if (gpolicy_check_line(&pol, GPOLICY_MANUAL, cmd, n, &v) == GPOLICY_REFUSE)
        return sf_err_set(err, SF_EINVAL,
                          "printer '%s': %s is the host's: not a manual command (%s)", d->name,
                          v.cmd, v.why);
    if (v.action == GPOLICY_REWRITE)
        snprintf(cmd, sizeof(cmd), "%s", v.line);
    if (d->status.state == DRV_PRINTING)
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is printing", d->name);
    if (!marlin_inject(m, "%s", cmd))
        return sf_err_set(err, SF_EAGAIN, "printer '%s': command queue full", d->name);
    marlin_pump(m);
    return SF_OK;
}

static void
m_close(struct drv *d)
{
    struct marlin *m = marlin_of(d);
    if (m->mode != J_NONE)
        marlin_job_fail(m, DRV_OFFLINE, "disconnected by host");
    transport_free(m->t);
    m->t = NULL;
    transport_free(m->t_dead);
    m->t_dead = NULL;
    m->phase = PH_OFF;
    m->relink_ms = 0;
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
    marlin_set_state(m, DRV_OFFLINE);
}

static void
m_destroy(struct drv *d)
{
    struct marlin *m = marlin_of(d);
    marlin_job_close(m);
    linewin_release(&m->win);
    free(m);
}

static const struct drv_ops marlin_ops = {
    .version = DRV_OPS_VERSION,
    .kind = "marlin",
    .open = m_open,
    .start_job = marlin_start_job,
    .pause = marlin_pause,
    .resume = marlin_resume,
    .cancel = marlin_cancel,
    .command = m_command,
    .estop = m_estop,
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
