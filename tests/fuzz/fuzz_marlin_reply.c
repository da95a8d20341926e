/* fuzz_marlin_reply.c - the Marlin reply classifier on arbitrary bytes. */
#include <stdint.h>

#include "../../drivers/marlin/marlin_reply.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int
LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct mreply r;
    mreply_parse((const char *)data, size, &r);
    return 0;
}
