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
 * Thread: loop thread only.
 */
#include "sim_marlin.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/timerfd.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "../../src/base/buf.h"
#include "../../src/base/gcode.h"
#include "../../src/base/log.h"
#include "../../src/base/mem.h"

#define MAX_CMD_SIZE   96        /* Marlin's line buffer */
#define TX_MAX         (1 << 20) /* reply bytes waiting for the wire */
#define KEEPALIVE_MS   2000      /* Marlin's DEFAULT_KEEPALIVE_INTERVAL */
#define WAIT_REPORT_MS 1000      /* M109/M190 print temperatures every second */
#define BOOT_MS        100       /* bootloader: input ignored, then "start" */
#define G29_S          45.0      /* bed levelling: a 3x3 probe grid, simulated seconds */
#define AMBIENT_C      22.0

enum link_kind { LINK_PTY, LINK_TCP };

struct outline {
    double due_us;        /* when it may go on the wire (slow replies), wire clock */
    struct outline *next; /* FIFO */
    size_t len;
    char text[]; /* line with its '\n' */
};

struct block {
    double dur_s; /* simulated seconds the move takes */
};

struct sim_marlin {
    struct loop *loop;
    struct sim_marlin_config cfg;
    struct faults faults;
    enum link_kind kind;
    char path[256];     /* what hosts open */
    char link[256];     /* symlink to keep current, or "" */
    int fd;             /* pty master or connected TCP client; -1 none */
    int keep_fd;        /* pty slave we hold until a host has it open, so the master
                           sees no HUP before; then closed, so the host leaving shows */
    bool host_gone;     /* pty: the host closed the port; fd is out of the loop */
    int listen_fd;      /* TCP listener or -1 */
    unsigned fd_events; /* events asked of the loop for fd */
    uint64_t tick;      /* pending step timer id */
    int64_t last_ms;    /* time of the previous step */
    FILE *log;          /* executed commands */

    /* wire, timed in microseconds (wire_now_us) */
    double byte_us;    /* one byte (10 bits) at the baud rate */
    char *stage;       /* bytes taken from the link, still on the wire to the printer */
    int stage_len;     /* of stage_cap */
    int stage_cap;     /* about 4 ms of the wire: the host's side keeps the rest */
    double stage_us;   /* when the first staged byte has arrived */
    double rx_free_us; /* when the last byte taken in has arrived */
    double tx_head_us; /* when the first byte in tx reaches the host (tx.len > 0) */
    double tx_free_us; /* when the last byte written reached the host */
    int wake_fd;       /* real time: a timerfd for the next wire event; -1 */
    uint64_t wake;     /* simulated time: the loop timer for it */
    double wake_at_us; /* when the armed wake-up fires; 0: none */
    double event_us;   /* when what this step answers happened: the last line end
                          delivered, else now; an idle transmitter starts then */
    char *rx;          /* RX buffer, rx_len of rx_size bytes */
    int rx_len;
    bool rx_line_hit; /* corruption already hit this line (one per line) */
    bool hit_done;    /* the targeted reply corruption (faults.hit_*) happened */
    bool bad_done;    /* the line faults.bad_line was rejected once */
    bool tx_line_hit;
    char emerg[MAX_CMD_SIZE + 8]; /* the incoming line, for the emergency parser */
    bool emerg_garbled;           /* a byte of it was garbled on the way (corrupt-rx) */
    bool hit_rx_done;             /* faults.hit_rx_line was garbled */
    bool hit_rx_bad;              /* ... and is to be refused by its checksum */
    int emerg_len;
    struct outline *out_head, *out_tail;
    struct buf tx; /* bytes on their way out */

    /* firmware */
    int64_t boot_until_ms; /* > now: booting, input dropped */
    bool hung;             /* cfg.hang_after reached: silent for good */
    bool halted;           /* killed */
    long last_n;           /* last good line number */
    char line[MAX_CMD_SIZE];
    int line_len;
    bool line_eol; /* in a ';' comment or overflowed: skip to EOL */
    char (*queue)[MAX_CMD_SIZE];
    int q_head, q_len;
    bool head_started;     /* queue head logged and being processed */
    int64_t head_since_ms; /* when the head started (keepalive) */
    int64_t keepalive_ms;  /* next busy/temperature line while blocking */
    double dwell_s;        /* G4/G28: simulated seconds left to wait */
    struct block *planner;
    int pl_head, pl_len;
    double pl_left_s;      /* time left of the executing block */
    bool starve_armed;     /* planner ran dry after moves, no sync since */
    double starve_since_s; /* when it ran dry (simulated) */
    double sim_s;          /* simulated clock, s */
    bool rel_xyz, rel_e;
    double pos[4]; /* X Y Z E */
    double feed_mm_s;
    double t_noz, t_noz_target, t_bed, t_bed_target;
    bool wait_heat_interrupted; /* M108 */
    int autoreport_s;           /* M155 S; 0 off */
    int64_t autoreport_ms;      /* next auto-report */
    struct sim_marlin_stats st;
};

static void step(struct sim_marlin *s);
static void assemble_lines(struct sim_marlin *s);
static void firmware_reset(struct sim_marlin *s, bool banner);

/* A host is connected: bytes can flow. */
static bool
linked(const struct sim_marlin *s)
{
    return s->fd >= 0 && !s->host_gone;
}

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

/* ---- output ------------------------------------------------------------ */

static void emit(struct sim_marlin *s, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void emit_raw(struct sim_marlin *s, const char *text, size_t n);

static void
emit(struct sim_marlin *s, const char *fmt, ...)
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

static void
free_out(struct sim_marlin *s)
{
    while (s->out_head) {
        struct outline *n = s->out_head->next;
        free(s->out_head);
        s->out_head = n;
    }
    s->out_tail = NULL;
}

static void
emit_temps(struct sim_marlin *s, const char *prefix, bool with_wait)
{
    char w[16] = "";
    if (with_wait)
        snprintf(w, sizeof(w), " W:?");
    emit(s, "%sT:%.2f /%.2f B:%.2f /%.2f @:%d B@:%d%s", prefix, s->t_noz, s->t_noz_target, s->t_bed,
         s->t_bed_target, s->t_noz < s->t_noz_target ? 127 : 0,
         s->t_bed < s->t_bed_target ? 127 : 0, w);
}

static int
planner_free(const struct sim_marlin *s)
{
    return s->cfg.planner_blocks - s->pl_len;
}

static void
send_ok(struct sim_marlin *s, const char *line)
{
    if (!s->cfg.advanced_ok) {
        emit(s, "ok");
        return;
    }
    /* Marlin echoes the N word of the acknowledged line, if it had one. */
    char n[24] = "";
    const char *p = line;
    while (*p == ' ')
        p++;
    if (*p == 'N') {
        int k = 0;
        n[k++] = ' ';
        n[k++] = *p++;
        while ((*p == '-' || (*p >= '0' && *p <= '9')) && k < 22)
            n[k++] = *p++;
        n[k] = '\0';
    }
    emit(s, "ok%s P%d B%d", n, planner_free(s), s->cfg.bufsize - s->q_len);
}

/* ---- link -------------------------------------------------------------- */

static void on_fd(struct loop *l, int fd, unsigned events, void *ud);
static void host_left(struct sim_marlin *s);

static void
close_link(struct sim_marlin *s)
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
    free_out(s);
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
            close_link(s);
            return sf_err_sys(err, "sim: link '%s' -> '%s'", s->link, name);
        }
        snprintf(s->path, sizeof(s->path), "%s", s->link);
    } else {
        snprintf(s->path, sizeof(s->path), "%s", name);
    }
    s->fd_events = LOOP_READ;
    int rc = loop_add_fd(s->loop, m, LOOP_READ, on_fd, s, err);
    if (rc < 0) {
        close_link(s);
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
    step(s);
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
static void
drop_link(struct sim_marlin *s)
{
    close_link(s);
    if (s->kind == LINK_PTY) {
        struct sf_err err;
        if (open_pty(s, &err) < 0)
            log_error("sim", "%s", err.msg);
    }
}

/* ---- planner, heaters ---------------------------------------------------- */

static void
sync_planner(struct sim_marlin *s)
{
    s->starve_armed = false;
}

static void
push_block(struct sim_marlin *s, double dur_s)
{
    if (s->pl_len == 0 && s->starve_armed) {
        s->st.starved++;
        s->st.starved_s += s->sim_s - s->starve_since_s;
        s->starve_armed = false;
    }
    int i = (s->pl_head + s->pl_len) % s->cfg.planner_blocks;
    s->planner[i].dur_s = dur_s;
    if (s->pl_len == 0)
        s->pl_left_s = dur_s;
    s->pl_len++;
}

static void
advance_planner(struct sim_marlin *s, double dt_s)
{
    while (s->pl_len > 0 && dt_s > 0) {
        double use = dt_s < s->pl_left_s ? dt_s : s->pl_left_s;
        s->pl_left_s -= use;
        dt_s -= use;
        if (s->pl_left_s <= 1e-12) {
            s->pl_head = (s->pl_head + 1) % s->cfg.planner_blocks;
            s->pl_len--;
            if (s->pl_len > 0) {
                s->pl_left_s = s->planner[s->pl_head].dur_s;
            } else {
                s->starve_armed = true;
                s->starve_since_s = s->sim_s - dt_s;
            }
        }
    }
}

static double
approach(double t, double target, double heat_c_s, double dt_s)
{
    double floor_c = target > AMBIENT_C ? target : AMBIENT_C;
    if (target > t)
        return fmin(target, t + heat_c_s * dt_s);
    double cool = fmax(0.5, (t - AMBIENT_C) / 40.0) * dt_s;
    return fmax(floor_c, t - cool);
}

static void
advance_heaters(struct sim_marlin *s, double dt_s)
{
    s->t_noz = approach(s->t_noz, s->t_noz_target, 4.0, dt_s);
    s->t_bed = approach(s->t_bed, s->t_bed_target, 1.5, dt_s);
}

/* ---- commands ------------------------------------------------------------ */

static double
move_len(struct sim_marlin *s, const struct gcode_line *g, double *target)
{
    static const char axes[4] = { 'X', 'Y', 'Z', 'E' };
    for (int a = 0; a < 4; a++) {
        double v;
        target[a] = s->pos[a];
        if (gcode_get(g, axes[a], &v) && !isnan(v))
            target[a] = (a < 3 ? s->rel_xyz : s->rel_e) ? s->pos[a] + v : v;
    }
    double dx = target[0] - s->pos[0], dy = target[1] - s->pos[1], dz = target[2] - s->pos[2];
    double d = sqrt(dx * dx + dy * dy + dz * dz);
    if (gcode_is(g, 'G', 2) || gcode_is(g, 'G', 3)) {
        double i = 0, j = 0;
        gcode_get(g, 'I', &i);
        gcode_get(g, 'J', &j);
        double cx = s->pos[0] + (isnan(i) ? 0 : i), cy = s->pos[1] + (isnan(j) ? 0 : j);
        double r = hypot(s->pos[0] - cx, s->pos[1] - cy);
        double a0 = atan2(s->pos[1] - cy, s->pos[0] - cx);
        double a1 = atan2(target[1] - cy, target[0] - cx);
        double sweep = gcode_is(g, 'G', 2) ? a0 - a1 : a1 - a0;
        while (sweep <= 1e-9)
            sweep += 2 * M_PI;
        d = hypot(r * sweep, dz);
    }
    return d > 0 ? d : fabs(target[3] - s->pos[3]);
}

/* Run the queue head; false while it blocks (planner full, heating, dwell). */
static bool
run_command(struct sim_marlin *s, const char *raw, const char *cmd, struct gcode_line *g)
{
    double v;
    int64_t now = loop_now_ms(s->loop);
    if (g->letter == 'G') {
        switch (g->code) {
        case 0:
        case 1:
        case 2:
        case 3: {
            if (gcode_get(g, 'F', &v) && v > 0)
                s->feed_mm_s = v / 60.0;
            if (planner_free(s) == 0)
                return false;
            double target[4];
            double d = move_len(s, g, target);
            if (d > 0)
                push_block(s, d / s->feed_mm_s);
            memcpy(s->pos, target, sizeof(target));
            break;
        }
        case 4:
        case 28:
        case 29:
            if (s->pl_len > 0)
                return false;
            sync_planner(s);
            if (s->dwell_s < 0) {
                double secs = 0;
                if (g->code == 28)
                    secs = 3.0;
                else if (g->code == 29)
                    secs = G29_S;
                else if (gcode_get(g, 'P', &v) && !isnan(v))
                    secs = v / 1000.0;
                else if (gcode_get(g, 'S', &v) && !isnan(v))
                    secs = v;
                s->dwell_s = s->sim_s + secs;
            }
            if (s->sim_s < s->dwell_s) {
                if (g->code >= 28 && !s->cfg.no_keepalive && now >= s->keepalive_ms) {
                    emit(s, "echo:busy: processing");
                    s->keepalive_ms = now + KEEPALIVE_MS;
                }
                return false;
            }
            s->dwell_s = -1;
            if (g->code == 28) {
                /* G28 X Y homes those axes only (a resume must not home Z into the part) */
                bool any =
                    gcode_get(g, 'X', NULL) || gcode_get(g, 'Y', NULL) || gcode_get(g, 'Z', NULL);
                for (int a = 0; a < 3; a++)
                    if (!any || gcode_get(g, "XYZ"[a], NULL))
                        s->pos[a] = 0;
            }
            break;
        case 90:
            s->rel_xyz = s->rel_e = false;
            break;
        case 91:
            s->rel_xyz = s->rel_e = true;
            break;
        case 92: {
            static const char axes[4] = { 'X', 'Y', 'Z', 'E' };
            for (int a = 0; a < 4; a++)
                if (gcode_get(g, axes[a], &v))
                    s->pos[a] = isnan(v) ? 0 : v;
            break;
        }
        case 20:
        case 21:
            break;
        default:
            goto unknown;
        }
    } else if (g->letter == 'M') {
        switch (g->code) {
        case 82:
            s->rel_e = false;
            break;
        case 83:
            s->rel_e = true;
            break;
        case 104:
        case 140:
            if (gcode_get(g, 'S', &v) && !isnan(v))
                *(g->code == 104 ? &s->t_noz_target : &s->t_bed_target) = v;
            break;
        case 109:
        case 190: {
            double *t = g->code == 109 ? &s->t_noz : &s->t_bed;
            double *tt = g->code == 109 ? &s->t_noz_target : &s->t_bed_target;
            bool both = false;
            if (!s->head_started || s->head_since_ms == now) {
                if (gcode_get(g, 'S', &v) && !isnan(v))
                    *tt = v;
                else if (gcode_get(g, 'R', &v) && !isnan(v))
                    *tt = v;
            }
            both = gcode_get(g, 'R', NULL);
            bool reached = both ? fabs(*t - *tt) <= 1.0 : *t >= *tt - 1.0;
            if (!reached && !s->wait_heat_interrupted) {
                if (now >= s->keepalive_ms) {
                    emit_temps(s, " ", true);
                    s->keepalive_ms = now + WAIT_REPORT_MS;
                }
                return false;
            }
            s->wait_heat_interrupted = false;
            break;
        }
        case 105:
            emit_temps(s, "ok ", false);
            return true; /* M105 prints its own ok */
        case 400:
            if (s->pl_len > 0)
                return false;
            sync_planner(s);
            break;
        case 110:
            if (gcode_get(g, 'N', &v) && !isnan(v))
                s->last_n = (long)v;
            break;
        case 114:
            emit(s, "X:%.2f Y:%.2f Z:%.2f E:%.2f Count X:%ld Y:%ld Z:%ld", s->pos[0], s->pos[1],
                 s->pos[2], s->pos[3], lround(s->pos[0] * 80), lround(s->pos[1] * 80),
                 lround(s->pos[2] * 400));
            break;
        case 115:
            emit(s, "FIRMWARE_NAME:Marlin 2.1.2.1 (slimfarm-sim) SOURCE_CODE_URL:"
                    "github.com/MarlinFirmware/Marlin PROTOCOL_VERSION:1.0 "
                    "MACHINE_TYPE:slimfarm-sim EXTRUDER_COUNT:1 "
                    "UUID:cede2a2f-41a2-4748-9b12-c55c62f367ff");
            emit(s, "Cap:SERIAL_XON_XOFF:0");
            emit(s, "Cap:EEPROM:0");
            emit(s, "Cap:AUTOREPORT_TEMP:1");
            emit(s, "Cap:PROGRESS:0");
            emit(s, "Cap:PRINT_JOB:1");
            emit(s, "Cap:EMERGENCY_PARSER:1");
            emit(s, "Cap:HOST_ACTION_COMMANDS:1");
            emit(s, "Cap:THERMAL_PROTECTION:1");
            emit(s, "Cap:ARCS:1");
            emit(s, "Cap:ADVANCED_OK:%d", s->cfg.advanced_ok ? 1 : 0);
            break;
        case 118: {
            const char *t = g->text ? g->text : "";
            size_t n = g->text ? g->text_len : 0;
            if (n >= 3 && strncmp(t, "A1 ", 3) == 0)
                emit(s, "//%.*s", (int)(n - 3), t + 3);
            else if (n >= 3 && strncmp(t, "E1 ", 3) == 0)
                emit(s, "echo:%.*s", (int)(n - 3), t + 3);
            else
                emit(s, "%.*s", (int)n, t);
            break;
        }
        case 155:
            if (gcode_get(g, 'S', &v) && !isnan(v) && v >= 0 && v <= 60) {
                s->autoreport_s = (int)v;
                s->autoreport_ms = now + (int64_t)v * 1000;
            }
            break;
        case 17:
        case 18:
        case 84:
        case 106:
        case 107:
        case 108:
        case 112:
        case 117:
        case 73:
        case 75:
        case 76:
        case 77:
        case 201:
        case 203:
        case 204:
        case 205:
        case 220:
        case 221:
        case 410:
        case 900:
        case 999:
            break;
        default:
            goto unknown;
        }
    } else if (g->letter == 'T') {
        /* one extruder: T0 only */
        if (g->code != 0)
            emit(s, "echo:Invalid extruder %d", g->code);
    } else {
        goto unknown;
    }
    send_ok(s, raw);
    return true;
unknown:
    emit(s, "echo:Unknown command: \"%s\"", cmd);
    send_ok(s, raw);
    return true;
}

/* Commands this printer runs; anything else is "Unknown command" and not logged. */
static bool
known(const struct gcode_line *g)
{
    static const int g_codes[] = { 0, 1, 2, 3, 4, 20, 21, 28, 29, 90, 91, 92 };
    static const int m_codes[] = { 17,  18,  73,  75,  76,  77,  82,  83,  84,  104, 105, 106,
                                   107, 108, 109, 110, 112, 114, 115, 117, 118, 140, 155, 190,
                                   201, 203, 204, 205, 220, 221, 400, 410, 900, 999 };
    if (g->letter == 'T')
        return true;
    const int *v = g->letter == 'G' ? g_codes : g->letter == 'M' ? m_codes : NULL;
    size_t n = g->letter == 'G' ? sizeof(g_codes) / sizeof(int) : sizeof(m_codes) / sizeof(int);
    for (size_t i = 0; v && i < n; i++)
        if (v[i] == g->code)
            return true;
    return false;
}

static void
check_fault_triggers(struct sim_marlin *s)
{
    uint64_t n = s->st.executed;
    if (s->faults.runaway_after && n == (uint64_t)s->faults.runaway_after) {
        emit(s, "Error:Thermal Runaway, system stopped! Heater_ID: 0");
        emit(s, "Error:Printer halted. kill() called!");
        s->halted = true;
    }
    if (s->faults.reset_after && n == (uint64_t)s->faults.reset_after)
        firmware_reset(s, true);
    if (s->faults.disconnect_after && n == (uint64_t)s->faults.disconnect_after)
        drop_link(s);
    if (s->cfg.hang_after && n == (uint64_t)s->cfg.hang_after) {
        s->hung = true; /* what it was about to send is lost with it */
        free_out(s);
        buf_reset(&s->tx);
    }
}

static void
run_queue(struct sim_marlin *s)
{
    for (int guard = 0; guard < 64 && s->q_len > 0 && !s->halted && !s->hung; guard++) {
        const char *raw = s->queue[s->q_head];
        char cmd[MAX_CMD_SIZE];
        size_t n = gcode_strip(raw, strlen(raw), cmd, sizeof(cmd), NULL);
        struct gcode_line g;
        struct sf_err err;
        int64_t now = loop_now_ms(s->loop);
        bool fresh = !s->head_started;
        if (fresh) {
            s->head_started = true;
            s->head_since_ms = now;
            s->keepalive_ms = now + KEEPALIVE_MS;
            s->dwell_s = -1;
        }
        bool done;
        if (gcode_parse(cmd, n, &g, &err) < 0) {
            emit(s, "echo:Unknown command: \"%s\"", cmd);
            send_ok(s, raw);
            done = true;
        } else {
            if (fresh && known(&g)) {
                s->st.executed++;
                /* the command as Marlin reads it: "M00105" runs as M105 */
                size_t z = 1;
                while (cmd[0] == 'M' && cmd[z] == '0' && cmd[z + 1] >= '0' && cmd[z + 1] <= '9')
                    z++;
                if (s->log && n > 0)
                    fprintf(s->log, "%c%s\n", cmd[0], cmd + z);
            }
            done = run_command(s, raw, cmd, &g);
        }
        if (!done)
            return;
        s->head_started = false;
        s->q_head = (s->q_head + 1) % s->cfg.bufsize;
        s->q_len--;
        check_fault_triggers(s);
        if (s->fd < 0 && s->kind == LINK_TCP)
            return;
    }
}

/* ---- input ----------------------------------------------------------- */

static void
line_error(struct sim_marlin *s, const char *what)
{
    emit(s, "Error:%s%ld", what, s->last_n);
    s->rx_len = 0; /* Marlin empties its RX buffer on a line error */
    s->emerg_len = 0;
    emit(s, "Resend: %ld", s->last_n + 1);
    emit(s, "ok");
    s->st.resends++;
}

/* A complete line arrived (Marlin's get_serial_commands()). */
static void
line_done(struct sim_marlin *s)
{
    s->line[s->line_len] = '\0';
    s->line_len = 0;
    s->line_eol = false;
    char *cmd = s->line;
    while (*cmd == ' ')
        cmd++;
    if (!*cmd)
        return;
    if (*cmd == 'N') {
        char *npos = cmd;
        bool m110 = strstr(cmd, "M110") != NULL;
        if (m110) {
            char *n2 = strchr(cmd + 4, 'N');
            if (n2)
                npos = n2;
        }
        long n = strtol(npos + 1, NULL, 10);
        if (n != s->last_n + 1 && !m110) {
            line_error(s, "Line Number is not Last Line Number+1, Last Line: ");
            return;
        }
        char *star = strrchr(cmd, '*');
        if (!star) {
            line_error(s, "No Checksum with line number, Last Line: ");
            return;
        }
        uint8_t cs = gcode_checksum(cmd, (size_t)(star - cmd));
        bool bad = n == s->faults.bad_line && !m110 && !s->bad_done;
        s->bad_done |= bad;
        if (s->hit_rx_bad && strtol(cmd + 1, NULL, 10) == s->faults.hit_rx_line) {
            bad = true; /* garbled on the way in (hit-rx): one byte off, the checksum fails */
            s->hit_rx_bad = false;
        }
        if (strtol(star + 1, NULL, 10) != cs || bad) {
            line_error(s, "checksum mismatch, Last Line: ");
            return;
        }
        s->last_n = n;
    } else if (strchr(cmd, '*')) {
        /* Marlin 1.1's rule: a checksum without a line number is the tail of
           a line whose head an RX flush ate; drop it, no resend, no ok.
           (2.x dropped this check and can run such a tail: see the README.) */
        emit(s, "Error:No Line Number with checksum, Last Line: %ld", s->last_n);
        return;
    }
    int i = (s->q_head + s->q_len) % s->cfg.bufsize;
    snprintf(s->queue[i], MAX_CMD_SIZE, "%s", cmd);
    s->q_len++;
}

/*
 * Marlin's EMERGENCY_PARSER (feature/e_parser.cpp), which reads every byte
 * before the RX ring and any checksum: at a line's start, after spaces
 * and "N" with digits, '-' and spaces, "M" (spaces) "108", "112" or "410"
 * followed by anything acts when the line ends.  Its states, folded (ACT:
 * one of the three reached).
 */
enum ep_state { EP_RESET, EP_N, EP_M, EP_M1, EP_M10, EP_M11, EP_M4, EP_M41, EP_ACT, EP_IGNORE };

static enum ep_state
ep_step(enum ep_state st, unsigned char c)
{
    bool eol = c == '\n' || c == '\r';
    switch (st) {
    case EP_RESET:
        return c == ' ' || eol ? EP_RESET : c == 'N' ? EP_N : c == 'M' ? EP_M : EP_IGNORE;
    case EP_N:
        return (c >= '0' && c <= '9') || c == '-' || c == ' ' ? EP_N : c == 'M' ? EP_M : EP_IGNORE;
    case EP_M:
        return c == ' ' ? EP_M : c == '1' ? EP_M1 : c == '4' ? EP_M4 : EP_IGNORE;
    case EP_M1:
        return c == '0' ? EP_M10 : c == '1' ? EP_M11 : EP_IGNORE;
    case EP_M10:
        return c == '8' ? EP_ACT : EP_IGNORE;
    case EP_M11:
        return c == '2' ? EP_ACT : EP_IGNORE;
    case EP_M4:
        return c == '1' ? EP_M41 : EP_IGNORE;
    case EP_M41:
        return c == '0' ? EP_ACT : EP_IGNORE;
    case EP_ACT:
        return EP_ACT;
    case EP_IGNORE:
        return EP_IGNORE;
    }
    return EP_IGNORE;
}

/* The state a line's bytes leave it in (its end not included). */
static enum ep_state
ep_line(enum ep_state st, const char *b, int len)
{
    for (int i = 0; i < len && st != EP_IGNORE && st != EP_ACT; i++)
        st = ep_step(st, (unsigned char)b[i]);
    return st;
}

/*
 * Would one byte of this line, replaced by any other (a newline included:
 * what follows it is a line of its own), make the parser act?  The judge
 * of the driver's line numbers, written apart from the driver's own check.
 */
static bool
ep_one_byte_away(const char *b, int len)
{
    enum ep_state pre = EP_RESET;
    for (int i = 0; i < len; i++) {
        for (int c = 1; c < 256; c++) {
            /* the parser tells apart spaces, N, M, digits, '-' and line
               ends; one other byte stands for the rest */
            if (c == (unsigned char)b[i] ||
                (c != 'X' && c != 'Y' && !strchr(" NM-\n\r", c) && !(c >= '0' && c <= '9')))
                continue;
            if (c == '\n' || c == '\r') {
                if (pre == EP_ACT ||
                    (pre == EP_RESET && ep_line(EP_RESET, b + i + 1, len - i - 1) == EP_ACT))
                    return true;
                continue;
            }
            if (pre == EP_IGNORE)
                break;
            if (ep_line(ep_step(pre, (unsigned char)c), b + i + 1, len - i - 1) == EP_ACT)
                return true;
        }
        pre = ep_step(pre, (unsigned char)b[i]);
    }
    /* its newline garbled: the line runs on into the next */
    return pre == EP_ACT;
}

/* A line ended: act as Marlin's emergency parser would on its bytes. */
static void
emergency_line(struct sim_marlin *s)
{
    int len = s->emerg_len;
    s->emerg_len = 0;
    bool intact = !s->emerg_garbled;
    s->emerg_garbled = false;
    const char *b = s->emerg;
    if (s->faults.hit_rx && !s->hit_rx_done && len > 1 && b[0] == 'N' &&
        strtol(b + 1, NULL, 10) == s->faults.hit_rx_line && s->faults.hit_rx_pos < len) {
        s->hit_rx_done = true;
        s->hit_rx_bad = true;
        s->emerg[s->faults.hit_rx_pos] = (char)s->faults.hit_rx_byte;
        s->st.hits++;
    } else if (intact && len > 1 && b[0] == 'N' && b[1] >= '1' && b[1] <= '9' &&
               ep_line(EP_RESET, b, len) != EP_ACT && ep_one_byte_away(b, len)) {
        s->st.ep_near++; /* the stream's lines as sent (the handshake's are N0 or unnumbered) */
    }
    if (ep_line(EP_RESET, b, len) != EP_ACT)
        return;
    s->st.ep_acted++;
    while (*b == ' ' || *b == 'N' || *b == '-' || (*b >= '0' && *b <= '9'))
        b++;
    while (*b == 'M' || *b == ' ')
        b++;
    if (b[0] == '1' && b[1] == '1') {
        emit(s, "Error:Printer halted. kill() called!");
        s->halted = true;
    } else if (b[0] == '1') {
        s->wait_heat_interrupted = true; /* M108 */
    } else {
        s->pl_len = 0; /* M410: quickstop */
    }
}

static void
emergency_byte(struct sim_marlin *s, char c)
{
    if (c != '\n' && c != '\r') {
        if (s->emerg_len < (int)sizeof(s->emerg) - 1)
            s->emerg[s->emerg_len++] = c;
        return;
    }
    emergency_line(s);
}

/* Now on the wire's clock, microseconds (on simulated time the loop's
   whole milliseconds: wake-ups come at the first one at or after an
   event, and what an event causes is timed from the event, not from the
   wake-up, so the rounding does not add up along a round trip). */
static double
wire_now_us(const struct sim_marlin *s)
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
static void
take_input(struct sim_marlin *s, double now)
{
    if (s->boot_until_ms && s->cfg.boot_hold)
        return; /* held in the link until the banner is out */
    int want = s->stage_cap - s->stage_len;
    if (want <= 0 || !linked(s))
        return;
    ssize_t n = read(s->fd, s->stage + s->stage_len, (size_t)want);
    if (n < 0 && errno == EIO && s->kind == LINK_PTY) {
        host_left(s); /* the slave was closed: no host on the port */
        return;
    }
    if (n == 0 || (n < 0 && errno != EAGAIN && errno != EINTR)) {
        /* TCP host went away: the bridge's listener waits for the next. */
        close_link(s);
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
static void
deliver_input(struct sim_marlin *s, double now)
{
    int64_t now_ms = loop_now_ms(s->loop);
    double until = wire_horizon_us(s, now);
    int i = 0;
    for (; i < s->stage_len && s->stage_us + i * s->byte_us <= until; i++) {
        bool live = now_ms >= s->boot_until_ms && !s->halted;
        if (live && s->rx_len == s->cfg.rx_size) {
            assemble_lines(s);
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
        emergency_byte(s, c);
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

/*
 * Move RX bytes into lines while the queue has room (get_serial_commands).
 * Marlin 2 calls it from loop() and from idle() (manage_inactivity() calls
 * queue.get_available_commands() first thing), and every blocking wait
 * (planner full, M109/M190, G28/G29 moves, G4, M400) runs idle(): the ring
 * drains into the queue while a command blocks, until the queue is full.
 */
static void
assemble_lines(struct sim_marlin *s)
{
    int i = 0;
    while (i < s->rx_len && s->q_len < s->cfg.bufsize) {
        char c = s->rx[i++];
        if (c == '\n' || c == '\r') {
            int before = s->rx_len;
            line_done(s);
            if (s->rx_len != before) { /* a line error emptied the buffer */
                i = 0;
                break;
            }
            continue;
        }
        if (s->line_eol)
            continue;
        if (c == ';') {
            s->line_eol = true;
            continue;
        }
        s->line[s->line_len++] = c;
        if (s->line_len >= MAX_CMD_SIZE - 1)
            s->line_eol = true;
    }
    memmove(s->rx, s->rx + i, (size_t)(s->rx_len - i));
    s->rx_len -= i;
}

/* ---- output pacing ----------------------------------------------------- */

static void
write_output(struct sim_marlin *s, double now)
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
    if (!linked(s)) {
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

static void on_wake(struct loop *l, int fd, unsigned events, void *ud);
static void on_wake_timer(struct loop *l, void *ud);

/* Arm the wake-up for the next event on the wire: a line end reaching the
   printer or the host, a late reply falling due, or the stage half gone
   while the host may have written more. */
static void
arm_wake(struct sim_marlin *s, double now)
{
    double at = 0;
    if (s->stage_len > 0) {
        at = next_line_end_us(s->stage, (size_t)s->stage_len, s->stage_us, s->byte_us);
        double low = s->stage_us + (double)(s->stage_len / 2) * s->byte_us;
        if (low < at)
            at = low;
    }
    if (s->tx.len > 0 && linked(s)) {
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

/* ---- the step ---------------------------------------------------------- */

static void
on_tick(struct loop *l, void *ud)
{
    (void)l;
    struct sim_marlin *s = ud;
    s->tick = 0;
    step(s);
}

static void
on_wake(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)l;
    (void)events;
    struct sim_marlin *s = ud;
    uint64_t n;
    if (read(fd, &n, sizeof(n)) < 0 && errno != EAGAIN)
        log_warn("sim", "timerfd: %s", strerror(errno));
    s->wake_at_us = 0;
    step(s);
}

static void
on_wake_timer(struct loop *l, void *ud)
{
    (void)l;
    struct sim_marlin *s = ud;
    s->wake = 0;
    s->wake_at_us = 0;
    step(s);
}

/*
 * The host closed the pty (or died).  A USB Marlin keeps running what it
 * already received (its replies go nowhere), heaters on, until the port is
 * opened again: that asserts DTR, which resets the board (see host_back).
 * The master stays open, out of the loop (it would report HUP forever).
 */
static void
host_left(struct sim_marlin *s)
{
    loop_del_fd(s->loop, s->fd);
    s->host_gone = true;
    buf_reset(&s->tx); /* what it had received still runs; only replies are lost */
    free_out(s);
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
    firmware_reset(s, true); /* DTR: the bootloader runs, then "start" */
}

static void
on_fd(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)l;
    (void)fd;
    struct sim_marlin *s = ud;
    if (s->hung && (events & (LOOP_HUP | LOOP_ERROR))) {
        close_link(s); /* the host gave up on it */
        return;
    }
    if ((events & LOOP_HUP) && s->kind == LINK_PTY && s->keep_fd < 0 && !s->host_gone) {
        host_left(s);
        return;
    }
    step(s);
}

static void
step(struct sim_marlin *s)
{
    if (s->hung) {
        /* Nothing is read, run or sent any more; the link stays up. */
        if (linked(s) && s->fd_events != 0 && loop_mod_fd(s->loop, s->fd, 0, NULL) == 0)
            s->fd_events = 0;
        return;
    }
    int64_t now = loop_now_ms(s->loop);
    double now_us = wire_now_us(s);
    s->event_us = now_us;
    int64_t dt_ms = now - s->last_ms;
    s->last_ms = now;
    double dt_s = (double)dt_ms / 1000.0 * s->cfg.speed;
    s->sim_s += dt_s;

    if (!s->halted) {
        advance_planner(s, dt_s);
        advance_heaters(s, dt_s);
    }
    if (s->boot_until_ms && now >= s->boot_until_ms) {
        s->boot_until_ms = 0;
        emit(s, "start");
        emit(s, "echo:Marlin 2.1.2.1");
        emit(s, "echo: Last Updated: 2023-08-06 | Author: (slimfarm-sim)");
        emit(s, "echo: Free Memory: 4096  PlannerBufferBytes: 1792");
    }
    take_input(s, now_us);
    deliver_input(s, now_us);
    take_input(s, now_us); /* the stage made room: keep the wire busy */
    if (!s->halted) {
        for (int round = 0; round < 8 && !s->hung; round++) {
            int before = s->q_len;
            assemble_lines(s);
            run_queue(s);
            if (s->q_len == before || s->rx_len == 0)
                break;
        }
        if (s->autoreport_s > 0 && now >= s->autoreport_ms) {
            emit_temps(s, " ", false);
            s->autoreport_ms = now + (int64_t)s->autoreport_s * 1000;
        }
    } else {
        s->rx_len = 0;
    }
    if (s->hung) {
        free_out(s);
        buf_reset(&s->tx);
        step(s); /* silent from here on */
        return;
    }
    write_output(s, now_us);

    /* Ask for input only when the stage can take it, or epoll would spin. */
    if (s->host_gone)
        host_back(s);
    if (linked(s)) {
        bool held = s->boot_until_ms && s->cfg.boot_hold;
        unsigned ev = !held && s->stage_len < s->stage_cap ? LOOP_READ : 0;
        if (ev != s->fd_events && loop_mod_fd(s->loop, s->fd, ev, NULL) == 0)
            s->fd_events = ev;
    }
    arm_wake(s, now_us);
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
static void
firmware_reset(struct sim_marlin *s, bool banner)
{
    s->halted = false;
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
    s->dwell_s = -1;
    free_out(s);
    buf_reset(&s->tx);
    if (banner)
        s->boot_until_ms = loop_now_ms(s->loop) + BOOT_MS;
}

struct sim_marlin *
sim_marlin_new(struct loop *l, const struct sim_marlin_config *c, struct sf_err *err)
{
    if (c->baud < 0 || c->baud > 4000000 || !(c->speed >= 0) || c->speed > 1e6 || c->bufsize < 0 ||
        c->bufsize > 64 || c->planner_blocks < 0 || c->planner_blocks > 256 || c->rx_size < 0 ||
        c->rx_size > 65536 || c->tcp_port > 65535 || c->hang_after < 0) {
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
        if (loop_add_fd(l, s->wake_fd, LOOP_READ, on_wake, s, err) < 0) {
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
    s->event_us = wire_now_us(s);
    firmware_reset(s, true);
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
    step(s);
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
    close_link(s);
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
