/*
 * test_slice_oom.c - every allocation of a small slice failing in turn
 * (mem.h's injection): slice_mesh must return SF_ENOMEM (or succeed when
 * the failed allocation was optional), never crash or leak; the sanitizer
 * build checks the leaks.
 */
#include <stdio.h>

#include "../../slicer/slice.h"
#include "../../src/base/mem.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"

T_CASE(slice_survives_every_failed_allocation)
{
    struct mesh m;
    struct sf_err err;
    mesh_init(&m);
    T_OK(shape_tee(&m, &err), &err);
    for (uint32_t i = 0; i < m.n_verts; i++) /* a quarter-size tee: 30 layers */
        m.v[i] = v3_scale(m.v[i], 0.25);
    /* and a post beside it, so layers have two islands */
    struct mesh b;
    mesh_init(&b);
    T_OK(shape_box(&b, v3(10, -2, 0), v3(14, 2, 6), &err), &err);
    struct vec3 *nv = mem_realloc_array(m.v, m.n_verts + b.n_verts, sizeof(*nv));
    T_TRUE(nv != NULL);
    m.v = nv;
    uint32_t(*nt)[3] = mem_realloc_array(m.t, m.n_tris + b.n_tris, sizeof(*nt));
    T_TRUE(nt != NULL);
    m.t = nt;
    for (uint32_t i = 0; i < b.n_verts; i++)
        m.v[m.n_verts + i] = b.v[i];
    for (uint32_t i = 0; i < b.n_tris; i++)
        for (int c = 0; c < 3; c++)
            m.t[m.n_tris + i][c] = b.t[i][c] + m.n_verts;
    m.n_verts += b.n_verts;
    m.n_tris += b.n_tris;
    mesh_release(&b);
    struct slice_profile p;
    T_OK(slice_profile_default(&p), NULL);
    p.layer_mm = p.first_layer_mm = 0.3; /* fewer layers: a faster loop */
    p.support_pitch_mm = 0.5;
    p.infill_density = 0.1;
    char path[512];
    snprintf(path, sizeof(path), "%s/oom.gcode", t_tmpdir());
    mem_fail_after(0);
    mem_alloc_count();
    T_OK(slice_mesh(&m, &p, path, NULL, NULL, NULL, &err), &err);
    long total = mem_alloc_count();
    T_TRUE(total > 100);
    int n_fail = 0, n_ok = 0;
    /* every allocation of the first 120, then about 120 more spread over the rest */
    for (long n = 1; n <= total; n += n < 120 ? 1 : total / 120 + 1) {
        mem_fail_after(n);
        int rc = slice_mesh(&m, &p, path, NULL, NULL, NULL, &err);
        mem_fail_after(0);
        if (rc == SF_OK)
            n_ok++;
        else if (rc == SF_ENOMEM)
            n_fail++;
        else
            t_fail(__FILE__, __LINE__, "allocation %ld failed: %s (%s)", n, sf_status_name(rc),
                   err.msg);
    }
    T_TRUE(n_fail > 150);
    (void)n_ok;
    slice_profile_release(&p);
    mesh_release(&m);
}
