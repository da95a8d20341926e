/*
 * mesh.c - the indexed triangle mesh: storage, measures, transforms,
 * loading by content and saving.  Welding, topology and orientation repair
 * are in mesh_repair.c.
 *
 * Single-threaded per mesh.
 */
#include "mesh.h"

#include <fcntl.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include "../base/buf.h"
#include "../base/limits.h"
#include "../base/mem.h"
#include "mesh_int.h"

void
mesh_init(struct mesh *m)
{
    memset(m, 0, sizeof(*m));
}

void
mesh_release(struct mesh *m)
{
    free(m->v);
    free(m->t);
    mesh_init(m);
}

int
mesh_alloc(struct mesh *m, uint32_t n_verts, uint32_t n_tris, struct sf_err *err)
{
    mesh_release(m);
    if (n_verts > SF_MESH_VERTS_MAX || n_tris > SF_MESH_TRIS_MAX)
        return sf_err_set(err, SF_ENOMEM, "mesh of %u vertices and %u triangles is over the limit",
                          n_verts, n_tris);
    m->v = mem_array(n_verts ? n_verts : 1, sizeof(*m->v));
    m->t = mem_array(n_tris ? n_tris : 1, sizeof(*m->t));
    if (!m->v || !m->t) {
        mesh_release(m);
        return sf_err_set(err, SF_ENOMEM, "out of memory for %u triangles", n_tris);
    }
    m->n_verts = n_verts;
    m->n_tris = n_tris;
    return SF_OK;
}

int
mesh_copy(struct mesh *dst, const struct mesh *src, struct sf_err *err)
{
    int rc = mesh_alloc(dst, src->n_verts, src->n_tris, err);
    if (rc)
        return rc;
    memcpy(dst->v, src->v, sizeof(*src->v) * src->n_verts);
    memcpy(dst->t, src->t, sizeof(*src->t) * src->n_tris);
    return SF_OK;
}

void
mesh_bbox(const struct mesh *m, struct vec3 *lo, struct vec3 *hi)
{
    struct vec3 a = v3(0, 0, 0), b = v3(0, 0, 0);
    if (m->n_verts) {
        a = b = m->v[0];
        for (uint32_t i = 1; i < m->n_verts; i++) {
            a = v3_min(a, m->v[i]);
            b = v3_max(b, m->v[i]);
        }
    }
    if (lo)
        *lo = a;
    if (hi)
        *hi = b;
}

double
mesh_diag(const struct mesh *m)
{
    struct vec3 lo, hi;
    mesh_bbox(m, &lo, &hi);
    return v3_len(v3_sub(hi, lo));
}

struct vec3
mesh_tri_cross(const struct mesh *m, uint32_t i)
{
    struct vec3 a = m->v[m->t[i][0]], b = m->v[m->t[i][1]], c = m->v[m->t[i][2]];
    return v3_cross(v3_sub(b, a), v3_sub(c, a));
}

struct vec3
mesh_tri_normal(const struct mesh *m, uint32_t i)
{
    return v3_normalize(mesh_tri_cross(m, i));
}

double
mesh_tri_area(const struct mesh *m, uint32_t i)
{
    return 0.5 * v3_len(mesh_tri_cross(m, i));
}

struct vec3
mesh_tri_centroid(const struct mesh *m, uint32_t i)
{
    struct vec3 a = m->v[m->t[i][0]], b = m->v[m->t[i][1]], c = m->v[m->t[i][2]];
    return v3_scale(v3_add(v3_add(a, b), c), 1.0 / 3.0);
}

double
mesh_area(const struct mesh *m)
{
    double s = 0;
    for (uint32_t i = 0; i < m->n_tris; i++)
        s += mesh_tri_area(m, i);
    return s;
}

double
mesh_volume(const struct mesh *m, struct vec3 *centroid)
{
    /* Signed tetrahedra against a point inside the bbox (the bbox centre),
       which keeps the sums well conditioned far from the origin. */
    struct vec3 lo, hi;
    mesh_bbox(m, &lo, &hi);
    struct vec3 o = v3_scale(v3_add(lo, hi), 0.5);
    double vol = 0;
    struct vec3 c = v3(0, 0, 0);
    for (uint32_t i = 0; i < m->n_tris; i++) {
        struct vec3 a = v3_sub(m->v[m->t[i][0]], o);
        struct vec3 b = v3_sub(m->v[m->t[i][1]], o);
        struct vec3 d = v3_sub(m->v[m->t[i][2]], o);
        double v6 = v3_dot(a, v3_cross(b, d));
        vol += v6;
        c = v3_add(c, v3_scale(v3_add(v3_add(a, b), d), v6));
    }
    vol /= 6.0;
    if (centroid)
        *centroid = fabs(vol) > 0 ? v3_add(o, v3_scale(c, 1.0 / (24.0 * vol))) : o;
    return vol;
}

void
mesh_transform(struct mesh *m, struct mat3 r, struct vec3 t)
{
    for (uint32_t i = 0; i < m->n_verts; i++)
        m->v[i] = v3_add(m3_mul_v(r, m->v[i]), t);
}

void
mesh_translate(struct mesh *m, struct vec3 t)
{
    for (uint32_t i = 0; i < m->n_verts; i++)
        m->v[i] = v3_add(m->v[i], t);
}

void
mesh_rotate_up(struct mesh *m, struct vec3 up)
{
    mesh_transform(m, m3_rotate_onto(v3_normalize(up), v3(0, 0, 1)), v3(0, 0, 0));
}

void
mesh_place_on_bed(struct mesh *m, double cx, double cy)
{
    struct vec3 lo, hi;
    mesh_bbox(m, &lo, &hi);
    mesh_translate(m, v3(cx - 0.5 * (lo.x + hi.x), cy - 0.5 * (lo.y + hi.y), -lo.z));
}

/* ---- formats ------------------------------------------------------------ */

const char *
mesh_format_name(enum mesh_format f)
{
    switch (f) {
    case MESH_FMT_STL_BINARY:
        return "binary STL";
    case MESH_FMT_STL_ASCII:
        return "ASCII STL";
    case MESH_FMT_OBJ:
        return "OBJ";
    case MESH_FMT_3MF:
        return "3MF";
    case MESH_FMT_UNKNOWN:
        break;
    }
    return "unknown";
}

enum mesh_format
mesh_detect(const void *data, size_t len)
{
    const unsigned char *p = data;
    if (len >= 4 && p[0] == 'P' && p[1] == 'K' && p[2] == 3 && p[3] == 4)
        return MESH_FMT_3MF;
    if (len >= 84) {
        uint32_t n;
        memcpy(&n, p + 80, 4);
        if ((uint64_t)84 + (uint64_t)50 * n == len)
            return MESH_FMT_STL_BINARY;
    }
    size_t i = 0;
    while (i < len && (p[i] == ' ' || p[i] == '\t' || p[i] == '\r' || p[i] == '\n'))
        i++;
    if (len - i >= 5 && memcmp(p + i, "solid", 5) == 0)
        return MESH_FMT_STL_ASCII;
    /* OBJ: text whose first keyword lines are OBJ statements */
    size_t scan = len < 4096 ? len : 4096;
    bool text = true;
    for (size_t k = 0; k < scan; k++)
        if (p[k] == 0) {
            text = false;
            break;
        }
    if (text) {
        for (size_t k = i; k + 2 < scan; k++) {
            if ((k == 0 || p[k - 1] == '\n') &&
                ((p[k] == 'v' && (p[k + 1] == ' ' || p[k + 1] == '\t')) ||
                 (p[k] == 'f' && p[k + 1] == ' ') || (p[k] == 'o' && p[k + 1] == ' ') ||
                 (p[k] == 'g' && p[k + 1] == ' ') || (p[k] == '#') ||
                 (k + 6 < scan && memcmp(p + k, "mtllib", 6) == 0)))
                return MESH_FMT_OBJ;
        }
    }
    if (len >= 84)
        return MESH_FMT_STL_BINARY; /* let the STL parser explain what is wrong */
    return MESH_FMT_UNKNOWN;
}

int
mesh_load_mem(const void *data, size_t len, const char *name, struct mesh *m,
              struct mesh_load_info *info, struct sf_err *err)
{
    struct mesh_load_info local;
    if (!info)
        info = &local;
    memset(info, 0, sizeof(*info));
    mesh_release(m);
    if (len == 0)
        return sf_err_set(err, SF_EINVAL, "'%s': file is empty", name);
    info->format = mesh_detect(data, len);
    int rc;
    switch (info->format) {
    case MESH_FMT_STL_BINARY:
    case MESH_FMT_STL_ASCII:
        rc = stl_parse(data, len, name, m, err);
        break;
    case MESH_FMT_OBJ:
        rc = obj_parse(data, len, name, m, err);
        break;
    case MESH_FMT_3MF:
        rc = tmf_parse(data, len, name, m, err);
        break;
    default:
        return sf_err_set(err, SF_EINVAL, "'%s': not a mesh file (STL, OBJ or 3MF expected)", name);
    }
    if (rc)
        return rc;
    info->n_input_tris = m->n_tris;
    /* binary STL merges bit-identical corners while parsing: count those too */
    uint32_t parse_merged = 0;
    if (info->format == MESH_FMT_STL_BINARY || info->format == MESH_FMT_STL_ASCII)
        parse_merged = 3 * m->n_tris - m->n_verts;
    if (m->n_tris == 0) {
        mesh_release(m);
        return sf_err_set(err, SF_EINVAL, "'%s': no triangles", name);
    }
    double tol = 1e-6 * mesh_diag(m);
    rc = mesh_weld_distinct(m, tol, info->format == MESH_FMT_STL_BINARY, err);
    if (rc < 0)
        goto fail;
    info->n_merged = parse_merged + (uint32_t)rc;
    info->n_degenerate = mesh_drop_degenerate(m);
    /* Copies of one face (the same three vertices, either winding) are
       no surface: keep the first.  Each copy would also be another user of
       its edges, making every one of them non-manifold. */
    rc = mesh_drop_duplicates(m, err);
    if (rc < 0)
        goto fail;
    info->n_duplicate = (uint32_t)rc;
    mesh_compact(m);
    if (m->n_tris == 0) {
        mesh_release(m);
        return sf_err_set(err, SF_EINVAL, "'%s': every triangle is degenerate (zero area)", name);
    }
    rc = mesh_orient(m, err);
    if (rc < 0)
        goto fail;
    info->n_flipped = (uint32_t)rc;
    return SF_OK;
fail:
    mesh_release(m);
    return sf_err_prefix(err, "'%s'", name);
}

/*
 * Files are mapped rather than read: the parser walks the page cache
 * directly, with no copy and no first-touch faults on a fresh buffer (for a
 * 50 MB STL, read() into a new buffer cost more than parsing it).  Non-regular
 * files (pipes, /dev/stdin) fall back to a capped read.
 */
int
mesh_load(const char *path, struct mesh *m, struct mesh_load_info *info, struct sf_err *err)
{
    const char *slash = strrchr(path, '/');
    const char *name = slash ? slash + 1 : path;
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0)
        return sf_err_sys(err, "cannot open '%s'", path);
    struct stat st;
    if (fstat(fd, &st) != 0) {
        int rc = sf_err_sys(err, "cannot stat '%s'", path);
        close(fd);
        return rc;
    }
    if (S_ISDIR(st.st_mode)) {
        close(fd);
        return sf_err_set(err, SF_EINVAL, "'%s' is a directory", path);
    }
    if (S_ISREG(st.st_mode) && (uintmax_t)st.st_size > SF_MESH_FILE_MAX) {
        close(fd);
        return sf_err_set(err, SF_EINVAL, "'%s' is %jd bytes, over the limit of %zu", path,
                          (intmax_t)st.st_size, SF_MESH_FILE_MAX);
    }
    if (S_ISREG(st.st_mode) && st.st_size > 0) {
        void *map = mmap(NULL, (size_t)st.st_size, PROT_READ, MAP_PRIVATE | MAP_POPULATE, fd, 0);
        close(fd);
        if (map == MAP_FAILED)
            return sf_err_sys(err, "cannot map '%s'", path);
        int rc = mesh_load_mem(map, (size_t)st.st_size, name, m, info, err);
        munmap(map, (size_t)st.st_size);
        return rc;
    }
    close(fd);
    struct buf b;
    buf_init(&b, SF_MESH_FILE_MAX);
    int rc = buf_read_file(&b, path, err);
    if (rc == SF_OK)
        rc = mesh_load_mem(b.data, b.len, name, m, info, err);
    buf_release(&b);
    return rc;
}

static int
write_all(int fd, const void *data, size_t len)
{
    const char *p = data;
    while (len) {
        ssize_t n = write(fd, p, len);
        if (n < 0)
            return -1;
        p += n;
        len -= (size_t)n;
    }
    return 0;
}

/*
 * A part written to path.tmp in chunks, then renamed over path, so a reader
 * (or a crash of this process) never sees a half-written part.  Chunks keep
 * the memory small and already mapped: growing one buffer to the file's
 * size cost a page fault every 4 KB and a copy on every doubling (armadillo,
 * 2.6 MB: 750 of the run's 5,300 faults).  No fsync: these are the CLI's
 * outputs, which the operator reads next; the daemon keeps its files in the
 * store (src/farm/store.c), which fsyncs what it commits.
 */
enum { SAVE_CHUNK = 64 * 1024 };

struct save_file {
    const char *path;
    char tmp[4096];
    int fd;
    struct buf b; /* pending bytes, written out at SAVE_CHUNK */
};

static int
save_open(struct save_file *f, const char *path, struct sf_err *err)
{
    f->path = path;
    f->fd = -1;
    buf_init(&f->b, 0);
    if (snprintf(f->tmp, sizeof(f->tmp), "%s.tmp", path) >= (int)sizeof(f->tmp))
        return sf_err_set(err, SF_EINVAL, "path too long: '%s'", path);
    f->fd = open(f->tmp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (f->fd < 0)
        return sf_err_sys(err, "cannot create '%s'", f->tmp);
    return SF_OK;
}

/* Write the pending bytes once there are a chunk of them (all of them if force). */
static int
save_flush(struct save_file *f, bool force, struct sf_err *err)
{
    if (f->b.len < SAVE_CHUNK && !(force && f->b.len))
        return SF_OK;
    if (write_all(f->fd, f->b.data, f->b.len) != 0)
        return sf_err_sys(err, "cannot write '%s'", f->tmp);
    buf_reset(&f->b);
    return SF_OK;
}

/* Finish (rc == SF_OK: flush and rename into place) or abandon the file; returns rc. */
static int
save_close(struct save_file *f, int rc, struct sf_err *err)
{
    if (rc == SF_OK)
        rc = save_flush(f, true, err);
    if (f->fd >= 0 && close(f->fd) != 0 && rc == SF_OK)
        rc = sf_err_sys(err, "cannot write '%s'", f->tmp);
    if (rc == SF_OK && rename(f->tmp, f->path) != 0)
        rc = sf_err_sys(err, "cannot rename '%s' to '%s'", f->tmp, f->path);
    if (rc != SF_OK && f->fd >= 0)
        unlink(f->tmp);
    buf_release(&f->b);
    return rc;
}

static int
save_append(struct save_file *f, const void *data, size_t n, struct sf_err *err)
{
    if (buf_append(&f->b, data, n) != SF_OK)
        return sf_err_set(err, SF_ENOMEM, "out of memory writing '%s'", f->path);
    return save_flush(f, false, err);
}

int
mesh_save_stl(const struct mesh *m, const char *path, struct sf_err *err)
{
    struct save_file f;
    int rc = save_open(&f, path, err);
    char header[80] = "binary STL written by slimfarm";
    uint32_t n = m->n_tris;
    rc = rc ? rc : save_append(&f, header, sizeof(header), err);
    rc = rc ? rc : save_append(&f, &n, 4, err);
    for (uint32_t i = 0; i < m->n_tris && rc == SF_OK; i++) {
        struct vec3 nn = mesh_tri_normal(m, i);
        unsigned char rec[50];
        float f32[12] = { (float)nn.x, (float)nn.y, (float)nn.z };
        for (int k = 0; k < 3; k++) {
            struct vec3 p = m->v[m->t[i][k]];
            f32[3 + 3 * k] = (float)p.x;
            f32[4 + 3 * k] = (float)p.y;
            f32[5 + 3 * k] = (float)p.z;
        }
        memcpy(rec, f32, sizeof(f32));
        memset(rec + sizeof(f32), 0, 2); /* attribute byte count */
        rc = save_append(&f, rec, sizeof(rec), err);
    }
    return save_close(&f, rc, err);
}

int
mesh_save_obj(const struct mesh *m, const char *path, struct sf_err *err)
{
    struct save_file f;
    int rc = save_open(&f, path, err);
    if (rc == SF_OK && buf_printf(&f.b, "# written by slimfarm: %u vertices, %u triangles\n",
                                  m->n_verts, m->n_tris) != SF_OK)
        rc = sf_err_set(err, SF_ENOMEM, "out of memory writing '%s'", path);
    for (uint32_t i = 0; i < m->n_verts && rc == SF_OK; i++) {
        if (buf_printf(&f.b, "v %.9g %.9g %.9g\n", m->v[i].x, m->v[i].y, m->v[i].z) != SF_OK)
            rc = sf_err_set(err, SF_ENOMEM, "out of memory writing '%s'", path);
        rc = rc ? rc : save_flush(&f, false, err);
    }
    for (uint32_t i = 0; i < m->n_tris && rc == SF_OK; i++) {
        if (buf_printf(&f.b, "f %u %u %u\n", m->t[i][0] + 1, m->t[i][1] + 1, m->t[i][2] + 1) !=
            SF_OK)
            rc = sf_err_set(err, SF_ENOMEM, "out of memory writing '%s'", path);
        rc = rc ? rc : save_flush(&f, false, err);
    }
    return save_close(&f, rc, err);
}

int
mesh_save(const struct mesh *m, const char *path, struct sf_err *err)
{
    size_t n = strlen(path);
    if (n > 4 && strcasecmp(path + n - 4, ".obj") == 0)
        return mesh_save_obj(m, path, err);
    if (n > 4 && strcasecmp(path + n - 4, ".stl") == 0)
        return mesh_save_stl(m, path, err);
    return sf_err_set(err, SF_EINVAL, "'%s': output must end in .stl or .obj", path);
}
