/*
 * api_printers.h - the routes that manage printers at run time (farm.h's
 * run-time printers), a group of the route table (route.h) placed before
 * api.c's rows:
 *
 *   GET    /api/printer-kinds             the driver kinds, each with its options (name,
 *                                         type, range, default, required, secret), and
 *                                         the options every printer takes: the form's data
 *   POST   /api/printers                  {"name": N, "driver": K, OPTION: VALUE, ...} -> 201
 *   GET    /api/printers/NAME/config      its options as text (secrets left out, named in
 *                                         "secrets"), and where they come from
 *   PUT    /api/printers/NAME             replace its options (a body as POST's)
 *   PATCH  /api/printers/NAME             change the options given (null: back to the
 *                                         default), keep the others
 *   POST   /api/printers/NAME/disable     {"reason": "..."}: no new job; refused while it
 *                                         prints
 *   POST   /api/printers/NAME/enable
 *   DELETE /api/printers/NAME             refused while it prints or holds a part
 *
 * OPTION is an option of farm.ini's [printer NAME] (config/farm.ini), a
 * VALUE a string, number, boolean or, for bed_size, [X, Y, Z]; each is
 * checked by the file's own rules (farmcfg_printer_parse), and an error
 * names the field.  Writes need a read-write key (read-only: 403).
 * Statuses: 400 a bad body or option, 404 no such printer, 409 not now
 * (the name is taken, it prints, its bed holds a part: farm.h says which).
 *
 * Thread: the loop thread.
 */
#ifndef SF_API_API_PRINTERS_H
#define SF_API_API_PRINTERS_H

#include <stddef.h>

#include "route.h"

/* The rows; their handlers take the struct farm * as ctx. */
const struct route *api_printers_routes(size_t *n);

#endif
