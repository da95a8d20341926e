/*
 * api_remote.c - actions on printers other hosts own (api_remote.h).
 *
 * A request waits, suspended (http_defer), while the command goes to the
 * owner on the farm's store thread and back: the loop goes on.  The
 * waiting struct holds no pointer into the API, so an answer that comes
 * after api_free (the farm stops after the API) is safe: http.c drops it.
 *
 * Thread: the loop thread.
 */
#include "api_remote.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"
#include "../farm/farm_remote.h"

struct remote_wait {
    struct http_defer *d;
    char line[256]; /* a manual command's line, echoed in the answer ("": none) */
};

static void
on_answer(void *ud, const struct farm_remote_result *r)
{
    struct remote_wait *w = ud;
    struct http_resp resp = { .status = 200 };
    if (r->rc == SF_ETIMEDOUT) {
        http_error(&resp, 504, "%s", r->err->msg);
    } else if (r->rc) {
        http_fail(&resp, r->rc, r->err->msg);
    } else {
        resp.json = json_pack("{s{ss ss ss}}", "printer", "name", r->printer, "host", r->host,
                              "state", r->state);
        if (resp.json && w->line[0])
            json_object_set_new(resp.json, "command", json_string(w->line));
    }
    http_defer_answer(w->d, &resp);
    free(w);
}

bool
api_remote_try(struct farm *f, const char *name, const char *kind, const char *line,
               const char *who, struct http_resp *resp)
{
    if (!farm_remote_is(f, name))
        return false;
    struct sf_err err;
    struct remote_wait *w = mem_calloc(1, sizeof(*w));
    if (!w || !(w->d = http_defer(resp))) {
        free(w);
        http_error(resp, 500, "printer %.64s: out of memory", name);
        return true;
    }
    snprintf(w->line, sizeof(w->line), "%s", line ? line : "");
    int rc = farm_remote_send(f, name, kind, line, who, on_answer, w, &err);
    if (rc) { /* refused now: answered now */
        free(resp->defer);
        resp->defer = NULL;
        free(w);
        http_fail(resp, rc, err.msg);
    }
    return true;
}
