/*
 * selfx_int.h - internal to the self-intersection test (selfx*.c), not a
 * contract for anyone else: selfx.c's Embree scenes and edge casts, which
 * selfx_moved.c (selfx_ref_count's check of what moved) reuses.
 *
 * Thread: as selfx.h (one thread at a time on a selfx_ref).
 */
#ifndef SF_GEOM_SELFX_INT_H
#define SF_GEOM_SELFX_INT_H

#include <embree3/rtcore.h>
#include <stdbool.h>
#include <stdint.h>

#include "../base/err.h"
#include "../mesh/mesh.h"
#include "selfx.h"

struct edge_ctx {
    struct RTCIntersectContext ctx; /* first: Embree hands the filter this pointer */
    const struct mesh *m;
    uint32_t a, b; /* the edge's vertices */
    /* optional: a pierced triangle is judged here (true: a crossing); the
       search goes on along the edge past every hit, so the judge sees each
       triangle the edge pierces, whatever order the BVH finds them in */
    bool (*judge)(void *ud, uint32_t a, uint32_t b, uint32_t tri);
    void *ud;
    bool crossed;         /* the judge said yes on this edge */
    const uint32_t *prim; /* optional: the scene's triangle i is the mesh's prim[i] */
    const uint8_t *skip;  /* optional: per vertex, cast no edge from or to it */
};

/* An Embree scene of one mesh's triangles, kept to be refitted when the
   vertices move (the same connectivity: a deformation's iterates). */
struct scene {
    RTCDevice dev;
    RTCScene s;
    RTCGeometry g;
    float *vb;
    uint32_t n_verts;
};

struct moved;

struct selfx_ref {
    const struct mesh *ref;
    double tol;
    uint32_t *comp;       /* per vertex: its connected shell (a representative vertex) */
    uint8_t *near;        /* per vertex: within two rings of a crossing the input has */
    uint32_t (*pairs)[2]; /* shells that cross each other in the input */
    size_t n_pairs, cap_pairs;
    int n_input; /* edges of ref crossing it (selfx_count) */
    bool oom;
    /* the triangles with no corner near: a crossing needs one of them, and
       an edge with no end near (apart_in_ref); refitted to each mesh
       counted (none: sc is empty, nothing can be new) */
    struct scene sc;
    uint32_t *prim; /* the scene's triangle i is ref's prim[i] */
    uint32_t n_prim;
    struct moved *inc; /* selfx_ref_count's base (made at its first count) */
};

/* One check of a deformed mesh against a prepared reference. */
struct new_ctx {
    const struct selfx_ref *sr;
    uint8_t *mark; /* optional: vertices of new crossings are set to 1 */
};

/* Build the scene of m's triangles (with prim, only its n_prim: the
   scene's triangle i is m's prim[i]) on dev (retained; NULL: a device of
   its own); refit: RTC_BUILD_QUALITY_REFIT.  SF_ENOMEM. */
int selfx_scene_init(struct scene *sc, const struct mesh *m, const uint32_t *prim, uint32_t n_prim,
                     bool refit, RTCDevice dev, struct sf_err *err);
void selfx_scene_release(struct scene *sc);

/* Move the scene's vertices to m's (same connectivity) and rebuild it. */
void selfx_scene_refit(struct scene *sc, const struct mesh *m);

/* Cast edge ab of ec->m through sc (ec->ctx initialised): 1 when it
   pierces a triangle not touching it (with a judge: that the judge calls
   a crossing), else 0; what cast_some does for each edge. */
int selfx_cast_one(const struct scene *sc, struct edge_ctx *ec, uint32_t a, uint32_t b);

/* Distance from segment pq to triangle abc, mm (0 when it crosses it). */
double selfx_seg_tri(struct vec3 p, struct vec3 q, struct vec3 a, struct vec3 b, struct vec3 c);

/* Is edge ab piercing ref's triangle tri a new crossing (ud: a struct
   new_ctx; marks its vertices when asked)?  selfx_ref_count's judge. */
bool selfx_apart_in_ref(void *ud, uint32_t a, uint32_t b, uint32_t tri);

/* selfx_ref_count past its argument checks (sr->n_prim > 0), in
   selfx_moved.c: the count and marks of every edge cast through sr->sc,
   casting only what moved near something since the last full cast. */
int selfx_moved_count(struct selfx_ref *sr, const struct mesh *m, uint8_t *mark,
                      struct sf_err *err);
void selfx_moved_free(struct moved *mv);

#endif
