/*
 * drv_octoprint_int.h - internal to the OctoPrint driver: its state, which
 * drv_octoprint.c (the REST side) and drv_octoprint_push.c (the push
 * socket) share.  Not for other modules.
 *
 * The push socket: once a poll has answered, the driver logs in passively
 * (POST /api/login {"passive": true} with the API key: the user's name and
 * a session) and opens OctoPrint's push socket, /sockjs/websocket (SockJS's
 * raw transport: one JSON message a frame), authenticates it with
 * {"auth": "name:session"}, and reads its `current` and `history` messages
 * (state, job, progress, temperatures: what GET /api/job and /api/printer
 * say) into the status the polls fill; while it stands they take the
 * polls' place (netpush.h: the lifecycle shared with Moonraker's driver).
 * A print's end (PrintDone, PrintFailed, PrintCancelled events) asks one
 * poll to confirm it over REST, as an action does.  An OctoPrint without
 * /api/login (before 1.3.10: 404) is polled only.
 *
 * Thread: the loop thread.
 */
#ifndef SF_DRIVERS_NET_DRV_OCTOPRINT_INT_H
#define SF_DRIVERS_NET_DRV_OCTOPRINT_INT_H

#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>

#include "../../src/base/limits.h"
#include "drv_octoprint.h"
#include "httpc.h"
#include "netdrv.h"
#include "netpush.h"

enum { RQ_PRINTER = NETDRV_RQ_OWN, RQ_SELECT, RQ_COMMAND, RQ_LOGIN };

struct octo {
    struct netdrv n;
    const char *hdrs[2];         /* the key, NULL */
    const char *json_hdrs[3];    /* the key, Content-Type: application/json, NULL */
    bool ready;                  /* /api/version answered since the last loss of contact */
    struct octo_job last;        /* the last /api/job (attach reads it) */
    bool saw_printing;           /* OctoPrint was seen printing our job (or we re-attached) */
    int missing_polls;           /* polls without it where it should be */
    char cmd[SF_GCODE_LINE_MAX]; /* the manual command waiting, or the last one sent */
    bool want_cmd;               /* it waits for the slot */
    FILE *cur;                   /* the job file, read up to OctoPrint's file position */
    int64_t cur_pos;             /* bytes of it counted */
    uint64_t cur_lines;          /* command lines in those bytes */
    char *cur_buf;               /* getline buffer */
    size_t cur_cap;
    /* the push socket (drv_octoprint_push.c) */
    struct netpush push;
    char auth[256];         /* "name:session" from the passive login, "" before it */
    bool no_login;          /* /api/login is not there: poll until contact is lost */
    char peer_ip[64];       /* the address the last poll reached */
    struct octo_job ws_job; /* the job as the socket told it last */
    struct octo_printer ws_printer;
    int throttle; /* the throttle the socket was last asked for, 0 before it opened */
};

/* Request kind in the free slot (its route, the key); false if it could not. */
bool octo_start(struct netdrv *n, int kind);
/* Judge o->last (a poll's or the socket's) and report it. */
void octo_evaluate(struct octo *o);
/* The temperatures of p into the status. */
void octo_temps(struct octo *o, const struct octo_printer *p);

/* After a poll: log in or open the socket, if the slot is free and there is none; the socket's
   rate follows the printer's state. */
void octo_push_kick(struct octo *o);
/* The reply to POST /api/login. */
void octo_push_login_reply(struct octo *o, const struct httpc_result *res);
/* Judge what the socket said last, if it is new and may be judged now. */
void octo_push_apply(struct octo *o);
/* Close the socket (why: logged, polling takes over; NULL: quietly). */
void octo_push_close(struct octo *o, const char *why);

#endif
