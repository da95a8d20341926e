/*
 * err.h - the error vocabulary every slimfarm module speaks.
 *
 * Functions that can fail return an enum sf_status (negative on failure,
 * SF_OK = 0, positive values may carry counts) and, when they handle input
 * from outside, take a trailing `struct sf_err *err` (NULL allowed) that
 * receives a one-line message saying where and what went wrong, in git's
 * style: "stl 'part.stl': facet 12: normal is NaN".  There is no global
 * "last error" and errno is never the channel: sys_errno keeps it when the
 * failure came from the OS.
 *
 * Thread-safe: no shared state.
 */
#ifndef SF_BASE_ERR_H
#define SF_BASE_ERR_H

#include <stdarg.h>

enum sf_status {
    SF_OK = 0,
    SF_EINVAL = -1,    /* bad input from outside (file, request, reply) */
    SF_EIO = -2,       /* OS or device failure; sys_errno holds errno */
    SF_ENOMEM = -3,    /* allocation failed or a size cap was hit */
    SF_EUNSUPP = -4,   /* valid but not supported */
    SF_EAGAIN = -5,    /* try again later (would block, busy) */
    SF_ETIMEDOUT = -6, /* a deadline passed */
    SF_ECANCELED = -7, /* cancelled by request */
    SF_EBUG = -8,      /* a broken internal invariant */
    SF_ENOTFOUND = -9, /* a named thing does not exist */
    SF_EUNREACH = -10, /* a device does not answer now (an offline printer) */
    SF_ESTALE = -11,   /* a lease or fencing token another process has since replaced */
    SF_EINDOUBT = -12, /* an outcome nobody knows (a commit the connection was lost during):
                          read it back before trying again */
    SF_EBUSY = -13,    /* a database busy or locked: nothing applied, try again (not SF_EAGAIN,
                          which the job rules use for "not in this state": a refusal) */
};

#define SF_ERR_MSG_MAX 256

struct sf_err {
    int code;                 /* enum sf_status of the failure, SF_OK if none */
    int sys_errno;            /* errno when code is SF_EIO, else 0 */
    char msg[SF_ERR_MSG_MAX]; /* human-readable, no trailing newline */
};

/* Clear err (if non-NULL) to SF_OK and an empty message. */
void sf_err_clear(struct sf_err *err);

/*
 * Record a failure in err (if non-NULL) and return code, so that a failure
 * is a one-line `return sf_err_set(err, SF_EINVAL, "...", ...)`.  The
 * message is truncated to SF_ERR_MSG_MAX - 1 bytes.
 */
int sf_err_set(struct sf_err *err, int code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

/* As sf_err_set, for code SF_EIO, also keeping errno and appending strerror. */
int sf_err_sys(struct sf_err *err, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

/*
 * Put "prefix: " before the message already in err, for adding context on
 * the way up ("job 12: " + "stl 'a.stl': ...").  Returns err->code (or
 * SF_EBUG if err is NULL).
 */
int sf_err_prefix(struct sf_err *err, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

/* The short name of a status code ("EINVAL"), never NULL. */
const char *sf_status_name(int code);

#endif
