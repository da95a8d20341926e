/*
 * farm.h - the running farm: printers from the config with their drivers,
 * the prepare stage on the worker pool, and the scheduler, all over the
 * job store, on the event loop.
 *
 * Flow: a queued job is prepared (prepare.h) for a printer it could run
 * on; a ready job goes to an idle printer chosen by sched.h; driver events
 * move jobs and printers (job.h) with every change committed to the store
 * (store.h).  A printer whose link drops goes offline and is reconnected
 * with drv_backoff_ms's exponential backoff; one slow or dead printer never blocks the
 * others, because nothing here waits: drivers and the pool report back
 * through the loop.
 *
 * Drivers come in through hooks.driver (slimfarmd passes drv_new from
 * drivers/, tests their own); with none, printers stay offline (tests of
 * the prepare stage alone).  farm_reload()
 * applies a new config (SIGHUP) without disturbing running prints.
 *
 * Thread: the loop thread.  The pool must be drained (pool_free, then one
 * loop iteration) before farm_free, since prepare completions use the farm.
 */
#ifndef SF_FARM_FARM_H
#define SF_FARM_FARM_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../../drivers/drv.h"
#include "../base/err.h"
#include "../base/loop.h"
#include "../base/pool.h"
#include "farmcfg.h"
#include "job.h"
#include "prepare.h"
#include "store.h"

#define FARM_PROGRESS_MS                                                                           \
    1000 /* persist lines acknowledged this often: what a resume                                   \
            after a crash may print twice (one UPDATE per                                          \
            printing printer per second) */

/* drv_new's shape: slimfarmd hands drv_new in; tests may hand in their own. */
typedef struct drv *(*farm_driver_fn)(struct loop *l, const struct drv_config *cfg,
                                      drv_event_fn on_event, void *ud, struct sf_err *err);

struct farm_hooks {
    farm_driver_fn driver;    /* drv_new, a test's, or NULL: printers stay offline */
    prepare_fn prepare;       /* prepare_part, or a test's */
    void (*notify)(void *ud); /* the event log grew (wake event streams) */
    int64_t progress_ms;      /* persist progress this often (0: FARM_PROGRESS_MS) */
    void *notify_ud;
};

/* A printer as the API shows it. */
struct farm_printer_info {
    const struct farmcfg_printer *cfg; /* its config (valid until the next reload) */
    enum printer_state state;          /* current state */
    int64_t job_id;                    /* job on it, 0 if none */
    double progress;                   /* 0..1 */
    double nozzle_c, nozzle_target_c, bed_c, bed_target_c; /* deg C, 0 if unknown */
    const char *message; /* why offline/error, "" if nothing to say */
};

struct farm;

struct farm *farm_new(struct loop *l, struct store *s, struct pool *pool, const struct farmcfg *cfg,
                      const struct farm_hooks *hooks, struct sf_err *err);
void farm_free(struct farm *f);

/* Apply a new config; running prints keep their printer until they end. */
int farm_reload(struct farm *f, const struct farmcfg *cfg, struct sf_err *err);

/* Something changed (job submitted, bed cleared): prepare and schedule soon. */
void farm_kick(struct farm *f);

size_t farm_printer_count(const struct farm *f);
void farm_printer_info(const struct farm *f, size_t i, struct farm_printer_info *out);

/*
 * "pause", "resume", "cancel" (the job on it), "cleared" (bed is clear).
 * SF_ENOTFOUND unknown printer, SF_EINVAL not legal now, SF_EUNSUPP unknown
 * action; err says why.
 */
int farm_printer_action(struct farm *f, const char *name, const char *action, struct sf_err *err);

/*
 * Resume interrupted job id on the printer its part is on, from command
 * line `line` (0-based; -1: the last acknowledged line the store holds).
 * The printer must be idle.  SF_ENOTFOUND no such job; SF_EINVAL not
 * interrupted, printer not idle, or line outside 1..lines-1 (err says
 * which and the range).
 */
int farm_job_resume(struct farm *f, int64_t id, int64_t line, struct sf_err *err);

#endif
