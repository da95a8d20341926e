/*
 * linewin.h - the host side of Marlin's line protocol: line numbers, XOR
 * checksums and the window of lines in flight.
 *
 * Lines are pushed in order and get consecutive numbers; each is kept,
 * formatted as "N<n> <cmd>*<checksum>", in a ring so it can be sent again
 * when the printer asks.  The window decides what may go out now: at most
 * `window` lines whose reply is outstanding and, when rx_bytes is set, at
 * most rx_bytes - 1 bytes of them besides the oldest (Marlin reads serial
 * only between commands: while the oldest line runs, the others wait in
 * its RX ring, which a UART board overflows).  Replies move it: "ok"
 * (ADVANCED_OK's N acknowledges exactly that line; a plain ok the oldest
 * one), "Resend: k" rewinds to k, and the answer of a numbered M105 is a
 * barrier: M105 runs in order, so every line up to it was handled.
 * Lines before k stay in flight after a rewind (they are in the printer's
 * queue; their oks are still to come); every rejected line is answered
 * with Resend and an ok, which is swallowed.  Marlin answers each line
 * still in flight after a bad one with another "Resend: k"; those repeats
 * are recognised and ignored, so one error costs one rewind, not a storm.
 * The printer's sequence check guarantees no line runs twice or is
 * skipped, whatever the host's bookkeeping believes; the window only has
 * to stay live, which barriers and linewin_resync() restore.
 *
 * Pure logic on caller-owned storage, no I/O, no time: thread-safe on
 * distinct structs, fuzzed (tests/fuzz/fuzz_linewin.c).
 */
#ifndef SF_DRIVERS_MARLIN_LINEWIN_H
#define SF_DRIVERS_MARLIN_LINEWIN_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../../src/base/err.h"

/* Longest formatted line: Marlin's MAX_CMD_SIZE is 96 including the NUL. */
#define LINEWIN_LINE_MAX 96

struct linewin_entry {
    char text[LINEWIN_LINE_MAX]; /* "N<n> <cmd>*<cs>" */
    uint8_t len;                 /* its length */
    int32_t exec_ms;             /* the caller's bound on its execution time (linewin_set_cost) */
    bool after_ok;               /* that time runs after its ok (a move, planned, then run);
                                    else before it (M109, G28, G4: the ok ends the wait) */
    bool heats;                  /* a heat-up wait (M109, M190, M191): reports temperatures */
    long tag;                    /* caller's tag (job line index, -1 for host commands) */
};

struct linewin {
    struct linewin_entry *ring; /* line n lives at ring[n % cap] */
    long cap;                   /* ring size, lines */
    long high;                  /* last number pushed */
    long next;                  /* number the next send carries (<= high + 1) */
    long acked;                 /* last line known processed by the printer */
    int in_flight;              /* lines sent whose reply is outstanding: next - 1 - acked */
    int window;                 /* most lines allowed in flight (>= 1) */
    int rx_bytes;               /* the printer's RX ring, bytes; 0: no byte limit */
    int extra;                  /* lines that may still go beyond the window (linewin_force) */
    bool advanced;              /* replies carry ADVANCED_OK's N */
    int swallow;                /* oks still due for rejected lines (one per Resend) */
    long rewound_to;            /* line of the last rewind */
    long stale;                 /* repeats of that Resend still expected from older lines */
    long doubted;               /* a Resend for an acknowledged line, ignored once */
    uint64_t rewinds;           /* times the window went back */
};

/* Ring of cap lines (cap > window).  SF_ENOMEM. */
int linewin_init(struct linewin *w, long cap, int window);
void linewin_release(struct linewin *w);

/* Start numbering after `last` (what "M110 N<last>" told the printer). */
void linewin_reset(struct linewin *w, long last);

/*
 * Number cmd (already stripped of comments) and keep it.  Returns the line
 * number; SF_EAGAIN when the ring holds only unacknowledged lines;
 * SF_EINVAL when the formatted line is longer than Marlin accepts.
 */
long linewin_push(struct linewin *w, const char *cmd, long tag, struct sf_err *err);

/* Record line n's execution time bound, ms (for the caller's time-outs),
   whether that time runs after the line's ok (a planned move) or before it,
   and whether it is a heat-up wait. */
void linewin_set_cost(struct linewin *w, long n, int32_t exec_ms, bool after_ok, bool heats);

/* The line to send now, or NULL (window full or nothing to send). */
const struct linewin_entry *linewin_peek(const struct linewin *w);
/* The peeked line was written to the printer. */
void linewin_sent(struct linewin *w);

/* Let one more line go out beyond the window (a probe into a stalled window). */
void linewin_force(struct linewin *w);

/*
 * An ok arrived; has_n/n from ADVANCED_OK.  Returns how many lines it
 * acknowledged, or -1 when it cannot be right (an impossible line number,
 * or a plain ok where only a barrier may answer): the caller should probe.
 * A plain ok never acknowledges a line tagged `barrier_tag` (a numbered
 * M105: its own answer, "ok T:", does that).
 */
long linewin_on_ok(struct linewin *w, bool has_n, long n, long barrier_tag);

/*
 * "Resend: k" arrived.  SF_OK: rewound to k.  1: a repeat, or the line
 * after the last one sent (the rejected line was a copy the printer had),
 * nothing to do.  2: a line never pushed (garbled), ignored.
 * SF_ENOTFOUND: k is older than the ring holds (the printer lost lines it
 * had acknowledged: it was reset).
 */
int linewin_on_resend(struct linewin *w, long k);

/*
 * Line n (sent, a numbered M105) was answered: it and every line before it
 * were handled, and every reply to them has arrived.  Returns the lines
 * this newly acknowledges (0 when n is not in flight).
 */
long linewin_barrier(struct linewin *w, long n);

/*
 * The printer stayed silent for longer than what is in flight can take:
 * count everything sent as handled (the next line tells; Marlin rejects a
 * line it had with a Resend for the one it wants).
 */
void linewin_resync(struct linewin *w);

/* Execution time bound of lines first..last held in the ring, ms (capped per
   line at cap_ms, a heat-up's at heat_cap_ms). */
int64_t linewin_cost(const struct linewin *w, long first, long last, int32_t cap_ms,
                     int32_t heat_cap_ms);
/* The part of it that can still run once the lines are acknowledged (moves). */
int64_t linewin_cost_after_ok(const struct linewin *w, long first, long last, int32_t cap_ms);

/* Retag line n (if held). */
void linewin_set_tag(struct linewin *w, long n, long tag);

/* Tag of line n, or -1 if not held. */
long linewin_tag(const struct linewin *w, long n);

/* True when every pushed line is acknowledged. */
bool linewin_idle(const struct linewin *w);

/*
 * The host sends again from line k, unasked (a renumbering M110 whose ok
 * is overdue): lines before k count as handled, next = k.
 */
void linewin_rewind(struct linewin *w, long k);

/*
 * Marlin's EMERGENCY_PARSER (feature/e_parser.cpp) reads every byte as it
 * arrives, before any checksum: at the start of a line, after spaces and
 * "N" with digits, '-' and spaces, "M108", "M112" or "M410" followed by
 * anything up to the end of the line acts at once (M112 kills the
 * printer).  True when line (len bytes, without its newline) makes it act
 * as written, or would after any one of its bytes, or its newline, is
 * replaced by any other: "N2112 G1..." is one byte from "NM112 G1...",
 * "N1120 G1..." from "M1120 G1...", "M110" from "M112".  Pure.
 */
bool linewin_ep_hazard(const char *line, size_t len);

/* True when lines numbered n are no such hazard by their number. */
bool linewin_number_ok(long n);

/*
 * cmd ("M<code>...") in a form the emergency parser cannot be one byte
 * from acting on once numbered as line n, into out (cap bytes): cmd itself,
 * or its code with one or two leading zeros ("M00105": Marlin reads the
 * code as a number, the parser stops at the 0).  Returns false (out = cmd)
 * when none is, or when cmd is M108, M112 or M410 itself (meant to act).
 */
bool linewin_ep_safe_form(long n, const char *cmd, char *out, size_t cap);

#endif
