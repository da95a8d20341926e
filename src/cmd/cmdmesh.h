/*
 * cmdmesh.h - loading and saving parts for the command programs that take
 * a part (cmd_inspect.c, cmd_orient.c, cmd_optimize*.c, cmd_slice.c), with
 * the commands' error line.  Linked only into them: it brings the mesh
 * loaders.
 */
#ifndef SF_CMD_CMDMESH_H
#define SF_CMD_CMDMESH_H

#include <stdbool.h>

#include "../mesh/mesh.h"

/*
 * Load the part at path into m (mesh_init'ed by the caller, who releases
 * it; info may be NULL).  On failure print "slimfarm CMD: message" on
 * stderr and return false.
 */
bool cmd_load_part(const char *cmd, const char *path, struct mesh *m, struct mesh_load_info *info);
/* Save m to path (its format by the extension); on failure print "slimfarm
   CMD: message" on stderr and return false. */
bool cmd_save_part(const char *cmd, const struct mesh *m, const char *path);

#endif
