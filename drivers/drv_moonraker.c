/*
 * drv_moonraker.c - Klipper through Moonraker (drv_moonraker.h).
 *
 * This part reads Moonraker's replies: the object query the driver polls,
 * /server/info, the upload's answer and error bodies, each checked against
 * the documented shape (docs/external_api/ (server, printer, file_manager), docs/printer_objects.md
 * of Arksine/moonraker v0.10.0-31) with a message naming the field that is wrong, and the mapping
 * of Klipper's states onto netjob's words.
 *
 * Thread: the parsers are pure; the driver runs on the loop thread.
 */
#include "drv_moonraker.h"

#include <jansson.h>
#include <stdio.h>
#include <string.h>

/* ---- JSON helpers: field access that names what is wrong ---- */

static json_t *
load(const char *body, size_t len, const char *what, struct sf_err *err)
{
    json_error_t je;
    json_t *root = json_loadb(body, len, JSON_REJECT_DUPLICATES, &je);
    if (!root)
        sf_err_set(err, SF_EINVAL, "moonraker %s: not JSON: %s (line %d)", what, je.text, je.line);
    return root;
}

/* root.result if the reply is wrapped, else root. */
static json_t *
unwrap(json_t *root)
{
    json_t *r = json_object_get(root, "result");
    return r ? r : root;
}

static int
get_str(json_t *obj, const char *key, const char *where, char *out, size_t n, bool required,
        struct sf_err *err)
{
    json_t *v = json_object_get(obj, key);
    if (!v || json_is_null(v)) {
        out[0] = '\0';
        return required ? sf_err_set(err, SF_EINVAL, "moonraker %s.%s: missing", where, key)
                        : SF_OK;
    }
    if (!json_is_string(v))
        return sf_err_set(err, SF_EINVAL, "moonraker %s.%s: not a string", where, key);
    snprintf(out, n, "%s", json_string_value(v));
    return SF_OK;
}

static int
get_num(json_t *obj, const char *key, const char *where, double *out, struct sf_err *err)
{
    json_t *v = json_object_get(obj, key);
    if (!v || json_is_null(v))
        return SF_OK;
    if (!json_is_number(v))
        return sf_err_set(err, SF_EINVAL, "moonraker %s.%s: not a number", where, key);
    *out = json_number_value(v);
    return SF_OK;
}

static int
get_int(json_t *obj, const char *key, const char *where, int64_t *out, struct sf_err *err)
{
    double d = (double)*out;
    int rc = get_num(obj, key, where, &d, err);
    if (rc == SF_OK && (d < 0 || d > 9.0e15))
        return sf_err_set(err, SF_EINVAL, "moonraker %s.%s: %g is out of range", where, key, d);
    *out = (int64_t)d;
    return rc;
}

static int
get_bool(json_t *obj, const char *key, const char *where, bool *out, struct sf_err *err)
{
    json_t *v = json_object_get(obj, key);
    if (!v)
        return sf_err_set(err, SF_EINVAL, "moonraker %s.%s: missing", where, key);
    if (!json_is_boolean(v))
        return sf_err_set(err, SF_EINVAL, "moonraker %s.%s: not a boolean", where, key);
    *out = json_is_true(v);
    return SF_OK;
}

static json_t *
get_obj(json_t *obj, const char *key, const char *where, bool required, struct sf_err *err)
{
    json_t *v = json_object_get(obj, key);
    if (v && json_is_object(v))
        return v;
    if (v || required)
        sf_err_set(err, SF_EINVAL, "moonraker %s.%s: %s", where, key,
                   v ? "not an object" : "missing");
    return NULL;
}

/* status.key into *out if it is there (NULL if not); SF_EINVAL if it is not an object. */
static int
opt_obj(json_t *status, const char *key, json_t **out, struct sf_err *err)
{
    json_t *v = json_object_get(status, key);
    *out = v && json_is_object(v) ? v : NULL;
    if (v && !json_is_null(v) && !*out)
        return sf_err_set(err, SF_EINVAL, "moonraker status.%s: not an object", key);
    return SF_OK;
}

/* ---- parsers ---- */

int
drv_moonraker_parse_status(const char *body, size_t len, struct moonraker_status *st,
                           struct sf_err *err)
{
    memset(st, 0, sizeof(*st));
    json_t *root = load(body, len, "objects query", err);
    if (!root)
        return SF_EINVAL;
    int rc = SF_EINVAL;
    json_t *status = get_obj(unwrap(root), "status", "result", true, err);
    json_t *wh = status ? get_obj(status, "webhooks", "status", true, err) : NULL;
    json_t *ps = wh ? get_obj(status, "print_stats", "status", true, err) : NULL;
    if (!ps)
        goto out;
    if ((rc = get_str(wh, "state", "webhooks", st->klippy, sizeof(st->klippy), true, err)) ||
        (rc = get_str(wh, "state_message", "webhooks", st->klippy_message,
                      sizeof(st->klippy_message), false, err)) ||
        (rc = get_str(ps, "state", "print_stats", st->state, sizeof(st->state), true, err)) ||
        (rc = get_str(ps, "filename", "print_stats", st->filename, sizeof(st->filename), false,
                      err)) ||
        (rc =
             get_str(ps, "message", "print_stats", st->message, sizeof(st->message), false, err)) ||
        (rc = get_num(ps, "print_duration", "print_stats", &st->print_duration_s, err)))
        goto out;
    json_t *vs, *ex, *bed;
    if ((rc = opt_obj(status, "virtual_sdcard", &vs, err)) ||
        (rc = opt_obj(status, "extruder", &ex, err)) ||
        (rc = opt_obj(status, "heater_bed", &bed, err)))
        goto out;
    if (vs && ((rc = get_num(vs, "progress", "virtual_sdcard", &st->progress, err)) ||
               (rc = get_int(vs, "file_position", "virtual_sdcard", &st->file_position, err)) ||
               (rc = get_int(vs, "file_size", "virtual_sdcard", &st->file_size, err))))
        goto out;
    if (ex && ((rc = get_num(ex, "temperature", "extruder", &st->nozzle_c, err)) ||
               (rc = get_num(ex, "target", "extruder", &st->nozzle_target_c, err))))
        goto out;
    if (bed && ((rc = get_num(bed, "temperature", "heater_bed", &st->bed_c, err)) ||
                (rc = get_num(bed, "target", "heater_bed", &st->bed_target_c, err))))
        goto out;
    if (st->progress < 0 || st->progress > 1) {
        rc = sf_err_set(err, SF_EINVAL, "moonraker virtual_sdcard.progress: %g is not in 0..1",
                        st->progress);
        goto out;
    }
    rc = SF_OK;
out:
    json_decref(root);
    return rc;
}

int
drv_moonraker_parse_info(const char *body, size_t len, char *state, size_t n, struct sf_err *err)
{
    json_t *root = load(body, len, "server info", err);
    if (!root)
        return SF_EINVAL;
    json_t *res = json_object_get(root, "result");
    int rc = res && json_is_object(res)
                 ? get_str(res, "klippy_state", "result", state, n, true, err)
                 : sf_err_set(err, SF_EINVAL, "moonraker server info: no result object");
    json_decref(root);
    return rc;
}

int
drv_moonraker_parse_upload(const char *body, size_t len, struct moonraker_upload *up,
                           struct sf_err *err)
{
    memset(up, 0, sizeof(*up));
    json_t *root = load(body, len, "upload", err);
    if (!root)
        return SF_EINVAL;
    int rc = SF_EINVAL;
    json_t *r = unwrap(root);
    json_t *item = json_is_object(r) ? get_obj(r, "item", "upload", true, err) : NULL;
    if (!item) {
        if (!json_is_object(r))
            sf_err_set(err, SF_EINVAL, "moonraker upload: not an object");
        goto out;
    }
    if ((rc = get_str(item, "path", "item", up->path, sizeof(up->path), true, err)) ||
        (rc = get_int(item, "size", "item", &up->size, err)) ||
        (rc = get_bool(r, "print_started", "upload", &up->print_started, err)))
        goto out;
    /* print_queued came with the job queue (API 1.1); older servers lack it */
    if (json_object_get(r, "print_queued"))
        rc = get_bool(r, "print_queued", "upload", &up->print_queued, err);
out:
    json_decref(root);
    return rc;
}

void
drv_moonraker_error_text(const char *body, size_t len, char *out, size_t n)
{
    out[0] = '\0';
    if (n == 0)
        return;
    json_t *root = json_loadb(body, len, 0, NULL);
    json_t *e = root ? json_object_get(root, "error") : NULL;
    json_t *m = e ? json_object_get(e, "message") : NULL;
    if (m && json_is_string(m)) {
        snprintf(out, n, "%s", json_string_value(m));
        json_decref(root);
        return;
    }
    json_decref(root);
    /* not the documented shape (a proxy's page): its first non-blank line */
    size_t i = 0;
    while (i < len && (body[i] == ' ' || body[i] == '\n' || body[i] == '\r' || body[i] == '\t'))
        i++;
    size_t k = 0;
    for (; i < len && body[i] != '\n' && body[i] != '\r' && k + 1 < n; i++)
        out[k++] = (unsigned char)body[i] < 0x20 ? ' ' : body[i];
    while (k > 0 && out[k - 1] == ' ')
        k--;
    out[k] = '\0';
}

void
drv_moonraker_observe(const struct moonraker_status *st, const char *job_name, int64_t job_size,
                      struct netjob_obs *o)
{
    memset(o, 0, sizeof(*o));
    o->file = st->filename;
    o->message = st->message;
    o->ours = job_name && job_name[0] && strcmp(st->filename, job_name) == 0 &&
              (job_size <= 0 || st->file_size == 0 || st->file_size == job_size);
    if (strcmp(st->klippy, "ready") != 0) {
        /* startup, shutdown, error (and anything newer): the host first */
        o->message = st->klippy_message;
        o->remote = strcmp(st->klippy, "startup") == 0 ? NETJOB_R_STARTING : NETJOB_R_HALTED;
        return;
    }
    static const struct {
        const char *name;
        enum netjob_remote r;
    } map[] = {
        { "standby", NETJOB_R_IDLE },        { "printing", NETJOB_R_PRINTING },
        { "paused", NETJOB_R_PAUSED },       { "complete", NETJOB_R_DONE },
        { "cancelled", NETJOB_R_CANCELLED }, { "error", NETJOB_R_FAILED },
    };
    o->remote = NETJOB_R_BUSY; /* a state newer than this driver: send it nothing */
    for (size_t i = 0; i < sizeof(map) / sizeof(map[0]); i++)
        if (strcmp(st->state, map[i].name) == 0)
            o->remote = map[i].r;
}
