/*
 * gcjob.c - the comments of uploaded G-code, and which printers may run it
 * (see gcjob.h).
 *
 * Why comments and not the commands: a start G-code's M862.3 P "MK3S" or
 * bed size are printer-specific conventions; the slicers' own comments are
 * what OctoPrint, Moonraker and PrusaLink read too, and they name the
 * profile the file was sliced with.  Only printable ASCII is kept from a
 * value, so a key never carries a byte that would upset the store, JSON or
 * a log line.
 *
 * Pure: any thread.
 */
#include "gcjob.h"

#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <unistd.h>

#include "../base/mem.h"

/* The value of comment line l (without its ';') if it is NAME followed by
   '=' or ':' (blanks around), else NULL; *n its length, trailing blanks cut. */
static const char *
value_of(const char *l, size_t len, const char *name, size_t *n)
{
    size_t i = 0, k = strlen(name);
    while (i < len && l[i] == ' ')
        i++;
    if (len - i < k || strncasecmp(l + i, name, k) != 0)
        return NULL;
    i += k;
    while (i < len && l[i] == ' ')
        i++;
    if (i == len || (l[i] != '=' && l[i] != ':'))
        return NULL;
    i++;
    while (i < len && l[i] == ' ')
        i++;
    size_t e = len;
    while (e > i && (l[e - 1] == ' ' || l[e - 1] == '\r' || l[e - 1] == '\t'))
        e--;
    *n = e - i;
    return l + i;
}

/* Copy the first element of a list value (cut at any of seps) as printable ASCII. */
static void
take(char *out, size_t cap, const char *v, size_t n, const char *seps)
{
    if (out[0])
        return; /* first value wins */
    size_t o = 0;
    for (size_t i = 0; i < n && !strchr(seps, v[i]) && o + 1 < cap; i++)
        if (v[i] >= 0x20 && v[i] < 0x7f)
            out[o++] = v[i];
    while (o > 0 && out[o - 1] == ' ')
        o--;
    out[o] = '\0';
}

static double
num(const char *v, size_t n)
{
    char tmp[32];
    if (n >= sizeof(tmp))
        n = sizeof(tmp) - 1;
    memcpy(tmp, v, n);
    tmp[n] = '\0';
    char *end;
    double d = strtod(tmp, &end);
    return end != tmp && d > 0 && d < 1e9 ? d : 0;
}

/* Sum of a comma-separated list of numbers ("12.3, 1.5"). */
static double
num_sum(const char *v, size_t n)
{
    double s = 0;
    size_t i = 0;
    while (i < n) {
        size_t e = i;
        while (e < n && v[e] != ',')
            e++;
        while (i < e && v[i] == ' ')
            i++;
        s += num(v + i, e - i);
        i = e + 1;
    }
    return s;
}

static void
comment(const char *l, size_t len, struct gcjob_info *g, bool *have_g, bool *have_sup)
{
    const char *v;
    size_t n;
    if ((v = value_of(l, len, "printer_model", &n)) ||
        (v = value_of(l, len, "TARGET_MACHINE.NAME", &n)))
        take(g->model, sizeof(g->model), v, n, "");
    else if ((v = value_of(l, len, "nozzle_diameter", &n)) ||
             (v = value_of(l, len, "EXTRUDER_TRAIN.0.NOZZLE.DIAMETER", &n))) {
        size_t k = 0; /* the first element; v is not NUL-terminated */
        while (k < n && v[k] != ',' && v[k] != ';')
            k++;
        if (g->nozzle_mm == 0)
            g->nozzle_mm = num(v, k);
    } else if ((v = value_of(l, len, "filament_type", &n)) ||
               (v = value_of(l, len, "material", &n)))
        take(g->material, sizeof(g->material), v, n, ";,");
    else if ((v = value_of(l, len, "gcode_flavor", &n)) || (v = value_of(l, len, "FLAVOR", &n)))
        take(g->flavor, sizeof(g->flavor), v, n, "");
    else if (!*have_g && ((v = value_of(l, len, "filament used [g]", &n)) ||
                          (v = value_of(l, len, "total filament weight [g]", &n)))) {
        g->filament_g = num_sum(v, n);
        *have_g = true;
    } else if (!*have_sup && (v = value_of(l, len, "support material used [g]", &n))) {
        g->support_g = num(v, n);
        *have_sup = true;
    }
}

static void
scan(const char *text, size_t len, bool skip_first, struct gcjob_info *g, bool *have_g,
     bool *have_sup)
{
    size_t i = 0;
    if (skip_first) { /* a chunk from the middle: its first line is cut */
        while (i < len && text[i] != '\n')
            i++;
        i++;
    }
    while (i < len) {
        size_t e = i;
        while (e < len && text[e] != '\n')
            e++;
        size_t s = i;
        while (s < e && (text[s] == ' ' || text[s] == '\t'))
            s++;
        if (s < e && text[s] == ';')
            comment(text + s + 1, e - s - 1, g, have_g, have_sup);
        i = e + 1;
    }
}

/* Flavors whose files a Marlin-style host cannot stream as they are. */
static int
check_flavor(const struct gcjob_info *g, struct sf_err *err)
{
    static const char *const foreign[] = { "ultigcode", "makerbot", "sailfish", "bfb", "mach3" };
    for (size_t i = 0; i < sizeof(foreign) / sizeof(foreign[0]); i++)
        if (strncasecmp(g->flavor, foreign[i], strlen(foreign[i])) == 0)
            return sf_err_set(err, SF_EINVAL,
                              "G-code flavor '%s' is for firmware no farm printer speaks; slice "
                              "for Marlin (RepRap/Marlin/Sprinter)",
                              g->flavor);
    return SF_OK;
}

int
gcjob_parse(const char *text, size_t len, struct gcjob_info *out, struct sf_err *err)
{
    memset(out, 0, sizeof(*out));
    bool have_g = false, have_sup = false;
    scan(text, len, false, out, &have_g, &have_sup);
    return check_flavor(out, err);
}

int
gcjob_read(const char *path, struct gcjob_info *out, struct sf_err *err)
{
    memset(out, 0, sizeof(*out));
    FILE *f = fopen(path, "rb");
    if (!f)
        return sf_err_sys(err, "G-code '%s'", path);
    struct stat st;
    char *buf = mem_alloc(GCJOB_HEAD_BYTES + GCJOB_TAIL_BYTES);
    int rc = SF_OK;
    if (!buf) {
        fclose(f);
        return sf_err_set(err, SF_ENOMEM, "G-code '%s': out of memory", path);
    }
    bool have_g = false, have_sup = false;
    if (fstat(fileno(f), &st) != 0) {
        rc = sf_err_sys(err, "G-code '%s'", path);
    } else if ((size_t)st.st_size <= GCJOB_HEAD_BYTES + GCJOB_TAIL_BYTES) {
        size_t n = fread(buf, 1, (size_t)st.st_size, f);
        if (ferror(f))
            rc = sf_err_sys(err, "G-code '%s'", path);
        else
            scan(buf, n, false, out, &have_g, &have_sup);
    } else {
        size_t n = fread(buf, 1, GCJOB_HEAD_BYTES, f);
        size_t cut = n;
        while (cut > 0 && buf[cut - 1] != '\n')
            cut--; /* the last line of the head may be cut */
        scan(buf, cut, false, out, &have_g, &have_sup);
        if (fseeko(f, st.st_size - GCJOB_TAIL_BYTES, SEEK_SET) != 0)
            rc = sf_err_sys(err, "G-code '%s'", path);
        else {
            n = fread(buf, 1, GCJOB_TAIL_BYTES, f);
            scan(buf, n, true, out, &have_g, &have_sup);
        }
        if (rc == SF_OK && ferror(f))
            rc = sf_err_sys(err, "G-code '%s'", path);
    }
    free(buf);
    fclose(f);
    return rc ? rc : check_flavor(out, err);
}

void
gcjob_key(const struct gcjob_info *g, char *key, size_t cap)
{
    snprintf(key, cap, GCJOB_KEY_PREFIX "n%g/%s", g->nozzle_mm, g->model);
}

bool
gcjob_key_is(const char *key)
{
    return key && strncmp(key, GCJOB_KEY_PREFIX, strlen(GCJOB_KEY_PREFIX)) == 0;
}

/* Does the comma-separated list hold name (case-insensitive, blanks trimmed)? */
static bool
listed(const char *list, const char *name)
{
    const char *p = list;
    size_t k = strlen(name);
    while (*p) {
        while (*p == ' ' || *p == ',')
            p++;
        size_t n = strcspn(p, ",");
        size_t t = n;
        while (t > 0 && p[t - 1] == ' ')
            t--;
        if (t && ((t == 1 && p[0] == '*') || (t == k && strncasecmp(p, name, k) == 0)))
            return true;
        p += n;
    }
    return false;
}

bool
gcjob_runs_on(const char *key, const char *gcode_models, double nozzle_mm, char *why,
              size_t why_cap)
{
    const char *p = key + strlen(GCJOB_KEY_PREFIX);
    char *end;
    double nozzle = strtod(p + 1, &end);
    const char *model = *end == '/' ? end + 1 : "";
    const char *models = gcode_models ? gcode_models : "";
    if (!models[0]) {
        if (why)
            snprintf(why, why_cap, "runs no uploaded G-code (no gcode_models in farm.ini)");
        return false;
    }
    if (!model[0] && !listed(models, "*")) {
        if (why)
            snprintf(why, why_cap,
                     "the G-code names no printer model and gcode_models is '%s', not '*'", models);
        return false;
    }
    if (model[0] && !listed(models, model)) {
        if (why)
            snprintf(why, why_cap, "G-code for '%s', gcode_models is '%s'", model, models);
        return false;
    }
    if (nozzle > 0 && (nozzle - nozzle_mm > 0.005 || nozzle_mm - nozzle > 0.005)) {
        if (why)
            snprintf(why, why_cap, "G-code for a %g mm nozzle, has %g mm", nozzle, nozzle_mm);
        return false;
    }
    return true;
}

double
gcjob_estimate_s(const char *path)
{
    static const char key[] = "\n; estimated printing time [s] = ";
    char head[GCJOB_EST_HEAD_BYTES + 2];
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    ssize_t n = fd >= 0 ? read(fd, head + 1, GCJOB_EST_HEAD_BYTES) : -1;
    if (fd >= 0)
        close(fd);
    if (n <= 0)
        return -1;
    head[0] = '\n';
    head[n + 1] = '\0';
    const char *p = strstr(head, key);
    if (!p)
        return -1;
    char *end;
    double v = strtod(p + sizeof(key) - 1, &end);
    return end != p + sizeof(key) - 1 && v >= 0 && v < 1e9 ? v : -1;
}
