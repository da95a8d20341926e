/*
 * drv_prusalink.c - Prusa printers through PrusaLink v1 (drv_prusalink.h).
 *
 * This part reads PrusaLink's replies: /api/v1/status (polled), /api/v1/job
 * and error bodies, checked against the OpenAPI specification
 * (prusa3d/Prusa-Link-Web spec/openapi.yaml, 1.0.0-draft, commit
 * 337fabbd) with a message naming the field that is wrong, and the
 * mapping of the printer states onto netjob's words.
 *
 * Thread: the parsers are pure; the driver runs on the loop thread.
 */
#include "drv_prusalink.h"

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
        sf_err_set(err, SF_EINVAL, "prusalink %s: not JSON: %s (line %d)", what, je.text, je.line);
    else if (!json_is_object(root)) {
        sf_err_set(err, SF_EINVAL, "prusalink %s: not an object", what);
        json_decref(root);
        root = NULL;
    }
    return root;
}

static int
get_str(json_t *obj, const char *key, const char *where, char *out, size_t n, bool required,
        struct sf_err *err)
{
    json_t *v = json_object_get(obj, key);
    out[0] = '\0';
    if (!v || json_is_null(v))
        return required ? sf_err_set(err, SF_EINVAL, "prusalink %s.%s: missing", where, key)
                        : SF_OK;
    if (!json_is_string(v))
        return sf_err_set(err, SF_EINVAL, "prusalink %s.%s: not a string", where, key);
    snprintf(out, n, "%s", json_string_value(v));
    return SF_OK;
}

static int
get_num(json_t *obj, const char *key, const char *where, double *out, bool required,
        struct sf_err *err)
{
    json_t *v = json_object_get(obj, key);
    if (!v || json_is_null(v))
        return required ? sf_err_set(err, SF_EINVAL, "prusalink %s.%s: missing", where, key)
                        : SF_OK;
    if (!json_is_number(v))
        return sf_err_set(err, SF_EINVAL, "prusalink %s.%s: not a number", where, key);
    *out = json_number_value(v);
    return SF_OK;
}

static int
get_int(json_t *obj, const char *key, const char *where, int64_t *out, bool required,
        struct sf_err *err)
{
    double d = (double)*out;
    int rc = get_num(obj, key, where, &d, required, err);
    if (rc == SF_OK && (d < 0 || d > 9.0e15))
        return sf_err_set(err, SF_EINVAL, "prusalink %s.%s: %g is out of range", where, key, d);
    *out = (int64_t)d;
    return rc;
}

static int
opt_obj(json_t *obj, const char *key, const char *where, json_t **out, struct sf_err *err)
{
    json_t *v = json_object_get(obj, key);
    *out = v && json_is_object(v) ? v : NULL;
    if (v && !json_is_null(v) && !*out)
        return sf_err_set(err, SF_EINVAL, "prusalink %s.%s: not an object", where, key);
    return SF_OK;
}

static int
percent(double *p, const char *where, struct sf_err *err)
{
    if (*p < 0 || *p > 100)
        return sf_err_set(err, SF_EINVAL, "prusalink %s.progress: %g is not a percentage", where,
                          *p);
    *p /= 100;
    return SF_OK;
}

/* ---- parsers ---- */

int
drv_prusalink_parse_status(const char *body, size_t len, struct prusalink_status *st,
                           struct sf_err *err)
{
    memset(st, 0, sizeof(*st));
    st->time_remaining_s = -1;
    json_t *root = load(body, len, "status", err);
    if (!root)
        return SF_EINVAL;
    int rc;
    json_t *pr, *job, *sto, *sp;
    if ((rc = opt_obj(root, "printer", "status", &pr, err)) ||
        (rc = opt_obj(root, "job", "status", &job, err)) ||
        (rc = opt_obj(root, "storage", "status", &sto, err)))
        goto out;
    if (!pr) { /* the one required member (StatusPrinter.state with it) */
        rc = sf_err_set(err, SF_EINVAL, "prusalink status.printer: missing");
        goto out;
    }
    if ((rc = get_str(pr, "state", "printer", st->state, sizeof(st->state), true, err)) ||
        (rc = get_num(pr, "temp_nozzle", "printer", &st->nozzle_c, false, err)) ||
        (rc = get_num(pr, "target_nozzle", "printer", &st->nozzle_target_c, false, err)) ||
        (rc = get_num(pr, "temp_bed", "printer", &st->bed_c, false, err)) ||
        (rc = get_num(pr, "target_bed", "printer", &st->bed_target_c, false, err)) ||
        (rc = opt_obj(pr, "status_printer", "printer", &sp, err)))
        goto out;
    if (sp) {
        json_t *ok = json_object_get(sp, "ok");
        if (ok && json_is_false(ok) &&
            (rc = get_str(sp, "message", "printer.status_printer", st->message, sizeof(st->message),
                          false, err)))
            goto out;
    }
    if (job) {
        st->has_job = true;
        double tr = -1;
        if ((rc = get_int(job, "id", "job", &st->job_id, false, err)) ||
            (rc = get_num(job, "progress", "job", &st->progress, false, err)) ||
            (rc = percent(&st->progress, "job", err)) ||
            (rc = get_num(job, "time_remaining", "job", &tr, false, err)))
            goto out;
        st->time_remaining_s = tr < 0 ? -1 : (int64_t)tr;
    }
    if (sto) {
        char path[64];
        json_t *ro = json_object_get(sto, "read_only");
        if ((rc = get_str(sto, "path", "storage", path, sizeof(path), true, err)))
            goto out;
        if (ro && !json_is_boolean(ro)) {
            rc = sf_err_set(err, SF_EINVAL, "prusalink storage.read_only: not a boolean");
            goto out;
        }
        st->read_only = ro && json_is_true(ro);
        /* "/usb/" -> "usb": the {storage} of /api/v1/files/{storage}/{path} */
        size_t k = 0;
        for (const char *c = path; *c && k + 1 < sizeof(st->storage); c++)
            if (*c != '/')
                st->storage[k++] = *c;
        st->storage[k] = '\0';
    }
    rc = SF_OK;
out:
    json_decref(root);
    return rc;
}

int
drv_prusalink_parse_job(const char *body, size_t len, struct prusalink_job *job, struct sf_err *err)
{
    memset(job, 0, sizeof(*job));
    json_t *root = load(body, len, "job", err);
    if (!root)
        return SF_EINVAL;
    int rc;
    json_t *file;
    if ((rc = get_int(root, "id", "job", &job->id, true, err)) ||
        (rc = get_str(root, "state", "job", job->state, sizeof(job->state), true, err)) ||
        (rc = get_num(root, "progress", "job", &job->progress, true, err)) ||
        (rc = percent(&job->progress, "job", err)) ||
        (rc = opt_obj(root, "file", "job", &file, err)))
        goto out;
    if (file) {
        if ((rc = get_str(file, "display_name", "job.file", job->name, sizeof(job->name), false,
                          err)) ||
            (!job->name[0] &&
             (rc = get_str(file, "name", "job.file", job->name, sizeof(job->name), true, err))) ||
            (rc = get_int(file, "size", "job.file", &job->size, false, err)))
            goto out;
    }
out:
    json_decref(root);
    return rc;
}

void
drv_prusalink_error_text(const char *body, size_t len, char *out, size_t n)
{
    out[0] = '\0';
    if (n == 0)
        return;
    json_t *root = json_loadb(body, len, 0, NULL);
    json_t *title = root ? json_object_get(root, "title") : NULL;
    json_t *text = root ? json_object_get(root, "text") : NULL;
    if (text && json_is_string(text)) {
        if (title && json_is_string(title) && json_string_length(title) > 0)
            snprintf(out, n, "%s: %s", json_string_value(title), json_string_value(text));
        else
            snprintf(out, n, "%s", json_string_value(text));
        json_decref(root);
        return;
    }
    json_decref(root);
    /* text/plain (the spec's default without Accept: application/json) */
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
drv_prusalink_observe(const struct prusalink_status *st, int64_t job_id, struct netjob_obs *o)
{
    static const struct {
        const char *name;
        enum netjob_remote r;
    } map[] = {
        { "IDLE", NETJOB_R_IDLE },     { "READY", NETJOB_R_IDLE },
        { "BUSY", NETJOB_R_BUSY },     { "PRINTING", NETJOB_R_PRINTING },
        { "PAUSED", NETJOB_R_PAUSED }, { "ATTENTION", NETJOB_R_PAUSED },
        { "FINISHED", NETJOB_R_DONE }, { "STOPPED", NETJOB_R_CANCELLED },
        { "ERROR", NETJOB_R_HALTED },
    };
    memset(o, 0, sizeof(*o));
    o->remote = NETJOB_R_BUSY; /* a state newer than this driver: send it nothing */
    for (size_t i = 0; i < sizeof(map) / sizeof(map[0]); i++)
        if (strcmp(st->state, map[i].name) == 0)
            o->remote = map[i].r;
    o->message = st->message;
    if (o->remote == NETJOB_R_PAUSED && strcmp(st->state, "ATTENTION") == 0 && !st->message[0])
        o->message = "the printer needs attention";
    if (o->remote == NETJOB_R_HALTED && !st->message[0])
        o->message = "the printer reports an error";
    o->ours = job_id > 0 &&
              ((st->has_job && st->job_id == job_id) ||
               (!st->has_job && (o->remote == NETJOB_R_DONE || o->remote == NETJOB_R_CANCELLED)));
}
