/*
 * utf8.c - one UTF-8 sequence's validity (see utf8.h).
 *
 * The lead byte gives the length; each continuation byte must be
 * 10xxxxxx, and the second byte's range rules out the overlong 3- and
 * 4-byte forms, the surrogates and what lies past U+10FFFF (RFC 3629,
 * table 3-7 of the Unicode standard).  A NUL ends the check early so a
 * string cut inside a character is told apart from a bad one.
 *
 * Thread: any.
 */
#include "utf8.h"

int
utf8_seq(const unsigned char *p)
{
    if (p[0] < 0x80)
        return 1;
    int n = p[0] >= 0xf0 ? 4 : p[0] >= 0xe0 ? 3 : p[0] >= 0xc2 ? 2 : 0;
    if (n == 0 || p[0] > 0xf4)
        return 0;
    for (int i = 1; i < n; i++) {
        if (p[i] == 0)
            return -1;
        if ((p[i] & 0xc0) != 0x80)
            return 0;
        /* overlong 3/4-byte forms, surrogates, > U+10FFFF */
        if (i == 1 && ((p[0] == 0xe0 && p[1] < 0xa0) || (p[0] == 0xed && p[1] >= 0xa0) ||
                       (p[0] == 0xf0 && p[1] < 0x90) || (p[0] == 0xf4 && p[1] >= 0x90)))
            return 0;
    }
    return n;
}
