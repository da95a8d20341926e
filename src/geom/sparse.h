/*
 * sparse.h - sparse symmetric positive definite solves with CHOLMOD:
 * factor once, solve many.
 *
 * The ARAP global step (slim.c) solves L x = b with the same L every
 * iteration, so the factorization is done once (simplicial LDL', AMD
 * ordering: on the small meshes of the local/global loop it is ~4x faster
 * than the supernodal path with Debian's reference BLAS) and each solve is
 * two triangular back-substitutions into workspace kept in the object.
 *
 * Thread-safety: one struct sparse_chol per thread; distinct objects are
 * independent (each has its own cholmod_common).
 */
#ifndef SF_GEOM_SPARSE_H
#define SF_GEOM_SPARSE_H

#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"

struct sparse_chol;

/*
 * Assemble the n x n symmetric matrix from triplets (row[k], col[k],
 * val[k]); duplicates are summed, and only entries with row <= col are
 * used (pass each off-diagonal pair once, or both: the lower one is
 * ignored).  Then analyze and factorize.  NULL with err set: SF_EINVAL if
 * the matrix is not positive definite (e.g. a part with no fixed vertex),
 * SF_ENOMEM.  Free with sparse_chol_free().
 */
struct sparse_chol *sparse_chol_new(uint32_t n, const uint32_t *row, const uint32_t *col,
                                    const double *val, size_t n_entries, struct sf_err *err);
void sparse_chol_free(struct sparse_chol *s);

/* Order of the matrix and the nonzeros in its factor. */
uint32_t sparse_chol_n(const struct sparse_chol *s);
size_t sparse_chol_factor_nnz(const struct sparse_chol *s);

/*
 * Solve A X = B for k right-hand sides, column-major n x k (B and X may
 * not alias).  Allocates only on the first call or when k grows.
 */
int sparse_chol_solve(struct sparse_chol *s, const double *b, double *x, int k, struct sf_err *err);

#endif
