/*
 * test_netdrv.c - the Moonraker and PrusaLink drivers against their
 * simulators, in one process on one loop, through HTTP on loopback as with
 * a real printer: a job's commands run once each and in order, pause,
 * resume and cancel, authentication failures, Klipper's shutdown, a job
 * cancelled or failed at the printer, 5xx bursts and an upload cut
 * half-way (the job is retried, never lost), 409 from a busy printer, and
 * HTTP Digest.
 *
 * Waits are bounded on the wall clock (WAIT_MS), never by loop turns: the
 * machine may be loaded.
 */
#include <arpa/inet.h>
#include <netinet/in.h>
#include <signal.h>
#include <stdlib.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "../../drivers/drv.h"
#include "../../drivers/net/drv_moonraker.h"
#include "../../drivers/net/drv_prusalink.h"
#include "../../sim/net/sim_moonraker.h"
#include "../../sim/net/sim_netbase.h"
#include "../../sim/net/sim_octoprint.h"
#include "../../sim/net/sim_prusalink.h"
#include "../../src/base/buf.h"
#include "../../src/base/log.h"
#include "../t.h"

#define WAIT_MS    120000
#define SPEED      2000.0
#define MAX_EVENTS 4096

/* What the driver reported, in order. */
struct rec {
    int n;
    enum drv_event ev[MAX_EVENTS];
    enum drv_state st[MAX_EVENTS];
    char last_msg[160]; /* status.message at the last job end or state change */
    int done, failed, cancelled;
    char end_msg[160]; /* status.message at the job's end */
};

static void
on_event(struct drv *d, enum drv_event ev, void *ud)
{
    struct rec *r = ud;
    if (r->n < MAX_EVENTS) {
        r->ev[r->n] = ev;
        r->st[r->n] = d->status.state;
        r->n++;
    }
    if (ev == DRV_EV_JOB_DONE)
        r->done++;
    if (ev == DRV_EV_JOB_FAILED)
        r->failed++;
    if (ev == DRV_EV_JOB_CANCELLED)
        r->cancelled++;
    if (ev == DRV_EV_JOB_DONE || ev == DRV_EV_JOB_FAILED || ev == DRV_EV_JOB_CANCELLED)
        snprintf(r->end_msg, sizeof(r->end_msg), "%s", d->status.message);
    if (ev == DRV_EV_STATE || ev == DRV_EV_JOB_FAILED)
        snprintf(r->last_msg, sizeof(r->last_msg), "%s", d->status.message);
}

static int64_t
wall_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000 + ts.tv_nsec / 1000000;
}

/* Run l until cond(ud) holds or WAIT_MS pass; true if it held. */
static bool
run_until(struct loop *l, bool (*cond)(void *), void *ud)
{
    int64_t end = wall_ms() + WAIT_MS;
    while (!cond(ud)) {
        if (wall_ms() > end)
            return false;
        loop_run_once(l, 50);
    }
    return true;
}

struct waiter {
    struct drv *d;
    struct rec *r;
    enum drv_state state;
    int ends;
};

static bool
is_state(void *ud)
{
    struct waiter *w = ud;
    return w->d->status.state == w->state;
}

static bool
job_ended(void *ud)
{
    struct waiter *w = ud;
    return w->r->done + w->r->failed + w->r->cancelled >= w->ends;
}

static bool
progressed(void *ud)
{
    struct waiter *w = ud;
    return w->d->status.lines_acked > 40 && w->d->status.state == DRV_PRINTING;
}

/* A job of n_moves moves (and a few set-up commands) in the test's scratch dir. */
static const char *
job_file(const char *name, int n_moves)
{
    static char path[512];
    snprintf(path, sizeof(path), "%s/%s", t_tmpdir(), name);
    FILE *f = fopen(path, "w");
    if (!f)
        return NULL;
    fprintf(f, "; a test job\nG28\nG90\nM82\nG92 E0\n");
    for (int i = 0; i < n_moves; i++)
        fprintf(f, "G1 X%d.%d Y%d E%d.%02d F1800 ; move %d\n", 10 + i % 50, i % 10, 20 + i % 40,
                i / 10, i % 100, i);
    fprintf(f, "G1 Z10 F600\nM84\n");
    fclose(f);
    return path;
}

/* The commands of a G-code file (comments and blanks dropped), or a log's lines. */
static int
commands(const char *path, char ***out, struct sf_err *err)
{
    struct buf b;
    buf_init(&b, (size_t)64 << 20);
    int rc = buf_read_file(&b, path, err);
    if (rc) {
        buf_release(&b);
        return rc;
    }
    int n = 0, cap = 0;
    char **v = NULL;
    char *save = NULL;
    for (char *line = strtok_r(b.data, "\n", &save); line; line = strtok_r(NULL, "\n", &save)) {
        char *semi = strchr(line, ';');
        if (semi)
            *semi = '\0';
        while (*line == ' ')
            line++;
        size_t k = strlen(line);
        while (k > 0 && (line[k - 1] == ' ' || line[k - 1] == '\r'))
            line[--k] = '\0';
        if (!k)
            continue;
        if (n == cap) {
            cap = cap ? cap * 2 : 256;
            v = realloc(v, (size_t)cap * sizeof(*v));
        }
        v[n++] = strdup(line);
    }
    buf_release(&b);
    *out = v;
    return n;
}

static void
free_commands(char **v, int n)
{
    for (int i = 0; i < n; i++)
        free(v[i]);
    free(v);
}

/* Lines the host in front of the firmware adds (handshake, M400 at the end). */
static bool
host_line(const char *s)
{
    return strncmp(s, "M110", 4) == 0 || strcmp(s, "M400") == 0 || strcmp(s, "M105") == 0 ||
           strcmp(s, "M115") == 0 || strncmp(s, "M155", 4) == 0;
}

/*
 * The executed log at log_path equals the file's commands, once each, in
 * order (host lines aside), followed by at most `tail` lines (a cancel
 * script).  Returns the number of the file's commands found, or -1.
 */
static int
log_matches(const char *log_path, const char *gcode, bool whole, char *why, size_t n)
{
    struct sf_err err;
    char **want, **got;
    int nw = commands(gcode, &want, &err);
    int ng = commands(log_path, &got, &err);
    if (nw < 0 || ng < 0) {
        snprintf(why, n, "%s", err.msg);
        return -1;
    }
    int i = 0, j = 0;
    for (; j < ng && i < nw; j++) {
        if (host_line(got[j]))
            continue;
        if (strcmp(got[j], want[i]) != 0) {
            if (!whole)
                break; /* the prefix ends here: the rest is checked below */
            snprintf(why, n, "log line %d '%s' where command %d '%s' was due", j + 1, got[j], i + 1,
                     want[i]);
            i = -1;
            break;
        }
        i++;
    }
    if (i >= 0 && whole && i != nw) {
        snprintf(why, n, "%d of the file's %d commands ran", i, nw);
        i = -1;
    }
    if (i >= 0 && !whole) {
        /* a cancelled job: after its prefix, the host's cancel script and nothing else */
        static const char *const script[] = { "M104 S0", "M140 S0", "M107", "M84" };
        size_t k = 0;
        for (; j < ng; j++) {
            if (host_line(got[j]))
                continue;
            if (k >= 4 || strcmp(got[j], script[k]) != 0) {
                snprintf(why, n, "log line %d '%s' after the job's %d commands", j + 1, got[j], i);
                i = -1;
                break;
            }
            k++;
        }
        if (i >= 0 && k != 4) {
            snprintf(why, n, "the cancel script is not whole (%zu of 4 lines)", k);
            i = -1;
        }
    }
    free_commands(want, nw);
    free_commands(got, ng);
    return i;
}

/* ---- a fixture: one simulator, one driver ---- */

enum kind { MOONRAKER, PRUSALINK };

struct fx {
    struct loop *l;
    enum kind kind;
    struct sim_moonraker *mr;
    struct sim_prusalink *pl;
    struct drv *d;
    struct rec rec;
    char log[512];
    char url[64];
};

/* The simulators' speed (a case may slow them down for a print that lasts). */
static double fx_speed = SPEED;
/* The driver's poll periods (0: its defaults; a case may set them). */
static int fx_poll_ms, fx_poll_idle_ms;

/* Start a simulator of kind with faults (NULL-terminated) and a driver with key/user. */
static int
fx_start(struct fx *f, enum kind kind, const char *sim_key, const char *const *faults,
         const char *drv_key, const char *user, const char *password, struct sf_err *err)
{
    memset(f, 0, sizeof(*f));
    f->kind = kind;
    static int seq;
    snprintf(f->log, sizeof(f->log), "%s/exec-%d.log", t_tmpdir(), ++seq);
    f->l = loop_new(err);
    if (!f->l)
        return SF_EIO;
    int port;
    if (kind == MOONRAKER) {
        struct sim_moonraker_config c;
        sim_moonraker_config_init(&c);
        c.api_key = sim_key;
        c.machine.speed = fx_speed;
        c.machine.log_path = f->log;
        for (int i = 0; faults && faults[i]; i++)
            if (sim_moonraker_fault_parse(&c, faults[i], err))
                return SF_EINVAL;
        f->mr = sim_moonraker_new(f->l, &c, err);
        if (!f->mr)
            return SF_EIO;
        port = sim_moonraker_port(f->mr);
    } else {
        struct sim_prusalink_config c;
        sim_prusalink_config_init(&c);
        c.api_key = user ? NULL : sim_key;
        c.user = user ? "maker" : NULL;
        c.password = user ? sim_key : NULL;
        c.machine.speed = SPEED;
        c.machine.log_path = f->log;
        for (int i = 0; faults && faults[i]; i++)
            if (sim_prusalink_fault_parse(&c, faults[i], err))
                return SF_EINVAL;
        f->pl = sim_prusalink_new(f->l, &c, err);
        if (!f->pl)
            return SF_EIO;
        port = sim_prusalink_port(f->pl);
    }
    snprintf(f->url, sizeof(f->url), "http://127.0.0.1:%d/", port);
    struct drv_config dc = { .name = kind == MOONRAKER ? "voron" : "mk4",
                             .kind = kind == MOONRAKER ? "moonraker" : "prusalink",
                             .url = f->url,
                             .api_key = drv_key,
                             .poll_ms = fx_poll_ms,
                             .poll_idle_ms = fx_poll_idle_ms };
    (void)password;

    dc.user = user;
    dc.password = password;

    f->d = drv_new(f->l, &dc, on_event, &f->rec, err);
    if (!f->d)
        return SF_EINVAL;
    return f->d->ops->open(f->d, err);
}

/* Free the driver, then the simulator (its log is flushed). */
static void
fx_stop(struct fx *f)
{
    drv_free(f->d);
    f->d = NULL;
    sim_moonraker_free(f->mr);
    sim_prusalink_free(f->pl);
    f->mr = NULL;
    f->pl = NULL;
    loop_free(f->l);
    f->l = NULL;
}

/* Stop the printer, then check its executed log against the job file: the
   whole file, or (a job cancelled) a prefix of it; a failure names the
   case's line. */
#define FX_STOP_CHECK(f, job, whole) fx_stop_check(f, job, whole, __LINE__)
static void
fx_stop_check(struct fx *f, const char *job, bool whole, int line)
{
    fx_stop(f);
    char why[300] = "";
    if (log_matches(f->log, job, whole, why, sizeof(why)) < 0)
        t_fail(__FILE__, line, "%s", why);
}

static bool
fx_wait_state(struct fx *f, enum drv_state s)
{
    if (getenv("NETDRV_SETTLE"))
        for (int i = 0; i < 20; i++)
            loop_run_once(f->l, 50);
    struct waiter w = { .d = f->d, .r = &f->rec, .state = s };
    return run_until(f->l, is_state, &w);
}

static bool
fx_wait_end(struct fx *f, int ends)
{
    struct waiter w = { .d = f->d, .r = &f->rec, .ends = ends };
    return run_until(f->l, job_ended, &w);
}

static bool
fx_wait_progress(struct fx *f)
{
    struct waiter w = { .d = f->d, .r = &f->rec };
    return run_until(f->l, progressed, &w);
}

/* ---- the cases, each for both drivers ---- */

static void
job_runs_once_each(enum kind kind)
{
    struct fx f;
    struct sf_err err;
    T_OK(fx_start(&f, kind, "k3y", NULL, "k3y", NULL, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    const char *job = job_file("once.gcode", 300);
    T_OK(f.d->ops->start_job(f.d, job, 0, NULL, &err), &err);
    T_TRUE(fx_wait_end(&f, 1));
    T_EQ_INT(f.rec.done, 1);
    T_EQ_INT(f.d->status.state, DRV_IDLE);
    T_EQ_INT(f.d->status.lines_acked, f.d->status.lines_total);
    /* the printer's temperatures reach the farm (the machine sits at room temperature) */
    T_TRUE(f.d->status.nozzle_c > 10 && f.d->status.bed_c > 10);
    FX_STOP_CHECK(&f, job, true);
}

T_CASE(moonraker_job_runs_once_each)
{
    job_runs_once_each(MOONRAKER);
}

static bool
mr_subscribed(void *ud)
{
    struct fx *f = ud;
    return sim_moonraker_subscribed(f->mr) > 0;
}

static int
progress_events(const struct rec *r)
{
    int k = 0;
    for (int i = 0; i < r->n; i++)
        k += r->ev[i] == DRV_EV_PROGRESS;
    return k;
}

static bool
progress_6_or_end(void *ud)
{
    struct fx *f = ud;
    return progress_events(&f->rec) >= 6 || f->rec.done + f->rec.failed > 0;
}

/* How a push case watches its printer: status polls made so far, cutting the push sockets,
   and whether one stands. */
struct push_probe {
    void *ud;
    uint64_t (*polls)(void *ud);
    void (*cut)(void *ud);
    bool (*up)(void *ud);
};
static const struct push_probe *probe;
static uint64_t polls_mark; /* the status polls at a point of the case */

static bool
probe_polled_again(void *ud)
{
    (void)ud;
    return probe->polls(probe->ud) > polls_mark;
}

static bool
probe_up(void *ud)
{
    (void)ud;
    return probe->up(probe->ud);
}

/*
 * A push driver's print (f idle): once the socket stands, a print whose
 * progress the farm sees move again and again costs no status poll but the
 * one or two that confirm its start; when the socket drops mid-print,
 * polling takes over at once, the socket comes back, and the job ends done
 * with every line counted.
 */
static void
push_print(struct fx *f, const char *job, const struct push_probe *p)
{
    struct sf_err err;
    probe = p;
    T_TRUE(run_until(f->l, probe_up, NULL));
    uint64_t q0 = p->polls(p->ud);
    T_OK(f->d->ops->start_job(f->d, job, 0, NULL, &err), &err);
    T_TRUE(run_until(f->l, progress_6_or_end, f));
    T_EQ_INT(f->rec.done + f->rec.failed, 0);
    T_TRUE(p->polls(p->ud) - q0 <= 2); /* polling would have asked each time */
    polls_mark = p->polls(p->ud);
    p->cut(p->ud);
    T_TRUE(run_until(f->l, probe_polled_again, NULL));
    T_EQ_INT(f->rec.done + f->rec.failed, 0);
    T_TRUE(fx_wait_end(f, 1));
    T_EQ_INT(f->rec.done, 1);
    T_EQ_INT(f->d->status.lines_acked, f->d->status.lines_total);
    T_TRUE(run_until(f->l, probe_up, NULL));
}

static uint64_t
mr_queries(void *ud)
{
    return sim_moonraker_queries(((struct fx *)ud)->mr);
}

static void
mr_drop(void *ud)
{
    sim_moonraker_drop_sockets(((struct fx *)ud)->mr);
}

/* Moonraker's websocket: once the driver has subscribed, the socket's updates replace the
   polls (push_print). */
T_CASE(moonraker_push_socket_replaces_polls)
{
    struct fx f;
    struct sf_err err;
    fx_speed = 60; /* a print of seconds: time for many updates */
    int rc = fx_start(&f, MOONRAKER, "k3y", NULL, "k3y", NULL, NULL, &err);
    fx_speed = SPEED;
    T_OK(rc, &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    const char *job = job_file("push.gcode", 4000);
    struct push_probe p = { &f, mr_queries, mr_drop, mr_subscribed };
    push_print(&f, job, &p);
    FX_STOP_CHECK(&f, job, true);
}

static bool
mr_unsubscribed(void *ud)
{
    return !mr_subscribed(ud);
}

/*
 * A Klippy restart drops every websocket subscription (Moonraker's
 * klippy_connection.py, _on_connection_closed): the driver, told by
 * notify_klippy_disconnected, polls meanwhile and subscribes again on the
 * same socket after notify_klippy_ready, and the socket's updates stand in
 * for the polls again (a print costs no more than its confirming polls).
 */
static void
resubscribes_after_klippy_restart(const char *const *faults)
{
    struct fx f;
    struct sf_err err;
    fx_speed = 60;
    int rc = fx_start(&f, MOONRAKER, "k3y", faults, "k3y", NULL, NULL, &err);
    fx_speed = SPEED;
    T_OK(rc, &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    T_TRUE(run_until(f.l, mr_subscribed, &f));
    int opened = sim_moonraker_ws_opened(f.mr);
    sim_moonraker_firmware_restart(f.mr);
    T_TRUE(run_until(f.l, mr_unsubscribed, &f));
    T_TRUE(run_until(f.l, mr_subscribed, &f));
    T_EQ_INT(sim_moonraker_ws_opened(f.mr), opened); /* the same socket, not a new one */
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    const char *job = job_file("resub.gcode", 4000);
    struct push_probe p = { &f, mr_queries, mr_drop, mr_subscribed };
    probe = &p;
    uint64_t q0 = mr_queries(&f);
    T_OK(f.d->ops->start_job(f.d, job, 0, NULL, &err), &err);
    T_TRUE(run_until(f.l, progress_6_or_end, &f));
    T_TRUE(mr_queries(&f) - q0 <= 2); /* the socket's updates, not polls */
    T_TRUE(fx_wait_end(&f, 1));
    T_EQ_INT(f.rec.done, 1);
    FX_STOP_CHECK(&f, job, true);
}

T_CASE(moonraker_push_resubscribes_after_klippy_restart)
{
    resubscribes_after_klippy_restart(NULL);
}

/*
 * As above, but the socket never hears notify_klippy_ready (miss-ready=1:
 * lost on its way): the polls, asking /server/info meanwhile, see Klippy
 * ready, and the driver subscribes again on the held socket.  It once
 * waited for the notification for ever, the printer polled all along.
 */
T_CASE(moonraker_push_resubscribes_when_klippy_ready_is_missed)
{
    const char *faults[] = { "miss-ready=1", NULL };
    resubscribes_after_klippy_restart(faults);
}

T_CASE(prusalink_job_runs_once_each)
{
    job_runs_once_each(PRUSALINK);
}

static bool
sim_paused(void *ud)
{
    struct fx *f = ud;
    struct sim_np_status st;
    f->mr ? sim_moonraker_status(f->mr, &st) : sim_prusalink_status(f->pl, &st);
    return st.state == SIM_NP_PAUSED;
}

static void
pause_resume_cancel(enum kind kind)
{
    struct fx f;
    struct sf_err err;
    T_OK(fx_start(&f, kind, "k3y", NULL, "k3y", NULL, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    const char *job = job_file("prc.gcode", 4000);
    T_OK(f.d->ops->start_job(f.d, job, 0, NULL, &err), &err);
    T_TRUE(fx_wait_progress(&f));
    T_OK(f.d->ops->pause(f.d, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_PAUSED));
    /* nothing runs while paused: once the machine has stopped, its count stands still */
    T_TRUE(run_until(f.l, sim_paused, &f));
    struct sim_np_status a, b;
    f.mr ? sim_moonraker_status(f.mr, &a) : sim_prusalink_status(f.pl, &a);
    int64_t until = wall_ms() + 1000;
    while (wall_ms() < until)
        loop_run_once(f.l, 50);
    f.mr ? sim_moonraker_status(f.mr, &b) : sim_prusalink_status(f.pl, &b);
    T_EQ_INT(a.lines_done, b.lines_done);
    T_OK(f.d->ops->resume(f.d, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_PRINTING));
    T_OK(f.d->ops->cancel(f.d, &err), &err);
    T_TRUE(fx_wait_end(&f, 1));
    T_EQ_INT(f.rec.cancelled, 1);
    T_EQ_INT(f.rec.failed, 0);
    T_EQ_INT(f.d->status.state, DRV_IDLE);
    FX_STOP_CHECK(&f, job, false);
}

T_CASE(moonraker_pause_resume_cancel)
{
    pause_resume_cancel(MOONRAKER);
}

T_CASE(prusalink_pause_resume_cancel)
{
    pause_resume_cancel(PRUSALINK);
}

static void
wrong_key(enum kind kind)
{
    struct fx f;
    struct sf_err err;
    T_OK(fx_start(&f, kind, "right", NULL, "wrong", NULL, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_OFFLINE));
    T_TRUE(strstr(f.d->status.message, "authentication failed") != NULL);
    fx_stop(&f);
}

T_CASE(moonraker_wrong_key)
{
    wrong_key(MOONRAKER);
}

T_CASE(prusalink_wrong_key)
{
    wrong_key(PRUSALINK);
}

T_CASE(moonraker_klippy_shutdown_is_an_error_with_its_message)
{
    struct fx f;
    struct sf_err err;
    const char *faults[] = { "shutdown=100", NULL };
    T_OK(fx_start(&f, MOONRAKER, NULL, faults, NULL, NULL, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    T_OK(f.d->ops->start_job(f.d, job_file("shut.gcode", 2000), 0, NULL, &err), &err);
    T_TRUE(fx_wait_end(&f, 1));
    T_EQ_INT(f.rec.failed, 1);
    T_EQ_INT(f.d->status.state, DRV_ERROR);
    T_TRUE(strstr(f.rec.end_msg, "MCU 'mcu' shutdown: Timer too close") != NULL);
    fx_stop(&f);
}

static void
cancelled_at_printer(enum kind kind)
{
    struct fx f;
    struct sf_err err;
    const char *faults[] = { "cancel=50", NULL };
    T_OK(fx_start(&f, kind, NULL, faults, NULL, NULL, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    T_OK(f.d->ops->start_job(f.d, job_file("cap.gcode", 2000), 0, NULL, &err), &err);
    T_TRUE(fx_wait_end(&f, 1));
    T_EQ_INT(f.rec.failed, 1);
    T_EQ_STR(f.rec.end_msg, "cancelled at the printer");
    T_EQ_INT(f.d->status.state, DRV_IDLE);
    fx_stop(&f);
}

T_CASE(moonraker_cancelled_at_printer)
{
    cancelled_at_printer(MOONRAKER);
}

T_CASE(prusalink_cancelled_at_printer)
{
    cancelled_at_printer(PRUSALINK);
}

static void
survives_5xx_and_cut_upload(enum kind kind)
{
    struct fx f;
    struct sf_err err;
    /* the first upload is cut half-way; later a burst of 503s hits the polls */
    const char *faults[] = { "drop-upload=1", "5xx=3@8", NULL };
    T_OK(fx_start(&f, kind, NULL, faults, NULL, NULL, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    const char *job = job_file("flaky.gcode", 3000); /* over 64 KiB: cut inside the body */
    T_OK(f.d->ops->start_job(f.d, job, 0, NULL, &err), &err);
    T_TRUE(fx_wait_end(&f, 1));
    T_EQ_INT(f.rec.done, 1);
    T_EQ_INT(f.rec.failed, 0);
    FX_STOP_CHECK(&f, job, true);
}

T_CASE(moonraker_survives_5xx_and_cut_upload)
{
    survives_5xx_and_cut_upload(MOONRAKER);
}

T_CASE(prusalink_survives_5xx_and_cut_upload)
{
    survives_5xx_and_cut_upload(PRUSALINK);
}

static bool offline_or_ended(void *ud);

static void
cut_upload_then_5xx(enum kind kind, const char *burst)
{
    /* the upload is cut half-way and the three requests right after it (the
       polls asking whether it arrived) answer 503: three failed contacts, a
       short outage the job rides out (job_tries 4).  The cut upload is not a
       fourth: it was counted as one, and the printer went offline with a job
       that never reached it, left interrupted.  burst is 5xx=3@<the
       upload's request number at the simulator>.  PrusaLink only: its
       upload is streamed from the file, which curl cannot rewind, so the
       cut is one request; Moonraker's form body curl sends again at once
       on a reused connection, which moves the burst's place with curl's
       connection reuse. */
    struct fx f;
    struct sf_err err;
    const char *faults[] = { "drop-upload=1", burst, NULL };
    T_OK(fx_start(&f, kind, NULL, faults, NULL, NULL, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    const char *job = job_file("cut-then-5xx.gcode", 3000); /* over 64 KiB: cut inside the body */
    T_OK(f.d->ops->start_job(f.d, job, 0, NULL, &err), &err);
    T_TRUE(run_until(f.l, offline_or_ended, &f));
    T_TRUE(f.d->status.state != DRV_OFFLINE);
    T_TRUE(fx_wait_end(&f, 1));
    T_EQ_INT(f.rec.done, 1);
    T_EQ_INT(f.rec.failed, 0);
    FX_STOP_CHECK(&f, job, true);
}

T_CASE(prusalink_cut_upload_then_5xx_burst_is_ridden_out)
{
    cut_upload_then_5xx(PRUSALINK, "5xx=3@2");
}

static void
cut_upload_then_outage(enum kind kind, const char *burst)
{
    /* as above, but the printer answers 503 past job_tries: the driver goes
       offline before it could send the file again.  The upload was cut
       short, so the printer never had the file whole and cannot print it:
       the job failed to start (the farm's retry policy sends it again),
       not a job left on the printer for attach(), which for an idle
       PrusaLink could only say how it ended is not known.  burst is
       5xx=5@<the upload's request number>: the four polls after it, and
       for Moonraker the form body curl may send again at once on the
       reused connection (then answered 503, the polls one later) */
    struct fx f;
    struct sf_err err;
    const char *faults[] = { "drop-upload=1", burst, NULL };
    T_OK(fx_start(&f, kind, NULL, faults, NULL, NULL, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    /* 13 MB, cut at 64 KiB: the socket buffers cannot take the rest, so curl
       never reads the file to its end */
    const char *job = job_file("cut-then-outage.gcode", 300000);
    T_OK(f.d->ops->start_job(f.d, job, 0, NULL, &err), &err);
    T_TRUE(run_until(f.l, offline_or_ended, &f));
    struct waiter w = { .d = f.d, .r = &f.rec, .state = DRV_OFFLINE };
    T_TRUE(run_until(f.l, is_state, &w));
    T_EQ_INT(f.rec.failed, 1);
    T_EQ_INT(f.rec.done, 0);
    T_TRUE(strstr(f.rec.end_msg, "unreachable before the upload could be sent again (upload "
                                 "failed: ") == f.rec.end_msg);
    fx_stop(&f);
}

T_CASE(prusalink_cut_upload_then_outage_fails_the_job)
{
    cut_upload_then_outage(PRUSALINK, "5xx=5@2");
}

T_CASE(moonraker_cut_upload_then_outage_fails_the_job)
{
    /* requests 1 and 2 are /server/info and the first objects query */
    cut_upload_then_outage(MOONRAKER, "5xx=5@3");
}

T_CASE(moonraker_offline_without_job_then_back)
{
    /* a printer that answers 503 (Klippy gone) without a job is offline with the reason */
    struct fx f;
    struct sf_err err;
    const char *faults[] = { "5xx=3", NULL };
    T_OK(fx_start(&f, MOONRAKER, NULL, faults, NULL, NULL, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_OFFLINE));
    T_TRUE(strstr(f.d->status.message, "HTTP 503") != NULL);
    /* the farm's backoff would open() again: the printer is back */
    for (int i = 0; i < 4 && f.d->status.state != DRV_IDLE; i++) {
        T_OK(f.d->ops->open(f.d, &err), &err);
        struct waiter w = { .d = f.d, .r = &f.rec, .state = DRV_IDLE };
        int64_t end = wall_ms() + 5000;
        while (!is_state(&w) && f.d->status.state != DRV_OFFLINE && wall_ms() < end)
            loop_run_once(f.l, 50);
        if (f.d->status.state == DRV_CONNECTING)
            T_TRUE(fx_wait_state(&f, DRV_IDLE));
    }
    T_EQ_INT(f.d->status.state, DRV_IDLE);
    fx_stop(&f);
}

T_CASE(prusalink_busy_is_409_with_the_reason)
{
    struct fx f;
    struct sf_err err;
    const char *faults[] = { "busy=1", NULL };
    T_OK(fx_start(&f, PRUSALINK, "k", faults, "k", NULL, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    const char *job = job_file("busy.gcode", 100);
    T_OK(f.d->ops->start_job(f.d, job, 0, NULL, &err), &err);
    T_TRUE(fx_wait_end(&f, 1));
    T_EQ_INT(f.rec.failed, 1);
    T_TRUE(strstr(f.rec.end_msg, "409") && strstr(f.rec.end_msg, "Printer is busy"));
    /* the next one goes through */
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    T_OK(f.d->ops->start_job(f.d, job, 0, NULL, &err), &err);
    T_TRUE(fx_wait_end(&f, 2));
    T_EQ_INT(f.rec.done, 1);
    fx_stop(&f);
}

T_CASE(prusalink_printer_error)
{
    struct fx f;
    struct sf_err err;
    const char *faults[] = { "error=60", NULL };
    T_OK(fx_start(&f, PRUSALINK, NULL, faults, NULL, NULL, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    T_OK(f.d->ops->start_job(f.d, job_file("err.gcode", 2000), 0, NULL, &err), &err);
    T_TRUE(fx_wait_end(&f, 1));
    T_EQ_INT(f.rec.failed, 1);
    T_EQ_INT(f.d->status.state, DRV_ERROR);
    T_TRUE(strstr(f.rec.end_msg, "Thermal runaway") != NULL);
    fx_stop(&f);
}

T_CASE(moonraker_print_error_fails_the_job_only)
{
    struct fx f;
    struct sf_err err;
    const char *faults[] = { "error=60", NULL };
    T_OK(fx_start(&f, MOONRAKER, NULL, faults, NULL, NULL, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    T_OK(f.d->ops->start_job(f.d, job_file("merr.gcode", 2000), 0, NULL, &err), &err);
    T_TRUE(fx_wait_end(&f, 1));
    T_EQ_INT(f.rec.failed, 1);
    T_TRUE(strstr(f.rec.end_msg, "Move out of range") != NULL);
    T_EQ_INT(f.d->status.state, DRV_IDLE); /* Klipper is ready: the next job may come */
    fx_stop(&f);
}

static bool
heating(void *ud)
{
    struct fx *f = ud;
    return f->d->status.nozzle_target_c == 200;
}

T_CASE(moonraker_manual_command)
{
    struct fx f;
    struct sf_err err;
    T_OK(fx_start(&f, MOONRAKER, NULL, NULL, NULL, NULL, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    T_OK(f.d->ops->command(f.d, "G28", &err), &err);
    T_OK(f.d->ops->command(f.d, "M104 S200", &err), &err);
    /* the machine took them when a poll reports the new target */
    T_TRUE(run_until(f.l, heating, &f));
    fx_stop(&f);
    char **got;
    int n = commands(f.log, &got, &err);
    T_OK(n, &err);
    int seen = 0;
    for (int i = 0; i < n; i++)
        seen += strcmp(got[i], "G28") == 0 || strcmp(got[i], "M104 S200") == 0;
    free_commands(got, n);
    T_EQ_INT(seen, 2);
}

T_CASE(prusalink_digest_auth)
{
    struct fx f;
    struct sf_err err;
    /* current firmware: user "maker" and the password shown on the printer */
    T_OK(fx_start(&f, PRUSALINK, "s3cret", NULL, NULL, "maker", "s3cret", &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    const char *job = job_file("digest.gcode", 2500); /* streamed past one buffer */
    T_OK(f.d->ops->start_job(f.d, job, 0, NULL, &err), &err);
    T_TRUE(fx_wait_end(&f, 1));
    T_EQ_INT(f.rec.done, 1);
    FX_STOP_CHECK(&f, job, true);
    /* a wrong password is an authentication error, not "offline" for no reason */
    T_OK(fx_start(&f, PRUSALINK, "s3cret", NULL, NULL, "maker", "guess", &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_OFFLINE));
    T_TRUE(strstr(f.d->status.message, "authentication failed") != NULL);
    fx_stop(&f);
}

/* The status requests the PrusaLink simulator of f has answered (sim_netbase.h: the
   simulator embeds its base first, so its pointer is the base's). */
static uint64_t
pl_served(const struct fx *f)
{
    return sim_http_served(((const struct sim_netbase *)(const void *)f->pl)->http);
}

static bool
pl_polled_6_more(void *ud)
{
    struct fx *f = ud;
    return pl_served(f) >= polls_mark + 6;
}

/*
 * PrusaLink is polled at the rate its state sets: every poll_idle_ms while
 * idle, every poll_ms while printing.  Counted at the simulator.  Idle, a
 * window of three idle periods holds at most four polls (a loaded machine
 * only makes fewer); at the old fixed rate (poll_ms whatever the state)
 * it held forty-five.  Printing, six polls come well within four idle
 * periods (a rate that stayed slow needs five).
 */
T_CASE(prusalink_polls_at_its_states_rate)
{
    enum { FAST = 200, SLOW = 3000 };
    struct fx f;
    struct sf_err err;
    fx_poll_ms = FAST;
    fx_poll_idle_ms = SLOW;
    int rc = fx_start(&f, PRUSALINK, "k3y", NULL, "k3y", NULL, NULL, &err);
    fx_poll_ms = fx_poll_idle_ms = 0;
    T_OK(rc, &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    uint64_t q0 = pl_served(&f);
    for (int64_t end = wall_ms() + 3 * SLOW; wall_ms() < end;)
        loop_run_once(f.l, 50);
    uint64_t idle = pl_served(&f) - q0;
    T_TRUE(idle <= 4);
    /* a print of 20 dwells of 3000 s, 30 s at the simulator's speed 2000 */
    char job[512];
    snprintf(job, sizeof(job), "%s/dwell.gcode", t_tmpdir());
    FILE *jf = fopen(job, "w");
    T_TRUE(jf != NULL);
    fprintf(jf, "G90\nM83\n");
    for (int i = 0; i < 20; i++)
        fprintf(jf, "G4 S3000\n");
    fclose(jf);
    T_OK(f.d->ops->start_job(f.d, job, 0, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_PRINTING));
    polls_mark = pl_served(&f);
    int64_t t0 = wall_ms();
    T_TRUE(run_until(f.l, pl_polled_6_more, &f));
    T_TRUE(wall_ms() - t0 < 4 * SLOW);
    T_TRUE(f.d->status.state == DRV_PRINTING);
    T_OK(f.d->ops->cancel(f.d, &err), &err);
    T_TRUE(fx_wait_end(&f, 1));
    T_EQ_INT(f.rec.cancelled, 1);
    fx_stop(&f);
}

static bool
left_connecting(void *ud)
{
    struct fx *f = ud;
    return f->d->status.state != DRV_CONNECTING && f->d->status.state != DRV_OFFLINE;
}

/* A second driver (a restarted daemon) on f's printer. */
static struct drv *
second_driver(struct fx *f, struct rec *r, struct sf_err *err)
{
    struct drv_config dc = { .name = "again",
                             .kind = f->kind == MOONRAKER ? "moonraker" : "prusalink",
                             .url = f->url };
    struct drv *d = drv_new(f->l, &dc, on_event, r, err);
    if (d && d->ops->open(d, err)) {
        drv_free(d);
        d = NULL;
    }
    return d;
}

/* attach, asked again while the driver answers "not yet" (Moonraker looks its history up) */
static int
attach_wait(struct fx *f, const char *path, struct sf_err *err)
{
    int rc = f->d->ops->attach(f->d, path, NULL, err);
    for (int i = 0; rc == SF_EAGAIN && i < 2000; i++) {
        loop_run_once(f->l, 25);
        rc = f->d->ops->attach(f->d, path, NULL, err);
    }
    return rc;
}

static void
reattach(enum kind kind)
{
    struct fx f;
    struct sf_err err;
    T_OK(fx_start(&f, kind, NULL, NULL, NULL, NULL, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    char job[512];
    snprintf(job, sizeof(job), "%s", job_file("long.gcode", 3000));
    T_OK(f.d->ops->start_job(f.d, job, 0, NULL, &err), &err);
    T_TRUE(fx_wait_progress(&f));
    /* the daemon dies: its driver goes without a word to the printer */
    drv_free(f.d);
    struct rec r2;
    memset(&r2, 0, sizeof(r2));
    f.d = second_driver(&f, &r2, &err);
    T_TRUE(f.d != NULL);
    T_TRUE(run_until(f.l, left_connecting, &f));
    T_EQ_INT(f.d->status.state, DRV_PRINTING); /* a job it did not send, so far */
    T_TRUE(f.d->ops->attach != NULL);
    /* another file is not taken for it */
    T_ERR(attach_wait(&f, job_file("other.gcode", 10), &err), SF_ENOTFOUND, &err, "long.gcode");
    T_OK(f.d->ops->attach(f.d, job, NULL, &err), &err);
    struct waiter w = { .d = f.d, .r = &r2, .ends = 1 };
    T_TRUE(run_until(f.l, job_ended, &w));
    T_EQ_INT(r2.done, 1);
    T_EQ_INT(f.d->status.lines_acked, f.d->status.lines_total);
    FX_STOP_CHECK(&f, job, true);
}

T_CASE(moonraker_reattach_after_restart)
{
    reattach(MOONRAKER);
}

T_CASE(prusalink_reattach_after_restart)
{
    reattach(PRUSALINK);
}

static void
reattach_gone(enum kind kind)
{
    /* a printer that knows nothing of the job: SF_ENOTFOUND, the farm marks it interrupted */
    struct fx f;
    struct sf_err err;
    T_OK(fx_start(&f, kind, NULL, NULL, NULL, NULL, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    T_ERR(attach_wait(&f, job_file("never.gcode", 10), &err), SF_ENOTFOUND, &err, "no job");
    fx_stop(&f);
}

T_CASE(moonraker_reattach_unknown_job)
{
    reattach_gone(MOONRAKER);
}

T_CASE(prusalink_reattach_unknown_job)
{
    reattach_gone(PRUSALINK);
}

static bool
offline_or_ended(void *ud)
{
    struct fx *f = ud;
    return f->d->status.state == DRV_OFFLINE || f->rec.done + f->rec.failed > 0;
}

static void
outage_then_attach(enum kind kind)
{
    /* a long outage mid-job: the driver rides out three failed polls, then
       goes offline and lets go of the job (the farm marks it interrupted);
       once the printer answers, attach takes it back and it ends done */
    struct fx f;
    struct sf_err err;
    const char *faults[] = { "5xx=8@5", NULL };
    T_OK(fx_start(&f, kind, NULL, faults, NULL, NULL, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    char job[512];
    snprintf(job, sizeof(job), "%s", job_file("outage.gcode", 6000));
    T_OK(f.d->ops->start_job(f.d, job, 0, NULL, &err), &err);
    T_TRUE(run_until(f.l, offline_or_ended, &f));
    T_EQ_INT(f.d->status.state, DRV_OFFLINE);
    T_EQ_INT(f.rec.done + f.rec.failed + f.rec.cancelled, 0); /* not ended: interrupted */
    T_TRUE(strstr(f.d->status.message, "503") != NULL);
    /* the farm's backoff re-opens it until it answers */
    for (int i = 0; i < 20 && !left_connecting(&f); i++) {
        T_OK(f.d->ops->open(f.d, &err), &err);
        int64_t end = wall_ms() + 3000;
        while (f.d->status.state == DRV_CONNECTING && wall_ms() < end)
            loop_run_once(f.l, 50);
    }
    T_TRUE(left_connecting(&f));
    T_OK(f.d->ops->attach(f.d, job, NULL, &err), &err);
    T_TRUE(fx_wait_end(&f, 1));
    T_EQ_INT(f.rec.done, 1);
    FX_STOP_CHECK(&f, job, true);
}

T_CASE(moonraker_outage_then_attach)
{
    outage_then_attach(MOONRAKER);
}

T_CASE(prusalink_outage_then_attach)
{
    outage_then_attach(PRUSALINK);
}

static bool
sim_job_over(void *ud)
{
    struct fx *f = ud;
    struct sim_np_status st;
    if (f->mr)
        sim_moonraker_status(f->mr, &st);
    else
        sim_prusalink_status(f->pl, &st);
    return st.state == SIM_NP_COMPLETE;
}

static void
ends_while_unreachable(enum kind kind)
{
    /* the printer answers 503 from line 100 of the job until after it has
       finished it (outage=100): the driver lets go of the job, which the
       farm marks interrupted; once the printer answers, attach learns from
       the printer that the print completed, and the job ends done */
    struct fx f;
    struct sf_err err;
    const char *faults[] = { "outage=100", NULL };
    T_OK(fx_start(&f, kind, NULL, faults, NULL, NULL, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    char job[512];
    snprintf(job, sizeof(job), "%s", job_file("ends-unseen.gcode", 3000));
    T_OK(f.d->ops->start_job(f.d, job, 0, NULL, &err), &err);
    T_TRUE(run_until(f.l, offline_or_ended, &f));
    T_EQ_INT(f.d->status.state, DRV_OFFLINE);
    T_EQ_INT(f.rec.done + f.rec.failed + f.rec.cancelled, 0); /* not ended: interrupted */
    T_TRUE(run_until(f.l, sim_job_over, &f));
    for (int i = 0; i < 20 && !left_connecting(&f); i++) {
        T_OK(f.d->ops->open(f.d, &err), &err);
        int64_t end = wall_ms() + 3000;
        while (f.d->status.state == DRV_CONNECTING && wall_ms() < end)
            loop_run_once(f.l, 50);
    }
    T_TRUE(left_connecting(&f));
    T_OK(f.d->ops->attach(f.d, job, NULL, &err), &err);
    T_TRUE(fx_wait_end(&f, 1));
    T_EQ_INT(f.rec.done, 1);
    T_EQ_INT(f.d->status.lines_acked, f.d->status.lines_total);
    fx_stop(&f);
    char why[300] = "";
    if (log_matches(f.log, job, true, why, sizeof(why)) < 0)
        t_fail(__FILE__, __LINE__, "%s", why);
}

T_CASE(moonraker_print_ends_while_unreachable)
{
    ends_while_unreachable(MOONRAKER);
}

T_CASE(prusalink_print_ends_while_unreachable)
{
    ends_while_unreachable(PRUSALINK);
}

T_CASE(prusalink_print_ends_unseen_then_dismissed_is_not_known)
{
    /* as above, but the finished screen is dismissed at once (dismiss=1):
       the printer is idle with no job and PrusaLink v1 keeps no record of
       it, so attach cannot know how the print ended and says so (the farm
       leaves the job interrupted for an operator) */
    struct fx f;
    struct sf_err err;
    const char *faults[] = { "outage=100", "dismiss=1", NULL };
    T_OK(fx_start(&f, PRUSALINK, NULL, faults, NULL, NULL, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    char job[512];
    snprintf(job, sizeof(job), "%s", job_file("ends-dismissed.gcode", 3000));
    T_OK(f.d->ops->start_job(f.d, job, 0, NULL, &err), &err);
    T_TRUE(run_until(f.l, offline_or_ended, &f));
    T_EQ_INT(f.d->status.state, DRV_OFFLINE);
    T_TRUE(run_until(f.l, sim_job_over, &f));
    for (int i = 0; i < 20 && !left_connecting(&f); i++) {
        T_OK(f.d->ops->open(f.d, &err), &err);
        int64_t end = wall_ms() + 3000;
        while (f.d->status.state == DRV_CONNECTING && wall_ms() < end)
            loop_run_once(f.l, 50);
    }
    T_TRUE(left_connecting(&f));
    T_ERR(f.d->ops->attach(f.d, job, NULL, &err), SF_ENOTFOUND, &err, "is not known");
    T_EQ_INT(f.rec.done + f.rec.failed + f.rec.cancelled, 0);
    fx_stop(&f);
}

T_CASE(prusalink_job_query_lost_is_asked_again)
{
    /* requests: 1 status, 2 the upload, 3 status (a job now), 4 GET
       /api/v1/job, which answers 503 (5xx=1@3): the driver rides it out
       and must ask about the job again, or it never learns that the job
       the printer runs is ours (it once failed it: "the printer runs '?',
       not this job") */
    struct fx f;
    struct sf_err err;
    const char *faults[] = { "5xx=1@3", NULL };
    T_OK(fx_start(&f, PRUSALINK, NULL, faults, NULL, NULL, NULL, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    const char *job = job_file("job-query.gcode", 300);
    T_OK(f.d->ops->start_job(f.d, job, 0, NULL, &err), &err);
    T_TRUE(fx_wait_end(&f, 1));
    T_EQ_INT(f.rec.done, 1);
    T_EQ_INT(f.rec.failed, 0);
    fx_stop(&f);
}

/* ---- OctoPrint's push socket: the simulator in a child, a relay on the loop ---- */

/*
 * The OctoPrint simulator has no in-process face: it runs in a child
 * (sim_octoprint_main, as `slimfarm-sim octoprint`), and the driver
 * reaches it through a relay on the test's loop, which counts the status
 * polls (GET /api/job request lines) and can cut the push sockets alone.
 */
#define RELAY_MAX 64

struct relay {
    struct loop *l;
    int lfd, port, to_port;
    int a[RELAY_MAX], b[RELAY_MAX]; /* client side, simulator side; -1 free */
    bool ws[RELAY_MAX];             /* the pair carries a push socket */
    uint64_t job_polls;             /* GET /api/job requests relayed */
};

static void
relay_cut(struct relay *r, int i)
{
    loop_del_fd(r->l, r->a[i]);
    loop_del_fd(r->l, r->b[i]);
    close(r->a[i]);
    close(r->b[i]);
    r->a[i] = r->b[i] = -1;
}

static bool
write_all(int fd, const char *p, size_t n)
{
    while (n) {
        ssize_t k = write(fd, p, n);
        if (k <= 0)
            return false;
        p += k;
        n -= (size_t)k;
    }
    return true;
}

static void
relay_io(struct loop *l, int fd, unsigned ev, void *ud)
{
    (void)l, (void)ev;
    struct relay *r = ud;
    int i = 0;
    while (i < RELAY_MAX && r->a[i] != fd && r->b[i] != fd)
        i++;
    if (i == RELAY_MAX)
        return;
    char buf[65536];
    ssize_t k = read(fd, buf, sizeof(buf) - 1);
    bool up = fd == r->a[i];
    if (k <= 0 || !write_all(up ? r->b[i] : r->a[i], buf, (size_t)k)) {
        relay_cut(r, i);
        return;
    }
    buf[k] = 0;
    if (up && strncmp(buf, "GET /sockjs/", 12) == 0)
        r->ws[i] = true;
    for (char *s = buf; up && (s = strstr(s, "GET /api/job ")); s++)
        r->job_polls++;
}

static void
relay_accept(struct loop *l, int fd, unsigned ev, void *ud)
{
    (void)ev;
    struct relay *r = ud;
    int c = accept(fd, NULL, NULL);
    if (c < 0)
        return;
    int i = 0;
    while (i < RELAY_MAX && r->a[i] >= 0)
        i++;
    int s = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in sa = { .sin_family = AF_INET, .sin_port = htons((uint16_t)r->to_port) };
    sa.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (i == RELAY_MAX || s < 0 || connect(s, (struct sockaddr *)&sa, sizeof(sa)) < 0) {
        close(c);
        if (s >= 0)
            close(s);
        return;
    }
    r->a[i] = c;
    r->b[i] = s;
    r->ws[i] = false;
    loop_add_fd(l, c, LOOP_READ, relay_io, r, NULL);
    loop_add_fd(l, s, LOOP_READ, relay_io, r, NULL);
}

static int
relay_start(struct relay *r, struct loop *l, int to_port)
{
    memset(r, 0, sizeof(*r));
    r->l = l;
    r->to_port = to_port;
    for (int i = 0; i < RELAY_MAX; i++)
        r->a[i] = r->b[i] = -1;
    r->lfd = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in sa = { .sin_family = AF_INET };
    sa.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    socklen_t n = sizeof(sa);
    if (r->lfd < 0 || bind(r->lfd, (struct sockaddr *)&sa, sizeof(sa)) || listen(r->lfd, 16) ||
        getsockname(r->lfd, (struct sockaddr *)&sa, &n))
        return -1;
    r->port = ntohs(sa.sin_port);
    return loop_add_fd(l, r->lfd, LOOP_READ, relay_accept, r, NULL);
}

static void
relay_stop(struct relay *r)
{
    for (int i = 0; i < RELAY_MAX; i++)
        if (r->a[i] >= 0)
            relay_cut(r, i);
    loop_del_fd(r->l, r->lfd);
    close(r->lfd);
}

/* Cut every push socket (the HTTP connections stay); how many. */
static int
relay_cut_sockets(struct relay *r)
{
    int k = 0;
    for (int i = 0; i < RELAY_MAX; i++)
        if (r->a[i] >= 0 && r->ws[i]) {
            relay_cut(r, i);
            k++;
        }
    return k;
}

static bool
relay_has_socket(void *ud)
{
    struct relay *r = ud;
    for (int i = 0; i < RELAY_MAX; i++)
        if (r->a[i] >= 0 && r->ws[i])
            return true;
    return false;
}

/* The simulator in a child: its pid, and its port read from the address line it prints. */
static pid_t
octo_sim_spawn(const char *key, const char *speed, const char *log_path, int *port)
{
    int fds[2];
    if (pipe(fds))
        return -1;
    pid_t pid = fork();
    if (pid == 0) {
        dup2(fds[1], 1);
        close(fds[0]);
        char *argv[] = { "slimfarm-sim", "octoprint",      "--port",  "0",
                         "--api-key",    (char *)key,      "--speed", (char *)speed,
                         "--log",        (char *)log_path, NULL };
        _exit(sim_octoprint_main(10, argv));
    }
    close(fds[1]);
    char line[128] = "";
    FILE *f = fdopen(fds[0], "r");
    if (!f || !fgets(line, sizeof(line), f) || sscanf(line, "http://127.0.0.1:%d", port) != 1)
        *port = 0;
    if (f)
        fclose(f);
    return pid;
}

static uint64_t
relay_polls(void *ud)
{
    return ((struct relay *)ud)->job_polls;
}

static void
relay_cut_all(void *ud)
{
    T_TRUE(relay_cut_sockets(ud) > 0);
}

/*
 * OctoPrint's push socket: after the passive login the driver opens
 * /sockjs/websocket and its `current` messages replace the polls
 * (push_print, the polls counted as GET /api/job); every line runs once.
 */
T_CASE(octoprint_push_socket_replaces_polls)
{
    struct fx f;
    struct sf_err err;
    memset(&f, 0, sizeof(f));
    snprintf(f.log, sizeof(f.log), "%s/exec-octo.log", t_tmpdir());
    f.l = loop_new(&err);
    T_TRUE(f.l != NULL);
    int sim_port = 0;
    pid_t pid = octo_sim_spawn("k3y", "60", f.log, &sim_port);
    T_TRUE(pid > 0 && sim_port > 0);
    struct relay r;
    T_TRUE(relay_start(&r, f.l, sim_port) == 0);
    snprintf(f.url, sizeof(f.url), "http://127.0.0.1:%d/", r.port);
    struct drv_config dc = { .name = "octo", .kind = "octoprint", .url = f.url, .api_key = "k3y" };
    f.d = drv_new(f.l, &dc, on_event, &f.rec, &err);
    T_TRUE(f.d != NULL);
    T_OK(f.d->ops->open(f.d, &err), &err);
    T_TRUE(fx_wait_state(&f, DRV_IDLE));
    const char *job = job_file("octo-push.gcode", 4000);
    struct push_probe p = { &r, relay_polls, relay_cut_all, relay_has_socket };
    push_print(&f, job, &p);
    drv_free(f.d);
    f.d = NULL;
    relay_stop(&r);
    kill(pid, SIGTERM);
    waitpid(pid, NULL, 0);
    loop_free(f.l);
    char why[300] = "";
    if (log_matches(f.log, job, true, why, sizeof(why)) < 0)
        t_fail(__FILE__, __LINE__, "%s", why);
}
