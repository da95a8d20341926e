/*
 * store_command.h - an operator's action on a printer another host owns,
 * carried through the database (issue 32, "one farm from every host").
 *
 * The asking host writes a command row for the printer's owner (the host
 * whose config lists it: host_printers) with a deadline (the database's
 * clock: the hosts' clocks never judge it), and NOTIFYs
 * STORE_COMMAND_CHANNEL with the owner's name.  The owner takes its
 * pending rows (store_command_take: pending -> running, only those whose
 * deadline has not passed), runs each through its own printer action path
 * (every safety rule its own API has) and writes the result
 * (store_command_finish: running -> done, NOTIFY with the asker's name).
 * The asker reads the row back (store_command_get); once its deadline
 * passed it withdraws the row (store_command_expire: pending -> expired),
 * so an owner that comes late never runs it.  Both moves are conditional
 * single statements on the row's state: a row is taken or expired, never
 * both.
 *
 * On SQLite (one host) the table exists and stays empty: no other host
 * asks.  Errors: SF_EINVAL (bad argument, named), SF_ENOTFOUND (no such
 * printer or row), SF_ESTALE (the owner's lease ran out), SF_EIO from
 * the engine.  Thread: the store's, as store.h.
 */
#ifndef SF_FARM_STORE_COMMAND_H
#define SF_FARM_STORE_COMMAND_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"
#include "../base/limits.h"
#include "store.h"
#include "store_host.h"
#include "store_view.h"

#define STORE_COMMAND_CHANNEL  "slimfarm_commands"
#define STORE_COMMAND_LINE_MAX (SF_COMMAND_MAX + 1) /* a manual G-code line and its NUL */
#define STORE_COMMAND_KEEP_MS  3600000              /* finished rows are deleted after an hour */

enum store_command_state {
    STORE_CMD_PENDING = 0, /* written, the owner has not taken it */
    STORE_CMD_RUNNING,     /* the owner took it and acts */
    STORE_CMD_DONE,        /* the owner wrote its result */
    STORE_CMD_EXPIRED,     /* its deadline passed untaken: it never runs */
};
const char *store_command_state_name(enum store_command_state s);

/* A command row (plain data). */
struct store_command {
    int64_t id;
    char printer[64];
    char host[STORE_HOST_NAME_MAX];    /* the owner, who runs it */
    char from[STORE_HOST_NAME_MAX];    /* the host that asked */
    char kind[24];                     /* a printer action ("pause"...), "cancel-job",
                                          "command" or "emergency-stop" */
    char line[STORE_COMMAND_LINE_MAX]; /* kind "command": the G-code line; "cancel-job": the
                                          job's id (decimal) */
    char who[64];                      /* the operator (an API key's label) */
    enum store_command_state state;
    int rc;                          /* once done: SF_OK or the owner's error code, */
    char message[256];               /* its message, */
    char printer_state[16];          /* and the printer's state after it */
    int64_t created_ms, deadline_ms; /* the database's clock (ms since the epoch) */
    int64_t left_ms; /* store_command_take's: its deadline's distance from the take (> 0) */
};

/*
 * Ask printer's owner to run kind (line, who: may be NULL) for host from,
 * within wait_ms (> 0) of the database's clock now (the row's deadline_ms:
 * the database's clock judges it, never a host's): the row into *out, and
 * a NOTIFY to the owner, in one transaction.  now_ms: this host's wall
 * clock, which judges the owner's lease (as the leases are written).  SF_ENOTFOUND: no live or dead
 * host owns printer; SF_ESTALE: its owner's lease ran out (the message names the host and how long
 * ago: "host down"; not SF_EUNREACH, which the store queue takes for its connection lost and tries
 * again); SF_EINVAL: from owns printer itself, or a bad argument.  Rows finished over
 * STORE_COMMAND_KEEP_MS ago are deleted on the way.
 */
int store_command_add(struct store *s, const char *from, const char *printer, const char *kind,
                      const char *line, const char *who, int64_t now_ms, int64_t wait_ms,
                      struct store_command *out, struct sf_err *err);

/*
 * Host's pending commands whose deadline is after the database's clock
 * now, moved to running in one statement, into *rows (free() it; oldest
 * first; each with left_ms); its pending ones past their deadline become
 * expired on the way.
 */
int store_command_take(struct store *s, const char *host, struct store_command **rows, size_t *n,
                       struct sf_err *err);

/*
 * The result of running command id: rc, message (may be NULL), the
 * printer's state after (may be NULL); running -> done, and a NOTIFY to the
 * asker.  SF_ENOTFOUND when id is not running (nothing written).
 */
int store_command_finish(struct store *s, int64_t id, int rc, const char *message,
                         const char *printer_state, struct sf_err *err);

/* Command id into *out; SF_ENOTFOUND. */
int store_command_get(struct store *s, int64_t id, struct store_command *out, struct sf_err *err);

/*
 * Withdraw command id if it is still pending (-> expired: the owner never
 * takes it), then the row as it is into *out (its state says which:
 * expired now, or running or done already).  SF_ENOTFOUND.
 */
int store_command_expire(struct store *s, int64_t id, struct store_command *out,
                         struct sf_err *err);

/* A printer another host owns, as that host last wrote it (plain data). */
struct store_command_printer {
    char name[64];
    char host[STORE_HOST_NAME_MAX]; /* its owner */
    char state[16];                 /* printer_state_name, as the owner wrote it ("" if never) */
    bool live;                      /* the owner's lease runs */
    int64_t down_ms;                /* when not live: how long ago the lease ran out */
    bool bed_full;
    int64_t job_id;                   /* the job printing or paused on it, 0 if none, */
    int64_t lines_acked, gcode_lines; /* and how far it is */
    char view[STORE_VIEW_MAX];        /* the printer as its owner last published it (store_view.h: a
                                         JSON object), "" when not published by its current process */
};

/*
 * Every printer a host other than me owns, by name, as of now_ms, into
 * *rows (free() it): what `GET /api/printers` on me lists beside its own.
 */
int store_command_printers(struct store *s, const char *me, int64_t now_ms,
                           struct store_command_printer **rows, size_t *n, struct sf_err *err);

/*
 * The wake-ups: LISTEN on STORE_COMMAND_CHANNEL, STORE_VIEW_CHANNEL and
 * STORE_EVENT_CHANNEL (store_view.h) on a connection kept for it; drain
 * hands each notification's channel and payload (a host name; "" for an
 * event) to fn and returns how many (>= 0), or SF_EIO when the connection
 * is lost (call it again later: it reconnects); notify_fd is the socket to
 * watch (-1: none).  No-ops on SQLite.
 */
typedef void (*store_command_note_fn)(void *ud, const char *channel, const char *payload);
int store_command_listen(struct store *s, struct sf_err *err);
int store_command_drain(struct store *s, store_command_note_fn fn, void *ud);
int store_command_notify_fd(struct store *s);

#endif
