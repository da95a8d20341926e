/*
 * fuzz_rims.c - the open-rim slicing of the support model (src/geom/rims.h)
 * on whatever mesh an OBJ input makes after load's repairs: rims, the open
 * layers of a peer with a 2 mm gap along +z on a raster over the part's
 * footprint, and every kept-span query.  Bounded sizes keep each input fast.
 */
#include <math.h>
#include <stdint.h>

#include "../../src/geom/rims.h"
#include "fuzz_mesh.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int
LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct mesh m;
    mesh_init(&m);
    if (obj_parse(data, size, "fuzz", &m, NULL) != SF_OK || m.n_tris == 0 || m.n_tris > 4096)
        goto out;
    mesh_weld(&m, 1e-6 * mesh_diag(&m), NULL);
    mesh_drop_degenerate(&m);
    mesh_compact(&m);
    mesh_orient(&m, NULL);
    struct vec3 lo, hi;
    mesh_bbox(&m, &lo, &hi);
    if (m.n_tris == 0 || !(hi.x - lo.x <= 200 && hi.y - lo.y <= 200 && hi.z - lo.z <= 200))
        goto out;
    struct rims r;
    if (rims_build(&m, &r, NULL) != SF_OK)
        goto out;
    struct rim_frame f = { v3(0, 0, 1),
                           v3(1, 0, 0),
                           v3(0, 1, 0),
                           lo.x,
                           lo.y,
                           0.5,
                           lo.z,
                           0.2,
                           (uint32_t)ceil((hi.x - lo.x) / 0.5) + 1,
                           (uint32_t)ceil((hi.y - lo.y) / 0.5) + 1 };
    struct open_sections os;
    if (rims_open_sections(&r, &m, &f, 2, &os, NULL) == SF_OK) {
        uint32_t kept = 0;
        for (uint32_t l = 0; l < os.n_layers; l++)
            for (uint32_t j = 0; j < f.nw; j++)
                for (uint32_t i = 0; i < f.nu; i++)
                    kept += open_sections_keeps(&os, l, i, j);
        (void)kept;
        open_sections_release(&os);
    }
    rims_release(&r);
out:
    mesh_release(&m);
    return 0;
}
