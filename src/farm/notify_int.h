/*
 * notify_int.h - what notify.c and notify_body.c share: one message (an
 * event told in words) and one delivery (a request to one target, with
 * everything it needs copied in).
 *
 * Thread: the loop thread.
 */
#ifndef SF_FARM_NOTIFY_INT_H
#define SF_FARM_NOTIFY_INT_H

#include <curl/curl.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "notifycfg.h"
#include "store.h"

struct notify;
struct httpc_req;

/* One event as the operator is told it. */
struct notify_msg {
    enum notify_event ev;      /* what happened */
    const struct event_row *e; /* the log entry it came from */
    const char *event;         /* notify_event_name(ev) (notify_msg_text) */
    char text[384];            /* one line: "job #8 bigbox.stl done on mk3 (3 of 3 copies)" */
    char printer[64];          /* the event's printer, or the job's last print's; "" if none */
    int64_t job_id;            /* 0 if not about a job */
    char job_name[128];        /* "" if none */
    char job_state[16];        /* "" if none */
    int copies, copies_done;   /* the job's counters */
    char reason[160];          /* why it failed, "" if none */
};

/* One message on its way to one target. */
struct delivery {
    struct notify *n;                /* owner */
    struct delivery *prev, *next;    /* in n's pending list */
    char target[64];                 /* the section's name, for logs */
    char what[96];                   /* "job-done (event 12)", for logs */
    bool mail;                       /* smtp(s):// */
    char url[512];                   /* secret: never logged */
    char *body;                      /* the request body (mail: the whole message) */
    size_t body_len;                 /* its bytes */
    char hdr[3][320];                /* webhook headers */
    const char *headers[4];          /* pointers into hdr, NULL-terminated */
    char user[128], password[256];   /* mail login; the password is secret */
    char from[260];                  /* "<name@host>" */
    struct curl_slist *rcpt;         /* "<name@host>" each */
    bool starttls;                   /* require STARTTLS */
    int attempt, retries, timeout_s; /* tries made, allowed after the first, limit of one */
    struct httpc_req *req;           /* in flight, or NULL */
    uint64_t timer;                  /* retry timer, or 0 */
};

/* Fill m->event, m->text and the job fields from job (NULL: not about a job). */
void notify_msg_text(struct notify_msg *m, const struct job_row *job);

/* A delivery of m to t, its body built as t asks; NULL when out of memory. */
struct delivery *notify_delivery_new(const struct notifycfg *t, const struct notify_msg *m);

/* Free d (its request and timer must be gone). */
void notify_delivery_free(struct delivery *d);

#endif
