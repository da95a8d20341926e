/*
 * farmcfg.c - the farm config parser, over libinih.
 *
 * Why libinih: a well-kept INI parser already in Debian; we add only what
 * the farm needs on top.  Design: inih's handler does not learn line
 * numbers in Debian's build, so we feed inih through our own line reader
 * (ini_parse_stream), which (1) counts lines, so every handler call knows
 * its file:line, (2) sees every section header, even an empty one, so
 * unknown or duplicate sections are caught, (3) strips leading blanks, so
 * inih never takes a line for a multi-line continuation, and (4) cuts
 * inline '#'/';' comments (after a blank), Klipper style.  The first error
 * stops the reader; its message wins.  Each option is a row of a table
 * (name, section kind, parser, offset, range), so the set of options, their
 * checks and config/farm.ini stay in step; a printer's link options are the
 * rows of the driver kinds' tables (drivers/drv.c), parsed by the same
 * value checks and kept in its struct drv_link, and checked against its
 * kind once the section is complete (its driver may come last).
 *
 * Thread: any; no global state is touched (inih's global switches are left
 * at their defaults).
 */
#include "farmcfg.h"

#include <arpa/inet.h>
#include <errno.h>
#include <ini.h>
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <string.h>

#include "../../drivers/drv.h"
#include "../../drivers/drv_link.h"
#include "../../drivers/gpolicy.h"
#include "../base/buf.h"
#include "../base/limits.h"
#include "../base/mem.h"

enum kind { K_STR, K_IDENT, K_INT, K_DBL, K_BOOL, K_TRIPLE, K_LISTEN, K_KEYS, K_MIB };

/* One option: where it lives and how it is checked. */
struct option {
    const char *name; /* key in the file */
    bool printer;     /* in [printer NAME] (else [farm]) */
    enum kind kind;   /* value parser */
    size_t off;       /* offset in struct farmcfg or struct farmcfg_printer */
    size_t size;      /* K_STR/K_IDENT: buffer size */
    double lo, hi;    /* K_INT/K_DBL/K_TRIPLE/K_MIB: inclusive range */
};

#define F(field) offsetof(struct farmcfg, field), sizeof(((struct farmcfg *)0)->field)
#define P(field)                                                                                   \
    offsetof(struct farmcfg_printer, field), sizeof(((struct farmcfg_printer *)0)->field)

static const struct option options[] = {
    { "listen", false, K_LISTEN, 0, 0, 0, 0 },
    { "data_dir", false, K_STR, F(data_dir), 0, 0 },
    { "profiles_dir", false, K_STR, F(profiles_dir), 0, 0 },
    { "api_keys", false, K_KEYS, 0, 0, 0, 0 },
    { "api_keys_readonly", false, K_KEYS, 1, 0, 0, 0 },
    { "metrics_keys", false, K_KEYS, 2, 0, 0, 0 },
    { "upload_max_mb", false, K_MIB, 0, 0, 1, 4096 },
    { "gram_seconds", false, K_DBL, F(gram_s), 0, 1e6 },
    { "material_first", false, K_BOOL, F(material_first), 0, 0 },
    { "store", false, K_STR, F(store), 0, 0 },
    { "host", false, K_IDENT, F(host), 0, 0 },
    { "host_lease_s", false, K_DBL, F(host_lease_s), 2, 3600 },
    { "driver", true, K_IDENT, P(driver), 0, 0 },
    { "profile", true, K_IDENT, P(profile), 0, 0 },
    { "material", true, K_IDENT, P(material), 0, 0 },
    { "nozzle_mm", true, K_DBL, P(nozzle_mm), 0.1, 2.0 },
    { "bed_size", true, K_TRIPLE, P(bed_mm), 10, 2000 },
    { "overhang_deg", true, K_DBL, P(overhang_deg), 1, 89 },
    { "enabled", true, K_BOOL, P(enabled), 0, 0 },
    { "auto_eject", true, K_BOOL, P(auto_eject), 0, 0 },
    { "group", true, K_IDENT, P(group), 0, 0 },
    { "hold_heat_min", true, K_DBL, P(hold_heat_min), 0, 1440 },
    { "gcode_models", true, K_STR, P(gcode_models), 0, 0 },
    { "attended", true, K_BOOL, P(attended), 0, 0 },
    { "allow_gcode", true, K_STR, P(allow_gcode), 0, 0 },
};
#define N_OPTIONS (sizeof(options) / sizeof(options[0]))

/* Parser state shared by the reader and the handler. */
struct parse {
    struct farmcfg *cfg; /* being filled */
    const char *name; /* file name for messages; NULL: none, nor a line (farmcfg_printer_parse) */
    const char *p, *end;  /* unread text */
    int line;             /* line last handed to inih */
    bool failed;          /* an error was recorded; stop */
    struct sf_err *err;   /* where it went */
    int section;          /* -2 none yet, -1 [farm], -3 [notify], else printer index */
    bool farm_seen;       /* [farm] appeared */
    bool seen[N_OPTIONS]; /* options given in the current section */
};

static int fail(struct parse *ps, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

static int
fail(struct parse *ps, const char *fmt, ...)
{
    if (ps->failed)
        return 0;
    ps->failed = true;
    char msg[SF_ERR_MSG_MAX];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof(msg), fmt, ap);
    va_end(ap);
    if (ps->name)
        sf_err_set(ps->err, SF_EINVAL, "%s:%d: %s", ps->name, ps->line, msg);
    else
        sf_err_set(ps->err, SF_EINVAL, "%s", msg);
    return 0;
}

static bool
ident_ok(const char *s)
{
    if (!*s)
        return false;
    for (; *s; s++)
        if (!((*s >= 'a' && *s <= 'z') || (*s >= 'A' && *s <= 'Z') || (*s >= '0' && *s <= '9') ||
              *s == '-' || *s == '_' || *s == '.'))
            return false;
    return true;
}

bool
farmcfg_ident_ok(const char *s)
{
    return ident_ok(s);
}

void
farmcfg_printer_init(struct farmcfg_printer *p)
{
    memset(p, 0, sizeof(*p));
    drv_link_init(&p->link);
    snprintf(p->profile, sizeof(p->profile), "generic-marlin");
    snprintf(p->material, sizeof(p->material), "PLA");
    p->nozzle_mm = 0.4;
    p->bed_mm[0] = p->bed_mm[1] = 220;
    p->bed_mm[2] = 250;
    p->overhang_deg = 45;
    p->enabled = true;
    p->hold_heat_min = 10;
}

/* A [notify NAME] section: a new target with its defaults. */
static void
open_notify(struct parse *ps, const char *name)
{
    struct farmcfg *c = ps->cfg;
    while (*name == ' ')
        name++;
    if (!ident_ok(name) || strlen(name) >= sizeof(c->notify[0].name)) {
        fail(ps, "section 'notify %s': name must be 1..63 letters, digits, '-', '_', '.'", name);
        return;
    }
    for (size_t i = 0; i < c->n_notify; i++)
        if (strcmp(c->notify[i].name, name) == 0) {
            fail(ps, "section 'notify %s' appears twice", name);
            return;
        }
    size_t cap = c->n_notify;
    if (c->n_notify == NOTIFYCFG_TARGETS_MAX) {
        fail(ps, "more than %d notify sections", NOTIFYCFG_TARGETS_MAX);
        return;
    }
    if (!mem_grow((void **)&c->notify, &cap, c->n_notify + 1, sizeof(*c->notify))) {
        fail(ps, "out of memory");
        return;
    }
    notifycfg_init(&c->notify[c->n_notify++], name, ps->line);
    ps->section = -3;
}

/* A section header "[...]" on the current line: open the section. */
static void
open_section(struct parse *ps, const char *hdr, size_t len)
{
    char sec[128];
    if (len >= sizeof(sec)) {
        fail(ps, "section name is too long");
        return;
    }
    memcpy(sec, hdr, len);
    sec[len] = '\0';
    memset(ps->seen, 0, sizeof(ps->seen));
    if (strcmp(sec, "farm") == 0) {
        if (ps->farm_seen) {
            fail(ps, "section 'farm' appears twice");
            return;
        }
        ps->farm_seen = true;
        ps->section = -1;
        return;
    }
    if (strncmp(sec, "notify ", 7) == 0) {
        open_notify(ps, sec + 7);
        return;
    }
    if (strncmp(sec, "printer ", 8) != 0) {
        fail(ps, "section '%s' is not valid (expected 'farm', 'printer NAME' or 'notify NAME')",
             sec);
        return;
    }
    const char *name = sec + 8;
    while (*name == ' ')
        name++;
    if (!ident_ok(name) || strlen(name) >= sizeof(ps->cfg->printers[0].name)) {
        fail(ps, "section '%s': printer name must be 1..63 letters, digits, '-', '_', '.'", sec);
        return;
    }
    if (farmcfg_printer(ps->cfg, name)) {
        fail(ps, "section 'printer %s' appears twice", name);
        return;
    }
    struct farmcfg *c = ps->cfg;
    if (c->n_printers == FARMCFG_PRINTERS_MAX) {
        fail(ps, "more than %d printers", FARMCFG_PRINTERS_MAX);
        return;
    }
    size_t cap = c->n_printers;
    if (!mem_grow((void **)&c->printers, &cap, c->n_printers + 1, sizeof(*c->printers))) {
        fail(ps, "out of memory");
        return;
    }
    struct farmcfg_printer *p = &c->printers[c->n_printers];
    farmcfg_printer_init(p);
    snprintf(p->name, sizeof(p->name), "%s", name);
    p->line = ps->line;
    ps->section = (int)c->n_printers++;
}

/*
 * fgets-style reader handed to inih: one line per call, see the top of the
 * file for what it does on the way.
 */
static char *
read_line(char *str, int num, void *stream)
{
    struct parse *ps = stream;
    if (ps->failed || ps->p >= ps->end)
        return NULL;
    const char *nl = memchr(ps->p, '\n', (size_t)(ps->end - ps->p));
    const char *eol = nl ? nl : ps->end;
    ps->line++;
    const char *s = ps->p;
    ps->p = nl ? nl + 1 : ps->end;
    while (s < eol && (*s == ' ' || *s == '\t'))
        s++;
    size_t len = (size_t)(eol - s);
    if (len > 0 && s[len - 1] == '\r')
        len--;
    if (len + 2 > (size_t)num) {
        fail(ps, "line is longer than %d bytes", num - 3);
        return NULL;
    }
    if (memchr(s, '\0', len)) {
        fail(ps, "line holds a NUL byte");
        return NULL;
    }
    memcpy(str, s, len);
    str[len] = '\0';
    /* Inline comments start with '#' or ';' after a blank. */
    for (size_t i = 1; i < len; i++)
        if ((str[i] == '#' || str[i] == ';') && (str[i - 1] == ' ' || str[i - 1] == '\t')) {
            str[i] = '\0';
            len = i;
            break;
        }
    if (str[0] == '[') {
        char *close = strchr(str, ']');
        if (!close) {
            fail(ps, "section header lacks ']'");
            return NULL;
        }
        open_section(ps, str + 1, (size_t)(close - str - 1));
        if (ps->failed)
            return NULL;
    }
    /* inih wants the line end to find the line; give it one. */
    str[len] = '\n';
    str[len + 1] = '\0';
    return str;
}

static bool
parse_double(const char *v, double *out)
{
    char *end;
    errno = 0;
    double d = strtod(v, &end);
    while (*end == ' ')
        end++;
    if (end == v || *end || errno || !isfinite(d))
        return false;
    *out = d;
    return true;
}

static int
parse_keys(struct parse *ps, const char *opt, const char *sec, const char *v, size_t kind)
{
    struct farmcfg *c = ps->cfg;
    const char *p = v;
    while (*p) {
        while (*p == ' ' || *p == ',')
            p++;
        if (!*p)
            break;
        size_t n = strcspn(p, " ,");
        char key[FARMCFG_KEY_MAX + 1];
        if (n < FARMCFG_KEY_MIN || n > FARMCFG_KEY_MAX)
            return fail(ps, "option '%s' in section '%s': each key must be %d..%d characters", opt,
                        sec, FARMCFG_KEY_MIN, FARMCFG_KEY_MAX);
        memcpy(key, p, n);
        key[n] = '\0';
        for (size_t i = 0; i < n; i++)
            if (!((key[i] >= 'a' && key[i] <= 'z') || (key[i] >= 'A' && key[i] <= 'Z') ||
                  (key[i] >= '0' && key[i] <= '9') || key[i] == '-' || key[i] == '_'))
                return fail(ps,
                            "option '%s' in section '%s': keys may hold only letters, "
                            "digits, '-' and '_'",
                            opt, sec);
        if (farmcfg_key(c, key))
            return fail(ps, "option '%s' in section '%s': key given twice", opt, sec);
        if (c->n_keys == FARMCFG_KEYS_MAX)
            return fail(ps, "option '%s' in section '%s': more than %d keys", opt, sec,
                        FARMCFG_KEYS_MAX);
        size_t cap = c->n_keys;
        if (!mem_grow((void **)&c->keys, &cap, c->n_keys + 1, sizeof(*c->keys)))
            return fail(ps, "out of memory");
        snprintf(c->keys[c->n_keys].key, sizeof(c->keys[0].key), "%s", key);
        c->keys[c->n_keys].read_only = kind != 0;
        c->keys[c->n_keys].metrics_only = kind == 2;
        c->n_keys++;
        p += n;
    }
    return 1;
}

static int
parse_listen(struct parse *ps, const char *sec, const char *v)
{
    const char *colon = strrchr(v, ':');
    char host[64];
    if (!colon || (size_t)(colon - v) >= sizeof(host))
        return fail(ps, "option 'listen' in section '%s': '%s' is not ADDRESS:PORT", sec, v);
    memcpy(host, v, (size_t)(colon - v));
    host[colon - v] = '\0';
    char *end;
    errno = 0;
    long port = strtol(colon + 1, &end, 10);
    /* 0: a port the kernel picks, named in the "listening on" log line (tests) */
    if (end == colon + 1 || *end || errno || port < 0 || port > 65535)
        return fail(ps, "option 'listen' in section '%s': port '%s' is not in 0..65535", sec,
                    colon + 1);
    struct in_addr a4;
    if (strcmp(host, "*") != 0 && inet_pton(AF_INET, host, &a4) != 1)
        return fail(ps, "option 'listen' in section '%s': '%s' is not an IPv4 address or '*'", sec,
                    host);
    snprintf(ps->cfg->listen_host, sizeof(ps->cfg->listen_host), "%s", host);
    ps->cfg->listen_port = (int)port;
    return 1;
}

/* A text value of at most size - 1 bytes (K_IDENT: an identifier or empty): 1 if good. */
static int
check_text(struct parse *ps, const char *name, const char *section, enum kind kind, size_t size,
           const char *value)
{
    if (strlen(value) >= size)
        return fail(ps, "option '%s' in section '%s': value is longer than %zu bytes", name,
                    section, size - 1);
    if (kind == K_IDENT && value[0] && !ident_ok(value))
        return fail(ps,
                    "option '%s' in section '%s': '%s' may hold only letters, digits, "
                    "'-', '_', '.'",
                    name, section, value);
    return 1;
}

/* A number in lo..hi, whole unless kind is K_DBL: 1 with *d set if good. */
static int
check_number(struct parse *ps, const char *name, const char *section, enum kind kind, double lo,
             double hi, const char *value, double *d)
{
    if (!parse_double(value, d) || *d < lo || *d > hi || (kind != K_DBL && *d != floor(*d)))
        return fail(ps, "option '%s' in section '%s': '%s' is not a %s in %g..%g", name, section,
                    value, kind == K_DBL ? "number" : "whole number", lo, hi);
    return 1;
}

/* true/yes/1 or false/no/0: 1 with *b set if good. */
static int
check_bool(struct parse *ps, const char *name, const char *section, const char *value, bool *b)
{
    if (strcmp(value, "true") == 0 || strcmp(value, "yes") == 0 || strcmp(value, "1") == 0)
        *b = true;
    else if (strcmp(value, "false") == 0 || strcmp(value, "no") == 0 || strcmp(value, "0") == 0)
        *b = false;
    else
        return fail(ps, "option '%s' in section '%s': '%s' is not true or false", name, section,
                    value);
    return 1;
}

static int
parse_triple(struct parse *ps, const struct option *o, const char *section, const char *value,
             double *field)
{
    double v[3];
    char tmp[128];
    snprintf(tmp, sizeof(tmp), "%s", value);
    char *save = NULL, *tok = strtok_r(tmp, ",", &save);
    int n = 0;
    for (; tok && n < 3; tok = strtok_r(NULL, ",", &save)) {
        while (*tok == ' ')
            tok++;
        if (!parse_double(tok, &v[n]) || v[n] < o->lo || v[n] > o->hi)
            break;
        n++;
    }
    if (n != 3 || tok)
        return fail(ps,
                    "option '%s' in section '%s': '%s' is not X, Y, Z with each in "
                    "%g..%g mm",
                    o->name, section, value, o->lo, o->hi);
    memcpy(field, v, sizeof(v));
    return 1;
}

/* A printer's link option (a row of a driver kind's table): check it by its row and keep it. */
static int
link_option(struct parse *ps, const struct drv_option *o, const char *section, const char *value)
{
    struct farmcfg_printer *p = &ps->cfg->printers[ps->section];
    if (drv_link_get(&p->link, o))
        return fail(ps, "option '%s' in section '%s' is given twice", o->name, section);
    double d = 0;
    bool b = false;
    int ok;
    switch (o->type) {
    case DRV_OPT_INT:
        ok = check_number(ps, o->name, section, K_INT, o->lo, o->hi, value, &d);
        break;
    case DRV_OPT_BOOL:
        ok = check_bool(ps, o->name, section, value, &b);
        d = b;
        break;
    case DRV_OPT_IDENT:
        ok = check_text(ps, o->name, section, K_IDENT, o->size, value);
        break;
    default: /* other text: the URL is checked once the kind is known */
        ok = check_text(ps, o->name, section, K_STR, o->size, value);
        break;
    }
    struct sf_err err;
    if (ok && drv_link_set(&p->link, o, value, (int)d, ps->line, &err))
        return fail(ps, "option '%s' in section '%s': %s", o->name, section, err.msg);
    return ok;
}

static int
handler(void *user, const char *section, const char *name, const char *value)
{
    struct parse *ps = user;
    if (ps->failed)
        return 0;
    if (ps->section == -2)
        return fail(ps, "option '%s' comes before any section", name);
    if (ps->section == -3) {
        char why[SF_ERR_MSG_MAX - 64];
        int rc = notifycfg_option(&ps->cfg->notify[ps->cfg->n_notify - 1], name, value, why,
                                  sizeof(why));
        if (rc == 0)
            return fail(ps, "option '%s' is not valid in section '%s'", name, section);
        return rc < 0 ? fail(ps, "section '%s': %s", section, why) : 1;
    }
    const struct option *o = NULL;
    bool in_printer = ps->section >= 0;
    for (size_t i = 0; i < N_OPTIONS; i++)
        if (strcmp(options[i].name, name) == 0 && options[i].printer == in_printer)
            o = &options[i];
    const struct drv_option *lo = !o && in_printer ? drv_link_option(name) : NULL;
    if (lo)
        return link_option(ps, lo, section, value);
    if (!o)
        return fail(ps, "option '%s' is not valid in section '%s'", name, section);
    if (ps->seen[o - options])
        return fail(ps, "option '%s' in section '%s' is given twice", name, section);
    ps->seen[o - options] = true;
    char *base = in_printer ? (char *)&ps->cfg->printers[ps->section] : (char *)ps->cfg;
    void *field = base + o->off;
    double d;
    switch (o->kind) {
    case K_STR:
    case K_IDENT:
        if (!value[0] && strcmp(name, "profiles_dir") == 0)
            return 1; /* empty: keep the default, the config file's directory */
        if (!check_text(ps, name, section, o->kind, o->size, value))
            return 0;
        /* the value is not quoted back: it may hold a password */
        if (strcmp(name, "store") == 0 && value[0] && strncmp(value, "postgresql://", 13) != 0 &&
            strncmp(value, "postgres://", 11) != 0)
            return fail(ps,
                        "option 'store' in section '%s': not a postgresql:// URL (leave it out "
                        "for SQLite in data_dir)",
                        section);
        struct gpolicy gp;
        struct sf_err e;
        gpolicy_init(&gp);
        if (strcmp(name, "allow_gcode") == 0 && gpolicy_allow(&gp, value, &e))
            return fail(ps, "option 'allow_gcode' in section '%s': %s", section, e.msg);
        snprintf(field, o->size, "%s", value);
        return 1;
    case K_INT:
    case K_DBL:
    case K_MIB:
        if (!check_number(ps, name, section, o->kind, o->lo, o->hi, value, &d))
            return 0;
        if (o->kind == K_INT)
            *(int *)field = (int)d;
        else if (o->kind == K_DBL)
            *(double *)field = d;
        else
            ps->cfg->upload_max_bytes = (size_t)d << 20;
        return 1;
    case K_BOOL:
        return check_bool(ps, name, section, value, field);
    case K_TRIPLE:
        return parse_triple(ps, o, section, value, field);
    case K_LISTEN:
        return parse_listen(ps, section, value);
    case K_KEYS:
        return parse_keys(ps, name, section, value, o->off);
    }
    return fail(ps, "option '%s': internal error", name);
}

/*
 * A network printer's url: a scheme the driver takes, then a host, an
 * optional port and path, nothing a request line could trip on.  The
 * message names line, the url option's own (when it came from another
 * option, bambu's host, the section's).
 */
static int
check_url(struct parse *ps, const char *printer, const char *url, int line,
          const struct drv_kind *k)
{
    if (line)
        ps->line = line;
    const char *sep = strstr(url, "://");
    char scheme[16] = "";
    if (sep && (size_t)(sep - url) < sizeof(scheme))
        snprintf(scheme, sizeof(scheme), "%.*s", (int)(sep - url), url);
    bool known = false;
    const char *s = k->schemes ? k->schemes : "http https";
    size_t sl = strlen(scheme);
    while (sl && *s) {
        size_t w = strcspn(s, " ");
        if (w == sl && strncmp(s, scheme, w) == 0)
            known = true;
        s += w + (s[w] == ' ');
    }
    if (!known)
        return fail(ps, "section 'printer %s': option 'url': '%s' does not start with %s://",
                    printer, url, k->schemes ? k->schemes : "http");
    const char *host = sep + 3;
    if (!*host || *host == '/' || *host == ':')
        return fail(ps, "section 'printer %s': option 'url': '%s' has no host", printer, url);
    for (const char *c = url; *c; c++)
        if ((unsigned char)*c <= ' ' || *c == '"' || *c == '\\' || (unsigned char)*c >= 0x7f)
            return fail(ps,
                        "section 'printer %s': option 'url': '%s' holds a space or control byte",
                        printer, url);
    const char *colon = strchr(host, ':');
    const char *slash = strchr(host, '/');
    if (colon && (!slash || colon < slash)) {
        char *end;
        long port = strtol(colon + 1, &end, 10);
        if (end == colon + 1 || (*end && *end != '/') || port < 1 || port > 65535)
            return fail(ps, "section 'printer %s': option 'url': '%s' has no port in 1..65535",
                        printer, url);
    }
    return 1;
}

/* Is o's field in cfg set (text non-empty, number non-zero)? */
static bool
is_set(const struct drv_config *cfg, const struct drv_option *o)
{
    const char *f = (const char *)cfg + o->off;
    if (o->type == DRV_OPT_INT)
        return *(const int *)f != 0;
    if (o->type == DRV_OPT_BOOL)
        return *(const bool *)f;
    return (*(const char *const *)f)[0] != 0;
}

/*
 * Printer p's link against its kind k's rows: required options, URLs, the
 * credentials k's auth needs, then k's own check.  1 if good.
 */
static int
check_link(struct parse *ps, const struct farmcfg_printer *p, const struct drv_kind *k)
{
    struct drv_config dc = { .name = p->name, .kind = k->name };
    drv_link_config(&p->link, k, &dc);
    const struct drv_option *o;
    for (size_t i = 0; (o = drv_kind_option(k, i)); i++) {
        if ((o->flags & DRV_OPT_REQUIRED) && !is_set(&dc, o))
            return fail(ps, "section 'printer %s': option '%s' is required by driver %s", p->name,
                        o->name, p->driver);
        const struct drv_link_val *v = drv_link_get(&p->link, o);
        if (o->type == DRV_OPT_URL &&
            !check_url(ps, p->name, *(const char **)((char *)&dc + o->off), v ? v->line : 0, k))
            return 0;
        ps->line = p->line;
    }
    /* user and password as given, whether or not the kind takes them */
    bool user = drv_link_text(&p->link, "user")[0],
         password = drv_link_text(&p->link, "password")[0];
    if (k->auth == DRV_AUTH_KEY && !dc.api_key[0])
        return fail(ps,
                    "section 'printer %s': option 'api_key' is required by driver %s "
                    "(%s: Settings > Application Keys, or the global API key)",
                    p->name, p->driver, p->driver);
    if (k->auth == DRV_AUTH_KEY_OR_DIGEST && !dc.api_key[0] && !(user && password))
        return fail(ps,
                    "section 'printer %s': driver %s needs option 'api_key', or 'user' "
                    "and 'password'",
                    p->name, p->driver);
    if (k->url && user != password)
        return fail(ps, "section 'printer %s': options 'user' and 'password' go together", p->name);
    if (k->url && user && k->auth != DRV_AUTH_KEY_OR_DIGEST)
        return fail(ps, "section 'printer %s': driver %s takes no 'user'/'password'", p->name,
                    p->driver);
    char why[200];
    if (k->check && k->check(&dc, why, sizeof(why)) < 0)
        return fail(ps, "section 'printer %s': %s", p->name, why);
    return 1;
}

/* Checks that need a whole section: the driver, then its link. */
static int
check_printers(struct parse *ps)
{
    for (size_t i = 0; i < ps->cfg->n_printers; i++) {
        struct farmcfg_printer *p = &ps->cfg->printers[i];
        ps->line = p->line;
        if (!p->driver[0])
            return fail(ps, "section 'printer %s': option 'driver' is required", p->name);
        const struct drv_kind *k = drv_kind_find(p->driver);
        if (!k) {
            char known[128] = "";
            for (size_t d = 0, n = 0; drv_kind_at(d); d++)
                n += (size_t)snprintf(known + n, n < sizeof(known) ? sizeof(known) - n : 0, "%s%s",
                                      d ? ", " : "", drv_kind_at(d)->name);
            return fail(ps, "section 'printer %s': option 'driver': '%s' is not one of %s", p->name,
                        p->driver, known);
        }
        if (!check_link(ps, p, k))
            return 0;
    }
    return 1;
}

void
farmcfg_init(struct farmcfg *c)
{
    memset(c, 0, sizeof(*c));
    snprintf(c->listen_host, sizeof(c->listen_host), "127.0.0.1");
    c->listen_port = 7420;
    snprintf(c->data_dir, sizeof(c->data_dir), "/var/lib/slimfarm");
    snprintf(c->profiles_dir, sizeof(c->profiles_dir), "config");
    c->upload_max_bytes = (size_t)256 << 20;
    c->gram_s = 60;
    c->host_lease_s = 30;
}

void
farmcfg_store_shown(const char *url, char *out, size_t n)
{
    const char *auth = strstr(url, "://");
    auth = auth ? auth + 3 : url;
    const char *at = strchr(auth, '@'), *colon = strchr(auth, ':');
    if (at && colon && colon < at && !memchr(auth, '/', (size_t)(at - auth)))
        snprintf(out, n, "%.*s***%s", (int)(colon + 1 - url), url, at);
    else
        snprintf(out, n, "%s", url);
    /* a password=VALUE parameter: its value shown as "***" */
    char *pw = strstr(out, "password=");
    if (pw) {
        pw += strlen("password=");
        size_t len = strcspn(pw, "& "), rest = strlen(pw + len);
        if (len && (size_t)(pw - out) + 3 + rest < n) {
            memmove(pw + 3, pw + len, rest + 1);
            memcpy(pw, "***", 3);
        } else if (len) {
            *pw = '\0'; /* no room for the mask: cut there */
        }
    }
}

void
farmcfg_release(struct farmcfg *c)
{
    free(c->keys);
    free(c->printers);
    free(c->notify);
    farmcfg_init(c);
}

/* farmcfg_parse, messages without file:line when name is NULL. */
static int
parse_text(struct farmcfg *c, const char *text, size_t len, const char *name, struct sf_err *err)
{
    struct parse ps = {
        .cfg = c, .name = name, .p = text, .end = text + len, .err = err, .section = -2
    };
    int rc = ini_parse_stream(read_line, &ps, handler, &ps);
    if (!ps.failed && rc > 0) {
        ps.line = rc;
        fail(&ps, "syntax error (expected 'key: value', '[section]' or a comment)");
    } else if (!ps.failed && rc < 0) {
        fail(&ps, "out of memory");
    }
    if (!ps.failed)
        check_printers(&ps);
    for (size_t i = 0; !ps.failed && i < c->n_notify; i++) {
        char why[SF_ERR_MSG_MAX - 64];
        ps.line = c->notify[i].line;
        if (notifycfg_check(&c->notify[i], why, sizeof(why)))
            fail(&ps, "section 'notify %s': %s", c->notify[i].name, why);
    }
    if (ps.failed) {
        farmcfg_release(c);
        return SF_EINVAL;
    }
    return SF_OK;
}

int
farmcfg_parse(struct farmcfg *c, const char *text, size_t len, const char *name, struct sf_err *err)
{
    return parse_text(c, text, len, name ? name : "config", err);
}

int
farmcfg_printer_parse(struct farmcfg_printer *out, const char *name, const char *text, size_t len,
                      struct sf_err *err)
{
    if (!ident_ok(name) || strlen(name) >= sizeof(out->name))
        return sf_err_set(err, SF_EINVAL,
                          "printer name '%.64s' must be 1..63 letters, digits, '-', '_', '.'",
                          name);
    /* "." and ".." are path steps to every HTTP client (/api/printers/..): a printer of
       that name could not be reached again to edit or remove it */
    if (name[0] == '.')
        return sf_err_set(err, SF_EINVAL, "printer name '%.64s' must not start with '.'", name);
    /* The body under its own header, parsed as a file of one section: every check is the
       file's.  A section header in the body would reach past this printer: refused. */
    for (size_t i = 0; i < len; i++) {
        size_t j = i;
        while (j < len && (text[j] == ' ' || text[j] == '\t'))
            j++;
        if (j < len && text[j] == '[')
            return sf_err_set(err, SF_EINVAL, "section 'printer %.64s': a section header in it",
                              name);
        const char *nl = memchr(text + i, '\n', len - i);
        i = nl ? (size_t)(nl - text) : len;
    }
    struct buf b;
    struct farmcfg c;
    buf_init(&b, SF_CONFIG_FILE_MAX);
    farmcfg_init(&c);
    int rc = buf_printf(&b, "[printer %s]\n", name) || buf_append(&b, text, len)
                 ? sf_err_set(err, SF_ENOMEM, "out of memory")
                 : parse_text(&c, b.data, b.len, NULL, err);
    if (rc == SF_OK)
        *out = c.printers[0];
    farmcfg_release(&c);
    buf_release(&b);
    return rc;
}

int
farmcfg_load(struct farmcfg *c, const char *path, struct sf_err *err)
{
    struct buf b;
    buf_init(&b, SF_CONFIG_FILE_MAX);
    int rc = buf_read_file(&b, path, err);
    if (rc == SF_OK) {
        /* Profiles sit beside the config unless it says otherwise. */
        const char *slash = strrchr(path, '/');
        if (slash)
            snprintf(c->profiles_dir, sizeof(c->profiles_dir), "%.*s", (int)(slash - path), path);
        else
            snprintf(c->profiles_dir, sizeof(c->profiles_dir), ".");
        rc = farmcfg_parse(c, b.data ? b.data : "", b.len, path, err);
    }
    buf_release(&b);
    return rc;
}

const char *
farmcfg_option_name(size_t i, bool *printer)
{
    if (i >= N_OPTIONS) {
        const struct drv_option *o = drv_link_option_at(i - N_OPTIONS);
        if (o && printer)
            *printer = true;
        return o ? o->name : NULL;
    }
    if (printer)
        *printer = options[i].printer;
    return options[i].name;
}

void
farmcfg_printer_each(const struct farmcfg_printer *p, farmcfg_option_fn fn, void *ud)
{
    char v[300];
    for (size_t i = 0; i < N_OPTIONS; i++) {
        const struct option *o = &options[i];
        const char *field = (const char *)p + o->off;
        if (!o->printer)
            continue;
        if (o->kind == K_STR || o->kind == K_IDENT)
            snprintf(v, sizeof(v), "%s", field);
        else if (o->kind == K_DBL)
            snprintf(v, sizeof(v), "%.15g", *(const double *)field);
        else if (o->kind == K_BOOL)
            snprintf(v, sizeof(v), "%s", *(const bool *)field ? "true" : "false");
        else /* K_TRIPLE, the one other kind a printer option has */
            snprintf(v, sizeof(v), "%.15g, %.15g, %.15g", ((const double *)field)[0],
                     ((const double *)field)[1], ((const double *)field)[2]);
        fn(ud, o->name, v, false);
    }
    for (size_t i = 0; i < p->link.n; i++) {
        const struct drv_link_val *lv = &p->link.v[i];
        const struct drv_option *o = lv->opt;
        const char *t = p->link.text + lv->at;
        size_t pre = o->prefix ? strlen(o->prefix) : 0;
        if (o->type == DRV_OPT_INT)
            snprintf(v, sizeof(v), "%d", lv->num);
        else if (o->type == DRV_OPT_BOOL)
            snprintf(v, sizeof(v), "%s", lv->num ? "true" : "false");
        else /* text, as given: without the prefix drv_link_set put before it */
            snprintf(v, sizeof(v), "%s", pre && strncmp(t, o->prefix, pre) == 0 ? t + pre : t);
        fn(ud, o->name, v, (o->flags & DRV_OPT_SECRET) != 0);
    }
}

void
farmcfg_policy(const struct farmcfg_printer *p, struct gpolicy *out)
{
    gpolicy_init(out);
    out->attended = p->attended;
    gpolicy_allow(out, p->allow_gcode, NULL); /* checked when it was parsed */
}

const struct farmcfg_printer *
farmcfg_printer(const struct farmcfg *c, const char *name)
{
    for (size_t i = 0; i < c->n_printers; i++)
        if (strcmp(c->printers[i].name, name) == 0)
            return &c->printers[i];
    return NULL;
}

const struct farmcfg_key *
farmcfg_key(const struct farmcfg *c, const char *key)
{
    const struct farmcfg_key *found = NULL;
    size_t klen = strlen(key);
    for (size_t i = 0; i < c->n_keys; i++) {
        /* Compare every byte of every key so timing says nothing about where
           a guess went wrong. */
        const char *k = c->keys[i].key;
        size_t n = strlen(k);
        unsigned char diff = (unsigned char)(n != klen);
        for (size_t j = 0; j < n; j++)
            diff |= (unsigned char)(k[j] ^ (j < klen ? key[j] : 0));
        if (!diff)
            found = &c->keys[i];
    }
    return found;
}
