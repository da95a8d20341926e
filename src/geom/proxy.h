/*
 * proxy.h - the fast support proxy (risky faces, their area, and the sum
 * of projected area times height) for many directions of one part.
 *
 * The orientation search evaluates it for a thousand directions or more,
 * so the per-triangle data is laid out once, structure-of-arrays, with the
 * triangles grouped by the direction of their normals (a cube map of
 * bins).  For a direction d, a bin whose whole cone of normals lies beyond
 * the overhang limit adds its precomputed sums in O(1) (the proxy is a
 * quadratic form in d: sum a (-n.d)(g.d - lo) = -d.M d + lo S.d); a bin
 * wholly on the safe side adds nothing; only bins that straddle the limit,
 * or whose faces may lie within min_gap of the bed (the proxy leaves those
 * out), are walked face by face.  The
 * result equals the face-by-face sum (measure_proxy) up to rounding.
 *
 * Read-only after init: any number of threads may evaluate at once.
 */
#ifndef SF_GEOM_PROXY_H
#define SF_GEOM_PROXY_H

#include <stdint.h>

#include "../base/err.h"
#include "../mesh/mesh.h"

struct support_params;
struct support_metrics;

struct proxy_bin {
    float cx, cy, cz; /* unit centre of the bin's normals */
    float cos_radius; /* cosine of the widest angle from the centre to a member normal */
    float sin_radius;
    float lo[3], hi[3]; /* bounding box of the members' centroids */
    uint32_t first, n;  /* members: faces [first, first + n) of the arrays below */
    double area;        /* sum of member areas */
    double s[3];        /* sum a n */
    double mm[9];       /* sum a n g^T (row-major) */
};

struct proxy_cache {
    uint32_t n_tris;        /* faces kept (zero-area faces are left out) */
    float *nx, *ny, *nz;    /* unit normals, grouped by bin */
    float *area;            /* mm2 */
    float *gx, *gy, *gz;    /* centroids */
    uint32_t n_verts;       /* entries of vx, vy, vz */
    float *vx, *vy, *vz;    /* candidates for the lowest and highest point */
    struct proxy_bin *bins; /* the bins that hold faces */
    uint32_t n_bins;
};

/*
 * Build the cache of m.  extreme: optional indices of the only vertices
 * that can be lowest or highest (the convex hull's, hull.h); NULL means all.
 */
int proxy_cache_init(struct proxy_cache *pc, const struct mesh *m, const uint32_t *extreme,
                     uint32_t n_extreme, struct sf_err *err);
void proxy_cache_release(struct proxy_cache *pc);

/* The proxy figures of struct support_metrics (n_risky, risky_area_mm2,
   proxy_mm3, build_height_mm) for direction up, as measure_proxy computes. */
void proxy_eval(const struct proxy_cache *pc, struct vec3 up, const struct support_params *p,
                struct support_metrics *out);

/* Area of the faces lying on the bed for up (facing straight down, centroid
   within 0.1 mm of the lowest point): what the part stands on. */
double proxy_bed_contact(const struct proxy_cache *pc, struct vec3 up);

#endif
