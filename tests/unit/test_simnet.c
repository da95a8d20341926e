/*
 * test_simnet.c - the shared core of the simulated network printers:
 * sim_netprinter streams an uploaded file to its simulated Marlin so that
 * the executed log holds the file's commands once each, in order; pause,
 * resume and cancel (the cancel script after the prefix), busy refusals,
 * file name checks, a printer fault, a job held by its firmware's hold
 * fault (printing, standing) until released.  sim_http serves routes on the loop
 * to our own HTTP client (httpc): JSON, a multipart upload kept byte for
 * byte, a wrong key, the 5xx, slow and drop-upload faults.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "../../drivers/net/httpc.h"
#include "../../sim/net/sim_http.h"
#include "../../sim/net/sim_netprinter.h"
#include "../../sim/net/sim_octoprint_int.h"
#include "../../src/base/buf.h"
#include "../t.h"

static double
wall_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec / 1e9;
}

static enum sim_np_state
state_of(struct sim_netprinter *np)
{
    struct sim_np_status st;
    sim_netprinter_status(np, &st);
    return st.state;
}

/* Turn the loop until np reaches state want (bounded by the wall clock). */
static bool
wait_state(struct loop *l, struct sim_netprinter *np, enum sim_np_state want)
{
    double end = wall_s() + 60;
    while (state_of(np) != want && wall_s() < end)
        loop_run_once(l, 20);
    struct sim_np_status st;
    sim_netprinter_status(np, &st);
    if (st.state != want)
        printf("# printer is %s, not %s: %s (%llu/%llu lines)\n", sim_np_state_name(st.state),
               sim_np_state_name(want), st.message, (unsigned long long)st.lines_done,
               (unsigned long long)st.lines_total);
    return st.state == want;
}

static void
write_job(struct sim_netprinter *np, const char *name, int moves)
{
    char path[1024];
    T_OK(sim_netprinter_path(np, name, path, sizeof(path), NULL), NULL);
    FILE *f = fopen(path, "w");
    fprintf(f, "; a test job\nM104 S200\nM140 S60\nG28\nG90\nM82\nG92 E0\n");
    for (int i = 0; i < moves; i++)
        fprintf(f, "G1 X%d.5 Y%d E%d.1 F3000 ; move %d\n\n", 10 + i % 50, 20 + i % 40, i, i);
    fprintf(f, "M104 S0\nM140 S0\nM84\n");
    fclose(f);
}

/* The log's lines, minus host queries (M110, M105, M400), joined by '\n'. */
static void
read_log(const char *path, struct buf *out)
{
    buf_init(out, 0);
    FILE *f = fopen(path, "r");
    char line[256];
    while (f && fgets(line, sizeof(line), f)) {
        if (strncmp(line, "M110", 4) == 0 || strncmp(line, "M105", 4) == 0 ||
            strncmp(line, "M400", 4) == 0)
            continue;
        buf_append(out, line, strlen(line));
    }
    if (f)
        fclose(f);
}

static struct sim_netprinter *
machine(struct loop *l, const char *log_name, char *log_path, size_t n)
{
    struct sim_netprinter_config c;
    sim_netprinter_config_init(&c);
    c.speed = 1000;
    snprintf(log_path, n, "%s/%s", t_tmpdir(), log_name);
    c.log_path = log_path;
    struct sf_err err;
    struct sim_netprinter *np = sim_netprinter_new(l, &c, &err);
    if (!np)
        printf("# %s\n", err.msg);
    return np;
}

T_CASE(job_runs_every_line_once_in_order)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    char log[512];
    struct sim_netprinter *np = machine(l, "run.log", log, sizeof(log));
    T_TRUE(np != NULL);
    write_job(np, "a.gcode", 200);
    T_EQ_INT(sim_netprinter_file_size(np, "a.gcode") > 0, 1);
    T_EQ_INT(sim_netprinter_file_size(np, "nope.gcode"), -1);
    T_ERR(sim_netprinter_start(np, "nope.gcode", &err), SF_ENOTFOUND, &err, "nope.gcode");
    T_OK(sim_netprinter_start(np, "a.gcode", &err), &err);
    T_ERR(sim_netprinter_start(np, "a.gcode", &err), SF_EAGAIN, &err, "busy");
    T_TRUE(sim_netprinter_file_busy(np, "a.gcode"));
    T_TRUE(wait_state(l, np, SIM_NP_COMPLETE));
    struct sim_np_status st;
    sim_netprinter_status(np, &st);
    T_EQ_INT(st.lines_total, 209);
    T_EQ_INT(st.lines_done, 209);
    T_EQ_INT(st.file_pos, st.file_size);
    T_EQ_DBL(st.progress, 1.0, 1e-9);
    T_EQ_DBL(st.time_left_s, 0, 1e-9);
    T_EQ_STR(st.file, "a.gcode");
    sim_netprinter_free(np);

    struct buf got;
    read_log(log, &got);
    struct buf want;
    buf_init(&want, 0);
    buf_printf(&want, "M104 S200\nM140 S60\nG28\nG90\nM82\nG92 E0\n");
    for (int i = 0; i < 200; i++)
        buf_printf(&want, "G1 X%d.5 Y%d E%d.1 F3000\n", 10 + i % 50, 20 + i % 40, i);
    buf_printf(&want, "M104 S0\nM140 S0\nM84\n");
    T_EQ_STR(got.data, want.data);
    buf_release(&got);
    buf_release(&want);
    loop_free(l);
}

/*
 * A network printer's firmware with the hold fault (faults.h hold=PATH):
 * while PATH exists the job stands at its first printing move, printing,
 * lines_done standing (the firmware's busy keeps its host patient); once
 * PATH is removed it runs to its end, every line once, in order.
 */
T_CASE(hold_fault_holds_a_job_until_released)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    char log[512], hold[512], spec[600];
    snprintf(log, sizeof(log), "%s/hold.log", t_tmpdir());
    snprintf(hold, sizeof(hold), "%s/hold", t_tmpdir());
    snprintf(spec, sizeof(spec), "hold=%s", hold);
    FILE *f = fopen(hold, "w");
    T_TRUE(f != NULL);
    if (f)
        fclose(f);
    struct sim_netprinter_config c;
    sim_netprinter_config_init(&c);
    c.speed = 1000;
    c.log_path = log;
    T_OK(faults_parse(&c.faults, spec, &err), &err);
    struct sim_netprinter *np = sim_netprinter_new(l, &c, &err);
    T_TRUE(np != NULL);
    if (!np)
        return;
    write_job(np, "h.gcode", 200);
    T_OK(sim_netprinter_start(np, "h.gcode", &err), &err);
    double end = wall_s() + 60;
    while (!t_slurp(hold)[0] && wall_s() < end)
        loop_run_once(l, 20);
    T_EQ_STR(t_slurp(hold), "held: G1 X10.5 Y20 E0.1 F3000\n");
    struct sim_np_status st;
    sim_netprinter_status(np, &st);
    uint64_t done = st.lines_done;
    T_TRUE(done >= 6 && done < 10);
    end = wall_s() + 3;
    while (wall_s() < end)
        loop_run_once(l, 20);
    sim_netprinter_status(np, &st);
    T_EQ_INT(st.state, SIM_NP_PRINTING);
    T_EQ_INT(st.lines_done, done);
    unlink(hold);
    T_TRUE(wait_state(l, np, SIM_NP_COMPLETE));
    sim_netprinter_status(np, &st);
    T_EQ_INT(st.lines_done, 209);
    sim_netprinter_free(np);
    struct buf got;
    read_log(log, &got);
    struct buf want;
    buf_init(&want, 0);
    buf_printf(&want, "M104 S200\nM140 S60\nG28\nG90\nM82\nG92 E0\n");
    for (int i = 0; i < 200; i++)
        buf_printf(&want, "G1 X%d.5 Y%d E%d.1 F3000\n", 10 + i % 50, 20 + i % 40, i);
    buf_printf(&want, "M104 S0\nM140 S0\nM84\n");
    T_EQ_STR(got.data, want.data);
    buf_release(&got);
    buf_release(&want);
    loop_free(l);
}

T_CASE(pause_resume_cancel_and_commands)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    char log[512];
    struct sim_netprinter *np = machine(l, "cancel.log", log, sizeof(log));
    T_TRUE(np != NULL);
    write_job(np, "b.gcode", 3000);
    T_ERR(sim_netprinter_pause(np, &err), SF_EAGAIN, &err, "cannot pause");
    T_OK(sim_netprinter_start(np, "b.gcode", &err), &err);
    for (int i = 0; i < 50; i++)
        loop_run_once(l, 5);
    T_OK(sim_netprinter_pause(np, &err), &err);
    T_TRUE(wait_state(l, np, SIM_NP_PAUSED));
    struct sim_np_status a, b;
    sim_netprinter_status(np, &a);
    for (int i = 0; i < 20; i++)
        loop_run_once(l, 5);
    sim_netprinter_status(np, &b);
    T_EQ_INT(a.lines_done, b.lines_done); /* nothing sent while paused */
    T_TRUE(a.lines_done < a.lines_total);
    T_OK(sim_netprinter_command(np, "M117 hello ; a note", &err), &err);
    T_ERR(sim_netprinter_command(np, "; only a comment", &err), SF_EINVAL, &err, "empty");
    T_OK(sim_netprinter_resume(np, &err), &err);
    /* Job lines move again only after the queued note went out (manual
       commands go before the next job line): wait for that, not for a time. */
    for (double end = wall_s() + 60; wall_s() < end;) {
        sim_netprinter_status(np, &b);
        if (b.lines_done > a.lines_done + 2)
            break;
        loop_run_once(l, 5);
    }
    T_TRUE(b.lines_done > a.lines_done + 2);
    T_OK(sim_netprinter_cancel(np, &err), &err);
    T_TRUE(wait_state(l, np, SIM_NP_CANCELLED));
    sim_netprinter_status(np, &b);
    T_TRUE(b.lines_done < b.lines_total);
    T_EQ_INT(sim_netprinter_file_busy(np, "b.gcode"), 0);
    /* A new job may start after a cancel; a printer fault ends it in error. */
    T_OK(sim_netprinter_start(np, "b.gcode", &err), &err);
    sim_netprinter_fail(np, "Thermal runaway (simulated)");
    T_EQ_INT(state_of(np), SIM_NP_ERROR);
    T_ERR(sim_netprinter_start(np, "b.gcode", &err), SF_EAGAIN, &err, "Thermal runaway");
    sim_netprinter_reset(np);
    T_EQ_INT(state_of(np), SIM_NP_IDLE);
    char path[1024];
    T_ERR(sim_netprinter_path(np, "a/../../etc/passwd", path, sizeof(path), &err), SF_EINVAL, &err,
          "'/'");
    T_ERR(sim_netprinter_path(np, ".hidden", path, sizeof(path), &err), SF_EINVAL, &err, "'.'");
    sim_netprinter_free(np);

    /* The log: the first lines_done job commands, the note, then the cancel script last. */
    struct buf got;
    read_log(log, &got);
    T_TRUE(strstr(got.data, "M117 hello\n") != NULL);
    size_t n = strlen(got.data);
    const char *tail = "M104 S0\nM140 S0\nM107\nM84\n";
    T_TRUE(n > strlen(tail) && strcmp(got.data + n - strlen(tail), tail) == 0);
    buf_release(&got);
    loop_free(l);
}

/* ---- sim_http ---- */

struct server {
    char dir[512];
    int hits;
};

static void
h_hello(struct sim_http_req *r, void *ud)
{
    struct server *s = ud;
    s->hits++;
    sim_http_reply_json(r, 200, json_pack("{s:s,s:s}", "api", "0.1", "text", "OctoPrint 1.10.0"));
}

static void
h_echo_json(struct sim_http_req *r, void *ud)
{
    (void)ud;
    struct sf_err err;
    json_t *j = sim_http_json(r, &err);
    if (!j) {
        sim_http_reply_error(r, 400, err.msg);
        return;
    }
    json_object_set_new(j, "path_rest", json_string(sim_http_rest(r)));
    sim_http_reply_json(r, 200, j);
}

static void
h_upload(struct sim_http_req *r, void *ud)
{
    struct server *s = ud;
    const struct sim_http_file *f = sim_http_upload(r);
    if (!f) {
        sim_http_reply_error(r, 400, "No file included");
        return;
    }
    char path[1024];
    snprintf(path, sizeof(path), "%s/%s", s->dir, f->filename);
    struct sf_err err;
    if (sim_http_keep_upload(r, path, &err) < 0) {
        sim_http_reply_error(r, 500, err.msg);
        return;
    }
    const char *sel = sim_http_field(r, "select");
    char loc[128];
    snprintf(loc, sizeof(loc), "http://x/api/files/local/%s", f->filename);
    sim_http_add_header(r, "Location", loc);
    sim_http_reply_json(r, 201,
                        json_pack("{s:s,s:I,s:s}", "name", f->filename, "size", (json_int_t)f->size,
                                  "select", sel ? sel : ""));
}

static const struct sim_http_route routes[] = {
    { "GET", "/api/version", SIM_HTTP_BODY_MEM, false, h_hello },
    { "POST", "/api/echo/*", SIM_HTTP_BODY_MEM, false, h_echo_json },
    { "POST", "/api/files/local", SIM_HTTP_BODY_FORM, false, h_upload },
    { "GET", "/open", SIM_HTTP_BODY_MEM, true, h_hello },
};

struct got {
    int calls, code;
    long status;
    char body[512];
    char location[128];
};

static void
on_done(struct httpc_req *r, const struct httpc_result *res, void *ud)
{
    (void)r;
    struct got *g = ud;
    g->calls++;
    g->code = res->code;
    g->status = res->status;
    snprintf(g->body, sizeof(g->body), "%s", res->code == SF_OK ? res->body : res->err.msg);
    if (!httpc_header(res, "Location", g->location, sizeof(g->location)))
        g->location[0] = 0;
}

/* One request through httpc to the sim on the same loop, waited for. */
static struct got
call(struct loop *l, struct httpc *h, struct httpc_opts o)
{
    struct got g = { 0 };
    o.done = on_done;
    o.ud = &g;
    struct sf_err err;
    if (!httpc_start(h, &o, &err)) {
        snprintf(g.body, sizeof(g.body), "%s", err.msg);
        return g;
    }
    double end = wall_s() + 60;
    while (!g.calls && wall_s() < end)
        loop_run_once(l, 20);
    return g;
}

static struct sim_http *
server(struct loop *l, struct server *s, const char *fault)
{
    struct sim_http_config c = { 0 };
    c.routes = routes;
    c.n_routes = sizeof(routes) / sizeof(routes[0]);
    c.ud = s;
    c.api_key = "secret-key";
    c.upload_dir = s->dir;
    struct sf_err err;
    if (fault && sim_http_fault_parse(&c.faults, fault, &err) < 0) {
        printf("# %s\n", err.msg);
        return NULL;
    }
    return sim_http_new(l, &c, &err);
}

T_CASE(http_routes_keys_uploads)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    struct server s = { 0 };
    snprintf(s.dir, sizeof(s.dir), "%s", t_tmpdir());
    struct sim_http *sh = server(l, &s, NULL);
    T_TRUE(sh != NULL);
    struct httpc *h = httpc_new(l, &err);
    char u[128];
    const char *key[] = { "X-Api-Key: secret-key", NULL };
    const char *bad[] = { "X-Api-Key: wrong", NULL };
    int port = sim_http_port(sh);

    snprintf(u, sizeof(u), "http://127.0.0.1:%d/api/version", port);
    struct got g = call(l, h, (struct httpc_opts){ .url = u, .headers = key });
    T_EQ_INT(g.status, 200);
    T_EQ_STR(g.body, "{\"api\":\"0.1\",\"text\":\"OctoPrint 1.10.0\"}");
    g = call(l, h, (struct httpc_opts){ .url = u, .headers = bad });
    T_EQ_INT(g.status, 403);
    T_TRUE(strstr(g.body, "Invalid API key") != NULL);
    g = call(l, h, (struct httpc_opts){ .url = u });
    T_EQ_INT(g.status, 403);
    snprintf(u, sizeof(u), "http://127.0.0.1:%d/open", port);
    g = call(l, h, (struct httpc_opts){ .url = u });
    T_EQ_INT(g.status, 200);
    snprintf(u, sizeof(u), "http://127.0.0.1:%d/nowhere", port);
    g = call(l, h, (struct httpc_opts){ .url = u, .headers = key });
    T_EQ_INT(g.status, 404);
    snprintf(u, sizeof(u), "http://127.0.0.1:%d/api/version", port);
    g = call(l, h, (struct httpc_opts){ .method = "DELETE", .url = u, .headers = key });
    T_EQ_INT(g.status, 405);

    snprintf(u, sizeof(u), "http://127.0.0.1:%d/api/echo/a/b", port);
    g = call(l, h,
             (struct httpc_opts){ .url = u, .headers = key, .body = "{\"x\":1}", .body_len = 7 });
    T_EQ_INT(g.status, 200);
    T_EQ_STR(g.body, "{\"x\":1,\"path_rest\":\"a/b\"}");
    g = call(l, h, (struct httpc_opts){ .url = u, .headers = key, .body = "nope", .body_len = 4 });
    T_EQ_INT(g.status, 400);

    /* A 3 MB multipart upload lands byte for byte. */
    char src[600];
    snprintf(src, sizeof(src), "%s/src.gcode", t_tmpdir());
    FILE *f = fopen(src, "w");
    for (int i = 0; i < 120000; i++)
        fprintf(f, "G1 X%d Y%d E%d\n", i % 200, i % 190, i);
    fclose(f);
    struct httpc_part parts[] = { { .name = "select", .value = "true" },
                                  { .name = "file", .file_path = src, .filename = "up.gcode" } };
    snprintf(u, sizeof(u), "http://127.0.0.1:%d/api/files/local", port);
    g = call(l, h, (struct httpc_opts){ .url = u, .headers = key, .parts = parts, .n_parts = 2 });
    T_EQ_INT(g.status, 201);
    T_TRUE(strstr(g.body, "\"select\":\"true\"") != NULL);
    T_EQ_STR(g.location, "http://x/api/files/local/up.gcode");
    struct buf a, b;
    buf_init(&a, 0);
    buf_init(&b, 0);
    char dst[600];
    snprintf(dst, sizeof(dst), "%s/up.gcode", t_tmpdir());
    T_OK(buf_read_file(&a, src, &err), &err);
    T_OK(buf_read_file(&b, dst, &err), &err);
    T_EQ_INT(a.len, b.len);
    T_TRUE(a.len == b.len && memcmp(a.data, b.data, a.len) == 0);
    buf_release(&a);
    buf_release(&b);
    httpc_free(h);
    sim_http_free(sh);
    loop_free(l);
}

T_CASE(http_faults)
{
    struct sf_err err;
    struct sim_http_faults fl = { 0 };
    T_ERR(sim_http_fault_parse(&fl, "thermal=3", &err), SF_EUNSUPP, &err, "thermal");
    T_ERR(sim_http_fault_parse(&fl, "5xx=x", &err), SF_EINVAL, &err, "5xx");
    T_OK(sim_http_fault_parse(&fl, "5xx=2@1", &err), &err);
    T_EQ_INT(fl.err5xx_count, 2);
    T_EQ_INT(fl.err5xx_after, 1);

    struct loop *l = loop_new(&err);
    struct server s = { 0 };
    snprintf(s.dir, sizeof(s.dir), "%s", t_tmpdir());
    struct httpc *h = httpc_new(l, &err);
    const char *key[] = { "X-Api-Key: secret-key", NULL };
    char u[128];

    struct sim_http *sh = server(l, &s, "5xx=2@1");
    snprintf(u, sizeof(u), "http://127.0.0.1:%d/api/version", sim_http_port(sh));
    long st[4];
    for (int i = 0; i < 4; i++)
        st[i] = call(l, h, (struct httpc_opts){ .url = u, .headers = key }).status;
    T_EQ_INT(st[0], 200);
    T_EQ_INT(st[1], 503);
    T_EQ_INT(st[2], 503);
    T_EQ_INT(st[3], 200);
    sim_http_free(sh);

    sh = server(l, &s, "slow=300");
    snprintf(u, sizeof(u), "http://127.0.0.1:%d/api/version", sim_http_port(sh));
    struct got g = call(l, h, (struct httpc_opts){ .url = u, .headers = key, .timeout_ms = 100 });
    T_EQ_INT(g.code, SF_ETIMEDOUT);
    g = call(l, h, (struct httpc_opts){ .url = u, .headers = key });
    T_EQ_INT(g.status, 200);
    sim_http_free(sh);

    sh = server(l, &s, "drop-upload=1");
    char src[600];
    snprintf(src, sizeof(src), "%s/drop.gcode", t_tmpdir());
    FILE *f = fopen(src, "w");
    for (int i = 0; i < 50000; i++)
        fprintf(f, "G1 X%d Y%d\n", i % 200, i % 190);
    fclose(f);
    struct httpc_part parts[] = { { .name = "file", .file_path = src, .filename = "d.gcode" } };
    snprintf(u, sizeof(u), "http://127.0.0.1:%d/api/files/local", sim_http_port(sh));
    g = call(l, h, (struct httpc_opts){ .url = u, .headers = key, .parts = parts, .n_parts = 1 });
    T_EQ_INT(g.code, SF_EIO);
    T_EQ_INT(g.status, 0);
    char kept[600];
    snprintf(kept, sizeof(kept), "%s/d.gcode", t_tmpdir());
    T_TRUE(access(kept, F_OK) != 0); /* nothing kept of a cut upload */
    g = call(l, h, (struct httpc_opts){ .url = u, .headers = key, .parts = parts, .n_parts = 1 });
    T_EQ_INT(g.status, 201); /* the next one goes through (a fresh connection: no re-send) */
    sim_http_free(sh);
    httpc_free(h);
    loop_free(l);
}

/* A print that ran to its end reads Finishing, not ready, from the moment the printer completes
   it, before the simulator's next watch turn: a client polling in between saw Operational and
   ready, started its next print and was refused "already printing" (a farmd_bambu flake). */
T_CASE(octoprint_finishing_from_the_moment_a_print_completes)
{
    struct octo_sim o = { .was_running = true };
    struct sim_np_status st = { .state = SIM_NP_COMPLETE };
    T_EQ_STR(sim_octoprint_state_text(&o, &st), "Finishing");
    json_t *flags = sim_octoprint_flags(&o, &st);
    T_TRUE(json_is_true(json_object_get(flags, "finishing")));
    T_TRUE(json_is_false(json_object_get(flags, "ready")));
    json_decref(flags);
    o.was_running = false; /* the watch turns passed: Operational and ready again */
    T_EQ_STR(sim_octoprint_state_text(&o, &st), "Operational");
    flags = sim_octoprint_flags(&o, &st);
    T_TRUE(json_is_true(json_object_get(flags, "ready")));
    json_decref(flags);
}
