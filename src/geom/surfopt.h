/*
 * surfopt.h - orientation-fused surface shape optimization (Jayakody et
 * al., "Part orientation fused shape optimization for minimisation of
 * print time and material waste in extrusion-based 3D printing";
 * DESIGN.md method 3).
 *
 * Works on the triangle mesh itself (any genus, several shells; a coarse
 * part is first subdivided, subdiv.h, so it has vertices to move).  Rounds
 * alternate two steps:
 *  - orientation: the orientation optimizer (orient.h: Fibonacci-sphere
 *    samples and hull bases, proxy-pruned, ray-cast scored) turns the
 *    current shape;
 *  - geometry: every face steeper than the aim (margin_deg inside the
 *    limit) has its normal projected onto the aimed cone and is
 *    to turn rigidly onto that normal, by the share its vertices' saliency
 *    (saliency.h) allows, so salient features move less; every other face
 *    is to keep its shape.  One sparse solve
 *        min  gamma sum_f w_f sum_(a,b) in f |v_a - v_b - R_f (a - b)|^2
 *             + beta |L (V - V0)|^2 + anchor |V - V0|^2
 *    (w_f the face's share of the area, R_f its target rotation, L the
 *    uniform Laplacian, V0 the input; vertices near the bed fixed) gives
 *    the next shape.  Its matrix does not change within a round, so it is
 *    factorized once (CHOLMOD) and each iteration is a back-substitution.
 * A round stops after max_iters, when the support proxy has not dropped
 * for `patience` iterations (while the deviation is under half its limits,
 * the anchor and detail weights are quartered first, down to 1/64: the
 * adaptive weights), or when the deviation from the input passes
 * max_mndr / max_andr or an improving iterate folds the surface onto
 * itself (first the face turns asked for are halved, down to 1/16); the
 * best iterate within the limits is kept.  When a run halved its turns,
 * a second run freezes instead: the vertices where an iterate folded or
 * moved past max_mndr, and two rings around them, ask for no turn from
 * then on and the rest of the part goes on at the same step (halving only
 * when nothing new can be frozen); when it froze any, a third run also
 * holds the frozen vertices where they stand (fixed like the bed's: a
 * frozen vertex that only asks for no turn is still dragged by its
 * neighbours' turns, back into the fold: scad example006, the search's
 * model grams 17.4 -> 12.3; the generated arch on its side, unchanged ->
 * 4.10 -> 3.82 g); the model picks among the runs.
 * A fold or a ledge is local, and halving everywhere held the whole part
 * back for it (pig: unchanged -> model 4.14 -> 3.45 g; cow's best searched
 * direction 2.96 -> 1.37 g, PrusaSlicer 4.52 -> 2.76 g).  Any part is optimized: several
 * shells, open shells, a self-intersecting input.  Only NEW
 * self-intersections refuse a shape (selfx_count_new: an edge crossing a
 * triangle it did not touch in the input), so a defective input is judged
 * by what the deformation adds.  The result never needs more model grams
 * than the oriented input (it falls back through the kept iterates to the
 * orientation alone, and unchanged_why says why).
 *
 * Departures from the paper, measured on the generated mushroom and torus
 * (support mm3 after orientation -> after shape):
 *  - Face targets enter as edge vectors, not as vertex positions averaged
 *    over the faces: averaged positions cancel on a flat overhang (each
 *    face turns about its own centroid, neighbours pull a shared vertex
 *    up and down) and stalled (mushroom 228 -> 111, torus 2483 -> 1472);
 *    edge targets are integrated by the solve (228 -> 102, 2483 -> 1122).
 *  - The detail term beta |L (V - V0)|^2 is off by default (beta = 0): its
 *    2-ring matrix made each factorization 3-4x slower and the results
 *    were no better (beta 1: 105 and 1262 mm3).
 *  - Faces are turned until they reach the aim, not only while they are
 *    past the limit: turned only past it, faces settled just inside 45
 *    degrees, where the slicers (PrusaSlicer's +1 degree, a layer's
 *    stair-step) and the model still support them.  knot1, PrusaSlicer
 *    support grams at 45 degrees: 15.6 g (as the limit) -> 9.4 g.
 *  - The anchor term pulls every vertex toward its input place: the edge
 *    targets alone let the whole part drift a little each iteration (each
 *    face keeps its current edges), and MNDR/ANDR count the drift.  With
 *    it the turns stay local: ANDR on knot1, cow and elephant 2.8, 2.3 and
 *    1.6 % -> 0.2, 0.1 and 0.1 %, so the limits of 5 % / 1.5 % hold; with
 *    the limits and no anchor, the runs stopped at the limit in 15
 *    iterations (model grams on the five meshes of bench_supgrams.sh: 35.7
 *    without it, 27.4 at 0.003, 25.6 at 0.01, 28.4 g at 0.03; PrusaSlicer
 *    34.2 g at 0.003, 32.1 g at 0.01, against 41.1 g before both changes).
 *  - The support energy mu E_support is not a separate gradient: the face
 *    targets lower the support, and the kept iterate is the one with the
 *    least support proxy.
 *
 * Thread-safety: surfopt_optimize may run on any thread (the orientation
 * step starts its own workers).
 */
#ifndef SF_GEOM_SURFOPT_H
#define SF_GEOM_SURFOPT_H

#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>

#include "../base/err.h"
#include "../mesh/mesh.h"
#include "measure.h"
#include "orient.h"

struct surfopt_progress {
    int round, n_rounds;
    int iter, max_iters;
    uint32_t n_risky;  /* risky faces now */
    double mndr, andr; /* deviation now */
};

struct surfopt_params {
    double angle_deg;        /* alpha: self-supporting angle from vertical (45) */
    double margin_deg;       /* faces are aimed this far past alpha (5) */
    double gamma;            /* weight of the face targets (1) */
    double beta;             /* weight of keeping the input's Laplacian detail (0, see above) */
    double anchor;           /* weight of the pull toward the input's positions, per vertex
                                against the edge terms' unit face weight (0.01; see above) */
    double saliency;         /* in [0, 1]: a fully salient vertex keeps this share of
                                its place instead of moving to its target (0.8) */
    double max_mndr;         /* limit on max displacement / bbox diagonal (0.05) */
    double max_andr;         /* limit on mean displacement / bbox diagonal (0.015) */
    double fix_bottom_mm;    /* vertices this close to the bed stay fixed (2) */
    int max_iters;           /* per round (100) */
    int patience;            /* stop a round when the proxy has not dropped for this many (5) */
    int rounds;              /* orientation/geometry alternations (2) */
    double min_gain;         /* keep the oriented shape unless a reshape saves this share
                                of its model grams and min_gain_g more (0.02): a
                                deformation that buys a rounding error of support is not
                                worth the part's fidelity */
    double min_gain_g;       /* (0.05 g: with 2 %, the peers' noise; a flat 5 % asked a
                                25 g part for 1.25 g and a 2 g part for 0.1 g, issue 36) */
    uint32_t refine_tris;    /* a coarser part is midpoint-subdivided until it has this many
                                triangles or edges under 1 % of its diagonal (10000): a
                                surface can only bend where it has vertices */
    bool orient;             /* run the orientation step (true); false: +z is up */
    bool keep_start_up;      /* the first round keeps +z up; later rounds re-orient the
                                reshaped part (false; dirsearch.h starts each direction so) */
    struct orient_params op; /* the orientation step's settings (angle set from angle_deg) */
    void (*progress)(void *ud, const struct surfopt_progress *pr); /* optional */
    void *progress_ud;
    const atomic_bool *cancel; /* optional: set to stop with SF_ECANCELED */
};

void surfopt_params_default(struct surfopt_params *p);

#define SURFOPT_CURVE_MAX 1024

struct surfopt_result {
    struct mesh out; /* optimized part on z = 0, bbox centred on x = y = 0 (mesh_release) */
    struct support_metrics input;      /* ray-cast metrics of the input as given (+z up) */
    struct support_metrics oriented;   /* after the first orientation step only */
    struct support_metrics after;      /* of out */
    struct deviation dev;              /* of out against the input turned the same way */
    uint32_t curve[SURFOPT_CURVE_MAX]; /* risky faces per iteration, all rounds; [0] = start */
    int n_curve;
    int n_rounds; /* rounds run */
    int n_iters;  /* geometry iterations run, all rounds */
    int selfx_input, selfx_out;
    uint32_t n_rejected; /* kept iterates refused: self-intersections or more support */
    uint32_t n_folded;   /* iterates refused during the rounds for new self-intersections */
    uint32_t n_halved;   /* times the face turns were halved everywhere (folds, limits) */
    uint32_t n_frozen;   /* times the run froze vertices where it folded or moved too far */
    bool shape_changed;  /* false: only the orientation step's result is returned */
    /* the layer-based support model (supmodel.h, PrusaSlicer's rules), grams: it picks the
       result among the kept shapes, which must need min_gain (and min_gain_g) fewer than the
       oriented part */
    double model_oriented_g, model_after_g;
    double model_after_s;      /* the model's seconds of support for out (supmodel_result.time_s) */
    const char *unchanged_why; /* shape kept: why, in words (static); NULL when changed */
    /* wall seconds: the saliency, factorizing, the iterations (their
       self-intersection checks aside), the orientation steps, choosing among
       the kept shapes, in all; and by what they ran, wherever it ran: the
       self-intersection checks and the support model's evaluations.  When
       the freezing run is made too, they count both runs. */
    double saliency_s, factor_s, iterate_s, orient_s, check_s, total_s;
    double selfx_s, model_s;
};

/*
 * Optimize part m (not modified).  Errors: SF_EINVAL (bad parameters),
 * SF_ENOMEM, SF_ECANCELED.
 */
int surfopt_optimize(const struct mesh *m, const struct surfopt_params *p,
                     struct surfopt_result *res, struct sf_err *err);
void surfopt_result_release(struct surfopt_result *res);

#endif
