/*
 * test_octoprint.c - the OctoPrint driver against OctoPrint's documented
 * replies.  The bodies below are the examples of docs.octoprint.org (the
 * docs/api/ pages (printer.rst, job.rst, files.rst) of OctoPrint 1.10/1.11: GET /api/printer
 * examples 1 and 2, GET /api/job, the POST /api/files/local upload example, GET /api/version),
 * field by field, fed first to the parsers and then, served by a scripted loopback server
 * (sim_http), to the driver itself, which must send the documented requests (multipart
 * file/select/print, the pause/resume/cancel bodies, X-Api-Key) and map what comes back: states,
 * temperatures, progress, DONE, CANCELLED, 409 reasons, 403.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../../drivers/net/drv_octoprint.h"
#include "../../sim/net/sim_http.h"
#include "../../src/base/buf.h"
#include "../t.h"

/* docs/api/printer.rst, Example 1 (history included, tool1 with a null target). */
static const char printer_ex1[] =
    "{\"temperature\":{\"tool0\":{\"actual\":214.8821,\"target\":220.0,\"offset\":0},"
    "\"tool1\":{\"actual\":25.3,\"target\":null,\"offset\":0},"
    "\"bed\":{\"actual\":50.221,\"target\":70.0,\"offset\":5},"
    "\"history\":[{\"time\":1395651928,\"tool0\":{\"actual\":214.8821,\"target\":220.0},"
    "\"tool1\":{\"actual\":25.3,\"target\":null},\"bed\":{\"actual\":50.221,\"target\":70.0}},"
    "{\"time\":1395651926,\"tool0\":{\"actual\":212.32,\"target\":220.0},"
    "\"tool1\":{\"actual\":25.1,\"target\":null},\"bed\":{\"actual\":49.1123,\"target\":70.0}}]},"
    "\"sd\":{\"ready\":true},"
    "\"state\":{\"text\":\"Operational\",\"flags\":{\"operational\":true,\"paused\":false,"
    "\"printing\":false,\"cancelling\":false,\"pausing\":false,\"sdReady\":true,\"error\":false,"
    "\"ready\":true,\"closedOrError\":false}}}";

/* docs/api/printer.rst, Example 2 (exclude=temperature,sd). */
static const char printer_ex2[] =
    "{\"state\":{\"text\":\"Operational\",\"flags\":{\"operational\":true,\"paused\":false,"
    "\"printing\":false,\"cancelling\":false,\"pausing\":false,\"sdReady\":true,\"error\":false,"
    "\"ready\":true,\"closedOrError\":false}}}";

/* docs/api/job.rst, the GET /api/job example ("completion" there is a fraction). */
static const char job_ex[] =
    "{\"job\":{\"file\":{\"name\":\"whistle_v2.gcode\",\"origin\":\"local\",\"size\":1468987,"
    "\"date\":1378847754},\"estimatedPrintTime\":8811,\"filament\":{\"length\":810,"
    "\"volume\":5.36}},\"progress\":{\"completion\":0.2298468264184775,\"filepos\":337942,"
    "\"printTime\":276,\"printTimeLeft\":912},\"state\":\"Printing\"}";

/* docs/api/files.rst, the upload example (local and sdcard). */
static const char upload_ex[] =
    "{\"files\":{\"local\":{\"name\":\"whistle_v2.gcode\",\"path\":\"whistle_v2.gcode\","
    "\"type\":\"machinecode\",\"typePath\":[\"machinecode\",\"gcode\"],\"origin\":\"local\","
    "\"refs\":{\"resource\":\"http://example.com/api/files/local/whistle_v2.gcode\","
    "\"download\":\"http://example.com/downloads/files/local/whistle_v2.gcode\"}},"
    "\"sdcard\":{\"name\":\"whistle_.gco\",\"path\":\"whistle_.gco\",\"origin\":\"sdcard\","
    "\"refs\":{\"resource\":\"http://example.com/api/files/sdcard/whistle_.gco\"}}},"
    "\"done\":false,\"effectiveSelect\":true,\"effectivePrint\":true}";

T_CASE(parsers_read_the_documented_bodies)
{
    struct sf_err err;
    struct octo_printer p;
    T_OK(octo_parse_printer(printer_ex1, strlen(printer_ex1), &p, &err), &err);
    T_EQ_STR(p.state, "Operational");
    T_TRUE(p.operational && !p.printing && !p.error && !p.closed_or_error);
    T_EQ_DBL(p.tool_c, 214.8821, 1e-9);
    T_EQ_DBL(p.tool_target_c, 220, 1e-9);
    T_EQ_DBL(p.bed_c, 50.221, 1e-9);
    T_EQ_DBL(p.bed_target_c, 70, 1e-9);
    T_OK(octo_parse_printer(printer_ex2, strlen(printer_ex2), &p, &err), &err);
    T_EQ_DBL(p.tool_c, -1, 0); /* excluded: unknown, not zero */

    struct octo_job j;
    T_OK(octo_parse_job(job_ex, strlen(job_ex), &j, &err), &err);
    T_EQ_STR(j.state, "Printing");
    T_EQ_STR(j.file, "whistle_v2.gcode");
    T_EQ_INT(j.size, 1468987);
    T_EQ_INT(j.filepos, 337942);
    T_EQ_DBL(j.print_time_s, 276, 0);
    T_EQ_DBL(j.time_left_s, 912, 0);
    T_EQ_STR(j.error, "");
    const char *idle =
        "{\"job\":{\"file\":{\"name\":null,\"origin\":null,\"size\":null,\"date\":null},"
        "\"estimatedPrintTime\":null,\"filament\":null},\"progress\":{\"completion\":"
        "null,\"filepos\":null,\"printTime\":null,\"printTimeLeft\":null},"
        "\"state\":\"Offline after error\",\"error\":\"SerialException\"}";
    T_OK(octo_parse_job(idle, strlen(idle), &j, &err), &err);
    T_EQ_STR(j.file, "");
    T_EQ_INT(j.size, -1);
    T_EQ_DBL(j.completion, -1, 0);
    T_EQ_STR(j.error, "SerialException");
    /* A size or filepos no file has (fuzz_octoprint: 5.6e113 cast to int64) reads as unknown. */
    const char *huge = "{\"job\":{\"file\":{\"size\":5.5e113}},\"progress\":{\"filepos\":-3},"
                       "\"state\":\"Printing\"}";
    T_OK(octo_parse_job(huge, strlen(huge), &j, &err), &err);
    T_EQ_INT(j.size, -1);
    T_EQ_INT(j.filepos, -1);
    T_ERR(octo_parse_job("{\"job\":{}}", 10, &j, &err), SF_EINVAL, &err, "no \"state\"");
    T_ERR(octo_parse_job("[1]", 3, &j, &err), SF_EINVAL, &err, "not a JSON object");

    bool print;
    char name[64];
    T_OK(octo_parse_upload(upload_ex, strlen(upload_ex), &print, name, sizeof(name), &err), &err);
    T_TRUE(print);
    T_EQ_STR(name, "whistle_v2.gcode");

    char text[64];
    const char *v = "{\"api\":\"0.1\",\"server\":\"1.10.0\",\"text\":\"OctoPrint 1.10.0\"}";
    T_OK(octo_parse_version(v, strlen(v), text, sizeof(text), &err), &err);
    T_EQ_STR(text, "OctoPrint 1.10.0");
    /* Moonraker's OctoPrint emulation says so in its text; still OctoPrint's API. */
    v = "{\"server\":\"1.5.0\",\"api\":\"0.1\",\"text\":\"OctoPrint (Moonraker v0.8.0)\"}";
    T_OK(octo_parse_version(v, strlen(v), text, sizeof(text), &err), &err);
    v = "{\"api\":\"2.0.0\",\"server\":\"2.1.2\",\"text\":\"PrusaLink\"}";
    T_ERR(octo_parse_version(v, strlen(v), text, sizeof(text), &err), SF_EINVAL, &err,
          "not OctoPrint");

    octo_reason("{\"error\":\"Printer is not operational\"}", 38, text, sizeof(text));
    T_EQ_STR(text, "Printer is not operational");
    octo_reason("<h1>Conflict</h1>\nmore", 22, text, sizeof(text));
    T_EQ_STR(text, "<h1>Conflict</h1>");

    T_EQ_INT(octo_classify("Operational"), OCTO_R_IDLE);
    T_EQ_INT(octo_classify("Printing from SD"), OCTO_R_PRINTING);
    T_EQ_INT(octo_classify("Pausing"), OCTO_R_PAUSED);
    T_EQ_INT(octo_classify("Paused"), OCTO_R_PAUSED);
    T_EQ_INT(octo_classify("Cancelling"), OCTO_R_CANCELLING);
    T_EQ_INT(octo_classify("Offline after error"), OCTO_R_ERROR);
    T_EQ_INT(octo_classify("Error"), OCTO_R_ERROR);
    T_EQ_INT(octo_classify("Offline"), OCTO_R_OFFLINE);
    T_EQ_INT(octo_classify("Opening serial connection"), OCTO_R_OFFLINE);
    T_EQ_INT(octo_classify("Detecting baudrate"), OCTO_R_OFFLINE);
    T_EQ_INT(octo_classify("Something new"), OCTO_R_UNKNOWN);
}

/* ---- the driver against a scripted server ---- */

struct script {
    char job[2048];         /* what GET /api/job answers */
    unsigned upload_status; /* what the upload answers (201, 409) */
    char upload_reply[1024];
    struct buf last_post; /* body of the last POST /api/job */
    char fields[256];     /* upload: "select=... print=... file=NAME:SIZE" */
    int uploads, job_posts;
    int job_gets;     /* GET /api/job answered */
    int printer_gets; /* GET /api/printer answered */
};
static struct script sc;

static void
h_version(struct sim_http_req *r, void *ud)
{
    (void)ud;
    const char *v = "{\"api\":\"0.1\",\"server\":\"1.10.0\",\"text\":\"OctoPrint 1.10.0\"}";
    sim_http_reply(r, 200, "application/json", v, strlen(v));
}

static void
h_job(struct sim_http_req *r, void *ud)
{
    (void)ud;
    sc.job_gets++;
    sim_http_reply(r, 200, "application/json", sc.job, strlen(sc.job));
}

static void
h_printer(struct sim_http_req *r, void *ud)
{
    (void)ud;
    sc.printer_gets++;
    sim_http_reply(r, 200, "application/json", printer_ex1, strlen(printer_ex1));
}

static void
h_post_job(struct sim_http_req *r, void *ud)
{
    (void)ud;
    size_t n;
    const char *b = sim_http_body(r, &n);
    buf_reset(&sc.last_post);
    buf_append(&sc.last_post, b, n);
    sc.job_posts++;
    sim_http_reply_empty(r, 204);
}

static void
h_upload(struct sim_http_req *r, void *ud)
{
    (void)ud;
    const struct sim_http_file *f = sim_http_upload(r);
    const char *sel = sim_http_field(r, "select"), *pr = sim_http_field(r, "print");
    snprintf(sc.fields, sizeof(sc.fields), "select=%s print=%s file=%s:%llu", sel ? sel : "-",
             pr ? pr : "-", f ? f->filename : "-", f ? (unsigned long long)f->size : 0ULL);
    sc.uploads++;
    sim_http_reply(r, sc.upload_status, "application/json", sc.upload_reply,
                   strlen(sc.upload_reply));
}

static const struct sim_http_route routes[] = {
    { "GET", "/api/version", SIM_HTTP_BODY_MEM, false, h_version },
    { "GET", "/api/job", SIM_HTTP_BODY_MEM, false, h_job },
    { "POST", "/api/job", SIM_HTTP_BODY_MEM, false, h_post_job },
    { "GET", "/api/printer", SIM_HTTP_BODY_MEM, false, h_printer },
    { "POST", "/api/files/local", SIM_HTTP_BODY_FORM, false, h_upload },
};

struct events {
    int n[8];
    enum drv_state last_state;
};

static void
on_event(struct drv *d, enum drv_event ev, void *ud)
{
    struct events *e = ud;
    e->n[ev]++;
    e->last_state = d->status.state;
}

static double
wall_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec / 1e9;
}

static bool
wait_for(struct loop *l, struct drv *d, enum drv_state st, const int *counter, int want)
{
    double end = wall_s() + 30;
    while (wall_s() < end && (d->status.state != st || (counter && *counter < want)))
        loop_run_once(l, 20);
    return d->status.state == st && (!counter || *counter >= want);
}

static bool
wait_lines(struct loop *l, struct drv *d, uint64_t want)
{
    double end = wall_s() + 30;
    while (wall_s() < end && d->status.lines_acked < want)
        loop_run_once(l, 20);
    return d->status.lines_acked >= want;
}

static void
set_job(const char *state, const char *file, long size, long pos)
{
    snprintf(sc.job, sizeof(sc.job),
             "{\"job\":{\"file\":{\"name\":\"%s\",\"origin\":\"local\",\"size\":%ld,"
             "\"date\":1378847754},\"estimatedPrintTime\":8811},\"progress\":{\"completion\":%g,"
             "\"filepos\":%ld,\"printTime\":276,\"printTimeLeft\":912},\"state\":\"%s\"}",
             file, size, size ? 100.0 * (double)pos / (double)size : 0.0, pos, state);
}

static struct sim_http *
serve(struct loop *l, const char *key)
{
    struct sim_http_config c = { 0 };
    c.routes = routes;
    c.n_routes = sizeof(routes) / sizeof(routes[0]);
    c.api_key = key;
    c.upload_dir = t_tmpdir();
    struct sf_err err;
    return sim_http_new(l, &c, &err);
}

static struct drv *
driver(struct loop *l, struct sim_http *h, const char *key, struct events *ev)
{
    char url[64];
    snprintf(url, sizeof(url), "http://127.0.0.1:%d/", sim_http_port(h));
    struct drv_config cfg = { .name = "op",
                              .kind = "octoprint",
                              .url = url,
                              .api_key = key,
                              .poll_ms = 50,
                              .poll_idle_ms = 50 };
    struct sf_err err;
    return drv_new(l, &cfg, on_event, ev, &err);
}

T_CASE(driver_speaks_the_documented_api)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    buf_init(&sc.last_post, 0);
    set_job("Operational", "", 0, 0);
    sc.upload_status = 201;
    struct sim_http *h = serve(l, "abcdef");
    struct events ev = { 0 };
    struct drv *d = driver(l, h, "abcdef", &ev);
    T_TRUE(d != NULL);
    T_OK(d->ops->open(d, &err), &err);
    T_TRUE(wait_for(l, d, DRV_IDLE, NULL, 0));
    T_EQ_STR(d->caps.firmware, "OctoPrint 1.10.0");
    T_EQ_DBL(d->status.nozzle_c, 214.8821, 1e-9);
    T_EQ_DBL(d->status.bed_target_c, 70, 1e-9);
    T_TRUE(ev.n[DRV_EV_TEMPS] >= 1);

    /* A job: 100 lines of 20 bytes. */
    char path[600];
    snprintf(path, sizeof(path), "%s/job.gcode", t_tmpdir());
    FILE *f = fopen(path, "w");
    for (int i = 0; i < 100; i++)
        fprintf(f, "G1 X%04d Y%03d F3000\n", i, i); /* 20 bytes a line */
    fclose(f);
    char remote[80];
    drv_remote_name(path, remote, sizeof(remote));
    T_EQ_STR(remote, "sf-job.gcode");
    snprintf(sc.upload_reply, sizeof(sc.upload_reply),
             "{\"files\":{\"local\":{\"name\":\"%s\",\"origin\":\"local\"}},\"done\":true,"
             "\"effectiveSelect\":true,\"effectivePrint\":true}",
             remote);
    set_job("Printing", remote, 2000, 0);
    T_ERR(d->ops->start_job(d, path, 5, NULL, &err), SF_EUNSUPP, &err, "resuming");
    T_OK(d->ops->start_job(d, path, 0, NULL, &err), &err);
    T_EQ_INT(d->status.lines_total, 100);
    T_ERR(d->ops->start_job(d, path, 0, NULL, &err), SF_EAGAIN, &err, "not idle");
    while (!sc.uploads)
        loop_run_once(l, 20);
    T_EQ_STR(sc.fields, "select=true print=true file=sf-job.gcode:2000");

    /* Printing, 37 whole lines and a half sent. */
    set_job("Printing", remote, 2000, 750);
    T_TRUE(wait_lines(l, d, 37) && d->status.state == DRV_PRINTING);
    T_EQ_INT(d->status.lines_acked, 37);
    T_EQ_DBL(d->status.progress, 0.375, 1e-9);

    /* Pause and resume send the documented bodies. */
    T_OK(d->ops->pause(d, &err), &err);
    T_EQ_INT(d->status.state, DRV_PAUSED);
    set_job("Paused", remote, 2000, 750);
    while (sc.job_posts < 1)
        loop_run_once(l, 20);
    T_EQ_STR(sc.last_post.data, "{\"command\":\"pause\",\"action\":\"pause\"}");
    for (int i = 0; i < 10; i++)
        loop_run_once(l, 20);
    T_EQ_INT(d->status.state, DRV_PAUSED);
    T_OK(d->ops->resume(d, &err), &err);
    set_job("Printing", remote, 2000, 750);
    while (sc.job_posts < 2)
        loop_run_once(l, 20);
    T_EQ_STR(sc.last_post.data, "{\"command\":\"pause\",\"action\":\"resume\"}");

    /* Operational again with the whole file read: DONE, every line. */
    set_job("Operational", remote, 2000, 2000);
    T_TRUE(wait_for(l, d, DRV_IDLE, &ev.n[DRV_EV_JOB_DONE], 1));
    T_EQ_INT(d->status.lines_acked, 100);
    T_EQ_INT(ev.n[DRV_EV_JOB_FAILED], 0);

    /* Another job, cancelled: the cancel body, then CANCELLED once OctoPrint is idle. */
    set_job("Printing", remote, 2000, 100);
    T_OK(d->ops->start_job(d, path, 0, NULL, &err), &err);
    T_TRUE(wait_lines(l, d, 5) && d->status.state == DRV_PRINTING);
    T_OK(d->ops->cancel(d, &err), &err);
    while (sc.job_posts < 3)
        loop_run_once(l, 20);
    T_EQ_STR(sc.last_post.data, "{\"command\":\"cancel\"}");
    set_job("Operational", remote, 2000, 400);
    T_TRUE(wait_for(l, d, DRV_IDLE, &ev.n[DRV_EV_JOB_CANCELLED], 1));
    T_EQ_INT(ev.n[DRV_EV_JOB_DONE], 1);

    /* A print stopped at the printer fails the job, saying so. */
    set_job("Printing", remote, 2000, 100);
    T_OK(d->ops->start_job(d, path, 0, NULL, &err), &err);
    T_TRUE(wait_lines(l, d, 5) && d->status.state == DRV_PRINTING);
    set_job("Operational", remote, 2000, 300);
    T_TRUE(wait_for(l, d, DRV_IDLE, &ev.n[DRV_EV_JOB_FAILED], 1));
    T_TRUE(strstr(d->status.message, "stopped at the printer") != NULL);

    /* 409 on upload: the job fails with OctoPrint's reason. */
    sc.upload_status = 409;
    snprintf(sc.upload_reply, sizeof(sc.upload_reply), "%s",
             "{\"error\":\"Trying to overwrite file that is currently being printed\"}");
    set_job("Operational", "", 0, 0);
    T_OK(d->ops->start_job(d, path, 0, NULL, &err), &err);
    T_TRUE(wait_for(l, d, DRV_IDLE, &ev.n[DRV_EV_JOB_FAILED], 2));
    T_TRUE(strstr(d->status.message, "Trying to overwrite file") != NULL);

    drv_free(d);
    sim_http_free(h);
    buf_release(&sc.last_post);
    loop_free(l);
}

/* The scripted OctoPrint, Operational, and a driver that has seen it idle. */
struct ofx {
    struct loop *l;
    struct sim_http *h;
    struct drv *d;
    struct events ev;
    char path[600]; /* the job (job_of_100) */
};

static void job_of_100(const char *name, char *path, size_t n);

static bool
ofx_idle(struct ofx *x, const char *job)
{
    struct sf_err err;
    memset(x, 0, sizeof(*x));
    x->l = loop_new(&err);
    buf_init(&sc.last_post, 0);
    set_job("Operational", "", 0, 0);
    sc.upload_status = 201;
    sc.uploads = sc.job_posts = 0;
    x->h = x->l ? serve(x->l, "abcdef") : NULL;
    x->d = x->h ? driver(x->l, x->h, "abcdef", &x->ev) : NULL; /* polls every 50 ms */
    job_of_100(job, x->path, sizeof(x->path));
    return x->d && x->d->ops->open(x->d, &err) == SF_OK && wait_for(x->l, x->d, DRV_IDLE, NULL, 0);
}

static void
ofx_stop(struct ofx *x)
{
    drv_free(x->d);
    sim_http_free(x->h);
    buf_release(&sc.last_post);
    loop_free(x->l);
}

/* A job of 100 lines of 20 bytes at path (n bytes), which OctoPrint takes and prints as
   sf-NAME. */
static void
job_of_100(const char *name, char *path, size_t n)
{
    snprintf(path, n, "%s/%s", t_tmpdir(), name);
    FILE *f = fopen(path, "w");
    for (int i = 0; f && i < 100; i++)
        fprintf(f, "G1 X%04d Y%03d F3000\n", i, i);
    if (f)
        fclose(f);
    snprintf(sc.upload_reply, sizeof(sc.upload_reply),
             "{\"files\":{\"local\":{\"name\":\"sf-%s\",\"origin\":\"local\"}},"
             "\"done\":true,\"effectiveSelect\":true,\"effectivePrint\":true}",
             name);
}

/* Run l until OctoPrint has answered n more polls; false if d left DRV_PAUSED meanwhile. */
static bool
stays_paused(struct loop *l, struct drv *d, int n)
{
    int until = sc.job_gets + n;
    double end = wall_s() + 30;
    while (wall_s() < end && sc.job_gets < until && d->status.state == DRV_PAUSED)
        loop_run_once(l, 20);
    return d->status.state == DRV_PAUSED && sc.job_gets >= until;
}

/*
 * OctoPrint is "Pausing" between the pause command and "Paused" (while the
 * printer finishes the moves it holds): a pause taking effect, not a
 * print, so the driver says paused throughout.  It once said printing
 * there, which the farm took for a resume at the printer: the job went
 * paused, printing, paused again within a poll or two.
 */
T_CASE(driver_pausing_is_paused)
{
    struct sf_err err;
    struct ofx x;
    T_TRUE(ofx_idle(&x, "pausing.gcode"));
    struct loop *l = x.l;
    struct drv *d = x.d;
    set_job("Printing", "sf-pausing.gcode", 2000, 500);
    T_OK(d->ops->start_job(d, x.path, 0, NULL, &err), &err);
    T_TRUE(wait_lines(l, d, 25) && d->status.state == DRV_PRINTING);

    T_OK(d->ops->pause(d, &err), &err);
    set_job("Pausing", "sf-pausing.gcode", 2000, 520);
    T_TRUE(stays_paused(l, d, 3));
    T_EQ_INT(sc.job_posts, 1);
    set_job("Paused", "sf-pausing.gcode", 2000, 540);
    T_TRUE(stays_paused(l, d, 2));
    /* someone pauses at the printer: "Pausing" is already paused */
    T_OK(d->ops->resume(d, &err), &err);
    set_job("Printing", "sf-pausing.gcode", 2000, 600);
    T_TRUE(wait_for(l, d, DRV_PRINTING, &sc.job_posts, 2));
    set_job("Pausing", "sf-pausing.gcode", 2000, 620);
    T_TRUE(wait_for(l, d, DRV_PAUSED, NULL, 0));
    T_EQ_INT(x.ev.n[DRV_EV_JOB_FAILED] + x.ev.n[DRV_EV_JOB_DONE], 0);
    ofx_stop(&x);
}

/*
 * A job handed over while a poll's second request (GET /api/printer) is
 * under way starts at once: the upload cuts it short as it does the poll's
 * first.  It once answered "not now" (SF_EAGAIN: the upload could not
 * start), which the farm counts as a refused start: a print of the job that
 * never began, the job back to ready and the printer held for 0.5 s.
 */
T_CASE(driver_starts_a_job_during_a_poll)
{
    struct sf_err err;
    struct ofx x;
    T_TRUE(ofx_idle(&x, "mid-poll.gcode"));
    /* OctoPrint has just answered GET /api/printer: the driver has not read it yet */
    int gets = sc.printer_gets;
    double end = wall_s() + 30;
    while (wall_s() < end && sc.printer_gets == gets)
        loop_run_once(x.l, 20);
    T_TRUE(sc.printer_gets > gets);
    T_OK(x.d->ops->start_job(x.d, x.path, 0, NULL, &err), &err);
    set_job("Printing", "sf-mid-poll.gcode", 2000, 100);
    end = wall_s() + 30;
    while (wall_s() < end && !sc.uploads)
        loop_run_once(x.l, 20);
    T_EQ_INT(sc.uploads, 1);
    set_job("Operational", "sf-mid-poll.gcode", 2000, 2000);
    T_TRUE(wait_for(x.l, x.d, DRV_IDLE, &x.ev.n[DRV_EV_JOB_DONE], 1));
    ofx_stop(&x);
}

T_CASE(driver_wrong_key_and_reattach)
{
    struct sf_err err;
    struct loop *l = loop_new(&err);
    buf_init(&sc.last_post, 0);
    struct sim_http *h = serve(l, "abcdef");
    struct events ev = { 0 };
    struct drv *d = driver(l, h, "wrong", &ev);
    T_OK(d->ops->open(d, &err), &err);
    double end = wall_s() + 30;
    while (wall_s() < end && !strstr(d->status.message, "authentication"))
        loop_run_once(l, 20);
    T_EQ_INT(d->status.state, DRV_OFFLINE);
    T_TRUE(strstr(d->status.message, "authentication failed (check api_key)") != NULL);
    drv_free(d);

    /* Re-attach: OctoPrint prints the farm's upload (same name and size). */
    char path[600];
    snprintf(path, sizeof(path), "%s/re.gcode", t_tmpdir());
    FILE *f = fopen(path, "w");
    for (int i = 0; i < 50; i++)
        fprintf(f, "G1 X%04d Y%03d F3000\n", i, i);
    fclose(f);
    set_job("Printing", "sf-re.gcode", 999, 500); /* another size: not ours */
    memset(&ev, 0, sizeof(ev));
    d = driver(l, h, "abcdef", &ev);
    T_OK(d->ops->open(d, &err), &err);
    T_TRUE(wait_for(l, d, DRV_PRINTING, NULL, 0));
    T_ERR(d->ops->attach(d, path, NULL, &err), SF_ENOTFOUND, &err, "not the farm's");
    set_job("Printing", "sf-re.gcode", 1000, 500);
    for (int i = 0; i < 10; i++)
        loop_run_once(l, 20);
    T_OK(d->ops->attach(d, path, NULL, &err), &err);
    T_EQ_INT(d->status.lines_acked, 25);
    set_job("Operational", "sf-re.gcode", 1000, 1000);
    T_TRUE(wait_for(l, d, DRV_IDLE, &ev.n[DRV_EV_JOB_DONE], 1));
    T_EQ_INT(d->status.lines_acked, 50);
    drv_free(d);
    sim_http_free(h);
    buf_release(&sc.last_post);
    loop_free(l);
}
