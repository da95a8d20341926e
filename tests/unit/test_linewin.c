/*
 * test_linewin.c - the line window and the reply classifier: numbering,
 * checksums, acknowledgements with and without ADVANCED_OK, Marlin's
 * repeated Resend after a bad line, resync after a probe, garbled replies.
 */
#include "../../drivers/marlin/linewin.h"
#include "../../drivers/marlin/marlin_reply.h"
#include "../../src/base/gcode.h"
#include "../t.h"

#define BARRIER (-2) /* the tag of a numbered M105 */

static const char *
peek_text(struct linewin *w)
{
    static char buf[LINEWIN_LINE_MAX + 1];
    const struct linewin_entry *e = linewin_peek(w);
    if (!e)
        return NULL;
    memcpy(buf, e->text, e->len);
    buf[e->len] = '\0';
    return buf;
}

static void
push_n(struct linewin *w, int n)
{
    char cmd[32];
    for (int i = 0; i < n; i++) {
        snprintf(cmd, sizeof(cmd), "G1 X%d", i);
        linewin_push(w, cmd, i, NULL);
    }
}

T_CASE(linewin_numbers_and_checksums)
{
    struct linewin w;
    T_OK(linewin_init(&w, 16, 2), NULL);
    T_EQ_INT(linewin_push(&w, "M105", 0, NULL), 1);
    T_EQ_STR(peek_text(&w), "N1 M105*38");
    struct gcode_line g;
    const char *t = peek_text(&w);
    T_OK(gcode_parse(t, strlen(t), &g, NULL), NULL);
    T_TRUE(g.has_checksum && g.checksum_ok && g.line_no == 1);
    struct sf_err err;
    char big[200];
    memset(big, 'X', sizeof(big) - 1);
    big[sizeof(big) - 1] = '\0';
    T_ERR((int)linewin_push(&w, big, 0, &err), SF_EINVAL, &err, "too long");
    linewin_release(&w);
}

T_CASE(linewin_window_limits_lines_in_flight)
{
    struct linewin w;
    T_OK(linewin_init(&w, 16, 3), NULL);
    push_n(&w, 10);
    for (int i = 0; i < 3; i++) {
        T_TRUE(linewin_peek(&w) != NULL);
        linewin_sent(&w);
    }
    T_TRUE(linewin_peek(&w) == NULL); /* window full */
    T_EQ_INT(linewin_on_ok(&w, false, 0, BARRIER), 1);
    T_TRUE(linewin_peek(&w) != NULL);
    T_EQ_INT(w.acked, 1);
    linewin_release(&w);
}

T_CASE(linewin_ring_full_refuses_push)
{
    struct linewin w;
    T_OK(linewin_init(&w, 8, 2), NULL);
    for (int i = 0; i < 7; i++)
        T_TRUE(linewin_push(&w, "G1 X1", i, NULL) > 0);
    T_EQ_INT(linewin_push(&w, "G1 X1", 7, NULL), SF_EAGAIN);
    linewin_release(&w);
}

T_CASE(linewin_resend_rewinds_once_despite_repeats)
{
    struct linewin w;
    T_OK(linewin_init(&w, 64, 4), NULL);
    push_n(&w, 10);
    for (int i = 0; i < 4; i++)
        linewin_sent(&w); /* 1..4 in flight */
    /* Line 2 was bad: Marlin answers ok(1), then Resend 2 for 2, 3 and 4. */
    T_EQ_INT(linewin_on_ok(&w, false, 0, BARRIER), 1);
    T_EQ_INT(linewin_on_resend(&w, 2), SF_OK);
    T_EQ_INT(linewin_on_ok(&w, false, 0, BARRIER), 0); /* the rejected line's ok */
    T_EQ_INT(w.next, 2);
    T_EQ_STR(peek_text(&w), "N2 G1 X1*99");
    linewin_sent(&w);
    T_EQ_INT(linewin_on_resend(&w, 2), 1); /* repeat from line 3 */
    T_EQ_INT(linewin_on_ok(&w, false, 0, BARRIER), 0);
    T_EQ_INT(linewin_on_resend(&w, 2), 1); /* repeat from line 4 */
    T_EQ_INT(linewin_on_ok(&w, false, 0, BARRIER), 0);
    T_EQ_INT(w.next, 3); /* not rewound again */
    T_EQ_INT(w.rewinds, 1);
    linewin_release(&w);
}

T_CASE(linewin_advanced_ok_acknowledges_by_number)
{
    struct linewin w;
    T_OK(linewin_init(&w, 64, 4), NULL);
    w.advanced = true;
    push_n(&w, 10);
    for (int i = 0; i < 4; i++)
        linewin_sent(&w);
    T_EQ_INT(linewin_on_ok(&w, true, 3, BARRIER), 3); /* oks for 1 and 2 were lost */
    T_EQ_INT(w.in_flight, 1);
    T_EQ_INT(linewin_on_ok(&w, false, 0, BARRIER), 0);  /* M105's ok: no line */
    T_EQ_INT(linewin_on_ok(&w, true, 99, BARRIER), -1); /* garbled: never sent */
    T_EQ_INT(linewin_on_ok(&w, true, 4, BARRIER), 1);
    T_TRUE(!linewin_idle(&w));
    linewin_release(&w);
}

T_CASE(linewin_resync_after_silence)
{
    struct linewin w;
    T_OK(linewin_init(&w, 64, 2), NULL);
    w.advanced = true;
    push_n(&w, 3);
    linewin_sent(&w);
    linewin_sent(&w);
    linewin_on_ok(&w, true, 1, BARRIER); /* ok N2 lost */
    T_EQ_INT(w.in_flight, 1);
    linewin_resync(&w); /* silence past what line 2 can take: it ran */
    T_EQ_INT(w.acked, 2);
    T_EQ_INT(w.next, 3);
    T_EQ_INT(linewin_tag(&w, 2), 1);
    T_EQ_INT(linewin_on_resend(&w, 0), 2);    /* garbled */
    T_EQ_INT(linewin_on_resend(&w, 4000), 2); /* never pushed */
    linewin_release(&w);
}

T_CASE(linewin_barrier_acknowledges_everything_before_it)
{
    struct linewin w;
    T_OK(linewin_init(&w, 64, 4), NULL);
    push_n(&w, 2);
    T_EQ_INT(linewin_push(&w, "M105", BARRIER, NULL), 3);
    push_n(&w, 2);
    for (int i = 0; i < 4; i++)
        linewin_sent(&w);                              /* 1..4 in flight, plain oks */
    T_EQ_INT(linewin_on_ok(&w, false, 0, BARRIER), 1); /* line 1; line 2's ok is lost */
    /* The next plain ok cannot be the probe's: its answer is "ok T:". */
    T_EQ_INT(linewin_on_ok(&w, false, 0, BARRIER), 1);
    T_EQ_INT(linewin_on_ok(&w, false, 0, BARRIER), -1);
    T_EQ_INT(linewin_barrier(&w, 3), 1);
    T_EQ_INT(w.acked, 3);
    T_EQ_INT(w.in_flight, 1);
    T_EQ_INT(linewin_barrier(&w, 9), 0); /* never sent */
    linewin_release(&w);
}

T_CASE(linewin_resend_keeps_queued_lines_in_flight)
{
    struct linewin w;
    T_OK(linewin_init(&w, 64, 4), NULL);
    push_n(&w, 10);
    for (int i = 0; i < 4; i++)
        linewin_sent(&w);
    /* Line 3 was bad; 1 and 2 sit in the printer's queue, their oks to come. */
    T_EQ_INT(linewin_on_resend(&w, 3), SF_OK);
    T_EQ_INT(w.in_flight, 2);
    T_EQ_INT(linewin_on_ok(&w, false, 0, BARRIER), 0); /* the rejection's */
    T_EQ_INT(linewin_on_ok(&w, false, 0, BARRIER), 1);
    T_EQ_INT(linewin_on_ok(&w, false, 0, BARRIER), 1);
    T_EQ_INT(w.acked, 2);
    /* The printer asks for the line after the last one sent: a copy it had. */
    linewin_sent(&w);
    T_EQ_INT(linewin_on_resend(&w, 4), 1);
    T_EQ_INT(w.next, 4);
    linewin_release(&w);
}

T_CASE(linewin_counts_bytes_behind_the_oldest_line)
{
    struct linewin w;
    T_OK(linewin_init(&w, 64, 4), NULL);
    w.rx_bytes = 128;
    for (int i = 0; i < 8; i++)
        linewin_push(&w, "G1 X100.123 Y99.456 Z0.2 E12.34567 F2100", i, NULL); /* 46 B */
    int sent = 0;
    while (linewin_peek(&w)) {
        linewin_sent(&w);
        sent++;
    }
    /* The oldest runs; two more (92 bytes with newlines) fit 127, a third does not. */
    T_EQ_INT(sent, 3);
    linewin_force(&w);
    T_TRUE(linewin_peek(&w) != NULL); /* a probe may pass */
    linewin_sent(&w);
    T_TRUE(linewin_peek(&w) == NULL);
    linewin_release(&w);
}

T_CASE(linewin_resend_older_than_ring_is_reset)
{
    struct linewin w;
    T_OK(linewin_init(&w, 8, 1), NULL);
    for (int i = 0; i < 20; i++) {
        linewin_push(&w, "G1 X1", i, NULL);
        linewin_sent(&w);
        linewin_on_ok(&w, false, 0, BARRIER);
    }
    T_EQ_INT(linewin_on_resend(&w, 1), SF_ENOTFOUND);
    linewin_release(&w);
}

static struct mreply
parse(const char *s)
{
    struct mreply r;
    mreply_parse(s, strlen(s), &r);
    return r;
}

T_CASE(mreply_classifies_marlin_lines)
{
    struct mreply r = parse("ok N123 P15 B3");
    T_EQ_INT(r.kind, MR_OK);
    T_TRUE(r.has_n && r.n == 123 && r.p == 15 && r.b == 3);
    r = parse("ok T:210.5 /215.0 B:60.1 /60.0 @:127 B@:0");
    T_TRUE(r.kind == MR_OK && r.has_temps && r.has_bed);
    T_EQ_DBL(r.t, 210.5, 1e-9);
    T_EQ_DBL(r.t_target, 215, 1e-9);
    T_EQ_DBL(r.bed_target, 60, 1e-9);
    r = parse(" T:200.00 /200.00 B:60.00 /60.00 @:0 B@:0 W:?");
    T_TRUE(r.kind == MR_TEMP && r.temp_wait);
    r = parse("Resend: 42");
    T_TRUE(r.kind == MR_RESEND && r.resend == 42 && !r.tail);
    r = parse("rs N7");
    T_TRUE(r.kind == MR_RESEND && r.resend == 7);
    r = parse("Error:checksum mismatch, Last Line: 41");
    T_TRUE(r.kind == MR_ERROR && r.err == MR_ERR_LINE && r.last_line == 41 && r.resend_follows);
    r = parse("Error:No Line Number with checksum, Last Line: 9");
    T_TRUE(r.err == MR_ERR_LINE && !r.resend_follows);
    r = parse("Error:Thermal Runaway, system stopped! Heater_ID: 0");
    T_EQ_INT(r.err, MR_ERR_FATAL);
    r = parse("Error:Printer halted. kill() called!");
    T_EQ_INT(r.err, MR_ERR_FATAL);
    T_EQ_INT(parse("echo:busy: processing").kind, MR_BUSY);
    T_EQ_INT(parse("wait").kind, MR_WAIT);
    T_EQ_INT(parse("start").kind, MR_START);
    r = parse("//action:pause");
    T_TRUE(r.kind == MR_ACTION);
    T_EQ_STR(r.name, "pause");
    r = parse("// action:cancel");
    T_EQ_STR(r.name, "cancel");
    r = parse("Cap:AUTOREPORT_TEMP:1");
    T_TRUE(r.kind == MR_CAP && r.cap_value == 1);
    T_EQ_STR(r.name, "AUTOREPORT_TEMP");
    r = parse("FIRMWARE_NAME:Marlin 2.1.2.1 (Github) SOURCE_CODE_URL:x");
    T_EQ_STR(r.name, "Marlin 2.1.2.1 (Github)");
}

T_CASE(mreply_garbled_lines_stay_harmless)
{
    T_EQ_INT(parse("ojk").kind, MR_OTHER);
    struct mreply r = parse("ok N12\xbd P3 B3");
    T_TRUE(r.kind == MR_OK && !r.has_n); /* a damaged number is no number */
    r = parse("ok T:2#5.0 /205.0 B:60 /60");
    T_TRUE(r.kind == MR_OK);
    r = parse("Resend: 30Vok");
    T_TRUE(r.kind == MR_RESEND && r.resend == 30 && r.tail);
    r = parse("oR T:205.00 /205.00 B:60.00 /60.00 @:0 B@:0");
    T_TRUE(r.kind == MR_OK && r.garbled && r.has_temps);
    char nul[] = { 'o', 'k', ' ', 'N', '1', '\0', '2', ' ', 'B', '3' };
    mreply_parse(nul, sizeof(nul), &r);
    T_EQ_INT(r.kind, MR_OK);
    char big[3000];
    memset(big, 'a', sizeof(big));
    mreply_parse(big, sizeof(big), &r);
    T_EQ_INT(r.kind, MR_OTHER);
    T_EQ_INT(parse("Cap:X:7").kind, MR_OTHER);
    T_EQ_INT(parse("Resend: -3").kind, MR_OTHER);
}
