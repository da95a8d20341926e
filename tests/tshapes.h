/*
 * tshapes.h - generated test parts more than one unit test needs, beyond
 * src/mesh/shapes.h.  Header-only.
 */
#ifndef SF_TESTS_TSHAPES_H
#define SF_TESTS_TSHAPES_H

#include <math.h>
#include <string.h>

#include "../src/mesh/mesh.h"
#include "../src/mesh/shapes.h"

/* An open shell: the sphere on its stem with its top cut away (the faces
   wholly in the top 5 % of its height dropped), so it has an open rim. */
static inline int
t_open_sphere_on_stem(struct mesh *m, struct sf_err *err)
{
    int rc = shape_sphere_on_stem(m, err);
    if (rc)
        return rc;
    struct vec3 lo, hi;
    mesh_bbox(m, &lo, &hi);
    uint32_t k = 0;
    for (uint32_t f = 0; f < m->n_tris; f++) {
        double z = fmin(fmin(m->v[m->t[f][0]].z, m->v[m->t[f][1]].z), m->v[m->t[f][2]].z);
        if (z < hi.z - 0.05 * (hi.z - lo.z))
            memcpy(m->t[k++], m->t[f], sizeof(m->t[f]));
    }
    m->n_tris = k;
    return 0;
}

#endif
