/*
 * poly.h - integer polygon sets, the currency of the slicer.
 *
 * A struct paths holds many paths in two flat arrays (cache-friendly, one
 * allocation each, cheap to hand to Clipper): pts[] and start[], where path
 * k is pts[start[k] .. start[k+1]).  Coordinates are integers in units of
 * 1/POLY_SCALE mm, so boolean operations are exact.  Closed polygons follow
 * Clipper's convention: outer boundaries counter-clockwise (positive
 * area), holes clockwise; sets produced by clip_* come in "tree order"
 * (an outer, then its holes, then the next outer), so a positive-area path
 * starts a new island.  Open paths (infill lines, travel) use the same type.
 *
 * Owner: whoever called paths_init releases with paths_release.
 * Not thread-safe per set; distinct sets are independent.
 */
#ifndef SF_SLICER_POLY_H
#define SF_SLICER_POLY_H

#include <math.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* 1 unit = 10 nm: exact enough for 0.4 mm lines, far from int64 overflow. */
#define POLY_SCALE 100000.0

struct ipt {
    int64_t x, y;
};

struct paths {
    struct ipt *pts;    /* all points, path after path */
    uint32_t *start;    /* n + 1 offsets into pts (start[0] = 0) */
    uint32_t n;         /* paths held */
    size_t cap_pts;     /* allocated points */
    uint32_t cap_paths; /* allocated paths (start has cap_paths + 1) */
};

static inline int64_t
poly_i(double mm)
{
    return (int64_t)llround(mm * POLY_SCALE);
}

static inline double
poly_mm(int64_t v)
{
    return (double)v / POLY_SCALE;
}

void paths_init(struct paths *p);
void paths_release(struct paths *p);
/* Drop every path, keep the memory. */
void paths_reset(struct paths *p);
/* Number of points of path k. */
static inline uint32_t
paths_len(const struct paths *p, uint32_t k)
{
    return p->start[k + 1] - p->start[k];
}
/* Append a path of n points (copied); false when memory runs out. */
bool paths_add(struct paths *p, const struct ipt *pts, uint32_t n);
/* Start an empty path, then push points into it; false on no memory. */
bool paths_begin(struct paths *p);
bool paths_push(struct paths *p, struct ipt pt);
/* Append every path of src to dst. */
bool paths_append(struct paths *dst, const struct paths *src);
/* Move src's contents into dst (dst released first); src left empty. */
void paths_move(struct paths *dst, struct paths *src);

/* Signed area (mm^2) of path k: positive counter-clockwise. */
double paths_area_k(const struct paths *p, uint32_t k);
/* Sum of signed areas, mm^2 (area of a well-formed polygon set). */
double paths_area(const struct paths *p);
/* Length in mm of path k, open (closed adds the closing edge). */
double paths_length_k(const struct paths *p, uint32_t k, bool closed);
/* Point-in-polygon by the nonzero rule over the whole set. */
bool paths_contains(const struct paths *p, struct ipt q);
/*
 * Douglas-Peucker in place: drop points closer than tol_mm to the chord
 * of the kept ones (closed paths keep their two farthest-apart anchors).
 * Paths reduced below 3 points are removed.  false when memory runs out
 * (p unchanged).
 */
bool paths_simplify(struct paths *p, double tol_mm);

/*
 * Point-in-polygon for many queries against one set: edges are bucketed
 * into horizontal bands, so a query reads only the edges that cross its
 * band (the only ones that can change the winding at its height).
 */
struct paths_index {
    int64_t y0, band_h; /* band b covers [y0 + b band_h, y0 + (b+1) band_h) */
    uint32_t n_bands;
    uint32_t *first;      /* n_bands + 1 offsets into edges */
    uint32_t (*edges)[2]; /* point indices of each edge's ends */
    const struct ipt *pts;
};
bool paths_index_init(struct paths_index *ix, const struct paths *p);
void paths_index_release(struct paths_index *ix);
bool paths_index_contains(const struct paths_index *ix, struct ipt q);
/* The band of height y (for walking ix->edges of one band). */
uint32_t band_of_index(const struct paths_index *ix, int64_t y);
/* True when segment a-b crosses or touches an edge of the set. */
bool paths_index_crosses(const struct paths_index *ix, struct ipt a, struct ipt b);

/* Bounding box of all points; false when empty. */
bool paths_bbox(const struct paths *p, struct ipt *lo, struct ipt *hi);

#ifdef __cplusplus
}
#endif

#endif
