/*
 * api_csv.c - the job list as CSV (api_csv.h).
 *
 * Built from store_job_page a page at a time, so the rows cap bounds the
 * work as the page size bounds a JSON page; each job's prints (an indexed
 * lookup) give its printer and print time.  RFC 4180 quoting.
 *
 * Thread: the store's (the API's reader thread).
 */
#include "api_csv.h"

#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../base/buf.h"
#include "../farm/job.h"

/* One field: quoted when it holds a comma, quote or line break; a formula defused. */
static void
field(struct buf *b, const char *v, bool last)
{
    bool formula = strchr("=+-@", v[0]) && v[0];
    if (strpbrk(v, ",\"\r\n") || formula) {
        buf_printf(b, "\"%s", formula ? "'" : "");
        for (const char *p = v; *p; p++)
            buf_printf(b, *p == '"' ? "\"\"" : "%c", *p);
        buf_printf(b, "\"");
    } else {
        buf_printf(b, "%s", v);
    }
    buf_printf(b, last ? "\r\n" : ",");
}

static void
iso(int64_t ms, char out[32])
{
    out[0] = '\0';
    if (ms <= 0)
        return;
    time_t t = (time_t)(ms / 1000);
    struct tm tm;
    gmtime_r(&t, &tm);
    strftime(out, 32, "%Y-%m-%dT%H:%M:%SZ", &tm);
}

/* One job's row; its prints from s. */
static int
row(struct buf *b, struct store *s, const struct job_row *j, struct sf_err *err)
{
    struct print_row *p;
    size_t n;
    int rc = store_prints(s, j->id, &p, &n, err);
    if (rc)
        return rc;
    int64_t print_ms = 0;
    for (size_t i = 0; i < n; i++)
        if (p[i].ended_ms > p[i].started_ms)
            print_ms += p[i].ended_ms - p[i].started_ms;
    char id[24], created[32], finished[32], secs[24], copies[16], done[16], fil[32], saved[32];
    snprintf(id, sizeof(id), "%" PRId64, j->id);
    iso(j->created_ms, created);
    iso(job_state_terminal(j->state) ? j->updated_ms : 0, finished);
    snprintf(secs, sizeof(secs), "%.0f", (double)print_ms / 1000);
    snprintf(copies, sizeof(copies), "%d", j->counts.copies);
    snprintf(done, sizeof(done), "%d", j->counts.copies_done);
    snprintf(fil, sizeof(fil), "%.1f", j->filament_g * j->counts.copies_done);
    snprintf(saved, sizeof(saved), "%.1f", j->support_saved_g * j->counts.copies_done);
    const char *printer = n ? p[n - 1].printer : j->printer;
    const char *const cols[] = { id,
                                 j->opts.name,
                                 job_state_name(j->state),
                                 created,
                                 finished,
                                 secs,
                                 printer,
                                 j->opts.material,
                                 copies,
                                 done,
                                 fil,
                                 saved,
                                 j->reason };
    size_t nc = sizeof(cols) / sizeof(cols[0]);
    for (size_t i = 0; i < nc; i++)
        field(b, cols[i], i + 1 == nc);
    free(p);
    return SF_OK;
}

char *
api_csv_render(struct store *s, const struct api_page_query *q, size_t *len, char next_cursor[24],
               struct sf_err *err)
{
    size_t cap = q->limit_given ? q->limit : API_CSV_ROWS_MAX, done = 0;
    struct store_job_filter f = q->f;
    struct buf b;
    buf_init(&b, API_CSV_BYTES_MAX);
    buf_printf(&b, "id,name,state,created,finished,print_s,printer,material,copies,copies_done,"
                   "filament_g,support_saved_g,reason\r\n");
    next_cursor[0] = '\0';
    bool more = true;
    int rc = SF_OK;
    while (rc == SF_OK && more && done < cap) {
        struct job_row *rows;
        size_t n, want = cap - done < STORE_PAGE_MAX ? cap - done : STORE_PAGE_MAX;
        if ((rc = store_job_page(s, &f, want, &rows, &n, &more, err)))
            break;
        for (size_t i = 0; i < n && rc == SF_OK; i++) {
            size_t before = b.len;
            rc = row(&b, s, &rows[i], err);
            if (rc == SF_OK && b.len + 1024 > API_CSV_BYTES_MAX) { /* room for no other row */
                b.len = before;
                b.data[before] = '\0';
                more = true;
                n = i;
                break;
            }
            f.after_id = rows[i].id;
            done++;
        }
        free(rows);
        if (n < want)
            break;
    }
    if (rc) {
        buf_release(&b);
        return NULL;
    }
    if (more && done)
        snprintf(next_cursor, 24, "%c%" PRIx64, q->f.newest_first ? 'd' : 'a',
                 (uint64_t)f.after_id);
    char *out = buf_take(&b, len);
    if (!out)
        sf_err_set(err, SF_ENOMEM, "job list: out of memory");
    return out;
}
