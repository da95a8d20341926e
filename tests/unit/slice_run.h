/*
 * slice_run.h - what the slicer tests do with a part: slice it into the test's
 * scratch dir, read the G-code back, or walk its moves through the
 * estimator (est_move_fn), which tells each move's type, layer and feed.
 * Header-only, for the slicer tests; parts come from slice_shapes.h or
 * src/mesh/shapes.h.
 */
#ifndef SF_TESTS_SLICE_RUN_H
#define SF_TESTS_SLICE_RUN_H

#include <stdbool.h>
#include <stdio.h>
#include <string.h>

#include "../../slicer/estimate.h"
#include "../../slicer/slice.h"
#include "../../src/base/buf.h"
#include "../t.h"

/* Is mv's ;TYPE: role t? */
static inline bool
ts_is_type(const struct est_move *mv, const char *t)
{
    size_t n = strlen(t);
    return mv->type && mv->type_len == n && memcmp(mv->type, t, n) == 0;
}

/* Slice m with p into t_tmpdir()/NAME.gcode, its path in path[cap]; r may be NULL. */
static inline int
ts_slice(const struct mesh *m, const struct slice_profile *p, const char *name,
         struct slice_result *r, char *path, size_t cap, struct sf_err *err)
{
    snprintf(path, cap, "%s/%s.gcode", t_tmpdir(), name);
    return slice_mesh(m, p, path, r, NULL, NULL, err);
}

/* Slice as ts_slice and read the G-code into text, which this initializes
   (the caller releases it, whatever the result). */
static inline int
ts_slice_text(const struct mesh *m, const struct slice_profile *p, const char *name,
              struct buf *text, struct slice_result *r, struct sf_err *err)
{
    char path[512];
    int rc = ts_slice(m, p, name, r, path, sizeof(path), err);
    buf_init(text, 0);
    return rc < 0 ? rc : buf_read_file(text, path, err);
}

/* Slice as ts_slice, then run the G-code through the estimator with p's
   limits, calling on_move(ud, move) for every move. */
static inline int
ts_slice_walk(const struct mesh *m, const struct slice_profile *p, const char *name,
              struct slice_result *r, est_move_fn on_move, void *ud, struct sf_err *err)
{
    struct buf b;
    int rc = ts_slice_text(m, p, name, &b, r, err);
    if (rc == SF_OK) {
        struct est_limits lim;
        slice_limits(p, &lim);
        struct estimate e;
        rc = estimate_gcode(b.data, b.len, name, &lim, on_move, ud, &e, err);
        estimate_release(&e);
    }
    buf_release(&b);
    return rc;
}

#endif
