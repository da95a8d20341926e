/*
 * test_bambu.c - the Bambu driver against the Bambu simulator, over the
 * real components: Debian's mosquitto broker with a TLS listener and a
 * password file, certificates made by openssl (a CA, the printer's with
 * CN = serial), and the simulator's implicit FTPS with session reuse
 * enforced.  Driver, simulator and its machine share one loop here; the
 * broker is a separate process (tests/bambu/env.sh).
 *
 * The job cases compare the simulator's executed-command log with the
 * commands of the G-code file: every command exactly once, in order.
 * Waits are bounded by the wall clock and end on events, never on sleeps.
 */
#include <arpa/inet.h>
#include <jansson.h>
#include <netinet/in.h>
#include <signal.h>
#include <stdlib.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "../../drivers/bambu/drv_bambu.h"
#include "../../drivers/drv.h"
#include "../../sim/bambu/sim_bambu.h"
#include "../../src/base/log.h"
#include "../../src/base/mqttloop.h"
#include "../t.h"

#define SERIAL  "01S00A2B3C4D5E6"
#define CODE    "31415926"
#define ENV_SH  "tests/bambu/env.sh"
#define WAIT_MS 120000

static char certs[512];
static int broker_port, broker_pid;
static int env_state; /* 0 unknown, 1 ready, -1 unavailable */

static int
run(const char *cmd, char *out, size_t n)
{
    FILE *p = popen(cmd, "r");
    if (!p)
        return -1;
    size_t got = out ? fread(out, 1, n - 1, p) : 0;
    if (out)
        out[got] = '\0';
    int st = pclose(p);
    return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

static int
start_broker(int port)
{
    char cmd[1024], out[64];
    snprintf(cmd, sizeof(cmd), ENV_SH " broker %s %s %d", certs, CODE, port);
    if (port == 0)
        snprintf(cmd, sizeof(cmd), ENV_SH " broker %s %s", certs, CODE);
    if (run(cmd, out, sizeof(out)) != 0 || sscanf(out, "%d %d", &broker_port, &broker_pid) != 2)
        return -1;
    return 0;
}

static void
stop_broker(void)
{
    char cmd[128];
    snprintf(cmd, sizeof(cmd), ENV_SH " stop %d", broker_pid);
    run(cmd, NULL, 0);
    broker_pid = 0;
}

static void
at_exit_stop(void)
{
    if (broker_pid > 0)
        stop_broker();
}

/* Certificates and a broker, once per program; false: skip (no mosquitto). */
static bool
env_ready(void)
{
    if (env_state)
        return env_state > 0;
    env_state = -1;
    signal(SIGPIPE, SIG_IGN);
    snprintf(certs, sizeof(certs), "%s/certs", t_tmpdir());
    char cmd[1024];
    snprintf(cmd, sizeof(cmd), ENV_SH " certs %s %s", certs, SERIAL);
    int rc = run(cmd, NULL, 0);
    if (rc == 77)
        return false;
    if (rc != 0 || start_broker(0) < 0) {
        fprintf(stderr, "bambu test environment failed (%s)\n", cmd);
        return false;
    }
    atexit(at_exit_stop);
    env_state = 1;
    return true;
}

struct run {
    struct loop *loop;
    struct sim_bambu *sim;
    struct drv *drv;
    int done, failed, cancelled, progress, temps;
    double max_noz_target; /* highest nozzle target reported */
    int64_t max_time_left; /* highest printer estimate seen at a progress event, s */
    int states[64];
    int n_states;
    int pause_at;  /* pause once progress reaches this percent (0: never) */
    int cancel_at; /* cancel at this percent */
    bool paused_once, cancel_sent;
    char log_path[512], gcode_path[512];
    char failed_msg[200];
};

static void
on_event(struct drv *d, enum drv_event ev, void *ud)
{
    struct run *r = ud;
    if (ev == DRV_EV_JOB_DONE)
        r->done++;
    else if (ev == DRV_EV_JOB_FAILED) {
        r->failed++;
        snprintf(r->failed_msg, sizeof(r->failed_msg), "%s", d->status.message);
    } else if (ev == DRV_EV_JOB_CANCELLED)
        r->cancelled++;
    else if (ev == DRV_EV_TEMPS) {
        r->temps++;
        if (d->status.nozzle_target_c > r->max_noz_target)
            r->max_noz_target = d->status.nozzle_target_c;
    } else if (ev == DRV_EV_STATE && r->n_states < 64)
        r->states[r->n_states++] = d->status.state;
    else if (ev == DRV_EV_PROGRESS) {
        r->progress++;
        if (d->status.has_time_left && d->status.time_left_s > r->max_time_left)
            r->max_time_left = d->status.time_left_s;
        int pct = (int)(d->status.progress * 100);
        if (r->pause_at && !r->paused_once && pct >= r->pause_at) {
            r->paused_once = true;
            d->ops->pause(d, NULL);
        }
        if (r->cancel_at && !r->cancel_sent && pct >= r->cancel_at) {
            r->cancel_sent = true;
            d->ops->cancel(d, NULL);
        }
    }
}

static int64_t
wall_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000 + ts.tv_nsec / 1000000;
}

/* Run the loop until *flag becomes true or WAIT_MS pass; returns *flag. */
#define WAIT_FOR(r, cond)                                                                          \
    ({                                                                                             \
        int64_t t_end_ = wall_ms() + WAIT_MS;                                                      \
        while (!(cond) && wall_ms() < t_end_)                                                      \
            loop_run_once((r)->loop, 50);                                                          \
        (cond);                                                                                    \
    })

/* A job of layers x per_layer moves, led by pad_bytes of comments that deflate poorly (hex
   digits: about half their size), for a large package that is quick to print. */
static void
write_job_pad(struct run *r, int layers, int per_layer, size_t pad_bytes)
{
    snprintf(r->gcode_path, sizeof(r->gcode_path), "%s/cube part.gcode", t_tmpdir());
    FILE *f = fopen(r->gcode_path, "w");
    fprintf(f, "; generated by test_bambu\n");
    uint64_t x = 88172645463325252ull; /* xorshift64 */
    for (size_t done = 0; done < pad_bytes; done += 131) {
        fputs("; ", f);
        for (int i = 0; i < 128; i++) {
            x ^= x << 13, x ^= x >> 7, x ^= x << 17;
            fputc("0123456789abcdef"[x & 15], f);
        }
        fputc('\n', f);
    }
    fprintf(f, "G28 ; home\nG90\nM83\nM104 S215\nM140 S60\nM190 S60\nM109 S215\n\n");
    for (int l = 0; l < layers; l++) {
        fprintf(f, ";LAYER_CHANGE\n;Z:%.2f\nG1 Z%.2f F600\n", 0.2 * (l + 1), 0.2 * (l + 1));
        for (int i = 0; i < per_layer; i++)
            fprintf(f, "G1 X%d.%d Y%d E0.%03d F3000 ; move %d\n", 50 + i % 5, l % 10,
                    50 + (i * 3) % 5, 10 + i % 90, i);
    }
    fprintf(f, "M104 S0\nM140 S0\nM84\n");
    fclose(f);
}

static void
write_job(struct run *r, int layers, int per_layer)
{
    write_job_pad(r, layers, per_layer, 0);
}

/* The commands of a G-code file as the machine logs them. */
static char *
commands_of(const char *path)
{
    FILE *f = fopen(path, "r");
    if (!f)
        return NULL;
    size_t cap = 1 << 16, len = 0;
    char *out = malloc(cap);
    char line[4096];
    while (fgets(line, sizeof(line), f)) {
        char *c = strchr(line, ';');
        if (c)
            *c = '\0';
        char *s = line;
        while (*s == ' ' || *s == '\t')
            s++;
        size_t n = strlen(s);
        while (n && strchr(" \t\r\n", s[n - 1]))
            s[--n] = '\0';
        if (!n)
            continue;
        if (len + n + 2 > cap)
            out = realloc(out, cap *= 2);
        memcpy(out + len, s, n);
        len += n;
        out[len++] = '\n';
    }
    out[len] = '\0';
    fclose(f);
    return out;
}

/* The machine's executed log, minus the host's own queries (M110 hello, M105, the M400
   that ends a job: sim_netprinter.h). */
static char *
slurp(const char *path)
{
    FILE *f = fopen(path, "r");
    if (!f)
        return NULL;
    size_t cap = 1 << 16, len = 0;
    char *out = malloc(cap);
    char line[4096];
    while (fgets(line, sizeof(line), f)) {
        if (!strncmp(line, "M110", 4) || !strncmp(line, "M105", 4) || !strncmp(line, "M400", 4))
            continue;
        size_t n = strlen(line);
        if (len + n + 1 > cap)
            out = realloc(out, cap *= 2);
        memcpy(out + len, line, n);
        len += n;
    }
    out[len] = '\0';
    fclose(f);
    return out;
}

struct setup {
    bool p1;
    double speed;
    const char *ca;   /* NULL: the right CA */
    const char *code; /* NULL: the right access code */
    bool insecure;
    const char *fault; /* one --fault spec or NULL */
    const char *fault2;
    const char *serial; /* NULL: the printer's */
    bool via_printer;   /* reach the broker through the printer's own MQTT port (mqtt-drop) */
    int pause_at;       /* pause once progress reaches this percent (0: never) */
    int cancel_at;      /* cancel at this percent (0: never) */
};

/* Make r's driver "bambu1" for the broker at mqtt_port and the printer's FTPS at ftps_port,
   with the CA, access code and serial of s (NULL: the right ones), and open it. */
static int
open_driver(struct run *r, const struct setup *s, int mqtt_port, int ftps_port, struct sf_err *err)
{
    char url[64], ca[600];
    snprintf(url, sizeof(url), "mqtts://127.0.0.1:%d", mqtt_port);
    snprintf(ca, sizeof(ca), "%s/%s", certs, s->ca ? s->ca : "ca.pem");
    struct drv_config dc = { .name = "bambu1",
                             .kind = "bambu",
                             .url = url,
                             .api_key = s->code ? s->code : CODE,
                             .serial = s->serial ? s->serial : SERIAL,
                             .ca_file = ca,
                             .tls_insecure = s->insecure,
                             .ftps_port = ftps_port };
    r->drv = drv_new(r->loop, &dc, on_event, r, err);
    if (!r->drv) {
        fprintf(stderr, "drv: %s\n", err->msg);
        return -1;
    }
    return r->drv->ops->open(r->drv, err);
}

static int
setup(struct run *r, const struct setup *s)
{
    memset(r, 0, sizeof(*r));
    r->pause_at = s->pause_at;
    r->cancel_at = s->cancel_at;
    struct sf_err err;
    r->loop = loop_new(&err);
    if (!r->loop)
        return -1;
    struct sim_bambu_config c;
    sim_bambu_config_init(&c);
    c.serial = SERIAL;
    c.access_code = CODE;
    c.mqtt_port = broker_port;
    c.ca_dir = certs;
    c.p1 = s->p1;
    c.speed = s->speed > 0 ? s->speed : 1;
    c.report_ms = 50;
    snprintf(r->log_path, sizeof(r->log_path), "%s/exec.log", t_tmpdir());
    c.log_path = r->log_path;
    if (s->fault && sim_bambu_fault_parse(&c.faults, s->fault, &err) < 0)
        return -1;
    if (s->fault2 && sim_bambu_fault_parse(&c.faults, s->fault2, &err) < 0)
        return -1;
    r->sim = sim_bambu_new(r->loop, &c, &err);
    if (!r->sim) {
        fprintf(stderr, "sim: %s\n", err.msg);
        return -1;
    }
    return open_driver(r, s, s->via_printer ? sim_bambu_mqtt_port(r->sim) : broker_port,
                       sim_bambu_ftps_port(r->sim), &err);
}

static void
teardown(struct run *r)
{
    drv_free(r->drv);
    sim_bambu_free(r->sim);
    loop_free(r->loop);
}

/* r with a loop and nothing else: a driver the case opens itself, no printer. */
static void
bare_run(struct run *r)
{
    memset(r, 0, sizeof(*r));
    r->loop = loop_new(NULL);
    T_TRUE(r->loop != NULL);
}

/* Write a job of layers x per_layer moves and start it on r's printer. */
static int
start(struct run *r, int layers, int per_layer, struct sf_err *err)
{
    write_job(r, layers, per_layer);
    return r->drv->ops->start_job(r->drv, r->gcode_path, 0, NULL, err);
}

/* A printer set up as s is refused: the driver ends in error, its message
   naming what and what2. */
static void
refused(const struct setup *s, const char *what, const char *what2)
{
    struct run r;
    T_EQ_INT(setup(&r, s), 0);
    T_TRUE(WAIT_FOR(&r, r.drv->status.state == DRV_ERROR));
    T_TRUE(strstr(r.drv->status.message, what) != NULL);
    T_TRUE(strstr(r.drv->status.message, what2) != NULL);
    teardown(&r);
}

static bool
idle(struct run *r)
{
    return r->drv->status.state == DRV_IDLE;
}

/* Set r up as s and run the loop until its printer is idle; false if either fails. */
static bool
ready(struct run *r, const struct setup *s)
{
    return setup(r, s) == 0 && WAIT_FOR(r, idle(r));
}

/* ready(), then start a job of layers x per_layer moves on it; false if a step fails. */
static bool
started(struct run *r, const struct setup *s, int layers, int per_layer)
{
    struct sf_err err;
    if (!ready(r, s))
        return false;
    if (start(r, layers, per_layer, &err) < 0) {
        fprintf(stderr, "start: %s\n", err.msg);
        return false;
    }
    return true;
}

/* Tear r down; true if the machine ran the job's file whole: its commands once each, in
   order, and nothing else. */
static bool
ran_the_file(struct run *r)
{
    teardown(r);
    char *want = commands_of(r->gcode_path), *got = slurp(r->log_path);
    bool same = want && got && strcmp(got, want) == 0;
    free(want);
    free(got);
    return same;
}

/* A whole job; the log must be the file's commands. */
static void
job_case(bool p1)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    struct run r;
    T_TRUE(started(&r, &(struct setup){ .p1 = p1, .speed = 300 }, 20, 100));
    T_EQ_INT(r.drv->status.state, DRV_PRINTING);
    T_TRUE(WAIT_FOR(&r, r.done || r.failed));
    T_EQ_INT(r.failed, 0);
    T_EQ_INT(r.done, 1);
    T_EQ_INT(r.drv->status.state, DRV_IDLE);
    T_EQ_INT(r.drv->status.lines_acked, r.drv->status.lines_total);
    T_TRUE(r.progress >= 2); /* it moved through the job, not just jumped to the end */
    /* the printer's estimate while it printed (whole minutes, at least 1), none once done */
    T_TRUE(r.max_time_left >= 60);
    T_EQ_INT(r.max_time_left % 60, 0);
    T_TRUE(!r.drv->status.has_time_left);
    T_TRUE(r.temps >= 1);
    struct drv_bambu_stats bs;
    T_TRUE(drv_bambu_stats(r.drv, &bs));
    T_EQ_STR(bs.gcode_state, "FINISH");
    T_EQ_INT(bs.mc_percent, 100);
    T_EQ_INT(bs.total_layer_num, 20); /* sent once in P1 style, kept by the merge */
    T_EQ_INT(bs.layer_num, 20);
    T_EQ_INT(bs.uploads, 1);
    T_EQ_INT(bs.pushalls, 1);
    T_EQ_DBL(r.max_noz_target, 215, 1e-9);            /* M104 S215 ran */
    T_EQ_DBL(r.drv->status.nozzle_target_c, 0, 1e-9); /* and M104 S0 at the end */
    struct sim_bambu_stats ss;
    sim_bambu_stats(r.sim, &ss);
    T_EQ_INT(ss.jobs_finished, 1);
    T_EQ_INT(ss.refused_reuse, 0);
    /* A second job on the same printer: a new upload, the FTPS session reused again. */
    struct sf_err err;
    T_OK(r.drv->ops->start_job(r.drv, r.gcode_path, 0, NULL, &err), &err);
    T_TRUE(WAIT_FOR(&r, r.done == 2 || r.failed));
    T_EQ_INT(r.failed, 0);
    sim_bambu_stats(r.sim, &ss);
    T_EQ_INT(ss.jobs_finished, 2);
    T_EQ_INT(ss.refused_reuse, 0);
    teardown(&r);
    char *want = commands_of(r.gcode_path), *got = slurp(r.log_path);
    T_TRUE(want && got);
    T_TRUE(strlen(want) > 10000);
    T_EQ_INT(strlen(got), 2 * strlen(want));
    T_EQ_INT(strncmp(got, want, strlen(want)), 0);
    T_EQ_INT(strcmp(got + strlen(want), want), 0);
    free(want);
    free(got);
}

T_CASE(bambu_job_x1_full_reports)
{
    job_case(false);
}

T_CASE(bambu_job_p1_delta_reports)
{
    job_case(true);
}

/* A printer played by the test: crafted reports on the broker, for the driver alone. */
struct fake {
    struct mqttloop *m;
    bool up;
    const char *want; /* a sequence_id awaited in a get_version reply (NULL: none) */
    bool got;         /* ... and seen (the driver's own get_version replies go by too) */
};

static void
fake_up(void *ud)
{
    ((struct fake *)ud)->up = true;
}

static void
fake_down(void *ud, int connack, bool tls, const char *why)
{
    (void)connack, (void)tls, (void)why;
    ((struct fake *)ud)->up = false;
}

static void
fake_msg(void *ud, const char *topic, const char *payload, size_t len)
{
    struct fake *f = ud;
    (void)topic;
    if (!f->want)
        return;
    json_t *j = json_loadb(payload, len, 0, NULL);
    json_t *info = json_object_get(j, "info");
    const char *cmd = json_string_value(json_object_get(info, "command"));
    const char *seq = json_string_value(json_object_get(info, "sequence_id"));
    if (cmd && strcmp(cmd, "get_version") == 0 && seq && strcmp(seq, f->want) == 0)
        f->got = true;
    json_decref(j);
}

/* Connect f to the broker as another MQTT client (a fake printer, or a second client). */
static bool
fake_connect(struct run *r, struct fake *f, const char *client_id)
{
    struct sf_err err;
    char ca[600];
    snprintf(ca, sizeof(ca), "%s/ca.pem", certs);
    struct mqttloop_config mc = { .host = "127.0.0.1",
                                  .port = broker_port,
                                  .client_id = client_id,
                                  .user = "bblp",
                                  .password = CODE,
                                  .ca_file = ca,
                                  .tls_name = SERIAL,
                                  .on_up = fake_up,
                                  .on_down = fake_down,
                                  .on_message = fake_msg,
                                  .ud = f };
    f->m = mqttloop_new(r->loop, &mc, &err);
    return f->m && mqttloop_connect(f->m, &err) == SF_OK;
}

static uint64_t
reports_of(struct drv *d)
{
    struct drv_bambu_stats bs;
    drv_bambu_stats(d, &bs);
    return bs.reports;
}

/* Publish one report and run the loop until the driver has merged it. */
static bool
fake_report(struct run *r, struct fake *f, const char *json)
{
    uint64_t n = reports_of(r->drv);
    mqttloop_publish(f->m, "device/" SERIAL "/report", json, strlen(json), NULL);
    return WAIT_FOR(r, reports_of(r->drv) > n);
}

/*
 * mc_remaining_time (minutes) becomes status.time_left_s while the printer
 * prints: from an X1's whole report, kept across a P1 delta that leaves it
 * out, replaced by the next delta that has it (a number or, as some
 * firmware sends it, a string), and gone once the print ended.
 */
T_CASE(bambu_time_left_from_full_and_delta_reports)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    struct run r;
    struct sf_err err;
    bare_run(&r);
    T_OK(open_driver(&r, &(struct setup){ 0 }, broker_port, 1, &err), &err);
    struct fake f = { 0 };
    T_TRUE(fake_connect(&r, &f, "test-printer"));
    struct drv_bambu_stats bs;
    T_TRUE(WAIT_FOR(&r, f.up && (drv_bambu_stats(r.drv, &bs), bs.connects == 1)));
    /* The driver's subscription may reach the broker after a first report: send the
       whole report until one is merged (the same one each time). */
    static const char full[] =
        "{\"print\":{\"command\":\"push_status\",\"msg\":0,\"gcode_state\":\"RUNNING\","
        "\"mc_percent\":10,\"mc_remaining_time\":42,\"subtask_name\":\"elsewhere\"}}";
    int64_t end = wall_ms() + WAIT_MS;
    while (reports_of(r.drv) == 0 && wall_ms() < end) {
        mqttloop_publish(f.m, "device/" SERIAL "/report", full, strlen(full), NULL);
        for (int i = 0; i < 4 && reports_of(r.drv) == 0; i++)
            loop_run_once(r.loop, 50);
    }
    T_TRUE(reports_of(r.drv) > 0);
    T_TRUE(r.drv->status.has_time_left);
    T_EQ_INT(r.drv->status.time_left_s, 42 * 60);
    T_TRUE(fake_report(&r, &f,
                       "{\"print\":{\"command\":\"push_status\",\"msg\":1,"
                       "\"mc_percent\":20}}"));
    T_TRUE(r.drv->status.has_time_left);
    T_EQ_INT(r.drv->status.time_left_s, 42 * 60); /* kept */
    T_TRUE(fake_report(&r, &f,
                       "{\"print\":{\"command\":\"push_status\",\"msg\":1,"
                       "\"mc_percent\":80,\"mc_remaining_time\":7}}"));
    T_EQ_INT(r.drv->status.time_left_s, 7 * 60);
    T_TRUE(fake_report(&r, &f,
                       "{\"print\":{\"command\":\"push_status\",\"msg\":1,"
                       "\"gcode_state\":\"PAUSE\",\"mc_remaining_time\":\"5\"}}"));
    T_TRUE(r.drv->status.has_time_left);
    T_EQ_INT(r.drv->status.time_left_s, 5 * 60);
    T_TRUE(fake_report(&r, &f,
                       "{\"print\":{\"command\":\"push_status\",\"msg\":1,"
                       "\"mc_remaining_time\":-3}}"));
    T_TRUE(!r.drv->status.has_time_left); /* nonsense is no estimate */
    T_TRUE(fake_report(&r, &f,
                       "{\"print\":{\"command\":\"push_status\",\"msg\":1,"
                       "\"mc_remaining_time\":3}}"));
    T_EQ_INT(r.drv->status.time_left_s, 3 * 60);
    T_TRUE(fake_report(&r, &f,
                       "{\"print\":{\"command\":\"push_status\",\"msg\":1,"
                       "\"gcode_state\":\"FINISH\",\"mc_percent\":100,"
                       "\"mc_remaining_time\":0}}"));
    T_TRUE(!r.drv->status.has_time_left);
    mqttloop_free(f.m);
    drv_free(r.drv);
    loop_free(r.loop);
}

T_CASE(bambu_pause_resume_then_done)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    struct run r;
    T_TRUE(started(&r, &(struct setup){ .speed = 30, .pause_at = 20 }, 10, 100));
    T_TRUE(WAIT_FOR(&r, r.drv->status.state == DRV_PAUSED));
    /* Paused at the printer: the machine runs nothing over many reports. */
    struct sim_bambu_stats a, b;
    sim_bambu_stats(r.sim, &a);
    T_EQ_STR(a.gcode_state, "PAUSE");
    struct drv_bambu_stats bs0, bs1;
    drv_bambu_stats(r.drv, &bs0);
    T_TRUE(WAIT_FOR(&r, (drv_bambu_stats(r.drv, &bs1), bs1.reports >= bs0.reports + 5)));
    sim_bambu_stats(r.sim, &b);
    T_EQ_INT(b.executed, a.executed);
    T_TRUE(a.executed < 1000);
    struct sf_err err;
    T_OK(r.drv->ops->resume(r.drv, &err), &err);
    T_TRUE(WAIT_FOR(&r, r.drv->status.state == DRV_PRINTING || r.done));
    T_TRUE(WAIT_FOR(&r, r.done || r.failed));
    T_EQ_INT(r.done, 1);
    T_TRUE(ran_the_file(&r));
}

T_CASE(bambu_stop_cancels)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    struct run r;
    T_TRUE(started(&r, &(struct setup){ .speed = 30, .cancel_at = 10 }, 10, 100));
    T_TRUE(WAIT_FOR(&r, r.cancelled || r.done || r.failed));
    T_EQ_INT(r.cancelled, 1);
    T_EQ_INT(r.done + r.failed, 0);
    T_EQ_INT(r.drv->status.state, DRV_IDLE);
    struct sim_bambu_stats ss;
    sim_bambu_stats(r.sim, &ss);
    T_EQ_STR(ss.gcode_state, "FAILED");
    T_TRUE(ss.executed < 1000 + 13);
    teardown(&r);
    /* What ran is a prefix of the file, each line once, then the machine's cancel script. */
    char *want = commands_of(r.gcode_path), *got = slurp(r.log_path);
    static const char script[] = "M104 S0\nM140 S0\nM107\nM84\n"; /* sim_netprinter's */
    size_t gl = strlen(got), sl = strlen(script);
    T_TRUE(gl > sl && strcmp(got + gl - sl, script) == 0);
    T_TRUE(gl - sl < strlen(want) && strncmp(want, got, gl - sl) == 0);
    T_TRUE(gl - sl > 200); /* it printed a while before the stop */
    free(want);
    free(got);
}

T_CASE(bambu_manual_command_runs)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    struct run r;
    T_TRUE(ready(&r, &(struct setup){ 0 }));
    struct sf_err err;
    T_OK(r.drv->ops->command(r.drv, "M104 S180", &err), &err);
    T_TRUE(WAIT_FOR(&r, r.drv->status.nozzle_target_c == 180));
    teardown(&r);
    char *got = slurp(r.log_path);
    T_EQ_STR(got, "M104 S180\n");
    free(got);
}

T_CASE(bambu_wrong_access_code_is_an_auth_error)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    refused(&(struct setup){ .code = "00000000" }, "authentication failed", "access_code");
}

/* Warnings of printer bambu1, for the tls_insecure case. */
struct warned {
    int n;
    char text[300];
};

static void
catch_warning(void *ud, enum log_level level, const char *subsys, const char *printer,
              const char *msg)
{
    (void)subsys;
    struct warned *w = ud;
    if (level == LOG_WARN && printer && strcmp(printer, "bambu1") == 0) {
        w->n++;
        snprintf(w->text, sizeof(w->text), "%s", msg);
    }
}

T_CASE(bambu_wrong_ca_is_a_tls_error_and_insecure_connects)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    refused(&(struct setup){ .ca = "other-ca.pem" }, "TLS", "certificate");
    struct run r;
    /* tls_insecure: the operator's override connects (and prints), with a warning */
    struct setup s2 = { .ca = "other-ca.pem", .insecure = true, .speed = 300 };
    struct warned w = { 0 };
    log_set_sink(catch_warning, &w);
    int rc = setup(&r, &s2);
    log_set_sink(NULL, NULL);
    T_EQ_INT(rc, 0);
    T_EQ_INT(w.n, 1);
    T_TRUE(strstr(w.text, "tls_insecure") != NULL);
    T_TRUE(strstr(w.text, "not checked") != NULL);
    T_TRUE(WAIT_FOR(&r, idle(&r)));
    struct sf_err err;
    T_OK(start(&r, 2, 20, &err), &err);
    T_TRUE(WAIT_FOR(&r, r.done || r.failed));
    T_EQ_INT(r.done, 1);
    teardown(&r);
}

T_CASE(bambu_certificate_of_another_serial_is_a_tls_error)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    /* the message names the name it expected, and what the printer showed */
    refused(&(struct setup){ .serial = "01S00FFFFFFFFFF" }, "TLS (MQTT)", "mismatch");
    refused(&(struct setup){ .serial = "01S00FFFFFFFFFF" },
            "expected a certificate for "
            "CN=01S00FFFFFFFFFF",
            "CN=" SERIAL);
}

/* The same for the upload: MQTT is the printer, FTPS shows another printer's certificate
   (same CA, CN 01S00OTHER00000); the job fails, the printer waits in error for the operator
   with the expected name in its message, and nothing reached the printer's storage. */
T_CASE(bambu_ftps_certificate_of_another_serial_is_a_tls_error)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    struct run r;
    T_TRUE(started(&r, &(struct setup){ .fault = "ftps-wrong-cert" }, 2, 20));
    T_TRUE(WAIT_FOR(&r, r.failed || r.done));
    T_EQ_INT(r.failed, 1);
    T_EQ_INT(r.drv->status.state, DRV_ERROR);
    const char *m = r.drv->status.message;
    fprintf(stderr, "message: %s\n", m);
    T_TRUE(strstr(m, "TLS (FTPS upload)") != NULL);
    T_TRUE(strstr(m, "expected a certificate for CN=" SERIAL) != NULL);
    T_TRUE(strstr(m, "01S00OTHER00000") != NULL);
    T_EQ_STR(r.failed_msg, m);
    struct sim_bambu_stats ss;
    sim_bambu_stats(r.sim, &ss);
    T_EQ_INT(ss.uploads, 0);
    T_EQ_INT(ss.jobs_started, 0);
    teardown(&r);
}

T_CASE(bambu_unsigned_refusal_says_developer_mode)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    struct run r;
    /* status works without Developer Mode: the printer comes up idle */
    T_TRUE(started(&r, &(struct setup){ .fault = "unsigned" }, 2, 20));
    T_TRUE(WAIT_FOR(&r, r.failed));
    T_EQ_INT(r.drv->status.state, DRV_ERROR);
    T_TRUE(strstr(r.failed_msg, "Developer Mode") != NULL);
    T_TRUE(strstr(r.drv->status.message, "LAN Only") != NULL);
    teardown(&r);
}

T_CASE(bambu_hms_failure_and_stop_at_printer)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    struct run r;
    T_TRUE(
        started(&r, &(struct setup){ .fault = "hms=0300010000010007@30", .speed = 100 }, 10, 100));
    T_TRUE(WAIT_FOR(&r, r.failed || r.done));
    T_EQ_INT(r.failed, 1);
    T_TRUE(strstr(r.failed_msg, "HMS 0300-0100-0001-0007") != NULL);
    T_EQ_INT(r.drv->status.state, DRV_IDLE);
    teardown(&r);
    T_TRUE(started(&r, &(struct setup){ .fault = "stop-at=40", .speed = 100 }, 10, 100));
    T_TRUE(WAIT_FOR(&r, r.failed || r.done));
    T_EQ_INT(r.failed, 1);
    T_TRUE(strstr(r.failed_msg, "stopped at the printer") != NULL);
    teardown(&r);
}

T_CASE(bambu_storage_full_fails_the_job)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    struct run r;
    T_TRUE(started(&r, &(struct setup){ .fault = "storage-full" }, 2, 20));
    T_TRUE(WAIT_FOR(&r, r.failed || r.done));
    T_EQ_INT(r.failed, 1);
    T_TRUE(strstr(r.failed_msg, "upload") != NULL);
    T_EQ_INT(r.drv->status.state, DRV_IDLE);
    teardown(&r);
}

/*
 * The FTPS server's 227 is already there when the driver's PASV goes out
 * (the simulator sends it with the PWD reply): libcurl 7.88 then ends its DO
 * phase within one call and waits for a data socket it has not opened, so
 * on the old httpc every such upload stalled until its connect timeout and
 * the job failed ("1 upload in 6 stalls after PASV" in the daemon, where a
 * loaded loop let the real answer arrive first).  httpc nudges the transfer
 * (httpc.c, nudge()); both jobs upload and finish.
 */
T_CASE(bambu_upload_goes_on_when_the_pasv_answer_is_already_there)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    struct run r;
    T_TRUE(ready(&r, &(struct setup){ .fault = "pasv-early", .speed = 300 }));
    write_job(&r, 2, 20);
    struct sf_err err;
    for (int i = 1; i <= 2; i++) {
        T_OK(r.drv->ops->start_job(r.drv, r.gcode_path, 0, NULL, &err), &err);
        T_TRUE(WAIT_FOR(&r, r.done == i || r.failed));
        if (r.failed)
            fprintf(stderr, "job %d failed: %s\n", i, r.failed_msg);
        T_EQ_INT(r.failed, 0);
    }
    struct sim_bambu_stats ss;
    sim_bambu_stats(r.sim, &ss);
    T_EQ_INT(ss.uploads, 2);
    T_EQ_INT(ss.jobs_finished, 2);
    teardown(&r);
}

/*
 * A printer slow to answer on the FTPS control connection: libcurl 7.88
 * starts the data connection's TLS as soon as its TCP is up and then polls
 * only that socket, while the server starts that TLS after STOR; the reply
 * to TYPE I, a moment late, was never read and the upload failed with "SSL
 * connection timeout" (farmd_bambu_crash's second job).  httpc kicks FTP
 * transfers during set-up (httpc.c, on_kick()); the job prints.
 */
T_CASE(bambu_upload_to_a_printer_slow_to_answer)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    struct run r;
    T_TRUE(started(&r, &(struct setup){ .fault = "ftps-slow=200", .speed = 300 }, 2, 20));
    T_TRUE(WAIT_FOR(&r, r.done || r.failed));
    if (r.failed)
        fprintf(stderr, "job failed: %s\n", r.failed_msg);
    T_EQ_INT(r.failed, 0);
    T_EQ_INT(r.done, 1);
    teardown(&r);
}

/*
 * Upload progress in the printer's message, as the HTTP drivers show it:
 * "uploading N %", rising.  The package (about 2 MB) is some thirty times
 * libcurl's 64 kB upload buffer, and curl reports progress after each
 * buffer it sends, so percentages strictly between 0 and 100 are shown
 * whatever the machine's speed (the driver counts them: upload_steps); the
 * simulator takes the data in slowly (ftps-slow), so the looks the test
 * takes between loop turns see the message move too.
 */
T_CASE(bambu_upload_progress_rises_in_the_message)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    struct run r;
    T_TRUE(ready(&r, &(struct setup){ .fault = "ftps-slow=100", .speed = 300 }));
    write_job_pad(&r, 2, 20, 4 << 20);
    struct sf_err err;
    T_OK(r.drv->ops->start_job(r.drv, r.gcode_path, 0, NULL, &err), &err);
    int last = -1, looks = 0;
    bool rising = true;
    int64_t end = wall_ms() + WAIT_MS;
    while (!r.done && !r.failed && wall_ms() < end) {
        loop_run_once(r.loop, 50);
        int pct;
        if (sscanf(r.drv->status.message, "uploading %d %%", &pct) == 1) {
            rising = rising && pct >= last && pct <= 100;
            looks += pct != last;
            last = pct;
        }
    }
    if (r.failed)
        fprintf(stderr, "job failed: %s\n", r.failed_msg);
    T_EQ_INT(r.done, 1);
    T_TRUE(rising);
    T_TRUE(looks >= 1);
    struct drv_bambu_stats bs;
    T_TRUE(drv_bambu_stats(r.drv, &bs));
    T_EQ_INT(bs.upload_pct, 100);
    T_TRUE(bs.upload_steps >= 1);
    T_EQ_STR(r.drv->status.message, ""); /* printed: the upload's words are gone */
    fprintf(stderr, "upload: %llu percentages shown between 0 and 100, %d seen between turns\n",
            (unsigned long long)bs.upload_steps, looks);
    T_TRUE(ran_the_file(&r));
}

/* The TLS data connection dies mid-upload: the job fails with the upload's error (the farm
   retries it), the printer is idle again, nothing was started or stored half; the next
   upload (the fault strikes once) prints the file whole. */
T_CASE(bambu_upload_cut_midway_fails_the_job_cleanly)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    struct run r;
    /* packed, the job is well over 1000 bytes */
    T_TRUE(started(&r, &(struct setup){ .fault = "ftps-drop=1000", .speed = 300 }, 20, 100));
    T_TRUE(WAIT_FOR(&r, r.failed || r.done));
    T_EQ_INT(r.failed, 1);
    T_TRUE(strstr(r.failed_msg, "upload failed") != NULL);
    T_TRUE(WAIT_FOR(&r, idle(&r)));
    struct sim_bambu_stats ss;
    sim_bambu_stats(r.sim, &ss);
    T_EQ_INT(ss.uploads, 0);
    T_EQ_INT(ss.jobs_started, 0);
    /* and the printer takes the next job */
    struct sf_err err;
    T_OK(r.drv->ops->start_job(r.drv, r.gcode_path, 0, NULL, &err), &err);
    T_TRUE(WAIT_FOR(&r, r.failed == 2 || r.done));
    T_EQ_INT(r.failed, 1);
    T_EQ_INT(r.done, 1);
    sim_bambu_stats(r.sim, &ss);
    T_EQ_INT(ss.uploads, 1);
    T_EQ_INT(ss.jobs_started, 1);
    T_TRUE(ran_the_file(&r));
}

T_CASE(bambu_ftps_refuses_data_without_session_reuse)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    T_SKIP_UNLESS(access("/usr/bin/curl", X_OK) == 0, "curl missing");
    struct run r;
    T_EQ_INT(setup(&r, &(struct setup){ 0 }), 0);
    int port = sim_bambu_ftps_port(r.sim);
    char file[600], cmd[2048];
    snprintf(file, sizeof(file), "%s/probe.gcode", t_tmpdir());
    FILE *f = fopen(file, "w");
    fputs("G28\n", f);
    fclose(f);
    /* The FTPS server runs on its own thread, so curl can run while the loop waits. */
    snprintf(cmd, sizeof(cmd),
             "curl -sS --no-sessionid --cacert %s/ca.pem --resolve %s:%d:127.0.0.1 --ssl-reqd "
             "-u bblp:%s -T %s ftps://%s:%d/probe.gcode 2>&1",
             certs, SERIAL, port, CODE, file, SERIAL, port);
    T_TRUE(run(cmd, NULL, 0) != 0);
    /* the same with the session cache on succeeds */
    snprintf(cmd, sizeof(cmd),
             "curl -sS --cacert %s/ca.pem --resolve %s:%d:127.0.0.1 --ssl-reqd "
             "-u bblp:%s -T %s ftps://%s:%d/probe.gcode 2>&1",
             certs, SERIAL, port, CODE, file, SERIAL, port);
    T_EQ_INT(run(cmd, NULL, 0), 0);
    struct sim_bambu_stats ss;
    sim_bambu_stats(r.sim, &ss);
    T_EQ_INT(ss.refused_reuse, 1);
    T_EQ_INT(ss.uploads, 1);
    teardown(&r);
}

/*
 * LIST as the printer's vsFTPd answers it (issue 35): clients list the root
 * to check the connection and find files ("LIST", "LIST /", "LIST -a /"),
 * over a data connection that must resume the control session like STOR's;
 * STRU F is accepted.  curl lists a URL ending in '/' with LIST, -X sets
 * the list command, -Q sends a command first.
 */
T_CASE(bambu_ftps_lists_files_as_vsftpd)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    T_SKIP_UNLESS(access("/usr/bin/curl", X_OK) == 0, "curl missing");
    struct run r;
    T_EQ_INT(setup(&r, &(struct setup){ 0 }), 0);
    int port = sim_bambu_ftps_port(r.sim);
    char file[600], base[1024], cmd[2048], out[4096];
    snprintf(file, sizeof(file), "%s/listed.gcode", t_tmpdir());
    FILE *f = fopen(file, "w");
    fputs("G28\n", f);
    fclose(f);
    snprintf(base, sizeof(base),
             "curl -sS --cacert %s/ca.pem --resolve %s:%d:127.0.0.1 --ssl-reqd -u bblp:%s", certs,
             SERIAL, port, CODE);
    snprintf(cmd, sizeof(cmd), "%s -Q 'STRU F' -T %s ftps://%s:%d/listed.gcode 2>&1", base, file,
             SERIAL, port);
    T_EQ_INT(run(cmd, out, sizeof(out)), 0);
    const char *lists[] = { "", "-X 'LIST /'", "-X 'LIST -a /'" };
    for (int i = 0; i < 3; i++) {
        snprintf(cmd, sizeof(cmd), "%s %s ftps://%s:%d/ 2>&1", base, lists[i], SERIAL, port);
        T_EQ_INT(run(cmd, out, sizeof(out)), 0);
        T_TRUE(strstr(out, "-rw-r--r--    1 0        0               4 ") != NULL);
        /* vsFTPd ends lines with CRLF; curl's ASCII listing turns them to LF */
        T_TRUE(strstr(out, " listed.gcode\n") != NULL || strstr(out, " listed.gcode\r\n") != NULL);
    }
    /* without session reuse the listing is refused, as an upload is */
    snprintf(cmd, sizeof(cmd), "%s --no-sessionid ftps://%s:%d/ 2>&1", base, SERIAL, port);
    T_TRUE(run(cmd, out, sizeof(out)) != 0);
    struct sim_bambu_stats ss;
    sim_bambu_stats(r.sim, &ss);
    T_EQ_INT(ss.refused_reuse, 1);
    T_EQ_INT(ss.uploads, 1);
    teardown(&r);
}

/* Ask get_version with sequence_id seq_json (JSON text) until a reply carries want. */
static bool
ask_version(struct run *r, struct fake *e, const char *seq_json, const char *want)
{
    char req[160];
    snprintf(req, sizeof(req), "{\"info\":{\"command\":\"get_version\",\"sequence_id\":%s}}",
             seq_json);
    e->want = want;
    e->got = false;
    int64_t end = wall_ms() + WAIT_MS;
    while (!e->got && wall_ms() < end) {
        mqttloop_publish(e->m, "device/" SERIAL "/request", req, strlen(req), NULL);
        for (int i = 0; i < 4 && !e->got; i++)
            loop_run_once(r->loop, 50);
    }
    return e->got;
}

/* The printer's replies echo the request's sequence_id, a string or a number (issue 35). */
T_CASE(bambu_replies_echo_the_sequence_id)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    struct run r;
    T_EQ_INT(setup(&r, &(struct setup){ 0 }), 0);
    struct fake e = { 0 };
    struct sf_err err;
    T_TRUE(fake_connect(&r, &e, "test-client"));
    T_TRUE(WAIT_FOR(&r, e.up));
    T_OK(mqttloop_subscribe(e.m, "device/" SERIAL "/report", &err), &err);
    T_TRUE(ask_version(&r, &e, "\"4711\"", "4711"));
    T_TRUE(ask_version(&r, &e, "20002", "20002"));
    mqttloop_free(e.m);
    teardown(&r);
}

/*
 * pushall is rate-limited (P1 printers dislike it): once per connection,
 * never twice within PUSHALL_RECONNECT_MS (10 s) on a flapping link.  The
 * link is dropped and re-opened three times in a row (the farm's
 * reconnect does close + open); the printer sees the first connection's
 * pushall and one more, sent when the 10 s are up, whatever the machine's
 * speed (the gap is taken on the loop's clock as they are sent).
 */
T_CASE(bambu_pushall_is_rate_limited_on_a_flapping_link)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    struct run r;
    T_TRUE(ready(&r, &(struct setup){ .p1 = true }));
    /* The printer may have subscribed after the driver's first pushall (the
       sim and the driver connect to the broker side by side): count from here. */
    struct sim_bambu_stats ss;
    sim_bambu_stats(r.sim, &ss);
    uint64_t seen = ss.pushalls;
    struct sf_err err;
    struct drv_bambu_stats bs;
    for (int i = 0; i < 3; i++) {
        r.drv->ops->close(r.drv);
        T_OK(r.drv->ops->open(r.drv, &err), &err);
        T_TRUE(WAIT_FOR(&r, idle(&r)));
    }
    T_TRUE(drv_bambu_stats(r.drv, &bs));
    T_EQ_INT(bs.connects, 4);
    T_TRUE(WAIT_FOR(&r, (sim_bambu_stats(r.sim, &ss), ss.pushalls >= seen + 1)));
    int64_t until = wall_ms() + 1000; /* nothing more follows */
    while (wall_ms() < until)
        loop_run_once(r.loop, 50);
    sim_bambu_stats(r.sim, &ss);
    T_TRUE(drv_bambu_stats(r.drv, &bs));
    T_EQ_INT(ss.pushalls, seen + 1);
    T_EQ_INT(bs.pushalls, 2);
    T_TRUE(bs.pushall_gap_ms >= 10000); /* as sent; the printer saw them 10 s apart give or
                                           take the broker's delivery */
    teardown(&r);
}

/* The owner's reconnect (the farm's backoff) until the link is up again; the attempts. */
static int
reconnect(struct run *r)
{
    int attempt = 0;
    int64_t end = wall_ms() + WAIT_MS;
    while (r->drv->status.state == DRV_OFFLINE && wall_ms() < end) {
        int64_t next = wall_ms() + drv_backoff_ms(attempt++);
        r->drv->ops->open(r->drv, NULL);
        while (wall_ms() < next && r->drv->status.state != DRV_OFFLINE && !r->done)
            loop_run_once(r->loop, 50);
        while (wall_ms() < next && r->drv->status.state == DRV_OFFLINE)
            loop_run_once(r->loop, 50);
    }
    return attempt;
}

/*
 * The printer's MQTT goes away mid-print (fault mqtt-drop: after 10 reports
 * sent while printing, its own link and the driver's, through the
 * printer's port, are cut, and the port refuses for half a second).  The
 * driver goes offline with the job kept, reconnects with the farm's
 * backoff, picks the job up from the reports and sees it done; the
 * machine ran the file once.
 */
T_CASE(bambu_mqtt_drop_mid_print_reconnects_and_job_ends_done)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    struct run r;
    /* a job of a few seconds: the drop comes early in it */
    T_TRUE(started(&r, &(struct setup){ .speed = 30, .fault = "mqtt-drop=10", .via_printer = true },
                   20, 100));
    T_TRUE(WAIT_FOR(&r, r.drv->status.state == DRV_OFFLINE || r.done || r.failed));
    T_EQ_INT(r.drv->status.state, DRV_OFFLINE);
    T_EQ_INT(r.done + r.failed, 0);
    T_TRUE(reconnect(&r) >= 1);
    T_TRUE(WAIT_FOR(&r, r.done || r.failed));
    if (r.failed)
        fprintf(stderr, "job failed: %s\n", r.failed_msg);
    T_EQ_INT(r.failed, 0);
    T_EQ_INT(r.done, 1);
    T_EQ_INT(r.drv->status.state, DRV_IDLE);
    struct drv_bambu_stats bs;
    T_TRUE(drv_bambu_stats(r.drv, &bs));
    T_TRUE(bs.connects >= 2);
    T_EQ_INT(bs.uploads, 1);
    struct sim_bambu_stats ss;
    sim_bambu_stats(r.sim, &ss);
    T_EQ_INT(ss.mqtt_drops, 1);
    T_TRUE(ss.mqtt_connects >= 2);
    T_TRUE(ss.mqtt_clients >= 2); /* the driver came back through the printer's port */
    T_EQ_INT(ss.jobs_started, 1);
    T_EQ_INT(ss.jobs_finished, 1);
    T_TRUE(ran_the_file(&r));
}

/* A port that reads a client's first bytes (its TLS hello) and hangs up, as a
   printer's MQTT port does while the broker behind it comes back up. */
static void
read_and_close(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)events;
    int *n = ud;
    char buf[4096];
    if (recv(fd, buf, sizeof(buf), 0) > 0)
        (*n)++;
    loop_del_fd(l, fd);
    close(fd);
}

static void
accept_hello(struct loop *l, int fd, unsigned events, void *ud)
{
    (void)events;
    int c = accept(fd, NULL, NULL);
    if (c >= 0 && loop_add_fd(l, c, LOOP_READ, read_and_close, ud, NULL) != SF_OK)
        close(c);
}

/* A TLS handshake the other end cuts short is a lost connection (offline: the
   farm connects again), not a certificate the operator must fix (error). */
T_CASE(bambu_tls_handshake_cut_short_is_offline_not_an_error)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    struct run r;
    struct sf_err err;
    bare_run(&r);
    int ls = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in a = { .sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK) };
    socklen_t al = sizeof(a);
    T_TRUE(ls >= 0 && bind(ls, (struct sockaddr *)&a, sizeof(a)) == 0 && listen(ls, 8) == 0 &&
           getsockname(ls, (struct sockaddr *)&a, &al) == 0);
    int hellos = 0;
    T_OK(loop_add_fd(r.loop, ls, LOOP_READ, accept_hello, &hellos, &err), &err);
    T_EQ_INT(open_driver(&r, &(struct setup){ 0 }, ntohs(a.sin_port), 1, &err), 0);
    T_TRUE(WAIT_FOR(&r, hellos > 0 && r.drv->status.state != DRV_CONNECTING));
    printf("    %s\n", r.drv->status.message);
    T_EQ_INT(r.drv->status.state, DRV_OFFLINE);
    T_TRUE(strstr(r.drv->status.message, "handshake cut short") != NULL);
    loop_del_fd(r.loop, ls);
    close(ls);
    teardown(&r);
}

T_CASE(bambu_broker_restart_offline_then_job_finishes)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    struct run r;
    T_TRUE(started(&r, &(struct setup){ .speed = 30, .p1 = true }, 10, 100));
    T_TRUE(WAIT_FOR(&r, r.drv->status.progress >= 0.1));
    int port = broker_port;
    stop_broker();
    T_TRUE(WAIT_FOR(&r, r.drv->status.state == DRV_OFFLINE));
    T_EQ_INT(r.failed + r.done, 0);
    T_EQ_INT(start_broker(port), 0);
    T_TRUE(reconnect(&r) >= 1);
    T_TRUE(WAIT_FOR(&r, r.done || r.failed));
    T_EQ_INT(r.failed, 0);
    T_EQ_INT(r.done, 1);
    T_TRUE(ran_the_file(&r));
}

/* The daemon dies mid-print (its driver goes away); the printer prints on; a new driver
   re-attaches from the report and sees the job to its end. */
T_CASE(bambu_reattach_after_restart)
{
    T_SKIP_UNLESS(env_ready(), "mosquitto or openssl missing");
    struct run r;
    T_TRUE(started(&r, &(struct setup){ .speed = 30, .p1 = true }, 10, 100));
    T_TRUE(WAIT_FOR(&r, r.drv->status.progress >= 0.1));
    drv_free(r.drv); /* the daemon is gone */
    r.drv = NULL;
    struct sf_err err;
    T_OK(open_driver(&r, &(struct setup){ 0 }, broker_port, sim_bambu_ftps_port(r.sim), &err),
         &err);
    T_TRUE(
        WAIT_FOR(&r, r.drv->status.state != DRV_CONNECTING && r.drv->status.state != DRV_OFFLINE));
    T_EQ_INT(r.drv->status.state, DRV_PRINTING); /* a job it did not start, so far */
    /* another file is not what the printer runs */
    char other[600];
    snprintf(other, sizeof(other), "%s/other.gcode", t_tmpdir());
    FILE *f = fopen(other, "w");
    fputs("G28\n", f);
    fclose(f);
    T_EQ_INT(r.drv->ops->attach(r.drv, other, NULL, &err), SF_ENOTFOUND);
    T_OK(r.drv->ops->attach(r.drv, r.gcode_path, NULL, &err), &err);
    T_TRUE(WAIT_FOR(&r, r.done || r.failed));
    T_EQ_INT(r.done, 1);
    T_EQ_INT(r.drv->status.state, DRV_IDLE);
    struct sim_bambu_stats ss;
    sim_bambu_stats(r.sim, &ss);
    T_EQ_INT(ss.jobs_started, 1);
    T_TRUE(ran_the_file(&r));
}
