/*
 * farmcfg.h - the farm configuration (config/farm.ini): one [farm] section,
 * one [printer NAME] section per printer and one [notify NAME] section per
 * place the operator is told about events (notifycfg.h), Klipper style
 * ("key: value", '#' or ';' comments).  config/farm.ini documents every option and its
 * default.
 *
 * A printer's link options (how to reach it) are not listed here: each
 * driver kind's registry row carries them (drivers/drv.c, drv_link.h), and
 * [printer NAME] takes the options of every kind (those its driver does
 * not take are ignored, so one commented example documents them all).
 *
 * Parsing is strict: an unknown section or option, an option given twice, a
 * value out of range or a missing required option is an error naming
 * file:line, the option and the section, e.g.
 *     farm.ini:14: option 'baud_rate' is not valid in section 'printer mk3'
 *
 * Thread: any; a parsed struct farm_cfg is plain data owned by the caller.
 */
#ifndef SF_FARM_FARMCFG_H
#define SF_FARM_FARMCFG_H

#include <stdbool.h>
#include <stddef.h>

#include "../../drivers/drv_link.h"
#include "../base/err.h"
#include "notifycfg.h"

struct gpolicy; /* drivers/gpolicy.h */

#define FARMCFG_KEY_MIN      16   /* shorter API keys are guessable */
#define FARMCFG_KEY_MAX      128  /* longer ones are a paste error */
#define FARMCFG_KEYS_MAX     64   /* API keys per farm */
#define FARMCFG_PRINTERS_MAX 1000 /* printers per farm */

/* One API key. */
struct farmcfg_key {
    char key[FARMCFG_KEY_MAX + 1]; /* [A-Za-z0-9_-], FARMCFG_KEY_MIN.. bytes */
    bool read_only;                /* may only GET */
    bool metrics_only;             /* may only GET /metrics (implies read_only) */
};

/* One [printer NAME] section. */
struct farmcfg_printer {
    char name[64];        /* NAME: letters, digits, -_. */
    int line;             /* line of the section header, for later messages */
    char driver[16];      /* a kind of drivers/drv.c's registry, e.g. marlin (required) */
    struct drv_link link; /* link options (port, url, api_key, ...): the rows of the driver's
                             kind (drivers/drv.c), values as given (drivers/drv_link.h) */
    char profile[64];     /* PROFILES_DIR/printers/PROFILE.cfg (default "generic-marlin") */
    char material[32];    /* loaded material (default "PLA") */
    double nozzle_mm;     /* nozzle diameter (default 0.4) */
    double bed_mm[3];     /* build volume x, y, z (default 220, 220, 250) */
    double overhang_deg;  /* overhang threshold for this printer (default 45) */
    bool enabled;         /* schedule jobs on it (default true) */
    bool auto_eject;      /* clears its own bed: skip the bed-clear gate (default false) */
    char group[64];       /* group name jobs may target; "" for none (default) */
    double hold_heat_min; /* minutes a printer hot with no print (an interrupted one) keeps its
                             temperatures before the farm turns its heaters off (default 10) */
    /* uploaded G-code it runs (gcjob.h): slicer printer models, comma-separated;
       "*" any, "" none (default) */
    char gcode_models[256];
    bool attended; /* a person watches it: waits for a person (M0, M600, ...) pass the G-code
                      policy (drivers/gpolicy.h; default false) */
    /* commands the G-code policy refuses that this printer takes: "M600 M0" (default "") */
    char allow_gcode[256];
    /* why an operator disabled it at run time (farm.h farm_printer_disable; enabled is then
       false); "" if not.  Not an option of the file: the store keeps it */
    char disabled[128];
};

struct farmcfg {
    char listen_host[64];     /* address to listen on (default 127.0.0.1) */
    int listen_port;          /* port (default 7420; 0: the kernel picks) */
    char data_dir[512];       /* database and files (default /var/lib/slimfarm) */
    char profiles_dir[512];   /* printers/NAME.cfg, materials/NAME.cfg live here (default: the
                                 config file's directory; "config" before a file is loaded) */
    size_t upload_max_bytes;  /* largest part upload (default 256 MiB) */
    double gram_s;            /* the direction search: a gram of support is worth this many
                                 print seconds (default 60; printtime.h) */
    bool material_first;      /* the search may hand back a part that prints slower than
                                 uploaded when it saves support (default false) */
    char store[512];          /* the job database: "" SQLite in data_dir (default), or a
                                 postgresql:// URL shared by several hosts (farm_host.h);
                                 its password is never logged (farmcfg_store_shown) */
    char host[64];            /* this host's name on a shared store; "" (default): the
                                 machine's hostname */
    double host_lease_s;      /* a host's lease on a shared store: the others take its
                                 work this long after its last beat (default 30; it beats
                                 every third of it) */
    struct farmcfg_key *keys; /* n_keys API keys; free with farmcfg_release */
    size_t n_keys;
    struct farmcfg_printer *printers; /* n_printers, in file order */
    size_t n_printers;
    struct notifycfg *notify; /* n_notify [notify NAME] sections, in file order */
    size_t n_notify;
};

/* Set every option to its default (no keys, no printers). */
void farmcfg_init(struct farmcfg *c);

/* Free what the parser allocated and reset c to defaults. */
void farmcfg_release(struct farmcfg *c);

/*
 * Parse the text of a config file (name is used in messages) into c, which
 * must have been farmcfg_init()ed.  SF_EINVAL with "name:line: ..." on the
 * first error; c is released on error.
 */
int farmcfg_parse(struct farmcfg *c, const char *text, size_t len, const char *name,
                  struct sf_err *err);

/* Read and parse a file (capped at SF_CONFIG_FILE_MAX). */
int farmcfg_load(struct farmcfg *c, const char *path, struct sf_err *err);

/* Name of option i, link options included (NULL past the last); *printer says which
   section kind. */
const char *farmcfg_option_name(size_t i, bool *printer);

/* Set every option of printer p to its default (no name, no driver, no link option). */
/* Is s an identifier as farm.ini's K_IDENT keys take it (1..n letters, digits, '-', '_',
   '.')?  Also for a printer's settings another host published (farm_spare.c). */
bool farmcfg_ident_ok(const char *s);
void farmcfg_printer_init(struct farmcfg_printer *p);

/*
 * One printer section's body (text: "key: value" lines, as a [printer NAME]
 * section of the file holds them) for printer name, checked by the very
 * rules the file's are, into *out.  SF_EINVAL with a message naming the
 * option and the section, without a file:line ("option 'nozzle_mm' in
 * section 'printer a': '9' is not a number in 0.1..2"), also for a name
 * the file would refuse.  The run-time printers' path (farm.h).
 */
int farmcfg_printer_parse(struct farmcfg_printer *out, const char *name, const char *text,
                          size_t len, struct sf_err *err);

/* Called once per option of a printer by farmcfg_printer_each: its name, its value as the
   file writes it, and whether it is a secret (an api_key, a password). */
typedef void (*farmcfg_option_fn)(void *ud, const char *name, const char *value, bool secret);

/*
 * Every option of printer p with its value as text the parser takes back
 * (farmcfg_printer_parse gives p again, but for line numbers): the
 * section's options in table order, defaults included, then the link
 * options p was given, in the order given.
 */
void farmcfg_printer_each(const struct farmcfg_printer *p, farmcfg_option_fn fn, void *ud);

/* The G-code policy (drivers/gpolicy.h) of printer p: its attended and allow_gcode. */
void farmcfg_policy(const struct farmcfg_printer *p, struct gpolicy *out);

/* Store URL url for a log line: a password in it shown as "***". */
void farmcfg_store_shown(const char *url, char *out, size_t n);

/* The printer called name, or NULL. */
const struct farmcfg_printer *farmcfg_printer(const struct farmcfg *c, const char *name);

/* The key record matching key (constant-time compare), or NULL. */
const struct farmcfg_key *farmcfg_key(const struct farmcfg *c, const char *key);

#endif
