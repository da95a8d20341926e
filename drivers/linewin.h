/*
 * linewin.h - the host side of Marlin's line protocol: line numbers, XOR
 * checksums and the resend window.
 *
 * Lines are pushed in order and get consecutive numbers; each is kept,
 * formatted as "N<n> <cmd>*<checksum>", in a ring so it can be sent again
 * when the printer asks.  The window decides what may go out now: at most
 * `window` lines whose reply is outstanding.  Replies move it: "ok" (with
 * ADVANCED_OK's N, exactly the line acknowledged; without, one line each),
 * "Resend: k" rewinds to line k.  Marlin answers every line still in
 * flight after a bad one with another "Resend: k"; those repeats are
 * recognised and ignored, so one error costs one rewind, not a storm.
 * The printer's sequence check guarantees no line runs twice or is
 * skipped, whatever the host's bookkeeping believes: the window only has
 * to stay live, which linewin_resync() restores after a timeout probe.
 *
 * Pure logic on caller-owned storage, no I/O, no time: thread-safe on
 * distinct structs, fuzzed (tests/fuzz/fuzz_linewin.c).
 */
#ifndef SF_DRIVERS_LINEWIN_H
#define SF_DRIVERS_LINEWIN_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../src/base/err.h"

/* Longest formatted line: Marlin's MAX_CMD_SIZE is 96 including the NUL. */
#define LINEWIN_LINE_MAX 96

struct linewin_entry {
    char text[LINEWIN_LINE_MAX]; /* "N<n> <cmd>*<cs>" */
    uint8_t len;                 /* its length */
    long tag;                    /* caller's tag (job line index, -1 for host commands) */
};

struct linewin {
    struct linewin_entry *ring; /* line n lives at ring[n % cap] */
    long cap;                   /* ring size, lines */
    long high;                  /* last number pushed */
    long next;                  /* number the next send carries (<= high + 1) */
    long acked;                 /* last line known processed by the printer */
    long recv;                  /* last line known received (queued or done) by the printer */
    bool synced;                /* a probe was answered: everything received is processed */
    int in_flight;              /* lines sent whose reply is outstanding */
    int window;                 /* most lines allowed in flight (>= 1) */
    bool advanced;              /* replies carry ADVANCED_OK's N */
    bool swallow_ok;            /* the ok after a Resend belongs to the rejected line */
    long rewound_to;            /* line of the last rewind */
    long stale;                 /* repeats of that Resend still expected from older lines */
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

/* The line to send now, or NULL (window full or nothing to send). */
const struct linewin_entry *linewin_peek(const struct linewin *w);
/* The peeked line was written to the printer. */
void linewin_sent(struct linewin *w);

/*
 * An ok arrived; has_n/n from ADVANCED_OK.  Returns how many lines it
 * acknowledged, or -1 when its line number is impossible (a garbled reply:
 * the caller should probe).
 */
long linewin_on_ok(struct linewin *w, bool has_n, long n);

/*
 * "Resend: k" arrived.  SF_OK: rewound to k.  1: a repeat, ignored.  2: a
 * line never pushed (garbled, or the printer counts ahead of us), ignored.
 * SF_ENOTFOUND: k is older than the ring holds (the printer lost lines it
 * had acknowledged: it was reset).
 */
int linewin_on_resend(struct linewin *w, long k);

/*
 * A probe answered after a stall: everything sent before it has been
 * processed or rejected.  Forget what is in flight and send the last line
 * again (the printer rejects it with a Resend if it had it).
 */
void linewin_resync(struct linewin *w);

/* Tag of line n, or -1 if not held. */
long linewin_tag(const struct linewin *w, long n);

/* True when every pushed line is acknowledged. */
bool linewin_idle(const struct linewin *w);

#endif
