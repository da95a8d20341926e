/*
 * api_stats.c - GET /api/stats (api_stats.h): the query, and the store's
 * per-printer figures turned into rates, hours and a day series.
 *
 * Thread: see the header.
 */
#include "api_stats.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../base/clock.h"
#include "route.h"

int
api_stats_parse(const char *query, int *days, struct sf_err *err)
{
    *days = API_STATS_DAYS;
    if (!query || !query[0])
        return SF_OK;
    int64_t v;
    if (strncmp(query, "days=", 5) != 0 || strchr(query, '&'))
        return sf_err_set(err, SF_EINVAL, "unknown parameter (expected days=N)");
    if (!route_num(query + 5, strlen(query + 5), &v) || v < 1 || v > STORE_STATS_DAYS_MAX)
        return sf_err_set(err, SF_EINVAL, "parameter 'days': expected a number from 1 to %d",
                          STORE_STATS_DAYS_MAX);
    *days = (int)v;
    return SF_OK;
}

json_t *
api_stats_json(const struct store_printer_stats *rows, size_t n, int days, int64_t now_ms)
{
    int64_t since = store_stats_since_ms(now_ms, days);
    char iso[32];
    time_t t = (time_t)(since / 1000);
    struct tm tm;
    gmtime_r(&t, &tm);
    strftime(iso, sizeof(iso), "%Y-%m-%dT%H:%M:%SZ", &tm);
    json_t *printers = json_array();
    json_t *o = json_pack("{si ss sI so}", "days", days, "since", iso, "since_ms",
                          (json_int_t)since, "printers", printers);
    if (!o)
        return NULL;
    for (size_t i = 0; i < n; i++) {
        const struct store_printer_stats *r = &rows[i];
        json_t *use = json_array();
        for (int d = 0; use && d < days; d++) {
            /* today counts up to now, the other days whole */
            double len_s =
                d == days - 1 ? (double)(now_ms - (since + d * 86400000LL)) / 1000 : 86400;
            double u = len_s > 0 ? r->day_s[d] / len_s : 0;
            json_array_append_new(use, json_real((double)(int64_t)(u * 1e6 + 0.5) / 1e6));
        }
        uint64_t judged = r->done + r->failed;
        json_t *p = json_pack(
            "{ss s{sIsIsIsI} so sf so}", "printer", r->printer, "prints", "done",
            (json_int_t)r->done, "failed", (json_int_t)r->failed, "cancelled",
            (json_int_t)r->cancelled, "other", (json_int_t)r->other, "success_rate",
            judged ? json_real((double)r->done / (double)judged) : json_null(), "hours_printing",
            (double)(int64_t)(r->print_s / 36 + 0.5) / 100, "utilisation", use ? use : json_null());
        json_array_append_new(printers, p);
    }
    return o;
}

void
api_stats_read(struct store *s, void *ud, struct http_resp *resp)
{
    int days = *(int *)ud;
    struct store_printer_stats *rows;
    size_t n;
    struct sf_err err;
    int64_t now = clock_wall_ms();
    if (store_print_stats(s, now, days, &rows, &n, &err)) {
        http_fail(resp, err.code, err.msg);
        return;
    }
    resp->json = api_stats_json(rows, n, days, now);
    free(rows);
    if (!resp->json)
        http_error(resp, 500, "out of memory");
}
