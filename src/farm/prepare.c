/*
 * prepare.c - the prepare stage: part file in, G-code for one printer out.
 *
 * Why a separate module: the farm must not know how parts are oriented,
 * reshaped and sliced; this file is the one place that calls those stages
 * (src/mesh, src/geom, slicer/), with plain data in and out, so it runs on
 * a pool worker.  Design: load (a broken part fails its job with the
 * loader's message naming the uploaded file), orient with the job's angle
 * or the printer's, slim it (Hu 2015) within the job's deviation budget
 * when the method is 'slim' (a method not in the build is SF_EUNSUPP
 * naming it: never fake output), keeping the slimmed shape only if our
 * slicer prints it with less support (prepare_slice_better); a slimming
 * that fails (a mesh TetGen cannot enclose, a budget it refuses) is no
 * reason to leave the job unprinted: the part prints as oriented (a failed
 * surface optimization: as given) and the outcome says why
 * (prepare_out.shape_failed).  Then slice with the
 * printer's profile, overridden by the farm config's view of the hardware
 * (nozzle, bed, overhang angle) so one file is the truth about machines.
 * The part as it prints is saved for a later re-slice for another printer
 * (mesh_out), which then skips straight to slicing (mesh_in).
 * The cancel flag is checked between stages and inside the slicer.
 *
 * Thread: a pool worker; reads only its request and the profile files.
 * orient_find gets one thread: the pool already runs one task per core.
 */
#include "prepare.h"

#include <ctype.h>
#include <stdio.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "../../slicer/profile.h"
#include "../../slicer/slice.h"
#include "../base/buf.h"
#include "../base/clock.h"
#include "../base/limits.h"
#include "../base/log.h"
#include "../geom/dirsearch.h"
#include "../geom/orient.h"
#include "../geom/slim.h"
#include "../geom/surfopt.h"
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
    /* The farm config is the truth about the machine; the profile's own
       figures are only its defaults. */
    p->nozzle_mm = req->printer.nozzle_mm;
    p->bed_x_mm = req->printer.bed_mm[0];
    p->bed_y_mm = req->printer.bed_mm[1];
    p->max_z_mm = req->printer.bed_mm[2];
    p->max_overhang_deg =
        req->opts.overhang_deg > 0 ? req->opts.overhang_deg : req->printer.overhang_deg;
    rc = slice_profile_check(p, err);
    if (rc) {
        sf_err_prefix(err, "printer %s", req->printer.name);
        slice_profile_release(p);
    }
    return rc;
}

/*
 * The job's deviation budget for a shape optimizer: the largest vertex
 * displacement may not pass deviation_mm, nor the method's own limit
 * (max_mndr, a share of the diagonal); the mean not more than the max.
 */
static void
cap_deviation(const struct mesh *m, double deviation_mm, double *max_mndr, double *max_andr)
{
    double diag = mesh_diag(m);
    if (diag > 0 && deviation_mm / diag < *max_mndr)
        *max_mndr = deviation_mm / diag;
    if (*max_andr > *max_mndr)
        *max_andr = *max_mndr;
}

/* m becomes the optimizer's result (taken from out), back on the bed centre. */
static void
take_part(struct mesh *m, struct mesh *out, const struct slice_profile *prof)
{
    mesh_release(m);
    *m = *out;
    mesh_init(out);
    mesh_place_on_bed(m, prof->bed_x_mm / 2, prof->bed_y_mm / 2);
}

/*
 * Support slimming (Hu 2015) of the oriented part within the job's
 * deviation budget.  On success m holds the slimmed part, on the bed centre,
 * *changed says whether it is not the part it was given and *dev how far
 * it moved (MNDR / ANDR).
 */
static int
slim_part(struct mesh *m, const struct prepare_req *req, const struct slice_profile *prof,
          const atomic_bool *cancel, bool *changed, struct deviation *dev, struct sf_err *err)
{
    struct slim_params sp;
    slim_params_default(&sp);
    sp.angle_deg = prof->max_overhang_deg;
    /* a job may ask for less than the margin (1..89 degrees): aim at vertical */
    sp.margin_deg = sp.margin_deg < sp.angle_deg ? sp.margin_deg : sp.angle_deg;
    sp.cancel = cancel;
    cap_deviation(m, req->opts.deviation_mm, &sp.max_mndr, &sp.max_andr);
    struct slim_result sr;
    int rc = slim_optimize(m, &sp, &sr, err);
    if (rc)
        return rc;
    *changed = sr.best_iter > 0;
    *dev = sr.dev;
    log_info("prepare",
             "job %lld: slimmed (Hu 2015): iteration %d of %d kept, risky faces %u -> %u, "
             "support %.1f -> %.1f mm3, largest move %.3f mm",
             (long long)req->job_id, sr.best_iter, sr.n_curve - 1, sr.before.n_risky,
             sr.after.n_risky, sr.before.volume_mm3, sr.after.volume_mm3, sr.dev.max_mm);
    take_part(m, &sr.out, prof);
    slim_result_release(&sr);
    return SF_OK;
}

int
prepare_slice_better(const struct mesh *start, const struct mesh *shaped,
                     const struct slice_profile *prof, const char *out_path,
                     const atomic_bool *cancel, struct prepare_choice *ch, struct sf_err *err)
{
    memset(ch, 0, sizeof(*ch));
    char other[PREPARE_PATH_MAX + 16];
    if (snprintf(other, sizeof(other), "%s.start", out_path) >= (int)sizeof(other))
        return sf_err_set(err, SF_EINVAL, "prepare: path too long: '%s'", out_path);
    struct slice_result rs, r0;
    int rc = slice_mesh(shaped, prof, out_path, &rs, on_slice_progress, (void *)cancel, err);
    if (rc == SF_OK)
        rc = slice_mesh(start, prof, other, &r0, on_slice_progress, (void *)cancel, err);
    if (rc) {
        unlink(out_path);
        return rc;
    }
    ch->support_g_shaped = rs.support_g;
    ch->support_g_start = r0.support_g;
    ch->took_shaped = rs.support_g < r0.support_g;
    ch->filament_g = ch->took_shaped ? rs.filament_g : r0.filament_g;
    if (ch->took_shaped) {
        unlink(other);
        return SF_OK;
    }
    if (rename(other, out_path) != 0) {
        rc = sf_err_sys(err, "prepare: cannot rename '%s' to '%s'", other, out_path);
        unlink(other);
        unlink(out_path);
    }
    return rc;
}

/*
 * Orientation-fused surface optimization (Jayakody; src/geom/surfopt.h):
 * the part is turned and reshaped in alternating rounds within the same
 * deviation budget as slimming.  On success m holds the result, back on
 * the bed centre, and out's deviation fields say how far it moved.
 */
static int
surface_part(struct mesh *m, const struct prepare_req *req, const struct slice_profile *prof,
             const atomic_bool *cancel, double *saved_g, struct prepare_out *out,
             struct sf_err *err)
{
    struct surfopt_params sp;
    surfopt_params_default(&sp);
    sp.angle_deg = prof->max_overhang_deg;
    sp.margin_deg = sp.margin_deg < sp.angle_deg ? sp.margin_deg : sp.angle_deg;
    sp.cancel = cancel;
    cap_deviation(m, req->opts.deviation_mm, &sp.max_mndr, &sp.max_andr);
    /* shape inside the direction search: the best few directions are each
       reshaped and the support model picks (dirsearch.h, issue 21) */
    struct dirsearch_params dp;
    dirsearch_params_default(&dp);
    dp.sp = sp;
    dp.op.cancel = cancel;
    dp.policy.gram_s = req->gram_s;
    dp.policy.material_first = req->material_first;
    struct dirsearch_result dr;
    int rc = dirsearch_surface(m, &dp, &dr, err);
    if (rc)
        return rc;
    const struct surfopt_result *sr = &dr.best;
    out->dev_measured = true;
    out->shape_changed = !dr.kept_input && sr->shape_changed;
    out->mndr = out->shape_changed ? sr->dev.mndr : 0;
    out->andr = out->shape_changed ? sr->dev.andr : 0;
    if (!dr.kept_input && dr.model_input_g > sr->model_after_g)
        *saved_g = dr.model_input_g - sr->model_after_g;
    if (dr.kept_input)
        log_info("prepare",
                 "job %lld: surface (Jayakody 2025) in the direction search: none of %d "
                 "directions is worth it (model %.2f g of support, %.0f s estimated): printed "
                 "as given: %s",
                 (long long)req->job_id, dr.n_tried, dr.model_input_g, dr.input_cost.print_s,
                 sr->unchanged_why ? sr->unchanged_why : "");
    else
        log_info("prepare",
                 "job %lld: surface (Jayakody 2025) in the direction search: %d directions, "
                 "model support %.2f -> %.2f g, estimated %.0f -> %.0f s, risky faces %u -> %u, "
                 "shape %s%s%s, largest move %.3f mm",
                 (long long)req->job_id, dr.n_tried, dr.model_input_g, sr->model_after_g,
                 dr.input_cost.print_s, dr.cost.print_s, sr->input.n_risky, sr->after.n_risky,
                 sr->shape_changed ? "changed" : "kept", sr->unchanged_why ? ": " : "",
                 sr->unchanged_why ? sr->unchanged_why : "", sr->dev.max_mm);
    take_part(m, &dr.best.out, prof);
    dirsearch_result_release(&dr);
    return SF_OK;
}

/* A shape step (what) failed with rc / serr: say so in out->shape_failed and
   the log; the part prints `as` it stood before the step. */
static void
shape_fallback(const struct prepare_req *req, struct prepare_out *out, int rc,
               const struct sf_err *serr, const char *what, const char *as)
{
    snprintf(out->shape_failed, sizeof(out->shape_failed), "%s failed (%s): printed %s, unchanged",
             what, serr->msg[0] ? serr->msg : sf_status_name(rc), as);
    log_warn("prepare", "job %lld: %s", (long long)req->job_id, out->shape_failed);
}

/* Load stage: the part file (or the saved part a re-slice reuses) into m. */
static int
load_part(const struct prepare_req *req, bool reuse, struct mesh *m, struct sf_err *err)
{
    struct buf data;
    buf_init(&data, SF_MESH_FILE_MAX);
    int rc = buf_read_file(&data, reuse ? req->mesh_in : req->part_path, err);
    if (rc == SF_OK)
        rc = mesh_load_mem(data.data ? data.data : "", data.len, req->part_name, m, NULL, err);
    buf_release(&data);
    return rc;
}

/* Orient stage: m turned to the up-direction that needs the least support at the profile's
   overhang angle, on the bed centre; *saved_g the support that saves, when the model knows. */
static int
orient_part(struct mesh *m, const struct prepare_req *req, const struct slice_profile *prof,
            const atomic_bool *cancel, double *saved_g, struct sf_err *err)
{
    if (atomic_load(cancel))
        return cancelled(req, err);
    struct orient_params op;
    struct orient_result res;
    orient_params_default(&op);
    op.angle_deg = prof->max_overhang_deg;
    op.cancel = cancel;
    int rc = orient_find(m, &op, &res, err);
    if (rc)
        return rc;
    orient_apply(m, res.best.up, prof->bed_x_mm / 2, prof->bed_y_mm / 2);
    /* the support model ranks only finalists: both grams are known only
       when the input direction was one */
    if (res.input.support_g > 0 && res.best.support_g > 0 &&
        res.input.support_g > res.best.support_g)
        *saved_g = res.input.support_g - res.best.support_g;
    return SF_OK;
}

/* Record stage, after a slice that succeeded: save the part as it prints for a re-slice when
   save (and req->mesh_out asks; a failure removes the G-code) and fill out's figures. */
static int
record(const struct prepare_req *req, const struct mesh *printed, bool save,
       const struct slice_profile *prof, const struct slice_result *sres, double saved_g,
       struct prepare_out *out, struct sf_err *err)
{
    struct vec3 lo, hi;
    mesh_bbox(printed, &lo, &hi);
    int rc = SF_OK;
    if (req->mesh_out[0] && save) {
        if ((rc = mesh_save_stl(printed, req->mesh_out, err)))
            unlink(req->out_path);
        out->mesh_saved = rc == SF_OK;
    }
    if (rc == SF_OK) {
        out->size_mm[0] = hi.x - lo.x;
        out->size_mm[1] = hi.y - lo.y;
        out->size_mm[2] = hi.z - lo.z;
        out->nozzle_mm = prof->nozzle_mm;
        out->filament_g = sres->filament_g;
        out->support_g = sres->support_g;
        out->support_saved_g = saved_g;
    }
    return rc;
}

int
prepare_part(const struct prepare_req *req, struct prepare_out *out, const atomic_bool *cancel,
             struct sf_err *err)
{
    const char *method = req->opts.method;
    out->dev_measured = out->shape_changed = false;
    out->mndr = out->andr = 0;
    out->shape_failed[0] = '\0';
    if (atomic_load(cancel))
        return cancelled(req, err);
    struct mesh m, start; /* start: a slim job's part before slimming */
    double saved_g = 0;   /* support the optimization saved (prepare_out) */
    struct sf_err serr;   /* slimming's failure, kept even when err is NULL */
    sf_err_clear(&serr);
    mesh_init(&m);
    mesh_init(&start);
    bool reuse = req->mesh_in[0] != '\0';
    int rc = load_part(req, reuse, &m, err);
    if (rc)
        goto out;
    struct slice_profile prof;
    if ((rc = load_profile(req, &prof, err)))
        goto out;
    if (reuse)
        method = "none"; /* oriented and shaped already: the slicer centres it on this bed */
    bool slim = strcmp(method, "slim") == 0;
    if ((strcmp(method, "orient") == 0 || slim) &&
        (rc = orient_part(&m, req, &prof, cancel, &saved_g, err)))
        goto release;
    bool slimmed = false;
    struct deviation sdev = { 0 };
    if (slim && (rc = mesh_copy(&start, &m, err)))
        goto release;
    if (slim && (rc = slim_part(&m, req, &prof, cancel, &slimmed, &sdev, &serr))) {
        /* A part TetGen or CHOLMOD cannot take still prints: m is the part as
           oriented, untouched.  A cancel cancels; out of memory fails the job
           as it does in every other stage. */
        if (rc == SF_ECANCELED || rc == SF_ENOMEM) {
            if (err)
                *err = serr;
            goto release;
        }
        shape_fallback(req, out, rc, &serr, "slimming", "as oriented");
        slimmed = false;
        rc = SF_OK;
    }
    if (slim) {
        out->dev_measured = true;
        out->shape_changed = slimmed;
        out->mndr = slimmed ? sdev.mndr : 0;
        out->andr = slimmed ? sdev.andr : 0;
    }
    if (strcmp(method, "surface") == 0 &&
        (rc = surface_part(&m, req, &prof, cancel, &saved_g, out, &serr))) {
        /* as for slimming: the part prints as given, m untouched */
        if (rc == SF_ECANCELED || rc == SF_ENOMEM) {
            if (err)
                *err = serr;
            goto release;
        }
        shape_fallback(req, out, rc, &serr, "surface optimization", "as given");
        out->dev_measured = true;
        out->shape_changed = false;
        out->mndr = out->andr = 0;
        rc = SF_OK;
    }
    if (atomic_load(cancel)) {
        rc = cancelled(req, err);
        goto release;
    }
    const struct mesh *printed = &m;
    struct slice_result sres = { 0 };
    int64_t t0 = clock_mono_ms();
    if (slimmed) {
        struct prepare_choice ch;
        rc = prepare_slice_better(&start, &m, &prof, req->out_path, cancel, &ch, err);
        if (rc == SF_OK) {
            sres.filament_g = ch.filament_g;
            sres.support_g = ch.took_shaped ? ch.support_g_shaped : ch.support_g_start;
            saved_g += ch.support_g_start - sres.support_g; /* sliced both: the slicer's grams */
        }
        if (rc == SF_OK && !ch.took_shaped) {
            printed = &start; /* as oriented: not moved */
            out->shape_changed = false;
            out->mndr = out->andr = 0;
            log_info("prepare",
                     "job %lld: the slimmed part needs %.2f g of support, the part as oriented "
                     "%.2f g: printing it as oriented",
                     (long long)req->job_id, ch.support_g_shaped, ch.support_g_start);
        }
    } else {
        rc = slice_mesh(&m, &prof, req->out_path, &sres, on_slice_progress, (void *)cancel, err);
    }
    out->slice_ms = clock_mono_ms() - t0;
    if (rc == SF_OK)
        rc = record(req, printed, !reuse && strcmp(method, "none") != 0, &prof, &sres, saved_g, out,
                    err);
release:
    slice_profile_release(&prof);
out:
    mesh_release(&start);
    mesh_release(&m);
    if (rc && rc != SF_EUNSUPP && rc != SF_ECANCELED)
        sf_err_prefix(err, "job %lld", (long long)req->job_id);
    return rc;
}
