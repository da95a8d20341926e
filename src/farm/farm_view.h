/*
 * farm_view.h - the other hosts' printers as this host shows them, and
 * this host's printers as it shows them to the others (issue 32, "one farm
 * from every host"; store_view.h's rows).
 *
 * Publishing: the API hands farm_view_publish the text of this host's
 * printers (a JSON object by name) whenever it looks (each tick, each
 * event); it is written only when it differs from what was written last
 * (the API rounds what moves by the sample: temperatures to a degree,
 * progress to a percent, time left to a minute), at most every
 * FARM_VIEW_MIN_MS (the last change of a burst goes out at the end of
 * it), one statement on the store thread: never a write per sample, and
 * a print never waits on it.
 *
 * Reading: the cache of the other hosts' printers (store_command_printers,
 * their published views joined) is read again on the store thread when a
 * host publishes (its NOTIFY, heard by farm_remote's listener), and every
 * FARM_VIEW_REFRESH_MS while the cache is used (a lease running out sends
 * no NOTIFY): no polling while nothing reads it.
 *
 * Every call is a no-op on a farm that is not one of several hosts.
 * Thread: the loop thread.
 */
#ifndef SF_FARM_FARM_VIEW_H
#define SF_FARM_FARM_VIEW_H

#include <stddef.h>

#include "../base/err.h"
#include "store_command.h"

struct farm;

#define FARM_VIEW_MIN_MS     2000 /* the least time between two publishes of one host */
#define FARM_VIEW_REFRESH_MS 5000 /* the cache's re-read while used and not woken */

/* Start (farm_remote_start, once f is a host): SF_ENOMEM. */
int farm_view_start(struct farm *f, struct sf_err *err);
/* Stop: before f's store queue is freed (what is in flight comes back then, unheard). */
void farm_view_stop(struct farm *f);

/* Publish text (copied), this host's printers, if it changed (see above). */
void farm_view_publish(struct farm *f, const char *text);
/* Another host published (its NOTIFY), or the listener is back: read the cache again. */
void farm_view_heard(struct farm *f);
/*
 * The other hosts' printers as last read (*rows valid until the next loop turn), their count
 * (0 before the first read, or not a host).  Marks the cache used: it is kept fresh.
 */
size_t farm_view_printers(struct farm *f, const struct store_command_printer **rows);

#endif
