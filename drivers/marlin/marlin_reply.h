/*
 * marlin_reply.h - classify one reply line of a Marlin printer.
 *
 * Printer replies carry no checksum, so every field is validated and a
 * garbled line parses to MR_OTHER (or a kind with fewer fields), never to a
 * crash: the caller decides what an unknown line means (usually nothing).
 * Knows: ok (plain, ADVANCED_OK "ok N.. P.. B..", M105's "ok T:.."),
 * Resend:/rs, Error: (line errors, fatal halts, others), echo:busy,
 * wait, start, temperature reports (auto-report and M109/M190 waits with
 * W:), host actions (// action:NAME), M115 FIRMWARE_NAME and Cap: lines.
 *
 * Pure, thread-safe, fuzzed (tests/fuzz/fuzz_marlin_reply.c).
 */
#ifndef SF_DRIVERS_MARLIN_MARLIN_REPLY_H
#define SF_DRIVERS_MARLIN_MARLIN_REPLY_H

#include <stdbool.h>
#include <stddef.h>

enum mreply_kind {
    MR_OTHER = 0, /* anything else (echo:, garbage) */
    MR_OK,        /* ok, with optional N/P/B and temperatures */
    MR_RESEND,    /* Resend: N / rs N */
    MR_ERROR,     /* Error:...; see err */
    MR_BUSY,      /* echo:busy: processing / paused for user */
    MR_WAIT,      /* wait (queue empty, nothing arriving) */
    MR_START,     /* start (firmware booted) */
    MR_TEMP,      /* temperature report without ok */
    MR_ACTION,    /* // action:NAME */
    MR_CAP,       /* Cap:NAME:0|1 */
    MR_FIRMWARE,  /* FIRMWARE_NAME:... */
    MR_ECHO,      /* echo:... (messages, unknown command notices) */
};

enum mreply_error {
    MR_ERR_NONE = 0,
    MR_ERR_LINE,  /* checksum / line number errors: a Resend follows */
    MR_ERR_FATAL, /* halted, kill(), thermal runaway, MAXTEMP...: printer stopped */
    MR_ERR_OTHER, /* unknown error text: reported, not fatal */
};

struct mreply {
    enum mreply_kind kind;
    bool has_n; /* ok N<line> */
    long n;
    int p, b;              /* ok P<planner free> B<queue free>; -1 if absent */
    long resend;           /* MR_RESEND: line wanted */
    bool tail;             /* MR_RESEND: junk after the number (the next line merged in) */
    enum mreply_error err; /* MR_ERROR: class */
    long last_line;        /* "Last Line: N" in an error, else -1 */
    bool resend_follows;   /* MR_ERR_LINE that Marlin follows with Resend (not "No Line Number") */
    bool garbled;          /* MR_OK recognised despite a damaged "ok" */
    bool has_temps;        /* T: present (MR_OK or MR_TEMP) */
    bool has_bed;          /* B: present */
    bool temp_wait;        /* W: present: an M109/M190 wait report */
    double t, t_target, bed, bed_target; /* deg C */
    char name[64];                       /* action name, capability name or firmware name */
    int cap_value;                       /* MR_CAP: 0 or 1 */
};

/* Classify line (len bytes, no newline needed; long lines are cut at 1 KiB). */
void mreply_parse(const char *line, size_t len, struct mreply *out);

#endif
