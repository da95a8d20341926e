/* fuzz_farmcfg.c - the farm config parser on arbitrary bytes. */
#include <stdint.h>

#include "../../src/farm/farmcfg.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int
LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct farmcfg c;
    farmcfg_init(&c);
    if (farmcfg_parse(&c, (const char *)data, size, "fuzz.ini", NULL) == SF_OK)
        farmcfg_release(&c);
    return 0;
}
