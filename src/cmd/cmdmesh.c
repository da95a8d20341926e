/*
 * cmdmesh.c - a part in and out of a command, errors printed (see
 * cmdmesh.h).  Apart from cmd.c so that only the programs that take a
 * part link the mesh loaders.
 */
#include "cmdmesh.h"

#include <stdio.h>

bool
cmd_load_part(const char *cmd, const char *path, struct mesh *m, struct mesh_load_info *info)
{
    struct sf_err err;
    if (mesh_load(path, m, info, &err) != SF_OK) {
        fprintf(stderr, "slimfarm %s: %s\n", cmd, err.msg);
        return false;
    }
    return true;
}

bool
cmd_save_part(const char *cmd, const struct mesh *m, const char *path)
{
    struct sf_err err;
    if (mesh_save(m, path, &err) != SF_OK) {
        fprintf(stderr, "slimfarm %s: %s\n", cmd, err.msg);
        return false;
    }
    return true;
}
