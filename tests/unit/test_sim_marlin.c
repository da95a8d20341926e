/*
 * test_sim_marlin.c - the Marlin simulator runs the G-code policy's rows
 * (drivers/gpolicy.h) as Marlin 2.1 does, talked to raw over a socketpair
 * on simulated time: M110 by queue.cpp's line-number check (the number
 * after "M110" when the line's text holds "M110", whatever the command)
 * and by the M110 handler (set_current_line_number when the command runs,
 * unnumbered too); M118 without E1 prints its text raw ("Resend: 1" looks
 * like a reply), with E1 as echo:; M0 and M600 wait for the user until
 * M108; M999 asks for a resend; M111 S1 echoes every command; M997 reboots.
 * The hold fault (faults.h hold=PATH) holds printing moves while its file
 * exists, as a slow printer.
 */
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include "../../sim/marlin/sim_marlin.h"
#include "../../src/base/gcode.h"
#include "../../src/base/log.h"
#include "../t.h"

struct host {
    struct loop *loop;
    struct sim_marlin *sim;
    int fd;        /* our end */
    char in[8192]; /* what the printer said, NUL-terminated */
    size_t in_len;
};

static void
quiet(void *ud, enum log_level lv, const char *subsys, const char *printer, const char *msg)
{
    (void)ud;
    (void)lv;
    (void)subsys;
    (void)printer;
    (void)msg;
}

static void
pump(struct host *h, int ms)
{
    for (int i = 0; i < ms; i++) {
        loop_run_once(h->loop, 1);
        ssize_t n;
        while (h->in_len + 1 < sizeof(h->in) &&
               (n = recv(h->fd, h->in + h->in_len, sizeof(h->in) - 1 - h->in_len, MSG_DONTWAIT)) >
                   0)
            h->in_len += (size_t)n;
        h->in[h->in_len] = '\0';
    }
}

/* Pump until the printer has said want since the last clear (true), or ms ran out. */
static bool
heard(struct host *h, const char *want, int ms)
{
    for (int i = 0; i < ms && !strstr(h->in, want); i += 10)
        pump(h, 10);
    return strstr(h->in, want) != NULL;
}

static void
clear(struct host *h)
{
    h->in_len = 0;
    h->in[0] = '\0';
}

/* Send line, numbered n (with its checksum) when n >= 0. */
static void
say(struct host *h, long n, const char *line)
{
    char b[160];
    if (n >= 0) {
        int k = snprintf(b, sizeof(b), "N%ld %s", n, line);
        snprintf(b + k, sizeof(b) - (size_t)k, "*%u\n", gcode_checksum(b, (size_t)k));
    } else {
        snprintf(b, sizeof(b), "%s\n", line);
    }
    T_TRUE(write(h->fd, b, strlen(b)) == (ssize_t)strlen(b));
}

/* A fault spec the next open_host gives its printer, or NULL. */
static const char *host_fault;

static bool
open_host(struct host *h)
{
    struct sf_err err;
    log_set_sink(quiet, NULL);
    *h = (struct host){ .fd = -1 };
    h->loop = loop_new(&err);
    if (!h->loop)
        return false;
    loop_set_virtual(h->loop);
    int sv[2];
    if (socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, sv) < 0)
        return false;
    struct sim_marlin_config c;
    sim_marlin_config_init(&c);
    c.fd = sv[0];
    c.virtual_time = true;
    c.speed = 100;
    c.boot_hold = true;
    if (host_fault && faults_parse(&c.faults, host_fault, &err) < 0)
        return false;
    h->fd = sv[1];
    h->sim = sim_marlin_new(h->loop, &c, &err);
    if (!h->sim)
        return false;
    return heard(h, "start", 10000);
}

/* Forget what was heard, send line (numbered n, as say), and wait up to ms for want. */
static bool
ask(struct host *h, long n, const char *line, const char *want, int ms)
{
    clear(h);
    say(h, n, line);
    return heard(h, want, ms);
}

/* open_host, then "N0 M110 N0" answered: the next line is N1. */
static bool
open_numbered(struct host *h)
{
    if (!open_host(h))
        return false;
    say(h, 0, "M110 N0");
    return heard(h, "ok", 2000);
}

static void
close_host(struct host *h)
{
    sim_marlin_free(h->sim);
    if (h->fd >= 0)
        close(h->fd);
    loop_free(h->loop);
    log_set_sink(NULL, NULL);
}

T_CASE(sim_m110_as_marlin_queue_and_handler)
{
    struct host h;
    T_TRUE(open_numbered(&h));
    say(&h, 1, "G28");
    T_TRUE(heard(&h, "ok", 20000));
    /* "M110" in another command's text: the queue takes the N after it */
    T_TRUE(ask(&h, 2, "M117 M110 N7", "ok", 2000));
    T_TRUE(ask(&h, 3, "G1 X1", "Resend: 8", 2000));
    T_TRUE(strstr(h.in, "Line Number is not Last Line Number+1, Last Line: 7") != NULL);
    /* the handler: an unnumbered M110 sets the number when it runs */
    T_TRUE(ask(&h, -1, "M110 N50", "ok", 2000));
    T_TRUE(ask(&h, 51, "G1 X2", "ok", 2000));
    T_TRUE(strstr(h.in, "Resend") == NULL);
    close_host(&h);
}

T_CASE(sim_m118_prints_raw_without_e1)
{
    struct host h;
    T_TRUE(open_numbered(&h));
    clear(&h);
    say(&h, 1, "M118 Resend: 1");
    T_TRUE(heard(&h, "\nok", 2000) || heard(&h, "ok", 100));
    T_TRUE(strncmp(h.in, "Resend: 1\n", 10) == 0);
    T_TRUE(ask(&h, 2, "M118 E1 A1 P0 Resend: 1", "echo://Resend: 1\n", 2000));
    close_host(&h);
}

T_CASE(sim_waits_for_the_user_until_m108)
{
    struct host h;
    T_TRUE(open_numbered(&h));
    const char *waits[] = { "M0", "M600" };
    for (int i = 0; i < 2; i++) {
        clear(&h);
        say(&h, 1 + i, waits[i]);
        T_TRUE(heard(&h, "echo:busy: paused for user", 10000));
        T_TRUE(strstr(h.in, "ok") == NULL);
        pump(&h, 3000);
        T_TRUE(strstr(h.in, "ok") == NULL);
        say(&h, -1, "M108");
        T_TRUE(heard(&h, "ok", 2000));
    }
    close_host(&h);
}

T_CASE(sim_m999_m111_m997)
{
    struct host h;
    T_TRUE(open_numbered(&h));
    T_TRUE(ask(&h, 1, "M999", "Resend: 2", 2000));
    T_TRUE(ask(&h, 2, "M111 S1", "echo:DEBUG:ECHO", 2000));
    T_TRUE(ask(&h, 3, "G1 X3", "echo:G1 X3", 2000));
    T_TRUE(ask(&h, 4, "M997", "start", 10000));
    close_host(&h);
}

/*
 * hold=PATH: while PATH exists a printing move (G0-G3 with E and X or Y)
 * does not start: no ok, the lines behind it wait, "echo:busy: processing"
 * keeps the host patient, and "held: CMD" is appended to PATH; travels and
 * retractions run.  Removing PATH lets it go on (its ok, then the lines
 * behind); a new PATH holds the next printing move.  A missing PATH never
 * holds, and is never made.
 */
T_CASE(sim_hold_holds_printing_moves_while_its_file_exists)
{
    char path[512];
    snprintf(path, sizeof(path), "%s/marlin.hold", t_tmpdir());
    int fd = open(path, O_WRONLY | O_CREAT | O_EXCL, 0600);
    T_TRUE(fd >= 0);
    if (fd < 0)
        return;
    close(fd);
    char spec[600];
    snprintf(spec, sizeof(spec), "hold=%s", path);
    host_fault = spec;
    struct host h;
    bool up = open_numbered(&h);
    host_fault = NULL;
    T_TRUE(up);
    if (!up) {
        unlink(path);
        return;
    }
    T_TRUE(ask(&h, 1, "G1 X5 Y5 F3000", "ok", 2000)); /* a travel */
    T_TRUE(ask(&h, 2, "G1 E-1 F2400", "ok", 2000));   /* a retraction */
    T_EQ_STR(t_slurp(path), "");
    clear(&h);
    say(&h, 3, "G1 X10 Y10 E0.5");
    say(&h, 4, "M105");
    T_TRUE(heard(&h, "echo:busy: processing", 5000));
    pump(&h, 5000);
    T_TRUE(strstr(h.in, "ok") == NULL);
    T_EQ_STR(t_slurp(path), "held: G1 X10 Y10 E0.5\n");
    unlink(path);
    clear(&h);
    T_TRUE(heard(&h, "ok T:", 1000)); /* the move's ok, then M105's */
    T_TRUE(strncmp(h.in, "ok", 2) == 0);
    T_TRUE(ask(&h, 5, "G1 X20 Y20 E1", "ok", 2000)); /* no file: no hold */
    /* armed again: the next printing move holds */
    fd = open(path, O_WRONLY | O_CREAT | O_EXCL, 0600);
    T_TRUE(fd >= 0);
    close(fd);
    pump(&h, 100);
    clear(&h);
    say(&h, 6, "G2 X30 Y20 I5 J0 E1.5");
    pump(&h, 3000);
    T_TRUE(strstr(h.in, "ok") == NULL);
    T_EQ_STR(t_slurp(path), "held: G2 X30 Y20 I5 J0 E1.5\n");
    close_host(&h);
    unlink(path);
    /* a PATH that does not exist holds nothing, and is not made */
    host_fault = spec;
    up = open_numbered(&h);
    host_fault = NULL;
    T_TRUE(up);
    if (up) {
        T_TRUE(ask(&h, 1, "G1 X10 Y10 E0.5", "ok", 2000));
        T_TRUE(access(path, F_OK) != 0);
        close_host(&h);
    }
}

/*
 * The counters say where the host's last lines sit (slimfarm-sim prints
 * them on exit, and a failing scenario shows them): the last number taken,
 * the commands queued, the bytes waiting in the RX ring and on the wire.
 * A dwell blocks the queue: lines 2-4 wait in it, 5 and 6 before it.
 */
T_CASE(sim_stats_say_where_the_hosts_lines_sit)
{
    struct host h;
    T_TRUE(open_numbered(&h));
    say(&h, 1, "G4 S100"); /* 1 s at speed 100 */
    for (long n = 2; n <= 6; n++)
        say(&h, n, "G1 X5");
    pump(&h, 50);
    struct sim_marlin_stats st;
    sim_marlin_stats(h.sim, &st);
    T_EQ_INT(st.last_n, 4);
    T_EQ_INT(st.queued, 4);
    T_TRUE(st.rx_len + st.stage_len > 0);
    pump(&h, 3000);
    sim_marlin_stats(h.sim, &st);
    T_EQ_INT(st.last_n, 6);
    T_EQ_INT(st.queued, 0);
    T_EQ_INT(st.rx_len + st.stage_len, 0);
    close_host(&h);
}
