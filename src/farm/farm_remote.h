/*
 * farm_remote.h - an operator's action on a printer another host owns
 * (issue 32, "one farm from every host"), over store_command.h's rows.
 *
 * The asking host: farm_remote_send writes a command row for the printer's
 * owner (on the store's thread: the loop never waits on the database) and
 * waits for its answer, read back when the owner's NOTIFY arrives; at
 * FARM_REMOTE_WAIT_MS it withdraws the row (it never runs late) and
 * answers SF_ETIMEDOUT.  The owner: a NOTIFY with its name takes its
 * pending rows and runs each through its own action path (jobctl.h: the
 * same checks and refusals as its own API), then writes the result.
 *
 * Each host listens on a connection of its own (store_command_listen on a
 * store_open_listener: its reconnect never waits for the network), watched
 * on the loop's epoll; a lost one is tried again every 200 ms, each try a
 * step of its connect.  Every
 * call is a no-op, or refuses, on a farm that is not one of several hosts.
 * Thread: the loop thread.
 */
#ifndef SF_FARM_FARM_REMOTE_H
#define SF_FARM_FARM_REMOTE_H

#include <stdbool.h>
#include <stdint.h>

#include "../base/err.h"

struct farm;

/* How long an asker waits for the owner's answer before it withdraws the command. */
#define FARM_REMOTE_WAIT_MS 10000

/* A command's outcome, on the loop. */
struct farm_remote_result {
    int rc;                   /* SF_OK, or the owner's refusal (its code), SF_ETIMEDOUT (no
                                 answer in time), SF_EUNREACH (its host is down), ... */
    const struct sf_err *err; /* rc's message */
    const char *printer;      /* the printer, */
    const char *host;         /* its owner ("" when not known), */
    const char *state;        /* and its state after the command ("" when not known) */
};
typedef void (*farm_remote_fn)(void *ud, const struct farm_remote_result *r);

/* Start listening (farm_host_start, once f is a host): SF_EIO, SF_ENOMEM. */
int farm_remote_start(struct farm *f, struct sf_err *err);
/* Stop: every waiting ask is answered SF_ECANCELED now; before f's store queue is freed. */
void farm_remote_stop(struct farm *f);

/* Is printer name another host's (f is one of several hosts, and has no printer of that name
   or another live host owns it: store_host_own)? */
bool farm_remote_is(const struct farm *f, const char *name);

/* The kind of a job's cancel by its id (line: the id, in decimal). */
#define FARM_REMOTE_CANCEL_JOB "cancel-job"

/*
 * Ask name's owner to run kind: a printer action ("pause", "resume",
 * "cancel", "cleared", "cancel-copy"), FARM_REMOTE_CANCEL_JOB (line, the
 * job's id: the owner cancels only while that job is the printer's, else
 * refuses SF_EAGAIN; a plain "cancel" stops whatever the printer prints
 * when it runs), "command" (line, a manual G-code line, from who) or
 * "emergency-stop" (from who).  SF_OK, then done(ud, r)
 * on the loop once answered (always, within about FARM_REMOTE_WAIT_MS plus
 * the store's time); or an error now (done not called): SF_EAGAIN (this
 * host has not joined yet), SF_EINVAL, SF_ENOMEM.
 */
int farm_remote_send(struct farm *f, const char *name, const char *kind, const char *line,
                     const char *who, farm_remote_fn done, void *ud, struct sf_err *err);

#endif
