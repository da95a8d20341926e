/*
 * selfx.h - does a triangle mesh intersect itself?  The support-slimming
 * deformation may fold a thin part onto itself; a result that does is
 * never returned (slim.c falls back to an earlier iterate).
 *
 * Thread-safe: selfx_count and selfx_count_new build their own Embree
 * scene; a selfx_ref keeps one of the triangles that can cross anew,
 * refitted by each selfx_ref_count: one thread at a time on a handle.
 */
#ifndef SF_GEOM_SELFX_H
#define SF_GEOM_SELFX_H

#include <stdbool.h>
#include <stdint.h>

#include "../base/err.h"
#include "../mesh/mesh.h"

/*
 * Count the mesh edges that pierce a triangle not touching them (0 for a
 * mesh that does not intersect itself; two crossing triangles give at
 * least one).  Returns the count (>= 0) or a negative sf_status.
 */
int selfx_count(const struct mesh *m, struct sf_err *err);

/*
 * The new ones only: edges of m that pierce a triangle they were more than
 * tol mm from in ref (the same connectivity, another shape: the input of a
 * deformation), except between two shells that already cross in ref, and
 * within two rings of a crossing ref has (a deformation slides the crossing
 * curve over its neighbours).  Crossings and contacts the input already had
 * (overlapping shells, a soup's T-junctions and coincident faces) are not
 * counted, so a deformation of a defective part is judged by what it adds.  Returns the
 * count or a negative sf_status (SF_EINVAL: connectivity differs, tol < 0).
 */
int selfx_count_new(const struct mesh *ref, const struct mesh *m, double tol, struct sf_err *err);

/*
 * The same with the reference's work done once, for a deformation checked
 * iterate by iterate: selfx_ref_new notes ref's shells and crossings (ref
 * must outlive the handle and keep its shape; NULL on error: SF_EINVAL for
 * tol < 0, SF_ENOMEM); selfx_ref_count counts m's new crossings as
 * selfx_count_new does and, when mark (m->n_verts bytes) is given, sets it
 * to 1 at the vertices of each new crossing's edge and triangle (every
 * triangle an edge pierces, not the first the search meets), 0 elsewhere
 * (where the deformation folded).  The reference's own crossings are
 * noted the same way.  selfx_ref_free(NULL) is a no-op.
 */
struct selfx_ref;
struct selfx_ref *selfx_ref_new(const struct mesh *ref, double tol, struct sf_err *err);
int selfx_ref_count(struct selfx_ref *sr, const struct mesh *m, uint8_t *mark, struct sf_err *err);
void selfx_ref_free(struct selfx_ref *sr);

/*
 * selfx_ref_count casts only the edges with no end near the input's
 * crossings, through a scene of only the triangles with no corner there
 * (a crossing there is not new: it could only be judged no).  Embree's
 * verdict on an edge and a triangle depends on the two alone, so this is
 * the count, and the marks, of every edge through every triangle, which
 * selfx_ref_count_all still does (for the tests that hold the two equal).
 */
int selfx_ref_count_all(struct selfx_ref *sr, const struct mesh *m, uint8_t *mark,
                        struct sf_err *err);

/* The reference's own crossings: what selfx_count(ref) returns (the same
   edge casts, done once by selfx_ref_new). */
int selfx_ref_input_count(const struct selfx_ref *sr);

/*
 * Read the reference from ref from now on: a copy of it, or it moved
 * rigidly (the same connectivity and distances; what was noted stays
 * valid), which must outlive the handle and keep its shape.  SF_EINVAL
 * when its vertex or triangle count differs.
 */
int selfx_ref_rebind(struct selfx_ref *sr, const struct mesh *ref, struct sf_err *err);

#endif
