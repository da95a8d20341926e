/*
 * store_host.c - hosts, their leases and printers, and the claims and
 * fencing tokens that move jobs between them (store_host.h), over the
 * schema of migration 11 (store_int.h).
 *
 * Why leases and tokens rather than a coordinator: the database is the one
 * thing every host shares, and its transactions already decide races.  A
 * host's token (hosts.token, bumped at each join) says which process holds
 * a name; its lease says until when the others trust it.  A job's fencing
 * token (jobs.fence, bumped at each claim and attach) says which host may
 * move it: a host cut off from the database keeps its old token, and every
 * event it sends once it is back carries that token and is refused
 * (store_job_fence, which store_job_event calls first).  State moves keep
 * job.c's rules: a claim is the PREPARE event (its states come from
 * job_next), a reaped host's jobs take the CRASHED event through
 * store_job_event_in.
 *
 * Races: a claim and a reap of the same host meet on the host's row (the
 * claim reads it FOR SHARE on PostgreSQL, the reap updates it), so a host
 * never claims a job after it was reaped.  Two claims meet on the job's row:
 * PostgreSQL's SKIP LOCKED passes a row another claim holds, SQLite has one
 * writer.
 *
 * Thread: the store's.
 */
#include "store_host.h"

#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "../base/clock.h"
#include "../base/mem.h"
#include "store_int.h"

static bool
name_valid(const char *name)
{
    size_t len = name ? strlen(name) : 0;
    if (len == 0 || len >= STORE_HOST_NAME_MAX)
        return false;
    for (const char *p = name; *p; p++)
        if (!((*p >= 'a' && *p <= 'z') || (*p >= 'A' && *p <= 'Z') || (*p >= '0' && *p <= '9') ||
              *p == '.' || *p == '-' || *p == '_'))
            return false;
    return true;
}

static int
check_name(const char *name, struct sf_err *err)
{
    if (name_valid(name))
        return SF_OK;
    return sf_err_set(err, SF_EINVAL,
                      "host: '%.80s' is not a host name (1..%d letters, digits, '.', '-', '_')",
                      name ? name : "", STORE_HOST_NAME_MAX - 1);
}

static int
check_lease(int64_t lease_ms, struct sf_err *err)
{
    if (lease_ms >= 1 && lease_ms <= STORE_LEASE_MAX_MS)
        return SF_OK;
    return sf_err_set(err, SF_EINVAL, "lease_ms: %lld is not in 1..%lld", (long long)lease_ms,
                      (long long)STORE_LEASE_MAX_MS);
}

bool
store_is_pg(const struct store *s)
{
    return sqldb_engine(s->db) == SQLDB_PG;
}

/* End the transaction a body ran in: commit if it returned SF_OK, else roll back. */
int
store_end_tx(struct store *s, int rc, struct sf_err *err)
{
    if (rc == SF_OK && (rc = store_commit(s, err)) == SF_OK)
        return SF_OK;
    store_rollback(s);
    return rc;
}

/* ---- connections ---- */

static struct store *
conn_store(const char *dir, const char *target, unsigned flags, struct sf_err *err)
{
    struct store *r = mem_calloc(1, sizeof(*r));
    if (!r) {
        sf_err_set(err, SF_ENOMEM, "store: out of memory");
        return NULL;
    }
    snprintf(r->dir, sizeof(r->dir), "%s", dir);
    snprintf(r->target, sizeof(r->target), "%s", target);
    r->lock_fd = -1; /* a peer or a viewer: the data dir is its daemon's */
    if (!(r->db = sqldb_open(r->target, flags, err))) {
        store_close(r);
        return NULL;
    }
    return r;
}

struct store *
store_open_peer(const struct store *s, struct sf_err *err)
{
    struct store *r = conn_store(s->dir, s->target, 0, err);
    if (r) /* one of several hosts: a holder's events without a fence are refused here too */
        r->host = s->host;
    return r;
}

struct store *
store_open_listener(const struct store *s, struct sf_err *err)
{
    return conn_store(s->dir, s->target, SQLDB_NOWAIT, err);
}

struct store *
store_open_view(const char *target, struct sf_err *err)
{
    if (!target || !target[0] || strlen(target) >= STORE_PATH_MAX - 16) {
        sf_err_set(err, SF_EINVAL, "store: '%.80s' is empty or too long", target ? target : "");
        return NULL;
    }
    if (sqldb_is_url(target))
        return conn_store("", target, SQLDB_READONLY, err);
    char path[STORE_PATH_MAX];
    snprintf(path, sizeof(path), "%s/slimfarm.db", target);
    if (access(path, F_OK) != 0) {
        sf_err_sys(err, "store: no store in data dir '%s' ('%s')", target, path);
        return NULL;
    }
    return conn_store(target, path, SQLDB_READONLY, err);
}

/* ---- the host's row ---- */

/* Why name's token is not current (SF_ESTALE), or SF_EIO. */
static int
lease_lost(struct store *s, const char *name, int64_t token, int64_t now_ms, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(
        s, &st, "SELECT token, reaped_ms, lease_until_ms FROM hosts WHERE name = ?1", err);
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, name);
    rc = sqldb_step(st);
    int64_t cur = rc == SQLDB_ROW ? sqldb_column_int64(st, 0) : 0;
    int64_t reaped = rc == SQLDB_ROW ? sqldb_column_int64(st, 1) : 0;
    int64_t until = rc == SQLDB_ROW ? sqldb_column_int64(st, 2) : 0;
    sqldb_finalize(st);
    if (rc == SQLDB_DONE)
        return sf_err_set(err, SF_ESTALE, "host '%s' has not joined", name);
    if (rc != SQLDB_ROW)
        return store_db_fail(s, err, "read host");
    if (cur != token)
        return sf_err_set(err, SF_ESTALE,
                          "host '%s': another process joined under this name (token %lld; this "
                          "one holds %lld): its lease is lost",
                          name, (long long)cur, (long long)token);
    if (reaped)
        return sf_err_set(err, SF_ESTALE,
                          "host '%s': its lease ran out and its work was reaped %.1f s ago: join "
                          "again",
                          name, (double)(now_ms - reaped) / 1000);
    return sf_err_set(err, SF_ESTALE, "host '%s': its lease ran out %.1f s ago: renew it first",
                      name, (double)(now_ms - until) / 1000);
}

/* In the caller's transaction: that name's lease is token's and runs at now_ms, holding its row
   (PostgreSQL: FOR SHARE, so a reap waits for the caller, and the caller's claims go with it). */
int
store_host_hold(struct store *s, const char *name, int64_t token, int64_t now_ms,
                struct sf_err *err)
{
    int rc = check_name(name, err);
    if (rc)
        return rc;
    char sql[192];
    snprintf(sql, sizeof(sql),
             "SELECT token FROM hosts WHERE name = ?1 AND token = ?2 AND reaped_ms = 0"
             " AND lease_until_ms > ?3%s",
             store_is_pg(s) ? " FOR SHARE" : "");
    struct sqldb_stmt *st;
    if ((rc = store_prepare(s, &st, sql, err)))
        return rc;
    sqldb_bind_text(st, 1, name);
    sqldb_bind_int64(st, 2, token);
    sqldb_bind_int64(st, 3, now_ms);
    rc = sqldb_step(st);
    sqldb_finalize(st);
    if (rc == SQLDB_ROW)
        return SF_OK;
    return rc == SQLDB_DONE ? lease_lost(s, name, token, now_ms, err)
                            : store_db_fail(s, err, "hold host");
}

/* FNV-1a of the name: the key of its session lock on PostgreSQL. */
static int64_t
name_key(const char *name)
{
    uint64_t h = 1469598103934665603u;
    for (const char *p = "slimfarm host "; *p; p++)
        h = (h ^ (unsigned char)*p) * 1099511628211u;
    for (const char *p = name; *p; p++)
        h = (h ^ (unsigned char)*p) * 1099511628211u;
    return (int64_t)h;
}

/* PostgreSQL: lock name to this connection (*got: whether it could); SQLite: the data dir's
   flock did. */
static int
lock_name(struct store *s, const char *name, bool *got, struct sf_err *err)
{
    *got = true;
    if (!store_is_pg(s))
        return SF_OK;
    struct sqldb_stmt *st;
    int rc =
        store_prepare(s, &st, "SELECT CASE WHEN pg_try_advisory_lock(?1) THEN 1 ELSE 0 END", err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, name_key(name));
    rc = sqldb_step(st);
    *got = rc == SQLDB_ROW && sqldb_column_int(st, 0) == 1;
    sqldb_finalize(st);
    return rc == SQLDB_ROW ? SF_OK : store_db_fail(s, err, "lock host name");
}

/* Undo one lock_name that got the lock (a join that failed after it): the session holds the
   name as many times as it locked it. */
static void
unlock_name(struct store *s, const char *name)
{
    struct sqldb_stmt *st;
    if (!store_is_pg(s) || store_prepare(s, &st, "SELECT pg_advisory_unlock(?1)", NULL))
        return;
    sqldb_bind_int64(st, 1, name_key(name));
    sqldb_step(st);
    sqldb_finalize(st);
}

/* What the name's row holds now, for join. */
struct holder {
    bool found;
    int64_t pid, heartbeat_ms, lease_until_ms, reaped_ms;
};

static int
read_holder(struct store *s, const char *name, struct holder *h, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st,
                           "SELECT pid, heartbeat_ms, lease_until_ms, reaped_ms FROM hosts"
                           " WHERE name = ?1",
                           err);
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, name);
    rc = sqldb_step(st);
    *h = (struct holder){ rc == SQLDB_ROW, 0, 0, 0, 0 };
    if (rc == SQLDB_ROW) {
        h->pid = sqldb_column_int64(st, 0);
        h->heartbeat_ms = sqldb_column_int64(st, 1);
        h->lease_until_ms = sqldb_column_int64(st, 2);
        h->reaped_ms = sqldb_column_int64(st, 3);
    }
    sqldb_finalize(st);
    return rc == SQLDB_ROW || rc == SQLDB_DONE ? SF_OK : store_db_fail(s, err, "read host");
}

static int
refuse_join(const char *name, const struct holder *h, int64_t now_ms, struct sf_err *err)
{
    if (!h->found || h->lease_until_ms <= now_ms)
        return sf_err_set(err, SF_EAGAIN,
                          "host '%s' is in use by another process (its connection holds the "
                          "name): stop it first, or give this host another name",
                          name);
    return sf_err_set(err, SF_EAGAIN,
                      "host '%s' is held by another process (pid %lld): its lease, renewed "
                      "%.1f s ago, runs %.1f s more: stop it first, or give this host another "
                      "name",
                      name, (long long)h->pid, (double)(now_ms - h->heartbeat_ms) / 1000,
                      (double)(h->lease_until_ms - now_ms) / 1000);
}

static int reap_host(struct store *s, const char *name, int64_t now_ms, int64_t heartbeat_ms,
                     struct store_recovery *moved, struct sf_err *err);

/* Write name's row for this process, in the caller's transaction: token 1, or one past its
   last holder's. */
static int
take_name(struct store *s, const char *name, int64_t now_ms, int64_t lease_ms, int64_t *token,
          struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(
        s, &st,
        "INSERT INTO hosts(name, token, pid, version, started_ms, heartbeat_ms, lease_until_ms,"
        " reaped_ms) VALUES(?1, 1, ?2, ?3, ?4, ?4, ?5, 0) ON CONFLICT(name) DO UPDATE SET"
        " token = hosts.token + 1, pid = excluded.pid, version = excluded.version,"
        " started_ms = excluded.started_ms, heartbeat_ms = excluded.heartbeat_ms,"
        " lease_until_ms = excluded.lease_until_ms, reaped_ms = 0 RETURNING token",
        err);
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, name);
    sqldb_bind_int64(st, 2, (int64_t)getpid());
    sqldb_bind_int64(st, 3, store_schema_version());
    sqldb_bind_int64(st, 4, now_ms);
    sqldb_bind_int64(st, 5, now_ms + lease_ms);
    rc = sqldb_step(st);
    if (rc == SQLDB_ROW)
        *token = sqldb_column_int64(st, 0);
    sqldb_finalize(st);
    if (rc != SQLDB_ROW)
        return store_db_fail(s, err, "join host");
    char detail[160];
    snprintf(detail, sizeof(detail), "host '%s' joined: pid %lld, token %lld, lease %lld ms", name,
             (long long)getpid(), (long long)*token, (long long)lease_ms);
    return store_log_event(s, 0, NULL, "host-join", detail, err);
}

/* The rest of store_host_join, in the caller's transaction, once the name is locked. */
static int
join_tx(struct store *s, const char *name, int64_t now, int64_t lease_ms, int64_t *token,
        struct sf_err *err)
{
    struct holder h;
    int rc = read_holder(s, name, &h, err);
    if (rc)
        return rc;
    if (h.found && !h.reaped_ms && h.lease_until_ms > now)
        return refuse_join(name, &h, now, err);
    /* the name's last holder died with its lease: its work moves on before this one starts */
    if (h.found && !h.reaped_ms && (rc = reap_host(s, name, now, h.heartbeat_ms, NULL, err)))
        return rc;
    return take_name(s, name, now, lease_ms, token, err);
}

int
store_host_join(struct store *s, const char *name, int64_t lease_ms, int64_t *token,
                struct sf_err *err)
{
    int rc;
    bool got;
    if ((rc = check_name(name, err)) || (rc = check_lease(lease_ms, err)) ||
        (rc = lock_name(s, name, &got, err)))
        return rc;
    int64_t now = store_clock_ms(s);
    struct holder h;
    if (!got) {
        if ((rc = read_holder(s, name, &h, err)))
            return rc;
        return refuse_join(name, &h, now, err);
    }
    if ((rc = store_begin(s, err)) == SF_OK)
        rc = store_end_tx(s, join_tx(s, name, now, lease_ms, token, err), err);
    if (rc) {
        unlock_name(s, name); /* refused or failed: the name stays free for its holder */
        return rc;
    }
    /* the lock is this session's: a reconnect takes it again (store_host_relock) */
    snprintf(s->host_name, sizeof(s->host_name), "%s", name);
    s->host_token = *token;
    s->name_lost = false;
    return SF_OK;
}

int
store_host_relock(struct store *s, struct sf_err *err)
{
    if (!s->host_name[0] || s->name_lost)
        return SF_OK;
    bool got;
    int rc = lock_name(s, s->host_name, &got, err);
    if (rc || got)
        return rc;
    /* held: by this process's lost session, which the server has not ended yet (try again
       shortly), or by a process that joined under the name since (the lease is lost) */
    struct sqldb_stmt *st;
    if ((rc = store_prepare(s, &st, "SELECT token FROM hosts WHERE name = ?1", err)))
        return rc;
    sqldb_bind_text(st, 1, s->host_name);
    rc = sqldb_step(st);
    int64_t cur = rc == SQLDB_ROW ? sqldb_column_int64(st, 0) : 0;
    sqldb_finalize(st);
    if (rc != SQLDB_ROW && rc != SQLDB_DONE)
        return store_db_fail(s, err, "read host");
    if (cur == s->host_token)
        return sf_err_set(err, SF_EAGAIN,
                          "host '%s': its name's lock is still held by the lost session",
                          s->host_name);
    s->name_lost = true;
    return SF_OK;
}

int
store_host_beat(struct store *s, const char *name, int64_t token, int64_t lease_ms,
                struct sf_err *err)
{
    int rc;
    if ((rc = check_name(name, err)) || (rc = check_lease(lease_ms, err)))
        return rc;
    struct sqldb_stmt *st;
    if ((rc = store_prepare(s, &st,
                            "UPDATE hosts SET heartbeat_ms = ?1, lease_until_ms = ?2"
                            " WHERE name = ?3 AND token = ?4 AND reaped_ms = 0",
                            err)))
        return rc;
    int64_t now = store_clock_ms(s);
    sqldb_bind_int64(st, 1, now);
    sqldb_bind_int64(st, 2, now + lease_ms);
    sqldb_bind_text(st, 3, name);
    sqldb_bind_int64(st, 4, token);
    if ((rc = store_step_done(s, st, err, "renew lease")))
        return rc;
    if (s->name_lost && strcmp(name, s->host_name) == 0)
        return sf_err_set(err, SF_ESTALE,
                          "host '%s': another process took the name while the connection was "
                          "away: its lease is lost",
                          name);
    return sqldb_changes(s->db) == 1 ? SF_OK : lease_lost(s, name, token, now, err);
}

/* How many hosts other than name hold a lease running at now_ms, into *n. */
int
store_host_peers(struct store *s, const char *name, int64_t now_ms, int *n, struct sf_err *err)
{
    now_ms += store_clock_ms(s) - clock_wall_ms(); /* onto the database's clock */
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st,
                           "SELECT count(*) FROM hosts WHERE name != ?1 AND reaped_ms = 0"
                           " AND lease_until_ms > ?2",
                           err);
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, name);
    sqldb_bind_int64(st, 2, now_ms);
    rc = sqldb_step(st);
    *n = rc == SQLDB_ROW ? (int)sqldb_column_int64(st, 0) : 0;
    sqldb_finalize(st);
    return rc == SQLDB_ROW ? SF_OK : store_db_fail(s, err, "count the live hosts");
}

int
store_ping(struct store *s, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st, "SELECT 1", err);
    if (rc)
        return rc;
    rc = sqldb_step(st);
    sqldb_finalize(st);
    return rc == SQLDB_ROW ? SF_OK : store_db_fail(s, err, "ping");
}

/* ---- who tells the operator ---- */

int
store_host_teller(struct store *s, int64_t job_id, const char *printer, int64_t now_ms, char *host,
                  size_t cap, struct sf_err *err)
{
    now_ms += store_clock_ms(s) - clock_wall_ms(); /* onto the database's clock */
    struct sqldb_stmt *st;
    /* the job's live holder; else the live owner of the event's printer, or of the job's;
       else the live host first by name (the same for every host: one database's order) */
    int rc = store_prepare(
        s, &st,
        "SELECT coalesce((SELECT j.claimed_by FROM jobs j JOIN hosts h ON h.name = j.claimed_by"
        " WHERE j.id = ?1 AND h.reaped_ms = 0 AND h.lease_until_ms > ?3),"
        " (SELECT o.host FROM host_printers o JOIN hosts h ON h.name = o.host"
        " WHERE o.printer = coalesce(nullif(?2, ''), (SELECT printer FROM jobs WHERE id = ?1))"
        " AND h.reaped_ms = 0 AND h.lease_until_ms > ?3),"
        " (SELECT min(name) FROM hosts WHERE reaped_ms = 0 AND lease_until_ms > ?3), '')",
        err);
    host[0] = '\0';
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, job_id);
    sqldb_bind_text(st, 2, printer ? printer : "");
    sqldb_bind_int64(st, 3, now_ms);
    rc = sqldb_step(st);
    if (rc == SQLDB_ROW)
        store_copy_text(host, cap, st, 0);
    sqldb_finalize(st);
    return rc == SQLDB_ROW ? SF_OK : store_db_fail(s, err, "who tells of an event");
}

/* ---- printers ---- */

/*
 * Printer p's owner, if a host other than name that was not reaped: SF_EAGAIN, its name into
 * other (cap bytes; "" when p is free).
 *
 * Why unreaped rather than "its lease runs": a printer has one owner at a time.  After an
 * outage of the database longer than the lease every lease ran out though no host died; a
 * host that took the printers of an owner whose lease had only run out would schedule on them
 * beside that owner, which renews and carries on (it calls own() again only for printers it
 * found foreign).  A reap is final (the reaped process joins again as a new one, and own()s
 * then), and it comes only after the reap's grace (farm_host.c may_reap): so a printer moves
 * only from a reaped or absent owner.
 */
static int
printer_free(struct store *s, const char *name, const char *p, char *other, size_t cap,
             struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st,
                           "SELECT o.host FROM host_printers o JOIN hosts h ON h.name = o.host"
                           " WHERE o.printer = ?1 AND o.host != ?2 AND h.reaped_ms = 0",
                           err);
    other[0] = '\0';
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, p);
    sqldb_bind_text(st, 2, name);
    rc = sqldb_step(st);
    if (rc == SQLDB_ROW)
        store_copy_text(other, cap, st, 0);
    sqldb_finalize(st);
    if (rc == SQLDB_ROW)
        return sf_err_set(err, SF_EAGAIN,
                          "printer '%s' belongs to live host '%s', not '%s': a printer is in one "
                          "host's config",
                          p, other, name);
    return rc == SQLDB_DONE ? SF_OK : store_db_fail(s, err, "printer owner");
}

/* Own printer p, unless an unreaped host other than name owns it (printer_free): SF_EAGAIN,
   that host's name into other (cap bytes). */
static int
own_one(struct store *s, const char *name, const char *p, int64_t now_ms, char *other, size_t cap,
        struct sf_err *err)
{
    other[0] = '\0';
    if (!p || !p[0] || strlen(p) >= 64)
        return sf_err_set(err, SF_EINVAL, "printer: '%.80s' is empty or longer than 63 bytes",
                          p ? p : "");
    int rc = printer_free(s, name, p, other, cap, err);
    struct sqldb_stmt *st;
    /* the owner's reap again in the upsert: two hosts that both found the printer free
       above would otherwise both take it (PostgreSQL: the second waits for the first's row,
       then finds it unreaped) */
    if (rc || (rc = store_prepare(s, &st,
                                  "INSERT INTO host_printers(printer, host, since_ms)"
                                  " VALUES(?1, ?2, ?3) ON CONFLICT(printer) DO UPDATE SET"
                                  " host = excluded.host, since_ms = excluded.since_ms"
                                  " WHERE host_printers.host = excluded.host OR NOT EXISTS"
                                  " (SELECT 1 FROM hosts h WHERE h.name = host_printers.host"
                                  " AND h.reaped_ms = 0)",
                                  err)))
        return rc;
    sqldb_bind_text(st, 1, p);
    sqldb_bind_text(st, 2, name);
    sqldb_bind_int64(st, 3, now_ms);
    if ((rc = store_step_done(s, st, err, "own printer")))
        return rc;
    if (sqldb_changes(s->db) == 1)
        return SF_OK;
    rc = printer_free(s, name, p, other, cap, err); /* the message naming the owner */
    if (rc == SF_OK)
        snprintf(other, cap, "(unknown)");
    return rc ? rc : sf_err_set(err, SF_EAGAIN, "printer '%s' was taken by a live host", p);
}

/* store_host_own in the caller's transaction. */
static int
own_tx(struct store *s, const char *name, int64_t token, const char *const *printers, size_t n,
       struct store_host_owned *out, struct sf_err *err)
{
    int64_t now = store_clock_ms(s);
    struct sqldb_stmt *st;
    int rc = store_host_hold(s, name, token, now, err);
    if (rc || (rc = store_prepare(s, &st, "DELETE FROM host_printers WHERE host = ?1", err)))
        return rc;
    sqldb_bind_text(st, 1, name);
    if ((rc = store_step_done(s, st, err, "disown printers")))
        return rc;
    size_t n_other = 0;
    char other[STORE_HOST_NAME_MAX];
    for (size_t i = 0; i < n; i++) {
        rc = own_one(s, name, printers[i], now, other, sizeof(other), err);
        /* another live host's: left to it, and said so, when the caller asked per printer */
        if (rc == SF_EAGAIN && out && other[0]) {
            out[i].owned = false;
            snprintf(out[i].other, sizeof(out[i].other), "%s", other);
            n_other++;
            continue;
        }
        if (rc)
            return rc;
        if (out) {
            out[i].owned = true;
            out[i].other[0] = '\0';
        }
    }
    char detail[128];
    snprintf(detail, sizeof(detail), "host '%s' owns %zu printer%s", name, n - n_other,
             n - n_other == 1 ? "" : "s");
    if (n_other)
        snprintf(detail + strlen(detail), sizeof(detail) - strlen(detail),
                 " (%zu of its config live hosts own)", n_other);
    return store_log_event(s, 0, NULL, "host-printers", detail, err);
}

int
store_host_own(struct store *s, const char *name, int64_t token, const char *const *printers,
               size_t n, struct store_host_owned *out, struct sf_err *err)
{
    int rc = store_begin(s, err);
    return rc ? rc : store_end_tx(s, own_tx(s, name, token, printers, n, out, err), err);
}

/* ---- reaping ---- */

/* Host name lost its lease (last beat at heartbeat_ms): move its work on, in the caller's
   transaction. */
static int
reap_host(struct store *s, const char *name, int64_t now_ms, int64_t heartbeat_ms,
          struct store_recovery *moved, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int64_t *ids = NULL;
    size_t n = 0;
    struct store_recovery r = { 0, 0 };
    int rc = store_prepare(
        s, &st,
        "SELECT id FROM jobs WHERE (claimed_by = ?1 AND state IN ('preparing','printing','paused'))"
        " OR (claimed_by = '' AND state IN ('printing','paused')"
        " AND printer IN (SELECT printer FROM host_printers WHERE host = ?1)) ORDER BY id",
        err);
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, name);
    if ((rc = store_read_rows(s, st, sizeof(*ids), store_read_id, (void **)&ids, &n, "host's jobs",
                              err)))
        return rc;
    char reason[96];
    snprintf(reason, sizeof(reason), "host %s lost its lease", name);
    struct job_event_args a = { .reason = reason };
    for (size_t i = 0; i < n && rc == SF_OK; i++) {
        enum job_state to;
        if ((rc = store_job_event_in(s, ids[i], JOB_EV_CRASHED, &a, &to, err)) == SF_OK)
            *(to == JOB_INTERRUPTED ? &r.interrupted : &r.requeued) += 1;
        /* the reaped host's token for the job is stale from now on: a write it still sends
           (it may be alive behind a partition) is refused */
        if (rc == SF_OK &&
            (rc = store_prepare(s, &st, "UPDATE jobs SET fence = fence + 1 WHERE id = ?1", err)) ==
                SF_OK) {
            sqldb_bind_int64(st, 1, ids[i]);
            rc = store_step_done(s, st, err, "bump fencing token");
        }
    }
    free(ids);
    /* its claims on waiting jobs go, their tokens with them; an interrupted job stays its
       (its part is on its printer) */
    if (rc || (rc = store_prepare(s, &st,
                                  "UPDATE jobs SET claimed_by = '', fence = fence + 1"
                                  " WHERE claimed_by = ?1 AND state IN ('queued','preparing',"
                                  "'ready')",
                                  err)))
        return rc;
    sqldb_bind_text(st, 1, name);
    if ((rc = store_step_done(s, st, err, "release claims")))
        return rc;
    char detail[192];
    snprintf(detail, sizeof(detail),
             "host '%s' lost its lease (last heartbeat %.1f s ago): %d jobs back in the queue, "
             "%d interrupted",
             name, (double)(now_ms - heartbeat_ms) / 1000, r.requeued, r.interrupted);
    if ((rc = store_log_event(s, 0, NULL, "host-reaped", detail, err)))
        return rc;
    if (moved) {
        moved->requeued += r.requeued;
        moved->interrupted += r.interrupted;
    }
    return SF_OK;
}

/* A host the reap takes: its name and last beat. */
struct reaped {
    char name[STORE_HOST_NAME_MAX];
    int64_t heartbeat_ms;
};

static void
read_reaped(struct sqldb_stmt *st, void *row)
{
    struct reaped *r = row;
    store_copy_text(r->name, sizeof(r->name), st, 0);
    r->heartbeat_ms = sqldb_column_int64(st, 1);
}

int
store_host_reap(struct store *s, int64_t now_ms, struct store_recovery *moved, struct sf_err *err)
{
    now_ms += store_clock_ms(s) - clock_wall_ms(); /* onto the database's clock */
    if (moved)
        *moved = (struct store_recovery){ 0, 0 };
    struct sqldb_stmt *st;
    struct reaped *rows = NULL;
    size_t n = 0;
    int rc = store_begin(s, err);
    if (rc)
        return rc;
    /* marking them first takes their rows: a claim of theirs in flight finishes before, or
       finds them reaped (host_hold) */
    if ((rc = store_prepare(s, &st,
                            "UPDATE hosts SET reaped_ms = ?1 WHERE reaped_ms = 0"
                            " AND lease_until_ms <= ?1 RETURNING name, heartbeat_ms",
                            err)))
        return store_end_tx(s, rc, err);
    sqldb_bind_int64(st, 1, now_ms);
    rc = store_read_rows(s, st, sizeof(*rows), read_reaped, (void **)&rows, &n, "reap hosts", err);
    for (size_t i = 0; i < n && rc == SF_OK; i++)
        rc = reap_host(s, rows[i].name, now_ms, rows[i].heartbeat_ms, moved, err);
    free(rows);
    if ((rc = store_end_tx(s, rc, err)) && moved)
        *moved = (struct store_recovery){ 0, 0 };
    return rc ? rc : (int)n;
}

int
store_host_leave(struct store *s, const char *name, int64_t token, struct store_recovery *moved,
                 struct sf_err *err)
{
    if (moved)
        *moved = (struct store_recovery){ 0, 0 };
    struct sqldb_stmt *st;
    struct reaped *rows = NULL;
    size_t n = 0;
    int64_t now = store_clock_ms(s);
    int rc = check_name(name, err);
    if (rc || (rc = store_begin(s, err)))
        return rc;
    /* this process's lease alone: the other hosts' are the reap's, after its grace */
    if ((rc = store_prepare(s, &st,
                            "UPDATE hosts SET reaped_ms = ?1, lease_until_ms = ?1 WHERE name = ?2"
                            " AND token = ?3 AND reaped_ms = 0 RETURNING name, heartbeat_ms",
                            err)))
        return store_end_tx(s, rc, err);
    sqldb_bind_int64(st, 1, now);
    sqldb_bind_text(st, 2, name);
    sqldb_bind_int64(st, 3, token);
    rc = store_read_rows(s, st, sizeof(*rows), read_reaped, (void **)&rows, &n, "leave", err);
    for (size_t i = 0; i < n && rc == SF_OK; i++)
        rc = reap_host(s, rows[i].name, now, rows[i].heartbeat_ms, moved, err);
    free(rows);
    if ((rc = store_end_tx(s, rc, err)) && moved)
        *moved = (struct store_recovery){ 0, 0 };
    return rc;
}

/* ---- listing ---- */

static void
read_host(struct sqldb_stmt *st, void *row)
{
    struct store_host_row *h = row;
    memset(h, 0, sizeof(*h));
    store_copy_text(h->name, sizeof(h->name), st, 0);
    h->token = sqldb_column_int64(st, 1);
    h->pid = sqldb_column_int64(st, 2);
    h->version = sqldb_column_int(st, 3);
    h->started_ms = sqldb_column_int64(st, 4);
    h->heartbeat_ms = sqldb_column_int64(st, 5);
    h->lease_until_ms = sqldb_column_int64(st, 6);
    h->live = sqldb_column_int(st, 7) != 0;
    h->n_claimed = sqldb_column_int(st, 8);
}

/* Each printer's name into its owner's row (rows by name, as the printers come). */
static int
add_printers(struct store *s, struct store_host_row *rows, size_t n, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st, "SELECT host, printer FROM host_printers ORDER BY host, printer",
                           err);
    if (rc)
        return rc;
    size_t i = 0;
    while ((rc = sqldb_step(st)) == SQLDB_ROW) {
        const char *host = sqldb_column_text(st, 0), *p = sqldb_column_text(st, 1);
        while (i < n && strcmp(rows[i].name, host) < 0)
            i++;
        if (i == n || strcmp(rows[i].name, host) != 0)
            continue;
        struct store_host_row *h = &rows[i];
        size_t len = strlen(h->printers), cap = sizeof(h->printers);
        if (len + strlen(p) + 5 < cap)
            snprintf(h->printers + len, cap - len, "%s%s", len ? "," : "", p);
        else if (len + 4 < cap && strcmp(h->printers + (len > 3 ? len - 3 : 0), "...") != 0)
            snprintf(h->printers + len, cap - len, "...");
        h->n_printers++;
    }
    sqldb_finalize(st);
    return rc == SQLDB_DONE ? SF_OK : store_db_fail(s, err, "list host printers");
}

int
store_host_list(struct store *s, int64_t now_ms, struct store_host_row **rows, size_t *n,
                struct sf_err *err)
{
    now_ms += store_clock_ms(s) - clock_wall_ms(); /* onto the database's clock */
    struct sqldb_stmt *st;
    /* ORDER BY in the bytes' order on both engines, as add_printers merges by strcmp */
    int rc = store_select(
        s, &st,
        "SELECT h.name, h.token, h.pid, h.version, h.started_ms, h.heartbeat_ms,"
        " h.lease_until_ms, CASE WHEN h.reaped_ms = 0 AND h.lease_until_ms > ?1 THEN 1 ELSE 0 END,"
        " (SELECT count(*) FROM jobs j WHERE j.claimed_by = h.name"
        "  AND j.state IN ('preparing','ready','printing','paused','interrupted'))"
        " FROM hosts h ORDER BY h.name",
        (void **)rows, n, err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, now_ms);
    if ((rc = store_read_rows(s, st, sizeof(**rows), read_host, (void **)rows, n, "list hosts",
                              err)) ||
        (rc = add_printers(s, *rows, *n, err))) {
        free(*rows);
        *rows = NULL;
        *n = 0;
    }
    return rc;
}

int
store_host_listen(struct store *s, struct sf_err *err)
{
    int rc = sqldb_listen(s->db, STORE_HOST_CHANNEL);
    return rc ? store_db_fail(s, err, "listen") : SF_OK;
}

int
store_host_wake(struct store *s, struct sf_err *err)
{
    int rc = sqldb_notify(s->db, STORE_HOST_CHANNEL, NULL);
    return rc ? store_db_fail(s, err, "notify") : SF_OK;
}

int
store_host_notify_fd(struct store *s)
{
    return sqldb_notify_fd(s->db);
}

static void
count_note(void *arg, const char *channel, const char *payload)
{
    (void)arg, (void)channel, (void)payload;
}

int
store_host_drain(struct store *s)
{
    return sqldb_notifications(s->db, count_note, NULL);
}

int64_t
store_host_reconnects(struct store *s)
{
    return sqldb_reconnects(s->db);
}

int64_t
store_clock_ms(const struct store *s)
{
    return sqldb_clock_ms(s->db);
}

int64_t
store_round_trips(const struct store *s)
{
    return sqldb_round_trips(s->db);
}

/* store_host_printer_set in the caller's transaction. */
static int
printer_set_tx(struct store *s, const char *host, int64_t token, const char *printer,
               enum printer_state state, struct sf_err *err)
{
    int64_t now = store_clock_ms(s);
    struct sqldb_stmt *st;
    int rc = store_host_hold(s, host, token, now, err);
    if (rc ||
        (rc = store_prepare(s, &st, "SELECT host FROM host_printers WHERE printer = ?1", err)))
        return rc;
    sqldb_bind_text(st, 1, printer);
    rc = sqldb_step(st);
    char owner[STORE_HOST_NAME_MAX] = "";
    if (rc == SQLDB_ROW)
        store_copy_text(owner, sizeof(owner), st, 0);
    sqldb_finalize(st);
    if (rc != SQLDB_ROW && rc != SQLDB_DONE)
        return store_db_fail(s, err, "printer owner");
    if (!owner[0])
        return sf_err_set(err, SF_ESTALE, "printer '%s' belongs to no host, not '%s': not written",
                          printer, host);
    if (strcmp(owner, host) != 0)
        return sf_err_set(err, SF_ESTALE,
                          "printer '%s' belongs to host '%s', not '%s': not written", printer,
                          owner, host);
    if ((rc = store_prepare(s, &st,
                            "INSERT INTO printers(name, state, updated_ms) VALUES(?1, ?2, ?3)"
                            " ON CONFLICT(name) DO UPDATE SET state = ?2, updated_ms = ?3",
                            err)))
        return rc;
    sqldb_bind_text(st, 1, printer);
    sqldb_bind_text(st, 2, printer_state_name(state));
    sqldb_bind_int64(st, 3, now);
    if ((rc = store_step_done(s, st, err, "set printer")))
        return rc;
    return store_log_event(s, 0, printer, "printer-state", printer_state_name(state), err);
}

int
store_host_printer_set(struct store *s, const char *host, int64_t token, const char *printer,
                       enum printer_state state, struct sf_err *err)
{
    int rc = store_begin(s, err);
    return rc ? rc : store_end_tx(s, printer_set_tx(s, host, token, printer, state, err), err);
}
