/*
 * faults.h - the fault model of the simulated printers: what goes wrong on
 * the wire and in the firmware, each fault settable on its own.
 *
 * A spec is "name=value"; several specs may be given (--fault ... --fault):
 *   corrupt=RATE      each byte, both directions, replaced with probability RATE
 *   corrupt-rx=RATE   only bytes host -> printer
 *   corrupt-tx=RATE   only bytes printer -> host
 *   drop-ok=RATE      an "ok" reply is not sent, with probability RATE
 *   drop-oks=LINE:N   once, the first N oks after line LINE was received are not sent (M105's
 *                     "ok T:" among them): a burst, where drop-ok's losses are scattered.
 *                     With ADVANCED_OK a later "ok N" makes up for a scattered loss; nothing
 *                     makes up for a burst of at least the host's window: it must time out.
 *   garbage=RATE      after a reply line, a line of random bytes, with probability RATE
 *   slow=MS           every reply line leaves MS milliseconds late
 *   reset=N           the firmware resets after executing N commands
 *   disconnect=N      the link drops after executing N commands
 *   runaway=N         thermal runaway (Error:Thermal Runaway, then halt) after N commands
 *   stuck=N           after N commands the firmware never ends the next one (a probing or a
 *                     homing that hangs): no ok, nothing read past its command buffer, only
 *                     "echo:busy: processing" every 2 s (its host keepalive), for good
 *   dup=RATE          a reply line is sent twice, with probability RATE
 *   merge=RATE        a reply line loses its newline (runs into the next), with probability RATE
 *   bad-line=N        line N is taken as garbled once (checksum mismatch): Error, Resend, ok
 *   hit=KIND:LINE:POS:BYTE  once, the first reply of KIND after line LINE was received has
 *                     its byte POS (0-based; its length is the newline) replaced by BYTE
 *                     (0-255; 256 flips its low bit); KIND is ok (a plain "ok"), okn ("ok N.."),
 * okt (M105's "ok T:.."), resend, error, busy or temp (an M109/M190 wait report)
 *   okt=plain         M105 is answered with a plain "ok", no temperatures (a firmware or
 *                     bridge that reports them elsewhere, or not at all)
 *   hold=PATH         while the file PATH exists, the firmware starts no printing move (a G0-G3
 *                     with E and X or Y): it holds at it as at a long dwell (no ok, nothing read
 *                     past its command buffer, "echo:busy: processing" every 2 s), a slow
 *                     printer to any host; it goes on within 50 ms of PATH's removal.  On
 *                     holding it appends "held: COMMAND" to PATH (never creating it), so a test
 *                     arms the hold (creates PATH), sees a print held under way (PATH not
 *                     empty), places its fault and releases (removes PATH).  A network
 *                     printer's firmware holds so too: its job stands, printing
 *   hit-rx=LINE:POS:BYTE  once, the first line the host sends numbered LINE has its byte POS
 *                     (0-based, from its N) replaced by BYTE as it arrives: the emergency
 *                     parser reads it so, and the checksum refuses it
 * seed=N seed of the
 * fault dice (default 1): runs are reproducible Corruption hits at most one byte per line: Marlin's
 * XOR checksum catches every single-byte error but not two that cancel, and a test that lets those
 * through would test the checksum's weakness, not the host.
 *
 * Pure data and a small PRNG; thread-safe on distinct structs.
 */
#ifndef SF_SIM_MARLIN_FAULTS_H
#define SF_SIM_MARLIN_FAULTS_H

#include <stdbool.h>
#include <stdint.h>

#include "../../src/base/err.h"

struct faults {
    double corrupt_rx;     /* byte corruption rate host -> printer, 0..1 */
    double corrupt_tx;     /* byte corruption rate printer -> host, 0..1 */
    double drop_ok;        /* probability an ok is swallowed */
    long drop_oks_line;    /* drop-oks: the burst starts after this line was received */
    long drop_oks;         /* ... and swallows this many oks in a row; 0 = none */
    double garbage;        /* probability of a garbage line after a reply */
    int slow_ms;           /* delay added before each reply line */
    long reset_after;      /* commands executed before a firmware reset; 0 = never */
    long disconnect_after; /* commands executed before the link drops; 0 = never */
    long runaway_after;    /* commands executed before thermal runaway; 0 = never */
    long stuck_after;      /* commands executed before the firmware is stuck for good; 0 = never */
    double dup;            /* probability a reply line is sent twice */
    double merge;          /* probability a reply line loses its newline */
    long bad_line;         /* line taken as garbled once; 0 = none */
    int hit_kind;          /* FAULT_HIT_*: reply kind to corrupt once; 0 = none */
    long hit_line;         /* ... the first one after this line number was received */
    int hit_pos;           /* byte position in the reply line (its newline included) */
    int hit_byte;          /* the byte written there (256: its low bit flipped) */
    bool hit_rx;           /* a host line is to be garbled once (hit-rx) */
    long hit_rx_line;      /* ... its number */
    int hit_rx_pos;        /* ... its byte position */
    int hit_rx_byte;       /* ... the byte written there */
    bool okt_plain;        /* M105 answers a plain "ok" (okt=plain) */
    char hold_path[256];   /* hold=PATH: printing moves wait while it exists; "" none */
    uint64_t rng;          /* xorshift state; never 0 */
};

enum {
    FAULT_HIT_NONE,
    FAULT_HIT_OK,     /* "ok" alone (no ADVANCED_OK) */
    FAULT_HIT_OKN,    /* "ok N<line> P<n> B<n>" */
    FAULT_HIT_OKT,    /* M105's "ok T:..." */
    FAULT_HIT_RESEND, /* "Resend: N" */
    FAULT_HIT_ERROR,  /* "Error:..." */
    FAULT_HIT_BUSY,   /* "echo:busy: processing" */
    FAULT_HIT_TEMP,   /* " T:... W:?" while M109/M190 wait */
};

/* Which FAULT_HIT_* kind a reply line (without its newline) is, or FAULT_HIT_NONE. */
int faults_hit_kind(const char *line);

/* No faults, seed 1. */
void faults_init(struct faults *f);

/* Apply one "name=value" spec; SF_EINVAL naming the spec when bad. */
int faults_parse(struct faults *f, const char *spec, struct sf_err *err);

/* True with probability p (0..1), from the fault dice. */
bool faults_roll(struct faults *f, double p);

/* A random byte other than `not`. */
uint8_t faults_byte(struct faults *f, uint8_t not );

#endif
