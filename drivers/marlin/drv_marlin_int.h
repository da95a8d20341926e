/*
 * drv_marlin_int.h - internal to the Marlin driver: the state its files
 * share and the functions they call across (drv_marlin.c: lifecycle,
 * handshake, timer; drv_marlin_send.c: the window's feed;
 * drv_marlin_rx.c: replies; drv_marlin_recover.c: acknowledgements,
 * resends, probes, deadlines; drv_marlin_job.c: the job stream).
 * Nothing outside drivers/marlin includes it.
 *
 * Thread: loop thread.
 */
#ifndef SF_DRIVERS_MARLIN_DRV_MARLIN_INT_H
#define SF_DRIVERS_MARLIN_DRV_MARLIN_INT_H

#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>

#include "../../src/base/limits.h"
#include "drv_marlin.h"
#include "linewin.h"
#include "transport.h"

#define WINDOW_MAX 32   /* most lines in flight however large B claims */
#define INJECT_MAX 32   /* host lines waiting (park, resume, end sequences) */
#define TAG_HOST   (-1) /* a line the driver added */
#define TAG_M105   (-2) /* a numbered M105 (poll or probe): its answer is a barrier */

enum phase { PH_OFF, PH_HELLO, PH_READY };
enum jobmode { J_NONE, J_RUN, J_PAUSED, J_CANCELLING };

struct marlin {
    struct drv base; /* first: drv.h casts */
    char port[256];  /* transport spec */
    int baud;
    int margin_ms;            /* beyond the expected execution time before a probe */
    int cfg_lines;            /* the firmware's BUFSIZE (lines in flight at most) */
    int cfg_rx;               /* the firmware's RX ring, bytes (0: no byte limit) */
    struct transport *t;      /* NULL when offline */
    struct transport *t_dead; /* closed inside its callback; freed on the next tick */
    int64_t relink_ms;        /* open the port again at this time (marlin_relink; 0: no) */
    uint64_t timer;           /* periodic housekeeping */
    enum phase phase;
    int hello_tries, hello_oks;
    int hello_out;                    /* hellos sent in this handshake (2 oks each) */
    int64_t hello_ms;                 /* last hello sent */
    int64_t hello_ok_ms;              /* last ok of the handshake */
    char rx[SF_PRINTER_LINE_MAX + 1]; /* partial reply line */
    size_t rx_len;
    bool rx_skip; /* dropping an over-long line */
    struct linewin win;
    int max_b;                  /* largest ADVANCED_OK B seen twice */
    int b_seen[WINDOW_MAX + 1]; /* how often each B value was seen */
    int max_p;                  /* largest ADVANCED_OK P seen: the planner's depth */
    int full_window;            /* window when the link is clean */
    int clean;                  /* lines acknowledged since the last rewind */
    long unconfirmed_from;      /* a silence counted lines after this one as handled, with no */
    long unconfirmed_to;        /* reply, up to this one (0: none): not progress until one comes */
    bool settling;              /* after a Resend: wait for the stale replies to stop */
    int settle_ms;              /* quiet time that ends settling (3 line times) */
    int64_t last_reply_ms;      /* last complete reply line */
    uint64_t settle_timer;      /* pending settle check */
    uint64_t line_timer;        /* pending check of a reply line without its newline */
    int64_t progress_ms;        /* last protocol progress (ok, resend, busy...) */
    int64_t last_rx_ms;         /* last byte of any kind */
    int probes;                 /* deadlines in a row with no protocol reply */
    int unmatched;              /* deadlines in a row whose probe went unanswered as one ("ok T:")
                                   though oks came: the oks do not match the lines */
    bool probe_sent;            /* the last deadline sent a probe */
    bool m105_answered;         /* an M105 answer came since the last deadline */
    bool ok_since;              /* an ok came since the last deadline */
    char last_ok[40];           /* the last ok as it came, for the message */
    char last_reply[40];        /* the last reply line of any kind, for the message */
    bool waits_for_user;        /* the last busy said "paused for user" (M0, M600 attended) */
    uint64_t stall_acked;       /* lines_acked when the stall clock last restarted */
    int64_t stall_ms;           /* ... and when: the last confirmed job line, or the job's start */
    bool probe_wanted;          /* a probe waits in the inject queue */
    bool keepalive_seen;        /* the firmware sends "busy:" while any command blocks */
    bool heat_reports_seen;     /* it reports temperatures while M109/M190 wait */
    int64_t busy_until_ms;      /* when the moves acknowledged so far end at the latest */
    int64_t poll_ms;            /* next M105 poll (no auto-report) */
    long error_wants;           /* "Error:... Last Line: L" just came: L + 1, until its Resend */
    long renumber_n;            /* the renumbering M110 in the window, its ok awaited (0: none) */
    long renumber_to;           /* ... and the number it sets (the next line is one more) */
    long bad_resend;            /* resend target out of range */
    int bad_resend_count;       /* times in a row it was asked for */
    char inject[INJECT_MAX][LINEWIN_LINE_MAX];
    int inj_head, inj_len;
    /* job */
    enum jobmode mode;
    FILE *job;
    char job_path[256];
    long job_index; /* next job line (0-based command index) to push */
    bool job_eof;
    bool final_pushed;            /* M400 after the last line */
    long last_tag;                /* highest job index acknowledged + 1 */
    int64_t progress_ev_ms;       /* last DRV_EV_PROGRESS */
    uint64_t progress_ev_lines;   /* lines_acked it reported */
    struct drv_machine mo, saved; /* tracked from the lines pushed (for pause and resume) */
    struct drv_machine est;       /* position for execution time bounds (all lines pushed) */
    struct drv_marlin_stats st;
};

static inline struct marlin *
marlin_of(struct drv *d)
{
    return (struct marlin *)d;
}

/* ---- drv_marlin.c ---- */

/* Tell the owner (drv.h on_event). */
void marlin_emit_event(struct marlin *m, enum drv_event ev);

/* Enter state s (logged, DRV_EV_STATE) unless already there. */
void marlin_set_state(struct marlin *m, enum drv_state s);

/* Set the status message. */
void marlin_message(struct marlin *m, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

/* Write text as it is, past the window; SF_EIO when offline. */
int marlin_send_raw(struct marlin *m, const char *text);

/* Queue a host line after the others; false when the queue is full. */
bool marlin_inject(struct marlin *m, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

/* The handshake is over: a fresh window, then idle. */
void marlin_handshake_done(struct marlin *m);

/* Send a hello (M110 N0 and M115), starting or continuing the handshake. */
void marlin_hello(struct marlin *m);

/*
 * Drop the link (nothing more is sent on it) and open the port again a
 * moment later (a USB board sees its port closed: opened again, it
 * resets) for a new handshake; the state stays as it is until the
 * handshake ends (DRV_IDLE) or fails (DRV_OFFLINE).
 */
void marlin_relink(struct marlin *m);

/* ---- drv_marlin_send.c ---- */

/* A numbered M105 is in flight. */
bool marlin_m105_in_flight(const struct marlin *m);

/* Host line at the head of the inject queue (it goes next). */
void marlin_inject_front(struct marlin *m, const char *cmd);

/*
 * Line numbers near the emergency parser's commands.  Marlin's parser acts
 * on M108/M112/M410 at a line's start or after its N and digits, before
 * the checksum is checked, so "N2112 G1..." is one garbled byte from
 * "NM112 G1..." (kill), and "N1120 G1..." from "M1120 G1...".  No line
 * goes out under such a number: the line before one is
 * "N<n> M0110 N<m>", which makes the next line m + 1, the first of two
 * safe numbers.  "M0110", not "M110": the parser stops at the 0 where
 * "M110" is one byte from "M112"; Marlin reads the code as 110 but, not
 * finding "M110" in the text, checks its N like any line's (n is the one
 * it expects).  It is a barrier: Marlin sets the count when it runs the
 * line, so nothing follows it until its ok.  Host lines take the form of
 * their command that no one garbled byte turns into one of the three
 * (linewin_ep_safe_form: "M105" is one byte from "M108", "M00105" none).
 * Returns true when a renumbering is in the window (nothing may be pushed).
 */
bool marlin_renumber_pending(struct marlin *m);

/* The renumbering M110 was handled: number on from its target. */
void marlin_renumber_check(struct marlin *m, bool took);

/* Push a host line (cmd as the driver wrote it) in its safe form. */
long marlin_push_host(struct marlin *m, const char *cmd, long tag, struct sf_err *err);

/* Lines that may go out now: resends first, then host lines, then the job. */
void marlin_pump(struct marlin *m);

/* ---- drv_marlin_recover.c ---- */

/*
 * When the printer's next reply is overdue, ms: after the last reply, or
 * the end of the moves it has planned, the lines in flight and the margin.
 * How long the printer may legitimately take:
 * the lines in flight, and the moves acknowledged before them that may
 * still wait in the planner (an ok leaves once a move is planned, and the
 * next line waits for a free block): busy_until_ms follows them, each
 * acknowledged move starting when the one before it ends at the latest.  A firmware that has shown
 * it reports while it blocks (busy, M109's temperatures) gets only the report interval for a
 * blocking command: those reports count as replies.
 */
int64_t marlin_deadline_ms(const struct marlin *m);

/*
 * Something did not add up (an unreadable reply, an ok for a line that
 * cannot be, an error without its Resend): ask for a barrier.  The probe is
 * a numbered M105 in the stream, inside the window like any line: Marlin
 * checks its number and checksum, so garbled on the wire it is refused
 * (Resend), never run as another command; M105 runs in order and answers
 * "ok T:..." itself, so its answer means every line before it was handled.
 */
void marlin_want_probe(struct marlin *m);

/* The job lines among window lines from+1..to were run: lines_acked follows. */
void marlin_report_acked(struct marlin *m, long from, long to);

/* A reply acknowledged window lines from+1..to (and so every line before them). */
void marlin_credit(struct marlin *m, long from, long to);

/* An M105's "ok T:": a barrier at the oldest numbered M105 in flight. */
void marlin_on_m105_answer(struct marlin *m);

/* The printer asked for line k (a Resend, or what a line error implies). */
void marlin_on_resend(struct marlin *m, long k);

/*
 * Nothing came back for longer than what is in flight can take, plus the
 * margin: an ok or a Resend was lost.  With lines still to send (after a
 * rewind) the quiet says the printer handled what it had, so the window
 * resyncs and the next line tells (Marlin refuses a line it had with a
 * Resend for the one it wants).  Otherwise a numbered M105 goes out past
 * the full window: refused with a Resend if the printer misses a line,
 * else answered after everything before it.  The job fails only when the
 * printer truly says nothing: PROBES_MAX deadlines in a row and no byte at
 * all for SILENCE_MS (offline: the link is dropped), or only unreadable
 * bytes for GARBLED_MAX deadlines (in error: the link is dropped and opened
 * again, marlin_relink).
 */
void marlin_deadline(struct marlin *m, int64_t now);

/*
 * After each reply and each deadline: true when the job was failed because
 * its stream stopped moving (no job line confirmed for STALL_MS while the
 * printer kept talking, unless it waits for a person).
 */
bool marlin_stall_check(struct marlin *m, int64_t now);

/* ---- drv_marlin_rx.c ---- */

/* The window for this firmware: BUFSIZE lines (ADVANCED_OK's B + 1 once seen twice). */
void marlin_set_full_window(struct marlin *m);

/* One reply line; two if a garbled newline merged them. */
void marlin_on_line(struct marlin *m, const char *line, size_t len);

/* ---- drv_marlin_job.c ---- */

/* Close the job file and drop the host lines; no event. */
void marlin_job_close(struct marlin *m);

/* Fail the job, if any, with why and enter state next. */
void marlin_job_fail(struct marlin *m, enum drv_state next, const char *why);

/*
 * Read the next command of the job file into out.  1: got one, 0: end of
 * file, <0: a bad line (message set).
 */
int marlin_next_job_command(struct marlin *m, char *out, size_t cap);

/* Report progress; end the job once its last line (or the cancel sequence) is acknowledged. */
void marlin_check_job_progress(struct marlin *m);

/* The drv_ops start_job operation (drv.h). */
int marlin_start_job(struct drv *d, const char *path, uint64_t first_line,
                     const struct drv_job_scan *scan, struct sf_err *err);

/* Park the head: the job stops after what is in flight. */
void marlin_do_pause(struct marlin *m);

/* Back to where the pause left the job, and on. */
void marlin_do_resume(struct marlin *m);

/* Stop heating (M108 breaks a wait), lift, and end the job when acknowledged. */
void marlin_do_cancel(struct marlin *m);

/* The drv_ops pause, resume and cancel operations (drv.h). */
int marlin_pause(struct drv *d, struct sf_err *err);

int marlin_resume(struct drv *d, struct sf_err *err);

int marlin_cancel(struct drv *d, struct sf_err *err);

#endif
