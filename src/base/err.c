/*
 * err.c - status names and the error-message helpers of err.h.
 *
 * Messages are formatted straight into the caller's fixed buffer, so setting
 * an error never allocates and works after an allocation failure.
 */
#include "err.h"

#include <errno.h>
#include <stdio.h>
#include <string.h>

void
sf_err_clear(struct sf_err *err)
{
    if (!err)
        return;
    err->code = SF_OK;
    err->sys_errno = 0;
    err->msg[0] = '\0';
}

static int
err_vset(struct sf_err *err, int code, int sys_errno, const char *fmt, va_list ap)
{
    if (!err)
        return code;
    err->code = code;
    err->sys_errno = sys_errno;
    vsnprintf(err->msg, sizeof(err->msg), fmt, ap);
    return code;
}

int
sf_err_set(struct sf_err *err, int code, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    err_vset(err, code, 0, fmt, ap);
    va_end(ap);
    return code;
}

int
sf_err_sys(struct sf_err *err, const char *fmt, ...)
{
    int saved = errno;
    va_list ap;
    va_start(ap, fmt);
    err_vset(err, SF_EIO, saved, fmt, ap);
    va_end(ap);
    if (err) {
        size_t len = strlen(err->msg);
        snprintf(err->msg + len, sizeof(err->msg) - len, ": %s", strerror(saved));
    }
    errno = saved;
    return SF_EIO;
}

int
sf_err_prefix(struct sf_err *err, const char *fmt, ...)
{
    char head[SF_ERR_MSG_MAX];
    char old[SF_ERR_MSG_MAX];
    va_list ap;

    if (!err)
        return SF_EBUG;
    va_start(ap, fmt);
    vsnprintf(head, sizeof(head), fmt, ap);
    va_end(ap);
    memcpy(old, err->msg, sizeof(old));
    snprintf(err->msg, sizeof(err->msg), "%s: %s", head, old);
    return err->code;
}

const char *
sf_status_name(int code)
{
    switch (code) {
    case SF_OK:
        return "OK";
    case SF_EINVAL:
        return "EINVAL";
    case SF_EIO:
        return "EIO";
    case SF_ENOMEM:
        return "ENOMEM";
    case SF_EUNSUPP:
        return "EUNSUPP";
    case SF_EAGAIN:
        return "EAGAIN";
    case SF_ETIMEDOUT:
        return "ETIMEDOUT";
    case SF_ECANCELED:
        return "ECANCELED";
    case SF_EBUG:
        return "EBUG";
    case SF_ENOTFOUND:
        return "ENOTFOUND";
    case SF_EUNREACH:
        return "EUNREACH";
    case SF_ESTALE:
        return "ESTALE";
    case SF_EINDOUBT:
        return "EINDOUBT";
    case SF_EBUSY:
        return "EBUSY";
    }
    return code > 0 ? "count" : "unknown";
}
