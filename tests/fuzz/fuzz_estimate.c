/* fuzz_estimate.c - the G-code reader and planner (slicer/estimate.c) on arbitrary bytes. */
#include <stdint.h>

#include "../../slicer/estimate.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int
LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct est_limits l = { .max_feed_mm_s = { 500, 500, 12, 120 },
                            .max_accel_mm_s2 = { 9000, 9000, 500, 10000 },
                            .accel_extrude_mm_s2 = 1500,
                            .accel_travel_mm_s2 = 1250,
                            .accel_retract_mm_s2 = 1500,
                            .jerk_mm_s = { 10, 10, 0.2, 2.5 } };
    if (size % 3 == 0)
        l.junction_dev_mm = 0.05;
    struct estimate e;
    if (estimate_gcode((const char *)data, size, "fuzz", &l, NULL, NULL, &e, NULL) == 0)
        estimate_release(&e);
    return 0;
}
