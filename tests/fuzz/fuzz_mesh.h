/*
 * fuzz_mesh.h - the body of the mesh loaders' fuzz harnesses (fuzz_stl.c,
 * fuzz_obj.c, fuzz_3mf.c): parse the input with one loader, then weld,
 * drop degenerate faces, compact and orient what it yields, as every part
 * is on load.  Header-only.
 */
#ifndef SF_TESTS_FUZZ_MESH_H
#define SF_TESTS_FUZZ_MESH_H

#include <stdint.h>

#include "../../src/mesh/mesh.h"

/* stl_parse, obj_parse, tmf_parse (mesh.h) */
typedef int (*fuzz_mesh_parse_fn)(const void *data, size_t len, const char *name, struct mesh *m,
                                  struct sf_err *err);

static inline int
fuzz_mesh(const uint8_t *data, size_t size, fuzz_mesh_parse_fn parse)
{
    struct mesh m;
    mesh_init(&m);
    if (parse(data, size, "fuzz", &m, NULL) == SF_OK && m.n_tris > 0) {
        mesh_weld(&m, 1e-6 * mesh_diag(&m), NULL);
        mesh_drop_degenerate(&m);
        mesh_compact(&m);
        mesh_orient(&m, NULL);
    }
    mesh_release(&m);
    return 0;
}

#endif
