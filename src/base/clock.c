/*
 * clock.c - monotonic and wall-clock time in ms or s (see clock.h).
 *
 * Thin wrappers over clock_gettime(2), which cannot fail for these clocks
 * on Linux, so they return the time without an error path.
 *
 * Thread: any.
 */
#include "clock.h"

#include <time.h>

static int64_t
ms(clockid_t id)
{
    struct timespec ts;
    clock_gettime(id, &ts);
    return (int64_t)ts.tv_sec * 1000 + ts.tv_nsec / 1000000;
}

int64_t
clock_mono_ms(void)
{
    return ms(CLOCK_MONOTONIC);
}

double
clock_mono_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

int64_t
clock_wall_ms(void)
{
    return ms(CLOCK_REALTIME);
}
