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

int
prepare_part(const struct prepare_req *req, struct prepare_out *out, const atomic_bool *cancel,
             struct sf_err *err)
{
    (void)out;
    if (atomic_load(cancel))
        return sf_err_set(err, SF_ECANCELED, "job %lld: prepare cancelled", (long long)req->job_id);
    /* TODO(#7): load the part (src/mesh), orient for req->printer.overhang_deg
       or req->opts.overhang_deg, run req->opts.method within
       req->opts.deviation_mm (src/geom), slice with req->printer.profile
       (slicer/), write req->out_path. */
    return sf_err_set(err, SF_EUNSUPP,
                      "prepare: slicing is not available in this build (slicer/ not merged yet); "
                      "method '%s' for printer %s waits for it",
                      req->opts.method, req->printer.name);
}
