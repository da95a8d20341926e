/*
 * test_route.c - the route table's dispatcher without a server: patterns
 * and their placeholders, first match wins, 405 with Allow and the row's
 * message for a known path, 404 for the rest (and for rows unknown to
 * other methods), the body a head may carry, a read-only key on a
 * read-write row.
 */
#include <string.h>

#include "../../src/api/route.h"
#include "../t.h"

static char seen[128]; /* what the last handler saw */

static void
h_id(void *ctx, const struct route_args *a, const struct http_req *req, struct http_resp *resp)
{
    (void)ctx, (void)req, (void)resp;
    snprintf(seen, sizeof(seen), "id %lld", (long long)a->id);
}

static void
h_act(void *ctx, const struct route_args *a, const struct http_req *req, struct http_resp *resp)
{
    (void)ctx, (void)req, (void)resp;
    snprintf(seen, sizeof(seen), "%s %s %s", (const char *)ctx, a->name, a->action);
}

static void
h_rest(void *ctx, const struct route_args *a, const struct http_req *req, struct http_resp *resp)
{
    (void)ctx, (void)req, (void)resp;
    snprintf(seen, sizeof(seen), "rest '%s'", a->rest ? a->rest : "-");
}

static bool
is_file(const char *path)
{
    return strcmp(path, "/app.js") == 0;
}

#define ROW(methods, pattern, body, scope, fn, not_allowed)                                        \
    {                                                                                              \
        methods, pattern, NULL, body, scope, fn, not_allowed                                       \
    }
#define RW ROUTE_WRITE

static const struct route rows[] = {
    { ROUTE_GET | ROUTE_HEAD, NULL, is_file, HTTP_BODY_NONE, ROUTE_PUBLIC, h_rest, "use GET" },
    ROW(ROUTE_GET, "/api/jobs/{id}", HTTP_BODY_NONE, ROUTE_READ, h_id, ROUTE_405),
    ROW(ROUTE_PATCH, "/api/jobs/{id}", HTTP_BODY_JSON, RW, h_id, ROUTE_405),
    ROW(ROUTE_POST, "/api/printers/{name}/command", HTTP_BODY_JSON, RW, h_act, ROUTE_405),
    ROW(ROUTE_POST, "/api/printers/{name}/{action}", HTTP_BODY_NONE, RW, h_act, ROUTE_405),
    ROW(ROUTE_POST, "/files/{*}", HTTP_BODY_UPLOAD, RW, h_rest, "use POST"),
    ROW(ROUTE_GET, "/version", HTTP_BODY_NONE, ROUTE_READ, h_rest, NULL),
};

static const struct route_group group = { rows, sizeof(rows) / sizeof(rows[0]), "ctx" };

/* Dispatch method path; the status (200 if a handler ran), its error text into msg. */
static int
go(const char *method, const char *path, bool read_only, char *msg, size_t cap)
{
    struct http_req req = { .method = method, .path = path, .read_only = read_only };
    struct http_resp resp = { .status = 200 };
    seen[0] = msg[0] = '\0';
    route_dispatch(&group, 1, &req, &resp);
    const char *e = json_string_value(json_object_get(resp.json, "error"));
    snprintf(msg, cap, "%s", e ? e : "");
    for (size_t i = 0; i < resp.n_headers; i++)
        if (strcmp(resp.headers[i].name, "Allow") == 0)
            snprintf(msg + strlen(msg), cap - strlen(msg), " [Allow: %s]", resp.headers[i].value);
    json_decref(resp.json);
    return resp.status;
}

/* One request and what it must come to: its status, and what the handler
   saw (200) or the error with its Allow header. */
struct want {
    const char *method, *path;
    bool read_only;
    int status;
    const char *said;
};

static void
check(const struct want *w, size_t n)
{
    char msg[256];
    for (size_t i = 0; i < n; i++) {
        int st = go(w[i].method, w[i].path, w[i].read_only, msg, sizeof(msg));
        const char *said = st == 200 ? seen : msg;
        if (st != w[i].status || strcmp(said, w[i].said) != 0)
            t_fail(__FILE__, __LINE__, "%s %s: %d '%s', want %d '%s'", w[i].method, w[i].path, st,
                   said, w[i].status, w[i].said);
    }
}

T_CASE(route_placeholders_first_match_404_405)
{
    static const struct want w[] = {
        { "GET", "/api/jobs/12", false, 200, "id 12" },
        { "PATCH", "/api/jobs/7", false, 200, "id 7" },
        { "POST", "/api/printers/mk3/command", false, 200, "ctx mk3 " },
        { "POST", "/api/printers/mk3/pause", false, 200, "ctx mk3 pause" },
        { "POST", "/files/job-1/a.gcode", false, 200, "rest 'job-1/a.gcode'" },
        { "POST", "/files/", false, 200, "rest ''" },
        { "HEAD", "/app.js", false, 200, "rest '-'" },
        /* unknown paths are 404, known ones asked with another method 405 */
        { "GET", "/api/jobs/0", false, 404, "no such resource: /api/jobs/0" },
        { "GET", "/api/jobs/x1", false, 404, "no such resource: /api/jobs/x1" },
        { "GET", "/api/jobs/12/", false, 404, "no such resource: /api/jobs/12/" },
        { "GET", "/api/jobs/1234567890123456789", false, 404,
          "no such resource: /api/jobs/1234567890123456789" },
        { "POST", "/api/printers//go", false, 404, "no such resource: /api/printers//go" },
        { "POST", "/api/printers/a/b/c", false, 404, "no such resource: /api/printers/a/b/c" },
        /* a segment longer than its placeholder takes */
        { "POST", "/api/printers/a/averyveryverylongaction", false, 404,
          "no such resource: /api/printers/a/averyveryverylongaction" },
        { "DELETE", "/api/jobs/3", false, 405,
          "method DELETE is not allowed on /api/jobs/3 [Allow: GET, PATCH]" },
        { "POST", "/app.js", false, 405, "use GET [Allow: GET, HEAD]" },
        { "GET", "/files/x", false, 405, "use POST [Allow: POST]" },
        /* a row unknown to other methods */
        { "POST", "/version", false, 404, "no such resource: /version" },
        /* a read-only key on a read-write row */
        { "PATCH", "/api/jobs/3", true, 403, "read-only API key: PATCH is not allowed" },
    };
    check(w, sizeof(w) / sizeof(w[0]));
}

T_CASE(route_body_from_the_head)
{
    T_EQ_INT(route_body(&group, 1, "PATCH", "/api/jobs/3"), HTTP_BODY_JSON);
    T_EQ_INT(route_body(&group, 1, "GET", "/api/jobs/3"), HTTP_BODY_NONE);
    T_EQ_INT(route_body(&group, 1, "POST", "/files/a"), HTTP_BODY_UPLOAD);
    T_EQ_INT(route_body(&group, 1, "GET", "/files/a"), HTTP_BODY_NONE);
    T_EQ_INT(route_body(&group, 1, "POST", "/api/printers/a/command"), HTTP_BODY_JSON);
    T_EQ_INT(route_body(&group, 1, "POST", "/api/printers/a/pause"), HTTP_BODY_NONE);
    T_EQ_INT(route_body(&group, 1, "POST", "/elsewhere"), HTTP_BODY_NONE);
}
