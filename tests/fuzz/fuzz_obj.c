/* fuzz_obj.c - the obj loader, then weld, orientation repair and topology on what it yields. */
#include <stdint.h>

#include "fuzz_mesh.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int
LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    return fuzz_mesh(data, size, obj_parse);
}
