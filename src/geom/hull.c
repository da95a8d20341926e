/*
 * hull.c - stable resting bases from qhull's convex hull (see hull.h).
 *
 * For each merged facet we project its vertices and the centre of mass into
 * the facet's plane, order the vertices by angle (the facet is convex), and
 * take the smallest signed distance from the projected centre of mass to an
 * edge: positive means the part stands, and by how much margin.
 */
#include "hull.h"

#include <libqhull_r/qhull_ra.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"

struct angle_pt {
    double a, x, y;
};

static int
cmp_angle(const void *p, const void *q)
{
    double a = ((const struct angle_pt *)p)->a, b = ((const struct angle_pt *)q)->a;
    return (a > b) - (a < b);
}

static int
cmp_base(const void *p, const void *q)
{
    double a = ((const struct hull_base *)p)->area_mm2, b = ((const struct hull_base *)q)->area_mm2;
    return (a < b) - (a > b);
}

/* Signed distance of (px, py) inside the convex polygon pts (CCW): min over edges. */
static double
inside_margin(const struct angle_pt *pts, int n, double px, double py)
{
    double m = INFINITY;
    for (int i = 0; i < n; i++) {
        const struct angle_pt *a = &pts[i], *b = &pts[(i + 1) % n];
        double ex = b->x - a->x, ey = b->y - a->y, len = hypot(ex, ey);
        if (len < 1e-12)
            continue;
        double d = (ex * (py - a->y) - ey * (px - a->x)) / len;
        m = fmin(m, d);
    }
    return m;
}

/* The base that hull facet (normal nrm) gives: its vertices in the facet's
   plane (poly, room for all), in angle order; its area and com's margin. */
static void
facet_base(facetT *facet, struct vec3 nrm, struct vec3 com, struct angle_pt *poly,
           struct hull_base *b)
{
    /* plane basis */
    struct vec3 e1 = fabs(nrm.x) < 0.9 ? v3(1, 0, 0) : v3(0, 1, 0);
    e1 = v3_normalize(v3_sub(e1, v3_scale(nrm, v3_dot(e1, nrm))));
    struct vec3 e2 = v3_cross(nrm, e1);
    double cx = 0, cy = 0;
    vertexT *vertex, **vertexp;
    int k = 0;
    FOREACHvertex_(facet->vertices)
    {
        struct vec3 p = v3(vertex->point[0], vertex->point[1], vertex->point[2]);
        poly[k].x = v3_dot(p, e1);
        poly[k].y = v3_dot(p, e2);
        cx += poly[k].x;
        cy += poly[k].y;
        k++;
    }
    cx /= k;
    cy /= k;
    for (int i = 0; i < k; i++)
        poly[i].a = atan2(poly[i].y - cy, poly[i].x - cx);
    qsort(poly, (size_t)k, sizeof(*poly), cmp_angle);
    double area = 0;
    for (int i = 0; i < k; i++)
        area += poly[i].x * poly[(i + 1) % k].y - poly[(i + 1) % k].x * poly[i].y;
    b->normal = nrm;
    b->area_mm2 = 0.5 * fabs(area);
    b->margin_mm = inside_margin(poly, k, v3_dot(com, e1), v3_dot(com, e2));
}

int
hull_bases(const struct mesh *m, struct vec3 com, struct hull_base **out, uint32_t *n_out,
           uint32_t **verts, uint32_t *n_verts, struct sf_err *err)
{
    *out = NULL;
    *n_out = 0;
    if (verts) {
        *verts = NULL;
        *n_verts = 0;
    }
    if (m->n_verts < 4)
        return sf_err_set(err, SF_EINVAL, "convex hull needs 4 or more vertices");
    coordT *pts = mem_array((size_t)m->n_verts * 3, sizeof(coordT));
    if (!pts)
        return sf_err_set(err, SF_ENOMEM, "out of memory for the hull");
    for (uint32_t i = 0; i < m->n_verts; i++) {
        pts[3 * i] = m->v[i].x;
        pts[3 * i + 1] = m->v[i].y;
        pts[3 * i + 2] = m->v[i].z;
    }
    /* qhull reports into a FILE: keep its page-long report off the user's terminal and quote
       its first line in the error */
    char *qmsg = NULL;
    size_t qmsg_len = 0;
    FILE *qerr = open_memstream(&qmsg, &qmsg_len);
    if (!qerr) {
        free(pts);
        return sf_err_set(err, SF_ENOMEM, "out of memory for the hull");
    }
    qhT qh_qh;
    qhT *qh = &qh_qh;
    qh_zero(qh, qerr);
    char opts[] = "qhull Pp"; /* Pp: no precision warnings */
    int exitcode = qh_new_qhull(qh, 3, (int)m->n_verts, pts, False, opts, NULL, qerr);
    int rc = SF_OK;
    struct hull_base *bases = NULL;
    struct angle_pt *poly = NULL;
    uint32_t n = 0, cap = 0;
    if (exitcode) {
        fflush(qerr);
        size_t first = qmsg ? strcspn(qmsg, "\n") : 0;
        rc = sf_err_set(err, SF_EINVAL, "convex hull failed: flat or degenerate part (%.*s)",
                        (int)(first < 160 ? first : 160), qmsg ? qmsg : "");
        goto out;
    }
    facetT *facet;
    FORALLfacets
    {
        struct vec3 nrm = v3(facet->normal[0], facet->normal[1], facet->normal[2]);
        int nv = qh_setsize(qh, facet->vertices);
        if (nv < 3)
            continue;
        void *pp = poly;
        size_t pcap = 0;
        if (!mem_grow(&pp, &pcap, (size_t)nv, sizeof(*poly))) {
            rc = sf_err_set(err, SF_ENOMEM, "out of memory for the hull");
            goto out;
        }
        poly = pp;
        void *bp = bases;
        size_t bcap = cap;
        if (!mem_grow(&bp, &bcap, n + 1, sizeof(*bases))) {
            rc = sf_err_set(err, SF_ENOMEM, "out of memory for the hull");
            goto out;
        }
        bases = bp;
        cap = (uint32_t)bcap;
        facet_base(facet, nrm, com, poly, &bases[n]);
        n++;
        free(poly);
        poly = NULL;
    }
    qsort(bases, n, sizeof(*bases), cmp_base);
    if (verts) {
        uint32_t *ids = mem_array((size_t)qh->num_vertices + 1, sizeof(uint32_t));
        if (!ids) {
            rc = sf_err_set(err, SF_ENOMEM, "out of memory for the hull");
            goto out;
        }
        uint32_t k = 0;
        vertexT *vertex;
        FORALLvertices ids[k++] = (uint32_t)qh_pointid(qh, vertex->point);
        *verts = ids;
        *n_verts = k;
    }
out:
    free(poly);
    qh_freeqhull(qh, !qh_ALL);
    int curlong, totlong;
    qh_memfreeshort(qh, &curlong, &totlong);
    fclose(qerr);
    free(qmsg);
    free(pts);
    if (rc) {
        free(bases);
        return rc;
    }
    *out = bases;
    *n_out = n;
    return SF_OK;
}
