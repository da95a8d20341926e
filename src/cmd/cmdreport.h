/*
 * cmdreport.h - what the optimizing commands report (cmd_orient.c,
 * cmd_optimize*.c): support figures as JSON and as one text line
 * ("  LABEL    risky faces ..."), a risky-faces-per-iteration curve, and
 * JSON on stdout.  Linked only into the programs that call it: it brings
 * libjansson.
 */
#ifndef SF_CMD_CMDREPORT_H
#define SF_CMD_CMDREPORT_H

#include <jansson.h>
#include <stdint.h>

#include "../geom/measure.h"

json_t *cmd_metrics_json(const struct support_metrics *m);
void cmd_print_metrics(const char *label, const struct support_metrics *m);
void cmd_print_curve(const uint32_t *curve, int n);
json_t *cmd_curve_json(const uint32_t *curve, int n);

/* Print o (taking its reference; NULL means it could not be built) as
 * indented JSON on stdout: 0, or 1 with "slimfarm CMD: out of memory". */
int cmd_put_json(const char *cmd, json_t *o);

#endif
