/*
 * banned.h - libc calls that are too easy to misuse, turned into compile
 * errors (after git's banned.h).  Included last by every .c file through
 * the compiler's -include flag, so it cannot be forgotten.
 *
 * strcpy/strcat/sprintf/vsprintf: no bound; use snprintf or buf.
 * gets: no bound at all.  atoi/atof: no error reporting; use strtol/strtod
 * and check the end pointer.  strtok: hidden global state; use strtok_r or
 * a hand-rolled scanner.
 */
#ifndef SF_BASE_BANNED_H
#define SF_BASE_BANNED_H

#define BANNED(func) sorry_##func##_is_a_banned_function

#undef strcpy
#define strcpy(x, y) BANNED(strcpy)
#undef strcat
#define strcat(x, y) BANNED(strcat)
#undef sprintf
#define sprintf(...) BANNED(sprintf)
#undef vsprintf
#define vsprintf(...) BANNED(vsprintf)
#undef gets
#define gets(x) BANNED(gets)
#undef atoi
#define atoi(x) BANNED(atoi)
#undef atof
#define atof(x) BANNED(atof)
#undef strtok
#define strtok(x, y) BANNED(strtok)

#endif
