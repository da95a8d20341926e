/*
 * gcode.c - G-code line tokenizer and host-protocol checksum (see gcode.h).
 *
 * Numbers are scanned by hand rather than with strtod: strtod honours the
 * locale, accepts hex, "inf" and "nan", and reads past the word into things
 * like "1e5" that Marlin would not; G-code numbers are plain decimals with
 * an optional sign and point.
 */
#include "gcode.h"

#include <ctype.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

/* True for commands whose rest of line is free text (file names, messages). */
static bool
takes_text(char letter, int code)
{
    if (letter != 'M')
        return false;
    switch (code) {
    case 23:  /* select SD file */
    case 28:  /* begin SD write */
    case 30:  /* delete SD file */
    case 32:  /* select and start */
    case 117: /* LCD message */
    case 118: /* serial echo */
    case 928: /* start SD logging */
        return true;
    }
    return false;
}

/*
 * Scan a decimal number at s[*i..len); on success store it, advance *i.
 * Accepts [+-]digits[.digits] and [+-].digits; at most 18 significant digits
 * are kept so the value never overflows.
 */
static bool
scan_number(const char *s, size_t len, size_t *i, double *out)
{
    size_t p = *i;
    bool neg = false;
    if (p < len && (s[p] == '+' || s[p] == '-')) {
        neg = s[p] == '-';
        p++;
    }
    double v = 0;
    int digits = 0;
    while (p < len && isdigit((unsigned char)s[p])) {
        if (digits < 18)
            v = v * 10 + (s[p] - '0');
        else
            v *= 10;
        digits++;
        p++;
        if (v > 1e300)
            return false;
    }
    if (p < len && s[p] == '.') {
        p++;
        double scale = 0.1;
        while (p < len && isdigit((unsigned char)s[p])) {
            v += (s[p] - '0') * scale;
            scale *= 0.1;
            digits++;
            p++;
        }
    }
    if (digits == 0)
        return false;
    *out = neg ? -v : v;
    *i = p;
    return true;
}

static size_t
skip_blanks(const char *s, size_t len, size_t i)
{
    while (i < len && (s[i] == ' ' || s[i] == '\t' || s[i] == '\r' || s[i] == '\n'))
        i++;
    return i;
}

static bool
is_blank(char c)
{
    return c == ' ' || c == '\t' || c == '\r' || c == '\n';
}

/* Skip a ( ... ) comment starting at s[i] == '('. */
static size_t
skip_paren(const char *s, size_t len, size_t i)
{
    while (i < len && s[i] != ')')
        i++;
    return i < len ? i + 1 : i;
}

/*
 * The checksum: it covers everything before the last '*' outside comments.
 * Sets *end to where the line's words end (the '*', the comment or len).
 */
static int
parse_checksum(const char *s, size_t len, struct gcode_line *out, size_t *end_out,
               struct sf_err *err)
{
    size_t end = len;
    for (size_t i = 0; i < len; i++) {
        if (s[i] == ';') {
            end = i;
            break;
        }
    }
    size_t star = end;
    for (size_t i = end; i-- > 0;) {
        if (s[i] == '*') {
            star = i;
            break;
        }
    }
    if (star < end) {
        double cs;
        size_t p = star + 1;
        if (!scan_number(s, end, &p, &cs) || cs < 0 || cs > 255 || cs != floor(cs) ||
            skip_blanks(s, end, p) != end)
            return sf_err_set(err, SF_EINVAL, "column %zu: bad checksum", star + 1);
        out->has_checksum = true;
        out->checksum = (unsigned)cs;
        out->checksum_ok = gcode_checksum(s, star) == out->checksum;
        end = star;
    }
    *end_out = end;
    return SF_OK;
}

/* The parameter words from s[i] to s[end], after the command. */
static int
parse_words(const char *s, size_t end, size_t i, struct gcode_line *out, struct sf_err *err)
{
    for (;;) {
        i = skip_blanks(s, end, i);
        if (i < end && s[i] == '(') {
            i = skip_paren(s, end, i);
            continue;
        }
        if (i >= end)
            break;
        char w = (char)toupper((unsigned char)s[i]);
        if (w < 'A' || w > 'Z')
            return sf_err_set(err, SF_EINVAL, "column %zu: parameter letter expected, found '%c'",
                              i + 1, isprint((unsigned char)s[i]) ? s[i] : '?');
        if (out->n_words == GCODE_WORDS_MAX)
            return sf_err_set(err, SF_EINVAL, "column %zu: more than %d parameters", i + 1,
                              GCODE_WORDS_MAX);
        struct gcode_word *word = &out->words[out->n_words++];
        word->letter = w;
        size_t p = i + 1;
        size_t quote = skip_blanks(s, end, p); /* P "MK3S": blanks may come first */
        if (quote < end && s[quote] == '"') {
            p = quote;
            /* A quoted string value (Prusa's M862.3 P "MK3S", Marlin's
             * GCODE_QUOTED_STRINGS): the word has no number; the first
             * string is kept as the line's text. */
            size_t q = p + 1;
            while (q < end && s[q] != '"')
                q++;
            if (q >= end)
                return sf_err_set(err, SF_EINVAL, "column %zu: unterminated string after '%c'",
                                  p + 1, w);
            word->value = NAN;
            if (!out->text) {
                out->text = s + p + 1;
                out->text_len = q - p - 1;
            }
            i = q + 1;
            continue;
        }
        bool num_ok = scan_number(s, end, &p, &word->value);
        size_t stop = p;
        while (stop < end && !is_blank(s[stop]) && s[stop] != '(')
            stop++;
        if (!num_ok || stop != p) {
            /* A bare letter ("G28 X") is legal.  So is any other value of an
             * M command's word (Prusa's M115 U3.13.0 firmware version):
             * firmware-specific settings, kept as no number.  A move's
             * words must be numbers. */
            if (stop != p && out->letter != 'M')
                return sf_err_set(err, SF_EINVAL, "column %zu: number expected after '%c'", p + 1,
                                  w);
            word->value = NAN;
        }
        i = stop;
    }
    return SF_OK;
}

int
gcode_parse(const char *s, size_t len, struct gcode_line *out, struct sf_err *err)
{
    memset(out, 0, sizeof(*out));
    out->subcode = -1;
    size_t end = len;
    int rc = parse_checksum(s, len, out, &end, err);
    if (rc < 0)
        return rc;

    size_t i = skip_blanks(s, end, 0);
    while (i < end && s[i] == '(')
        i = skip_blanks(s, end, skip_paren(s, end, i));
    if (i < end && (s[i] == 'N' || s[i] == 'n')) {
        double n;
        size_t p = i + 1;
        if (!scan_number(s, end, &p, &n) || n < 0 || n > 2147483647.0 || n != floor(n))
            return sf_err_set(err, SF_EINVAL, "column %zu: bad line number", i + 1);
        out->has_line_no = true;
        out->line_no = (long)n;
        i = skip_blanks(s, end, p);
    }
    if (i >= end)
        return SF_OK;

    char c = (char)toupper((unsigned char)s[i]);
    if (c < 'A' || c > 'Z')
        return sf_err_set(err, SF_EINVAL, "column %zu: command expected, found '%c'", i + 1,
                          isprint((unsigned char)s[i]) ? s[i] : '?');
    size_t p = i + 1;
    double num;
    if (!scan_number(s, end, &p, &num) || num < 0 || num > 99999)
        return sf_err_set(err, SF_EINVAL, "column %zu: number expected after '%c'", i + 2, c);
    out->letter = c;
    out->code = (int)num;
    double frac = num - floor(num);
    if (frac > 1e-9)
        out->subcode = (int)lround(frac * 10);
    i = p;

    if (takes_text(out->letter, out->code)) {
        i = skip_blanks(s, end, i);
        size_t e = end;
        while (e > i &&
               (s[e - 1] == ' ' || s[e - 1] == '\t' || s[e - 1] == '\r' || s[e - 1] == '\n'))
            e--;
        out->text = s + i;
        out->text_len = e - i;
        return SF_OK;
    }

    return parse_words(s, end, i, out, err);
}

bool
gcode_get(const struct gcode_line *l, char letter, double *value)
{
    for (int i = 0; i < l->n_words; i++) {
        if (l->words[i].letter == letter) {
            if (value)
                *value = l->words[i].value;
            return true;
        }
    }
    return false;
}

bool
gcode_is(const struct gcode_line *l, char letter, int code)
{
    return l->letter == letter && l->code == code;
}

size_t
gcode_strip(const char *s, size_t len, char *out, size_t cap, bool *too_long)
{
    if (too_long)
        *too_long = false;
    size_t o = 0;
    size_t i = 0;
    bool pending_space = false;
    bool first_word = true;

    /* Find the ';' comment or the end; '*' checksum is dropped too. */
    size_t end = len;
    for (size_t k = 0; k < len; k++) {
        if (s[k] == ';' || s[k] == '\n' || s[k] == '\r') {
            end = k;
            break;
        }
    }
    while (i < end) {
        char c = s[i];
        if (c == '(') {
            i = skip_paren(s, end, i);
            pending_space = o > 0;
            continue;
        }
        if (c == '*')
            break;
        if (c == '"') {
            /* a quoted string is copied as it is: blanks and '(' included */
            size_t q = i + 1;
            while (q < end && s[q] != '"')
                q++;
            size_t n = (q < end ? q + 1 : q) - i;
            if (pending_space) {
                if (o + 1 >= cap)
                    goto overflow;
                out[o++] = ' ';
                pending_space = false;
            }
            if (o + n >= cap)
                goto overflow;
            memcpy(out + o, s + i, n);
            o += n;
            i += n;
            first_word = false;
            continue;
        }
        if (c == ' ' || c == '\t') {
            pending_space = o > 0;
            i++;
            continue;
        }
        if (first_word && (c == 'N' || c == 'n') && i + 1 < end &&
            (isdigit((unsigned char)s[i + 1]) || s[i + 1] == '-')) {
            /* drop the line number word */
            i++;
            while (i < end && (isdigit((unsigned char)s[i]) || s[i] == '-'))
                i++;
            first_word = false;
            continue;
        }
        first_word = false;
        if (pending_space) {
            if (o + 1 >= cap)
                goto overflow;
            out[o++] = ' ';
            pending_space = false;
        }
        if (o + 1 >= cap)
            goto overflow;
        out[o++] = c;
        i++;
    }
    if (cap)
        out[o] = '\0';
    return o;
overflow:
    if (too_long)
        *too_long = true;
    if (cap)
        out[0] = '\0';
    return 0;
}

uint8_t
gcode_checksum(const char *s, size_t len)
{
    uint8_t cs = 0;
    for (size_t i = 0; i < len; i++)
        cs ^= (uint8_t)s[i];
    return cs;
}

size_t
gcode_number_line(long n, const char *cmd, char *out, size_t cap)
{
    int k = snprintf(out, cap, "N%ld %s", n, cmd);
    if (k < 0 || (size_t)k >= cap)
        return 0;
    uint8_t cs = gcode_checksum(out, (size_t)k);
    int m = snprintf(out + k, cap - (size_t)k, "*%u", cs);
    if (m < 0 || (size_t)(k + m) >= cap)
        return 0;
    return (size_t)(k + m);
}
