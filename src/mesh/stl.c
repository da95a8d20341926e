/*
 * stl.c - binary and ASCII STL to a triangle soup (welded later by
 * mesh_load).
 *
 * Binary STL is read in one pass: its size must match the triangle count
 * in the header (a count larger than the file is the classic corrupt-file
 * case and is reported as such, never allocated), and bit-identical corners
 * are merged on the fly.
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
        return sf_err_set(err, SF_EINVAL, "stl '%s': %s %u: coordinate is %s", name, where, facet,
                          isnan(x) ? "NaN" : "infinite");
    if (fabs(x) > SF_MESH_COORD_MAX)
        return sf_err_set(err, SF_EINVAL,
                          "stl '%s': %s %u: coordinate %g is beyond %g mm (wrong unit or corrupt)",
                          name, where, facet, x, SF_MESH_COORD_MAX);
    return SF_OK;
}

/*
 * Binary STL is parsed straight into an indexed mesh: each corner's three
 * floats are hashed by their bits and looked up in an open-addressing table
 * of vertex indices, so the 3n-corner soup is never materialised (a soup of
 * doubles is 72 bytes a triangle; a closed mesh has about n/2 vertices).
 * Bit-identical corners become one vertex; the tolerance weld in mesh_load
 * then only sees the unique ones.  -0.0 is folded into 0.0 first.
 */
struct corner_table {
    uint32_t *slot; /* vertex index or UINT32_MAX */
    uint64_t mask;
    uint32_t used;
};

static uint64_t
corner_hash(const uint32_t b[3])
{
    uint64_t h =
        b[0] * 0x9E3779B97F4A7C15ULL ^ b[1] * 0xC2B2AE3D27D4EB4FULL ^ b[2] * 0x165667B19E3779F9ULL;
    return h ^ (h >> 29);
}

static bool
corner_table_grow(struct corner_table *ct, const struct vec3 *v)
{
    uint64_t size = (ct->mask + 1) * 2;
    uint32_t *slot = mem_array(size, sizeof(uint32_t));
    if (!slot)
        return false;
    memset(slot, 0xff, size * sizeof(uint32_t));
    for (uint64_t i = 0; i <= ct->mask; i++) {
        uint32_t r = ct->slot[i];
        if (r == UINT32_MAX)
            continue;
        float f[3] = { (float)v[r].x, (float)v[r].y, (float)v[r].z };
        uint32_t bits[3];
        memcpy(bits, f, sizeof(bits));
        uint64_t s = corner_hash(bits) & (size - 1);
        while (slot[s] != UINT32_MAX)
            s = (s + 1) & (size - 1);
        slot[s] = r;
    }
    free(ct->slot);
    ct->slot = slot;
    ct->mask = size - 1;
    return true;
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
        return sf_err_set(err, SF_EINVAL, "stl '%s': %u triangles is over the limit of %u", name, n,
                          SF_MESH_TRIS_MAX);
    mesh_release(m);
    struct corner_table ct = { NULL, 0, 0 };
    size_t cap_v = (size_t)n / 2 + 16;
    m->t = mem_array(n ? n : 1, sizeof(*m->t));
    m->v = mem_array(cap_v, sizeof(*m->v));
    uint64_t size = 64;
    while (size < 2 * cap_v)
        size <<= 1;
    ct.slot = mem_array(size, sizeof(uint32_t));
    ct.mask = size - 1;
    int rc = SF_OK;
    if (!m->t || !m->v || !ct.slot) {
        rc = sf_err_set(err, SF_ENOMEM, "stl '%s': out of memory for %u triangles", name, n);
        goto fail;
    }
    memset(ct.slot, 0xff, size * sizeof(uint32_t));
    const unsigned char *rec = p + 84;
    for (uint32_t i = 0; i < n; i++, rec += 50) {
        float f[9];
        memcpy(f, rec + 12, sizeof(f));
        for (int k = 0; k < 3; k++) {
            float *c = f + 3 * k;
            for (int a = 0; a < 3; a++) {
                if ((rc = check_coord(c[a], name, "facet", i + 1, err)))
                    goto fail;
                c[a] += 0.0f; /* -0.0 -> 0.0, so equal coordinates hash alike */
            }
            uint32_t bits[3];
            memcpy(bits, c, sizeof(bits));
            uint64_t s = corner_hash(bits) & ct.mask;
            uint32_t r;
            for (;;) {
                r = ct.slot[s];
                if (r == UINT32_MAX ||
                    (m->v[r].x == c[0] && m->v[r].y == c[1] && m->v[r].z == c[2]))
                    break;
                s = (s + 1) & ct.mask;
            }
            if (r == UINT32_MAX) {
                if (m->n_verts == cap_v) {
                    void *vp = m->v;
                    if (!mem_grow(&vp, &cap_v, cap_v + 1, sizeof(*m->v))) {
                        rc = sf_err_set(err, SF_ENOMEM, "stl '%s': out of memory", name);
                        goto fail;
                    }
                    m->v = vp;
                }
                r = m->n_verts++;
                m->v[r] = v3(c[0], c[1], c[2]);
                ct.slot[s] = r;
                if (++ct.used * 2 > ct.mask + 1 && !corner_table_grow(&ct, m->v)) {
                    rc = sf_err_set(err, SF_ENOMEM, "stl '%s': out of memory", name);
                    goto fail;
                }
            }
            m->t[i][k] = r;
        }
    }
    m->n_tris = n;
    free(ct.slot);
    return SF_OK;
fail:
    free(ct.slot);
    mesh_release(m);
    return rc;
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
            rc = sf_err_set(err, SF_EINVAL, "stl '%s': line %u: file ends before 'endsolid'", name,
                            s.line);
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
                    rc =
                        sf_err_set(err, SF_EINVAL, "stl '%s': line %u: facet %u: unexpected '%.*s'",
                                   name, s.line, facet, (int)(tl > 32 ? 32 : tl), tok);
                    goto fail;
                }
            }
        }
        if (facet > SF_MESH_TRIS_MAX) {
            rc =
                sf_err_set(err, SF_EINVAL, "stl '%s': more than %u facets", name, SF_MESH_TRIS_MAX);
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
                                    "stl '%s': line %u: facet %u: vertex coordinate expected", name,
                                    s.line, facet);
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
