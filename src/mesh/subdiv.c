/*
 * subdiv.c - midpoint subdivision; see subdiv.h.
 */
#include "subdiv.h"

#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"

struct edge_key {
    uint64_t key;  /* lower vertex << 32 | higher vertex */
    uint32_t slot; /* triangle * 3 + edge */
};

static int
cmp_edge(const void *a, const void *b)
{
    uint64_t x = ((const struct edge_key *)a)->key, y = ((const struct edge_key *)b)->key;
    return x < y ? -1 : x > y;
}

int
mesh_subdivide(struct mesh *m, struct sf_err *err)
{
    if (m->n_tris > UINT32_MAX / 4)
        return sf_err_set(err, SF_ENOMEM, "subdivision: %u triangles would be too many", m->n_tris);
    size_t n_slots = (size_t)m->n_tris * 3;
    struct edge_key *ek = mem_array(n_slots ? n_slots : 1, sizeof(*ek));
    uint32_t *mid = mem_array(n_slots ? n_slots : 1, sizeof(*mid));
    if (!ek || !mid) {
        free(ek);
        free(mid);
        return sf_err_set(err, SF_ENOMEM, "subdivision: out of memory for %u triangles", m->n_tris);
    }
    for (uint32_t f = 0; f < m->n_tris; f++) {
        for (int e = 0; e < 3; e++) {
            uint32_t a = m->t[f][e], b = m->t[f][(e + 1) % 3];
            uint64_t lo = a < b ? a : b, hi = a < b ? b : a;
            ek[f * 3 + e] = (struct edge_key){ lo << 32 | hi, f * 3 + (uint32_t)e };
        }
    }
    qsort(ek, n_slots, sizeof(*ek), cmp_edge);
    size_t n_edges = 0;
    for (size_t i = 0; i < n_slots; i++) {
        if (i == 0 || ek[i].key != ek[i - 1].key)
            n_edges++;
        mid[ek[i].slot] = m->n_verts + (uint32_t)(n_edges - 1);
    }
    struct mesh out;
    mesh_init(&out);
    int rc = mesh_alloc(&out, m->n_verts + (uint32_t)n_edges, m->n_tris * 4, err);
    if (rc == SF_OK) {
        memcpy(out.v, m->v, (size_t)m->n_verts * sizeof(*m->v));
        for (size_t i = 0; i < n_slots; i++) {
            uint32_t a = (uint32_t)(ek[i].key >> 32), b = (uint32_t)ek[i].key;
            out.v[mid[ek[i].slot]] = v3_scale(v3_add(m->v[a], m->v[b]), 0.5);
        }
        for (uint32_t f = 0; f < m->n_tris; f++) {
            const uint32_t *t = m->t[f];
            uint32_t m01 = mid[f * 3], m12 = mid[f * 3 + 1], m20 = mid[f * 3 + 2];
            uint32_t(*o)[3] = out.t + (size_t)f * 4;
            o[0][0] = t[0], o[0][1] = m01, o[0][2] = m20;
            o[1][0] = m01, o[1][1] = t[1], o[1][2] = m12;
            o[2][0] = m20, o[2][1] = m12, o[2][2] = t[2];
            o[3][0] = m01, o[3][1] = m12, o[3][2] = m20;
        }
        mesh_release(m);
        *m = out;
    }
    free(ek);
    free(mid);
    return rc;
}

static double
longest_edge(const struct mesh *m)
{
    double best = 0;
    for (uint32_t f = 0; f < m->n_tris; f++) {
        for (int e = 0; e < 3; e++) {
            double l = v3_len(v3_sub(m->v[m->t[f][e]], m->v[m->t[f][(e + 1) % 3]]));
            best = l > best ? l : best;
        }
    }
    return best;
}

int
mesh_refine(struct mesh *m, uint32_t min_tris, double max_edge_mm, uint32_t max_tris,
            struct sf_err *err)
{
    int rounds = 0;
    while (m->n_tris < min_tris && longest_edge(m) > max_edge_mm &&
           (uint64_t)m->n_tris * 4 <= max_tris) {
        int rc = mesh_subdivide(m, err);
        if (rc < 0)
            return rc;
        rounds++;
    }
    return rounds;
}
