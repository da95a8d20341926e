/*
 * test_session.c - the dashboard's session table (src/api/session.h) and
 * the failed-login limiter (src/api/authlimit.h), on times the test steps:
 * idle and absolute expiry, revoke, the per-key quota, a reload's removed
 * keys; a token bucket per address, its 429s and its log lines.  The same
 * rules over real HTTP: test_web.c and tests/integ/farmd_sess.sh.
 */
#include <arpa/inet.h>
#include <netinet/in.h>
#include <stdio.h>
#include <string.h>

#include "../../src/api/authlimit.h"
#include "../../src/api/session.h"
#include "../../src/base/log.h"
#include "../t.h"

#define KEY_RW "rw-key-0123456789abcdef"
#define KEY_RO "ro-key-0123456789abcdef"

T_CASE(session_idle_and_absolute_expiry)
{
    struct sf_err err;
    struct sessions *s = sessions_new(1000, 5000, &err); /* idle 1 s, at most 5 s */
    T_TRUE(s != NULL);
    char tok[SESSION_TOKEN_LEN + 1], csrf[SESSION_TOKEN_LEN + 1];
    T_OK(sessions_make(s, KEY_RW, 0, tok, csrf, &err), &err);
    T_EQ_INT(strlen(tok), SESSION_TOKEN_LEN);
    T_TRUE(strcmp(tok, csrf) != 0);
    /* used every 900 ms it lives on, up to its absolute end */
    for (int64_t t = 900; t < 5000; t += 900)
        T_EQ_STR(sessions_key(s, tok, NULL, t), KEY_RW);
    T_TRUE(sessions_key(s, tok, NULL, 5000) == NULL);
    T_TRUE(sessions_key(s, tok, NULL, 5100) == NULL); /* and stays gone */
    /* left alone past its idle time, it ends */
    T_OK(sessions_make(s, KEY_RW, 10000, tok, csrf, &err), &err);
    T_EQ_STR(sessions_key(s, tok, NULL, 10999), KEY_RW);
    T_TRUE(sessions_key(s, tok, NULL, 12000) == NULL);
    T_TRUE(sessions_csrf(s, tok, 12000) == NULL);
    sessions_free(s);
}

T_CASE(session_csrf_and_revoke)
{
    struct sf_err err;
    struct sessions *s = sessions_new(0, 0, &err);
    T_TRUE(s != NULL);
    char tok[SESSION_TOKEN_LEN + 1], csrf[SESSION_TOKEN_LEN + 1];
    T_OK(sessions_make(s, KEY_RW, 0, tok, csrf, &err), &err);
    T_TRUE(sessions_key(s, tok, "", 1) == NULL);
    T_TRUE(sessions_key(s, tok, tok, 1) == NULL); /* the token is not its CSRF token */
    T_EQ_STR(sessions_key(s, tok, csrf, 1), KEY_RW);
    T_EQ_STR(sessions_csrf(s, tok, 1), csrf);
    T_TRUE(sessions_key(s, "short", NULL, 1) == NULL);
    T_TRUE(sessions_revoke(s, tok));
    T_TRUE(sessions_key(s, tok, NULL, 2) == NULL);
    T_TRUE(!sessions_revoke(s, tok));
    sessions_free(s);
}

T_CASE(session_quota_is_per_key_and_reload_ends_removed_keys)
{
    struct sf_err err;
    struct sessions *s = sessions_new(0, 0, &err);
    T_TRUE(s != NULL);
    char rw[SESSION_TOKEN_LEN + 1], ro[3][SESSION_TOKEN_LEN + 1], csrf[SESSION_TOKEN_LEN + 1];
    T_OK(sessions_make(s, KEY_RW, 0, rw, csrf, &err), &err);
    for (int i = 0; i < 1000; i++)
        T_OK(sessions_make(s, KEY_RO, 1 + i, ro[i < 2 ? i : 2], csrf, &err), &err);
    T_EQ_STR(sessions_key(s, rw, NULL, 2000), KEY_RW); /* never another key's */
    T_EQ_INT(sessions_count(s, KEY_RO, 2000), SESSION_PER_KEY_MAX);
    T_TRUE(sessions_key(s, ro[0], NULL, 2000) == NULL); /* its own least recently used */
    T_EQ_STR(sessions_key(s, ro[2], NULL, 2000), KEY_RO);
    /* the least recently used goes, not the oldest made */
    char a[SESSION_TOKEN_LEN + 1], b[SESSION_TOKEN_LEN + 1], x[SESSION_TOKEN_LEN + 1];
    struct sessions *q = sessions_new(0, 0, &err);
    T_OK(sessions_make(q, KEY_RW, 0, a, csrf, &err), &err);
    T_OK(sessions_make(q, KEY_RW, 1, b, csrf, &err), &err);
    for (int i = 2; i < SESSION_PER_KEY_MAX; i++)
        T_OK(sessions_make(q, KEY_RW, i, x, csrf, &err), &err);
    T_EQ_STR(sessions_key(q, a, NULL, 100), KEY_RW); /* a is used: b is now the stalest */
    T_OK(sessions_make(q, KEY_RW, 101, x, csrf, &err), &err);
    T_EQ_STR(sessions_key(q, a, NULL, 102), KEY_RW);
    T_TRUE(sessions_key(q, b, NULL, 102) == NULL);
    sessions_free(q);
    /* a reload that drops the read-only key ends its sessions */
    struct farmcfg_key keep = { .key = KEY_RW };
    T_EQ_INT(sessions_keep_keys(s, &keep, 1), SESSION_PER_KEY_MAX);
    T_TRUE(sessions_key(s, ro[2], NULL, 2001) == NULL);
    T_EQ_STR(sessions_key(s, rw, NULL, 2001), KEY_RW);
    sessions_free(s);
}

struct seen {
    int n;
    char last[512];
};

static void
sink(void *ud, enum log_level level, const char *subsys, const char *printer, const char *msg)
{
    (void)level, (void)subsys, (void)printer;
    struct seen *s = ud;
    s->n++;
    snprintf(s->last, sizeof(s->last), "%s", msg);
}

T_CASE(authlimit_slows_and_logs_failed_logins_per_address)
{
    struct authlimit *al = authlimit_new();
    T_TRUE(al != NULL);
    struct seen seen = { 0 };
    log_set_sink(sink, &seen);
    /* a burst of failures at one instant: answered as they come (401) */
    for (int i = 0; i < AUTHLIMIT_BURST; i++)
        T_EQ_INT(authlimit_check(al, "10.0.0.1", true, "unknown API key", 1000), 0);
    T_EQ_INT(seen.n, 1); /* the first at once, the rest counted */
    T_TRUE(strstr(seen.last, "failed login from 10.0.0.1: unknown API key") != NULL);
    /* past it: 429, good key or not, so a guess that hits says nothing */
    T_TRUE(authlimit_check(al, "10.0.0.1", true, "unknown API key", 1000) > 0);
    T_TRUE(authlimit_check(al, "10.0.0.1", false, "", 1000) > 0);
    /* another address is never slowed */
    T_EQ_INT(authlimit_check(al, "10.0.0.2", false, "", 1000), 0);
    T_EQ_INT(authlimit_check(al, "10.0.0.2", true, "missing X-Api-Key header", 1000), 0);
    T_EQ_INT(seen.n, 2);
    /* each refusal adds a second to wait: the two above make it 3 s */
    T_TRUE(authlimit_check(al, "10.0.0.1", true, "unknown API key", 3999) > 0);
    T_EQ_INT(authlimit_check(al, "10.0.0.1", true, "unknown API key", 5000), 0);
    T_TRUE(authlimit_check(al, "10.0.0.1", true, "unknown API key", 5000) > 0);
    /* one line per address per interval, with the count, never the key */
    T_EQ_INT(seen.n, 2);
    T_EQ_INT(authlimit_check(al, "10.0.0.1", true, "unknown API key", 15000), 0);
    T_EQ_INT(seen.n, 3);
    T_TRUE(strstr(seen.last, "21 failed logins from 10.0.0.1") != NULL);
    T_TRUE(strstr(seen.last, "4 refused") != NULL);
    /* hammering is capped: a minute past the burst at most */
    for (int i = 0; i < 1000; i++)
        authlimit_check(al, "10.0.0.3", true, "unknown API key", 20000);
    T_TRUE(authlimit_check(al, "10.0.0.3", false, "", 20000) <= 61);
    T_EQ_INT(authlimit_check(al, "10.0.0.3", false, "", 20000 + 62000), 0);
    /* bounded: a flood of addresses reuses the table */
    for (int i = 0; i < 4 * AUTHLIMIT_ADDRS; i++) {
        char a[32];
        snprintf(a, sizeof(a), "10.1.%d.%d", i / 256, i % 256);
        authlimit_check(al, a, true, "unknown API key", 20000);
    }
    log_set_sink(NULL, NULL);
    authlimit_free(al);
}

T_CASE(authlimit_names_ipv4_and_ipv6_addresses)
{
    char out[AUTHLIMIT_ADDR_MAX];
    struct sockaddr_in a4 = { .sin_family = AF_INET, .sin_addr.s_addr = htonl(0x7f000001) };
    authlimit_addr((struct sockaddr *)&a4, out);
    T_EQ_STR(out, "127.0.0.1");
    struct sockaddr_in6 a6 = { .sin6_family = AF_INET6, .sin6_addr = IN6ADDR_LOOPBACK_INIT };
    authlimit_addr((struct sockaddr *)&a6, out);
    T_EQ_STR(out, "::1");
    authlimit_addr(NULL, out);
    T_EQ_STR(out, "?");
}
