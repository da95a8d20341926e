/*
 * sparse.c - CHOLMOD behind a small interface (see sparse.h).
 *
 * Design: triplets -> cholmod_triplet (upper part, stype +1) -> compressed
 * column -> analyze (AMD only: predictable, and METIS gains nothing on a
 * few thousand unknowns) -> simplicial LDL' factorization.  Solves go
 * through cholmod_solve2, which reuses its X, Y and E workspaces between
 * calls, so an iteration of the ARAP loop allocates nothing.
 *
 * Thread: one object per thread; nothing global.
 */
#include "sparse.h"

#include <cholmod.h>
#include <string.h>

#include "../base/mem.h"

struct sparse_chol {
    cholmod_common c;         /* CHOLMOD's settings and statistics for this object */
    cholmod_sparse *a;        /* the matrix (upper triangle) */
    cholmod_factor *l;        /* its LDL' factor */
    cholmod_dense *b;         /* right-hand side wrapper, n x k */
    cholmod_dense *x, *y, *e; /* cholmod_solve2's reusable solution and workspaces */
    uint32_t n;
    int k; /* columns b is sized for */
};

struct sparse_chol *
sparse_chol_new(uint32_t n, const uint32_t *row, const uint32_t *col, const double *val,
                size_t n_entries, struct sf_err *err)
{
    if (n == 0) {
        sf_err_set(err, SF_EINVAL, "sparse: empty matrix");
        return NULL;
    }
    struct sparse_chol *s = mem_calloc(1, sizeof(*s));
    if (!s) {
        sf_err_set(err, SF_ENOMEM, "sparse: out of memory");
        return NULL;
    }
    s->n = n;
    cholmod_start(&s->c);
    s->c.supernodal = CHOLMOD_SIMPLICIAL;
    s->c.nmethods = 1;
    s->c.method[0].ordering = CHOLMOD_AMD;
    s->c.postorder = 1;
    s->c.print = 0;
    size_t upper = 0;
    for (size_t k = 0; k < n_entries; k++)
        upper += row[k] <= col[k];
    cholmod_triplet *t = cholmod_allocate_triplet(n, n, upper ? upper : 1, 1, CHOLMOD_REAL, &s->c);
    if (!t) {
        sf_err_set(err, SF_ENOMEM, "sparse: out of memory for %zu entries", n_entries);
        goto fail;
    }
    int *ti = t->i, *tj = t->j;
    double *tx = t->x;
    size_t m = 0;
    for (size_t k = 0; k < n_entries; k++) {
        if (row[k] > col[k])
            continue;
        if (row[k] >= n || col[k] >= n) {
            cholmod_free_triplet(&t, &s->c);
            sf_err_set(err, SF_EBUG, "sparse: entry (%u, %u) outside %u x %u", row[k], col[k], n,
                       n);
            goto fail;
        }
        ti[m] = (int)row[k];
        tj[m] = (int)col[k];
        tx[m] = val[k];
        m++;
    }
    t->nnz = m;
    s->a = cholmod_triplet_to_sparse(t, m, &s->c);
    cholmod_free_triplet(&t, &s->c);
    if (!s->a) {
        sf_err_set(err, SF_ENOMEM, "sparse: out of memory converting %zu entries", m);
        goto fail;
    }
    s->l = cholmod_analyze(s->a, &s->c);
    if (!s->l) {
        sf_err_set(err, SF_ENOMEM, "sparse: analysis failed (status %d)", s->c.status);
        goto fail;
    }
    if (!cholmod_factorize(s->a, s->l, &s->c) || s->c.status == CHOLMOD_NOT_POSDEF) {
        sf_err_set(err, SF_EINVAL,
                   "sparse: matrix is not positive definite (column %d); is anything fixed?",
                   (int)s->l->minor);
        goto fail;
    }
    return s;
fail:
    sparse_chol_free(s);
    return NULL;
}

void
sparse_chol_free(struct sparse_chol *s)
{
    if (!s)
        return;
    cholmod_free_dense(&s->b, &s->c);
    cholmod_free_dense(&s->x, &s->c);
    cholmod_free_dense(&s->y, &s->c);
    cholmod_free_dense(&s->e, &s->c);
    cholmod_free_factor(&s->l, &s->c);
    cholmod_free_sparse(&s->a, &s->c);
    cholmod_finish(&s->c);
    free(s);
}

uint32_t
sparse_chol_n(const struct sparse_chol *s)
{
    return s->n;
}

size_t
sparse_chol_factor_nnz(const struct sparse_chol *s)
{
    const int *colcount = s->l->ColCount;
    size_t nnz = 0;
    for (uint32_t j = 0; j < s->n; j++)
        nnz += (size_t)colcount[j];
    return nnz;
}

int
sparse_chol_solve(struct sparse_chol *s, const double *b, double *x, int k, struct sf_err *err)
{
    if (k <= 0)
        return sf_err_set(err, SF_EBUG, "sparse: %d right-hand sides", k);
    if (!s->b || s->k != k) {
        cholmod_free_dense(&s->b, &s->c);
        cholmod_free_dense(&s->x, &s->c);
        s->b = cholmod_allocate_dense(s->n, (size_t)k, s->n, CHOLMOD_REAL, &s->c);
        if (!s->b)
            return sf_err_set(err, SF_ENOMEM, "sparse: out of memory for %d columns", k);
        s->k = k;
    }
    memcpy(s->b->x, b, sizeof(double) * s->n * (size_t)k);
    if (!cholmod_solve2(CHOLMOD_A, s->l, s->b, NULL, &s->x, NULL, &s->y, &s->e, &s->c))
        return sf_err_set(err, SF_ENOMEM, "sparse: solve failed (status %d)", s->c.status);
    memcpy(x, s->x->x, sizeof(double) * s->n * (size_t)k);
    return SF_OK;
}
