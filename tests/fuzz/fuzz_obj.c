/* fuzz_obj.c - the obj loader, then weld, orientation repair and topology on what it yields. */
#include <stdint.h>

#include "../../src/mesh/mesh.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int
LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct mesh m;
    mesh_init(&m);
    if (obj_parse(data, size, "fuzz", &m, NULL) == SF_OK && m.n_tris > 0) {
        mesh_weld(&m, 1e-6 * mesh_diag(&m), NULL);
        mesh_drop_degenerate(&m);
        mesh_compact(&m);
        mesh_orient(&m, NULL);
    }
    mesh_release(&m);
    return 0;
}
