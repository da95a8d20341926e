/*
 * notify.h - tells the operator when the farm needs them: a job done or
 * failed, a bed to clear, a printer in error or gone offline, the queue
 * run empty.  Each [notify NAME] section of farm.ini (notifycfg.h) is a
 * webhook (one POST per event) or an SMTP relay (one mail per event).
 *
 * Where events come from: the store's event log, read after the last id
 * seen (an indexed range, at most NOTIFY_BATCH rows a turn), when
 * notify_kick says the farm logged something and on a slow timer for the
 * rest.  Where they go: the loop's shared libcurl client (httpc.h), so a
 * slow or dead service never blocks the loop that feeds the printers.  A
 * failed attempt (no answer, or a status that is not 2xx) is tried again
 * after 1, 2, 4 ... s (at most 60 s between tries), up to the target's
 * retries; then dropped with a warning.
 *
 * Delivery: at least once within a run, up to the retries (an attempt the
 * service took but whose answer was lost is sent again); at most once
 * across a restart: the daemon starts reading at the newest event, so
 * events logged while it was down, and tries pending when it stopped, are
 * not sent.  Logs name the target by its section, never its url, token
 * or password.
 *
 * Thread: the loop thread.  Owns its copy of the targets and every
 * pending delivery.
 */
#ifndef SF_FARM_NOTIFY_H
#define SF_FARM_NOTIFY_H

#include <stddef.h>

#include "../base/err.h"
#include "../base/loop.h"
#include "notifycfg.h"
#include "store.h"

#define NOTIFY_BATCH       64   /* events read from the log per turn */
#define NOTIFY_PENDING_MAX 256  /* deliveries waiting or in flight; more are dropped, logged */
#define NOTIFY_POLL_MS     1000 /* log read when no kick came (events the farm did not signal) */
#define NOTIFY_BACKOFF_MS  1000 /* first retry's delay; doubled per try */
#define NOTIFY_BACKOFF_MAX 60000

struct notify;

/*
 * Start sending the events logged from now on to targets (copied): from
 * the newest event when its read runs, on q's thread (as notify_set_queue;
 * so after every request posted to q before) or, q NULL, now on s.  Until
 * it has run nothing is told (a read that fails is tried again at the next
 * poll).  s and l must outlive it.  NULL with err set (SF_ENOMEM, or the
 * curl client's error).
 */
struct storeq;
struct notify *notify_new(struct loop *l, struct store *s, struct storeq *q,
                          const struct notifycfg *targets, size_t n_targets, struct sf_err *err);

/* Cancel every pending delivery (not sent) and free.  NULL is fine. */
void notify_free(struct notify *n);

/* Use these targets from now on (copied); deliveries already pending keep theirs. */
int notify_reload(struct notify *n, const struct notifycfg *targets, size_t n_targets,
                  struct sf_err *err);

/*
 * One of several hosts on a shared store (farm_host.h), named host: every
 * host reads the whole farm's log, and tells the operator only of the
 * events it is the teller of (store_host_teller: the job's holder, the
 * printer's owner, else the first live host by name; the queue running
 * empty by that first host), so each event is told once per farm.  ""
 * (the default): one host, which tells of every event.
 */
void notify_set_host(struct notify *n, const char *host);

/*
 * Read the log on q's thread (the farm's store queue, storeq_read), so the
 * loop's own connection sends nothing for it; NULL: on the store
 * notify_new was given, on the loop.  q must outlive the reads posted to
 * it: set NULL before freeing it (storeq_free delivers what is in flight).
 */
void notify_set_queue(struct notify *n, struct storeq *q);

/* New events may be in the log: read them on the next loop turn. */
void notify_kick(struct notify *n);

/* Deliveries waiting for a retry or in flight (tests). */
size_t notify_pending(const struct notify *n);

#endif
