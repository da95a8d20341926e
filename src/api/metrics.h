/*
 * metrics.h - the farm in Prometheus text exposition format 0.0.4, for
 * GET /metrics (api_compat.h): every figure read from the store and the
 * printers at scrape time, so counters survive restarts and never go
 * backwards (jobs and prints are never deleted).
 *
 *   slimfarm_jobs{state}                      gauge: jobs by state (all 9 states)
 *   slimfarm_printers{state}                  gauge: configured printers by state
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
 *
 * Thread: the loop thread (the store's).
 */
#ifndef SF_API_METRICS_H
#define SF_API_METRICS_H

#include "../base/err.h"
#include "../farm/farm.h"
#include "../farm/store.h"

#define METRICS_CONTENT_TYPE "text/plain; version=0.0.4; charset=utf-8"

/* The exposition text (free() it), or NULL with err set.  farm may be NULL. */
char *metrics_render(struct store *s, struct farm *f, struct sf_err *err);

#endif
