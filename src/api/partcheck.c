/*
 * partcheck.c - what an upload holds, by its content (partcheck.h).
 *
 * The kinds are told apart from the head in the order that cannot be
 * fooled: a zip's magic, then a binary STL (whose 80-byte header may well
 * begin "solid", so its count is checked before any text rule; text never
 * passes it, as four text bytes make a count of 538 million triangles or
 * more), then NUL bytes (binary), then the text kinds.
 *
 * Thread: any.
 */
#include "partcheck.h"

#include <fcntl.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <unistd.h>

#include "../base/mem.h"
#include "../mesh/mesh.h"
#include "api_compat.h"

/* The next line of [*at, end): its start and length (no line end); false at the end. */
static bool
next_line(const unsigned char *p, size_t len, size_t *at, const char **line, size_t *n)
{
    if (*at >= len)
        return false;
    size_t s = *at, e = s;
    while (e < len && p[e] != '\n')
        e++;
    *line = (const char *)p + s;
    *n = e - s;
    while (*n && ((*line)[*n - 1] == '\r' || (*line)[*n - 1] == ' ' || (*line)[*n - 1] == '\t'))
        (*n)--;
    while (*n && (**line == ' ' || **line == '\t')) {
        (*line)++;
        (*n)--;
    }
    *at = e + 1;
    return true;
}

/* Is the first word of line (n bytes) w? */
static bool
word_is(const char *line, size_t n, const char *w)
{
    size_t k = strlen(w);
    return n >= k && memcmp(line, w, k) == 0 && (n == k || line[k] == ' ' || line[k] == '\t');
}

/* "solid NAME", then "facet" or "endsolid" (what stl_parse reads first). */
static bool
ascii_stl(const unsigned char *p, size_t len)
{
    size_t at = 0, n;
    const char *l;
    bool got;
    while ((got = next_line(p, len, &at, &l, &n)) && n == 0)
        ;
    if (!got)
        return false; /* empty, or blank lines only */
    if (!(word_is(l, n, "solid") || (n == 5 && memcmp(l, "solid", 5) == 0)))
        return false;
    while (next_line(p, len, &at, &l, &n))
        if (n)
            return word_is(l, n, "facet") || (n >= 8 && memcmp(l, "endsolid", 8) == 0);
    return false;
}

/* Its first line that is no comment is a G, M or T code (N: a numbered line). */
static bool
gcode(const unsigned char *p, size_t len)
{
    size_t at = 0, n;
    const char *l;
    while (next_line(p, len, &at, &l, &n)) {
        if (n == 0 || l[0] == ';' || l[0] == '(')
            continue;
        char c = l[0] & ~0x20; /* upper case */
        return n >= 2 && (c == 'G' || c == 'M' || c == 'T' || c == 'N') && l[1] >= '0' &&
               l[1] <= '9';
    }
    return false;
}

/* Every whole line an OBJ statement or comment, and some v or f among them. */
static bool
obj(const unsigned char *p, size_t len)
{
    static const char *const words[] = { "v",      "vt",       "vn",      "vp",   "f",     "l",
                                         "p",      "o",        "g",       "s",    "mg",    "mtllib",
                                         "usemtl", "cstype",   "deg",     "curv", "curv2", "surf",
                                         "parm",   "trim",     "hole",    "scrv", "sp",    "end",
                                         "bmat",   "step",     "lod",     "call", "csh",   "maplib",
                                         "usemap", "c_interp", "d_interp" };
    size_t at = 0, n;
    const char *l;
    bool geometry = false;
    /* the last line may be cut by the head's end: judge whole lines only */
    size_t whole = len;
    while (whole > 0 && p[whole - 1] != '\n')
        whole--;
    if (whole == 0)
        whole = len; /* one line, all of the file or of the head */
    while (next_line(p, whole, &at, &l, &n)) {
        if (n == 0 || l[0] == '#')
            continue;
        bool known = false;
        for (size_t k = 0; k < sizeof(words) / sizeof(*words) && !known; k++)
            known = word_is(l, n, words[k]);
        if (!known)
            return false;
        geometry |= word_is(l, n, "v") || word_is(l, n, "f");
    }
    return geometry;
}

enum partcheck_kind
partcheck_kind(const unsigned char *p, size_t len, size_t size)
{
    if (len >= 4 && memcmp(p, "PK\3\4", 4) == 0)
        return PARTCHECK_ZIP;
    if (len >= 84) {
        uint32_t n;
        memcpy(&n, p + 80, 4);
        if ((uint64_t)84 + (uint64_t)50 * n <= size)
            return PARTCHECK_STL_BINARY;
    }
    if (memchr(p, 0, len))
        return PARTCHECK_BINARY;
    if (ascii_stl(p, len))
        return PARTCHECK_STL_ASCII;
    if (gcode(p, len))
        return PARTCHECK_GCODE;
    return obj(p, len) ? PARTCHECK_OBJ : PARTCHECK_TEXT;
}

/* What kind k is, for a refusal, with what to do about it. */
static const char *
holds(enum partcheck_kind k)
{
    switch (k) {
    case PARTCHECK_TEXT:
        return "holds plain text";
    case PARTCHECK_BINARY:
        return "holds binary data of no kind a part comes in";
    case PARTCHECK_STL_BINARY:
        return "is a binary STL by its content: name it .stl";
    case PARTCHECK_STL_ASCII:
        return "is an ASCII STL by its content: name it .stl";
    case PARTCHECK_OBJ:
        return "is a Wavefront OBJ by its content: name it .obj";
    case PARTCHECK_ZIP:
        return "is a zip archive (a 3MF?): name a 3MF .3mf";
    case PARTCHECK_GCODE:
        return "is G-code by its content: name it .gcode (POST /api/files/local prints it as is)";
    }
    return "?";
}

/* The file's extension's kind: what it must hold ("STL", "OBJ", "3MF", "G-code"), and the
   refusal's words ("not an STL"). */
static const char *
wanted(const char *name, const char * * not )
{
    const char *dot = strrchr(name, '.');
    if (api_compat_is_gcode(name)) {
        *not = "not G-code";
        return "G-code";
    }
    if (dot && strcasecmp(dot, ".obj") == 0) {
        *not = "not an OBJ";
        return "OBJ";
    }
    if (dot && strcasecmp(dot, ".3mf") == 0) {
        *not = "not a 3MF";
        return "3MF";
    }
    *not = "not an STL";
    return "STL";
}

/* Does kind k hold what `want` names?  G-code is anything but a mesh: its lines are judged
   later, each refusal naming its line and byte (farm_gcode_check). */
static bool
fits(const char *want, enum partcheck_kind k)
{
    if (strcmp(want, "STL") == 0)
        return k == PARTCHECK_STL_BINARY || k == PARTCHECK_STL_ASCII;
    if (strcmp(want, "OBJ") == 0)
        return k == PARTCHECK_OBJ;
    if (strcmp(want, "3MF") == 0)
        return k == PARTCHECK_ZIP;
    return k == PARTCHECK_GCODE || k == PARTCHECK_TEXT || k == PARTCHECK_BINARY;
}

/* A whole small file through its mesh parser (STL, OBJ); the parser's message on a refusal. */
static int
parse_whole(const unsigned char *p, size_t len, const char *name, enum partcheck_kind k,
            struct sf_err *err)
{
    struct mesh m;
    mesh_init(&m);
    int rc =
        k == PARTCHECK_OBJ ? obj_parse(p, len, name, &m, err) : stl_parse(p, len, name, &m, err);
    mesh_release(&m);
    return rc;
}

int
partcheck_file(const char *path, const char *name, struct sf_err *err)
{
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    struct stat sb;
    if (fd < 0 || fstat(fd, &sb) != 0) {
        int rc = sf_err_sys(err, "upload '%s': cannot read it back", name);
        if (fd >= 0)
            close(fd);
        return rc;
    }
    unsigned char *head = mem_alloc(PARTCHECK_HEAD);
    ssize_t len = head ? read(fd, head, PARTCHECK_HEAD) : -1;
    close(fd);
    int rc = SF_OK;
    if (len < 0) {
        rc = head ? sf_err_sys(err, "upload '%s': cannot read it back", name)
                  : sf_err_set(err, SF_ENOMEM, "out of memory");
        goto out;
    }
    const char * not ;
    const char *want = wanted(name, &not );
    enum partcheck_kind k = partcheck_kind(head, (size_t)len, (size_t)sb.st_size);
    if (!fits(want, k)) {
        rc = sf_err_set(err, SF_EINVAL, "%s: '%s' %s", not, name, holds(k));
        goto out;
    }
    if ((k == PARTCHECK_STL_BINARY || k == PARTCHECK_STL_ASCII || k == PARTCHECK_OBJ) &&
        (size_t)sb.st_size <= PARTCHECK_HEAD) {
        struct sf_err why;
        if (parse_whole(head, (size_t)len, name, k, &why))
            rc = sf_err_set(err, SF_EINVAL, "%s: %s", not, why.msg);
    }
out:
    free(head);
    return rc;
}
