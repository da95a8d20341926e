/*
 * filament.c - the net E of a G-code file by command line (filament.h).
 *
 * One pass over the file with a line buffer of SF_GCODE_LINE_MAX (a longer
 * line is refused by the policy check before any print, and counted here
 * as one command without E).  The marks start one a line; when they would
 * overflow, every other one is dropped and the step doubles, so a file of
 * any length needs no count beforehand.
 *
 * Thread: any.
 */
#include "filament.h"

#include <stdbool.h>
#include <stdio.h>
#include <string.h>

#include "../base/gcode.h"
#include "../base/limits.h"

/* The E state the commands leave: absolute or relative, and the position. */
struct estate {
    bool rel_e;
    double e;
};

/* Net E of one command (G0-G3 with E; G92, G90/G91, M82/M83 change the state). */
static double
extruded(struct estate *m, const struct gcode_line *l)
{
    double e;
    bool has_e = gcode_get(l, 'E', &e) && e == e; /* a bare "E" is no position */
    if (l->letter == 'G' && l->code >= 0 && l->code <= 3 && has_e) {
        double de = m->rel_e ? e : e - m->e;
        m->e = m->rel_e ? m->e + e : e;
        return de;
    }
    if (gcode_is(l, 'G', 92))
        m->e = has_e ? e : l->n_words == 0 ? 0 : m->e;
    else if (gcode_is(l, 'G', 90) || gcode_is(l, 'M', 82))
        m->rel_e = false;
    else if (gcode_is(l, 'G', 91) || gcode_is(l, 'M', 83))
        m->rel_e = true;
    return 0;
}

/* Keep the net E after f->lines commands if it falls on a mark. */
static void
mark(struct filament *f, double used)
{
    if (f->lines % f->step)
        return;
    if (f->n_marks == FILAMENT_MARKS + 1) {
        for (int i = 0; 2 * i < f->n_marks; i++)
            f->mark_mm[i] = f->mark_mm[2 * i];
        f->n_marks = (f->n_marks + 1) / 2;
        f->step *= 2;
        if (f->lines % f->step)
            return;
    }
    f->mark_mm[f->n_marks++] = used;
}

int
filament_scan(const char *path, struct filament *out, struct sf_err *err)
{
    memset(out, 0, sizeof(*out));
    out->step = 1;
    out->n_marks = 1; /* mark 0: nothing used before the first line */
    FILE *fp = fopen(path, "re");
    if (!fp)
        return sf_err_sys(err, "filament: cannot open '%s'", path);
    char line[SF_GCODE_LINE_MAX + 2], cmd[SF_GCODE_LINE_MAX + 1];
    struct estate m = { false, 0 };
    double used = 0;
    bool rest = false; /* the tail of a line longer than the buffer */
    while (fgets(line, sizeof(line), fp)) {
        size_t len = strlen(line);
        bool whole = len && line[len - 1] == '\n';
        bool tail = rest;
        rest = !whole;
        if (tail)
            continue;
        struct gcode_line l;
        if (!gcode_strip(line, len, cmd, sizeof(cmd), NULL))
            continue;
        if (gcode_parse(cmd, strlen(cmd), &l, NULL) == SF_OK)
            used += extruded(&m, &l);
        out->lines++;
        mark(out, used);
    }
    int bad = ferror(fp);
    fclose(fp);
    if (bad)
        return sf_err_set(err, SF_EIO, "filament: cannot read '%s'", path);
    out->total_mm = used;
    return SF_OK;
}

double
filament_at(const struct filament *f, int64_t lines)
{
    if (lines >= f->lines)
        return f->total_mm > 0 ? f->total_mm : 0;
    if (lines <= 0 || f->step < 1 || f->n_marks < 1)
        return 0;
    int64_t k = lines / f->step;
    if (k >= f->n_marks)
        k = f->n_marks - 1;
    /* the next known point: the next mark, or the file's end */
    int64_t at0 = k * f->step, at1 = k + 1 < f->n_marks ? at0 + f->step : f->lines;
    double e0 = f->mark_mm[k], e1 = k + 1 < f->n_marks ? f->mark_mm[k + 1] : f->total_mm;
    double e = e0 + (e1 - e0) * (double)(lines - at0) / (double)(at1 > at0 ? at1 - at0 : 1);
    return e > 0 ? e : 0;
}
