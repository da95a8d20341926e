/*
 * api_csv.h - GET /api/jobs?format=csv: the jobs a query selects
 * (api_page.h's filters and order) as CSV for a spreadsheet, one row a
 * job, bounded: at most the query's limit, or API_CSV_ROWS_MAX rows
 * without one, and API_CSV_BYTES_MAX bytes.  When more jobs pass, the
 * cursor to go on from is returned (the route sends it as X-Next-Cursor).
 *
 * Columns: id, name, state, created, finished (UTC, ISO 8601; finished
 * empty while the job lives), print_s (its prints' time, summed), printer
 * (its last print's), material, copies, copies_done, filament_g (used:
 * the estimate per copy times the copies done), support_saved_g (the
 * same), reason.  A field that a spreadsheet would take for a formula
 * (starting with = + - @) gets a leading '.
 *
 * Thread: the thread of the store it is given (the API's reader).
 */
#ifndef SF_API_API_CSV_H
#define SF_API_API_CSV_H

#include <stddef.h>

#include "../base/err.h"
#include "../farm/store.h"
#include "api_page.h"

#define API_CSV_ROWS_MAX  10000     /* a year of a busy farm's jobs in one file */
#define API_CSV_BYTES_MAX (4 << 20) /* rows are ~200 bytes: the rows cap comes first */

/*
 * The CSV text (free() it) of *len bytes; next_cursor gets the cursor
 * after the last row when more jobs pass ("" when none).  NULL with err
 * set on a store failure.
 */
char *api_csv_render(struct store *s, const struct api_page_query *q, size_t *len,
                     char next_cursor[24], struct sf_err *err);

#endif
