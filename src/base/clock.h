/*
 * clock.h - the process's two clocks in the units its callers keep: the
 * monotonic clock for durations, timers and time budgets, the wall clock
 * for what is stored or shown (ms since the epoch).
 *
 * One copy instead of a static helper in every file that timed something;
 * each caller still says which clock it means.
 *
 * Thread: any; the functions keep no state.
 */
#ifndef SF_BASE_CLOCK_H
#define SF_BASE_CLOCK_H

#include <stdint.h>

/* CLOCK_MONOTONIC in whole milliseconds (truncated). */
int64_t clock_mono_ms(void);
/* CLOCK_MONOTONIC in seconds, with its nanoseconds. */
double clock_mono_s(void);
/* CLOCK_REALTIME in whole milliseconds since the epoch (truncated). */
int64_t clock_wall_ms(void);

#endif
