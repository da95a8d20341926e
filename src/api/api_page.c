/*
 * api_page.c - GET /api/jobs's query and pages (see api_page.h).
 *
 * The cursor is the last id of the page with the walk's direction
 * ("a" oldest first, "d" newest first) before it, in hex: keyset paging,
 * so a page costs an index range however deep the walk, and a job added
 * meanwhile neither shifts nor repeats what follows.  The page is built as
 * text a job at a time, so its byte bound holds whatever the jobs hold.
 *
 * Thread: any (see the header).
 */
#include "api_page.h"

#include <ctype.h>
#include <inttypes.h>
#include <jansson.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/buf.h"
#include "../base/mem.h"
#include "../farm/job.h"
#include "api_json.h"
#include "route.h"

#define STR_(x)        #x
#define STR(x)         STR_(x)
#define LIMIT_MAX_TEXT STR(STORE_PAGE_MAX)
#define VALUE_MAX      200 /* a parameter's value, decoded; a printer name or nine states fit */

static const char *const params[] = { "limit", "cursor", "state", "printer", "since",
                                      "until", "order",  "name",  "format" };
#define N_PARAMS (sizeof(params) / sizeof(params[0]))

static int
hex_digit(char c)
{
    return isdigit((unsigned char)c) ? c - '0'
           : c >= 'a' && c <= 'f'    ? c - 'a' + 10
           : c >= 'A' && c <= 'F'    ? c - 'A' + 10
                                     : -1;
}

/* Percent-decode [s, s+n) ('+' is a blank) into out; false if malformed, too long or NUL. */
static bool
decode(const char *s, size_t n, char *out, size_t cap)
{
    size_t k = 0;
    for (size_t i = 0; i < n; i++) {
        char c = s[i];
        if (c == '%') {
            int hi = i + 2 < n ? hex_digit(s[i + 1]) : -1;
            int lo = i + 2 < n ? hex_digit(s[i + 2]) : -1;
            if (hi < 0 || lo < 0 || (hi == 0 && lo == 0))
                return false;
            c = (char)(hi << 4 | lo);
            i += 2;
        } else if (c == '+') {
            c = ' ';
        }
        if (k + 1 >= cap)
            return false;
        out[k++] = c;
    }
    out[k] = '\0';
    return true;
}

static int
bad(struct sf_err *err, const char *param, const char *value, const char *why)
{
    char v[64];
    return sf_err_set(err, SF_EINVAL, "parameter '%s'%s%s%s: %s", param, value ? " ('" : "",
                      value ? route_clip(v, sizeof(v), value) : "", value ? "')" : "", why);
}

static int
parse_states(const char *v, unsigned *states, struct sf_err *err)
{
    *states = 0;
    for (const char *p = v;;) {
        size_t n = strcspn(p, ",");
        char name[16];
        enum job_state st;
        if (n == 0 || n >= sizeof(name))
            return bad(err, "state", v, "expected state names separated by commas");
        memcpy(name, p, n);
        name[n] = '\0';
        if (!job_state_parse(name, &st))
            return bad(err, "state", name,
                       "not a job state (queued, preparing, ready, printing, paused, done, "
                       "failed, cancelled, interrupted)");
        *states |= 1u << st;
        if (!p[n])
            return SF_OK;
        p += n + 1;
    }
}

static int
parse_one(struct api_page_query *q, size_t which, const char *v, char *order, int64_t *cursor,
          struct sf_err *err)
{
    int64_t num;
    const char *name = params[which];
    switch (which) {
    case 0: /* limit */
        if (!route_num(v, strlen(v), &num) || num < 1 || num > API_PAGE_LIMIT_MAX)
            return bad(err, name, v, "expected a number from 1 to " LIMIT_MAX_TEXT);
        q->limit = (size_t)num;
        q->limit_given = true;
        return SF_OK;
    case 1: /* cursor: a or d, then 1 to 16 hex digits */
        if ((v[0] != 'a' && v[0] != 'd') || strlen(v) < 2 || strlen(v) > 17 ||
            strspn(v + 1, "0123456789abcdef") != strlen(v) - 1)
            return bad(err, name, v, "not a cursor this server gave (use next_cursor as is)");
        *cursor = (int64_t)strtoull(v + 1, NULL, 16);
        *order = v[0];
        return *cursor > 0 ? SF_OK : bad(err, name, v, "not a cursor this server gave");
    case 2:
        return parse_states(v, &q->f.states, err);
    case 3: /* printer */
        if (!v[0] || strlen(v) >= sizeof(q->printer))
            return bad(err, name, v, "expected a printer name of 1 to 63 bytes");
        snprintf(q->printer, sizeof(q->printer), "%s", v);
        q->f.printer = q->printer;
        return SF_OK;
    case 4: /* since */
    case 5: /* until */
        if (!route_num(v, strlen(v), &num))
            return bad(err, name, v, "expected milliseconds since the epoch (0 or more)");
        *(which == 4 ? &q->f.since_ms : &q->f.until_ms) = num;
        return SF_OK;
    case 6: /* order */
        if (strcmp(v, "asc") != 0 && strcmp(v, "desc") != 0)
            return bad(err, name, v, "expected asc or desc");
        q->f.newest_first = v[0] == 'd';
        return SF_OK;
    case 7: /* name */
        if (strlen(v) >= sizeof(q->name))
            return bad(err, name, v, "expected 1 to 127 bytes of a job's name");
        snprintf(q->name, sizeof(q->name), "%s", v);
        q->f.name = q->name;
        return SF_OK;
    default: /* format */
        if (strcmp(v, "json") != 0 && strcmp(v, "csv") != 0)
            return bad(err, name, v, "expected json or csv");
        q->csv = v[0] == 'c';
        return SF_OK;
    }
}

int
api_page_parse(const char *query, struct api_page_query *q, struct sf_err *err)
{
    *q = (struct api_page_query){ .limit = API_PAGE_LIMIT };
    /* http.c keeps the first 255 bytes of a query: a longer one is not read in part */
    if (query && strlen(query) >= 255)
        return sf_err_set(err, SF_EINVAL, "query is over 254 bytes");
    bool seen[N_PARAMS] = { false };
    char order = 0; /* the cursor's */
    int64_t cursor = 0;
    for (const char *p = query; p && *p;) {
        size_t n = strcspn(p, "&"), k = strcspn(p, "=&");
        char key[64], v[VALUE_MAX];
        if (n == 0) { /* "a&&b" */
            p++;
            continue;
        }
        if (!decode(p, k, key, sizeof(key)))
            return sf_err_set(err, SF_EINVAL, "query: a parameter name is malformed or unknown");
        size_t which = 0;
        while (which < N_PARAMS && strcmp(key, params[which]) != 0)
            which++;
        char clipped[32];
        if (which == N_PARAMS)
            return sf_err_set(err, SF_EINVAL,
                              "unknown parameter '%s' (expected limit, cursor, state, printer, "
                              "since, until, order, name or format)",
                              route_clip(clipped, sizeof(clipped), key));
        if (seen[which])
            return bad(err, key, NULL, "given twice");
        seen[which] = true;
        if (k == n || !decode(p + k + 1, n - k - 1, v, sizeof(v)) || !v[0])
            return bad(err, key, NULL, "needs a value (malformed, empty or too long)");
        int rc = parse_one(q, which, v, &order, &cursor, err);
        if (rc)
            return rc;
        p += n + (p[n] == '&');
    }
    if (q->f.since_ms && q->f.until_ms && q->f.until_ms <= q->f.since_ms)
        return bad(err, "until", NULL, "must be after since");
    if (order && (order == 'd') != q->f.newest_first)
        return bad(err, "cursor", NULL,
                   q->f.newest_first ? "is from an order=asc walk" : "is from an order=desc walk");
    q->f.after_id = cursor;
    return SF_OK;
}

/* Append v to b percent-encoded (everything but unreserved characters). */
static void
put_encoded(struct buf *b, const char *v)
{
    for (const unsigned char *p = (const unsigned char *)v; *p; p++) {
        if (isalnum(*p) || strchr("-._~", *p))
            buf_printf(b, "%c", *p);
        else
            buf_printf(b, "%%%02X", *p);
    }
}

/* ,"next_cursor":...,"next":... for a page that ended at last_id (0: the last page). */
static int
put_next(struct buf *b, const struct api_page_query *q, int64_t last_id)
{
    if (!last_id)
        return buf_printf(b, ",\"next_cursor\":null,\"next\":null}");
    char cursor[24];
    snprintf(cursor, sizeof(cursor), "%c%" PRIx64, q->f.newest_first ? 'd' : 'a',
             (uint64_t)last_id);
    buf_printf(b, ",\"next_cursor\":\"%s\",\"next\":\"/api/jobs?limit=%zu", cursor, q->limit);
    if (q->f.newest_first)
        buf_printf(b, "&order=desc");
    if (q->f.states) {
        const char *sep = "&state=";
        for (int i = 0; i < JOB_STATE_COUNT; i++)
            if (q->f.states & (1u << i)) {
                buf_printf(b, "%s%s", sep, job_state_name((enum job_state)i));
                sep = ",";
            }
    }
    if (q->f.printer && q->f.printer[0]) {
        buf_printf(b, "&printer=");
        put_encoded(b, q->f.printer);
    }
    if (q->f.since_ms)
        buf_printf(b, "&since=%" PRId64, q->f.since_ms);
    if (q->f.until_ms)
        buf_printf(b, "&until=%" PRId64, q->f.until_ms);
    if (q->f.name && q->f.name[0]) {
        buf_printf(b, "&name=");
        put_encoded(b, q->f.name);
    }
    return buf_printf(b, "&cursor=%s\"}", cursor);
}

/* "last_printer": where job r's newest print ran ("" if none; last from
   store_last_printers, by job id): a finished job names no printer, the
   dashboard's Finished jobs show this one. */
static void
last_printer(const struct store_job_printer *last, size_t n_last, const struct job_row *r,
             json_t *j)
{
    size_t lo = 0, hi = n_last;
    while (lo < hi) { /* the first row with job_id >= r->id */
        size_t mid = lo + (hi - lo) / 2;
        if (last[mid].job_id < r->id)
            lo = mid + 1;
        else
            hi = mid;
    }
    if (j)
        json_object_set_new(
            j, "last_printer",
            json_string(lo < n_last && last[lo].job_id == r->id ? last[lo].printer : ""));
}

char *
api_page_render(struct store *s, const struct api_page_query *q, size_t *len, struct sf_err *err)
{
    struct job_row *rows;
    size_t n;
    bool more;
    int rc = store_job_page(s, &q->f, q->limit, &rows, &n, &more, err);
    if (rc)
        return NULL;
    struct store_job_printer *lp = NULL;
    size_t n_lp = 0;
    int64_t *ids = n ? mem_array(n, sizeof(*ids)) : NULL;
    if (n && !ids) {
        free(rows);
        sf_err_set(err, SF_ENOMEM, "out of memory listing a page");
        return NULL;
    }
    for (size_t k = 0; k < n; k++)
        ids[k] = rows[k].id;
    rc = n ? store_last_printers(s, ids, n, &lp, &n_lp, err) : SF_OK;
    free(ids);
    if (rc) {
        free(rows);
        return NULL;
    }
    /* room kept for the tail: the cursor and the next URL (~600 bytes at most) */
    const size_t tail = 1024, room = API_PAGE_BYTES_MAX - tail;
    struct buf b;
    buf_init(&b, API_PAGE_BYTES_MAX);
    buf_printf(&b, "{\"jobs\":[");
    int64_t last = 0;
    size_t i;
    for (i = 0; i < n; i++) {
        json_t *j = api_job_json(&rows[i]);
        last_printer(lp, n_lp, &rows[i], j);
        char *text = j ? json_dumps(j, JSON_COMPACT) : NULL;
        json_decref(j);
        size_t tlen = text ? strlen(text) : 0;
        bool fits = text && b.len + tlen + 1 <= room;
        if (fits)
            rc = buf_printf(&b, "%s%s", i ? "," : "", text);
        free(text);
        if (!fits || rc)
            break;
        last = rows[i].id;
    }
    free(rows);
    free(lp);
    if (rc == SF_OK && i == 0 && n > 0)
        rc = sf_err_set(err, SF_ENOMEM, "job list: out of memory"); /* no job is near the bound */
    else if (rc == SF_OK)
        rc = buf_printf(&b, "]") || put_next(&b, q, i < n || more ? last : 0) ? SF_ENOMEM : SF_OK;
    char *out = rc == SF_OK ? buf_take(&b, len) : NULL;
    if (rc == SF_OK && !out)
        rc = SF_ENOMEM;
    if (rc == SF_ENOMEM)
        sf_err_set(err, SF_ENOMEM, "job list: out of memory");
    buf_release(&b);
    return out;
}
