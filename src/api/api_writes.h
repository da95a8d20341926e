/*
 * api_writes.h - the API's writes to jobs and its printer actions, each
 * answered once what it wrote has committed on the farm's store queue
 * (storeq.h): the loop does not wait for the store (issue 32: SQLite's
 * write lock held by another process, PostgreSQL's network).  A group of
 * the route table (route.h) placed before api.c's rows:
 *
 *   POST  /api/jobs               multipart 'file' (the part) and 'options' -> 201 {"job"}
 *   PATCH /api/jobs/ID            {"priority": N}
 *   POST  /api/jobs/ID/move       {"by": -1 | 1}: one place up or down among the waiting jobs
 *   POST  /api/jobs/ID/cancel     a job on a printer stops it (printer_action_then)
 *   POST  /api/jobs/ID/restart    an interrupted job's copy prints again from the start
 *   POST  /api/jobs/ID/resume     {"line": N} (optional): an interrupted job continues
 *   POST  /api/jobs/ID/again      a new job from the same file and options -> 201 {"job"}
 *
 * The request waits (http_defer) while its write runs on the store's
 * thread, in order with the farm's own; then it is answered with the job
 * as it is (api.c's answer).  Without a farm (an API over a store alone)
 * or out of memory a write runs on the loop and is answered at once, as
 * before.  Statuses as jobctl.h maps them.
 *
 * Thread: the loop thread; the writes' store parts on the farm's store
 * thread.
 */
#ifndef SF_API_API_WRITES_H
#define SF_API_API_WRITES_H

#include <stddef.h>
#include <stdint.h>

#include "../farm/farm.h"
#include "../farm/store.h"
#include "http.h"
#include "route.h"

/* An upload in progress (api.c's sink): the store's writer, until a route commits it. */
struct upload {
    struct store_file *f; /* NULL once committed */
    size_t size;          /* bytes written */
    char name[64];        /* the file name, clipped, for messages */
};

struct api_write;

/* The writes' view of the API (api.c's), and the writes waiting for the store. */
struct api_writes {
    struct store *store; /* the loop's connection: reads for the answers */
    struct farm *farm;   /* NULL: no store queue, writes on the loop */
    /* the job id as it is now (with its prints and time left), or the failure */
    void (*job)(void *ud, int64_t id, struct http_resp *resp);
    /* what only the loop knows of job id, added to its answer read off the loop (time left) */
    void (*job_more)(void *ud, int64_t id, struct http_resp *resp);
    /* the printer called name as it is now */
    void (*printer)(void *ud, const char *name, struct http_resp *resp);
    void (*changed)(void *ud); /* something changed: wake the streams */
    void *ud;
    struct api_write *pending; /* answers to come */
};

/* The rows; their handlers take the struct api_writes * as ctx. */
const struct route *api_writes_routes(size_t *n);

/*
 * POST /api/printers/NAME/ACTION: act on printer name (jobctl_printer_action_then), answered
 * once its writes committed with the printer as it is; who: the operator (route_key_label),
 * carried with the command to another host's printer.
 */
void api_writes_printer_act(struct api_writes *ws, const char *name, enum printer_action act,
                            const char *who, struct http_resp *resp);

/*
 * POST /api/printers/NAME/command: printer name's manual command (jobctl_printer_command_then),
 * answered once sent (the store read whether it holds an interrupted job) with the printer as
 * it is and the command; a refusal as jobctl.h maps it.
 */
void api_writes_printer_cmd(struct api_writes *ws, const char *name, const char *line,
                            const char *who, struct http_resp *resp);

/* The API is freed: the answers still to come (the farm's queue calls back later, when the
   daemon stops) go to no one. */
void api_writes_orphan(struct api_writes *ws);

#endif
