/*
 * buf.h - a growable byte buffer with a hard cap.
 *
 * Every buffer fed from outside (a printer's reply stream, an HTTP body, a
 * file read into memory) has a cap, so a peer that never stops talking costs
 * an error, not all of memory.  The contents are always NUL-terminated (not
 * counted in len) so text can be used in place.  buf_take() hands the bytes
 * to the caller, who frees them with free().
 *
 * Not thread-safe: one owner at a time.
 */
#ifndef SF_BASE_BUF_H
#define SF_BASE_BUF_H

#include <stdbool.h>
#include <stddef.h>

#include "err.h"

struct buf {
    char *data; /* len bytes plus a NUL; NULL until first growth */
    size_t len; /* bytes held */
    size_t cap; /* bytes allocated (including the NUL) */
    size_t max; /* hard cap on len; 0 = SIZE_MAX */
};

/* Initialise an empty buffer that may hold at most max bytes (0: no cap). */
void buf_init(struct buf *b, size_t max);

/* Free the contents; b may be reused after buf_init. */
void buf_release(struct buf *b);

/* Append n bytes.  SF_ENOMEM if memory or the cap runs out (b unchanged). */
int buf_append(struct buf *b, const void *data, size_t n);

/* Append formatted text; SF_ENOMEM as buf_append. */
int buf_printf(struct buf *b, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

/* Drop the first n bytes (n > len drops all). */
void buf_consume(struct buf *b, size_t n);

/* Empty the buffer, keeping its memory. */
void buf_reset(struct buf *b);

/* Take the bytes (NUL-terminated; free() them) and leave b empty. */
char *buf_take(struct buf *b, size_t *len);

/*
 * Read a whole file into b, up to b's cap.  SF_EIO on a read error,
 * SF_ENOMEM if the file is larger than the cap (message names the file and
 * the cap).
 */
int buf_read_file(struct buf *b, const char *path, struct sf_err *err);

#endif
