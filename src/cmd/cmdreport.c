/*
 * cmdreport.c - the support figures and curves the optimizers print, as
 * text and as JSON, and JSON output itself (cmdreport.h).  Apart from cmd.c
 * so that only the commands that report link libjansson.
 */
#include "cmdreport.h"

#include <stdio.h>
#include <stdlib.h>

json_t *
cmd_metrics_json(const struct support_metrics *m)
{
    return json_pack("{s:i, s:f, s:f, s:f, s:i, s:f}", "risky_faces", (json_int_t)m->n_risky,
                     "risky_area_mm2", m->risky_area_mm2, "support_volume_mm3", m->volume_mm3,
                     "contact_area_mm2", m->contact_area_mm2, "anchors", (json_int_t)m->n_anchors,
                     "build_height_mm", m->build_height_mm);
}

void
cmd_print_metrics(const char *label, const struct support_metrics *m)
{
    printf("  %-8s risky faces %7u (%8.0f mm2), support %9.0f mm3, contact %7.0f mm2, "
           "%u anchors, height %.1f mm\n",
           label, m->n_risky, m->risky_area_mm2, m->volume_mm3, m->contact_area_mm2, m->n_anchors,
           m->build_height_mm);
}

void
cmd_print_curve(const uint32_t *curve, int n)
{
    printf("  risky faces per iteration:");
    for (int i = 0; i < n; i++)
        printf("%s%u", i % 16 ? " " : "\n   ", curve[i]);
    printf("\n");
}

json_t *
cmd_curve_json(const uint32_t *curve, int n)
{
    json_t *a = json_array();
    for (int i = 0; a && i < n; i++)
        json_array_append_new(a, json_integer(curve[i]));
    return a;
}

int
cmd_put_json(const char *cmd, json_t *o)
{
    char *text = o ? json_dumps(o, JSON_INDENT(2) | JSON_REAL_PRECISION(8)) : NULL;
    json_decref(o);
    if (!text) {
        fprintf(stderr, "slimfarm %s: out of memory\n", cmd);
        return 1;
    }
    puts(text);
    free(text);
    return 0;
}
