/*
 * farm_files.c - a preparation's file lookups on its worker (farm_int.h),
 * and the jobs whose files could not be had a moment ago.
 *
 * On a shared store a stored file this host's cache lacks is fetched from
 * the database before its path is given (store.h store_file_path: a
 * 100 MB part, 1-2 s), so the lookup leaves the loop's connection for a
 * reader of the worker's own.  A start's G-code lookup is farm_gcheck.c's.
 *
 * Thread: farm_prep_files on a prepare worker; the rest on the loop thread.
 */
#include "farm_int.h"

#include <stdio.h>
#include <string.h>

#include "../base/clock.h"
#include "../base/mem.h"

int
farm_prep_files(const struct store *s, struct prepare_req *req, const char *part_sha,
                const char *reuse_sha, bool reslice, struct sf_err *err)
{
    struct store *r = store_open_reader(s, err);
    if (!r)
        return err->code;
    size_t cap = sizeof(req->out_path) - 32;
    int rc = store_file_path(r, part_sha, req->out_path, cap, err);
    if (rc == SF_OK && reuse_sha[0])
        rc = store_file_path(r, reuse_sha, req->mesh_in, sizeof(req->mesh_in), err);
    store_close(r);
    if (rc) {
        req->out_path[0] = req->mesh_in[0] = '\0'; /* nothing of the worker's to remove */
        return rc;
    }
    snprintf(req->part_path, sizeof(req->part_path), "%s", req->out_path);
    /* out: beside the stored files, named for the job and the task */
    char *slash = strrchr(req->out_path, '/');
    snprintf(slash + 1, 32, "job-%lld%s.gcode", (long long)req->job_id, reslice ? "-re" : "");
    if (!reuse_sha[0])
        snprintf(req->mesh_out, sizeof(req->mesh_out), "%s.stl", req->out_path);
    return SF_OK;
}

void
farm_cool(struct farm *f, int64_t id)
{
    if (mem_grow((void **)&f->cool, &f->cap_cool, f->n_cool + 1, sizeof(*f->cool))) {
        f->cool[f->n_cool].job_id = id;
        f->cool[f->n_cool++].until_ms = clock_mono_ms() + FARM_RETRY_MS;
    }
    farm_retry_later(f);
}

bool
farm_cooling(struct farm *f, int64_t id)
{
    bool hit = false;
    int64_t now = clock_mono_ms();
    for (size_t i = 0; i < f->n_cool;) {
        if (f->cool[i].until_ms <= now) { /* over: dropped */
            f->cool[i] = f->cool[--f->n_cool];
            continue;
        }
        hit = hit || f->cool[i].job_id == id;
        i++;
    }
    return hit;
}
