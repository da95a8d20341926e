/*
 * bench_jobstart.c FILE.gcode - how long start_job holds the loop thread.
 *
 * A simulated Marlin on a pty and the real driver on one loop; the job is
 * started (then cancelled) four ways, each timed around the start_job call
 * alone, which runs on the loop thread and so stalls every other printer's
 * stream for as long as it takes:
 *   start, no scan       the driver reads and checks the whole file (the
 *                        path every start took before the farm scanned
 *                        jobs when preparing them);
 *   start, with scan     the farm's path: the scan was made off the loop;
 *   resume at 2/3, ...   the same for a resume (with a scan the driver
 *                        reads only up to the line; with the line's resume
 *                        point, drv_job_scan_to, nothing).
 * drv_job_scan itself is timed too: what the prepare worker now spends.
 * With DATA_DIR, putting the job into a store there is timed both ways:
 * streamed through a store writer (the loop's work before the prepare
 * worker adopted the file) and adopted on the worker then recorded on the
 * loop.
 * Wall times on a shared machine: give the load average next to them.
 */
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include <unistd.h>

#include "../../drivers/drv.h"
#include "../../sim/marlin/sim_marlin.h"
#include "../../src/base/log.h"
#include "../../src/farm/store.h"

static double
now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

static bool
wait_idle(struct loop *l, struct drv *d, int max_ms)
{
    double until = now_ms() + max_ms;
    while (d->status.state != DRV_IDLE && now_ms() < until)
        loop_run_once(l, 10);
    return d->status.state == DRV_IDLE;
}

/* Time one start_job, then cancel the job and wait for the printer. */
static int
timed_start(struct loop *l, struct drv *d, const char *label, const char *path, uint64_t first,
            const struct drv_job_scan *scan)
{
    struct sf_err err;
    double t0 = now_ms();
    int rc = d->ops->start_job(d, path, first, scan, &err);
    double t1 = now_ms();
    if (rc) {
        fprintf(stderr, "bench_jobstart: %s: %s\n", label, err.msg);
        return rc;
    }
    printf("  %-28s %9.1f ms on the loop thread (lines_total %llu)\n", label, t1 - t0,
           (unsigned long long)d->status.lines_total);
    d->ops->cancel(d, NULL);
    if (!wait_idle(l, d, 20000)) {
        fprintf(stderr, "bench_jobstart: %s: printer not idle after cancel\n", label);
        return SF_ETIMEDOUT;
    }
    return SF_OK;
}

/* Put path into a store in dir both ways and time each half. */
static int
time_store(const char *path, const char *dir)
{
    struct sf_err err;
    struct store *s = store_open(dir, NULL, &err);
    if (!s) {
        fprintf(stderr, "bench_jobstart: %s\n", err.msg);
        return 1;
    }
    char sha[STORE_SHA_HEX], made[1024];
    int64_t size = 0;
    double t0 = now_ms();
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    struct store_file *w = fd >= 0 ? store_file_begin(s, &err) : NULL;
    int rc = w ? SF_OK : SF_EIO;
    static char buf[1 << 16];
    ssize_t n;
    while (rc == SF_OK && (n = read(fd, buf, sizeof(buf))) > 0)
        rc = store_file_write(w, buf, (size_t)n, &err);
    rc = rc ? rc : store_file_commit(w, sha, &err);
    if (fd >= 0)
        close(fd);
    double t1 = now_ms();
    /* the job file as the prepare worker leaves it: a name beside the store's files */
    snprintf(made, sizeof(made), "%s/files/job-1.gcode", dir);
    if (rc == SF_OK && link(path, made) != 0)
        rc = sf_err_sys(&err, "link '%s'", made);
    double t2 = now_ms();
    rc = rc ? rc : store_file_adopt(s, made, sha, &size, &err);
    double t3 = now_ms();
    rc = rc ? rc : store_file_record(s, sha, size, &err);
    double t4 = now_ms();
    store_close(s);
    if (rc) {
        fprintf(stderr, "bench_jobstart: store: %s\n", err.msg);
        return 1;
    }
    printf("  %-28s %9.1f ms on the loop thread (before)\n", "store: stream a copy", t1 - t0);
    printf("  %-28s %9.1f ms on a prepare worker\n", "store: adopt", t3 - t2);
    printf("  %-28s %9.1f ms on the loop thread\n", "store: record", t4 - t3);
    return 0;
}

int
main(int argc, char **argv)
{
    if (argc != 2 && argc != 3) {
        fprintf(stderr, "usage: bench_jobstart FILE.gcode [DATA_DIR]\n");
        return 2;
    }
    if (argc == 3 && time_store(argv[1], argv[2]))
        return 1;
    const char *path = argv[1];
    log_set_level(LOG_ERROR);
    struct sf_err err;
    struct drv_job_scan scan;
    double t0 = now_ms();
    if (drv_job_scan(path, &scan, &err)) {
        fprintf(stderr, "bench_jobstart: %s\n", err.msg);
        return 1;
    }
    printf("  %-28s %9.1f ms on a prepare worker (%llu command lines)\n", "drv_job_scan",
           now_ms() - t0, (unsigned long long)scan.lines_total);
    struct loop *l = loop_new(&err);
    struct sim_marlin_config sc;
    sim_marlin_config_init(&sc);
    sc.advanced_ok = true;
    sc.baud = 1000000;
    sc.speed = 1000;
    struct sim_marlin *sim = l ? sim_marlin_new(l, &sc, &err) : NULL;
    struct drv_config dc = { .name = "bench", .kind = "marlin", .baud = 115200 };
    dc.port = sim ? sim_marlin_path(sim) : NULL;
    struct drv *d = sim ? drv_new(l, &dc, NULL, NULL, &err) : NULL;
    if (!d || d->ops->open(d, &err) || !wait_idle(l, d, 5000)) {
        fprintf(stderr, "bench_jobstart: no printer: %s\n", d ? d->status.message : err.msg);
        return 1;
    }
    uint64_t resume = scan.lines_total * 2 / 3;
    int rc = timed_start(l, d, "start, no scan", path, 0, NULL) ||
             timed_start(l, d, "start, with scan", path, 0, &scan) ||
             timed_start(l, d, "resume at 2/3, no scan", path, resume, NULL) ||
             timed_start(l, d, "resume at 2/3, with scan", path, resume, &scan);
    /* what the farm does now: the resume point read on its io thread */
    t0 = now_ms();
    if (rc == SF_OK && (rc = drv_job_scan_to(path, resume, &scan, &err)))
        fprintf(stderr, "bench_jobstart: %s\n", err.msg);
    if (rc == SF_OK) {
        printf("  %-28s %9.1f ms on the farm's io thread\n", "drv_job_scan_to 2/3", now_ms() - t0);
        rc = timed_start(l, d, "resume at 2/3, resume point", path, resume, &scan);
    }
    drv_free(d);
    sim_marlin_free(sim);
    loop_free(l);
    return rc ? 1 : 0;
}
