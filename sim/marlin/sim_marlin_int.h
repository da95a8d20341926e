/*
 * sim_marlin_int.h - internal to the simulated Marlin printer: the state
 * its files share and the functions they call across (sim_marlin.c:
 * lifecycle, link, the step; sim_marlin_wire.c: the UART and reply
 * pacing; sim_marlin_serial.c: lines, numbers, checksums, the emergency
 * parser; sim_marlin_cmd.c: commands, planner, heaters).  Nothing outside
 * sim/marlin includes it.
 *
 * Thread: loop thread only.
 */
#ifndef SF_SIM_MARLIN_SIM_MARLIN_INT_H
#define SF_SIM_MARLIN_SIM_MARLIN_INT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "../../src/base/buf.h"
#include "../../src/base/loop.h"
#include "faults.h"
#include "sim_marlin.h"

#define MAX_CMD_SIZE 96        /* Marlin's line buffer */
#define TX_MAX       (1 << 20) /* reply bytes waiting for the wire */
#define AMBIENT_C    22.0

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
    bool deaf;             /* cfg.deaf_after reached: reads nothing until a reset */
    bool stuck;            /* faults.stuck_after reached: busy for good */
    bool held;             /* the head is a printing move held by faults.hold_path */
    bool hold_on;          /* faults.hold_path existed at the last look */
    int64_t hold_look_ms;  /* when to look at it again */
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
    bool wait_heat_interrupted; /* M108: ends a heating wait, and a wait for the user (M0, M600) */
    int debug_flags;            /* M111 S: Marlin's marlin_debug_flags (1 ECHO ... 32 LEVELING) */
    bool reset_pending;         /* M997 ran: reset once it is popped */
    int autoreport_s;           /* M155 S; 0 off */
    int64_t autoreport_ms;      /* next auto-report */
    struct sim_marlin_stats st;
};

/* A host is connected: bytes can flow. */
static inline bool
sim_linked(const struct sim_marlin *s)
{
    return s->fd >= 0 && !s->host_gone;
}

/* ---- sim_marlin.c ---- */

/* Close the link to the host (and the pty slave held); what is on the wire is lost. */
void sim_close_link(struct sim_marlin *s);

/* The link drops: the host sees EOF/EIO; a new pty (same link) or the listener waits. */
void sim_drop_link(struct sim_marlin *s);

/*
 * The host closed the pty (or died).  A USB Marlin keeps running what it
 * already received (its replies go nowhere), heaters on, until the port is
 * opened again: that asserts DTR, which resets the board (see host_back).
 * The master stays open, out of the loop (it would report HUP forever).
 */
void sim_host_left(struct sim_marlin *s);

/* Advance the printer to now: the wire, the queue, the planner and heaters; rearm the timers. */
void sim_step(struct sim_marlin *s);

/* Power-on or reset: everything volatile is lost; "start" after the boot delay. */
void sim_firmware_reset(struct sim_marlin *s, bool banner);

/* ---- sim_marlin_wire.c ---- */

/* Queue a reply line (the reply faults apply). */
void sim_emit(struct sim_marlin *s, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

/* Drop the queued reply lines. */
void sim_free_out(struct sim_marlin *s);

/* A temperature report after prefix ("ok ", " "), with " W:?" while a wait runs. */
void sim_emit_temps(struct sim_marlin *s, const char *prefix, bool with_wait);

/* Now on the wire's clock, microseconds (on simulated time the loop's
   whole milliseconds: wake-ups come at the first one at or after an
   event, and what an event causes is timed from the event, not from the
   wake-up, so the rounding does not add up along a round trip). */
double sim_wire_now_us(const struct sim_marlin *s);

/* Take what the host wrote off the link onto the wire (the stage). */
void sim_take_input(struct sim_marlin *s, double now);

/*
 * Staged bytes whose time has come reach the RX ring, one by one as the
 * UART's interrupt stores them.  A full ring drains into the queue while
 * the queue has room (idle() runs often enough on a real board); with the
 * queue full too, a UART loses the byte and a native-USB board holds the
 * host back.
 */
void sim_deliver_input(struct sim_marlin *s, double now);

/* Queued replies whose time has come go on the wire; bytes that reached the host by now are
 * written. */
void sim_write_output(struct sim_marlin *s, double now);

/* Arm the wake-up for the next event on the wire: a line end reaching the
   printer or the host, a late reply falling due, or the stage half gone
   while the host may have written more. */
void sim_arm_wake(struct sim_marlin *s, double now);

/* The timerfd wake-up (real time). */
void sim_on_wake(struct loop *l, int fd, unsigned events, void *ud);

/* ---- sim_marlin_serial.c ---- */

/* The ok for line (ADVANCED_OK: its N, the planner and queue room). */
void sim_send_ok(struct sim_marlin *s, const char *line);

/* One byte through the emergency parser; a line end acts on the line. */
void sim_emergency_byte(struct sim_marlin *s, char c);

/*
 * Move RX bytes into lines while the queue has room (get_serial_commands).
 * Marlin 2 calls it from loop() and from idle() (manage_inactivity() calls
 * queue.get_available_commands() first thing), and every blocking wait
 * (planner full, M109/M190, G28/G29 moves, G4, M400) runs idle(): the ring
 * drains into the queue while a command blocks, until the queue is full.
 */
void sim_assemble_lines(struct sim_marlin *s);

/* ---- sim_marlin_cmd.c ---- */

/* Free planner blocks. */
int sim_planner_free(const struct sim_marlin *s);

/* Run the planner for dt_s simulated seconds. */
void sim_advance_planner(struct sim_marlin *s, double dt_s);

/* Heat or cool toward the targets for dt_s simulated seconds. */
void sim_advance_heaters(struct sim_marlin *s, double dt_s);

/* Run the queue head, and the ones after it that do not block. */
void sim_run_queue(struct sim_marlin *s);

#endif
