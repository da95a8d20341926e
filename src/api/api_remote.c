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

#include "../base/clock.h"
#include "../base/log.h"
#include "../base/mem.h"
#include "../farm/farm_host.h"
#include "../farm/farm_remote.h"
#include "../farm/store_command.h"

struct remote_wait {
    struct http_defer *d;
    char line[SF_COMMAND_MAX + 1]; /* a manual command's line, echoed in the answer ("": none) */
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
api_remote_answer(struct farm *f, const char *name, const char *kind, const char *line,
                  const char *who, struct http_defer *d)
{
    if (!farm_remote_is(f, name))
        return false;
    struct sf_err err;
    struct remote_wait *w = mem_calloc(1, sizeof(*w));
    if (w)
        w->d = d;
    int rc = w ? farm_remote_send(f, name, kind, line, who, on_answer, w, &err)
               : sf_err_set(&err, SF_ENOMEM, "printer %.64s: out of memory", name);
    if (rc == SF_OK)
        return true;
    free(w);
    struct http_resp resp = { .status = 200 };
    http_fail(&resp, rc, err.msg);
    http_defer_answer(d, &resp);
    return true;
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

/* A listing of the farm's printers waiting for the other hosts' from the store. */
struct listing {
    api_remote_local_fn local;
    void *ud;
    char me[STORE_HOST_NAME_MAX];
    char name[64]; /* one printer ("": all) */
    int64_t now_ms;
    bool own; /* name is this host's: only the beds to read */
    /* the reader's */
    struct store_command_printer *rows;
    size_t n;
    int rc;
    struct sf_err err;
    struct store_bed *beds;
    size_t n_beds;
    int beds_rc;
    struct sf_err beds_err;
};

/* Another host's printer p as GET /api/printers shows a printer. */
static json_t *
remote_json(const struct store_command_printer *p)
{
    char msg[160];
    if (p->live)
        snprintf(msg, sizeof(msg), "on host %s", p->host);
    else
        snprintf(msg, sizeof(msg), "host %s is down: its lease ran out %.0f s ago", p->host,
                 (double)(p->down_ms > 0 ? p->down_ms : 0) / 1000);
    double progress = p->job_id && p->gcode_lines > 0 ? (double)p->lines_acked / p->gcode_lines : 0;
    json_t *v = p->view[0] ? json_loads(p->view, 0, NULL) : NULL;
    if (json_is_object(v)) { /* as its owner published it: its temperatures, enabled, ... */
        const char *state = !p->live ? "offline" : p->state[0] ? p->state : "unknown";
        const char *own = json_string_value(json_object_get(v, "message"));
        json_object_update_new(v, json_pack("{ss ss sb ss sI sf ss sb sn sn}", "name", p->name,
                                            "host", p->host, "remote", true, "state", state,
                                            "job_id", (json_int_t)p->job_id, "progress",
                                            progress > 1 ? 1.0 : progress, "message",
                                            p->live && own && own[0] ? own : msg, "bed_full",
                                            p->bed_full, "interrupted_job", "last_print"));
        if (!p->live) { /* its host is down: nothing it published is current */
            json_object_set_new(v, "temps",
                                json_pack("{sfsfsfsf}", "nozzle_c", 0.0, "nozzle_target_c", 0.0,
                                          "bed_c", 0.0, "bed_target_c", 0.0));
            json_object_set_new(v, "time_left_s", json_null());
            json_object_set_new(v, "time_left_from", json_null());
        }
        return v;
    }
    json_decref(v);
    return json_pack("{ss ss sb ss sb ss sf s[fff] ss s{sfsfsfsf} sI sf ss sn sn sn sb sn sn}",
                     "name", p->name, "host", p->host, "remote", true, "state",
                     !p->live      ? "offline"
                     : p->state[0] ? p->state
                                   : "unknown",
                     "enabled", true, "material", "", "nozzle_mm", 0.0, "bed_mm", 0.0, 0.0, 0.0,
                     "group", "", "temps", "nozzle_c", 0.0, "nozzle_target_c", 0.0, "bed_c", 0.0,
                     "bed_target_c", 0.0, "job_id", (json_int_t)p->job_id, "progress",
                     progress > 1 ? 1.0 : progress, "message", msg, "time_left_s", "time_left_from",
                     "disabled_reason", "bed_full", p->bed_full, "interrupted_job", "last_print");
}

/* On the reader's thread. */
static void
listing_read(struct store *s, void *ud, struct http_resp *resp)
{
    (void)resp;
    struct listing *q = ud;
    q->beds_rc = store_beds(s, &q->beds, &q->n_beds, &q->beds_err);
    if (!q->own)
        q->rc = store_command_printers(s, q->me, q->now_ms, &q->rows, &q->n, &q->err);
}

/* Set "host" on the printer objects of arr (an array, or one object). */
static void
own_host(json_t *arr, const char *me)
{
    size_t i;
    json_t *p;
    if (json_is_object(arr))
        json_object_set_new(arr, "host", json_string(me));
    json_array_foreach(arr, i, p) json_object_set_new(p, "host", json_string(me));
}

/* On the loop: this host's printers, then the others'. */
static void
listing_finish(void *ud, struct http_resp *resp)
{
    struct listing *q = ud;
    if (q->beds_rc) /* the cards go without */
        log_warn("api", "printers: %s", q->beds_err.msg);
    if (q->own) {
        q->local(q->ud, q->name, q->beds, q->n_beds, resp);
        own_host(json_object_get(resp->json, "printer"), q->me);
        return;
    }
    if (q->rc)
        log_warn("api", "printers of the other hosts: %s", q->err.msg);
    if (q->name[0]) {
        for (size_t i = 0; i < q->n; i++)
            if (strcmp(q->rows[i].name, q->name) == 0) {
                resp->json = json_pack("{so}", "printer", remote_json(&q->rows[i]));
                return;
            }
        if (q->rc)
            http_fail(resp, q->rc, q->err.msg);
        else
            http_error(resp, 404, "no printer '%.64s'", q->name);
        return;
    }
    q->local(q->ud, NULL, q->beds, q->n_beds, resp);
    json_t *arr = json_object_get(resp->json, "printers");
    /* a printer this host's config lists but another live host owns is that host's row
       (this host never schedules on it, farm_host.h): listed once, as its owner shows it */
    for (size_t i = json_array_size(arr); i-- > 0;) {
        const char *name = json_string_value(json_object_get(json_array_get(arr, i), "name"));
        for (size_t k = 0; name && k < q->n; k++)
            if (strcmp(q->rows[k].name, name) == 0) {
                json_array_remove(arr, i);
                break;
            }
    }
    own_host(arr, q->me);
    for (size_t i = 0; arr && i < q->n; i++)
        json_array_append_new(arr, remote_json(&q->rows[i]));
}

static void
listing_free(void *ud)
{
    struct listing *q = ud;
    free(q->rows);
    free(q->beds);
    free(q);
}

bool
api_remote_printers(struct api_read *reads, struct farm *f, const char *name,
                    api_remote_local_fn local, void *ud, struct http_resp *resp)
{
    char me[STORE_HOST_NAME_MAX];
    if (!f || !farm_host_on(f) || !farm_host_reader(f, me, sizeof(me)) || !me[0])
        return false; /* not a host (or not joined yet: nothing of the farm is known) */
    struct listing *q = mem_calloc(1, sizeof(*q));
    if (!q) {
        http_error(resp, 500, "printers: out of memory");
        return true;
    }
    q->local = local;
    q->ud = ud;
    q->own = name && !farm_remote_is(f, name); /* this host's own: as before, with its name */
    snprintf(q->me, sizeof(q->me), "%s", me);
    snprintf(q->name, sizeof(q->name), "%s", name ? name : "");
    q->now_ms = clock_wall_ms();
    api_read_run(reads, resp, listing_read, listing_finish, q, listing_free);
    return true;
}
