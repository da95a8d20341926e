/* fuzz_gpolicy.c - the G-code policy (drivers/gpolicy.h) and the upload
   check's two readers of a file (gpolicy_check_file, drv_job_scan) on
   arbitrary bytes.  The first byte picks the policy (attended, allowed
   rows); the file reader must find what the text judge finds, and a manual
   command's rewrite must itself pass. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

#include "../../drivers/drv.h"
#include "../../drivers/gpolicy.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int
LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct gpolicy p;
    gpolicy_init(&p);
    p.attended = size && (data[0] & 1);
    if (size && (data[0] & 2))
        gpolicy_allow(&p, data[0] & 4 ? "M600 M500" : "SAVE_CONFIG m0", NULL);
    const char *t = (const char *)data;
    char msg[4096], fmsg[4096];
    size_t found = gpolicy_check_text(&p, t, size, "f", msg, sizeof(msg));
    if (strlen(msg) >= sizeof(msg) || (found == 0) != (msg[0] == '\0'))
        abort();
    for (size_t s = 0, i = 0; i <= size; i++)
        if (i == size || t[i] == '\n') {
            struct gpolicy_verdict v, w;
            if (gpolicy_check_line(&p, GPOLICY_MANUAL, t + s, i - s, &v) == GPOLICY_REWRITE &&
                gpolicy_check_line(&p, GPOLICY_MANUAL, v.line, strlen(v.line), &w) != GPOLICY_PASS)
                abort();
            s = i + 1;
        }
    int fd = memfd_create("gpolicy", 0);
    if (fd < 0 || write(fd, data, size) != (ssize_t)size) {
        if (fd >= 0)
            close(fd);
        return 0;
    }
    char path[64];
    snprintf(path, sizeof(path), "/proc/self/fd/%d", fd);
    size_t n = 0;
    struct drv_job_scan scan;
    int rc = gpolicy_check_file(&p, path, "f", fmsg, sizeof(fmsg), &n, NULL);
    if ((rc == 0) != (n == 0) || n != found || strcmp(msg, fmsg) != 0)
        abort();
    drv_job_scan(path, &scan, NULL);
    close(fd);
    return 0;
}
