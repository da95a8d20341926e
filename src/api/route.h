/*
 * route.h - the HTTP routes as one table and the one dispatcher over it.
 *
 * A route is a row: the methods it answers, a path pattern, the body it
 * takes, the key scope it needs and its handler.  The modules that answer
 * requests (api.c, api_compat.c, web.c) each keep their handlers and
 * export their rows; api.c lists the groups in order and every request
 * goes through route_dispatch(), and every request head through
 * route_body().  The first row whose pattern and method match answers.
 *
 * Patterns are literal text with placeholders that each take one whole
 * path segment (slashes are matched exactly, so "/metrics/" is not
 * "/metrics"):
 *   {id}      a job id: 1 to 18 decimal digits, above 0    -> args.id
 *   {name}    a printer name, under 64 bytes              -> args.name
 *   {action}  an action word, under 16 bytes              -> args.action
 *   {*}       the rest of the path, maybe empty, last only -> args.rest
 * A segment too long for its placeholder does not match (404).
 *
 * A known path asked with a method no row of it takes answers 405 with an
 * Allow header naming the methods that would do, and the row's
 * not_allowed message; a row whose not_allowed is NULL is unknown to other
 * methods (404), as the OctoPrint and Moonraker read-only answers are.
 *
 * Every request but GET/HEAD is logged once answered: method, path, the
 * key's label (route_key_label, never the key) and the status.
 *
 * Scope: ROUTE_WRITE rows need a read-write key; http.c already refused a
 * read-only key on anything but GET/HEAD before the body (it must decide
 * from the head alone), and the dispatcher checks the row's scope again.
 *
 * Thread: the thread that runs http_run().
 */
#ifndef SF_API_ROUTE_H
#define SF_API_ROUTE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "http.h"

/* Methods, as a row's mask. */
enum {
    ROUTE_GET = 1 << 0,
    ROUTE_HEAD = 1 << 1,
    ROUTE_POST = 1 << 2,
    ROUTE_PATCH = 1 << 3,
    ROUTE_OTHER = 1 << 4, /* any method not named above (PUT, DELETE ...) */
    ROUTE_ANY = 0x1f,
};

/* The key a row needs. */
enum route_scope {
    ROUTE_PUBLIC, /* none (the dashboard's static files) */
    ROUTE_READ,   /* any key: read-only, read-write (and a metrics key for GET /metrics) */
    ROUTE_WRITE,  /* a read-write key */
};

/* What a matched path's placeholders held. */
struct route_args {
    int64_t id;       /* {id} */
    char name[64];    /* {name} */
    char action[16];  /* {action} */
    const char *rest; /* {*}: points into the request's path */
};

typedef void (*route_fn)(void *ctx, const struct route_args *args, const struct http_req *req,
                         struct http_resp *resp);

/* Generic 405 text for not_allowed: "method M is not allowed on PATH". */
#define ROUTE_405 ""

struct route {
    unsigned methods;                /* ROUTE_GET | ... */
    const char *pattern;             /* "/api/jobs/{id}/cancel" */
    bool (*match)(const char *path); /* or NULL: instead of pattern (a list of files) */
    enum http_body body;             /* what its requests may carry */
    enum route_scope scope;          /* the key it needs */
    route_fn fn;                     /* the handler */
    const char *not_allowed; /* 405 message for other methods; ROUTE_405 generic; NULL: 404 */
};

/* One module's rows and the ctx their handlers take. */
struct route_group {
    const struct route *rows;
    size_t n;
    void *ctx;
};

/*
 * Answer req from the first matching row of the groups, in order; 405 or
 * 404 ("no such resource: PATH") when none matches.
 */
void route_dispatch(const struct route_group *groups, size_t n_groups, const struct http_req *req,
                    struct http_resp *resp);

/* The body the row for method and path takes; HTTP_BODY_NONE if none matches. */
enum http_body route_body(const struct route_group *groups, size_t n_groups, const char *method,
                          const char *path);

/* The decimal number >= 0 of 1 to 18 digits that is all of [s, s+n), into
 *out; false if it is not one. */
bool route_num(const char *s, size_t n, int64_t *out);

/* The label of the request's key for logs and notes, "key 1a2b3c4d" (a
   hash: never the key), or "no key". */
void route_key_label(const struct http_req *req, char *out, size_t n);

/* s cut to fit out (cap bytes with the NUL) between UTF-8 characters, for
   quoting client text in a message.  Returns out. */
const char *route_clip(char *out, size_t cap, const char *s);

#endif
