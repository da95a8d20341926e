/*
 * drv_bambu_upload.c - a Bambu job's way onto the printer (drv_bambu_int.h):
 * the .gcode.3mf packed a megabyte per loop turn, uploaded by implicit FTPS
 * (the shared httpc client, with the TLS options Bambu's vsftpd needs),
 * then started with project_file.  A failure here fails the job before it
 * starts (a TLS refusal leaves the printer in error for the operator, as
 * MQTT's does); drv_bambu.c follows the job once a report shows it.
 *
 * Thread: loop thread.
 */
#include "drv_bambu_int.h"

#include <jansson.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "../../src/base/log.h"

#define PACK_STEP         (1 << 20) /* G-code bytes packed per loop turn */
#define UPLOAD_STALL_MS   60000     /* an H2D can take 30 s before its 226 */
#define UPLOAD_CONNECT_MS 20000     /* TCP + TLS on a busy printer (or test machine) */

static CURLcode
ftps_opts(CURL *e, void *ud)
{
    struct bambu *b = ud;
    CURLcode rc = CURLE_OK;
    /* The serial is the URL's host, resolved to the printer: curl checks the name on the
       certificate (CN = serial) against it. */
    rc |= curl_easy_setopt(e, CURLOPT_RESOLVE, b->resolve);
    /* PROT P and TLS everywhere; fail rather than fall back to clear text. */
    rc |= curl_easy_setopt(e, CURLOPT_USE_SSL, (long)CURLUSESSL_ALL);
    /* The data connection resumes the control connection's session (X1: 522 otherwise). */
    rc |= curl_easy_setopt(e, CURLOPT_SSL_SESSIONID_CACHE, 1L);
    /* curl's TLS session cache belongs to the easy handle, its connection pool to the
       multi: a control connection kept from an earlier upload (another easy handle) has
       no session in this handle's cache, so the data connection would handshake afresh
       and be refused (522; test_bambu's second job caught it).  One control connection
       per upload, closed after it. */
    rc |= curl_easy_setopt(e, CURLOPT_FRESH_CONNECT, 1L);
    rc |= curl_easy_setopt(e, CURLOPT_FORBID_REUSE, 1L);
    /* TLS 1.2: X1C/H2D refuse others, and vsftpd's session reuse breaks on 1.3 (curl #4654). */
    rc |= curl_easy_setopt(e, CURLOPT_SSLVERSION,
                           (long)(CURL_SSLVERSION_TLSv1_2 | CURL_SSLVERSION_MAX_TLSv1_2));
    rc |= curl_easy_setopt(e, CURLOPT_FTP_SKIP_PASV_IP, 1L);
    rc |= curl_easy_setopt(e, CURLOPT_FTP_USE_EPSV, 0L); /* EPSV is unverified on printers */
    if (log_trace_enabled("ftps")) /* SLIMFARM_TRACE=ftps: curl's own account on stderr */
        rc |= curl_easy_setopt(e, CURLOPT_VERBOSE, 1L);
    if (b->insecure) {
        rc |= curl_easy_setopt(e, CURLOPT_SSL_VERIFYPEER, 0L);
        rc |= curl_easy_setopt(e, CURLOPT_SSL_VERIFYHOST, 0L);
    } else {
        rc |= curl_easy_setopt(e, CURLOPT_CAINFO, b->ca_file);
    }
    return rc;
}

void
drv_bambu_drop_package(struct bambu *b)
{
    gcode3mf_free(b->pack);
    b->pack = NULL;
    loop_timer_cancel(b->d.loop, b->pack_timer);
    b->pack_timer = 0;
    if (b->pkg_path[0])
        unlink(b->pkg_path);
    b->pkg_path[0] = '\0';
}

static void
fail_start(struct bambu *b, const char *msg)
{
    log_printer(LOG_WARN, b->d.name, "%s", msg);
    drv_bambu_drop_package(b);
    drv_bambu_job_end(b, DRV_EV_JOB_FAILED, msg);
}

static void
upload_done(struct httpc_req *r, const struct httpc_result *res, void *ud)
{
    (void)r;
    struct bambu *b = ud;
    b->upload = NULL;
    drv_bambu_drop_package(b);
    if (res->code != SF_OK && res->tls_peer) {
        /* not worth a retry: the printer waits for the operator, as for MQTT's */
        char msg[300];
        drv_bambu_tls_message(b, "FTPS upload", res->detail, msg, sizeof(msg));
        log_printer(LOG_ERROR, b->d.name, "%s; ca_file '%s', curl said: %s", msg, b->ca_file,
                    res->err.msg);
        b->phase = J_NONE;
        b->cancelling = false;
        snprintf(b->d.status.message, sizeof(b->d.status.message), "%s", msg);
        b->d.status.state = DRV_ERROR;
        drv_bambu_emit(b, DRV_EV_JOB_FAILED);
        drv_bambu_emit(b, DRV_EV_STATE);
        return;
    }
    /* curl itself requires the 226 after the data (else CURLE_UPLOAD_FAILED / PARTIAL_FILE);
       status is the last reply, the QUIT's 221 on success. */
    if (res->code != SF_OK) {
        char msg[300];
        snprintf(msg, sizeof(msg), "upload failed: %s", res->err.msg);
        /* status is the last reply curl read, not always the refusal (a 227 when STOR's
           552 ended it): the code is taken from curl's words when they carry it */
        long code = strstr(res->err.msg, ": 552")   ? 552
                    : strstr(res->err.msg, ": 553") ? 553
                                                    : res->status;
        if (code == 552 || code == 553)
            snprintf(msg, sizeof(msg),
                     "upload refused (FTP %ld): the printer's storage is full or missing", code);
        fail_start(b, msg);
        return;
    }
    b->stats.uploads++;
    /* project_file: the stock plugin's LAN frame (BAMBU-LAN.md section 2). */
    char url[160];
    snprintf(url, sizeof(url), "ftp://%s", b->file);
    json_t *o = json_pack("{s:s,s:s,s:s,s:s,s:s,s:s,s:s,s:s,s:s,s:s,s:s,s:b,s:b,s:b,s:b,s:b,s:b,"
                          "s:[i]}",
                          "command", "project_file", "param", "Metadata/plate_1.gcode", "url", url,
                          "file", b->file, "subtask_name", b->subtask, "md5", b->pkg_md5,
                          "project_id", "0", "profile_id", "0", "task_id", "0", "subtask_id", "0",
                          "bed_type", "auto", "bed_leveling", 1, "flow_cali", 0, "vibration_cali",
                          0, "layer_inspect", 0, "timelapse", 0, "use_ams", 0, "ams_mapping", -1);
    struct sf_err err;
    if (!o || drv_bambu_request(b, "print", o, b->project_seq, &err) < 0) {
        /* The link dropped between upload and start: the file waits on the printer. */
        fail_start(b, "could not send project_file: not connected");
        return;
    }
    b->phase = J_SENT;
    snprintf(b->d.status.message, sizeof(b->d.status.message), "uploaded; starting");
    log_printer(LOG_INFO, b->d.name, "job '%s' sent", b->subtask);
}

/* "uploading N %" in the printer's message, as the HTTP drivers show it; N only rises, and
   100 only once every byte is sent (the printer's 226 and the start still follow). */
static void
upload_progress(struct httpc_req *r, uint64_t sent, uint64_t total, void *ud)
{
    (void)r;
    struct bambu *b = ud;
    if (!total || b->phase != J_UPLOADING)
        return;
    int pct = sent >= total ? 100 : (int)((double)sent * 100.0 / (double)total);
    if (pct <= b->stats.upload_pct)
        return;
    b->stats.upload_pct = pct;
    if (pct > 0 && pct < 100)
        b->stats.upload_steps++;
    snprintf(b->d.status.message, sizeof(b->d.status.message), "uploading %d %%", pct);
}

static void
start_upload(struct bambu *b)
{
    struct sf_err err;
    if (gcode3mf_file_md5(b->pkg_path, b->pkg_md5, &err) < 0) {
        fail_start(b, err.msg);
        return;
    }
    char url[400];
    /* The serial as host name: curl checks the certificate against it (CN = serial). */
    snprintf(url, sizeof(url), "ftps://%s:%d/%s", b->serial, b->ftps_port, b->file);
    struct httpc_opts o = { .method = "PUT",
                            .url = url,
                            .body_path = b->pkg_path,
                            .timeout_ms = -1,
                            .connect_timeout_ms = UPLOAD_CONNECT_MS,
                            .stall_ms = UPLOAD_STALL_MS,
                            .user = "bblp",
                            .password = b->code,
                            .done = upload_done,
                            .progress = upload_progress,
                            .ud = b,
                            .setopt = ftps_opts,
                            .setopt_ud = b };
    b->upload = httpc_start(b->http, &o, &err);
    if (!b->upload) {
        fail_start(b, err.msg);
        return;
    }
    b->phase = J_UPLOADING;
    b->stats.upload_pct = -1;
    snprintf(b->d.status.message, sizeof(b->d.status.message), "uploading");
}

void
drv_bambu_pack_step(struct loop *l, void *ud)
{
    struct bambu *b = ud;
    b->pack_timer = 0;
    struct sf_err err;
    int rc = gcode3mf_step(b->pack, PACK_STEP, &err);
    if (rc < 0) {
        fail_start(b, err.msg);
        return;
    }
    if (rc == 1) {
        b->pack_timer = loop_timer_add(l, 0, drv_bambu_pack_step, b);
        return;
    }
    gcode3mf_free(b->pack);
    b->pack = NULL;
    start_upload(b);
}
