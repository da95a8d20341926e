/*
 * mesh_repair.c - repair of an indexed triangle mesh (mesh.h): welding,
 * degenerate and duplicate triangles, compaction, topology and orientation.
 *
 * Welding hashes vertices into cells of the tolerance size and compares
 * against the own cell first (exact duplicates, the common STL case) and
 * then the 26 neighbours, so it is linear in the vertex count.  Topology is
 * built from a vertex -> outgoing half-edge table (CSR) instead of a sort of
 * all edges: each half-edge a->b finds its users by scanning the short
 * lists of a and b.  Orientation repair flood-fills each component across
 * manifold edges, then turns closed components with negative volume inside
 * out.
 *
 * Single-threaded per mesh.
 */
#include "mesh.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"
#include "mesh_int.h"

/* ---- welding ---------------------------------------------------------- */

static uint64_t
cell_hash(int64_t x, int64_t y, int64_t z)
{
    uint64_t h = (uint64_t)x * 0x9E3779B97F4A7C15ULL;
    h ^= (uint64_t)y * 0xC2B2AE3D27D4EB4FULL;
    h ^= (uint64_t)z * 0x165667B19E3779F9ULL;
    return h ^ (h >> 29);
}

/* A cell's index along an axis: clamped, as a part 1e19 cells wide (or a zero tolerance, all
   corners on one point) would overflow the conversion; such cells only make welding slower. */
static int64_t
cell_index(double f)
{
    const double lim = 4e18; /* below INT64_MAX with room for the neighbours' +-1 */
    if (!(f == f))
        return 0;
    return f > lim ? (int64_t)lim : f < -lim ? -(int64_t)lim : (int64_t)f;
}

struct weld_table {
    uint64_t mask;
    int64_t (*key)[3]; /* cell coordinates of each slot */
    uint32_t *head;    /* first representative vertex in the cell, UINT32_MAX if empty */
    uint32_t *next;    /* per representative: next in the same cell */
};

static uint32_t *
weld_slot(struct weld_table *w, int64_t x, int64_t y, int64_t z, bool insert)
{
    uint64_t s = cell_hash(x, y, z) & w->mask;
    for (;;) {
        if (w->head[s] == UINT32_MAX)
            return insert ? &w->head[s] : NULL;
        if (w->key[s][0] == x && w->key[s][1] == y && w->key[s][2] == z)
            return &w->head[s];
        s = (s + 1) & w->mask;
    }
}

static uint64_t
vertex_hash(struct vec3 p)
{
    uint64_t a, b, c;
    /* +0.0 so that -0.0 hashes like 0.0 (they compare equal) */
    double x = p.x + 0.0, y = p.y + 0.0, z = p.z + 0.0;
    memcpy(&a, &x, 8);
    memcpy(&b, &y, 8);
    memcpy(&c, &z, 8);
    uint64_t h = a * 0x9E3779B97F4A7C15ULL ^ b * 0xC2B2AE3D27D4EB4FULL ^ c * 0x165667B19E3779F9ULL;
    return h ^ (h >> 31);
}

/*
 * Merge bit-identical vertices: one hash probe each, no tolerance.  STL
 * soups repeat every vertex exactly (six times on average), so this pass
 * does most of the work and leaves the tolerance pass a sixth of the input.
 * Fills remap (old -> new) and compacts m->v in place.
 */
static int
weld_exact(struct mesh *m, uint32_t *remap)
{
    uint64_t size = 1;
    while (size < 2ull * m->n_verts)
        size <<= 1;
    uint32_t *slot = mem_array(size, sizeof(uint32_t));
    if (!slot)
        return SF_ENOMEM;
    memset(slot, 0xff, size * sizeof(uint32_t));
    uint32_t n_out = 0;
    for (uint32_t i = 0; i < m->n_verts; i++) {
        struct vec3 p = m->v[i];
        uint64_t s = vertex_hash(p) & (size - 1);
        for (;;) {
            uint32_t r = slot[s];
            if (r == UINT32_MAX) {
                slot[s] = n_out;
                m->v[n_out] = p; /* n_out <= i: never overwrites an unread vertex */
                remap[i] = n_out++;
                break;
            }
            struct vec3 q = m->v[r];
            if (q.x == p.x && q.y == p.y && q.z == p.z) {
                remap[i] = r;
                break;
            }
            s = (s + 1) & (size - 1);
        }
    }
    free(slot);
    m->n_verts = n_out;
    return SF_OK;
}

int
mesh_weld_distinct(struct mesh *m, double tol, bool distinct, struct sf_err *err)
{
    if (m->n_verts == 0)
        return 0;
    if (!(tol > 0))
        tol = 1e-9;
    uint32_t n_in = m->n_verts;
    uint32_t *exact = mem_array(n_in, sizeof(uint32_t));
    if (exact && distinct) {
        for (uint32_t i = 0; i < n_in; i++)
            exact[i] = i;
    } else if (!exact || weld_exact(m, exact) != SF_OK) {
        free(exact);
        return sf_err_set(err, SF_ENOMEM, "out of memory welding %u vertices", n_in);
    }
    uint64_t size = 1;
    while (size < 2ull * m->n_verts)
        size <<= 1;
    struct weld_table w = { size - 1, NULL, NULL, NULL };
    uint32_t *remap = mem_array(m->n_verts, sizeof(uint32_t));
    struct vec3 *out = mem_array(m->n_verts, sizeof(struct vec3));
    w.key = mem_array(size, sizeof(*w.key));
    w.head = mem_array(size, sizeof(uint32_t));
    w.next = mem_array(m->n_verts, sizeof(uint32_t));
    int rc = SF_OK;
    if (!remap || !out || !w.key || !w.head || !w.next) {
        rc = sf_err_set(err, SF_ENOMEM, "out of memory welding %u vertices", m->n_verts);
        goto out_free;
    }
    memset(w.head, 0xff, size * sizeof(uint32_t));
    /* Cells are 64 tolerances wide, so a point needs to look into a
       neighbouring cell only along axes where it lies within tol of the
       cell's wall: most points probe just their own cell. */
    double cell = 64 * tol, inv = 1.0 / cell, tol2 = tol * tol;
    uint32_t n_out = 0;
    for (uint32_t i = 0; i < m->n_verts; i++) {
        struct vec3 p = m->v[i];
        double fx = floor(p.x * inv), fy = floor(p.y * inv), fz = floor(p.z * inv);
        int64_t cx = cell_index(fx), cy = cell_index(fy), cz = cell_index(fz);
        double rx = p.x - fx * cell, ry = p.y - fy * cell, rz = p.z - fz * cell;
        int lx = rx < tol ? -1 : 0, hx = rx > cell - tol ? 1 : 0;
        int ly = ry < tol ? -1 : 0, hy = ry > cell - tol ? 1 : 0;
        int lz = rz < tol ? -1 : 0, hz = rz > cell - tol ? 1 : 0;
        uint32_t found = UINT32_MAX;
        for (int dz = lz; dz <= hz && found == UINT32_MAX; dz++)
            for (int dy = ly; dy <= hy && found == UINT32_MAX; dy++)
                for (int dx = lx; dx <= hx && found == UINT32_MAX; dx++) {
                    uint32_t *h = weld_slot(&w, cx + dx, cy + dy, cz + dz, false);
                    for (uint32_t r = h ? *h : UINT32_MAX; r != UINT32_MAX; r = w.next[r]) {
                        struct vec3 d = v3_sub(out[r], p);
                        if (v3_dot(d, d) <= tol2) {
                            found = r;
                            break;
                        }
                    }
                }
        if (found == UINT32_MAX) {
            uint32_t *h = weld_slot(&w, cx, cy, cz, true);
            uint64_t slot = (uint64_t)(h - w.head);
            w.key[slot][0] = cx;
            w.key[slot][1] = cy;
            w.key[slot][2] = cz;
            out[n_out] = p;
            w.next[n_out] = *h;
            *h = n_out;
            found = n_out++;
        }
        remap[i] = found;
    }
    for (uint32_t i = 0; i < m->n_tris; i++)
        for (int k = 0; k < 3; k++)
            m->t[i][k] = remap[exact[m->t[i][k]]];
    rc = (int)(n_in - n_out);
    free(m->v);
    m->v = mem_realloc_array(out, n_out ? n_out : 1, sizeof(struct vec3));
    if (!m->v)
        m->v = out; /* shrinking failed: keep the larger block */
    out = NULL;
    m->n_verts = n_out;
out_free:
    if (rc < 0) { /* undo nothing: the exact pass already renumbered; keep it consistent */
        for (uint32_t i = 0; i < m->n_tris; i++)
            for (int k = 0; k < 3; k++)
                m->t[i][k] = exact[m->t[i][k]];
    }
    free(exact);
    free(out);
    free(remap);
    free(w.key);
    free(w.head);
    free(w.next);
    return rc;
}

int
mesh_weld(struct mesh *m, double tol, struct sf_err *err)
{
    return mesh_weld_distinct(m, tol, false, err);
}

/* An edge of a triangle, its ends in order, for the sorted edge table of heal_slivers. */
struct tri_edge {
    uint32_t lo, hi, tri;
};

static int
tri_edge_cmp(const void *x, const void *y)
{
    const struct tri_edge *a = x, *b = y;
    if (a->lo != b->lo)
        return a->lo < b->lo ? -1 : 1;
    return a->hi < b->hi ? -1 : a->hi > b->hi;
}

static bool
is_sliver(const struct mesh *m, uint32_t i)
{
    uint32_t a = m->t[i][0], b = m->t[i][1], c = m->t[i][2];
    if (a == b || b == c || a == c)
        return false;
    struct vec3 n = v3_cross(v3_sub(m->v[b], m->v[a]), v3_sub(m->v[c], m->v[a]));
    return !(v3_dot(n, n) > 0);
}

/* Split triangle n, which has the edge p-q (either way), at vertex mid on that edge: n keeps
   its first half, slot gets the second, both in n's winding.  False if n lost the edge. */
static bool
split_at(struct mesh *m, uint32_t n, uint32_t p, uint32_t q, uint32_t mid, uint32_t slot)
{
    const uint32_t *t = m->t[n];
    for (int k = 0; k < 3; k++) {
        uint32_t x = t[k], y = t[(k + 1) % 3], z = t[(k + 2) % 3];
        if ((x == p && y == q) || (x == q && y == p)) {
            if (z == mid)
                return false;
            uint32_t first[3] = { x, mid, z }, second[3] = { mid, y, z };
            memcpy(m->t[n], first, sizeof(first));
            memcpy(m->t[slot], second, sizeof(second));
            return true;
        }
    }
    return false;
}

/*
 * A sliver (three distinct corners on a line, as CAD exporters leave where a
 * face meets a finer one) covers no area, but dropping it leaves a crack:
 * its long edge belongs to the triangle beyond, its two short edges to the
 * triangles on its side.  Splitting the triangle beyond at the sliver's
 * middle corner closes the crack; the sliver's slot takes the second half.
 * Best effort: without memory, or where two slivers share a long edge, the
 * sliver is dropped as before.
 */
static void
heal_slivers(struct mesh *m)
{
    uint32_t n_sliver = 0;
    for (uint32_t i = 0; i < m->n_tris; i++)
        n_sliver += is_sliver(m, i);
    if (n_sliver == 0)
        return;
    struct tri_edge *e = mem_array((size_t)m->n_tris * 3, sizeof(*e));
    if (!e)
        return;
    size_t n_e = 0;
    for (uint32_t i = 0; i < m->n_tris; i++) {
        const uint32_t *t = m->t[i];
        if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2] || is_sliver(m, i))
            continue;
        for (int k = 0; k < 3; k++) {
            uint32_t a = t[k], b = t[(k + 1) % 3];
            e[n_e++] = (struct tri_edge){ a < b ? a : b, a < b ? b : a, i };
        }
    }
    qsort(e, n_e, sizeof(*e), tri_edge_cmp);
    for (uint32_t i = 0; i < m->n_tris; i++) {
        if (!is_sliver(m, i))
            continue;
        /* the middle corner is the one opposite the longest edge */
        const uint32_t *t = m->t[i];
        int mid = 0;
        double longest = -1;
        for (int k = 0; k < 3; k++) {
            struct vec3 d = v3_sub(m->v[t[(k + 1) % 3]], m->v[t[(k + 2) % 3]]);
            if (v3_dot(d, d) > longest)
                longest = v3_dot(d, d), mid = k;
        }
        uint32_t c = t[mid], p = t[(mid + 1) % 3], q = t[(mid + 2) % 3];
        /* only a corner strictly inside the edge splits it (corners not welded onto one point
           are no middle) */
        if (v3_dot(v3_sub(m->v[c], m->v[p]), v3_sub(m->v[c], m->v[p])) == 0 ||
            v3_dot(v3_sub(m->v[c], m->v[q]), v3_sub(m->v[c], m->v[q])) == 0)
            continue;
        struct tri_edge key = { p < q ? p : q, p < q ? q : p, 0 };
        const struct tri_edge *hit = bsearch(&key, e, n_e, sizeof(*e), tri_edge_cmp);
        if (!hit)
            continue;
        /* bsearch lands on any of the edge's users: the first unsplit one */
        while (hit > e && tri_edge_cmp(hit - 1, &key) == 0)
            hit--;
        for (; hit < e + n_e && tri_edge_cmp(hit, &key) == 0; hit++)
            if (split_at(m, hit->tri, p, q, c, i))
                break;
    }
    free(e);
}

uint32_t
mesh_drop_degenerate(struct mesh *m)
{
    heal_slivers(m);
    uint32_t kept = 0;
    for (uint32_t i = 0; i < m->n_tris; i++) {
        uint32_t a = m->t[i][0], b = m->t[i][1], c = m->t[i][2];
        if (a == b || b == c || a == c)
            continue;
        struct vec3 n = v3_cross(v3_sub(m->v[b], m->v[a]), v3_sub(m->v[c], m->v[a]));
        if (!(v3_dot(n, n) > 0))
            continue;
        memcpy(m->t[kept++], m->t[i], sizeof(m->t[0]));
    }
    uint32_t dropped = m->n_tris - kept;
    m->n_tris = kept;
    return dropped;
}

/* Hash of a triangle's vertex set (sorted indices). */
static uint64_t
tri_key_hash(const uint32_t k[3])
{
    uint64_t h = ((uint64_t)k[0] * 0x9e3779b97f4a7c15ull) ^
                 ((uint64_t)k[1] * 0xc2b2ae3d27d4eb4full) ^
                 ((uint64_t)k[2] * 0x165667b19e3779f9ull);
    return h ^ (h >> 29);
}

static void
tri_key(const uint32_t t[3], uint32_t k[3])
{
    uint32_t a = t[0], b = t[1], c = t[2], x;
    if (a > b)
        x = a, a = b, b = x;
    if (b > c)
        x = b, b = c, c = x;
    if (a > b)
        x = a, a = b, b = x;
    k[0] = a, k[1] = b, k[2] = c;
}

int
mesh_drop_duplicates(struct mesh *m, struct sf_err *err)
{
    if (m->n_tris < 2)
        return 0;
    /* open addressing over triangle indices, load <= 1/2 */
    size_t cap = 2;
    while (cap < (size_t)m->n_tris * 2)
        cap *= 2;
    uint32_t *slot = mem_array(cap, sizeof(uint32_t));
    if (!slot)
        return sf_err_set(err, SF_ENOMEM, "out of memory checking %u triangles for duplicates",
                          m->n_tris);
    memset(slot, 0xff, cap * sizeof(uint32_t));
    uint32_t kept = 0;
    for (uint32_t i = 0; i < m->n_tris; i++) {
        uint32_t k[3], o[3];
        tri_key(m->t[i], k);
        size_t h = (size_t)tri_key_hash(k) & (cap - 1);
        bool dup = false;
        for (; slot[h] != UINT32_MAX; h = (h + 1) & (cap - 1)) {
            tri_key(m->t[slot[h]], o);
            if (o[0] == k[0] && o[1] == k[1] && o[2] == k[2]) {
                dup = true;
                break;
            }
        }
        if (dup)
            continue;
        memcpy(m->t[kept], m->t[i], sizeof(m->t[0]));
        slot[h] = kept++;
    }
    free(slot);
    int dropped = (int)(m->n_tris - kept);
    m->n_tris = kept;
    return dropped;
}

/* Are the vertices already numbered in order of first use, every one used?
   (Then mesh_compact has nothing to do: the STL loader numbers them so.) */
static bool
compact_already(const struct mesh *m)
{
    uint32_t next = 0; /* vertices met so far */
    for (uint32_t i = 0; i < m->n_tris; i++)
        for (int k = 0; k < 3; k++) {
            uint32_t v = m->t[i][k];
            if (v > next)
                return false;
            next += v == next;
        }
    return next == m->n_verts;
}

void
mesh_compact(struct mesh *m)
{
    if (compact_already(m))
        return;
    uint32_t *map = mem_array(m->n_verts ? m->n_verts : 1, sizeof(uint32_t));
    struct vec3 *v = mem_array(m->n_verts ? m->n_verts : 1, sizeof(struct vec3));
    if (!map || !v) {
        free(map);
        free(v);
        return; /* keeping unused vertices is harmless */
    }
    memset(map, 0xff, sizeof(uint32_t) * m->n_verts);
    uint32_t n = 0;
    for (uint32_t i = 0; i < m->n_tris; i++)
        for (int k = 0; k < 3; k++) {
            uint32_t old = m->t[i][k];
            if (map[old] == UINT32_MAX) {
                map[old] = n;
                v[n++] = m->v[old];
            }
            m->t[i][k] = map[old];
        }
    free(m->v);
    m->v = v;
    m->n_verts = n;
    free(map);
}

/* ---- topology ----------------------------------------------------------- */

/*
 * Half-edges grouped by undirected edge, in O(n_tris + n_verts) whatever
 * the input: two stable counting sorts (by the larger vertex, then by the
 * smaller) put every half-edge of one edge next to the others, in
 * increasing half-edge order.  Scanning each vertex's half-edges for the
 * edge's partners, as this used to, costs the square of how many faces
 * share a vertex: a cone of 10^5 segments, or 10^5 copies of one face (an
 * 800 KB OBJ), took minutes.
 */
static uint32_t *
edges_sorted(const struct mesh *m)
{
    size_t n_he = (size_t)m->n_tris * 3;
    uint32_t *cnt = mem_calloc((size_t)m->n_verts + 1, sizeof(uint32_t));
    uint32_t *tmp = mem_array(n_he + 1, sizeof(uint32_t));
    uint32_t *out = mem_array(n_he + 1, sizeof(uint32_t));
    if (!cnt || !tmp || !out) {
        free(cnt);
        free(tmp);
        free(out);
        return NULL;
    }
    for (int pass = 0; pass < 2; pass++) {
        /* pass 0: he in order into tmp by max(a, b); pass 1: tmp into out by min(a, b) */
        uint32_t *dst = pass == 0 ? tmp : out;
        memset(cnt, 0, sizeof(uint32_t) * ((size_t)m->n_verts + 1));
        for (size_t s = 0; s < n_he; s++) {
            uint32_t he = pass == 0 ? (uint32_t)s : tmp[s];
            uint32_t a = m->t[he / 3][he % 3], b = m->t[he / 3][(he % 3 + 1) % 3];
            cnt[(pass == 0 ? (a > b ? a : b) : (a < b ? a : b)) + 1]++;
        }
        for (uint32_t v = 0; v < m->n_verts; v++)
            cnt[v + 1] += cnt[v];
        for (size_t s = 0; s < n_he; s++) {
            uint32_t he = pass == 0 ? (uint32_t)s : tmp[s];
            uint32_t a = m->t[he / 3][he % 3], b = m->t[he / 3][(he % 3 + 1) % 3];
            dst[cnt[pass == 0 ? (a > b ? a : b) : (a < b ? a : b)]++] = he;
        }
    }
    free(cnt);
    free(tmp);
    return out;
}

int
mesh_topo_build(const struct mesh *m, struct mesh_topo *topo, struct sf_err *err)
{
    memset(topo, 0, sizeof(*topo));
    topo->adj = mem_array(m->n_tris ? m->n_tris : 1, sizeof(*topo->adj));
    topo->comp = mem_array(m->n_tris ? m->n_tris : 1, sizeof(uint32_t));
    uint32_t *queue = mem_array(m->n_tris ? m->n_tris : 1, sizeof(uint32_t));
    uint32_t *he = topo->adj && topo->comp && queue ? edges_sorted(m) : NULL;
    if (!he) {
        free(queue);
        mesh_topo_release(topo);
        return sf_err_set(err, SF_ENOMEM, "out of memory for the topology of %u triangles",
                          m->n_tris);
    }
    size_t n_he = (size_t)m->n_tris * 3;
    for (size_t s = 0; s < n_he;) {
        uint32_t h0 = he[s];
        uint32_t a = m->t[h0 / 3][h0 % 3], b = m->t[h0 / 3][(h0 % 3 + 1) % 3];
        uint32_t lo = a < b ? a : b, hi = a < b ? b : a;
        size_t e = s + 1;
        while (e < n_he) {
            uint32_t h = he[e];
            uint32_t x = m->t[h / 3][h % 3], y = m->t[h / 3][(h % 3 + 1) % 3];
            if ((x < y ? x : y) != lo || (x < y ? y : x) != hi)
                break;
            e++;
        }
        /* he[s..e) are every half-edge of edge {lo, hi}: each has e-s-1
           partners.  A loop (lo == hi, a repeated index) runs both ways at
           once: it is its own partner, and every other loop's twice. */
        size_t users = lo == hi ? 2 * (e - s) - 1 : e - s - 1;
        for (size_t i = s; i < e; i++) {
            uint32_t other = MESH_NO_TRI;
            if (users == 1)
                other = lo == hi ? he[i] / 3 : he[i == s ? s + 1 : s] / 3;
            topo->adj[he[i] / 3][he[i] % 3] = other;
        }
        topo->n_edges++;
        if (users == 0)
            topo->n_boundary++;
        else if (users >= 2)
            topo->n_nonmanifold++;
        else if (lo != hi && m->t[he[s + 1] / 3][he[s + 1] % 3] == a) /* both run a -> b */
            topo->n_misoriented++;
        s = e;
    }
    free(he);
    /* components by breadth-first search over adjacency */
    memset(topo->comp, 0xff, sizeof(uint32_t) * m->n_tris);
    for (uint32_t seed = 0; seed < m->n_tris; seed++) {
        if (topo->comp[seed] != UINT32_MAX)
            continue;
        uint32_t head = 0, tail = 0;
        queue[tail++] = seed;
        topo->comp[seed] = topo->n_comps;
        while (head < tail) {
            uint32_t i = queue[head++];
            for (int k = 0; k < 3; k++) {
                uint32_t j = topo->adj[i][k];
                if (j != MESH_NO_TRI && topo->comp[j] == UINT32_MAX) {
                    topo->comp[j] = topo->n_comps;
                    queue[tail++] = j;
                }
            }
        }
        topo->n_comps++;
    }
    free(queue);
    return SF_OK;
}

void
mesh_topo_release(struct mesh_topo *topo)
{
    free(topo->adj);
    free(topo->comp);
    memset(topo, 0, sizeof(*topo));
}

bool
mesh_topo_closed(const struct mesh_topo *topo)
{
    return topo->n_boundary == 0 && topo->n_nonmanifold == 0 && topo->n_misoriented == 0;
}

/* Does triangle t contain the directed edge a->b? */
static bool
tri_has_edge(const uint32_t t[3], uint32_t a, uint32_t b)
{
    for (int k = 0; k < 3; k++)
        if (t[k] == a && t[(k + 1) % 3] == b)
            return true;
    return false;
}

int
mesh_orient(struct mesh *m, struct sf_err *err)
{
    struct mesh_topo topo;
    int rc = mesh_topo_build(m, &topo, err);
    if (rc)
        return rc;
    uint8_t *seen = mem_calloc(m->n_tris ? m->n_tris : 1, 1);
    uint32_t *queue = mem_array(m->n_tris ? m->n_tris : 1, sizeof(uint32_t));
    bool *open = mem_calloc(topo.n_comps ? topo.n_comps : 1, sizeof(bool));
    double *vol = mem_calloc(topo.n_comps ? topo.n_comps : 1, sizeof(double));
    uint32_t(*orig)[3] = mem_array(m->n_tris ? m->n_tris : 1, sizeof(*orig));
    if (!seen || !queue || !open || !vol || !orig) {
        rc = sf_err_set(err, SF_ENOMEM, "out of memory orienting %u triangles", m->n_tris);
        goto out;
    }
    memcpy(orig, m->t, sizeof(*orig) * m->n_tris);
    int flipped = 0;
    for (uint32_t seed = 0; seed < m->n_tris; seed++) {
        if (seen[seed])
            continue;
        uint32_t head = 0, tail = 0;
        queue[tail++] = seed;
        seen[seed] = 1;
        while (head < tail) {
            uint32_t i = queue[head++];
            for (int k = 0; k < 3; k++) {
                uint32_t j = topo.adj[i][k];
                if (j == MESH_NO_TRI || seen[j])
                    continue;
                /* adj is indexed by the edges of the original winding, which flips
                   reorder: take the edge's vertices from the copy, its direction from i
                   as it is now (final), and flip j if it runs the same way */
                uint32_t a = orig[i][k], b = orig[i][(k + 1) % 3];
                if (!tri_has_edge(m->t[i], a, b)) {
                    uint32_t tmp = a;
                    a = b;
                    b = tmp;
                }
                if (tri_has_edge(m->t[j], a, b)) {
                    uint32_t tmp = m->t[j][1];
                    m->t[j][1] = m->t[j][2];
                    m->t[j][2] = tmp;
                    flipped++;
                }
                seen[j] = 1;
                queue[tail++] = j;
            }
        }
    }
    /* turn closed components with negative volume inside out */
    for (uint32_t i = 0; i < m->n_tris; i++)
        for (int k = 0; k < 3; k++)
            if (topo.adj[i][k] == MESH_NO_TRI)
                open[topo.comp[i]] = true;
    for (uint32_t i = 0; i < m->n_tris; i++) {
        struct vec3 a = m->v[m->t[i][0]], b = m->v[m->t[i][1]], c = m->v[m->t[i][2]];
        vol[topo.comp[i]] += v3_dot(a, v3_cross(b, c));
    }
    for (uint32_t i = 0; i < m->n_tris; i++) {
        uint32_t c = topo.comp[i];
        if (!open[c] && vol[c] < 0) {
            uint32_t tmp = m->t[i][1];
            m->t[i][1] = m->t[i][2];
            m->t[i][2] = tmp;
            flipped++;
        }
    }
    rc = flipped;
out:
    free(seen);
    free(queue);
    free(open);
    free(vol);
    free(orig);
    mesh_topo_release(&topo);
    return rc;
}
