/* fuzz_gcode.c - the G-code line tokenizer and stripper on arbitrary bytes. */
#include <stdint.h>

#include "../../src/base/gcode.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int
LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct gcode_line l;
    char out[128];
    gcode_parse((const char *)data, size, &l, NULL);
    gcode_strip((const char *)data, size, out, sizeof(out), NULL);
    return 0;
}
