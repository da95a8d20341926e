/*
 * route.c - the one dispatcher over the route table (see route.h).
 *
 * Why a table: the routes used to be four routers in turn (api_compat's,
 * web's, then api.c's if-chains), each deciding 404 and 405 its own way.
 * As rows, what each path takes (methods, body, key) reads in one place
 * and the dispatcher decides 404/405 once.
 *
 * Every request that may change something (any method but GET/HEAD) is
 * logged once answered, with its key's label, so the log says who did it.
 *
 * Thread: the thread that runs http_run().
 */
#include "route.h"

#include <stdio.h>
#include <string.h>

#include "../base/log.h"

const char *
route_clip(char *out, size_t cap, const char *s)
{
    size_t n = strlen(s);
    if (n >= cap) {
        n = cap - 1;
        while (n > 0 && ((unsigned char)s[n] & 0xc0) == 0x80)
            n--; /* s[n] continues a character: cut before its lead byte */
    }
    memcpy(out, s, n);
    out[n] = '\0';
    return out;
}

static unsigned
method_bit(const char *m)
{
    static const char *const names[] = { "GET", "HEAD", "POST", "PATCH" };
    for (unsigned i = 0; i < sizeof(names) / sizeof(names[0]); i++)
        if (strcmp(m, names[i]) == 0)
            return 1u << i;
    return ROUTE_OTHER;
}

bool
route_num(const char *s, size_t n, int64_t *out)
{
    if (n == 0 || n > 18)
        return false;
    int64_t v = 0;
    for (size_t i = 0; i < n; i++) {
        if (s[i] < '0' || s[i] > '9')
            return false;
        v = v * 10 + (s[i] - '0');
    }
    *out = v;
    return true;
}

/* Copy segment [s, s+n) into out (cap bytes with the NUL); false if too long. */
static bool
take(char *out, size_t cap, const char *s, size_t n)
{
    if (n >= cap)
        return false;
    memcpy(out, s, n);
    out[n] = '\0';
    return true;
}

/* path against pattern, filling a; false if it does not match. */
static bool
match(const char *pattern, const char *path, struct route_args *a)
{
    const char *p = pattern, *s = path;
    while (*p) {
        if (*p != '{') {
            if (*p++ != *s++)
                return false;
            continue;
        }
        const char *close = strchr(p, '}');
        size_t pl = (size_t)(close - p) + 1;
        if (strncmp(p, "{*}", pl) == 0) {
            a->rest = s;
            return true;
        }
        size_t n = strcspn(s, "/");
        bool ok = strncmp(p, "{id}", pl) == 0     ? route_num(s, n, &a->id) && a->id > 0
                  : strncmp(p, "{name}", pl) == 0 ? n > 0 && take(a->name, sizeof(a->name), s, n)
                  : strncmp(p, "{action}", pl) == 0
                      ? n > 0 && take(a->action, sizeof(a->action), s, n)
                      : false;
        if (!ok)
            return false;
        p += pl;
        s += n;
    }
    return *s == '\0';
}

static bool
row_matches(const struct route *r, const char *path, struct route_args *a)
{
    memset(a, 0, sizeof(*a));
    return r->match ? r->match(path) : match(r->pattern, path, a);
}

void
route_key_label(const struct http_req *req, char *out, size_t n)
{
    if (!req->key || !req->key[0]) {
        snprintf(out, n, "no key");
        return;
    }
    /* FNV-1a: a name that tells keys apart in logs, not a way back to one */
    uint32_t h = 2166136261u;
    for (const unsigned char *c = (const unsigned char *)req->key; *c; c++)
        h = (h ^ *c) * 16777619u;
    snprintf(out, n, "key %08x", (unsigned)h);
}

static void
dispatch(const struct route_group *groups, size_t n_groups, const struct http_req *req,
         struct http_resp *resp)
{
    unsigned m = method_bit(req->method), allow = 0;
    const struct route *known = NULL; /* the first row of the path, for its 405 */
    struct route_args a;
    char clipped[101];
    for (size_t g = 0; g < n_groups; g++)
        for (size_t i = 0; i < groups[g].n; i++) {
            const struct route *r = &groups[g].rows[i];
            if (!row_matches(r, req->path, &a))
                continue;
            if (!(r->methods & m)) {
                if (r->not_allowed && !known)
                    known = r;
                allow |= r->not_allowed ? r->methods : 0;
                continue;
            }
            if (r->scope == ROUTE_WRITE && req->read_only) {
                http_error(resp, 403, "read-only API key: %s is not allowed", req->method);
                return;
            }
            r->fn(groups[g].ctx, &a, req, resp);
            return;
        }
    if (!known) {
        http_error(resp, 404, "no such resource: %s",
                   route_clip(clipped, sizeof(clipped), req->path));
        return;
    }
    static const char *const names[] = { "GET", "HEAD", "POST", "PATCH" };
    char list[40] = "";
    for (unsigned i = 0; i < sizeof(names) / sizeof(names[0]); i++)
        if (allow & (1u << i))
            snprintf(list + strlen(list), sizeof(list) - strlen(list), "%s%s", list[0] ? ", " : "",
                     names[i]);
    http_resp_header(resp, "Allow", "%s", list);
    if (known->not_allowed[0])
        http_error(resp, 405, "%s", known->not_allowed);
    else
        http_error(resp, 405, "method %s is not allowed on %s", req->method,
                   route_clip(clipped, sizeof(clipped), req->path));
}

void
route_dispatch(const struct route_group *groups, size_t n_groups, const struct http_req *req,
               struct http_resp *resp)
{
    dispatch(groups, n_groups, req, resp);
    if (strcmp(req->method, "GET") == 0 || strcmp(req->method, "HEAD") == 0)
        return;
    /* Who changed what: every other method is logged with its key's label
       (never the key), whatever came of it. */
    char label[32], clipped[101];
    route_key_label(req, label, sizeof(label));
    route_clip(clipped, sizeof(clipped), req->path);
    if (resp->defer) { /* its status is logged when it goes out */
        char line[192];
        snprintf(line, sizeof(line), "%s %s by %s", req->method, clipped, label);
        http_defer_audit(resp->defer, line);
    } else
        log_info("api", "%s %s by %s: %d", req->method, clipped, label, resp->status);
}

enum http_body
route_body(const struct route_group *groups, size_t n_groups, const char *method, const char *path)
{
    unsigned m = method_bit(method);
    struct route_args a;
    for (size_t g = 0; g < n_groups; g++)
        for (size_t i = 0; i < groups[g].n; i++) {
            const struct route *r = &groups[g].rows[i];
            if ((r->methods & m) && row_matches(r, path, &a))
                return r->body;
        }
    return HTTP_BODY_NONE;
}
