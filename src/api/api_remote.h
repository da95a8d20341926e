/*
 * api_remote.h - the API's actions on a printer another host owns (issue
 * 32): carried to the owner through the database (farm_remote.h), the
 * request's answer deferred until the owner's result comes back.
 *
 * Answers: 200 {"printer": {"name", "host", "state"}} (and "command" for a
 * manual G-code line) once the owner ran it; the owner's refusal with its
 * status (409 not now, 400 a refused G-code line, 503 its printer offline);
 * 503 when the owner's host is down (its lease ran out: nothing was sent);
 * 504 when the owner did not answer within FARM_REMOTE_WAIT_MS (the command
 * was withdrawn and will not run, or the message says the owner took it).
 *
 * Thread: the loop thread.
 */
#ifndef SF_API_API_REMOTE_H
#define SF_API_API_REMOTE_H

#include <stdbool.h>

#include "../farm/farm.h"
#include "api_read.h"
#include "http.h"

/*
 * If printer name is another host's (farm_remote_is), send kind (line, who:
 * farm_remote_send's) to it and answer resp (deferred, or an error now):
 * true.  False when name is not another host's: the caller acts itself.
 */
bool api_remote_try(struct farm *f, const char *name, const char *kind, const char *line,
                    const char *who, struct http_resp *resp);

/*
 * As api_remote_try, for a request deferred already (d): true when name is
 * another host's (d is answered later, or now with a refusal).  line: as
 * farm_remote_send's (a cancel-job's id), may be NULL; who: the operator, may be NULL.
 */
bool api_remote_answer(struct farm *f, const char *name, const char *kind, const char *line,
                       const char *who, struct http_defer *d);

/* The API's own printers (NULL name: all, as {"printers": [...]}; else {"printer": ...}),
   with the beds' state beds[n_beds] (read on reads' thread with the rest; none if unread). */
typedef void (*api_remote_local_fn)(void *ud, const char *name, const struct store_bed *beds,
                                    size_t n_beds, struct http_resp *resp);

/*
 * GET /api/printers (name NULL) or /api/printers/NAME on one of several
 * hosts: this host's own printers from local(ud, ...), each with "host"
 * (this host's name), and every printer another host owns as that host
 * last wrote it to the store (read on reads' thread: the loop never waits
 * on the database), with "host", "remote": true, and state "offline" and
 * a message saying the host is down when its lease ran out.  True when
 * answered (or deferred); false when f is not one of several hosts (the
 * caller answers as before).
 */
bool api_remote_printers(struct api_read *reads, struct farm *f, const char *name,
                         api_remote_local_fn local, void *ud, struct http_resp *resp);

#endif
