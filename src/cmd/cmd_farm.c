/*
 * cmd_farm.c - the `slimfarm` subcommands that talk to a running slimfarmd
 * over its REST API (libcurl): submit, jobs, printers, cancel, pause,
 * resume, cleared, watch.
 *
 * Where: --url URL or $SLIMFARM_URL (default http://127.0.0.1:7420); the
 * key: --key KEY or $SLIMFARM_API_KEY.  Errors print the daemon's own
 * message ("slimfarm submit: options: copies: 0 is not in 1..1000") and
 * exit 1; usage errors exit 2.
 *
 * Why one file: the commands share the client (request, JSON reply, error
 * reporting) and each is a few lines on top of it.
 *
 * Thread: single-threaded CLI.
 */
#include <curl/curl.h>
#include <errno.h>
#include <jansson.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "../base/buf.h"
#include "cmd.h"

#define REPLY_MAX (64 << 20) /* a job list of 100k jobs fits */

/* Connection settings shared by every command. */
struct client {
    const char *cmd; /* subcommand name, for messages */
    char url[512];   /* base URL, no trailing slash */
    char key[160];   /* API key ("" if none) */
};

/* Take --url/--key out of argv (in place); returns the new argc, -1 on error. */
static int
client_init(struct client *c, const char *cmd, int argc, char **argv)
{
    const char *url = getenv("SLIMFARM_URL"), *key = getenv("SLIMFARM_API_KEY");
    int w = 0;
    for (int i = 0; i < argc; i++) {
        if ((strcmp(argv[i], "--url") == 0 || strcmp(argv[i], "--key") == 0) && i + 1 < argc) {
            if (argv[i][2] == 'u')
                url = argv[++i];
            else
                key = argv[++i];
            continue;
        }
        argv[w++] = argv[i];
    }
    c->cmd = cmd;
    snprintf(c->url, sizeof(c->url), "%s", url && *url ? url : "http://127.0.0.1:7420");
    size_t n = strlen(c->url);
    while (n && c->url[n - 1] == '/')
        c->url[--n] = '\0';
    snprintf(c->key, sizeof(c->key), "%s", key ? key : "");
    return w;
}

static size_t
on_body(char *data, size_t size, size_t n, void *ud)
{
    return buf_append(ud, data, size * n) == SF_OK ? size * n : 0;
}

/*
 * One request.  body (JSON) or mime may be set.  Returns the parsed JSON
 * reply for 2xx (json_decref it), or NULL after printing the error.
 */
static json_t *
request(const struct client *c, const char *method, const char *path, const char *body,
        curl_mime *mime)
{
    CURL *h = curl_easy_init();
    if (!h) {
        fprintf(stderr, "slimfarm %s: cannot start libcurl\n", c->cmd);
        return NULL;
    }
    char url[1024], hdr[200];
    snprintf(url, sizeof(url), "%s%s", c->url, path);
    snprintf(hdr, sizeof(hdr), "X-Api-Key: %s", c->key);
    struct curl_slist *hs = curl_slist_append(NULL, hdr);
    if (body)
        hs = curl_slist_append(hs, "Content-Type: application/json");
    /* ask for "100 Continue" whatever the body's size (curl asks only above 1 MiB): a
       smaller body sent at once races slimfarmd's early refusal, which closes the
       connection, and curl then reports a send error instead of the answer */
    if (body || mime)
        hs = curl_slist_append(hs, "Expect: 100-continue");
    struct buf reply;
    buf_init(&reply, REPLY_MAX);
    curl_easy_setopt(h, CURLOPT_URL, url);
    curl_easy_setopt(h, CURLOPT_CUSTOMREQUEST, method);
    curl_easy_setopt(h, CURLOPT_HTTPHEADER, hs);
    curl_easy_setopt(h, CURLOPT_WRITEFUNCTION, on_body);
    curl_easy_setopt(h, CURLOPT_WRITEDATA, &reply);
    curl_easy_setopt(h, CURLOPT_CONNECTTIMEOUT, 10L);
    /* slimfarmd refuses an unwanted upload (401/403/413) before "100
     * Continue": wait for that answer rather than curl's default 1 s,
     * after which the body goes out and races the refusal on a busy host */
    curl_easy_setopt(h, CURLOPT_EXPECT_100_TIMEOUT_MS, 10000L);
    if (mime)
        curl_easy_setopt(h, CURLOPT_MIMEPOST, mime);
    else if (body || strcmp(method, "POST") == 0)
        curl_easy_setopt(h, CURLOPT_POSTFIELDS, body ? body : "");
    CURLcode rc = curl_easy_perform(h);
    long status = 0;
    curl_easy_getinfo(h, CURLINFO_RESPONSE_CODE, &status);
    curl_slist_free_all(hs);
    curl_easy_cleanup(h);
    json_t *j = NULL;
    if (rc != CURLE_OK) {
        fprintf(stderr, "slimfarm %s: %s: %s\n", c->cmd, url, curl_easy_strerror(rc));
    } else {
        j = json_loadb(reply.data ? reply.data : "", reply.len, 0, NULL);
        if (status < 200 || status > 299) {
            json_t *e = json_object_get(j, "error");
            fprintf(stderr, "slimfarm %s: %ld: %s\n", c->cmd, status,
                    json_is_string(e) ? json_string_value(e) : "(no message)");
            json_decref(j);
            j = NULL;
        } else if (!j) {
            fprintf(stderr, "slimfarm %s: the daemon's reply is not JSON\n", c->cmd);
        }
    }
    buf_release(&reply);
    return j;
}

static const char *
str(json_t *o, const char *k)
{
    json_t *v = json_object_get(o, k);
    return json_is_string(v) ? json_string_value(v) : "";
}

static long long
num(json_t *o, const char *k)
{
    return (long long)json_integer_value(json_object_get(o, k));
}

static bool
parse_long(const char *s, long lo, long hi, long *out)
{
    char *end;
    errno = 0;
    long v = strtol(s, &end, 10);
    if (end == s || *end || errno || v < lo || v > hi)
        return false;
    *out = v;
    return true;
}

static bool
parse_double(const char *s, double *out)
{
    char *end;
    errno = 0;
    double v = strtod(s, &end);
    if (end == s || *end || errno)
        return false;
    *out = v;
    return true;
}

/* ---- submit ---- */

static const char submit_usage[] =
    "submit PART [--copies N] [--material M] [--printer P | --group G] "
    "[--method none|orient|slim|surface] [--deviation MM] [--overhang DEG] [--priority N] "
    "[--retries N]";

static int
run_submit(int argc, char **argv)
{
    struct client c;
    argc = client_init(&c, "submit", argc, argv);
    const char *part = NULL;
    json_t *opts = json_object();
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        long n;
        double d;
        if (a[0] != '-') {
            if (part) {
                fprintf(stderr, "slimfarm submit: one part per job ('%s' and '%s')\n", part, a);
                goto usage;
            }
            part = a;
            continue;
        }
        if (!v)
            goto usage;
        i++;
        if (strcmp(a, "--copies") == 0 && parse_long(v, -2147483647, 2147483647, &n))
            json_object_set_new(opts, "copies", json_integer(n));
        else if (strcmp(a, "--priority") == 0 && parse_long(v, -10000000, 10000000, &n))
            json_object_set_new(opts, "priority", json_integer(n));
        else if (strcmp(a, "--retries") == 0 && parse_long(v, 0, 1000, &n))
            json_object_set_new(opts, "max_retries", json_integer(n));
        else if (strcmp(a, "--deviation") == 0 && parse_double(v, &d))
            json_object_set_new(opts, "deviation_mm", json_real(d));
        else if (strcmp(a, "--overhang") == 0 && parse_double(v, &d))
            json_object_set_new(opts, "overhang_deg", json_real(d));
        else if (strcmp(a, "--material") == 0)
            json_object_set_new(opts, "material", json_string(v));
        else if (strcmp(a, "--printer") == 0)
            json_object_set_new(opts, "printer", json_string(v));
        else if (strcmp(a, "--group") == 0)
            json_object_set_new(opts, "group", json_string(v));
        else if (strcmp(a, "--method") == 0)
            json_object_set_new(opts, "method", json_string(v));
        else {
            fprintf(stderr, "slimfarm submit: bad option or value: %s %s\n", a, v);
            goto usage;
        }
    }
    if (!part)
        goto usage;
    FILE *f = fopen(part, "rb");
    if (!f) {
        fprintf(stderr, "slimfarm submit: cannot read '%s': %s\n", part, strerror(errno));
        json_decref(opts);
        return 1;
    }
    fclose(f);
    char *text = json_dumps(opts, JSON_COMPACT);
    json_decref(opts);
    CURL *h = curl_easy_init();
    curl_mime *mime = curl_mime_init(h);
    curl_mimepart *mp = curl_mime_addpart(mime);
    curl_mime_name(mp, "file");
    curl_mime_filedata(mp, part); /* sends the base name, never the path */
    mp = curl_mime_addpart(mime);
    curl_mime_name(mp, "options");
    curl_mime_data(mp, text ? text : "{}", CURL_ZERO_TERMINATED);
    json_t *r = request(&c, "POST", "/api/jobs", NULL, mime);
    curl_mime_free(mime);
    curl_easy_cleanup(h);
    free(text);
    if (!r)
        return 1;
    json_t *job = json_object_get(r, "job");
    printf("job %lld queued: %s x%lld\n", num(job, "id"), str(job, "name"), num(job, "copies"));
    json_decref(r);
    return 0;
usage:
    json_decref(opts);
    fprintf(stderr, "usage: slimfarm %s\n", submit_usage);
    return 2;
}

CMD_REGISTER(submit, "submit", submit_usage, "queue a part on the farm (slimfarmd)", run_submit)

/* ---- jobs, printers ---- */

static void
print_job(json_t *j)
{
    char copies[32], line[48] = "-";
    snprintf(copies, sizeof(copies), "%lld/%lld", num(j, "copies_done"), num(j, "copies"));
    /* where a print stands, or where a resume would start */
    const char *state = str(j, "state");
    if (num(j, "gcode_lines") > 0 &&
        (!strcmp(state, "printing") || !strcmp(state, "paused") || !strcmp(state, "interrupted")))
        snprintf(line, sizeof(line), "%lld/%lld", num(j, "lines_acked"), num(j, "gcode_lines"));
    printf("%-5lld %-11s %-6s %-17s %-4lld %-12s %-24s %s\n", num(j, "id"), state, copies, line,
           num(j, "priority"), str(j, "printer")[0] ? str(j, "printer") : "-", str(j, "name"),
           str(j, "reason"));
}

#define JOBS_USAGE "jobs [--state S[,S...]] [--printer NAME] [--url URL] [--key KEY]"

/* Every job that passes the filters, a page at a time (GET /api/jobs follows "next"). */
static int
run_jobs(int argc, char **argv)
{
    struct client c;
    argc = client_init(&c, "jobs", argc, argv);
    char path[1024] = "/api/jobs?limit=500";
    for (int i = 1; i < argc; i++) {
        char *v = i + 1 < argc ? curl_easy_escape(NULL, argv[i + 1], 0) : NULL;
        size_t len = strlen(path);
        if (v && (strcmp(argv[i], "--state") == 0 || strcmp(argv[i], "--printer") == 0) &&
            strlen(v) < 200)
            snprintf(path + len, sizeof(path) - len, "&%s=%s", argv[i] + 2, v);
        else
            argc = -1;
        curl_free(v);
        if (argc < 0) {
            fprintf(stderr, "usage: slimfarm " JOBS_USAGE "\n");
            return 2;
        }
        i++;
    }
    printf("%-5s %-11s %-6s %-17s %-4s %-12s %-24s %s\n", "ID", "STATE", "COPIES", "LINE", "PRIO",
           "PRINTER", "NAME", "REASON");
    while (path[0]) {
        json_t *r = request(&c, "GET", path, NULL, NULL);
        if (!r)
            return 1;
        size_t i;
        json_t *j;
        json_array_foreach(json_object_get(r, "jobs"), i, j) print_job(j);
        const char *next = json_string_value(json_object_get(r, "next"));
        snprintf(path, sizeof(path), "%s", next && next[0] == '/' ? next : "");
        json_decref(r);
    }
    return 0;
}

CMD_REGISTER(jobs, "jobs", JOBS_USAGE, "list the farm's jobs (every page; filters: state, printer)",
             run_jobs)

/* "1h02m (printer)", "4m05s (farm)": p's time left and whose estimate it is; "-" if none. */
static void
time_left_text(json_t *p, char *out, size_t n)
{
    json_t *t = json_object_get(p, "time_left_s");
    const char *from = str(p, "time_left_from");
    if (!json_is_integer(t) || !from[0]) {
        snprintf(out, n, "-");
        return;
    }
    long long s = json_integer_value(t);
    if (s >= 3600)
        snprintf(out, n, "%lldh%02lldm (%s)", s / 3600, s / 60 % 60, from);
    else
        snprintf(out, n, "%lldm%02llds (%s)", s / 60, s % 60, from);
}

static int
run_printers(int argc, char **argv)
{
    struct client c;
    if (client_init(&c, "printers", argc, argv) != 1) {
        fprintf(stderr, "usage: slimfarm printers [--url URL] [--key KEY]\n");
        return 2;
    }
    json_t *r = request(&c, "GET", "/api/printers", NULL, NULL);
    if (!r)
        return 1;
    printf("%-12s %-15s %-8s %-6s %-14s %-5s %-5s %-17s %s\n", "NAME", "STATE", "MATERIAL",
           "NOZZLE", "BED", "JOB", "DONE", "LEFT", "MESSAGE");
    size_t i;
    json_t *p;
    json_array_foreach(json_object_get(r, "printers"), i, p)
    {
        json_t *bed = json_object_get(p, "bed_mm");
        char bedtxt[48], job[24];
        snprintf(bedtxt, sizeof(bedtxt), "%gx%gx%g", json_number_value(json_array_get(bed, 0)),
                 json_number_value(json_array_get(bed, 1)),
                 json_number_value(json_array_get(bed, 2)));
        snprintf(job, sizeof(job), "%lld", num(p, "job_id"));
        char left[48];
        time_left_text(p, left, sizeof(left));
        printf("%-12s %-15s %-8s %-6g %-14s %-5s %3.0f%%  %-17s %s\n", str(p, "name"),
               str(p, "state"), str(p, "material"),
               json_number_value(json_object_get(p, "nozzle_mm")), bedtxt,
               num(p, "job_id") ? job : "-",
               100 * json_number_value(json_object_get(p, "progress")), left, str(p, "message"));
    }
    json_decref(r);
    return 0;
}

CMD_REGISTER(printers, "printers", "printers [--url URL] [--key KEY]",
             "list the farm's printers with state, progress and time left (the printer's own "
             "estimate when it gives one, else the farm's from the G-code)",
             run_printers)

/* ---- actions ---- */

/* cancel JOB_ID | cancel PRINTER, pause|resume|cleared PRINTER */
static int
action(const char *name, int argc, char **argv)
{
    struct client c;
    argc = client_init(&c, name, argc, argv);
    if (argc != 2) {
        fprintf(stderr, "usage: slimfarm %s %s\n", name,
                strcmp(name, "cancel") == 0 ? "JOB_ID|PRINTER" : "PRINTER");
        return 2;
    }
    char path[256];
    long id;
    bool restart = strcmp(name, "restart") == 0;
    bool job =
        (restart || strcmp(name, "cancel") == 0) && parse_long(argv[1], 1, 999999999999L, &id);
    if (restart && !job) {
        fprintf(stderr, "usage: slimfarm restart JOB_ID\n");
        return 2;
    }
    char *esc = curl_easy_escape(NULL, argv[1], 0);
    if (job)
        snprintf(path, sizeof(path), "/api/jobs/%ld/%s", id, name);
    else
        snprintf(path, sizeof(path), "/api/printers/%s/%s", esc ? esc : "", name);
    curl_free(esc);
    json_t *r = request(&c, "POST", path, NULL, NULL);
    if (!r)
        return 1;
    json_t *o = json_object_get(r, job ? "job" : "printer");
    if (job)
        printf("job %lld: %s\n", num(o, "id"), str(o, "state"));
    else
        printf("printer %s: %s\n", str(o, "name"), str(o, "state"));
    json_decref(r);
    return 0;
}

static int
run_cancel(int argc, char **argv)
{
    return action("cancel", argc, argv);
}

static int
run_restart(int argc, char **argv)
{
    return action("restart", argc, argv);
}

static int
run_pause(int argc, char **argv)
{
    return action("pause", argc, argv);
}

static int
run_resume(int argc, char **argv)
{
    return action("resume", argc, argv);
}

static int
run_cleared(int argc, char **argv)
{
    return action("cleared", argc, argv);
}

static int
run_estop(int argc, char **argv)
{
    return action("emergency-stop", argc, argv);
}

/* command PRINTER G-CODE...: one manual command for an idle printer. */
static int
run_command(int argc, char **argv)
{
    struct client c;
    argc = client_init(&c, "command", argc, argv);
    if (argc < 3) {
        fprintf(stderr,
                "usage: slimfarm command PRINTER G-CODE...  (e.g. slimfarm command a G28 X Y)\n");
        return 2;
    }
    /* the words after the printer are one line: "G1 X10 F600" */
    char line[1024] = "";
    size_t len = 0;
    for (int i = 2; i < argc; i++) {
        int k = snprintf(line + len, sizeof(line) - len, "%s%s", i > 2 ? " " : "", argv[i]);
        if (k < 0 || (size_t)k >= sizeof(line) - len) {
            fprintf(stderr, "slimfarm command: the command is too long\n");
            return 2;
        }
        len += (size_t)k;
    }
    json_t *body = json_pack("{ss}", "command", line);
    char *text = body ? json_dumps(body, JSON_COMPACT) : NULL;
    json_decref(body);
    char path[256];
    char *esc = curl_easy_escape(NULL, argv[1], 0);
    snprintf(path, sizeof(path), "/api/printers/%s/command", esc ? esc : "");
    curl_free(esc);
    json_t *r = text ? request(&c, "POST", path, text, NULL) : NULL;
    free(text);
    if (!r)
        return 1;
    printf("printer %s: sent '%s'\n", str(json_object_get(r, "printer"), "name"),
           str(r, "command"));
    json_decref(r);
    return 0;
}

CMD_REGISTER(command, "command", "command PRINTER G-CODE...",
             "send one manual G-code command (G28, M104 S200, ...) to an idle printer: queued to "
             "Marlin, OctoPrint's and Moonraker's consoles (PrusaLink has none)",
             run_command)

/* resume-job JOB_ID [--line N]: continue an interrupted job on its printer. */
static int
run_resume_job(int argc, char **argv)
{
    struct client c;
    argc = client_init(&c, "resume-job", argc, argv);
    long id = 0, line = -1;
    bool ok = argc >= 2 && parse_long(argv[1], 1, 999999999999L, &id);
    for (int i = 2; ok && i < argc; i += 2)
        ok = strcmp(argv[i], "--line") == 0 && i + 1 < argc &&
             parse_long(argv[i + 1], 0, 999999999999L, &line);
    if (!ok) {
        fprintf(stderr, "usage: slimfarm resume-job JOB_ID [--line N]\n");
        return 2;
    }
    char path[64], body[64] = "";
    snprintf(path, sizeof(path), "/api/jobs/%ld/resume", id);
    if (line >= 0)
        snprintf(body, sizeof(body), "{\"line\": %ld}", line);
    json_t *r = request(&c, "POST", path, line >= 0 ? body : NULL, NULL);
    if (!r)
        return 1;
    json_t *o = json_object_get(r, "job");
    printf("job %lld: %s on %s from line %lld\n", num(o, "id"), str(o, "state"), str(o, "printer"),
           num(o, "lines_acked"));
    json_decref(r);
    return 0;
}

CMD_REGISTER(resume_job, "resume-job", "resume-job JOB_ID [--line N]",
             "continue an interrupted job on its printer from its last acknowledged line "
             "(or command line N)",
             run_resume_job)
CMD_REGISTER(cancel, "cancel", "cancel JOB_ID|PRINTER", "cancel a job, or the job on a printer",
             run_cancel)
CMD_REGISTER(restart, "restart", "restart JOB_ID",
             "print an interrupted job's copy again from the start", run_restart)
CMD_REGISTER(pause, "pause", "pause PRINTER", "pause the job on a printer", run_pause)
CMD_REGISTER(resume, "resume", "resume PRINTER", "resume a paused printer", run_resume)
CMD_REGISTER(cleared, "cleared", "cleared PRINTER",
             "confirm a printer's bed is clear so it takes the next job", run_cleared)
CMD_REGISTER(estop, "emergency-stop", "emergency-stop PRINTER",
             "halt a printer now (its emergency stop; the job on it fails, not retried)", run_estop)

/* ---- watch ---- */

/* SSE parser state: lines are collected until the blank line ending an event. */
struct watch {
    struct buf line; /* the current line */
    char event[32];  /* "event:" of the current event */
    struct buf data; /* "data:" of the current event */
    long left;       /* events still to print; < 0 for no limit */
    char id[32];     /* "id:" of the last whole event, to resume after */
    char id_cur[32]; /* "id:" of the current event */
};

/* A progress snapshot: one line per printer with a job. */
static void
print_progress(struct watch *w)
{
    json_t *arr = json_loadb(w->data.data ? w->data.data : "", w->data.len, 0, NULL);
    size_t i;
    json_t *p;
    json_array_foreach(arr, i, p)
    {
        printf("progress %-12s job %-5lld %-10s %5.1f%%\n", str(p, "printer"), num(p, "job_id"),
               str(p, "state"), 100 * json_number_value(json_object_get(p, "progress")));
    }
    fflush(stdout);
    json_decref(arr);
}

static void
print_event(struct watch *w)
{
    if (strcmp(w->event, "progress") == 0) {
        print_progress(w);
        return;
    }
    json_t *e = json_loadb(w->data.data ? w->data.data : "", w->data.len, 0, NULL);
    time_t t = (time_t)(json_integer_value(json_object_get(e, "at_ms")) / 1000);
    struct tm tm;
    char when[16] = "";
    if (localtime_r(&t, &tm))
        strftime(when, sizeof(when), "%H:%M:%S", &tm);
    long long job = num(e, "job_id");
    char jobtxt[32] = "";
    if (job)
        snprintf(jobtxt, sizeof(jobtxt), "job %lld ", job);
    const char *printer = str(e, "printer");
    printf("%s %-16s %s%s%s%s\n", when, w->event, jobtxt, printer[0] ? "on " : "", printer,
           printer[0] || job ? ": " : "");
    printf("         %s\n", str(e, "detail"));
    fflush(stdout);
    json_decref(e);
}

static size_t
on_sse(char *data, size_t size, size_t n, void *ud)
{
    struct watch *w = ud;
    for (size_t i = 0; i < size * n; i++) {
        if (data[i] != '\n') {
            if (buf_append(&w->line, &data[i], 1))
                return 0;
            continue;
        }
        const char *l = w->line.data ? w->line.data : "";
        if (!l[0]) {
            if (w->event[0] && w->left != 0) {
                print_event(w);
                /* --count counts log events; progress snapshots are extra */
                if (strcmp(w->event, "progress") != 0 && w->left > 0 && --w->left == 0)
                    return 0; /* enough: end the transfer */
            }
            if (w->id_cur[0])
                memcpy(w->id, w->id_cur, sizeof(w->id));
            w->event[0] = w->id_cur[0] = '\0';
            buf_reset(&w->data);
        } else if (strncmp(l, "event: ", 7) == 0) {
            snprintf(w->event, sizeof(w->event), "%s", l + 7);
        } else if (strncmp(l, "data: ", 6) == 0) {
            buf_append(&w->data, l + 6, w->line.len - 6);
        } else if (strncmp(l, "id: ", 4) == 0) {
            snprintf(w->id_cur, sizeof(w->id_cur), "%s", l + 4);
        }
        buf_reset(&w->line);
    }
    return size * n;
}

static int
run_watch(int argc, char **argv)
{
    struct client c;
    argc = client_init(&c, "watch", argc, argv);
    struct watch w = { .left = -1 };
    const char *since = NULL;
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--count") == 0 && i + 1 < argc &&
            parse_long(argv[i + 1], 1, 1000000000, &w.left))
            i++;
        else if (strcmp(argv[i], "--since") == 0 && i + 1 < argc)
            since = argv[++i];
        else {
            fprintf(stderr, "usage: slimfarm watch [--count N] [--since EVENT_ID]\n");
            return 2;
        }
    }
    buf_init(&w.line, 1 << 20);
    buf_init(&w.data, 1 << 20);
    if (since)
        snprintf(w.id, sizeof(w.id), "%s", since);
    CURL *h = curl_easy_init();
    char url[600], hdr[200], last[64];
    snprintf(url, sizeof(url), "%s/api/events", c.url);
    snprintf(hdr, sizeof(hdr), "X-Api-Key: %s", c.key);
    CURLcode rc;
    /* The daemon ends a stream after its lifetime (README, "Connection
       limits"): reconnect after the last event seen, as EventSource does. */
    for (;;) {
        struct curl_slist *hs = curl_slist_append(NULL, hdr);
        if (w.id[0]) {
            snprintf(last, sizeof(last), "Last-Event-ID: %s", w.id);
            hs = curl_slist_append(hs, last);
        }
        curl_easy_setopt(h, CURLOPT_URL, url);
        curl_easy_setopt(h, CURLOPT_HTTPHEADER, hs);
        curl_easy_setopt(h, CURLOPT_WRITEFUNCTION, on_sse);
        curl_easy_setopt(h, CURLOPT_WRITEDATA, &w);
        curl_easy_setopt(h, CURLOPT_FAILONERROR, 1L);
        rc = curl_easy_perform(h);
        curl_slist_free_all(hs);
        if (rc != CURLE_OK)
            break;
        buf_reset(&w.line); /* an event cut by the end is sent again */
        buf_reset(&w.data);
        w.event[0] = w.id_cur[0] = '\0';
        sleep(1);
    }
    int status = 0;
    if (!(rc == CURLE_WRITE_ERROR && w.left == 0)) {
        fprintf(stderr, "slimfarm watch: %s: %s\n", url, curl_easy_strerror(rc));
        status = 1;
    }
    curl_easy_cleanup(h);
    buf_release(&w.line);
    buf_release(&w.data);
    return status;
}

CMD_REGISTER(watch, "watch", "watch [--count N] [--since EVENT_ID]",
             "follow the farm's live events (job progress, printer states)", run_watch)
