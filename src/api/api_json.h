/*
 * api_json.h - the REST API's JSON: strict parsing of what clients send
 * (job options, priority changes) and the shapes of what they get back
 * (jobs, prints, events), over jansson.
 *
 * Parsing is strict: malformed JSON, a field of the wrong type or an
 * unknown field is SF_EINVAL with a message naming the field (the API
 * answers 400 with it).  Encoders return a new reference, NULL on
 * allocation failure.
 *
 * Thread: any; no state.
 */
#ifndef SF_API_API_JSON_H
#define SF_API_API_JSON_H

#include <jansson.h>
#include <stddef.h>

#include "../base/err.h"
#include "../farm/store.h"

#define API_JSON_DEPTH_MAX 8 /* our bodies are flat objects; deeper is an attack */

/*
 * Parse a job options object ({"copies": 2, "material": "PETG", ...}) over
 * the values already in o (defaults), then validate the result
 * (job_opts_validate).  An empty text leaves o as it is.
 */
int api_opts_parse(const char *text, size_t len, struct job_opts *o, struct sf_err *err);

/* Parse {"priority": N}. */
int api_priority_parse(const char *text, size_t len, int *priority, struct sf_err *err);
/* Parse POST /api/jobs/ID/move's {"by": -1 | 1}. */
int api_move_parse(const char *text, size_t len, int *by, struct sf_err *err);

/*
 * POST /api/printers/NAME/command's body: {"command": "G28"} and nothing
 * else; the command is one line of printable ASCII, its comment and blanks
 * stripped (gcode_strip), at most SF_COMMAND_MAX bytes, into out (n >=
 * SF_COMMAND_MAX + 1).  SF_EINVAL naming what is wrong.
 */
int api_command_parse(const char *text, size_t len, char *out, size_t n, struct sf_err *err);

/* POST .../resume's body: empty (*line = -1, the stored line) or {"line": N >= 0}. */
int api_resume_parse(const char *text, size_t len, int64_t *line, struct sf_err *err);

json_t *api_job_json(const struct job_row *j);
json_t *api_print_json(const struct print_row *p);
json_t *api_event_json(const struct event_row *e);

struct printer_info;
/* Set o's "time_left_s" and "time_left_from" from printer p (null when not known). */
void api_time_left_json(json_t *o, const struct printer_info *p);

#endif
