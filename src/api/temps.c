/*
 * temps.c - the printers' temperature rings (temps.h).
 *
 * A fixed ring a printer, found by name (a farm has tens of printers, a
 * linear search per 5 s tick is nothing); a printer dropped from the
 * config keeps its ring until the daemon restarts, bounded by the
 * printers it ever had this run.
 *
 * Thread: the loop thread.
 */
#include "temps.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"

struct sample {
    int64_t at_ms; /* wall clock */
    float c[4];    /* nozzle, its target, bed, its target (deg C) */
    bool known;    /* false: offline, temperatures unknown */
};

struct ring {
    char printer[64];
    size_t next, n; /* where the next sample goes; samples held */
    struct sample s[TEMPS_SAMPLES];
};

struct temps {
    struct ring **rings; /* n rings, each its own allocation */
    size_t n, cap;
};

struct temps *
temps_new(void)
{
    return mem_calloc(1, sizeof(struct temps));
}

void
temps_free(struct temps *t)
{
    if (!t)
        return;
    for (size_t i = 0; i < t->n; i++)
        free(t->rings[i]);
    free(t->rings);
    free(t);
}

static struct ring *
find(const struct temps *t, const char *printer)
{
    for (size_t i = 0; i < t->n; i++)
        if (strcmp(t->rings[i]->printer, printer) == 0)
            return t->rings[i];
    return NULL;
}

void
temps_add(struct temps *t, const char *printer, int64_t at_ms, bool known, const double c[4])
{
    struct ring *r = find(t, printer);
    if (!r) {
        if (!mem_grow((void **)&t->rings, &t->cap, t->n + 1, sizeof(*t->rings)) ||
            !(r = mem_calloc(1, sizeof(*r))))
            return; /* a sample lost; the next tick tries again */
        snprintf(r->printer, sizeof(r->printer), "%s", printer);
        t->rings[t->n++] = r;
    }
    struct sample *s = &r->s[r->next];
    s->at_ms = at_ms;
    s->known = known;
    for (int i = 0; i < 4; i++)
        s->c[i] = (float)c[i];
    r->next = (r->next + 1) % TEMPS_SAMPLES;
    if (r->n < TEMPS_SAMPLES)
        r->n++;
}

json_t *
temps_json(const struct temps *t, const char *printer, int interval_ms)
{
    const struct ring *r = find(t, printer);
    if (!r)
        return NULL;
    json_t *arr = json_array();
    size_t first = (r->next + TEMPS_SAMPLES - r->n) % TEMPS_SAMPLES;
    for (size_t k = 0; arr && k < r->n; k++) {
        const struct sample *s = &r->s[(first + k) % TEMPS_SAMPLES];
        json_t *row = json_array();
        json_array_append_new(row, json_integer((json_int_t)s->at_ms));
        for (int i = 0; i < 4; i++)
            /* a tenth of a degree: what printers report */
            json_array_append_new(row, s->known ? json_real((double)(int)(s->c[i] * 10 + 0.5) / 10)
                                                : json_null());
        json_array_append_new(arr, row);
    }
    return json_pack("{ss si so}", "printer", r->printer, "interval_ms", interval_ms, "samples",
                     arr ? arr : json_null());
}
