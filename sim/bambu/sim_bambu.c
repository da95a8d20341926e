/*
 * sim_bambu.c - the Bambu LAN-mode printer simulator (sim_bambu.h).
 *
 * Why: the Bambu driver must be tested against the components a real
 * printer puts in its way (a broker that checks the access code, TLS with a
 * CN = serial certificate, FTPS that refuses a data connection without
 * session reuse, delta reports), not against a mirror of itself.
 *
 * Design: the printer's state is one struct of the report fields
 * (BAMBU-LAN.md section 4); a report is built from it, in full (X1, and
 * every pushall) or as the fields that changed since the last report
 * (P1).  Requests are parsed with jansson; each command answers on the
 * report topic with the same top-level key, command and sequence_id, and a
 * result.  The job runs on the machine, sim_netprinter (a sim_marlin and the
 * host streaming the plate to it, as the printer's own firmware does); its progress
 * moves mc_percent, layer_num and mc_remaining_time.
 *
 * Thread: loop thread; sim_ftps runs its own.
 */
#include "sim_bambu.h"

#include <errno.h>
#include <jansson.h>
#include <minizip/unzip.h>
#include <openssl/evp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <unistd.h>

#include "../../src/base/buf.h"
#include "../../src/base/log.h"
#include "../../src/base/mem.h"
#include "../../src/base/mqttloop.h"
#include "../net/sim_netprinter.h"
#include "sim_bambu_relay.h"
#include "sim_ftps.h"

#define GCODE_MAX    ((size_t)1 << 30)    /* a plate's G-code, unpacked */
#define PLATE_NAME   "sf-sim-plate.gcode" /* the unpacked plate, in the uploads dir */
#define REQUEST_MAX  (1 << 16)            /* a request message */
#define HMS_VERIFY   "0500050000010007"   /* "MQTT command verification failed" */
#define ERR_CANCELED 0x0300400C           /* print_error "task canceled" */
#define ERR_PARSE    0x05004003           /* 0500-4003 "unable to parse" (bad md5) */
#define ERR_BUSY     0x05004004           /* 0500-4004 busy */
#define ERR_VERIFY   0x05024007           /* err_code 84033543 on screen */
#define ERR_NO_FILE  0x0500400E           /* file not found (as seen by clients) */

/* The report's print object: what the printer tells. */
struct pstate {
    char gcode_state[16];
    int mc_percent;
    int mc_remaining_time; /* minutes */
    int layer_num, total_layer_num;
    char gcode_file[160];
    char subtask_name[160];
    int prepare_percent;
    double nozzle, nozzle_target, bed, bed_target;
    long long print_error;
    int stg_cur;
    char hms[17]; /* one HMS code, 16 hex digits, or "" */
};

struct sim_bambu {
    struct loop *loop;
    struct sim_bambu_config c;
    char serial[64], code[64];
    char topic_report[96], topic_request[96];
    char storage[512]; /* the machine's uploads directory: FTPS stores there */
    char ca[512], cert[512], key[512];
    char ftps_cert[512], ftps_key[512]; /* what FTPS presents: cert and key, or ftps-wrong-cert's */
    struct mqttloop *mqtt;
    struct sim_bambu_relay *relay; /* the printer's MQTT port, for clients (mqtt-drop cuts them) */
    long printing_reports;         /* reports published while a job ran (mqtt-drop counts them) */
    struct sim_ftps *ftps;
    struct pstate st;   /* now */
    struct pstate sent; /* as last reported (P1 deltas) */
    bool sent_valid;
    uint64_t report_timer, reconnect_timer;
    struct sim_bambu_stats stats;
    int64_t last_pushall_ms; /* loop time of the last pushall received */
    /* the job */
    char plate_path[600]; /* unpacked plate G-code */
    uint64_t *layer_at;   /* command index where layer i+1 starts */
    size_t n_layers;
    struct sim_netprinter *np; /* the machine: firmware and the host streaming the plate */
    bool stop_fired, hms_fired;
    bool job_on; /* a job of ours runs on np */
};

/* ---- reports ---- */

static void reconnect(struct loop *l, void *ud);

static json_t *
state_json(const struct pstate *p, const struct pstate *old)
{
    json_t *o = json_object();
#define F_STR(name, field)                                                                         \
    if (!old || strcmp(p->field, old->field) != 0)                                                 \
    json_object_set_new(o, name, json_string(p->field))
#define F_INT(name, field)                                                                         \
    if (!old || p->field != old->field)                                                            \
    json_object_set_new(o, name, json_integer((json_int_t)p->field))
#define F_DBL(name, field)                                                                         \
    if (!old || p->field != old->field)                                                            \
    json_object_set_new(o, name, json_real(p->field))
    F_STR("gcode_state", gcode_state);
    F_INT("mc_percent", mc_percent);
    F_INT("mc_remaining_time", mc_remaining_time);
    F_INT("layer_num", layer_num);
    F_INT("total_layer_num", total_layer_num);
    F_STR("gcode_file", gcode_file);
    F_STR("subtask_name", subtask_name);
    if (!old || p->prepare_percent != old->prepare_percent) {
        char pp[16];
        snprintf(pp, sizeof(pp), "%d", p->prepare_percent); /* a string on real printers */
        json_object_set_new(o, "gcode_file_prepare_percent", json_string(pp));
    }
    F_DBL("nozzle_temper", nozzle);
    F_DBL("nozzle_target_temper", nozzle_target);
    F_DBL("bed_temper", bed);
    F_DBL("bed_target_temper", bed_target);
    F_INT("print_error", print_error);
    F_INT("mc_print_error_code", print_error);
    F_INT("stg_cur", stg_cur);
    if (!old || strcmp(p->hms, old->hms) != 0) {
        json_t *arr = json_array();
        if (p->hms[0]) {
            char a[9], b[9];
            memcpy(a, p->hms, 8);
            a[8] = '\0';
            memcpy(b, p->hms + 8, 8);
            b[8] = '\0';
            json_array_append_new(arr,
                                  json_pack("{s:I,s:I}", "attr", (json_int_t)strtoll(a, NULL, 16),
                                            "code", (json_int_t)strtoll(b, NULL, 16)));
        }
        json_object_set_new(o, "hms", arr);
    }
#undef F_STR
#undef F_INT
#undef F_DBL
    return o;
}

static void
publish(struct sim_bambu *s, json_t *msg)
{
    char *text = json_dumps(msg, JSON_COMPACT);
    json_decref(msg);
    if (!text)
        return;
    if (mqttloop_publish(s->mqtt, s->topic_report, text, strlen(text), NULL) == SF_OK)
        s->stats.reports++;
    free(text);
    if (s->job_on)
        s->printing_reports++;
    if (s->c.faults.mqtt_drop > 0 && s->printing_reports >= s->c.faults.mqtt_drop &&
        mqttloop_is_up(s->mqtt)) {
        /* The printer's MQTT service goes away mid-print: its own link, and every client's
           through its port, which refuses until the service is back. */
        s->c.faults.mqtt_drop = 0; /* once */
        s->stats.mqtt_drops++;
        size_t cut = sim_bambu_relay_set_down(s->relay, true);
        log_info("sim-bambu", "fault: dropping MQTT (%zu client connection%s cut)", cut,
                 cut == 1 ? "" : "s");
        mqttloop_close(s->mqtt);
        s->sent_valid = false;
        loop_timer_cancel(s->loop, s->reconnect_timer);
        s->reconnect_timer = loop_timer_add(s->loop, 500, reconnect, s);
    }
}

/* A push_status report: full (X1, pushall) or the changed fields (P1). */
static void
report(struct sim_bambu *s, bool full)
{
    if (!mqttloop_is_up(s->mqtt))
        return;
    bool delta = s->c.p1 && !full && s->sent_valid;
    json_t *p = state_json(&s->st, delta ? &s->sent : NULL);
    if (delta && json_object_size(p) == 0) {
        json_decref(p);
        return;
    }
    static unsigned seq;
    char sq[16];
    snprintf(sq, sizeof(sq), "%u", ++seq);
    json_object_set_new(p, "command", json_string("push_status"));
    json_object_set_new(p, "msg", json_integer(delta ? 1 : 0));
    json_object_set_new(p, "sequence_id", json_string(sq));
    s->sent = s->st;
    s->sent_valid = true;
    publish(s, json_pack("{s:o}", "print", p));
}

static void
set_state(struct sim_bambu *s, const char *gs)
{
    if (strcmp(s->st.gcode_state, gs) == 0)
        return;
    snprintf(s->st.gcode_state, sizeof(s->st.gcode_state), "%s", gs);
    if (strcmp(gs, "FINISH") == 0)
        s->stats.jobs_finished++;
    s->st.stg_cur = strcmp(gs, "RUNNING") == 0 ? 0 : strcmp(gs, "PAUSE") == 0 ? 16 : 255;
    report(s, false);
}

/* Move the report fields along with the machine. */
static void
follow_machine(struct sim_bambu *s)
{
    struct sim_np_status ms;
    sim_netprinter_status(s->np, &ms);
    s->st.nozzle = ms.nozzle_c;
    s->st.nozzle_target = ms.nozzle_target_c;
    s->st.bed = ms.bed_c;
    s->st.bed_target = ms.bed_target_c;
    if (!s->job_on)
        return;
    s->stats.executed = ms.lines_done;
    double pct = 100.0 * ms.progress;
    s->st.mc_percent = (int)pct;
    size_t layer = 0;
    while (layer < s->n_layers && s->layer_at[layer] <= ms.lines_done)
        layer++;
    s->st.layer_num = (int)layer;
    s->st.mc_remaining_time = ms.time_left_s >= 0 ? (int)((ms.time_left_s + 59) / 60) : 0;
    switch (ms.state) {
    case SIM_NP_COMPLETE:
        s->job_on = false;
        s->st.mc_percent = 100;
        s->st.mc_remaining_time = 0;
        s->st.layer_num = s->st.total_layer_num;
        set_state(s, "FINISH");
        return;
    case SIM_NP_CANCELLED:
        s->job_on = false;
        s->st.print_error = ERR_CANCELED;
        set_state(s, "FAILED");
        return;
    case SIM_NP_ERROR:
        s->job_on = false;
        if (!s->st.print_error)
            s->st.print_error = 0x03008000; /* a machine fault with no HMS code of ours */
        log_info("sim-bambu", "machine: %s", ms.message);
        sim_netprinter_reset(s->np);
        set_state(s, "FAILED");
        return;
    case SIM_NP_PAUSING: /* still RUNNING: the line in flight finishes first */
        break;
    case SIM_NP_PAUSED:
        set_state(s, "PAUSE");
        break;
    case SIM_NP_PRINTING:
        set_state(s, "RUNNING");
        break;
    default:
        break;
    }
    if (ms.state != SIM_NP_PRINTING)
        return;
    if (s->c.faults.stop_at > 0 && !s->stop_fired && pct >= s->c.faults.stop_at) {
        s->stop_fired = true; /* someone presses stop on the screen */
        sim_netprinter_cancel(s->np, NULL);
        return;
    }
    if (s->c.faults.hms[0] && !s->hms_fired && pct >= s->c.faults.hms_at) {
        s->hms_fired = true;
        snprintf(s->st.hms, sizeof(s->st.hms), "%s", s->c.faults.hms);
        char a[5], b[5];
        memcpy(a, s->c.faults.hms, 4);
        a[4] = '\0';
        memcpy(b, s->c.faults.hms + 12, 4);
        b[4] = '\0';
        s->st.print_error = strtoll(a, NULL, 16) << 16 | strtoll(b, NULL, 16);
        sim_netprinter_fail(s->np, "HMS fault injected");
        follow_machine(s);
    }
}

static void
report_tick(struct loop *l, void *ud)
{
    struct sim_bambu *s = ud;
    follow_machine(s);
    report(s, false);
    s->report_timer = loop_timer_add(l, s->c.report_ms, report_tick, s);
}

/* ---- requests ---- */

static void
answer(struct sim_bambu *s, const char *key, const char *cmd, const char *seq, bool ok,
       const char *reason, json_t *extra)
{
    json_t *o = extra ? extra : json_object();
    json_object_set_new(o, "command", json_string(cmd));
    json_object_set_new(o, "sequence_id", json_string(seq));
    json_object_set_new(o, "result", json_string(ok ? "success" : "failed"));
    json_object_set_new(o, "reason", json_string(reason ? reason : ""));
    publish(s, json_pack("{s:o}", key, o));
}

/* "ftp://x.3mf", "ftp:///x.3mf", "file:///sdcard/x.3mf", "file:///mnt/sdcard/x.3mf" -> x.3mf */
static const char *
url_file(const char *url)
{
    static const char *const prefixes[] = { "ftp:///", "ftp://", "file:///mnt/sdcard/",
                                            "file:///sdcard/", "file:///" };
    for (size_t i = 0; i < sizeof(prefixes) / sizeof(prefixes[0]); i++)
        if (strncmp(url, prefixes[i], strlen(prefixes[i])) == 0)
            return url + strlen(prefixes[i]);
    return NULL;
}

static int
md5_file(const char *path, char out[33])
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return -1;
    EVP_MD_CTX *c = EVP_MD_CTX_new();
    EVP_DigestInit_ex(c, EVP_md5(), NULL);
    unsigned char b[16384];
    size_t n;
    while ((n = fread(b, 1, sizeof(b), f)) > 0)
        EVP_DigestUpdate(c, b, n);
    unsigned char d[16];
    unsigned dn = 0;
    EVP_DigestFinal_ex(c, d, &dn);
    EVP_MD_CTX_free(c);
    fclose(f);
    for (unsigned i = 0; i < 16; i++)
        snprintf(out + 2 * i, 3, "%02X", d[i]);
    return 0;
}

/* Unpack entry `param` of the package to s->plate_path and check its sidecar. */
static int
unpack_plate(struct sim_bambu *s, const char *pkg, const char *param, char *why, size_t n)
{
    unzFile z = unzOpen64(pkg);
    if (!z) {
        snprintf(why, n, "'%s' is not a 3MF (zip) package", pkg);
        return -1;
    }
    int rc = -1;
    FILE *out = NULL;
    EVP_MD_CTX *c = EVP_MD_CTX_new();
    EVP_DigestInit_ex(c, EVP_md5(), NULL);
    if (unzLocateFile(z, param, 1) != UNZ_OK || unzOpenCurrentFile(z) != UNZ_OK) {
        snprintf(why, n, "the package has no '%s'", param);
        goto out;
    }
    out = fopen(s->plate_path, "wb");
    if (!out) {
        snprintf(why, n, "cannot write '%s'", s->plate_path);
        unzCloseCurrentFile(z);
        goto out;
    }
    char b[16384];
    int r;
    size_t total = 0;
    while ((r = unzReadCurrentFile(z, b, sizeof(b))) > 0) {
        total += (size_t)r;
        if (total > GCODE_MAX || fwrite(b, 1, (size_t)r, out) != (size_t)r) {
            r = -1;
            break;
        }
        EVP_DigestUpdate(c, b, (size_t)r);
    }
    if (unzCloseCurrentFile(z) != UNZ_OK || r < 0) {
        snprintf(why, n, "'%s' in the package is damaged", param);
        goto out;
    }
    unsigned char d[16];
    unsigned dn = 0;
    EVP_DigestFinal_ex(c, d, &dn);
    char md5[33];
    for (unsigned i = 0; i < 16; i++)
        snprintf(md5 + 2 * i, 3, "%02X", d[i]);
    char side[160];
    snprintf(side, sizeof(side), "%s.md5", param);
    if (unzLocateFile(z, side, 1) == UNZ_OK && unzOpenCurrentFile(z) == UNZ_OK) {
        char want[64] = "";
        int k = unzReadCurrentFile(z, want, sizeof(want) - 1);
        unzCloseCurrentFile(z);
        want[k > 0 ? k : 0] = '\0';
        if (strcmp(want, md5) != 0) { /* uppercase, no newline: what the firmware compares */
            snprintf(why, n, "'%s' is '%s', the G-code's MD5 is %s", side, want, md5);
            goto out;
        }
    }
    rc = 0;
out:
    if (out)
        fclose(out);
    EVP_MD_CTX_free(c);
    unzClose(z);
    return rc;
}

/* Commands and layer starts of the plate, for progress. */
static void
scan_layers(struct sim_bambu *s)
{
    free(s->layer_at);
    s->layer_at = NULL;
    s->n_layers = 0;
    size_t cap = 0;
    FILE *f = fopen(s->plate_path, "r");
    if (!f)
        return;
    char line[4096];
    uint64_t cmds = 0;
    while (fgets(line, sizeof(line), f)) {
        const char *p = line + strspn(line, " \t");
        if (strncmp(p, ";LAYER_CHANGE", 13) == 0 || strncmp(p, ";LAYER:", 7) == 0) {
            if (mem_grow((void **)&s->layer_at, &cap, s->n_layers + 1, sizeof(uint64_t)))
                s->layer_at[s->n_layers++] = cmds;
            continue;
        }
        if (*p && *p != ';' && *p != '\n' && *p != '\r')
            cmds++;
    }
    fclose(f);
}

static void
do_project_file(struct sim_bambu *s, json_t *o, const char *seq)
{
    const char *gs = s->st.gcode_state;
    if (strcmp(gs, "IDLE") && strcmp(gs, "FINISH") && strcmp(gs, "FAILED")) {
        s->st.print_error = ERR_BUSY;
        answer(s, "print", "project_file", seq, false, "printer is busy", NULL);
        report(s, false);
        return;
    }
    const char *param = json_string_value(json_object_get(o, "param"));
    const char *url = json_string_value(json_object_get(o, "url"));
    const char *md5 = json_string_value(json_object_get(o, "md5"));
    const char *name = json_string_value(json_object_get(o, "subtask_name"));
    const char *file = url ? url_file(url) : NULL;
    char why[400] = "", pkg[800];
    if (!param || !file || !*file || strchr(file, '/') || file[0] == '.') {
        snprintf(why, sizeof(why), "bad param or url");
        goto failed_parse;
    }
    snprintf(pkg, sizeof(pkg), "%s/%s", s->storage, file);
    struct stat sb;
    if (stat(pkg, &sb) != 0) {
        s->st.print_error = ERR_NO_FILE;
        snprintf(why, sizeof(why), "no file '%s' on the storage", file);
        answer(s, "print", "project_file", seq, false, why, NULL);
        report(s, false);
        return;
    }
    if (md5 && *md5) {
        char have[33];
        if (md5_file(pkg, have) < 0 || strcasecmp(have, md5) != 0) {
            snprintf(why, sizeof(why), "md5 %s does not match the file's %s", md5, have);
            goto failed_parse;
        }
    }
    if (unpack_plate(s, pkg, param, why, sizeof(why)) < 0)
        goto failed_parse;
    scan_layers(s);
    struct sf_err err;
    if (sim_netprinter_start(s->np, PLATE_NAME, &err) < 0) {
        snprintf(why, sizeof(why), "%s", err.msg);
        goto failed_parse;
    }
    s->stats.jobs_started++;
    s->job_on = true;
    s->stop_fired = s->hms_fired = false;
    s->st.print_error = 0;
    s->st.hms[0] = '\0';
    s->st.mc_percent = 0;
    s->st.layer_num = 0;
    s->st.total_layer_num = (int)s->n_layers;
    snprintf(s->st.gcode_file, sizeof(s->st.gcode_file), "%s", file);
    snprintf(s->st.subtask_name, sizeof(s->st.subtask_name), "%s", name ? name : file);
    answer(s, "print", "project_file", seq, true, NULL, NULL);
    s->st.prepare_percent = 100;
    set_state(s, "PREPARE");
    set_state(s, "RUNNING");
    return;
failed_parse:
    log_info("sim-bambu", "project_file refused: %s", why);
    s->st.print_error = ERR_PARSE;
    answer(s, "print", "project_file", seq, false, why, NULL);
    set_state(s, "FAILED");
    report(s, false);
}

static bool
is_control(const char *cmd)
{
    static const char *const ctl[] = { "project_file", "gcode_file", "pause",       "resume",
                                       "stop",         "gcode_line", "print_speed", NULL };
    for (int i = 0; ctl[i]; i++)
        if (strcmp(cmd, ctl[i]) == 0)
            return true;
    return false;
}

static void
on_request(void *ud, const char *topic, const char *payload, size_t len)
{
    struct sim_bambu *s = ud;
    if (strcmp(topic, s->topic_request) != 0 || len > REQUEST_MAX)
        return;
    s->stats.requests++;
    json_error_t je;
    json_t *root = json_loadb(payload, len, 0, &je);
    if (!json_is_object(root)) {
        json_decref(root);
        return; /* firmware ignores what it cannot parse */
    }
    const char *key;
    json_t *o;
    json_object_foreach(root, key, o)
    {
        const char *cmd = json_string_value(json_object_get(o, "command"));
        json_t *sj = json_object_get(o, "sequence_id");
        const char *seq = json_string_value(sj);
        char num[32];
        if (!cmd)
            continue;
        if (json_is_integer(sj)) { /* some clients send a number: the reply echoes it */
            snprintf(num, sizeof(num), "%" JSON_INTEGER_FORMAT, json_integer_value(sj));
            seq = num;
        }
        if (!seq)
            seq = "0";
        if (strcmp(key, "pushing") == 0 && strcmp(cmd, "pushall") == 0) {
            /* A P1 dislikes them (OpenBambuAPI): the tests read how close they came. */
            int64_t now = loop_now_ms(s->loop);
            if (s->stats.pushalls > 0 &&
                (s->stats.pushall_gap_ms < 0 || now - s->last_pushall_ms < s->stats.pushall_gap_ms))
                s->stats.pushall_gap_ms = now - s->last_pushall_ms;
            s->stats.pushalls++;
            s->last_pushall_ms = now;
            follow_machine(s);
            report(s, true);
        } else if (strcmp(key, "info") == 0 && strcmp(cmd, "get_version") == 0) {
            json_t *mods = json_pack("[{s:s,s:s,s:s}]", "name", "ota", "sw_ver", "01.08.02.00",
                                     "sn", s->serial);
            json_t *ex = json_object();
            json_object_set_new(ex, "module", mods);
            answer(s, "info", cmd, seq, true, NULL, ex);
        } else if (strcmp(key, "print") == 0 && is_control(cmd) && s->c.faults.unsigned_refused) {
            s->stats.refused++;
            snprintf(s->st.hms, sizeof(s->st.hms), "%s", HMS_VERIFY);
            s->st.print_error = ERR_VERIFY;
            answer(s, key, cmd, seq, false, "mqtt message verify failed", NULL);
            report(s, false);
        } else if (strcmp(key, "print") == 0 && strcmp(cmd, "project_file") == 0) {
            do_project_file(s, o, seq);
        } else if (strcmp(key, "print") == 0 && strcmp(cmd, "pause") == 0) {
            bool ok = strcmp(s->st.gcode_state, "RUNNING") == 0 &&
                      sim_netprinter_pause(s->np, NULL) == SF_OK;
            /* PAUSE once the machine has stopped (follow_machine), as a
               printer reports it after the move in progress ends */
            answer(s, key, cmd, seq, ok, ok ? NULL : "not printing", NULL);
        } else if (strcmp(key, "print") == 0 && strcmp(cmd, "resume") == 0) {
            bool ok = strcmp(s->st.gcode_state, "PAUSE") == 0 &&
                      sim_netprinter_resume(s->np, NULL) == SF_OK;
            answer(s, key, cmd, seq, ok, ok ? NULL : "not paused", NULL);
            if (ok)
                set_state(s, "RUNNING");
        } else if (strcmp(key, "print") == 0 && strcmp(cmd, "stop") == 0) {
            bool active = strcmp(s->st.gcode_state, "RUNNING") == 0 ||
                          strcmp(s->st.gcode_state, "PAUSE") == 0 ||
                          strcmp(s->st.gcode_state, "PREPARE") == 0;
            /* FAILED (print_error "task canceled") once the machine has run its cancel
               script; follow_machine sees it. */
            if (active && s->job_on)
                sim_netprinter_cancel(s->np, NULL);
            answer(s, key, cmd, seq, true, NULL, NULL);
        } else if (strcmp(key, "print") == 0 && strcmp(cmd, "gcode_line") == 0) {
            const char *param = json_string_value(json_object_get(o, "param"));
            struct sf_err err;
            int rc = param ? SF_OK : SF_EINVAL;
            /* "G28\nM104 S0\n": one manual command per line, between job lines */
            for (const char *p = param; rc == SF_OK && p && *p;) {
                size_t n = strcspn(p, "\n");
                char line[256];
                if (n >= sizeof(line)) {
                    rc = SF_EINVAL;
                    break;
                }
                memcpy(line, p, n);
                line[n] = '\0';
                while (n && (line[n - 1] == '\r' || line[n - 1] == ' '))
                    line[--n] = '\0';
                if (n)
                    rc = sim_netprinter_command(s->np, line, &err);
                p += strcspn(p, "\n");
                if (*p)
                    p++;
            }
            answer(s, key, cmd, seq, rc == SF_OK, rc == SF_OK ? NULL : "bad gcode_line", NULL);
        } else {
            answer(s, key, cmd, seq, false, "unsupported command", NULL);
        }
    }
    json_decref(root);
}

/* ---- MQTT connection ---- */

static void
on_up(void *ud)
{
    struct sim_bambu *s = ud;
    s->stats.mqtt_connects++;
    log_info("sim-bambu", "broker: connected");
    struct sf_err err;
    if (mqttloop_subscribe(s->mqtt, s->topic_request, &err) < 0)
        log_warn("sim-bambu", "%s", err.msg);
    s->sent_valid = false;
    report(s, true);
}

static void
reconnect(struct loop *l, void *ud)
{
    (void)l;
    struct sim_bambu *s = ud;
    s->reconnect_timer = 0;
    sim_bambu_relay_set_down(s->relay, false);
    mqttloop_connect(s->mqtt, NULL);
}

static void
on_down(void *ud, int connack, bool tls, const char *why)
{
    (void)connack;
    (void)tls;
    struct sim_bambu *s = ud;
    log_info("sim-bambu", "broker: %s; retrying in 1 s", why);
    loop_timer_cancel(s->loop, s->reconnect_timer);
    s->reconnect_timer = loop_timer_add(s->loop, 1000, reconnect, s);
}

/* ---- lifecycle ---- */

void
sim_bambu_config_init(struct sim_bambu_config *c)
{
    memset(c, 0, sizeof(*c));
    c->mqtt_host = "127.0.0.1";
    c->speed = 1;
    c->report_ms = 1000;
}

static int
parse_pct(const char *v, double *out)
{
    char *end;
    double d = strtod(v, &end);
    if (end == v || *end || !(d >= 0 && d <= 100))
        return -1;
    *out = d;
    return 0;
}

int
sim_bambu_fault_parse(struct sim_bambu_faults *f, const char *spec, struct sf_err *err)
{
    const char *eq = strchr(spec, '=');
    size_t kl = eq ? (size_t)(eq - spec) : strlen(spec);
    const char *v = eq ? eq + 1 : "";
#define IS(k) (kl == strlen(k) && strncmp(spec, k, kl) == 0)
    if (IS("unsigned") && !eq) {
        f->unsigned_refused = true;
    } else if (IS("storage-full") && !eq) {
        f->storage_full = true;
    } else if (IS("no-reuse-check") && !eq) {
        f->no_reuse_check = true;
    } else if (IS("pasv-early") && !eq) {
        f->pasv_early = true;
    } else if (IS("ftps-wrong-cert") && !eq) {
        f->ftps_wrong_cert = true;
    } else if (IS("ftps-slow")) {
        char *end;
        long n = strtol(v, &end, 10);
        if (end == v || *end || n <= 0 || n > 10000)
            return sf_err_set(err, SF_EINVAL, "fault '%s': expects milliseconds from 1 to 10000",
                              spec);
        f->ftps_slow_ms = (int)n;
    } else if (IS("ftps-drop") || IS("mqtt-drop")) {
        char *end;
        long long n = strtoll(v, &end, 10);
        if (end == v || *end || n <= 0)
            return sf_err_set(err, SF_EINVAL, "fault '%s': expects a count above 0", spec);
        if (IS("ftps-drop"))
            f->ftps_drop = n;
        else
            f->mqtt_drop = (long)n;
    } else if (IS("stop-at")) {
        if (parse_pct(v, &f->stop_at) < 0 || f->stop_at <= 0)
            return sf_err_set(err, SF_EINVAL, "fault '%s': expects a percent above 0", spec);
    } else if (IS("hms")) {
        const char *at = strchr(v, '@');
        if (!at || at - v != 16 || strspn(v, "0123456789abcdefABCDEF") != 16 ||
            parse_pct(at + 1, &f->hms_at) < 0)
            return sf_err_set(err, SF_EINVAL, "fault '%s': expects hms=HEX16@PERCENT", spec);
        memcpy(f->hms, v, 16);
        f->hms[16] = '\0';
    } else {
        return sf_err_set(err, SF_EINVAL,
                          "unknown fault '%s' (unsigned, storage-full, ftps-drop=BYTES, "
                          "no-reuse-check, pasv-early, ftps-slow=MS, hms=HEX16@PCT, stop-at=PCT, "
                          "mqtt-drop=N, ftps-wrong-cert)",
                          spec);
    }
#undef IS
    return SF_OK;
}

struct sim_bambu *
sim_bambu_new(struct loop *l, const struct sim_bambu_config *c, struct sf_err *err)
{
    if (!c->serial || !*c->serial || strlen(c->serial) > 40 ||
        strspn(c->serial, "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789") !=
            strlen(c->serial)) {
        sf_err_set(err, SF_EINVAL, "sim bambu: --serial must be 1-40 letters and digits");
        return NULL;
    }
    if (!c->access_code || !*c->access_code || strlen(c->access_code) > 60 || !c->ca_dir ||
        c->mqtt_port <= 0) {
        sf_err_set(err, SF_EINVAL, "sim bambu: --access-code, --ca and --mqtt-port are needed");
        return NULL;
    }
    struct sim_bambu *s = mem_calloc(1, sizeof(*s));
    if (!s) {
        sf_err_set(err, SF_ENOMEM, "sim bambu: out of memory");
        return NULL;
    }
    s->loop = l;
    s->stats.pushall_gap_ms = -1;
    s->c = *c;
    if (s->c.report_ms <= 0)
        s->c.report_ms = 1000;
    if (!(s->c.speed > 0))
        s->c.speed = 1;
    snprintf(s->serial, sizeof(s->serial), "%s", c->serial);
    snprintf(s->code, sizeof(s->code), "%s", c->access_code);
    snprintf(s->topic_report, sizeof(s->topic_report), "device/%s/report", s->serial);
    snprintf(s->topic_request, sizeof(s->topic_request), "device/%s/request", s->serial);
    snprintf(s->ca, sizeof(s->ca), "%s/ca.pem", c->ca_dir);
    snprintf(s->cert, sizeof(s->cert), "%s/printer.pem", c->ca_dir);
    snprintf(s->key, sizeof(s->key), "%s/printer.key", c->ca_dir);
    if (c->faults.ftps_wrong_cert) {
        snprintf(s->ftps_cert, sizeof(s->ftps_cert), "%s/other-printer.pem", c->ca_dir);
        snprintf(s->ftps_key, sizeof(s->ftps_key), "%s/other-printer.key", c->ca_dir);
    } else {
        snprintf(s->ftps_cert, sizeof(s->ftps_cert), "%s", s->cert);
        snprintf(s->ftps_key, sizeof(s->ftps_key), "%s", s->key);
    }
    s->c.serial = s->serial;
    s->c.access_code = s->code;
    s->c.ca_dir = NULL;
    s->c.mqtt_host = NULL;
    s->c.storage_dir = NULL;
    struct sim_netprinter_config nc;
    sim_netprinter_config_init(&nc);
    nc.speed = s->c.speed;
    nc.log_path = c->log_path;
    nc.uploads_dir = c->storage_dir;
    s->np = sim_netprinter_new(l, &nc, err);
    if (!s->np)
        goto fail;
    snprintf(s->storage, sizeof(s->storage), "%s", sim_netprinter_uploads(s->np));
    snprintf(s->plate_path, sizeof(s->plate_path), "%s/" PLATE_NAME, s->storage);
    snprintf(s->st.gcode_state, sizeof(s->st.gcode_state), "IDLE");
    s->st.stg_cur = 255;
    struct sim_ftps_config fc = { .port = c->ftps_port,
                                  .cert_file = s->ftps_cert,
                                  .key_file = s->ftps_key,
                                  .storage_dir = s->storage,
                                  .user = "bblp",
                                  .password = s->code,
                                  .storage_full = c->faults.storage_full,
                                  .drop_after = c->faults.ftps_drop,
                                  .no_reuse_check = c->faults.no_reuse_check,
                                  .pasv_early = c->faults.pasv_early,
                                  .reply_delay_ms = c->faults.ftps_slow_ms,
                                  /* 16 kB per MS/20: 200 ms -> 1.6 MB/s */
                                  .read_delay_ms = (c->faults.ftps_slow_ms + 19) / 20 };
    s->ftps = sim_ftps_new(&fc, err);
    if (!s->ftps)
        goto fail;
    char client_id[96];
    snprintf(client_id, sizeof(client_id), "printer-%s", s->serial);
    struct mqttloop_config mc = {
        .host = c->mqtt_host ? c->mqtt_host : "127.0.0.1",
        .port = c->mqtt_port,
        .client_id = client_id,
        .user = "bblp",
        .password = s->code,
        .ca_file = s->ca,
        .tls_name = s->serial, /* the broker is "us": it shows the printer's certificate */
        .keepalive_s = 10,
        .on_up = on_up,
        .on_down = on_down,
        .on_message = on_request,
        .ud = s,
    };
    s->mqtt = mqttloop_new(l, &mc, err);
    if (!s->mqtt)
        goto fail;
    s->relay = sim_bambu_relay_new(l, mc.host, c->mqtt_port, err);
    if (!s->relay)
        goto fail;
    mqttloop_connect(s->mqtt, NULL);
    s->report_timer = loop_timer_add(l, s->c.report_ms, report_tick, s);
    return s;
fail:
    sim_bambu_free(s);
    return NULL;
}

int
sim_bambu_ftps_port(const struct sim_bambu *s)
{
    return sim_ftps_port(s->ftps);
}

int
sim_bambu_mqtt_port(const struct sim_bambu *s)
{
    return sim_bambu_relay_port(s->relay);
}

void
sim_bambu_stats(const struct sim_bambu *s, struct sim_bambu_stats *out)
{
    *out = s->stats;
    struct sim_ftps_stats fs;
    sim_ftps_stats(s->ftps, &fs);
    out->uploads = fs.uploads;
    out->refused_reuse = fs.refused_reuse;
    out->mqtt_clients = sim_bambu_relay_accepted(s->relay);
    snprintf(out->gcode_state, sizeof(out->gcode_state), "%s", s->st.gcode_state);
}

void
sim_bambu_free(struct sim_bambu *s)
{
    if (!s)
        return;
    loop_timer_cancel(s->loop, s->report_timer);
    loop_timer_cancel(s->loop, s->reconnect_timer);
    mqttloop_free(s->mqtt);
    sim_bambu_relay_free(s->relay);
    sim_ftps_free(s->ftps);
    sim_netprinter_free(s->np);
    free(s->layer_at);
    free(s);
}
