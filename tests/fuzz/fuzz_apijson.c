/* fuzz_apijson.c - the REST API's JSON bodies (job options, priority) on arbitrary bytes. */
#include <stdint.h>

#include "../../src/api/api_json.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int
LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "part.stl");
    int prio;
    api_opts_parse((const char *)data, size, &o, NULL);
    api_priority_parse((const char *)data, size, &prio, NULL);
    return 0;
}
