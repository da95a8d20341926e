/*
 * gcode.h - the G-code line tokenizer shared by the slicer (reading back its
 * own output), the drivers (stripping and numbering lines) and the
 * simulator (executing them).
 *
 * A line is: [N<number>] <command> <words...> [*<checksum>] [; comment]
 * with ( ... ) comments allowed too.  The command is a letter and a number
 * (G1, M105, T0, G29.1 is command 29 with subcode 1).  Words are a letter and
 * a number each, a bare letter, or a letter and a "quoted string".  Commands
 * that take free text (M23 file name, M117 and M118 messages, M28/M30 file
 * names) keep their argument as text.
 *
 * Pure functions on caller memory, thread-safe, fuzzed (tests/fuzz).
 */
#ifndef SF_BASE_GCODE_H
#define SF_BASE_GCODE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "err.h"

/* Most words on one command line: G1 uses at most 6 (X Y Z E F S). */
#define GCODE_WORDS_MAX 16

struct gcode_word {
    char letter;  /* upper-case parameter letter */
    double value; /* NAN when the letter stands alone (e.g. "G28 X") */
};

struct gcode_line {
    bool has_line_no;  /* N<number> present */
    long line_no;      /* its value */
    bool has_checksum; /* *<number> present */
    unsigned checksum; /* the value given */
    bool checksum_ok;  /* given checksum equals the computed one */
    char letter;       /* 'G', 'M', 'T' ...; 0 for an empty line */
    int code;          /* command number (1 in G1) */
    int subcode;       /* after a dot (G29.1); -1 if none */
    int n_words;       /* parameter words in words[] */
    struct gcode_word words[GCODE_WORDS_MAX];
    /* free-text argument (M117 msg) or the first quoted string value
     * (P "MK3S", without the quotes) into the input, or NULL */
    const char *text;
    size_t text_len; /* its length */
};

/*
 * Parse one line (no newline needed; len bytes, NUL not required).  An
 * empty or comment-only line parses to letter 0.  SF_EINVAL with a message
 * ("column 5: number expected after 'X'") on malformed input.
 */
int gcode_parse(const char *line, size_t len, struct gcode_line *out, struct sf_err *err);

/* Value of word `letter`, or false if absent.  */
bool gcode_get(const struct gcode_line *l, char letter, double *value);

/* True when the line's command is letter+code ("G", 1). */
bool gcode_is(const struct gcode_line *l, char letter, int code);

/*
 * Copy the command part of a line into out (cap bytes incl. NUL): comments
 * removed, leading/trailing blanks trimmed, any N word and *checksum
 * removed.  Returns the length written, 0 for a line with no command.
 * A result that would not fit returns 0 and sets *too_long if given.
 */
size_t gcode_strip(const char *line, size_t len, char *out, size_t cap, bool *too_long);

/* XOR of the bytes, as Marlin's host protocol computes it. */
uint8_t gcode_checksum(const char *s, size_t len);

/*
 * Format "N<n> <cmd>*<checksum>" into out (cap bytes); returns the length,
 * or 0 if it does not fit.
 */
size_t gcode_number_line(long n, const char *cmd, char *out, size_t cap);

#endif
