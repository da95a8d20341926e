/*
 * vec.h - 3-vectors and 3x3 matrices in double precision, inline.
 *
 * Plain structs passed by value: the compiler keeps them in registers, and
 * geometry code reads like the formulas it implements.
 */
#ifndef SF_MESH_VEC_H
#define SF_MESH_VEC_H

#include <math.h>

struct vec3 {
    double x, y, z;
};

/* Row-major 3x3 matrix: m[row][col]. */
struct mat3 {
    double m[3][3];
};

static inline struct vec3
v3(double x, double y, double z)
{
    struct vec3 r = { x, y, z };
    return r;
}

static inline struct vec3
v3_add(struct vec3 a, struct vec3 b)
{
    return v3(a.x + b.x, a.y + b.y, a.z + b.z);
}

static inline struct vec3
v3_sub(struct vec3 a, struct vec3 b)
{
    return v3(a.x - b.x, a.y - b.y, a.z - b.z);
}

static inline struct vec3
v3_scale(struct vec3 a, double s)
{
    return v3(a.x * s, a.y * s, a.z * s);
}

static inline double
v3_dot(struct vec3 a, struct vec3 b)
{
    return a.x * b.x + a.y * b.y + a.z * b.z;
}

static inline struct vec3
v3_cross(struct vec3 a, struct vec3 b)
{
    return v3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}

static inline double
v3_len(struct vec3 a)
{
    return sqrt(v3_dot(a, a));
}

/* a / |a|, or (0,0,0) when |a| is 0. */
static inline struct vec3
v3_normalize(struct vec3 a)
{
    double l = v3_len(a);
    return l > 0 ? v3_scale(a, 1.0 / l) : v3(0, 0, 0);
}

/* fmin / fmax to the bit (a NaN loses; of two equal values, zeros of either
   sign included, the first wins, as glibc's), inline: at -O2 gcc calls the
   library for them, and bounding boxes call them per vertex. */
static inline double
min_d(double a, double b)
{
    return b < a || a != a ? b : a;
}

static inline double
max_d(double a, double b)
{
    return b > a || a != a ? b : a;
}

static inline struct vec3
v3_min(struct vec3 a, struct vec3 b)
{
    return v3(min_d(a.x, b.x), min_d(a.y, b.y), min_d(a.z, b.z));
}

static inline struct vec3
v3_max(struct vec3 a, struct vec3 b)
{
    return v3(max_d(a.x, b.x), max_d(a.y, b.y), max_d(a.z, b.z));
}

static inline int
v3_isfinite(struct vec3 a)
{
    return isfinite(a.x) && isfinite(a.y) && isfinite(a.z);
}

static inline struct mat3
m3_identity(void)
{
    struct mat3 r = { { { 1, 0, 0 }, { 0, 1, 0 }, { 0, 0, 1 } } };
    return r;
}

static inline struct vec3
m3_mul_v(struct mat3 a, struct vec3 v)
{
    return v3(a.m[0][0] * v.x + a.m[0][1] * v.y + a.m[0][2] * v.z,
              a.m[1][0] * v.x + a.m[1][1] * v.y + a.m[1][2] * v.z,
              a.m[2][0] * v.x + a.m[2][1] * v.y + a.m[2][2] * v.z);
}

static inline struct mat3
m3_mul(struct mat3 a, struct mat3 b)
{
    struct mat3 r;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            r.m[i][j] = a.m[i][0] * b.m[0][j] + a.m[i][1] * b.m[1][j] + a.m[i][2] * b.m[2][j];
    return r;
}

static inline struct mat3
m3_transpose(struct mat3 a)
{
    struct mat3 r;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            r.m[i][j] = a.m[j][i];
    return r;
}

static inline double
m3_det(struct mat3 a)
{
    return a.m[0][0] * (a.m[1][1] * a.m[2][2] - a.m[1][2] * a.m[2][1]) -
           a.m[0][1] * (a.m[1][0] * a.m[2][2] - a.m[1][2] * a.m[2][0]) +
           a.m[0][2] * (a.m[1][0] * a.m[2][1] - a.m[1][1] * a.m[2][0]);
}

/* Rotation by angle_rad about the unit axis (Rodrigues). */
static inline struct mat3
m3_axis_angle(struct vec3 axis, double angle_rad)
{
    double c = cos(angle_rad), s = sin(angle_rad), t = 1 - c;
    double x = axis.x, y = axis.y, z = axis.z;
    struct mat3 r = { { { t * x * x + c, t * x * y - s * z, t * x * z + s * y },
                        { t * x * y + s * z, t * y * y + c, t * y * z - s * x },
                        { t * x * z - s * y, t * y * z + s * x, t * z * z + c } } };
    return r;
}

/*
 * The rotation taking unit vector `from` onto unit vector `to` by the
 * shortest arc; for opposite vectors, a half turn about an axis
 * perpendicular to `from`.
 */
static inline struct mat3
m3_rotate_onto(struct vec3 from, struct vec3 to)
{
    struct vec3 axis = v3_cross(from, to);
    double s = v3_len(axis), c = v3_dot(from, to);
    if (s < 1e-12) {
        if (c > 0)
            return m3_identity();
        struct vec3 p = fabs(from.x) < 0.9 ? v3(1, 0, 0) : v3(0, 1, 0);
        return m3_axis_angle(v3_normalize(v3_cross(from, p)), M_PI);
    }
    return m3_axis_angle(v3_scale(axis, 1.0 / s), atan2(s, c));
}

/* Closest point to p on triangle abc (Ericson 5.1.5). */
static inline struct vec3
v3_closest_on_tri(struct vec3 p, struct vec3 a, struct vec3 b, struct vec3 c)
{
    struct vec3 ab = v3_sub(b, a), ac = v3_sub(c, a), ap = v3_sub(p, a);
    double d1 = v3_dot(ab, ap), d2 = v3_dot(ac, ap);
    if (d1 <= 0 && d2 <= 0)
        return a;
    struct vec3 bp = v3_sub(p, b);
    double d3 = v3_dot(ab, bp), d4 = v3_dot(ac, bp);
    if (d3 >= 0 && d4 <= d3)
        return b;
    double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0)
        return v3_add(a, v3_scale(ab, d1 / (d1 - d3)));
    struct vec3 cp = v3_sub(p, c);
    double d5 = v3_dot(ab, cp), d6 = v3_dot(ac, cp);
    if (d6 >= 0 && d5 <= d6)
        return c;
    double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0)
        return v3_add(a, v3_scale(ac, d2 / (d2 - d6)));
    double va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
        return v3_add(b, v3_scale(v3_sub(c, b), (d4 - d3) / ((d4 - d3) + (d5 - d6))));
    double den = 1 / (va + vb + vc);
    return v3_add(a, v3_add(v3_scale(ab, vb * den), v3_scale(ac, vc * den)));
}

#endif
