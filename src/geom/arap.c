/*
 * arap.c - local/global ARAP on a tet mesh with minimal rotations (see
 * arap.h; Hu 2015, sec. 4, eq. 5-8).
 *
 * Layout: tets in blocks of POLAR_W lanes, structure of arrays (vertex
 * indices, D^-1 and volume per lane), so the deformation gradients and
 * the nearest rotations of a block are straight-line loops the compiler
 * vectorizes; the tail block is padded with zero-volume copies of tet 0.
 * The minimal rotation touches only the tets the caller lists (struct
 * arap_drive), with the normals the caller measured; it does not depend on
 * the nearest rotation, so the local step solves those first and then
 * makes one pass over the blocks: gather the corners, J = E D^-1, nearest
 * rotation, R <- Q R where a minimal rotation is pending, and the tet's
 * share of the right-hand side b_i = sum_T V_T R_T g_i
 * (g_0 = -(g_1 + g_2 + g_3)) scattered while R is still in registers.
 * The global step only adds the Dirichlet part L_fc x_c (a small CSR
 * product, so fixed vertices may be anywhere the caller puts them) and
 * back-substitutes; after arap_set_rotation it assembles b itself.
 *
 * Thread: one object per thread.
 */
#include "arap.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../base/clock.h"
#include "../base/mem.h"
#include "minrot.h"
#include "polar.h"
#include "sparse.h"

#define W POLAR_W

struct block {
    uint32_t idx[4][W]; /* vertex indices per lane */
    double dinv[9][W];  /* D^-1 row-major: row i is the gradient g_(i+1) */
    double vol[W];      /* rest volume (0 on padding lanes) */
    double rot[9][W];   /* target rotation, row-major */
};

struct arap {
    uint32_t n_verts, n_tets, n_blocks, n_free;
    struct block *blocks;
    int32_t *free_index; /* per vertex: row in L_ff, or -1 when fixed */
    uint32_t *free_vert; /* per free row: its vertex */
    /* L_fc in CSR over free rows: columns are (fixed) vertex indices */
    uint32_t *fc_start, *fc_col;
    double *fc_val;
    struct sparse_chol *chol;
    double *b;        /* 3 * n_verts: assembled right-hand side, x y z interleaved */
    double *rhs;      /* 3 * n_free column-major */
    double *sol;      /* 3 * n_free column-major */
    bool b_fresh;     /* b matches the rotations (set by the fused local pass) */
    int32_t *pending; /* per tet: its slot in q, or -1 */
    double (*q)[9];   /* minimal rotations of this local step, row-major */
    uint32_t q_cap;
    struct arap_timing timing;
};

static bool
invert3(const double m[3][3], double out[3][3])
{
    double c00 = m[1][1] * m[2][2] - m[1][2] * m[2][1];
    double c01 = m[1][2] * m[2][0] - m[1][0] * m[2][2];
    double c02 = m[1][0] * m[2][1] - m[1][1] * m[2][0];
    double det = m[0][0] * c00 + m[0][1] * c01 + m[0][2] * c02;
    if (!(fabs(det) > 0) || !isfinite(det))
        return false;
    double id = 1 / det;
    out[0][0] = c00 * id;
    out[1][0] = c01 * id;
    out[2][0] = c02 * id;
    out[0][1] = (m[0][2] * m[2][1] - m[0][1] * m[2][2]) * id;
    out[1][1] = (m[0][0] * m[2][2] - m[0][2] * m[2][0]) * id;
    out[2][1] = (m[0][1] * m[2][0] - m[0][0] * m[2][1]) * id;
    out[0][2] = (m[0][1] * m[1][2] - m[0][2] * m[1][1]) * id;
    out[1][2] = (m[0][2] * m[1][0] - m[0][0] * m[1][2]) * id;
    out[2][2] = (m[0][0] * m[1][1] - m[0][1] * m[1][0]) * id;
    return true;
}

void
arap_free(struct arap *a)
{
    if (!a)
        return;
    free(a->blocks);
    free(a->free_index);
    free(a->free_vert);
    free(a->fc_start);
    free(a->fc_col);
    free(a->fc_val);
    sparse_chol_free(a->chol);
    free(a->b);
    free(a->rhs);
    free(a->sol);
    free(a->pending);
    free(a->q);
    free(a);
}

/* Gradients g_0..g_3 of tet lane l of block bl. */
static void
grads(const struct block *bl, int l, double g[4][3])
{
    for (int c = 0; c < 3; c++) {
        g[1][c] = bl->dinv[c][l];
        g[2][c] = bl->dinv[3 + c][l];
        g[3][c] = bl->dinv[6 + c][l];
        g[0][c] = -(g[1][c] + g[2][c] + g[3][c]);
    }
}

static int
setup_tets(struct arap *a, const struct tetmesh *tm, struct sf_err *err)
{
    a->n_blocks = (tm->n_tets + W - 1) / W;
    a->blocks = mem_calloc(a->n_blocks, sizeof(*a->blocks));
    if (!a->blocks)
        return sf_err_set(err, SF_ENOMEM, "arap: out of memory for %u tets", tm->n_tets);
    for (uint32_t t = 0; t < a->n_blocks * W; t++) {
        struct block *bl = &a->blocks[t / W];
        int l = (int)(t % W);
        uint32_t src = t < tm->n_tets ? t : 0;
        const uint32_t *q = tm->tet[src];
        double d[3][3], di[3][3];
        for (int i = 0; i < 3; i++) { /* D's columns are the rest edges */
            struct vec3 e = v3_sub(tm->x[q[i + 1]], tm->x[q[0]]);
            d[0][i] = e.x;
            d[1][i] = e.y;
            d[2][i] = e.z;
        }
        if (!invert3(d, di))
            return sf_err_set(err, SF_EINVAL, "arap: tet %u is degenerate", src);
        for (int i = 0; i < 4; i++)
            bl->idx[i][l] = q[i];
        for (int c = 0; c < 9; c++)
            bl->dinv[c][l] = di[c / 3][c % 3];
        bl->vol[l] = t < tm->n_tets ? tetmesh_volume(tm, tm->x, t) : 0;
        for (int c = 0; c < 9; c++)
            bl->rot[c][l] = c % 4 == 0;
    }
    return SF_OK;
}

static int
setup_matrix(struct arap *a, const struct tetmesh *tm, const uint8_t *fixed, struct sf_err *err)
{
    a->free_index = mem_array(tm->n_verts, sizeof(int32_t));
    a->free_vert = mem_array(tm->n_verts, sizeof(uint32_t));
    if (!a->free_index || !a->free_vert)
        return sf_err_set(err, SF_ENOMEM, "arap: out of memory");
    for (uint32_t v = 0; v < tm->n_verts; v++) {
        a->free_index[v] = fixed[v] ? -1 : (int32_t)a->n_free;
        if (!fixed[v])
            a->free_vert[a->n_free++] = v;
    }
    if (a->n_free == tm->n_verts)
        return sf_err_set(err, SF_EINVAL,
                          "arap: no fixed vertex (the system has no unique solution)");
    if (a->n_free == 0)
        return sf_err_set(err, SF_EINVAL, "arap: every vertex is fixed");
    size_t n16 = (size_t)tm->n_tets * 16;
    uint32_t *row = mem_array(n16, sizeof(uint32_t)), *col = mem_array(n16, sizeof(uint32_t));
    double *val = mem_array(n16, sizeof(double));
    uint32_t *frow = mem_array(n16, sizeof(uint32_t)), *fcol = mem_array(n16, sizeof(uint32_t));
    double *fval = mem_array(n16, sizeof(double));
    a->fc_start = mem_calloc((size_t)a->n_free + 1, sizeof(uint32_t));
    int rc = SF_OK;
    if (!row || !col || !val || !frow || !fcol || !fval || !a->fc_start) {
        rc = sf_err_set(err, SF_ENOMEM, "arap: out of memory assembling %u tets", tm->n_tets);
        goto done;
    }
    size_t n = 0, nf = 0;
    for (uint32_t t = 0; t < tm->n_tets; t++) {
        const struct block *bl = &a->blocks[t / W];
        int l = (int)(t % W);
        double g[4][3];
        grads(bl, l, g);
        for (int i = 0; i < 4; i++) {
            int32_t fi = a->free_index[bl->idx[i][l]];
            if (fi < 0)
                continue;
            for (int j = 0; j < 4; j++) {
                double w = bl->vol[l] * (g[i][0] * g[j][0] + g[i][1] * g[j][1] + g[i][2] * g[j][2]);
                int32_t fj = a->free_index[bl->idx[j][l]];
                if (fj >= 0) {
                    if (fi <= fj) {
                        row[n] = (uint32_t)fi, col[n] = (uint32_t)fj, val[n] = w;
                        n++;
                    }
                } else {
                    frow[nf] = (uint32_t)fi, fcol[nf] = bl->idx[j][l], fval[nf] = w;
                    nf++;
                }
            }
        }
    }
    /* L_fc as CSR (counting sort by row; duplicates stay, the product sums them) */
    a->fc_col = mem_array(nf ? nf : 1, sizeof(uint32_t));
    a->fc_val = mem_array(nf ? nf : 1, sizeof(double));
    if (!a->fc_col || !a->fc_val) {
        rc = sf_err_set(err, SF_ENOMEM, "arap: out of memory");
        goto done;
    }
    for (size_t k = 0; k < nf; k++)
        a->fc_start[frow[k] + 1]++;
    for (uint32_t r = 0; r < a->n_free; r++)
        a->fc_start[r + 1] += a->fc_start[r];
    for (size_t k = 0; k < nf; k++) {
        uint32_t at = a->fc_start[frow[k]]++;
        a->fc_col[at] = fcol[k];
        a->fc_val[at] = fval[k];
    }
    for (uint32_t r = a->n_free; r > 0; r--)
        a->fc_start[r] = a->fc_start[r - 1];
    a->fc_start[0] = 0;
    a->chol = sparse_chol_new(a->n_free, row, col, val, n, err);
    if (!a->chol)
        rc = err ? err->code : SF_EINVAL;
done:
    free(row);
    free(col);
    free(val);
    free(frow);
    free(fcol);
    free(fval);
    return rc;
}

struct arap *
arap_new(const struct tetmesh *tm, const uint8_t *fixed, struct sf_err *err)
{
    if (!tm->n_tets) {
        sf_err_set(err, SF_EINVAL, "arap: no tets");
        return NULL;
    }
    struct arap *a = mem_calloc(1, sizeof(*a));
    if (!a) {
        sf_err_set(err, SF_ENOMEM, "arap: out of memory");
        return NULL;
    }
    a->n_verts = tm->n_verts;
    a->n_tets = tm->n_tets;
    if (setup_tets(a, tm, err) || setup_matrix(a, tm, fixed, err))
        goto fail;
    a->b = mem_array(tm->n_verts, 3 * sizeof(double));
    a->rhs = mem_array(a->n_free, 3 * sizeof(double));
    a->sol = mem_array(a->n_free, 3 * sizeof(double));
    a->pending = mem_array(tm->n_tets, sizeof(int32_t));
    if (!a->b || !a->rhs || !a->sol || !a->pending) {
        sf_err_set(err, SF_ENOMEM, "arap: out of memory");
        goto fail;
    }
    for (uint32_t t = 0; t < tm->n_tets; t++)
        a->pending[t] = -1;
    return a;
fail:
    arap_free(a);
    return NULL;
}

/* Lane l's share of the right-hand side: V R g_i to b_i, i = 0..3 (Hu 2015, eq. 8). */
static inline __attribute__((always_inline)) void
scatter_rhs(const struct block *bl, int l, double *b)
{
    double v = bl->vol[l];
    double s0x = 0, s0y = 0, s0z = 0;
    for (int i = 0; i < 3; i++) {
        /* g_(i+1) = row i of D^-1 */
        double gx = bl->dinv[3 * i][l] * v, gy = bl->dinv[3 * i + 1][l] * v,
               gz = bl->dinv[3 * i + 2][l] * v;
        double wx = bl->rot[0][l] * gx + bl->rot[1][l] * gy + bl->rot[2][l] * gz;
        double wy = bl->rot[3][l] * gx + bl->rot[4][l] * gy + bl->rot[5][l] * gz;
        double wz = bl->rot[6][l] * gx + bl->rot[7][l] * gy + bl->rot[8][l] * gz;
        double *bi = b + 3 * (size_t)bl->idx[i + 1][l];
        bi[0] += wx, bi[1] += wy, bi[2] += wz;
        s0x += wx, s0y += wy, s0z += wz;
    }
    double *b0 = b + 3 * (size_t)bl->idx[0][l];
    b0[0] -= s0x, b0[1] -= s0y, b0[2] -= s0z;
}

/* b from the stored rotations (after arap_set_rotation). */
static void
assemble_rhs(struct arap *a)
{
    memset(a->b, 0, sizeof(double) * 3 * a->n_verts);
    for (uint32_t k = 0; k < a->n_blocks; k++)
        for (int l = 0; l < W; l++)
            scatter_rhs(&a->blocks[k], l, a->b);
}

/* J = E D^-1 of every lane (E's columns the current edges). */
static inline __attribute__((always_inline)) void
block_gradients(const struct block *bl, const struct vec3 *x, double j[9][W])
{
    double e[9][W];
    for (int l = 0; l < W; l++) {
        struct vec3 p0 = x[bl->idx[0][l]];
        for (int i = 0; i < 3; i++) {
            struct vec3 pi = x[bl->idx[i + 1][l]];
            e[3 * i][l] = pi.x - p0.x; /* edge i, components x y z */
            e[3 * i + 1][l] = pi.y - p0.y;
            e[3 * i + 2][l] = pi.z - p0.z;
        }
    }
    /* J[r][c] = sum_i e_i[r] dinv[i][c] */
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            for (int l = 0; l < W; l++)
                j[3 * r + c][l] = e[r][l] * bl->dinv[c][l] + e[3 + r][l] * bl->dinv[3 + c][l] +
                                  e[6 + r][l] * bl->dinv[6 + c][l];
}

/* The fused pass (see the top comment); returns the lanes on polar's scalar path. */
static POLAR_CLONES uint32_t
local_pass(struct arap *a, const struct vec3 *x)
{
    uint32_t slow = 0;
    double *b = a->b;
    memset(b, 0, sizeof(double) * 3 * a->n_verts);
    for (uint32_t k = 0; k < a->n_blocks; k++) {
        struct block *bl = &a->blocks[k];
        double j[9][W];
        block_gradients(bl, x, j);
        slow += (uint32_t)polar_block((const double(*)[W])j, bl->rot);
        for (int l = 0; l < W; l++) {
            uint32_t t = k * W + (uint32_t)l;
            int32_t s = t < a->n_tets ? a->pending[t] : -1;
            if (s >= 0) { /* R <- Q R */
                const double *q = a->q[s];
                double r[9];
                for (int c = 0; c < 9; c++)
                    r[c] = bl->rot[c][l];
                for (int row = 0; row < 3; row++)
                    for (int c = 0; c < 3; c++)
                        bl->rot[3 * row + c][l] = q[3 * row] * r[c] + q[3 * row + 1] * r[3 + c] +
                                                  q[3 * row + 2] * r[6 + c];
                a->pending[t] = -1;
            }
            scatter_rhs(bl, l, b);
        }
    }
    return slow;
}

void
arap_local(struct arap *a, const struct vec3 *x, struct vec3 d, double tau, double beta,
           const struct arap_drive *drv, uint32_t n_drv, struct arap_local_stats *stats)
{
    double t0 = clock_mono_s();
    uint32_t rotated = 0;
    if (n_drv > a->q_cap) {
        free(a->q);
        a->q_cap = 0;
        a->q = mem_array(n_drv, sizeof(*a->q));
        if (a->q)
            a->q_cap = n_drv;
    }
    for (uint32_t i = 0; i < n_drv && i < a->q_cap; i++) {
        const struct arap_drive *dv = &drv[i];
        if (dv->tet >= a->n_tets || dv->k < 1 || dv->k > 2)
            continue;
        struct minrot mr;
        minrot_solve(dv->n, dv->k, d, tau, dv->hint, &mr); /* Hu 2015, sec. 4.2 */
        if (!(mr.angle > beta))
            continue;
        struct mat3 q = minrot_matrix(&mr, beta);
        int32_t s = a->pending[dv->tet];
        if (s >= 0) { /* listed twice: compose, as applying both in turn would */
            struct mat3 p;
            for (int c = 0; c < 9; c++)
                p.m[c / 3][c % 3] = a->q[s][c];
            q = m3_mul(q, p);
        } else {
            s = (int32_t)rotated++;
            a->pending[dv->tet] = s;
        }
        for (int c = 0; c < 9; c++)
            a->q[s][c] = q.m[c / 3][c % 3];
    }
    double t1 = clock_mono_s();
    uint32_t slow = local_pass(a, x);
    a->b_fresh = true;
    a->timing.minrot_s += t1 - t0;
    a->timing.local_s += clock_mono_s() - t1;
    if (stats) {
        stats->n_rotated = rotated;
        stats->n_slow_polar = slow;
    }
}

void
arap_set_rotation(struct arap *a, struct mat3 r)
{
    for (uint32_t b = 0; b < a->n_blocks; b++)
        for (int c = 0; c < 9; c++)
            for (int l = 0; l < W; l++)
                a->blocks[b].rot[c][l] = r.m[c / 3][c % 3];
    a->b_fresh = false;
}

int
arap_global(struct arap *a, struct vec3 *x, struct sf_err *err)
{
    double t0 = clock_mono_s();
    const double *b = a->b;
    if (!a->b_fresh)
        assemble_rhs(a);
    a->b_fresh = true; /* b depends on the rotations only */
    uint32_t nf = a->n_free;
    for (uint32_t r = 0; r < nf; r++) {
        const double *br = b + 3 * (size_t)a->free_vert[r];
        double cx = 0, cy = 0, cz = 0;
        for (uint32_t k = a->fc_start[r]; k < a->fc_start[r + 1]; k++) {
            struct vec3 p = x[a->fc_col[k]];
            cx += a->fc_val[k] * p.x, cy += a->fc_val[k] * p.y, cz += a->fc_val[k] * p.z;
        }
        a->rhs[r] = br[0] - cx;
        a->rhs[nf + r] = br[1] - cy;
        a->rhs[2 * (size_t)nf + r] = br[2] - cz;
    }
    double t1 = clock_mono_s();
    int rc = sparse_chol_solve(a->chol, a->rhs, a->sol, 3, err);
    if (rc == SF_OK)
        for (uint32_t r = 0; r < nf; r++)
            x[a->free_vert[r]] = v3(a->sol[r], a->sol[nf + r], a->sol[2 * (size_t)nf + r]);
    a->timing.rhs_s += t1 - t0;
    a->timing.solve_s += clock_mono_s() - t1;
    return rc;
}

const struct arap_timing *
arap_timing(const struct arap *a)
{
    return &a->timing;
}

size_t
arap_factor_nnz(const struct arap *a)
{
    return sparse_chol_factor_nnz(a->chol);
}

uint32_t
arap_n_free(const struct arap *a)
{
    return a->n_free;
}
