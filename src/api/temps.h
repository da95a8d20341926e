/*
 * temps.h - each printer's recent temperatures, kept by the daemon so the
 * dashboard's chart survives a reload: a ring of TEMPS_SAMPLES samples a
 * printer (one every API_TICK_MS, 5 s: the last hour), in memory only,
 * served as GET /api/printers/NAME/temps:
 *
 *   {"printer": "mk3", "interval_ms": 5000, "samples":
 *    [[at_ms, nozzle_c, nozzle_target_c, bed_c, bed_target_c], ...]}
 *
 * oldest first; the four temperatures are null while the printer is
 * offline (what it last said is not what it is now).
 *
 * Thread: the loop thread.  Owns the rings.
 */
#ifndef SF_API_TEMPS_H
#define SF_API_TEMPS_H

#include <jansson.h>
#include <stdbool.h>
#include <stdint.h>

#define TEMPS_SAMPLES 720 /* an hour at one sample per 5 s: 17 KB a printer */

struct temps;

/* An empty history; NULL when out of memory. */
struct temps *temps_new(void);
void temps_free(struct temps *t);

/* One sample of printer at at_ms; known false: the printer is offline. */
void temps_add(struct temps *t, const char *printer, int64_t at_ms, bool known, const double c[4]);

/* The JSON above for printer (a new reference); NULL if it has no samples. */
json_t *temps_json(const struct temps *t, const char *printer, int interval_ms);

#endif
