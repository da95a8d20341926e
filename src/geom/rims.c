/*
 * rims.c - open rims and the layers an outside slicer drops (see rims.h).
 */
#include "rims.h"

#include <math.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"

void
rims_release(struct rims *r)
{
    free(r->edge);
    free(r->edge_comp);
    free(r->tri_comp);
    memset(r, 0, sizeof(*r));
}

/* A half-edge without a partner triangle: its undirected key and component. */
struct loose {
    uint32_t lo, hi, comp;
};

static int
loose_cmp(const void *a, const void *b)
{
    const struct loose *x = a, *y = b;
    if (x->lo != y->lo)
        return x->lo < y->lo ? -1 : 1;
    return (x->hi > y->hi) - (x->hi < y->hi);
}

int
rims_build(const struct mesh *m, struct rims *r, struct sf_err *err)
{
    memset(r, 0, sizeof(*r));
    struct mesh_topo topo;
    int rc = mesh_topo_build(m, &topo, err);
    if (rc)
        return rc;
    r->tri_comp = topo.comp;
    r->n_comps = topo.n_comps;
    topo.comp = NULL;
    /* adj has no partner on boundary and non-manifold edges alike: a boundary
       edge is the one whose undirected key occurs once among those */
    size_t n = 0;
    for (uint32_t i = 0; i < m->n_tris; i++)
        for (int k = 0; k < 3; k++)
            n += topo.adj[i][k] == MESH_NO_TRI;
    struct loose *lz = n ? mem_array(n, sizeof(*lz)) : NULL;
    if (n && !lz) {
        mesh_topo_release(&topo);
        rims_release(r);
        return sf_err_set(err, SF_ENOMEM, "open rims: out of memory");
    }
    n = 0;
    for (uint32_t i = 0; i < m->n_tris; i++)
        for (int k = 0; k < 3; k++)
            if (topo.adj[i][k] == MESH_NO_TRI) {
                uint32_t a = m->t[i][k], b = m->t[i][(k + 1) % 3];
                lz[n++] = (struct loose){ a < b ? a : b, a < b ? b : a, r->tri_comp[i] };
            }
    mesh_topo_release(&topo);
    if (n)
        qsort(lz, n, sizeof(*lz), loose_cmp);
    size_t n_rim = 0;
    for (size_t s = 0, e; s < n; s = e) {
        for (e = s + 1; e < n && lz[e].lo == lz[s].lo && lz[e].hi == lz[s].hi;)
            e++;
        if (e - s == 1 && lz[s].lo != lz[s].hi)
            lz[n_rim++] = lz[s];
    }
    if (n_rim) {
        r->edge = mem_array(n_rim, sizeof(*r->edge));
        r->edge_comp = mem_array(n_rim, sizeof(uint32_t));
        if (!r->edge || !r->edge_comp) {
            free(lz);
            rims_release(r);
            return sf_err_set(err, SF_ENOMEM, "open rims: out of memory");
        }
        for (size_t k = 0; k < n_rim; k++) {
            r->edge[k][0] = lz[k].lo;
            r->edge[k][1] = lz[k].hi;
            r->edge_comp[k] = lz[k].comp;
        }
    }
    r->n_edges = (uint32_t)n_rim;
    free(lz);
    return SF_OK;
}

/* Where a layer plane cuts a rim edge: the plane coordinates of the point. */
struct crossing {
    int32_t k;
    uint32_t comp;
    double x, y;
};

static int
crossing_cmp(const void *a, const void *b)
{
    const struct crossing *p = a, *q = b;
    if (p->k != q->k)
        return p->k < q->k ? -1 : 1;
    return (p->x > q->x) - (p->x < q->x);
}

static int
open_layer_cmp(const void *a, const void *b)
{
    const struct open_layer *p = a, *q = b;
    if (p->comp != q->comp)
        return p->comp < q->comp ? -1 : 1;
    return (p->k > q->k) - (p->k < q->k);
}

/* Does crossing i of the layer [s, e) (sorted by x) have another within gap? */
static bool
has_partner(const struct crossing *c, size_t s, size_t e, size_t i, double gap)
{
    for (size_t j = i + 1; j < e && c[j].x - c[i].x <= gap; j++)
        if (hypot(c[j].x - c[i].x, c[j].y - c[i].y) <= gap)
            return true;
    for (size_t j = i; j-- > s && c[i].x - c[j].x <= gap;)
        if (hypot(c[j].x - c[i].x, c[j].y - c[i].y) <= gap)
            return true;
    return false;
}

int
rims_open_layers(const struct rims *r, const struct mesh *m, struct vec3 up, double base,
                 double layer_mm, double max_gap_mm, struct open_layer **out, size_t *n_out,
                 struct sf_err *err)
{
    *out = NULL;
    *n_out = 0;
    if (!(layer_mm > 0) || !(max_gap_mm >= 0))
        return sf_err_set(err, SF_EINVAL, "open rims: layer %g mm, gap %g mm", layer_mm,
                          max_gap_mm);
    if (!r->n_edges)
        return SF_OK;
    up = v3_normalize(up);
    struct vec3 ax = fabs(up.x) < 0.9 ? v3(1, 0, 0) : v3(0, 1, 0);
    ax = v3_normalize(v3_sub(ax, v3_scale(up, v3_dot(ax, up))));
    struct vec3 ay = v3_cross(up, ax);
    size_t n = 0, cap = 0;
    struct crossing *c = NULL;
    for (uint32_t e = 0; e < r->n_edges; e++) {
        struct vec3 a = m->v[r->edge[e][0]], b = m->v[r->edge[e][1]];
        double ha = v3_dot(a, up) - base, hb = v3_dot(b, up) - base;
        if (ha > hb) {
            struct vec3 t = a;
            a = b;
            b = t;
            double th = ha;
            ha = hb;
            hb = th;
        }
        /* the planes strictly between the ends: ha < (k + 0.5) h < hb */
        int32_t k0 = (int32_t)floor(ha / layer_mm - 0.5) + 1;
        int32_t k1 = (int32_t)ceil(hb / layer_mm - 0.5) - 1;
        if (k0 < 0)
            k0 = 0;
        for (int32_t k = k0; k <= k1; k++) {
            double t = ((k + 0.5) * layer_mm - ha) / (hb - ha);
            struct vec3 p = v3_add(a, v3_scale(v3_sub(b, a), t));
            void *o = c;
            if (!mem_grow(&o, &cap, n + 1, sizeof(*c))) {
                free(c);
                return sf_err_set(err, SF_ENOMEM, "open rims: out of memory");
            }
            c = o;
            c[n++] = (struct crossing){ k, r->edge_comp[e], v3_dot(p, ax), v3_dot(p, ay) };
        }
    }
    if (!n)
        return SF_OK;
    qsort(c, n, sizeof(*c), crossing_cmp);
    /* the unpaired crossings' layers */
    struct open_layer *ol = mem_array(n, sizeof(*ol));
    if (!ol) {
        free(c);
        return sf_err_set(err, SF_ENOMEM, "open rims: out of memory");
    }
    size_t n_ol = 0;
    for (size_t s = 0, e; s < n; s = e) {
        for (e = s + 1; e < n && c[e].k == c[s].k;)
            e++;
        for (size_t i = s; i < e; i++)
            if (!has_partner(c, s, e, i, max_gap_mm))
                ol[n_ol++] = (struct open_layer){ c[i].comp, c[i].k };
    }
    free(c);
    qsort(ol, n_ol, sizeof(*ol), open_layer_cmp);
    size_t u = 0;
    for (size_t i = 0; i < n_ol; i++)
        if (u == 0 || ol[u - 1].comp != ol[i].comp || ol[u - 1].k != ol[i].k)
            ol[u++] = ol[i];
    if (!u) {
        free(ol);
        return SF_OK;
    }
    *out = ol;
    *n_out = u;
    return SF_OK;
}
