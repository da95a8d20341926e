/*
 * envelope.h - a coarse closed surface around a part: the outer offset
 * surface at distance offset_mm, sampled on a lattice of pitch pitch_mm.
 *
 * It is what the support-slimming tet mesh is built in (Hu 2015, sec. 3:
 * "an enclosing tetrahedral mesh"): closed, manifold and free of
 * self-intersections by construction, whatever the part's genus, number
 * of shells or defects (an open part gets an envelope around its surface).
 *
 * Thread-safe: each call is independent.
 */
#ifndef SF_GEOM_ENVELOPE_H
#define SF_GEOM_ENVELOPE_H

#include "../base/err.h"
#include "../mesh/mesh.h"

/* Most lattice points: 8M keeps the distance field under ~100 MB. */
#define ENVELOPE_POINTS_MAX 8000000u

/*
 * Fill out (initialised by the caller; old contents freed) with the offset
 * surface {x : signed distance to the part = offset_mm}, outward-oriented.
 * offset_mm should be at least pitch_mm for the part to lie inside.
 * SF_EINVAL on an empty part or bad sizes, SF_ENOMEM past the point cap.
 */
int envelope_build(const struct mesh *part, double pitch_mm, double offset_mm, struct mesh *out,
                   struct sf_err *err);

#endif
