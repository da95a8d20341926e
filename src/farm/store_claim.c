/*
 * store_claim.c - jobs among several hosts (store_host.h): a host claims a
 * queued job to prepare (one statement, FOR UPDATE SKIP LOCKED on
 * PostgreSQL: never two hosts), takes a ready one for its printer, reads
 * the live jobs that are its own or nobody's, attaches a printing job it
 * finds on a printer, and every claim, take and attach bumps the job's
 * fencing token (store_job_fence checks a writer's).  The hosts' leases
 * are store_host.c's.
 *
 * Thread: any, one store handle per thread (store.h).
 */
#include "store.h"
#include "store_host.h"
#include "store_int.h"

#include <stdio.h>
#include <string.h>

#include "../base/clock.h"

/* ---- claims and fencing ---- */

/* methods ("orient,slim") as ",orient,slim," into out, each checked as a job's method. */
static int
method_list(const char *methods, char *out, size_t cap, struct sf_err *err)
{
    out[0] = '\0';
    if (!methods || !methods[0])
        return SF_OK;
    if (strlen(methods) + 3 > cap)
        return sf_err_set(err, SF_EINVAL, "methods: '%.80s' is too long", methods);
    snprintf(out, cap, ",%s,", methods);
    for (const char *p = out + 1; *p;) {
        size_t len = strcspn(p, ",");
        struct job_opts o;
        job_opts_init(&o);
        snprintf(o.name, sizeof(o.name), "x");
        snprintf(o.method, sizeof(o.method), "%.*s", (int)len, p);
        if (len == 0 || len >= sizeof(o.method) || job_opts_validate(&o, err)) {
            sf_err_set(err, SF_EINVAL,
                       "methods: '%.*s' is not one of none, orient, slim, surface (in '%s')",
                       (int)len, p, methods);
            return SF_EINVAL;
        }
        p += len + (p[len] == ',');
    }
    return SF_OK;
}

/* The claim, in the caller's transaction: the job into *out and its fence, SF_ENOTFOUND. */
static int
claim_next(struct store *s, const char *host, const char *list, int64_t id, int64_t now_ms,
           struct job_row *out, int64_t *fence, struct sf_err *err)
{
    enum job_state to;
    struct job_counts c = { 1, 0, 0, 0 };
    int rc = job_next(JOB_QUEUED, JOB_EV_PREPARE, &c, &to, err);
    if (rc)
        return rc;
    /* the queued state as a literal, so both engines may read the claim order's partial index;
       SQLite is told to (INDEXED BY): without statistics it took jobs_state and sorted every
       queued job at each claim.  On PostgreSQL the next job skips a row another transaction
       holds (claimers never wait on each other); one chosen job (id) does not: a row held is
       another host's claim on its way or any other write to the job (a waiting reason another
       host's pass writes, which wakes nobody when it commits), and the job may still be
       queued after it, so the claim is busy (NOWAIT: SF_EBUSY, try again), not gone */
    const char *lock = !store_is_pg(s) ? ""
                       : id > 0        ? " FOR UPDATE NOWAIT"
                                       : " FOR UPDATE SKIP LOCKED";
    char sql[sizeof(STORE_JOB_COLS) + 512];
    snprintf(sql, sizeof(sql),
             "UPDATE jobs SET state = ?1, claimed_by = ?2, fence = fence + 1, updated_ms = ?3"
             " WHERE id = (SELECT id FROM jobs%s WHERE state = '%s'"
             " AND (?4 = '' OR instr(?4, ',' || method || ',') > 0) AND (?5 = 0 OR id = ?5)"
             " ORDER BY priority DESC, queue_pos, id LIMIT 1%s) AND state = '%s'"
             " RETURNING %s, fence",
             store_is_pg(s) ? "" : " INDEXED BY jobs_claim_order", job_state_name(JOB_QUEUED), lock,
             job_state_name(JOB_QUEUED), STORE_JOB_COLS);
    struct sqldb_stmt *st;
    if ((rc = store_prepare(s, &st, sql, err)))
        return rc;
    sqldb_bind_text(st, 1, job_state_name(to));
    sqldb_bind_text(st, 2, host);
    sqldb_bind_int64(st, 3, now_ms);
    sqldb_bind_text(st, 4, list);
    sqldb_bind_int64(st, 5, id);
    rc = sqldb_step(st);
    if (rc == SQLDB_ROW) {
        store_read_job(st, out);
        *fence = sqldb_column_int64(st, 40);
    }
    sqldb_finalize(st);
    if (rc != SQLDB_ROW && rc != SQLDB_DONE && id > 0 && sqldb_errcode(s->db) == SF_EBUSY)
        return sf_err_set(err, SF_EBUSY,
                          "store: job %lld is held by another transaction (another host's claim "
                          "on its way, or a write to the job): %s",
                          (long long)id, sqldb_errmsg(s->db));
    if (rc != SQLDB_ROW)
        return rc == SQLDB_DONE ? SF_ENOTFOUND : store_db_fail(s, err, "claim job");
    char detail[192];
    snprintf(detail, sizeof(detail), "%s -> %s: claimed by host '%s'", job_state_name(JOB_QUEUED),
             job_state_name(to), host);
    return store_log_event(s, out->id, NULL, "job-prepare", detail, err);
}

int
store_job_claim(struct store *s, const char *host, int64_t token, const char *methods,
                struct job_row *out, int64_t *fence, struct sf_err *err)
{
    char list[128];
    int64_t f = 0, now = store_clock_ms(s);
    int rc = method_list(methods, list, sizeof(list), err);
    if (rc || (rc = store_begin(s, err)))
        return rc;
    if ((rc = store_host_hold(s, host, token, now, err)) == SF_OK)
        rc = claim_next(s, host, list, 0, now, out, &f, err);
    if ((rc = store_end_tx(s, rc, err)))
        return rc;
    if (fence)
        *fence = f;
    return SF_OK;
}

int
store_job_claim_id(struct store *s, const char *host, int64_t token, int64_t id,
                   struct job_row *out, int64_t *fence, struct sf_err *err)
{
    int64_t f = 0, now = store_clock_ms(s);
    if (id <= 0)
        return sf_err_set(err, SF_EINVAL, "claim: job id %lld", (long long)id);
    int rc = store_begin(s, err);
    if (rc)
        return rc;
    if ((rc = store_host_hold(s, host, token, now, err)) == SF_OK)
        rc = claim_next(s, host, "", id, now, out, &f, err);
    if ((rc = store_end_tx(s, rc, err)))
        return rc;
    if (fence)
        *fence = f;
    return SF_OK;
}

/* The first of ids[0..n) (their order) still queued, into *id (0 if none); lock: only one
   whose row no other transaction holds, locked until the caller's transaction ends
   (PostgreSQL: SKIP LOCKED), else as committed writes left it. */
static int
pick_first(struct store *s, const int64_t *ids, size_t n, bool lock, int64_t *id,
           struct sf_err *err)
{
    char sql[1024];
    int len = snprintf(sql, sizeof(sql), "SELECT id FROM jobs WHERE state = '%s' AND id IN (",
                       job_state_name(JOB_QUEUED));
    for (int k = 1; k <= STORE_CLAIM_IDS_MAX; k++)
        len += snprintf(sql + len, sizeof(sql) - (size_t)len, "%s?%d", k > 1 ? "," : "", k);
    len += snprintf(sql + len, sizeof(sql) - (size_t)len, ") ORDER BY CASE id");
    for (int k = 1; k <= STORE_CLAIM_IDS_MAX; k++)
        len += snprintf(sql + len, sizeof(sql) - (size_t)len, " WHEN ?%d THEN %d", k, k);
    snprintf(sql + len, sizeof(sql) - (size_t)len, " END LIMIT 1%s",
             lock && store_is_pg(s) ? " FOR UPDATE SKIP LOCKED" : "");
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st, sql, err);
    if (rc)
        return rc;
    for (size_t k = 0; k < STORE_CLAIM_IDS_MAX; k++) /* the rest: the last again */
        sqldb_bind_int64(st, (int)k + 1, ids[k < n ? k : n - 1]);
    rc = sqldb_step(st);
    *id = rc == SQLDB_ROW ? sqldb_column_int64(st, 0) : 0;
    sqldb_finalize(st);
    return rc == SQLDB_ROW || rc == SQLDB_DONE ? SF_OK : store_db_fail(s, err, "pick a job");
}

/* None of ids[0..n) was free to claim: SF_EBUSY if one is still queued as far as committed
   writes say (its row held by a write that may leave it queued, or by a claim on its way:
   the flake SKIP LOCKED alone made, claim_next), else SF_ENOTFOUND (err not set). */
static int
none_free(struct store *s, const int64_t *ids, size_t n, struct sf_err *err)
{
    int64_t held;
    int rc = pick_first(s, ids, n, false, &held, err);
    if (rc || !held)
        return rc ? rc : SF_ENOTFOUND;
    return sf_err_set(err, SF_EBUSY,
                      "store: job %lld is held by another transaction (another host's claim on "
                      "its way, or a write to the job)%s",
                      (long long)held, n > 1 ? ", and no other job chosen with it is free" : "");
}

int
store_job_claim_first(struct store *s, const char *host, int64_t token, const int64_t *ids,
                      size_t n, int64_t *tried, struct job_row *out, int64_t *fence,
                      struct sf_err *err)
{
    int64_t f = 0, id = 0, now = store_clock_ms(s);
    *tried = 0;
    if (n == 0 || n > STORE_CLAIM_IDS_MAX)
        return sf_err_set(err, SF_EINVAL, "claim: %zu jobs to choose from (1 to %d)", n,
                          STORE_CLAIM_IDS_MAX);
    for (size_t k = 0; k < n; k++)
        if (ids[k] <= 0)
            return sf_err_set(err, SF_EINVAL, "claim: job id %lld", (long long)ids[k]);
    int rc = store_begin(s, err);
    if (rc)
        return rc;
    if ((rc = store_host_hold(s, host, token, now, err)) == SF_OK &&
        (rc = pick_first(s, ids, n, true, &id, err)) == SF_OK) {
        /* the row is this transaction's now: the claim's NOWAIT passes */
        *tried = id;
        rc = id ? claim_next(s, host, "", id, now, out, &f, err) : none_free(s, ids, n, err);
    }
    if ((rc = store_end_tx(s, rc, err)))
        return rc;
    if (fence)
        *fence = f;
    return SF_OK;
}

/* store_job_claim_settle in the caller's transaction. */
static int
settle_tx(struct store *s, const char *host, int64_t id, bool *released, struct sf_err *err)
{
    char sql[192];
    /* NOWAIT: a claim whose session the server has not ended yet still holds the row, and
       its outcome is not known until it ends (SF_EBUSY: ask again) */
    snprintf(sql, sizeof(sql),
             "SELECT fence FROM jobs WHERE id = ?1 AND state = '%s' AND claimed_by = ?2%s",
             job_state_name(JOB_PREPARING), store_is_pg(s) ? " FOR UPDATE NOWAIT" : "");
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st, sql, err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, id);
    sqldb_bind_text(st, 2, host);
    rc = sqldb_step(st);
    int64_t fence = rc == SQLDB_ROW ? sqldb_column_int64(st, 0) : 0;
    sqldb_finalize(st);
    if (rc == SQLDB_DONE)
        return SF_OK; /* the claim did not commit: the job is as it was */
    if (rc != SQLDB_ROW)
        return store_db_fail(s, err, "read back a claim");
    char reason[96];
    snprintf(reason, sizeof(reason), "host '%s' gave its claim back: its commit was in doubt",
             host);
    struct job_event_args a = { .reason = reason, .fence = fence };
    if ((rc = store_job_event_in(s, id, JOB_EV_DEFER, &a, NULL, err)) ||
        (rc = store_host_wake(s, err)))
        return rc;
    *released = true;
    return SF_OK;
}

int
store_job_claim_settle(struct store *s, const char *host, int64_t id, bool *released,
                       struct sf_err *err)
{
    *released = false;
    int rc = store_begin(s, err);
    if (rc)
        return rc;
    if ((rc = store_end_tx(s, settle_tx(s, host, id, released, err), err)))
        *released = false;
    return rc;
}

int
store_job_take(struct store *s, const char *host, int64_t token, int64_t id, int64_t *fence,
               struct sf_err *err)
{
    int64_t now = store_clock_ms(s), f = 0;
    struct sqldb_stmt *st;
    int rc = store_begin(s, err);
    if (rc)
        return rc;
    if ((rc = store_host_hold(s, host, token, now, err)) == SF_OK &&
        (rc = store_prepare(s, &st,
                            "UPDATE jobs SET claimed_by = ?1, fence = fence + 1, updated_ms = ?2"
                            " WHERE id = ?3 AND state = 'ready' AND claimed_by IN ('', ?1)"
                            " RETURNING fence",
                            err)) == SF_OK) {
        sqldb_bind_text(st, 1, host);
        sqldb_bind_int64(st, 2, now);
        sqldb_bind_int64(st, 3, id);
        rc = sqldb_step(st);
        if (rc == SQLDB_ROW)
            f = sqldb_column_int64(st, 0);
        sqldb_finalize(st);
        rc = rc == SQLDB_ROW    ? SF_OK
             : rc == SQLDB_DONE ? SF_ENOTFOUND
                                : store_db_fail(s, err, "take job");
    }
    if ((rc = store_end_tx(s, rc, err)))
        return rc;
    if (fence)
        *fence = f;
    return SF_OK;
}

/* store_job_give_back in the caller's transaction. */
static int
give_back_tx(struct store *s, const char *host, int64_t id, int64_t fence, const char *why,
             struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st,
                           "UPDATE jobs SET claimed_by = '', fence = fence + 1, updated_ms = ?1"
                           " WHERE id = ?2 AND claimed_by = ?3 AND fence = ?4 AND state = 'ready'",
                           err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, clock_wall_ms());
    sqldb_bind_int64(st, 2, id);
    sqldb_bind_text(st, 3, host);
    sqldb_bind_int64(st, 4, fence);
    if ((rc = store_step_done(s, st, err, "give a job back")))
        return rc;
    if (sqldb_changes(s->db) != 1)
        return sf_err_set(err, SF_ESTALE,
                          "job %lld: not given back: host '%s' no longer holds it ready under "
                          "fencing token %lld",
                          (long long)id, host, (long long)fence);
    char detail[192];
    snprintf(detail, sizeof(detail), "ready -> ready: host '%s' gave it back: %.120s", host,
             why ? why : "");
    if ((rc = store_log_event(s, id, NULL, "job-give-back", detail, err)))
        return rc;
    return store_is_pg(s) ? store_host_wake(s, err) : SF_OK; /* at the commit */
}

int
store_job_give_back(struct store *s, const char *host, int64_t id, int64_t fence, const char *why,
                    struct sf_err *err)
{
    int rc = store_begin(s, err);
    return rc ? rc : store_end_tx(s, give_back_tx(s, host, id, fence, why, err), err);
}

int
store_job_live_host(struct store *s, const char *host, struct job_row **rows, size_t *n,
                    struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_select(s, &st,
                          "SELECT " STORE_JOB_COLS " FROM jobs"
                          " WHERE state NOT IN ('done','failed','cancelled')"
                          " AND (claimed_by IN ('', ?1) OR printer IN"
                          " (SELECT printer FROM host_printers WHERE host = ?1)) ORDER BY id",
                          (void **)rows, n, err);
    if (rc)
        return rc;
    sqldb_bind_text(st, 1, host);
    return store_read_rows(s, st, sizeof(**rows), store_read_job, (void **)rows, n,
                           "list the host's live jobs", err);
}

/* ---- wake-ups ---- */

/* Why job id cannot be attached: SF_ENOTFOUND or SF_EAGAIN naming its state. */
static int
not_attachable(struct store *s, int64_t id, struct sf_err *err)
{
    struct job_row j;
    int rc = store_job_get(s, id, &j, err);
    if (rc)
        return rc;
    return sf_err_set(err, SF_EAGAIN,
                      "job %lld is %s: a host attaches a ready, printing, paused or interrupted "
                      "job",
                      (long long)id, job_state_name(j.state));
}

/* SF_EAGAIN if job id is on a printer a live host other than host owns: the owner wins (both
   configs may list a network printer; only its owner drives its prints while it lives). */
static int
owner_elsewhere(struct store *s, const char *host, int64_t id, int64_t now_ms, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st,
                           "SELECT o.host, j.printer FROM jobs j JOIN host_printers o"
                           " ON o.printer = j.printer JOIN hosts h ON h.name = o.host"
                           " WHERE j.id = ?1 AND o.host != ?2 AND h.reaped_ms = 0"
                           " AND h.lease_until_ms > ?3",
                           err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, id);
    sqldb_bind_text(st, 2, host);
    sqldb_bind_int64(st, 3, now_ms);
    char owner[STORE_HOST_NAME_MAX] = "", printer[64] = "";
    rc = sqldb_step(st);
    if (rc == SQLDB_ROW) {
        store_copy_text(owner, sizeof(owner), st, 0);
        store_copy_text(printer, sizeof(printer), st, 1);
    }
    sqldb_finalize(st);
    if (rc == SQLDB_ROW)
        return sf_err_set(err, SF_EAGAIN,
                          "job %lld is on printer '%s', which live host '%s' owns: not attached "
                          "by '%s'",
                          (long long)id, printer, owner, host);
    return rc == SQLDB_DONE ? SF_OK : store_db_fail(s, err, "printer owner");
}

/* Job id is not interrupted on printer: SF_ENOTFOUND (a refusal that does not pass). */
static int
not_reattachable(struct store *s, int64_t id, const char *printer, struct sf_err *err)
{
    struct job_row j;
    int rc = store_job_get(s, id, &j, err);
    if (rc)
        return rc;
    return sf_err_set(err, SF_ENOTFOUND,
                      "job %lld is %s on printer '%s': not re-attached to printer '%s'",
                      (long long)id, job_state_name(j.state), j.printer, printer);
}

/* store_job_attach (printer NULL) or store_job_reattach in the caller's transaction, the new
   token into *fence. */
static int
attach_tx(struct store *s, const char *host, int64_t token, int64_t id, const char *printer,
          int64_t *fence, struct sf_err *err)
{
    int64_t now = store_clock_ms(s);
    struct sqldb_stmt *st;
    int rc = store_host_hold(s, host, token, now, err);
    if (rc || (rc = owner_elsewhere(s, host, id, now, err)) ||
        (rc = store_prepare(s, &st,
                            printer ? "UPDATE jobs SET claimed_by = ?1, fence = fence + 1,"
                                      " updated_ms = ?2 WHERE id = ?3 AND state = 'interrupted'"
                                      " AND printer = ?4 RETURNING fence, state"
                                    : "UPDATE jobs SET claimed_by = ?1, fence = fence + 1,"
                                      " updated_ms = ?2 WHERE id = ?3 AND state IN ('ready',"
                                      "'printing','paused','interrupted') RETURNING fence, state",
                            err)))
        return rc;
    sqldb_bind_text(st, 1, host);
    sqldb_bind_int64(st, 2, now);
    sqldb_bind_int64(st, 3, id);
    if (printer)
        sqldb_bind_text(st, 4, printer);
    char state[16] = "";
    rc = sqldb_step(st);
    if (rc == SQLDB_ROW) {
        *fence = sqldb_column_int64(st, 0);
        store_copy_text(state, sizeof(state), st, 1);
    }
    sqldb_finalize(st);
    if (rc != SQLDB_ROW)
        return rc != SQLDB_DONE ? store_db_fail(s, err, "attach job")
               : printer        ? not_reattachable(s, id, printer, err)
                                : not_attachable(s, id, err);
    char detail[160];
    snprintf(detail, sizeof(detail), "host '%s' holds it (%s), fencing token %lld", host, state,
             (long long)*fence);
    return store_log_event(s, id, NULL, "job-attach", detail, err);
}

int
store_job_attach(struct store *s, const char *host, int64_t token, int64_t id, int64_t *fence,
                 struct sf_err *err)
{
    int64_t f = 0;
    int rc = store_begin(s, err);
    if (rc || (rc = store_end_tx(s, attach_tx(s, host, token, id, NULL, &f, err), err)))
        return rc;
    if (fence)
        *fence = f;
    return SF_OK;
}

int
store_job_reattach(struct store *s, const char *host, int64_t token, int64_t id,
                   const char *printer, int64_t *fence, struct sf_err *err)
{
    int64_t f = 0;
    int rc = store_begin(s, err);
    if (rc || (rc = store_end_tx(s, attach_tx(s, host, token, id, printer, &f, err), err)))
        return rc;
    if (fence)
        *fence = f;
    return SF_OK;
}

int
store_job_fence(struct store *s, int64_t id, int64_t fence, struct sf_err *err)
{
    struct sqldb_stmt *st;
    /* an UPDATE, not a SELECT: it locks the row on PostgreSQL until the caller commits */
    int rc =
        store_prepare(s, &st, "UPDATE jobs SET fence = fence WHERE id = ?1 AND fence = ?2", err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, id);
    sqldb_bind_int64(st, 2, fence);
    if ((rc = store_step_done(s, st, err, "check fencing token")))
        return rc;
    if (sqldb_changes(s->db) == 1)
        return SF_OK;
    if ((rc = store_prepare(s, &st, "SELECT fence, claimed_by FROM jobs WHERE id = ?1", err)))
        return rc;
    sqldb_bind_int64(st, 1, id);
    rc = sqldb_step(st);
    int64_t cur = rc == SQLDB_ROW ? sqldb_column_int64(st, 0) : 0;
    char holder[STORE_HOST_NAME_MAX] = "";
    if (rc == SQLDB_ROW)
        store_copy_text(holder, sizeof(holder), st, 1);
    sqldb_finalize(st);
    if (rc == SQLDB_DONE)
        return sf_err_set(err, SF_ENOTFOUND, "job %lld: no such job", (long long)id);
    if (rc != SQLDB_ROW)
        return store_db_fail(s, err, "read fencing token");
    return sf_err_set(err, SF_ESTALE,
                      "job %lld: fencing token %lld is stale: host '%s' holds the job now "
                      "(token %lld)",
                      (long long)id, (long long)fence, holder[0] ? holder : "none", (long long)cur);
}
