/*
 * clip_shim.h - polygon booleans and offsets (Clipper 6, libpolyclipping)
 * behind a C interface: the project's only C++ lives in clip_shim.cpp.
 *
 * Why Clipper: it is what PrusaSlicer and Cura build on, exact on integer
 * coordinates, handles holes and self-touching input, and Debian ships it.
 * Inputs and outputs are struct paths (poly.h).  Closed results come in
 * tree order (outer, its holes, next outer), outers counter-clockwise.
 *
 * Every function writes into out (reset first; out must not alias an
 * input) and returns SF_OK, SF_ENOMEM, or SF_EBUG if Clipper throws (a
 * coordinate beyond its range).  Thread-safe: no shared state.
 */
#ifndef SF_SLICER_CLIP_SHIM_H
#define SF_SLICER_CLIP_SHIM_H

#include "poly.h"

#ifdef __cplusplus
extern "C" {
#endif

enum clip_op { CLIP_UNION, CLIP_INTERSECTION, CLIP_DIFFERENCE, CLIP_XOR };
enum clip_fill { CLIP_EVENODD, CLIP_NONZERO };
enum clip_join { CLIP_JOIN_MITER, CLIP_JOIN_ROUND, CLIP_JOIN_SQUARE };

/* out = subj OP clip (clip may be NULL), both read with the fill rule. */
int clip_bool(enum clip_op op, const struct paths *subj, const struct paths *clip,
              enum clip_fill fill, struct paths *out);

/* Grow (delta_mm > 0) or shrink closed polygons; miter limit 3, arcs to 5 um. */
int clip_offset(const struct paths *in, double delta_mm, enum clip_join join, struct paths *out);

/* Pieces of the open paths lines inside the closed polygons region. */
int clip_lines(const struct paths *lines, const struct paths *region, struct paths *out);

#ifdef __cplusplus
}
#endif

#endif
