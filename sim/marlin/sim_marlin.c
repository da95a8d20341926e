/*
 * sim_marlin.c - the simulated Marlin printer (sim_marlin.h).
 *
 * Why: integration tests and benchmarks need a printer that behaves like
 * Marlin 2.1 on the wire, including its rough edges: on a bad line it
 * prints "Error:...Last Line: N", empties its RX buffer, then "Resend: N+1"
 * and "ok"; it stops reading serial while the BUFSIZE queue is full; "ok"
 * for a move leaves only once the move is in the planner; M105 prints its
 * own "ok T:..."; M109/M190/G28 keep the host alive with "busy" lines.
 *
 * Design: the wire is timed to the microsecond, as a UART is: a byte
 * takes 10 bits at the baud rate each way.  Bytes the host writes are taken
 * from the link into a short "on the wire" stage as soon as they are there
 * (readability), the first after an idle line starting at once; each
 * reaches the RX ring (RX_BUFFER_SIZE) when its last bit would have, and
 * reply bytes reach the host when theirs would have.  step() runs on
 * readability, on a wake-up at the next line end either way (a timerfd in
 * real time, so no millisecond step adds latency a UART does not have; a
 * loop timer on simulated time), and on a firmware tick (1 ms while
 * anything moves, 50 ms when idle) for the planner and heaters.  It
 * assembles lines into the queue as Marlin's get_serial_commands() does,
 * whenever the queue has room (Marlin calls it from idle(), so also while
 * a command blocks), runs the queue head (a command may block: planner
 * full, heating, dwell), advances the planner and heaters in simulated
 * time (real time x speed), and paces reply bytes out.  Faults are applied
 * where they happen on a real link: bytes garbled on the wire, replies
 * lost or late, resets.
 *
 * This file holds the lifecycle, the link (pty, TCP, a given fd) and the
 * step; sim_marlin_wire.c times the UART and paces replies,
 * sim_marlin_serial.c turns bytes into checked lines (and is the
 * emergency parser), sim_marlin_cmd.c runs commands on the planner and
 * heaters (sim_marlin_int.h holds what they share).
 *
 * Thread: loop thread only.
 */
#include "sim_marlin.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/timerfd.h>
#include <termios.h>
#include <unistd.h>

#include "../../src/base/buf.h"
#include "../../src/base/log.h"
#include "../../src/base/mem.h"
#include "sim_marlin_int.h"

#define BOOT_MS 100 /* bootloader: input ignored, then "start" */

static void on_fd(struct loop *l, int fd, unsigned events, void *ud);

void
sim_marlin_config_init(struct sim_marlin_config *c)
{
    memset(c, 0, sizeof(*c));
    c->baud = 115200;
    c->speed = 1;
    c->bufsize = 4;
    c->planner_blocks = 16;
    c->rx_size = 128;
    c->tcp_port = -1;
    c->fd = -1;
    faults_init(&c->faults);
}

void
sim_close_link(struct sim_marlin *s)
{
    if (s->fd >= 0) {
        if (!s->host_gone)
            loop_del_fd(s->loop, s->fd);
        close(s->fd);
        s->fd = -1;
    }
    s->host_gone = false;
    if (s->keep_fd >= 0) {
        close(s->keep_fd);
        s->keep_fd = -1;
    }
    s->rx_len = 0;
    s->stage_len = 0;
    s->line_len = 0;
    s->line_eol = false;
    s->emerg_len = 0;
    buf_reset(&s->tx);
    sim_free_out(s);
}

static int
open_pty(struct sim_marlin *s, struct sf_err *err)
{
    int m = posix_openpt(O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
    if (m < 0)
        return sf_err_sys(err, "sim: posix_openpt");
    if (grantpt(m) < 0 || unlockpt(m) < 0) {
        close(m);
        return sf_err_sys(err, "sim: unlock pty");
    }
    char name[128];
    if (ptsname_r(m, name, sizeof(name)) != 0) {
        close(m);
        return sf_err_sys(err, "sim: ptsname");
    }
    /* Raw mode on the slave: no echo, no line editing, 8 bits through. */
    int k = open(name, O_RDWR | O_NOCTTY | O_CLOEXEC);
    if (k < 0) {
        close(m);
        return sf_err_sys(err, "sim: open '%s'", name);
    }
    struct termios tio;
    if (tcgetattr(k, &tio) == 0) {
        cfmakeraw(&tio);
        tcsetattr(k, TCSANOW, &tio);
    }
    s->fd = m;
    s->keep_fd = k;
    if (s->link[0]) {
        char tmp[300];
        snprintf(tmp, sizeof(tmp), "%s.tmp", s->link);
        unlink(tmp);
        if (symlink(name, tmp) < 0 || rename(tmp, s->link) < 0) {
            sim_close_link(s);
            return sf_err_sys(err, "sim: link '%s' -> '%s'", s->link, name);
        }
        snprintf(s->path, sizeof(s->path), "%s", s->link);
    } else {
        snprintf(s->path, sizeof(s->path), "%s", name);
    }
    s->fd_events = LOOP_READ;
    int rc = loop_add_fd(s->loop, m, LOOP_READ, on_fd, s, err);
    if (rc < 0) {
        sim_close_link(s);
        return rc;
    }
    s->st.connects++;
    return SF_OK;
}

static void
on_accept(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)l;
    (void)events;
    struct sim_marlin *s = ud;
    int c = accept4(fd, NULL, NULL, SOCK_NONBLOCK | SOCK_CLOEXEC);
    if (c < 0)
        return;
    if (s->fd >= 0) {
        /* One host at a time, like a serial port. */
        close(c);
        return;
    }
    int one = 1;
    setsockopt(c, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one)); /* a UART does not batch */
    s->fd = c;
    s->fd_events = LOOP_READ;
    if (loop_add_fd(s->loop, c, LOOP_READ, on_fd, s, NULL) < 0) {
        close(c);
        s->fd = -1;
        return;
    }
    s->st.connects++;
    sim_step(s);
}

static int
open_tcp(struct sim_marlin *s, struct sf_err *err)
{
    int fd = socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (fd < 0)
        return sf_err_sys(err, "sim: socket");
    int one = 1;
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
    struct sockaddr_in a = { .sin_family = AF_INET,
                             .sin_port = htons((uint16_t)s->cfg.tcp_port),
                             .sin_addr.s_addr = htonl(INADDR_LOOPBACK) };
    socklen_t alen = sizeof(a);
    if (bind(fd, (struct sockaddr *)&a, sizeof(a)) < 0 || listen(fd, 4) < 0 ||
        getsockname(fd, (struct sockaddr *)&a, &alen) < 0) {
        int rc = sf_err_sys(err, "sim: listen on 127.0.0.1:%d", s->cfg.tcp_port);
        close(fd);
        return rc;
    }
    int rc = loop_add_fd(s->loop, fd, LOOP_READ, on_accept, s, err);
    if (rc < 0) {
        close(fd);
        return rc;
    }
    s->listen_fd = fd;
    snprintf(s->path, sizeof(s->path), "tcp://127.0.0.1:%u", ntohs(a.sin_port));
    return SF_OK;
}

/* The link drops: the host sees EOF/EIO; a new pty (same link) or the listener waits. */
void
sim_drop_link(struct sim_marlin *s)
{
    sim_close_link(s);
    if (s->kind == LINK_PTY) {
        struct sf_err err;
        if (open_pty(s, &err) < 0)
            log_error("sim", "%s", err.msg);
    }
}

static void
on_tick(struct loop *l, void *ud)
{
    (void)l;
    struct sim_marlin *s = ud;
    s->tick = 0;
    sim_step(s);
}

/*
 * The host closed the pty (or died).  A USB Marlin keeps running what it
 * already received (its replies go nowhere), heaters on, until the port is
 * opened again: that asserts DTR, which resets the board (see host_back).
 * The master stays open, out of the loop (it would report HUP forever).
 */
void
sim_host_left(struct sim_marlin *s)
{
    loop_del_fd(s->loop, s->fd);
    s->host_gone = true;
    buf_reset(&s->tx); /* what it had received still runs; only replies are lost */
    sim_free_out(s);
}

/* Polled each step while the host is gone: the slave opened again means a reset. */
static void
host_back(struct sim_marlin *s)
{
    struct pollfd p = { .fd = s->fd, .events = POLLIN };
    if (poll(&p, 1, 0) < 0 || (p.revents & POLLHUP))
        return;
    if (loop_add_fd(s->loop, s->fd, LOOP_READ, on_fd, s, NULL) < 0)
        return;
    s->fd_events = LOOP_READ;
    s->host_gone = false;
    s->st.connects++;
    sim_firmware_reset(s, true); /* DTR: the bootloader runs, then "start" */
}

static void
on_fd(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)l;
    (void)fd;
    struct sim_marlin *s = ud;
    if (s->hung && (events & (LOOP_HUP | LOOP_ERROR))) {
        sim_close_link(s); /* the host gave up on it */
        return;
    }
    if ((events & LOOP_HUP) && s->kind == LINK_PTY && s->keep_fd < 0 && !s->host_gone) {
        sim_host_left(s);
        return;
    }
    sim_step(s);
}

void
sim_step(struct sim_marlin *s)
{
    if (s->hung) {
        /* Nothing is read, run or sent any more; the link stays up. */
        if (sim_linked(s) && s->fd_events != 0 && loop_mod_fd(s->loop, s->fd, 0, NULL) == 0)
            s->fd_events = 0;
        return;
    }
    int64_t now = loop_now_ms(s->loop);
    double now_us = sim_wire_now_us(s);
    s->event_us = now_us;
    int64_t dt_ms = now - s->last_ms;
    s->last_ms = now;
    double dt_s = (double)dt_ms / 1000.0 * s->cfg.speed;
    s->sim_s += dt_s;

    if (!s->halted) {
        sim_advance_planner(s, dt_s);
        sim_advance_heaters(s, dt_s);
    }
    if (s->boot_until_ms && now >= s->boot_until_ms) {
        s->boot_until_ms = 0;
        sim_emit(s, "start");
        sim_emit(s, "echo:Marlin 2.1.2.1");
        sim_emit(s, "echo: Last Updated: 2023-08-06 | Author: (slimfarm-sim)");
        sim_emit(s, "echo: Free Memory: 4096  PlannerBufferBytes: 1792");
    }
    if (!s->deaf) {
        sim_take_input(s, now_us);
        sim_deliver_input(s, now_us);
        sim_take_input(s, now_us); /* the stage made room: keep the wire busy */
    }
    if (!s->halted) {
        for (int round = 0; round < 8 && !s->hung; round++) {
            int before = s->q_len;
            sim_assemble_lines(s);
            sim_run_queue(s);
            if (s->q_len == before || s->rx_len == 0)
                break;
        }
        if (s->autoreport_s > 0 && now >= s->autoreport_ms) {
            sim_emit_temps(s, " ", false);
            s->autoreport_ms = now + (int64_t)s->autoreport_s * 1000;
        }
    } else {
        s->rx_len = 0;
    }
    if (s->hung) {
        sim_free_out(s);
        buf_reset(&s->tx);
        sim_step(s); /* silent from here on */
        return;
    }
    sim_write_output(s, now_us);

    /* Ask for input only when the stage can take it, or epoll would spin. */
    if (s->host_gone)
        host_back(s);
    if (sim_linked(s)) {
        bool held = s->boot_until_ms && s->cfg.boot_hold;
        unsigned ev = !held && !s->deaf && s->stage_len < s->stage_cap ? LOOP_READ : 0;
        if (ev != s->fd_events && loop_mod_fd(s->loop, s->fd, ev, NULL) == 0)
            s->fd_events = ev;
    }
    sim_arm_wake(s, now_us);
    bool busy = s->q_len > 0 || s->pl_len > 0 || s->rx_len > 0 || s->boot_until_ms ||
                fabs(s->t_noz - fmax(s->t_noz_target, AMBIENT_C)) > 0.5 ||
                fabs(s->t_bed - fmax(s->t_bed_target, AMBIENT_C)) > 0.5;
    if (s->halted)
        busy = false; /* its last words go out on the wire's wake-ups */
    if (s->tick)
        loop_timer_cancel(s->loop, s->tick);
    s->tick = loop_timer_add(s->loop, busy ? 1 : 50, on_tick, s);
    if (s->log && !busy)
        fflush(s->log);
}

/* Power-on or reset: everything volatile is lost; "start" after the boot delay. */
void
sim_firmware_reset(struct sim_marlin *s, bool banner)
{
    s->halted = false;
    s->deaf = false;
    s->stuck = false;
    s->held = false;
    s->last_n = 0;
    s->q_len = 0;
    s->q_head = 0;
    s->head_started = false;
    s->pl_len = 0;
    s->pl_head = 0;
    s->starve_armed = false;
    s->rx_len = 0;
    s->stage_len = 0;
    s->line_len = 0;
    s->line_eol = false;
    s->emerg_len = 0;
    s->rel_xyz = s->rel_e = false;
    memset(s->pos, 0, sizeof(s->pos));
    s->feed_mm_s = 25;
    s->t_noz_target = s->t_bed_target = 0;
    s->autoreport_s = 0;
    s->debug_flags = 0;
    s->dwell_s = -1;
    sim_free_out(s);
    buf_reset(&s->tx);
    if (banner)
        s->boot_until_ms = loop_now_ms(s->loop) + BOOT_MS;
}

struct sim_marlin *
sim_marlin_new(struct loop *l, const struct sim_marlin_config *c, struct sf_err *err)
{
    if (c->baud < 0 || c->baud > 4000000 || !(c->speed >= 0) || c->speed > 1e6 || c->bufsize < 0 ||
        c->bufsize > 64 || c->planner_blocks < 0 || c->planner_blocks > 256 || c->rx_size < 0 ||
        c->rx_size > 65536 || c->tcp_port > 65535 || c->hang_after < 0 || c->deaf_after < 0) {
        sf_err_set(err, SF_EINVAL,
                   "sim: config out of range (baud %d, speed %g, bufsize %d, "
                   "planner %d, rx %d, port %d)",
                   c->baud, c->speed, c->bufsize, c->planner_blocks, c->rx_size, c->tcp_port);
        return NULL;
    }
    struct sim_marlin *s = mem_calloc(1, sizeof(*s));
    if (!s) {
        sf_err_set(err, SF_ENOMEM, "sim: out of memory");
        return NULL;
    }
    s->loop = l;
    s->cfg = *c;
    if (!s->cfg.baud)
        s->cfg.baud = 115200;
    if (s->cfg.speed == 0)
        s->cfg.speed = 1;
    if (!s->cfg.bufsize)
        s->cfg.bufsize = 4;
    if (!s->cfg.planner_blocks)
        s->cfg.planner_blocks = 16;
    if (!s->cfg.rx_size)
        s->cfg.rx_size = 128;
    s->cfg.log_path = NULL;
    s->cfg.link = NULL;
    s->faults = c->faults;
    if (!s->faults.rng)
        s->faults.rng = 1;
    s->fd = s->keep_fd = s->listen_fd = s->wake_fd = -1;
    s->byte_us = 10.0 * 1e6 / s->cfg.baud;
    s->stage_cap = (int)fmax(64, 4000.0 / s->byte_us);
    s->t_noz = s->t_bed = AMBIENT_C;
    buf_init(&s->tx, TX_MAX);
    s->rx = mem_alloc((size_t)s->cfg.rx_size);
    s->stage = mem_alloc((size_t)s->stage_cap);
    s->queue = mem_array((size_t)s->cfg.bufsize, sizeof(*s->queue));
    s->planner = mem_array((size_t)s->cfg.planner_blocks, sizeof(*s->planner));
    if (!s->rx || !s->stage || !s->queue || !s->planner) {
        sf_err_set(err, SF_ENOMEM, "sim: out of memory");
        goto fail;
    }
    if (!s->cfg.virtual_time) {
        s->wake_fd = timerfd_create(CLOCK_MONOTONIC, TFD_NONBLOCK | TFD_CLOEXEC);
        if (s->wake_fd < 0) {
            sf_err_sys(err, "sim: timerfd");
            goto fail;
        }
        if (loop_add_fd(l, s->wake_fd, LOOP_READ, sim_on_wake, s, err) < 0) {
            close(s->wake_fd);
            s->wake_fd = -1;
            goto fail;
        }
    }
    if (c->link)
        snprintf(s->link, sizeof(s->link), "%s", c->link);
    if (c->log_path) {
        s->log = fopen(c->log_path, "w");
        if (!s->log) {
            sf_err_sys(err, "sim: log '%s'", c->log_path);
            goto fail;
        }
        setvbuf(s->log, NULL, _IOLBF, 0); /* readers see each command as it runs */
    }
    s->last_ms = loop_now_ms(l);
    s->event_us = sim_wire_now_us(s);
    sim_firmware_reset(s, true);
    s->kind = c->tcp_port >= 0 || c->fd >= 0 ? LINK_TCP : LINK_PTY;
    if (c->fd >= 0) {
        /* A host on the other end already: a bridge whose one client never leaves. */
        s->fd = c->fd;
        int fl = fcntl(s->fd, F_GETFL);
        if (fl < 0 || fcntl(s->fd, F_SETFL, fl | O_NONBLOCK) < 0) {
            sf_err_sys(err, "sim: fd %d", c->fd);
            s->fd = -1;
            goto fail;
        }
        s->fd_events = LOOP_READ;
        snprintf(s->path, sizeof(s->path), "fd:%d", c->fd);
        if (loop_add_fd(l, s->fd, LOOP_READ, on_fd, s, err) < 0) {
            s->fd = -1;
            goto fail;
        }
        s->st.connects++;
    } else if ((s->kind == LINK_TCP ? open_tcp(s, err) : open_pty(s, err)) < 0) {
        goto fail;
    }
    sim_step(s);
    return s;
fail:
    sim_marlin_free(s);
    return NULL;
}

const char *
sim_marlin_path(const struct sim_marlin *s)
{
    return s->path;
}

void
sim_marlin_stats(const struct sim_marlin *s, struct sim_marlin_stats *out)
{
    *out = s->st;
    out->halted = s->halted;
    out->last_n = s->last_n;
    out->queued = s->q_len;
    out->rx_len = s->rx_len;
    out->stage_len = s->stage_len;
    out->x = s->pos[0];
    out->y = s->pos[1];
    out->z = s->pos[2];
    out->e = s->pos[3];
    out->nozzle_c = s->t_noz;
    out->nozzle_target_c = s->t_noz_target;
    out->bed_c = s->t_bed;
    out->bed_target_c = s->t_bed_target;
    if (s->log)
        fflush(s->log);
}

void
sim_marlin_free(struct sim_marlin *s)
{
    if (!s)
        return;
    if (s->tick)
        loop_timer_cancel(s->loop, s->tick);
    if (s->wake)
        loop_timer_cancel(s->loop, s->wake);
    if (s->wake_fd >= 0) {
        loop_del_fd(s->loop, s->wake_fd);
        close(s->wake_fd);
    }
    sim_close_link(s);
    if (s->listen_fd >= 0) {
        loop_del_fd(s->loop, s->listen_fd);
        close(s->listen_fd);
    }
    if (s->link[0])
        unlink(s->link);
    if (s->log)
        fclose(s->log);
    buf_release(&s->tx);
    free(s->rx);
    free(s->stage);
    free(s->queue);
    free(s->planner);
    free(s);
}
