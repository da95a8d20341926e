/*
 * test_wsc.c - the websocket client (drivers/net/wsc.h) against the
 * Moonraker simulator's /websocket over loopback: the handshake, a
 * JSON-RPC round trip, a refused handshake, a refused connection, the
 * URLs it leaves to polling, and the owner freeing it from a callback.
 */
#include <string.h>

#include "../../drivers/net/wsc.h"
#include "../../sim/net/sim_moonraker.h"
#include "../t.h"

struct seen {
    int opened, texts, closed;
    char last[512];
    char why[256];
    struct wsc *w; /* freed in closed() when free_in_cb */
    bool free_in_cb;
};

static void
c_open(struct wsc *w, void *ud)
{
    struct seen *s = ud;
    s->opened++;
    const char req[] = "{\"jsonrpc\":\"2.0\",\"method\":\"server.info\",\"id\":7}";
    wsc_send(w, req, sizeof(req) - 1);
}

static void
c_text(struct wsc *w, const char *text, size_t len, void *ud)
{
    (void)w;
    struct seen *s = ud;
    s->texts++;
    snprintf(s->last, sizeof(s->last), "%.*s", (int)len, text);
}

static void
c_closed(struct wsc *w, const char *why, void *ud)
{
    struct seen *s = ud;
    s->closed++;
    snprintf(s->why, sizeof(s->why), "%s", why);
    if (s->free_in_cb) {
        wsc_free(w);
        s->w = NULL;
    }
}

static const struct wsc_ops ops = { c_open, c_text, c_closed };

static bool
run_until(struct loop *l, const int *counter)
{
    for (int i = 0; i < 400 && *counter == 0; i++)
        loop_run_once(l, 50);
    return *counter > 0;
}

struct fx {
    struct loop *l;
    struct sim_moonraker *mr;
    char url[64];
};

static int
fx_start(struct fx *f, struct sf_err *err)
{
    memset(f, 0, sizeof(*f));
    f->l = loop_new(err);
    if (!f->l)
        return SF_EIO;
    struct sim_moonraker_config c;
    sim_moonraker_config_init(&c);
    f->mr = sim_moonraker_new(f->l, &c, err);
    if (!f->mr)
        return SF_EIO;
    snprintf(f->url, sizeof(f->url), "http://127.0.0.1:%d", sim_moonraker_port(f->mr));
    return SF_OK;
}

static void
fx_stop(struct fx *f)
{
    sim_moonraker_free(f->mr);
    loop_free(f->l);
}

T_CASE(wsc_round_trip_with_moonraker)
{
    struct fx f;
    struct sf_err err;
    T_OK(fx_start(&f, &err), &err);
    struct seen s = { 0 };
    struct wsc *w = wsc_new(f.l, f.url, NULL, "/websocket", "X-Test: 1\r\n", &ops, &s, &err);
    T_TRUE(w != NULL);
    T_TRUE(run_until(f.l, &s.texts));
    T_EQ_INT(s.opened, 1);
    T_TRUE(strstr(s.last, "\"id\":7") && strstr(s.last, "\"klippy_state\":\"ready\""));
    T_EQ_INT(s.closed, 0);
    wsc_free(w);
    /* the address a poll reached, for a URL whose host is a name */
    char named[80];
    snprintf(named, sizeof(named), "http://printer.invalid:%d", sim_moonraker_port(f.mr));
    struct seen s2 = { 0 };
    w = wsc_new(f.l, named, "127.0.0.1", "/websocket", NULL, &ops, &s2, &err);
    T_TRUE(w != NULL);
    T_TRUE(run_until(f.l, &s2.texts));
    wsc_free(w);
    fx_stop(&f);
}

T_CASE(wsc_refusals_close_with_the_reason)
{
    struct fx f;
    struct sf_err err;
    T_OK(fx_start(&f, &err), &err);
    /* a path with no socket: the server's status line is the reason; freed in the callback */
    struct seen s = { .free_in_cb = true };
    s.w = wsc_new(f.l, f.url, NULL, "/no-socket-here", NULL, &ops, &s, &err);
    T_TRUE(s.w != NULL);
    T_TRUE(run_until(f.l, &s.closed));
    T_TRUE(strstr(s.why, "refused: HTTP/1.1 404") != NULL);
    T_EQ_INT(s.opened, 0);
    T_TRUE(s.w == NULL);
    /* nobody listening */
    char gone[64];
    int port = sim_moonraker_port(f.mr);
    sim_moonraker_free(f.mr);
    f.mr = NULL;
    snprintf(gone, sizeof(gone), "http://127.0.0.1:%d", port);
    struct seen s2 = { 0 };
    struct wsc *w = wsc_new(f.l, gone, NULL, "/websocket", NULL, &ops, &s2, &err);
    if (w) { /* (connect may fail at once or on the loop) */
        T_TRUE(run_until(f.l, &s2.closed));
        T_TRUE(strstr(s2.why, "connect") != NULL);
        wsc_free(w);
    } else {
        T_TRUE(strstr(err.msg, "connect") != NULL);
    }
    fx_stop(&f);
}

T_CASE(wsc_leaves_what_it_cannot_reach_to_polling)
{
    struct loop *l = loop_new(NULL);
    struct sf_err err;
    struct seen s = { 0 };
    T_TRUE(wsc_new(l, "https://127.0.0.1:7125", NULL, "/websocket", NULL, &ops, &s, &err) == NULL);
    T_ERR(err.code, SF_EUNSUPP, &err, "only http://");
    T_TRUE(wsc_new(l, "http://voron.local:7125", NULL, "/websocket", NULL, &ops, &s, &err) == NULL);
    T_ERR(err.code, SF_EUNSUPP, &err, "no IP address");
    T_TRUE(wsc_new(l, "http://127.0.0.1:99999", NULL, "/websocket", NULL, &ops, &s, &err) == NULL);
    T_ERR(err.code, SF_EUNSUPP, &err, "bad port");
    loop_free(l);
}
