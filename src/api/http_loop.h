/*
 * http_loop.h - run an http server (http.h) on the event loop (loop.h):
 * its epoll fd is watched for reading and MHD's timeout is a loop timer.
 *
 * Kept apart from http.c so that http.c needs no loop (tests drive it with
 * epoll_wait) and the loop binding is one small, obvious file.
 *
 * Thread: the loop thread.
 */
#ifndef SF_API_HTTP_LOOP_H
#define SF_API_HTTP_LOOP_H

#include "../base/err.h"
#include "../base/loop.h"
#include "http.h"

struct http_loop;

/* Watch h on l; NULL with err set.  h must outlive the binding. */
struct http_loop *http_loop_attach(struct loop *l, struct http *h, struct sf_err *err);
/* Stop watching (before http_free). */
void http_loop_detach(struct http_loop *hl);
/* Run MHD now and re-arm its timer. */
void http_loop_kick(struct http_loop *hl);

#endif
