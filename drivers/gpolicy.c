/*
 * gpolicy.c - the G-code policy of gpolicy.h: one table of commands, the
 * line judge, and the file reader that judges every line of a job.
 *
 * A line is judged in three steps: its bytes (control bytes anywhere,
 * non-ASCII outside a comment), its command word (after an optional line
 * number "N12"; "M0110" is M110 as Marlin reads it; Klipper's extended
 * commands are one word, "SAVE_CONFIG"), then two rules that read the
 * text: any line holding "M110" outside a comment (Marlin's queue.cpp
 * takes the number after "M110" as the new line number when a line's text
 * holds it, whatever the command), and M117/M118 text that would print a
 * line the host reads as a reply (M118 without E1 or A1 prints its text
 * raw on the serial line).  The table is data: a row's command, its action
 * for files and for manual commands, whether farm.ini may allow it, and
 * the why every message quotes.
 *
 * Thread: any (pure).
 */
#include "gpolicy.h"

#include <ctype.h>
#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "../src/base/gcode.h"
#include "../src/base/limits.h"
#include "../src/base/mem.h"

/* Row flags. */
#define ALLOWABLE 1u /* farm.ini's allow_gcode may name it */
#define WAIT      2u /* waits for a person: passes on an attended printer */
#define TEXT      4u /* M117/M118: refused only when its text reads as a host reply */

/* One command the policy knows. */
struct row {
    const char *cmd;            /* "M110", "SAVE_CONFIG" */
    enum gpolicy_action file;   /* in a job file, unless allowed */
    enum gpolicy_action manual; /* as a manual command, unless allowed */
    unsigned flags;             /* ALLOWABLE, WAIT, TEXT */
    const char *why;            /* why it is refused */
};

#define R GPOLICY_REFUSE
#define P GPOLICY_PASS
#define W GPOLICY_REWRITE

static const struct row rows[] = {
    { "M110", R, R, 0,
      "the host numbers the lines: a line number reset breaks the stream (lines lost or run "
      "again)" },
    { "M111", R, R, 0, "debug flags change what the firmware tells the host" },
    { "M112", R, R, 0,
      "an emergency stop halts the printer until it is reset: use the farm's emergency stop" },
    { "M108", R, P, 0, "breaks a heating wait or a prompt the job relies on" },
    { "M410", R, P, 0, "a quick stop drops planned moves: the position is lost" },
    { "M999", R, R, 0, "restarts a halted printer and asks the host to resend" },
    { "M117", R, R, TEXT, "its text would read as a host reply (ok, Resend, Error, busy, ...)" },
    { "M118", R, W, TEXT,
      "prints its text raw on the serial line, where it reads as a host reply (ok, Resend, "
      "Error, busy, ...): print it with M118 E1" },
    { "M500", R, R, ALLOWABLE, "saves the settings to EEPROM" },
    { "M501", R, R, ALLOWABLE, "loads the settings from EEPROM over the printer's profile" },
    { "M502", R, R, ALLOWABLE, "resets the settings to the firmware's defaults" },
    { "M997", R, R, ALLOWABLE, "starts a firmware update" },
    { "SAVE_CONFIG", R, R, ALLOWABLE, "Klipper: writes printer.cfg and restarts" },
    { "FIRMWARE_RESTART", R, R, ALLOWABLE, "Klipper: restarts the firmware" },
    { "RESTART", R, R, ALLOWABLE, "Klipper: restarts the host software" },
    { "M0", R, R, ALLOWABLE | WAIT, "waits for a person to press the printer's button" },
    { "M1", R, R, ALLOWABLE | WAIT, "waits for a person to press the printer's button" },
    { "M25", R, R, ALLOWABLE | WAIT, "pauses the print until a person resumes it" },
    { "M226", R, R, ALLOWABLE | WAIT, "waits for a pin (a person's switch)" },
    { "M600", R, R, ALLOWABLE | WAIT, "a filament change waits for a person to load filament" },
    { "M601", R, R, ALLOWABLE | WAIT, "pauses the print until a person resumes it" },
    { "PAUSE", R, R, ALLOWABLE | WAIT, "Klipper: pauses the print until a person resumes it" },
};
#define N_ROWS (sizeof(rows) / sizeof(rows[0]))

#undef R
#undef P
#undef W

/* Host replies a printed line must not look like (marlin_reply.c's prefixes, case ignored);
   "start" and "wait" are replies only as the whole line. */
static const char *const replies[] = { "ok",        "resend",
                                       "rs ",       "error",
                                       "!!",        "busy",
                                       "echo:busy", "t:",
                                       "b:",        "cap:",
                                       "//action:", "firmware_name:",
                                       "x:",        "echo:unknown command" };
static const char *const whole[] = { "start", "wait" };

void
gpolicy_init(struct gpolicy *p)
{
    *p = (struct gpolicy){ 0 };
}

void
gpolicy_all(struct gpolicy *p)
{
    gpolicy_init(p);
    for (size_t i = 0; i < N_ROWS; i++)
        if (rows[i].flags & ALLOWABLE)
            p->allow |= (uint64_t)1 << i;
}

/* The rows p passes by allowance (attended: the waits too). */
static uint64_t
passed(const struct gpolicy *p)
{
    uint64_t m = p->allow;
    for (size_t i = 0; p->attended && i < N_ROWS; i++)
        if (rows[i].flags & WAIT)
            m |= (uint64_t)1 << i;
    return m;
}

void
gpolicy_meet(struct gpolicy *acc, const struct gpolicy *p)
{
    acc->allow = passed(acc) & passed(p);
    acc->attended = false;
}

static bool
prefix_ci(const char *s, size_t n, const char *pre)
{
    size_t k = strlen(pre);
    if (n < k)
        return false;
    for (size_t i = 0; i < k; i++)
        if (tolower((unsigned char)s[i]) != pre[i])
            return false;
    return true;
}

/* The row of command word w (n bytes, upper case), or -1. */
static int
find_row(const char *w, size_t n)
{
    for (size_t i = 0; i < N_ROWS; i++)
        if (strlen(rows[i].cmd) == n && memcmp(rows[i].cmd, w, n) == 0)
            return (int)i;
    return -1;
}

int
gpolicy_allow(struct gpolicy *p, const char *list, struct sf_err *err)
{
    uint64_t add = 0;
    const char *s = list;
    while (*s) {
        while (*s == ' ' || *s == ',' || *s == '\t')
            s++;
        if (!*s)
            break;
        char w[32];
        size_t n = 0;
        while (*s && *s != ' ' && *s != ',' && *s != '\t') {
            if (n < sizeof(w) - 1)
                w[n++] = (char)toupper((unsigned char)*s);
            s++;
        }
        w[n] = '\0';
        int r = find_row(w, n);
        if (r < 0 || !(rows[r].flags & ALLOWABLE))
            return sf_err_set(err, SF_EINVAL,
                              r < 0 ? "'%s' is not a command of the G-code policy (M0 M1 M25 "
                                      "M226 M600 M601 PAUSE M500 M501 M502 M997 SAVE_CONFIG "
                                      "FIRMWARE_RESTART RESTART may be allowed)"
                                    : "'%s' is the host's protocol: it cannot be allowed",
                              w);
        add |= (uint64_t)1 << r;
    }
    p->allow |= add;
    return SF_OK;
}

/* The bytes: a control byte anywhere, a non-ASCII byte before the comment.  True if bad. */
static bool
judge_bytes(const char *b, size_t len, struct gpolicy_verdict *v)
{
    bool comment = false;
    for (size_t i = 0; i < len; i++) {
        unsigned char c = (unsigned char)b[i];
        comment |= c == ';';
        bool ctl = (c < 0x20 && c != '\t' && !(c == '\r' && i + 1 == len)) || c == 0x7f;
        if (ctl || (c >= 0x80 && !comment)) {
            snprintf(v->cmd, sizeof(v->cmd), "byte 0x%02x", c);
            v->why = ctl ? "control bytes are not G-code (a NUL ends a line early, a CR starts "
                           "a new one)"
                         : "non-ASCII bytes are G-code only inside a comment";
            v->action = GPOLICY_REFUSE;
            return true;
        }
    }
    return false;
}

/* The line's command word into w (upper case, "M0110" as "M110"); its end. */
static size_t
command_word(const char *s, size_t len, char *w, size_t wn)
{
    size_t i = 0, k = 0;
    while (i < len && (s[i] == ' ' || s[i] == '\t'))
        i++;
    if (i + 1 < len && (s[i] == 'N' || s[i] == 'n') && isdigit((unsigned char)s[i + 1])) {
        for (i++; i < len && isdigit((unsigned char)s[i]); i++)
            ;
        while (i < len && (s[i] == ' ' || s[i] == '\t'))
            i++;
    }
    w[0] = '\0';
    /* Marlin's parser skips blanks between a command's letter and its
       number: "M 110" runs M110 */
    size_t d = i + 1;
    while (d < len && (s[d] == ' ' || s[d] == '\t'))
        d++;
    if (d < len && isalpha((unsigned char)s[i]) && isdigit((unsigned char)s[d])) {
        w[k++] = (char)toupper((unsigned char)s[i]);
        i = d;
        while (i + 1 < len && s[i] == '0' && isdigit((unsigned char)s[i + 1]))
            i++; /* Marlin reads the number: M0110 runs M110 */
        while (i < len && isdigit((unsigned char)s[i])) {
            if (k < wn - 1)
                w[k++] = s[i];
            i++;
        }
    } else {
        while (i < len && (isalnum((unsigned char)s[i]) || s[i] == '_')) {
            if (k < wn - 1)
                w[k++] = (char)toupper((unsigned char)s[i]);
            i++;
        }
    }
    w[k] = '\0';
    return i;
}

/* Would printed line out (n bytes) read as a host reply? */
static bool
reply_like(const char *out, size_t n)
{
    while (n && *out == ' ') {
        out++;
        n--;
    }
    for (size_t i = 0; i < sizeof(replies) / sizeof(replies[0]); i++) {
        size_t k = strlen(replies[i]);
        /* a word ends the prefix: "ok" and "start" are replies, "okay" and "starting" not */
        if (prefix_ci(out, n, replies[i]) &&
            (k == n || !isalnum((unsigned char)replies[i][k - 1]) ||
             !isalnum((unsigned char)out[k])))
            return true;
    }
    while (n && out[n - 1] == ' ')
        n--;
    for (size_t i = 0; i < sizeof(whole) / sizeof(whole[0]); i++)
        if (n == strlen(whole[i]) && prefix_ci(out, n, whole[i]))
            return true;
    /* an "ok" with a byte damaged, as marlin_reply.c still reads it ("oR T:...") */
    return n > 4 && out[2] == ' ' && (out[0] == 'o' || out[1] == 'k') &&
           (strncmp(out + 3, "T:", 2) == 0 || out[3] == 'N');
}

/*
 * What M117/M118 text t (n bytes) prints, judged; for M118 manual commands
 * the safe rewrite.  True if it reads as a reply.
 */
static bool
judge_text(bool m118, const char *t, size_t n, bool *e1)
{
    bool has_e = false, has_a = false;
    while (n && *t == ' ') {
        t++;
        n--;
    }
    /* M118 parses A1, E1 and Pn off the front, up to three of them (Marlin M118.cpp) */
    for (int k = 0; m118 && k < 3 && n >= 2; k++) {
        bool ae = (t[0] == 'A' || t[0] == 'E') && t[1] == '1';
        if (!ae && !(t[0] == 'P' && isdigit((unsigned char)t[1])))
            break;
        has_e |= t[0] == 'E';
        has_a |= t[0] == 'A';
        t += 2;
        n -= 2;
        while (n && *t == ' ') {
            t++;
            n--;
        }
    }
    *e1 = has_e;
    char out[GPOLICY_LINE_MAX];
    int m = snprintf(out, sizeof(out), "%s%s%.*s", has_e ? "echo:" : "", has_a ? "//" : "",
                     (int)(n < 200 ? n : 200), t);
    return reply_like(out, m < 0 ? 0 : (size_t)m);
}

/* Does the code part hold "M110" (any case), as Marlin's queue check reads a line? */
static bool
holds_m110(const char *s, size_t len)
{
    for (size_t i = 0; i + 4 <= len && s[i] != ';'; i++)
        if (prefix_ci(s + i, len - i, "m110"))
            return true;
    return false;
}

static enum gpolicy_action
verdict(struct gpolicy_verdict *v, enum gpolicy_action a, const char *why)
{
    v->action = a;
    v->why = why;
    return a;
}

/* One form of a line (bytes already judged), by p from src. */
static enum gpolicy_action
judge_line(const struct gpolicy *p, enum gpolicy_source src, const char *line, size_t len,
           struct gpolicy_verdict *v)
{
    size_t code = 0;
    while (code < len && line[code] != ';')
        code++;
    size_t end = command_word(line, code, v->cmd, sizeof(v->cmd));
    int r = find_row(v->cmd, strlen(v->cmd));
    bool text = r < 0 || (rows[r].flags & TEXT);
    if (!text && !(passed(p) & ((uint64_t)1 << r))) {
        enum gpolicy_action a = src == GPOLICY_FILE ? rows[r].file : rows[r].manual;
        if (a != GPOLICY_PASS)
            return verdict(v, a, rows[r].why);
    }
    /* whatever the command, even one a printer allows (Marlin's queue.cpp) */
    if (holds_m110(line, code))
        return verdict(v, GPOLICY_REFUSE,
                       "the line holds \"M110\", which Marlin reads as a line number reset");
    if (text) {
        bool e1 = false;
        if (r < 0 || !judge_text(strcmp(v->cmd, "M118") == 0, line + end, code - end, &e1))
            return GPOLICY_PASS;
        if (e1 || src == GPOLICY_FILE || rows[r].manual != GPOLICY_REWRITE)
            return verdict(v, GPOLICY_REFUSE, rows[r].why);
        const char *t = line + end;
        size_t n = code - end;
        while (n && *t == ' ') {
            t++;
            n--;
        }
        snprintf(v->line, sizeof(v->line), "M118 E1 %.*s", (int)(n < 200 ? n : 200), t);
        if (judge_text(true, v->line + 4, strlen(v->line + 4), &e1)) { /* "echo:busy" */
            v->line[0] = '\0';
            return verdict(v, GPOLICY_REFUSE, rows[r].why);
        }
        return verdict(v, GPOLICY_REWRITE, "its text would read as a host reply: echoed instead");
    }
    return GPOLICY_PASS;
}

enum gpolicy_action
gpolicy_check_line(const struct gpolicy *p, enum gpolicy_source src, const char *line, size_t len,
                   struct gpolicy_verdict *v)
{
    *v = (struct gpolicy_verdict){ .action = GPOLICY_PASS, .why = "" };
    if (judge_bytes(line, len, v))
        return v->action;
    /* The line as a Marlin printer receives it first: the driver sends
       gcode_strip's form, without (paren) comments, line number or
       checksum, so "M(x)110" arrives as "M 110" and "M118 (x)ok" prints
       "ok".  Then the line as written, for the hosts that send it whole. */
    char sent[SF_GCODE_LINE_MAX];
    size_t n = gcode_strip(line, len, sent, sizeof(sent), NULL);
    if (n && (n != len || memcmp(sent, line, n) != 0) &&
        judge_line(p, src, sent, n, v) != GPOLICY_PASS)
        return v->action;
    *v = (struct gpolicy_verdict){ .action = GPOLICY_PASS, .why = "" };
    return judge_line(p, src, line, len, v);
}

/* The findings of one file or text: counted, the first GPOLICY_FINDINGS_MAX written. */
struct report {
    const struct gpolicy *p;
    char *msg;    /* the caller's */
    size_t n;     /* its size */
    size_t used;  /* bytes written */
    size_t found; /* lines refused */
    uint64_t line;
};

static void add(struct report *r, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

static void
add(struct report *r, const char *fmt, ...)
{
    if (r->used >= r->n)
        return;
    va_list ap;
    va_start(ap, fmt);
    int m = vsnprintf(r->msg + r->used, r->n - r->used, fmt, ap);
    va_end(ap);
    if (m > 0)
        r->used += (size_t)m < r->n - r->used ? (size_t)m : r->n - r->used - 1;
}

/* Judge one line of a file (its first SF_GCODE_LINE_MAX bytes, no line end). */
static void
judge(struct report *r, const char *b, size_t len)
{
    struct gpolicy_verdict v;
    r->line++;
    if (gpolicy_check_line(r->p, GPOLICY_FILE, b, len, &v) == GPOLICY_PASS)
        return;
    if (++r->found <= GPOLICY_FINDINGS_MAX)
        add(r, "%sline %llu: %s: %s", r->found > 1 ? "; " : "", (unsigned long long)r->line, v.cmd,
            v.why);
}

static void
finish(struct report *r)
{
    if (r->found > GPOLICY_FINDINGS_MAX)
        add(r, "; and %zu more", r->found - GPOLICY_FINDINGS_MAX);
}

size_t
gpolicy_check_text(const struct gpolicy *p, const char *text, size_t len, const char *name,
                   char *msg, size_t n)
{
    struct report r = { .p = p, .msg = msg, .n = n };
    if (n)
        msg[0] = '\0';
    add(&r, "G-code '%s': ", name);
    size_t s = 0;
    for (size_t i = 0; i <= len; i++)
        if (i == len || text[i] == '\n') {
            if (i > s || i < len)
                judge(&r, text + s, i - s > SF_GCODE_LINE_MAX ? SF_GCODE_LINE_MAX : i - s);
            s = i + 1;
        }
    finish(&r);
    if (!r.found && n)
        msg[0] = '\0';
    return r.found;
}

/*
 * Read fp in blocks, judging each line by its first SF_GCODE_LINE_MAX bytes
 * (a longer line is refused by the scan, gcheck.h, in any case).
 */
static int
read_lines(struct report *r, FILE *fp, char *line)
{
    enum { BLOCK = 1 << 16 };
    char *b = mem_alloc(BLOCK);
    if (!b)
        return SF_ENOMEM;
    size_t len = 0, got;
    bool any = false;
    while ((got = fread(b, 1, BLOCK, fp)) > 0) {
        for (size_t i = 0; i < got; i++) {
            if (b[i] == '\n') {
                judge(r, line, len);
                len = 0;
                any = false;
            } else {
                any = true;
                if (len < SF_GCODE_LINE_MAX)
                    line[len++] = b[i];
            }
        }
    }
    if (any)
        judge(r, line, len);
    int rc = ferror(fp) ? SF_EIO : SF_OK;
    free(b);
    return rc;
}

int
gpolicy_check_file(const struct gpolicy *p, const char *path, const char *name, char *msg, size_t n,
                   size_t *n_found, struct sf_err *err)
{
    struct report r = { .p = p, .msg = msg, .n = n };
    if (n)
        msg[0] = '\0';
    if (n_found)
        *n_found = 0;
    FILE *fp = fopen(path, "rb");
    if (!fp) {
        sf_err_set(err, SF_EIO, "G-code '%s': %s", name, strerror(errno));
        add(&r, "G-code '%s': cannot be read", name);
        return SF_EIO;
    }
    char *line = mem_alloc(SF_GCODE_LINE_MAX);
    int rc = line ? SF_OK : SF_ENOMEM;
    add(&r, "G-code '%s': ", name);
    if (!rc)
        rc = read_lines(&r, fp, line);
    free(line);
    fclose(fp);
    if (rc) {
        if (n) /* the error, not a report begun on a file that could not be read */
            msg[0] = '\0';
        return sf_err_set(err, rc, "G-code '%s': %s", name,
                          rc == SF_EIO ? "read failed" : "out of memory");
    }
    finish(&r);
    if (n_found)
        *n_found = r.found;
    if (!r.found) {
        if (n)
            msg[0] = '\0';
        return SF_OK;
    }
    return sf_err_set(err, SF_EINVAL, "%s", msg);
}

bool
gpolicy_row(size_t i, const char **cmd, enum gpolicy_action *file, enum gpolicy_action *manual,
            bool *allowable, const char **why)
{
    if (i >= N_ROWS)
        return false;
    *cmd = rows[i].cmd;
    *file = rows[i].file;
    *manual = rows[i].manual;
    *allowable = (rows[i].flags & ALLOWABLE) != 0;
    *why = rows[i].why;
    return true;
}
