/*
 * test_temps.c - the printers' temperature rings (src/api/temps.c): oldest
 * first, an hour kept and the oldest dropped past it, unknown (null)
 * while offline, one ring a printer.
 */
#include <jansson.h>

#include "../../src/api/temps.h"
#include "../t.h"

T_CASE(temps_ring_keeps_the_last_hour)
{
    struct temps *t = temps_new();
    T_TRUE(t != NULL);
    T_TRUE(temps_json(t, "mk3", 5000) == NULL);
    for (int i = 0; i < TEMPS_SAMPLES + 10; i++) {
        const double c[4] = { 200 + i % 7, 210, 60.04, 60 };
        temps_add(t, "mk3", 1000 * (int64_t)i, i != TEMPS_SAMPLES + 9, c);
    }
    const double other[4] = { 25, 0, 24, 0 };
    temps_add(t, "mini", 5, true, other);
    json_t *o = temps_json(t, "mk3", 5000);
    json_t *s = json_object_get(o, "samples");
    T_EQ_INT(json_array_size(s), TEMPS_SAMPLES);
    json_t *first = json_array_get(s, 0), *last = json_array_get(s, TEMPS_SAMPLES - 1);
    T_EQ_INT(json_integer_value(json_array_get(first, 0)), 10000); /* the 10 oldest dropped */
    T_EQ_DBL(json_real_value(json_array_get(first, 1)), 203, 1e-9);
    T_EQ_DBL(json_real_value(json_array_get(first, 3)), 60, 1e-9); /* a tenth of a degree */
    T_TRUE(json_is_null(json_array_get(last, 1)));                 /* offline: unknown */
    T_EQ_INT(json_integer_value(json_array_get(last, 0)), 1000 * (TEMPS_SAMPLES + 9));
    T_EQ_INT(json_integer_value(json_object_get(o, "interval_ms")), 5000);
    json_decref(o);
    o = temps_json(t, "mini", 5000);
    T_EQ_INT(json_array_size(json_object_get(o, "samples")), 1);
    json_decref(o);
    temps_free(t);
}
