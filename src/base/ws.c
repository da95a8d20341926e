/*
 * ws.c - RFC 6455 framing and handshake values (ws.h).
 *
 * The parser works on the bytes not yet parsed, kept in one buffer: a
 * frame is read once all of it is there (a header first tells its
 * length, so a frame over the cap fails before its payload arrives), its
 * payload unmasked in place.  A whole unfragmented message is handed out
 * where it lies, with a NUL put after it (the byte under it is put back
 * on the next call); fragments are copied into a second buffer until the
 * last one.  SHA-1 and base64 are OpenSSL's (libcrypto is linked for TLS).
 *
 * Thread: any.
 */
#include "ws.h"

#include <openssl/evp.h>
#include <string.h>
#include <strings.h>

#include "utf8.h"

/* The GUID RFC 6455 section 1.3 appends to the key. */
static const char ws_guid[] = "258EAFA5-E914-47DA-95CA-C5AB0DC85B11";

void
ws_parser_init(struct ws_parser *p, bool masked, size_t max_msg)
{
    memset(p, 0, sizeof(*p));
    p->masked = masked;
    p->max_msg = max_msg;
    buf_init(&p->in, 2 * max_msg + WS_HEADER_MAX);
    buf_init(&p->msg, max_msg);
}

void
ws_parser_release(struct ws_parser *p)
{
    buf_release(&p->in);
    buf_release(&p->msg);
}

int
ws_parser_feed(struct ws_parser *p, const void *data, size_t len, struct sf_err *err)
{
    if (p->nul_set) { /* the NUL sits inside in: put the byte back before it moves */
        p->in.data[p->nul_at] = p->nul_saved;
        p->nul_set = false;
    }
    if (buf_append(&p->in, data, len) < 0) {
        p->close_code = WS_CLOSE_TOO_BIG;
        return sf_err_set(err, SF_ENOMEM, "websocket: more than %zu bytes unread", p->in.max);
    }
    return SF_OK;
}

static int
fail(struct ws_parser *p, uint16_t code, struct sf_err *err, const char *what)
{
    p->close_code = code;
    return sf_err_set(err, SF_EINVAL, "websocket: %s", what);
}

/* Whether data[0..len) is UTF-8; data[len] must be writable (it is put back). */
static bool
utf8_ok(char *data, size_t len)
{
    char keep = data[len];
    data[len] = 0;
    bool ok = true;
    for (size_t i = 0; i < len && ok;) {
        int k = utf8_seq((const unsigned char *)data + i);
        if (k <= 0)
            ok = false;
        else
            i += (size_t)k;
    }
    data[len] = keep;
    return ok;
}

static bool
close_code_ok(unsigned c)
{
    return (c >= 1000 && c <= 1003) || (c >= 1007 && c <= 1011) || (c >= 3000 && c <= 4999);
}

/*
 * The frame header at b[0..n): 1 with *hdr (bytes, with the mask), *len
 * (payload bytes) set; 0 if more bytes are needed; < 0 on a protocol error.
 */
static int
header(struct ws_parser *p, const uint8_t *b, size_t n, size_t *hdr, uint64_t *len,
       struct sf_err *err)
{
    if (n < 2)
        return 0;
    int op = b[0] & 0x0f;
    bool control = op & 0x8;
    if (b[0] & 0x70)
        return fail(p, WS_CLOSE_PROTOCOL, err, "reserved bits set (no extension was agreed)");
    if (op != WS_CONT && op != WS_TEXT && op != WS_BINARY && op != WS_CLOSE && op != WS_PING &&
        op != WS_PONG)
        return fail(p, WS_CLOSE_PROTOCOL, err, "unknown opcode");
    if (((b[1] & 0x80) != 0) != p->masked)
        return fail(p, WS_CLOSE_PROTOCOL, err,
                    p->masked ? "a client frame without a mask" : "a server frame with a mask");
    uint64_t l = b[1] & 0x7f;
    size_t h = 2;
    if (l == 126) {
        if (n < 4)
            return 0;
        l = (uint64_t)b[2] << 8 | b[3];
        h = 4;
        if (l < 126)
            return fail(p, WS_CLOSE_PROTOCOL, err, "length not in its shortest form");
    } else if (l == 127) {
        if (n < 10)
            return 0;
        l = 0;
        for (int i = 2; i < 10; i++)
            l = l << 8 | b[i];
        h = 10;
        if (l >> 63)
            return fail(p, WS_CLOSE_PROTOCOL, err, "length with its top bit set");
        if (l < 65536)
            return fail(p, WS_CLOSE_PROTOCOL, err, "length not in its shortest form");
    }
    if (control && (!(b[0] & 0x80) || l > 125))
        return fail(p, WS_CLOSE_PROTOCOL, err, "a fragmented or long control frame");
    if (!control) {
        if (op == WS_CONT && !p->msg_op)
            return fail(p, WS_CLOSE_PROTOCOL, err, "a continuation without a message");
        if (op != WS_CONT && p->msg_op)
            return fail(p, WS_CLOSE_PROTOCOL, err, "a new message inside a fragmented one");
        if ((op == WS_CONT ? p->msg.len : 0) + l > p->max_msg)
            return fail(p, WS_CLOSE_TOO_BIG, err, "message too big");
    }
    *hdr = h + (p->masked ? 4 : 0);
    *len = l;
    return 1;
}

/* Hand out payload at in+off (len bytes) in place as message op. */
static void
hand_out(struct ws_parser *p, struct ws_msg *m, int op, size_t off, size_t len)
{
    p->nul_at = off + len;
    p->nul_saved = p->in.data[p->nul_at];
    p->in.data[p->nul_at] = 0;
    p->nul_set = true;
    m->op = (enum ws_op)op;
    m->data = p->in.data + off;
    m->len = len;
    m->code = 0;
}

static int
control_frame(struct ws_parser *p, struct ws_msg *m, int op, size_t off, size_t len,
              struct sf_err *err)
{
    char *d = p->in.data + off;
    if (op != WS_CLOSE) {
        hand_out(p, m, op, off, len);
        return 1;
    }
    if (len == 1)
        return fail(p, WS_CLOSE_PROTOCOL, err, "a close frame of one byte");
    unsigned code = len ? (unsigned)(uint8_t)d[0] << 8 | (uint8_t)d[1] : WS_CLOSE_NO_CODE;
    if (len && !close_code_ok(code))
        return fail(p, WS_CLOSE_PROTOCOL, err, "a close code no peer may send");
    if (len > 2 && !utf8_ok(d + 2, len - 2))
        return fail(p, WS_CLOSE_BAD_DATA, err, "a close reason that is not UTF-8");
    hand_out(p, m, op, off + (len ? 2 : 0), len ? len - 2 : 0);
    m->code = (uint16_t)code;
    return 1;
}

int
ws_parser_next(struct ws_parser *p, struct ws_msg *m, struct sf_err *err)
{
    if (p->nul_set) {
        p->in.data[p->nul_at] = p->nul_saved;
        p->nul_set = false;
    }
    buf_consume(&p->in, p->drop);
    p->drop = 0;
    if (p->msg_done) {
        buf_reset(&p->msg);
        p->msg_done = false;
    }
    if (p->close_code)
        return sf_err_set(err, SF_EINVAL, "websocket: the stream failed before");
    for (;;) {
        const uint8_t *b = (const uint8_t *)p->in.data;
        size_t hdr = 0;
        uint64_t len = 0;
        int rc = header(p, b, p->in.len, &hdr, &len, err);
        if (rc <= 0)
            return rc;
        if (p->in.len < hdr || p->in.len - hdr < len)
            return 0;
        int op = b[0] & 0x0f;
        bool fin = b[0] & 0x80;
        char *payload = p->in.data + hdr;
        if (p->masked)
            for (size_t i = 0; i < len; i++)
                payload[i] ^= (char)b[hdr - 4 + i % 4];
        p->drop = hdr + (size_t)len;
        if (op & 0x8)
            return control_frame(p, m, op, hdr, (size_t)len, err);
        if (fin && op != WS_CONT) {
            if (op == WS_TEXT && !utf8_ok(payload, (size_t)len))
                return fail(p, WS_CLOSE_BAD_DATA, err, "text that is not UTF-8");
            hand_out(p, m, op, hdr, (size_t)len);
            return 1;
        }
        if (buf_append(&p->msg, payload, (size_t)len) < 0)
            return fail(p, WS_CLOSE_TOO_BIG, err, "message too big");
        if (op != WS_CONT)
            p->msg_op = op;
        buf_consume(&p->in, p->drop);
        p->drop = 0;
        if (!fin)
            continue;
        if (p->msg_op == WS_TEXT && !utf8_ok(p->msg.data ? p->msg.data : (char *)"", p->msg.len))
            return fail(p, WS_CLOSE_BAD_DATA, err, "text that is not UTF-8");
        m->op = (enum ws_op)p->msg_op;
        m->data = p->msg.data ? p->msg.data : "";
        m->len = p->msg.len;
        m->code = 0;
        p->msg_op = 0;
        p->msg_done = true;
        return 1;
    }
}

int
ws_frame(struct buf *out, enum ws_op op, const void *data, size_t len, const uint8_t *mask)
{
    uint8_t h[WS_HEADER_MAX];
    size_t n = 2;
    h[0] = (uint8_t)(0x80 | op);
    if (len < 126) {
        h[1] = (uint8_t)len;
    } else if (len < 65536) {
        h[1] = 126;
        h[2] = (uint8_t)(len >> 8);
        h[3] = (uint8_t)len;
        n = 4;
    } else {
        h[1] = 127;
        for (int i = 0; i < 8; i++)
            h[2 + i] = (uint8_t)((uint64_t)len >> (56 - 8 * i));
        n = 10;
    }
    if (mask) {
        h[1] |= 0x80;
        memcpy(h + n, mask, 4);
        n += 4;
    }
    size_t at = out->len;
    if (len > SIZE_MAX - n || buf_append(out, h, n) < 0 || buf_append(out, data, len) < 0) {
        out->len = at;
        if (out->data)
            out->data[at] = 0;
        return SF_ENOMEM;
    }
    if (mask)
        for (size_t i = 0; i < len; i++)
            out->data[at + n + i] ^= (char)mask[i % 4];
    return SF_OK;
}

int
ws_close_frame(struct buf *out, uint16_t code, const char *reason, const uint8_t *mask)
{
    char body[125];
    size_t n = reason ? strlen(reason) : 0;
    if (n > sizeof(body) - 2)
        n = sizeof(body) - 2;
    body[0] = (char)(code >> 8);
    body[1] = (char)(code & 0xff);
    if (n)
        memcpy(body + 2, reason, n);
    return ws_frame(out, WS_CLOSE, body, n + 2, mask);
}

bool
ws_key_valid(const char *key)
{
    /* 16 bytes in base64: 22 characters of the alphabet, then "==" */
    if (!key || strlen(key) != 24 || strcmp(key + 22, "==") != 0)
        return false;
    for (int i = 0; i < 22; i++)
        if (!strchr("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/", key[i]))
            return false;
    return key[21] && strchr("AQgw", key[21]); /* the last 4 bits are zero */
}

int
ws_accept(const char *key, char out[WS_ACCEPT_LEN + 1], struct sf_err *err)
{
    if (!ws_key_valid(key))
        return sf_err_set(err, SF_EINVAL,
                          "websocket: Sec-WebSocket-Key '%.40s' is not base64 of "
                          "16 bytes",
                          key ? key : "");
    char text[24 + sizeof(ws_guid)];
    memcpy(text, key, 24);
    memcpy(text + 24, ws_guid, sizeof(ws_guid));
    unsigned char md[EVP_MAX_MD_SIZE];
    unsigned int n = 0;
    if (EVP_Digest(text, strlen(text), md, &n, EVP_sha1(), NULL) != 1 || n != 20)
        return sf_err_set(err, SF_EIO, "websocket: SHA-1 failed");
    EVP_EncodeBlock((unsigned char *)out, md, 20);
    out[WS_ACCEPT_LEN] = 0;
    return SF_OK;
}

/* Whether a comma-separated header value holds token (any case). */
static bool
has_token(const char *v, const char *token)
{
    size_t n = strlen(token);
    while (v && *v) {
        while (*v == ' ' || *v == '\t' || *v == ',')
            v++;
        size_t k = strcspn(v, ",");
        size_t e = k;
        while (e && (v[e - 1] == ' ' || v[e - 1] == '\t'))
            e--;
        if (e == n && strncasecmp(v, token, n) == 0)
            return true;
        v += k;
    }
    return false;
}

int
ws_handshake(const char *method, const char *upgrade, const char *connection, const char *version,
             const char *key, char accept[WS_ACCEPT_LEN + 1], const char **why)
{
    *why = NULL;
    if (strcmp(method, "GET") != 0 || !has_token(upgrade, "websocket") ||
        !has_token(connection, "upgrade")) {
        *why = "Can \"Upgrade\" only to \"WebSocket\"."; /* tornado's words */
        return 400;
    }
    if (!version || strcmp(version, "13") != 0) {
        *why = "Sec-WebSocket-Version must be 13";
        return 426;
    }
    if (ws_accept(key, accept, NULL) < 0) {
        *why = "Missing/Invalid WebSocket headers";
        return 400;
    }
    return 101;
}
