/*
 * cmdprofile.c - slicing profiles by name for the commands that slice or
 * estimate (cmdprofile.h).  Apart from cmd.c so that only those programs
 * link the profile loader and its INI parser.
 */
#include "cmdprofile.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

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
