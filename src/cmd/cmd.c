/*
 * cmd.c - what every command program shares: the helpers of cmd.h and the
 * main() of libexec/slimfarm/slimfarm-MODULE, which runs one of the
 * commands its cmd_MODULE.c registered (argv[1] names it).  Users reach it
 * through bin/slimfarm (slimfarm.c); `--describe MODULE` prints the rows of
 * that program's command table.
 */
#include "cmd.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define CMD_MAX 64

static const struct cmd *cmds[CMD_MAX];
static int n_cmds;
/* isatty(stderr), asked once in main: progress is drawn from worker threads
   once per scored item (orient: 50+ ioctl calls a run otherwise) */
static bool stderr_tty;

void
cmd_register(const struct cmd *c)
{
    if (n_cmds < CMD_MAX)
        cmds[n_cmds++] = c;
}

bool
cmd_parse_num(const char *cmd, const char *opt, const char *text, double lo, double hi,
              const char *want, double *out)
{
    char *end;
    double v = strtod(text, &end);
    if (end == text || *end || !isfinite(v) || v < lo || v > hi) {
        fprintf(stderr, "slimfarm %s: --%s wants %s, got '%s'\n", cmd, opt, want, text);
        return false;
    }
    *out = v;
    return true;
}

bool
cmd_parse_vec3(const char *cmd, const char *opt, const char *text, double out[3])
{
    const char *s = text;
    char *end;
    for (int i = 0; i < 3; i++) {
        out[i] = strtod(s, &end);
        if (end == s || !isfinite(out[i]) || (i < 2 && *end != ','))
            goto bad;
        s = end + (i < 2);
    }
    if (*end == '\0' && (out[0] != 0 || out[1] != 0 || out[2] != 0))
        return true;
bad:
    fprintf(stderr, "slimfarm %s: --%s wants x,y,z (not all zero), got '%s'\n", cmd, opt, text);
    return false;
}

static const char *
find_profile(const char *kind, const char *name, char *buf, size_t cap)
{
    if (strchr(name, '/') || strstr(name, ".cfg")) {
        snprintf(buf, cap, "%s", name);
        return access(buf, R_OK) == 0 ? buf : NULL;
    }
    const char *roots[] = { getenv("SLIMFARM_CONFIG"), "config", "/usr/local/share/slimfarm/config",
                            "/usr/share/slimfarm/config" };
    for (size_t i = 0; i < sizeof(roots) / sizeof(roots[0]); i++) {
        if (!roots[i] || !roots[i][0])
            continue;
        snprintf(buf, cap, "%s/%s/%s.cfg", roots[i], kind, name);
        if (access(buf, R_OK) == 0)
            return buf;
    }
    return NULL;
}

bool
cmd_load_profile(const char *cmd, const char *printer, const char *material,
                 struct slice_profile *p)
{
    char pbuf[1024], mbuf[1024];
    const char *pcfg = NULL, *mcfg = NULL;
    if (printer && !(pcfg = find_profile("printers", printer, pbuf, sizeof(pbuf)))) {
        fprintf(stderr, "slimfarm %s: no printer profile '%s'\n", cmd, printer);
        return false;
    }
    if (material && !(mcfg = find_profile("materials", material, mbuf, sizeof(mbuf)))) {
        fprintf(stderr, "slimfarm %s: no material profile '%s'\n", cmd, material);
        return false;
    }
    struct sf_err err;
    if (slice_profile_load(pcfg, mcfg, p, &err) < 0) {
        fprintf(stderr, "slimfarm %s: %s\n", cmd, err.msg);
        return false;
    }
    return true;
}

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

bool
cmd_stdout_is_tty(void)
{
    return isatty(STDOUT_FILENO);
}

void
cmd_progress(const char *label, double done, double total)
{
    if (!stderr_tty || total <= 0)
        return;
    double f = done / total;
    if (f > 1)
        f = 1;
    char bar[31];
    int fill = (int)(f * 30);
    for (int i = 0; i < 30; i++)
        bar[i] = i < fill ? '#' : '.';
    bar[30] = '\0';
    fprintf(stderr, "\r%-12s [%s] %3d%%%s", label, bar, (int)(f * 100), f >= 1 ? "\n" : "");
    fflush(stderr);
}

/* A C string literal of s (the build compiles --describe's output). */
static void
put_c_string(const char *s)
{
    putchar('"');
    for (; *s; s++) {
        if (*s == '"' || *s == '\\')
            putchar('\\');
        putchar(*s);
    }
    putchar('"');
}

static void
describe(const char *module)
{
    for (int i = 0; i < n_cmds; i++) {
        const char *f[] = { cmds[i]->name, module, cmds[i]->usage, cmds[i]->summary };
        printf("{ ");
        for (int k = 0; k < 4; k++) {
            put_c_string(f[k]);
            printf(k < 3 ? ", " : " },\n");
        }
    }
}

/* Help, usage and unknown names are the front door's (slimfarm.c): it execs
   this program only with one of the names --describe listed. */
int
main(int argc, char **argv)
{
    if (argc == 3 && strcmp(argv[1], "--describe") == 0) {
        describe(argv[2]);
        return 0;
    }
    stderr_tty = isatty(STDERR_FILENO);
    for (int i = 0; argc >= 2 && i < n_cmds; i++)
        if (strcmp(cmds[i]->name, argv[1]) == 0)
            return cmds[i]->run(argc - 1, argv + 1);
    fprintf(stderr, "%s: run it as 'slimfarm COMMAND'; 'slimfarm help' lists the commands\n",
            argv[0]);
    return 2;
}
