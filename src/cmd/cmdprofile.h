/*
 * cmdprofile.h - slicing profiles by name, for the command programs that
 * slice or estimate (cmd_slice.c, cmd_estimate.c).  Linked only into them:
 * the loader brings the INI parser (libinih).
 */
#ifndef SF_CMD_CMDPROFILE_H
#define SF_CMD_CMDPROFILE_H

#include <stdbool.h>

#include "../../slicer/profile.h"

/*
 * Load the slicing profile from a printer and a material (either NULL for
 * the defaults).  Each NAME is a path when it holds a '/' or ends in
 * ".cfg", else KIND/NAME.cfg under $SLIMFARM_CONFIG, ./config, then the
 * installed share/slimfarm/config folders.  On failure print "slimfarm
 * CMD: no printer profile 'NAME'" or the loader's error and return false.
 */
bool cmd_load_profile(const char *cmd, const char *printer, const char *material,
                      struct slice_profile *p);

#endif
