/*
 * sockjs.c - SockJS's websocket framing (see sockjs.h), by jansson: a
 * message is a JSON string inside the frame, escaped as JSON escapes it.
 *
 * Thread: any.
 */
#include "sockjs.h"

#include <jansson.h>
#include <stdlib.h>
#include <string.h>

#include "mem.h"

char *
sockjs_frame(const char *msg, size_t len)
{
    json_t *arr = json_array();
    if (!arr || json_array_append_new(arr, json_stringn(msg, len))) {
        json_decref(arr);
        return NULL;
    }
    char *inner = json_dumps(arr, JSON_COMPACT);
    json_decref(arr);
    size_t n = inner ? strlen(inner) : 0;
    char *frame = inner ? mem_alloc(n + 2) : NULL;
    if (frame) {
        frame[0] = 'a';
        memcpy(frame + 1, inner, n + 1);
    }
    free(inner);
    return frame;
}

int
sockjs_unframe(const char *text, size_t len, void (*fn)(void *arg, const char *msg, size_t len),
               void *arg)
{
    json_t *v = json_loadb(text, len, 0, NULL);
    if (!v || !(json_is_array(v) || json_is_string(v))) {
        json_decref(v);
        return -1;
    }
    int n = 0;
    if (json_is_string(v)) {
        fn(arg, json_string_value(v), json_string_length(v));
        n = 1;
    } else {
        size_t i;
        json_t *s;
        json_array_foreach(v, i, s)
        {
            if (json_is_string(s)) {
                fn(arg, json_string_value(s), json_string_length(s));
                n++;
            }
        }
    }
    json_decref(v);
    return n;
}
