/*
 * sim_netbase.c - the machine, server and watch timer an HTTP printer
 * simulator is built on (sim_netbase.h).
 *
 * The watch timer re-arms itself before it calls the simulator, so a
 * simulator may fail or cancel the job from its watch and still be
 * watched on the next tick.  Uploads land in the machine's folder: the
 * server is made after the machine and told where that is.
 *
 * Thread: the loop thread.
 */
#include "sim_netbase.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/base/mem.h"

static void
on_tick(struct loop *l, void *ud)
{
    struct sim_netbase *b = ud;
    b->watch = loop_timer_add(l, b->watch_ms, on_tick, b);
    b->on_watch(b->ud);
}

void *
sim_netbase_alloc(size_t size, const char *kind, struct sf_err *err)
{
    void *sim = mem_calloc(1, size);
    if (!sim)
        sf_err_set(err, SF_ENOMEM, "%s sim: out of memory", kind);
    return sim;
}

int
sim_netbase_init(struct sim_netbase *b, struct loop *l, const struct sim_netprinter_config *machine,
                 struct sim_http_config *hc, int watch_ms, sim_netbase_watch_fn on_watch,
                 struct sf_err *err)
{
    struct sf_err local = { 0 };
    if (!err)
        err = &local; /* for the code to return */
    memset(b, 0, sizeof(*b));
    b->l = l;
    b->watch_ms = watch_ms;
    b->on_watch = on_watch;
    b->ud = hc->ud;
    b->np = sim_netprinter_new(l, machine, err);
    if (!b->np)
        return err->code < 0 ? err->code : SF_EIO;
    hc->upload_dir = sim_netprinter_uploads(b->np);
    b->http = sim_http_new(l, hc, err);
    if (!b->http)
        return err->code < 0 ? err->code : SF_EIO;
    b->watch = loop_timer_add(l, watch_ms, on_tick, b);
    return SF_OK;
}

void
sim_netbase_release(struct sim_netbase *b)
{
    if (b->watch)
        loop_timer_cancel(b->l, b->watch);
    sim_ws_hub_free(b->hub); /* its sockets came through the server: before it */
    sim_http_free(b->http);
    sim_netprinter_free(b->np);
    memset(b, 0, sizeof(*b));
}

void
sim_netbase_free(void *sim)
{
    if (!sim)
        return;
    sim_netbase_release(sim);
    free(sim);
}

int
sim_netbase_port(const struct sim_netbase *b)
{
    return sim_http_port(b->http);
}

void
sim_netbase_status(const struct sim_netbase *b, struct sim_np_status *out)
{
    sim_netprinter_status(b->np, out);
}

static struct sim_netprinter *
face_machine(void *sim)
{
    return ((struct sim_netbase *)sim)->np;
}

static struct sim_http *
face_http(void *sim)
{
    return ((struct sim_netbase *)sim)->http;
}

static struct sim_ws_hub *
face_hub(void *sim)
{
    return ((struct sim_netbase *)sim)->hub;
}

int
sim_netbase_main(int argc, char **argv, const char *extra,
                 void *(*create)(struct loop *l, const struct sim_net_opts *o, int index,
                                 struct sf_err *err))
{
    struct sim_net_opts o;
    int rc = sim_net_parse(argc, argv, &o, extra);
    if (rc >= 0)
        return rc;
    struct sim_net_face face = {
        .create = create,
        .destroy = sim_netbase_free,
        .machine = face_machine,
        .http = face_http,
        .hub = face_hub,
    };
    return sim_net_serve(&o, &face);
}

const char *
sim_netbase_fault_arg(const char *spec, const char *name)
{
    const char *eq = strchr(spec, '=');
    size_t n = eq ? (size_t)(eq - spec) : strlen(spec);
    if (n != strlen(name) || strncmp(spec, name, n) != 0)
        return NULL;
    return eq ? eq + 1 : "";
}

int
sim_netbase_fault_count(const char *spec, const char *v, long *out, struct sf_err *err)
{
    char *end;
    errno = 0;
    long n = strtol(v, &end, 10);
    if (errno || end == v || *end || n < 1 || n > 1000000000L)
        return sf_err_set(err, SF_EINVAL, "fault '%s': expected a whole number from 1", spec);
    *out = n;
    return SF_OK;
}
