/*
 * test_base.c - err, mem, buf and the G-code tokenizer.
 */
#include <math.h>
#include <stdlib.h>
#include <unistd.h>

#include "../../src/base/buf.h"
#include "../../src/base/err.h"
#include "../../src/base/gcode.h"
#include "../../src/base/log.h"
#include "../../src/base/mem.h"
#include "../t.h"

T_CASE(err_set_returns_code_and_formats)
{
    struct sf_err err;
    T_EQ_INT(sf_err_set(&err, SF_EINVAL, "facet %d: %s", 12, "normal is NaN"), SF_EINVAL);
    T_EQ_STR(err.msg, "facet 12: normal is NaN");
    sf_err_prefix(&err, "stl '%s'", "a.stl");
    T_EQ_STR(err.msg, "stl 'a.stl': facet 12: normal is NaN");
    T_EQ_INT(sf_err_set(NULL, SF_EIO, "x"), SF_EIO);
    T_EQ_STR(sf_status_name(SF_ETIMEDOUT), "ETIMEDOUT");
}

T_CASE(err_sys_keeps_errno)
{
    struct sf_err err;
    struct buf b;
    buf_init(&b, 0);
    T_EQ_INT(buf_read_file(&b, "/nonexistent/x", &err), SF_EIO);
    T_TRUE(strstr(err.msg, "No such file") != NULL);
    T_TRUE(err.sys_errno != 0);
}

T_CASE(mem_injected_failure)
{
    mem_fail_after(2);
    void *a = mem_alloc(8);
    void *b = mem_alloc(8);
    mem_fail_after(0);
    T_TRUE(a != NULL);
    T_TRUE(b == NULL);
    free(a);
    T_TRUE(mem_array((size_t)1 << 62, 16) == NULL);
}

T_CASE(buf_cap_enforced)
{
    struct buf b;
    buf_init(&b, 10);
    T_OK(buf_append(&b, "12345", 5), NULL);
    T_OK(buf_printf(&b, "%d", 6789), NULL);
    T_EQ_STR(b.data, "123456789");
    T_EQ_INT(buf_append(&b, "ab", 2), SF_ENOMEM);
    T_EQ_INT(b.len, 9);
    buf_consume(&b, 4);
    T_EQ_STR(b.data, "56789");
    size_t n;
    char *s = buf_take(&b, &n);
    T_EQ_INT(n, 5);
    T_EQ_STR(s, "56789");
    free(s);
    buf_release(&b);
}

T_CASE(buf_read_file_over_cap)
{
    char path[300];
    snprintf(path, sizeof(path), "%s/f", t_tmpdir());
    FILE *f = fopen(path, "w");
    fputs("0123456789abcdef", f);
    fclose(f);
    struct buf b;
    struct sf_err err;
    buf_init(&b, 16);
    T_OK(buf_read_file(&b, path, &err), &err);
    T_EQ_INT(b.len, 16);
    buf_release(&b);
    buf_init(&b, 15);
    T_ERR(buf_read_file(&b, path, &err), SF_ENOMEM, &err, "over the limit");
    buf_release(&b);
}

T_CASE(gcode_parse_move)
{
    struct gcode_line l;
    struct sf_err err;
    const char *s = "G1 X10.5 Y-3 E.25 F1800 ; move";
    T_OK(gcode_parse(s, strlen(s), &l, &err), &err);
    T_TRUE(gcode_is(&l, 'G', 1));
    double v;
    T_TRUE(gcode_get(&l, 'X', &v));
    T_EQ_DBL(v, 10.5, 1e-12);
    T_TRUE(gcode_get(&l, 'Y', &v));
    T_EQ_DBL(v, -3, 1e-12);
    T_TRUE(gcode_get(&l, 'E', &v));
    T_EQ_DBL(v, 0.25, 1e-12);
    T_TRUE(!gcode_get(&l, 'Z', &v));
    T_EQ_INT(l.n_words, 4);
}

T_CASE(gcode_line_number_and_checksum)
{
    char out[128];
    size_t n = gcode_number_line(3, "M105", out, sizeof(out));
    /* Marlin docs: "N3 M105*..." with XOR checksum of everything before '*' */
    T_TRUE(n > 0);
    struct gcode_line l;
    struct sf_err err;
    T_OK(gcode_parse(out, n, &l, &err), &err);
    T_TRUE(l.has_line_no && l.line_no == 3);
    T_TRUE(l.has_checksum && l.checksum_ok);
    T_TRUE(gcode_is(&l, 'M', 105));
    out[1] = '4'; /* corrupt the line number: checksum must now fail */
    T_OK(gcode_parse(out, n, &l, &err), &err);
    T_TRUE(!l.checksum_ok);
    /* The classic documented example: "N1 M110 N0*125"? compute by hand. */
    const char *m110 = "N0 M110 N0";
    T_EQ_INT(gcode_checksum(m110, strlen(m110)),
             'N' ^ '0' ^ ' ' ^ 'M' ^ '1' ^ '1' ^ '0' ^ ' ' ^ 'N' ^ '0');
}

T_CASE(gcode_text_argument)
{
    struct gcode_line l;
    struct sf_err err;
    const char *s = "M117 Printing part 3 of 7  ";
    T_OK(gcode_parse(s, strlen(s), &l, &err), &err);
    T_TRUE(gcode_is(&l, 'M', 117));
    T_EQ_INT(l.text_len, strlen("Printing part 3 of 7"));
    T_TRUE(memcmp(l.text, "Printing part 3 of 7", l.text_len) == 0);
}

T_CASE(gcode_quoted_string_value)
{
    /* Prusa start G-code: M862.3 P "MK3S" checks the printer model */
    struct gcode_line l;
    struct sf_err err;
    const char *s = "M862.3 P \"MK3S (x)\" Q1";
    T_OK(gcode_parse(s, strlen(s), &l, &err), &err);
    T_TRUE(gcode_is(&l, 'M', 862) && l.subcode == 3);
    double v;
    T_TRUE(gcode_get(&l, 'P', &v) && isnan(v));
    T_TRUE(gcode_get(&l, 'Q', &v) && v == 1);
    T_EQ_INT(l.text_len, strlen("MK3S (x)"));
    T_TRUE(memcmp(l.text, "MK3S (x)", l.text_len) == 0);
    s = "M115 U3.13.0"; /* Prusa: warn when the firmware is older */
    T_OK(gcode_parse(s, strlen(s), &l, &err), &err);
    T_TRUE(gcode_get(&l, 'U', &v) && isnan(v));
    T_ERR(gcode_parse("G1 X3.13.0", 10, &l, &err), SF_EINVAL, &err, "number expected after 'X'");
    T_ERR(gcode_parse("M862.3 P \"MK3S", 14, &l, &err), SF_EINVAL, &err,
          "unterminated string after 'P'");
    char out[64];
    T_EQ_INT(gcode_strip("N7 M862.3  P\"MK3S  (x)\" ; c", 27, out, sizeof(out), NULL), 19);
    T_EQ_STR(out, "M862.3 P\"MK3S  (x)\"");
    T_EQ_INT(gcode_strip("M862.3 P\"MK3S\"", 14, out, 10, NULL), 0);
}

T_CASE(gcode_rejects_garbage)
{
    struct gcode_line l;
    struct sf_err err;
    T_ERR(gcode_parse("G1 XQ1", 6, &l, &err), SF_EINVAL, &err, "number expected after 'X'");
    T_ERR(gcode_parse("#$%", 3, &l, &err), SF_EINVAL, &err, "command expected");
    T_ERR(gcode_parse("G1 X1*300", 9, &l, &err), SF_EINVAL, &err, "bad checksum");
    T_OK(gcode_parse("  ; only a comment", 18, &l, &err), &err);
    T_EQ_INT(l.letter, 0);
    T_OK(gcode_parse("G28 X (home x)", 14, &l, &err), &err);
    double v;
    T_TRUE(gcode_get(&l, 'X', &v) && isnan(v));
}

T_CASE(gcode_strip_removes_comments_numbers_checksums)
{
    char out[64];
    bool too_long;
    T_EQ_INT(gcode_strip("N12 G1  X1 (c) Y2*33 ; hi", 25, out, sizeof(out), &too_long), 8);
    T_EQ_STR(out, "G1 X1 Y2");
    T_EQ_INT(gcode_strip("   ; nothing", 12, out, sizeof(out), NULL), 0);
    T_EQ_INT(gcode_strip("G1 X1234567", 11, out, 6, &too_long), 0);
    T_TRUE(too_long);
}

struct sink_seen {
    int n;
    char last[256];
};

static void
sink(void *ud, enum log_level level, const char *subsys, const char *printer, const char *msg)
{
    struct sink_seen *s = ud;
    (void)level;
    (void)subsys;
    s->n++;
    snprintf(s->last, sizeof(s->last), "%s:%s", printer ? printer : "-", msg);
}

T_CASE(log_printer_rate_limits_repeats)
{
    struct sink_seen seen = { 0 };
    log_set_sink(sink, &seen);
    for (int i = 0; i < 50; i++)
        log_printer(LOG_WARN, "mk3-a", "cable flapping");
    log_printer(LOG_WARN, "mk3-b", "cable flapping");
    log_set_sink(NULL, NULL);
    T_EQ_INT(seen.n, 2);
    T_EQ_STR(seen.last, "mk3-b:cable flapping");
}
