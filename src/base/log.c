/*
 * log.c - the logging behind log.h.
 *
 * Lines are formatted into a stack buffer and written with one fputs under
 * a mutex, so lines from worker threads never interleave.  The per-printer
 * rate limit keeps a small fixed table of (printer, message hash) with the
 * last time printed; it is a cache, so an evicted entry only means a
 * repeated line gets through once more.
 */
#include "log.h"

#include <pthread.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define LOG_LINE_MAX  1024
#define RATE_SLOTS    64
#define RATE_WINDOW_S 10

struct rate_slot {
    uint64_t key;     /* hash of printer name and message; 0 = empty */
    time_t last;      /* when it was last printed */
    unsigned dropped; /* repeats swallowed since */
};

static pthread_mutex_t log_lock = PTHREAD_MUTEX_INITIALIZER;
static int level_threshold = -1; /* -1: read SLIMFARM_LOG on first use */
static log_sink_fn sink_fn;
static void *sink_ud;
static struct rate_slot rate[RATE_SLOTS];

static const char *const level_names[] = { "error", "warn", "info", "debug" };

const char *
log_level_name(enum log_level level)
{
    return (unsigned)level < 4 ? level_names[level] : "?";
}

bool
log_level_parse(const char *s, enum log_level *out)
{
    for (int i = 0; i < 4; i++) {
        if (strcmp(s, level_names[i]) == 0) {
            *out = (enum log_level)i;
            return true;
        }
    }
    return false;
}

static int
threshold(void)
{
    if (level_threshold < 0) {
        enum log_level l = LOG_INFO;
        const char *env = getenv("SLIMFARM_LOG");
        if (env)
            log_level_parse(env, &l);
        level_threshold = (int)l;
    }
    return level_threshold;
}

void
log_set_level(enum log_level level)
{
    pthread_mutex_lock(&log_lock);
    level_threshold = (int)level;
    pthread_mutex_unlock(&log_lock);
}

enum log_level
log_get_level(void)
{
    pthread_mutex_lock(&log_lock);
    int t = threshold();
    pthread_mutex_unlock(&log_lock);
    return (enum log_level)t;
}

void
log_set_sink(log_sink_fn fn, void *ud)
{
    pthread_mutex_lock(&log_lock);
    sink_fn = fn;
    sink_ud = ud;
    pthread_mutex_unlock(&log_lock);
}

/* Called with log_lock held. */
static void
emit(enum log_level level, const char *subsys, const char *printer, const char *msg)
{
    if (sink_fn) {
        sink_fn(sink_ud, level, subsys, printer, msg);
        return;
    }
    char line[LOG_LINE_MAX + 128];
    struct timespec ts;
    struct tm tm;
    clock_gettime(CLOCK_REALTIME, &ts);
    gmtime_r(&ts.tv_sec, &tm);
    snprintf(line, sizeof(line), "%04d-%02d-%02dT%02d:%02d:%02d.%03ld %s %s%s%s%s: %s\n",
             tm.tm_year + 1900, tm.tm_mon + 1, tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec,
             ts.tv_nsec / 1000000, log_level_name(level), subsys, printer ? "[" : "",
             printer ? printer : "", printer ? "]" : "", msg);
    fputs(line, stderr);
}

static void
vlog(enum log_level level, const char *subsys, const char *printer, const char *fmt, va_list ap)
{
    char msg[LOG_LINE_MAX];

    pthread_mutex_lock(&log_lock);
    if ((int)level <= threshold()) {
        vsnprintf(msg, sizeof(msg), fmt, ap);
        emit(level, subsys, printer, msg);
    }
    pthread_mutex_unlock(&log_lock);
}

void
log_msg(enum log_level level, const char *subsys, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vlog(level, subsys, NULL, fmt, ap);
    va_end(ap);
}

void
log_printer_each(enum log_level level, const char *printer, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vlog(level, "printer", printer, fmt, ap);
    va_end(ap);
}

static uint64_t
hash_str(uint64_t h, const char *s)
{
    /* FNV-1a: fast, and collisions only cost a swallowed log line. */
    for (; *s; s++)
        h = (h ^ (unsigned char)*s) * 0x100000001b3ULL;
    return h;
}

void
log_printer(enum log_level level, const char *printer, const char *fmt, ...)
{
    char msg[LOG_LINE_MAX];
    va_list ap;

    pthread_mutex_lock(&log_lock);
    if ((int)level > threshold())
        goto out;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof(msg), fmt, ap);
    va_end(ap);

    uint64_t key = hash_str(hash_str(0xcbf29ce484222325ULL, printer), msg) | 1;
    struct rate_slot *slot = &rate[key % RATE_SLOTS];
    time_t now = time(NULL);
    if (slot->key == key && now - slot->last < RATE_WINDOW_S) {
        slot->dropped++;
        goto out;
    }
    if (slot->key == key && slot->dropped) {
        char note[LOG_LINE_MAX + 64];
        snprintf(note, sizeof(note), "%s (repeated %u times)", msg, slot->dropped);
        emit(level, "printer", printer, note);
    } else {
        emit(level, "printer", printer, msg);
    }
    slot->key = key;
    slot->last = now;
    slot->dropped = 0;
out:
    pthread_mutex_unlock(&log_lock);
}

bool
log_trace_enabled(const char *subsys)
{
    const char *env = getenv("SLIMFARM_TRACE");
    if (!env || !*env)
        return false;
    if (strcmp(env, "all") == 0)
        return true;
    size_t n = strlen(subsys);
    for (const char *p = env; *p;) {
        const char *comma = strchr(p, ',');
        size_t len = comma ? (size_t)(comma - p) : strlen(p);
        if (len == n && strncmp(p, subsys, n) == 0)
            return true;
        if (!comma)
            break;
        p = comma + 1;
    }
    return false;
}

void
log_trace(const char *subsys, const char *who, const char *dir, const void *data, size_t len)
{
    if (!log_trace_enabled(subsys))
        return;
    char esc[LOG_LINE_MAX - 32];
    size_t o = 0;
    const unsigned char *b = data;
    for (size_t i = 0; i < len && o + 5 < sizeof(esc); i++) {
        unsigned char c = b[i];
        if (c == '\n') {
            esc[o++] = '\\';
            esc[o++] = 'n';
        } else if (c == '\r') {
            esc[o++] = '\\';
            esc[o++] = 'r';
        } else if (c < 0x20 || c >= 0x7f || c == '\\') {
            o += (size_t)snprintf(esc + o, sizeof(esc) - o, "\\x%02x", c);
        } else {
            esc[o++] = (char)c;
        }
    }
    esc[o] = '\0';
    char msg[LOG_LINE_MAX];
    snprintf(msg, sizeof(msg), "%s %s", dir, esc);
    /* Tracing was asked for by name, so it bypasses the level threshold. */
    pthread_mutex_lock(&log_lock);
    emit(LOG_DEBUG, subsys, who, msg);
    pthread_mutex_unlock(&log_lock);
}
