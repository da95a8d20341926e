/*
 * buf.c - growable capped byte buffer (see buf.h).
 */
#include "buf.h"

#include <errno.h>
#include <fcntl.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "mem.h"

void
buf_init(struct buf *b, size_t max)
{
    b->data = NULL;
    b->len = 0;
    b->cap = 0;
    b->max = max ? max : SIZE_MAX - 1;
}

void
buf_release(struct buf *b)
{
    free(b->data);
    buf_init(b, b->max);
}

static int
buf_reserve(struct buf *b, size_t extra)
{
    if (extra > b->max - b->len)
        return SF_ENOMEM;
    size_t need = b->len + extra + 1;
    if (need <= b->cap)
        return SF_OK;
    void *p = b->data;
    size_t cap = b->cap;
    if (!mem_grow(&p, &cap, need, 1))
        return SF_ENOMEM;
    b->data = p;
    b->cap = cap;
    return SF_OK;
}

int
buf_append(struct buf *b, const void *data, size_t n)
{
    if (buf_reserve(b, n) != SF_OK)
        return SF_ENOMEM;
    if (n)
        memcpy(b->data + b->len, data, n);
    b->len += n;
    b->data[b->len] = '\0';
    return SF_OK;
}

int
buf_printf(struct buf *b, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(NULL, 0, fmt, ap);
    va_end(ap);
    if (n < 0)
        return SF_EINVAL;
    if (buf_reserve(b, (size_t)n) != SF_OK)
        return SF_ENOMEM;
    va_start(ap, fmt);
    vsnprintf(b->data + b->len, (size_t)n + 1, fmt, ap);
    va_end(ap);
    b->len += (size_t)n;
    return SF_OK;
}

void
buf_consume(struct buf *b, size_t n)
{
    if (n >= b->len) {
        buf_reset(b);
        return;
    }
    memmove(b->data, b->data + n, b->len - n);
    b->len -= n;
    b->data[b->len] = '\0';
}

void
buf_reset(struct buf *b)
{
    b->len = 0;
    if (b->data)
        b->data[0] = '\0';
}

char *
buf_take(struct buf *b, size_t *len)
{
    char *d = b->data;
    if (!d)
        d = mem_calloc(1, 1);
    if (len)
        *len = d ? b->len : 0;
    buf_init(b, b->max);
    return d;
}

int
buf_read_file(struct buf *b, const char *path, struct sf_err *err)
{
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0)
        return sf_err_sys(err, "cannot open '%s'", path);
    struct stat st;
    if (fstat(fd, &st) == 0 && S_ISDIR(st.st_mode)) {
        close(fd);
        return sf_err_set(err, SF_EINVAL, "'%s' is a directory", path);
    }
    if (fstat(fd, &st) == 0 && S_ISREG(st.st_mode) && (uintmax_t)st.st_size > b->max) {
        close(fd);
        return sf_err_set(err, SF_ENOMEM, "'%s' is %jd bytes, over the limit of %zu", path,
                          (intmax_t)st.st_size, b->max);
    }
    /* Read straight into the buffer: one copy from the page cache, no more. */
    size_t want = st.st_size > 0 ? (size_t)st.st_size + 1 : 65536;
    for (;;) {
        if (b->len == b->max) {
            char probe; /* at the cap: one more byte tells EOF from overflow */
            ssize_t n = read(fd, &probe, 1);
            close(fd);
            if (n == 0)
                return SF_OK;
            buf_reset(b);
            return sf_err_set(err, SF_ENOMEM, "'%s' is over the limit of %zu bytes", path, b->max);
        }
        if (b->cap - b->len <= 1 &&
            buf_reserve(b, want < b->max - b->len ? want : b->max - b->len) != SF_OK) {
            close(fd);
            return sf_err_set(err, SF_ENOMEM, "'%s' is over the limit of %zu bytes", path, b->max);
        }
        size_t room = b->cap - b->len - 1;
        if (room > b->max - b->len)
            room = b->max - b->len;
        ssize_t n = read(fd, b->data + b->len, room);
        if (n < 0 && errno == EINTR)
            continue;
        if (n < 0) {
            int rc = sf_err_sys(err, "cannot read '%s'", path);
            close(fd);
            return rc;
        }
        if (n == 0)
            break;
        b->len += (size_t)n;
        b->data[b->len] = '\0';
        want = 65536;
    }
    close(fd);
    return SF_OK;
}
