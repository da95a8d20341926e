/*
 * drv_link.h - a printer's link options: how the config reaches a driver.
 *
 * Each kind's registry row (drv.h's struct drv_kind, rows in drv.c) lists
 * its link options as tables of struct drv_option: the option's config
 * name, its type and check, its default, the struct drv_config field it
 * fills, whether it is a secret and whether a reload may change it live.
 * Tables common to several kinds are shared, so no option is written down
 * twice.  Everything else works from those rows: the config parser checks
 * and stores the values (src/farm/farmcfg.c), drv_link_config makes the
 * driver's struct drv_config, drv_link_diff tells a reload whether the
 * printer must reconnect, drv_link_show prints a value without its secret.
 *
 * struct drv_link holds the values one [printer NAME] section gave, as
 * plain data (no pointers into itself: copy it by value).
 *
 * Thread: any; the tables are constant.
 */
#ifndef SF_DRIVERS_DRV_LINK_H
#define SF_DRIVERS_DRV_LINK_H

#include <stdbool.h>
#include <stddef.h>

#include "../src/base/err.h"
#include "../src/base/limits.h"
#include "drv.h"

/* What an option's value is, and so how the config parser checks it. */
enum drv_opt_type {
    DRV_OPT_STR,   /* any text (size - 1 bytes at most) */
    DRV_OPT_IDENT, /* letters, digits, '-', '_', '.' */
    DRV_OPT_INT,   /* a whole number in lo..hi */
    DRV_OPT_BOOL,  /* true/false, yes/no, 1/0 */
    DRV_OPT_URL,   /* scheme://host[:port][/path], scheme one of the kind's schemes */
    DRV_OPT_PATH,  /* a file name (CA bundle), any text */
};

#define DRV_OPT_SECRET   0x1u /* never shown (API, metrics, logs): keys, passwords */
#define DRV_OPT_LIVE     0x2u /* a reload may change it without reconnecting the printer */
#define DRV_OPT_REQUIRED 0x4u /* the kind needs it set (non-empty, non-zero) */
#define DRV_OPT_FALLBACK 0x8u /* fills its field only if no other option did (bambu's host) */

/* One link option: a row of a kind's option table. */
struct drv_option {
    const char *name;       /* key in [printer NAME]; NULL ends a table */
    enum drv_opt_type type; /* its value and check */
    size_t off;             /* the struct drv_config field it fills (offsetof): const char *
                               for text types, int for DRV_OPT_INT, bool for DRV_OPT_BOOL */
    size_t size;            /* text types: longest value + 1 */
    int lo, hi;             /* DRV_OPT_INT: inclusive range */
    int def;                /* DRV_OPT_INT, DRV_OPT_BOOL: the default (text defaults to "") */
    const char *prefix;     /* put before a text value in the field ("mqtts://"), or NULL */
    unsigned flags;         /* DRV_OPT_* */
};

/* One value a section gave. */
struct drv_link_val {
    const struct drv_option *opt; /* its row (constant tables: safe to copy) */
    int line;                     /* the config line it was given on */
    int num;                      /* DRV_OPT_INT, DRV_OPT_BOOL: the value */
    size_t at;                    /* text types: its offset in text (prefix included) */
};

/* The link options one [printer NAME] section gave, in file order. */
struct drv_link {
    size_t n;                                /* values given */
    struct drv_link_val v[SF_LINK_OPTS_MAX]; /* each option at most once */
    size_t used;                             /* bytes of text in use */
    char text[SF_LINK_TEXT_MAX];             /* text values, each ended by '\0' */
};

/* No option given. */
void drv_link_init(struct drv_link *l);

/* The link option called name in any kind's tables, or NULL. */
const struct drv_option *drv_link_option(const char *name);
/* Link option i (0, 1, ...) of all kinds, each once; NULL past the last. */
const struct drv_option *drv_link_option_at(size_t i);
/* Option i (0, 1, ...) of kind k, in its tables' order; NULL past the last or if k is NULL. */
const struct drv_option *drv_kind_option(const struct drv_kind *k, size_t i);
/* Does kind k take option o? */
bool drv_kind_takes(const struct drv_kind *k, const struct drv_option *o);

/*
 * Record option o's value, checked by the caller against o's row: text for
 * the text types (o->prefix is put before a non-empty one), num for DRV_OPT_INT and
 * DRV_OPT_BOOL.  SF_EINVAL when o was given already or l is full (cannot
 * happen within SF_LINK_OPTS_MAX / SF_LINK_TEXT_MAX: a unit test sums the
 * tables).
 */
int drv_link_set(struct drv_link *l, const struct drv_option *o, const char *text, int num,
                 int line, struct sf_err *err);
/* The value of option o given in l, or NULL if it was not. */
const struct drv_link_val *drv_link_get(const struct drv_link *l, const struct drv_option *o);
/* Text value of option name as given (prefix included), or "" if not given. */
const char *drv_link_text(const struct drv_link *l, const char *name);

/*
 * The driver's config for kind k from l: every field of k's options to its
 * default, then the values l holds for options k takes, in file order (a
 * DRV_OPT_FALLBACK option only into an empty field).  Text fields point
 * into l (valid while l is) or to "".  Fields of options k does not take,
 * and name and kind, are left as the caller set them.  k NULL: nothing.
 */
void drv_link_config(const struct drv_link *l, const struct drv_kind *k, struct drv_config *cfg);

/*
 * The first option of kind k, not DRV_OPT_LIVE, whose value differs
 * between a and b once each is made into a struct drv_config, or NULL when
 * none does (a reload then keeps the printer's link).
 */
const struct drv_option *drv_link_diff(const struct drv_kind *k, const struct drv_link *a,
                                       const struct drv_link *b);

/*
 * Option o's value for kind k from l (drv_link_config's) as text for people
 * (logs, the API): "(secret)" for a DRV_OPT_SECRET option, so keys and
 * passwords never leave the config.
 */
void drv_link_show(const struct drv_link *l, const struct drv_kind *k, const struct drv_option *o,
                   char *out, size_t n);

#endif
