/*
 * simlog.c - a simulated printer's executed-command log beside its G-code
 * (simlog.h).  One reader for the tests and the soak, so both judge a run
 * by the same rules.
 */
#include "simlog.h"

#include <stdlib.h>
#include <string.h>

#include "../src/base/buf.h"
#include "../src/base/gcode.h"
#include "../src/base/mem.h"

char **
simlog_commands(const char *path, size_t *n)
{
    struct buf b;
    buf_init(&b, 0);
    *n = 0;
    if (buf_read_file(&b, path, NULL) < 0) {
        buf_release(&b);
        return NULL;
    }
    char **out = mem_calloc(b.len / 2 + 2, sizeof(char *));
    char *p = b.data;
    while (out && p && *p) {
        char *nl = strchr(p, '\n');
        size_t len = nl ? (size_t)(nl - p) : strlen(p);
        char cmd[256];
        if (gcode_strip(p, len, cmd, sizeof(cmd), NULL) > 0)
            out[(*n)++] = strdup(cmd);
        p = nl ? nl + 1 : NULL;
    }
    buf_release(&b);
    return out;
}

void
simlog_free(char **v, size_t n)
{
    for (size_t i = 0; v && i < n; i++)
        free(v[i]);
    free(v);
}

bool
simlog_host_line(const char *cmd)
{
    struct gcode_line g;
    if (gcode_parse(cmd, strlen(cmd), &g, NULL) < 0 || g.letter != 'M')
        return false;
    return g.code == 105 || g.code == 110 || g.code == 115 || g.code == 155 || g.code == 400;
}
