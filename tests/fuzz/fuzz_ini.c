/* fuzz_ini.c - the INI reader and the profile option table on arbitrary bytes. */
#include <stdint.h>

#include "../../slicer/profile.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int
LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct slice_profile p;
    if (slice_profile_default(&p) < 0)
        return 0;
    slice_profile_parse(&p, (const char *)data, size, "fuzz.cfg", size % 2 ? "printer" : "material",
                        NULL);
    slice_profile_release(&p);
    return 0;
}
