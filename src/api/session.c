/*
 * session.c - the browser sessions' table (see session.h).
 *
 * Why a flat table: at most SESSION_TABLE_MAX entries, looked up by a
 * token a client sent.  A lookup walks every slot and compares every
 * token in full (constant time), so how long a wrong token takes to be
 * refused says nothing about any live one; a thousand 32-byte compares
 * cost microseconds, once per request.  Expired entries are cleared as
 * they are met and before each make.
 *
 * Why the quota is per key: the table used to hold 64 sessions in all, the
 * oldest evicted first, so 64 logins with any key (a read-only one, in a
 * loop) logged every operator out.  Now a key only ever evicts its own.
 *
 * Thread: the loop thread.
 */
#include "session.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/random.h>

#include "../base/mem.h"

struct session {
    char token[SESSION_TOKEN_LEN + 1]; /* "" if the slot is free */
    char csrf[SESSION_TOKEN_LEN + 1];  /* what X-Csrf-Token must say for a change */
    char key[FARMCFG_KEY_MAX + 1];     /* the API key it stands for */
    int64_t made_ms;                   /* for the absolute expiry */
    int64_t used_ms;                   /* last use: the idle expiry, and which goes first */
};

struct sessions {
    int64_t idle_ms, max_ms;
    struct session tab[SESSION_TABLE_MAX];
};

/* a and b (n bytes each) equal, in time that does not depend on where they differ. */
static bool
same(const char *a, const char *b, size_t n)
{
    unsigned char d = 0;
    for (size_t i = 0; i < n; i++)
        d |= (unsigned char)(a[i] ^ b[i]);
    return d == 0;
}

static bool
expired(const struct sessions *s, const struct session *e, int64_t now_ms)
{
    return now_ms - e->used_ms >= s->idle_ms || now_ms - e->made_ms >= s->max_ms;
}

/* The live session of token, or NULL; expired ones met on the way are cleared. */
static struct session *
find(struct sessions *s, const char *token, int64_t now_ms)
{
    if (strlen(token) != SESSION_TOKEN_LEN)
        return NULL;
    struct session *hit = NULL;
    for (size_t i = 0; i < SESSION_TABLE_MAX; i++) {
        struct session *e = &s->tab[i];
        if (!e->token[0])
            continue;
        if (expired(s, e, now_ms)) {
            memset(e, 0, sizeof(*e));
            continue;
        }
        if (same(e->token, token, SESSION_TOKEN_LEN))
            hit = e;
    }
    return hit;
}

static int
random_hex(char *out, struct sf_err *err)
{
    unsigned char rnd[SESSION_TOKEN_LEN / 2];
    if (getrandom(rnd, sizeof(rnd), 0) != (ssize_t)sizeof(rnd))
        return sf_err_set(err, SF_EIO, "no random bytes for a session token");
    for (size_t i = 0; i < sizeof(rnd); i++)
        snprintf(out + 2 * i, 3, "%02x", rnd[i]);
    return SF_OK;
}

struct sessions *
sessions_new(int64_t idle_ms, int64_t max_ms, struct sf_err *err)
{
    struct sessions *s = mem_calloc(1, sizeof(*s));
    if (!s) {
        sf_err_set(err, SF_ENOMEM, "sessions: out of memory");
        return NULL;
    }
    s->idle_ms = idle_ms > 0 ? idle_ms : (int64_t)SESSION_IDLE_S * 1000;
    s->max_ms = max_ms > 0 ? max_ms : (int64_t)SESSION_MAX_S * 1000;
    return s;
}

void
sessions_free(struct sessions *s)
{
    if (s)
        explicit_bzero(s, sizeof(*s));
    free(s);
}

int
sessions_make(struct sessions *s, const char *key, int64_t now_ms, char *token, char *csrf,
              struct sf_err *err)
{
    struct session *free_slot = NULL, *own_lru = NULL;
    size_t own = 0;
    for (size_t i = 0; i < SESSION_TABLE_MAX; i++) {
        struct session *e = &s->tab[i];
        if (e->token[0] && expired(s, e, now_ms))
            memset(e, 0, sizeof(*e));
        if (!e->token[0]) {
            if (!free_slot)
                free_slot = e;
            continue;
        }
        if (strcmp(e->key, key) != 0)
            continue;
        own++;
        if (!own_lru || e->used_ms < own_lru->used_ms)
            own_lru = e;
    }
    struct session *e = own >= SESSION_PER_KEY_MAX ? own_lru : free_slot;
    if (!e)
        return sf_err_set(err, SF_EAGAIN, "every session slot is taken; try again later");
    struct session n = { .made_ms = now_ms, .used_ms = now_ms };
    int rc = random_hex(n.token, err);
    if (rc == SF_OK)
        rc = random_hex(n.csrf, err);
    if (rc)
        return rc;
    snprintf(n.key, sizeof(n.key), "%s", key);
    *e = n;
    memcpy(token, e->token, sizeof(e->token));
    memcpy(csrf, e->csrf, sizeof(e->csrf));
    return SF_OK;
}

const char *
sessions_key(struct sessions *s, const char *token, const char *csrf, int64_t now_ms)
{
    struct session *e = find(s, token, now_ms);
    if (!e)
        return NULL;
    if (csrf && (strlen(csrf) != SESSION_TOKEN_LEN || !same(e->csrf, csrf, SESSION_TOKEN_LEN)))
        return NULL;
    e->used_ms = now_ms;
    return e->key;
}

const char *
sessions_csrf(struct sessions *s, const char *token, int64_t now_ms)
{
    struct session *e = find(s, token, now_ms);
    if (!e)
        return NULL;
    e->used_ms = now_ms;
    return e->csrf;
}

bool
sessions_revoke(struct sessions *s, const char *token)
{
    /* revoking an expired session is still a revoke: INT64_MIN never expires one */
    struct session *e = find(s, token, INT64_MIN / 2);
    if (e)
        memset(e, 0, sizeof(*e));
    return e != NULL;
}

size_t
sessions_keep_keys(struct sessions *s, const struct farmcfg_key *keys, size_t n_keys)
{
    struct farmcfg view = { .keys = (struct farmcfg_key *)keys, .n_keys = n_keys };
    size_t ended = 0;
    for (size_t i = 0; i < SESSION_TABLE_MAX; i++) {
        struct session *e = &s->tab[i];
        if (e->token[0] && !farmcfg_key(&view, e->key)) {
            memset(e, 0, sizeof(*e));
            ended++;
        }
    }
    return ended;
}

size_t
sessions_count(struct sessions *s, const char *key, int64_t now_ms)
{
    size_t n = 0;
    for (size_t i = 0; i < SESSION_TABLE_MAX; i++) {
        const struct session *e = &s->tab[i];
        if (e->token[0] && !expired(s, e, now_ms) && strcmp(e->key, key) == 0)
            n++;
    }
    return n;
}
