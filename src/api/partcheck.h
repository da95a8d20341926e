/*
 * partcheck.h - an uploaded file judged by its content before it becomes a
 * job (issue 31: a text file renamed .stl was queued and failed later with
 * broken pictures).  A part named .stl must hold a binary or ASCII STL, .obj
 * a Wavefront OBJ, .3mf a zip archive (what a 3MF is), and G-code must not
 * be a mesh (its lines are judged on the io thread, naming each bad one);
 * a refusal says what the file holds instead ("not an STL:
 * 'notes.stl' holds plain text, ...").
 *
 * Cheap by design, as it runs on the loop thread that feeds the printers:
 * the first PARTCHECK_HEAD bytes and the size (a binary STL's header count
 * must fit it), and a file no longer than that is parsed whole by its
 * mesh parser (src/mesh), whose message is then the reason.  G-code's
 * lines are judged later on the farm's io thread (farm_gcode_check).
 *
 * Thread: any (reads the file it is given).
 */
#ifndef SF_API_PARTCHECK_H
#define SF_API_PARTCHECK_H

#include <stddef.h>

#include "../base/err.h"

/* Bytes read from an upload's start (and parsed whole when it is no longer). */
#define PARTCHECK_HEAD 65536

/* What a file's content says it is. */
enum partcheck_kind {
    PARTCHECK_TEXT = 0,   /* text that is none of the below */
    PARTCHECK_BINARY,     /* NUL bytes, and none of the below */
    PARTCHECK_STL_BINARY, /* 84-byte header, then 50 bytes a triangle as the header counts */
    PARTCHECK_STL_ASCII,  /* "solid NAME", then "facet" or "endsolid" */
    PARTCHECK_OBJ,        /* lines of OBJ statements, at least one v or f */
    PARTCHECK_ZIP,        /* "PK\3\4": a zip archive, as a 3MF is */
    PARTCHECK_GCODE,      /* its first command line is a G, M or T code */
};

/* The kind of a file of `size` bytes whose first len bytes are head. */
enum partcheck_kind partcheck_kind(const unsigned char *head, size_t len, size_t size);

/*
 * Judge the upload at path, named name (its extension says what it must
 * be).  SF_OK, or SF_EINVAL with the reason ("not an STL: 'NAME' ...");
 * SF_EIO when it cannot be read.
 */
int partcheck_file(const char *path, const char *name, struct sf_err *err);

#endif
