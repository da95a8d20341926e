/*
 * obj.c - Wavefront OBJ to an indexed mesh.
 *
 * Reads `v x y z [w]` and `f` lines (polygons fan-triangulated; indices in
 * the forms i, i/t, i//n, i/t/n; negative indices count back from the last
 * vertex).  Every other statement (vt, vn, g, o, s, usemtl, mtllib, l, ...)
 * is skipped: it does not change the shape.  Faces may refer to vertices
 * defined later in the file, so indices are checked once all are read.
 */
#include <ctype.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "../base/limits.h"
#include "../base/mem.h"
#include "mesh.h"

struct obj_state {
    const char *name;
    struct vec3 *v;
    size_t n_v, cap_v;
    int64_t (*f)[3];  /* raw indices (1-based or negative, resolved later) */
    uint32_t *f_line; /* source line of each triangle, for messages */
    size_t n_f, cap_f;
};

static const char *
skip_ws(const char *p, const char *end)
{
    while (p < end && (*p == ' ' || *p == '\t' || *p == '\r'))
        p++;
    return p;
}

static bool
parse_double(const char **pp, const char *end, double *out)
{
    char tmp[64];
    const char *p = skip_ws(*pp, end);
    size_t n = 0;
    while (p + n < end && !isspace((unsigned char)p[n]) && n < sizeof(tmp) - 1)
        n++;
    if (n == 0 || n == sizeof(tmp) - 1)
        return false;
    memcpy(tmp, p, n);
    tmp[n] = '\0';
    char *e;
    *out = strtod(tmp, &e);
    if (*e != '\0')
        return false;
    *pp = p + n;
    return true;
}

/* Parse "i", "i/t", "i//n", "i/t/n"; store i.  Returns false on junk. */
static bool
parse_index(const char **pp, const char *end, int64_t *out)
{
    const char *p = *pp;
    bool neg = false;
    if (p < end && (*p == '-' || *p == '+')) {
        neg = *p == '-';
        p++;
    }
    int64_t v = 0;
    const char *digits = p;
    while (p < end && isdigit((unsigned char)*p)) {
        v = v * 10 + (*p - '0');
        if (v > (int64_t)SF_MESH_VERTS_MAX * 4)
            return false;
        p++;
    }
    if (p == digits || v == 0)
        return false;
    /* skip /t and /n parts */
    while (p < end && (*p == '/' || isdigit((unsigned char)*p) || *p == '-'))
        p++;
    if (p < end && !isspace((unsigned char)*p))
        return false;
    *out = neg ? -v : v;
    *pp = p;
    return true;
}

static int
add_tri(struct obj_state *st, int64_t a, int64_t b, int64_t c, uint32_t line, struct sf_err *err)
{
    if (st->n_f >= SF_MESH_TRIS_MAX)
        return sf_err_set(err, SF_EINVAL, "obj '%s': line %u: more than %u triangles", st->name,
                          line, SF_MESH_TRIS_MAX);
    if (st->n_f == st->cap_f) {
        size_t cap = st->cap_f;
        void *f = st->f, *fl = st->f_line;
        if (!mem_grow(&f, &cap, st->n_f + 1, sizeof(*st->f)))
            return sf_err_set(err, SF_ENOMEM, "obj '%s': out of memory", st->name);
        st->f = f;
        cap = st->cap_f;
        if (!mem_grow(&fl, &cap, st->n_f + 1, sizeof(*st->f_line)))
            return sf_err_set(err, SF_ENOMEM, "obj '%s': out of memory", st->name);
        st->f_line = fl;
        st->cap_f = cap;
    }
    st->f[st->n_f][0] = a;
    st->f[st->n_f][1] = b;
    st->f[st->n_f][2] = c;
    st->f_line[st->n_f] = line;
    st->n_f++;
    return SF_OK;
}

/* Resolve a raw OBJ index against the vertex count at its line (negative) or overall. */
static int64_t
resolve(int64_t raw, size_t n_v_at_line)
{
    return raw > 0 ? raw - 1 : (int64_t)n_v_at_line + raw;
}

int
obj_parse(const void *data, size_t len, const char *name, struct mesh *m, struct sf_err *err)
{
    struct obj_state st = { name, NULL, 0, 0, NULL, NULL, 0, 0 };
    const char *p = data, *end = p + len;
    uint32_t line = 0;
    int rc = SF_OK;

    mesh_release(m);
    while (p < end) {
        const char *eol = memchr(p, '\n', (size_t)(end - p));
        if (!eol)
            eol = end;
        line++;
        if (eol - p > SF_TEXT_LINE_MAX) {
            rc = sf_err_set(err, SF_EINVAL, "obj '%s': line %u: longer than %d bytes", name, line,
                            SF_TEXT_LINE_MAX);
            goto fail;
        }
        const char *q = skip_ws(p, eol);
        if (q + 1 < eol && q[0] == 'v' && (q[1] == ' ' || q[1] == '\t')) {
            double c[3];
            q += 1;
            for (int k = 0; k < 3; k++) {
                if (!parse_double(&q, eol, &c[k])) {
                    rc = sf_err_set(err, SF_EINVAL, "obj '%s': line %u: vertex needs x y z", name,
                                    line);
                    goto fail;
                }
                if (!isfinite(c[k]) || fabs(c[k]) > SF_MESH_COORD_MAX) {
                    rc =
                        sf_err_set(err, SF_EINVAL,
                                   "obj '%s': line %u: coordinate %g is not finite or beyond %g mm",
                                   name, line, c[k], SF_MESH_COORD_MAX);
                    goto fail;
                }
            }
            if (st.n_v >= SF_MESH_VERTS_MAX) {
                rc = sf_err_set(err, SF_EINVAL, "obj '%s': line %u: more than %u vertices", name,
                                line, SF_MESH_VERTS_MAX);
                goto fail;
            }
            void *vp = st.v;
            if (!mem_grow(&vp, &st.cap_v, st.n_v + 1, sizeof(*st.v))) {
                rc = sf_err_set(err, SF_ENOMEM, "obj '%s': out of memory", name);
                goto fail;
            }
            st.v = vp;
            st.v[st.n_v++] = v3(c[0], c[1], c[2]);
        } else if (q + 1 < eol && q[0] == 'f' && (q[1] == ' ' || q[1] == '\t')) {
            int64_t first = 0, prev = 0, idx;
            int n = 0;
            q += 1;
            for (;;) {
                q = skip_ws(q, eol);
                if (q >= eol)
                    break;
                if (!parse_index(&q, eol, &idx)) {
                    rc =
                        sf_err_set(err, SF_EINVAL, "obj '%s': line %u: bad face index", name, line);
                    goto fail;
                }
                /* negative indices are relative to the vertices read so far */
                if (idx < 0)
                    idx = resolve(idx, st.n_v) + 1;
                if (idx <= 0) {
                    rc = sf_err_set(err, SF_EINVAL,
                                    "obj '%s': line %u: relative index points before vertex 1",
                                    name, line);
                    goto fail;
                }
                if (n == 0)
                    first = idx;
                else if (n >= 2 && (rc = add_tri(&st, first, prev, idx, line, err)))
                    goto fail;
                prev = idx;
                n++;
            }
            if (n < 3) {
                rc = sf_err_set(err, SF_EINVAL,
                                "obj '%s': line %u: a face needs 3 or more vertices", name, line);
                goto fail;
            }
        }
        p = eol < end ? eol + 1 : end;
    }
    if ((rc = mesh_alloc(m, (uint32_t)st.n_v, (uint32_t)st.n_f, err)))
        goto fail;
    if (st.n_v)
        memcpy(m->v, st.v, sizeof(*st.v) * st.n_v);
    for (size_t i = 0; i < st.n_f; i++)
        for (int k = 0; k < 3; k++) {
            int64_t v = st.f[i][k] - 1;
            if (v < 0 || (size_t)v >= st.n_v) {
                rc = sf_err_set(err, SF_EINVAL,
                                "obj '%s': line %u: vertex index %lld out of range (%zu vertices)",
                                name, st.f_line[i], (long long)st.f[i][k], st.n_v);
                mesh_release(m);
                goto fail;
            }
            m->t[i][k] = (uint32_t)v;
        }
fail:
    free(st.v);
    free(st.f);
    free(st.f_line);
    return rc;
}
