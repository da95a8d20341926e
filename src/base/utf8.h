/*
 * utf8.h - the UTF-8 validity check shared by whatever takes text from
 * outside (job names, HTTP error text): RFC 3629's well-formed sequences,
 * so overlong forms, surrogates and code points past U+10FFFF are invalid.
 *
 * Thread: any; no state.
 */
#ifndef SF_BASE_UTF8_H
#define SF_BASE_UTF8_H

/*
 * Length of the valid UTF-8 sequence at p (1..4); 0 if invalid; -1 if p
 * holds a valid beginning cut by the end of the string (a NUL where a
 * continuation byte belongs).  p points into a NUL-terminated string and
 * is not read past its NUL.
 */
int utf8_seq(const unsigned char *p);

#endif
