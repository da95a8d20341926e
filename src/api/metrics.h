/*
 * metrics.h - the farm in Prometheus text exposition format 0.0.4, for
 * GET /metrics (api_compat.h): every figure read from the store and the
 * printers at scrape time, so counters survive restarts and never go
 * backwards (jobs and prints are never deleted).
 *
 *   slimfarm_jobs{state}                      gauge: jobs by state (all 9 states; the
 *                                             store's: on a shared store, the whole farm's)
 *   slimfarm_printers{state}                  gauge: configured printers by state (on one
 *                                             of several hosts, every host's printers)
 *   slimfarm_printer_state{printer,state}     gauge: 1 for each printer, in its state
 *   slimfarm_printer_temperature_celsius{printer,sensor}  gauge: nozzle and bed, for each
 *                                             printer not offline
 *   slimfarm_prints_total{printer,outcome}    counter: prints ended (done, failed,
 *                                             cancelled, refused, interrupted)
 *   slimfarm_filament_used_grams_total{printer}       counter: prints done x their
 *                                             G-code's filament estimate
 *   slimfarm_support_saved_grams_total{printer}       counter: prints done x the
 *                                             support their optimization saved (prepare.h)
 *   slimfarm_stage_duration_seconds{stage}    histogram: prepare (orient .. slice, each
 *                                             job's last), slice (its slicing part),
 *                                             print (prints done, start to end)
 *   slimfarm_queue_wait_seconds               histogram: a print's wait from its job
 *                                             becoming ready to its start
 *   slimfarm_loop_turn_max_seconds            gauge: the event loop's longest turn
 *   slimfarm_store_queue_depth, _depth_max    gauge: store writes queued now, at most
 *   slimfarm_store_queue_wait_max_seconds     gauge: a queued write's longest post to end
 *   slimfarm_store_writes_total, _write_failures_total, _write_retries_total
 *                                             counter: the store thread's writes (storeq.h)
 *
 * On one of several hosts (store_host.h) every per-printer series also has
 * host="NAME", the printer's owner: any host's scrape shows the whole farm,
 * the other hosts' printers as they published them (farm_view.h).  The
 * loop's and store queue's series stay this host's own, unlabelled.
 *
 * Thread: metrics_printers on the loop thread (the farm's); metrics_render
 * on the thread of the store it is given (the API's reader).
 */
#ifndef SF_API_METRICS_H
#define SF_API_METRICS_H

#include <stddef.h>

#include "../base/err.h"
#include "../farm/farm.h"
#include "../farm/store.h"
#include "../farm/store_host.h"

#define METRICS_CONTENT_TYPE "text/plain; version=0.0.4; charset=utf-8"

/* The printers as a scrape reports them. */
struct metrics_printer {
    char name[64];
    char host[STORE_HOST_NAME_MAX]; /* its host, "" on a single host (no host label) */
    enum printer_state state;
    bool temps;             /* nozzle_c and bed_c are known (not offline) */
    double nozzle_c, bed_c; /* deg C */
};
/* f's printers now (f NULL: none) into *out (free() it), *n their count; SF_ENOMEM.  On one
   of several hosts, the other hosts' printers too, as they published them (farm_view.h):
   offline while their host is down. */
int metrics_printers(struct farm *f, struct metrics_printer **out, size_t *n);

/* The exposition text (free() it) from s, n printers and the farm's health h (taken on
   the loop: farm_health; NULL leaves those series out), or NULL with err set. */
char *metrics_render(struct store *s, const struct metrics_printer *printers, size_t n,
                     const struct farm_health *h, struct sf_err *err);

#endif
