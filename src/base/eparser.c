/*
 * eparser.c - Marlin's emergency parser, one byte at a time (eparser.h).
 *
 * Why its own module: the driver judges its line numbers against this
 * parser and the simulator acts on it; sim/ may use only src/base, so the
 * one model both rest on lives here, and they cannot drift apart.
 *
 * Thread: any (no state).
 */
#include "eparser.h"

#include <stdbool.h>

enum eparser_state
eparser_step(enum eparser_state s, unsigned char c)
{
    bool eol = c == '\n' || c == '\r';
    switch (s) {
    case EPARSER_RESET:
        return c == ' ' || eol ? EPARSER_RESET
               : c == 'N'      ? EPARSER_N
               : c == 'M'      ? EPARSER_M
                               : EPARSER_IGNORE;
    case EPARSER_N:
        return (c >= '0' && c <= '9') || c == '-' || c == ' ' ? EPARSER_N
               : c == 'M'                                     ? EPARSER_M
                                                              : EPARSER_IGNORE;
    case EPARSER_M:
        return c == ' '   ? EPARSER_M
               : c == '1' ? EPARSER_M1
               : c == '4' ? EPARSER_M4
                          : EPARSER_IGNORE;
    case EPARSER_M1:
        return c == '0' ? EPARSER_M10 : c == '1' ? EPARSER_M11 : EPARSER_IGNORE;
    case EPARSER_M10:
        return c == '8' ? EPARSER_ACT : EPARSER_IGNORE;
    case EPARSER_M11:
        return c == '2' ? EPARSER_ACT : EPARSER_IGNORE;
    case EPARSER_M4:
        return c == '1' ? EPARSER_M41 : EPARSER_IGNORE;
    case EPARSER_M41:
        return c == '0' ? EPARSER_ACT : EPARSER_IGNORE;
    case EPARSER_ACT:
        return EPARSER_ACT;
    case EPARSER_IGNORE:
        return EPARSER_IGNORE;
    }
    return EPARSER_IGNORE;
}
