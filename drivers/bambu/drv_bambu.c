/*
 * drv_bambu.c - Bambu Lab printers in LAN mode (drv_bambu.h).
 *
 * The protocol, as ../shared/BAMBU-LAN.md collects it from the open
 * clients: MQTT 3.1.1 over TLS on 8883 (user bblp, password = access
 * code); subscribe device/SERIAL/report, publish device/SERIAL/request.
 * The printer reports a "print" object: X1s send it whole each time, P1s
 * only the fields that changed, so every report is merged into one cached
 * object and the driver reads that.  A job is our G-code in a .gcode.3mf
 * (gcode3mf.h), uploaded by implicit FTPS (httpc.h, libcurl: TLS 1.2,
 * PROT P, the data connection resuming the control connection's TLS
 * session, which X1s require), then started with project_file.  The
 * acknowledgement only means "accepted": the job is ours once a report
 * shows an active gcode_state with our subtask_name, and it ends on FINISH
 * (done) or FAILED (cancelled when we stopped it, else failed with
 * print_error and HMS codes).
 *
 * Design: all network work on the loop (mqttloop.h for MQTT, the shared
 * httpc client for FTPS); the package is written a megabyte per loop turn.
 * This file follows the printer (reports, state, job control);
 * drv_bambu_upload.c packs, uploads and starts the job (drv_bambu_int.h).
 * A dropped MQTT link makes the printer offline but keeps the job: the
 * printer prints on, and the reports after the reconnect carry it to its
 * end.  pushall is sent on connect (P1 printers
 * dislike polling; OpenBambuAPI): never periodically, once per connection,
 * at most every 10 s on a flapping link.
 *
 * Thread: loop thread.
 */
#include "drv_bambu.h"

#include <ctype.h>
#include <jansson.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <unistd.h>

#include "../../src/base/log.h"
#include "../../src/base/mem.h"
#include "../../src/base/mqttloop.h"
#include "../net/httpc.h"
#include "drv_bambu_int.h"
#include "gcode3mf.h"

#define MQTT_PORT_DEFAULT 8883
#define FTPS_PORT_DEFAULT 990
#define PUSHALL_RECONNECT_MS                                                                        \
    10000                              /* pushall after a reconnect at most this often: the link    \
                                          gap left the cache stale, and a P1 sends only deltas; the \
                                          5-minute caution (OpenBambuAPI) is for periodic polling,  \
                                          which this driver never does */
#define REPORT_MAX        (256 * 1024) /* one report (AMS and HMS lists included) */
#define TIME_LEFT_MAX_MIN 1e7          /* mc_remaining_time past this (19 years) is garbage */
#define ERR_CANCELED      0x0300400C   /* print_error "task canceled" */
#define HMS_VERIFY_ATTR   0x05000500   /* HMS 0500-0500-0001-0007 */
#define HMS_VERIFY_CODE   0x00010007   /* "MQTT command verification failed" */
#define ERR_VERIFY        0x05024007   /* the same, as print_error / err_code */

/* Fits drv_status.message (160 bytes): what the operator must switch on. */
static const char devmode_msg[] =
    "unsigned command refused (HMS 0500-0500-0001-0007): turn on LAN Only mode, then "
    "Developer Mode, on the printer; without them only monitoring works";

static const struct drv_ops bambu_ops;

static struct bambu *
B(struct drv *d)
{
    return (struct bambu *)d;
}

void
drv_bambu_emit(struct bambu *b, enum drv_event ev)
{
    if (b->d.on_event)
        b->d.on_event(&b->d, ev, b->d.ud);
}

static void
set_state(struct bambu *b, enum drv_state s, const char *msg)
{
    if (msg)
        snprintf(b->d.status.message, sizeof(b->d.status.message), "%s", msg);
    if (b->d.status.state == s)
        return;
    b->d.status.state = s;
    drv_bambu_emit(b, DRV_EV_STATE);
}

/* ---- requests ---- */

int
drv_bambu_request(struct bambu *b, const char *key, json_t *body, char *seq_out, struct sf_err *err)
{
    char seq[16];
    snprintf(seq, sizeof(seq), "%u", ++b->seq);
    if (seq_out)
        snprintf(seq_out, 16, "%s", seq);
    json_object_set_new(body, "sequence_id", json_string(seq));
    json_t *msg = json_pack("{s:o}", key, body);
    char *text = msg ? json_dumps(msg, JSON_COMPACT) : NULL;
    json_decref(msg);
    if (!text)
        return sf_err_set(err, SF_ENOMEM, "printer '%s': out of memory", b->d.name);
    int rc = mqttloop_publish(b->mqtt, b->topic_request, text, strlen(text), err);
    free(text);
    if (rc == SF_OK)
        b->stats.requests++;
    else if (rc == SF_EAGAIN)
        sf_err_set(err, SF_EAGAIN, "printer '%s': not connected", b->d.name);
    return rc;
}

static void
pushall(struct bambu *b)
{
    json_t *o = json_pack("{s:s,s:i,s:i}", "command", "pushall", "version", 1, "push_target", 1);
    if (drv_bambu_request(b, "pushing", o, NULL, NULL) == SF_OK) {
        int64_t now = loop_now_ms(b->d.loop);
        if (b->stats.pushalls > 0 &&
            (b->stats.pushall_gap_ms < 0 || now - b->last_pushall_ms < b->stats.pushall_gap_ms))
            b->stats.pushall_gap_ms = now - b->last_pushall_ms;
        b->stats.pushalls++;
        b->last_pushall_ms = now;
    }
}

static void
pushall_due(struct loop *l, void *ud)
{
    (void)l;
    struct bambu *b = ud;
    b->pushall_timer = 0;
    if (mqttloop_is_up(b->mqtt))
        pushall(b);
}

/* ---- reading the cached report ---- */

static const char *
str_field(struct bambu *b, const char *k)
{
    const char *s = json_string_value(json_object_get(b->print, k));
    return s ? s : "";
}

static double
num_field(struct bambu *b, const char *k, double dflt)
{
    json_t *v = json_object_get(b->print, k);
    if (json_is_number(v))
        return json_number_value(v);
    if (json_is_string(v)) { /* some fields come as strings on some firmware */
        char *end;
        double d = strtod(json_string_value(v), &end);
        if (end != json_string_value(v))
            return d;
    }
    return dflt;
}

static bool
state_active(const char *gs)
{
    return !strcmp(gs, "PREPARE") || !strcmp(gs, "RUNNING") || !strcmp(gs, "PAUSE") ||
           !strcmp(gs, "SLICING");
}

/* "HMS 0300-0100-0001-0007, ..." from the hms list; "" when empty. */
static void
hms_text(struct bambu *b, char *out, size_t n, bool *verify)
{
    out[0] = '\0';
    size_t used = 0;
    json_t *arr = json_object_get(b->print, "hms");
    size_t i;
    json_t *e;
    json_array_foreach(arr, i, e)
    {
        long long attr = json_integer_value(json_object_get(e, "attr"));
        long long code = json_integer_value(json_object_get(e, "code"));
        if (attr == HMS_VERIFY_ATTR && code == HMS_VERIFY_CODE)
            *verify = true;
        int k =
            snprintf(out + used, n - used, "%s%04llX-%04llX-%04llX-%04llX", used ? ", " : "HMS ",
                     (attr >> 16) & 0xffff, attr & 0xffff, (code >> 16) & 0xffff, code & 0xffff);
        if (k < 0 || (size_t)k >= n - used)
            break;
        used += (size_t)k;
    }
}

static void
refused(struct bambu *b)
{
    if (!b->refused)
        log_printer(LOG_ERROR, b->d.name, "%s", devmode_msg);
    b->refused = true;
    if (b->phase != J_NONE) {
        b->phase = J_NONE;
        snprintf(b->d.status.message, sizeof(b->d.status.message), "%s", devmode_msg);
        b->d.status.state = DRV_ERROR;
        drv_bambu_emit(b, DRV_EV_JOB_FAILED);
    }
    set_state(b, DRV_ERROR, devmode_msg);
}

void
drv_bambu_job_end(struct bambu *b, enum drv_event ev, const char *msg)
{
    b->phase = J_NONE;
    b->cancelling = false;
    if (ev == DRV_EV_JOB_DONE)
        b->d.status.lines_acked = b->d.status.lines_total, b->d.status.progress = 1;
    if (msg)
        snprintf(b->d.status.message, sizeof(b->d.status.message), "%s", msg);
    b->d.status.state = DRV_IDLE;
    drv_bambu_emit(b, ev);
    drv_bambu_emit(b, DRV_EV_STATE);
}

/* The cached report changed: move status, progress and the job along. */
static void
follow(struct bambu *b)
{
    const char *gs = str_field(b, "gcode_state");
    snprintf(b->stats.gcode_state, sizeof(b->stats.gcode_state), "%s", gs);
    int pct = (int)num_field(b, "mc_percent", 0);
    b->stats.mc_percent = pct;
    b->stats.remaining_min = (int)num_field(b, "mc_remaining_time", 0);
    b->stats.layer_num = (int)num_field(b, "layer_num", 0);
    b->stats.total_layer_num = (int)num_field(b, "total_layer_num", 0);
    struct drv_status *st = &b->d.status;
    /* The printer's own estimate (minutes), while it prints: the cache keeps the last value a
       P1 sent, as its deltas leave out what did not change. */
    double left_min = num_field(b, "mc_remaining_time", -1);
    st->has_time_left = state_active(gs) && left_min >= 0 && left_min < TIME_LEFT_MAX_MIN;
    st->time_left_s = st->has_time_left ? (int64_t)left_min * 60 : 0;
    double noz = num_field(b, "nozzle_temper", st->nozzle_c);
    double bed = num_field(b, "bed_temper", st->bed_c);
    double nozt = num_field(b, "nozzle_target_temper", st->nozzle_target_c);
    double bedt = num_field(b, "bed_target_temper", st->bed_target_c);
    if (noz != st->nozzle_c || bed != st->bed_c || nozt != st->nozzle_target_c ||
        bedt != st->bed_target_c) {
        st->nozzle_c = noz, st->bed_c = bed, st->nozzle_target_c = nozt, st->bed_target_c = bedt;
        drv_bambu_emit(b, DRV_EV_TEMPS);
    }
    bool verify = false;
    char hms[160];
    hms_text(b, hms, sizeof(hms), &verify);
    long long perr = (long long)num_field(b, "print_error", 0);
    if (verify || perr == ERR_VERIFY) {
        refused(b);
        return;
    }
    if (b->d.status.state == DRV_ERROR)
        return; /* needs the operator */
    const char *sub = str_field(b, "subtask_name");
    bool ours = b->subtask[0] && strcmp(sub, b->subtask) == 0;
    if (b->phase == J_SENT && ours && state_active(gs)) {
        b->phase = J_ACTIVE;
        b->d.status.message[0] = '\0'; /* the upload's words are history */
    }
    if (b->phase == J_ACTIVE) {
        if (pct != b->last_percent && pct >= 0 && pct <= 100) {
            b->last_percent = pct;
            st->progress = pct / 100.0;
            st->lines_acked = (uint64_t)((double)st->lines_total * pct / 100.0);
            drv_bambu_emit(b, DRV_EV_PROGRESS);
        }
        if (!strcmp(gs, "FINISH")) {
            drv_bambu_job_end(b, DRV_EV_JOB_DONE, "");
            return;
        }
        if (!strcmp(gs, "FAILED") || !strcmp(gs, "IDLE")) {
            if (b->cancelling) {
                drv_bambu_job_end(b, DRV_EV_JOB_CANCELLED, "cancelled");
                return;
            }
            char msg[160];
            if (perr == ERR_CANCELED)
                snprintf(msg, sizeof(msg), "print stopped at the printer (print_error 0x%08llX)",
                         perr);
            else
                snprintf(msg, sizeof(msg), "print failed at %d%%: print_error 0x%08llX%s%s", pct,
                         perr, hms[0] ? "; " : "", hms);
            log_printer(LOG_WARN, b->d.name, "%s", msg);
            drv_bambu_job_end(b, DRV_EV_JOB_FAILED, msg);
            return;
        }
        set_state(b, !strcmp(gs, "PAUSE") ? DRV_PAUSED : DRV_PRINTING, NULL);
        return;
    }
    if (b->phase != J_NONE)
        return; /* ours is on its way; the printer still shows the last one */
    /* No job of ours: a print started elsewhere keeps the printer busy. */
    if (state_active(gs))
        set_state(b, !strcmp(gs, "PAUSE") ? DRV_PAUSED : DRV_PRINTING,
                  "printing a job of another host");
    else if (gs[0])
        set_state(b, DRV_IDLE, "");
}

/* A command's answer: {"print": {"command": ..., "result": ..., "reason": ...}}. */
static void
on_answer(struct bambu *b, const char *key, json_t *o)
{
    const char *cmd = json_string_value(json_object_get(o, "command"));
    const char *result = json_string_value(json_object_get(o, "result"));
    const char *reason = json_string_value(json_object_get(o, "reason"));
    const char *seq = json_string_value(json_object_get(o, "sequence_id"));
    if (!cmd || !result || strcmp(key, "print") != 0)
        return;
    if (!strcasecmp(result, "success"))
        return;
    if (reason && strcasestr(reason, "verify")) {
        refused(b);
        return;
    }
    log_printer(LOG_WARN, b->d.name, "printer refused %s: %s", cmd, reason ? reason : result);
    if (!strcmp(cmd, "project_file") && b->phase == J_SENT && seq && !strcmp(seq, b->project_seq)) {
        char msg[160];
        snprintf(msg, sizeof(msg), "printer refused the job: %s", reason ? reason : result);
        drv_bambu_job_end(b, DRV_EV_JOB_FAILED, msg);
    }
}

static void
on_message(void *ud, const char *topic, const char *payload, size_t len)
{
    struct bambu *b = ud;
    if (strcmp(topic, b->topic_report) != 0 || len > REPORT_MAX)
        return;
    json_error_t je;
    json_t *root = json_loadb(payload, len, 0, &je);
    if (!json_is_object(root)) {
        log_printer(LOG_DEBUG, b->d.name, "unreadable report: %s", je.text);
        json_decref(root);
        return;
    }
    const char *key;
    json_t *o;
    json_object_foreach(root, key, o)
    {
        if (!json_is_object(o))
            continue;
        const char *cmd = json_string_value(json_object_get(o, "command"));
        if (!strcmp(key, "print") && cmd && !strcmp(cmd, "push_status")) {
            b->stats.reports++;
            json_object_update(b->print, o); /* P1 deltas and X1 wholes alike */
            follow(b);
        } else {
            on_answer(b, key, o);
        }
    }
    json_decref(root);
}

/* ---- connection ---- */

static void
on_up(void *ud)
{
    struct bambu *b = ud;
    struct sf_err err;
    b->stats.connects++;
    if (mqttloop_subscribe(b->mqtt, b->topic_report, &err) < 0) {
        log_printer(LOG_WARN, b->d.name, "%s", err.msg);
        return;
    }
    int64_t now = loop_now_ms(b->d.loop);
    loop_timer_cancel(b->d.loop, b->pushall_timer);
    b->pushall_timer = 0;
    /* A P1 sends only what changes: after a gap in the link the cache may miss a state
       change (a job that ended meanwhile sends no more deltas), so a reconnect asks for the
       whole state, rate-limited against a flapping link; see PUSHALL_RECONNECT_MS. */
    int64_t min_ms = b->last_pushall_ms ? PUSHALL_RECONNECT_MS : 0;
    if (!b->last_pushall_ms || now - b->last_pushall_ms >= min_ms)
        pushall(b);
    else
        b->pushall_timer =
            loop_timer_add(b->d.loop, b->last_pushall_ms + min_ms - now, pushall_due, b);
    json_t *v = json_pack("{s:s}", "command", "get_version");
    drv_bambu_request(b, "info", v, NULL, NULL);
    log_printer(LOG_INFO, b->d.name, "connected to %s:%d", b->host, b->mqtt_port);
    /* The state follows from the first report; until then, connected and waiting. */
    if (json_object_size(b->print) > 0 && b->d.status.state != DRV_ERROR)
        follow(b);
    else if (b->d.status.state != DRV_ERROR)
        set_state(b, b->phase == J_NONE ? DRV_CONNECTING : DRV_PRINTING, NULL);
}

/*
 * A certificate the driver cannot accept, on link (MQTT or FTPS): the
 * operator's line, the expected name first (status.message is short), then
 * what the printer showed.  curl's "certificate subject name 'X' does not
 * match target host name 'Y'" becomes "it shows CN=X".
 */
void
drv_bambu_tls_message(struct bambu *b, const char *link, const char *detail, char *out, size_t n)
{
    const char *subj = strstr(detail, "subject name '");
    const char *end = subj ? strchr(subj + 14, '\'') : NULL;
    if (subj && end)
        snprintf(out, n,
                 "TLS (%s): expected a certificate for CN=%s (the serial) from ca_file; "
                 "it shows CN=%.*s",
                 link, b->serial, (int)(end - subj - 14), subj + 14);
    else
        snprintf(out, n, "TLS (%s): expected a certificate for CN=%s (the serial) from ca_file; %s",
                 link, b->serial, detail);
}

static void
on_down(void *ud, int connack, bool tls, const char *why)
{
    struct bambu *b = ud;
    char msg[300];
    if (connack == 4 || connack == 5) {
        /* status.message is short: the operator's line first, the broker's words in the log */
        snprintf(msg, sizeof(msg),
                 "authentication failed (CONNACK %d): check access_code against the printer's "
                 "screen (Settings > Network)",
                 connack);
        log_printer(LOG_ERROR, b->d.name, "%s; %s", msg, why);
        set_state(b, DRV_ERROR, msg);
        return;
    }
    if (tls) {
        const char *p = strstr(why, "certificate rejected: ");
        drv_bambu_tls_message(b, "MQTT", p ? p + 22 : why, msg, sizeof(msg));
        log_printer(LOG_ERROR, b->d.name, "%s; ca_file '%s', MQTT said: %s", msg, b->ca_file, why);
        set_state(b, DRV_ERROR, msg);
        return;
    }
    log_printer(LOG_WARN, b->d.name, "MQTT: %s", why);
    /* The job stays: the printer prints on without us, and we pick it up again. */
    set_state(b, DRV_OFFLINE, why);
}

/* ---- drv_ops ---- */

static int
bambu_open(struct drv *d, struct sf_err *err)
{
    struct bambu *b = B(d);
    (void)err;
    b->open = true;
    set_state(b, DRV_CONNECTING, NULL);
    return mqttloop_connect(b->mqtt, err);
}

/*
 * The job's names on the printer, from drv_remote_name (content-addressed,
 * [A-Za-z0-9._-]: 0500-400A refuses others): the package "sf-X.gcode.3mf",
 * the subtask "sf-X".  The same file always gets the same names, which is
 * how attach() finds a job after a daemon restart.
 */
static void
job_names(struct bambu *b, const char *gcode_path)
{
    char remote[96];
    drv_remote_name(gcode_path, remote, sizeof(remote));
    size_t n = strlen(remote);
    if (n > 6 && !strcmp(remote + n - 6, ".gcode"))
        n -= 6;
    snprintf(b->subtask, sizeof(b->subtask), "%.*s", (int)n, remote);
    snprintf(b->file, sizeof(b->file), "%s.gcode.3mf", b->subtask);
}

static int
bambu_start_job(struct drv *d, const char *gcode_path, uint64_t first_line,
                const struct drv_job_scan *scan, struct sf_err *err)
{
    struct bambu *b = B(d);
    if (first_line > 0)
        return sf_err_set(err, SF_EUNSUPP,
                          "printer '%s': a Bambu printer cannot start a file part-way", d->name);
    if (b->refused)
        return sf_err_set(err, SF_EAGAIN, "printer '%s': %s", d->name, devmode_msg);
    if (d->status.state != DRV_IDLE || b->phase != J_NONE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s': not idle (%s)", d->name,
                          drv_state_name(d->status.state));
    struct drv_job_scan own;
    if (!scan) {
        if (drv_job_scan(gcode_path, &own, err) < 0)
            return err ? err->code : SF_EINVAL;
        scan = &own;
    }
    job_names(b, gcode_path);
    const char *tmp = getenv("TMPDIR");
    /* The serial in the name: printers given the same file at once each pack their own (with
       the file's name alone they wrote, sent and removed one package between them). */
    snprintf(b->pkg_path, sizeof(b->pkg_path), "%s/slimfarm-%d-%s-%s", tmp && *tmp ? tmp : "/tmp",
             (int)getpid(), b->serial, b->file);
    struct gcode3mf_meta meta = { .title = b->subtask };
    b->pack = gcode3mf_new(b->pkg_path, gcode_path, &meta, err);
    if (!b->pack) {
        b->pkg_path[0] = '\0';
        return err ? err->code : SF_EIO;
    }
    b->phase = J_PACKING;
    b->cancelling = false;
    b->last_percent = -1;
    d->status.lines_total = scan->lines_total;
    d->status.lines_acked = 0;
    d->status.progress = 0;
    d->status.job_started_ms = loop_now_ms(d->loop);
    b->pack_timer = loop_timer_add(d->loop, 0, drv_bambu_pack_step, b);
    set_state(b, DRV_PRINTING, "packing");
    return SF_OK;
}

/* drv.h: adopt the job the printer runs (or ended) under this file's names. */
static int
bambu_attach(struct drv *d, const char *gcode_path, const struct drv_job_scan *scan,
             struct sf_err *err)
{
    struct bambu *b = B(d);
    if (!mqttloop_is_up(b->mqtt) || !json_object_size(b->print))
        return sf_err_set(err, SF_EAGAIN, "printer '%s': not connected", d->name);
    if (b->phase != J_NONE) {
        /* The link dropped under a job we still follow: it is this one, or another. */
        char sub[96];
        snprintf(sub, sizeof(sub), "%s", b->subtask);
        job_names(b, gcode_path);
        bool same = strcmp(sub, b->subtask) == 0;
        snprintf(b->subtask, sizeof(b->subtask), "%s", sub);
        snprintf(b->file, sizeof(b->file), "%s.gcode.3mf", sub);
        if (same)
            return SF_OK;
        return sf_err_set(err, SF_EAGAIN, "printer '%s': another job is running", d->name);
    }
    job_names(b, gcode_path);
    const char *gs = str_field(b, "gcode_state");
    bool ended = !strcmp(gs, "FINISH") || !strcmp(gs, "FAILED");
    if (strcmp(str_field(b, "subtask_name"), b->subtask) != 0 || (!state_active(gs) && !ended)) {
        b->subtask[0] = '\0';
        return sf_err_set(err, SF_ENOTFOUND, "printer '%s': no job '%s' on the printer", d->name,
                          gcode_path);
    }
    struct drv_job_scan own;
    if (!scan) {
        if (drv_job_scan(gcode_path, &own, err) < 0)
            return err ? err->code : SF_EINVAL;
        scan = &own;
    }
    d->status.lines_total = scan->lines_total;
    d->status.lines_acked = 0;
    d->status.progress = 0;
    d->status.job_started_ms = loop_now_ms(d->loop);
    b->phase = J_ACTIVE;
    b->cancelling = false;
    b->last_percent = -1;
    log_printer(LOG_INFO, d->name, "re-attached to job '%s' (%s)", b->subtask, gs);
    set_state(b, DRV_PRINTING, "");
    follow(b); /* progress, and the end at once if it ended meanwhile */
    return SF_OK;
}

static int
simple_cmd(struct bambu *b, const char *cmd, struct sf_err *err)
{
    json_t *o = json_pack("{s:s,s:s}", "command", cmd, "param", "");
    return drv_bambu_request(b, "print", o, NULL, err);
}

static int
bambu_pause(struct drv *d, struct sf_err *err)
{
    struct bambu *b = B(d);
    if (b->phase != J_ACTIVE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s': no print running", d->name);
    return simple_cmd(b, "pause", err);
}

static int
bambu_resume(struct drv *d, struct sf_err *err)
{
    struct bambu *b = B(d);
    if (b->phase != J_ACTIVE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s': no print to resume", d->name);
    return simple_cmd(b, "resume", err);
}

static int
bambu_cancel(struct drv *d, struct sf_err *err)
{
    struct bambu *b = B(d);
    switch (b->phase) {
    case J_NONE:
        return sf_err_set(err, SF_EAGAIN, "printer '%s': no job to cancel", d->name);
    case J_PACKING:
    case J_UPLOADING:
        if (b->upload)
            httpc_cancel(b->upload);
        b->upload = NULL;
        drv_bambu_drop_package(b);
        drv_bambu_job_end(b, DRV_EV_JOB_CANCELLED, "cancelled before it started");
        return SF_OK;
    case J_SENT:
    case J_ACTIVE:
        b->cancelling = true;
        return simple_cmd(b, "stop", err);
    }
    return SF_OK;
}

static int
bambu_command(struct drv *d, const char *line, struct sf_err *err)
{
    struct bambu *b = B(d);
    if (b->phase != J_NONE)
        return sf_err_set(err, SF_EAGAIN, "printer '%s': printing", d->name);
    if (strlen(line) > 4096)
        return sf_err_set(err, SF_EINVAL, "printer '%s': command too long", d->name);
    char text[4100];
    snprintf(text, sizeof(text), "%s\n", line);
    json_t *o = json_pack("{s:s,s:s}", "command", "gcode_line", "param", text);
    return drv_bambu_request(b, "print", o, NULL, err);
}

static void
bambu_close(struct drv *d)
{
    struct bambu *b = B(d);
    b->open = false;
    loop_timer_cancel(d->loop, b->pushall_timer);
    b->pushall_timer = 0;
    mqttloop_close(b->mqtt);
    if (d->status.state != DRV_OFFLINE) {
        d->status.state = DRV_OFFLINE;
        drv_bambu_emit(b, DRV_EV_STATE);
    }
}

static void
bambu_destroy(struct drv *d)
{
    struct bambu *b = B(d);
    if (b->upload)
        httpc_cancel(b->upload);
    drv_bambu_drop_package(b);
    loop_timer_cancel(d->loop, b->pushall_timer);
    mqttloop_free(b->mqtt);
    if (b->http)
        httpc_put(b->http);
    json_decref(b->print);
    curl_slist_free_all(b->resolve);
    free(b);
}

static const struct drv_ops bambu_ops = {
    .version = DRV_OPS_VERSION,
    .kind = "bambu",
    .open = bambu_open,
    .start_job = bambu_start_job,
    .pause = bambu_pause,
    .resume = bambu_resume,
    .cancel = bambu_cancel,
    .command = bambu_command,
    .close = bambu_close,
    .destroy = bambu_destroy,
    .attach = bambu_attach,
};

/* url: "IP", "IP:PORT", "mqtts://IP[:PORT]" -> host, port. */
static int
parse_url(const char *name, const char *url, char *host, size_t hn, int *port, struct sf_err *err)
{
    const char *p = url;
    if (!strncmp(p, "mqtts://", 8))
        p += 8;
    else if (strstr(p, "://"))
        return sf_err_set(err, SF_EINVAL,
                          "printer '%s': url '%s': a Bambu printer is reached as IP or "
                          "mqtts://IP[:PORT]",
                          name, url);
    const char *colon = strrchr(p, ':');
    size_t len = colon ? (size_t)(colon - p) : strlen(p);
    if (len > 0 && p[len - 1] == '/')
        len--;
    if (!len || len >= hn)
        return sf_err_set(err, SF_EINVAL, "printer '%s': url '%s' has no host", name, url);
    memcpy(host, p, len);
    host[len] = '\0';
    for (size_t i = 0; i < len; i++)
        if (!isalnum((unsigned char)host[i]) && host[i] != '.' && host[i] != '-')
            return sf_err_set(err, SF_EINVAL, "printer '%s': url '%s': bad host", name, url);
    *port = MQTT_PORT_DEFAULT;
    if (colon) {
        char *end;
        long v = strtol(colon + 1, &end, 10);
        if (end == colon + 1 || (*end && strcmp(end, "/")) || v < 1 || v > 65535)
            return sf_err_set(err, SF_EINVAL, "printer '%s': url '%s': bad port", name, url);
        *port = (int)v;
    }
    return SF_OK;
}

struct drv *
drv_bambu_new(struct loop *l, const struct drv_config *cfg, drv_event_fn on_event, void *ud,
              struct sf_err *err)
{
    const char *name = cfg->name ? cfg->name : "bambu";
    if (!cfg->url || !*cfg->url) {
        sf_err_set(err, SF_EINVAL, "printer '%s': no host (url) given", name);
        return NULL;
    }
    if (!cfg->serial || !*cfg->serial || strlen(cfg->serial) > 40) {
        sf_err_set(err, SF_EINVAL, "printer '%s': option 'serial' (the device id) is required",
                   name);
        return NULL;
    }
    for (const char *p = cfg->serial; *p; p++)
        if (!isalnum((unsigned char)*p)) {
            sf_err_set(err, SF_EINVAL, "printer '%s': serial '%s' is not letters and digits", name,
                       cfg->serial);
            return NULL;
        }
    if (!cfg->api_key || !*cfg->api_key || strlen(cfg->api_key) > 60) {
        sf_err_set(err, SF_EINVAL, "printer '%s': option 'access_code' is required", name);
        return NULL;
    }
    if (!cfg->tls_insecure && (!cfg->ca_file || !*cfg->ca_file)) {
        sf_err_set(err, SF_EINVAL,
                   "printer '%s': option 'ca_file' is required to check the printer's "
                   "certificate (or tls_insecure: true, which checks nothing)",
                   name);
        return NULL;
    }
    if (cfg->ftps_port < 0 || cfg->ftps_port > 65535) {
        sf_err_set(err, SF_EINVAL, "printer '%s': ftps_port %d out of range", name, cfg->ftps_port);
        return NULL;
    }
    struct bambu *b = mem_calloc(1, sizeof(*b));
    if (!b) {
        sf_err_set(err, SF_ENOMEM, "printer '%s': out of memory", name);
        return NULL;
    }
    b->d.ops = &bambu_ops;
    b->d.loop = l;
    b->stats.pushall_gap_ms = -1;
    b->stats.upload_pct = -1;
    snprintf(b->d.name, sizeof(b->d.name), "%s", name);
    b->d.on_event = on_event;
    b->d.ud = ud;
    snprintf(b->d.caps.firmware, sizeof(b->d.caps.firmware), "Bambu Lab LAN");
    if (parse_url(name, cfg->url, b->host, sizeof(b->host), &b->mqtt_port, err) < 0)
        goto fail;
    b->ftps_port = cfg->ftps_port ? cfg->ftps_port : FTPS_PORT_DEFAULT;
    snprintf(b->serial, sizeof(b->serial), "%s", cfg->serial);
    snprintf(b->code, sizeof(b->code), "%s", cfg->api_key);
    snprintf(b->ca_file, sizeof(b->ca_file), "%s", cfg->ca_file ? cfg->ca_file : "");
    b->insecure = cfg->tls_insecure;
    if (b->insecure)
        log_printer(LOG_WARN, name,
                    "tls_insecure: the printer's certificate is not checked; anyone on the "
                    "network path can read the access code and the jobs");
    snprintf(b->topic_report, sizeof(b->topic_report), "device/%s/report", b->serial);
    snprintf(b->topic_request, sizeof(b->topic_request), "device/%s/request", b->serial);
    char resolve[256];
    snprintf(resolve, sizeof(resolve), "%s:%d:%s", b->serial, b->ftps_port, b->host);
    b->resolve = curl_slist_append(NULL, resolve);
    b->print = json_object();
    if (!b->print || !b->resolve) {
        sf_err_set(err, SF_ENOMEM, "printer '%s': out of memory", name);
        goto fail;
    }
    char client_id[96];
    snprintf(client_id, sizeof(client_id), "slimfarm-%d-%s", (int)getpid(), b->serial);
    struct mqttloop_config mc = { .host = b->host,
                                  .port = b->mqtt_port,
                                  .client_id = client_id,
                                  .user = "bblp",
                                  .password = b->code,
                                  .ca_file = b->insecure ? NULL : b->ca_file,
                                  .tls_name = b->serial,
                                  .tls_insecure = b->insecure,
                                  .tls12_only = true,
                                  .keepalive_s = 30,
                                  .on_up = on_up,
                                  .on_down = on_down,
                                  .on_message = on_message,
                                  .ud = b };
    b->mqtt = mqttloop_new(l, &mc, err);
    if (!b->mqtt) {
        sf_err_prefix(err, "printer '%s'", name);
        goto fail;
    }
    b->http = httpc_get(l, err);
    if (!b->http)
        goto fail;
    return &b->d;
fail:
    bambu_destroy(&b->d);
    return NULL;
}

bool
drv_bambu_stats(const struct drv *d, struct drv_bambu_stats *out)
{
    if (!d || d->ops != &bambu_ops)
        return false;
    *out = ((const struct bambu *)d)->stats;
    return true;
}
