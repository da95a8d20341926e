/*
 * sim_marlin_wire.c - the simulated Marlin's UART (sim_marlin_int.h).
 *
 * What: times the wire to the microsecond, as a UART is (a byte takes 10
 * bits at the baud rate each way): takes what the host wrote onto a short
 * "on the wire" stage, delivers each byte to the RX ring when its last bit
 * would have arrived, queues replies (with the reply faults: lost oks,
 * merged, duplicated or garbled lines) and paces them out, and arms the
 * wake-up for the next line end either way.  Garbles bytes on the wire
 * (corrupt-rx, corrupt-tx).
 *
 * Thread: loop thread only.
 */
#include "sim_marlin_int.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/timerfd.h>
#include <time.h>
#include <unistd.h>

#include "../../src/base/buf.h"
#include "../../src/base/log.h"
#include "../../src/base/mem.h"

static void emit_raw(struct sim_marlin *s, const char *text, size_t n);
static void on_wake_timer(struct loop *l, void *ud);

void
sim_emit(struct sim_marlin *s, const char *fmt, ...)
{
    char text[512];
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(text, sizeof(text) - 1, fmt, ap);
    va_end(ap);
    if (n < 0)
        return;
    if ((size_t)n > sizeof(text) - 2)
        n = (int)sizeof(text) - 2;
    if (strncmp(text, "ok", 2) == 0) {
        bool burst =
            s->st.oks_burst < (uint64_t)s->faults.drop_oks && s->last_n >= s->faults.drop_oks_line;
        if (burst || faults_roll(&s->faults, s->faults.drop_ok)) {
            s->st.oks_burst += burst;
            s->st.oks_dropped++;
            return;
        }
    }
    int kind = s->faults.hit_kind && !s->hit_done && s->last_n >= s->faults.hit_line
                   ? faults_hit_kind(text)
                   : FAULT_HIT_NONE;
    text[n++] = '\n';
    if (kind && kind == s->faults.hit_kind && s->faults.hit_pos < n) {
        int b = s->faults.hit_byte;
        text[s->faults.hit_pos] = (char)(b > 255 ? text[s->faults.hit_pos] ^ 1 : b);
        s->hit_done = true;
        s->st.hits++;
    }
    if (faults_roll(&s->faults, s->faults.merge))
        n--; /* its newline lost: it runs into the next line */
    int copies = faults_roll(&s->faults, s->faults.dup) ? 2 : 1;
    for (int c = 0; c < copies; c++)
        emit_raw(s, text, (size_t)n);
}

/* Queue n bytes of reply, maybe followed by a garbage line (faults.garbage). */
static void
emit_raw(struct sim_marlin *s, const char *text, size_t n)
{
    struct outline *o = mem_alloc(sizeof(*o) + n);
    if (!o)
        return;
    o->due_us = s->event_us + s->faults.slow_ms * 1000.0;
    o->next = NULL;
    o->len = n;
    memcpy(o->text, text, n);
    if (s->out_tail)
        s->out_tail->next = o;
    else
        s->out_head = o;
    s->out_tail = o;
    if (faults_roll(&s->faults, s->faults.garbage)) {
        char junk[24];
        int k = 4 + (int)(faults_byte(&s->faults, 0) % 16);
        for (int i = 0; i < k; i++) {
            uint8_t b = faults_byte(&s->faults, '\n');
            junk[i] = (char)(b == '\r' ? 'x' : b);
        }
        junk[k] = '\0';
        struct outline *g = mem_alloc(sizeof(*g) + (size_t)k + 1);
        if (g) {
            g->due_us = o->due_us;
            g->next = NULL;
            g->len = (size_t)k + 1;
            memcpy(g->text, junk, (size_t)k);
            g->text[k] = '\n';
            s->out_tail->next = g;
            s->out_tail = g;
        }
    }
}

void
sim_free_out(struct sim_marlin *s)
{
    while (s->out_head) {
        struct outline *n = s->out_head->next;
        free(s->out_head);
        s->out_head = n;
    }
    s->out_tail = NULL;
}

void
sim_emit_temps(struct sim_marlin *s, const char *prefix, bool with_wait)
{
    char w[16] = "";
    if (with_wait)
        snprintf(w, sizeof(w), " W:?");
    sim_emit(s, "%sT:%.2f /%.2f B:%.2f /%.2f @:%d B@:%d%s", prefix, s->t_noz, s->t_noz_target,
             s->t_bed, s->t_bed_target, s->t_noz < s->t_noz_target ? 127 : 0,
             s->t_bed < s->t_bed_target ? 127 : 0, w);
}

/* Now on the wire's clock, microseconds (on simulated time the loop's
   whole milliseconds: wake-ups come at the first one at or after an
   event, and what an event causes is timed from the event, not from the
   wake-up, so the rounding does not add up along a round trip). */
double
sim_wire_now_us(const struct sim_marlin *s)
{
    if (s->cfg.virtual_time)
        return (double)loop_now_ms(s->loop) * 1000.0;
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e6 + (double)ts.tv_nsec / 1e3;
}

/* Events up to this time count as now.  On simulated time a loop
   millisecond stands for the events within half a millisecond of it, so
   the rounding is as often early as late. */
static double
wire_horizon_us(const struct sim_marlin *s, double now)
{
    return s->cfg.virtual_time ? now + 500.0 : now;
}

/* Take what the host wrote off the link onto the wire (the stage). */
void
sim_take_input(struct sim_marlin *s, double now)
{
    if (s->boot_until_ms && s->cfg.boot_hold)
        return; /* held in the link until the banner is out */
    int want = s->stage_cap - s->stage_len;
    if (want <= 0 || !sim_linked(s))
        return;
    ssize_t n = read(s->fd, s->stage + s->stage_len, (size_t)want);
    if (n < 0 && errno == EIO && s->kind == LINK_PTY) {
        sim_host_left(s); /* the slave was closed: no host on the port */
        return;
    }
    if (n == 0 || (n < 0 && errno != EAGAIN && errno != EINTR)) {
        /* TCP host went away: the bridge's listener waits for the next. */
        sim_close_link(s);
        return;
    }
    if (n < 0)
        return;
    if (s->keep_fd >= 0 && s->kind == LINK_PTY) {
        /* A host has the port open: from now on its leaving shows as HUP. */
        close(s->keep_fd);
        s->keep_fd = -1;
    }
    if (s->stage_len == 0) /* an idle line: the first byte starts now */
        s->stage_us = fmax(now, s->rx_free_us) + s->byte_us;
    s->stage_len += (int)n;
    s->rx_free_us = s->stage_us + (s->stage_len - 1) * s->byte_us;
    s->st.rx_bytes += (uint64_t)n;
}

/*
 * Staged bytes whose time has come reach the RX ring, one by one as the
 * UART's interrupt stores them.  A full ring drains into the queue while
 * the queue has room (idle() runs often enough on a real board); with the
 * queue full too, a UART loses the byte and a native-USB board holds the
 * host back.
 */
void
sim_deliver_input(struct sim_marlin *s, double now)
{
    int64_t now_ms = loop_now_ms(s->loop);
    double until = wire_horizon_us(s, now);
    int i = 0;
    for (; i < s->stage_len && s->stage_us + i * s->byte_us <= until; i++) {
        bool live = now_ms >= s->boot_until_ms && !s->halted;
        if (live && s->rx_len == s->cfg.rx_size) {
            sim_assemble_lines(s);
            if (s->rx_len == s->cfg.rx_size && !s->cfg.uart)
                break; /* native USB: nothing more until there is room */
        }
        char c = s->stage[i];
        bool eol = c == '\n' || c == '\r';
        if (!s->rx_line_hit && faults_roll(&s->faults, s->faults.corrupt_rx)) {
            c = (char)faults_byte(&s->faults, (uint8_t)c);
            s->rx_line_hit = true;
            s->emerg_garbled = true;
        }
        if (eol)
            s->rx_line_hit = false;
        if (!live)
            continue; /* the bootloader, or a killed printer, takes nothing */
        if (eol)
            s->event_us = s->stage_us + i * s->byte_us;
        sim_emergency_byte(s, c);
        if (s->rx_len == s->cfg.rx_size) {
            s->st.rx_dropped++; /* a UART's ring overflows */
            continue;
        }
        s->rx[s->rx_len++] = c;
    }
    if (i == 0)
        return;
    memmove(s->stage, s->stage + i, (size_t)(s->stage_len - i));
    s->stage_len -= i;
    s->stage_us += i * s->byte_us;
    if (s->stage_len > 0 && s->stage_us < now)
        s->stage_us = now; /* held back (native USB): the rest follows once there is room */
    if (s->stage_len > 0)
        s->rx_free_us = s->stage_us + (s->stage_len - 1) * s->byte_us;
}

void
sim_write_output(struct sim_marlin *s, double now)
{
    while (s->out_head && s->out_head->due_us <= wire_horizon_us(s, now) && s->tx.len < TX_MAX) {
        struct outline *o = s->out_head;
        if (s->tx.len == 0) /* an idle transmitter starts at once */
            s->tx_head_us = fmax(o->due_us, s->tx_free_us) + s->byte_us;
        for (size_t i = 0; i < o->len; i++) {
            char c = o->text[i];
            if (!s->tx_line_hit && faults_roll(&s->faults, s->faults.corrupt_tx)) {
                c = (char)faults_byte(&s->faults, (uint8_t)c);
                s->tx_line_hit = true;
            }
            if (buf_append(&s->tx, &c, 1) < 0)
                break;
        }
        s->tx_line_hit = false;
        s->out_head = o->next;
        if (!s->out_head)
            s->out_tail = NULL;
        free(o);
    }
    if (!sim_linked(s)) {
        buf_reset(&s->tx);
        return;
    }
    double until = wire_horizon_us(s, now);
    if (s->tx.len == 0 || until < s->tx_head_us)
        return;
    /* the bytes whose last bit has reached the host by now */
    size_t want = (size_t)((until - s->tx_head_us) / s->byte_us) + 1;
    if (want > s->tx.len)
        want = s->tx.len;
    ssize_t n = write(s->fd, s->tx.data, want);
    if (n > 0) {
        buf_consume(&s->tx, (size_t)n);
        s->tx_free_us = s->tx_head_us + (double)(n - 1) * s->byte_us;
        s->tx_head_us += (double)n * s->byte_us;
        if (s->tx.len > 0 && s->tx_head_us < now)
            s->tx_head_us = now; /* the host was not reading: the rest follows as it does */
        s->st.tx_bytes += (uint64_t)n;
    }
}

/* When the next line end among len bytes at b (the first arriving at t0,
   one every byte_us) has arrived; the last byte's time if none ends. */
static double
next_line_end_us(const char *b, size_t len, double t0, double byte_us)
{
    const char *nl = memchr(b, '\n', len);
    const char *cr = memchr(b, '\r', len);
    if (cr && (!nl || cr < nl))
        nl = cr;
    size_t i = nl ? (size_t)(nl - b) : len - 1;
    return t0 + (double)i * byte_us;
}

/* Arm the wake-up for the next event on the wire: a line end reaching the
   printer or the host, a late reply falling due, or the stage half gone
   while the host may have written more. */
void
sim_arm_wake(struct sim_marlin *s, double now)
{
    double at = 0;
    if (s->stage_len > 0) {
        at = next_line_end_us(s->stage, (size_t)s->stage_len, s->stage_us, s->byte_us);
        double low = s->stage_us + (double)(s->stage_len / 2) * s->byte_us;
        if (low < at)
            at = low;
    }
    if (s->tx.len > 0 && sim_linked(s)) {
        double t = next_line_end_us(s->tx.data, s->tx.len, s->tx_head_us, s->byte_us);
        if (at == 0 || t < at)
            at = t;
    }
    if (s->out_head && s->tx.len < TX_MAX) {
        double t = s->out_head->due_us;
        if (at == 0 || t < at)
            at = t;
    }
    if (at != 0)
        at -= wire_horizon_us(s, now) - now;
    if (at != 0 && at <= now)
        at = now + 1000; /* the host reads nothing, or the ring is full (native USB): retry */
    if (at == s->wake_at_us)
        return;
    s->wake_at_us = at;
    if (s->cfg.virtual_time) {
        if (s->wake)
            loop_timer_cancel(s->loop, s->wake);
        s->wake = 0;
        if (at != 0)
            s->wake = loop_timer_add(s->loop, (int64_t)ceil((at - now) / 1000.0), on_wake_timer, s);
        return;
    }
    struct itimerspec its;
    memset(&its, 0, sizeof(its));
    if (at != 0) {
        double t = at < 1 ? 1 : at; /* all zero disarms */
        its.it_value.tv_sec = (time_t)(t / 1e6);
        its.it_value.tv_nsec = (long)((t - (double)its.it_value.tv_sec * 1e6) * 1e3);
    }
    timerfd_settime(s->wake_fd, TFD_TIMER_ABSTIME, &its, NULL);
}

void
sim_on_wake(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)l;
    (void)events;
    struct sim_marlin *s = ud;
    uint64_t n;
    if (read(fd, &n, sizeof(n)) < 0 && errno != EAGAIN)
        log_warn("sim", "timerfd: %s", strerror(errno));
    s->wake_at_us = 0;
    sim_step(s);
}

static void
on_wake_timer(struct loop *l, void *ud)
{
    (void)l;
    struct sim_marlin *s = ud;
    s->wake = 0;
    s->wake_at_us = 0;
    sim_step(s);
}
