/*
 * simopt.h - the small pieces every `slimfarm-sim KIND` command line
 * shares: a number option checked against its range, the process's one
 * loop that SIGINT/SIGTERM stop, and the head of a stats line.
 *
 * Why: each simulator's main (marlin in slimfarm_sim.c, bambu in
 * sim_bambu_main.c) had its own copy of both (review finding D6).  The
 * option tables themselves stay with each simulator: their options differ.
 *
 * Thread: main thread.
 */
#ifndef SF_SIM_SIMOPT_H
#define SF_SIM_SIMOPT_H

#include <stdbool.h>

#include "../src/base/loop.h"

/*
 * Parse v as a number in [lo, hi] into *out.  On a bad value prints
 * "PROG: OPT expects a number from LO to HI" (or "a whole number" when
 * whole) on stderr and returns -1; 0 on success.  v NULL counts as bad.
 */
int simopt_num(const char *prog, const char *opt, const char *v, double lo, double hi, bool whole,
               double *out);

/*
 * The head of printer index's stats line: "stats: " for a process serving
 * one printer, "stats: printer=INDEX " for one serving count > 1 (--count),
 * as the benchmarks read them.  A static buffer: use it before the next call.
 */
const char *simopt_stats_head(int index, int count);

/*
 * A new loop on which SIGINT and SIGTERM call loop_stop, with SIGPIPE
 * ignored (a peer that hangs up must not kill the simulator).  NULL after
 * printing "PROG: reason" on stderr.  Free with loop_free.
 */
struct loop *simopt_loop(const char *prog);

#endif
