/*
 * ini.c - libinih with line numbers, limits and typed option tables.
 *
 * Debian's libinih is built without INI_HANDLER_LINENO, so the handler
 * would not know the line.  We feed inih through our own reader over the
 * bytes in memory: each reader call hands over exactly one line (lines
 * are checked against SF_INI_LINE_MAX first, so inih never splits one),
 * and the reader's count is the line the handler is looking at.  The
 * reader also remembers whether the line began with a blank, which tells
 * a continuation from a repeated key.  NUL bytes are rejected up front.
 *
 * Thread: reentrant; all state is on the caller's stack.
 */
#include "ini.h"

#include <errno.h>
#include <ini.h>
#include <math.h>
#include <stdint.h>
#include <string.h>
#include <strings.h>

#include "buf.h"
#include "limits.h"
#include "mem.h"

struct rd {
    const char *p, *end;
    int line;      /* number of the line last handed to inih */
    bool indented; /* that line starts with a blank */
    const char *name;
    ini_fn fn;
    void *ud;
    struct sf_err *err;
    int rc;
};

static char *
rd_line(char *str, int num, void *stream)
{
    struct rd *r = stream;
    if (r->p >= r->end || num < 2)
        return NULL;
    size_t n = 0, cap = (size_t)num - 1;
    r->indented = *r->p == ' ' || *r->p == '\t';
    while (n < cap && r->p < r->end) {
        char c = *r->p++;
        str[n++] = c;
        if (c == '\n')
            break;
    }
    str[n] = '\0';
    r->line++;
    return str;
}

static int
on_key(void *user, const char *section, const char *name, const char *value)
{
    struct rd *r = user;
    if (r->rc < 0)
        return 0;
    int rc = r->fn(r->ud, section, name, value, r->indented, r->err);
    if (rc < 0) {
        r->rc = rc;
        sf_err_prefix(r->err, "%s:%d", r->name, r->line);
        return 0;
    }
    return 1;
}

int
ini_parse_mem(const char *text, size_t len, const char *name, ini_fn fn, void *ud,
              struct sf_err *err)
{
    if (len > SF_CONFIG_FILE_MAX)
        return sf_err_set(err, SF_EINVAL, "%s: larger than %zu bytes", name, SF_CONFIG_FILE_MAX);
    int line = 1;
    size_t col = 0;
    for (size_t i = 0; i < len; i++) {
        if (text[i] == '\0')
            return sf_err_set(err, SF_EINVAL, "%s:%d: NUL byte in text", name, line);
        if (text[i] == '\n') {
            line++;
            col = 0;
        } else if (++col > SF_INI_LINE_MAX) {
            return sf_err_set(err, SF_EINVAL, "%s:%d: line longer than %d bytes", name, line,
                              SF_INI_LINE_MAX);
        }
    }
    struct rd r = { text, text + len, 0, false, name, fn, ud, err, SF_OK };
    int bad = ini_parse_stream(rd_line, &r, on_key, &r);
    if (r.rc < 0)
        return r.rc;
    if (bad == -2)
        return sf_err_set(err, SF_ENOMEM, "%s: out of memory", name);
    if (bad != 0)
        return sf_err_set(err, SF_EINVAL, "%s:%d: expected '[section]' or 'key = value'", name,
                          bad);
    return SF_OK;
}

int
ini_load(const char *path, ini_fn fn, void *ud, struct sf_err *err)
{
    struct buf b;
    buf_init(&b, SF_CONFIG_FILE_MAX);
    int rc = buf_read_file(&b, path, err);
    if (rc == SF_OK)
        rc = ini_parse_mem(b.data ? b.data : "", b.len, path, fn, ud, err);
    buf_release(&b);
    return rc;
}

const struct ini_opt *
ini_opt_find(const struct ini_opt *opts, size_t n, const char *key)
{
    for (size_t i = 0; i < n; i++)
        if (strcmp(opts[i].key, key) == 0)
            return &opts[i];
    return NULL;
}

static int
parse_real(const struct ini_opt *o, const char *value, double *out, struct sf_err *err)
{
    char *end;
    errno = 0;
    double v = strtod(value, &end);
    if (end == value || *end != '\0' || errno == ERANGE || !isfinite(v))
        return sf_err_set(err, SF_EINVAL, "option '%s': '%s' is not a number", o->key, value);
    if (v < o->min || v > o->max)
        return sf_err_set(err, SF_EINVAL, "option '%s': %g is outside [%g, %g]", o->key, v, o->min,
                          o->max);
    *out = v;
    return SF_OK;
}

int
ini_opt_set(const struct ini_opt *o, void *base, const char *value, bool append, struct sf_err *err)
{
    char *field = (char *)base + o->offset;
    double v;
    switch (o->type) {
    case INI_REAL:
        if (parse_real(o, value, &v, err) < 0)
            return SF_EINVAL;
        memcpy(field, &v, sizeof(v));
        return SF_OK;
    case INI_INT: {
        if (parse_real(o, value, &v, err) < 0)
            return SF_EINVAL;
        if (v != floor(v))
            return sf_err_set(err, SF_EINVAL, "option '%s': '%s' is not a whole number", o->key,
                              value);
        int i = (int)v;
        memcpy(field, &i, sizeof(i));
        return SF_OK;
    }
    case INI_BOOL: {
        static const char *const yes[] = { "1", "true", "yes", "on" };
        static const char *const no[] = { "0", "false", "no", "off" };
        for (int i = 0; i < 4; i++) {
            if (strcasecmp(value, yes[i]) == 0 || strcasecmp(value, no[i]) == 0) {
                bool b = strcasecmp(value, yes[i]) == 0;
                memcpy(field, &b, sizeof(b));
                return SF_OK;
            }
        }
        return sf_err_set(err, SF_EINVAL, "option '%s': '%s' is not a boolean (yes/no)", o->key,
                          value);
    }
    case INI_STR:
    case INI_TEXT: {
        char *old;
        memcpy(&old, field, sizeof(old));
        char *s;
        if (append && o->type != INI_TEXT)
            return sf_err_set(err, SF_EINVAL, "option '%s' takes one line", o->key);
        if (append && old && old[0]) {
            size_t a = strlen(old), b = strlen(value);
            s = mem_alloc(a + b + 2);
            if (s) {
                memcpy(s, old, a);
                s[a] = '\n';
                memcpy(s + a + 1, value, b + 1);
            }
        } else {
            s = mem_strdup(value);
        }
        if (!s)
            return sf_err_set(err, SF_ENOMEM, "option '%s': out of memory", o->key);
        free(old);
        memcpy(field, &s, sizeof(s));
        return SF_OK;
    }
    }
    return sf_err_set(err, SF_EBUG, "option '%s': bad type", o->key);
}

int
ini_opt_set_kv(const struct ini_opt *opts, size_t n, void *base, const char *kv, struct sf_err *err)
{
    const char *eq = strchr(kv, '=');
    if (!eq || eq == kv)
        return sf_err_set(err, SF_EINVAL, "'%s': expected key=value", kv);
    char key[64];
    size_t kl = (size_t)(eq - kv);
    if (kl >= sizeof(key))
        return sf_err_set(err, SF_EINVAL, "'%.*s': no such option", (int)kl, kv);
    memcpy(key, kv, kl);
    key[kl] = '\0';
    const struct ini_opt *o = ini_opt_find(opts, n, key);
    if (!o)
        return sf_err_set(err, SF_EINVAL, "'%s': no such option", key);
    return ini_opt_set(o, base, eq + 1, false, err);
}

int
ini_opts_dup(const struct ini_opt *opts, size_t n, void *base)
{
    int rc = SF_OK;
    for (size_t i = 0; i < n; i++) {
        if (opts[i].type != INI_STR && opts[i].type != INI_TEXT)
            continue;
        char *s, *field = (char *)base + opts[i].offset;
        memcpy(&s, field, sizeof(s));
        if (s) {
            s = mem_strdup(s);
            if (!s)
                rc = SF_ENOMEM;
        }
        memcpy(field, &s, sizeof(s));
    }
    return rc;
}

void
ini_opts_release(const struct ini_opt *opts, size_t n, void *base)
{
    for (size_t i = 0; i < n; i++) {
        if (opts[i].type != INI_STR && opts[i].type != INI_TEXT)
            continue;
        char *s, *field = (char *)base + opts[i].offset;
        memcpy(&s, field, sizeof(s));
        free(s);
        s = NULL;
        memcpy(field, &s, sizeof(s));
    }
}
