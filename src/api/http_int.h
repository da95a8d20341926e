/*
 * http_int.h - internal to the http module (http.c, http_resp.c): how an
 * answer is sent on an MHD connection.  Nothing outside src/api/http*.c
 * includes it.
 *
 * Thread: whichever thread calls http_run().
 */
#ifndef SF_API_HTTP_INT_H
#define SF_API_HTTP_INT_H

#include <jansson.h>
#include <microhttpd.h>
#include <stdbool.h>

#include "http.h"

/* Queue j (the reference is taken) as the JSON answer; close: end the
   connection after it. */
enum MHD_Result http_send_json(struct MHD_Connection *conn, int status, json_t *j, bool close);
/* {"error": msg}; a 400, 401, 501 or 503 closes the connection. */
enum MHD_Result http_send_error(struct MHD_Connection *conn, int status, const char *msg);
/* A route's raw body (resp->body, freed by body_free) or open file (resp->fd, closed). */
enum MHD_Result http_send_raw(struct MHD_Connection *conn, struct http_resp *resp);
/* Put the route's extra headers on r. */
void http_add_headers(struct MHD_Response *r, const struct http_resp *resp);
/* Free what a route answered without sending it. */
void http_resp_discard(struct http_resp *resp);

#endif
