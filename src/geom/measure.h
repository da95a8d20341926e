/*
 * measure.h - the support and deviation metrics every stage reports,
 * computed in one place so the orienter, both shape optimizers, the slicer
 * and the CLI agree on every number.
 *
 * Convention (Cura's support_angle, the support-slimming paper's
 * tau = sin(alpha)): alpha is the largest self-supporting angle measured
 * from the vertical.  A face with outward unit normal n needs support for
 * up-direction d when n . d < -sin(alpha).  PrusaSlicer's
 * support_material_threshold T is measured from the horizontal: T = 90 - alpha.
 *
 * Thread-safe on distinct outputs; the raycast may be shared.
 */
#ifndef SF_GEOM_MEASURE_H
#define SF_GEOM_MEASURE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"
#include "../mesh/mesh.h"
#include "proxy.h"
#include "raycast.h"

struct support_params {
    double angle_deg;  /* alpha, largest self-supporting angle from vertical (default 45) */
    double pitch_mm;   /* ray grid pitch (default 1) */
    double min_gap_mm; /* a risky hit closer than this above the surface below needs no
                          column (it rests on it); default 0.05 */
};

/* Defaults: 45 degrees, 1 mm grid, 0.05 mm gap. */
void support_params_default(struct support_params *p);

/* A support column on a grid of vertical cells (a ray grid, or the
   support_grid below): from lo (bed or part below) up to hi (the risky hit
   or the overhanging bottom), heights along up above the bed.  The one
   column type of the farm: the metrics, the growth simulation, the support
   model, the slicer's layers and the pictures all use it.  With iface set
   it is not a column but a dense-interface band of one (supmodel_columns):
   the layers of the cell wholly inside lo..hi print dense. */
struct support_column {
    uint32_t cell; /* grid cell: i = cell % nu, j = cell / nu */
    float lo, hi;  /* mm above the bed */
    uint32_t tri;  /* the risky triangle it holds up (measure_columns), else 0 */
    bool iface;    /* a dense-interface band, not a column */
};

/* Where the cells of support columns stand: cell (i, j) is centred at
   (x0 + i pitch, y0 + j pitch), the bed at height base (columns' lo and hi
   are above it).  A ray grid along +z in the part's coordinates, or the
   same moved onto the print bed. */
struct support_grid {
    double x0, y0, base, pitch;
    uint32_t nu, nw;
};

struct support_metrics {
    uint32_t n_risky;        /* faces with n . d < -sin(alpha) (bed contact excluded) */
    double risky_area_mm2;   /* their area */
    double proxy_mm3;        /* sum over risky faces: projected area * centroid height */
    double volume_mm3;       /* ray-cast column volume: sum of column length * pitch^2 */
    double contact_area_mm2; /* columns * pitch^2: part surface touched by support */
    uint32_t n_columns;      /* support columns on the grid */
    uint32_t n_anchors;      /* clusters of adjacent supported grid points */
    double com_height_mm;    /* centre of mass height above the bed */
    double build_height_mm;  /* part height along d */
    /* growth simulation (growth.h), filled by measure_support */
    uint32_t n_islands;       /* regions starting in mid-air with no column under them */
    double island_volume_mm3; /* support they need, included in volume_mm3 */
    double base_margin_mm;    /* least margin of the growing part's centre of mass inside
                                 its extended base; negative: it would tip over */
    /* trust: on a closed solid every ray leaves as often as it enters */
    uint32_t n_rays;      /* grid rays that hit the part */
    uint32_t n_rays_open; /* of those, rays whose entries and exits do not pair up: the part
                             is not a closed solid there and the figures above are estimates */
};

/*
 * Risky faces and the proxy only (no ray cast): cheap, for pruning.
 * Faces resting on the bed (centroid within min_gap of the lowest point)
 * are not counted as risky.
 */
void measure_proxy(const struct mesh *m, struct vec3 up, const struct support_params *p,
                   struct support_metrics *out);

/*
 * Support columns on a cast grid: walking up each ray, a hit on a risky
 * face more than min_gap above the last surface below (the bed, or the
 * part's last exit) needs a column from there.  *cols is allocated (free()).
 */
int measure_columns(const struct ray_grid *g, const struct support_params *p,
                    struct support_column **cols, size_t *n_cols, struct sf_err *err);

/* Everything in struct support_metrics for up-direction up, growth included. */
int measure_support(const struct mesh *m, struct raycast *rc, struct vec3 up,
                    const struct support_params *p, struct support_metrics *out,
                    struct sf_err *err);

/* The same, taking the risky-face figures from a proxy cache of m (for
   callers that score many directions of one part). */
int measure_support_cached(const struct mesh *m, struct raycast *rc, const struct proxy_cache *pc,
                           struct vec3 up, const struct support_params *p,
                           struct support_metrics *out, struct sf_err *err);

/*
 * The same for n_p parameter sets that differ only in angle (or min_gap),
 * from one ray cast: out[i] is for p[i].  Every p[i] must have p[0]'s pitch.
 */
int measure_support_angles(const struct mesh *m, struct raycast *rc, const struct proxy_cache *pc,
                           struct vec3 up, const struct support_params *p, int n_p,
                           struct support_metrics *out, struct sf_err *err);

/* Shape deviation between two meshes with the same connectivity (a deformed copy). */
struct deviation {
    double max_mm, mean_mm; /* vertex displacement */
    double mndr, andr;      /* max / mean displacement over the bbox diagonal of a */
};
int measure_deviation(const struct mesh *a, const struct mesh *b, struct deviation *out,
                      struct sf_err *err);
/* The same with a's bounding-box diagonal given (a loop comparing many b with one a measures
   it once); a and b must have the same vertex count. */
void measure_deviation_diag(const struct mesh *a, const struct mesh *b, double diag,
                            struct deviation *out);

/*
 * One-sided Hausdorff distance from a to b (max over a's vertices and
 * triangle samples of the distance to b's surface), and the symmetric one.
 */
int measure_hausdorff(const struct mesh *a, const struct mesh *b, double *one_sided_mm,
                      double *symmetric_mm, struct sf_err *err);

/*
 * Unsigned distance from points to the surface of m (Embree point queries,
 * exact closest point on triangle).  m must outlive d.  Queries on one d
 * may run from several threads.  NULL with err set on failure.
 */
struct surface_dist;
struct surface_dist *surface_dist_new(const struct mesh *m, struct sf_err *err);
double surface_dist_query(const struct surface_dist *d, struct vec3 p);
void surface_dist_free(struct surface_dist *d);

#endif
