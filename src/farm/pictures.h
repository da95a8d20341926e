/*
 * pictures.h - the farm gives the pictures of a job: its part as uploaded
 * ("before") or as it prints, oriented and shaped ("after"), with the faces
 * that need support red for the job's overhang angle (slicer/preview.h),
 * and what the support model says that part needs (geom/supmodel.h).
 *
 * A render is slow (load, ray grid, cairo: a second or more), so it runs
 * on the worker pool; the caller asks again after ready() says a render
 * ended.  Pictures are kept by what they show (file sha and angle) in a
 * small least-recently-used cache of PICTURES_MAX.
 *
 * Thread: the loop thread; renders on the pool, delivered on the loop.
 * Owns the rendered PNGs; a render in flight when pictures_free runs
 * finishes unseen.
 */
#ifndef SF_FARM_PICTURES_H
#define SF_FARM_PICTURES_H

#include <stdbool.h>
#include <stddef.h>

#include "../base/err.h"
#include "../base/pool.h"
#include "job.h"
#include "store.h"

#define PICTURES_MAX     16 /* rendered pictures kept (about 100 kB each) */
#define PICTURES_W_PX    640
#define PICTURES_H_PX    480
#define PICTURES_KEY_MAX 96

struct pictures_config {
    struct store *store;     /* the parts (not owned): looked up on a worker's reader of it */
    struct pool *pool;       /* renders (not owned); NULL: no pictures */
    void (*ready)(void *ud); /* a render ended: ask again */
    void *ud;
};

struct pictures;

/* NULL with err set (SF_ENOMEM). */
struct pictures *pictures_new(const struct pictures_config *cfg, struct sf_err *err);
void pictures_free(struct pictures *p);

/* What job j's picture shows: the part file's sha (after: the shaped part
   if the job has one, else the upload) and the overhang angle, degrees. */
void pictures_what(const struct job_row *j, bool after, const char **sha, double *angle_deg);

/* How a picture stands. */
enum pictures_state {
    PICTURES_READY,   /* *png holds a copy (free() it), *len bytes */
    PICTURES_PENDING, /* rendering: ask again after ready() */
    PICTURES_FAILED,  /* it could not be made; err says why (the next ask tries again) */
    PICTURES_BUSY,    /* every slot is rendering: try again in a while */
    PICTURES_NONE,    /* no pool to render on */
};

/*
 * Job j's picture (after: as it prints); starts its render when it is not
 * kept (the part's path is looked up on the worker: a lookup that fails
 * fails the render).  Returns SF_OK with *state, or a failure (SF_ENOMEM,
 * the pool's) with err set.
 */
int pictures_get(struct pictures *p, const struct job_row *j, bool after,
                 enum pictures_state *state, unsigned char **png, size_t *len, struct sf_err *err);

/*
 * The picture that job j's pictures_get named by key (pictures_key) once
 * it is no longer rendering: PICTURES_READY with a copy in *png (free() it),
 * PICTURES_PENDING, or PICTURES_FAILED (failed, evicted, or out of memory).
 */
enum pictures_state pictures_take(struct pictures *p, const char *key, unsigned char **png,
                                  size_t *len);

/* The cache key of job j's picture (what it shows), into key. */
void pictures_key(const struct job_row *j, bool after, char key[PICTURES_KEY_MAX]);

/*
 * The support model's grams and seconds for the part job j's picture shows,
 * known once that picture was rendered; false before then or if the model
 * failed.
 */
bool pictures_support(struct pictures *p, const struct job_row *j, bool after, double *grams,
                      double *seconds);

#endif
