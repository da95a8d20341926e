/*
 * log.h - levelled, subsystem-tagged logging.
 *
 * One line per event on stderr: "2026-11-23T11:40:02.123 warn marlin[mk3-a]: message".
 * The level threshold comes from SLIMFARM_LOG (error|warn|info|debug,
 * default info) or log_set_level().  log_printer() tags a printer by name
 * and rate-limits repeats of the same message per printer (a flapping USB
 * cable must not flood the log).  SLIMFARM_TRACE=serial,http turns on
 * log_trace() dumps of escaped wire traffic for those subsystems.
 *
 * Tests install a sink with log_set_sink() and assert on what was logged.
 * Thread-safe: a mutex serializes output and the rate-limit table.
 */
#ifndef SF_BASE_LOG_H
#define SF_BASE_LOG_H

#include <stdbool.h>
#include <stddef.h>

enum log_level { LOG_ERROR = 0, LOG_WARN, LOG_INFO, LOG_DEBUG };

/* Receives every line that passes the level threshold (without newline). */
typedef void (*log_sink_fn)(void *ud, enum log_level level, const char *subsys, const char *printer,
                            const char *msg);

void log_set_level(enum log_level level);
enum log_level log_get_level(void);

/* Route lines to fn instead of stderr; fn = NULL restores stderr. */
void log_set_sink(log_sink_fn fn, void *ud);

void log_msg(enum log_level level, const char *subsys, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

/*
 * Log for one printer.  The same message text for the same printer is
 * printed at most once per 10 s; the next line after a quiet spell says how
 * many were suppressed.
 */
void log_printer(enum log_level level, const char *printer, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

/* As log_printer, every line printed, never folded as a repeat: for events
   each of which matters (who sent which manual command). */
void log_printer_each(enum log_level level, const char *printer, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

#define log_error(subsys, ...) log_msg(LOG_ERROR, subsys, __VA_ARGS__)
#define log_warn(subsys, ...)  log_msg(LOG_WARN, subsys, __VA_ARGS__)
#define log_info(subsys, ...)  log_msg(LOG_INFO, subsys, __VA_ARGS__)
#define log_debug(subsys, ...) log_msg(LOG_DEBUG, subsys, __VA_ARGS__)

/* True when SLIMFARM_TRACE names subsys (or is "all"). */
bool log_trace_enabled(const char *subsys);

/*
 * Dump len bytes of wire traffic, escaped (\r, \n, \xNN), tagged with the
 * direction ("<" or ">") and who; does nothing unless tracing subsys.
 */
void log_trace(const char *subsys, const char *who, const char *dir, const void *data, size_t len);

/* Name of a level ("warn"); parse one, returning false if unknown. */
const char *log_level_name(enum log_level level);
bool log_level_parse(const char *s, enum log_level *out);

#endif
