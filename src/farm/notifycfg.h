/*
 * notifycfg.h - one [notify NAME] section of farm.ini: where the daemon
 * sends word of what needs the operator (notify.h does the sending).
 *
 * A section is a webhook (url http:// or https://: a JSON POST per event,
 * or a body shaped for ntfy, Discord, Slack, or an operator's template) or
 * a mail through an SMTP relay (url smtp:// or smtps://, with from and
 * to).  farmcfg.c hands each option of such a section to
 * notifycfg_option and, once the file is read, checks the whole section
 * with notifycfg_check; messages name the option, farmcfg adds file:line
 * and the section.  token and password are secrets: never logged, and
 * the url neither (a Discord or ntfy url holds its own secret).
 *
 * Thread: any; plain data owned by the caller.
 */
#ifndef SF_FARM_NOTIFYCFG_H
#define SF_FARM_NOTIFYCFG_H

#include <stdbool.h>
#include <stddef.h>

#define NOTIFYCFG_TARGETS_MAX  16   /* [notify] sections: a few services, not a broadcast list */
#define NOTIFYCFG_RETRIES_MAX  10   /* 1+2+...+60 s of back-off: over 5 minutes */
#define NOTIFYCFG_TEMPLATE_MAX 1024 /* a chat message body, not a document */

/* What a target is told about; a bit each. */
enum notify_event {
    NOTIFY_JOB_DONE = 1 << 0,        /* a job's last copy printed */
    NOTIFY_JOB_FAILED = 1 << 1,      /* a job failed (prepare, print, refused) */
    NOTIFY_BED_CLEAR = 1 << 2,       /* a printer waits for its bed to be cleared */
    NOTIFY_PRINTER_ERROR = 1 << 3,   /* a printer went into error */
    NOTIFY_PRINTER_OFFLINE = 1 << 4, /* a printer seen online went offline */
    NOTIFY_QUEUE_EMPTY = 1 << 5,     /* no job waits for a printer any more */
    NOTIFY_ALL = (1 << 6) - 1,
};

/* How a webhook's body is shaped. */
enum notify_format {
    NOTIFY_FMT_JSON = 0, /* our JSON object (README: Notifications) */
    NOTIFY_FMT_NTFY,     /* ntfy: the text as a plain body, a Title header */
    NOTIFY_FMT_DISCORD,  /* {"content": text} */
    NOTIFY_FMT_SLACK,    /* {"text": text} (Slack, Mattermost, Rocket.Chat) */
    NOTIFY_FMT_TEMPLATE, /* the template option, placeholders filled */
};

/* One [notify NAME] section. */
struct notifycfg {
    char name[64];                              /* NAME: letters, digits, -_. */
    int line;                                   /* its header's line, for messages */
    char url[512];                              /* http(s):// webhook or smtp(s):// relay; secret */
    unsigned events;                            /* enum notify_event bits (default NOTIFY_ALL) */
    enum notify_format format;                  /* webhook body (default json) */
    char template_text[NOTIFYCFG_TEMPLATE_MAX]; /* format template: {event} {text} {job_id}
                                               {job_name} {printer} {detail} {at} */
    char content_type[64];                      /* template's Content-Type (default text/plain) */
    char token[256];                            /* webhook: "Authorization: Bearer TOKEN"; secret */
    char from[256];                             /* mail: the sender address */
    char to[1024];                              /* mail: recipients, comma-separated */
    char user[128];                             /* mail: relay login, "" for none */
    char password[256];                         /* mail: its password; secret */
    bool starttls;                              /* smtp://: require STARTTLS (default false) */
    int retries;                                /* attempts after the first (default 4) */
    int timeout_s;                              /* one attempt's limit (default 10) */
    unsigned seen;                              /* options given, for "given twice" */
};

/* Defaults for a section called name, starting at line. */
void notifycfg_init(struct notifycfg *t, const char *name, int line);

/*
 * Take option name = value into t.  1 if taken, 0 if name is no option of
 * a notify section, -1 if the value is bad (why says so, naming the
 * option: "option 'events': 'job-dne' is not one of job-done, ...").
 */
int notifycfg_option(struct notifycfg *t, const char *name, const char *value, char *why,
                     size_t why_cap);

/* Check the whole section (url given, from/to for mail, ...): 0 or -1 with why. */
int notifycfg_check(const struct notifycfg *t, char *why, size_t why_cap);

/* Is t a mail target (smtp:// or smtps://)? */
bool notifycfg_is_mail(const struct notifycfg *t);

/* Does t hold a secret (token, password, or a url with a path or query)? */
bool notifycfg_has_secret(const struct notifycfg *t);

/* "job-done", ... for one bit; "?" for anything else. */
const char *notify_event_name(enum notify_event e);

#endif
