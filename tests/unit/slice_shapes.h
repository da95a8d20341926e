/*
 * slice_shapes.h - analytic test parts built in memory (no mesh loader needed):
 * boxes, a pyramid, an octahedron, a T-shape.  Several closed shells may
 * be appended into one mesh.  Vertices and triangles are allocated with
 * mem.h and freed by ts_free().  Header-only, for the slicer tests.
 */
#ifndef SF_TESTS_SLICE_SHAPES_H
#define SF_TESTS_SLICE_SHAPES_H

#include <stdlib.h>

#include "../../src/base/mem.h"
#include "../../src/mesh/mesh.h"

static inline void
ts_free(struct mesh *m)
{
    free(m->v);
    free(m->t);
    m->v = NULL;
    m->t = NULL;
    m->n_verts = m->n_tris = 0;
}

/* Append nv vertices and nt triangles (indices relative to the new vertices). */
static inline int
ts_add(struct mesh *m, const struct vec3 *v, uint32_t nv, const uint32_t (*t)[3], uint32_t nt)
{
    struct vec3 *nvp = mem_realloc_array(m->v, m->n_verts + nv, sizeof(*nvp));
    if (!nvp)
        return -1;
    m->v = nvp;
    uint32_t(*ntp)[3] = mem_realloc_array(m->t, m->n_tris + nt, sizeof(*ntp));
    if (!ntp)
        return -1;
    m->t = ntp;
    for (uint32_t i = 0; i < nv; i++)
        m->v[m->n_verts + i] = v[i];
    for (uint32_t i = 0; i < nt; i++)
        for (int c = 0; c < 3; c++)
            m->t[m->n_tris + i][c] = t[i][c] + m->n_verts;
    m->n_verts += nv;
    m->n_tris += nt;
    return 0;
}

/* Append mesh b's triangles to m (a shell of its own); SF_ENOMEM on failure. */
static inline int
ts_merge(struct mesh *m, const struct mesh *b)
{
    return ts_add(m, b->v, b->n_verts, (const uint32_t(*)[3])b->t, b->n_tris) < 0 ? SF_ENOMEM
                                                                                  : SF_OK;
}

/* Axis-aligned box, outward CCW triangles. */
static inline int
ts_box(struct mesh *m, double x0, double y0, double z0, double x1, double y1, double z1)
{
    struct vec3 v[8];
    for (int i = 0; i < 8; i++)
        v[i] = v3(i & 1 ? x1 : x0, i & 2 ? y1 : y0, i & 4 ? z1 : z0);
    static const uint32_t t[12][3] = {
        { 0, 2, 1 }, { 1, 2, 3 }, /* bottom z0 */
        { 4, 5, 6 }, { 5, 7, 6 }, /* top z1 */
        { 0, 1, 4 }, { 1, 5, 4 }, /* y0 */
        { 2, 6, 3 }, { 3, 6, 7 }, /* y1 */
        { 0, 4, 2 }, { 2, 4, 6 }, /* x0 */
        { 1, 3, 5 }, { 3, 7, 5 }, /* x1 */
    };
    return ts_add(m, v, 8, t, 12);
}

/* Square pyramid: base side a centred at (0,0) on z = 0, apex at height h. */
static inline int
ts_pyramid(struct mesh *m, double a, double h)
{
    double s = a / 2;
    struct vec3 v[5] = { v3(-s, -s, 0), v3(s, -s, 0), v3(s, s, 0), v3(-s, s, 0), v3(0, 0, h) };
    static const uint32_t t[6][3] = { { 0, 2, 1 }, { 0, 3, 2 }, { 0, 1, 4 },
                                      { 1, 2, 4 }, { 2, 3, 4 }, { 3, 0, 4 } };
    return ts_add(m, v, 5, t, 6);
}

/* Octahedron: tips at z = 0 and z = 2 zc, equator square (radius r) at zc. */
static inline int
ts_octahedron(struct mesh *m, double r, double zc)
{
    struct vec3 v[6] = { v3(r, 0, zc),  v3(0, r, zc),     v3(-r, 0, zc),
                         v3(0, -r, zc), v3(0, 0, 2 * zc), v3(0, 0, 0) };
    static const uint32_t t[8][3] = { { 0, 1, 4 }, { 1, 2, 4 }, { 2, 3, 4 }, { 3, 0, 4 },
                                      { 1, 0, 5 }, { 2, 1, 5 }, { 3, 2, 5 }, { 0, 3, 5 } };
    return ts_add(m, v, 6, t, 8);
}

/* The peers' tee: a 10 x 20 stem 30 tall under a 50 x 20 x 5 bar. */
static inline int
ts_tee(struct mesh *m)
{
    if (ts_box(m, -5, -10, 0, 5, 10, 30) < 0)
        return -1;
    return ts_box(m, -25, -10, 30, 25, 10, 35);
}

#endif
