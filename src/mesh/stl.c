/*
 * stl.c - binary and ASCII STL to a triangle soup (welded later by
 * mesh_load).
 *
 * Binary STL is read in one pass over the mapped bytes: its size must
 * match the triangle count in the header (a count larger than the file is
 * the classic corrupt-file case and is reported as such, never allocated).
 * ASCII STL is scanned by keyword; the facet normal is ignored because
 * many exporters write zeros there, and the winding defines the normal.
 * Every coordinate must be finite and within SF_MESH_COORD_MAX.
 */
#include <ctype.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "../base/limits.h"
#include "../base/mem.h"
#include "mesh.h"

static int
check_coord(double x, const char *name, const char *where, uint32_t facet, struct sf_err *err)
{
    if (!isfinite(x))
        return sf_err_set(err, SF_EINVAL, "stl '%s': %s %u: coordinate is %s", name, where,
                          facet, isnan(x) ? "NaN" : "infinite");
    if (fabs(x) > SF_MESH_COORD_MAX)
        return sf_err_set(err, SF_EINVAL,
                          "stl '%s': %s %u: coordinate %g is beyond %g mm (wrong unit or corrupt)",
                          name, where, facet, x, SF_MESH_COORD_MAX);
    return SF_OK;
}

static int
parse_binary(const unsigned char *p, size_t len, const char *name, struct mesh *m,
             struct sf_err *err)
{
    if (len < 84)
        return sf_err_set(err, SF_EINVAL,
                          "stl '%s': %zu bytes is too short for a binary STL header", name, len);
    uint32_t n;
    memcpy(&n, p + 80, 4);
    uint64_t need = 84 + (uint64_t)50 * n;
    if (need > len)
        return sf_err_set(err, SF_EINVAL,
                          "stl '%s': header declares %u triangles (%llu bytes) but the file has "
                          "only %zu bytes",
                          name, n, (unsigned long long)need, len);
    if (n > SF_MESH_TRIS_MAX)
        return sf_err_set(err, SF_EINVAL, "stl '%s': %u triangles is over the limit of %u", name,
                          n, SF_MESH_TRIS_MAX);
    int rc = mesh_alloc(m, 3 * n, n, err);
    if (rc)
        return rc;
    const unsigned char *rec = p + 84;
    for (uint32_t i = 0; i < n; i++, rec += 50) {
        float f[9];
        memcpy(f, rec + 12, sizeof(f));
        for (int k = 0; k < 3; k++) {
            struct vec3 v = v3(f[3 * k], f[3 * k + 1], f[3 * k + 2]);
            if ((rc = check_coord(v.x, name, "facet", i + 1, err)) ||
                (rc = check_coord(v.y, name, "facet", i + 1, err)) ||
                (rc = check_coord(v.z, name, "facet", i + 1, err))) {
                mesh_release(m);
                return rc;
            }
            m->v[3 * i + (uint32_t)k] = v;
            m->t[i][k] = 3 * i + (uint32_t)k;
        }
    }
    return SF_OK;
}

struct scanner {
    const char *p, *end;
    uint32_t line; /* 1-based, for messages */
};

/* Next whitespace-separated token; false at end of input. */
static bool
next_token(struct scanner *s, const char **tok, size_t *len)
{
    while (s->p < s->end && isspace((unsigned char)*s->p)) {
        if (*s->p == '\n')
            s->line++;
        s->p++;
    }
    if (s->p >= s->end)
        return false;
    *tok = s->p;
    while (s->p < s->end && !isspace((unsigned char)*s->p))
        s->p++;
    *len = (size_t)(s->p - *tok);
    return true;
}

static bool
tok_is(const char *tok, size_t len, const char *word)
{
    return len == strlen(word) && strncasecmp(tok, word, len) == 0;
}

static bool
tok_number(const char *tok, size_t len, double *out)
{
    char tmp[64];
    if (len == 0 || len >= sizeof(tmp))
        return false;
    memcpy(tmp, tok, len);
    tmp[len] = '\0';
    char *end;
    *out = strtod(tmp, &end);
    return *end == '\0';
}

static int
parse_ascii(const char *data, size_t len, const char *name, struct mesh *m, struct sf_err *err)
{
    struct scanner s = { data, data + len, 1 };
    const char *tok;
    size_t tl;
    uint32_t cap_v = 0, cap_t = 0, facet = 0;
    struct vec3 *v = NULL;
    uint32_t(*t)[3] = NULL;
    int rc = SF_OK;

    if (!next_token(&s, &tok, &tl) || !tok_is(tok, tl, "solid"))
        return sf_err_set(err, SF_EINVAL, "stl '%s': line 1: 'solid' expected", name);
    /* the solid's name runs to the end of the line */
    while (s.p < s.end && *s.p != '\n')
        s.p++;
    mesh_release(m);
    for (;;) {
        if (!next_token(&s, &tok, &tl)) {
            rc = sf_err_set(err, SF_EINVAL, "stl '%s': line %u: file ends before 'endsolid'",
                            name, s.line);
            goto fail;
        }
        if (tok_is(tok, tl, "endsolid"))
            break;
        if (!tok_is(tok, tl, "facet")) {
            rc = sf_err_set(err, SF_EINVAL, "stl '%s': line %u: 'facet' or 'endsolid' expected",
                            name, s.line);
            goto fail;
        }
        facet++;
        /* skip "normal nx ny nz outer loop" up to the first vertex */
        for (;;) {
            if (!next_token(&s, &tok, &tl)) {
                rc = sf_err_set(err, SF_EINVAL, "stl '%s': line %u: facet %u is cut short", name,
                                s.line, facet);
                goto fail;
            }
            if (tok_is(tok, tl, "loop"))
                break;
            if (!tok_is(tok, tl, "normal") && !tok_is(tok, tl, "outer")) {
                double dummy;
                if (!tok_number(tok, tl, &dummy)) {
                    rc = sf_err_set(err, SF_EINVAL,
                                    "stl '%s': line %u: facet %u: unexpected '%.*s'", name,
                                    s.line, facet, (int)(tl > 32 ? 32 : tl), tok);
                    goto fail;
                }
            }
        }
        if (facet > SF_MESH_TRIS_MAX) {
            rc = sf_err_set(err, SF_EINVAL, "stl '%s': more than %u facets", name,
                            SF_MESH_TRIS_MAX);
            goto fail;
        }
        if (m->n_verts + 3 > cap_v) {
            cap_v = cap_v ? 2 * cap_v : 768;
            struct vec3 *nv = mem_realloc_array(v, cap_v, sizeof(*v));
            if (!nv) {
                rc = sf_err_set(err, SF_ENOMEM, "stl '%s': out of memory", name);
                goto fail;
            }
            v = nv;
        }
        if (m->n_tris + 1 > cap_t) {
            cap_t = cap_t ? 2 * cap_t : 256;
            uint32_t(*nt)[3] = mem_realloc_array(t, cap_t, sizeof(*t));
            if (!nt) {
                rc = sf_err_set(err, SF_ENOMEM, "stl '%s': out of memory", name);
                goto fail;
            }
            t = nt;
        }
        for (int k = 0; k < 3; k++) {
            double c[3];
            if (!next_token(&s, &tok, &tl) || !tok_is(tok, tl, "vertex")) {
                rc = sf_err_set(err, SF_EINVAL,
                                "stl '%s': line %u: facet %u: 'vertex' expected (a facet has "
                                "exactly 3)",
                                name, s.line, facet);
                goto fail;
            }
            for (int a = 0; a < 3; a++) {
                if (!next_token(&s, &tok, &tl) || !tok_number(tok, tl, &c[a])) {
                    rc = sf_err_set(err, SF_EINVAL,
                                    "stl '%s': line %u: facet %u: vertex coordinate expected",
                                    name, s.line, facet);
                    goto fail;
                }
                if ((rc = check_coord(c[a], name, "facet", facet, err)))
                    goto fail;
            }
            t[m->n_tris][k] = m->n_verts;
            v[m->n_verts++] = v3(c[0], c[1], c[2]);
        }
        m->n_tris++;
        if (!next_token(&s, &tok, &tl) || !tok_is(tok, tl, "endloop") ||
            !next_token(&s, &tok, &tl) || !tok_is(tok, tl, "endfacet")) {
            rc = sf_err_set(err, SF_EINVAL,
                            "stl '%s': line %u: facet %u: 'endloop endfacet' expected", name,
                            s.line, facet);
            goto fail;
        }
    }
    m->v = v;
    m->t = t;
    return SF_OK;
fail:
    free(v);
    free(t);
    mesh_init(m);
    return rc;
}

int
stl_parse(const void *data, size_t len, const char *name, struct mesh *m, struct sf_err *err)
{
    if (mesh_detect(data, len) == MESH_FMT_STL_ASCII)
        return parse_ascii(data, len, name, m, err);
    return parse_binary(data, len, name, m, err);
}
