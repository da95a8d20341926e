/*
 * session.h - the dashboard's browser sessions, kept on the server: a
 * table of random tokens, each standing for the API key it was made with,
 * with an idle and an absolute expiry, revocable (log out), and a quota
 * per key.
 *
 * A session is made when a browser logs in with its key (GET /api/whoami
 * with X-Api-Key, web.c).  Its token travels only in the HttpOnly cookie;
 * its CSRF token, which the page reads from whoami's JSON and sends as
 * the X-Csrf-Token header, is what lets the cookie authorize a request
 * that changes something (a page on another origin can read neither).
 *
 * Rules:
 *   - idle expiry: a session not used for idle_ms ends (default
 *     SESSION_IDLE_S); absolute expiry: it ends max_ms after it was made,
 *     used or not (default SESSION_MAX_S).  An ended session is gone: its
 *     token authorizes nothing, ever again.
 *   - quota: each key holds at most SESSION_PER_KEY_MAX sessions; a new
 *     one beyond that evicts that key's least recently used session, never
 *     another key's (a read-only key logging in over and over cannot log
 *     out the operators).
 *   - tokens are 128 random bits from the kernel, compared in constant
 *     time, and live only in this process: no other daemon (or this one
 *     restarted) knows them, whatever keys it shares.
 *
 * Times are the caller's (now_ms, any monotonic ms clock), so tests step
 * them.  Thread: one thread (the loop's); nothing is locked.
 */
#ifndef SF_API_SESSION_H
#define SF_API_SESSION_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"
#include "../farm/farmcfg.h"

#define SESSION_IDLE_S      (8 * 3600)      /* a working shift away ends it */
#define SESSION_MAX_S       (7 * 24 * 3600) /* a week, however busy */
#define SESSION_PER_KEY_MAX 16              /* browsers per key: tabs of one browser share one */
/* Every key at its quota: FARMCFG_KEYS_MAX * 16 * ~200 bytes = 200 KiB at most. */
#define SESSION_TABLE_MAX (FARMCFG_KEYS_MAX * SESSION_PER_KEY_MAX)
#define SESSION_TOKEN_LEN 32 /* hex digits of a token or CSRF token (128 bits) */

struct sessions;

/* idle_ms, max_ms <= 0: the defaults above.  NULL with err set (SF_ENOMEM). */
struct sessions *sessions_new(int64_t idle_ms, int64_t max_ms, struct sf_err *err);
void sessions_free(struct sessions *s);

/*
 * A new session for key at now_ms: its token and CSRF token into token and
 * csrf (SESSION_TOKEN_LEN + 1 bytes each).  Evicts key's least recently
 * used session when key is at its quota.  SF_EIO when the kernel gives no
 * random bytes, SF_EAGAIN when the table is full (cannot happen while keys
 * are at most FARMCFG_KEYS_MAX).
 */
int sessions_make(struct sessions *s, const char *key, int64_t now_ms, char *token, char *csrf,
                  struct sf_err *err);

/*
 * The API key token stands for at now_ms, or NULL (unknown, ended, or
 * expired: then it is dropped).  csrf NULL: a safe request (GET/HEAD);
 * otherwise it must be the session's CSRF token, or NULL is returned.  A
 * hit counts as use (the idle clock restarts).  The string lives until the
 * session ends.
 */
const char *sessions_key(struct sessions *s, const char *token, const char *csrf, int64_t now_ms);

/* The CSRF token of a live session (as sessions_key with csrf NULL), or NULL. */
const char *sessions_csrf(struct sessions *s, const char *token, int64_t now_ms);

/* End the session of token (log out); false if there was none. */
bool sessions_revoke(struct sessions *s, const char *token);

/* End every session whose key is not among keys (a reload removed it);
   returns how many ended. */
size_t sessions_keep_keys(struct sessions *s, const struct farmcfg_key *keys, size_t n_keys);

/* Live sessions of key at now_ms (tests, logs). */
size_t sessions_count(struct sessions *s, const char *key, int64_t now_ms);

#endif
