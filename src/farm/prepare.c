/*
 * prepare.c - the prepare stage: part file in, G-code for one printer out.
 *
 * Why a separate module: the farm must not know how parts are oriented,
 * reshaped and sliced, and those stages are written on other branches.
 * This file is the one place that will call them (src/geom orient and
 * shape optimization, slicer/ slice) once they exist; until then it fails
 * loudly with SF_EUNSUPP naming what is missing, never producing fake
 * G-code.  The farm turns SF_EUNSUPP into "job stays queued, reason: ...".
 *
 * Thread: a pool worker; reads only its request.
 */
#include "prepare.h"

#include <stdio.h>
#include <string.h>

#include "../base/buf.h"
#include "../base/limits.h"
#include "../mesh/mesh.h"

int
prepare_part(const struct prepare_req *req, struct prepare_out *out, const atomic_bool *cancel,
             struct sf_err *err)
{
    if (atomic_load(cancel))
        return sf_err_set(err, SF_ECANCELED, "job %lld: prepare cancelled", (long long)req->job_id);
    /* Load first: a broken part fails its job now, with the loader's
       message naming the uploaded file, instead of waiting for a slicer. */
    struct buf data;
    struct mesh m;
    buf_init(&data, SF_MESH_FILE_MAX);
    mesh_init(&m);
    int rc = buf_read_file(&data, req->part_path, err);
    if (rc == SF_OK)
        rc = mesh_load_mem(data.data ? data.data : "", data.len, req->part_name, &m, NULL, err);
    buf_release(&data);
    if (rc == SF_OK) {
        struct vec3 lo, hi;
        mesh_bbox(&m, &lo, &hi);
        out->size_mm[0] = hi.x - lo.x;
        out->size_mm[1] = hi.y - lo.y;
        out->size_mm[2] = hi.z - lo.z;
    }
    mesh_release(&m);
    if (rc)
        return rc;
    if (atomic_load(cancel))
        return sf_err_set(err, SF_ECANCELED, "job %lld: prepare cancelled", (long long)req->job_id);
    /* TODO(#7): orient for req->opts.overhang_deg (or the printer's), run
       req->opts.method within req->opts.deviation_mm (src/geom), slice
       with req->printer.profile (slicer/), write req->out_path. */
    return sf_err_set(err, SF_EUNSUPP,
                      "prepare: slicing is not available in this build (slicer/ not merged yet); "
                      "method '%s' for printer %s waits for it",
                      req->opts.method, req->printer.name);
}
