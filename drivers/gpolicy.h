/*
 * gpolicy.h - the farm's G-code policy: for each command a job file or a
 * manual command may carry, what the farm does with it: pass it, rewrite it
 * to a safe equivalent, or refuse it with a message naming the file, the
 * line, the command and why.  One table (gpolicy.c), read by the upload
 * check (farm_gcode_check), by every driver kind's job (the farm checks a
 * file before it is stored, so a driver streams only files that passed)
 * and by manual commands.
 *
 * What it guards: the host owns the serial protocol (line numbers, "ok",
 * "Resend"), the firmware's settings and the firmware itself, and a farm
 * printer has nobody in front of it.  Commands that break one of those are
 * refused; a printer marked attended (farm.ini "attended: true") passes the
 * waits for a person, and "allow_gcode: M600 M0" passes single rows on one
 * printer.  Bytes: NUL and control bytes are refused anywhere (a bare CR is
 * a line end to Marlin), non-ASCII bytes outside comments.
 *
 * Thread: any (pure: reads its arguments and the file it is given).
 * Ownership: the caller owns every struct; nothing is allocated but the
 * file reader's buffer, freed before return.
 */
#ifndef SF_DRIVERS_GPOLICY_H
#define SF_DRIVERS_GPOLICY_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../src/base/err.h"

/* Where a line comes from: rows may differ (a manual M108 is fine). */
enum gpolicy_source {
    GPOLICY_FILE = 0, /* a job file: uploaded, or made by the farm's slicer */
    GPOLICY_MANUAL,   /* one command an operator sends to an idle printer */
};

/* What the farm does with a line. */
enum gpolicy_action {
    GPOLICY_PASS = 0, /* send it as it is */
    GPOLICY_REWRITE,  /* send verdict.line instead (a safe equivalent) */
    GPOLICY_REFUSE,   /* never send it: verdict.why says why */
};

/* Longest rewritten line (a manual command plus a few bytes). */
#define GPOLICY_LINE_MAX 256
/* gpolicy_check_file names at most this many lines, then "and N more". */
#define GPOLICY_FINDINGS_MAX 20

/* One printer's policy: plain data, gpolicy_init's defaults are an unattended farm's. */
struct gpolicy {
    bool attended;  /* a person watches it: waits for a person (M0, M600, ...) pass */
    uint64_t allow; /* table rows passed by name (gpolicy_allow), one bit per row */
};

/* What gpolicy_check_line decided. */
struct gpolicy_verdict {
    enum gpolicy_action action;
    char cmd[32];                /* the command as judged ("M110", "SAVE_CONFIG", "byte 0x07") */
    const char *why;             /* static text, why it was refused or rewritten; "" on pass */
    char line[GPOLICY_LINE_MAX]; /* GPOLICY_REWRITE: the line to send instead, else "" */
};

/* Defaults: not attended, no row allowed. */
void gpolicy_init(struct gpolicy *p);

/*
 * Allow the commands list names ("M600 M0", commas or blanks between
 * them, case ignored) on top of p.  Only rows that an operator may allow
 * can be named (waits, EEPROM and firmware commands); a protocol command
 * (M110, M111, M112, M108, M410, M999, M117/M118 replies) or an unknown one
 * is SF_EINVAL with a message naming it; p is unchanged then.
 */
int gpolicy_allow(struct gpolicy *p, const char *list, struct sf_err *err);

/*
 * Narrow acc to what both acc and p pass: a file checked by the result
 * passes on either printer.  Start from gpolicy_all().
 */
void gpolicy_meet(struct gpolicy *acc, const struct gpolicy *p);
/* The policy that passes every allowable row (the start of gpolicy_meet). */
void gpolicy_all(struct gpolicy *p);

/*
 * Judge one line (len bytes, no line end; a trailing CR is allowed) from
 * src by p into *v, and return v->action.  Comments (after ';') are judged
 * for control bytes only.
 */
enum gpolicy_action gpolicy_check_line(const struct gpolicy *p, enum gpolicy_source src,
                                       const char *line, size_t len, struct gpolicy_verdict *v);

/*
 * Judge every line of the job file at path by p (as GPOLICY_FILE).  SF_OK
 * when every line passes; SF_EINVAL when some do not, msg (n bytes, e.g.
 * 4096) then naming each ("G-code 'NAME': line 12: M110: why; line 40:
 * ...") up to GPOLICY_FINDINGS_MAX lines, then "and N more", and
 * *n_found (may be NULL) their number; SF_EIO when it cannot be read (err
 * set, msg too).  name is the file's name for messages.
 */
int gpolicy_check_file(const struct gpolicy *p, const char *path, const char *name, char *msg,
                       size_t n, size_t *n_found, struct sf_err *err);

/* Same over a buffer of text (the fuzz target's and the tests' entry). */
size_t gpolicy_check_text(const struct gpolicy *p, const char *text, size_t len, const char *name,
                          char *msg, size_t n);

/*
 * Row i of the table (0, 1, ...), false past the last: its command, what a
 * file and a manual command get by default, whether gpolicy_allow may name
 * it, and why.  For listings (README, tests).
 */
bool gpolicy_row(size_t i, const char **cmd, enum gpolicy_action *file, enum gpolicy_action *manual,
                 bool *allowable, const char **why);

#endif
