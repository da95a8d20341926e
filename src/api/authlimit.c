/*
 * authlimit.c - failed logins per address: a token bucket each, and a
 * log line per address per interval (see authlimit.h).
 *
 * Why in its own module: http.c decides what a request may do; how much
 * failing an address may do, and what the log says of it, is a policy of
 * its own with its own numbers, tested without a server.
 *
 * The bucket is kept as one time (GCRA's "theoretical arrival time"): tat
 * is when the address's failures will have been paid off at one per
 * AUTHLIMIT_REFILL_MS.  A failure adds AUTHLIMIT_REFILL_MS to it; the
 * address is over its burst while tat is more than AUTHLIMIT_BURST - 1
 * refills ahead of now.  One number, no timer, nothing to refill.  A
 * refused request adds to it too (up to AUTHLIMIT_PENALTY_MAX_MS), so a
 * client hammering past its burst stays refused until it waits.
 *
 * Thread: the loop thread.
 */
#include "authlimit.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/log.h"
#include "../base/mem.h"

struct entry {
    char addr[AUTHLIMIT_ADDR_MAX]; /* "" if the slot is free */
    int64_t tat_ms;                /* when its failures are paid off */
    int64_t logged_ms;             /* its last log line */
    unsigned n_failed;             /* failures since that line */
    unsigned n_refused;            /* 429s since that line */
    char why[96];                  /* the last failure's reason */
};

struct authlimit {
    struct entry tab[AUTHLIMIT_ADDRS];
};

struct authlimit *
authlimit_new(void)
{
    return mem_calloc(1, sizeof(struct authlimit));
}

void
authlimit_free(struct authlimit *al)
{
    free(al);
}

void
authlimit_addr(const struct sockaddr *sa, char out[AUTHLIMIT_ADDR_MAX])
{
    const void *a = NULL;
    if (sa && sa->sa_family == AF_INET)
        a = &((const struct sockaddr_in *)(const void *)sa)->sin_addr;
    else if (sa && sa->sa_family == AF_INET6)
        a = &((const struct sockaddr_in6 *)(const void *)sa)->sin6_addr;
    if (!a || !inet_ntop(sa->sa_family, a, out, AUTHLIMIT_ADDR_MAX))
        snprintf(out, AUTHLIMIT_ADDR_MAX, "?");
}

/* addr's entry; a new one (the slot clean longest) if make; NULL if none. */
static struct entry *
entry_of(struct authlimit *al, const char *addr, bool make, int64_t now_ms)
{
    struct entry *oldest = &al->tab[0];
    for (size_t i = 0; i < AUTHLIMIT_ADDRS; i++) {
        struct entry *e = &al->tab[i];
        if (e->addr[0] && strcmp(e->addr, addr) == 0)
            return e;
        if (!oldest->addr[0])
            continue; /* a free slot is found: keep it */
        if (!e->addr[0] || e->tat_ms < oldest->tat_ms)
            oldest = e;
    }
    if (!make)
        return NULL;
    *oldest = (struct entry){ .tat_ms = now_ms, .logged_ms = INT64_MIN };
    snprintf(oldest->addr, sizeof(oldest->addr), "%s", addr);
    return oldest;
}

/* One line per address per AUTHLIMIT_LOG_MS, counting what it stands for. */
static void
maybe_log(struct entry *e, int64_t now_ms)
{
    if (e->logged_ms != INT64_MIN && now_ms - e->logged_ms < AUTHLIMIT_LOG_MS)
        return;
    if (e->n_failed == 1 && !e->n_refused)
        log_warn("http", "failed login from %s: %s", e->addr, e->why);
    else
        log_warn("http", "%u failed logins from %s (last: %s), %u refused (429: too many)",
                 e->n_failed, e->addr, e->why, e->n_refused);
    e->logged_ms = now_ms;
    e->n_failed = e->n_refused = 0;
}

unsigned
authlimit_check(struct authlimit *al, const char *addr, bool failed, const char *why,
                int64_t now_ms)
{
    struct entry *e = entry_of(al, addr, failed, now_ms);
    if (!e)
        return 0; /* no failures on record: nothing to slow */
    int64_t allowance = (int64_t)(AUTHLIMIT_BURST - 1) * AUTHLIMIT_REFILL_MS;
    int64_t ahead = e->tat_ms - now_ms;
    if (ahead > allowance) {
        /* hammering while refused keeps it refused (up to a minute past
           the burst), so only a client that waits gets its next try */
        if (ahead < allowance + AUTHLIMIT_PENALTY_MAX_MS)
            e->tat_ms += AUTHLIMIT_REFILL_MS;
        ahead = e->tat_ms - now_ms;
        e->n_refused++;
        maybe_log(e, now_ms);
        return (unsigned)((ahead - allowance + 999) / 1000);
    }
    if (!failed)
        return 0;
    e->tat_ms = (e->tat_ms > now_ms ? e->tat_ms : now_ms) + AUTHLIMIT_REFILL_MS;
    e->n_failed++;
    snprintf(e->why, sizeof(e->why), "%s", why);
    maybe_log(e, now_ms);
    return 0;
}
