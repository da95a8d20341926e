/*
 * shapes.c - generated test parts (see shapes.h).
 *
 * Two builders cover every shape: extrusion of a planar polygon (caps by
 * ear clipping, fine for the few dozen vertices used here) and revolution
 * of a profile about z.  Each result goes through mesh_orient so normals
 * point outward whatever winding the generator produced.
 */
#include "shapes.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"

static int
finish(struct mesh *m, struct sf_err *err)
{
    int rc = mesh_orient(m, err);
    if (rc < 0)
        return rc;
    struct vec3 lo, hi;
    mesh_bbox(m, &lo, &hi);
    mesh_translate(m, v3(0, 0, -lo.z));
    return SF_OK;
}

int
shape_box(struct mesh *m, struct vec3 lo, struct vec3 hi, struct sf_err *err)
{
    double x[4] = { lo.x, hi.x, hi.x, lo.x }, z[4] = { lo.z, lo.z, hi.z, hi.z };
    int rc = shape_extrude_xz(m, x, z, 4, hi.y - lo.y, err);
    if (rc)
        return rc;
    /* extrusion starts at y = 0 and finish() rests it on z = 0: put it back at lo */
    mesh_translate(m, v3(0, lo.y, lo.z));
    return SF_OK;
}

static double
cross2(double ax, double az, double bx, double bz, double cx, double cz)
{
    return (bx - ax) * (cz - az) - (bz - az) * (cx - ax);
}

/* Ear-clip polygon idx[0..n) (CCW in x-z) into tris; returns triangles written. */
static int
ear_clip(const double *x, const double *z, int n, uint32_t (*tris)[3], uint32_t base)
{
    int *idx = mem_array((size_t)n, sizeof(int));
    if (!idx)
        return -1;
    for (int i = 0; i < n; i++)
        idx[i] = i;
    int count = n, out = 0, guard = 0;
    while (count > 3 && guard++ < 10 * n * n) {
        bool clipped = false;
        for (int i = 0; i < count && !clipped; i++) {
            int a = idx[(i + count - 1) % count], b = idx[i], c = idx[(i + 1) % count];
            if (cross2(x[a], z[a], x[b], z[b], x[c], z[c]) <= 0)
                continue; /* reflex corner */
            bool inside = false;
            for (int k = 0; k < count && !inside; k++) {
                int p = idx[k];
                if (p == a || p == b || p == c)
                    continue;
                inside = cross2(x[a], z[a], x[b], z[b], x[p], z[p]) >= 0 &&
                         cross2(x[b], z[b], x[c], z[c], x[p], z[p]) >= 0 &&
                         cross2(x[c], z[c], x[a], z[a], x[p], z[p]) >= 0;
            }
            if (inside)
                continue;
            tris[out][0] = base + (uint32_t)a;
            tris[out][1] = base + (uint32_t)b;
            tris[out][2] = base + (uint32_t)c;
            out++;
            for (int k = i; k < count - 1; k++)
                idx[k] = idx[k + 1];
            count--;
            clipped = true;
        }
        if (!clipped)
            break;
    }
    if (count == 3) {
        tris[out][0] = base + (uint32_t)idx[0];
        tris[out][1] = base + (uint32_t)idx[1];
        tris[out][2] = base + (uint32_t)idx[2];
        out++;
    }
    free(idx);
    return out == n - 2 ? out : -1;
}

int
shape_extrude_xz(struct mesh *m, const double *xin, const double *zin, int n, double depth,
                 struct sf_err *err)
{
    if (n < 3)
        return sf_err_set(err, SF_EINVAL, "extrusion needs 3 or more points");
    double *x = mem_array((size_t)n, sizeof(double)), *z = mem_array((size_t)n, sizeof(double));
    if (!x || !z) {
        free(x);
        free(z);
        return sf_err_set(err, SF_ENOMEM, "out of memory");
    }
    double area2 = 0;
    for (int i = 0; i < n; i++)
        area2 += xin[i] * zin[(i + 1) % n] - xin[(i + 1) % n] * zin[i];
    for (int i = 0; i < n; i++) { /* make it CCW */
        int s = area2 >= 0 ? i : n - 1 - i;
        x[i] = xin[s];
        z[i] = zin[s];
    }
    int rc = mesh_alloc(m, 2 * (uint32_t)n, 2 * (uint32_t)(n - 2) + 2 * (uint32_t)n, err);
    if (rc)
        goto out;
    for (int i = 0; i < n; i++) {
        m->v[i] = v3(x[i], 0, z[i]);
        m->v[n + i] = v3(x[i], depth, z[i]);
    }
    int k = ear_clip(x, z, n, m->t, 0);
    if (k < 0 || ear_clip(x, z, n, m->t + k, (uint32_t)n) < 0) {
        rc = sf_err_set(err, SF_EINVAL, "extrusion polygon is not simple");
        mesh_release(m);
        goto out;
    }
    uint32_t t = 2 * (uint32_t)k;
    for (int i = 0; i < n; i++) {
        uint32_t a = (uint32_t)i, b = (uint32_t)((i + 1) % n);
        m->t[t][0] = a;
        m->t[t][1] = b;
        m->t[t][2] = (uint32_t)n + b;
        t++;
        m->t[t][0] = a;
        m->t[t][1] = (uint32_t)n + b;
        m->t[t][2] = (uint32_t)n + a;
        t++;
    }
    rc = finish(m, err);
out:
    free(x);
    free(z);
    return rc;
}

int
shape_revolve(struct mesh *m, const double *r, const double *z, int n, int seg, struct sf_err *err)
{
    if (n < 3 || seg < 3 || r[0] != 0 || r[n - 1] != 0)
        return sf_err_set(err, SF_EINVAL, "profile must run from the axis to the axis");
    uint32_t rings = (uint32_t)n - 2;
    int rc = mesh_alloc(m, 2 + rings * (uint32_t)seg, 2 * (uint32_t)seg * (rings), err);
    if (rc)
        return rc;
    m->v[0] = v3(0, 0, z[0]);
    m->v[1] = v3(0, 0, z[n - 1]);
    for (uint32_t i = 0; i < rings; i++)
        for (int s = 0; s < seg; s++) {
            double a = 2 * M_PI * s / seg;
            m->v[2 + i * (uint32_t)seg + (uint32_t)s] =
                v3(r[i + 1] * cos(a), r[i + 1] * sin(a), z[i + 1]);
        }
    uint32_t t = 0;
    for (int s = 0; s < seg; s++) {
        uint32_t s1 = (uint32_t)((s + 1) % seg);
        m->t[t][0] = 0;
        m->t[t][1] = 2 + s1;
        m->t[t][2] = 2 + (uint32_t)s;
        t++;
        uint32_t top = 2 + (rings - 1) * (uint32_t)seg;
        m->t[t][0] = 1;
        m->t[t][1] = top + (uint32_t)s;
        m->t[t][2] = top + s1;
        t++;
        for (uint32_t i = 0; i + 1 < rings; i++) {
            uint32_t a = 2 + i * (uint32_t)seg + (uint32_t)s, b = 2 + i * (uint32_t)seg + s1;
            uint32_t c = a + (uint32_t)seg, d = b + (uint32_t)seg;
            m->t[t][0] = a;
            m->t[t][1] = b;
            m->t[t][2] = d;
            t++;
            m->t[t][0] = a;
            m->t[t][1] = d;
            m->t[t][2] = c;
            t++;
        }
    }
    m->n_tris = t;
    return finish(m, err);
}

int
shape_sphere(struct mesh *m, double radius, int stacks, struct sf_err *err)
{
    double *r = mem_array((size_t)stacks + 1, sizeof(double));
    double *z = mem_array((size_t)stacks + 1, sizeof(double));
    int rc;
    if (!r || !z) {
        rc = sf_err_set(err, SF_ENOMEM, "out of memory");
        goto out;
    }
    for (int i = 0; i <= stacks; i++) {
        double a = M_PI * i / stacks;
        r[i] = i == 0 || i == stacks ? 0 : radius * sin(a);
        z[i] = radius - radius * cos(a);
    }
    rc = shape_revolve(m, r, z, stacks + 1, 2 * stacks, err);
out:
    free(r);
    free(z);
    return rc;
}

int
shape_torus(struct mesh *m, double R, double r, int n_ring, int n_tube, struct sf_err *err)
{
    int rc = mesh_alloc(m, (uint32_t)(n_ring * n_tube), 2 * (uint32_t)(n_ring * n_tube), err);
    if (rc)
        return rc;
    for (int i = 0; i < n_ring; i++)
        for (int j = 0; j < n_tube; j++) {
            double u = 2 * M_PI * i / n_ring, w = 2 * M_PI * j / n_tube;
            m->v[i * n_tube + j] =
                v3((R + r * cos(w)) * cos(u), (R + r * cos(w)) * sin(u), r * sin(w));
        }
    uint32_t t = 0;
    for (int i = 0; i < n_ring; i++)
        for (int j = 0; j < n_tube; j++) {
            uint32_t a = (uint32_t)(i * n_tube + j);
            uint32_t b = (uint32_t)(((i + 1) % n_ring) * n_tube + j);
            uint32_t c = (uint32_t)(((i + 1) % n_ring) * n_tube + (j + 1) % n_tube);
            uint32_t d = (uint32_t)(i * n_tube + (j + 1) % n_tube);
            m->t[t][0] = a;
            m->t[t][1] = b;
            m->t[t][2] = c;
            t++;
            m->t[t][0] = a;
            m->t[t][1] = c;
            m->t[t][2] = d;
            t++;
        }
    return finish(m, err);
}

int
shape_tee(struct mesh *m, struct sf_err *err)
{
    double x[8] = { -5, 5, 5, 25, 25, -25, -25, -5 };
    double z[8] = { 0, 0, 30, 30, 35, 35, 30, 30 };
    return shape_extrude_xz(m, x, z, 8, 20, err);
}

int
shape_arch(struct mesh *m, struct sf_err *err)
{
    enum { N = 24 };
    double x[N + 5], z[N + 5];
    int n = 0;
    x[n] = -30, z[n++] = 0;
    x[n] = -20, z[n++] = 0;
    for (int i = 1; i < N; i++) { /* the opening, from (-20,0) over to (20,0) */
        double a = M_PI - M_PI * i / N;
        x[n] = 20 * cos(a);
        z[n++] = 20 * sin(a);
    }
    x[n] = 20, z[n++] = 0;
    x[n] = 30, z[n++] = 0;
    x[n] = 30, z[n++] = 30;
    x[n] = -30, z[n++] = 30;
    return shape_extrude_xz(m, x, z, n, 20, err);
}

int
shape_lbracket(struct mesh *m, struct sf_err *err)
{
    /* profile in x-z: plate 40 long (x) and 5 thick, wall 5 thick and 30 tall */
    double x[6] = { 0, 40, 40, 5, 5, 0 };
    double z[6] = { 0, 0, 5, 5, 30, 30 };
    return shape_extrude_xz(m, x, z, 6, 60, err);
}

int
shape_sphere_on_stem(struct mesh *m, struct sf_err *err)
{
    enum { N = 16 };
    double r[N + 4], z[N + 4];
    int n = 0;
    const double R = 10, rs = 3, h = 15;
    r[n] = 0, z[n++] = 0;
    r[n] = rs, z[n++] = 0;
    /* where the stem meets the sphere (centre at h + sqrt(R^2 - rs^2)) */
    double zc = h + sqrt(R * R - rs * rs);
    double a0 = asin(rs / R); /* angle from the bottom pole */
    for (int i = 0; i < N; i++) {
        double a = a0 + (M_PI - a0) * i / N;
        r[n] = R * sin(a);
        z[n++] = zc - R * cos(a);
    }
    r[n] = 0, z[n++] = zc + R;
    return shape_revolve(m, r, z, n, 32, err);
}

int
shape_frame(struct mesh *m, struct sf_err *err)
{
    const double o = 20, in = 10, hgt = 10;
    double ox[4] = { -o, o, o, -o }, oy[4] = { -o, -o, o, o };
    double ix[4] = { -in, in, in, -in }, iy[4] = { -in, -in, in, in };
    int rc = mesh_alloc(m, 16, 32, err);
    if (rc)
        return rc;
    for (int i = 0; i < 4; i++) {
        m->v[i] = v3(ox[i], oy[i], 0);
        m->v[4 + i] = v3(ix[i], iy[i], 0);
        m->v[8 + i] = v3(ox[i], oy[i], hgt);
        m->v[12 + i] = v3(ix[i], iy[i], hgt);
    }
    uint32_t t = 0;
    for (uint32_t i = 0; i < 4; i++) {
        uint32_t j = (i + 1) % 4;
        uint32_t quads[4][4] = {
            { i, j, 4 + j, 4 + i },           /* bottom ring */
            { 8 + i, 12 + i, 12 + j, 8 + j }, /* top ring */
            { i, 8 + i, 8 + j, j },           /* outer wall */
            { 4 + i, 4 + j, 12 + j, 12 + i }, /* inner wall */
        };
        for (int q = 0; q < 4; q++) {
            m->t[t][0] = quads[q][0];
            m->t[t][1] = quads[q][1];
            m->t[t][2] = quads[q][2];
            t++;
            m->t[t][0] = quads[q][0];
            m->t[t][1] = quads[q][2];
            m->t[t][2] = quads[q][3];
            t++;
        }
    }
    return finish(m, err);
}

int
shape_tray(struct mesh *m, double x, double y, double h, double wall_mm, double floor_mm,
           bool lip_down, struct sf_err *err)
{
    double ox[4] = { 0, x, x, 0 }, oy[4] = { 0, 0, y, y };
    double ix[4] = { wall_mm, x - wall_mm, x - wall_mm, wall_mm };
    double iy[4] = { wall_mm, wall_mm, y - wall_mm, y - wall_mm };
    int rc = mesh_alloc(m, 16, 28, err);
    if (rc)
        return rc;
    for (int i = 0; i < 4; i++) { /* outer bottom, outer top, rim inside, pocket floor */
        m->v[i] = v3(ox[i], oy[i], 0);
        m->v[4 + i] = v3(ox[i], oy[i], h);
        m->v[8 + i] = v3(ix[i], iy[i], h);
        m->v[12 + i] = v3(ix[i], iy[i], floor_mm);
    }
    uint32_t quads[14][4] = { { 0, 3, 2, 1 }, { 12, 13, 14, 15 } }; /* bottom, pocket floor */
    for (uint32_t i = 0; i < 4; i++) {
        uint32_t j = (i + 1) % 4;
        /* ring r to ring r + 1: outer wall, rim, pocket wall */
        for (uint32_t r = 0; r < 3; r++) {
            uint32_t *q = quads[2 + 3 * i + r];
            q[0] = 4 * r + i;
            q[1] = 4 * r + j;
            q[2] = 4 * r + 4 + j;
            q[3] = 4 * r + 4 + i;
        }
    }
    for (uint32_t q = 0; q < 14; q++) {
        uint32_t t[2][3] = { { quads[q][0], quads[q][1], quads[q][2] },
                             { quads[q][0], quads[q][2], quads[q][3] } };
        memcpy(m->t[2 * q], t, sizeof(t));
    }
    if (lip_down)
        for (uint32_t i = 0; i < 16; i++)
            m->v[i].z = h - m->v[i].z;
    return finish(m, err); /* mesh_orient turns the flipped faces back out */
}

int
shape_wedge(struct mesh *m, double lean_deg, struct sf_err *err)
{
    const double h = 20;
    double off = h * tan(lean_deg * M_PI / 180);
    double x[4] = { 0, 20, 20 + off, 0 }, z[4] = { 0, 0, h, h };
    return shape_extrude_xz(m, x, z, 4, 20, err);
}
