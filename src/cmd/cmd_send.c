/*
 * cmd_send.c - `slimfarm send FILE.gcode --port SPEC [--baud N]`: stream one
 * G-code file to a Marlin printer with a live progress line.
 *
 * Why: the quickest way to print without the daemon, and the CLI face of
 * the Marlin driver for tests and benchmarks.  Design: one loop, one
 * driver; the progress line (lines, %, temperatures, ETA) is redrawn on
 * progress events when stderr is a terminal, else printed every 10%.  On
 * exit it prints one summary line on stdout (lines, seconds, lines/s,
 * bytes/s) that the benchmarks read.  Ctrl-C cancels the job cleanly.
 *
 * Thread: main thread.
 */
#include <errno.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "../../drivers/drv.h"
#include "../../drivers/marlin/drv_marlin.h"
#include "../base/log.h"
#include "../base/loop.h"
#include "cmd.h"

struct send_ctx {
    struct loop *loop;
    struct drv *drv;
    const char *file;
    bool started;
    int result;      /* -1 running, 0 done, 1 failed/cancelled */
    int last_decile; /* non-tty progress */
    int64_t t0_ms;   /* job start */
    bool interrupted;
};

static void
draw(struct send_ctx *c, bool final)
{
    const struct drv_status *st = &c->drv->status;
    double secs = (double)(loop_now_ms(c->loop) - c->t0_ms) / 1000.0;
    double eta = st->progress > 0.001 ? secs / st->progress - secs : 0;
    if (isatty(STDERR_FILENO)) {
        fprintf(stderr, "\r%llu/%llu lines %5.1f%%  T:%.1f/%.0f B:%.1f/%.0f  ETA %02d:%02d%s",
                (unsigned long long)st->lines_acked, (unsigned long long)st->lines_total,
                st->progress * 100, st->nozzle_c, st->nozzle_target_c, st->bed_c, st->bed_target_c,
                (int)eta / 60, (int)eta % 60, final ? "\n" : "  ");
        return;
    }
    int decile = (int)(st->progress * 10);
    if (decile > c->last_decile || final) {
        c->last_decile = decile;
        fprintf(stderr, "%llu/%llu lines %.0f%% T:%.1f B:%.1f\n",
                (unsigned long long)st->lines_acked, (unsigned long long)st->lines_total,
                st->progress * 100, st->nozzle_c, st->bed_c);
    }
}

static void
on_event(struct drv *d, enum drv_event ev, void *ud)
{
    struct send_ctx *c = ud;
    struct sf_err err;
    switch (ev) {
    case DRV_EV_STATE:
        if (d->status.state == DRV_IDLE && !c->started) {
            c->started = true;
            c->t0_ms = loop_now_ms(c->loop);
            if (d->ops->start_job(d, c->file, 0, NULL, &err) < 0) {
                fprintf(stderr, "slimfarm send: %s\n", err.msg);
                c->result = 1;
                loop_stop(c->loop);
            }
        } else if (d->status.state == DRV_OFFLINE && c->result < 0) {
            fprintf(stderr, "slimfarm send: %s\n", d->status.message);
            c->result = 1;
            loop_stop(c->loop);
        }
        break;
    case DRV_EV_PROGRESS:
    case DRV_EV_TEMPS:
        if (c->started)
            draw(c, false);
        break;
    case DRV_EV_JOB_DONE:
        draw(c, true);
        c->result = 0;
        loop_stop(c->loop);
        break;
    case DRV_EV_JOB_FAILED:
    case DRV_EV_JOB_CANCELLED:
        draw(c, true);
        fprintf(stderr, "slimfarm send: %s\n", d->status.message);
        c->result = 1;
        loop_stop(c->loop);
        break;
    }
}

static void
on_sigint(struct loop *l, int signo, void *ud)
{
    (void)signo;
    struct send_ctx *c = ud;
    if (c->interrupted || !c->drv->ops->cancel || c->drv->ops->cancel(c->drv, NULL) < 0) {
        c->result = 1;
        loop_stop(l);
    }
    c->interrupted = true;
}

static const char usage_line[] = "send FILE.gcode --port DEVICE|pty:PATH|tcp://host:port "
                                 "[--baud N] [--window N] [--timeout-ms N]";

static int
run_send(int argc, char **argv)
{
    const char *file = NULL, *port = NULL;
    long baud = 115200, timeout_ms = 0, window = 0;
    for (int i = 1; i < argc; i++) {
        const char *o = argv[i];
        if (strcmp(o, "--port") == 0 || strcmp(o, "--baud") == 0 ||
            strcmp(o, "--timeout-ms") == 0 || strcmp(o, "--window") == 0) {
            if (i + 1 >= argc) {
                fprintf(stderr, "slimfarm send: %s needs a value\n", o);
                return 2;
            }
            const char *v = argv[++i];
            if (strcmp(o, "--port") == 0) {
                port = v;
                continue;
            }
            char *end;
            errno = 0;
            long n = strtol(v, &end, 10);
            long lo = strcmp(o, "--baud") == 0 ? 300 : 0;
            long hi = strcmp(o, "--baud") == 0 ? 4000000 : strcmp(o, "--window") == 0 ? 32 : 600000;
            if (errno || end == v || *end || n < lo || n > hi) {
                fprintf(stderr, "slimfarm send: %s expects a whole number from %ld to %ld\n", o, lo,
                        hi);
                return 2;
            }
            if (strcmp(o, "--baud") == 0)
                baud = n;
            else if (strcmp(o, "--window") == 0)
                window = n;
            else
                timeout_ms = n;
        } else if (o[0] == '-' && o[1]) {
            fprintf(stderr, "slimfarm send: unknown option '%s'\n", o);
            return 2;
        } else if (!file) {
            file = o;
        } else {
            fprintf(stderr, "slimfarm send: more than one file given\n");
            return 2;
        }
    }
    if (!file || !port) {
        fprintf(stderr, "usage: slimfarm %s\n", usage_line);
        return 2;
    }
    struct sf_err err;
    struct send_ctx c = { .file = file, .result = -1, .last_decile = -1 };
    c.loop = loop_new(&err);
    if (!c.loop) {
        fprintf(stderr, "slimfarm send: %s\n", err.msg);
        return 1;
    }
    struct drv_config dc = { .name = "send",
                             .kind = "marlin",
                             .port = port,
                             .baud = (int)baud,
                             .timeout_ms = (int)timeout_ms,
                             .buffer_lines = (int)window };
    /* Marlin only: the driver itself, not the registry, which links every driver. */
    c.drv = drv_marlin_new(c.loop, &dc, on_event, &c, &err);
    if (!c.drv || loop_add_signal(c.loop, SIGINT, on_sigint, &c, &err) < 0 ||
        c.drv->ops->open(c.drv, &err) < 0) {
        fprintf(stderr, "slimfarm send: %s\n", err.msg);
        drv_free(c.drv);
        loop_free(c.loop);
        return 1;
    }
    loop_run(c.loop);
    double secs = (double)(loop_now_ms(c.loop) - c.t0_ms) / 1000.0;
    struct drv_marlin_stats ds;
    if (c.started && drv_marlin_stats(c.drv, &ds))
        printf("sent: lines=%llu acked=%llu seconds=%.3f lines_per_s=%.1f bytes=%llu "
               "bytes_per_s=%.0f rewinds=%llu probes=%llu window=%d\n",
               (unsigned long long)c.drv->status.lines_total,
               (unsigned long long)c.drv->status.lines_acked, secs,
               secs > 0 ? (double)c.drv->status.lines_acked / secs : 0,
               (unsigned long long)ds.bytes_sent, secs > 0 ? (double)ds.bytes_sent / secs : 0,
               (unsigned long long)ds.rewinds, (unsigned long long)ds.probes, ds.window);
    int rc = c.result == 0 ? 0 : 1;
    drv_free(c.drv);
    loop_free(c.loop);
    return rc;
}

CMD_REGISTER(send, "send", usage_line, "stream one G-code file to a Marlin printer", run_send)
