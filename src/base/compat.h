/*
 * compat.h - force-included before every C file of the project (-include).
 *
 * It pulls in the libc headers that declare the functions banned.h
 * poisons, so that their declarations are seen before the poison, then
 * banned.h itself.  Nothing else belongs here.
 */
#ifndef SF_BASE_COMPAT_H
#define SF_BASE_COMPAT_H

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "banned.h"

#endif
