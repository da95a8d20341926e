/*
 * api_json.c - strict JSON in, plain JSON out, for the REST API.
 *
 * Why a module of its own: it is the part of the API that takes arbitrary
 * bytes from clients, so it is small, pure and fuzzed on its own
 * (tests/fuzz/fuzz_apijson.c).  Design: a table of option fields (name,
 * type, where it goes) drives parsing, so an unknown field, a wrong type
 * and an out-of-range value each get one clear message; range checks are
 * job_opts_validate()'s, shared with the store.  jansson is told to refuse
 * duplicate keys and stray bytes after the object.
 *
 * Thread: any; no state.
 */
#include "api_json.h"

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "../base/gcode.h"
#include "../base/limits.h"
#include "../farm/farm.h"

enum ftype { F_STR, F_DBL, F_INT };

/* One accepted option field. */
struct field {
    const char *name; /* JSON key */
    enum ftype type;  /* expected JSON type */
    size_t off;       /* offset in struct job_opts */
    size_t size;      /* F_STR: buffer size */
};

#define O(f) offsetof(struct job_opts, f), sizeof(((struct job_opts *)0)->f)

static const struct field fields[] = {
    { "method", F_STR, O(method) },
    { "deviation_mm", F_DBL, O(deviation_mm) },
    { "overhang_deg", F_DBL, O(overhang_deg) },
    { "copies", F_INT, O(copies) },
    { "max_retries", F_INT, O(max_retries) },
    { "material", F_STR, O(material) },
    { "printer", F_STR, O(printer) },
    { "group", F_STR, O(group) },
    { "priority", F_INT, O(priority) },
};

static json_t *
load_object(const char *text, size_t len, const char *what, struct sf_err *err)
{
    json_error_t je;
    json_t *root = json_loadb(text, len, JSON_REJECT_DUPLICATES, &je);
    if (!root) {
        sf_err_set(err, SF_EINVAL, "%s: malformed JSON at line %d column %d: %s", what, je.line,
                   je.column, je.text);
        return NULL;
    }
    if (!json_is_object(root)) {
        json_decref(root);
        sf_err_set(err, SF_EINVAL, "%s: expected a JSON object", what);
        return NULL;
    }
    return root;
}

int
api_opts_parse(const char *text, size_t len, struct job_opts *o, struct sf_err *err)
{
    if (len == 0)
        return job_opts_validate(o, err);
    json_t *root = load_object(text, len, "options", err);
    if (!root)
        return SF_EINVAL;
    int rc = SF_OK;
    const char *key;
    json_t *v;
    json_object_foreach(root, key, v)
    {
        const struct field *f = NULL;
        for (size_t i = 0; i < sizeof(fields) / sizeof(fields[0]); i++)
            if (strcmp(fields[i].name, key) == 0)
                f = &fields[i];
        if (!f) {
            rc = sf_err_set(err, SF_EINVAL, "options: unknown field '%.64s'", key);
            goto out;
        }
        char *dst = (char *)o + f->off;
        if (f->type == F_STR) {
            if (!json_is_string(v)) {
                rc = sf_err_set(err, SF_EINVAL, "options: field '%s': expected a string", key);
                goto out;
            }
            if (json_string_length(v) >= f->size ||
                strlen(json_string_value(v)) != json_string_length(v)) {
                rc = sf_err_set(err, SF_EINVAL,
                                "options: field '%s': longer than %zu bytes or holds NUL", key,
                                f->size - 1);
                goto out;
            }
            snprintf(dst, f->size, "%s", json_string_value(v));
        } else if (f->type == F_DBL) {
            if (!json_is_number(v)) {
                rc = sf_err_set(err, SF_EINVAL, "options: field '%s': expected a number", key);
                goto out;
            }
            *(double *)dst = json_number_value(v);
        } else {
            json_int_t n = json_is_integer(v) ? json_integer_value(v) : 0;
            if (!json_is_integer(v) || n < INT32_MIN || n > INT32_MAX) {
                rc = sf_err_set(err, SF_EINVAL, "options: field '%s': expected an integer", key);
                goto out;
            }
            *(int *)dst = (int)n;
        }
    }
    rc = job_opts_validate(o, err);
    if (rc)
        sf_err_prefix(err, "options");
out:
    json_decref(root);
    return rc;
}

/* Parse a body of one integer field {"key": N} with lo <= N <= hi. */
static int
one_int(const char *text, size_t len, const char *key, int lo, int hi, int *out, struct sf_err *err)
{
    json_t *root = load_object(text, len, "body", err);
    if (!root)
        return SF_EINVAL;
    int rc = SF_OK;
    json_t *p = json_object_get(root, key);
    if (json_object_size(root) != 1 || !json_is_integer(p)) {
        rc = sf_err_set(err, SF_EINVAL, "body: expected {\"%s\": INTEGER} and nothing else", key);
    } else {
        json_int_t n = json_integer_value(p);
        if (n < lo || n > hi)
            rc = sf_err_set(err, SF_EINVAL, "%s: %lld is not in %d..%d", key, (long long)n, lo, hi);
        else
            *out = (int)n;
    }
    json_decref(root);
    return rc;
}

int
api_priority_parse(const char *text, size_t len, int *priority, struct sf_err *err)
{
    return one_int(text, len, "priority", -JOB_PRIORITY_MAX, JOB_PRIORITY_MAX, priority, err);
}

int
api_move_parse(const char *text, size_t len, int *by, struct sf_err *err)
{
    int rc = one_int(text, len, "by", -1, 1, by, err);
    if (rc == SF_OK && *by == 0)
        rc = sf_err_set(err, SF_EINVAL, "by: 0 is not -1 (up) or 1 (down)");
    return rc;
}

int
api_command_parse(const char *text, size_t len, char *out, size_t n, struct sf_err *err)
{
    json_t *root = load_object(text, len, "body", err);
    if (!root)
        return SF_EINVAL;
    int rc = SF_OK;
    json_t *c = json_object_get(root, "command");
    if (json_object_size(root) != 1 || !json_is_string(c)) {
        rc = sf_err_set(err, SF_EINVAL,
                        "body: expected {\"command\": \"G-CODE LINE\"} and nothing else");
        goto out;
    }
    const char *line = json_string_value(c);
    size_t ll = json_string_length(c);
    for (size_t i = 0; i < ll; i++)
        if ((unsigned char)line[i] < 0x20 || (unsigned char)line[i] > 0x7e) {
            rc = sf_err_set(err, SF_EINVAL,
                            "command: byte %zu is not printable ASCII (one G-code line only)",
                            i + 1);
            goto out;
        }
    bool too_long = false;
    size_t cap = n < SF_COMMAND_MAX + 1 ? n : SF_COMMAND_MAX + 1;
    if (gcode_strip(line, ll, out, cap, &too_long) > 0)
        goto out;
    if (too_long)
        rc = sf_err_set(err, SF_EINVAL, "command: longer than %d bytes", SF_COMMAND_MAX);
    else
        rc = sf_err_set(err, SF_EINVAL, "command: '%.64s' holds no command", line);
out:
    json_decref(root);
    return rc;
}

int
api_resume_parse(const char *text, size_t len, int64_t *line, struct sf_err *err)
{
    *line = -1;
    if (len == 0)
        return SF_OK; /* no body: the last acknowledged line */
    json_t *root = load_object(text, len, "body", err);
    if (!root)
        return SF_EINVAL;
    int rc = SF_OK;
    json_t *l = json_object_get(root, "line");
    if (json_object_size(root) != 1 || !json_is_integer(l))
        rc = sf_err_set(err, SF_EINVAL, "body: expected {\"line\": INTEGER} and nothing else");
    else if (json_integer_value(l) < 0)
        rc = sf_err_set(err, SF_EINVAL, "line: %lld is negative", (long long)json_integer_value(l));
    else
        *line = json_integer_value(l);
    json_decref(root);
    return rc;
}

json_t *
api_job_json(const struct job_row *j)
{
    json_t *o = json_pack(
        "{sI ss ss ss sf sf si si si si ss ss ss si ss sI sI ss ss ss s[fff] sI sI}", "id",
        (json_int_t)j->id, "name", j->opts.name, "state", job_state_name(j->state), "method",
        j->opts.method, "deviation_mm", j->opts.deviation_mm, "overhang_deg", j->opts.overhang_deg,
        "copies", j->counts.copies, "copies_done", j->counts.copies_done, "failures",
        j->counts.failures, "max_retries", j->counts.max_retries, "material", j->opts.material,
        "target_printer", j->opts.printer, "target_group", j->opts.group, "priority",
        j->opts.priority, "printer", j->printer, "lines_acked", (json_int_t)j->lines_acked,
        "gcode_lines", (json_int_t)j->gcode_lines, "reason", j->reason, "file_sha", j->file_sha,
        "gcode_sha", j->gcode_sha, "size_mm", j->size_mm[0], j->size_mm[1], j->size_mm[2],
        "created_ms", (json_int_t)j->created_ms, "updated_ms", (json_int_t)j->updated_ms);
    /* MNDR / ANDR (fractions of the bounding-box diagonal): null when not measured */
    if (o && (json_object_set_new(o, "mndr", j->dev_measured ? json_real(j->mndr) : json_null()) ||
              json_object_set_new(o, "andr", j->dev_measured ? json_real(j->andr) : json_null()) ||
              json_object_set_new(o, "shape_changed", json_boolean(j->shape_changed)) ||
              json_object_set_new(o, "queue_pos", json_integer((json_int_t)j->queue_pos)) ||
              /* the G-code's print time estimate, s, and filament, g: null when not known */
              json_object_set_new(
                  o, "est_s", j->est_known && j->est_s >= 0 ? json_real(j->est_s) : json_null()) ||
              json_object_set_new(o, "filament_g",
                                  j->gcode_sha[0] ? json_real(j->filament_g) : json_null()))) {
        json_decref(o);
        o = NULL;
    }
    return o;
}

json_t *
api_print_json(const struct print_row *p)
{
    return json_pack("{sI si ss ss sI sI sf sI sI ss ss}", "id", (json_int_t)p->id, "copy", p->copy,
                     "printer", p->printer, "material", p->material, "start_line",
                     (json_int_t)p->start_line, "lines_acked", (json_int_t)p->lines_acked,
                     "filament_mm", p->filament_mm, "started_ms", (json_int_t)p->started_ms,
                     "ended_ms", (json_int_t)p->ended_ms, "outcome", p->outcome, "gcode_sha",
                     p->gcode_sha);
}

json_t *
api_event_json(const struct event_row *e)
{
    return json_pack("{sI sI sI ss ss ss}", "id", (json_int_t)e->id, "at_ms", (json_int_t)e->at_ms,
                     "job_id", (json_int_t)e->job_id, "printer", e->printer, "kind", e->kind,
                     "detail", e->detail);
}

void
api_time_left_json(json_t *o, const struct printer_info *p)
{
    bool known = p->time_left_s >= 0 && p->time_left_from && p->time_left_from[0];
    json_object_set_new(o, "time_left_s",
                        known ? json_integer((json_int_t)p->time_left_s) : json_null());
    json_object_set_new(o, "time_left_from", known ? json_string(p->time_left_from) : json_null());
}
