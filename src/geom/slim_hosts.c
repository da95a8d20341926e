/*
 * slim_hosts.c - which part faces lie in which tet (slim_int.h), for the
 * slimming loop's drives.
 */
#include "slim_int.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../base/mem.h"

static int
pair_cmp(const void *pa, const void *pb)
{
    const uint32_t *a = pa, *b = pb;
    if (a[0] != b[0])
        return a[0] < b[0] ? -1 : 1;
    return a[1] < b[1] ? -1 : a[1] > b[1];
}

int
slim_face_hosts_build(const struct mesh *m, const struct tetmesh *tm, struct face_hosts *fh,
                      struct sf_err *err)
{
    memset(fh, 0, sizeof(*fh));
    double step = tm->pitch_mm / 2;
    size_t n_pts = 0, cap = 0;
    struct vec3 *pts = NULL;
    uint32_t *owner = NULL;
    size_t cap_o = 0;
    for (uint32_t f = 0; f < m->n_tris; f++) {
        struct vec3 a = m->v[m->t[f][0]], b = m->v[m->t[f][1]], c = m->v[m->t[f][2]];
        double e = fmax(v3_len(v3_sub(b, a)), fmax(v3_len(v3_sub(c, b)), v3_len(v3_sub(a, c))));
        int ns = (int)fmin(ceil(e / step), 24); /* interior grid; vertices use their hosts */
        for (int i = 0; i <= ns; i++)
            for (int j = 0; i + j <= ns; j++) {
                int k = ns - i - j;
                if ((i == ns || j == ns || k == ns) && ns > 0)
                    continue;
                if (!mem_grow((void **)&pts, &cap, n_pts + 2, sizeof(*pts)) ||
                    !mem_grow((void **)&owner, &cap_o, n_pts + 2, sizeof(*owner))) {
                    free(pts);
                    free(owner);
                    return sf_err_set(err, SF_ENOMEM, "slim: out of memory sampling faces");
                }
                double u = ns ? (double)i / ns : 1.0 / 3, v = ns ? (double)j / ns : 1.0 / 3;
                pts[n_pts] = v3_add(v3_add(v3_scale(a, u), v3_scale(b, v)), v3_scale(c, 1 - u - v));
                owner[n_pts++] = f;
            }
    }
    uint32_t *host = mem_array(n_pts ? n_pts : 1, sizeof(uint32_t));
    size_t n_pairs = n_pts + 3 * (size_t)m->n_tris;
    uint32_t(*pairs)[2] = mem_array(n_pairs, sizeof(*pairs));
    int rc = host && pairs ? tetmesh_locate(tm, pts, (uint32_t)n_pts, host, NULL, NULL, err)
                           : sf_err_set(err, SF_ENOMEM, "slim: out of memory sampling faces");
    if (rc == SF_OK) {
        size_t k = 0;
        for (size_t i = 0; i < n_pts; i++)
            pairs[k][0] = host[i], pairs[k++][1] = owner[i];
        for (uint32_t f = 0; f < m->n_tris; f++)
            for (int c = 0; c < 3; c++)
                pairs[k][0] = tm->host[m->t[f][c]], pairs[k++][1] = f;
        qsort(pairs, k, sizeof(*pairs), pair_cmp);
        size_t u = 0;
        for (size_t i = 0; i < k; i++)
            if (i == 0 || pair_cmp(pairs[i], pairs[u - 1]) != 0)
                memcpy(pairs[u++], pairs[i], sizeof(*pairs));
        uint32_t nt = 0;
        for (size_t i = 0; i < u; i++)
            nt += i == 0 || pairs[i][0] != pairs[i - 1][0];
        fh->tet = mem_array(nt ? nt : 1, sizeof(uint32_t));
        fh->start = mem_array((size_t)nt + 1, sizeof(uint32_t));
        fh->face = mem_array(u ? u : 1, sizeof(uint32_t));
        if (!fh->tet || !fh->start || !fh->face) {
            rc = sf_err_set(err, SF_ENOMEM, "slim: out of memory for face hosts");
        } else {
            for (size_t i = 0; i < u; i++) {
                if (i == 0 || pairs[i][0] != pairs[i - 1][0]) {
                    fh->tet[fh->n] = pairs[i][0];
                    fh->start[fh->n++] = (uint32_t)i;
                }
                fh->face[i] = pairs[i][1];
            }
            fh->start[fh->n] = (uint32_t)u;
        }
    }
    free(pts);
    free(owner);
    free(host);
    free(pairs);
    return rc;
}

void
slim_face_hosts_release(struct face_hosts *fh)
{
    free(fh->tet);
    free(fh->start);
    free(fh->face);
    memset(fh, 0, sizeof(*fh));
}
