/* fuzz_gcjob.c - the slicer comments of uploaded G-code (gcjob_parse) on
   arbitrary bytes, and the key it makes read back by gcjob_runs_on. */
#include <stdint.h>

#include "../../src/farm/gcjob.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int
LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct gcjob_info g;
    if (gcjob_parse((const char *)data, size, &g, NULL) == 0) {
        char key[256], why[160];
        gcjob_key(&g, key, sizeof(key));
        gcjob_runs_on(key, size % 2 ? "*" : g.model, 0.4, why, sizeof(why));
    }
    return 0;
}
