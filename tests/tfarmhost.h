/*
 * tfarmhost.h - a farm as one of several hosts, for the unit tests that
 * run one (PostgreSQL only, as farm.ini's store is a URL): hdrv, a small
 * in-test driver that stands in for its printers; hx, the farm of one host
 * with its loop, store and pool (host_farm, host_farm_free); what it
 * logged (was_logged, wait_logged); and the database's view of its jobs
 * (db_text, wait_state).  Header-only, one farm at a time, one thread (the
 * log sink excepted).
 */
#ifndef SF_TESTS_TFARMHOST_H
#define SF_TESTS_TFARMHOST_H

#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../src/base/clock.h"
#include "../src/base/log.h"
#include "../src/base/mem.h"
#include "../src/farm/farm.h"
#include "../src/farm/farmcfg.h"
#include "../src/farm/store_host.h"
#include "tstore.h"

/* hdrv: a printer that connects idle and prints what it is given, reporting on the loop.  A
   network kind (octoprint, moonraker, prusalink) re-attaches: it connects again in the state it
   had (a link drop: the printer prints on), and attach adopts the job it still prints. */
struct hdrv {
    struct drv base; /* first: drv.h's rule */
    int starts, cancels, attaches;
    bool ended; /* a network printer's print ended while the farm was away: attach adopts it
                   and reports the end at once, as a network driver does */
};

static struct hdrv *hdrvs[4];
static int n_hdrvs;

static void
h_deliver(struct loop *l, void *ud)
{
    (void)l;
    struct drv *d = ud;
    d->on_event(d, DRV_EV_STATE, d->ud);
}

static int
h_open(struct drv *d, struct sf_err *err)
{
    (void)err;
    bool prints = d->status.state == DRV_PRINTING || d->status.state == DRV_PAUSED;
    if (!d->ops->attach || !prints)
        d->status.state = DRV_IDLE;
    loop_timer_add(d->loop, 0, h_deliver, d);
    return SF_OK;
}

static int
h_start(struct drv *d, const char *path, uint64_t first_line, const struct drv_job_scan *scan,
        struct sf_err *err)
{
    (void)path, (void)err;
    ((struct hdrv *)d)->starts++;
    d->status.lines_acked = first_line;
    d->status.lines_total = scan ? scan->lines_total : 2;
    d->status.state = DRV_PRINTING;
    loop_timer_add(d->loop, 0, h_deliver, d);
    return SF_OK;
}

static int
h_ok(struct drv *d, struct sf_err *err)
{
    (void)d, (void)err;
    return SF_OK;
}

static int
h_cancel(struct drv *d, struct sf_err *err)
{
    (void)err;
    ((struct hdrv *)d)->cancels++;
    d->status.state = DRV_IDLE;
    return SF_OK;
}

static int
h_command(struct drv *d, const char *line, struct sf_err *err)
{
    (void)line;
    return sf_err_set(err, SF_EUNSUPP, "printer '%s': hdrv: no console", d->name);
}

static void
h_close(struct drv *d)
{
    d->status.state = DRV_OFFLINE;
}

static void
h_destroy(struct drv *d)
{
    for (int i = 0; i < n_hdrvs; i++)
        if (hdrvs[i] == (struct hdrv *)d)
            hdrvs[i] = NULL;
    free(d);
}

static int
h_attach(struct drv *d, const char *path, const struct drv_job_scan *scan, struct sf_err *err)
{
    (void)path, (void)scan;
    struct hdrv *h = (struct hdrv *)d;
    h->attaches++;
    if (h->ended) {
        h->ended = false;
        d->on_event(d, DRV_EV_JOB_DONE, d->ud);
        return SF_OK;
    }
    if (d->status.state != DRV_PRINTING && d->status.state != DRV_PAUSED)
        return sf_err_set(err, SF_ENOTFOUND, "printer '%s': hdrv: no job", d->name);
    return SF_OK;
}

static const struct drv_ops hdrv_ops = {
    DRV_OPS_VERSION, "hdrv",    h_open,  h_start,   h_ok, h_ok,
    h_cancel,        h_command, h_close, h_destroy, NULL, NULL
};
static const struct drv_ops hdrv_net_ops = { DRV_OPS_VERSION, "hdrv-net", h_open,
                                             h_start,         h_ok,       h_ok,
                                             h_cancel,        h_command,  h_close,
                                             h_destroy,       h_attach,   NULL };

static inline struct drv *
hdrv_new(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event, void *ud,
         struct sf_err *err)
{
    struct hdrv *t = mem_calloc(1, sizeof(*t));
    if (!t) {
        sf_err_set(err, SF_ENOMEM, "hdrv: out of memory");
        return NULL;
    }
    bool net =
        cfg->kind && (strcmp(cfg->kind, "octoprint") == 0 || strcmp(cfg->kind, "moonraker") == 0 ||
                      strcmp(cfg->kind, "prusalink") == 0);
    t->base.ops = net ? &hdrv_net_ops : &hdrv_ops;
    t->base.loop = l;
    snprintf(t->base.name, sizeof(t->base.name), "%s", cfg->name);
    t->base.on_event = on_event;
    t->base.ud = ud;
    if (n_hdrvs < 4)
        hdrvs[n_hdrvs++] = t;
    return &t->base;
}

static inline struct hdrv *
hdrv_named(const char *name)
{
    for (int i = n_hdrvs - 1; i >= 0; i--)
        if (hdrvs[i] && strcmp(hdrvs[i]->base.name, name) == 0)
            return hdrvs[i];
    return NULL;
}

static inline int
no_prepare(const struct prepare_req *req, struct prepare_out *out, const atomic_bool *cancel,
           struct sf_err *err)
{
    (void)req, (void)out, (void)cancel;
    return sf_err_set(err, SF_EUNSUPP, "test: no preparing here");
}

/* What was logged at warn level or above, and the hosts' news (the sink runs on any
   thread). */
static pthread_mutex_t logged_mu = PTHREAD_MUTEX_INITIALIZER;
static char logged[8192];

static inline void
sink(void *ud, enum log_level level, const char *subsys, const char *printer, const char *msg)
{
    (void)ud, (void)printer;
    pthread_mutex_lock(&logged_mu);
    size_t n = strlen(logged);
    if ((level <= LOG_WARN || strcmp(subsys, "host") == 0) && n + 1 < sizeof(logged))
        snprintf(logged + n, sizeof(logged) - n, "%s: %s\n", subsys, msg);
    pthread_mutex_unlock(&logged_mu);
}

static inline bool
was_logged(const char *what)
{
    pthread_mutex_lock(&logged_mu);
    bool yes = strstr(logged, what) != NULL;
    pthread_mutex_unlock(&logged_mu);
    return yes;
}

/* The farm of host name on url's database: its loop, store, pool and config. */
static struct {
    struct loop *l;
    struct store *s;
    struct pool *pool;
    struct farm *f;
    struct farmcfg cfg;
} hx;

/* Build hx: data dir dir, printers the [printer] sections of its farm.ini. */
static prepare_fn host_prepare; /* the next host_farm's prepare hook (NULL: no_prepare) */
static int host_lease_s = 600;  /* the next host_farm's lease: far above any stall */

static inline int
host_farm(const char *dir, const char *url, const char *name, const char *printers,
          struct sf_err *err)
{
    char ini[4096];
    snprintf(ini, sizeof(ini), "[farm]\nstore: %s\nhost: %s\nhost_lease_s: %d\n%s", url, name,
             host_lease_s, printers);
    host_lease_s = 600;
    memset(&hx, 0, sizeof(hx));
    memset(hdrvs, 0, sizeof(hdrvs));
    n_hdrvs = 0;
    logged[0] = '\0';
    log_set_level(LOG_INFO);
    log_set_sink(sink, NULL);
    farmcfg_init(&hx.cfg);
    int rc = farmcfg_parse(&hx.cfg, ini, strlen(ini), "farm.ini", err);
    if (rc)
        return rc;
    if (!(hx.l = loop_new(err)) || !(hx.s = store_open_host(dir, url, NULL, err)) ||
        !(hx.pool = pool_new(hx.l, 1, err)))
        return SF_EIO;
    struct farm_hooks hooks = { .driver = hdrv_new,
                                .prepare = host_prepare ? host_prepare : no_prepare,
                                .progress_ms = 50 };
    host_prepare = NULL;
    hx.f = farm_new(hx.l, hx.s, hx.pool, &hx.cfg, &hooks, err);
    return hx.f ? SF_OK : SF_EIO;
}

static inline void
host_farm_free(void)
{
    farm_drop_pool(hx.f);
    pool_free(hx.pool);
    if (hx.l)
        loop_run_once(hx.l, 0);
    farm_free(hx.f);
    store_close(hx.s);
    loop_free(hx.l);
    farmcfg_release(&hx.cfg);
    log_set_sink(NULL, NULL);
}

/* A ready G-code job for printer (any G-code printer runs it), added through s. */
static inline int
add_ready_for(struct store *s, const char *printer, int64_t *id, struct sf_err *err)
{
    char sha[STORE_SHA_HEX];
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "part.gcode");
    snprintf(o.printer, sizeof(o.printer), "%s", printer);
    struct job_event_args g = { .prep_key = GCJOB_KEY_PREFIX "n0/", .gcode_lines = 2 };
    int rc = store_file_put(s, "G28\nG1 X1\n", 10, sha, err);
    return rc ? rc : store_job_add_gcode(s, &o, sha, &g, id, err);
}

/* The first column of sql's first row (its ?1 bound to id) on url's database, as text. */
static inline void
db_text(const char *url, const char *sql, int64_t id, char *out, size_t cap)
{
    struct sf_err err;
    struct sqldb *db = sqldb_open(url, 0, &err);
    struct sqldb_stmt *st;
    snprintf(out, cap, "(no row)");
    if (db && sqldb_prepare(db, sql, &st) == SF_OK) {
        sqldb_bind_int64(st, 1, id);
        if (sqldb_step(st) == SQLDB_ROW)
            snprintf(out, cap, "%s", sqldb_column_text(st, 0));
        sqldb_finalize(st);
    }
    sqldb_close(db);
}

#define WAIT_LIMIT_MS 120000

/* Turn hx's loop until job id's state (its name) is want, or WAIT_LIMIT_MS pass. */
static inline bool
wait_state(const char *url, int64_t id, const char *want)
{
    char st[32];
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; clock_mono_ms() < end;) {
        farm_sync(hx.f, -1, NULL);
        db_text(url, "SELECT state FROM jobs WHERE id = ?1", id, st, sizeof(st));
        if (strcmp(st, want) == 0)
            return true;
        loop_run_once(hx.l, 20);
    }
    return false;
}

/* Turn hx's loop until what was logged holds what, or WAIT_LIMIT_MS pass. */
static inline bool
wait_logged(const char *what)
{
    for (int64_t end = clock_mono_ms() + WAIT_LIMIT_MS; clock_mono_ms() < end;) {
        if (was_logged(what))
            return true;
        loop_run_once(hx.l, 20);
    }
    return false;
}

#endif
