/*
 * sim_marlin.h - a simulated Marlin printer on a pseudo-terminal or TCP.
 *
 * The simulator is a printer, not a mirror of our driver: it speaks the
 * host protocol of Marlin 2.1 as the firmware does (line numbers, XOR
 * checksums, Resend, ADVANCED_OK, busy, M115 capabilities, M155
 * auto-report, host actions, emergency parser), paces bytes like a UART at
 * the configured baud rate, keeps Marlin's BUFSIZE command queue, RX buffer
 * and planner buffer, heats and moves with simulated time (speed factor),
 * and injects the faults of faults.h.  Any host that works with a real
 * Marlin works with it (Printrun's printcore is tested against it).
 *
 * Thread: loop thread only (it registers its fds and timers on the loop).
 * Owns its pty or sockets, its log file and its memory; sim_marlin_free()
 * releases all.
 */
#ifndef SF_SIM_MARLIN_SIM_MARLIN_H
#define SF_SIM_MARLIN_SIM_MARLIN_H

#include <stdbool.h>
#include <stdint.h>

#include "../../src/base/err.h"
#include "../../src/base/loop.h"
#include "faults.h"

struct sim_marlin_config {
    int baud;             /* link rate for pacing, bits/s (10 bits a byte); 0: 115200 */
    double speed;         /* simulated time runs this much faster; 0: 1 */
    int bufsize;          /* BUFSIZE command queue slots; 0: 4 */
    int planner_blocks;   /* BLOCK_BUFFER_SIZE; 0: 16 */
    int rx_size;          /* RX_BUFFER_SIZE bytes; 0: 128 */
    bool advanced_ok;     /* reply "ok N<line> P<planner free> B<queue free>" */
    bool uart;            /* bytes arriving at a full RX buffer are lost (a UART board);
                             false: the host waits (native USB flow control) */
    int tcp_port;         /* -1: pty; 0: any free loopback port; >0: that port */
    int fd;               /* >= 0: serve this connected stream fd (a socketpair end, for
                             simulated-time runs: loop_set_virtual); the sim owns it */
    const char *link;     /* pty mode: keep this symlink pointing at the current pty, or NULL */
    const char *log_path; /* every executed command, one per line, or NULL */
    long hang_after;      /* the firmware hangs after executing this many commands: nothing
                             more is read, run or sent, the link stays up; 0: never */
    long deaf_after;      /* after executing this many commands the firmware reads nothing
                             more (its USB input wedged) but runs on and sends its
                             autoreports; a firmware reset clears it; 0: never */
    bool no_keepalive;    /* HOST_KEEPALIVE_FEATURE off: no "busy" lines while G28/G29 run */
    bool boot_hold;       /* bytes the host sends while the firmware boots wait in the link
                             and are read after "start" (a USB bridge that holds them while
                             the board resets); false: the bootloader loses them */
    bool virtual_time;    /* the loop runs on simulated time (loop_set_virtual): the wire's
                             events wake the printer on loop timers, to the millisecond;
                             false: on a timerfd, to the microsecond */
    struct faults faults; /* faults_init() for none */
};

struct sim_marlin_stats {
    uint64_t executed;           /* commands executed (what the log holds) */
    uint64_t resends;            /* Resend requests sent */
    uint64_t starved;            /* times the planner ran dry between streamed moves */
    double starved_s;            /* simulated seconds it stood dry in those gaps */
    uint64_t rx_bytes, tx_bytes; /* bytes over the link */
    uint64_t connects;           /* host connections (TCP) or pty openings */
    uint64_t rx_dropped;         /* bytes lost to a full RX buffer (uart) */
    uint64_t hits;               /* targeted reply corruptions made (faults.hit_*) */
    uint64_t oks_dropped;        /* oks not sent (faults.drop_ok, faults.drop_oks) */
    uint64_t oks_burst;          /* of them, the burst's (faults.drop_oks) */
    uint64_t ep_near;  /* lines numbered from 1 one byte from the emergency parser acting */
    uint64_t ep_acted; /* lines the emergency parser acted on (M108, M112, M410) */
    bool halted;       /* killed (M112, thermal runaway); needs a reset */
    long last_n;       /* the last line number taken (a line's N, or M110's) */
    int queued;        /* commands in the BUFSIZE queue, the one running included */
    int rx_len;        /* bytes in the RX ring, not yet made into a line */
    int stage_len;     /* bytes taken from the link, still on the wire to the printer */
    double x, y, z, e; /* current logical position, mm */
    double nozzle_c, nozzle_target_c, bed_c, bed_target_c;
};

/* Default config: pty, 115200, speed 1, stock Marlin sizes, no faults. */
void sim_marlin_config_init(struct sim_marlin_config *c);

/* Start the printer on loop l: open the pty or listen.  NULL with err set. */
struct sim_marlin *sim_marlin_new(struct loop *l, const struct sim_marlin_config *c,
                                  struct sf_err *err);
/* Where hosts connect: the pty path (or the link), or "tcp://127.0.0.1:PORT". */
const char *sim_marlin_path(const struct sim_marlin *s);
void sim_marlin_stats(const struct sim_marlin *s, struct sim_marlin_stats *out);
/* Flush the log, close everything, free.  NULL is fine. */
void sim_marlin_free(struct sim_marlin *s);

#endif
