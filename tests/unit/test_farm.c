/*
 * test_farm.c - the farm glue on a real loop, pool and store: prepare on
 * the pool, scheduling, starts, copies, the bed-clear gate, auto-eject,
 * pause/resume, a dropped printer failing its print into a retry, a job
 * that fits no printer, the missing-slicer path, and reload (one of them
 * with a real PrusaLink driver against the simulator over HTTP: a changed
 * password must reach the driver).
 *
 * Printers here are "tdrv", a small in-test driver behind drv.h standing
 * in for sim/ (being written on another branch): it records what it was
 * told and reports the events the test asks for, through the loop, as a
 * real driver would.  The prepare hook writes a tiny real G-code file.
 */
#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "../../sim/net/sim_prusalink.h"
#include "../../src/base/buf.h"
#include "../../src/base/gcode.h"
#include "../../src/base/log.h"
#include "../../src/base/mem.h"
#include "../../src/farm/farm.h"
#include "../../src/farm/farm_host.h"
#include "../../src/farm/jobctl.h"
#include "../../src/farm/sqldb.h"
#include "../../src/farm/store_host.h"
#include "../t.h"
#include "../tstore.h"

/* ---- tdrv ---- */

struct tdrv {
    struct drv base; /* first: drv.h's rule */
    char path[1200]; /* last job started */
    int starts, pauses, resumes, cancels, opens;
    uint64_t first_line;    /* of the last start */
    int64_t scan_lines;     /* the scan the last start came with; -1: none */
    enum drv_event pending; /* event to deliver on the next loop turn */
    bool has_pending;
};

static void
deliver(struct loop *l, void *ud)
{
    (void)l;
    struct tdrv *t = ud;
    if (t->has_pending) {
        t->has_pending = false;
        t->base.on_event(&t->base, t->pending, t->base.ud);
    }
}

/* Report ev (after setting state) on the next loop turn. */
static void
report(struct tdrv *t, enum drv_state st, enum drv_event ev)
{
    t->base.status.state = st;
    t->pending = ev;
    t->has_pending = true;
    loop_timer_add(t->base.loop, 0, deliver, t);
}

static const char *held; /* printer whose link stays down until the test connects it */
static enum drv_state open_state = DRV_IDLE; /* what a (re)connect finds the printer doing */
static int refuse_starts; /* start_job answers "not idle" (SF_EAGAIN) this many times */
static int attach_waits;  /* attach answers "not yet" (SF_EAGAIN) this many times */
static int attaches;      /* attach calls */
static int64_t watch_job; /* t_start records its state in the store (start_saw), once */
static int start_saw = -1;
static enum job_state state_of(int64_t id);

static int
t_open(struct drv *d, struct sf_err *err)
{
    (void)err;
    struct tdrv *t = (struct tdrv *)d;
    t->opens++;
    if (!held || strcmp(held, d->name) != 0)
        report(t, open_state, DRV_EV_STATE);
    return SF_OK;
}

static int
t_start(struct drv *d, const char *path, uint64_t first_line, const struct drv_job_scan *scan,
        struct sf_err *err)
{
    struct tdrv *t = (struct tdrv *)d;
    snprintf(t->path, sizeof(t->path), "%s", path);
    t->starts++;
    if (watch_job && start_saw < 0)
        start_saw = state_of(watch_job);
    if (refuse_starts > 0) {
        refuse_starts--;
        return sf_err_set(err, SF_EAGAIN, "printer '%s' is not idle", d->name);
    }
    t->first_line = first_line;
    t->scan_lines = scan ? (int64_t)scan->lines_total : -1;
    t->base.status.lines_acked = first_line;
    t->base.status.lines_total = scan ? scan->lines_total : 2;
    report(t, DRV_PRINTING, DRV_EV_STATE);
    return SF_OK;
}

static int
t_pause(struct drv *d, struct sf_err *err)
{
    (void)err;
    ((struct tdrv *)d)->pauses++;
    d->status.state = DRV_PAUSED;
    return SF_OK;
}

static int
t_resume(struct drv *d, struct sf_err *err)
{
    (void)err;
    ((struct tdrv *)d)->resumes++;
    d->status.state = DRV_PRINTING;
    return SF_OK;
}

static int
t_cancel(struct drv *d, struct sf_err *err)
{
    (void)err;
    ((struct tdrv *)d)->cancels++;
    d->status.state = DRV_IDLE;
    return SF_OK;
}

static bool t_console;   /* t_command takes commands (else SF_EUNSUPP) */
static char t_sent[128]; /* what it took, one line each */

static int
t_command(struct drv *d, const char *line, struct sf_err *err)
{
    if (!t_console)
        return sf_err_set(err, SF_EUNSUPP, "printer '%s': tdrv: no console", d->name);
    size_t n = strlen(t_sent);
    snprintf(t_sent + n, sizeof(t_sent) - n, "%s\n", line);
    return SF_OK;
}

/* As Marlin's: closing reports OFFLINE at once, to whoever still listens. */
static void
t_close(struct drv *d)
{
    if (d->status.state == DRV_OFFLINE)
        return;
    d->status.state = DRV_OFFLINE;
    d->on_event(d, DRV_EV_STATE, d->ud);
}

static struct tdrv *tdrvs[8];
static int n_tdrvs;

static void
t_destroy(struct drv *d)
{
    for (int i = 0; i < n_tdrvs; i++)
        if (tdrvs[i] == (struct tdrv *)d)
            tdrvs[i] = NULL;
    free(d);
}

static const struct drv_ops tdrv_ops = { DRV_OPS_VERSION, "tdrv",    t_open,   t_start,
                                         t_pause,         t_resume,  t_cancel, t_command,
                                         t_close,         t_destroy, NULL,     NULL };

/* A network printer's attach: "not yet" attach_waits times, then the job is still printing. */
static int
t_attach(struct drv *d, const char *path, const struct drv_job_scan *scan, struct sf_err *err)
{
    (void)scan;
    struct tdrv *t = (struct tdrv *)d;
    attaches++;
    if (attach_waits > 0) {
        attach_waits--;
        return sf_err_set(err, SF_EAGAIN, "printer '%s': its job is not described yet", d->name);
    }
    snprintf(t->path, sizeof(t->path), "%s", path);
    report(t, DRV_PRINTING, DRV_EV_STATE);
    return SF_OK;
}

/* tdrv for config kinds that re-attach (the network ones) */
static const struct drv_ops tdrv_net_ops = { DRV_OPS_VERSION, "tdrv-net", t_open,   t_start,
                                             t_pause,         t_resume,   t_cancel, t_command,
                                             t_close,         t_destroy,  t_attach, NULL };

static struct drv *
tdrv_new(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event, void *ud,
         struct sf_err *err)
{
    struct tdrv *t = mem_calloc(1, sizeof(*t));
    if (!t) {
        sf_err_set(err, SF_ENOMEM, "tdrv: out of memory");
        return NULL;
    }
    t->base.ops = strcmp(cfg->kind, "marlin") == 0 ? &tdrv_ops : &tdrv_net_ops;
    t->base.loop = l;
    snprintf(t->base.name, sizeof(t->base.name), "%s", cfg->name);
    t->base.on_event = on_event;
    t->base.ud = ud;
    if (n_tdrvs < 8)
        tdrvs[n_tdrvs++] = t;
    return &t->base;
}

static struct tdrv *
tdrv_find(const char *name)
{
    for (int i = n_tdrvs - 1; i >= 0; i--)
        if (tdrvs[i] && strcmp(tdrvs[i]->base.name, name) == 0)
            return tdrvs[i];
    return NULL;
}

/* tdrv_find, never NULL: the callers write through it (gcc -O2's array-bounds check said so). */
static struct tdrv *
tdrv_named(const char *name)
{
    struct tdrv *t = tdrv_find(name);
    if (!t) {
        fprintf(stderr, "test_farm: no test driver named '%s'\n", name);
        abort();
    }
    return t;
}

/* ---- prepare hook: a real (tiny) G-code file, size from the part text ---- */

static atomic_int prepares;

static int
test_prepare(const struct prepare_req *req, struct prepare_out *out, const atomic_bool *cancel,
             struct sf_err *err)
{
    (void)cancel;
    atomic_fetch_add(&prepares, 1);
    struct buf part;
    buf_init(&part, 1 << 20);
    int rc = buf_read_file(&part, req->part_path, err);
    if (rc)
        return rc;
    double x = 0, y = 0, z = 0;
    int n = sscanf(part.data ? part.data : "", "size %lf %lf %lf", &x, &y, &z);
    bool long_cmd = part.data && strstr(part.data, "long command");
    bool m600 = part.data && strstr(part.data, "filament change"); /* a profile's custom G-code */
    bool extrude = part.data && strstr(part.data, "extrude");
    const char *est = part.data ? strstr(part.data, "est ") : NULL;
    long est_s = est ? strtol(est + 4, NULL, 10) : -1;
    buf_release(&part);
    if (n != 3)
        return sf_err_set(err, SF_EINVAL, "test part: no size line");
    FILE *f = fopen(req->out_path, "w");
    if (!f)
        return sf_err_sys(err, "cannot write '%s'", req->out_path);
    if (est_s >= 0) /* the slicer's header line (slicer/slice.c) */
        fprintf(f, "; estimated printing time [s] = %ld\n", est_s);
    fprintf(f, "; for %s\nG28\nG1 X%g Y%g Z%g\n", req->printer.name, x, y, z);
    if (long_cmd) /* fits the G-code limit, not a numbered Marlin line */
        fprintf(f, "M117 %0120d\nG1 X0\n", 0);
    if (m600)
        fprintf(f, "M600\n");
    if (extrude) /* 15 mm of filament: 5, 7.5 (absolute E), a reset, 2.5 */
        fprintf(f, "M82\nG1 X10 E5 ; wall\n\nG1 X20 E12.5\nG92 E0\nG1 X30 E2.5\n");
    fclose(f);
    out->size_mm[0] = x;
    out->size_mm[1] = y;
    out->size_mm[2] = z;
    out->nozzle_mm = req->printer.nozzle_mm;
    return SF_OK;
}

/* ---- fixture ---- */

static struct {
    struct loop *l;
    struct store *s;
    struct pool *pool;
    struct farm *f;
    struct farmcfg cfg;
} fx;

static const char farm_ini[] = "[printer a]\ndriver: marlin\nport: pty:/dev/null\n"
                               "material: PLA\nbed_size: 200, 200, 200\n"
                               "[printer b]\ndriver: marlin\nport: pty:/dev/null\n"
                               "material: PETG\nbed_size: 300, 300, 300\nauto_eject: true\n";

static const char *setup_held;    /* held while the farm opens its printers */
static int64_t setup_progress_ms; /* the farm's progress timer for the next setup; 0: 50 ms */

static int
setup(const char *name, const char *ini, printer_driver_fn driver, prepare_fn prep,
      struct sf_err *err)
{
    char dir[512];
    snprintf(dir, sizeof(dir), "%s/%s", t_tmpdir(), name);
    memset(&fx, 0, sizeof(fx));
    memset(tdrvs, 0, sizeof(tdrvs));
    n_tdrvs = 0;
    held = setup_held;
    setup_held = NULL;
    open_state = DRV_IDLE;
    refuse_starts = attach_waits = attaches = 0;
    t_console = false;
    t_sent[0] = '\0';
    log_set_level(LOG_ERROR);
    farmcfg_init(&fx.cfg);
    int rc = farmcfg_parse(&fx.cfg, ini, strlen(ini), "test.ini", err);
    if (rc)
        return rc;
    if (!(fx.l = loop_new(err)) || !(fx.s = t_store_open(dir, NULL, err)) ||
        !(fx.pool = pool_new(fx.l, 2, err)))
        return SF_EIO;
    struct farm_hooks hooks = { .driver = driver,
                                .prepare = prep,
                                .progress_ms = setup_progress_ms ? setup_progress_ms : 50 };
    setup_progress_ms = 0;
    fx.f = farm_new(fx.l, fx.s, fx.pool, &fx.cfg, &hooks, err);
    return fx.f ? SF_OK : SF_EIO;
}

static void
teardown(void)
{
    farm_drop_pool(fx.f);
    pool_free(fx.pool);
    loop_run_once(fx.l, 0); /* deliver completions of cancelled work */
    farm_free(fx.f);
    store_close(fx.s);
    loop_free(fx.l);
    farmcfg_release(&fx.cfg);
}

static int64_t
add_m(const char *part, const char *material, int copies, const char *method)
{
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.method, sizeof(o.method), "%s", method);
    snprintf(o.name, sizeof(o.name), "part.stl");
    snprintf(o.material, sizeof(o.material), "%s", material);
    o.copies = copies;
    char sha[STORE_SHA_HEX];
    int64_t id = 0;
    if (store_file_put(fx.s, part, strlen(part), sha, NULL) ||
        store_job_add(fx.s, &o, sha, &id, NULL))
        return 0;
    farm_kick(fx.f);
    return id;
}

static int64_t
add(const char *part, const char *material, int copies)
{
    return add_m(part, material, copies, "orient");
}

/* The store once every write the farm queued is in (farm_sync): what a test reads. */
static struct store *
synced(void)
{
    farm_sync(fx.f, -1, NULL);
    return fx.s;
}

static int
job_get(int64_t id, struct job_row *j, struct sf_err *err)
{
    return store_job_get(synced(), id, j, err);
}

static enum job_state
state_of(int64_t id)
{
    struct job_row j;
    return job_get(id, &j, NULL) ? (enum job_state) - 1 : j.state;
}

static enum printer_state
pstate(size_t i)
{
    struct printer_info info;
    farm_printer_info(fx.f, i, &info);
    return info.state;
}

/* Wall-clock ms, for waits that must not depend on how fast the loop turns. */
static int64_t
wall_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000 + ts.tv_nsec / 1000000;
}

/* How long a wait for something that must happen may take: a real prepare
   on a loaded machine under the sanitizers takes seconds, and a loop turn
   ends early whenever an event comes, so both bounds are on the wall clock. */
#define WAIT_LIMIT_MS 120000

/* Every printer printing a job has its driver started: a start is committed
   first, and reaches the driver once the file is judged (farm.c start). */
static bool
drivers_started(void)
{
    for (size_t i = 0; i < farm_printer_count(fx.f); i++) {
        struct printer_info info;
        farm_printer_info(fx.f, i, &info);
        struct tdrv *t = tdrv_find(info.cfg->name);
        if (info.state == PRINTER_PRINTING && info.job_id && t && t->base.status.state == DRV_IDLE)
            return false;
    }
    return true;
}

/* Turn the loop until job id is in state want (or WAIT_LIMIT_MS pass). */
static bool
wait_job(int64_t id, enum job_state want)
{
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS; wall_ms() < end;) {
        if (state_of(id) == want && drivers_started())
            return true;
        loop_run_once(fx.l, 10);
    }
    return state_of(id) == want;
}

/* Turn the loop until job id is in state want or failed (or WAIT_LIMIT_MS pass): its state
   then, so that a case's check shows which state it ended in. */
static enum job_state
wait_job_or_failure(int64_t id, enum job_state want)
{
    enum job_state st = JOB_QUEUED;
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS;
         wall_ms() < end && (st = state_of(id)) != want && st != JOB_FAILED;)
        loop_run_once(fx.l, 10);
    return st;
}

/* Turn the loop until printer i is in state want (or WAIT_LIMIT_MS pass). */
static bool
wait_printer(size_t i, enum printer_state want)
{
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS; wall_ms() < end;) {
        if (pstate(i) == want && drivers_started())
            return true;
        loop_run_once(fx.l, 10);
    }
    return pstate(i) == want;
}

T_CASE(farm_prints_copies_with_bed_clear_gate_and_auto_eject)
{
    struct sf_err err;
    T_OK(setup("flow", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE) && wait_printer(1, PRINTER_IDLE));
    int64_t j1 = add("size 50 50 50", "PLA", 2), j2 = add("size 250 250 10", "PETG", 1);
    int64_t j3 = add("size 10 10 10", "ABS", 1);
    T_TRUE(wait_job(j1, JOB_PRINTING));
    T_TRUE(wait_job(j2, JOB_PRINTING));
    struct tdrv *a = tdrv_named("a"), *b = tdrv_named("b");
    T_EQ_INT(a->starts, 1);
    T_EQ_INT(b->starts, 1);
    /* the printer got the job's real G-code */
    struct buf g;
    buf_init(&g, 4096);
    T_OK(buf_read_file(&g, a->path, &err), &err);
    T_EQ_STR(g.data, "; for a\nG28\nG1 X50 Y50 Z50\n");
    buf_release(&g);
    /* with its command count, scanned on the prepare worker and kept with
       the job: start_job had no file to read on the loop thread */
    T_EQ_INT(a->scan_lines, 2);
    struct job_row j;
    T_OK(job_get(j1, &j, &err), &err);
    T_EQ_INT(j.gcode_lines, 2);
    /* a job nobody can print stays queued, saying why */
    loop_run_once(fx.l, 10);
    T_OK(job_get(j3, &j, &err), &err);
    T_EQ_INT(j.state, JOB_QUEUED);
    T_EQ_STR(j.reason, "fits no printer: a: material ABS not loaded (has PLA); b: material ABS "
                       "not loaded (has PETG)");

    /* copy 1 done: a waits for its bed; the job waits for a */
    a->base.status.lines_acked = 2;
    report(a, DRV_IDLE, DRV_EV_JOB_DONE);
    T_TRUE(wait_job(j1, JOB_READY));
    T_TRUE(wait_printer(0, PRINTER_AWAITING_CLEAR));
    for (int i = 0; i < 5; i++)
        loop_run_once(fx.l, 10);
    T_EQ_INT(a->starts, 1);
    T_OK(job_get(j1, &j, &err), &err);
    T_EQ_STR(j.reason, "waits for a printer: a is awaiting-clear");
    /* the scheduler runs at every change: a reason it wrote is not posted again (each a
       statement on the store thread, per waiting job per pass: most of what 10,000 queued
       jobs cost a host); what each pass posts is its read of the live jobs */
    T_OK(farm_sync(fx.f, 10000, &err), &err);
    struct storeq_stats st0, st1;
    storeq_stats(farm_storeq(fx.f), &st0);
    for (int i = 0; i < 5; i++) {
        farm_kick(fx.f);
        loop_run_once(fx.l, 10); /* the pass */
        T_OK(farm_sync(fx.f, 10000, &err), &err);
    }
    storeq_stats(farm_storeq(fx.f), &st1);
    /* five passes: five reads, and none of the two waiting jobs' reasons again (before: 13
       posts; a pass more, woken by a commit, adds its read) */
    T_TRUE(st1.posted - st0.posted < 10);
    T_OK(farm_printer_action(fx.f, "a", PRINTER_ACT_CLEARED, &err), &err);
    T_TRUE(wait_job(j1, JOB_PRINTING));
    T_EQ_INT(a->starts, 2);

    /* pause and resume through the farm */
    T_OK(farm_printer_action(fx.f, "a", PRINTER_ACT_PAUSE, &err), &err);
    T_EQ_INT(state_of(j1), JOB_PAUSED);
    T_EQ_INT(a->pauses, 1);
    T_ERR(farm_printer_action(fx.f, "a", PRINTER_ACT_PAUSE, &err), SF_EINVAL, &err,
          "cannot pause a printer that is paused");
    T_OK(farm_printer_action(fx.f, "a", PRINTER_ACT_RESUME, &err), &err);
    T_EQ_INT(state_of(j1), JOB_PRINTING);
    T_EQ_INT(farm_printer_action(fx.f, "zz", PRINTER_ACT_PAUSE, &err), SF_ENOTFOUND);

    /* b has an ejector: done means idle at once */
    report(b, DRV_IDLE, DRV_EV_JOB_DONE);
    T_TRUE(wait_job(j2, JOB_DONE));
    T_TRUE(wait_printer(1, PRINTER_IDLE));

    /* copy 2 done too */
    report(a, DRV_IDLE, DRV_EV_JOB_DONE);
    T_TRUE(wait_job(j1, JOB_DONE));
    struct print_row *p;
    size_t n;
    T_OK(store_prints(synced(), j1, &p, &n, &err), &err);
    T_EQ_INT(n, 2);
    T_EQ_STR(p[0].outcome, "done");
    T_EQ_STR(p[1].outcome, "done");
    free(p);
    T_OK(store_check(synced(), &err), &err);
    teardown();
}

/*
 * A print's end records the filament it used (issue 31: print history said
 * Filament 0.00 m for done prints, nobody set job_event_args.filament_mm):
 * a done print all of its G-code's net E, a cancelled one the E up to its
 * last acknowledged line (comments and blank lines are not lines).
 */
T_CASE(farm_print_records_its_filament)
{
    struct sf_err err;
    T_OK(setup("filament", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    int64_t done = add("size 20 20 20 extrude", "PLA", 1);
    T_TRUE(wait_job(done, JOB_PRINTING));
    struct tdrv *a = tdrv_named("a");
    T_EQ_INT(a->scan_lines, 7); /* G28, G1, M82, G1 E5, G1 E12.5, G92, G1 E2.5 */
    a->base.status.lines_acked = 7;
    report(a, DRV_IDLE, DRV_EV_JOB_DONE);
    T_TRUE(wait_job(done, JOB_DONE));
    struct print_row *p;
    size_t n;
    T_OK(store_prints(synced(), done, &p, &n, &err), &err);
    T_EQ_INT(n, 1);
    T_EQ_DBL(p[0].filament_mm, 15, 1e-9);
    free(p);
    T_OK(farm_printer_action(fx.f, "a", PRINTER_ACT_CLEARED, &err), &err);
    /* cancelled after 5 lines: G1 E12.5 was the last acknowledged */
    int64_t cut = add("size 20 20 20 extrude", "PLA", 1);
    T_TRUE(wait_job(cut, JOB_PRINTING));
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS; wall_ms() < end && a->starts < 2;)
        loop_run_once(fx.l, 10);
    T_EQ_INT(a->starts, 2);
    a->base.status.lines_acked = 5;
    report(a, DRV_PRINTING, DRV_EV_PROGRESS);
    struct job_row jr = { 0 }; /* the farm has it once it saved it (its 50 ms progress timer) */
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS; wall_ms() < end && jr.lines_acked != 5;) {
        loop_run_once(fx.l, 10);
        T_OK(job_get(cut, &jr, &err), &err);
    }
    T_EQ_INT(jr.lines_acked, 5);
    T_OK(farm_printer_action(fx.f, "a", PRINTER_ACT_CANCEL, &err), &err);
    T_EQ_INT(state_of(cut), JOB_CANCELLED);
    T_OK(store_prints(synced(), cut, &p, &n, &err), &err);
    T_EQ_INT(n, 1);
    T_EQ_INT(p[0].lines_acked, 5);
    T_EQ_DBL(p[0].filament_mm, 12.5, 1e-9);
    free(p);
    teardown();
}

T_CASE(farm_dropped_printer_fails_print_into_retry_and_reconnects)
{
    struct sf_err err;
    T_OK(setup("drop", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    int64_t id = add("size 20 20 20", "PLA", 1); /* max_retries defaults to 1 */
    T_TRUE(wait_job(id, JOB_PRINTING));
    struct tdrv *a = tdrv_named("a");
    a->base.status.lines_acked = 1;
    report(a, DRV_PRINTING, DRV_EV_PROGRESS);
    loop_run_once(fx.l, 10);
    snprintf(a->base.status.message, sizeof(a->base.status.message), "USB cable pulled");
    report(a, DRV_OFFLINE, DRV_EV_STATE);
    T_TRUE(wait_printer(0, PRINTER_OFFLINE));
    struct job_row j;
    T_OK(job_get(id, &j, &err), &err);
    T_EQ_INT(j.state, JOB_READY); /* retry */
    T_EQ_INT(j.counts.failures, 1);
    struct print_row *p;
    size_t n;
    T_OK(store_prints(synced(), id, &p, &n, &err), &err);
    T_EQ_INT(n, 1);
    T_EQ_STR(p[0].outcome, "failed");
    T_EQ_INT(p[0].lines_acked, 1);
    free(p);
    /* reconnected after the backoff, the retry starts */
    T_TRUE(wait_printer(0, PRINTER_PRINTING));
    T_EQ_INT(a->opens, 2);
    T_EQ_INT(state_of(id), JOB_PRINTING);
    /* the operator cancels: the printer keeps the bed gate */
    T_OK(farm_printer_action(fx.f, "a", PRINTER_ACT_CANCEL, &err), &err);
    T_EQ_INT(state_of(id), JOB_CANCELLED);
    T_EQ_INT(pstate(0), PRINTER_AWAITING_CLEAR);
    T_EQ_INT(a->cancels, 1);
    T_OK(store_check(synced(), &err), &err);
    teardown();
}

/*
 * A start the printer refuses with "not now" (SF_EAGAIN: not idle) puts
 * the job back to ready without spending a retry, leaves the bed as it was,
 * and the printer holds off (0.5, 1, 2 s) before it takes a job again.  It
 * used to count as a failed print: with max_retries 1 the second refusal
 * failed the job, and the first left the printer awaiting a bed clear.
 */
T_CASE(farm_refused_start_waits_without_spending_a_retry)
{
    struct sf_err err;
    T_OK(setup("refuse", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    refuse_starts = 3;
    int64_t id = add("size 20 20 20", "PLA", 1); /* max_retries defaults to 1 */
    T_TRUE(wait_job(id, JOB_PRINTING));
    struct tdrv *a = tdrv_named("a");
    T_EQ_INT(a->starts, 4);
    struct job_row j;
    T_OK(job_get(id, &j, &err), &err);
    T_EQ_INT(j.counts.failures, 0);
    struct print_row *p;
    size_t n;
    T_OK(store_prints(synced(), id, &p, &n, &err), &err);
    T_EQ_INT(n, 4);
    for (size_t i = 0; i < 3; i++)
        T_EQ_STR(p[i].outcome, "refused");
    T_EQ_STR(p[3].outcome, "");
    free(p);
    report(a, DRV_IDLE, DRV_EV_JOB_DONE);
    T_TRUE(wait_job(id, JOB_DONE));
    T_OK(store_check(synced(), &err), &err);
    teardown();
}

/* Rewrite the "[s] = 400" of job id's stored G-code to say 900 (same size). */
static bool
gcode_says_900(int64_t id)
{
    struct job_row j;
    char path[1024];
    struct buf g;
    buf_init(&g, 1 << 20);
    bool ok = job_get(id, &j, NULL) == SF_OK &&
              store_file_path(fx.s, j.gcode_sha, path, sizeof(path), NULL) == SF_OK &&
              buf_read_file(&g, path, NULL) == SF_OK && g.data && strstr(g.data, "= 400\n");
    if (ok) {
        memcpy(strstr(g.data, "= 400\n"), "= 900", 5);
        chmod(path, 0644);
        FILE *f = fopen(path, "w");
        ok = f && fwrite(g.data, 1, g.len, f) == g.len;
        ok = f && fclose(f) == 0 && ok;
    }
    buf_release(&g);
    return ok;
}

/*
 * The G-code's time estimate is kept with the job when it is prepared, and
 * a start takes it from there, not from the file; a job stored before the
 * store kept it (no est_s: an older data dir) reads the file's head.
 */
T_CASE(farm_time_estimate_travels_in_the_job)
{
    struct sf_err err;
    struct job_row j;
    T_OK(setup("estjob", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    int64_t id = add("size 20 20 20 est 400", "PLA", 3);
    T_TRUE(wait_job(id, JOB_PRINTING) && job_get(id, &j, NULL) == SF_OK);
    T_TRUE(j.est_known);
    T_EQ_DBL(j.est_s, 400, 0);
    T_TRUE(gcode_says_900(id));
    struct tdrv *a = tdrv_named("a");
    struct printer_info info;
    for (int copy = 2; copy <= 3; copy++) {
        report(a, DRV_IDLE, DRV_EV_JOB_DONE);
        T_TRUE(wait_printer(0, PRINTER_AWAITING_CLEAR));
        if (copy == 3) { /* the row as a schema-5 store left it */
            char dir[600];
            snprintf(dir, sizeof(dir), "%s/estjob", t_tmpdir());
            T_OK(t_store_exec(dir, "UPDATE jobs SET est_s = NULL"), NULL);
        }
        T_OK(farm_printer_action(fx.f, "a", PRINTER_ACT_CLEARED, &err), &err);
        T_TRUE(wait_job(id, JOB_PRINTING));
        a->base.status.progress = 0.25;
        farm_printer_info(fx.f, 0, &info);
        T_EQ_STR(info.time_left_from, "farm");
        /* copy 2: the job's 400, though the file now says 900; copy 3: the file's */
        T_EQ_INT(info.time_left_s, copy == 2 ? 300 : 675);
    }
    teardown();
}

/*
 * The time left a printer shows: the printer's own estimate when its
 * driver has one, else the farm's (the G-code's estimated print time less
 * the progress made), saying which; none without either.
 */
T_CASE(farm_time_left_is_the_printers_own_else_the_farms)
{
    struct sf_err err;
    T_OK(setup("left", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE) && wait_printer(1, PRINTER_IDLE));
    int64_t id = add("size 20 20 20 est 400", "PLA", 1);
    T_TRUE(wait_job(id, JOB_PRINTING));
    struct tdrv *a = tdrv_named("a");
    a->base.status.progress = 0.25;
    struct printer_info info;
    farm_printer_info(fx.f, 0, &info);
    T_EQ_STR(info.time_left_from, "farm");
    T_EQ_INT(info.time_left_s, 300);
    a->base.status.has_time_left = true;
    a->base.status.time_left_s = 42;
    farm_printer_info(fx.f, 0, &info);
    T_EQ_STR(info.time_left_from, "printer");
    T_EQ_INT(info.time_left_s, 42);
    /* no estimate anywhere: none */
    int64_t other = add("size 20 20 20", "PETG", 1);
    T_TRUE(wait_job(other, JOB_PRINTING));
    farm_printer_info(fx.f, 1, &info);
    T_EQ_STR(info.time_left_from, "");
    T_EQ_INT(info.time_left_s, -1);
    /* the printer's estimate goes with the job */
    report(a, DRV_IDLE, DRV_EV_JOB_DONE);
    T_TRUE(wait_job(id, JOB_DONE));
    farm_printer_info(fx.f, 0, &info);
    T_EQ_STR(info.time_left_from, "");
    teardown();
}

/*
 * A network printer comes back while its job is interrupted, and its
 * driver cannot tell yet whether the printer still runs it (SF_EAGAIN:
 * PrusaLink's job details are still on their way): the farm asks again and
 * re-attaches.  It used to mark the attach tried before asking, so the job
 * stayed interrupted until the printer's next reconnect.
 */
T_CASE(farm_attach_not_yet_is_asked_again)
{
    static const char ini[] = "[printer n]\ndriver: octoprint\nurl: http://127.0.0.1:9\n"
                              "api_key: k\nmaterial: PLA\nbed_size: 200, 200, 200\n";
    struct sf_err err;
    T_OK(setup("attach", ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    int64_t id = add("size 20 20 20", "PLA", 1);
    T_TRUE(wait_job(id, JOB_PRINTING));
    struct tdrv *t = tdrv_named("n");
    /* contact lost while printing: interrupted, re-offered on reconnect */
    open_state = DRV_PRINTING;
    attach_waits = 2;
    snprintf(t->base.status.message, sizeof(t->base.status.message), "timed out");
    report(t, DRV_OFFLINE, DRV_EV_STATE);
    T_TRUE(wait_job(id, JOB_INTERRUPTED));
    T_TRUE(wait_job(id, JOB_PRINTING));
    T_EQ_INT(attaches, 3);
    T_EQ_INT(t->opens, 2);
    T_EQ_INT(pstate(0), PRINTER_PRINTING);
    report(t, DRV_IDLE, DRV_EV_JOB_DONE);
    T_TRUE(wait_job(id, JOB_DONE));
    T_OK(store_check(synced(), &err), &err);
    teardown();
}

/*
 * A host restarted on a shared store (issue 32): its predecessor died
 * printing on a network printer and its lease runs on, so the new process
 * cannot join yet, while the printer connects at once, still printing.
 * The join reaps the predecessor, which interrupts its prints: a job
 * re-attached before the join was interrupted under the printer that ran
 * it ("host h lost its lease", farmd_net on PostgreSQL).  The printer now
 * waits offline for the lease, and re-attaches the job after the join,
 * under the new process's lease (store_job_attach).
 */
T_CASE(farm_restarted_host_reattaches_after_its_join)
{
    static const char ini[] = "[farm]\nstore: postgresql:///unused\nhost: h\nhost_lease_s: 2\n"
                              "[printer n]\ndriver: octoprint\nurl: http://127.0.0.1:9\n"
                              "api_key: k\nmaterial: PLA\nbed_size: 200, 200, 200\n";
    struct sf_err err;
    char dir[512];
    snprintf(dir, sizeof(dir), "%s/rejoin", t_tmpdir());
    /* the predecessor: joined as h, printing job id on n, then gone (no beat) */
    struct store *s = t_store_open(dir, NULL, &err);
    T_TRUE(s != NULL);
    int64_t tok, id, fence;
    T_OK(store_host_join(s, "h", 1500, &tok, &err), &err);
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "part.gcode");
    snprintf(o.material, sizeof(o.material), "PLA");
    char sha[STORE_SHA_HEX];
    struct job_event_args g = { .prep_key = "k", .gcode_lines = 2 };
    T_OK(store_file_put(s, "G28\nG1 X1\n", 10, sha, &err), &err);
    T_OK(store_job_add_gcode(s, &o, sha, &g, &id, &err), &err);
    T_OK(store_job_take(s, "h", tok, id, &fence, &err), &err);
    struct job_event_args a = { .printer = "n", .fence = fence };
    T_OK(store_job_event(s, id, JOB_EV_START, &a, NULL, &err), &err);
    store_close(s);
    T_OK(setup("rejoin", ini, tdrv_new, test_prepare, &err), &err);
    open_state = DRV_PRINTING; /* the printer still runs it */
    report(tdrv_named("n"), DRV_PRINTING, DRV_EV_STATE);
    char host[64];
    /* before the join: the printer waits, nothing attached */
    struct printer_info info;
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS; wall_ms() < end;) {
        farm_printer_info(fx.f, 0, &info);
        if (attaches > 0 || strstr(info.message, "no lease yet") ||
            farm_host_reader(fx.f, host, sizeof(host)))
            break;
        loop_run_once(fx.l, 10);
    }
    T_TRUE(!farm_host_reader(fx.f, host, sizeof(host))); /* 1.5 s: the lease still runs */
    T_EQ_INT(attaches, 0);
    T_EQ_INT(pstate(0), PRINTER_OFFLINE);
    /* the join reaps the predecessor; then the printer takes the job back */
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS; wall_ms() < end;) {
        if (farm_host_reader(fx.f, host, sizeof(host)))
            break;
        loop_run_once(fx.l, 10);
    }
    T_EQ_STR(host, "h");
    T_TRUE(wait_job(id, JOB_PRINTING));
    T_EQ_INT(attaches, 1);
    T_EQ_INT(pstate(0), PRINTER_PRINTING);
    report(tdrv_named("n"), DRV_IDLE, DRV_EV_JOB_DONE);
    T_TRUE(wait_job(id, JOB_DONE));
    teardown();
}

/*
 * An operator clears a printer's error before its driver has seen the
 * printer recover (a network driver polls): the printer stays in error,
 * starts nothing, and leaves the error when the driver reports idle.  It
 * used to go idle at once and hand the retry to a driver that refused it,
 * failing the job (farmd_octoprint_faults, CI of stop 24).  And a print
 * someone starts at an idle printer takes it out of the farm until the
 * driver sees it idle again.
 */
T_CASE(farm_printer_takes_jobs_only_when_its_driver_is_idle)
{
    struct sf_err err;
    T_OK(setup("clear", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    int64_t id = add("size 20 20 20", "PLA", 1); /* max_retries defaults to 1 */
    T_TRUE(wait_job(id, JOB_PRINTING));
    struct tdrv *a = tdrv_named("a");
    snprintf(a->base.status.message, sizeof(a->base.status.message), "heater failure");
    report(a, DRV_ERROR, DRV_EV_JOB_FAILED);
    T_TRUE(wait_printer(0, PRINTER_ERROR));
    T_EQ_INT(state_of(id), JOB_READY);
    /* cleared while the driver still says error */
    T_OK(farm_printer_action(fx.f, "a", PRINTER_ACT_CLEARED, &err), &err);
    for (int i = 0; i < 10; i++)
        loop_run_once(fx.l, 10);
    T_EQ_INT(pstate(0), PRINTER_ERROR);
    T_EQ_INT(a->starts, 1);
    T_EQ_INT(state_of(id), JOB_READY);
    /* the printer recovers: the retry starts without another clear */
    a->base.status.message[0] = '\0';
    report(a, DRV_IDLE, DRV_EV_STATE);
    T_TRUE(wait_job(id, JOB_PRINTING));
    T_EQ_INT(a->starts, 2);
    report(a, DRV_IDLE, DRV_EV_JOB_DONE);
    T_TRUE(wait_job(id, JOB_DONE));
    T_TRUE(wait_printer(0, PRINTER_AWAITING_CLEAR));
    T_OK(farm_printer_action(fx.f, "a", PRINTER_ACT_CLEARED, &err), &err);
    T_EQ_INT(pstate(0), PRINTER_IDLE);

    /* a print started at the printer: out of the farm, saying why */
    snprintf(a->base.status.message, sizeof(a->base.status.message), "busy (Printing 'x')");
    report(a, DRV_PRINTING, DRV_EV_STATE);
    T_TRUE(wait_printer(0, PRINTER_OFFLINE));
    struct printer_info info;
    farm_printer_info(fx.f, 0, &info);
    T_EQ_STR(info.message, "busy (Printing 'x')");
    int64_t next = add("size 20 20 20", "PLA", 1);
    T_TRUE(wait_job(next, JOB_READY));
    for (int i = 0; i < 10; i++)
        loop_run_once(fx.l, 10);
    T_EQ_INT(a->starts, 2);
    a->base.status.message[0] = '\0';
    report(a, DRV_IDLE, DRV_EV_STATE);
    T_TRUE(wait_job(next, JOB_PRINTING));
    T_EQ_INT(a->starts, 3);
    T_OK(store_check(synced(), &err), &err);
    teardown();
}

/*
 * A Marlin that talks but takes no line fails its job in error; its driver
 * drops the link and opens it again, and if the printer does not answer
 * that handshake the driver goes offline and the farm connects it again.
 * On auto-eject printer b the error's look is still owed: it comes back
 * awaiting clear, and the retry waits for the operator.  Before, the
 * reconnect made it idle and the retry started with nobody having looked.
 */
T_CASE(farm_error_printer_that_goes_offline_comes_back_awaiting_clear)
{
    struct sf_err err;
    T_OK(setup("errofl", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(1, PRINTER_IDLE));
    int64_t id = add("size 20 20 20", "PETG", 1); /* max_retries defaults to 1 */
    T_TRUE(wait_job(id, JOB_PRINTING));
    struct tdrv *b = tdrv_named("b");
    T_EQ_INT(b->starts, 1);
    snprintf(b->base.status.message, sizeof(b->base.status.message),
             "printer stopped answering: it talks, but takes no line");
    report(b, DRV_ERROR, DRV_EV_JOB_FAILED);
    T_TRUE(wait_printer(1, PRINTER_ERROR));
    T_EQ_INT(state_of(id), JOB_READY);
    /* the new handshake goes unanswered: offline, and the farm connects it again */
    int opens = b->opens;
    snprintf(b->base.status.message, sizeof(b->base.status.message), "no reply");
    report(b, DRV_OFFLINE, DRV_EV_STATE);
    T_TRUE(wait_printer(1, PRINTER_AWAITING_CLEAR));
    T_EQ_INT(b->opens, opens + 1);
    for (int i = 0; i < 10; i++)
        loop_run_once(fx.l, 10);
    T_EQ_INT(pstate(1), PRINTER_AWAITING_CLEAR);
    T_EQ_INT(b->starts, 1);
    T_EQ_INT(state_of(id), JOB_READY);
    /* the operator looks: the retry starts */
    T_OK(farm_printer_action(fx.f, "b", PRINTER_ACT_CLEARED, &err), &err);
    T_TRUE(wait_job(id, JOB_PRINTING));
    T_EQ_INT(b->starts, 2);
    report(b, DRV_IDLE, DRV_EV_JOB_DONE);
    T_TRUE(wait_job(id, JOB_DONE));
    teardown();
}

/*
 * A job whose G-code holds a command no printer can take fails when it is
 * prepared, naming the file and line, and never reaches a printer: the
 * check that used to run in start_job on the loop thread now runs on the
 * prepare worker, and it still keeps a job from failing half-way.
 */
T_CASE(farm_bad_gcode_line_or_policy_fails_at_prepare_naming_file_and_line)
{
    struct sf_err err;
    T_OK(setup("badline", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    int64_t bad = add("size 20 20 20 long command", "PLA", 1);
    T_TRUE(wait_job(bad, JOB_FAILED));
    struct job_row j;
    T_OK(job_get(bad, &j, &err), &err);
    char want[64];
    snprintf(want, sizeof(want), "job-%lld.gcode':4: command too long", (long long)bad);
    T_TRUE(strstr(j.reason, want) != NULL);
    T_EQ_STR(j.gcode_sha, "");
    /* sliced G-code that breaks the printer's G-code policy (a profile's M600 on an
       unattended printer) fails the same way, naming its line */
    int64_t m600 = add("size 20 20 20 filament change", "PLA", 1);
    T_TRUE(wait_job(m600, JOB_FAILED));
    T_OK(job_get(m600, &j, &err), &err);
    T_TRUE(strstr(j.reason, "line 4: M600: a filament change waits for a person") != NULL);
    T_EQ_INT(tdrv_named("a")->starts, 0);
    /* a good job after it prints */
    int64_t good = add("size 20 20 20", "PLA", 1);
    T_TRUE(wait_job(good, JOB_PRINTING));
    T_EQ_INT(tdrv_named("a")->scan_lines, 2);
    teardown();
}

/* A closed tetrahedron, 10 mm on each axis. */
static const char tetra_stl[] = "solid t\n"
                                "facet normal 0 0 -1\nouter loop\nvertex 0 0 0\nvertex 0 10 0\n"
                                "vertex 10 0 0\nendloop\nendfacet\n"
                                "facet normal 0 -1 0\nouter loop\nvertex 0 0 0\nvertex 10 0 0\n"
                                "vertex 0 0 10\nendloop\nendfacet\n"
                                "facet normal -1 0 0\nouter loop\nvertex 0 0 0\nvertex 0 0 10\n"
                                "vertex 0 10 0\nendloop\nendfacet\n"
                                "facet normal 1 1 1\nouter loop\nvertex 10 0 0\nvertex 0 10 0\n"
                                "vertex 0 0 10\nendloop\nendfacet\n"
                                "endsolid t\n";

/* What prepare logged (its figures per method), for the pipeline test. */
static char prep_log[16384];
static size_t prep_log_len;

static void
prep_sink(void *ud, enum log_level level, const char *subsys, const char *printer, const char *msg)
{
    (void)ud, (void)level, (void)printer;
    if (strcmp(subsys, "prepare") == 0 && prep_log_len < sizeof(prep_log))
        prep_log_len +=
            (size_t)snprintf(prep_log + prep_log_len, sizeof(prep_log) - prep_log_len, "%s\n", msg);
}

/* True when prepare logged a line starting "job ID: what". */
static bool
logged(int64_t id, const char *what)
{
    char want[128];
    snprintf(want, sizeof(want), "job %lld: %s", (long long)id, what);
    for (const char *l = prep_log; l && *l; l = strchr(l, '\n') ? strchr(l, '\n') + 1 : NULL)
        if (strncmp(l, want, strlen(want)) == 0)
            return true;
    return false;
}

T_CASE(farm_default_prepare_runs_every_method)
{
    /* the real pipeline: src/mesh, src/geom orient, slicer/ with
       config/printers and config/materials (tests run from the top) */
    struct sf_err err;
    T_OK(setup("pipeline", farm_ini, NULL, prepare_part, &err), &err);
    prep_log_len = 0;
    prep_log[0] = '\0';
    log_set_level(LOG_INFO);
    log_set_sink(prep_sink, NULL);
    T_EQ_INT(pstate(0), PRINTER_OFFLINE);
    int64_t ok = add(tetra_stl, "PLA", 1), surf = add_m(tetra_stl, "PLA", 1, "surface"),
            junk = add("this is no mesh", "", 1), abs = add_m(tetra_stl, "", 1, "none"),
            slimmed = add_m(tetra_stl, "PLA", 1, "slim");
    T_TRUE(wait_job(junk, JOB_FAILED));
    T_TRUE(wait_job(ok, JOB_READY));
    T_TRUE(wait_job(slimmed, JOB_READY)); /* oriented, slimmed (Hu 2015) and sliced */
    T_TRUE(wait_job(surf, JOB_READY));    /* turned and reshaped (Jayakody) and sliced */
    for (int i = 0; i < 20; i++)
        loop_run_once(fx.l, 10);
    struct job_row j;
    /* oriented and sliced for printer a (PLA, 0.4 mm), waiting for it */
    T_OK(job_get(ok, &j, &err), &err);
    T_EQ_DBL(j.nozzle_mm, 0.4, 1e-9);
    T_TRUE(j.size_mm[2] > 0 && j.size_mm[2] <= 10.0 * 1.7321 + 1e-6);
    T_EQ_STR(j.reason, "waits for a printer: a is offline");
    char path[1200];
    T_OK(store_file_path(fx.s, j.gcode_sha, path, sizeof(path), &err), &err);
    struct buf g;
    buf_init(&g, 64 << 20);
    T_OK(buf_read_file(&g, path, &err), &err);
    T_TRUE(strstr(g.data, "G1 ") != NULL);
    /* its command count, as a driver numbers them, kept with the job */
    int64_t cmds = 0;
    for (char *line = g.data, *nl; line && *line; line = nl ? nl + 1 : NULL) {
        nl = strchr(line, '\n');
        char cmd[256];
        size_t len = nl ? (size_t)(nl - line) : strlen(line);
        cmds += gcode_strip(line, len, cmd, sizeof(cmd), NULL) > 0;
    }
    T_TRUE(cmds > 100);
    T_EQ_INT(j.gcode_lines, cmds);
    buf_release(&g);
    T_OK(job_get(surf, &j, &err), &err);
    T_EQ_STR(j.reason, "waits for a printer: a is offline");
    /* a broken part fails at once, naming the uploaded file */
    T_OK(job_get(junk, &j, &err), &err);
    T_TRUE(strstr(j.reason, "'part.stl': not a mesh file") != NULL);
    /* method none: sliced as uploaded */
    T_TRUE(wait_job(abs, JOB_READY));
    log_set_sink(NULL, NULL);
    log_set_level(LOG_ERROR);
    /* each method did its own work, with its figures: slimming ran on the
       oriented part; the surface method turned and reshaped it its own way,
       so the part it prints is not the one orientation alone chose */
    T_TRUE(logged(slimmed, "slimmed (Hu 2015): iteration "));
    T_TRUE(logged(surf, "surface (Jayakody 2025) in the direction search: "));
    T_TRUE(!logged(ok, "slimmed") && !logged(ok, "surface"));
    struct job_row o, sf;
    T_OK(job_get(ok, &o, &err), &err);
    T_OK(job_get(surf, &sf, &err), &err);
    T_TRUE(o.mesh_sha[0] && sf.mesh_sha[0]);
    T_TRUE(strcmp(o.mesh_sha, sf.mesh_sha) != 0);
    T_TRUE(strcmp(o.gcode_sha, sf.gcode_sha) != 0);
    /* the shape methods' deviation is recorded with the job, the others' is not */
    T_TRUE(!o.dev_measured && !o.shape_changed);
    T_TRUE(sf.dev_measured);
    T_TRUE(sf.shape_changed ? sf.mndr > 0 && sf.andr > 0 : sf.mndr == 0);
    T_TRUE(sf.andr <= sf.mndr);
    struct job_row sl, no;
    T_OK(job_get(slimmed, &sl, &err), &err);
    T_OK(job_get(abs, &no, &err), &err);
    T_TRUE(!no.dev_measured);
    T_TRUE(sl.dev_measured);
    T_OK(store_check(synced(), &err), &err);
    teardown();
}

/*
 * A slimming that fails does not fail the job (prepare.h): it is prepared
 * from the part as oriented, records the shape as unchanged, and its
 * prepared event says why.  Slimming fails for real here: a 0 mm deviation
 * budget is a valid job option that slim_optimize refuses.
 */
T_CASE(farm_prepares_the_oriented_part_when_slimming_fails)
{
    struct sf_err err;
    T_OK(setup("slimfail", farm_ini, NULL, prepare_part, &err), &err);
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.method, sizeof(o.method), "slim");
    snprintf(o.name, sizeof(o.name), "part.stl");
    snprintf(o.material, sizeof(o.material), "PLA");
    o.deviation_mm = 0;
    char sha[STORE_SHA_HEX];
    int64_t id = 0;
    T_OK(store_file_put(fx.s, tetra_stl, strlen(tetra_stl), sha, &err), &err);
    T_OK(store_job_add(fx.s, &o, sha, &id, &err), &err);
    farm_kick(fx.f);
    T_TRUE(wait_job(id, JOB_READY));
    struct job_row j;
    T_OK(job_get(id, &j, &err), &err);
    T_TRUE(j.gcode_sha[0] && j.gcode_lines > 0);
    T_TRUE(j.dev_measured && !j.shape_changed);
    T_EQ_DBL(j.mndr, 0, 0);
    T_TRUE(strstr(j.reason, "slimming") == NULL); /* the reason is why it waits */
    struct event_row *ev;
    size_t n;
    T_OK(store_events(synced(), 0, 1000, &ev, &n, &err), &err);
    const char *detail = NULL;
    for (size_t i = 0; i < n; i++)
        if (ev[i].job_id == id && strcmp(ev[i].kind, "job-prepared") == 0)
            detail = ev[i].detail;
    T_TRUE(detail != NULL);
    printf("    job-prepared: %s\n", detail ? detail : "(none)");
    T_TRUE(detail && strstr(detail, "-> ready: slimming failed (slim: deviation limits must be "
                                    "positive): printed as oriented, unchanged") != NULL);
    free(ev);
    T_OK(store_check(synced(), &err), &err);
    teardown();
}

T_CASE(farm_missing_profile_fails_the_job_naming_the_file)
{
    struct sf_err err;
    static const char ini[] = "[printer a]\ndriver: marlin\nport: x\nprofile: nosuch\n";
    T_OK(setup("profile", ini, NULL, prepare_part, &err), &err);
    int64_t id = add(tetra_stl, "", 1);
    T_TRUE(wait_job(id, JOB_FAILED));
    struct job_row j;
    T_OK(job_get(id, &j, &err), &err);
    T_TRUE(strstr(j.reason, "profile 'nosuch' not found (config/printers/nosuch.cfg)") != NULL);
    teardown();
}

T_CASE(farm_progress_is_persisted_and_survives_a_crash)
{
    struct sf_err err;
    T_OK(setup("crash", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    int64_t id = add("size 20 20 20", "PLA", 1);
    T_TRUE(wait_job(id, JOB_PRINTING));
    struct tdrv *a = tdrv_named("a");
    a->base.status.lines_acked = 1234;
    report(a, DRV_PRINTING, DRV_EV_PROGRESS);
    for (int i = 0; i < 20; i++)
        loop_run_once(fx.l, 10); /* a few progress periods */
    struct job_row j;
    T_OK(job_get(id, &j, &err), &err);
    T_EQ_INT(j.lines_acked, 1234);
    /* the daemon stops here (a kill -9 is farm_bed_gate_survives_stop_and_kill's):
       the store is reopened as on restart */
    char dir[512];
    snprintf(dir, sizeof(dir), "%s/crash", t_tmpdir());
    teardown();
    struct store_recovery rec;
    struct store *s = t_store_open(dir, &rec, &err);
    T_TRUE(s != NULL);
    T_OK(store_job_get(s, id, &j, &err), &err);
    T_EQ_INT(j.state, JOB_INTERRUPTED);
    T_EQ_INT(j.lines_acked, 1234);
    T_EQ_STR(j.printer, "a");
    T_OK(store_check(s, &err), &err);
    store_close(s);
}

/*
 * Progress 16 lines or more ahead of the store is saved when the driver
 * reports it, not only on the farm's timer (1 s by default): a resume after
 * a kill -9 re-ran up to a second of lines.  The timer here never fires.
 */
T_CASE(farm_progress_is_saved_within_16_lines)
{
    struct sf_err err;
    setup_progress_ms = 3600 * 1000;
    T_OK(setup("savelines", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    int64_t id = add("size 20 20 20", "PLA", 1);
    T_TRUE(wait_job(id, JOB_PRINTING));
    struct tdrv *a = tdrv_named("a");
    struct job_row j;
    a->base.status.lines_acked = 15;
    report(a, DRV_PRINTING, DRV_EV_PROGRESS);
    for (int i = 0; i < 3; i++)
        loop_run_once(fx.l, 10);
    T_OK(job_get(id, &j, &err), &err);
    T_EQ_INT(j.lines_acked, 0); /* under 16 lines: the timer's */
    a->base.status.lines_acked = 16;
    report(a, DRV_PRINTING, DRV_EV_PROGRESS);
    for (int i = 0; i < 3; i++)
        loop_run_once(fx.l, 10);
    T_OK(job_get(id, &j, &err), &err);
    T_EQ_INT(j.lines_acked, 16);
    a->base.status.lines_acked = 40;
    report(a, DRV_PRINTING, DRV_EV_PROGRESS);
    for (int i = 0; i < 3; i++)
        loop_run_once(fx.l, 10);
    T_OK(job_get(id, &j, &err), &err);
    T_EQ_INT(j.lines_acked, 40);
    teardown();
}

T_CASE(farm_reload_adds_and_removes_printers)
{
    struct sf_err err;
    T_OK(setup("reload", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    int64_t id = add("size 20 20 20", "PLA", 1);
    T_TRUE(wait_job(id, JOB_PRINTING));
    /* a (printing) leaves the config, c arrives, b changes material */
    static const char next[] = "[printer b]\ndriver: marlin\nport: pty:/dev/null\n"
                               "material: ABS\nbed_size: 300, 300, 300\n"
                               "[printer c]\ndriver: marlin\nport: pty:/dev/null\n";
    struct farmcfg c2;
    farmcfg_init(&c2);
    T_OK(farmcfg_parse(&c2, next, strlen(next), "next.ini", &err), &err);
    T_OK(farm_reload(fx.f, &c2, &err), &err);
    T_EQ_INT(farm_printer_count(fx.f), 3); /* a stays until its print ends */
    struct printer_info info;
    farm_printer_info(fx.f, 1, &info);
    T_EQ_STR(info.cfg->material, "ABS");
    T_EQ_INT(state_of(id), JOB_PRINTING); /* undisturbed */
    report(tdrv_named("a"), DRV_IDLE, DRV_EV_JOB_DONE);
    T_TRUE(wait_job(id, JOB_DONE));
    T_OK(farm_reload(fx.f, &c2, &err), &err);
    T_EQ_INT(farm_printer_count(fx.f), 2);
    farm_printer_info(fx.f, 0, &info);
    T_EQ_STR(info.cfg->name, "b");
    farmcfg_release(&c2);
    teardown();
}

/* Printer name's info; false if the farm has none of that name. */
static bool
info_of(const char *name, struct printer_info *out)
{
    for (size_t i = 0; i < farm_printer_count(fx.f); i++) {
        farm_printer_info(fx.f, i, out);
        if (strcmp(out->cfg->name, name) == 0)
            return true;
    }
    return false;
}

/*
 * Printers managed at run time (farm.h) over farm.ini's: an added printer
 * comes after farm.ini's; an edited one runs on the API's options, and a
 * disabled or removed one stays so, whatever a reload or a restart of
 * farm.ini says; a disable keeps farm.ini's options.  Refusals name why.
 */
T_CASE(farm_runtime_printers_win_over_farm_ini)
{
    struct sf_err err;
    struct printer_info info;
    T_OK(setup("runtime", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    T_OK(farm_printer_add(fx.f, "c", "driver: marlin\nport: pty:/dev/null\nmaterial: ABS\n", &err),
         &err);
    T_OK(farm_printer_edit(fx.f, "a", "driver: marlin\nport: pty:/dev/null\nmaterial: TPU\n", &err),
         &err);
    T_OK(farm_printer_disable(fx.f, "b", "belt worn", &err), &err);
    T_EQ_INT(farm_printer_add(fx.f, "c", "driver: marlin\nport: x\n", &err), SF_EAGAIN);
    T_EQ_INT(farm_printer_edit(fx.f, "zz", "driver: marlin\nport: x\n", &err), SF_ENOTFOUND);
    T_EQ_INT(farm_printer_add(fx.f, "d", "driver: marlin\n", &err), SF_EINVAL);
    T_EQ_STR(err.msg, "section 'printer d': option 'port' is required by driver marlin");
    T_EQ_INT(farm_printer_disable(fx.f, "a", "", &err), SF_EINVAL);
    /* farm.ini changes a and b: a stays the API's, b takes farm.ini's options, still disabled */
    static const char next[] =
        "[printer a]\ndriver: marlin\nport: pty:/dev/null\nmaterial: PLA\n"
        "[printer b]\ndriver: marlin\nport: pty:/dev/null\nmaterial: NYLON\n";
    struct farmcfg c2;
    farmcfg_init(&c2);
    T_OK(farmcfg_parse(&c2, next, strlen(next), "next.ini", &err), &err);
    T_OK(farm_reload(fx.f, &c2, &err), &err);
    T_EQ_INT(farm_printer_count(fx.f), 3);
    farm_printer_info(fx.f, 2, &info);
    T_EQ_STR(info.cfg->name, "c"); /* after farm.ini's */
    T_TRUE(info_of("a", &info) && strcmp(info.cfg->material, "TPU") == 0);
    T_TRUE(info_of("b", &info) && strcmp(info.cfg->material, "NYLON") == 0);
    T_TRUE(!info.cfg->enabled && strcmp(info.cfg->disabled, "belt worn") == 0);
    T_TRUE(strstr(info.message, "disabled: belt worn") != NULL);
    /* a farm.ini printer removed stays removed; a restart over the same store agrees */
    T_OK(farm_printer_remove(fx.f, "a", &err), &err);
    T_TRUE(!info_of("a", &info));
    T_OK(farm_reload(fx.f, &c2, &err), &err);
    T_TRUE(!info_of("a", &info));
    farmcfg_release(&c2);
    teardown();
    T_OK(setup("runtime", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_EQ_INT(farm_printer_count(fx.f), 2);
    T_TRUE(!info_of("a", &info) && info_of("c", &info));
    T_TRUE(info_of("b", &info) && !info.cfg->enabled);
    T_EQ_STR(info.cfg->material, "PETG"); /* farm.ini's at this start */
    T_OK(farm_printer_enable(fx.f, "b", &err), &err);
    T_TRUE(info_of("b", &info) && info.cfg->enabled && !info.cfg->disabled[0]);
    T_OK(farm_printer_add(fx.f, "a", "driver: marlin\nport: pty:/dev/null\n", &err), &err);
    T_TRUE(info_of("a", &info)); /* added again: back */
    teardown();
}

/* Printer i's message holds what. */
static bool
message_has(size_t i, const char *what)
{
    struct printer_info info;
    farm_printer_info(fx.f, i, &info);
    return info.message && strstr(info.message, what);
}

/* Reload the farm with text (the new farm.ini); the config is kept in *c. */
static int
reload_with(struct farmcfg *c, const char *text, struct sf_err *err)
{
    farmcfg_init(c);
    int rc = farmcfg_parse(c, text, strlen(text), "farm.ini", err);
    return rc ? rc : farm_reload(fx.f, c, err);
}

/*
 * A PrusaLink printer on HTTP Digest whose password changes in farm.ini:
 * the reload must hand the new one to the driver (it used to compare only
 * driver, port, baud, url, api_key and enabled, so the driver kept the old
 * password while the config showed the new one).  The simulator takes only
 * the new password: the printer is refused, then comes online.
 */
T_CASE(farm_reload_gives_the_driver_a_changed_password)
{
    struct sf_err err;
    T_OK(setup("reload-pw", "", drv_new, test_prepare, &err), &err);
    struct sim_prusalink_config sc;
    sim_prusalink_config_init(&sc);
    sc.user = "maker";
    sc.password = "new-pw";
    struct sim_prusalink *sim = sim_prusalink_new(fx.l, &sc, &err);
    T_TRUE(sim != NULL);
    char ini[2][512];
    for (int i = 0; i < 2; i++)
        snprintf(ini[i], sizeof(ini[i]),
                 "[printer mk4]\ndriver: prusalink\nurl: http://127.0.0.1:%d\nuser: maker\n"
                 "password: %s\nmaterial: PLA\nbed_size: 250, 210, 220\n",
                 sim_prusalink_port(sim), i ? "new-pw" : "old-pw");
    struct farmcfg c1, c2;
    T_OK(reload_with(&c1, ini[0], &err), &err);
    T_EQ_INT(farm_printer_count(fx.f), 1);
    /* the old password is refused */
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS;
         wall_ms() < end && !message_has(0, "authentication failed");)
        loop_run_once(fx.l, 10);
    T_TRUE(message_has(0, "authentication failed"));
    T_EQ_INT(pstate(0), PRINTER_OFFLINE);
    /* SIGHUP's path: the new farm.ini, only the password changed */
    T_OK(reload_with(&c2, ini[1], &err), &err);
    T_EQ_INT(farm_printer_count(fx.f), 1);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    T_TRUE(!message_has(0, "authentication failed"));
    /* the same config again: nothing changed, the printer stays connected */
    struct printer_info before, after;
    farm_printer_info(fx.f, 0, &before);
    struct farmcfg c3;
    T_OK(reload_with(&c3, ini[1], &err), &err);
    farm_printer_info(fx.f, 0, &after);
    T_TRUE(before.cfg == after.cfg); /* the same printer, not a fresh one */
    T_EQ_INT(after.state, PRINTER_IDLE);
    sim_prusalink_free(sim);
    farmcfg_release(&c1);
    farmcfg_release(&c2);
    farmcfg_release(&c3);
    teardown();
}

/* ---- a job's G-code runs only on a printer it was prepared for ---- */

/* prepare_part, counting the preparations that reused an optimized part */
static atomic_int reused;

static int
counting_prepare(const struct prepare_req *req, struct prepare_out *out, const atomic_bool *cancel,
                 struct sf_err *err)
{
    atomic_fetch_add(&prepares, 1);
    if (req->mesh_in[0])
        atomic_fetch_add(&reused, 1);
    return prepare_part(req, out, cancel, err);
}

/* An 80 x 80 x 4 mm plate (ASCII STL, 12 facets). */
static void
plate_stl(char *buf, size_t cap)
{
    static const double v[8][3] = { { 0, 0, 0 }, { 80, 0, 0 }, { 80, 80, 0 }, { 0, 80, 0 },
                                    { 0, 0, 4 }, { 80, 0, 4 }, { 80, 80, 4 }, { 0, 80, 4 } };
    static const int f[12][3] = { { 0, 2, 1 }, { 0, 3, 2 }, { 4, 5, 6 }, { 4, 6, 7 },
                                  { 0, 1, 5 }, { 0, 5, 4 }, { 1, 2, 6 }, { 1, 6, 5 },
                                  { 2, 3, 7 }, { 2, 7, 6 }, { 3, 0, 4 }, { 3, 4, 7 } };
    size_t n = (size_t)snprintf(buf, cap, "solid plate\n");
    for (int i = 0; i < 12; i++) {
        n += (size_t)snprintf(buf + n, cap - n, "facet normal 0 0 0\nouter loop\n");
        for (int k = 0; k < 3; k++)
            n += (size_t)snprintf(buf + n, cap - n, "vertex %g %g %g\n", v[f[i][k]][0],
                                  v[f[i][k]][1], v[f[i][k]][2]);
        n += (size_t)snprintf(buf + n, cap - n, "endloop\nendfacet\n");
    }
    snprintf(buf + n, cap - n, "endsolid plate\n");
}

/* Copy a file, replacing the first `from` with `to` (NULL: a plain copy). */
static int
copy_with(const char *src, const char *dst, const char *from, const char *to, struct sf_err *err)
{
    struct buf b;
    buf_init(&b, 1 << 20);
    int rc = buf_read_file(&b, src, err);
    if (rc)
        return rc;
    FILE *f = fopen(dst, "w");
    if (!f) {
        buf_release(&b);
        return sf_err_sys(err, "cannot write '%s'", dst);
    }
    const char *at = from ? strstr(b.data, from) : NULL;
    if (at)
        fprintf(f, "%.*s%s%s", (int)(at - b.data), b.data, to, at + strlen(from));
    else
        fputs(b.data, f);
    fclose(f);
    buf_release(&b);
    return from && !at ? sf_err_set(err, SF_EINVAL, "'%s' has no '%s'", src, from) : SF_OK;
}

/*
 * Two printer profiles made from config/'s generic one, each with its own
 * start G-code line ("M117 start NAME"), and a farm of two printers of
 * equal nozzle and material: big (300x300 bed) and small (180x180).
 */
static int
mixed_setup(const char *name, const char *hold, struct sf_err *err)
{
    char dir[600], path[700], ini[2048];
    snprintf(dir, sizeof(dir), "%s/%s-profiles", t_tmpdir(), name);
    const char *sub[] = { "", "/printers", "/materials" };
    for (int i = 0; i < 3; i++) {
        snprintf(path, sizeof(path), "%s%s", dir, sub[i]);
        if (mkdir(path, 0700) && errno != EEXIST)
            return sf_err_sys(err, "mkdir '%s'", path);
    }
    const char *names[] = { "wide", "narrow" };
    for (int i = 0; i < 2; i++) {
        char to[128];
        snprintf(path, sizeof(path), "%s/printers/%s.cfg", dir, names[i]);
        snprintf(to, sizeof(to), "G1 Z5 F3000\n    M117 start %s", names[i]);
        int rc = copy_with("config/printers/generic-marlin.cfg", path, "G1 Z5 F3000", to, err);
        if (rc)
            return rc;
    }
    snprintf(path, sizeof(path), "%s/materials/pla.cfg", dir);
    int rc = copy_with("config/materials/pla.cfg", path, NULL, NULL, err);
    if (rc)
        return rc;
    snprintf(ini, sizeof(ini),
             "[farm]\nprofiles_dir: %s\n"
             "[printer big]\ndriver: marlin\nport: pty:/dev/null\nprofile: wide\n"
             "bed_size: 300, 300, 250\n"
             "[printer small]\ndriver: marlin\nport: pty:/dev/null\nprofile: narrow\n"
             "bed_size: 180, 180, 180\n",
             dir);
    atomic_store(&prepares, 0);
    atomic_store(&reused, 0);
    setup_held = hold;
    return setup(name, ini, tdrv_new, counting_prepare, err);
}

/*
 * The G-code file a printer was given runs on it: every X/Y it moves to
 * lies on its bed, and its start G-code is the one of its profile.
 */
static bool
printed_for(const char *printer, const char *profile, double bed_x, double bed_y)
{
    struct tdrv *t = tdrv_named(printer);
    struct buf g;
    buf_init(&g, 64 << 20);
    struct sf_err err;
    if (!t || !t->starts || buf_read_file(&g, t->path, &err)) {
        t_fail(__FILE__, __LINE__, "%s printed nothing", printer);
        return false;
    }
    char marker[64];
    snprintf(marker, sizeof(marker), "M117 start %s\n", profile);
    bool ok = strstr(g.data, marker) != NULL;
    double lo[2] = { 1e9, 1e9 }, hi[2] = { -1e9, -1e9 };
    for (char *line = g.data, *nl; line && *line; line = nl ? nl + 1 : NULL) {
        nl = strchr(line, '\n');
        if (strncmp(line, "G0 ", 3) != 0 && strncmp(line, "G1 ", 3) != 0)
            continue;
        for (char *w = line; w && w < (nl ? nl : line + strlen(line)); w = strchr(w + 1, ' ')) {
            char axis = w[0] == ' ' ? w[1] : w[0];
            if (axis != 'X' && axis != 'Y')
                continue;
            double v = strtod(w + (w[0] == ' ' ? 2 : 1), NULL);
            int a = axis == 'Y';
            lo[a] = v < lo[a] ? v : lo[a];
            hi[a] = v > hi[a] ? v : hi[a];
        }
    }
    buf_release(&g);
    if (!ok || lo[0] < 0 || lo[1] < 0 || hi[0] > bed_x || hi[1] > bed_y) {
        t_fail(__FILE__, __LINE__,
               "%s (bed %gx%g, profile %s) got G-code %s its start, moving over X %g..%g, "
               "Y %g..%g",
               printer, bed_x, bed_y, profile, ok ? "with" : "without", lo[0], hi[0], lo[1], hi[1]);
        return false;
    }
    return true;
}

static int64_t
add_plate(void)
{
    static char plate[4096];
    plate_stl(plate, sizeof(plate));
    return add(plate, "", 1);
}

/*
 * Issue 15's bug: a job prepared for one printer was started on another
 * with the same nozzle whose bed was large enough (an 80 mm plate centred
 * for a 300 mm bed printed on a 180 mm one, moving to X/Y 190).  Each file
 * must print where it was sliced for, and both printers get work.
 */
T_CASE(farm_mixed_profiles_print_each_file_inside_its_printers_bed)
{
    struct sf_err err;
    T_OK(mixed_setup("mixed", NULL, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE) && wait_printer(1, PRINTER_IDLE));
    int64_t j1 = add_plate(), j2 = add_plate();
    T_TRUE(wait_job(j1, JOB_PRINTING));
    for (int i = 0; i < 3000 && !(state_of(j2) == JOB_PRINTING && drivers_started()); i++)
        loop_run_once(fx.l, 10);
    T_EQ_INT(state_of(j2), JOB_PRINTING);
    T_EQ_INT(tdrv_named("big")->starts, 1);
    T_EQ_INT(tdrv_named("small")->starts, 1);
    T_TRUE(printed_for("big", "wide", 300, 300));
    T_TRUE(printed_for("small", "narrow", 180, 180));
    T_OK(store_check(synced(), &err), &err);
    teardown();
}

/*
 * A job prepared for a busy printer moves to an idle printer of another
 * profile by being sliced again for it; the part keeps the orientation it
 * was given (the optimized mesh is reused, not computed again).
 */
T_CASE(farm_job_waiting_for_a_busy_printer_is_resliced_for_an_idle_one)
{
    struct sf_err err;
    T_OK(mixed_setup("reslice", "small", &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    int64_t j1 = add_plate();
    T_TRUE(wait_job(j1, JOB_PRINTING)); /* big is busy from now on */
    int64_t j2 = add_plate();
    T_TRUE(wait_job(j2, JOB_READY));
    struct job_row before, after;
    T_OK(job_get(j2, &before, &err), &err);
    T_TRUE(strncmp(before.prep_key, "wide/", 5) == 0);
    T_TRUE(before.mesh_sha[0] != '\0');
    for (int i = 0; i < 5; i++)
        loop_run_once(fx.l, 10);
    T_EQ_INT(state_of(j2), JOB_READY); /* waits for big: small is offline */
    T_EQ_INT(atomic_load(&prepares), 2);
    /* small comes up */
    struct tdrv *small = tdrv_named("small");
    report(small, DRV_IDLE, DRV_EV_STATE);
    for (int i = 0; i < 3000 && !(state_of(j2) == JOB_PRINTING && drivers_started()); i++)
        loop_run_once(fx.l, 10);
    T_EQ_INT(state_of(j2), JOB_PRINTING);
    T_EQ_INT(small->starts, 1);
    T_TRUE(printed_for("small", "narrow", 180, 180));
    T_OK(job_get(j2, &after, &err), &err);
    T_TRUE(strncmp(after.prep_key, "narrow/", 7) == 0);
    T_EQ_STR(after.printer, "small");
    T_TRUE(strcmp(after.gcode_sha, before.gcode_sha) != 0);
    /* sliced again from the part as oriented for big: no second optimization */
    T_EQ_INT(atomic_load(&prepares), 3);
    T_EQ_INT(atomic_load(&reused), 1);
    T_EQ_STR(after.mesh_sha, before.mesh_sha);
    T_TRUE(printed_for("big", "wide", 300, 300));
    T_OK(store_check(synced(), &err), &err);
    teardown();
}

/* ---- stops and restarts (issue 16) ---- */

/*
 * SIGTERM mid-print: the job is left interrupted at its last acknowledged
 * line, exactly as after a crash, with no retry spent and no requeue from
 * line 0 (it used to be "printer went offline": failed into a retry).
 */
T_CASE(farm_stop_mid_print_leaves_the_job_interrupted_at_its_line)
{
    struct sf_err err;
    T_OK(setup("stop", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    int64_t id = add("size 20 20 20", "PLA", 1);
    T_TRUE(wait_job(id, JOB_PRINTING));
    struct tdrv *a = tdrv_named("a");
    a->base.status.lines_acked = 777;
    report(a, DRV_PRINTING, DRV_EV_PROGRESS);
    while (a->has_pending)
        loop_run_once(fx.l, 10);
    teardown(); /* the daemon's stop: farm_free closes the drivers */
    char dir[512];
    snprintf(dir, sizeof(dir), "%s/stop", t_tmpdir());
    struct store_recovery rec;
    struct store *s = t_store_open(dir, &rec, &err);
    T_TRUE(s != NULL);
    T_EQ_INT(rec.interrupted, 0); /* the stop did it already */
    struct job_row j;
    T_OK(store_job_get(s, id, &j, &err), &err);
    T_EQ_INT(j.state, JOB_INTERRUPTED);
    T_EQ_INT(j.lines_acked, 777);
    T_EQ_INT(j.counts.failures, 0);
    T_EQ_STR(j.printer, "a");
    struct print_row *p;
    size_t n;
    T_OK(store_prints(s, id, &p, &n, &err), &err);
    T_EQ_INT(n, 1);
    T_EQ_STR(p[0].outcome, "interrupted");
    T_EQ_INT(p[0].lines_acked, 777);
    free(p);
    T_OK(store_check(s, &err), &err);
    store_close(s);
}

/* Print one job to the end on printer a (no ejector): its bed holds the part. */
static bool
finish_one_on_a(void)
{
    if (!wait_printer(0, PRINTER_IDLE))
        return false;
    int64_t id = add("size 20 20 20", "PLA", 1);
    if (!wait_job(id, JOB_PRINTING))
        return false;
    report(tdrv_named("a"), DRV_IDLE, DRV_EV_JOB_DONE);
    return wait_job(id, JOB_DONE) && wait_printer(0, PRINTER_AWAITING_CLEAR);
}

/* After a restart: a stays awaiting clear and starts nothing until cleared. */
static void
check_bed_gate_kept(void)
{
    T_TRUE(wait_printer(0, PRINTER_AWAITING_CLEAR));
    int64_t next = add("size 20 20 20", "PLA", 1);
    T_TRUE(wait_job(next, JOB_READY));
    for (int i = 0; i < 10; i++)
        loop_run_once(fx.l, 10);
    T_EQ_INT(tdrv_named("a")->starts, 0);
    T_EQ_INT(state_of(next), JOB_READY);
    struct sf_err err;
    T_OK(farm_printer_action(fx.f, "a", PRINTER_ACT_CLEARED, &err), &err);
    T_TRUE(wait_job(next, JOB_PRINTING));
}

/*
 * A printer awaiting bed clear comes back from a stop (SIGTERM) and from a
 * kill -9 awaiting clear: the finished part is still on the bed.  It used
 * to come back offline -> idle and start the next job on top of it.
 */
T_CASE(farm_bed_gate_survives_stop_and_kill)
{
    struct sf_err err;
    T_OK(setup("bedstop", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(finish_one_on_a());
    teardown();
    T_OK(setup("bedstop", farm_ini, tdrv_new, test_prepare, &err), &err);
    check_bed_gate_kept();
    teardown();

    pid_t pid = fork();
    T_TRUE(pid >= 0);
    if (pid == 0) {
        if (setup("bedkill", farm_ini, tdrv_new, test_prepare, &err) || !finish_one_on_a())
            _exit(1);
        raise(SIGKILL);
        _exit(2);
    }
    int status;
    T_EQ_INT(waitpid(pid, &status, 0), pid);
    T_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL);
    T_OK(setup("bedkill", farm_ini, tdrv_new, test_prepare, &err), &err);
    check_bed_gate_kept();
    teardown();
}

/*
 * Issue 29: manual commands only on an idle printer with a clear bed (a
 * move on a finished part, or in error, is refused as "not now"), never
 * M110/M111 or control bytes; an operator's emergency stop puts the
 * printer in error and fails its job for good, although it has a retry
 * left (max_retries 1: a plain failure goes back to ready).
 */
T_CASE(farm_manual_commands_and_emergency_stop)
{
    struct sf_err err;
    T_OK(setup("estop", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_ERR(farm_printer_command(fx.f, "a", "M110 N1000", "key t", &err), SF_EINVAL, &err, "M110");
    T_ERR(farm_printer_command(fx.f, "a", " m111 S7", "key t", &err), SF_EINVAL, &err, "M111");
    T_ERR(farm_printer_command(fx.f, "a", "G28\x1b", "key t", &err), SF_EINVAL, &err, "0x1b");
    T_ERR(farm_printer_command(fx.f, "a", "M112", "key t", &err), SF_EINVAL, &err, "M112");
    T_TRUE(finish_one_on_a());
    T_ERR(farm_printer_command(fx.f, "a", "G1 Z0.2 F600", "key t", &err), SF_EAGAIN, &err,
          "awaiting-clear");
    T_OK(farm_printer_action(fx.f, "a", PRINTER_ACT_CLEARED, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    /* past the farm's gate: tdrv has no console */
    T_ERR(farm_printer_command(fx.f, "a", "G28", "key t", &err), SF_EUNSUPP, &err, "console");

    int64_t id = add("size 20 20 20", "PLA", 1);
    T_TRUE(wait_job(id, JOB_PRINTING));
    T_OK(farm_printer_estop(fx.f, "a", "key t", &err), &err);
    T_EQ_INT(state_of(id), JOB_FAILED);
    T_EQ_INT(pstate(0), PRINTER_ERROR);
    T_EQ_INT(tdrv_named("a")->cancels, 1); /* tdrv has no estop of its own: the job's cancel */
    struct job_row j;
    T_OK(job_get(id, &j, &err), &err);
    T_TRUE(strstr(j.reason, "emergency stop by an operator (key t)") != NULL);
    T_ERR(farm_printer_command(fx.f, "a", "G28", "key t", &err), SF_EAGAIN, &err, "error");
    for (int i = 0; i < 10; i++)
        loop_run_once(fx.l, 10);
    T_EQ_INT(state_of(id), JOB_FAILED);
    T_EQ_INT(tdrv_named("a")->starts, 2); /* no retry started */
    teardown();
}

/*
 * Issue 29, heaters: a printer hot with no print (found so after a
 * restart: a TCP bridge does not reset it) keeps its temperatures for
 * hold_heat_min, then the farm turns them off and says so; a job started
 * meanwhile keeps them.
 */
T_CASE(farm_heaters_off_after_hold_heat_min)
{
    struct sf_err err;
    static const char ini[] = "[printer a]\ndriver: marlin\nport: pty:/dev/null\n"
                              "material: PLA\nhold_heat_min: 0.005\n";
    T_OK(setup("heat", ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    t_console = true;
    t_sent[0] = '\0';
    struct tdrv *t = tdrv_named("a");
    t->base.status.nozzle_target_c = 210;
    t->base.status.bed_target_c = 60;
    report(t, DRV_IDLE, DRV_EV_TEMPS);
    for (int64_t end = wall_ms() + 200; wall_ms() < end;) /* 0.3 s hold: not yet */
        loop_run_once(fx.l, 10);
    T_EQ_STR(t_sent, "");
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS; wall_ms() < end && !t_sent[0];)
        loop_run_once(fx.l, 10);
    T_EQ_STR(t_sent, "M104 S0\nM140 S0\n");
    T_TRUE(message_has(0, "heaters off (were 210/60 C)"));
    t_console = false;
    teardown();
}

/* farm_gcode_check's answer: how many came. */
static int gchecks_done;

static void
on_gcheck(void *ud, int rc, const struct farm_gcode *g, const char *msg)
{
    (void)ud, (void)rc, (void)g, (void)msg;
    gchecks_done++;
}

/*
 * A start is committed, then its file judged on the io thread before the
 * driver has it.  A cancel in between cancels the job without the driver
 * (which has nothing to cancel: it answered "no job to cancel", 409, under
 * load in farmd_mr_history), the printer is idle again, and the judged
 * start that comes later sends nothing.  The io thread is held by an
 * upload check reading a FIFO until the test writes it.
 */
T_CASE(farm_cancel_while_the_start_is_judged)
{
    struct sf_err err;
    T_OK(setup("judged", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    char fifo[600];
    snprintf(fifo, sizeof(fifo), "%s/judged/hold.gcode", t_tmpdir());
    T_EQ_INT(mkfifo(fifo, 0600), 0);
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "hold.gcode");
    gchecks_done = 0;
    T_OK(farm_gcode_check(fx.f, fifo, &o, on_gcheck, NULL, &err), &err);
    int64_t id = add("size 20 20 20", "PLA", 1);
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS; wall_ms() < end && state_of(id) != JOB_PRINTING;)
        loop_run_once(fx.l, 10);
    T_EQ_INT(state_of(id), JOB_PRINTING);
    struct tdrv *a = tdrv_named("a");
    T_EQ_INT(a->starts, 0);
    T_OK(farm_printer_action(fx.f, "a", PRINTER_ACT_CANCEL, &err), &err);
    T_EQ_INT(state_of(id), JOB_CANCELLED);
    T_EQ_INT(pstate(0), PRINTER_IDLE);
    /* release the io thread (its later reads find a plain file there); a
       second check, queued after the start's, says that one ran */
    int w = open(fifo, O_WRONLY);
    T_TRUE(w >= 0 && unlink(fifo) == 0);
    FILE *plain = fopen(fifo, "w");
    T_TRUE(plain && fputs("G28\n", plain) >= 0 && fclose(plain) == 0);
    T_TRUE(write(w, "G28\n", 4) == 4);
    close(w);
    T_OK(farm_gcode_check(fx.f, fifo, &o, on_gcheck, NULL, &err), &err);
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS; wall_ms() < end && gchecks_done < 2;)
        loop_run_once(fx.l, 10);
    T_EQ_INT(gchecks_done, 2);
    T_EQ_INT(a->starts, 0);
    T_EQ_INT(pstate(0), PRINTER_IDLE);
    /* the printer takes the next job */
    int64_t next = add("size 20 20 20", "PLA", 1);
    T_TRUE(wait_job(next, JOB_PRINTING));
    T_EQ_INT(a->starts, 1);
    teardown();
}

/* Another process's hold on fixture `name`'s store (t_store_lock: SQLite's write lock, or
   its every table locked on PostgreSQL); NULL if it cannot. */
static struct sqldb *
lock_store(const char *name)
{
    char dir[600];
    snprintf(dir, sizeof(dir), "%s/%s", t_tmpdir(), name);
    return t_store_lock(dir);
}

static void
unlock_store(struct sqldb *other)
{
    t_store_unlock(other);
}

/*
 * The store is held busy by another process when a printer takes a job:
 * the printer takes it at once (the START waits on the store thread, the
 * loop goes on), the driver gets nothing until the START has committed,
 * then the print starts.  Before the store thread the START waited out the
 * busy timeout on the loop and failed, and the printer stayed idle.
 */
T_CASE(farm_start_commits_on_the_store_thread_before_the_driver_has_it)
{
    struct sf_err err;
    setup_held = "a";
    T_OK(setup("busystart", farm_ini, tdrv_new, test_prepare, &err), &err);
    int64_t id = add("size 20 20 20", "PLA", 1);
    T_TRUE(wait_job(id, JOB_READY)); /* a is not connected yet */
    struct sqldb *other = lock_store("busystart");
    T_TRUE(other != NULL);
    watch_job = id;
    start_saw = -1;
    struct tdrv *a = tdrv_named("a");
    report(a, DRV_IDLE, DRV_EV_STATE);
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS; wall_ms() < end && pstate(0) != PRINTER_PRINTING;)
        loop_run_once(fx.l, 10);
    T_EQ_INT(pstate(0), PRINTER_PRINTING); /* taken while the store is locked */
    T_EQ_INT(a->starts, 0);
    struct job_row j;
    T_OK(store_job_get(fx.s, id, &j, &err), &err); /* a read: WAL lets it through */
    T_EQ_INT(j.state, JOB_READY);                  /* its START waits on the store thread */
    unlock_store(other);
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS; wall_ms() < end && a->starts == 0;)
        loop_run_once(fx.l, 10);
    T_EQ_INT(a->starts, 1);
    T_EQ_INT(start_saw, JOB_PRINTING); /* committed before the driver had it */
    watch_job = 0;
    T_TRUE(wait_job(id, JOB_PRINTING));
    T_OK(store_check(synced(), &err), &err);
    teardown();
}

/* ---- the loop does not wait for a locked store (issue 32) ---- */

/* Answers to operator actions, in the order they came. */
static struct {
    int n;
    char tag[4];
    int rc[4];
} answers;

static void
on_answer(void *ud, const struct storeq_result *r)
{
    if (answers.n < 4) {
        answers.tag[answers.n] = *(const char *)ud;
        answers.rc[answers.n] = r->rc;
    }
    answers.n++;
}

/*
 * An operator's pause and cancel while another process holds the store's
 * write lock: the printer acts at once (the driver paused, then cancelled,
 * the loop never waits), the answers come once the lock goes, in order,
 * each with the store's verdict, and the job is paused then cancelled once
 * each.  Before (printer_job_commit) the pause waited 250 ms for the queue,
 * then was refused "the store is busy" with the driver paused already.
 */
T_CASE(farm_operator_actions_go_on_while_the_store_is_locked)
{
    struct sf_err err;
    T_OK(setup("busyop", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    int64_t id = add("size 20 20 20", "PLA", 1);
    T_TRUE(wait_job(id, JOB_PRINTING));
    struct tdrv *a = tdrv_named("a");
    memset(&answers, 0, sizeof(answers));
    struct sqldb *other = lock_store("busyop");
    T_TRUE(other != NULL);
    /* the plain action (no answer wanted) is taken at once too */
    T_OK(farm_printer_action(fx.f, "a", PRINTER_ACT_PAUSE, &err), &err);
    T_EQ_INT(pstate(0), PRINTER_PAUSED);
    T_EQ_INT(a->pauses, 1);
    T_OK(farm_printer_action_then(fx.f, "a", PRINTER_ACT_RESUME, on_answer, "r", &err), &err);
    T_OK(farm_printer_action_then(fx.f, "a", PRINTER_ACT_CANCEL, on_answer, "c", &err), &err);
    T_EQ_INT(a->resumes, 1);
    T_EQ_INT(a->cancels, 1);
    for (int i = 0; i < 20; i++)
        loop_run_once(fx.l, 10);
    T_EQ_INT(answers.n, 0); /* nothing committed while the lock is held */
    struct job_row j;
    T_OK(store_job_get(fx.s, id, &j, &err), &err); /* a read: WAL lets it through */
    T_EQ_INT(j.state, JOB_PRINTING);
    unlock_store(other);
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS; wall_ms() < end && answers.n < 2;)
        loop_run_once(fx.l, 10);
    T_EQ_INT(answers.n, 2);
    T_EQ_INT(answers.tag[0], 'r');
    T_EQ_INT(answers.tag[1], 'c');
    T_EQ_INT(answers.rc[0], SF_OK);
    T_EQ_INT(answers.rc[1], SF_OK);
    T_EQ_INT(state_of(id), JOB_CANCELLED);
    struct print_row *p;
    size_t n;
    T_OK(store_prints(synced(), id, &p, &n, &err), &err);
    T_EQ_INT(n, 1); /* one print, cancelled once */
    T_EQ_STR(p[0].outcome, "cancelled");
    free(p);
    T_OK(store_check(synced(), &err), &err);
    teardown();
}

/* The prepare hook takes the store's write lock from a second connection as it ends, so the
   prepare's records (its files, PREPARED) meet a locked store. */
static struct sqldb *_Atomic prep_lock;

static int
locking_prepare(const struct prepare_req *req, struct prepare_out *out, const atomic_bool *cancel,
                struct sf_err *err)
{
    int rc = test_prepare(req, out, cancel, err);
    if (!atomic_load(&prep_lock))
        atomic_store(&prep_lock, lock_store("busyprep"));
    return rc;
}

/*
 * A prepare that ends while another process holds the store's write lock
 * waits for it on the store thread and the job is ready once the lock
 * goes.  Before, the G-code's record (store_file_record on the loop) waited
 * out SQLite's busy timeout on the loop, then failed the job for good
 * (PREPARE_FAILED) for a lock that was only passing.  On PostgreSQL the
 * worker's upload of the G-code meets the lock (its lock timeout): it was
 * SF_EIO, the job failed; busy now, the job goes back to the queue.
 */
T_CASE(farm_prepare_waits_out_a_locked_store_instead_of_failing_the_job)
{
    struct sf_err err;
    atomic_store(&prep_lock, NULL);
    setup_held = "a"; /* the job is prepared for a, not started */
    T_OK(setup("busyprep", farm_ini, tdrv_new, locking_prepare, &err), &err);
    T_TRUE(wait_printer(1, PRINTER_IDLE));
    synced(); /* the printers' states are written: what waits under the lock is the prepare's */
    int64_t id = add("size 20 20 20", "PLA", 1);
    struct farm_health h = { 0 };
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS;
         wall_ms() < end && (!atomic_load(&prep_lock) || h.store.depth == 0);) {
        loop_run_once(fx.l, 10);
        farm_health(fx.f, &h);
    }
    struct sqldb *other = atomic_load(&prep_lock);
    T_TRUE(other != NULL);
    T_TRUE(h.store.depth > 0); /* the prepare's end waits for the store */
    unlock_store(other);
    T_EQ_INT(wait_job_or_failure(id, JOB_READY), JOB_READY);
    T_OK(store_check(synced(), &err), &err);
    teardown();
}

/* The first prepare's worker cannot adopt its G-code into the store: the database is not
   reachable that moment (sqldb_open's SF_EUNREACH, PostgreSQL restarting). */
static atomic_int unreachable_calls;

static int
unreachable_prepare(const struct prepare_req *req, struct prepare_out *out,
                    const atomic_bool *cancel, struct sf_err *err)
{
    int rc = test_prepare(req, out, cancel, err);
    if (rc == SF_OK && atomic_fetch_add(&unreachable_calls, 1) == 0)
        return sf_err_set(err, SF_EUNREACH,
                          "store: cannot connect to 'postgresql:///farm': Connection refused");
    return rc;
}

/*
 * A worker that finds the store's database unreachable fails nothing: the
 * job goes back to the queue (DEFER) and is prepared again.  Before, the
 * blip failed the job for good (PREPARE_FAILED).
 */
T_CASE(farm_prepare_defers_when_the_database_is_unreachable)
{
    struct sf_err err;
    atomic_store(&unreachable_calls, 0);
    int before = atomic_load(&prepares);
    T_OK(setup("unreach", farm_ini, tdrv_new, unreachable_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    int64_t id = add("size 20 20 20", "PLA", 1);
    T_EQ_INT(wait_job_or_failure(id, JOB_PRINTING), JOB_PRINTING);
    T_EQ_INT(atomic_load(&prepares) - before, 2); /* prepared again, once */
    struct job_row j;
    T_OK(job_get(id, &j, &err), &err);
    T_EQ_INT(j.counts.failures, 0);
    teardown();
}

/* The prepare hook takes the store's write lock as it ends, as locking_prepare, on "rewrite". */
static int
locking_prepare_rewrite(const struct prepare_req *req, struct prepare_out *out,
                        const atomic_bool *cancel, struct sf_err *err)
{
    int rc = test_prepare(req, out, cancel, err);
    if (!atomic_load(&prep_lock))
        atomic_store(&prep_lock, lock_store("rewrite"));
    return rc;
}

/*
 * A PREPARED the store thread could not write in its retry window (the
 * lock held past it: SF_EBUSY, as SF_EUNREACH or SF_EINDOUBT would come
 * back) is written again, and the job is ready once the lock goes.
 * Before, it was answered with a DEFER, which met the same lock and was
 * lost too: the job stayed preparing until the next restart.  On PostgreSQL
 * the G-code's upload meets the lock first, so the job's DEFER is what the
 * store gives up on: written again too (farm_prep_end), the job queued and
 * prepared again once the lock goes.
 */
T_CASE(farm_prepared_is_written_again_after_the_store_gave_up)
{
    struct sf_err err;
    atomic_store(&prep_lock, NULL);
    setup_held = "a"; /* the job is prepared for a, not started */
    T_OK(setup("rewrite", farm_ini, tdrv_new, locking_prepare_rewrite, &err), &err);
    T_TRUE(wait_printer(1, PRINTER_IDLE));
    synced();
    storeq_set_retry_ms(farm_storeq(fx.f), 200);
    int64_t id = add("size 20 20 20", "PLA", 1);
    struct farm_health h = { 0 };
    /* two writes given up: the PREPARED and what followed it */
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS; wall_ms() < end && h.store.failed < 2;) {
        loop_run_once(fx.l, 10);
        farm_health(fx.f, &h);
    }
    T_TRUE(h.store.failed >= 2);
    struct sqldb *other = atomic_load(&prep_lock);
    T_TRUE(other != NULL);
    unlock_store(other);
    T_EQ_INT(wait_job_or_failure(id, JOB_READY), JOB_READY);
    teardown();
}

/* A PREPARED the store refuses for good (here a trigger, as a constraint would) fails the
   job once, saying why.  It was sent back to the queue, prepared and refused again, on and
   on. */
T_CASE(farm_prepared_refused_for_good_fails_the_job_once)
{
    struct sf_err err;
    int before = atomic_load(&prepares);
    T_OK(setup("refusedprep", farm_ini, tdrv_new, test_prepare, &err), &err);
    char dir[600];
    snprintf(dir, sizeof(dir), "%s/refusedprep", t_tmpdir());
    const char *trigger =
        t_store_pg()
            ? "CREATE FUNCTION refuse_ready() RETURNS trigger AS $$ BEGIN IF NEW.state = 'ready'"
              " THEN RAISE EXCEPTION 'ready refused (test)' USING ERRCODE = 'check_violation';"
              " END IF; RETURN NEW; END $$ LANGUAGE plpgsql;"
              " CREATE TRIGGER refuse_ready BEFORE UPDATE ON jobs FOR EACH ROW EXECUTE FUNCTION"
              " refuse_ready()"
            : "CREATE TRIGGER refuse_ready BEFORE UPDATE OF state ON jobs WHEN NEW.state ="
              " 'ready' BEGIN SELECT RAISE(ABORT, 'ready refused (test)'); END";
    T_OK(t_store_exec(dir, trigger), NULL);
    int64_t id = add("size 20 20 20", "PLA", 1);
    enum job_state st = JOB_QUEUED;
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS; wall_ms() < end &&
                                                  (st = state_of(id)) != JOB_FAILED &&
                                                  atomic_load(&prepares) - before < 3;)
        loop_run_once(fx.l, 10);
    T_EQ_INT(st, JOB_FAILED);
    for (int i = 0; i < 50; i++)
        loop_run_once(fx.l, 10);
    T_EQ_INT(atomic_load(&prepares) - before, 1);
    struct job_row j;
    T_OK(job_get(id, &j, &err), &err);
    T_EQ_INT(j.state, JOB_FAILED);
    T_TRUE(strstr(j.reason, "the store refused its prepared G-code") != NULL);
    T_TRUE(strstr(j.reason, "ready refused (test)") != NULL);
    teardown();
}

/*
 * An operator resumes an interrupted job while another process holds the
 * store's write lock: the printer takes the job at once (printing), the
 * driver gets nothing until the RESUME has committed, then starts at the
 * resume line.  Before, the RESUME was written on the loop, which waited
 * out SQLite's busy timeout and refused the resume ("database is locked").
 */
T_CASE(farm_resume_commits_on_the_store_thread_before_the_driver_has_it)
{
    struct sf_err err;
    T_OK(setup("busyresume", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    int64_t id = add("size 20 20 20", "PLA", 1);
    T_TRUE(wait_job(id, JOB_PRINTING));
    struct tdrv *a = tdrv_named("a");
    a->base.status.lines_acked = 1;
    report(a, DRV_PRINTING, DRV_EV_PROGRESS);
    for (int i = 0; i < 20; i++)
        loop_run_once(fx.l, 10);
    teardown(); /* the daemon stops mid-print: the job is interrupted on a */
    T_OK(setup("busyresume", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    T_EQ_INT(state_of(id), JOB_INTERRUPTED);
    a = tdrv_named("a");
    struct sqldb *other = lock_store("busyresume");
    T_TRUE(other != NULL);
    T_OK(farm_job_resume(fx.f, id, 1, &err), &err);
    T_EQ_INT(pstate(0), PRINTER_PRINTING); /* taken at once */
    for (int i = 0; i < 20; i++)
        loop_run_once(fx.l, 10);
    T_EQ_INT(a->starts, 0); /* its RESUME waits for the lock: nothing sent */
    struct job_row j;
    T_OK(store_job_get(fx.s, id, &j, &err), &err); /* a read: WAL lets it through */
    T_EQ_INT(j.state, JOB_INTERRUPTED);
    unlock_store(other);
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS; wall_ms() < end && a->starts == 0;)
        loop_run_once(fx.l, 10);
    T_EQ_INT(a->starts, 1);
    T_EQ_INT(a->first_line, 1);
    T_TRUE(wait_job(id, JOB_PRINTING));
    T_OK(store_check(synced(), &err), &err);
    teardown();
}

/* Job id's state read on a connection of the test's own (r), not the loop's: a test that counts
   the loop's round trips must not add its own. */
static enum job_state
state_on(struct store *r, int64_t id)
{
    struct job_row j;
    return store_job_get(r, id, &j, NULL) ? (enum job_state) - 1 : j.state;
}

/* On PostgreSQL, the stored file sha's copy in this host's cache removed: the next
   store_file_path fetches it from the database, as on a host other than the one that stored
   it.  (On SQLite the data dir's copy is the only one: kept.) */
static void
uncache(const char *sha)
{
    if (!t_store_pg())
        return;
    char path[1200];
    T_OK(store_file_path(fx.s, sha, path, sizeof(path), NULL), NULL);
    T_EQ_INT(unlink(path), 0);
}

/*
 * Preparing a queued job looks its part up (on PostgreSQL: fetched from the
 * database when this host's cache lacks it, 1-2 s per 100 MB) on the
 * worker, not on the loop's connection: the loop's round trips stay as
 * they were from the job's add to its G-code ready.  Before, prepare()
 * called store_file_path on the loop, twice.
 */
T_CASE(farm_prepare_looks_its_part_up_off_the_loop)
{
    struct sf_err err;
    setup_held = "a"; /* the job is prepared for a and waits for it: nothing starts */
    T_OK(setup("preplook", farm_ini, tdrv_new, test_prepare, &err), &err);
    struct store *r = store_open_reader(fx.s, &err);
    T_TRUE(r != NULL);
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "part.stl");
    snprintf(o.material, sizeof(o.material), "PLA");
    char sha[STORE_SHA_HEX];
    int64_t id = 0;
    T_OK(store_file_put(fx.s, "size 20 20 20", 13, sha, &err), &err);
    uncache(sha);
    T_OK(store_job_add(fx.s, &o, sha, &id, &err), &err);
    uint64_t before = store_round_trips(fx.s);
    farm_kick(fx.f);
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS; wall_ms() < end && state_on(r, id) != JOB_READY;)
        loop_run_once(fx.l, 10);
    T_EQ_INT(state_on(r, id), JOB_READY);
    T_EQ_INT((long long)(store_round_trips(fx.s) - before), 0);
    store_close(r);
    teardown();
}

/*
 * A ready job's G-code stored by another host (not in this host's cache)
 * starts without the loop's connection: the G-code is looked up (fetched)
 * on the io thread, and the driver has it once it is local.  Before,
 * farm_start called store_file_path on the loop.
 */
T_CASE(farm_start_looks_its_gcode_up_off_the_loop)
{
    struct sf_err err;
    setup_held = "a";
    T_OK(setup("startlook", farm_ini, tdrv_new, test_prepare, &err), &err);
    struct store *r = store_open_reader(fx.s, &err);
    T_TRUE(r != NULL);
    int64_t id = add("size 20 20 20", "PLA", 1);
    T_TRUE(wait_job(id, JOB_READY)); /* a is not connected yet */
    struct job_row j;
    T_OK(store_job_get(r, id, &j, &err), &err);
    uncache(j.gcode_sha);
    uint64_t before = store_round_trips(fx.s);
    struct tdrv *a = tdrv_named("a");
    report(a, DRV_IDLE, DRV_EV_STATE);
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS;
         wall_ms() < end && (a->starts == 0 || state_on(r, id) != JOB_PRINTING);)
        loop_run_once(fx.l, 10);
    T_EQ_INT(a->starts, 1);
    T_EQ_INT(state_on(r, id), JOB_PRINTING);
    T_EQ_INT((long long)(store_round_trips(fx.s) - before), 0);
    char path[1200];
    T_OK(store_file_path(r, j.gcode_sha, path, sizeof(path), &err), &err);
    T_EQ_STR(a->path, path); /* the driver had the file, local */
    T_EQ_INT(access(path, R_OK), 0);
    store_close(r);
    teardown();
}

/*
 * A queued job whose part is lost (PostgreSQL: neither in this host's cache
 * nor in the database; SQLite: gone from the data dir) fails at its
 * preparation, naming the file: the worker's lookup (farm_prep_files) keeps
 * prepare()'s verdict, a file that is not there is no passing error.
 */
T_CASE(farm_prepare_of_a_lost_part_fails_the_job_naming_it)
{
    struct sf_err err;
    setup_held = "a";
    T_OK(setup("lostpart", farm_ini, tdrv_new, test_prepare, &err), &err);
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "part.stl");
    snprintf(o.material, sizeof(o.material), "PLA");
    char sha[STORE_SHA_HEX], path[1200];
    int64_t id = 0;
    T_OK(store_file_put(fx.s, "size 20 20 20", 13, sha, &err), &err);
    T_OK(store_file_path(fx.s, sha, path, sizeof(path), &err), &err);
    T_EQ_INT(unlink(path), 0);
    if (t_store_pg()) { /* its bytes gone from the database too */
        char dir[600], sql[256];
        snprintf(dir, sizeof(dir), "%s/lostpart", t_tmpdir());
        struct sqldb *db = sqldb_open(t_store_db(dir), 0, &err);
        T_TRUE(db != NULL);
        snprintf(sql, sizeof(sql), "DELETE FROM file_chunks WHERE sha256 = '%s'", sha);
        T_EQ_INT(sqldb_exec(db, sql), 0);
        snprintf(sql, sizeof(sql), "DELETE FROM file_blobs WHERE sha256 = '%s'", sha);
        T_EQ_INT(sqldb_exec(db, sql), 0);
        sqldb_close(db);
    }
    T_OK(store_job_add(fx.s, &o, sha, &id, &err), &err);
    farm_kick(fx.f);
    T_TRUE(wait_job(id, JOB_FAILED));
    struct job_row j;
    T_OK(job_get(id, &j, &err), &err);
    T_TRUE(strstr(j.reason, sha) != NULL);
    teardown();
}

/*
 * A network printer that comes back while its job is interrupted is offered
 * the job without the loop's connection: the interrupted job and its G-code
 * (fetched from the database when this host's cache lacks it) are read on
 * the store's thread, the printer waiting offline for the answer.  Before,
 * try_attach called store_job_interrupted and store_file_path on the loop.
 */
T_CASE(farm_reattach_reads_its_job_off_the_loop)
{
    static const char ini[] = "[printer n]\ndriver: octoprint\nurl: http://127.0.0.1:9\n"
                              "api_key: k\nmaterial: PLA\nbed_size: 200, 200, 200\n";
    struct sf_err err;
    T_OK(setup("attachlook", ini, tdrv_new, test_prepare, &err), &err);
    struct store *r = store_open_reader(fx.s, &err);
    T_TRUE(r != NULL);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    int64_t id = add("size 20 20 20", "PLA", 1);
    T_TRUE(wait_job(id, JOB_PRINTING));
    struct job_row j;
    T_OK(job_get(id, &j, &err), &err);
    uncache(j.gcode_sha);
    struct tdrv *t = tdrv_named("n");
    open_state = DRV_PRINTING; /* the printer prints on */
    uint64_t before = store_round_trips(fx.s);
    snprintf(t->base.status.message, sizeof(t->base.status.message), "timed out");
    report(t, DRV_OFFLINE, DRV_EV_STATE);
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS;
         wall_ms() < end && (attaches == 0 || state_on(r, id) != JOB_PRINTING);)
        loop_run_once(fx.l, 10);
    T_EQ_INT(attaches, 1);
    T_EQ_INT(state_on(r, id), JOB_PRINTING);
    T_EQ_INT(pstate(0), PRINTER_PRINTING);
    T_EQ_INT((long long)(store_round_trips(fx.s) - before), 0);
    char path[1200];
    T_OK(store_file_path(r, j.gcode_sha, path, sizeof(path), &err), &err);
    T_EQ_STR(t->path, path); /* the driver was offered the file, local */
    report(t, DRV_IDLE, DRV_EV_JOB_DONE);
    T_TRUE(wait_job(id, JOB_DONE));
    store_close(r);
    teardown();
}

/*
 * A printer added by a reload reads its bed (a part left on it under that name) on the
 * store's thread, not on the loop's connection; its driver, connected first, waits for the
 * bed gate's decision: the printer awaits clear, not idle.  Before, printer_new called
 * store_printer_bed_get on the loop.
 */
T_CASE(farm_new_printer_reads_its_bed_off_the_loop)
{
    struct sf_err err;
    T_OK(setup("bedlook", farm_ini, tdrv_new, test_prepare, &err), &err);
    T_TRUE(wait_printer(0, PRINTER_IDLE));
    /* c's part, from an earlier run */
    T_OK(store_printer_bed_set(synced(), "c", true, &err), &err);
    /* the reload's own reads (the run-time printers) are measured by one that adds none */
    static const char same[] = "[printer a]\ndriver: marlin\nport: pty:/dev/null\n"
                               "[printer b]\ndriver: marlin\nport: pty:/dev/null\n";
    static const char next[] = "[printer a]\ndriver: marlin\nport: pty:/dev/null\n"
                               "[printer b]\ndriver: marlin\nport: pty:/dev/null\n"
                               "[printer c]\ndriver: marlin\nport: pty:/dev/null\n";
    struct farmcfg c1, c2;
    farmcfg_init(&c1);
    farmcfg_init(&c2);
    T_OK(farmcfg_parse(&c1, same, strlen(same), "same.ini", &err), &err);
    T_OK(farmcfg_parse(&c2, next, strlen(next), "next.ini", &err), &err);
    T_OK(farm_reload(fx.f, &c1, &err), &err);
    uint64_t before = store_round_trips(fx.s);
    T_OK(farm_reload(fx.f, &c1, &err), &err);
    uint64_t reload = store_round_trips(fx.s) - before;
    before = store_round_trips(fx.s);
    T_OK(farm_reload(fx.f, &c2, &err), &err);
    struct printer_info info;
    for (int64_t end = wall_ms() + WAIT_LIMIT_MS; wall_ms() < end;) {
        if (info_of("c", &info) && info.state == PRINTER_AWAITING_CLEAR)
            break;
        loop_run_once(fx.l, 10);
    }
    T_TRUE(info_of("c", &info));
    T_EQ_INT(info.state, PRINTER_AWAITING_CLEAR);
    T_EQ_INT((long long)(store_round_trips(fx.s) - before), (long long)reload);
    farmcfg_release(&c1);
    farmcfg_release(&c2);
    teardown();
}
