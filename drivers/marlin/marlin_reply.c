/*
 * marlin_reply.c - reply-line classifier for the Marlin driver (marlin_reply.h).
 *
 * Why its own module: it is the one place that reads untrusted printer
 * text, so it is small, pure and fuzzed.  Design: copy the line into a
 * bounded NUL-terminated buffer, trim, then match prefixes in the order
 * Marlin can emit them.  Numbers go through strtol/strtod with end-pointer
 * and range checks; a field that fails its check is simply absent.
 *
 * Thread: any (no state).
 */
#include "marlin_reply.h"

#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/base/limits.h"

static bool
get_long(const char *s, long lo, long hi, long *out)
{
    char *end;
    errno = 0;
    long v = strtol(s, &end, 10);
    if (errno || end == s || v < lo || v > hi)
        return false;
    *out = v;
    return true;
}

/* A whole word: the number must end at a blank or the end of the line. */
static bool
get_word_long(const char *s, long lo, long hi, long *out)
{
    char *end;
    errno = 0;
    long v = strtol(s, &end, 10);
    if (errno || end == s || (*end != '\0' && *end != ' ') || v < lo || v > hi)
        return false;
    *out = v;
    return true;
}

static bool
get_double(const char *s, double *out)
{
    char *end;
    errno = 0;
    double v = strtod(s, &end);
    if (errno || end == s || !isfinite(v) || v < -300 || v > 2000)
        return false;
    *out = v;
    return true;
}

/* Find "KEY" as a word start (after start of line or a blank). */
static const char *
find_word(const char *s, const char *key)
{
    size_t k = strlen(key);
    for (const char *p = strstr(s, key); p; p = strstr(p + 1, key))
        if (p == s || p[-1] == ' ')
            return p + k;
    return NULL;
}

/* "KEY:value /target": value into *v, target (if present) into *target. */
static bool
temp_pair(const char *s, const char *key, double *v, double *target)
{
    const char *p = find_word(s, key);
    if (!p)
        return false;
    char *end;
    errno = 0;
    double x = strtod(p, &end);
    if (errno || end == p || !isfinite(x) || x < -300 || x > 2000)
        return false;
    *v = x;
    while (*end == ' ')
        end++;
    if (*end == '/')
        get_double(end + 1, target);
    return true;
}

static void
parse_temps(const char *s, struct mreply *r)
{
    if (!temp_pair(s, "T:", &r->t, &r->t_target))
        return;
    r->has_temps = true;
    r->has_bed = temp_pair(s, "B:", &r->bed, &r->bed_target);
    r->temp_wait = find_word(s, "W:") != NULL;
}

static void
copy_name(struct mreply *r, const char *s)
{
    size_t n = strcspn(s, " \t");
    if (n >= sizeof(r->name))
        n = sizeof(r->name) - 1;
    memcpy(r->name, s, n);
    r->name[n] = '\0';
}

/* An ok, damaged or not, with its N, P, B and temperatures. */
static bool
parse_ok(const char *p, struct mreply *r)
{
    /* "ok" with one byte damaged: "oR T:...", "\x18k T:...", "ok\xcdN12 ...". */
    bool ok_like = strncmp(p, "ok", 2) == 0 && !isalnum((unsigned char)p[2]) && p[2] != ':';
    bool ok_damaged = !ok_like && strlen(p) > 4 && p[2] == ' ' && (p[0] == 'o' || p[1] == 'k') &&
                      (strncmp(p + 3, "T:", 2) == 0 || p[3] == 'N');
    if (!ok_like && !ok_damaged)
        return false;
    r->kind = MR_OK;
    r->garbled = ok_damaged || (p[2] != '\0' && p[2] != ' ');
    const char *w;
    long v;
    if ((w = find_word(p, "N")) && get_word_long(w, 0, 2147483647L, &v)) {
        r->has_n = true;
        r->n = v;
    }
    if ((w = find_word(p, "P")) && get_word_long(w, 0, 4096, &v))
        r->p = (int)v;
    if ((w = find_word(p, "B")) && get_word_long(w, 0, 4096, &v))
        r->b = (int)v;
    parse_temps(p, r);
    return true;
}

/* "Resend: N" or "rs N"; a number that fails its check leaves MR_OTHER. */
static bool
parse_resend(const char *p, struct mreply *r)
{
    if (strncmp(p, "Resend:", 7) != 0 && strncmp(p, "rs ", 3) != 0)
        return false;
    const char *q = p + (p[0] == 'R' ? 7 : 3);
    while (*q == ' ' || *q == 'N')
        q++;
    long v;
    if (get_long(q, 0, 2147483647L, &v)) {
        r->kind = MR_RESEND;
        r->resend = v;
        while (*q >= '0' && *q <= '9')
            q++;
        r->tail = *q != '\0';
    }
    return true;
}

/* "Error:..." or "!!...": its class, and the Last Line it names. */
static bool
parse_error(const char *p, struct mreply *r)
{
    if (strncmp(p, "Error:", 6) != 0 && strncmp(p, "!!", 2) != 0)
        return false;
    r->kind = MR_ERROR;
    const char *ll = strstr(p, "Last Line:");
    long v;
    if (ll && get_long(ll + 10, -1, 2147483647L, &v))
        r->last_line = v;
    if (strstr(p, "checksum") || strstr(p, "Checksum") || strstr(p, "Line Number") ||
        strstr(p, "Last Line")) {
        r->err = MR_ERR_LINE;
        r->resend_follows =
            strstr(p, "mismatch") || strstr(p, "not Last") || strstr(p, "No Checksum");
    } else if (strstr(p, "halted") || strstr(p, "kill()") || strstr(p, "Thermal Runaway") ||
               strstr(p, "MAXTEMP") || strstr(p, "MINTEMP") || strstr(p, "stopped") ||
               strstr(p, "Heating failed") || strncmp(p, "!!", 2) == 0)
        r->err = MR_ERR_FATAL;
    else
        r->err = MR_ERR_OTHER;
    snprintf(r->name, sizeof(r->name), "%s", p + (p[0] == 'E' ? 6 : 2));
    return true;
}

/* "// action:NAME": a host action. */
static bool
parse_action(const char *p, struct mreply *r)
{
    if (strncmp(p, "//", 2) != 0)
        return false;
    const char *q = p + 2;
    while (*q == ' ')
        q++;
    if (strncmp(q, "action:", 7) == 0 && q[7]) {
        r->kind = MR_ACTION;
        copy_name(r, q + 7);
    }
    return true;
}

/* "Cap:NAME:0|1" from M115. */
static bool
parse_cap(const char *p, struct mreply *r)
{
    if (strncmp(p, "Cap:", 4) != 0)
        return false;
    const char *colon = strrchr(p + 4, ':');
    if (colon && (colon[1] == '0' || colon[1] == '1') && colon[2] == '\0' &&
        (size_t)(colon - (p + 4)) < sizeof(r->name)) {
        r->kind = MR_CAP;
        memcpy(r->name, p + 4, (size_t)(colon - (p + 4)));
        r->name[colon - (p + 4)] = '\0';
        r->cap_value = colon[1] - '0';
    }
    return true;
}

/* "FIRMWARE_NAME:..." from M115, up to its SOURCE_CODE_URL. */
static bool
parse_firmware(const char *p, struct mreply *r)
{
    if (strncmp(p, "FIRMWARE_NAME:", 14) != 0)
        return false;
    r->kind = MR_FIRMWARE;
    const char *q = p + 14;
    const char *end = strstr(q, " SOURCE_CODE_URL:");
    size_t n = end ? (size_t)(end - q) : strlen(q);
    if (n >= sizeof(r->name))
        n = sizeof(r->name) - 1;
    memcpy(r->name, q, n);
    r->name[n] = '\0';
    return true;
}

void
mreply_parse(const char *line, size_t len, struct mreply *r)
{
    memset(r, 0, sizeof(*r));
    r->p = r->b = -1;
    r->last_line = -1;
    char s[SF_PRINTER_LINE_MAX + 1];
    if (len > SF_PRINTER_LINE_MAX)
        len = SF_PRINTER_LINE_MAX;
    size_t o = 0;
    for (size_t i = 0; i < len; i++)
        s[o++] = line[i] == '\0' ? '?' : line[i]; /* NUL inside a garbled line */
    while (o > 0 && (s[o - 1] == '\r' || s[o - 1] == '\n' || s[o - 1] == ' '))
        o--;
    s[o] = '\0';
    const char *p = s;
    while (*p == ' ')
        p++;

    if (parse_ok(p, r) || parse_resend(p, r) || parse_error(p, r))
        return;
    if (strncmp(p, "echo:busy:", 10) == 0 || strncmp(p, "busy:", 5) == 0) {
        r->kind = MR_BUSY;
        return;
    }
    if (strncmp(p, "echo:", 5) == 0) {
        r->kind = MR_ECHO;
        snprintf(r->name, sizeof(r->name), "%s", p + 5);
        return;
    }
    if (strcmp(p, "wait") == 0) {
        r->kind = MR_WAIT;
        return;
    }
    if (strcmp(p, "start") == 0) {
        r->kind = MR_START;
        return;
    }
    if (parse_action(p, r) || parse_cap(p, r) || parse_firmware(p, r))
        return;
    if (strncmp(p, "T:", 2) == 0) {
        parse_temps(p, r);
        if (r->has_temps)
            r->kind = MR_TEMP;
        return;
    }
}
