/*
 * api_stats.h - GET /api/stats?days=N: each printer's success rate, hours
 * printing and use per day over the last N UTC days (1 .. 90, default 7),
 * from the print history (store_print_stats):
 *
 *   {"days": N, "since": "2026-11-29T00:00:00Z", "since_ms": ...,
 *    "printers": [{"printer": "mk3", "prints": {"done": 40, "failed": 2,
 *      "cancelled": 1, "other": 0}, "success_rate": 0.952,
 *      "hours_printing": 61.5, "utilisation": [0.31, ...]}]}
 *
 * success_rate is done / (done + failed), null with neither; utilisation
 * is each day's printing time over the day's length (today's so far),
 * to 6 decimals; hours_printing to 2.
 *
 * Thread: api_stats_parse any; api_stats_read on the reader's thread.
 */
#ifndef SF_API_API_STATS_H
#define SF_API_API_STATS_H

#include "../base/err.h"
#include "../farm/store.h"
#include "http.h"

#define API_STATS_DAYS 7 /* days without days= */

/* The query: days.  SF_EINVAL naming the parameter. */
int api_stats_parse(const char *query, int *days, struct sf_err *err);

/* The answer for *(int *)ud days, as of now, into resp (an api_read_fn). */
void api_stats_read(struct store *s, void *ud, struct http_resp *resp);

/* The JSON for rows over days ending at now_ms (tests; NULL when out of memory). */
json_t *api_stats_json(const struct store_printer_stats *rows, size_t n, int days, int64_t now_ms);

#endif
