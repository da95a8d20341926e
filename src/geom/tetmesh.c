/*
 * tetmesh.c - the enclosing tet mesh and the part's embedding (see
 * tetmesh.h; Hu 2015, sec. 3).
 *
 * Design: envelope (offset surface) -> TetGen with quality switches ->
 * orient every tet positively -> surface faces (faces used by one tet,
 * found by sorting the 4 n faces by their vertex triple) -> split tets with
 * three or more surface faces at their centroid -> embed each part vertex
 * in the tet whose smallest barycentric coordinate is largest (>= 0 means
 * inside), looked up through a bucket grid of tet bounding boxes.  When
 * the mesh has too many vertices the lattice is coarsened and it is built
 * again.
 *
 * Thread: the caller's; no shared state.
 */
#include "tetmesh.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../base/log.h"
#include "../base/mem.h"
#include "envelope.h"
#include "tet_shim.h"

const int tetmesh_face[4][3] = { { 1, 2, 3 }, { 0, 3, 2 }, { 0, 1, 3 }, { 0, 2, 1 } };

void
tetmesh_params_default(struct tetmesh_params *p)
{
    p->max_verts = 5000;
    p->cells = 16;
    p->offset_cells = 1.2;
    p->switches = "pq2.0Y";
}

void
tetmesh_release(struct tetmesh *tm)
{
    free(tm->x);
    free(tm->tet);
    free(tm->surf);
    free(tm->host);
    free(tm->bary);
    memset(tm, 0, sizeof(*tm));
}

static double
vol6(struct vec3 a, struct vec3 b, struct vec3 c, struct vec3 d)
{
    return v3_dot(v3_sub(b, a), v3_cross(v3_sub(c, a), v3_sub(d, a)));
}

double
tetmesh_volume(const struct tetmesh *tm, const struct vec3 *x, uint32_t t)
{
    const uint32_t *q = tm->tet[t];
    return vol6(x[q[0]], x[q[1]], x[q[2]], x[q[3]]) / 6;
}

struct face_key {
    uint32_t v[3]; /* sorted vertex indices */
    uint32_t tet;
    uint8_t f;
};

static int
face_cmp(const void *pa, const void *pb)
{
    const struct face_key *a = pa, *b = pb;
    for (int i = 0; i < 3; i++)
        if (a->v[i] != b->v[i])
            return a->v[i] < b->v[i] ? -1 : 1;
    return 0;
}

static int
find_surface(struct tetmesh *tm, struct sf_err *err)
{
    size_t nf = (size_t)tm->n_tets * 4;
    struct face_key *fk = mem_array(nf, sizeof(*fk));
    tm->surf = mem_calloc(tm->n_tets ? tm->n_tets : 1, 1);
    if (!fk || !tm->surf) {
        free(fk);
        return sf_err_set(err, SF_ENOMEM, "tetmesh: out of memory for %zu faces", nf);
    }
    for (uint32_t t = 0; t < tm->n_tets; t++)
        for (int f = 0; f < 4; f++) {
            struct face_key *k = &fk[(size_t)t * 4 + (size_t)f];
            for (int i = 0; i < 3; i++)
                k->v[i] = tm->tet[t][tetmesh_face[f][i]];
            for (int i = 0; i < 2; i++) /* sort three */
                for (int j = 0; j < 2 - i; j++)
                    if (k->v[j] > k->v[j + 1]) {
                        uint32_t s = k->v[j];
                        k->v[j] = k->v[j + 1];
                        k->v[j + 1] = s;
                    }
            k->tet = t;
            k->f = (uint8_t)f;
        }
    qsort(fk, nf, sizeof(*fk), face_cmp);
    for (size_t i = 0; i < nf;) {
        size_t j = i + 1;
        while (j < nf && face_cmp(&fk[i], &fk[j]) == 0)
            j++;
        if (j - i == 1)
            tm->surf[fk[i].tet] |= (uint8_t)(1u << fk[i].f);
        i = j;
    }
    free(fk);
    return SF_OK;
}

static int
popcount4(uint8_t m)
{
    return (m & 1) + ((m >> 1) & 1) + ((m >> 2) & 1) + ((m >> 3) & 1);
}

/* Split every tet with 3+ surface faces into 4 around its centroid. */
static int
split_corners(struct tetmesh *tm, struct sf_err *err)
{
    uint32_t n = 0;
    for (uint32_t t = 0; t < tm->n_tets; t++)
        n += popcount4(tm->surf[t]) >= 3;
    tm->n_split = n;
    if (!n)
        return SF_OK;
    uint32_t nv = tm->n_verts + n, nt = tm->n_tets + 3 * n;
    void *x = mem_realloc_array(tm->x, nv, sizeof(*tm->x));
    if (x)
        tm->x = x;
    void *tt = x ? mem_realloc_array(tm->tet, nt, sizeof(*tm->tet)) : NULL;
    if (tt)
        tm->tet = tt;
    void *s = tt ? mem_realloc_array(tm->surf, nt, 1) : NULL;
    if (!s)
        return sf_err_set(err, SF_ENOMEM, "tetmesh: out of memory splitting %u tets", n);
    tm->surf = s;
    uint32_t vi = tm->n_verts, ti = tm->n_tets, old = tm->n_tets;
    for (uint32_t t = 0; t < old; t++) {
        uint8_t m = tm->surf[t];
        if (popcount4(m) < 3)
            continue;
        uint32_t q[4];
        memcpy(q, tm->tet[t], sizeof(q));
        struct vec3 c = v3(0, 0, 0);
        for (int i = 0; i < 4; i++)
            c = v3_add(c, tm->x[q[i]]);
        tm->x[vi] = v3_scale(c, 0.25);
        for (int f = 0; f < 4; f++) {
            uint32_t dst = f == 0 ? t : ti++;
            const int *fv = tetmesh_face[f];
            /* outward face (a, b, c) with the centroid inside: (a, c, b, e) is positive */
            tm->tet[dst][0] = q[fv[0]];
            tm->tet[dst][1] = q[fv[2]];
            tm->tet[dst][2] = q[fv[1]];
            tm->tet[dst][3] = vi;
            tm->surf[dst] = (m >> f) & 1 ? 8 : 0; /* face opposite the centroid */
        }
        vi++;
    }
    tm->n_verts = nv;
    tm->n_tets = nt;
    return SF_OK;
}

static double
mesh_diag_of(struct vec3 lo, struct vec3 hi)
{
    return v3_len(v3_sub(hi, lo));
}

/* Barycentric coordinates of p in tet t; returns the smallest. */
static double
bary_of(const struct tetmesh *tm, uint32_t t, struct vec3 p, double b[4])
{
    const uint32_t *q = tm->tet[t];
    struct vec3 a = tm->x[q[0]], bb = tm->x[q[1]], c = tm->x[q[2]], d = tm->x[q[3]];
    double v = vol6(a, bb, c, d);
    b[0] = vol6(p, bb, c, d) / v;
    b[1] = vol6(a, p, c, d) / v;
    b[2] = vol6(a, bb, p, d) / v;
    b[3] = 1 - b[0] - b[1] - b[2];
    return fmin(fmin(b[0], b[1]), fmin(b[2], b[3]));
}

int
tetmesh_locate(const struct tetmesh *tm, const struct vec3 *pts, uint32_t n_pts, uint32_t *host,
               double (*bary)[4], uint32_t *n_outside, struct sf_err *err)
{
    struct vec3 lo = tm->x[0], hi = tm->x[0];
    for (uint32_t i = 1; i < tm->n_verts; i++) {
        lo = v3_min(lo, tm->x[i]);
        hi = v3_max(hi, tm->x[i]);
    }
    double cell = tm->pitch_mm > 0 ? tm->pitch_mm : fmax(mesh_diag_of(lo, hi) / 16, 1e-9);
    uint32_t n[3] = { (uint32_t)((hi.x - lo.x) / cell) + 1, (uint32_t)((hi.y - lo.y) / cell) + 1,
                      (uint32_t)((hi.z - lo.z) / cell) + 1 };
    size_t nc = (size_t)n[0] * n[1] * n[2];
    uint32_t *start = mem_calloc(nc + 1, sizeof(uint32_t));
    uint32_t *list = NULL;
    int rc = SF_OK;
    if (!start) {
        rc = sf_err_set(err, SF_ENOMEM, "tetmesh: out of memory for the tet grid");
        goto done;
    }
    /* two passes over tet bounding boxes: count, then fill (CSR) */
    for (int pass = 0; pass < 2; pass++) {
        for (uint32_t t = 0; t < tm->n_tets; t++) {
            struct vec3 a = tm->x[tm->tet[t][0]], b = a;
            for (int k = 1; k < 4; k++) {
                a = v3_min(a, tm->x[tm->tet[t][k]]);
                b = v3_max(b, tm->x[tm->tet[t][k]]);
            }
            uint32_t i0 = (uint32_t)((a.x - lo.x) / cell), i1 = (uint32_t)((b.x - lo.x) / cell);
            uint32_t j0 = (uint32_t)((a.y - lo.y) / cell), j1 = (uint32_t)((b.y - lo.y) / cell);
            uint32_t k0 = (uint32_t)((a.z - lo.z) / cell), k1 = (uint32_t)((b.z - lo.z) / cell);
            for (uint32_t k = k0; k <= k1 && k < n[2]; k++)
                for (uint32_t j = j0; j <= j1 && j < n[1]; j++)
                    for (uint32_t i = i0; i <= i1 && i < n[0]; i++) {
                        size_t c = ((size_t)k * n[1] + j) * n[0] + i;
                        if (pass == 0)
                            start[c + 1]++;
                        else
                            list[start[c]++] = t;
                    }
        }
        if (pass == 0) {
            for (size_t c = 0; c < nc; c++)
                start[c + 1] += start[c];
            list = mem_array(start[nc] ? start[nc] : 1, sizeof(uint32_t));
            if (!list) {
                rc = sf_err_set(err, SF_ENOMEM, "tetmesh: out of memory for the tet grid");
                goto done;
            }
        } else {
            for (size_t c = nc; c > 0; c--) /* fill advanced each start to the next one's */
                start[c] = start[c - 1];
            start[0] = 0;
        }
    }
    uint32_t outside = 0;
    for (uint32_t v = 0; v < n_pts; v++) {
        struct vec3 p = pts[v];
        double best = -INFINITY, b[4], keep[4] = { 0.25, 0.25, 0.25, 0.25 };
        uint32_t bt = 0;
        long i = (long)floor((p.x - lo.x) / cell), j = (long)floor((p.y - lo.y) / cell),
             k = (long)floor((p.z - lo.z) / cell);
        if (i >= 0 && j >= 0 && k >= 0 && i < (long)n[0] && j < (long)n[1] && k < (long)n[2]) {
            size_t c = ((size_t)k * n[1] + (size_t)j) * n[0] + (size_t)i;
            for (uint32_t q = start[c]; q < start[c + 1]; q++) {
                double m = bary_of(tm, list[q], p, b);
                if (m > best) {
                    best = m;
                    bt = list[q];
                    memcpy(keep, b, sizeof(b));
                    if (m >= 0)
                        break; /* inside: any containing tet will do */
                }
            }
        }
        if (best < -1e-9) { /* outside every tet nearby: the nearest tet anywhere */
            outside++;
            for (uint32_t t = 0; t < tm->n_tets; t++) {
                double m = bary_of(tm, t, p, b);
                if (m > best) {
                    best = m;
                    bt = t;
                    memcpy(keep, b, sizeof(b));
                }
            }
        }
        host[v] = bt;
        if (bary)
            memcpy(bary[v], keep, sizeof(keep));
    }
    if (n_outside)
        *n_outside = outside;
done:
    free(start);
    free(list);
    return rc;
}

static int
embed(struct tetmesh *tm, const struct mesh *part, struct sf_err *err)
{
    tm->n_part = part->n_verts;
    tm->host = mem_array(part->n_verts ? part->n_verts : 1, sizeof(uint32_t));
    tm->bary = mem_array(part->n_verts ? part->n_verts : 1, sizeof(*tm->bary));
    if (!tm->host || !tm->bary)
        return sf_err_set(err, SF_ENOMEM, "tetmesh: out of memory embedding the part");
    return tetmesh_locate(tm, part->v, part->n_verts, tm->host, tm->bary, &tm->n_outside, err);
}

static int
build_once(const struct mesh *part, const struct tetmesh_params *p, double pitch,
           struct tetmesh *tm, struct sf_err *err)
{
    struct mesh env;
    mesh_init(&env);
    int rc = envelope_build(part, pitch, p->offset_cells * pitch, &env, err);
    if (rc)
        return rc;
    struct tet_shim_out out;
    double *xyz = mem_array(env.n_verts, 3 * sizeof(double));
    if (!xyz) {
        mesh_release(&env);
        return sf_err_set(err, SF_ENOMEM, "tetmesh: out of memory");
    }
    memcpy(xyz, env.v, sizeof(double) * 3 * env.n_verts);
    rc =
        tet_shim_tetrahedralize(xyz, env.n_verts, &env.t[0][0], env.n_tris, p->switches, &out, err);
    free(xyz);
    tm->n_env_tris = env.n_tris;
    mesh_release(&env);
    if (rc)
        return rc;
    tm->pitch_mm = pitch;
    tm->n_verts = out.n_points;
    tm->n_tets = out.n_tets;
    tm->x = (struct vec3 *)out.xyz; /* struct vec3 is three packed doubles */
    tm->tet = (uint32_t(*)[4])out.tets;
    for (uint32_t t = 0; t < tm->n_tets; t++)
        if (tetmesh_volume(tm, tm->x, t) < 0) {
            uint32_t s = tm->tet[t][2];
            tm->tet[t][2] = tm->tet[t][3];
            tm->tet[t][3] = s;
        }
    return SF_OK;
}

int
tetmesh_build(const struct mesh *part, const struct tetmesh_params *p, struct tetmesh *tm,
              struct sf_err *err)
{
    memset(tm, 0, sizeof(*tm));
    if (!part->n_tris)
        return sf_err_set(err, SF_EINVAL, "tetmesh: the part has no triangles");
    if (p->cells < 2 || p->max_verts < 8 || !(p->offset_cells > 0))
        return sf_err_set(err, SF_EINVAL, "tetmesh: bad parameters (cells %d, max_verts %u)",
                          p->cells, p->max_verts);
    struct vec3 lo, hi;
    mesh_bbox(part, &lo, &hi);
    double longest = fmax(hi.x - lo.x, fmax(hi.y - lo.y, hi.z - lo.z));
    double pitch = longest / p->cells;
    int rc = SF_OK;
    for (int attempt = 0;; attempt++) {
        rc = build_once(part, p, pitch, tm, err);
        if (rc)
            return rc;
        if (tm->n_verts <= p->max_verts)
            break;
        if (attempt == 12) {
            uint32_t nv = tm->n_verts;
            tetmesh_release(tm);
            return sf_err_set(err, SF_EINVAL,
                              "tetmesh: still %u vertices at a %.2f mm pitch (target %u)", nv,
                              pitch, p->max_verts);
        }
        /* vertices scale about as pitch^-2 (surface) to pitch^-3 (volume) */
        double f = pow((double)tm->n_verts / p->max_verts, 0.4) * 1.03;
        pitch *= f > 1.05 ? f : 1.05;
        tetmesh_release(tm);
    }
    if ((rc = find_surface(tm, err)) || (rc = split_corners(tm, err)) ||
        (rc = embed(tm, part, err))) {
        tetmesh_release(tm);
        return rc;
    }
    log_debug("slim",
              "tet mesh: pitch %.2f mm, %u envelope triangles, %u vertices, %u tets, "
              "%u split, %u part vertices outside",
              tm->pitch_mm, tm->n_env_tris, tm->n_verts, tm->n_tets, tm->n_split, tm->n_outside);
    return SF_OK;
}

void
tetmesh_map(const struct tetmesh *tm, const struct vec3 *x, struct vec3 *part_v)
{
    for (uint32_t v = 0; v < tm->n_part; v++) {
        const uint32_t *q = tm->tet[tm->host[v]];
        const double *b = tm->bary[v];
        part_v[v] = v3(b[0] * x[q[0]].x + b[1] * x[q[1]].x + b[2] * x[q[2]].x + b[3] * x[q[3]].x,
                       b[0] * x[q[0]].y + b[1] * x[q[1]].y + b[2] * x[q[2]].y + b[3] * x[q[3]].y,
                       b[0] * x[q[0]].z + b[1] * x[q[1]].z + b[2] * x[q[2]].z + b[3] * x[q[3]].z);
    }
}
