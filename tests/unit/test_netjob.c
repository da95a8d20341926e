/*
 * test_netjob.c - the remote-state table (drivers/net/netjob.h) and the
 * Moonraker and PrusaLink reply parsers, against replay fixtures whose
 * bodies follow each project's documentation field by field
 * (tests/replay/README.md says which documents and versions).
 */
#include <stdlib.h>

#include "../../drivers/net/drv_moonraker.h"
#include "../../drivers/net/drv_prusalink.h"
#include "../../drivers/net/netjob.h"
#include "../../src/base/buf.h"
#include "../t.h"

/* Read tests/replay/DIR/NAME into b (capped at 1 MB). */
static int
fixture(struct buf *b, const char *dir, const char *name, struct sf_err *err)
{
    char path[256];
    snprintf(path, sizeof(path), "tests/replay/%s/%s", dir, name);
    buf_init(b, (size_t)1 << 20);
    return buf_read_file(b, path, err);
}

/* ---- the table ---- */

static struct netjob_verdict
judge(enum netjob_phase ph, enum netjob_remote r, bool ours, const char *msg)
{
    struct netjob_obs o = { .remote = r, .ours = ours, .file = "x.gcode", .message = msg };
    struct netjob_verdict v;
    netjob_judge(ph, &o, &v);
    return v;
}

T_CASE(netjob_no_job_states)
{
    /* a printer that keeps the last job's end state is simply idle */
    enum netjob_remote idle[] = { NETJOB_R_IDLE, NETJOB_R_DONE, NETJOB_R_CANCELLED,
                                  NETJOB_R_FAILED };
    for (size_t i = 0; i < sizeof(idle) / sizeof(idle[0]); i++) {
        struct netjob_verdict v = judge(NETJOB_NONE, idle[i], false, NULL);
        T_EQ_INT(v.state, DRV_IDLE);
        T_TRUE(!v.ends);
    }
    /* someone else's print: not idle, so the farm sends nothing */
    struct netjob_verdict v = judge(NETJOB_NONE, NETJOB_R_PRINTING, false, NULL);
    T_EQ_INT(v.state, DRV_PRINTING);
    T_TRUE(strstr(v.message, "did not send") != NULL);
    v = judge(NETJOB_NONE, NETJOB_R_BUSY, false, NULL);
    T_EQ_INT(v.state, DRV_PRINTING);
    v = judge(NETJOB_NONE, NETJOB_R_PAUSED, false, NULL);
    T_EQ_INT(v.state, DRV_PAUSED);
    v = judge(NETJOB_NONE, NETJOB_R_STARTING, false, NULL);
    T_EQ_INT(v.state, DRV_CONNECTING);
    v = judge(NETJOB_NONE, NETJOB_R_HALTED, false, "MCU 'mcu' shutdown: Timer too close");
    T_EQ_INT(v.state, DRV_ERROR);
    T_EQ_STR(v.message, "MCU 'mcu' shutdown: Timer too close");
    T_TRUE(!v.ends);
}

T_CASE(netjob_running_job)
{
    struct netjob_verdict v = judge(NETJOB_RUNNING, NETJOB_R_PRINTING, true, NULL);
    T_EQ_INT(v.state, DRV_PRINTING);
    T_TRUE(!v.ends);
    v = judge(NETJOB_RUNNING, NETJOB_R_PAUSED, true, NULL);
    T_EQ_INT(v.state, DRV_PAUSED);
    T_TRUE(!v.ends);
    v = judge(NETJOB_RUNNING, NETJOB_R_BUSY, false, NULL);
    T_EQ_INT(v.state, DRV_PRINTING);
    T_TRUE(!v.ends);
    v = judge(NETJOB_RUNNING, NETJOB_R_DONE, true, NULL);
    T_TRUE(v.ends);
    T_EQ_INT(v.ev, DRV_EV_JOB_DONE);
    T_EQ_INT(v.state, DRV_IDLE);
    /* a cancel nobody here asked for fails the job, visibly */
    v = judge(NETJOB_RUNNING, NETJOB_R_CANCELLED, true, NULL);
    T_TRUE(v.ends);
    T_EQ_INT(v.ev, DRV_EV_JOB_FAILED);
    T_EQ_STR(v.message, "cancelled at the printer");
    v = judge(NETJOB_RUNNING, NETJOB_R_FAILED, true, "Move out of range");
    T_TRUE(v.ends);
    T_EQ_INT(v.ev, DRV_EV_JOB_FAILED);
    T_EQ_INT(v.state, DRV_IDLE);
    T_EQ_STR(v.message, "Move out of range");
    v = judge(NETJOB_RUNNING, NETJOB_R_HALTED, true, "Printer is shutdown");
    T_TRUE(v.ends);
    T_EQ_INT(v.ev, DRV_EV_JOB_FAILED);
    T_EQ_INT(v.state, DRV_ERROR);
    T_EQ_STR(v.message, "Printer is shutdown");
    v = judge(NETJOB_RUNNING, NETJOB_R_STARTING, true, NULL);
    T_TRUE(v.ends);
    T_EQ_INT(v.ev, DRV_EV_JOB_FAILED);
    T_EQ_INT(v.state, DRV_CONNECTING);
}

T_CASE(netjob_running_job_gone)
{
    /* the job vanished, or another file runs: never left on the printer */
    struct netjob_verdict v = judge(NETJOB_RUNNING, NETJOB_R_IDLE, false, NULL);
    T_TRUE(v.ends);
    T_EQ_INT(v.ev, DRV_EV_JOB_FAILED);
    T_TRUE(strstr(v.message, "no longer") != NULL);
    v = judge(NETJOB_RUNNING, NETJOB_R_DONE, false, NULL);
    T_TRUE(v.ends);
    T_EQ_INT(v.ev, DRV_EV_JOB_FAILED);
    v = judge(NETJOB_RUNNING, NETJOB_R_PRINTING, false, NULL);
    T_TRUE(v.ends);
    T_EQ_INT(v.ev, DRV_EV_JOB_FAILED);
    T_EQ_INT(v.state, DRV_PRINTING);
    T_TRUE(strstr(v.message, "x.gcode") != NULL);
}

T_CASE(netjob_cancelling)
{
    struct netjob_verdict v = judge(NETJOB_CANCELLING, NETJOB_R_PRINTING, true, NULL);
    T_EQ_INT(v.state, DRV_PRINTING);
    T_TRUE(!v.ends);
    enum netjob_remote over[] = { NETJOB_R_CANCELLED, NETJOB_R_IDLE, NETJOB_R_DONE,
                                  NETJOB_R_FAILED };
    for (size_t i = 0; i < sizeof(over) / sizeof(over[0]); i++) {
        v = judge(NETJOB_CANCELLING, over[i], true, NULL);
        T_TRUE(v.ends);
        T_EQ_INT(v.ev, DRV_EV_JOB_CANCELLED);
        T_EQ_INT(v.state, DRV_IDLE);
    }
    v = judge(NETJOB_CANCELLING, NETJOB_R_HALTED, true, "Printer is shutdown");
    T_TRUE(v.ends);
    T_EQ_INT(v.ev, DRV_EV_JOB_CANCELLED);
    T_EQ_INT(v.state, DRV_ERROR);
}

/* ---- Moonraker ---- */

/* Parse fixture name as a query and judge it for our job in phase. */
static int
mr_judge(const char *name, enum netjob_phase ph, struct moonraker_status *st,
         struct netjob_verdict *v, struct sf_err *err)
{
    struct buf b;
    int rc = fixture(&b, "moonraker", name, err);
    if (rc == SF_OK)
        rc = drv_moonraker_parse_status(b.data, b.len, st, err);
    buf_release(&b);
    if (rc)
        return rc;
    struct netjob_obs o;
    drv_moonraker_observe(st, "sf-3f2a9c0d1e4b5a67.gcode", 1024000, &o);
    netjob_judge(ph, &o, v);
    return SF_OK;
}

T_CASE(moonraker_query_fields)
{
    struct sf_err err;
    struct moonraker_status st;
    struct netjob_verdict v;
    T_OK(mr_judge("query_printing.json", NETJOB_RUNNING, &st, &v, &err), &err);
    T_EQ_STR(st.klippy, "ready");
    T_EQ_STR(st.state, "printing");
    T_EQ_STR(st.filename, "sf-3f2a9c0d1e4b5a67.gcode");
    T_EQ_DBL(st.progress, 0.4, 1e-9);
    T_EQ_INT(st.file_position, 409600);
    T_EQ_INT(st.file_size, 1024000);
    T_EQ_DBL(st.nozzle_c, 214.9, 1e-9);
    T_EQ_DBL(st.nozzle_target_c, 215.0, 1e-9);
    T_EQ_DBL(st.bed_c, 59.5, 1e-9);
    T_EQ_DBL(st.bed_target_c, 60.0, 1e-9);
    T_EQ_DBL(st.print_duration_s, 1210.25, 1e-9);
    T_EQ_INT(v.state, DRV_PRINTING);
    T_TRUE(!v.ends);
}

T_CASE(moonraker_states_map)
{
    static const struct {
        const char *file;
        enum netjob_phase ph;
        enum drv_state state;
        int ev; /* -1: none */
        const char *msg;
    } rows[] = {
        { "query_standby.json", NETJOB_NONE, DRV_IDLE, -1, "" },
        { "query_paused.json", NETJOB_RUNNING, DRV_PAUSED, -1, "" },
        { "query_complete.json", NETJOB_RUNNING, DRV_IDLE, DRV_EV_JOB_DONE, "" },
        { "query_complete.json", NETJOB_NONE, DRV_IDLE, -1, "" },
        { "query_cancelled.json", NETJOB_RUNNING, DRV_IDLE, DRV_EV_JOB_FAILED,
          "cancelled at the printer" },
        { "query_cancelled.json", NETJOB_CANCELLING, DRV_IDLE, DRV_EV_JOB_CANCELLED, "" },
        { "query_error.json", NETJOB_RUNNING, DRV_IDLE, DRV_EV_JOB_FAILED,
          "Move out of range: 260.000 10.000 0.300 [1203.442]" },
        { "query_other_job.json", NETJOB_RUNNING, DRV_PRINTING, DRV_EV_JOB_FAILED,
          "benchy_0.2mm_PLA.gcode" },
        { "query_other_job.json", NETJOB_NONE, DRV_PRINTING, -1, "did not send" },
        { "query_standby.json", NETJOB_RUNNING, DRV_IDLE, DRV_EV_JOB_FAILED, "no longer" },
        { "query_shutdown.json", NETJOB_RUNNING, DRV_ERROR, DRV_EV_JOB_FAILED,
          "MCU 'mcu' shutdown: Timer too close" },
        { "query_shutdown.json", NETJOB_NONE, DRV_ERROR, -1,
          "MCU 'mcu' shutdown: Timer too close" },
    };
    for (size_t i = 0; i < sizeof(rows) / sizeof(rows[0]); i++) {
        struct sf_err err;
        struct moonraker_status st;
        struct netjob_verdict v;
        T_OK(mr_judge(rows[i].file, rows[i].ph, &st, &v, &err), &err);
        if (v.state != rows[i].state ||
            (rows[i].ev < 0 ? v.ends : !v.ends || (int)v.ev != rows[i].ev) ||
            !strstr(v.message, rows[i].msg)) {
            t_fail(__FILE__, __LINE__, "row %zu (%s, phase %d): state %s ends %d ev %d '%s'", i,
                   rows[i].file, (int)rows[i].ph, drv_state_name(v.state), v.ends, (int)v.ev,
                   v.message);
            return;
        }
    }
}

T_CASE(moonraker_info_upload_errors)
{
    struct sf_err err;
    struct buf b;
    char state[16];
    static const struct {
        const char *file, *state;
    } infos[] = { { "server_info_ready.json", "ready" },
                  { "server_info_startup.json", "startup" },
                  { "server_info_disconnected.json", "disconnected" } };
    for (size_t i = 0; i < 3; i++) {
        T_OK(fixture(&b, "moonraker", infos[i].file, &err), &err);
        int rc = drv_moonraker_parse_info(b.data, b.len, state, sizeof(state), &err);
        buf_release(&b);
        T_OK(rc, &err);
        T_EQ_STR(state, infos[i].state);
    }
    struct moonraker_upload up;
    T_OK(fixture(&b, "moonraker", "upload_started.json", &err), &err);
    int rc = drv_moonraker_parse_upload(b.data, b.len, &up, &err);
    buf_release(&b);
    T_OK(rc, &err);
    T_EQ_STR(up.path, "sf-3f2a9c0d1e4b5a67.gcode");
    T_EQ_INT(up.size, 1024000);
    T_TRUE(up.print_started && !up.print_queued);
    T_OK(fixture(&b, "moonraker", "upload_queued.json", &err), &err);
    rc = drv_moonraker_parse_upload(b.data, b.len, &up, &err);
    buf_release(&b);
    T_OK(rc, &err);
    T_TRUE(!up.print_started && up.print_queued);
    /* wrapped in "result" too (some proxies), and a broken one names the field */
    const char *wrapped = "{\"result\": {\"item\": {\"path\": \"a.gcode\", \"root\": \"gcodes\", "
                          "\"size\": 12}, \"print_started\": true, \"action\": \"create_file\"}}";
    T_OK(drv_moonraker_parse_upload(wrapped, strlen(wrapped), &up, &err), &err);
    T_EQ_INT(up.size, 12);
    const char *bad = "{\"item\": {\"path\": 7}, \"print_started\": true}";
    T_ERR(drv_moonraker_parse_upload(bad, strlen(bad), &up, &err), SF_EINVAL, &err,
          "item.path: not a string");

    static const struct {
        const char *file, *text;
    } errs[] = { { "error_401.json", "Unauthorized" },
                 { "error_403_loaded.json", "File is loaded, upload not permitted" },
                 { "error_503.json", "Klippy Host not connected" },
                 { "error_400_sd_busy.json", "SD busy" } };
    for (size_t i = 0; i < 4; i++) {
        char text[160];
        T_OK(fixture(&b, "moonraker", errs[i].file, &err), &err);
        drv_moonraker_error_text(b.data, b.len, text, sizeof(text));
        buf_release(&b);
        T_EQ_STR(text, errs[i].text);
    }
    char text[32];
    const char *html = "\n  <html>502 Bad Gateway</html>\r\nmore";
    drv_moonraker_error_text(html, strlen(html), text, sizeof(text));
    T_EQ_STR(text, "<html>502 Bad Gateway</html>");
}

/*
 * The file's metadata (file_manager.md, "Gcode Metadata") and the job
 * history (history.md, "Job History"): the newest run of a file started
 * since its upload, and the time left as Mainsail tells it.
 */
T_CASE(moonraker_metadata_history_time_left)
{
    struct sf_err err;
    struct buf b;
    struct moonraker_meta md;
    T_OK(fixture(&b, "moonraker", "metadata.json", &err), &err);
    int rc = drv_moonraker_parse_meta(b.data, b.len, &md, &err);
    buf_release(&b);
    T_OK(rc, &err);
    T_EQ_DBL(md.modified, 1765000000.25, 1e-6);
    T_EQ_INT(md.size, 1024000);
    T_EQ_DBL(md.estimated_s, 3632, 1e-9);
    static const char no_mtime[] = "{\"result\": {\"size\": 3}}";
    T_ERR(drv_moonraker_parse_meta(no_mtime, sizeof(no_mtime) - 1, &md, &err), SF_EINVAL, &err,
          "moonraker result.modified: missing");

    struct moonraker_hist h;
    T_OK(fixture(&b, "moonraker", "history_list.json", &err), &err);
    /* since the upload: the completed run, not the older cancelled one */
    rc = drv_moonraker_parse_history(b.data, b.len, "sf-3f2a9c0d1e4b5a67.gcode", md.modified - 1,
                                     &h, &err);
    T_OK(rc, &err);
    T_TRUE(h.found);
    T_EQ_STR(h.status, "completed");
    T_EQ_DBL(h.start_time, 1765000001.0, 1e-6);
    T_EQ_DBL(h.end_time, 1765000950.75, 1e-6);
    T_EQ_INT(h.size, 1024000);
    /* a later upload of the same name: none of these runs is of it */
    T_OK(drv_moonraker_parse_history(b.data, b.len, "sf-3f2a9c0d1e4b5a67.gcode", 1765000500, &h,
                                     &err),
         &err);
    T_TRUE(!h.found);
    /* the other file's run is in progress: end_time null */
    T_OK(drv_moonraker_parse_history(b.data, b.len, "other.gcode", 0, &h, &err), &err);
    T_TRUE(h.found);
    T_EQ_STR(h.status, "in_progress");
    T_EQ_DBL(h.end_time, 0, 0);
    buf_release(&b);
    static const char bad[] = "{\"result\": {\"count\": 1, \"jobs\": [{\"filename\": \"a\", "
                              "\"status\": \"completed\"}]}}";
    T_ERR(drv_moonraker_parse_history(bad, sizeof(bad) - 1, "a", 0, &h, &err), SF_EINVAL, &err,
          "moonraker jobs[0].start_time: missing");

    /* Mainsail: the slicer's estimate less print_duration, else by the file's progress */
    struct moonraker_status st = { .print_duration_s = 600, .progress = 0.25 };
    T_EQ_DBL(drv_moonraker_time_left(&st, 3632), 3032, 1e-9);
    T_EQ_DBL(drv_moonraker_time_left(&st, -1), 1800, 1e-9);
    T_EQ_DBL(drv_moonraker_time_left(&st, 500), 1800, 1e-9); /* running past the slicer's */
    st.print_duration_s = 0;
    T_EQ_DBL(drv_moonraker_time_left(&st, 3632), -1, 0);
}

T_CASE(moonraker_query_rejects_bad_shapes)
{
    struct sf_err err;
    struct moonraker_status st;
    const char *no_ps = "{\"result\": {\"eventtime\": 1.0, \"status\": {\"webhooks\": "
                        "{\"state\": \"ready\"}}}}";
    T_ERR(drv_moonraker_parse_status(no_ps, strlen(no_ps), &st, &err), SF_EINVAL, &err,
          "status.print_stats: missing");
    const char *bad_temp = "{\"result\": {\"status\": {\"webhooks\": {\"state\": \"ready\"}, "
                           "\"print_stats\": {\"state\": \"standby\"}, \"extruder\": "
                           "{\"temperature\": \"hot\"}}}}";
    T_ERR(drv_moonraker_parse_status(bad_temp, strlen(bad_temp), &st, &err), SF_EINVAL, &err,
          "extruder.temperature: not a number");
    const char *bad_prog = "{\"result\": {\"status\": {\"webhooks\": {\"state\": \"ready\"}, "
                           "\"print_stats\": {\"state\": \"printing\"}, \"virtual_sdcard\": "
                           "{\"progress\": 4.5}}}}";
    T_ERR(drv_moonraker_parse_status(bad_prog, strlen(bad_prog), &st, &err), SF_EINVAL, &err,
          "progress");
    T_ERR(drv_moonraker_parse_status("<html>", 6, &st, &err), SF_EINVAL, &err, "not JSON");
}

/* ---- PrusaLink ---- */

static int
pl_status(const char *name, struct prusalink_status *st, struct sf_err *err)
{
    struct buf b;
    int rc = fixture(&b, "prusalink", name, err);
    if (rc == SF_OK)
        rc = drv_prusalink_parse_status(b.data, b.len, st, err);
    buf_release(&b);
    return rc;
}

T_CASE(prusalink_status_fields)
{
    struct sf_err err;
    struct prusalink_status st;
    T_OK(pl_status("status_printing.json", &st, &err), &err);
    T_EQ_STR(st.state, "PRINTING");
    T_TRUE(st.has_job);
    T_EQ_INT(st.job_id, 420);
    T_EQ_DBL(st.progress, 0.42, 1e-9);
    T_EQ_INT(st.time_remaining_s, 520);
    T_EQ_DBL(st.nozzle_c, 214.9, 1e-9);
    T_EQ_DBL(st.nozzle_target_c, 215.0, 1e-9);
    T_EQ_DBL(st.bed_c, 59.5, 1e-9);
    T_EQ_DBL(st.bed_target_c, 60.0, 1e-9);
    T_EQ_STR(st.storage, "usb");
    T_TRUE(!st.read_only);
    T_OK(pl_status("status_idle.json", &st, &err), &err);
    T_TRUE(!st.has_job);
    T_EQ_INT(st.time_remaining_s, -1);
}

T_CASE(prusalink_states_map)
{
    static const struct {
        const char *file;
        enum netjob_phase ph;
        enum drv_state state;
        int ev;
        const char *msg;
    } rows[] = {
        { "status_idle.json", NETJOB_NONE, DRV_IDLE, -1, "" },
        { "status_ready.json", NETJOB_NONE, DRV_IDLE, -1, "" },
        { "status_busy.json", NETJOB_NONE, DRV_PRINTING, -1, "busy" },
        { "status_printing.json", NETJOB_RUNNING, DRV_PRINTING, -1, "" },
        { "status_paused.json", NETJOB_RUNNING, DRV_PAUSED, -1, "" },
        { "status_attention.json", NETJOB_RUNNING, DRV_PAUSED, -1, "attention" },
        { "status_finished.json", NETJOB_RUNNING, DRV_IDLE, DRV_EV_JOB_DONE, "" },
        { "status_finished.json", NETJOB_NONE, DRV_IDLE, -1, "" },
        { "status_stopped.json", NETJOB_RUNNING, DRV_IDLE, DRV_EV_JOB_FAILED,
          "cancelled at the printer" },
        { "status_stopped.json", NETJOB_CANCELLING, DRV_IDLE, DRV_EV_JOB_CANCELLED, "" },
        { "status_error.json", NETJOB_RUNNING, DRV_ERROR, DRV_EV_JOB_FAILED, "error" },
        { "status_error.json", NETJOB_NONE, DRV_ERROR, -1, "error" },
        { "status_idle.json", NETJOB_RUNNING, DRV_IDLE, DRV_EV_JOB_FAILED, "no longer" },
    };
    for (size_t i = 0; i < sizeof(rows) / sizeof(rows[0]); i++) {
        struct sf_err err;
        struct prusalink_status st;
        T_OK(pl_status(rows[i].file, &st, &err), &err);
        struct netjob_obs o;
        drv_prusalink_observe(&st, 420, &o);
        struct netjob_verdict v;
        netjob_judge(rows[i].ph, &o, &v);
        if (v.state != rows[i].state ||
            (rows[i].ev < 0 ? v.ends : !v.ends || (int)v.ev != rows[i].ev) ||
            !strstr(v.message, rows[i].msg)) {
            t_fail(__FILE__, __LINE__, "row %zu (%s, phase %d): state %s ends %d ev %d '%s'", i,
                   rows[i].file, (int)rows[i].ph, drv_state_name(v.state), v.ends, (int)v.ev,
                   v.message);
            return;
        }
    }
    /* another job id is not ours */
    struct sf_err err;
    struct prusalink_status st;
    T_OK(pl_status("status_printing.json", &st, &err), &err);
    struct netjob_obs o;
    drv_prusalink_observe(&st, 421, &o);
    T_TRUE(!o.ours);
}

T_CASE(prusalink_job_version_errors)
{
    struct sf_err err;
    struct buf b;
    struct prusalink_job job;
    T_OK(fixture(&b, "prusalink", "job_printing.json", &err), &err);
    int rc = drv_prusalink_parse_job(b.data, b.len, &job, &err);
    buf_release(&b);
    T_OK(rc, &err);
    T_EQ_INT(job.id, 420);
    T_EQ_STR(job.state, "PRINTING");
    T_EQ_STR(job.name, "sf-3f2a9c0d1e4b5a67.gcode"); /* the long name, not SF-3F2~1.GCO */
    T_EQ_INT(job.size, 1024000);
    T_EQ_DBL(job.progress, 0.42, 1e-9);
    T_OK(fixture(&b, "prusalink", "job_serial.json", &err), &err);
    rc = drv_prusalink_parse_job(b.data, b.len, &job, &err);
    buf_release(&b);
    T_OK(rc, &err);
    T_EQ_STR(job.name, "");
    const char *bad = "{\"id\": 1, \"state\": \"PRINTING\", \"progress\": 140}";
    T_ERR(drv_prusalink_parse_job(bad, strlen(bad), &job, &err), SF_EINVAL, &err,
          "not a percentage");
    const char *noid = "{\"state\": \"PRINTING\", \"progress\": 1}";
    T_ERR(drv_prusalink_parse_job(noid, strlen(noid), &job, &err), SF_EINVAL, &err,
          "job.id: missing");

    char text[160];
    T_OK(fixture(&b, "prusalink", "error_409.json", &err), &err);
    drv_prusalink_error_text(b.data, b.len, text, sizeof(text));
    buf_release(&b);
    T_EQ_STR(text, "CONFLICT: Printer is busy");
    T_OK(fixture(&b, "prusalink", "error_409.txt", &err), &err);
    drv_prusalink_error_text(b.data, b.len, text, sizeof(text));
    buf_release(&b);
    T_EQ_STR(text, "Printer is busy");

    struct prusalink_status st;
    const char *no_printer = "{\"job\": {\"id\": 3}}";
    T_ERR(drv_prusalink_parse_status(no_printer, strlen(no_printer), &st, &err), SF_EINVAL, &err,
          "status.printer: missing");
    const char *no_state = "{\"printer\": {\"temp_bed\": 20}}";
    T_ERR(drv_prusalink_parse_status(no_state, strlen(no_state), &st, &err), SF_EINVAL, &err,
          "printer.state: missing");
}
