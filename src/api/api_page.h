/*
 * api_page.h - GET /api/jobs in pages: its query parameters, strictly
 * parsed, and one page's JSON, bounded in size.
 *
 *   limit=N        jobs a page, 1 .. API_PAGE_LIMIT_MAX (default API_PAGE_LIMIT)
 *   cursor=C       where the previous page ended (its "next_cursor"); opaque
 *   state=S[,S]    only jobs in these states (job.h names)
 *   printer=NAME   only jobs on that printer now or printed on it
 *   since=MS       only jobs last changed at or after MS (ms since the epoch)
 *   until=MS       only jobs last changed before MS
 *   order=asc|desc oldest first (default) or newest first, by id
 *   name=TEXT      only jobs whose name holds TEXT (ASCII case aside)
 *   format=csv     the jobs as CSV (api_csv.h) rather than a JSON page
 *
 * The answer: {"jobs": [...], "next_cursor": C or null, "next": "/api/jobs?..."
 * or null}: "next" repeats the filters with the cursor, and is null on the
 * last page.  Ids only grow, so a walk sees every job that exists when it
 * starts exactly once, and the jobs added meanwhile at the end of an
 * oldest-first walk.
 *
 * Thread: any; api_page_render on the thread of the store it is given.
 */
#ifndef SF_API_API_PAGE_H
#define SF_API_API_PAGE_H

#include <stdbool.h>
#include <stddef.h>

#include "../base/err.h"
#include "../farm/job.h"
#include "../farm/store.h"

#define API_PAGE_LIMIT     100            /* a page without limit= */
#define API_PAGE_LIMIT_MAX STORE_PAGE_MAX /* jobs a page at most */
/* A page's JSON at most: a page ends early rather than grow past it (a job is
   ~0.7 KB, so only jobs with long escaped names and reasons reach it). */
#define API_PAGE_BYTES_MAX (512 << 10)

/* A parsed query. */
struct api_page_query {
    struct store_job_filter f; /* f.printer points at printer, f.name at name */
    size_t limit;              /* jobs a page */
    bool limit_given;          /* limit= was in the query */
    bool csv;                  /* format=csv */
    char printer[64];
    char name[JOB_NAME_MAX];
};

/*
 * Parse GET /api/jobs's raw query string (NULL or "": every default) into
 * q.  SF_EINVAL naming the parameter: an unknown or repeated one, a value
 * out of range, a state that does not exist, a cursor not made by us or
 * for the other order.
 */
int api_page_parse(const char *query, struct api_page_query *q, struct sf_err *err);

/*
 * One page of jobs for q from s, as JSON text (free() it) of *len bytes,
 * at most API_PAGE_BYTES_MAX.  NULL with err set on a store failure.
 */
char *api_page_render(struct store *s, const struct api_page_query *q, size_t *len,
                      struct sf_err *err);

#endif
