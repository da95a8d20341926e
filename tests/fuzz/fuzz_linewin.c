/*
 * fuzz_linewin.c - the line window driven by arbitrary reply sequences: each
 * input line is classified and fed to the window as the driver would, and
 * the window's invariants must hold after every step (no reply, however
 * garbled, drives its counters out of range); the input's head also goes
 * through the emergency parser's model.
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "../../drivers/marlin/linewin.h"
#include "../../drivers/marlin/marlin_reply.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int
LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    /* The emergency parser's model takes any bytes a line may hold. */
    (void)linewin_ep_hazard((const char *)data, size < 100 ? size : 100);
    struct linewin w;
    if (linewin_init(&w, 32, 4) < 0)
        return 0;
    w.advanced = size > 0 && (data[0] & 1);
    w.rx_bytes = size > 0 && (data[0] & 2) ? 128 : 0;
    const char *p = (const char *)data, *end = p + size;
    long pushed = 0;
    while (p < end) {
        const char *nl = memchr(p, '\n', (size_t)(end - p));
        size_t len = nl ? (size_t)(nl - p) : (size_t)(end - p);
        while (linewin_push(&w, pushed % 5 ? "G1 X1 Y2" : "M105", pushed % 5 ? pushed : -2, NULL) >
               0)
            pushed++;
        while (linewin_peek(&w))
            linewin_sent(&w);
        struct mreply r;
        mreply_parse(p, len, &r);
        if (r.kind == MR_OK && r.has_temps)
            linewin_barrier(&w, w.acked + 1);
        else if (r.kind == MR_OK)
            linewin_on_ok(&w, r.has_n, r.n, -2);
        else if (r.kind == MR_RESEND)
            linewin_on_resend(&w, r.resend);
        else if (r.kind == MR_WAIT)
            linewin_resync(&w);
        else if (r.kind == MR_OTHER)
            linewin_force(&w);
        /* Whatever the replies said, the window stays in range. */
        if (w.in_flight < 0 || w.in_flight > w.cap || w.next < 1 || w.next > w.high + 1 ||
            w.acked > w.next - 1 || w.stale < 0 || w.swallow < 0)
            abort();
        p = nl ? nl + 1 : end;
    }
    linewin_release(&w);
    return 0;
}
