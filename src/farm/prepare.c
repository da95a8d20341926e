/*
 * prepare.c - the prepare stage: part file in, G-code for one printer out.
 *
 * Why a separate module: the farm must not know how parts are oriented,
 * reshaped and sliced; this file is the one place that calls those stages
 * (src/mesh, src/geom, slicer/), with plain data in and out, so it runs on
 * a pool worker.  Design: load (a broken part fails its job with the
 * loader's message naming the uploaded file), orient with the job's angle
 * or the printer's, reshape when the method asks and the stage exists
 * (otherwise SF_EUNSUPP naming it: never fake output), then slice with the
 * printer's profile, overridden by the farm config's view of the hardware
 * (nozzle, bed, overhang angle) so one file is the truth about machines.
 * The cancel flag is checked between stages and inside the slicer.
 *
 * Thread: a pool worker; reads only its request and the profile files.
 * orient_find gets one thread: the pool already runs one task per core.
 */
#include "prepare.h"

#include <ctype.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "../../slicer/profile.h"
#include "../../slicer/slice.h"
#include "../base/buf.h"
#include "../base/limits.h"
#include "../geom/orient.h"
#include "../mesh/mesh.h"

static int
cancelled(const struct prepare_req *req, struct sf_err *err)
{
    return sf_err_set(err, SF_ECANCELED, "job %lld: prepare cancelled", (long long)req->job_id);
}

static int
on_slice_progress(void *ud, const char *stage, double done)
{
    (void)stage, (void)done;
    return atomic_load((const atomic_bool *)ud);
}

/* The profile: printer file, material file, then the farm's hardware facts. */
static int
load_profile(const struct prepare_req *req, struct slice_profile *p, struct sf_err *err)
{
    char printer[PREPARE_PATH_MAX + 96], material[PREPARE_PATH_MAX + 96], lower[32];
    const char *m = req->opts.material[0] ? req->opts.material : req->printer.material;
    size_t i = 0;
    for (; m[i] && i + 1 < sizeof(lower); i++)
        lower[i] = (char)tolower((unsigned char)m[i]);
    lower[i] = '\0';
    snprintf(printer, sizeof(printer), "%s/printers/%s.cfg", req->profiles_dir,
             req->printer.profile);
    snprintf(material, sizeof(material), "%s/materials/%s.cfg", req->profiles_dir, lower);
    if (access(printer, R_OK) != 0)
        return sf_err_set(err, SF_EINVAL, "printer %s: profile '%s' not found (%s)",
                          req->printer.name, req->printer.profile, printer);
    if (access(material, R_OK) != 0)
        return sf_err_set(err, SF_EINVAL, "material '%s' has no profile (%s)", m, material);
    int rc = slice_profile_load(printer, material, p, err);
    if (rc)
        return rc;
    double angle = req->opts.overhang_deg > 0 ? req->opts.overhang_deg : req->printer.overhang_deg;
    char kv[5][64];
    snprintf(kv[0], sizeof(kv[0]), "nozzle=%g", req->printer.nozzle_mm);
    snprintf(kv[1], sizeof(kv[1]), "bed_x=%g", req->printer.bed_mm[0]);
    snprintf(kv[2], sizeof(kv[2]), "bed_y=%g", req->printer.bed_mm[1]);
    snprintf(kv[3], sizeof(kv[3]), "max_z=%g", req->printer.bed_mm[2]);
    snprintf(kv[4], sizeof(kv[4]), "max_overhang=%g", angle);
    for (int k = 0; k < 5 && rc == SF_OK; k++)
        rc = slice_profile_set(p, kv[k], err);
    if (rc == SF_OK)
        rc = slice_profile_check(p, err);
    if (rc) {
        sf_err_prefix(err, "printer %s", req->printer.name);
        slice_profile_release(p);
    }
    return rc;
}

int
prepare_part(const struct prepare_req *req, struct prepare_out *out, const atomic_bool *cancel,
             struct sf_err *err)
{
    const char *method = req->opts.method;
    if (atomic_load(cancel))
        return cancelled(req, err);
    struct buf data;
    struct mesh m;
    buf_init(&data, SF_MESH_FILE_MAX);
    mesh_init(&m);
    int rc = buf_read_file(&data, req->part_path, err);
    if (rc == SF_OK)
        rc = mesh_load_mem(data.data ? data.data : "", data.len, req->part_name, &m, NULL, err);
    buf_release(&data);
    if (rc)
        goto out;
    if (strcmp(method, "slim") == 0 || strcmp(method, "surface") == 0) {
        /* TODO(#7): call src/geom's slimming (Hu 2015) / surface
           optimization (Jayakody) within req->opts.deviation_mm. */
        rc = sf_err_set(err, SF_EUNSUPP,
                        "prepare: method '%s' is not available in this build (its src/geom "
                        "stage is not merged yet); use 'orient' or 'none'",
                        method);
        goto out;
    }
    struct slice_profile prof;
    if ((rc = load_profile(req, &prof, err)))
        goto out;
    if (strcmp(method, "orient") == 0) {
        if (atomic_load(cancel)) {
            rc = cancelled(req, err);
            goto release;
        }
        struct orient_params op;
        struct orient_result res;
        orient_params_default(&op);
        op.angle_deg = prof.max_overhang_deg;
        op.threads = 1;
        if ((rc = orient_find(&m, &op, &res, err)))
            goto release;
        orient_apply(&m, res.best.up, prof.bed_x_mm / 2, prof.bed_y_mm / 2);
    }
    if (atomic_load(cancel)) {
        rc = cancelled(req, err);
        goto release;
    }
    struct vec3 lo, hi;
    mesh_bbox(&m, &lo, &hi);
    rc = slice_mesh(&m, &prof, req->out_path, NULL, on_slice_progress, (void *)cancel, err);
    if (rc == SF_OK) {
        out->size_mm[0] = hi.x - lo.x;
        out->size_mm[1] = hi.y - lo.y;
        out->size_mm[2] = hi.z - lo.z;
        out->nozzle_mm = prof.nozzle_mm;
    }
release:
    slice_profile_release(&prof);
out:
    mesh_release(&m);
    if (rc && rc != SF_EUNSUPP && rc != SF_ECANCELED)
        sf_err_prefix(err, "job %lld", (long long)req->job_id);
    return rc;
}
