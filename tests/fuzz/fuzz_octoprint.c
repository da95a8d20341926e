/* fuzz_octoprint.c - the OctoPrint driver's reply parsers on arbitrary bytes. */
#include <stdint.h>

#include "../../drivers/net/drv_octoprint.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int
LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    const char *s = (const char *)data;
    struct octo_job j;
    struct octo_printer p;
    char text[64];
    bool print;
    if (octo_parse_job(s, size, &j, NULL) == SF_OK)
        (void)octo_classify(j.state);
    (void)octo_parse_printer(s, size, &p, NULL);
    (void)octo_parse_version(s, size, text, sizeof(text), NULL);
    (void)octo_parse_upload(s, size, &print, text, sizeof(text), NULL);
    octo_reason(s, size, text, sizeof(text));
    return 0;
}
