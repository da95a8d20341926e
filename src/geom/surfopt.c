/*
 * surfopt.c - orientation-fused surface shape optimization (method 3);
 * the method and its one departure are described in surfopt.h.
 */
#include "surfopt.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../base/clock.h"
#include "../base/mem.h"
#include "../mesh/subdiv.h"
#include "saliency.h"
#include "selfx.h"
#include "sparse.h"
#include "supmodel.h"
#include "surfopt_int.h"

#define KEEP_MAX 8 /* improving iterates kept as fallbacks (keep_push) */
/* Edges and triangles closer than this share of the diagonal in the input
   already touched there (float noise, a soup's T-junctions): crossing them
   is no new self-intersection (selfx_count_new). */
#define SELFX_TOUCH 1e-6
/* A fold freezes its vertices and this many rings around them; after
   FREEZE_MAX freezes in a round, folds halve the turns everywhere. */
#define FREEZE_RINGS 2
#define FREEZE_MAX   16
/* The runs: halving only; freezing (frozen vertices ask for no turn);
   freezing and holding (frozen vertices also stay where they are). */
enum { FREEZE_NONE, FREEZE_SOFT, FREEZE_HOLD };
/* A round that lowers its proxy by less than this share in `patience`
   iterates is crawling: the adaptive weights loosen as when it stalls. */
#define CRAWL 0.01

static struct support_params
support_at(double angle_deg)
{
    struct support_params sp;
    support_params_default(&sp);
    sp.angle_deg = angle_deg;
    return sp;
}

/* The move that rests m on z = 0 with its bbox centred on x = y = 0. */
static struct vec3
rest_offset(const struct mesh *m)
{
    struct vec3 lo, hi;
    mesh_bbox(m, &lo, &hi);
    return v3(-(lo.x + hi.x) / 2, -(lo.y + hi.y) / 2, -lo.z);
}

int
surfopt_ray_metrics(const struct mesh *m, double angle_deg, struct support_metrics *out,
                    struct sf_err *err)
{
    struct support_params sp = support_at(angle_deg);
    struct raycast *rc = raycast_new(m, err);
    if (!rc)
        return err->code;
    int r = measure_support(m, rc, v3(0, 0, 1), &sp, out, err);
    raycast_free(rc);
    return r;
}

/* ---- the round's constant system, fixed rows as identity ---- */

struct system {
    uint32_t *nb_start, *nb; /* neighbour lists (CSR) */
    struct sparse_chol *chol;
    double *b0;  /* 3n, column-major: constant part of the right-hand side */
    double *rhs; /* 3n */
    double *x;   /* 3n */
    bool *fixed;
    double *w_face;      /* per face: its input area over the mean (constant) */
    double anchor;       /* the pull toward the input's positions in this factor */
    const uint8_t *hold; /* NULL, or per vertex: held where it stands (FREEZE_HOLD) */
};

/* A light pull toward the current shape: keeps the system definite when
 * nothing is fixed, too weak to hold any face back. */
#define MU 1e-4

static int
cmp_pair(const void *a, const void *b)
{
    const uint32_t *p = a, *q = b;
    return p[0] != q[0] ? (p[0] < q[0] ? -1 : 1) : p[1] != q[1] ? (p[1] < q[1] ? -1 : 1) : 0;
}

/* Neighbour lists from the triangles' edges (both directions, unique). */
static int
build_neighbours(const struct mesh *m, struct system *s, struct sf_err *err)
{
    size_t np = (size_t)m->n_tris * 6;
    uint32_t(*pairs)[2] = mem_array(np ? np : 1, sizeof(*pairs));
    s->nb_start = mem_calloc((size_t)m->n_verts + 1, sizeof(uint32_t));
    s->nb = mem_array(np ? np : 1, sizeof(uint32_t));
    if (!pairs || !s->nb_start || !s->nb) {
        free(pairs);
        return sf_err_set(err, SF_ENOMEM, "surface optimizer: out of memory for the edges");
    }
    size_t k = 0;
    for (uint32_t f = 0; f < m->n_tris; f++) {
        for (int e = 0; e < 3; e++) {
            uint32_t a = m->t[f][e], b = m->t[f][(e + 1) % 3];
            pairs[k][0] = a, pairs[k][1] = b, k++;
            pairs[k][0] = b, pairs[k][1] = a, k++;
        }
    }
    qsort(pairs, np, sizeof(*pairs), cmp_pair);
    uint32_t n_nb = 0;
    for (size_t i = 0; i < np; i++) {
        if (i > 0 && pairs[i][0] == pairs[i - 1][0] && pairs[i][1] == pairs[i - 1][1])
            continue;
        s->nb[n_nb++] = pairs[i][1];
        s->nb_start[pairs[i][0] + 1]++;
    }
    for (uint32_t v = 0; v < m->n_verts; v++)
        s->nb_start[v + 1] += s->nb_start[v];
    free(pairs);
    return SF_OK;
}

/* Free the factor and its vectors (the neighbour lists stay). */
static void
system_free_factor(struct system *s)
{
    sparse_chol_free(s->chol);
    free(s->b0);
    free(s->rhs);
    free(s->x);
    free(s->fixed);
    s->chol = NULL;
    s->b0 = s->rhs = s->x = NULL;
    s->fixed = NULL;
}

static void
system_free(struct system *s)
{
    system_free_factor(s);
    free(s->w_face);
    free(s->nb_start);
    free(s->nb);
    memset(s, 0, sizeof(*s));
}

/*
 * The detail term beta |L (V - V0)|^2 (L the uniform Laplacian, V0 = ref):
 * beta L'L as triplets from row[0] on (returns how many), beta L'L V0 into
 * s->b0; lv0 is 3n of workspace.
 */
static size_t
detail_term(struct system *s, const struct mesh *ref, double beta, double *lv0, uint32_t *row,
            uint32_t *col, double *val)
{
    uint32_t n = ref->n_verts;
    /* L V0 row by row (uniform Laplacian: v - mean of neighbours) */
    for (uint32_t i = 0; i < n; i++) {
        uint32_t a = s->nb_start[i], b = s->nb_start[i + 1];
        struct vec3 mean = v3(0, 0, 0);
        for (uint32_t k = a; k < b; k++)
            mean = v3_add(mean, ref->v[s->nb[k]]);
        struct vec3 l = b > a ? v3_sub(ref->v[i], v3_scale(mean, 1.0 / (b - a))) : v3(0, 0, 0);
        lv0[i] = l.x, lv0[n + i] = l.y, lv0[2 * (size_t)n + i] = l.z;
    }
    /* beta L'(L V0) into b0, beta L'L as triplets */
    size_t t = 0;
    for (uint32_t i = 0; i < n; i++) {
        uint32_t a = s->nb_start[i], b = s->nb_start[i + 1];
        double c_nb = b > a ? -1.0 / (b - a) : 0;
        for (uint32_t j = a; j <= b; j++) {
            uint32_t vj = j == b ? i : s->nb[j];
            double cj = j == b ? 1 : c_nb;
            for (int d = 0; d < 3; d++)
                s->b0[(size_t)d * n + vj] += beta * cj * lv0[(size_t)d * n + i];
            for (uint32_t k = a; k <= b; k++) {
                uint32_t vk = k == b ? i : s->nb[k];
                double ck = k == b ? 1 : c_nb;
                row[t] = vj, col[t] = vk, val[t] = beta * cj * ck, t++;
            }
        }
    }
    return t;
}

/*
 * Assemble and factorize the round's matrix: gamma's edge Laplacian (each
 * face weighted by its share of the area), beta L'L when the detail term
 * is on (beta is the adaptive detail weight) and MU I.  Rows of vertices
 * within fix_bottom_mm of the bed become identity rows holding their
 * place; the detail term's beta L'L V0 and the fixed vertices' pull on
 * their neighbours go into b0.
 */
static int
system_build(struct system *s, const struct mesh *cur, const struct mesh *ref,
             const struct surfopt_params *p, double beta, double anchor, struct sf_err *err)
{
    uint32_t n = cur->n_verts;
    size_t n_trip = n + 12 * (size_t)cur->n_tris;
    for (uint32_t i = 0; beta > 0 && i < n; i++) {
        size_t d = s->nb_start[i + 1] - s->nb_start[i] + 1;
        n_trip += d * d;
    }
    uint32_t *row = mem_array(n_trip, sizeof(uint32_t));
    uint32_t *col = mem_array(n_trip, sizeof(uint32_t));
    double *val = mem_array(n_trip, sizeof(double));
    double *lv0 = beta > 0 ? mem_calloc((size_t)n * 3, sizeof(double)) : NULL;
    s->b0 = mem_calloc((size_t)n * 3, sizeof(double));
    s->rhs = mem_calloc((size_t)n * 3, sizeof(double));
    s->x = mem_calloc((size_t)n * 3, sizeof(double));
    s->fixed = mem_calloc(n, sizeof(bool));
    int rc = SF_ENOMEM;
    if (!row || !col || !val || (beta > 0 && !lv0) || !s->b0 || !s->rhs || !s->x || !s->fixed) {
        rc = sf_err_set(err, SF_ENOMEM, "surface optimizer: out of memory for %u vertices", n);
        goto out;
    }
    struct vec3 lo, hi;
    mesh_bbox(cur, &lo, &hi);
    for (uint32_t i = 0; i < n; i++)
        s->fixed[i] = cur->v[i].z <= lo.z + p->fix_bottom_mm || (s->hold && s->hold[i]);

    size_t t = 0;
    if (beta > 0)
        t = detail_term(s, ref, beta, lv0, row, col, val);
    for (uint32_t i = 0; i < n; i++)
        row[t] = i, col[t] = i, val[t] = MU + anchor, t++;
    /* gamma sum_f w_f sum_(a,b) in f |v_a - v_b - d_ab|^2: an edge Laplacian */
    for (uint32_t f = 0; f < cur->n_tris; f++) {
        double g = p->gamma * s->w_face[f];
        for (int e = 0; e < 3; e++) {
            uint32_t a = cur->t[f][e], b = cur->t[f][(e + 1) % 3];
            row[t] = a, col[t] = a, val[t] = g, t++;
            row[t] = b, col[t] = b, val[t] = g, t++;
            row[t] = a, col[t] = b, val[t] = -g, t++;
            row[t] = b, col[t] = a, val[t] = -g, t++;
        }
    }
    /* Dirichlet rows: a fixed row becomes an identity row (added below);
     * a free row's entries in fixed columns move to the right-hand side */
    size_t w = 0;
    for (size_t k = 0; k < t; k++) {
        if (s->fixed[row[k]])
            continue;
        if (s->fixed[col[k]]) {
            struct vec3 xc = cur->v[col[k]];
            s->b0[row[k]] -= val[k] * xc.x;
            s->b0[n + row[k]] -= val[k] * xc.y;
            s->b0[2 * (size_t)n + row[k]] -= val[k] * xc.z;
            continue;
        }
        row[w] = row[k], col[w] = col[k], val[w] = val[k], w++;
    }
    for (uint32_t i = 0; i < n; i++) {
        if (!s->fixed[i])
            continue;
        row[w] = i, col[w] = i, val[w] = 1, w++;
        s->b0[i] = cur->v[i].x;
        s->b0[n + i] = cur->v[i].y;
        s->b0[2 * (size_t)n + i] = cur->v[i].z;
    }
    s->anchor = anchor;
    s->chol = sparse_chol_new(n, row, col, val, w, err);
    rc = s->chol ? SF_OK : err->code;
out:
    free(row);
    free(col);
    free(val);
    free(lv0);
    return rc;
}

/* ---- one geometry iteration ---------------------------------------------- */

/*
 * The edge targets' share of the right-hand side.  Every face steeper than the
 * aim (sin_a, the aim's sine; not on the bed)
 * wants its edges turned rigidly so its normal lies aim_rad
 * from the vertical on the safe side, by the share its vertices' saliency
 * allows times step; every other face wants its edges as they are.  acc (3n,
 * column-major) receives gamma w_f sum (e_a - e_b) d_ab.
 */
static void
edge_rhs(const struct mesh *cur, const struct system *s, const double *share, double step,
         double sin_a, double aim_rad, struct vec3 centre, double gamma, double *acc)
{
    uint32_t n = cur->n_verts;
    memset(acc, 0, 3 * (size_t)n * sizeof(double));
    struct vec3 lo, hi;
    mesh_bbox(cur, &lo, &hi);
    for (uint32_t f = 0; f < cur->n_tris; f++) {
        const uint32_t *t = cur->t[f];
        struct vec3 p[3] = { cur->v[t[0]], cur->v[t[1]], cur->v[t[2]] };
        struct vec3 cr = v3_cross(v3_sub(p[1], p[0]), v3_sub(p[2], p[0]));
        double len = v3_len(cr);
        struct mat3 r = m3_identity();
        struct vec3 nrm = len > 0 ? v3_scale(cr, 1 / len) : v3(0, 0, 1);
        struct vec3 c = v3_scale(v3_add(v3_add(p[0], p[1]), p[2]), 1.0 / 3);
        if (nrm.z < -sin_a && c.z > lo.z + 0.05) { /* past the aim, not resting on the bed */
            struct vec3 h = v3(nrm.x, nrm.y, 0);
            if (v3_len(h) < 1e-6)
                h = v3(c.x - centre.x, c.y - centre.y, 0); /* flat: lean away from the middle */
            if (v3_len(h) < 1e-9)
                h = v3(1, 0, 0);
            h = v3_normalize(h);
            struct vec3 want = v3(h.x * cos(aim_rad), h.y * cos(aim_rad), -sin(aim_rad));
            double k = step * (share[t[0]] + share[t[1]] + share[t[2]]) / 3;
            struct vec3 axis = v3_cross(nrm, want);
            double sn = v3_len(axis), cs = v3_dot(nrm, want);
            if (sn > 1e-12)
                r = m3_axis_angle(v3_scale(axis, 1 / sn), k * atan2(sn, cs));
        }
        double g = gamma * s->w_face[f];
        for (int e = 0; e < 3; e++) {
            uint32_t a = t[e], b = t[(e + 1) % 3];
            struct vec3 d = v3_scale(m3_mul_v(r, v3_sub(p[e], p[(e + 1) % 3])), g);
            acc[a] += d.x, acc[n + a] += d.y, acc[2 * (size_t)n + a] += d.z;
            acc[b] -= d.x, acc[n + b] -= d.y, acc[2 * (size_t)n + b] -= d.z;
        }
    }
}

/*
 * Keep an improving iterate as a fallback for the final checks.  The
 * latest is always kept; older ones only where the proxy fell by 15 %
 * since the one before, and when the slots fill up every other one goes,
 * so the kept iterates spread over the whole run (a late iterate may
 * intersect itself where an earlier one did not).  v has just been found
 * to add no self-intersection (geometry_round checks every iterate it keeps).
 */
static void
keep_push(struct snapshot *keep, int *n_keep, const struct vec3 *v, uint32_t n, double proxy)
{
    int k = *n_keep;
    if (k >= 2 && keep[k - 1].proxy > 0.85 * keep[k - 2].proxy) {
        k--; /* the latest was only provisional: replace it */
    } else if (k == KEEP_MAX) {
        for (int i = 1; i < KEEP_MAX / 2; i++) {
            struct snapshot t = keep[i];
            keep[i] = keep[2 * i];
            keep[2 * i] = t;
        }
        k = KEEP_MAX / 2;
    }
    memcpy(keep[k].v, v, (size_t)n * sizeof(*v));
    keep[k].proxy = proxy;
    keep[k].checked = true;
    *n_keep = k + 1;
}

/*
 * Grow the fold marks (per vertex) by FREEZE_RINGS rings over m's triangles
 * and freeze the marked vertices: their share of the turn becomes 0.
 * Returns how many were not frozen before.  grow is n bytes of workspace.
 */
static uint32_t
freeze_folds(const struct mesh *m, uint8_t *fold, uint8_t *grow, double *share)
{
    uint32_t n = m->n_verts, fresh = 0;
    for (int ring = 0; ring < FREEZE_RINGS; ring++) {
        memcpy(grow, fold, n);
        for (uint32_t f = 0; f < m->n_tris; f++) {
            const uint32_t *t = m->t[f];
            if (fold[t[0]] || fold[t[1]] || fold[t[2]])
                grow[t[0]] = grow[t[1]] = grow[t[2]] = 1;
        }
        memcpy(fold, grow, n);
    }
    for (uint32_t v = 0; v < n; v++) {
        if (fold[v] && share[v] > 0) {
            share[v] = 0;
            fresh++;
        }
    }
    return fresh;
}

/* The faces' weights: their areas in ref over the mean. */
static void
face_weights(struct system *s, const struct mesh *cur, const struct mesh *ref)
{
    double area_sum = 0;
    for (uint32_t f = 0; f < cur->n_tris; f++)
        area_sum += (s->w_face[f] = mesh_tri_area(ref, f));
    double mean_area = cur->n_tris ? area_sum / cur->n_tris : 1;
    for (uint32_t f = 0; f < cur->n_tris; f++)
        s->w_face[f] = mean_area > 0 ? s->w_face[f] / mean_area : 1;
}

/* One global step: the right-hand side from the edges' targets acc, solved
   into cur's positions. */
static int
solve_step(struct mesh *cur, const struct mesh *ref, struct system *s, const double *acc,
           struct sf_err *err)
{
    uint32_t n = cur->n_verts;
    for (uint32_t v = 0; v < n; v++) {
        for (int d = 0; d < 3; d++) {
            size_t k = (size_t)d * n + v;
            double x = d == 0 ? cur->v[v].x : d == 1 ? cur->v[v].y : cur->v[v].z;
            double x0 = d == 0 ? ref->v[v].x : d == 1 ? ref->v[v].y : ref->v[v].z;
            s->rhs[k] = s->fixed[v] ? s->b0[k] : s->b0[k] + acc[k] + MU * x + s->anchor * x0;
        }
    }
    int rc = sparse_chol_solve(s->chol, s->rhs, s->x, 3, err);
    if (rc < 0)
        return rc;
    for (uint32_t v = 0; v < n; v++)
        cur->v[v] = v3(s->x[v], s->x[n + v], s->x[2 * (size_t)n + v]);
    return SF_OK;
}

/* Count the iterate, its risky faces on the curve, and the progress callback. */
static void
note_iterate(const struct surfopt_params *p, int round, int it, const struct support_metrics *sm,
             const struct deviation *dev, struct surfopt_result *res)
{
    res->n_iters++;
    if (res->n_curve < SURFOPT_CURVE_MAX)
        res->curve[res->n_curve++] = sm->n_risky;
    if (p->progress) {
        struct surfopt_progress pr = { round,       p->rounds, it,       p->max_iters,
                                       sm->n_risky, dev->mndr, dev->andr };
        p->progress(p->progress_ud, &pr);
    }
}

/* Past the largest move only: mark the vertices that moved more than lim
   from ref (fold[v] 1, else 0); returns how many. */
static uint32_t
mark_far(const struct mesh *cur, const struct mesh *ref, double lim, uint8_t *fold)
{
    uint32_t far = 0;
    for (uint32_t v = 0; v < cur->n_verts; v++)
        far += (fold[v] = v3_len(v3_sub(cur->v[v], ref->v[v])) > lim);
    return far;
}

/* Factorize the system again at weights beta and anchor (timed in res). */
static int
refactor(struct system *s, const struct mesh *cur, const struct mesh *ref,
         const struct surfopt_params *p, double beta, double anchor, struct surfopt_result *res,
         struct sf_err *err)
{
    double tf = clock_mono_s();
    system_free_factor(s);
    int rc = system_build(s, cur, ref, p, beta, anchor, err);
    if (rc < 0)
        return rc;
    res->factor_s += clock_mono_s() - tf;
    return SF_OK;
}

/* A round's scratch: n = cur->n_verts of each (acc 3n). */
struct round_buf {
    double *acc;
    struct vec3 *best;
    double *share;
    uint8_t *fold, *grow, *held;
};

static void
round_buf_release(struct round_buf *rb)
{
    free(rb->acc);
    free(rb->best);
    free(rb->share);
    free(rb->fold);
    free(rb->grow);
    free(rb->held);
}

/* rb's buffers and s's face weights for cur, the shares from the saliency
   sal (folds freeze); SF_ENOMEM (release rb all the same). */
static int
round_buf_alloc(struct round_buf *rb, struct system *s, const struct mesh *cur, const double *sal,
                struct sf_err *err)
{
    uint32_t n = cur->n_verts;
    rb->acc = mem_array(3 * (size_t)n, sizeof(double));
    rb->best = mem_array(n, sizeof(*rb->best));
    rb->share = mem_array(n, sizeof(double));
    rb->fold = mem_array(n, 1), rb->grow = mem_array(n, 1), rb->held = mem_calloc(n, 1);
    s->w_face = mem_array(cur->n_tris, sizeof(double));
    if (!rb->acc || !rb->best || !rb->share || !rb->fold || !rb->grow || !rb->held || !s->w_face)
        return sf_err_set(err, SF_ENOMEM, "surface optimizer: out of memory for %u vertices", n);
    memcpy(rb->share, sal, (size_t)n * sizeof(*rb->share));
    return SF_OK;
}

/* The round's first system: face weights, neighbours, factor (timed in res). */
static int
system_start(struct system *s, struct mesh *cur, const struct mesh *ref,
             const struct surfopt_params *p, struct surfopt_result *res, struct sf_err *err)
{
    int rc;
    face_weights(s, cur, ref);
    double t0 = clock_mono_s();
    if ((p->beta > 0 && (rc = build_neighbours(cur, s, err)) < 0) ||
        (rc = system_build(s, cur, ref, p, p->beta, p->anchor, err)) < 0)
        return rc;
    res->factor_s += clock_mono_s() - t0;
    return SF_OK;
}

/*
 * Freezing: a fold is local (a thin fin, a tight crease), and so is a move
 * past the largest allowed one (a flange, a ledge): the vertices where it
 * crossed or moved too far (rb->fold) and two rings around them keep their
 * shape from now on (their faces ask for no turn), and the round goes on
 * from the best shape at the same step, so the rest of the part still
 * turns; with FREEZE_HOLD they are also held where the best shape has them
 * (a frozen vertex still moved with its neighbours' turns, which dragged a
 * fold back: scad example006's dimples).  Returns 1 when it froze (cur is
 * the best shape again), 0 when nothing new can be frozen or after
 * FREEZE_MAX freezes (the caller halves the turns everywhere), or an error.
 */
static int
freeze_step(struct mesh *cur, const struct mesh *ref, struct system *s, struct round_buf *rb,
            int freeze, int *n_freezes, double beta, double anchor, const struct surfopt_params *p,
            struct surfopt_result *res, struct sf_err *err)
{
    uint32_t n = cur->n_verts;
    if (!(freeze_folds(ref, rb->fold, rb->grow, rb->share) > 0 && *n_freezes < FREEZE_MAX))
        return 0;
    (*n_freezes)++;
    res->n_frozen++;
    memcpy(cur->v, rb->best, (size_t)n * sizeof(*rb->best));
    if (freeze == FREEZE_HOLD) {
        for (uint32_t v = 0; v < n; v++)
            rb->held[v] |= rb->fold[v];
        s->hold = rb->held;
        int rc = refactor(s, cur, ref, p, beta, anchor, res, err);
        if (rc < 0)
            return rc;
    }
    return 1;
}

/* How a round is getting on: the best proxy, and the iterations since it
   last dropped by CRAWL (from stall_ref). */
struct pace {
    double best_proxy, stall_ref;
    int since_best;
};

/* After an iterate within the limits (improved: its proxy is the new best):
   *crawling, improving by less than CRAWL in patience iterations; *stalled,
   not improving in patience iterations. */
static void
pace_step(struct pace *pc, bool improved, double proxy, int patience, bool *crawling, bool *stalled)
{
    if (improved) {
        pc->best_proxy = proxy;
        if (pc->best_proxy < pc->stall_ref * (1 - CRAWL)) {
            pc->since_best = 0;
            pc->stall_ref = pc->best_proxy;
        } else {
            *crawling = ++pc->since_best >= patience;
        }
    } else {
        *stalled = ++pc->since_best >= patience;
    }
}

/* check: selfx_ref_count of cur (marks in fold), timed into res->selfx_s
   and moving *t0 on by as much; else 0. */
static int
new_folds(struct selfx_ref *sxr, const struct mesh *cur, bool check, uint8_t *fold,
          struct surfopt_result *res, double *t0, struct sf_err *err)
{
    if (!check)
        return 0;
    double t = clock_mono_s();
    int folds = selfx_ref_count(sxr, cur, fold, err);
    t = clock_mono_s() - t;
    res->selfx_s += t;
    *t0 += t;
    return folds;
}

/* One geometry round in the current frame.  cur ends as the round's best. */
static int
geometry_round(struct mesh *cur, const struct mesh *ref, struct selfx_ref *sxr, const double *sal,
               const struct surfopt_params *p, int round, int freeze, struct surfopt_result *res,
               struct snapshot *keep, int *n_keep, int *n_improved, struct sf_err *err)
{
    uint32_t n = cur->n_verts;
    struct system s = { 0 };
    struct round_buf rb;
    int rc = round_buf_alloc(&rb, &s, cur, sal, err);
    if (rc < 0)
        goto out;
    int n_freezes = 0;
    double beta = p->beta, anchor = p->anchor;
    if ((rc = system_start(&s, cur, ref, p, res, err)) < 0)
        goto out;
    double t0 = clock_mono_s();

    struct support_params sp = support_at(p->angle_deg);
    struct support_metrics sm;
    measure_proxy(cur, v3(0, 0, 1), &sp, &sm);
    struct pace pc = { sm.proxy_mm3, sm.proxy_mm3, 0 };
    if (res->n_curve == 0)
        res->curve[res->n_curve++] = sm.n_risky; /* the oriented input */
    memcpy(rb.best, cur->v, (size_t)n * sizeof(*rb.best));
    *n_improved = 0;
    struct vec3 centre;
    mesh_volume(cur, &centre);
    double sin_a = sin((p->angle_deg - p->margin_deg) * M_PI / 180);
    double aim = (p->angle_deg - p->margin_deg) * M_PI / 180;
    double diag = mesh_diag(ref);
    double step = 1; /* share of each face's turn asked for; halved past the limits */
    for (int it = 1; it <= p->max_iters; it++) {
        if (p->cancel && atomic_load(p->cancel)) {
            rc = sf_err_set(err, SF_ECANCELED, "surface optimization cancelled");
            goto out;
        }
        edge_rhs(cur, &s, rb.share, step, sin_a, aim, centre, p->gamma, rb.acc);
        if ((rc = solve_step(cur, ref, &s, rb.acc, err)) < 0)
            goto out;
        measure_proxy(cur, v3(0, 0, 1), &sp, &sm);
        struct deviation dev;
        measure_deviation(ref, cur, &dev, NULL);
        note_iterate(p, round, it, &sm, &dev, res);
        bool improved = sm.proxy_mm3 < pc.best_proxy * (1 - 1e-6);
        /* new self-intersections, checked only where the shape would be kept
           (iterate_s leaves their seconds to selfx_s) */
        bool check = improved && dev.mndr <= p->max_mndr && dev.andr <= p->max_andr;
        int folds = new_folds(sxr, cur, check, rb.fold, res, &t0, err);
        if ((rc = folds) < 0)
            goto out;
        res->n_folded += folds > 0;
        uint32_t far = 0;
        if (freeze && folds == 0 && dev.mndr > p->max_mndr && dev.andr <= p->max_andr)
            far = mark_far(cur, ref, p->max_mndr * diag, rb.fold);
        if ((folds > 0 || far > 0) && freeze) {
            double factor_s = res->factor_s;
            if ((rc = freeze_step(cur, ref, &s, &rb, freeze, &n_freezes, beta, anchor, p, res,
                                  err)) < 0)
                goto out;
            t0 += res->factor_s - factor_s; /* a hold's refactor: in factor_s only */
            if (rc > 0) {
                pc.since_best = 0;
                continue;
            }
        }
        if (dev.mndr > p->max_mndr || dev.andr > p->max_andr || folds > 0) {
            /* Past the deviation limits, or folded onto itself: the turns
             * are too bold for this part (few, large faces; thin features).
             * Halve them and go on from the best shape; once they are
             * small, the round is done. */
            if (step <= 1.0 / 16)
                break;
            step /= 2;
            res->n_halved++;
            memcpy(cur->v, rb.best, (size_t)n * sizeof(*rb.best));
            pc.since_best = 0;
            continue;
        }
        bool crawling = false, stalled = false;
        if (improved) {
            memcpy(rb.best, cur->v, (size_t)n * sizeof(*rb.best));
            (*n_improved)++;
            keep_push(keep, n_keep, cur->v, n, sm.proxy_mm3);
        }
        pace_step(&pc, improved, sm.proxy_mm3, p->patience, &crawling, &stalled);
        if (crawling || stalled) {
            /* Adaptive weight: stalled, or crawling (under CRAWL in
             * `patience` iterations), well inside the deviation budget,
             * the input's detail is holding the faces back; loosen it and
             * go on from the best shape.  Otherwise a stalled round is
             * done and a crawling one goes on. */
            bool loosen =
                (p->beta > 0 && beta > p->beta / 64) || (p->anchor > 0 && anchor > p->anchor / 64);
            if (step < 1 || !loosen || dev.mndr > p->max_mndr / 2 || dev.andr > p->max_andr / 2) {
                if (stalled)
                    break;
                pc.since_best = 0;
                pc.stall_ref = pc.best_proxy;
                continue;
            }
            beta /= 4;
            anchor /= 4;
            memcpy(cur->v, rb.best, (size_t)n * sizeof(*rb.best));
            double factor_s = res->factor_s;
            if ((rc = refactor(&s, cur, ref, p, beta, anchor, res, err)) < 0)
                goto out;
            t0 += res->factor_s - factor_s; /* in factor_s, not iterate_s */
            pc.since_best = 0;
            pc.stall_ref = pc.best_proxy;
        }
    }
    memcpy(cur->v, rb.best, (size_t)n * sizeof(*rb.best));
    res->iterate_s += clock_mono_s() - t0;
    rc = SF_OK;
out:
    system_free(&s);
    round_buf_release(&rb);
    return rc;
}

/* Turn an array of n positions like mesh_rotate_up, then move it by t. */
static void
move_positions(struct vec3 *v, uint32_t n, const struct vec3 *up, struct vec3 t)
{
    struct mesh view = { .v = v, .n_verts = n };
    if (up)
        mesh_rotate_up(&view, *up);
    mesh_translate(&view, t);
}

/*
 * Orientation step: turn cur onto the orienter's best up, then rest it on
 * the bed; ref and the kept iterates move the same way, so deviations and
 * fallbacks stay comparable.
 */
static int
orientation_step(struct mesh *cur, struct mesh *ref, struct snapshot *keep, int n_keep,
                 const struct surfopt_params *p, bool search, struct sf_err *err)
{
    struct vec3 up = v3(0, 0, 1);
    if (search) {
        struct orient_params op = p->op;
        op.angle_deg = p->angle_deg;
        struct orient_result found;
        int rc = orient_find(cur, &op, &found, err);
        if (rc < 0)
            return rc;
        up = found.best.up;
    }
    bool turn = v3_dot(up, v3(0, 0, 1)) < cos(0.1 * M_PI / 180);
    const struct vec3 *r = turn ? &up : NULL;
    move_positions(cur->v, cur->n_verts, r, v3(0, 0, 0));
    struct vec3 t = rest_offset(cur);
    mesh_translate(cur, t);
    move_positions(ref->v, ref->n_verts, r, t);
    for (int k = 0; k < n_keep; k++) {
        move_positions(keep[k].v, cur->n_verts, r, t);
        keep[k].checked = false; /* a float cast of other positions */
    }
    return SF_OK;
}

/*
 * What both runs of surfopt_optimize start from, made once: the refined
 * input, its saliency, its crossings, the first orientation step and the
 * model of its result (each a pure function of the part and p, so the
 * freezing run saw the same; they were half of its time).
 */
struct prep {
    struct mesh ref;      /* the refined input after the first orientation step */
    struct mesh oriented; /* the same, the start of each run */
    double *sal;          /* per vertex: the share of its target it moves */
    struct selfx_ref *sxr;
    struct support_metrics input, oriented_m;
    double model_g, model_s; /* the model of the oriented part: grams, seconds */
    double saliency_s, orient_s, selfx_s, model_eval_s; /* wall seconds of each */
};

static void
prep_release(struct prep *pr)
{
    mesh_release(&pr->ref);
    mesh_release(&pr->oriented);
    free(pr->sal);
    selfx_ref_free(pr->sxr);
}

static int
prep_make(const struct mesh *m, const struct surfopt_params *p, struct prep *pr, struct sf_err *err)
{
    memset(pr, 0, sizeof(*pr));
    mesh_init(&pr->ref);
    mesh_init(&pr->oriented);
    int rc;
    if ((rc = mesh_copy(&pr->ref, m, err)) < 0 ||
        (rc = mesh_refine(&pr->ref, p->refine_tris, 0.01 * mesh_diag(m), 4 * p->refine_tris, err)) <
            0 ||
        (rc = mesh_copy(&pr->oriented, &pr->ref, err)) < 0)
        return rc;
    uint32_t n = pr->ref.n_verts;
    if (!(pr->sal = mem_array(n, sizeof(double))))
        return sf_err_set(err, SF_ENOMEM, "surface optimizer: out of memory for %u vertices", n);
    if ((rc = surfopt_ray_metrics(m, p->angle_deg, &pr->input, err)) < 0)
        return rc;
    double t0 = clock_mono_s();
    if ((rc = mesh_saliency(&pr->ref, pr->sal, err)) < 0)
        return rc;
    for (uint32_t v = 0; v < n; v++)
        pr->sal[v] = 1 - p->saliency * pr->sal[v]; /* the share of its target a vertex moves */
    pr->saliency_s = clock_mono_s() - t0;
    /* the input's crossings, noted once: the orientation steps move ref
       rigidly, which keeps its shells, crossings and distances */
    t0 = clock_mono_s();
    if (!(pr->sxr = selfx_ref_new(&pr->ref, SELFX_TOUCH * mesh_diag(&pr->ref), err)))
        return err->code;
    pr->selfx_s = clock_mono_s() - t0;
    t0 = clock_mono_s();
    if ((rc = orientation_step(&pr->oriented, &pr->ref, NULL, 0, p, p->orient && !p->keep_start_up,
                               err)) < 0)
        return rc;
    pr->orient_s = clock_mono_s() - t0;
    if ((rc = surfopt_ray_metrics(&pr->oriented, p->angle_deg, &pr->oriented_m, err)) < 0)
        return rc;
    struct supmodel_params mp;
    supmodel_params_steer(&mp, p->angle_deg);
    struct supmodel_result mr;
    t0 = clock_mono_s();
    if ((rc = supmodel_of_mesh(&pr->oriented, v3(0, 0, 1), &mp, &mr, err)) < 0)
        return rc;
    pr->model_eval_s = clock_mono_s() - t0;
    pr->model_g = mr.grams;
    pr->model_s = mr.time_s;
    return SF_OK;
}

/* One optimization from pr; a fold halves the turns, or with freeze first
   freezes where it folded (geometry_round). */
static int
optimize_once(const struct mesh *m, const struct surfopt_params *p, const struct prep *pr,
              int freeze, struct surfopt_result *res, struct sf_err *err)
{
    memset(res, 0, sizeof(*res));
    mesh_init(&res->out);
    double t_start = clock_mono_s();
    res->input = pr->input;
    res->oriented = pr->oriented_m;
    res->selfx_input = selfx_ref_input_count(pr->sxr);
    res->model_oriented_g = pr->model_g;
    res->saliency_s = pr->saliency_s;
    res->orient_s = pr->orient_s;
    res->selfx_s = pr->selfx_s;
    res->model_s = pr->model_eval_s;
    struct mesh cur, ref;
    mesh_init(&cur);
    mesh_init(&ref);
    int rc;
    if ((rc = mesh_copy(&ref, &pr->ref, err)) < 0 ||
        (rc = mesh_copy(&cur, &pr->oriented, err)) < 0 ||
        (rc = selfx_ref_rebind(pr->sxr, &ref, err)) < 0) {
        mesh_release(&ref);
        mesh_release(&cur);
        return rc;
    }
    uint32_t n = cur.n_verts;
    struct snapshot keep[KEEP_MAX] = { 0 };
    int n_keep = 0;
    for (int k = 0; k < KEEP_MAX; k++) {
        if (!(keep[k].v = mem_array(n, sizeof(struct vec3)))) {
            rc = sf_err_set(err, SF_ENOMEM, "surface optimizer: out of memory for %u vertices", n);
            goto out;
        }
    }
    for (int round = 0; round < p->rounds; round++) {
        double t0 = clock_mono_s();
        /* round 0's orientation step is pr's */
        if (round > 0 && (rc = orientation_step(&cur, &ref, keep, n_keep, p, p->orient, err)) < 0)
            goto out;
        res->orient_s += clock_mono_s() - t0;
        int n_improved = 0;
        if ((rc = geometry_round(&cur, &ref, pr->sxr, pr->sal, p, round, freeze, res, keep, &n_keep,
                                 &n_improved, err)) < 0)
            goto out;
        res->n_rounds++;
        if (n_improved == 0 || !p->orient)
            break; /* another orientation step would see the same shape */
    }

    /* the result: a kept shape, or the orientation alone (choose_kept) */
    double t0 = clock_mono_s();
    struct support_metrics sm;
    if ((rc = surfopt_choose_kept(m, &cur, pr->model_s, keep, n_keep, pr->sxr, p, res, &sm, err)) <
        0)
        goto out;
    res->check_s = clock_mono_s() - t0;
    if (res->shape_changed) {
        res->out = cur;
        mesh_init(&cur);
        res->after = sm;
        struct vec3 t = rest_offset(&res->out);
        mesh_translate(&res->out, t);
        mesh_translate(&ref, t);
        measure_deviation(&ref, &res->out, &res->dev, NULL);
    } else {
        if ((rc = mesh_copy(&res->out, &pr->oriented, err)) < 0)
            goto out;
        res->after = res->oriented;
        res->selfx_out = res->selfx_input;
    }
    rc = SF_OK;
out:
    res->total_s = clock_mono_s() - t_start;
    for (int k = 0; k < KEEP_MAX; k++)
        free(keep[k].v);
    mesh_release(&cur);
    mesh_release(&ref);
    if (rc < 0)
        mesh_release(&res->out);
    return rc;
}

/* Add the seconds of run b, beyond what both runs share from pr, to a's. */
static void
seconds_add(struct surfopt_result *a, const struct surfopt_result *b, const struct prep *pr)
{
    a->factor_s += b->factor_s;
    a->iterate_s += b->iterate_s;
    a->check_s += b->check_s;
    a->orient_s += b->orient_s - pr->orient_s;
    a->selfx_s += b->selfx_s - pr->selfx_s;
    a->model_s += b->model_s - pr->model_eval_s;
}

int
surfopt_optimize(const struct mesh *m, const struct surfopt_params *p, struct surfopt_result *res,
                 struct sf_err *err)
{
    memset(res, 0, sizeof(*res));
    mesh_init(&res->out);
    int rc = surfopt_check_params(p, err);
    if (rc < 0)
        return rc;
    if (m->n_verts < 4 || m->n_tris < 4)
        return sf_err_set(err, SF_EINVAL, "part has %u triangles: nothing to optimize", m->n_tris);
    double t0 = clock_mono_s();
    struct prep pr;
    if ((rc = prep_make(m, p, &pr, err)) < 0 ||
        (rc = optimize_once(m, p, &pr, FREEZE_NONE, res, err)) < 0 || res->n_halved == 0)
        goto out;
    /* Some iterate folded or moved too far, and halving the turns
     * everywhere held the whole part back for it: run again freezing only
     * where it folded or moved too far, and the model picks (anchor's 4 searched directions:
     * one 10.84 -> 6.83 model g halving, 9.01 freezing; cow's best 3.67 -> 2.60 halving, 2.96 ->
     * 1.37 freezing); when it froze any, once more holding the frozen
     * vertices in place (surfopt.h).  The kept run's seconds count every run. */
    for (int mode = FREEZE_SOFT; mode <= FREEZE_HOLD; mode++) {
        struct surfopt_result alt;
        if ((rc = optimize_once(m, p, &pr, mode, &alt, err)) < 0) {
            surfopt_result_release(res);
            goto out;
        }
        bool froze = alt.n_frozen > 0;
        if (alt.model_after_g < res->model_after_g) {
            struct surfopt_result t = *res;
            *res = alt;
            alt = t;
        }
        seconds_add(res, &alt, &pr);
        surfopt_result_release(&alt);
        if (!froze)
            break; /* holding nothing frozen is the same run */
    }
out:
    res->total_s = clock_mono_s() - t0;
    prep_release(&pr);
    return rc;
}
