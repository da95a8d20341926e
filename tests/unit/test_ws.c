/*
 * test_ws.c - the websocket framing (src/base/ws.h) against RFC 6455's own
 * examples (section 5.7, the handshake of section 1.3), fed whole and one
 * byte at a time, and every protocol error it must refuse with its code.
 */
#include <string.h>

#include "../../src/base/ws.h"
#include "../t.h"

/* Feed all of data (one byte at a time if bytewise) and collect the messages' ops and
   payloads into got ("op:payload|..."); the last parse result. */
static int
parse_all(bool masked, const void *data, size_t len, bool bytewise, char *got, size_t cap,
          uint16_t *close_code)
{
    struct ws_parser p;
    ws_parser_init(&p, masked, 70000);
    got[0] = 0;
    int rc = 0;
    size_t step = bytewise ? 1 : len;
    for (size_t at = 0; at < len && rc >= 0; at += step) {
        rc = ws_parser_feed(&p, (const char *)data + at, len - at < step ? len - at : step, NULL);
        struct ws_msg m;
        while (rc >= 0 && (rc = ws_parser_next(&p, &m, NULL)) == 1) {
            size_t n = strlen(got);
            snprintf(got + n, cap - n, "%d:%.*s%s|", m.op, m.len > 16 ? 16 : (int)m.len, m.data,
                     m.len > 16 ? "..." : "");
            if (m.op == WS_CLOSE)
                *close_code = m.code;
            if (m.data[m.len] != 0)
                snprintf(got, cap, "payload not NUL-terminated");
        }
    }
    if (rc < 0)
        *close_code = p.close_code;
    ws_parser_release(&p);
    return rc;
}

T_CASE(ws_accept_matches_rfc6455)
{
    char out[WS_ACCEPT_LEN + 1];
    struct sf_err err;
    T_OK(ws_accept("dGhlIHNhbXBsZSBub25jZQ==", out, &err), &err);
    T_EQ_STR(out, "s3pPLMBiTxaQ9kYGzzhZRbK+xOo=");
    T_ERR(ws_accept("dGhlIHNhbXBsZSBub25jZQ", out, &err), SF_EINVAL, &err, "Sec-WebSocket-Key");
    T_TRUE(!ws_key_valid("dGhlIHNhbXBsZSBub25jZR==")); /* stray bits in the last character */
    T_TRUE(!ws_key_valid(NULL));
    T_TRUE(!ws_key_valid("dGhlIHNhbXBsZS*ub25jZQ=="));
}

T_CASE(ws_parses_rfc_examples_whole_and_bytewise)
{
    static const unsigned char frames[] = {
        0x81, 0x05, 'H',  'e',  'l', 'l', 'o', /* unmasked text */
        0x01, 0x03, 'H',  'e',  'l',           /* fragmented ... */
        0x89, 0x05, 'H',  'e',  'l', 'l', 'o', /* ... a ping between ... */
        0x80, 0x02, 'l',  'o',                 /* ... its end */
        0x8a, 0x00,                            /* an empty pong */
        0x88, 0x05, 0x03, 0xe8, 'b', 'y', 'e', /* close 1000 "bye" */
    };
    char got[512];
    uint16_t code = 0;
    for (int bytewise = 0; bytewise < 2; bytewise++) {
        T_EQ_INT(parse_all(false, frames, sizeof(frames), bytewise, got, sizeof(got), &code), 0);
        T_EQ_STR(got, "1:Hello|9:Hello|1:Hello|10:|8:bye|");
        T_EQ_INT(code, 1000);
    }
    /* the masked example of 5.7 read by a server */
    static const unsigned char masked[] = { 0x81, 0x85, 0x37, 0xfa, 0x21, 0x3d,
                                            0x7f, 0x9f, 0x4d, 0x51, 0x58 };
    T_EQ_INT(parse_all(true, masked, sizeof(masked), true, got, sizeof(got), &code), 0);
    T_EQ_STR(got, "1:Hello|");
}

T_CASE(ws_frames_round_trip_at_every_length_form)
{
    static const size_t lens[] = { 0, 125, 126, 65535, 65536 };
    static const uint8_t mask[4] = { 0x12, 0x34, 0x56, 0x78 };
    static char payload[65536];
    for (size_t i = 0; i < sizeof(payload); i++)
        payload[i] = (char)('a' + i % 26);
    for (size_t k = 0; k < sizeof(lens) / sizeof(lens[0]); k++) {
        for (int m = 0; m < 2; m++) {
            struct buf out;
            buf_init(&out, 0);
            T_OK(ws_frame(&out, WS_TEXT, payload, lens[k], m ? mask : NULL), NULL);
            T_EQ_INT(out.len, lens[k] +
                                  (lens[k] < 126     ? 2
                                   : lens[k] < 65536 ? 4
                                                     : 10) +
                                  (m ? 4 : 0));
            struct ws_parser p;
            ws_parser_init(&p, m, 70000);
            struct ws_msg msg;
            T_OK(ws_parser_feed(&p, out.data, out.len, NULL), NULL);
            T_EQ_INT(ws_parser_next(&p, &msg, NULL), 1);
            T_EQ_INT(msg.op, WS_TEXT);
            T_EQ_INT(msg.len, lens[k]);
            T_TRUE(memcmp(msg.data, payload, lens[k]) == 0);
            T_EQ_INT(ws_parser_next(&p, &msg, NULL), 0);
            ws_parser_release(&p);
            buf_release(&out);
        }
    }
    struct buf out;
    buf_init(&out, 0);
    T_OK(ws_close_frame(&out, 1001, "going", NULL), NULL);
    T_EQ_INT(out.len, 9);
    T_TRUE(memcmp(out.data, "\x88\x07\x03\xe9going", 9) == 0);
    buf_release(&out);
}

/* Each bad stream fails with its close code, and the parser stays failed. */
T_CASE(ws_refuses_protocol_errors_with_their_codes)
{
    static const struct {
        const char *what;
        bool masked;
        const char *bytes;
        size_t len;
        uint16_t code;
    } bad[] = {
        { "reserved bit", false, "\xc1\x00", 2, WS_CLOSE_PROTOCOL },
        { "opcode 3", false, "\x83\x00", 2, WS_CLOSE_PROTOCOL },
        { "unmasked client frame", true, "\x81\x00", 2, WS_CLOSE_PROTOCOL },
        { "masked server frame", false, "\x81\x80\0\0\0\0", 6, WS_CLOSE_PROTOCOL },
        { "long form for 5", false, "\x81\x7e\x00\x05hello", 9, WS_CLOSE_PROTOCOL },
        { "top bit of 64-bit length", false, "\x82\x7f\x80\0\0\0\0\0\0\0", 10, WS_CLOSE_PROTOCOL },
        { "fragmented ping", false, "\x09\x00", 2, WS_CLOSE_PROTOCOL },
        { "126-byte ping", false, "\x89\x7e\x00\x7e", 4, WS_CLOSE_PROTOCOL },
        { "stray continuation", false, "\x80\x00", 2, WS_CLOSE_PROTOCOL },
        { "text inside a fragmented text", false,
          "\x01\x01"
          "a\x81\x01"
          "b",
          6, WS_CLOSE_PROTOCOL },
        { "close of one byte", false, "\x88\x01\x03", 3, WS_CLOSE_PROTOCOL },
        { "close code 1005", false, "\x88\x02\x03\xed", 4, WS_CLOSE_PROTOCOL },
        { "close code 999", false, "\x88\x02\x03\xe7", 4, WS_CLOSE_PROTOCOL },
        { "overlong UTF-8", false, "\x81\x02\xc0\xaf", 4, WS_CLOSE_BAD_DATA },
        { "surrogate split over fragments", false, "\x01\x02\xed\xa0\x80\x01\x80", 7,
          WS_CLOSE_BAD_DATA },
        { "bad close reason", false, "\x88\x03\x03\xe8\xff", 5, WS_CLOSE_BAD_DATA },
        { "message over the cap", false, "\x82\x7f\0\0\0\0\0\x10\0\0", 10, WS_CLOSE_TOO_BIG },
    };
    char got[256];
    for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
        for (int bytewise = 0; bytewise < 2; bytewise++) {
            uint16_t code = 0;
            int rc = parse_all(bad[i].masked, bad[i].bytes, bad[i].len, bytewise, got, sizeof(got),
                               &code);
            if (rc != SF_EINVAL || code != bad[i].code)
                t_fail(__FILE__, __LINE__, "%s: rc %d code %u, want %u", bad[i].what, rc, code,
                       bad[i].code);
        }
    }
    struct ws_parser p;
    struct ws_msg m;
    struct sf_err err;
    ws_parser_init(&p, false, 100);
    T_OK(ws_parser_feed(&p, "\x83\x00\x81\x01x", 5, NULL), NULL);
    T_ERR(ws_parser_next(&p, &m, &err), SF_EINVAL, &err, "unknown opcode");
    T_ERR(ws_parser_next(&p, &m, &err), SF_EINVAL, &err, "failed before");
    ws_parser_release(&p);
}

/* Text in several fragments is joined; binary is not checked as UTF-8. */
T_CASE(ws_joins_fragments_and_keeps_binary)
{
    /* "a\u00a9" cut inside its second character, then two binary bytes */
    static const unsigned char s[] = { 0x01, 0x02, 'a',  0xc2, 0x80, 0x01,
                                       0xa9, 0x82, 0x02, 0xff, 0x00 };
    struct ws_parser p;
    ws_parser_init(&p, false, 100);
    struct ws_msg m;
    T_OK(ws_parser_feed(&p, s, sizeof(s), NULL), NULL);
    T_EQ_INT(ws_parser_next(&p, &m, NULL), 1);
    T_EQ_INT(m.op, WS_TEXT);
    T_EQ_STR(m.data, "a\xc2\xa9");
    T_EQ_INT(ws_parser_next(&p, &m, NULL), 1);
    T_EQ_INT(m.op, WS_BINARY);
    T_EQ_INT(m.len, 2);
    T_TRUE((unsigned char)m.data[0] == 0xff && m.data[1] == 0);
    T_EQ_INT(ws_parser_next(&p, &m, NULL), 0);
    ws_parser_release(&p);
}
