/*
 * test_slice_oom.c - every allocation of a small slice failing in turn
 * (mem.h's injection): slice_mesh must return SF_ENOMEM and leave no
 * G-code behind, or succeed only when the failed allocation was optional,
 * and then write exactly the G-code of a clean run; never crash or leak
 * (the sanitizer build checks the leaks).
 */
#include <stdio.h>
#include <unistd.h>

#include "../../slicer/slice.h"
#include "../../src/base/buf.h"
#include "../../src/base/mem.h"
#include "../../src/mesh/shapes.h"
#include "../t.h"

/* The whole of file path into b (buf_release). */
static int
read_file(const char *path, struct buf *b)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return SF_EIO;
    char chunk[1 << 14];
    size_t n;
    int rc = SF_OK;
    while (rc == SF_OK && (n = fread(chunk, 1, sizeof(chunk), f)) > 0)
        rc = buf_append(b, chunk, n);
    if (ferror(f))
        rc = SF_EIO;
    fclose(f);
    return rc;
}

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
    struct buf clean;
    buf_init(&clean, 0);
    T_OK(read_file(path, &clean), NULL);
    T_TRUE(clean.len > 1000);
    int n_fail = 0, n_ok = 0;
    /* every allocation of the first 120 and of the last 40 (writing the file), then about
       120 more spread over the rest */
    for (long n = 1; n <= total; n += n < 120 || n >= total - 40 ? 1 : total / 120 + 1) {
        unlink(path);
        mem_fail_after(n);
        int rc = slice_mesh(&m, &p, path, NULL, NULL, NULL, &err);
        long tried = mem_alloc_count();
        mem_fail_after(0);
        if (rc == SF_ENOMEM) {
            n_fail++;
            /* a failed slice leaves no G-code a caller could take for the part's */
            if (access(path, F_OK) == 0)
                t_fail(__FILE__, __LINE__, "allocation %ld failed, yet %s was written", n, path);
            continue;
        }
        if (rc != SF_OK) {
            t_fail(__FILE__, __LINE__, "allocation %ld failed: %s (%s)", n, sf_status_name(rc),
                   err.msg);
            continue;
        }
        /* Success is right only if the failure never fired (this run allocated less), or
           if what failed was optional: then the G-code must be the clean run's, byte for
           byte, not a silently degraded part. */
        n_ok++;
        struct buf got;
        buf_init(&got, 0);
        int same = read_file(path, &got) == SF_OK && got.len == clean.len &&
                   memcmp(got.data, clean.data, clean.len) == 0;
        buf_release(&got);
        if (!same)
            t_fail(__FILE__, __LINE__,
                   "allocation %ld of %ld failed (%s), slice_mesh said SF_OK, and its G-code "
                   "differs from the clean run's",
                   n, tried, tried >= n ? "fired" : "never reached");
    }
    printf("    %ld allocations: %d failed runs said SF_ENOMEM, %d succeeded with the clean "
           "G-code\n",
           total, n_fail, n_ok);
    T_TRUE(n_fail > 150);
    buf_release(&clean);
    slice_profile_release(&p);
    mesh_release(&m);
}
