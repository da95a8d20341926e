/*
 * limits.h - every cap on input from outside, each with its reason.
 *
 * A cap turns a hostile or broken input (a 4 GB "STL", a printer that sends
 * an endless line) into a clear error instead of an exhausted machine.  Keep
 * them generous: they guard the machine, they are not policy.
 */
#ifndef SF_BASE_LIMITS_H
#define SF_BASE_LIMITS_H

/* Largest mesh file read into memory: a 20M-facet binary STL is 1 GB. */
#define SF_MESH_FILE_MAX ((size_t)1 << 30)

/* Most triangles in one part: 20M facets is far past any printable part at
   0.4 mm nozzle resolution and keeps a mesh under ~1 GB in memory. */
#define SF_MESH_TRIS_MAX 20000000u

/* Most vertices in one part, for the same reason. */
#define SF_MESH_VERTS_MAX 20000000u

/* Largest coordinate magnitude accepted, in mm: 100 m.  Beyond this a file
   is in the wrong unit or corrupt, and float precision is gone anyway. */
#define SF_MESH_COORD_MAX 1.0e5

/* Longest text line in OBJ/ASCII STL: real files stay far below 1 KiB. */
#define SF_TEXT_LINE_MAX 65536

/* Largest uncompressed 3MF model part: same budget as a mesh file. */
#define SF_3MF_MODEL_MAX ((size_t)1 << 30)

/* What a 3MF package may unpack to, all its entries together: this many
   times its own size (but at least SF_3MF_UNPACK_MIN, at most
   SF_3MF_MODEL_MAX).  Mesh XML deflates 3-8x in practice, so 64x is far past
   any real file, while deflate's own limit (~1000x) lets a 1 MB zip bomb
   claim a gigabyte; and the file itself is capped by the daemon's
   upload_max, so the unpacked text is too. */
#define SF_3MF_UNPACK_RATIO 64
#define SF_3MF_UNPACK_MIN   ((size_t)16 << 20)

/* Longest G-code line we accept: Marlin's MAX_CMD_SIZE is 96; slicers emit
   long comments, which we strip, so allow 4 KiB of raw line. */
#define SF_GCODE_LINE_MAX 4096

/* A manual command (POST /api/printers/NAME/command): one line, its comment
   stripped; Marlin takes 96 bytes with the line number and checksum, and a
   Klipper macro call with its parameters fits in 256. */
#define SF_COMMAND_MAX 256

/* Longest reply line from a printer before it is dropped as garbage:
   M115 capability lines and M503 dumps stay under 512 bytes. */
#define SF_PRINTER_LINE_MAX 1024

/* A printer's link options (drivers/drv_link.h): each option at most once
   per section; the longest values of all of them together (about 1.4 KiB:
   URLs, keys, paths) fit the text, which a unit test checks. */
#define SF_LINK_OPTS_MAX 32
#define SF_LINK_TEXT_MAX 2048

/* Largest file a PostgreSQL store shares through its database (store_blob.c):
   4 GiB, as upload_max_mb's ceiling; G-code for the largest beds stays far
   below.  It bounds what a host trusts a database row's size for, too. */
#define SF_STORE_BLOB_MAX ((int64_t)4 << 30)

/* Config file size: a farm of 1000 printers fits easily in 4 MiB. */
#define SF_CONFIG_FILE_MAX ((size_t)4 << 20)

/* Ray grid cells per side when measuring support: 1 mm pitch on a 4 m bed.
   Guards memory when a caller passes a tiny pitch. */
#define SF_GRID_CELLS_MAX 4000000u

/* Longest line of an INI profile: Debian's libinih reads lines into a
   200-byte stack buffer (INI_MAX_LINE), so longer lines would be split
   silently; we reject them with the line number instead.  Long G-code
   goes on indented continuation lines. */
#define SF_INI_LINE_MAX 196

/* Most layers in one print: 1 m of height at 0.05 mm. */
#define SF_SLICE_LAYERS_MAX 20000u

/* Host name lookups in flight at once, each a thread that a dead nameserver
   can hold for 30 s and more (5 s timeout x 2 attempts x 3 nameservers):
   a farm of TCP printers reconnecting while DNS is down must not grow
   threads without bound. */
#define SF_RESOLVER_THREADS_MAX 64

#endif
