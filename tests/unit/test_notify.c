/*
 * test_notify.c - what a notification says and how each target gets it:
 * the one-line text of each event, our JSON, the chat formats, a template
 * filled JSON-escaped (a job name with quotes must not break the
 * service's JSON) or as is, and the mail's headers and envelope.  Delivery
 * over real HTTP and SMTP is tests/integ/farmd_notify.sh.  On PostgreSQL
 * (tstore.h), hosts that share a store tell of each event of the farm once, reading the log
 * on their store threads (nothing on the loop's own connection).
 */
#include <jansson.h>
#include <stdio.h>
#include <string.h>

#include "../../src/base/loop.h"
#include "../../src/farm/notify.h"
#include "../../src/farm/notify_int.h"
#include "../../src/farm/store_host.h"
#include "../../src/farm/storeq.h"
#include "../t.h"
#include "../tstore.h"

static struct event_row ev = { .id = 7,
                               .at_ms = 1796495737000,
                               .job_id = 3,
                               .printer = "",
                               .kind = "job-print-done",
                               .detail = "printing -> done" };

static struct job_row
job(const char *name)
{
    struct job_row j;
    memset(&j, 0, sizeof(j));
    j.id = 3;
    snprintf(j.opts.name, sizeof(j.opts.name), "%s", name);
    j.state = JOB_DONE;
    j.counts.copies = 2;
    j.counts.copies_done = 2;
    return j;
}

static struct notify_msg
msg(enum notify_event e, const struct job_row *j)
{
    struct notify_msg m = { .ev = e, .e = &ev };
    snprintf(m.printer, sizeof(m.printer), "mk3");
    notify_msg_text(&m, j);
    return m;
}

T_CASE(notify_text_of_each_event)
{
    struct job_row j = job("bracket.stl");
    T_EQ_STR(msg(NOTIFY_JOB_DONE, &j).text, "job #3 bracket.stl done on mk3 (2 of 2 copies)");
    snprintf(j.reason, sizeof(j.reason), "thermal runaway");
    T_EQ_STR(msg(NOTIFY_JOB_FAILED, &j).text, "job #3 bracket.stl failed on mk3: thermal runaway");
    /* a printer's reply with a line break cannot add a mail or ntfy header */
    snprintf(j.reason, sizeof(j.reason), "halted\r\nBcc: x@example.com");
    T_EQ_STR(msg(NOTIFY_JOB_FAILED, &j).text,
             "job #3 bracket.stl failed on mk3: halted  Bcc: x@example.com");
    T_EQ_STR(msg(NOTIFY_BED_CLEAR, NULL).text, "printer mk3 needs its bed cleared");
    T_EQ_STR(msg(NOTIFY_PRINTER_ERROR, NULL).text, "printer mk3 is in error");
    T_EQ_STR(msg(NOTIFY_PRINTER_OFFLINE, NULL).text, "printer mk3 went offline");
    T_EQ_STR(msg(NOTIFY_QUEUE_EMPTY, NULL).text, "the queue is empty: no job waits for a printer");
    T_EQ_STR(msg(NOTIFY_QUEUE_EMPTY, NULL).event, "queue-empty");
    T_EQ_INT(msg(NOTIFY_QUEUE_EMPTY, NULL).job_id, 0); /* not about the job that ended */
}

static struct notifycfg
target(const char *url)
{
    struct notifycfg t;
    notifycfg_init(&t, "t", 1);
    snprintf(t.url, sizeof(t.url), "%s", url);
    return t;
}

T_CASE(notify_webhook_bodies)
{
    struct job_row j = job("say \"hi\".stl");
    struct notify_msg m = msg(NOTIFY_JOB_DONE, &j);
    struct notifycfg t = target("http://h/x");
    snprintf(t.token, sizeof(t.token), "tok");
    struct delivery *d = notify_delivery_new(&t, &m);
    T_TRUE(d != NULL);
    json_t *o = json_loads(d->body, 0, NULL);
    T_TRUE(o != NULL);
    T_EQ_STR(json_string_value(json_object_get(o, "event")), "job-done");
    T_EQ_STR(json_string_value(json_object_get(o, "at")), "2026-12-05T18:35:37Z");
    T_EQ_STR(json_string_value(json_object_get(json_object_get(o, "job"), "name")),
             "say \"hi\".stl");
    json_decref(o);
    T_EQ_STR(d->headers[0], "Content-Type: application/json");
    T_EQ_STR(d->headers[1], "Authorization: Bearer tok");
    T_TRUE(d->headers[2] == NULL);
    notify_delivery_free(d);

    t.format = NOTIFY_FMT_DISCORD;
    d = notify_delivery_new(&t, &m);
    T_EQ_STR(d->body, "{\"content\":\"slimfarm: job #3 say \\\"hi\\\".stl done on mk3 (2 of 2 "
                      "copies)\"}");
    notify_delivery_free(d);
    t.format = NOTIFY_FMT_NTFY;
    d = notify_delivery_new(&t, &m);
    T_EQ_STR(d->body, m.text);
    T_EQ_STR(d->headers[0], "Title: slimfarm job-done");
    notify_delivery_free(d);

    /* a template: escaped for JSON, as is for text; unknown braces kept */
    t.format = NOTIFY_FMT_TEMPLATE;
    snprintf(t.template_text, sizeof(t.template_text),
             "{\"m\": \"{job_name}\", \"e\": \"{event}\"} {x}");
    snprintf(t.content_type, sizeof(t.content_type), "application/json");
    d = notify_delivery_new(&t, &m);
    T_EQ_STR(d->body, "{\"m\": \"say \\\"hi\\\".stl\", \"e\": \"job-done\"} {x}");
    T_EQ_INT(d->body_len, strlen(d->body));
    T_EQ_STR(d->headers[0], "Content-Type: application/json");
    notify_delivery_free(d);
    snprintf(t.content_type, sizeof(t.content_type), "text/plain");
    snprintf(t.template_text, sizeof(t.template_text), "{printer}: {job_id} {job_name}");
    d = notify_delivery_new(&t, &m);
    T_EQ_STR(d->body, "mk3: 3 say \"hi\".stl");
    notify_delivery_free(d);
}

T_CASE(notify_mail_message_and_envelope)
{
    struct job_row j = job("bracket.stl");
    struct notify_msg m = msg(NOTIFY_JOB_DONE, &j);
    struct notifycfg t = target("smtp://relay:25");
    snprintf(t.from, sizeof(t.from), "farm@example.org");
    snprintf(t.to, sizeof(t.to), "a@example.org,  b@example.org");
    struct delivery *d = notify_delivery_new(&t, &m);
    T_TRUE(d && d->mail);
    T_EQ_STR(d->from, "<farm@example.org>");
    T_EQ_STR(d->rcpt->data, "<a@example.org>");
    T_EQ_STR(d->rcpt->next->data, "<b@example.org>");
    T_TRUE(d->rcpt->next->next == NULL);
    T_TRUE(strstr(d->body, "Subject: [slimfarm] job #3 bracket.stl done on mk3 (2 of 2 "
                           "copies)\r\n") != NULL);
    T_TRUE(strstr(d->body, "To: a@example.org,  b@example.org\r\n") != NULL);
    T_TRUE(strstr(d->body, "\r\n\r\njob #3 bracket.stl done") != NULL);
    T_TRUE(strstr(d->body, "Date: Sat, 05 Dec 2026 18:35:37 +0000\r\n") != NULL);
    notify_delivery_free(d);
}

/* ---- several hosts on one store (PostgreSQL: tests/integ/store_pg.sh) ---- */

/* Host a's notifications over s (its log read on q's thread), named host, to an address that
   refuses: each delivery waits for its retry, so notify_pending counts what the host told. */
static struct notify *
host_notify(struct loop *l, struct store *s, struct storeq *q, const char *host, struct sf_err *err)
{
    struct notifycfg t;
    notifycfg_init(&t, "hook", 1);
    snprintf(t.url, sizeof(t.url), "http://127.0.0.1:9/hook");
    t.events = NOTIFY_JOB_DONE | NOTIFY_PRINTER_ERROR | NOTIFY_QUEUE_EMPTY;
    t.retries = 4;
    struct notify *n = notify_new(l, s, q, &t, 1, err);
    notify_set_host(n, host);
    return n;
}

T_CASE(notify_each_event_of_a_farm_once_among_its_hosts)
{
    T_SKIP_UNLESS(t_store_pg(), "several hosts share a store on PostgreSQL (store_pg.sh)");
    struct sf_err err;
    struct t_pair p;
    char dir[512], sql[256];
    snprintf(dir, sizeof(dir), "%s/hosts", t_tmpdir());
    T_TRUE(t_pair_open(&p, dir, &err));
    T_OK(store_host_join(p.a, "a", 600000, &p.ta, &err), &err);
    T_OK(store_host_join(p.b, "b", 600000, &p.tb, &err), &err);
    const char *pa[] = { "pa" };
    T_OK(store_host_own(p.a, "a", p.ta, pa, 1, NULL, &err), &err);
    /* a job host b holds, printed */
    char sha[STORE_SHA_HEX];
    struct job_opts o;
    job_opts_init(&o);
    snprintf(o.name, sizeof(o.name), "part.gcode");
    struct job_event_args g = { .prep_key = "k", .gcode_lines = 2 };
    int64_t id, fence;
    T_OK(store_file_put(p.a, "G28\nG1 X1\n", 10, sha, &err), &err);
    T_OK(store_job_add_gcode(p.a, &o, sha, &g, &id, &err), &err);
    T_OK(store_job_take(p.b, "b", p.tb, id, &fence, &err), &err);
    snprintf(sql, sizeof(sql), "UPDATE jobs SET state = 'done' WHERE id = %lld", (long long)id);
    T_OK(t_store_exec(p.dir, sql), NULL);
    struct loop *l = loop_new(&err);
    T_TRUE(l != NULL);
    /* each host reads its log on its store's thread, as the daemon does (farm_storeq) */
    struct storeq *qa = storeq_new(l, p.a, &err), *qb = storeq_new(l, p.b, &err);
    T_TRUE(qa && qb);
    uint64_t trips_a = store_round_trips(p.a), trips_b = store_round_trips(p.b);
    struct notify *na = host_notify(l, p.a, qa, "a", &err);
    struct notify *nb = host_notify(l, p.b, qb, "b", &err);
    T_TRUE(na && nb);
    /* telling starts at the newest event, read on the store's thread: wait for it */
    T_OK(storeq_sync(qa, 30000, &err), &err);
    T_OK(storeq_sync(qb, 30000, &err), &err);
    /* the farm's log: b's job done, a's printer in error */
    snprintf(sql, sizeof(sql),
             "INSERT INTO events(at_ms, job_id, printer, kind, detail) VALUES"
             " (1, %lld, '', 'job-print-done', 'printing -> done'),"
             " (2, NULL, 'pa', 'printer-state', 'error')",
             (long long)id);
    T_OK(t_store_exec(p.dir, sql), NULL);
    notify_kick(na);
    notify_kick(nb);
    for (int i = 0; i < 2000 && (notify_pending(na) < 2 || notify_pending(nb) < 1); i++)
        loop_run_once(l, 10);
    /* both logs read to the end (each notifier's read answered, none after) */
    storeq_free(qa);
    storeq_free(qb);
    notify_set_queue(na, NULL);
    notify_set_queue(nb, NULL);
    /* a tells of its printer and of the queue run empty (the first live host by name), b of
       its job: each once in the farm */
    T_EQ_INT(notify_pending(na), 2);
    T_EQ_INT(notify_pending(nb), 1);
    /* the newest id, the tellers, the job and the counts were read on the store threads
       (issue 32) */
    T_EQ_INT(store_round_trips(p.a) - trips_a, 0);
    T_EQ_INT(store_round_trips(p.b) - trips_b, 0);
    notify_free(na);
    notify_free(nb);
    loop_free(l);
    t_pair_close(&p);
}
