/*
 * tetmesh.h - the enclosing tetrahedral mesh of the support-slimming
 * method (Hu 2015, sec. 3): a coarse tet mesh around the part, with every
 * part vertex embedded by barycentric coordinates, so that deforming the
 * few thousand tet vertices deforms the part.
 *
 * Built from the part's offset envelope (envelope.h) tetrahedralized by
 * TetGen (tet_shim.h).  Surface faces (on the envelope) are flagged per
 * tet; tets with three or four surface faces are split at their centroid
 * so each has at most two, as the minimal rotation needs (minrot.h).
 *
 * Plain data; not thread-safe per object.
 */
#ifndef SF_GEOM_TETMESH_H
#define SF_GEOM_TETMESH_H

#include <stdint.h>

#include "../base/err.h"
#include "../mesh/mesh.h"

struct tetmesh_params {
    uint32_t max_verts;   /* target: at most this many tet vertices (5000) */
    int cells;            /* first try: lattice cells along the longest side (16) */
    double offset_cells;  /* envelope offset in lattice pitches (1.2) */
    const char *switches; /* TetGen quality switches ("pq2.0Y": radius-edge <= 2, boundary kept) */
};

void tetmesh_params_default(struct tetmesh_params *p);

struct tetmesh {
    struct vec3 *x;     /* n_verts rest positions, mm */
    uint32_t (*tet)[4]; /* n_tets vertex indices, positive volume */
    uint8_t *surf;      /* per tet: bit f set when face f (opposite vertex f) is on the surface */
    uint32_t n_verts, n_tets;
    uint32_t n_split;    /* tets split at their centroid (3+ surface faces) */
    double pitch_mm;     /* lattice pitch used for the envelope */
    uint32_t n_env_tris; /* envelope triangles */
    /* embedding of the part */
    uint32_t n_part;    /* part vertices */
    uint32_t *host;     /* per part vertex: its tet */
    double (*bary)[4];  /* per part vertex: barycentric coordinates in host */
    uint32_t n_outside; /* part vertices in no tet (embedded in the nearest, extrapolated) */
};

/* Vertex indices of face f of a tet (opposite vertex f), outward for positive tets. */
extern const int tetmesh_face[4][3];

/*
 * Build the tet mesh around part and embed it.  Retries with a coarser
 * lattice until at most p->max_verts vertices.  tm is filled (release with
 * tetmesh_release).  Errors: SF_EINVAL (empty part, TetGen failure),
 * SF_ENOMEM.
 */
int tetmesh_build(const struct mesh *part, const struct tetmesh_params *p, struct tetmesh *tm,
                  struct sf_err *err);
void tetmesh_release(struct tetmesh *tm);

/*
 * For each point, the tet containing it (host) and its barycentric
 * coordinates there (bary may be NULL); a point in no tet gets the tet
 * whose smallest coordinate is largest (extrapolated) and is counted in
 * *n_outside (may be NULL).  SF_ENOMEM on failure.
 */
int tetmesh_locate(const struct tetmesh *tm, const struct vec3 *pts, uint32_t n_pts, uint32_t *host,
                   double (*bary)[4], uint32_t *n_outside, struct sf_err *err);

/* Signed volume of tet t for positions x (positive when not inverted). */
double tetmesh_volume(const struct tetmesh *tm, const struct vec3 *x, uint32_t t);

/* Part vertex positions for tet vertex positions x (barycentric map). */
void tetmesh_map(const struct tetmesh *tm, const struct vec3 *x, struct vec3 *part_v);

#endif
