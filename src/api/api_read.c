/*
 * api_read.c - store reads on a reader thread, answers on the loop (see
 * api_read.h).  A read is a pool task (src/base/pool.h) on a pool of one
 * thread: work() runs the read on the reader's connection into the
 * task's response; done() runs on the loop, adds the loop's part and
 * answers the deferred request.
 *
 * Thread: see api_read.h.
 */
#include "api_read.h"

#include <stdlib.h>

#include "../base/mem.h"
#include "../base/pool.h"

struct api_read {
    struct store *s;      /* the loop's store (reads that cannot be deferred) */
    struct store *reader; /* the reader thread's connection; NULL: reads run on the loop */
    struct pool *pool;    /* one thread; NULL with reader */
};

struct task {
    struct api_read *r;
    api_read_job_fn job;    /* api_read_post's read, or NULL */
    api_read_done_fn jdone; /* and its done */
    struct http_defer *d;   /* the waiting request */
    api_read_fn read;
    api_read_finish_fn finish;
    void *ud;
    void (*ud_free)(void *ud);
    struct http_resp resp; /* read's answer */
};

struct api_read *
api_read_new(struct loop *l, struct store *s, struct sf_err *err)
{
    struct api_read *r = mem_calloc(1, sizeof(*r));
    if (!r) {
        sf_err_set(err, SF_ENOMEM, "api: out of memory");
        return NULL;
    }
    r->s = s;
    if (!l)
        return r;
    if (!(r->reader = store_open_reader(s, err)) || !(r->pool = pool_new(l, 1, err))) {
        api_read_free(r);
        return NULL;
    }
    return r;
}

void
api_read_free(struct api_read *r)
{
    if (!r)
        return;
    /* Queued reads are answered (503) and freed now; a read running is
       awaited, its answer posted to the loop and dropped there (its
       request is gone with the server, http.h). */
    pool_free(r->pool);
    store_close(r->reader);
    free(r);
}

static int
work(void *ud, const atomic_bool *cancel)
{
    struct task *t = ud;
    if (atomic_load(cancel))
        return SF_ECANCELED;
    if (t->job) {
        t->job(t->r->reader, t->ud);
        return SF_OK;
    }
    t->read(t->r->reader, t->ud, &t->resp);
    return SF_OK;
}

static void
resp_drop(struct http_resp *resp)
{
    json_decref(resp->json);
    if (resp->body_free)
        resp->body_free((void *)resp->body);
    *resp = (struct http_resp){ .status = 200 };
}

static void
done_task(struct loop *l, void *ud, int rc)
{
    (void)l;
    struct task *t = ud;
    if (t->job) {
        t->jdone(t->ud, rc == SF_OK);
        free(t);
        return;
    }
    if (rc != SF_OK) {
        resp_drop(&t->resp);
        http_error(&t->resp, 503, "the daemon is stopping");
    } else if (t->finish && http_defer_alive(t->d)) {
        t->finish(t->ud, &t->resp);
    }
    http_defer_answer(t->d, &t->resp); /* frees the answer if the client left; wakes the server */
    if (t->ud_free)
        t->ud_free(t->ud);
    free(t);
}

void
api_read_run(struct api_read *r, struct http_resp *resp, api_read_fn read,
             api_read_finish_fn finish, void *ud, void (*ud_free)(void *ud))
{
    struct task *t = r->pool ? mem_calloc(1, sizeof(*t)) : NULL;
    struct http_defer *d = t ? http_defer(resp) : NULL;
    if (d) {
        *t = (struct task){ .r = r,
                            .d = d,
                            .read = read,
                            .finish = finish,
                            .ud = ud,
                            .ud_free = ud_free,
                            .resp = { .status = 200 } };
        if (pool_submit(r->pool, work, done_task, t, NULL))
            return;
        /* not queued: answer now after all (http_defer's handle is a plain
           allocation until the route returns it) */
        free(resp->defer);
        resp->defer = NULL;
    }
    free(t);
    read(r->s, ud, resp);
    if (finish)
        finish(ud, resp);
    if (ud_free)
        ud_free(ud);
}

bool
api_read_post(struct api_read *r, api_read_job_fn read, api_read_done_fn done, void *ud)
{
    if (!r->pool) {
        read(r->s, ud);
        done(ud, true);
        return true;
    }
    struct task *t = mem_calloc(1, sizeof(*t));
    if (!t)
        return false;
    *t = (struct task){ .r = r, .job = read, .jdone = done, .ud = ud };
    if (pool_submit(r->pool, work, done_task, t, NULL))
        return true;
    free(t);
    return false;
}
