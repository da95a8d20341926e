/*
 * estimate.h - read Marlin G-code back: every move, print time by a
 * trapezoidal planner like the firmware's, filament per role.
 *
 * The interpreter follows G0/G1, G2/G3 arcs (I J centre offsets, split
 * into segments of at most 1 mm as Marlin's ARC_SUPPORT does, planned
 * as at most EST_ARC_BLOCKS_MAX blocks; an arc longer than 10 m is an
 * error naming its line), G90/
 * G91, M82/M83, G92, G4 dwell and G28 (to the origin), and the comments
 * the slicer writes: ;LAYER_CHANGE starts a layer, ;TYPE: sets the role
 * (support when it names "Support material...").  Filament is summed the
 * way shared/peers does: positive E on moves with X or Y motion.
 *
 * The planner: each move is a block with a nominal speed (F, capped per
 * axis by max feed rates), an acceleration (printing, travel, or retract
 * for E-only moves) and a maximum entry speed from the junction with the
 * previous block, by Marlin's classic jerk rule (per-axis velocity change
 * at most the axis jerk; a reversal counts as the larger of the two
 * speeds) or, if junction_dev_mm > 0, by Marlin's junction deviation.
 * The print starts and ends at the jerk-limited "safe" speed of its first
 * and last block.  A backward then a forward pass make every block's entry
 * reachable, and each block takes the time of its trapezoid (or triangle).
 * A block's acceleration is also capped so no axis exceeds its own
 * maximum (M201), as Marlin does.  Limits start from the caller's and
 * follow the file's M201 (X Y Z E), M203 (X Y Z E, mm/s), M204 (P print,
 * T travel, R retract, S both print and travel) and M205 (X Y Z E jerk,
 * J junction deviation) from where they appear, as the firmware would.
 * Heating waits (M109/M190) cost nothing, as in PrusaSlicer's estimate.
 *
 * Thread: reentrant.
 */
#ifndef SF_SLICER_ESTIMATE_H
#define SF_SLICER_ESTIMATE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../src/base/err.h"

/* Most planner blocks held at once (20 bytes each): a block leaves once
   no later one can change its time, so a longer look-ahead changes no
   real print's estimate. */
#define EST_LOOKAHEAD_BLOCKS 65536

/* Most planner blocks one arc becomes.  An arc is split into 1 mm
   segments as the firmware does, but one longer than this many planned
   that way would let a few bytes of G-code cost thousands of blocks (a
   "G2 I1591" line: 10 m, 10000 segments, 0.7 ms); a longer arc is
   planned as this many blocks that take the time its 1 mm segments
   would (estimate.c, plan_arc_coarse): to within 1 % where the firmware
   would saw through a segment junction limit (0.6 % the worst seen), to
   within float rounding where it keeps full speed, as a slicer's arcs do.  An arc's line takes 4
   bytes at least ("G2I9"), so a file costs at most 8 blocks per byte. */
#define EST_ARC_BLOCKS_MAX 32

struct est_limits {
    double max_feed_mm_s[4];   /* X Y Z E (M203) */
    double max_accel_mm_s2[4]; /* X Y Z E (M201); 0: no per-axis cap */
    double accel_extrude_mm_s2, accel_travel_mm_s2, accel_retract_mm_s2; /* M204 P T R */
    double jerk_mm_s[4];                                                 /* X Y Z E */
    double junction_dev_mm; /* > 0: use it instead of jerk */
};

/* One move as read back. */
struct est_move {
    double x, y, z, e; /* position after the move (E absolute, machine sense) */
    double de;         /* E change of this move */
    double f_mm_s;     /* requested feed rate */
    bool support;      /* under a support role tag */
    const char *type;  /* text after the last ;TYPE: (into the input), or NULL */
    size_t type_len;
    uint32_t layer; /* layer number (0 before the first ;LAYER_CHANGE) */
    uint32_t line;  /* 1-based line in the text */
};

/* Called for every move; return < 0 to stop with that status. */
typedef int (*est_move_fn)(void *ud, const struct est_move *mv);

struct estimate {
    double time_s;      /* whole print */
    double filament_mm; /* positive E with XY motion */
    double support_mm;  /* of which under support tags */
    uint32_t n_moves;
    uint32_t n_layers;     /* ;LAYER_CHANGE count */
    double *layer_start_s; /* n_layers entries: time when each layer starts (free()) */
    size_t peak_blocks;    /* most planner blocks held at once (bounded by the look-ahead) */
    size_t n_blocks;       /* planner blocks in all: a move, or an arc's segments (the work done) */
};

/*
 * Interpret len bytes of G-code (name for messages).  on_move may be NULL.
 * SF_EINVAL naming the line on a malformed line or an arc longer than
 * 10 m; SF_ENOMEM; on_move's status when it stops the walk (the message
 * names the line and says the callback stopped it).  Every error sets err.
 * Release out with estimate_release.
 */
int estimate_gcode(const char *text, size_t len, const char *name, const struct est_limits *lim,
                   est_move_fn on_move, void *ud, struct estimate *out, struct sf_err *err);

void estimate_release(struct estimate *e);

#endif
