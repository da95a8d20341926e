/*
 * notify_body.c - an event told in words and shaped for one target
 * (notify_int.h): the one-line text, the webhook bodies (our JSON, ntfy,
 * Discord, Slack, an operator's template) and the mail.
 *
 * Template placeholders are filled JSON-escaped when the target's
 * Content-Type says json, as they are, otherwise: a job name with a quote
 * must not break the service's JSON.  The one-line text carries
 * a job's failure reason, which comes from outside (a printer's or a
 * slicer's words): its control bytes become spaces, so no reply with a
 * line break can add a mail or ntfy header.
 *
 * Thread: the loop thread (any, in fact: no state).
 */
#include "notify_int.h"

#include <jansson.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../base/buf.h"
#include "../base/mem.h"

#define BODY_MAX ((size_t)16 << 10) /* a message, its JSON, or a filled template */

/* Control bytes (CR, LF, ...) in s become spaces. */
static void
flatten(char *s)
{
    for (; *s; s++)
        if ((unsigned char)*s < 0x20 || *s == 0x7f)
            *s = ' ';
}

void
notify_msg_text(struct notify_msg *m, const struct job_row *job)
{
    const struct event_row *e = m->e;
    m->event = notify_event_name(m->ev);
    if (job) {
        m->job_id = job->id;
        snprintf(m->job_name, sizeof(m->job_name), "%s", job->opts.name);
        snprintf(m->job_state, sizeof(m->job_state), "%s", job_state_name(job->state));
        m->copies = job->counts.copies;
        m->copies_done = job->counts.copies_done;
        snprintf(m->reason, sizeof(m->reason), "%s", job->reason);
    } else if (e->job_id > 0 && (m->ev == NOTIFY_JOB_DONE || m->ev == NOTIFY_JOB_FAILED)) {
        m->job_id = e->job_id; /* a job event whose row could not be read */
    }
    const char *on = m->printer[0] ? " on " : "";
    switch (m->ev) {
    case NOTIFY_JOB_DONE:
        snprintf(m->text, sizeof(m->text), "job #%lld %s done%s%s (%d of %d copies)",
                 (long long)m->job_id, m->job_name, on, m->printer, m->copies_done, m->copies);
        break;
    case NOTIFY_JOB_FAILED:
        snprintf(m->text, sizeof(m->text), "job #%lld %s failed%s%s%s%s", (long long)m->job_id,
                 m->job_name, on, m->printer, m->reason[0] ? ": " : "", m->reason);
        break;
    case NOTIFY_BED_CLEAR:
        snprintf(m->text, sizeof(m->text), "printer %s needs its bed cleared", m->printer);
        break;
    case NOTIFY_PRINTER_ERROR:
        snprintf(m->text, sizeof(m->text), "printer %s is in error", m->printer);
        break;
    case NOTIFY_PRINTER_OFFLINE:
        snprintf(m->text, sizeof(m->text), "printer %s went offline", m->printer);
        break;
    default:
        snprintf(m->text, sizeof(m->text), "the queue is empty: no job waits for a printer");
        break;
    }
    flatten(m->text);
    flatten(m->reason);
}

/* "2026-12-05T18:40:00Z" of a wall-clock ms. */
static void
iso_time(int64_t ms, char out[32])
{
    time_t t = (time_t)(ms / 1000);
    struct tm tm;
    gmtime_r(&t, &tm);
    strftime(out, 32, "%Y-%m-%dT%H:%M:%SZ", &tm);
}

static char *
our_json(const struct notify_msg *m)
{
    char at[32];
    iso_time(m->e->at_ms, at);
    json_t *o = json_pack("{ss ss sI ss sI ss ss}", "event", m->event, "text", m->text, "event_id",
                          (json_int_t)m->e->id, "at", at, "at_ms", (json_int_t)m->e->at_ms,
                          "printer", m->printer, "detail", m->e->detail);
    if (o && m->job_id) {
        json_t *j = json_pack("{sI ss ss si si ss}", "id", (json_int_t)m->job_id, "name",
                              m->job_name, "state", m->job_state, "copies", m->copies,
                              "copies_done", m->copies_done, "reason", m->reason);
        json_object_set_new(o, "job", j ? j : json_null());
    }
    char *s = o ? json_dumps(o, JSON_COMPACT) : NULL;
    json_decref(o);
    return s;
}

/* {"KEY": text} for chat services. */
static char *
chat_json(const char *key, const struct notify_msg *m)
{
    char line[448];
    snprintf(line, sizeof(line), "slimfarm: %s", m->text);
    json_t *o = json_pack("{ss}", key, line);
    char *s = o ? json_dumps(o, JSON_COMPACT) : NULL;
    json_decref(o);
    return s;
}

/* v, JSON-escaped without its quotes when json, into b. */
static int
put_value(struct buf *b, const char *v, bool json)
{
    if (!json)
        return buf_printf(b, "%s", v);
    json_t *s = json_string(v);
    char *q = s ? json_dumps(s, JSON_ENCODE_ANY) : NULL;
    json_decref(s);
    if (!q)
        return SF_ENOMEM;
    int rc = buf_printf(b, "%.*s", (int)strlen(q) - 2, q + 1);
    free(q);
    return rc;
}

/* The template with {event} {text} {job_id} {job_name} {printer} {detail} {at} filled. */
static char *
fill_template(const struct notifycfg *t, const struct notify_msg *m, size_t *len)
{
    bool json = strstr(t->content_type, "json") != NULL;
    char at[32], id[24];
    iso_time(m->e->at_ms, at);
    snprintf(id, sizeof(id), "%lld", (long long)m->job_id);
    const char *const names[] = {
        "event", "text", "job_id", "job_name", "printer", "detail", "at"
    };
    const char *const vals[] = { m->event, m->text, id, m->job_name, m->printer, m->e->detail, at };
    struct buf b;
    buf_init(&b, BODY_MAX);
    int rc = SF_OK;
    for (const char *p = t->template_text; *p && rc == SF_OK;) {
        size_t k = 0;
        if (*p == '{')
            for (k = 0; k < sizeof(names) / sizeof(names[0]); k++) {
                size_t nl = strlen(names[k]);
                if (strncmp(p + 1, names[k], nl) == 0 && p[1 + nl] == '}')
                    break;
            }
        if (*p == '{' && k < sizeof(names) / sizeof(names[0])) {
            rc = put_value(&b, vals[k], json);
            p += strlen(names[k]) + 2;
        } else {
            rc = buf_printf(&b, "%c", *p++);
        }
    }
    if (rc != SF_OK || !b.len) {
        buf_release(&b);
        return NULL;
    }
    return buf_take(&b, len);
}

/* The whole mail: headers, a blank line, the text and the event's facts. */
static char *
mail_text(const struct notifycfg *t, const struct notify_msg *m, size_t *len)
{
    char date[64], at[32];
    time_t now = (time_t)(m->e->at_ms / 1000);
    struct tm tm;
    gmtime_r(&now, &tm);
    strftime(date, sizeof(date), "%a, %d %b %Y %H:%M:%S +0000", &tm);
    iso_time(m->e->at_ms, at);
    struct buf b;
    buf_init(&b, BODY_MAX);
    int rc = buf_printf(&b,
                        "From: slimfarm <%s>\r\nTo: %s\r\nSubject: [slimfarm] %s\r\nDate: %s\r\n"
                        "Message-ID: <slimfarm.%lld.%lld@%s>\r\nMIME-Version: 1.0\r\n"
                        "Content-Type: text/plain; charset=utf-8\r\n\r\n%s\r\n\r\nevent: %s\r\n"
                        "at: %s\r\n",
                        t->from, t->to, m->text, date, (long long)m->e->id, (long long)m->e->at_ms,
                        strchr(t->from, '@') + 1, m->text, m->event, at);
    if (rc == SF_OK && m->printer[0])
        rc = buf_printf(&b, "printer: %s\r\n", m->printer);
    if (rc == SF_OK && m->job_id)
        rc = buf_printf(&b, "job: #%lld %s (%s, %d of %d copies)\r\n", (long long)m->job_id,
                        m->job_name, m->job_state, m->copies_done, m->copies);
    if (rc != SF_OK) {
        buf_release(&b);
        return NULL;
    }
    return buf_take(&b, len);
}

/* Envelope recipients "<a@b>" from the to option. */
static int
mail_envelope(struct delivery *d, const struct notifycfg *t)
{
    snprintf(d->from, sizeof(d->from), "<%s>", t->from);
    for (const char *p = t->to; *p;) {
        p += strspn(p, " ,");
        size_t n = strcspn(p, " ,");
        if (!n)
            break;
        char one[260];
        snprintf(one, sizeof(one), "<%.*s>", (int)(n < 256 ? n : 256), p);
        struct curl_slist *s = curl_slist_append(d->rcpt, one);
        if (!s)
            return SF_ENOMEM;
        d->rcpt = s;
        p += n;
    }
    return SF_OK;
}

/* The webhook's body and headers as t's format asks. */
static int
webhook(struct delivery *d, const struct notifycfg *t, const struct notify_msg *m)
{
    size_t h = 0;
    const char *type = "application/json";
    switch (t->format) {
    case NOTIFY_FMT_JSON:
        d->body = our_json(m);
        break;
    case NOTIFY_FMT_NTFY:
        d->body = mem_strdup(m->text);
        type = "text/plain; charset=utf-8";
        snprintf(d->hdr[h++], sizeof(d->hdr[0]), "Title: slimfarm %s", m->event);
        break;
    case NOTIFY_FMT_DISCORD:
        d->body = chat_json("content", m);
        break;
    case NOTIFY_FMT_SLACK:
        d->body = chat_json("text", m);
        break;
    case NOTIFY_FMT_TEMPLATE:
        d->body = fill_template(t, m, &d->body_len);
        type = t->content_type;
        break;
    }
    if (!d->body)
        return SF_ENOMEM;
    if (t->format != NOTIFY_FMT_TEMPLATE)
        d->body_len = strlen(d->body);
    snprintf(d->hdr[h++], sizeof(d->hdr[0]), "Content-Type: %s", type);
    if (t->token[0])
        snprintf(d->hdr[h++], sizeof(d->hdr[0]), "Authorization: Bearer %s", t->token);
    for (size_t i = 0; i < h; i++)
        d->headers[i] = d->hdr[i];
    d->headers[h] = NULL;
    return SF_OK;
}

struct delivery *
notify_delivery_new(const struct notifycfg *t, const struct notify_msg *m)
{
    struct delivery *d = mem_calloc(1, sizeof(*d));
    if (!d)
        return NULL;
    snprintf(d->target, sizeof(d->target), "%s", t->name);
    snprintf(d->what, sizeof(d->what), "%s (event %lld)", m->event, (long long)m->e->id);
    snprintf(d->url, sizeof(d->url), "%s", t->url);
    d->mail = notifycfg_is_mail(t);
    d->retries = t->retries;
    d->timeout_s = t->timeout_s;
    int rc;
    if (d->mail) {
        snprintf(d->user, sizeof(d->user), "%s", t->user);
        snprintf(d->password, sizeof(d->password), "%s", t->password);
        d->starttls = t->starttls;
        d->body = mail_text(t, m, &d->body_len);
        rc = d->body ? mail_envelope(d, t) : SF_ENOMEM;
    } else {
        rc = webhook(d, t, m);
    }
    if (rc != SF_OK) {
        notify_delivery_free(d);
        return NULL;
    }
    return d;
}

void
notify_delivery_free(struct delivery *d)
{
    if (!d)
        return;
    free(d->body);
    curl_slist_free_all(d->rcpt);
    /* the password and token leave no copy in freed memory */
    memset(d, 0, sizeof(*d));
    free(d);
}
