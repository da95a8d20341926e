/*
 * notifycfg.c - the options of a [notify NAME] section (notifycfg.h).
 *
 * Why apart from farmcfg.c: the section has its own dozen options and
 * checks (schemes, addresses, event names, a template), and farmcfg.c
 * only routes the section's lines here.  Each check names its option;
 * farmcfg adds file:line and the section.
 *
 * Thread: any; no state.
 */
#include "notifycfg.h"

#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char *const event_names[] = { "job-done",      "job-failed",      "bed-clear",
                                           "printer-error", "printer-offline", "queue-empty" };
#define N_EVENTS (sizeof(event_names) / sizeof(event_names[0]))

static const char *const format_names[] = { "json", "ntfy", "discord", "slack", "template" };
#define N_FORMATS (sizeof(format_names) / sizeof(format_names[0]))

/* The options, in the order of the seen bits. */
static const char *const option_names[] = { "url",          "events",   "format",   "template",
                                            "content_type", "token",    "from",     "to",
                                            "user",         "password", "starttls", "retries",
                                            "timeout_s" };
#define N_OPTIONS (sizeof(option_names) / sizeof(option_names[0]))

static int say(char *why, size_t cap, const char *fmt, ...) __attribute__((format(printf, 3, 4)));

static int
say(char *why, size_t cap, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    if (why && cap)
        vsnprintf(why, cap, fmt, ap);
    va_end(ap);
    return -1;
}

const char *
notify_event_name(enum notify_event e)
{
    for (size_t i = 0; i < N_EVENTS; i++)
        if ((unsigned)e == 1u << i)
            return event_names[i];
    return "?";
}

void
notifycfg_init(struct notifycfg *t, const char *name, int line)
{
    memset(t, 0, sizeof(*t));
    snprintf(t->name, sizeof(t->name), "%s", name);
    t->line = line;
    t->events = NOTIFY_ALL;
    snprintf(t->content_type, sizeof(t->content_type), "text/plain");
    t->retries = 4;
    t->timeout_s = 10;
}

static bool
has_prefix(const char *s, const char *p)
{
    return strncmp(s, p, strlen(p)) == 0;
}

bool
notifycfg_is_mail(const struct notifycfg *t)
{
    return has_prefix(t->url, "smtp://") || has_prefix(t->url, "smtps://");
}

bool
notifycfg_has_secret(const struct notifycfg *t)
{
    const char *host = strstr(t->url, "://");
    /* a webhook's path is often its key (Discord, Slack, an ntfy topic) */
    const char *path = host ? strpbrk(host + 3, "/?") : NULL;
    return t->token[0] || t->password[0] || (path && path[1]);
}

/* "job-done, bed-clear" or "all" into bits. */
static int
parse_events(const char *v, unsigned *out, char *why, size_t cap)
{
    unsigned bits = 0;
    for (const char *p = v; *p;) {
        p += strspn(p, " ,");
        size_t n = strcspn(p, " ,");
        if (!n)
            break;
        bool known = false;
        if (n == 3 && strncmp(p, "all", 3) == 0) {
            bits = NOTIFY_ALL;
            known = true;
        }
        for (size_t i = 0; i < N_EVENTS && !known; i++)
            if (strlen(event_names[i]) == n && strncmp(p, event_names[i], n) == 0) {
                bits |= 1u << i;
                known = true;
            }
        if (!known)
            return say(why, cap,
                       "option 'events': '%.*s' is not one of all, job-done, job-failed, "
                       "bed-clear, printer-error, printer-offline, queue-empty",
                       (int)(n > 40 ? 40 : n), p);
        p += n;
    }
    if (!bits)
        return say(why, cap, "option 'events': name at least one event");
    *out = bits;
    return 1;
}

/* A text option into dst (cap bytes), no control bytes (they would split a header). */
static int
text(const char *opt, const char *v, char *dst, size_t cap, char *why, size_t why_cap)
{
    if (strlen(v) >= cap)
        return say(why, why_cap, "option '%s': value is longer than %zu bytes", opt, cap - 1);
    for (const char *c = v; *c; c++)
        if ((unsigned char)*c < ' ' || *c == 0x7f)
            return say(why, why_cap, "option '%s': value holds a control byte", opt);
    snprintf(dst, cap, "%s", v);
    return 1;
}

static int
number(const char *opt, const char *v, int lo, int hi, int *out, char *why, size_t cap)
{
    char *end;
    errno = 0;
    long n = strtol(v, &end, 10);
    if (end == v || *end || errno || n < lo || n > hi)
        return say(why, cap, "option '%s': '%s' is not a whole number in %d..%d", opt, v, lo, hi);
    *out = (int)n;
    return 1;
}

static int
take(struct notifycfg *t, size_t i, const char *v, char *why, size_t cap)
{
    const char *o = option_names[i];
    switch (i) {
    case 0:
        return text(o, v, t->url, sizeof(t->url), why, cap);
    case 1:
        return parse_events(v, &t->events, why, cap);
    case 2:
        for (size_t f = 0; f < N_FORMATS; f++)
            if (strcmp(v, format_names[f]) == 0) {
                t->format = (enum notify_format)f;
                return 1;
            }
        return say(why, cap,
                   "option 'format': '%.40s' is not one of json, ntfy, discord, "
                   "slack, template",
                   v);
    case 3:
        return text(o, v, t->template_text, sizeof(t->template_text), why, cap);
    case 4:
        return text(o, v, t->content_type, sizeof(t->content_type), why, cap);
    case 5:
        return text(o, v, t->token, sizeof(t->token), why, cap);
    case 6:
        return text(o, v, t->from, sizeof(t->from), why, cap);
    case 7:
        return text(o, v, t->to, sizeof(t->to), why, cap);
    case 8:
        return text(o, v, t->user, sizeof(t->user), why, cap);
    case 9:
        return text(o, v, t->password, sizeof(t->password), why, cap);
    case 10:
        if (strcmp(v, "true") && strcmp(v, "false") && strcmp(v, "yes") && strcmp(v, "no"))
            return say(why, cap, "option 'starttls': '%.40s' is not true or false", v);
        t->starttls = strcmp(v, "true") == 0 || strcmp(v, "yes") == 0;
        return 1;
    case 11:
        return number(o, v, 0, NOTIFYCFG_RETRIES_MAX, &t->retries, why, cap);
    default:
        return number(o, v, 1, 300, &t->timeout_s, why, cap);
    }
}

int
notifycfg_option(struct notifycfg *t, const char *name, const char *value, char *why,
                 size_t why_cap)
{
    for (size_t i = 0; i < N_OPTIONS; i++) {
        if (strcmp(name, option_names[i]) != 0)
            continue;
        if (t->seen & (1u << i))
            return say(why, why_cap, "option '%s' is given twice", name);
        t->seen |= 1u << i;
        return take(t, i, value, why, why_cap);
    }
    return 0;
}

/* One address: something@host, no spaces or angle brackets (they go in the SMTP envelope). */
static bool
address_ok(const char *a, size_t n)
{
    const char *at = memchr(a, '@', n);
    if (!at || at == a || at == a + n - 1)
        return false;
    for (size_t i = 0; i < n; i++)
        if (a[i] == ' ' || a[i] == '<' || a[i] == '>' || a[i] == ',' || a[i] == '"')
            return false;
    return true;
}

static int
check_mail(const struct notifycfg *t, char *why, size_t cap)
{
    if (!t->from[0] || !address_ok(t->from, strlen(t->from)))
        return say(why, cap,
                   "option 'from': a mail target needs one sender address, "
                   "name@host");
    size_t n_to = 0;
    for (const char *p = t->to; *p;) {
        p += strspn(p, " ,");
        size_t n = strcspn(p, " ,");
        if (!n)
            break;
        if (!address_ok(p, n))
            return say(why, cap, "option 'to': '%.*s' is not an address name@host",
                       (int)(n > 60 ? 60 : n), p);
        n_to++;
        p += n;
    }
    if (!n_to)
        return say(why, cap, "option 'to': a mail target needs at least one recipient");
    if (t->user[0] != 0 && !t->password[0])
        return say(why, cap, "options 'user' and 'password' go together");
    if (t->token[0] || t->seen & (1u << 2) || t->template_text[0])
        return say(why, cap,
                   "options 'token', 'format' and 'template' are for webhooks, "
                   "not smtp:// targets");
    return 0;
}

int
notifycfg_check(const struct notifycfg *t, char *why, size_t why_cap)
{
    if (!t->url[0])
        return say(why, why_cap, "option 'url' is required");
    bool web = has_prefix(t->url, "http://") || has_prefix(t->url, "https://");
    if (!web && !notifycfg_is_mail(t))
        return say(why, why_cap,
                   "option 'url': it does not start with http://, https://, smtp:// or smtps://");
    const char *host = strstr(t->url, "://") + 3;
    if (!*host || *host == '/' || *host == ':')
        return say(why, why_cap, "option 'url': it has no host");
    for (const char *c = t->url; *c; c++)
        if (*c == ' ' || *c == '"' || *c == '\\')
            return say(why, why_cap, "option 'url': it holds a space, quote or backslash");
    if (notifycfg_is_mail(t))
        return check_mail(t, why, why_cap);
    if (t->from[0] || t->to[0] || t->user[0] || t->password[0] || t->starttls)
        return say(why, why_cap,
                   "options 'from', 'to', 'user', 'password' and 'starttls' are "
                   "for smtp:// targets, not webhooks");
    if ((t->format == NOTIFY_FMT_TEMPLATE) != (t->template_text[0] != 0))
        return say(why, why_cap, "options 'format: template' and 'template' go together");
    return 0;
}
