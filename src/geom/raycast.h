/*
 * raycast.h - the "rays structure" of the orientation paper (Allen & Dutta):
 * a grid of parallel rays along an up-direction, every hit along each ray,
 * from one Embree scene of the part.
 *
 * Rays are rotated, never the mesh: one scene serves every candidate
 * direction.  Hits are found with Embree's stream queries and an
 * intersection filter that records every hit, then sorted per ray.
 *
 * Thread-safety: a struct raycast may be queried from several threads at
 * once (Embree scenes are read-only after commit); each call fills its own
 * struct ray_grid.  Create and free on one thread.
 */
#ifndef SF_GEOM_RAYCAST_H
#define SF_GEOM_RAYCAST_H

#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"
#include "../mesh/mesh.h"
#include "rims.h"

struct raycast;

/* One hit along a ray. */
struct ray_hit {
    float h;      /* height along up above the part's lowest point (the bed), mm */
    float cos_up; /* n . up of the hit triangle: < 0 faces down (ray enters the part) */
    uint32_t tri; /* triangle index in the mesh */
};

/*
 * Grid frame: cell (i, j) is the ray through base_point + (u0 + i*pitch) u +
 * (w0 + j*pitch) w, travelling along up.  For up = +z the frame is u = +x,
 * w = +y, so (u0 + i*pitch, w0 + j*pitch) are plain x, y coordinates.
 */
struct ray_grid {
    struct vec3 up, u, w; /* orthonormal frame; rays travel along up */
    double u0, w0;        /* coordinates of cell (0,0)'s centre in the u, w plane */
    double base;          /* lowest point of the part along up (the bed), mm */
    double pitch;         /* cell size, mm */
    uint32_t nu, nw;      /* cells along u and w */
    uint32_t *first;      /* nu*nw + 1 offsets: hits of cell c are hits[first[c] .. first[c+1]) */
    struct ray_hit *hits; /* sorted by h within each cell, duplicates on shared edges removed */
    size_t n_hits;
};

/* Build the Embree scene of m (m must outlive rc). NULL with err set on failure. */
struct raycast *raycast_new(const struct mesh *m, struct sf_err *err);
void raycast_free(struct raycast *rc);

/*
 * Optional: the indices of vertices that include every extreme point of the
 * mesh along any direction (the convex hull's vertices), so each grid finds
 * the part's extent from them instead of from every vertex.  Copied.
 */
int raycast_set_extreme(struct raycast *rc, const uint32_t *verts, uint32_t n, struct sf_err *err);

/* The part's centre of mass (solid for a closed mesh, surface centroid for an
   open one), computed once with the scene: it does not depend on direction. */
struct vec3 raycast_com(const struct raycast *rc);

/* The mesh the scene was built from, and its open rims (built with the scene). */
const struct mesh *raycast_mesh(const struct raycast *rc);
const struct rims *raycast_rims(const struct raycast *rc);

/*
 * Cast the grid for unit vector up with the given pitch (mm) over the
 * part's shadow.  g is filled (release with ray_grid_release).  SF_ENOMEM
 * when the grid would exceed SF_GRID_CELLS_MAX cells.
 */
int raycast_grid(struct raycast *rc, struct vec3 up, double pitch, struct ray_grid *g,
                 struct sf_err *err);
void ray_grid_release(struct ray_grid *g);

/* Cell index of (i, j). */
static inline uint32_t
ray_grid_cell(const struct ray_grid *g, uint32_t i, uint32_t j)
{
    return j * g->nu + i;
}

#endif
