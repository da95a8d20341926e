/*
 * store_view.h - what each host shows the others of its own printers
 * (issue 32, "one farm from every host").
 *
 * A host's printers live in its process: their temperatures, whether they
 * are enabled, their message and time left are nowhere in the database.
 * Each host publishes them as one row of its own (host_views: a JSON
 * object, printer name -> that printer as its own `GET /api/printers`
 * shows it), and NOTIFYs STORE_VIEW_CHANNEL with its name, so the other
 * hosts read it again (store_command_printers joins it) instead of
 * polling.  The row is written only by the process that holds the host's
 * name (its token), and read only while that token is current, so a
 * host that died and joined again never shows its predecessor's view.
 *
 * Cost, why one row a host and not a column a printer: one statement per
 * publish, whatever the host's printers; the publisher writes only when
 * what it shows changed, at most every few seconds (farm_view.h), never a
 * sample at a time.
 *
 * STORE_EVENT_CHANNEL: every event the store logs NOTIFYs it (in the
 * event's own INSERT: no statement more), so a host's event stream
 * carries the other hosts' events as they commit.
 *
 * On SQLite (one host) the table exists and is written the same way; no
 * notification goes out.  Thread: the store's, as store.h.
 */
#ifndef SF_FARM_STORE_VIEW_H
#define SF_FARM_STORE_VIEW_H

#include <stdint.h>

#include "../base/err.h"
#include "store.h"

#define STORE_VIEW_CHANNEL  "slimfarm_view"
#define STORE_EVENT_CHANNEL "slimfarm_events"
#define STORE_VIEW_MAX      2048 /* one printer's published object, bytes with its NUL */

/*
 * Host host (token: its join's) publishes view, a JSON object of its
 * printers (not checked here), and wakes the other hosts.  SF_ESTALE when
 * token is not host's current one (another process holds the name, or the
 * host was reaped): nothing written; SF_EIO.
 */
int store_view_publish(struct store *s, const char *host, int64_t token, const char *view,
                       struct sf_err *err);

#endif
