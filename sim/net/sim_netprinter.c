/*
 * sim_netprinter.c - a simulated network printer's machine: sim_marlin on a
 * socketpair, and the host in front of it that streams a job file the way
 * OctoPrint does (sim_netprinter.h).
 *
 * The host is deliberately simple and strict: one numbered, checksummed
 * line in flight (ping-pong), a short history of sent lines for Resend,
 * and a sequence per job: the file's commands, then M400 (so "complete"
 * means executed), or, on cancel, the cancel script.  Manual commands
 * take turns with job lines.  A watchdog re-sends the line in flight when
 * the firmware says nothing for long (a lost "ok"); Marlin then asks for
 * the next line if it had the first, which the host takes as the ok.
 *
 * Thread: the loop thread.
 */
#include "sim_netprinter.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include "../../src/base/buf.h"
#include "../../src/base/gcode.h"
#include "../../src/base/limits.h"
#include "../../src/base/mem.h"
#include "../marlin/sim_marlin.h"

/* Lines kept for Resend: one in flight, a few before it for safety. */
#define HISTORY 8
/* Manual commands waiting their turn. */
#define MANUAL_MAX 64
/* Silence from the firmware, with a line in flight, before it is re-sent (wall ms). */
#define WATCHDOG_MS 15000
/* Longest numbered line: Marlin's MAX_CMD_SIZE is 96; slack for N and *. */
#define LINE_MAX 128

/* Heaters off first, then the fan and the motors (OctoPrint's default script, reordered
   so the hot end cools from the first line). */
static const char *const cancel_script[] = { "M104 S0", "M140 S0", "M107", "M84" };
#define CANCEL_LINES (sizeof(cancel_script) / sizeof(cancel_script[0]))

enum sent_kind {
    SENT_NONE,   /* nothing in flight */
    SENT_HELLO,  /* M110 N0 */
    SENT_JOB,    /* a line of the job file */
    SENT_FINAL,  /* the M400 after the last job line */
    SENT_CANCEL, /* a line of the cancel script */
    SENT_MANUAL, /* a manual command */
};

struct sim_netprinter {
    struct loop *l;
    struct sim_netprinter_config cfg;
    struct sim_marlin *fw; /* the firmware, on the other end of fd */
    int fd;                /* the host's end of the socketpair */
    bool want_write;       /* LOOP_WRITE watched */
    struct buf in;         /* reply bytes not yet a whole line */
    struct buf out;        /* bytes not yet written */
    char uploads[512];     /* the uploads directory */
    bool own_uploads;      /* we made it: remove it */

    enum sim_np_state state;
    char file[SIM_NP_NAME_MAX + 1];
    int64_t file_size, file_pos;
    uint64_t lines_total, lines_done;
    FILE *job;     /* the job file while streaming */
    char *linebuf; /* getline buffer */
    size_t linecap;
    int64_t start_ms, end_ms; /* loop time the job started / ended (0: running) */
    size_t cancel_next;       /* next cancel script line */
    bool final_sent;          /* M400 sent after the last job line */

    bool ready;                   /* the firmware said "start" and took our M110 */
    long next_n;                  /* number of the next new line */
    enum sent_kind sent;          /* what is in flight */
    long sent_n;                  /* its number */
    int64_t sent_end_pos;         /* job line: file position after it */
    long sent_m73_r;              /* job line: its M73 R (minutes left), -1 if none */
    long m73_r;                   /* the last M73 R the firmware took this job, -1 if none */
    long resend_n;                /* > 0: the firmware asked for this line; the next ok sends it */
    char hist[HISTORY][LINE_MAX]; /* numbered lines sent, by number % HISTORY */
    uint64_t watchdog;            /* timer */

    char *manual[MANUAL_MAX]; /* queued manual commands (ring) */
    size_t man_head, man_len;
    char message[160];
};

static void pump(struct sim_netprinter *np);

void
sim_netprinter_config_init(struct sim_netprinter_config *c)
{
    memset(c, 0, sizeof(*c));
    c->speed = 1;
    c->baud = 1000000;
    faults_init(&c->faults);
}

bool
sim_np_running(const struct sim_np_status *st)
{
    return st->state == SIM_NP_PRINTING || st->state == SIM_NP_PAUSING ||
           st->state == SIM_NP_PAUSED || st->state == SIM_NP_CANCELLING;
}

const char *
sim_np_state_name(enum sim_np_state s)
{
    switch (s) {
    case SIM_NP_IDLE:
        return "idle";
    case SIM_NP_PRINTING:
        return "printing";
    case SIM_NP_PAUSING:
        return "pausing";
    case SIM_NP_PAUSED:
        return "paused";
    case SIM_NP_CANCELLING:
        return "cancelling";
    case SIM_NP_CANCELLED:
        return "cancelled";
    case SIM_NP_COMPLETE:
        return "complete";
    case SIM_NP_ERROR:
        return "error";
    }
    return "?";
}

static bool
job_active(const struct sim_netprinter *np)
{
    return np->state == SIM_NP_PRINTING || np->state == SIM_NP_PAUSING ||
           np->state == SIM_NP_PAUSED || np->state == SIM_NP_CANCELLING;
}

static void set_message(struct sim_netprinter *np, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));
static void
set_message(struct sim_netprinter *np, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(np->message, sizeof(np->message), fmt, ap);
    va_end(ap);
}

/* ---- the wire -------------------------------------------------------- */

static void on_fd(struct loop *l, int fd, unsigned events, void *ud);

static void
flush_out(struct sim_netprinter *np)
{
    while (np->out.len) {
        ssize_t k = write(np->fd, np->out.data, np->out.len);
        if (k < 0 && errno == EINTR)
            continue;
        if (k < 0)
            break; /* EAGAIN: wait for writable; other errors show as a hang-up */
        buf_consume(&np->out, (size_t)k);
    }
    bool want = np->out.len > 0;
    if (want != np->want_write) {
        np->want_write = want;
        loop_mod_fd(np->l, np->fd, LOOP_READ | (want ? LOOP_WRITE : 0), NULL);
    }
}

static void
on_watchdog(struct loop *l, void *ud)
{
    (void)l;
    struct sim_netprinter *np = ud;
    np->watchdog = 0;
    if (np->sent == SENT_NONE || np->fd < 0)
        return;
    /* No word for long: the ok was lost, or the line.  Send it again. */
    const char *line = np->hist[np->sent_n % HISTORY];
    buf_append(&np->out, line, strlen(line));
    buf_append(&np->out, "\n", 1);
    flush_out(np);
    np->watchdog = loop_timer_add(np->l, WATCHDOG_MS, on_watchdog, np);
}

static void
kick_watchdog(struct sim_netprinter *np)
{
    if (np->watchdog)
        loop_timer_cancel(np->l, np->watchdog);
    np->watchdog = 0;
    if (np->sent != SENT_NONE)
        np->watchdog = loop_timer_add(np->l, WATCHDOG_MS, on_watchdog, np);
}

/* Send cmd as line n (numbered, checksummed) and remember it. */
static void
send_numbered(struct sim_netprinter *np, long n, const char *cmd, enum sent_kind kind)
{
    char line[LINE_MAX];
    size_t len = gcode_number_line(n, cmd, line, sizeof(line));
    if (!len) {
        /* Too long for the firmware: Marlin would refuse it anyway. */
        len = gcode_number_line(n, "M117 line too long", line, sizeof(line));
    }
    snprintf(np->hist[n % HISTORY], LINE_MAX, "%s", line);
    buf_append(&np->out, line, len);
    buf_append(&np->out, "\n", 1);
    np->sent = kind;
    np->sent_n = n;
    flush_out(np);
    kick_watchdog(np);
}

static void
send_new(struct sim_netprinter *np, const char *cmd, enum sent_kind kind)
{
    send_numbered(np, np->next_n++, cmd, kind);
}

static void
hello(struct sim_netprinter *np)
{
    np->next_n = 0;
    np->resend_n = 0;
    send_new(np, "M110 N0", SENT_HELLO);
}

/* ---- the job --------------------------------------------------------- */

static void
close_job(struct sim_netprinter *np)
{
    if (np->job)
        fclose(np->job);
    np->job = NULL;
}

static void
end_job(struct sim_netprinter *np, enum sim_np_state st)
{
    close_job(np);
    np->state = st;
    np->end_ms = loop_now_ms(np->l);
    if (!np->end_ms)
        np->end_ms = 1;
}

/* The next command of the job file into cmd, or false at its end. */
static bool
next_job_line(struct sim_netprinter *np, char *cmd, size_t cap)
{
    for (;;) {
        ssize_t k = getline(&np->linebuf, &np->linecap, np->job);
        if (k < 0)
            return false;
        size_t n = gcode_strip(np->linebuf, (size_t)k, cmd, cap, NULL);
        if (n > 0) {
            np->sent_end_pos = ftello(np->job);
            /* M73 P.. R..: the slicer's minutes left, which Prusa firmware shows */
            const char *r = strncmp(cmd, "M73 ", 4) == 0 ? strstr(cmd, " R") : NULL;
            np->sent_m73_r = r && r[2] >= '0' && r[2] <= '9' ? strtol(r + 2, NULL, 10) : -1;
            return true;
        }
        /* a comment or blank line: consumed without a round trip */
        np->file_pos = ftello(np->job);
    }
}

/* Send the next line due, if nothing is in flight. */
static void
pump(struct sim_netprinter *np)
{
    if (np->fd < 0 || np->sent != SENT_NONE || !np->ready)
        return;
    if (np->state == SIM_NP_PAUSING) {
        np->state = SIM_NP_PAUSED;
        return;
    }
    if (np->state == SIM_NP_CANCELLING) {
        if (np->cancel_next < CANCEL_LINES) {
            send_new(np, cancel_script[np->cancel_next++], SENT_CANCEL);
            return;
        }
        end_job(np, SIM_NP_CANCELLED);
        return;
    }
    if (np->man_len && np->state != SIM_NP_ERROR) {
        char *cmd = np->manual[np->man_head];
        np->manual[np->man_head] = NULL;
        np->man_head = (np->man_head + 1) % MANUAL_MAX;
        np->man_len--;
        send_new(np, cmd, SENT_MANUAL);
        free(cmd);
        return;
    }
    if (np->state != SIM_NP_PRINTING)
        return;
    char cmd[SF_GCODE_LINE_MAX];
    if (!np->final_sent && next_job_line(np, cmd, sizeof(cmd))) {
        send_new(np, cmd, SENT_JOB);
        return;
    }
    if (!np->final_sent) {
        np->final_sent = true;
        np->file_pos = np->file_size;
        send_new(np, "M400", SENT_FINAL);
        return;
    }
}

/* The firmware took the line in flight. */
static void
line_taken(struct sim_netprinter *np)
{
    enum sent_kind k = np->sent;
    np->sent = SENT_NONE;
    kick_watchdog(np);
    switch (k) {
    case SENT_HELLO:
        np->ready = true;
        break;
    case SENT_JOB:
        np->lines_done++;
        np->file_pos = np->sent_end_pos;
        if (np->sent_m73_r >= 0)
            np->m73_r = np->sent_m73_r;
        break;
    case SENT_FINAL:
        if (np->state == SIM_NP_PRINTING || np->state == SIM_NP_PAUSING)
            end_job(np, SIM_NP_COMPLETE);
        break;
    default:
        break;
    }
}

/* Send numbered line n again, as remembered. */
static void
resend_hist(struct sim_netprinter *np, long n)
{
    const char *line = np->hist[n % HISTORY];
    buf_append(&np->out, line, strlen(line));
    buf_append(&np->out, "\n", 1);
    flush_out(np);
    kick_watchdog(np);
}

static void
on_ok(struct sim_netprinter *np)
{
    if (np->resend_n > 0) {
        long n = np->resend_n;
        np->resend_n = 0;
        if (np->sent != SENT_NONE && n == np->sent_n + 1) {
            line_taken(np); /* it had the line: this is its ok */
        } else if (np->sent != SENT_NONE && n == np->sent_n) {
            resend_hist(np, n); /* garbled on the way: the same line again */
            return;
        } else if (np->sent == SENT_NONE && n == np->next_n) {
            /* nothing in flight and it wants the next: nothing to do */
        } else {
            set_message(np, "printer asked for line %ld, which the host no longer has", n);
            np->sent = SENT_NONE;
            if (job_active(np))
                end_job(np, SIM_NP_ERROR);
        }
    } else if (np->sent != SENT_NONE) {
        line_taken(np);
    }
    pump(np);
}

static void
fail_job(struct sim_netprinter *np, const char *why)
{
    set_message(np, "%s", why);
    end_job(np, SIM_NP_ERROR);
}

static bool
starts(const char *s, const char *prefix)
{
    return strncmp(s, prefix, strlen(prefix)) == 0;
}

static void
on_reply(struct sim_netprinter *np, char *line)
{
    kick_watchdog(np);
    if (starts(line, "ok")) {
        on_ok(np);
    } else if (starts(line, "Resend:") || starts(line, "rs ")) {
        const char *p = line + (line[0] == 'R' ? 7 : 3);
        while (*p == ' ' || *p == 'N')
            p++;
        long n = strtol(p, NULL, 10);
        if (n >= 0)
            np->resend_n = n;
    } else if (starts(line, "Error:")) {
        const char *what = line + 6;
        if (strstr(what, "checksum") || strstr(what, "Checksum") || strstr(what, "Line Number") ||
            strstr(what, "Last Line"))
            return; /* the Resend that follows fixes it */
        fail_job(np, what);
    } else if (strcmp(line, "start") == 0) {
        /* The firmware restarted: whatever it had is gone.  (Its first
           banner, at power-on, only makes the host say hello.) */
        bool active = job_active(np) && np->ready;
        np->sent = SENT_NONE;
        np->ready = false;
        if (active)
            fail_job(np, "printer reset during the job");
        hello(np);
    } else if (starts(line, "//action:cancel")) {
        if (job_active(np) && np->state != SIM_NP_CANCELLING)
            sim_netprinter_cancel(np, NULL);
    } else if (starts(line, "//action:pause")) {
        sim_netprinter_pause(np, NULL);
    } else if (starts(line, "//action:resume")) {
        sim_netprinter_resume(np, NULL);
    }
    /* echo:busy, temperature reports and the rest: signs of life only */
}

static void
on_fd(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)l;
    struct sim_netprinter *np = ud;
    if (events & LOOP_WRITE)
        flush_out(np);
    if (!(events & (LOOP_READ | LOOP_HUP | LOOP_ERROR)))
        return;
    char chunk[4096];
    for (;;) {
        ssize_t k = read(fd, chunk, sizeof(chunk));
        if (k < 0 && errno == EINTR)
            continue;
        if (k < 0 && errno == EAGAIN)
            break;
        if (k <= 0) {
            /* The firmware link is gone (a disconnect fault): the host sees the port close. */
            loop_del_fd(np->l, np->fd);
            close(np->fd);
            np->fd = -1;
            np->sent = SENT_NONE;
            fail_job(np, "printer disconnected");
            return;
        }
        if (buf_append(&np->in, chunk, (size_t)k) < 0)
            buf_reset(&np->in); /* a runaway line: drop it */
        char *nl;
        while (np->fd >= 0 && (nl = memchr(np->in.data, '\n', np->in.len))) {
            size_t n = (size_t)(nl - np->in.data);
            char line[SF_PRINTER_LINE_MAX];
            size_t c = n < sizeof(line) - 1 ? n : sizeof(line) - 1;
            memcpy(line, np->in.data, c);
            line[c] = 0;
            if (c && line[c - 1] == '\r')
                line[c - 1] = 0;
            buf_consume(&np->in, n + 1);
            on_reply(np, line);
        }
    }
}

/* ---- public ---------------------------------------------------------- */

struct sim_netprinter *
sim_netprinter_new(struct loop *l, const struct sim_netprinter_config *c, struct sf_err *err)
{
    struct sim_netprinter *np = mem_calloc(1, sizeof(*np));
    if (!np) {
        sf_err_set(err, SF_ENOMEM, "sim: out of memory");
        return NULL;
    }
    np->l = l;
    np->cfg = *c;
    np->fd = -1;
    buf_init(&np->in, SF_PRINTER_LINE_MAX * 4);
    buf_init(&np->out, 0);
    if (c->uploads_dir) {
        snprintf(np->uploads, sizeof(np->uploads), "%s", c->uploads_dir);
        if (mkdir(np->uploads, 0755) < 0 && errno != EEXIST) {
            sf_err_sys(err, "sim: uploads directory '%s'", np->uploads);
            goto fail;
        }
    } else {
        const char *t = getenv("TMPDIR");
        snprintf(np->uploads, sizeof(np->uploads), "%s/slimfarm-sim-XXXXXX", t && *t ? t : "/tmp");
        if (!mkdtemp(np->uploads)) {
            sf_err_sys(err, "sim: uploads directory '%s'", np->uploads);
            goto fail;
        }
        np->own_uploads = true;
    }
    int sv[2];
    if (socketpair(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0, sv) < 0) {
        sf_err_sys(err, "sim: socketpair");
        goto fail;
    }
    np->fd = sv[0];
    struct sim_marlin_config mc;
    sim_marlin_config_init(&mc);
    mc.baud = c->baud ? c->baud : 1000000;
    mc.speed = c->speed > 0 ? c->speed : 1;
    mc.fd = sv[1];
    mc.log_path = c->log_path;
    mc.faults = c->faults;
    np->fw = sim_marlin_new(l, &mc, err);
    if (!np->fw) {
        close(sv[1]);
        goto fail;
    }
    if (loop_add_fd(l, np->fd, LOOP_READ, on_fd, np, err) < 0) {
        close(np->fd);
        np->fd = -1;
        goto fail;
    }
    return np; /* the firmware boots, says "start", and hello() follows */
fail:
    sim_netprinter_free(np);
    return NULL;
}

static void
remove_dir(const char *dir)
{
    DIR *d = opendir(dir);
    if (!d)
        return;
    struct dirent *e;
    char path[1024];
    while ((e = readdir(d)))
        if (strcmp(e->d_name, ".") && strcmp(e->d_name, "..")) {
            snprintf(path, sizeof(path), "%s/%s", dir, e->d_name);
            unlink(path);
        }
    closedir(d);
    rmdir(dir);
}

void
sim_netprinter_free(struct sim_netprinter *np)
{
    if (!np)
        return;
    if (np->watchdog)
        loop_timer_cancel(np->l, np->watchdog);
    if (np->fd >= 0) {
        loop_del_fd(np->l, np->fd);
        close(np->fd);
    }
    sim_marlin_free(np->fw);
    close_job(np);
    free(np->linebuf);
    for (size_t i = 0; i < MANUAL_MAX; i++)
        free(np->manual[i]);
    buf_release(&np->in);
    buf_release(&np->out);
    if (np->own_uploads)
        remove_dir(np->uploads);
    free(np);
}

const char *
sim_netprinter_uploads(const struct sim_netprinter *np)
{
    return np->uploads;
}

int
sim_netprinter_path(const struct sim_netprinter *np, const char *name, char *out, size_t n,
                    struct sf_err *err)
{
    size_t len = name ? strlen(name) : 0;
    if (!len || len > SIM_NP_NAME_MAX || name[0] == '.')
        return sf_err_set(err, SF_EINVAL, "file name '%s' is empty, too long or starts with '.'",
                          name ? name : "");
    for (size_t i = 0; i < len; i++)
        if (name[i] == '/' || name[i] == '\\' || (unsigned char)name[i] < 0x20)
            return sf_err_set(err, SF_EINVAL, "file name '%s' holds '/' or a control byte", name);
    if ((size_t)snprintf(out, n, "%s/%s", np->uploads, name) >= n)
        return sf_err_set(err, SF_EINVAL, "file name '%s' makes too long a path", name);
    return SF_OK;
}

int64_t
sim_netprinter_file_size(const struct sim_netprinter *np, const char *name)
{
    char path[1024];
    struct stat st;
    if (sim_netprinter_path(np, name, path, sizeof(path), NULL) < 0 || stat(path, &st) < 0 ||
        !S_ISREG(st.st_mode))
        return -1;
    return (int64_t)st.st_size;
}

static int
file_cmp(const void *a, const void *b)
{
    return strcmp(((const struct sim_np_file *)a)->name, ((const struct sim_np_file *)b)->name);
}

int
sim_netprinter_files(const struct sim_netprinter *np, struct sim_np_file *out, int max)
{
    DIR *d = opendir(np->uploads);
    if (!d)
        return 0;
    int n = 0;
    struct dirent *e;
    while (n < max && (e = readdir(d)) != NULL) {
        char path[1024];
        struct stat st;
        if (e->d_name[0] == '.' || strlen(e->d_name) > SIM_NP_NAME_MAX ||
            sim_netprinter_path(np, e->d_name, path, sizeof(path), NULL) < 0 ||
            stat(path, &st) < 0 || !S_ISREG(st.st_mode))
            continue;
        snprintf(out[n].name, sizeof(out[n].name), "%s", e->d_name);
        out[n].size = (int64_t)st.st_size;
        out[n].mtime_s = (int64_t)st.st_mtime;
        n++;
    }
    closedir(d);
    qsort(out, (size_t)n, sizeof(*out), file_cmp);
    return n;
}

bool
sim_netprinter_file_busy(const struct sim_netprinter *np, const char *name)
{
    return job_active(np) && strcmp(np->file, name) == 0;
}

int
sim_netprinter_start(struct sim_netprinter *np, const char *name, struct sf_err *err)
{
    if (job_active(np))
        return sf_err_set(err, SF_EAGAIN, "printer is busy (%s)", sim_np_state_name(np->state));
    if (np->state == SIM_NP_ERROR)
        return sf_err_set(err, SF_EAGAIN, "printer is in error: %s", np->message);
    if (np->fd < 0)
        return sf_err_set(err, SF_EAGAIN, "printer is not connected");
    char path[1024];
    if (sim_netprinter_path(np, name, path, sizeof(path), err) < 0)
        return err ? err->code : SF_EINVAL;
    FILE *f = fopen(path, "r");
    if (!f)
        return errno == ENOENT ? sf_err_set(err, SF_ENOTFOUND, "no file '%s'", name)
                               : sf_err_sys(err, "cannot read '%s'", name);
    /* Count the commands once, for lines_total (a real host shows bytes only). */
    uint64_t lines = 0;
    char cmd[SF_GCODE_LINE_MAX];
    while (getline(&np->linebuf, &np->linecap, f) >= 0)
        if (gcode_strip(np->linebuf, strlen(np->linebuf), cmd, sizeof(cmd), NULL) > 0)
            lines++;
    struct stat st;
    fstat(fileno(f), &st);
    rewind(f);
    close_job(np);
    np->job = f;
    snprintf(np->file, sizeof(np->file), "%s", name);
    np->file_size = (int64_t)st.st_size;
    np->file_pos = 0;
    np->lines_total = lines;
    np->lines_done = 0;
    np->m73_r = -1;
    np->start_ms = loop_now_ms(np->l);
    np->end_ms = 0;
    np->cancel_next = 0;
    np->final_sent = false;
    np->message[0] = 0;
    np->state = SIM_NP_PRINTING;
    pump(np);
    return SF_OK;
}

int
sim_netprinter_pause(struct sim_netprinter *np, struct sf_err *err)
{
    if (np->state != SIM_NP_PRINTING)
        return sf_err_set(err, SF_EAGAIN, "cannot pause: printer is %s",
                          sim_np_state_name(np->state));
    np->state = SIM_NP_PAUSING;
    if (np->sent == SENT_NONE)
        np->state = SIM_NP_PAUSED;
    return SF_OK;
}

int
sim_netprinter_resume(struct sim_netprinter *np, struct sf_err *err)
{
    if (np->state != SIM_NP_PAUSED && np->state != SIM_NP_PAUSING)
        return sf_err_set(err, SF_EAGAIN, "cannot resume: printer is %s",
                          sim_np_state_name(np->state));
    np->state = SIM_NP_PRINTING;
    pump(np);
    return SF_OK;
}

int
sim_netprinter_cancel(struct sim_netprinter *np, struct sf_err *err)
{
    if (np->state != SIM_NP_PRINTING && np->state != SIM_NP_PAUSING && np->state != SIM_NP_PAUSED)
        return sf_err_set(err, SF_EAGAIN, "cannot cancel: printer is %s",
                          sim_np_state_name(np->state));
    close_job(np);
    np->state = SIM_NP_CANCELLING;
    np->cancel_next = 0;
    pump(np);
    return SF_OK;
}

int
sim_netprinter_command(struct sim_netprinter *np, const char *line, struct sf_err *err)
{
    char cmd[96];
    bool too_long = false;
    size_t n = line ? gcode_strip(line, strlen(line), cmd, sizeof(cmd), &too_long) : 0;
    if (!n)
        return sf_err_set(err, SF_EINVAL, "command '%s' is %s", line ? line : "",
                          too_long ? "too long" : "empty");
    if (np->state == SIM_NP_ERROR || np->fd < 0)
        return sf_err_set(err, SF_EAGAIN, "printer is in error: %s", np->message);
    if (np->man_len == MANUAL_MAX)
        return sf_err_set(err, SF_EAGAIN, "%d commands are already queued", MANUAL_MAX);
    char *copy = mem_strdup(cmd);
    if (!copy)
        return sf_err_set(err, SF_ENOMEM, "out of memory");
    np->manual[(np->man_head + np->man_len) % MANUAL_MAX] = copy;
    np->man_len++;
    pump(np);
    return SF_OK;
}

void
sim_netprinter_fail(struct sim_netprinter *np, const char *message)
{
    fail_job(np, message);
}

void
sim_netprinter_reset(struct sim_netprinter *np)
{
    if (job_active(np))
        return;
    np->state = SIM_NP_IDLE;
    np->message[0] = 0;
}

void
sim_netprinter_status(const struct sim_netprinter *np, struct sim_np_status *out)
{
    memset(out, 0, sizeof(*out));
    out->state = np->state;
    snprintf(out->file, sizeof(out->file), "%s", np->file);
    out->file_size = np->file_size;
    out->file_pos = np->file_pos;
    out->lines_total = np->lines_total;
    out->lines_done = np->lines_done;
    out->progress = np->state == SIM_NP_COMPLETE ? 1.0
                    : np->file_size > 0          ? (double)np->file_pos / (double)np->file_size
                                                 : 0;
    if (np->start_ms) {
        int64_t end = np->end_ms ? np->end_ms : loop_now_ms(np->l);
        double speed = np->cfg.speed > 0 ? np->cfg.speed : 1;
        out->print_time_s = (double)(end - np->start_ms) / 1000.0 * speed;
    }
    out->m73_left_s = job_active(np) && np->m73_r >= 0 ? (double)np->m73_r * 60 : -1;
    out->time_left_s = -1;
    if (job_active(np) && out->progress > 0.001)
        out->time_left_s = out->print_time_s * (1 - out->progress) / out->progress;
    else if (np->state == SIM_NP_COMPLETE)
        out->time_left_s = 0;
    struct sim_marlin_stats st;
    sim_marlin_stats(np->fw, &st);
    out->nozzle_c = st.nozzle_c;
    out->nozzle_target_c = st.nozzle_target_c;
    out->bed_c = st.bed_c;
    out->bed_target_c = st.bed_target_c;
    snprintf(out->message, sizeof(out->message), "%s", np->message);
}
