/*
 * tmf.c - 3MF (the 3D Manufacturing Format) to one indexed mesh.
 *
 * A 3MF file is a zip package; _rels/.rels names the model part (usually
 * 3D/3dmodel.model), an XML document with <object>s holding <mesh>es or
 * <components>, and a <build> listing the <item>s to print with affine
 * transforms.  Every build item is flattened into one mesh in millimetres
 * (the model's unit attribute is honoured).
 *
 * Library choice: minizip (zlib's contrib/minizip, Debian libminizip) +
 * expat rather than lib3mf.  Debian 12's lib3mf is the 1.8 C++ COM-style
 * API; minizip and expat are small, C, and let the whole loader run on a
 * memory buffer (our own I/O callbacks) under our own caps (uncompressed
 * size, object count, nesting depth).  minizip rather than libzip: libzip
 * pulls in libcrypto and libbz2, ~130 more page faults on every start of
 * every program that can read a part (`slimfarm orient` on a small part
 * spent 3-5 ms of its ~50 ms loading them); minizip needs only zlib, and
 * 3MF (OPC) allows only stored and deflated parts anyway.  Only the core
 * specification's geometry is read; materials, colours and slices are
 * ignored because they do not change the shape to print.
 */
#include <expat.h>
#include <math.h>
#include <minizip/unzip.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "../base/limits.h"
#include "../base/mem.h"
#include "mesh.h"

#define TMF_OBJECTS_MAX 100000 /* objects per model: far past any real plate */
#define TMF_DEPTH_MAX   16     /* component nesting */
#define TMF_ITEMS_MAX   100000 /* build items and component references */

/* 3MF affine transform: 3x3 then translation (m00 m01 m02 m10 ... m32), row vectors. */
struct tmf_xform {
    double m[12];
};

struct tmf_ref {
    uint32_t object_id; /* referenced object */
    struct tmf_xform xf;
};

struct tmf_object {
    uint32_t id;
    struct vec3 *v;
    uint32_t n_v, cap_v;
    uint32_t (*t)[3];
    uint32_t n_t, cap_t;
    struct tmf_ref *comps; /* components, if the object is an assembly */
    uint32_t n_comps, cap_comps;
};

struct tmf_parse {
    const char *name;
    XML_Parser xp;
    struct sf_err *err;
    int rc;
    double unit_mm;
    struct tmf_object *objs;
    uint32_t n_objs, cap_objs;
    struct tmf_object *cur; /* object being read, or NULL */
    struct tmf_ref *items;
    uint32_t n_items, cap_items;
    uint64_t n_tris_total;
};

static void
xf_identity(struct tmf_xform *x)
{
    static const double id[12] = { 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0 };
    memcpy(x->m, id, sizeof(id));
}

static struct vec3
xf_apply(const struct tmf_xform *x, struct vec3 p)
{
    const double *m = x->m;
    return v3(p.x * m[0] + p.y * m[3] + p.z * m[6] + m[9],
              p.x * m[1] + p.y * m[4] + p.z * m[7] + m[10],
              p.x * m[2] + p.y * m[5] + p.z * m[8] + m[11]);
}

/* a then b (apply a first). */
static struct tmf_xform
xf_then(const struct tmf_xform *a, const struct tmf_xform *b)
{
    struct tmf_xform r;
    for (int i = 0; i < 4; i++) {
        struct vec3 row = v3(a->m[3 * i], a->m[3 * i + 1], a->m[3 * i + 2]);
        struct vec3 o;
        if (i < 3)
            o = v3(row.x * b->m[0] + row.y * b->m[3] + row.z * b->m[6],
                   row.x * b->m[1] + row.y * b->m[4] + row.z * b->m[7],
                   row.x * b->m[2] + row.y * b->m[5] + row.z * b->m[8]);
        else
            o = xf_apply(b, row);
        r.m[3 * i] = o.x;
        r.m[3 * i + 1] = o.y;
        r.m[3 * i + 2] = o.z;
    }
    return r;
}

static void
fail(struct tmf_parse *p, int code, const char *what)
{
    if (p->rc)
        return;
    p->rc = sf_err_set(p->err, code, "3mf '%s': model line %lu: %s", p->name,
                       (unsigned long)XML_GetCurrentLineNumber(p->xp), what);
    XML_StopParser(p->xp, XML_FALSE);
}

/* Element names may carry a namespace prefix ("m:vertex"); compare the local part. */
static bool
is(const char *el, const char *local)
{
    const char *colon = strrchr(el, ':');
    return strcmp(colon ? colon + 1 : el, local) == 0;
}

static const char *
attr(const char **atts, const char *key)
{
    for (int i = 0; atts[i]; i += 2)
        if (strcmp(atts[i], key) == 0)
            return atts[i + 1];
    return NULL;
}

static bool
num_attr(const char **atts, const char *key, double *out)
{
    const char *s = attr(atts, key);
    if (!s)
        return false;
    char *end;
    *out = strtod(s, &end);
    return end != s && *end == '\0' && isfinite(*out);
}

static bool
id_attr(const char **atts, const char *key, uint32_t *out)
{
    double d;
    if (!num_attr(atts, key, &d) || d < 0 || d > 4294967295.0 || d != floor(d))
        return false;
    *out = (uint32_t)d;
    return true;
}

static bool
parse_xform(const char *s, struct tmf_xform *x)
{
    xf_identity(x);
    if (!s)
        return true;
    for (int i = 0; i < 12; i++) {
        char *end;
        x->m[i] = strtod(s, &end);
        if (end == s || !isfinite(x->m[i]))
            return false;
        s = end;
    }
    while (*s == ' ' || *s == '\t' || *s == '\n' || *s == '\r')
        s++;
    return *s == '\0';
}

/* <model unit=...>: the unit of the coordinates. */
static void
on_model(struct tmf_parse *p, const char **atts)
{
    const char *u = attr(atts, "unit");
    static const struct {
        const char *name;
        double mm;
    } units[] = { { "micron", 0.001 }, { "millimeter", 1 }, { "centimeter", 10 },
                  { "inch", 25.4 },    { "foot", 304.8 },   { "meter", 1000 } };
    if (u) {
        p->unit_mm = 0;
        for (size_t i = 0; i < sizeof(units) / sizeof(units[0]); i++)
            if (strcmp(u, units[i].name) == 0)
                p->unit_mm = units[i].mm;
        if (p->unit_mm == 0)
            fail(p, SF_EINVAL, "unknown unit");
    }
}

/* <object id=...>: a new current object. */
static void
on_object(struct tmf_parse *p, const char **atts)
{
    if (p->n_objs >= TMF_OBJECTS_MAX) {
        fail(p, SF_EINVAL, "too many objects");
        return;
    }
    void *o = p->objs;
    size_t cap = p->cap_objs;
    if (!mem_grow(&o, &cap, p->n_objs + 1, sizeof(*p->objs))) {
        fail(p, SF_ENOMEM, "out of memory");
        return;
    }
    p->objs = o;
    p->cap_objs = (uint32_t)cap;
    p->cur = &p->objs[p->n_objs++];
    memset(p->cur, 0, sizeof(*p->cur));
    if (!id_attr(atts, "id", &p->cur->id))
        fail(p, SF_EINVAL, "object without a valid id");
}

/* <vertex x= y= z=>: a vertex of the current object. */
static void
on_vertex(struct tmf_parse *p, const char **atts)
{
    double c[3];
    if (!p->cur) {
        fail(p, SF_EINVAL, "vertex outside an object");
        return;
    }
    if (!num_attr(atts, "x", &c[0]) || !num_attr(atts, "y", &c[1]) || !num_attr(atts, "z", &c[2])) {
        fail(p, SF_EINVAL, "vertex needs finite x, y and z");
        return;
    }
    if (p->cur->n_v >= SF_MESH_VERTS_MAX) {
        fail(p, SF_EINVAL, "too many vertices");
        return;
    }
    void *v = p->cur->v;
    size_t cap = p->cur->cap_v;
    if (!mem_grow(&v, &cap, p->cur->n_v + 1, sizeof(struct vec3))) {
        fail(p, SF_ENOMEM, "out of memory");
        return;
    }
    p->cur->v = v;
    p->cur->cap_v = (uint32_t)cap;
    p->cur->v[p->cur->n_v++] = v3(c[0], c[1], c[2]);
}

/* <triangle v1= v2= v3=>: a triangle of the current object. */
static void
on_triangle(struct tmf_parse *p, const char **atts)
{
    uint32_t a, b, c;
    if (!p->cur) {
        fail(p, SF_EINVAL, "triangle outside an object");
        return;
    }
    if (!id_attr(atts, "v1", &a) || !id_attr(atts, "v2", &b) || !id_attr(atts, "v3", &c)) {
        fail(p, SF_EINVAL, "triangle needs indices v1, v2 and v3");
        return;
    }
    if (a >= p->cur->n_v || b >= p->cur->n_v || c >= p->cur->n_v) {
        fail(p, SF_EINVAL, "triangle index out of range");
        return;
    }
    if (++p->n_tris_total > SF_MESH_TRIS_MAX) {
        fail(p, SF_EINVAL, "too many triangles");
        return;
    }
    void *t = p->cur->t;
    size_t cap = p->cur->cap_t;
    if (!mem_grow(&t, &cap, p->cur->n_t + 1, sizeof(*p->cur->t))) {
        fail(p, SF_ENOMEM, "out of memory");
        return;
    }
    p->cur->t = t;
    p->cur->cap_t = (uint32_t)cap;
    uint32_t *tri = p->cur->t[p->cur->n_t++];
    tri[0] = a;
    tri[1] = b;
    tri[2] = c;
}

/* <component> of the current object, or a build <item>: a placed object. */
static void
on_ref(struct tmf_parse *p, const char **atts, bool item)
{
    struct tmf_ref ref;
    if (!item && !p->cur) {
        fail(p, SF_EINVAL, "component outside an object");
        return;
    }
    if (!id_attr(atts, "objectid", &ref.object_id)) {
        fail(p, SF_EINVAL, "missing objectid");
        return;
    }
    if (!parse_xform(attr(atts, "transform"), &ref.xf)) {
        fail(p, SF_EINVAL, "transform needs 12 numbers");
        return;
    }
    struct tmf_ref **arr = item ? &p->items : &p->cur->comps;
    uint32_t *n = item ? &p->n_items : &p->cur->n_comps;
    uint32_t *capp = item ? &p->cap_items : &p->cur->cap_comps;
    if (*n >= TMF_ITEMS_MAX) {
        fail(p, SF_EINVAL, "too many items or components");
        return;
    }
    void *a = *arr;
    size_t cap = *capp;
    if (!mem_grow(&a, &cap, *n + 1, sizeof(struct tmf_ref))) {
        fail(p, SF_ENOMEM, "out of memory");
        return;
    }
    *arr = a;
    *capp = (uint32_t)cap;
    (*arr)[(*n)++] = ref;
}

static void XMLCALL
on_start(void *ud, const char *el, const char **atts)
{
    struct tmf_parse *p = ud;
    if (p->rc)
        return;
    if (is(el, "model"))
        on_model(p, atts);
    else if (is(el, "object"))
        on_object(p, atts);
    else if (is(el, "vertex"))
        on_vertex(p, atts);
    else if (is(el, "triangle"))
        on_triangle(p, atts);
    else if (is(el, "component") || is(el, "item"))
        on_ref(p, atts, is(el, "item"));
}

static void XMLCALL
on_end(void *ud, const char *el)
{
    struct tmf_parse *p = ud;
    if (is(el, "object"))
        p->cur = NULL;
}

static struct tmf_object *
find_object(struct tmf_parse *p, uint32_t id)
{
    for (uint32_t i = 0; i < p->n_objs; i++)
        if (p->objs[i].id == id)
            return &p->objs[i];
    return NULL;
}

/* Append object id (and its components) under transform xf to m. */
static int
flatten(struct tmf_parse *p, uint32_t id, const struct tmf_xform *xf, int depth, struct mesh *m,
        uint32_t *cap_v, uint32_t *cap_t)
{
    struct tmf_object *o = find_object(p, id);
    if (!o)
        return sf_err_set(p->err, SF_EINVAL, "3mf '%s': reference to missing object %u", p->name,
                          id);
    if (depth > TMF_DEPTH_MAX)
        return sf_err_set(p->err, SF_EINVAL,
                          "3mf '%s': components nested deeper than %d (a cycle?)", p->name,
                          TMF_DEPTH_MAX);
    if ((uint64_t)m->n_tris + o->n_t > SF_MESH_TRIS_MAX ||
        (uint64_t)m->n_verts + o->n_v > SF_MESH_VERTS_MAX)
        return sf_err_set(p->err, SF_EINVAL, "3mf '%s': the build is over %u triangles", p->name,
                          SF_MESH_TRIS_MAX);
    void *v = m->v, *t = m->t;
    size_t cv = *cap_v, ct = *cap_t;
    if (!mem_grow(&v, &cv, m->n_verts + o->n_v, sizeof(struct vec3)))
        return sf_err_set(p->err, SF_ENOMEM, "3mf '%s': out of memory", p->name);
    m->v = v;
    *cap_v = (uint32_t)cv;
    if (!mem_grow(&t, &ct, m->n_tris + o->n_t, sizeof(*m->t)))
        return sf_err_set(p->err, SF_ENOMEM, "3mf '%s': out of memory", p->name);
    m->t = t;
    *cap_t = (uint32_t)ct;
    uint32_t base = m->n_verts;
    for (uint32_t i = 0; i < o->n_v; i++) {
        struct vec3 q = v3_scale(xf_apply(xf, o->v[i]), p->unit_mm);
        if (!v3_isfinite(q) || fabs(q.x) > SF_MESH_COORD_MAX || fabs(q.y) > SF_MESH_COORD_MAX ||
            fabs(q.z) > SF_MESH_COORD_MAX)
            return sf_err_set(p->err, SF_EINVAL, "3mf '%s': object %u: vertex %u lies beyond %g mm",
                              p->name, id, i, SF_MESH_COORD_MAX);
        m->v[m->n_verts++] = q;
    }
    for (uint32_t i = 0; i < o->n_t; i++) {
        for (int k = 0; k < 3; k++)
            m->t[m->n_tris][k] = base + o->t[i][k];
        m->n_tris++;
    }
    for (uint32_t c = 0; c < o->n_comps; c++) {
        struct tmf_xform sub = xf_then(&o->comps[c].xf, xf);
        int rc = flatten(p, o->comps[c].object_id, &sub, depth + 1, m, cap_v, cap_t);
        if (rc)
            return rc;
    }
    return SF_OK;
}

/* Find the model part's name from _rels/.rels (StartPart relationship). */
static void XMLCALL
on_rel(void *ud, const char *el, const char **atts)
{
    char *target = ud;
    if (!is(el, "Relationship") || target[0])
        return;
    const char *type = attr(atts, "Type"), *t = attr(atts, "Target");
    if (type && t && strstr(type, "3dmodel")) {
        while (*t == '/')
            t++;
        snprintf(target, 512, "%s", t);
    }
}

/* The package in memory, as minizip's I/O callbacks see it. */
struct mem_zip {
    const unsigned char *data;
    size_t len, pos;
};

static voidpf ZCALLBACK
mz_open(voidpf opaque, const void *name, int mode)
{
    (void)opaque;
    return (mode & ZLIB_FILEFUNC_MODE_READ) ? (voidpf)name : NULL;
}

static uLong ZCALLBACK
mz_read(voidpf opaque, voidpf stream, void *out, uLong size)
{
    (void)opaque;
    struct mem_zip *z = stream;
    size_t n = z->len - z->pos < size ? z->len - z->pos : size;
    memcpy(out, z->data + z->pos, n);
    z->pos += n;
    return (uLong)n;
}

static uLong ZCALLBACK
mz_write(voidpf opaque, voidpf stream, const void *in, uLong size)
{
    (void)opaque, (void)stream, (void)in, (void)size;
    return 0; /* read-only */
}

static ZPOS64_T ZCALLBACK
mz_tell(voidpf opaque, voidpf stream)
{
    (void)opaque;
    return ((struct mem_zip *)stream)->pos;
}

static long ZCALLBACK
mz_seek(voidpf opaque, voidpf stream, ZPOS64_T off, int origin)
{
    (void)opaque;
    struct mem_zip *z = stream;
    ZPOS64_T base = origin == ZLIB_FILEFUNC_SEEK_SET   ? 0
                    : origin == ZLIB_FILEFUNC_SEEK_CUR ? z->pos
                                                       : z->len;
    if (off > z->len - base) /* no seeking past the end */
        return -1;
    z->pos = base + off;
    return 0;
}

static int ZCALLBACK
mz_close(voidpf opaque, voidpf stream)
{
    (void)opaque, (void)stream;
    return 0;
}

static int ZCALLBACK
mz_error(voidpf opaque, voidpf stream)
{
    (void)opaque, (void)stream;
    return 0;
}

static const char *
unz_strerror(int rc)
{
    switch (rc) {
    case UNZ_BADZIPFILE:
        return "bad zip structure";
    case UNZ_CRCERROR:
        return "CRC mismatch";
    case Z_DATA_ERROR:
        return "bad deflate data";
    case UNZ_ERRNO:
    case UNZ_EOF:
        return "truncated";
    default:
        return "unreadable";
    }
}

/*
 * Stream entry through XML parser xp, chunk by chunk: the unpacked text is
 * never held whole (a 1 MB zip bomb used to cost 2-3.6 GB, its buffer
 * doubling as it grew).  *budget is what the package may still unpack (its
 * entries share one, so many small bombs add up); past it the entry is
 * refused.  SF_OK, SF_EINVAL (bad zip, over budget), or what stopped the
 * parser (*xml_rc, set by the element handlers) when the caller's handlers
 * failed, or SF_EINVAL with the XML error when the text is malformed.
 */
static int
read_entry(unzFile z, const char *entry, XML_Parser xp, const int *xml_rc, size_t *budget,
           size_t pkg_len, size_t limit, const char *name, struct sf_err *err)
{
    unz_file_info64 st;
    if (unzLocateFile(z, entry, 1) != UNZ_OK ||
        unzGetCurrentFileInfo64(z, &st, NULL, 0, NULL, 0, NULL, 0) != UNZ_OK)
        return sf_err_set(err, SF_EINVAL, "3mf '%s': package has no '%s'", name, entry);
    if (st.uncompressed_size > *budget)
        return sf_err_set(err, SF_EINVAL,
                          "3mf '%s': '%s' unpacks to more than %zu bytes (a package of %zu "
                          "bytes may unpack to %zu in all)",
                          name, entry, *budget, pkg_len, limit);
    if (st.flag & 1)
        return sf_err_set(err, SF_EINVAL, "3mf '%s': '%s' is encrypted", name, entry);
    if (st.compression_method != 0 && st.compression_method != Z_DEFLATED)
        return sf_err_set(err, SF_EINVAL,
                          "3mf '%s': '%s' uses compression method %lu (3MF allows stored and "
                          "deflated parts only)",
                          name, entry, st.compression_method);
    int n = unzOpenCurrentFile(z);
    if (n != UNZ_OK)
        return sf_err_set(err, SF_EINVAL, "3mf '%s': cannot open '%s': %s", name, entry,
                          unz_strerror(n));
    char chunk[65536];
    int rc = SF_OK;
    bool parsed_all = false;
    while ((n = unzReadCurrentFile(z, chunk, sizeof(chunk))) >= 0) {
        if ((size_t)n > *budget) {
            /* the header lied about the size: the actual bytes decide */
            rc = sf_err_set(err, SF_EINVAL,
                            "3mf '%s': '%s' unpacks to more than %zu bytes (a package of %zu "
                            "bytes may unpack to %zu in all)",
                            name, entry, *budget, pkg_len, limit);
            break;
        }
        *budget -= (size_t)n;
        if (XML_Parse(xp, chunk, n, n == 0) == XML_STATUS_ERROR) {
            if (xml_rc && *xml_rc)
                rc = *xml_rc;
            else
                rc = sf_err_set(err, SF_EINVAL, "3mf '%s': '%s' line %lu: %s", name, entry,
                                (unsigned long)XML_GetCurrentLineNumber(xp),
                                XML_ErrorString(XML_GetErrorCode(xp)));
            break;
        }
        if (n == 0) {
            parsed_all = true;
            break;
        }
    }
    /* the CRC is checked on closing an entry read to its end */
    int closed = unzCloseCurrentFile(z);
    if (rc == SF_OK && (n < 0 || closed != UNZ_OK || !parsed_all))
        rc = sf_err_set(err, SF_EINVAL, "3mf '%s': '%s' is corrupt: %s", name, entry,
                        unz_strerror(n < 0 ? n : closed));
    return rc;
}

int
tmf_parse(const void *data, size_t len, const char *name, struct mesh *m, struct sf_err *err)
{
    mesh_release(m);
    struct mem_zip mem = { .data = data, .len = len };
    zlib_filefunc64_def io = { .zopen64_file = mz_open,
                               .zread_file = mz_read,
                               .zwrite_file = mz_write,
                               .ztell64_file = mz_tell,
                               .zseek64_file = mz_seek,
                               .zclose_file = mz_close,
                               .zerror_file = mz_error };
    unzFile z = unzOpen2_64(&mem, &io);
    if (!z)
        return sf_err_set(err, SF_EINVAL,
                          "3mf '%s': not a valid zip package (no readable central directory)",
                          name);

    /* What the package may unpack to, all entries together: a multiple of
       its own size (limits.h), so the upload limit bounds it too. */
    size_t limit = SF_3MF_UNPACK_MIN;
    if (len <= SF_3MF_MODEL_MAX / SF_3MF_UNPACK_RATIO && len * SF_3MF_UNPACK_RATIO > limit)
        limit = len * SF_3MF_UNPACK_RATIO;
    else if (len > SF_3MF_MODEL_MAX / SF_3MF_UNPACK_RATIO)
        limit = SF_3MF_MODEL_MAX;
    size_t budget = limit;
    char model_path[512] = "";
    struct tmf_parse p = { .name = name, .err = err, .unit_mm = 1 };
    int rc = SF_OK;

    /* The relationships part says where the model is; fall back to the usual name. */
    XML_Parser rp = XML_ParserCreate(NULL);
    if (!rp) {
        rc = sf_err_set(err, SF_ENOMEM, "3mf '%s': out of memory", name);
        goto out;
    }
    XML_SetUserData(rp, model_path);
    XML_SetStartElementHandler(rp, on_rel);
    int rels = read_entry(z, "_rels/.rels", rp, NULL, &budget, len, limit, name, NULL);
    XML_ParserFree(rp);
    if (rels == SF_ENOMEM) {
        rc = sf_err_set(err, SF_ENOMEM, "3mf '%s': out of memory", name);
        goto out;
    }
    if (rels != SF_OK)
        model_path[0] = '\0'; /* unreadable relationships: the usual name */
    if (!model_path[0])
        snprintf(model_path, sizeof(model_path), "3D/3dmodel.model");
    p.xp = XML_ParserCreate(NULL);
    if (!p.xp) {
        rc = sf_err_set(err, SF_ENOMEM, "3mf '%s': out of memory", name);
        goto out;
    }
    XML_SetUserData(p.xp, &p);
    XML_SetElementHandler(p.xp, on_start, on_end);
    if ((rc = read_entry(z, model_path, p.xp, &p.rc, &budget, len, limit, name, err)))
        goto out;
    if ((rc = p.rc))
        goto out;

    uint32_t cap_v = 0, cap_t = 0;
    if (p.n_items == 0 && p.n_objs > 0) {
        /* no build section: print every object once, untransformed */
        struct tmf_xform id;
        xf_identity(&id);
        for (uint32_t i = 0; i < p.n_objs && rc == SF_OK; i++)
            rc = flatten(&p, p.objs[i].id, &id, 0, m, &cap_v, &cap_t);
    }
    for (uint32_t i = 0; i < p.n_items && rc == SF_OK; i++)
        rc = flatten(&p, p.items[i].object_id, &p.items[i].xf, 0, m, &cap_v, &cap_t);
    if (rc)
        mesh_release(m);
out:
    if (p.xp)
        XML_ParserFree(p.xp);
    for (uint32_t i = 0; i < p.n_objs; i++) {
        free(p.objs[i].v);
        free(p.objs[i].t);
        free(p.objs[i].comps);
    }
    free(p.objs);
    free(p.items);
    unzClose(z);
    return rc;
}
