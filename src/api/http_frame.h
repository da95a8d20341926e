/*
 * http_frame.h - internal to the http module: the request head checks
 * that keep a request framed one way only (no smuggling through a proxy
 * that reads it another way), which libmicrohttpd 0.9.75 does not make.
 *
 * Refused, each answered 400 with the connection closed: Transfer-Encoding
 * together with Content-Length, more than one Transfer-Encoding, a header
 * line folded onto the next (obs-fold), a header name that is not a token
 * (whitespace before its colon, say), and control bytes in a header value
 * (NUL, a CR or LF left over from a line end, any other C0 byte but HTAB,
 * DEL).  A Transfer-Encoding other than "chunked" is answered 501.
 *
 * Thread: whichever thread calls http_run().
 */
#ifndef SF_API_HTTP_FRAME_H
#define SF_API_HTTP_FRAME_H

#include <microhttpd.h>
#include <stddef.h>

/*
 * Check the request head of conn (call from the access handler's first
 * call).  0 if it is framed cleanly, else the HTTP status to refuse it
 * with and a message in msg (cap bytes).
 */
int http_frame_check(struct MHD_Connection *conn, char *msg, size_t cap);

#endif
