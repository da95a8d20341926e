/*
 * slimfarmd.c - the farm daemon: config, job store, event loop, worker
 * pool, printers, REST API, signals.
 *
 *     slimfarmd [-c CONFIG] [--check | --fsck] [--allow-readable-config]
 *               [--session-idle SECONDS] [--session-max SECONDS]
 *     slimfarmd --init-store DATA_DIR|postgresql://...
 *
 * Why it is small: every part is a module (farmcfg, store, farm, api,
 * loop, pool); main() only builds them in dependency order, wires the
 * callbacks between them and tears them down in reverse.  Signals arrive
 * on the loop (signalfd): SIGINT/SIGTERM stop it; SIGHUP re-reads the
 * config and applies it (keys, printers) without disturbing running
 * prints, keeping the old config if the new one is invalid.
 *
 * Files: the daemon runs with umask 077, and the store keeps its data dir
 * for its owner (0700, files 0600); a config holding keys that other users
 * can read is refused (its keys are as good as published), unless
 * --allow-readable-config, which warns instead.  The data dir's "instance"
 * file holds this daemon's random id, which names its session cookie.
 *
 * File descriptors: each printer holds a few (a network printer its kept-alive
 * HTTP connection, a push socket or MQTT link, one more while a request
 * reconnects; a Marlin its port), on top of the API's connections
 * (http.h), so the soft RLIMIT_NOFILE is raised toward the hard limit at start
 * for the most printers a farm takes, those the API may add later included
 * (raise_nofile; 1,000 printers need 4,640 where many systems start a process
 * at 1,024).
 *
 * Thread: main is the loop thread; the pool's workers run prepare work.
 */
#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/random.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include "../../drivers/drv.h"
#include "../../drivers/drv_link.h"
#include "../api/api.h"
#include "../api/http.h"
#include "../api/http_loop.h"
#include "../base/log.h"
#include "../base/loop.h"
#include "../base/par.h"
#include "../base/pool.h"
#include "../farm/farm.h"
#include "../farm/farm_host.h"
#include "../farm/farmcfg.h"
#include "../farm/notify.h"
#include "../farm/prepare.h"
#include "../farm/store.h"
#include "../farm/store_host.h"

/* Everything the daemon runs, for the callbacks. */
struct daemon {
    const char *config_path; /* -c */
    struct farmcfg cfg;      /* the config in force */
    struct loop *l;          /* the loop */
    struct store *s;         /* the job store */
    struct pool *pool;       /* prepare workers */
    struct farm *farm;       /* printers, scheduling */
    struct notify *notify;   /* webhooks and mails ([notify] sections) */
    struct api *api;         /* REST API */
    struct http_loop *hl;    /* the API on the loop */
    uint64_t wake;           /* pending event-stream wake timer */
    uint64_t tick;           /* API_TICK_MS timer: progress for event streams */
};

/* ---- wiring ---- */

static void
wake_streams(struct loop *l, void *ud)
{
    (void)l;
    struct daemon *d = ud;
    d->wake = 0;
    api_notify(d->api); /* resumed streams ask for a server run (http_set_wake) */
}

/* The farm logged events: wake the event streams on the next turn (never
   from inside an HTTP callback, which may be what caused the event). */
static void
on_farm_event(void *ud)
{
    struct daemon *d = ud;
    notify_kick(d->notify);
    if (d->api && d->hl && !d->wake)
        d->wake = loop_timer_add(d->l, 0, wake_streams, d);
}

static void
on_tick(struct loop *l, void *ud)
{
    struct daemon *d = ud;
    api_tick(d->api);
    http_loop_kick(d->hl);
    d->tick = loop_timer_add(l, API_TICK_MS, on_tick, d);
}

static void
on_api_change(void *ud)
{
    struct daemon *d = ud;
    farm_kick(d->farm);
    farm_host_wake(d->farm); /* a job added or changed: the other hosts may take it */
}

static void
on_stop(struct loop *l, int signo, void *ud)
{
    (void)ud;
    log_info("slimfarmd", "signal %d: stopping", signo);
    loop_stop(l);
}

/* File descriptors a printer may hold at once (see the top comment), with room to spare. */
#define FDS_PER_PRINTER 4

/* File descriptors n printers and the API may hold at once. */
static rlim_t
fds_for(size_t n)
{
    return (rlim_t)HTTP_CONNECTIONS_MAX + HTTP_FD_RESERVE + FDS_PER_PRINTER * n;
}

/* Raise the soft RLIMIT_NOFILE (never lowered) to cover the most printers a farm takes
   (FARMCFG_PRINTERS_MAX), not only the n_printers in force: printers added through the API
   at run time (farm.h) open their links without coming back here.  Warn when the hard
   limit stops it short of the n_printers in force. */
static void
raise_nofile(size_t n_printers)
{
    rlim_t need = fds_for(n_printers), want = fds_for(FARMCFG_PRINTERS_MAX);
    struct rlimit rl;
    if (getrlimit(RLIMIT_NOFILE, &rl) != 0 || rl.rlim_cur == RLIM_INFINITY || rl.rlim_cur >= want)
        return;
    struct rlimit up = rl;
    up.rlim_cur = rl.rlim_max == RLIM_INFINITY || rl.rlim_max > want ? want : rl.rlim_max;
    rlim_t now = setrlimit(RLIMIT_NOFILE, &up) == 0 ? up.rlim_cur : rl.rlim_cur;
    if (now < need)
        log_warn("slimfarmd",
                 "%zu printers may need %llu file descriptors; RLIMIT_NOFILE allows %llu "
                 "(raise the hard limit: ulimit -Hn, systemd's LimitNOFILE=)",
                 n_printers, (unsigned long long)need, (unsigned long long)now);
}

static void
on_reload(struct loop *l, int signo, void *ud)
{
    (void)l, (void)signo;
    struct daemon *d = ud;
    struct farmcfg next;
    struct sf_err err;
    farmcfg_init(&next);
    if (farmcfg_load(&next, d->config_path, &err)) {
        log_error("slimfarmd", "reload: %s; keeping the running config", err.msg);
        return;
    }
    if (strcmp(next.data_dir, d->cfg.data_dir) != 0 || strcmp(next.store, d->cfg.store) != 0 ||
        strcmp(next.host, d->cfg.host) != 0 || next.host_lease_s != d->cfg.host_lease_s ||
        strcmp(next.listen_host, d->cfg.listen_host) || next.listen_port != d->cfg.listen_port)
        log_warn("slimfarmd", "reload: listen, data_dir, store and host changes need a restart");
    raise_nofile(next.n_printers);
    if (api_reload(d->api, &d->cfg, &next, &err) || farm_reload(d->farm, &next, &err) ||
        notify_reload(d->notify, next.notify, next.n_notify, &err)) {
        log_error("slimfarmd", "reload: %s", err.msg);
        farmcfg_release(&next);
        return;
    }
    farmcfg_release(&d->cfg);
    d->cfg = next;
    log_info("slimfarmd", "reloaded %s: %zu printers, %zu API keys, %zu notify targets",
             d->config_path, d->cfg.n_printers, d->cfg.n_keys, d->cfg.n_notify);
}

/* --fsck: crash recovery plus every store check; prints a summary.  A shared store
   (store:) is checked as one of its hosts, without recovery (that would take every
   host's work for this one's, and each host recovers its own when it joins) and without
   migrating it (an older schema is refused: the other hosts run on it). */
static int
run_fsck(struct farmcfg *cfg)
{
    struct sf_err err;
    struct store_recovery rec;
    bool shared = cfg->store[0] != '\0';
    char shown[sizeof(cfg->store)];
    if (shared)
        farmcfg_store_shown(cfg->store, shown, sizeof(shown));
    else
        snprintf(shown, sizeof(shown), "%s", cfg->data_dir);
    struct store *s = shared ? store_open_check(cfg->data_dir, cfg->store, &err)
                             : store_open(cfg->data_dir, &rec, &err);
    int status = 1;
    struct job_row *jobs = NULL;
    size_t n = 0;
    if (s && store_check(s, &err) == SF_OK && store_job_list(s, &jobs, &n, &err) == SF_OK) {
        if (shared)
            printf("store %s: ok, %zu jobs, not recovered (each host recovers its own work "
                   "when it joins)\n",
                   shown, n);
        else
            printf("store %s: ok, %zu jobs, %d interrupted and %d requeued by recovery\n", shown, n,
                   rec.interrupted, rec.requeued);
        status = 0;
    } else {
        fprintf(stderr, "slimfarmd: store %s: %s\n", shown, err.msg);
    }
    free(jobs);
    store_close(s);
    farmcfg_release(cfg);
    return status;
}

/* --init-store: create or migrate a store's schema (store_init), say which, and exit. */
static int
run_init_store(const char *target)
{
    struct sf_err err;
    int from = 0;
    if (store_init(target, &from, &err) != SF_OK) {
        fprintf(stderr, "slimfarmd: --init-store: %s\n", err.msg);
        return 1;
    }
    int to = store_schema_version();
    if (from == 0)
        printf("store created at schema %d\n", to);
    else if (from < to)
        printf("store migrated from schema %d to %d\n", from, to);
    else
        printf("store at schema %d: up to date\n", to);
    return 0;
}

/* The config holds something secret: API keys, or a printer's key or password. */
static bool
holds_secrets(const struct farmcfg *cfg)
{
    if (cfg->n_keys)
        return true;
    for (size_t i = 0; i < cfg->n_notify; i++)
        if (notifycfg_has_secret(&cfg->notify[i]))
            return true;
    for (size_t i = 0; i < cfg->n_printers; i++) {
        const struct drv_link *l = &cfg->printers[i].link;
        for (size_t j = 0; j < l->n; j++)
            if ((l->v[j].opt->flags & DRV_OPT_SECRET) && l->text[l->v[j].at])
                return true;
    }
    return false;
}

/* A config holding secrets that group or others can read: refused (1,
   with the message on stderr), or with allow a loud warning (0). */
static int
check_config_mode(const char *path, const struct farmcfg *cfg, bool allow)
{
    struct stat st;
    if (!holds_secrets(cfg) || stat(path, &st) != 0 || !(st.st_mode & 044))
        return 0;
    if (allow) {
        log_warn("slimfarmd",
                 "WARNING: %s holds API keys, printer passwords or notify secrets and is readable "
                 "by other users "
                 "(mode %04o); running anyway (--allow-readable-config). Fix: chmod 600 %s",
                 path, (unsigned)(st.st_mode & 07777), path);
        return 0;
    }
    fprintf(stderr,
            "slimfarmd: %s holds API keys, printer passwords or notify secrets and is readable by "
            "other users "
            "(mode %04o): refusing to start.  Fix: chmod 600 %s (or run with "
            "--allow-readable-config)\n",
            path, (unsigned)(st.st_mode & 07777), path);
    return 1;
}

/* DATA_DIR/instance: this daemon's random id (16 hex digits, made on first
   start, 0600), which names its session cookie. */
static int
instance_id(const char *data_dir, char id[17], struct sf_err *err)
{
    char path[1100];
    snprintf(path, sizeof(path), "%s/instance", data_dir);
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd >= 0) {
        ssize_t n = read(fd, id, 16);
        close(fd);
        id[n > 0 ? n : 0] = '\0';
        if (n == 16 && strspn(id, "0123456789abcdef") == 16)
            return SF_OK;
        log_warn("slimfarmd", "%s is not an instance id: making a new one", path);
        unlink(path);
    } else if (errno != ENOENT) {
        return sf_err_sys(err, "cannot read '%s'", path);
    }
    unsigned char rnd[8];
    if (getrandom(rnd, sizeof(rnd), 0) != (ssize_t)sizeof(rnd))
        return sf_err_sys(err, "no random bytes for an instance id");
    for (size_t i = 0; i < sizeof(rnd); i++)
        snprintf(id + 2 * i, 3, "%02x", rnd[i]);
    fd = open(path, O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
    if (fd < 0 || write(fd, id, 16) != 16 || fsync(fd) != 0) {
        int rc = sf_err_sys(err, "cannot write '%s'", path);
        if (fd >= 0)
            close(fd);
        return rc;
    }
    close(fd);
    return SF_OK;
}

/* The usage on f; 0 when asked for (stdout), 2 after a usage error (stderr). */
static int
usage(FILE *f)
{
    fprintf(f, "usage: slimfarmd [-c CONFIG] [--check | --fsck] [--allow-readable-config]\n"
               "                 [--session-idle SECONDS] [--session-max SECONDS]\n"
               "       slimfarmd --init-store DATA_DIR|postgresql://...\n"
               "  -c CONFIG  farm config (default config/farm.ini)\n"
               "  --check    validate the config and exit\n"
               "  --fsck     recover and check the job store, then exit (a shared store:\n"
               "             checked only, never migrated; its hosts recover their own work)\n"
               "  --init-store DATA_DIR|postgresql://...\n"
               "             create or migrate the store's schema (SQLite in DATA_DIR, or a\n"
               "             PostgreSQL database by libpq URL) and exit; no config needed,\n"
               "             a schema newer than this program is refused\n"
               "  --allow-readable-config\n"
               "             start even though CONFIG holds keys other users can read\n"
               "             (warns; without it such a config is refused: chmod 600 it)\n"
               "  --session-idle SECONDS\n"
               "             a dashboard session unused this long ends (default 28800: 8 h)\n"
               "  --session-max SECONDS\n"
               "             a dashboard session ends this long after log in, used or not\n"
               "             (default 604800: 7 days)\n"
               "  -h, --help show this and exit\n");
    return f == stdout ? 0 : 2;
}

/* A whole number of seconds, 1 .. 10 years; false if not. */
static bool
seconds_arg(const char *s, int64_t *ms)
{
    char *end;
    errno = 0;
    long long v = strtoll(s, &end, 10);
    if (errno || end == s || *end || v < 1 || v > 10LL * 365 * 86400)
        return false;
    *ms = v * 1000;
    return true;
}

/* Free what main built, in reverse. */
static void
teardown(struct daemon *d)
{
    /* Drop the loop work that touches the API before freeing it: the loop
       turns below (draining the pool) would run a pending wake and kick
       the stopped server (a use-after-free in MHD_run when printers dropped
       as the daemon stopped).  With d->api NULL the farm's events post no
       new wake. */
    if (d->wake)
        loop_timer_cancel(d->l, d->wake);
    if (d->tick)
        loop_timer_cancel(d->l, d->tick);
    d->wake = d->tick = 0;
    http_loop_detach(d->hl);
    d->hl = NULL;
    api_free(d->api);
    d->api = NULL;
    if (d->pool) {
        farm_drop_pool(d->farm);
        pool_free(d->pool);
        loop_run_once(d->l, 0); /* deliver cancelled prepares */
    }
    notify_set_queue(d->notify, NULL); /* its read in flight is delivered by farm_free */
    farm_free(d->farm); /* may log events: a kick for the notifier, which cancels it */
    notify_free(d->notify);
    d->notify = NULL;
    store_close(d->s);
    loop_free(d->l);
}

int
main(int argc, char **argv)
{
    struct daemon d = { .config_path = "config/farm.ini" };
    bool check = false, fsck = false, allow_readable = false;
    int64_t idle_ms = 0, max_ms = 0;
    umask(077); /* the data dir and all in it are the farm's alone */
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "-c") == 0 && i + 1 < argc)
            d.config_path = argv[++i];
        else if (strcmp(argv[i], "--init-store") == 0 && i + 1 < argc)
            return run_init_store(argv[i + 1]);
        else if (strcmp(argv[i], "--check") == 0)
            check = true;
        else if (strcmp(argv[i], "--fsck") == 0)
            fsck = true;
        else if (strcmp(argv[i], "--allow-readable-config") == 0)
            allow_readable = true;
        else if (strcmp(argv[i], "--session-idle") == 0 && i + 1 < argc &&
                 seconds_arg(argv[i + 1], &idle_ms))
            i++;
        else if (strcmp(argv[i], "--session-max") == 0 && i + 1 < argc &&
                 seconds_arg(argv[i + 1], &max_ms))
            i++;
        else if (strcmp(argv[i], "-h") == 0 || strcmp(argv[i], "--help") == 0)
            return usage(stdout);
        else
            return usage(stderr);
    }
    struct sf_err err;
    int status = 1;
    farmcfg_init(&d.cfg);
    if (farmcfg_load(&d.cfg, d.config_path, &err)) {
        fprintf(stderr, "slimfarmd: %s\n", err.msg);
        return 1;
    }
    if (check_config_mode(d.config_path, &d.cfg, allow_readable)) {
        farmcfg_release(&d.cfg);
        return 1;
    }
    if (check) {
        printf("%s: ok, %zu printers, %zu API keys\n", d.config_path, d.cfg.n_printers,
               d.cfg.n_keys);
        farmcfg_release(&d.cfg);
        return 0;
    }
    if (fsck)
        return run_fsck(&d.cfg);
    raise_nofile(d.cfg.n_printers);
    if (d.cfg.n_keys == 0)
        log_warn("slimfarmd", "%s has no api_keys: every API request will get 401", d.config_path);
    struct store_recovery rec;
    /* a shared store (farm.ini store): one host of several (farm_host.h) */
    if (!(d.l = loop_new(&err)) ||
        !(d.s = d.cfg.store[0] ? store_open_host(d.cfg.data_dir, d.cfg.store, &rec, &err)
                               : store_open(d.cfg.data_dir, &rec, &err)) ||
        !(d.pool = pool_new(d.l, 0, &err)))
        goto out;
    char instance[17];
    if (instance_id(d.cfg.data_dir, instance, &err))
        goto out;
    par_share(pool_size(d.pool)); /* the prepare workers divide the cores (base/par.h) */
    if (rec.interrupted || rec.requeued)
        log_warn("slimfarmd",
                 "recovered from a crash: %d jobs interrupted (waiting for an operator), %d "
                 "back in the queue",
                 rec.interrupted, rec.requeued);
    struct farm_hooks hooks = {
        .driver = drv_new, .prepare = prepare_part, .notify = on_farm_event, .notify_ud = &d
    };
    if (!(d.farm = farm_new(d.l, d.s, d.pool, &d.cfg, &hooks, &err)) ||
        !(d.notify = notify_new(d.l, d.s, farm_storeq(d.farm), d.cfg.notify, d.cfg.n_notify,
                                &err))) /* its reads off the loop */
        goto out;
    /* one of several hosts: each event of the farm told once */
    notify_set_host(d.notify, farm_host_name(d.farm));
    raise_nofile(farm_printer_count(d.farm)); /* with those managed at run time (farm.h) */
    struct api_config ac = { .store = d.s,
                             .farm = d.farm,
                             .host = d.cfg.listen_host,
                             .port = d.cfg.listen_port,
                             .keys = d.cfg.keys,
                             .n_keys = d.cfg.n_keys,
                             .upload_max = d.cfg.upload_max_bytes,
                             .pool = d.pool,
                             .loop = d.l,
                             .on_change = on_api_change,
                             .ud = &d,
                             .instance = instance,
                             .session_idle_ms = idle_ms,
                             .session_max_ms = max_ms };
    if (!(d.api = api_new(&ac, &err)) || !(d.hl = http_loop_attach(d.l, api_http(d.api), &err)))
        goto out;
    d.tick = loop_timer_add(d.l, API_TICK_MS, on_tick, &d);
    if (loop_add_signal(d.l, SIGINT, on_stop, &d, &err) ||
        loop_add_signal(d.l, SIGTERM, on_stop, &d, &err) ||
        loop_add_signal(d.l, SIGHUP, on_reload, &d, &err))
        goto out;
    signal(SIGPIPE, SIG_IGN);
    char shown[sizeof(d.cfg.store)] = "SQLite";
    if (d.cfg.store[0])
        farmcfg_store_shown(d.cfg.store, shown, sizeof(shown));
    log_info("slimfarmd", "listening on %s:%d, data in %s, store %s, %zu printers",
             d.cfg.listen_host, http_port(api_http(d.api)), d.cfg.data_dir, shown,
             farm_printer_count(d.farm));
    if (loop_run(d.l) == SF_OK)
        status = 0;
    else
        sf_err_set(&err, SF_EIO, "event loop failed");
out:
    if (status)
        fprintf(stderr, "slimfarmd: %s\n", err.msg);
    teardown(&d);
    farmcfg_release(&d.cfg);
    return status;
}
