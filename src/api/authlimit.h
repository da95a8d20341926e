/*
 * authlimit.h - failed logins, per client address: logged without
 * flooding the log, and slowed.
 *
 * A failed login is a request to a keyed route with no key, an unknown key
 * or a dead session (http.c answers 401), or an OctoPrint push socket's
 * auth message with an unknown session (api_octopush.c, which closes the
 * socket where http.c answers 429).  Each address has a token bucket
 * (kept as the time its debt is paid, GCRA): AUTHLIMIT_BURST failures at
 * once, then one per AUTHLIMIT_REFILL_MS.  An address past its burst gets
 * 429 for every keyed request, good key or not, until the bucket refills
 * (each 429 adds a refill's worth of waiting, up to a minute),
 * so guessing keys runs at one a second (7,000 a second before), and the
 * answer never says whether a guess was right.  Other addresses are never
 * slowed: a good client elsewhere notices nothing.  Behind a reverse proxy
 * every client has the proxy's address; the limit then holds for all.
 *
 * Logging: the first failure from an address is logged at once, with its
 * reason (never the key); later ones within AUTHLIMIT_LOG_MS are counted
 * and the next line says how many failed and how many were refused.
 *
 * Memory: a fixed table of AUTHLIMIT_ADDRS addresses; a new address takes
 * the slot of the one that has been clean longest.
 *
 * Thread: one thread (the loop's); times are the caller's (monotonic ms).
 */
#ifndef SF_API_AUTHLIMIT_H
#define SF_API_AUTHLIMIT_H

#include <stdbool.h>
#include <stdint.h>
#include <sys/socket.h>

#define AUTHLIMIT_BURST          20    /* failures at once: typos, a tab with an old cookie */
#define AUTHLIMIT_REFILL_MS      1000  /* then one a second */
#define AUTHLIMIT_LOG_MS         10000 /* one log line per address per 10 s */
#define AUTHLIMIT_PENALTY_MAX_MS 60000 /* refused requests extend the wait up to a minute */
#define AUTHLIMIT_ADDRS          256   /* addresses tracked: a farm's LAN, and then some */
#define AUTHLIMIT_ADDR_MAX       64    /* an address as text (IPv6 with zone fits) */

struct authlimit;

/* NULL when out of memory. */
struct authlimit *authlimit_new(void);
void authlimit_free(struct authlimit *al);

/* The client address as text ("127.0.0.1", "::1"; "?" if unknown) into out. */
void authlimit_addr(const struct sockaddr *sa, char out[AUTHLIMIT_ADDR_MAX]);

/*
 * A keyed request from addr at now_ms whose key check failed (failed) or
 * passed.  Returns 0 to let it go its way (a failure still answers 401),
 * or the seconds to wait when addr is past its burst: answer 429 then,
 * whatever its key.  Failures and refusals are counted and logged.
 */
unsigned authlimit_check(struct authlimit *al, const char *addr, bool failed, const char *why,
                         int64_t now_ms);

#endif
