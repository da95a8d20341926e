/*
 * http_frame.c - request framing checks libmicrohttpd 0.9.75 lacks.
 *
 * What MHD 0.9.75 does itself (read from its connection.c): with
 * Transfer-Encoding present it ignores Content-Length (any TE value other
 * than "chunked" reads the body until the client closes); a space or tab
 * before a header's colon stays in the name, so "Transfer-Encoding :
 * chunked" is a header nobody asks for, and the body is framed by
 * Content-Length instead (its check for this runs only at
 * MHD_OPTION_STRICT_FOR_CLIENT -1, the permissive level, an inverted test;
 * level 1 adds only a Host check and spaces in the URL); a folded line
 * (obs-fold) is appended to the header's *name*, not its value, so the
 * header vanishes under another name; a line ends at CRLF or a bare LF,
 * and a NUL ends the value MHD reports (the rest of the line is dropped).
 * A proxy in front that reads any of these the other way (RFC 7230 3.3.3,
 * 3.2.4) frames a different request than ours: the smuggling of issue 30.
 *
 * No raw bytes are needed: MHD 0.9.x parses the head in place and each
 * header's name and value point into the line they came from, the colon
 * and the line end overwritten with NUL.  So a value must sit just after
 * its name (a folded header's name was moved, which shows), and the byte
 * after a value's end must be the NUL that replaced the LF of a CRLF (a
 * NUL inside the value, or a bare LF, leaves another byte there).  These
 * two checks hold for MHD's 0.9 parser only and are skipped with another
 * version; the name, value and Transfer-Encoding checks hold for any.
 *
 * Thread: whichever thread calls http_run().
 */
#include "http_frame.h"

#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <strings.h>

struct scan {
    bool in_place; /* MHD's 0.9 parser: names and values point into the head */
    int status;    /* refusal found, 0 if none */
    char *msg;     /* its message */
    size_t cap;    /* msg's size */
    unsigned n_te; /* Transfer-Encoding headers */
    bool chunked;  /* the (last) one says chunked */
    bool has_cl;   /* a Content-Length header */
};

static bool
is_tchar(unsigned char c)
{
    /* RFC 7230 3.2.6 token characters */
    return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') ||
           (c && strchr("!#$%&'*+-.^_`|~", c));
}

/* name, cut to 40 bytes and stripped of control bytes, for a message. */
static void
printable(char *out, size_t cap, const char *s, size_t n)
{
    size_t o = 0;
    for (size_t i = 0; i < n && o + 4 < cap && i < 40; i++) {
        unsigned char c = (unsigned char)s[i];
        if (c < 0x20 || c == 0x7f)
            o += (size_t)snprintf(out + o, cap - o, "\\x%02x", c);
        else
            out[o++] = (char)c;
    }
    out[o] = '\0';
}

static enum MHD_Result
refuse(struct scan *sc, int status, const char *what, const char *key, size_t key_size)
{
    char name[200];
    printable(name, sizeof(name), key, key_size);
    snprintf(sc->msg, sc->cap, "header '%s': %s", name, what);
    sc->status = status;
    return MHD_NO;
}

/* One line of the head as MHD parsed it in place: "NAME:<ws>VALUE\r\n". */
static bool
parsed_from_one_line(const char *key, size_t key_size, const char *value, size_t value_size)
{
    uintptr_t k = (uintptr_t)key, v = (uintptr_t)value;
    if (v <= k + key_size || key[key_size] != '\0')
        return false;
    for (const char *p = key + key_size + 1; p < value; p++)
        if (*p != ' ' && *p != '\t')
            return false;
    /* value[value_size] is the CR's NUL, the next byte the LF's */
    return value[value_size] == '\0' && value[value_size + 1] == '\0';
}

static enum MHD_Result
check_header(void *cls, enum MHD_ValueKind kind, const char *key, size_t key_size,
             const char *value, size_t value_size)
{
    (void)kind;
    struct scan *sc = cls;
    if (!key_size)
        return refuse(sc, MHD_HTTP_BAD_REQUEST, "a header line without a name", key, 0);
    for (size_t i = 0; i < key_size; i++)
        if (!is_tchar((unsigned char)key[i]))
            return refuse(sc, MHD_HTTP_BAD_REQUEST,
                          "the name holds a character that is not allowed (whitespace before "
                          "the colon, or a folded line)",
                          key, key_size);
    for (size_t i = 0; value && i < value_size; i++) {
        unsigned char c = (unsigned char)value[i];
        if ((c < 0x20 && c != '\t') || c == 0x7f)
            return refuse(sc, MHD_HTTP_BAD_REQUEST, "the value holds a control byte", key,
                          key_size);
    }
    if (sc->in_place && value && !parsed_from_one_line(key, key_size, value, value_size))
        return refuse(sc, MHD_HTTP_BAD_REQUEST,
                      "a folded line (obs-fold), a NUL in the value, or a line not ended by CRLF",
                      key, key_size);
    if (strcasecmp(key, MHD_HTTP_HEADER_TRANSFER_ENCODING) == 0) {
        sc->n_te++;
        sc->chunked = value && strcasecmp(value, "chunked") == 0;
    } else if (strcasecmp(key, MHD_HTTP_HEADER_CONTENT_LENGTH) == 0) {
        sc->has_cl = true;
    }
    return MHD_YES;
}

int
http_frame_check(struct MHD_Connection *conn, char *msg, size_t cap)
{
    struct scan sc = { .msg = msg, .cap = cap };
    const char *v = MHD_get_version();
    sc.in_place = v && strncmp(v, "0.9.", 4) == 0;
    MHD_get_connection_values_n(conn, MHD_HEADER_KIND, check_header, &sc);
    if (sc.status)
        return sc.status;
    if (sc.n_te && sc.has_cl) {
        snprintf(msg, cap, "Transfer-Encoding together with Content-Length");
        return MHD_HTTP_BAD_REQUEST;
    }
    if (sc.n_te > 1) {
        snprintf(msg, cap, "more than one Transfer-Encoding header");
        return MHD_HTTP_BAD_REQUEST;
    }
    if (sc.n_te && !sc.chunked) {
        snprintf(msg, cap, "Transfer-Encoding other than 'chunked' is not supported");
        return MHD_HTTP_NOT_IMPLEMENTED;
    }
    return 0;
}
