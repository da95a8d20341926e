/*
 * ini.h - INI files (libinih) with errors that say file:line, and typed
 * option tables.
 *
 * Syntax: [section] headers, `key = value` or `key: value`, comments on
 * lines starting with ; or #, and after " ;" at the end of a value.  A
 * line starting with blanks continues the previous value (multi-line
 * G-code).  Lines are at most SF_INI_LINE_MAX bytes, files at most
 * SF_CONFIG_FILE_MAX.
 *
 * Two layers: ini_parse_mem/ini_load call a handler per key with the line
 * number; ini_opt_* set fields of a caller's struct from a table of typed
 * options (reals and ints with ranges, bools, strings), which also serves
 * command-line overrides (--set key=value).
 *
 * Thread-safe: no shared state (libinih keeps none either).
 */
#ifndef SF_BASE_INI_H
#define SF_BASE_INI_H

#include <stdbool.h>
#include <stddef.h>

#include "err.h"

/*
 * Called for each key.  cont is true for a continuation line of the
 * previous key.  Return SF_OK, or a status with err set to a message
 * without position ("option 'x' is not valid in section 'printer'");
 * the parser then stops and prefixes "NAME:LINE: ".
 */
typedef int (*ini_fn)(void *ud, const char *section, const char *key, const char *value, bool cont,
                      struct sf_err *err);

/* Parse len bytes of text; name is used in messages.  SF_EINVAL on syntax. */
int ini_parse_mem(const char *text, size_t len, const char *name, ini_fn fn, void *ud,
                  struct sf_err *err);

/* Read and parse a file (SF_EIO if unreadable). */
int ini_load(const char *path, ini_fn fn, void *ud, struct sf_err *err);

enum ini_type {
    INI_REAL, /* double, checked finite and in [min, max] */
    INI_INT,  /* int, checked in [min, max] */
    INI_BOOL, /* bool: 1/0, true/false, yes/no, on/off */
    INI_STR,  /* char *, one line */
    INI_TEXT, /* char *, continuation lines append "\n" + line */
};

/* One option of a table: the field at offset in the caller's struct. */
struct ini_opt {
    const char *key;
    enum ini_type type;
    size_t offset;
    double min, max;
    const char *help; /* one line, with the unit */
};

/* The option named key, or NULL. */
const struct ini_opt *ini_opt_find(const struct ini_opt *opts, size_t n, const char *key);

/*
 * Parse value into the field of o in base.  append (INI_TEXT only) adds a
 * line instead of replacing.  SF_EINVAL with "option 'k': ..." on a bad
 * value, SF_ENOMEM.
 */
int ini_opt_set(const struct ini_opt *o, void *base, const char *value, bool append,
                struct sf_err *err);

/* Parse "key=value" against the table (command-line overrides). */
int ini_opt_set_kv(const struct ini_opt *opts, size_t n, void *base, const char *kv,
                   struct sf_err *err);

/* Duplicate every string field (after a struct copy) / free them. */
int ini_opts_dup(const struct ini_opt *opts, size_t n, void *base);
void ini_opts_release(const struct ini_opt *opts, size_t n, void *base);

#endif
