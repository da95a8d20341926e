/*
 * api_sse.h - GET /api/events: the event log as Server-Sent Events, from
 * the client's Last-Event-ID (or live), with a progress snapshot of every
 * printer with a job on each API tick (a keepalive comment when none).
 * The store is read on the API's reader thread (api_read.h), never on the
 * loop's connection.
 *
 * Thread: the loop thread.
 */
#ifndef SF_API_API_SSE_H
#define SF_API_API_SSE_H

#include "../farm/farm.h"
#include "api_read.h"
#include "http.h"

/* What the streams see of the API; lives as long as it (the API's). */
struct api_sse_env {
    struct api_read *reads; /* the reader */
    struct http *http;      /* the server the streams are on */
    struct farm *farm;      /* the printers (NULL: none) */
    unsigned tick;          /* the API's tick count: a stream sends progress when it moves */
};

/* Answer resp with a stream (deferred: the newest event's id is read on the reader). */
void api_sse_open(struct api_sse_env *env, const struct http_req *req, struct http_resp *resp);

#endif
