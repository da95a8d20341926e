/*
 * octopush.c - OctoPrint's push socket messages (see octopush.h), after
 * OctoPrint 1.11.8 src/octoprint/server/util/sockjs.py on_message: a
 * message that is no JSON object, or whose value has the wrong type, is
 * dropped; a subscription turns off what it does not name.
 *
 * Thread: any.
 */
#include "octopush.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sockjs.h"

void
octopush_sub_init(struct octopush_sub *s)
{
    *s = (struct octopush_sub){ .state = true, .events = NULL, .throttle = 1 };
}

void
octopush_sub_release(struct octopush_sub *s)
{
    json_decref(s->events);
    s->events = NULL;
}

/* {"subscribe": {...}}: false for a bad value (the message is void). */
static bool
subscribe(struct octopush_sub *s, json_t *sub, bool *history)
{
    json_t *state = json_object_get(sub, "state");
    json_t *events = json_object_get(sub, "events");
    if (!json_is_object(sub) || (state && !json_is_boolean(state) && !json_is_object(state)) ||
        (events && !json_is_boolean(events) && !json_is_array(events)))
        return false;
    bool was = s->state;
    s->state = json_is_true(state) || json_is_object(state);
    json_decref(s->events);
    s->events = json_is_array(events)  ? json_deep_copy(events)
                : json_is_true(events) ? NULL
                                       : json_array();
    *history = s->state && !was;
    return true;
}

enum octopush_msg
octopush_message(struct octopush_sub *s, const char *text, size_t len, char *auth, size_t auth_cap,
                 bool *history)
{
    *history = false;
    json_t *m = json_loadb(text, len, 0, NULL);
    enum octopush_msg kind = OCTOPUSH_IGNORED;
    json_t *v;
    if (!json_is_object(m)) {
        /* "Invalid JSON received from client" */
    } else if ((v = json_object_get(m, "auth"))) {
        const char *a = json_string_value(v);
        if (a && strlen(a) < auth_cap) {
            snprintf(auth, auth_cap, "%s", a);
            kind = OCTOPUSH_AUTH;
        }
    } else if ((v = json_object_get(m, "throttle"))) {
        if (json_is_integer(v) && json_integer_value(v) >= 1 &&
            json_integer_value(v) <= OCTOPUSH_THROTTLE_MAX) {
            s->throttle = (int)json_integer_value(v);
            kind = OCTOPUSH_THROTTLE;
        }
    } else if ((v = json_object_get(m, "subscribe"))) {
        if (subscribe(s, v, history))
            kind = OCTOPUSH_SUBSCRIBE;
    }
    json_decref(m);
    return kind;
}

bool
octopush_wants(const struct octopush_sub *s, const char *name)
{
    if (!s->events)
        return true;
    size_t i;
    json_t *e;
    json_array_foreach(s->events, i, e)
    {
        if (json_is_string(e) && strcmp(json_string_value(e), name) == 0)
            return true;
    }
    return false;
}

char *
octopush_text(const char *type, json_t *payload, bool framed)
{
    json_t *msg = json_object();
    if (!msg) {
        json_decref(payload);
        return NULL;
    }
    if (json_object_set_new(msg, type, payload ? payload : json_null())) {
        json_decref(msg);
        return NULL;
    }
    char *text = json_dumps(msg, JSON_COMPACT);
    json_decref(msg);
    if (!text || !framed)
        return text;
    char *frame = sockjs_frame(text, strlen(text));
    free(text);
    return frame;
}
