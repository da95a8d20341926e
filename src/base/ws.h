/*
 * ws.h - the websocket protocol of RFC 6455 without the I/O: an
 * incremental frame parser, a frame encoder and the opening handshake's
 * check (ws_handshake) and accept value.  Shared by the simulators' push sockets
 * (sim/net/sim_ws.c) and any driver that reads one; whoever owns the
 * socket reads and writes the bytes.
 *
 * The parser takes bytes as they arrive (ws_parser_feed) and hands out
 * whole messages (ws_parser_next): fragments are joined, control frames
 * (ping, pong, close) come out as they arrive, also between the fragments
 * of a message.  It refuses what RFC 6455 calls a protocol error and
 * tells the close code to answer with: reserved bits (no extension is
 * negotiated here), unknown opcodes, a mask where none belongs or none
 * where one must be (section 5.1), lengths not in their shortest form or
 * with the top bit set, fragmented or long control frames, stray
 * continuations, a close frame of one byte or with a code no peer may
 * send (1002); text that is not UTF-8 (1007); a message over the cap
 * (1009).  After an error it stays failed.
 *
 * Thread: any; a parser is one owner's.  Owns its buffers
 * (ws_parser_release frees them).
 */
#ifndef SF_BASE_WS_H
#define SF_BASE_WS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "buf.h"
#include "err.h"

enum ws_op {
    WS_CONT = 0x0,
    WS_TEXT = 0x1,
    WS_BINARY = 0x2,
    WS_CLOSE = 0x8,
    WS_PING = 0x9,
    WS_PONG = 0xa,
};

/* Close codes (RFC 6455 section 7.4.1). */
#define WS_CLOSE_NORMAL   1000
#define WS_CLOSE_AWAY     1001
#define WS_CLOSE_PROTOCOL 1002
#define WS_CLOSE_NO_CODE  1005 /* a close frame without a code (never sent) */
#define WS_CLOSE_BAD_DATA 1007
#define WS_CLOSE_TOO_BIG  1009

/* Length of Sec-WebSocket-Accept's value (base64 of a SHA-1). */
#define WS_ACCEPT_LEN 28

/* Largest frame header: 2 bytes, 8 of length, 4 of mask. */
#define WS_HEADER_MAX 14

struct ws_parser {
    bool masked;         /* frames must carry a mask (a server reading its client), else none */
    size_t max_msg;      /* largest message, joined */
    struct buf in;       /* bytes not parsed yet */
    struct buf msg;      /* the fragmented message so far */
    int msg_op;          /* its opcode, 0 when none is under way */
    bool msg_done;       /* msg was handed out: empty it on the next call */
    size_t drop;         /* bytes of in handed out: consumed on the next call */
    size_t nul_at;       /* ... where a NUL was put after the handed-out payload */
    char nul_saved;      /* ... and the byte it stands on */
    bool nul_set;        /* whether one was */
    uint16_t close_code; /* after an error: the code to close with (0: none) */
};

/* One message: data (NUL-terminated, not counted) lives until the next ws_parser_* call. */
struct ws_msg {
    enum ws_op op;    /* WS_TEXT, WS_BINARY, WS_CLOSE, WS_PING or WS_PONG */
    const char *data; /* the payload; for WS_CLOSE the reason after the code */
    size_t len;
    uint16_t code; /* WS_CLOSE: the peer's code, WS_CLOSE_NO_CODE if it sent none */
};

/* A parser of frames that must (masked) or must not carry a mask, messages up to max_msg. */
void ws_parser_init(struct ws_parser *p, bool masked, size_t max_msg);
void ws_parser_release(struct ws_parser *p);

/*
 * Take bytes read from the peer.  Call ws_parser_next until it returns 0
 * before feeding more than max_msg bytes again: the unparsed bytes are
 * capped at twice max_msg plus a header.  SF_ENOMEM when they would pass
 * the cap (close with WS_CLOSE_TOO_BIG).
 */
int ws_parser_feed(struct ws_parser *p, const void *data, size_t len, struct sf_err *err);

/*
 * The next whole message: 1 with *m set, 0 when more bytes are needed, or
 * SF_EINVAL with err set ("websocket: ...") and p->close_code the code to
 * close with; a failed parser keeps failing.
 */
int ws_parser_next(struct ws_parser *p, struct ws_msg *m, struct sf_err *err);

/*
 * Append one unfragmented frame (op, payload data/len) to out; mask is the
 * 4-byte masking key a client must use (NULL: none, as a server sends).
 * SF_ENOMEM if out's cap or memory runs out (out unchanged).
 */
int ws_frame(struct buf *out, enum ws_op op, const void *data, size_t len, const uint8_t *mask);
/* Append a close frame with code and a reason (NULL: none; cut at 123 bytes). */
int ws_close_frame(struct buf *out, uint16_t code, const char *reason, const uint8_t *mask);

/* Whether key is a valid Sec-WebSocket-Key: base64 of 16 bytes (24 characters). */
bool ws_key_valid(const char *key);
/*
 * Sec-WebSocket-Accept for key: base64(SHA-1(key + the RFC's GUID)), into
 * out (WS_ACCEPT_LEN + 1 bytes).  SF_EINVAL if the key is not valid,
 * SF_EIO if the digest fails.
 */
int ws_accept(const char *key, char out[WS_ACCEPT_LEN + 1], struct sf_err *err);

/*
 * A server's answer to an opening handshake (RFC 6455 4.2.1) from the
 * request's method and header values (NULL: absent): 101 with accept set;
 * 400 when it is no websocket upgrade (GET with Upgrade: websocket and
 * Connection: upgrade) or its key is not valid; 426 for another version
 * than 13 (answer Sec-WebSocket-Version: 13).  *why is the text to answer
 * a refusal with (tornado's words, as OctoPrint and Moonraker send them).
 */
int ws_handshake(const char *method, const char *upgrade, const char *connection,
                 const char *version, const char *key, char accept[WS_ACCEPT_LEN + 1],
                 const char **why);

#endif
