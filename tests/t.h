/*
 * t.h - the tiny test runner every unit test program uses.
 *
 *     T_CASE(stl_loads_cube) { ... T_EQ_INT(m.n_tris, 12); ... }
 *
 * Cases register themselves at load time; tests/t.c supplies main(), which
 * runs every case (or those whose names contain argv[1]), prints one line
 * per case and ends with "N passed, N failed".  A failed check prints the
 * expression, both values and the err message, then leaves the case.
 * `prog --count` prints the number of cases (run.sh uses it to count a
 * crashed program's cases as failed).
 */
#ifndef SF_TESTS_T_H
#define SF_TESTS_T_H

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "../src/base/err.h"

typedef void (*t_fn)(void);
void t_register(const char *name, t_fn fn);
void t_fail(const char *file, int line, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
/* Directory for scratch files of this test program (created, removed at exit). */
const char *t_tmpdir(void);
/* The first 511 bytes of file path ("" when it cannot be read), in a static buffer. */
const char *t_slurp(const char *path);
/* Path of ../shared/meshes/NAME if ../shared exists, else NULL (caller skips). */
const char *t_shared_mesh(const char *name);
/* Mark the running case skipped with a reason. */
void t_skip(const char *why);

static inline const char *
t_errmsg(const struct sf_err *e)
{
    return e ? e->msg : "";
}

#define T_CASE(name)                                                                               \
    static void t_case_##name(void);                                                               \
    __attribute__((constructor)) static void t_reg_##name(void)                                    \
    {                                                                                              \
        t_register(#name, t_case_##name);                                                          \
    }                                                                                              \
    static void t_case_##name(void)

#define T_TRUE(x)                                                                                  \
    do {                                                                                           \
        if (!(x)) {                                                                                \
            t_fail(__FILE__, __LINE__, "expected true: %s", #x);                                   \
            return;                                                                                \
        }                                                                                          \
    } while (0)

#define T_EQ_INT(a, b)                                                                             \
    do {                                                                                           \
        long long t_a_ = (long long)(a), t_b_ = (long long)(b);                                    \
        if (t_a_ != t_b_) {                                                                        \
            t_fail(__FILE__, __LINE__, "%s == %s: %lld != %lld", #a, #b, t_a_, t_b_);              \
            return;                                                                                \
        }                                                                                          \
    } while (0)

#define T_EQ_DBL(a, b, eps)                                                                        \
    do {                                                                                           \
        double t_a_ = (double)(a), t_b_ = (double)(b), t_e_ = (double)(eps);                       \
        if (!(fabs(t_a_ - t_b_) <= t_e_)) {                                                        \
            t_fail(__FILE__, __LINE__, "%s == %s (eps %g): %.9g != %.9g", #a, #b, t_e_, t_a_,      \
                   t_b_);                                                                          \
            return;                                                                                \
        }                                                                                          \
    } while (0)

#define T_EQ_STR(a, b)                                                                             \
    do {                                                                                           \
        const char *t_a_ = (a), *t_b_ = (b);                                                       \
        if (!t_a_ || !t_b_ || strcmp(t_a_, t_b_) != 0) {                                           \
            t_fail(__FILE__, __LINE__, "%s == %s: \"%s\" != \"%s\"", #a, #b,                       \
                   t_a_ ? t_a_ : "(null)", t_b_ ? t_b_ : "(null)");                                \
            return;                                                                                \
        }                                                                                          \
    } while (0)

/* rc must be SF_OK (or a non-negative count). */
#define T_OK(rc, err)                                                                              \
    do {                                                                                           \
        int t_rc_ = (rc);                                                                          \
        if (t_rc_ < 0) {                                                                           \
            t_fail(__FILE__, __LINE__, "%s: %s (%s)", #rc, sf_status_name(t_rc_), t_errmsg(err));  \
            return;                                                                                \
        }                                                                                          \
    } while (0)

/* rc must equal code and err->msg must contain substr. */
#define T_ERR(rc, code, err, substr)                                                               \
    do {                                                                                           \
        int t_rc_ = (rc);                                                                          \
        if (t_rc_ != (code)) {                                                                     \
            t_fail(__FILE__, __LINE__, "%s: got %s, want %s (msg: %s)", #rc,                       \
                   sf_status_name(t_rc_), sf_status_name(code), (err)->msg);                       \
            return;                                                                                \
        }                                                                                          \
        if (!strstr((err)->msg, (substr))) {                                                       \
            t_fail(__FILE__, __LINE__, "%s: message \"%s\" lacks \"%s\"", #rc, (err)->msg,         \
                   (substr));                                                                      \
            return;                                                                                \
        }                                                                                          \
    } while (0)

#define T_SKIP_UNLESS(cond, why)                                                                   \
    do {                                                                                           \
        if (!(cond)) {                                                                             \
            t_skip(why);                                                                           \
            return;                                                                                \
        }                                                                                          \
    } while (0)

#endif
