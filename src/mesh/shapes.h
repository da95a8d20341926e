/*
 * shapes.h - test and demo parts generated in code, so no test depends on
 * files outside the repository.  Every shape is a closed, outward-oriented
 * manifold resting on z = 0 (except where noted), dimensions in mm.
 *
 * Thread-safe: each call fills its own mesh.
 */
#ifndef SF_MESH_SHAPES_H
#define SF_MESH_SHAPES_H

#include "mesh.h"

/* Axis-aligned box from lo to hi. */
int shape_box(struct mesh *m, struct vec3 lo, struct vec3 hi, struct sf_err *err);

/*
 * Prism: the simple polygon (x[i], z[i]), i < n, in the x-z plane,
 * extruded along y from 0 to depth.  Any winding; caps by ear clipping.
 */
int shape_extrude_xz(struct mesh *m, const double *x, const double *z, int n, double depth,
                     struct sf_err *err);

/*
 * Solid of revolution about the z axis: profile (r[i], z[i]) from a point
 * on the axis (r = 0) to another on the axis, with `segments` around.
 */
int shape_revolve(struct mesh *m, const double *r, const double *z, int n, int segments,
                  struct sf_err *err);

/* Sphere of radius r centred at (0, 0, r), stacks x 2*stacks facets. */
int shape_sphere(struct mesh *m, double r, int stacks, struct sf_err *err);

/* Torus: tube radius r around a ring of radius R, lying flat (axis z), on z = 0. */
int shape_torus(struct mesh *m, double R, double r, int n_ring, int n_tube, struct sf_err *err);

/* The peers' tee: stem 10 x 20 x 30 under a 50 x 20 x 5 bar (20 mm overhang each side). */
int shape_tee(struct mesh *m, struct sf_err *err);

/* Block 60 x 20 x 30 with a semicircular opening of radius 20 from below. */
int shape_arch(struct mesh *m, struct sf_err *err);

/* L-bracket: a 60 x 40 x 5 plate with a 60 x 5 x 30 wall along one long edge. */
int shape_lbracket(struct mesh *m, struct sf_err *err);

/* Sphere of radius 10 on a stem of radius 3 and height 15. */
int shape_sphere_on_stem(struct mesh *m, struct sf_err *err);

/* Square frame: 40 x 40 outside, 20 x 20 hole, 10 tall (genus 1). */
int shape_frame(struct mesh *m, struct sf_err *err);

/*
 * Open box (a tray, an enclosure without its lid): x by y outside, h tall,
 * walls wall_mm thick, floor floor_mm thick, open at the top; with
 * lip_down the same solid upside down (a lid modelled lip-down: the plate
 * on top, its rim standing on the bed).  Corner at (0, 0).
 */
int shape_tray(struct mesh *m, double x, double y, double h, double wall_mm, double floor_mm,
               bool lip_down, struct sf_err *err);

/* Wedge whose one face leans lean_deg from vertical (overhanging), 20 tall. */
int shape_wedge(struct mesh *m, double lean_deg, struct sf_err *err);

#endif
