/*
 * mesh.h - the indexed triangle mesh every stage works on, and its
 * loaders, savers and repairs.
 *
 * Plain data (like cgltf): a vertex array and a triangle index array, both
 * owned by the mesh and freed by mesh_release().  Triangles wind counter-
 * clockwise seen from outside, so (b-a)x(c-a) is the outward normal.
 * Units are millimetres.  Loaders take bytes and give a welded, validated
 * mesh, or SF_EINVAL with a message naming the file and what is wrong.
 *
 * Not thread-safe per mesh; different meshes are independent.
 */
#ifndef SF_MESH_MESH_H
#define SF_MESH_MESH_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"
#include "vec.h"

struct mesh {
    struct vec3 *v;   /* n_verts positions, mm */
    uint32_t (*t)[3]; /* n_tris vertex index triples, CCW from outside */
    uint32_t n_verts;
    uint32_t n_tris;
};

enum mesh_format {
    MESH_FMT_UNKNOWN = 0,
    MESH_FMT_STL_BINARY,
    MESH_FMT_STL_ASCII,
    MESH_FMT_OBJ,
    MESH_FMT_3MF
};

/* What mesh_load found and repaired, for reports. */
struct mesh_load_info {
    enum mesh_format format;
    uint32_t n_input_tris; /* triangles in the file */
    uint32_t n_merged;     /* vertices merged by welding */
    uint32_t n_degenerate; /* zero-area or repeated-index triangles dropped */
    uint32_t n_duplicate;  /* copies of an earlier triangle (same vertices) dropped */
    uint32_t n_flipped;    /* triangles re-oriented for consistency */
};

/* Empty mesh. */
void mesh_init(struct mesh *m);
/* Free arrays and reset to empty. */
void mesh_release(struct mesh *m);
/* Allocate room for exactly nv vertices and nt triangles (contents undefined). */
int mesh_alloc(struct mesh *m, uint32_t n_verts, uint32_t n_tris, struct sf_err *err);
/* Deep copy src into dst (dst must be initialised; its old contents are freed). */
int mesh_copy(struct mesh *dst, const struct mesh *src, struct sf_err *err);

/* Guess the format from the first bytes (and size); name is used for messages only. */
enum mesh_format mesh_detect(const void *data, size_t len);
const char *mesh_format_name(enum mesh_format f);

/*
 * Load a part from a file or from memory: detect the format, parse, weld
 * (tolerance 1e-6 of the bounding-box diagonal), drop degenerate triangles,
 * make the orientation consistent with outward normals.  name is used in
 * messages ("stl 'part.stl': ...").  info may be NULL.
 */
int mesh_load(const char *path, struct mesh *m, struct mesh_load_info *info, struct sf_err *err);
int mesh_load_mem(const void *data, size_t len, const char *name, struct mesh *m,
                  struct mesh_load_info *info, struct sf_err *err);

/*
 * Raw parsers: bytes to an indexed mesh (binary STL merges bit-identical
 * corners as it reads; ASCII STL is a soup until mesh_load welds it) with
 * every coordinate checked finite and inside SF_MESH_COORD_MAX and every
 * index in range.  Used by mesh_load_mem and the fuzz targets.
 */
int stl_parse(const void *data, size_t len, const char *name, struct mesh *m, struct sf_err *err);
int obj_parse(const void *data, size_t len, const char *name, struct mesh *m, struct sf_err *err);
int tmf_parse(const void *data, size_t len, const char *name, struct mesh *m, struct sf_err *err);

/* Write binary STL / Wavefront OBJ. */
int mesh_save_stl(const struct mesh *m, const char *path, struct sf_err *err);
int mesh_save_obj(const struct mesh *m, const char *path, struct sf_err *err);
/* Save by extension (.stl or .obj). */
int mesh_save(const struct mesh *m, const char *path, struct sf_err *err);

/* Merge vertices closer than tol (mm); returns the number merged (>= 0) or an error. */
int mesh_weld(struct mesh *m, double tol, struct sf_err *err);
/*
 * Drop triangles with a repeated index or zero area; returns how many.  A
 * zero-area sliver along an edge of another triangle is healed instead (that
 * triangle is split at the sliver's middle corner), so no crack is left.
 */
uint32_t mesh_drop_degenerate(struct mesh *m);
/*
 * Drop every triangle whose three vertices (in any order or winding) an
 * earlier one already has; keeps order.  Returns how many (>= 0), or
 * SF_ENOMEM.  Linear time (hashing).
 */
int mesh_drop_duplicates(struct mesh *m, struct sf_err *err);
/* Remove vertices no triangle uses, renumbering. */
void mesh_compact(struct mesh *m);

void mesh_bbox(const struct mesh *m, struct vec3 *lo, struct vec3 *hi);
/* Length of the bounding-box diagonal. */
double mesh_diag(const struct mesh *m);

/* Unnormalised normal (b-a)x(c-a) of triangle i: its length is twice the area. */
struct vec3 mesh_tri_cross(const struct mesh *m, uint32_t i);
struct vec3 mesh_tri_normal(const struct mesh *m, uint32_t i);
double mesh_tri_area(const struct mesh *m, uint32_t i);
struct vec3 mesh_tri_centroid(const struct mesh *m, uint32_t i);
double mesh_area(const struct mesh *m);

/* Signed volume (positive for a closed outward-oriented mesh) and centroid
   of the enclosed solid (divergence theorem; meaningful for closed meshes). */
double mesh_volume(const struct mesh *m, struct vec3 *centroid);

/* p -> R p + t for every vertex. */
void mesh_transform(struct mesh *m, struct mat3 r, struct vec3 t);
void mesh_translate(struct mesh *m, struct vec3 t);
/* Rotate so that unit vector up becomes +z. */
void mesh_rotate_up(struct mesh *m, struct vec3 up);
/* Translate so the part rests on z = 0 with its bbox centred at (cx, cy). */
void mesh_place_on_bed(struct mesh *m, double cx, double cy);

/*
 * Topology: edge adjacency, boundary and non-manifold edges, components.
 * adj[i][k] is the triangle across edge k (vertices t[i][k], t[i][(k+1)%3])
 * or MESH_NO_TRI on a boundary or non-manifold edge.  comp[i] is the
 * connected component of triangle i (edge-connected).
 */
#define MESH_NO_TRI UINT32_MAX
struct mesh_topo {
    uint32_t (*adj)[3];
    uint32_t *comp;
    uint32_t n_comps;
    uint32_t n_edges;       /* distinct undirected edges */
    uint32_t n_boundary;    /* edges used by one triangle */
    uint32_t n_nonmanifold; /* edges used by three or more */
    uint32_t n_misoriented; /* manifold edges whose two triangles disagree on direction */
};

int mesh_topo_build(const struct mesh *m, struct mesh_topo *topo, struct sf_err *err);
void mesh_topo_release(struct mesh_topo *topo);
/* Closed: every edge shared by exactly two consistently oriented triangles. */
bool mesh_topo_closed(const struct mesh_topo *topo);

/*
 * Make triangle orientation consistent within each component (flood fill
 * across manifold edges), then flip closed components with negative volume
 * so normals point outward.  Returns the number of triangles flipped.
 */
int mesh_orient(struct mesh *m, struct sf_err *err);

#endif
