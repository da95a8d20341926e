/*
 * pictures.c - the pictures of a job, rendered on the worker pool and kept
 * by what they show (see pictures.h).
 *
 * Why in the farm: a picture is the farm's knowledge of a job (which part
 * file it prints, at which overhang angle, what support that needs), made
 * with the same geometry and slicer code as the job; the dashboard only
 * serves what this returns.  A task owns its own data; pictures_free cuts
 * its link to us, and done() of a task whose cache is gone only frees it.
 *
 * The part's path is looked up on the worker, on a reader of its own
 * (store_open_reader, as a preparation's files are: farm_files.c): on a
 * shared store a part this host's cache lacks comes whole from the
 * database first, and even a cached one is a round trip the loop's own
 * connection must not make (issue 32).  A lookup that fails fails the
 * render (its why logged and given to the next ask).
 *
 * Thread: the loop thread; render_work() on a pool worker.
 */
#include "pictures.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "../../slicer/preview.h"
#include "../base/buf.h"
#include "../base/log.h"
#include "../base/mem.h"
#include "../geom/supmodel.h"
#include "../mesh/mesh.h"

enum render_state { R_FREE, R_PENDING, R_READY, R_FAILED };

/* One picture, cached by what it shows. */
struct render {
    enum render_state state;
    char key[PICTURES_KEY_MAX]; /* "SHA@ANGLE" */
    unsigned char *png;         /* R_READY */
    size_t len;
    uint64_t used;            /* LRU stamp */
    char why[SF_ERR_MSG_MAX]; /* R_FAILED */
    double support_g;         /* R_READY: the support model's grams for it, -1 if it failed */
    double support_s;         /* and seconds */
};

/* A render on the pool: its own copies of everything. */
struct task {
    struct pictures *p;        /* NULL once pictures_free ran */
    const struct store *store; /* for the worker's reader (store_open_reader) */
    int64_t job_id;            /* the job whose part it is (its lookup's errors) */
    char sha[STORE_SHA_HEX];   /* the part */
    char key[PICTURES_KEY_MAX];
    char path[1100]; /* the stored part, once looked up */
    double angle_deg;
    unsigned char *png;
    size_t len;
    double support_g, support_s; /* supmodel_of_mesh, PrusaSlicer's rules; -1 if it failed */
    struct sf_err err;
    struct task *next; /* in p->tasks */
};

struct pictures {
    struct pictures_config cfg;
    struct render renders[PICTURES_MAX];
    uint64_t stamp;
    struct task *tasks;
};

static struct render *
render_find(struct pictures *p, const char *key)
{
    for (size_t i = 0; i < PICTURES_MAX; i++)
        if (p->renders[i].state != R_FREE && strcmp(p->renders[i].key, key) == 0)
            return &p->renders[i];
    return NULL;
}

/* A slot for a new render: a free one, else the least recently used
   finished one; NULL when every slot is rendering. */
static struct render *
render_slot(struct pictures *p)
{
    struct render *best = NULL;
    for (size_t i = 0; i < PICTURES_MAX; i++) {
        struct render *r = &p->renders[i];
        if (r->state == R_FREE)
            return r;
        if (r->state != R_PENDING && (!best || r->used < best->used))
            best = r;
    }
    if (best) {
        free(best->png);
        memset(best, 0, sizeof(*best));
    }
    return best;
}

/* The part's path into t->path, on the worker's own reader. */
static int
render_lookup(struct task *t)
{
    struct store *r = store_open_reader(t->store, &t->err);
    int rc = r ? store_file_path(r, t->sha, t->path, sizeof(t->path), &t->err) : t->err.code;
    store_close(r);
    if (rc)
        sf_err_prefix(&t->err, "job %lld", (long long)t->job_id);
    return rc;
}

static int
render_work(void *ud, const atomic_bool *cancel)
{
    struct task *t = ud;
    struct mesh m;
    mesh_init(&m);
    char png[64] = "";
    int rc = render_lookup(t);
    if (rc == SF_OK)
        rc = mesh_load(t->path, &m, NULL, &t->err);
    if (rc == SF_OK && atomic_load(cancel))
        rc = sf_err_set(&t->err, SF_ECANCELED, "cancelled");
    if (rc == SF_OK) {
        const char *dir = getenv("TMPDIR");
        snprintf(png, sizeof(png), "%.40s/sfpreview.XXXXXX", dir && *dir ? dir : "/tmp");
        int fd = mkstemp(png);
        if (fd < 0) {
            rc = sf_err_sys(&t->err, "preview: temporary file in %s", png);
            png[0] = '\0';
        } else {
            close(fd);
        }
    }
    if (rc == SF_OK) {
        struct preview_opts po;
        preview_opts_default(&po);
        po.width_px = PICTURES_W_PX;
        po.height_px = PICTURES_H_PX;
        po.angle_deg = t->angle_deg;
        rc = preview_part(&m, &po, png, &t->err);
    }
    if (rc == SF_OK) {
        struct buf b;
        buf_init(&b, 64 << 20);
        rc = buf_read_file(&b, png, &t->err);
        if (rc == SF_OK)
            t->png = (unsigned char *)buf_take(&b, &t->len);
        buf_release(&b);
    }
    if (png[0])
        unlink(png);
    /* what this part needs in support, as it stands on the bed (+z): the
       same model orientation and slimming rank by (supmodel.h) */
    t->support_g = t->support_s = -1;
    struct supmodel_params sp;
    struct supmodel_result sr;
    struct sf_err serr;
    supmodel_params_steer(&sp, t->angle_deg);
    if (rc == SF_OK && !atomic_load(cancel) &&
        supmodel_of_mesh(&m, (struct vec3){ 0, 0, 1 }, &sp, &sr, &serr) == SF_OK) {
        t->support_g = sr.grams;
        t->support_s = sr.time_s;
    }
    mesh_release(&m);
    return rc;
}

static void
render_done(struct loop *l, void *ud, int rc)
{
    (void)l;
    struct task *t = ud;
    struct pictures *p = t->p;
    if (p) {
        for (struct task **pp = &p->tasks; *pp; pp = &(*pp)->next)
            if (*pp == t) {
                *pp = t->next;
                break;
            }
        struct render *r = render_find(p, t->key);
        if (r && r->state == R_PENDING) {
            if (rc == SF_OK && t->png) {
                r->state = R_READY;
                r->png = t->png;
                r->len = t->len;
                r->support_g = t->support_g;
                r->support_s = t->support_s;
                t->png = NULL;
            } else {
                r->state = R_FAILED;
                snprintf(r->why, sizeof(r->why), "%s",
                         rc == SF_ECANCELED ? "cancelled" : t->err.msg);
                log_warn("web", "preview %s: %s", t->key, r->why);
            }
        }
        if (p->cfg.ready)
            p->cfg.ready(p->cfg.ud);
    }
    free(t->png);
    free(t);
}

void
pictures_what(const struct job_row *j, bool after, const char **sha, double *angle_deg)
{
    *sha = after && j->mesh_sha[0] ? j->mesh_sha : j->file_sha;
    *angle_deg = j->opts.overhang_deg > 0 ? j->opts.overhang_deg : 45;
}

/* The cache key of a job's picture: what it shows (after: the part as it
   prints, oriented and shaped; a job that kept its part, or is not
   prepared yet, shows the upload) and the angle its risky faces are for. */
void
pictures_key(const struct job_row *j, bool after, char key[PICTURES_KEY_MAX])
{
    const char *sha;
    double angle;
    pictures_what(j, after, &sha, &angle);
    snprintf(key, PICTURES_KEY_MAX, "%.64s@%g", sha, angle);
}

/* A copy of r's PNG into *png, *len; false when out of memory. */
static bool
copy_png(const struct render *r, unsigned char **png, size_t *len)
{
    if (!(*png = mem_alloc(r->len)))
        return false;
    memcpy(*png, r->png, r->len);
    *len = r->len;
    return true;
}

/* Start rendering key (job j's part at sha and angle) into a new slot. */
static int
render_start(struct pictures *p, const struct job_row *j, const char *key, const char *sha,
             double angle, enum pictures_state *state, struct sf_err *err)
{
    struct task *t = p->cfg.pool ? mem_calloc(1, sizeof(*t)) : NULL;
    if (!t) {
        *state = PICTURES_NONE;
        return SF_OK;
    }
    struct render *r = render_slot(p);
    if (!r) {
        free(t);
        *state = PICTURES_BUSY;
        return SF_OK;
    }
    t->p = p;
    t->store = p->cfg.store;
    t->job_id = j->id;
    snprintf(t->sha, sizeof(t->sha), "%s", sha);
    snprintf(t->key, sizeof(t->key), "%s", key);
    t->angle_deg = angle;
    if (!pool_submit(p->cfg.pool, render_work, render_done, t, err)) {
        free(t);
        return err && err->code ? err->code : SF_EIO;
    }
    t->next = p->tasks;
    p->tasks = t;
    r->state = R_PENDING;
    snprintf(r->key, sizeof(r->key), "%s", key);
    r->used = ++p->stamp;
    *state = PICTURES_PENDING;
    return SF_OK;
}

int
pictures_get(struct pictures *p, const struct job_row *j, bool after, enum pictures_state *state,
             unsigned char **png, size_t *len, struct sf_err *err)
{
    const char *sha;
    double angle;
    char key[PICTURES_KEY_MAX];
    pictures_what(j, after, &sha, &angle);
    pictures_key(j, after, key);
    struct render *r = render_find(p, key);
    if (!r)
        return render_start(p, j, key, sha, angle, state, err);
    if (r->state == R_FAILED) {
        *state = PICTURES_FAILED;
        sf_err_set(err, SF_EIO, "%s", r->why);
        r->state = R_FREE; /* the next request tries again */
        return SF_OK;
    }
    r->used = ++p->stamp;
    *state = r->state == R_READY ? PICTURES_READY : PICTURES_PENDING;
    if (r->state == R_READY && !copy_png(r, png, len))
        return sf_err_set(err, SF_ENOMEM, "out of memory");
    return SF_OK;
}

enum pictures_state
pictures_take(struct pictures *p, const char *key, unsigned char **png, size_t *len)
{
    struct render *r = render_find(p, key);
    if (r && r->state == R_PENDING)
        return PICTURES_PENDING;
    if (!r || r->state != R_READY || !copy_png(r, png, len))
        return PICTURES_FAILED;
    return PICTURES_READY;
}

bool
pictures_support(struct pictures *p, const struct job_row *j, bool after, double *grams,
                 double *seconds)
{
    char key[PICTURES_KEY_MAX];
    pictures_key(j, after, key);
    struct render *r = render_find(p, key);
    if (!r || r->state != R_READY || r->support_g < 0)
        return false;
    *grams = r->support_g;
    *seconds = r->support_s;
    return true;
}

struct pictures *
pictures_new(const struct pictures_config *cfg, struct sf_err *err)
{
    struct pictures *p = mem_calloc(1, sizeof(*p));
    if (p)
        p->cfg = *cfg;
    else
        sf_err_set(err, SF_ENOMEM, "pictures: out of memory");
    return p;
}

void
pictures_free(struct pictures *p)
{
    if (!p)
        return;
    for (struct task *t = p->tasks; t; t = t->next)
        t->p = NULL; /* its done() frees it alone */
    for (size_t i = 0; i < PICTURES_MAX; i++)
        free(p->renders[i].png);
    free(p);
}
