/*
 * eparser.h - Marlin's EMERGENCY_PARSER (feature/e_parser.cpp) as a state
 * machine over a line's bytes, shared by the Marlin driver (which line
 * numbers and command forms one garbled byte could turn into M108, M112 or
 * M410: linewin.c) and the simulator (which lines act: sim/marlin).
 *
 * The parser reads every byte before the RX ring and any checksum: at a
 * line's start, after spaces and "N" with digits, '-' and spaces, "M"
 * (spaces) "108", "112" or "410" followed by anything acts when the line
 * ends.  Its states are folded: EPARSER_ACT is one of the three reached.
 *
 * Pure, thread-safe; owns nothing.
 */
#ifndef SF_BASE_EPARSER_H
#define SF_BASE_EPARSER_H

enum eparser_state {
    EPARSER_RESET,  /* a line's start (or only spaces so far) */
    EPARSER_N,      /* in "N" and its digits, '-' and spaces */
    EPARSER_M,      /* after "M" (and spaces) */
    EPARSER_M1,     /* "M1" */
    EPARSER_M10,    /* "M10" */
    EPARSER_M11,    /* "M11" */
    EPARSER_M4,     /* "M4" */
    EPARSER_M41,    /* "M41" */
    EPARSER_ACT,    /* M108, M112 or M410 reached: the line acts when it ends */
    EPARSER_IGNORE, /* anything else: the rest of the line is ignored */
};

/*
 * The state after byte c in state s, within one line.  EPARSER_ACT and
 * EPARSER_IGNORE are final here: what a line end does to them (act, then
 * start over) is the caller's, as is a line end in any other state but
 * EPARSER_RESET (which stays there).
 */
enum eparser_state eparser_step(enum eparser_state s, unsigned char c);

#endif
