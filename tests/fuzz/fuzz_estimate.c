/* fuzz_estimate.c - the G-code reader and planner (slicer/estimate.c) on arbitrary bytes. */
#include <stdint.h>

#include "../../slicer/estimate.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int
LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct est_limits l = { { 500, 500, 12, 120 }, 1500, 1250, 1500, { 10, 10, 0.2, 2.5 }, 0 };
    if (size % 3 == 0)
        l.junction_dev_mm = 0.05;
    struct estimate e;
    if (estimate_gcode((const char *)data, size, "fuzz", &l, NULL, NULL, &e, NULL) == 0)
        estimate_release(&e);
    return 0;
}
