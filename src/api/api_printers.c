/*
 * api_printers.c - the run-time printer routes (api_printers.h): add,
 * edit, disable, enable and remove printers, and the data the dashboard's
 * form is built from.
 *
 * Design: a body's fields become the text of a [printer NAME] section
 * ("key: value" lines) and the farm checks that text with farm.ini's own
 * parser (farmcfg_printer_parse), so the API takes exactly what the file
 * takes and says what the file would.  This file checks only what the
 * text form itself could not carry: a field name that is not a word, a
 * value with a control byte or a blank before '#' or ';' (the file's
 * inline comment), a JSON type no option has.  PATCH starts from the
 * printer's options as text (farmcfg_printer_each) and lays the body's
 * fields over them.  What each change means is the farm's (farm.h).
 *
 * Thread: the loop thread.
 */
#include "api_printers.h"

#include <stdio.h>
#include <string.h>

#include "../../drivers/drv.h"
#include "../../drivers/drv_link.h"
#include "../base/buf.h"
#include "../base/mem.h"
#include "../farm/farm.h"
#include "../farm/farmcfg.h"
#include "../farm/store.h"

#define FIELDS_MAX 64 /* options a printer has: its section's and its kind's, with room */

/* A printer's options as text, in order. */
struct fields {
    size_t n;
    struct {
        char key[40];  /* option name */
        char val[320]; /* its value as farm.ini writes it (the longest option is 256) */
        bool secret;   /* never shown */
    } f[FIELDS_MAX];
};

static size_t
find(const struct fields *fs, const char *key)
{
    size_t i = 0;
    while (i < fs->n && strcmp(fs->f[i].key, key) != 0)
        i++;
    return i;
}

static void
put(struct fields *fs, const char *key, const char *val, bool secret)
{
    size_t i = find(fs, key);
    if (i == FIELDS_MAX)
        return; /* overlay() counts before it puts */
    snprintf(fs->f[i].key, sizeof(fs->f[i].key), "%s", key);
    snprintf(fs->f[i].val, sizeof(fs->f[i].val), "%s", val);
    fs->f[i].secret = secret;
    if (i == fs->n)
        fs->n++;
}

/* farmcfg_option_fn into a struct fields. */
static void
put_option(void *ud, const char *name, const char *value, bool secret)
{
    put(ud, name, value, secret);
}

/* A JSON value as the file's text, into out (n bytes); SF_EINVAL naming the field. */
static int
value_text(const char *key, const json_t *v, char *out, size_t n, struct sf_err *err)
{
    if (json_is_string(v) && json_string_length(v) < n)
        snprintf(out, n, "%s", json_string_value(v));
    else if (json_is_string(v))
        return sf_err_set(err, SF_EINVAL, "field '%s': longer than %zu bytes", key, n - 1);
    else if (json_is_integer(v))
        snprintf(out, n, "%lld", (long long)json_integer_value(v));
    else if (json_is_real(v))
        snprintf(out, n, "%.15g", json_real_value(v));
    else if (json_is_boolean(v))
        snprintf(out, n, "%s", json_is_true(v) ? "true" : "false");
    else if (json_is_array(v) && json_array_size(v) == 3 && json_is_number(json_array_get(v, 0)) &&
             json_is_number(json_array_get(v, 1)) && json_is_number(json_array_get(v, 2)))
        snprintf(out, n, "%.15g, %.15g, %.15g", json_number_value(json_array_get(v, 0)),
                 json_number_value(json_array_get(v, 1)), json_number_value(json_array_get(v, 2)));
    else
        return sf_err_set(err, SF_EINVAL,
                          "field '%s': expected a string, a number, true/false or [X, Y, Z]", key);
    if (json_is_string(v) && strlen(out) != json_string_length(v))
        return sf_err_set(err, SF_EINVAL, "field '%s': holds a NUL byte", key);
    for (size_t i = 0; out[i]; i++) {
        unsigned char c = (unsigned char)out[i];
        if (c < 0x20 || c == 0x7f)
            return sf_err_set(err, SF_EINVAL, "field '%s': holds a control character", key);
        if ((c == '#' || c == ';') && i > 0 && out[i - 1] == ' ')
            return sf_err_set(err, SF_EINVAL,
                              "field '%s': a blank then '%c' starts a comment in farm.ini", key, c);
    }
    return SF_OK;
}

/* The body's fields over fs (null: the option back to its default); "name" skipped. */
static int
overlay(struct fields *fs, const json_t *body, struct sf_err *err)
{
    const char *key;
    json_t *v;
    json_object_foreach((json_t *)body, key, v)
    {
        if (strcmp(key, "name") == 0)
            continue;
        size_t len = strspn(key, "abcdefghijklmnopqrstuvwxyz0123456789_");
        if (len == 0 || key[len] || len >= sizeof(fs->f[0].key))
            return sf_err_set(err, SF_EINVAL, "field '%.40s' is not an option name", key);
        if (json_is_null(v)) {
            size_t i = find(fs, key);
            if (i < fs->n)
                fs->f[i] = fs->f[--fs->n];
            continue;
        }
        char val[sizeof(fs->f[0].val)];
        int rc = value_text(key, v, val, sizeof(val), err);
        if (rc)
            return rc;
        if (find(fs, key) == FIELDS_MAX)
            return sf_err_set(err, SF_EINVAL, "more than %d fields", FIELDS_MAX);
        put(fs, key, val, false);
    }
    return SF_OK;
}

/* fs as a section's body into b ("key: value" lines). */
static int
to_text(const struct fields *fs, struct buf *b)
{
    for (size_t i = 0; i < fs->n; i++)
        if (buf_printf(b, "%s: %s\n", fs->f[i].key, fs->f[i].val))
            return SF_ENOMEM;
    return buf_append(b, "", 1); /* ends the text */
}

/* The request's body as a JSON object, or NULL with a 400 answered. */
static json_t *
body_object(const struct http_req *req, struct http_resp *resp)
{
    json_error_t je;
    json_t *o = json_loadb(req->body, req->body_len, 0, &je);
    if (o && json_is_object(o))
        return o;
    json_decref(o);
    http_error(resp, 400, "body: expected a JSON object of printer options%s%s", o ? "" : ": ",
               o ? "" : je.text);
    return NULL;
}

/* The farm, or NULL with a 503 answered (a daemon without one). */
static struct farm *
farm_of(void *ctx, struct http_resp *resp)
{
    if (!ctx)
        http_error(resp, 503, "this server runs no farm");
    return ctx;
}

/* Printer name's options as GET .../config shows them, with status into resp. */
static void
config_answer(struct farm *f, const char *name, int status, struct http_resp *resp)
{
    struct farmcfg_printer *c = mem_alloc(sizeof(*c));
    struct fields *fs = mem_calloc(1, sizeof(*fs));
    struct sf_err err;
    bool stored = false;
    int rc = c && fs ? farm_printer_base(f, name, c, &stored, &err)
                     : sf_err_set(&err, SF_ENOMEM, "out of memory");
    if (rc) {
        http_fail(resp, rc, err.msg);
        goto out;
    }
    farmcfg_printer_each(c, put_option, fs);
    json_t *opts = json_object(), *secrets = json_array();
    for (size_t i = 0; i < fs->n; i++) {
        if (!fs->f[i].secret)
            json_object_set_new(opts, fs->f[i].key, json_string(fs->f[i].val));
        else if (fs->f[i].val[0])
            json_array_append_new(secrets, json_string(fs->f[i].key));
    }
    /* what is in force: an operator's disable over the options */
    const char *disabled = NULL;
    for (size_t i = 0; i < farm_printer_count(f) && !disabled; i++) {
        struct printer_info pi;
        farm_printer_info(f, i, &pi);
        if (strcmp(pi.cfg->name, name) == 0 && pi.cfg->disabled[0])
            disabled = pi.cfg->disabled;
    }
    resp->json = json_pack("{s{ss ss sb so so so}}", "printer", "name", name, "source",
                           stored ? "api" : "farm.ini", "enabled", !disabled && c->enabled,
                           "disabled_reason", disabled ? json_string(disabled) : json_null(),
                           "options", opts, "secrets", secrets);
    resp->status = status;
out:
    free(c);
    free(fs);
}

/* GET /api/printers/NAME/config */
static void
config_get(void *ctx, const struct route_args *args, const struct http_req *req,
           struct http_resp *resp)
{
    (void)req;
    struct farm *f = farm_of(ctx, resp);
    if (f)
        config_answer(f, args->name, 200, resp);
}

/*
 * The body (its fields over the printer's options when patch) as a
 * section's text into b, then add (name NULL: take the body's) or edit.
 */
static void
write_printer(struct farm *f, const char *name, const struct http_req *req, bool patch,
              struct http_resp *resp)
{
    json_t *body = body_object(req, resp);
    if (!body)
        return;
    struct fields *fs = mem_calloc(1, sizeof(*fs));
    struct farmcfg_printer *base = patch ? mem_alloc(sizeof(*base)) : NULL;
    struct buf b;
    struct sf_err err;
    bool stored;
    char given[64] = "";
    int rc = SF_OK;
    buf_init(&b, STORE_PRINTER_CFG_MAX * 2);
    const json_t *jn = json_object_get(body, "name");
    if (jn && (!json_is_string(jn) || json_string_length(jn) >= sizeof(given)))
        rc = sf_err_set(&err, SF_EINVAL, "field 'name': expected a printer name of 1..63 bytes");
    else if (jn)
        snprintf(given, sizeof(given), "%s", json_string_value(jn));
    if (rc == SF_OK && !name && !given[0])
        rc = sf_err_set(&err, SF_EINVAL, "field 'name' is required");
    if (rc == SF_OK && name && jn && strcmp(given, name) != 0)
        rc = sf_err_set(&err, SF_EINVAL,
                        "field 'name': a printer cannot be renamed (remove it "
                        "and add it under the new name)");
    if (rc == SF_OK && (!fs || (patch && !base)))
        rc = sf_err_set(&err, SF_ENOMEM, "out of memory");
    if (rc == SF_OK && patch && !(rc = farm_printer_base(f, name, base, &stored, &err)))
        farmcfg_printer_each(base, put_option, fs);
    if (rc == SF_OK && !(rc = overlay(fs, body, &err)) && to_text(fs, &b))
        rc = sf_err_set(&err, SF_EINVAL, "the printer's options are longer than %d bytes",
                        STORE_PRINTER_CFG_MAX); /* b's cap: memory is not what ran out */
    if (rc == SF_OK)
        rc = name ? farm_printer_edit(f, name, b.data, &err)
                  : farm_printer_add(f, given, b.data, &err);
    if (rc == SF_EINVAL && !name && strncmp(err.msg, "printer name", 12) == 0)
        sf_err_prefix(&err, "field 'name'");
    if (rc)
        http_fail(resp, rc, err.msg);
    else
        config_answer(f, name ? name : given, name ? 200 : 201, resp);
    buf_release(&b);
    free(base);
    free(fs);
    json_decref(body);
}

/* POST /api/printers */
static void
printer_add(void *ctx, const struct route_args *args, const struct http_req *req,
            struct http_resp *resp)
{
    (void)args;
    struct farm *f = farm_of(ctx, resp);
    if (f)
        write_printer(f, NULL, req, false, resp);
}

/* PATCH /api/printers/NAME */
static void
printer_patch(void *ctx, const struct route_args *args, const struct http_req *req,
              struct http_resp *resp)
{
    struct farm *f = farm_of(ctx, resp);
    if (f)
        write_printer(f, args->name, req, true, resp);
}

/* PUT and DELETE /api/printers/NAME (ROUTE_OTHER: route.h names no other methods). */
static void
printer_put_delete(void *ctx, const struct route_args *args, const struct http_req *req,
                   struct http_resp *resp)
{
    struct farm *f = farm_of(ctx, resp);
    struct sf_err err;
    if (!f)
        return;
    if (strcmp(req->method, "PUT") == 0) {
        write_printer(f, args->name, req, false, resp);
    } else if (strcmp(req->method, "DELETE") == 0) {
        int rc = farm_printer_remove(f, args->name, &err);
        if (rc)
            http_fail(resp, rc, err.msg);
        else
            resp->json = json_pack("{ss}", "removed", args->name);
    } else {
        http_resp_header(resp, "Allow", "GET, PUT, PATCH, DELETE");
        http_error(resp, 405, "method %s is not allowed on a printer", req->method);
    }
}

/* POST /api/printers/NAME/disable {"reason": "..."} */
static void
printer_disable(void *ctx, const struct route_args *args, const struct http_req *req,
                struct http_resp *resp)
{
    struct farm *f = farm_of(ctx, resp);
    json_t *body = f ? body_object(req, resp) : NULL;
    if (!body)
        return;
    const json_t *r = json_object_get(body, "reason");
    struct sf_err err;
    char why[sizeof(((struct farmcfg_printer *)0)->disabled)];
    int rc = !json_is_string(r)
                 ? sf_err_set(&err, SF_EINVAL, "field 'reason' is required: say why (a string)")
                 : value_text("reason", r, why, sizeof(why), &err);
    if (rc == SF_OK)
        rc = farm_printer_disable(f, args->name, why, &err);
    json_decref(body);
    if (rc)
        http_fail(resp, rc, err.msg);
    else
        config_answer(f, args->name, 200, resp);
}

/* POST /api/printers/NAME/enable */
static void
printer_enable(void *ctx, const struct route_args *args, const struct http_req *req,
               struct http_resp *resp)
{
    (void)req;
    struct farm *f = farm_of(ctx, resp);
    struct sf_err err;
    if (!f)
        return;
    int rc = farm_printer_enable(f, args->name, &err);
    if (rc)
        http_fail(resp, rc, err.msg);
    else
        config_answer(f, args->name, 200, resp);
}

static const char *
type_name(enum drv_opt_type t)
{
    static const char *const names[] = { "text", "ident", "int", "bool", "url", "path" };
    return (size_t)t < sizeof(names) / sizeof(names[0]) ? names[t] : "text";
}

/* farmcfg_option_fn: a common option with its default, for the form (not driver, enabled). */
static void
common_option(void *ud, const char *name, const char *value, bool secret)
{
    (void)secret;
    if (strcmp(name, "driver") != 0 && strcmp(name, "enabled") != 0)
        json_array_append_new(ud, json_pack("{ss ss}", "name", name, "default", value));
}

/* GET /api/printer-kinds */
static void
kinds_get(void *ctx, const struct route_args *args, const struct http_req *req,
          struct http_resp *resp)
{
    (void)ctx, (void)args, (void)req;
    json_t *kinds = json_array(), *common = json_array();
    const struct drv_kind *k;
    for (size_t i = 0; (k = drv_kind_at(i)); i++) {
        json_t *opts = json_array();
        const struct drv_option *o;
        for (size_t j = 0; (o = drv_kind_option(k, j)); j++) {
            json_t *jo = json_pack("{ss ss sb sb}", "name", o->name, "type", type_name(o->type),
                                   "required", (o->flags & DRV_OPT_REQUIRED) != 0, "secret",
                                   (o->flags & DRV_OPT_SECRET) != 0);
            if (o->type == DRV_OPT_INT)
                json_object_update_new(
                    jo, json_pack("{si si si}", "min", o->lo, "max", o->hi, "default", o->def));
            else if (o->type == DRV_OPT_BOOL)
                json_object_set_new(jo, "default", json_boolean(o->def));
            json_array_append_new(opts, jo);
        }
        json_array_append_new(
            kinds, json_pack("{ss sb so}", "name", k->name, "network", k->url, "options", opts));
    }
    struct farmcfg_printer d;
    farmcfg_printer_init(&d);
    farmcfg_printer_each(&d, common_option, common);
    resp->json = json_pack("{so so}", "kinds", kinds, "options", common);
}

static const struct route rows[] = {
    /* methods, pattern, match, body, scope, handler, 405 message */
    { ROUTE_GET, "/api/printer-kinds", NULL, HTTP_BODY_NONE, ROUTE_READ, kinds_get, ROUTE_405 },
    { ROUTE_POST, "/api/printers", NULL, HTTP_BODY_JSON, ROUTE_WRITE, printer_add, ROUTE_405 },
    { ROUTE_GET, "/api/printers/{name}/config", NULL, HTTP_BODY_NONE, ROUTE_READ, config_get,
      ROUTE_405 },
    { ROUTE_PATCH, "/api/printers/{name}", NULL, HTTP_BODY_JSON, ROUTE_WRITE, printer_patch,
      ROUTE_405 },
    { ROUTE_OTHER, "/api/printers/{name}", NULL, HTTP_BODY_JSON, ROUTE_WRITE, printer_put_delete,
      ROUTE_405 },
    { ROUTE_POST, "/api/printers/{name}/disable", NULL, HTTP_BODY_JSON, ROUTE_WRITE,
      printer_disable, ROUTE_405 },
    { ROUTE_POST, "/api/printers/{name}/enable", NULL, HTTP_BODY_NONE, ROUTE_WRITE, printer_enable,
      ROUTE_405 },
};

const struct route *
api_printers_routes(size_t *n)
{
    *n = sizeof(rows) / sizeof(rows[0]);
    return rows;
}
