/*
 * store_job.c - jobs in the store (store.h): adding them, reading them,
 * moving them through job.h's state machine with their copies' print
 * history, and progress, priority and reason updates.
 *
 * Each state change is one transaction that reads the job, lets job_next()
 * decide whether the event is legal, fills in what the event carries
 * (apply_event), opens or closes the copy's row in prints, writes the job
 * row and appends to the event log.
 *
 * Thread: the store's.
 */
#include "store.h"

#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "../base/clock.h"
#include "store_host.h"
#include "store_int.h"

/* ---- jobs ---- */

static void
read_job(struct sqldb_stmt *st, struct job_row *j)
{
    memset(j, 0, sizeof(*j));
    j->id = sqldb_column_int64(st, 0);
    store_copy_text(j->opts.name, sizeof(j->opts.name), st, 1);
    store_copy_text(j->file_sha, sizeof(j->file_sha), st, 2);
    store_copy_text(j->gcode_sha, sizeof(j->gcode_sha), st, 3);
    char state[16];
    store_copy_text(state, sizeof(state), st, 4);
    if (!job_state_parse(state, &j->state))
        j->state = JOB_FAILED; /* the CHECK constraint makes this unreachable */
    store_copy_text(j->opts.method, sizeof(j->opts.method), st, 5);
    j->opts.deviation_mm = sqldb_column_double(st, 6);
    j->opts.overhang_deg = sqldb_column_double(st, 7);
    j->opts.copies = j->counts.copies = sqldb_column_int(st, 8);
    j->counts.copies_done = sqldb_column_int(st, 9);
    j->counts.failures = sqldb_column_int(st, 10);
    j->opts.max_retries = j->counts.max_retries = sqldb_column_int(st, 11);
    store_copy_text(j->opts.material, sizeof(j->opts.material), st, 12);
    store_copy_text(j->opts.printer, sizeof(j->opts.printer), st, 13);
    store_copy_text(j->opts.group, sizeof(j->opts.group), st, 14);
    j->opts.priority = sqldb_column_int(st, 15);
    for (int i = 0; i < 3; i++)
        j->size_mm[i] = sqldb_column_double(st, 16 + i);
    store_copy_text(j->printer, sizeof(j->printer), st, 19);
    j->lines_acked = sqldb_column_int64(st, 20);
    store_copy_text(j->reason, sizeof(j->reason), st, 21);
    j->created_ms = sqldb_column_int64(st, 22);
    j->updated_ms = sqldb_column_int64(st, 23);
    j->nozzle_mm = sqldb_column_double(st, 24);
    j->gcode_lines = sqldb_column_int64(st, 25);
    store_copy_text(j->prep_key, sizeof(j->prep_key), st, 26);
    store_copy_text(j->mesh_sha, sizeof(j->mesh_sha), st, 27);
    j->mesh_angle_deg = sqldb_column_double(st, 28);
    j->filament_g = sqldb_column_double(st, 29);
    j->support_g = sqldb_column_double(st, 30);
    j->support_saved_g = sqldb_column_double(st, 31);
    j->prepare_ms = sqldb_column_int64(st, 32);
    j->slice_ms = sqldb_column_int64(st, 33);
    j->ready_ms = sqldb_column_int64(st, 34);
    j->dev_measured = !sqldb_column_null(st, 35);
    j->mndr = sqldb_column_double(st, 35);
    j->andr = sqldb_column_double(st, 36);
    j->shape_changed = sqldb_column_int(st, 37) != 0;
    j->est_known = !sqldb_column_null(st, 38);
    j->est_s = j->est_known ? sqldb_column_double(st, 38) : -1;
    j->queue_pos = sqldb_column_int64(st, 39);
}

void
store_read_job(struct sqldb_stmt *st, void *row)
{
    read_job(st, row);
}

/* Bind what every new job row takes from o at parameters first .. first + 7: copies,
   max_retries, material, printer, group, priority, created_ms and updated_ms (both now_ms). */
/* The G-code's time estimate at parameter i: NULL when not known (store.h). */
static void
bind_est(struct sqldb_stmt *st, int i, bool known, double est_s)
{
    if (known)
        sqldb_bind_double(st, i, est_s >= 0 ? est_s : -1);
    else
        sqldb_bind_null(st, i);
}

static void
bind_opts(struct sqldb_stmt *st, int first, const struct job_opts *o, int64_t now_ms)
{
    sqldb_bind_int64(st, first, o->copies);
    sqldb_bind_int64(st, first + 1, o->max_retries);
    sqldb_bind_text(st, first + 2, o->material);
    sqldb_bind_text(st, first + 3, o->printer);
    sqldb_bind_text(st, first + 4, o->group);
    sqldb_bind_int64(st, first + 5, o->priority);
    sqldb_bind_int64(st, first + 6, now_ms);
    sqldb_bind_int64(st, first + 7, now_ms);
}

/* 1 if sha is a SHA-256 in hex that names a stored file, 0 if it is not (NULL, malformed or
   not stored), or a negative status with err set when the store could not tell. */
static int
file_stored(struct store *s, const char *sha, struct sf_err *err)
{
    return sha && store_sha_valid(sha) ? store_file_known(s, sha, err) : 0;
}

/* Finish a job add begun by store_write_begin: run the INSERT ... RETURNING id st, log "job-add"
   with detail and commit, or roll back; the new job's id into *id (may be NULL), set before
   the COMMIT, so that it names the job when the COMMIT is in doubt. */
static int
insert_job(struct store *s, struct sqldb_stmt *st, const char *what, const char *detail,
           int64_t *id, struct sf_err *err)
{
    int rc = sqldb_step(st) == SQLDB_ROW ? SF_OK : store_db_fail(s, err, what);
    int64_t new_id = rc ? 0 : sqldb_column_int64(st, 0);
    sqldb_finalize(st);
    if (rc)
        goto end_tx;
    /* a new job goes last in the queue of its priority (schema 9) */
    if ((rc = store_prepare(
             s, &st,
             "UPDATE jobs SET queue_pos = (SELECT max(queue_pos) FROM jobs) + 1 WHERE id = ?",
             err)))
        goto end_tx;
    sqldb_bind_int64(st, 1, new_id);
    if ((rc = store_step_done(s, st, err, "queue place")) ||
        (rc = store_log_event(s, new_id, NULL, "job-add", detail, err)))
        goto end_tx;
    /* before the COMMIT: one in doubt (SF_EINDOUBT) that the caller reads back as committed
       has added this job, which it must not lose, nor add again */
    if (id)
        *id = new_id;
end_tx:
    return store_end_tx(s, rc, err);
}

int
store_job_add(struct store *s, const struct job_opts *o, const char *file_sha, int64_t *id,
              struct sf_err *err)
{
    int rc = job_opts_validate(o, err);
    if (rc)
        return rc;
    if ((rc = file_stored(s, file_sha, err)) <= 0)
        return rc ? rc
                  : sf_err_set(err, SF_ENOTFOUND, "store: part file '%.80s' is not stored",
                               file_sha ? file_sha : "");
    struct sqldb_stmt *st;
    if ((rc = store_write_begin(
             s, &st,
             "INSERT INTO jobs(name, file_sha, state, method, deviation_mm, overhang_deg,"
             " copies, max_retries, material, target_printer, target_group, priority,"
             " created_ms, updated_ms) VALUES(?,?,'queued',?,?,?,?,?,?,?,?,?,?,?) RETURNING id",
             err)))
        return rc;
    sqldb_bind_text(st, 1, o->name);
    sqldb_bind_text(st, 2, file_sha);
    sqldb_bind_text(st, 3, o->method);
    sqldb_bind_double(st, 4, o->deviation_mm);
    sqldb_bind_double(st, 5, o->overhang_deg);
    bind_opts(st, 6, o, clock_wall_ms());
    char detail[192];
    snprintf(detail, sizeof(detail), "queued '%s' x%d", o->name, o->copies);
    return insert_job(s, st, "add job", detail, id, err);
}

int
store_job_add_gcode(struct store *s, const struct job_opts *o, const char *sha,
                    const struct job_event_args *g, int64_t *id, struct sf_err *err)
{
    struct job_opts v = *o;
    snprintf(v.method, sizeof(v.method), "none"); /* validate the rest as any job's */
    int rc = job_opts_validate(&v, err);
    if (rc)
        return rc;
    if ((rc = file_stored(s, sha, err)) <= 0)
        return rc ? rc
                  : sf_err_set(err, SF_ENOTFOUND, "store: G-code file '%.80s' is not stored",
                               sha ? sha : "");
    if (!g->prep_key || !g->prep_key[0])
        return sf_err_set(err, SF_EINVAL, "store: G-code job '%s' has no key", o->name);
    struct sqldb_stmt *st;
    if ((rc = store_write_begin(
             s, &st,
             "INSERT INTO jobs(name, file_sha, gcode_sha, state, method, deviation_mm,"
             " overhang_deg, copies, max_retries, material, target_printer, target_group,"
             " priority, created_ms, updated_ms, nozzle_mm, gcode_lines, prep_key,"
             " filament_g, support_g, ready_ms, est_s)"
             " VALUES(?,?,?,'ready','gcode',0,0,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?) RETURNING id",
             err)))
        return rc;
    int64_t t = clock_wall_ms();
    sqldb_bind_text(st, 1, o->name);
    sqldb_bind_text(st, 2, sha);
    sqldb_bind_text(st, 3, sha);
    bind_opts(st, 4, o, t);
    sqldb_bind_double(st, 12, g->nozzle_mm);
    sqldb_bind_int64(st, 13, g->gcode_lines > 0 ? g->gcode_lines : 0);
    sqldb_bind_text(st, 14, g->prep_key);
    sqldb_bind_double(st, 15, g->filament_g);
    sqldb_bind_double(st, 16, g->support_g);
    sqldb_bind_int64(st, 17, t);
    bind_est(st, 18, g->est_known, g->est_s);
    char detail[192];
    snprintf(detail, sizeof(detail), "ready '%s' x%d (G-code as uploaded, for %s)", o->name,
             o->copies, g->prep_key);
    return insert_job(s, st, "add G-code job", detail, id, err);
}

int
store_job_get(struct store *s, int64_t id, struct job_row *out, struct sf_err *err)
{
    char sql[sizeof(STORE_JOB_COLS) + 48];
    snprintf(sql, sizeof(sql), "SELECT %s FROM jobs WHERE id = ?", STORE_JOB_COLS);
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st, sql, err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, id);
    rc = store_job_one(s, st, out, "get job", err);
    if (rc == SF_ENOTFOUND)
        return sf_err_set(err, SF_ENOTFOUND, "job %lld: no such job", (long long)id);
    return rc;
}

int
store_job_one(struct store *s, struct sqldb_stmt *st, struct job_row *out, const char *what,
              struct sf_err *err)
{
    int rc = sqldb_step(st);
    if (rc == SQLDB_ROW)
        read_job(st, out);
    sqldb_finalize(st);
    if (rc == SQLDB_ROW)
        return SF_OK;
    return rc == SQLDB_DONE ? SF_ENOTFOUND : store_db_fail(s, err, what);
}

int
store_job_list(struct store *s, struct job_row **rows, size_t *n, struct sf_err *err)
{
    char sql[sizeof(STORE_JOB_COLS) + 48];
    snprintf(sql, sizeof(sql), "SELECT %s FROM jobs ORDER BY id", STORE_JOB_COLS);
    struct sqldb_stmt *st;
    int rc = store_select(s, &st, sql, (void **)rows, n, err);
    if (rc)
        return rc;
    return store_read_rows(s, st, sizeof(**rows), store_read_job, (void **)rows, n, "list jobs",
                           err);
}

/* Close the job's open print with an outcome. */
static int
close_print(struct store *s, int64_t job_id, const char *outcome, int64_t lines_acked,
            double filament_mm, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st,
                           "UPDATE prints SET ended_ms = ?, outcome = ?, lines_acked = ?,"
                           " filament_mm = ? WHERE job_id = ? AND outcome = ''",
                           err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, clock_wall_ms());
    sqldb_bind_text(st, 2, outcome);
    sqldb_bind_int64(st, 3, lines_acked);
    sqldb_bind_double(st, 4, filament_mm);
    sqldb_bind_int64(st, 5, job_id);
    return store_step_done(s, st, err, "close print");
}

static int
open_print(struct store *s, const struct job_row *j, const char *printer, int64_t start_line,
           struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc =
        store_prepare(s, &st,
                      "INSERT INTO prints(job_id, copy, printer, material, start_line,"
                      " lines_acked, started_ms, wait_ms, gcode_sha) VALUES(?,?,?,?,?,?,?,?,?)",
                      err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, j->id);
    sqldb_bind_int64(st, 2, j->counts.copies_done + 1);
    sqldb_bind_text(st, 3, printer);
    sqldb_bind_text(st, 4, j->opts.material);
    sqldb_bind_int64(st, 5, start_line);
    sqldb_bind_int64(st, 6, start_line);
    int64_t t = clock_wall_ms();
    sqldb_bind_int64(st, 7, t);
    /* a resume of an interrupted print waited for the operator, not in the queue */
    sqldb_bind_int64(
        st, 8, j->state == JOB_READY && j->ready_ms > 0 && t > j->ready_ms ? t - j->ready_ms : 0);
    sqldb_bind_text(st, 9, j->gcode_sha);
    return store_step_done(s, st, err, "open print");
}

/* Fill in j (already read) for the move from j->state to `to` by ev. */
static int
apply_event(struct store *s, struct job_row *j, enum job_event ev, const struct job_event_args *a,
            enum job_state to, struct sf_err *err)
{
    enum job_state from = j->state;
    int rc = SF_OK;
    char printer[sizeof(j->printer)]; /* a copy: j->printer is overwritten below */
    snprintf(printer, sizeof(printer), "%s", a->printer && a->printer[0] ? a->printer : j->printer);
    switch (ev) {
    case JOB_EV_PREPARED:
        if ((rc = file_stored(s, a->gcode_sha, err)) <= 0)
            return rc ? rc
                      : sf_err_set(err, SF_EINVAL, "job %lld: prepared without stored G-code",
                                   (long long)j->id);
        rc = SF_OK;
        snprintf(j->gcode_sha, sizeof(j->gcode_sha), "%s", a->gcode_sha);
        for (int i = 0; i < 3; i++)
            j->size_mm[i] = a->size_mm[i];
        j->nozzle_mm = a->nozzle_mm;
        j->gcode_lines = a->gcode_lines > 0 ? a->gcode_lines : 0;
        snprintf(j->prep_key, sizeof(j->prep_key), "%s", a->prep_key ? a->prep_key : "");
        if (a->mesh_sha && a->mesh_sha[0]) {
            if ((rc = file_stored(s, a->mesh_sha, err)) <= 0)
                return rc ? rc
                          : sf_err_set(err, SF_EINVAL, "job %lld: optimized part is not stored",
                                       (long long)j->id);
            rc = SF_OK;
            snprintf(j->mesh_sha, sizeof(j->mesh_sha), "%s", a->mesh_sha);
            j->mesh_angle_deg = a->mesh_angle_deg;
        }
        j->filament_g = a->filament_g;
        j->support_g = a->support_g;
        j->support_saved_g = a->saved_g;
        j->est_known = a->est_known;
        j->est_s = a->est_known ? a->est_s : -1;
        j->prepare_ms = a->prepare_ms;
        j->slice_ms = a->slice_ms;
        if (a->dev_measured || (a->mesh_sha && a->mesh_sha[0])) {
            j->dev_measured = a->dev_measured; /* a fresh preparation: measured or not */
            j->shape_changed = a->dev_measured && a->shape_changed;
            j->mndr = a->dev_measured && a->mndr > 0 ? a->mndr : 0;
            j->andr = a->dev_measured && a->andr > 0 ? a->andr : 0;
        }
        j->reason[0] = '\0';
        break;
    case JOB_EV_START:
    case JOB_EV_RESUME:
        if (ev == JOB_EV_RESUME && from == JOB_PAUSED)
            break;
        if (!printer[0])
            return sf_err_set(err, SF_EINVAL, "job %lld: %s needs a printer", (long long)j->id,
                              job_event_name(ev));
        if (ev == JOB_EV_START)
            j->lines_acked = 0;
        else if (a->lines_acked > 0)
            j->lines_acked = a->lines_acked; /* the operator chose where to resume */
        rc = open_print(s, j, printer, j->lines_acked, err);
        snprintf(j->printer, sizeof(j->printer), "%s", printer);
        j->reason[0] = '\0';
        break;
    case JOB_EV_PAUSE:
        if (a->lines_acked > j->lines_acked)
            j->lines_acked = a->lines_acked;
        break;
    case JOB_EV_PRINT_DONE:
    case JOB_EV_PRINT_FAILED:
    case JOB_EV_CANCEL:
    case JOB_EV_CANCEL_COPY:
    case JOB_EV_REFUSED:
        if (a->lines_acked > j->lines_acked)
            j->lines_acked = a->lines_acked;
        if (job_state_on_printer(from))
            rc = close_print(s, j->id,
                             ev == JOB_EV_PRINT_DONE     ? "done"
                             : ev == JOB_EV_PRINT_FAILED ? "failed"
                             : ev == JOB_EV_REFUSED      ? "refused"
                                                         : "cancelled",
                             j->lines_acked, a->filament_mm, err);
        j->printer[0] = '\0';
        j->lines_acked = 0;
        snprintf(j->reason, sizeof(j->reason), "%s", a->reason ? a->reason : "");
        break;
    case JOB_EV_CRASHED:
        if (job_state_on_printer(from))
            rc = close_print(s, j->id, "interrupted", j->lines_acked, 0, err);
        snprintf(j->reason, sizeof(j->reason), "%s", a->reason ? a->reason : "");
        break;
    case JOB_EV_RESTART:
        j->printer[0] = '\0';
        j->lines_acked = 0;
        j->reason[0] = '\0';
        break;
    case JOB_EV_PREPARE_FAILED:
    case JOB_EV_DEFER:
        snprintf(j->reason, sizeof(j->reason), "%s", a->reason ? a->reason : "");
        break;
    case JOB_EV_PREPARE:
        break;
    }
    if (to == JOB_READY && from != JOB_READY)
        j->ready_ms = clock_wall_ms(); /* a print's queue wait starts here */
    j->state = to;
    return rc;
}

int
store_job_event(struct store *s, int64_t id, enum job_event ev, const struct job_event_args *a,
                enum job_state *to, struct sf_err *err)
{
    int rc = store_begin(s, err);
    if (rc)
        return rc;
    /* one of several hosts: a job a DEFER gives back to the queue is the others' to take
       too, so wake them (a NOTIFY, sent at the commit) */
    if ((rc = store_job_event_in(s, id, ev, a, to, err)) == SF_OK && ev == JOB_EV_DEFER &&
        s->host && sqldb_engine(s->db) == SQLDB_PG)
        rc = store_host_wake(s, err);
    return store_end_tx(s, rc, err);
}

/*
 * A host-mode store (store_open_host) sent ev for job id without a fencing token: refused
 * (SF_ESTALE) if ev is one only the job's holder sends (a print's or a preparation's
 * progress) and a host has claimed or attached the job (its token is past 0), as a
 * host's writes must carry the token its claim or attach gave it.  The operator's
 * events (cancel, restart) and the reap's (crashed) need none.
 */
static int
unfenced_event(struct store *s, int64_t id, enum job_event ev, struct sf_err *err)
{
    switch (ev) {
    case JOB_EV_PREPARED:
    case JOB_EV_PREPARE_FAILED:
    case JOB_EV_DEFER:
    case JOB_EV_START:
    case JOB_EV_PAUSE:
    case JOB_EV_RESUME:
    case JOB_EV_PRINT_DONE:
    case JOB_EV_PRINT_FAILED:
    case JOB_EV_REFUSED:
        break;
    default:
        return SF_OK;
    }
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st, "SELECT fence, claimed_by FROM jobs WHERE id = ?1", err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, id);
    rc = sqldb_step(st);
    int64_t fence = rc == SQLDB_ROW ? sqldb_column_int64(st, 0) : 0;
    char holder[64] = "";
    if (rc == SQLDB_ROW)
        store_copy_text(holder, sizeof(holder), st, 1);
    sqldb_finalize(st);
    if (rc != SQLDB_ROW && rc != SQLDB_DONE)
        return store_db_fail(s, err, "read fencing token");
    if (fence == 0)
        return SF_OK; /* nobody claimed it: no token to show (or no such job: said later) */
    return sf_err_set(err, SF_ESTALE,
                      "job %lld: %s without a fencing token, refused: host '%s' holds the job "
                      "(token %lld)",
                      (long long)id, job_event_name(ev), holder[0] ? holder : "none",
                      (long long)fence);
}

int
store_job_event_in(struct store *s, int64_t id, enum job_event ev, const struct job_event_args *a,
                   enum job_state *to, struct sf_err *err)
{
    static const struct job_event_args none;
    if (!a)
        a = &none;
    int rc;
    /* first, so the row is locked (PostgreSQL) before it is read: no claim slips between */
    if (a->fence > 0 && (rc = store_job_fence(s, id, a->fence, err)))
        return rc;
    if (a->fence == 0 && s->host && (rc = unfenced_event(s, id, ev, err)))
        return rc;
    struct job_row j;
    if ((rc = store_job_get(s, id, &j, err)))
        return rc;
    enum job_state from = j.state, next;
    struct job_counts c = j.counts;
    if (ev == JOB_EV_PRINT_FAILED && a->no_retry && c.failures < c.max_retries)
        c.failures = c.max_retries; /* no retry left: the job fails */
    if ((rc = job_next(from, ev, &c, &next, err))) {
        sf_err_prefix(err, "job %lld", (long long)id);
        return rc;
    }
    j.counts = c;
    if ((rc = apply_event(s, &j, ev, a, next, err)))
        return rc;
    struct sqldb_stmt *st;
    if ((rc = store_prepare(
             s, &st,
             "UPDATE jobs SET state = ?, copies_done = ?, failures = ?, gcode_sha = ?,"
             " size_x = ?, size_y = ?, size_z = ?, printer = ?, lines_acked = ?,"
             " reason = ?, updated_ms = ?, nozzle_mm = ?, gcode_lines = ?, prep_key = ?,"
             " mesh_sha = ?, mesh_angle_deg = ?, filament_g = ?, support_g = ?,"
             " support_saved_g = ?, prepare_ms = ?, slice_ms = ?, ready_ms = ?,"
             " mndr = ?, andr = ?, shape_changed = ?, est_s = ?,"
             " claimed_by = CASE WHEN ?28 = 1 THEN '' ELSE claimed_by END WHERE id = ?27",
             err)))
        return rc;
    sqldb_bind_text(st, 1, job_state_name(j.state));
    sqldb_bind_int64(st, 2, j.counts.copies_done);
    sqldb_bind_int64(st, 3, j.counts.failures);
    if (j.gcode_sha[0])
        sqldb_bind_text(st, 4, j.gcode_sha);
    else
        sqldb_bind_null(st, 4);
    for (int i = 0; i < 3; i++)
        sqldb_bind_double(st, 5 + i, j.size_mm[i]);
    sqldb_bind_text(st, 8, j.printer);
    sqldb_bind_int64(st, 9, j.lines_acked);
    sqldb_bind_text(st, 10, j.reason);
    sqldb_bind_int64(st, 11, clock_wall_ms());
    sqldb_bind_double(st, 12, j.nozzle_mm);
    sqldb_bind_int64(st, 13, j.gcode_lines);
    sqldb_bind_text(st, 14, j.prep_key);
    sqldb_bind_text(st, 15, j.mesh_sha);
    sqldb_bind_double(st, 16, j.mesh_angle_deg);
    sqldb_bind_double(st, 17, j.filament_g);
    sqldb_bind_double(st, 18, j.support_g);
    sqldb_bind_double(st, 19, j.support_saved_g);
    sqldb_bind_int64(st, 20, j.prepare_ms);
    sqldb_bind_int64(st, 21, j.slice_ms);
    sqldb_bind_int64(st, 22, j.ready_ms);
    if (j.dev_measured) {
        sqldb_bind_double(st, 23, j.mndr);
        sqldb_bind_double(st, 24, j.andr);
    } else {
        sqldb_bind_null(st, 23);
        sqldb_bind_null(st, 24);
    }
    sqldb_bind_int64(st, 25, j.shape_changed);
    bind_est(st, 26, j.est_known, j.est_s);
    sqldb_bind_int64(st, 27, id);
    /* the host that held the job gave it up: any host may take it (store_job_live_host) */
    sqldb_bind_int64(st, 28, job_event_releases_claim(ev));
    char kind[24], detail[192];
    const char *why = j.reason[0] ? j.reason : ev == JOB_EV_PREPARED && a->note ? a->note : "";
    snprintf(kind, sizeof(kind), "job-%s", job_event_name(ev));
    snprintf(detail, sizeof(detail), "%s -> %s%s%s", job_state_name(from), job_state_name(j.state),
             why[0] ? ": " : "", why);
    if ((rc = store_step_done(s, st, err, "update job")) ||
        (rc = store_log_event(s, id, j.printer, kind, detail, err)))
        return rc;
    if (to)
        *to = j.state;
    return SF_OK;
}

static int
update_job_field(struct store *s, int64_t id, const char *sql, int64_t ival, const char *tval,
                 struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st, sql, err);
    if (rc)
        return rc;
    if (tval)
        sqldb_bind_text(st, 1, tval);
    else
        sqldb_bind_int64(st, 1, ival);
    sqldb_bind_int64(st, 2, clock_wall_ms());
    sqldb_bind_int64(st, 3, id);
    rc = sqldb_step(st);
    sqldb_finalize(st);
    if (rc != SQLDB_DONE)
        return store_db_fail(s, err, "update job");
    if (sqldb_changes(s->db) == 0)
        return sf_err_set(err, SF_ENOTFOUND, "job %lld: no such job", (long long)id);
    return SF_OK;
}

/* Raise job id's lines_acked; SF_ENOTFOUND if it is not printing or paused, SF_ESTALE if
   fence (0: none) is not its token (checked first, locking the row on PostgreSQL). */
static int
save_progress(struct store *s, int64_t id, int64_t lines_acked, int64_t fence, struct sf_err *err)
{
    int rc = fence > 0 ? store_job_fence(s, id, fence, err) : SF_OK;
    if (rc)
        return rc;
    return update_job_field(s, id,
                            "UPDATE jobs SET lines_acked = CASE WHEN lines_acked > ?1 THEN"
                            " lines_acked ELSE ?1 END, updated_ms = ?2"
                            " WHERE id = ?3 AND state IN ('printing', 'paused')",
                            lines_acked, NULL, err);
}

int
store_job_progress(struct store *s, int64_t id, int64_t lines_acked, struct sf_err *err)
{
    int rc = save_progress(s, id, lines_acked, 0, err);
    if (rc == SF_ENOTFOUND)
        return sf_err_set(err, SF_EINVAL, "job %lld: not printing", (long long)id);
    return rc;
}

static int store_jobs_progress_tx(struct store *s, struct store_progress *p, size_t n,
                                  struct sf_err *err);

int
store_jobs_progress(struct store *s, struct store_progress *p, size_t n, struct sf_err *err)
{
    /* Progress commits do not wait for the disk (sqldb_set_durable: they
       survive a kill -9, and the next state change's flush carries them to
       disk); state changes stay durable. */
    sqldb_set_durable(s->db, false);
    int rc = store_jobs_progress_tx(s, p, n, err);
    sqldb_set_durable(s->db, true);
    return rc;
}

static int
store_jobs_progress_tx(struct store *s, struct store_progress *p, size_t n, struct sf_err *err)
{
    int rc = store_begin(s, err);
    if (rc)
        return rc;
    int saved = 0;
    for (size_t i = 0; i < n; i++) {
        /* a job another host holds now (a stale fence) is skipped as one that ended */
        rc = save_progress(s, p[i].job_id, p[i].lines_acked, p[i].fence, err);
        if (rc && rc != SF_ENOTFOUND && rc != SF_ESTALE) {
            store_rollback(s);
            return rc;
        }
        p[i].saved = rc == SF_OK;
        saved += p[i].saved;
    }
    if ((rc = store_commit(s, err))) {
        store_rollback(s);
        for (size_t i = 0; i < n; i++)
            p[i].saved = false;
        return rc;
    }
    return saved;
}

int
store_job_progress_fenced(struct store *s, int64_t id, int64_t lines_acked, int64_t fence,
                          struct sf_err *err)
{
    if (fence < 1)
        return sf_err_set(err, SF_EINVAL, "job %lld: fencing token %lld is not one a host holds",
                          (long long)id, (long long)fence);
    sqldb_set_durable(s->db, false);
    int rc = store_begin(s, err);
    if (rc == SF_OK) {
        if ((rc = save_progress(s, id, lines_acked, fence, err)) == SF_OK)
            rc = store_commit(s, err);
        store_rollback(s); /* a no-op after the commit */
    }
    sqldb_set_durable(s->db, true);
    return rc;
}

int
store_job_set_priority(struct store *s, int64_t id, int priority, struct sf_err *err)
{
    if (priority < -JOB_PRIORITY_MAX || priority > JOB_PRIORITY_MAX)
        return sf_err_set(err, SF_EINVAL, "priority: %d is not in -%d..%d", priority,
                          JOB_PRIORITY_MAX, JOB_PRIORITY_MAX);
    int rc = store_begin(s, err);
    if (rc)
        return rc;
    char detail[64];
    snprintf(detail, sizeof(detail), "priority %d", priority);
    if ((rc = update_job_field(s, id, "UPDATE jobs SET priority = ?, updated_ms = ? WHERE id = ?",
                               priority, NULL, err)) == SF_OK)
        rc = store_log_event(s, id, NULL, "job-priority", detail, err);
    return store_end_tx(s, rc, err);
}

/* A job's place in the scheduler's order. */
struct qplace {
    int64_t id;
    int priority;
    int64_t pos;
};

/* Job me->id's place and state (16 bytes) from the store; SF_ENOTFOUND naming it. */
static int
queue_self(struct store *s, struct qplace *me, char *state, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st, "SELECT state, priority, queue_pos FROM jobs WHERE id = ?", err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, me->id);
    rc = sqldb_step(st);
    if (rc == SQLDB_ROW) {
        store_copy_text(state, 16, st, 0);
        me->priority = sqldb_column_int(st, 1);
        me->pos = sqldb_column_int64(st, 2);
    }
    sqldb_finalize(st);
    if (rc == SQLDB_DONE)
        return sf_err_set(err, SF_ENOTFOUND, "job %lld: no such job", (long long)me->id);
    return rc == SQLDB_ROW ? SF_OK : store_db_fail(s, err, "job's place");
}

/* The waiting job just before (by < 0) or after me in queue order, into *nb;
   SF_ENOTFOUND (err not set) if me is first (last). */
static int
queue_neighbour(struct store *s, const struct qplace *me, int by, struct qplace *nb,
                struct sf_err *err)
{
    static const char *const sql[2] = {
        "SELECT id, priority, queue_pos FROM jobs WHERE state IN ('queued','preparing','ready')"
        " AND (priority > ?1 OR (priority = ?1 AND (queue_pos < ?2 OR (queue_pos = ?2 AND id < "
        "?3))))"
        " ORDER BY priority, queue_pos DESC, id DESC LIMIT 1",
        "SELECT id, priority, queue_pos FROM jobs WHERE state IN ('queued','preparing','ready')"
        " AND (priority < ?1 OR (priority = ?1 AND (queue_pos > ?2 OR (queue_pos = ?2 AND id > "
        "?3))))"
        " ORDER BY priority DESC, queue_pos, id LIMIT 1",
    };
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st, sql[by > 0], err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, me->priority);
    sqldb_bind_int64(st, 2, me->pos);
    sqldb_bind_int64(st, 3, me->id);
    rc = sqldb_step(st);
    if (rc == SQLDB_ROW)
        *nb = (struct qplace){ sqldb_column_int64(st, 0), sqldb_column_int(st, 1),
                               sqldb_column_int64(st, 2) };
    sqldb_finalize(st);
    if (rc == SQLDB_DONE)
        return SF_ENOTFOUND;
    return rc == SQLDB_ROW ? SF_OK : store_db_fail(s, err, "queue neighbour");
}

/* Put job j at (priority, pos), in the caller's transaction. */
static int
queue_place(struct store *s, const struct qplace *j, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(
        s, &st, "UPDATE jobs SET priority = ?, queue_pos = ?, updated_ms = ? WHERE id = ?", err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, j->priority);
    sqldb_bind_int64(st, 2, j->pos);
    sqldb_bind_int64(st, 3, clock_wall_ms());
    sqldb_bind_int64(st, 4, j->id);
    return store_step_done(s, st, err, "move job");
}

/* One more than the largest queue_pos (by > 0: one less than the smallest), into *pos. */
static int
queue_end(struct store *s, int by, int64_t *pos, struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_prepare(s, &st,
                           by > 0 ? "SELECT min(queue_pos) - 1 FROM jobs"
                                  : "SELECT max(queue_pos) + 1 FROM jobs",
                           err);
    if (rc)
        return rc;
    rc = sqldb_step(st);
    if (rc == SQLDB_ROW)
        *pos = sqldb_column_int64(st, 0);
    sqldb_finalize(st);
    return rc == SQLDB_ROW ? SF_OK : store_db_fail(s, err, "queue end");
}

/* Trade places with the neighbour nb (store_job_move).  Within a priority the
   two swap queue_pos; across a boundary me takes nb's priority and place, and
   nb moves to its group's end on me's side (it was that group's last waiting
   job when me moves up, its first when me moves down), so no other job of
   either priority changes place. */
static int
queue_swap(struct store *s, struct qplace me, struct qplace nb, int by, struct sf_err *err)
{
    struct qplace a = { me.id, nb.priority, nb.pos };
    struct qplace b = { nb.id, nb.priority, me.pos };
    int rc = me.priority == nb.priority ? SF_OK : queue_end(s, by, &b.pos, err);
    if (rc == SF_OK)
        rc = queue_place(s, &a, err);
    return rc ? rc : queue_place(s, &b, err);
}

int
store_job_move(struct store *s, int64_t id, int by, struct sf_err *err)
{
    if (by != -1 && by != 1)
        return sf_err_set(err, SF_EINVAL, "by: %d is not -1 (up) or 1 (down)", by);
    struct qplace me = { id, 0, 0 }, nb = { 0, 0, 0 };
    char state[16];
    int rc = store_begin(s, err);
    if (rc)
        return rc;
    if ((rc = queue_self(s, &me, state, err)))
        goto end_tx;
    if (strcmp(state, "queued") != 0 && strcmp(state, "preparing") != 0 &&
        strcmp(state, "ready") != 0) {
        rc = sf_err_set(err, SF_EAGAIN,
                        "job %lld is %s: only a waiting job (queued, preparing, ready) moves in "
                        "the queue",
                        (long long)id, state);
        goto end_tx;
    }
    if ((rc = queue_neighbour(s, &me, by, &nb, err)) == SF_ENOTFOUND)
        rc = sf_err_set(err, SF_EAGAIN, "job %lld is already %s of the waiting jobs", (long long)id,
                        by < 0 ? "first" : "last");
    if (rc)
        goto end_tx;
    char detail[96];
    snprintf(detail, sizeof(detail), "moved %s job %lld, priority %d", by < 0 ? "above" : "below",
             (long long)nb.id, nb.priority);
    if ((rc = queue_swap(s, me, nb, by, err)) == SF_OK)
        rc = store_log_event(s, id, NULL, "job-move", detail, err);
end_tx:
    return store_end_tx(s, rc, err);
}

int
store_job_set_reason(struct store *s, int64_t id, const char *reason, struct sf_err *err)
{
    /* A reason longer than a job row holds (the scheduler's list of
       printers) would be cut mid-word when read: cut it here at a word,
       saying so with "...". */
    char cut[sizeof(((struct job_row *)0)->reason)];
    size_t len = strlen(reason);
    if (len >= sizeof(cut)) {
        size_t end = sizeof(cut) - 4;
        while (end > 0 && reason[end] != ' ')
            end--;
        while (end > 0 && (reason[end - 1] == ' ' || reason[end - 1] == ';' ||
                           reason[end - 1] == ':' || reason[end - 1] == ','))
            end--;
        if (end == 0) /* one long word: cut it */
            end = sizeof(cut) - 4;
        snprintf(cut, sizeof(cut), "%.*s...", (int)end, reason);
        reason = cut;
    }
    /* Only while the job waits: the scheduler's write goes through the store thread, so it
       may land after the job was cancelled or started, and must not replace that reason. */
    int rc = update_job_field(s, id,
                              "UPDATE jobs SET reason = ?1, updated_ms = ?2"
                              " WHERE id = ?3 AND reason != ?1"
                              " AND state IN ('queued', 'preparing', 'ready')",
                              0, reason, err);
    return rc == SF_ENOTFOUND ? SF_OK : rc; /* unchanged, gone or no longer waiting */
}

/* ---- history, events, checks ---- */

static void
read_print(struct sqldb_stmt *st, void *row)
{
    struct print_row *p = row;
    p->id = sqldb_column_int64(st, 0);
    p->job_id = sqldb_column_int64(st, 1);
    p->copy = sqldb_column_int(st, 2);
    store_copy_text(p->printer, sizeof(p->printer), st, 3);
    store_copy_text(p->material, sizeof(p->material), st, 4);
    p->start_line = sqldb_column_int64(st, 5);
    p->lines_acked = sqldb_column_int64(st, 6);
    p->filament_mm = sqldb_column_double(st, 7);
    p->started_ms = sqldb_column_int64(st, 8);
    p->ended_ms = sqldb_column_int64(st, 9);
    store_copy_text(p->outcome, sizeof(p->outcome), st, 10);
    p->gcode_sha[0] = '\0'; /* read_print_gcode's column 11: store_beds has another there */
}

/* read_print and column 11, the print's G-code (store_beds shares columns 0..10 alone). */
static void
read_print_gcode(struct sqldb_stmt *st, void *row)
{
    struct print_row *p = row;
    read_print(st, p);
    store_copy_text(p->gcode_sha, sizeof(p->gcode_sha), st, 11);
}

int
store_prints(struct store *s, int64_t job_id, struct print_row **rows, size_t *n,
             struct sf_err *err)
{
    struct sqldb_stmt *st;
    int rc = store_select(s, &st,
                          "SELECT id, job_id, copy, printer, material, start_line, lines_acked,"
                          " filament_mm, started_ms, ended_ms, outcome, gcode_sha FROM prints"
                          " WHERE job_id = ? ORDER BY id",
                          (void **)rows, n, err);
    if (rc)
        return rc;
    sqldb_bind_int64(st, 1, job_id);
    return store_read_rows(s, st, sizeof(**rows), read_print_gcode, (void **)rows, n, "list prints",
                           err);
}

static void
read_bed(struct sqldb_stmt *st, void *row)
{
    struct store_bed *b = row;
    read_print(st, &b->last); /* columns 0..10; all NULL (id 0) when it printed nothing */
    store_copy_text(b->printer, sizeof(b->printer), st, 11);
    b->bed_full = sqldb_column_int(st, 12) != 0;
    b->interrupted_job = sqldb_column_int64(st, 13);
    store_copy_text(b->job_name, sizeof(b->job_name), st, 14);
    b->copies = sqldb_column_int(st, 15);
    b->gcode_lines = sqldb_column_int64(st, 16);
}

int
store_beds(struct store *s, struct store_bed **rows, size_t *n, struct sf_err *err)
{
    /* One statement for the whole farm (GET /api/printers runs it on the
       loop).  A printer's newest print is read only while a part is on
       its bed or it is in error or awaiting clear (what the dashboard
       shows it for), through prints_printer_id (max(id) is one step):
       the printer's own prints, not a scan of every print down to its
       last one (a printer that never printed read the whole table).  Its
       interrupted job through jobs_state.  INDEXED BY is SQLite's
       (PostgreSQL's planner takes the index by itself). */
    char sql[1024];
    snprintf(sql, sizeof(sql),
             "SELECT p.id, p.job_id, p.copy, p.printer, p.material, p.start_line, p.lines_acked,"
             " p.filament_mm, p.started_ms, p.ended_ms, p.outcome, pr.name, pr.bed_full,"
             " (SELECT id FROM jobs WHERE state = 'interrupted' AND printer = pr.name"
             "  ORDER BY updated_ms DESC, id DESC LIMIT 1),"
             " j.name, j.copies, j.gcode_lines FROM printers pr"
             " LEFT JOIN prints p ON (pr.bed_full != 0 OR pr.state IN ('error', 'awaiting-clear'))"
             " AND p.id = (SELECT max(id) FROM prints%s WHERE printer = pr.name)"
             " LEFT JOIN jobs j ON j.id = p.job_id ORDER BY pr.name",
             sqldb_engine(s->db) == SQLDB_SQLITE ? " INDEXED BY prints_printer_id" : "");
    struct sqldb_stmt *st;
    int rc = store_select(s, &st, sql, (void **)rows, n, err);
    if (rc)
        return rc;
    return store_read_rows(s, st, sizeof(**rows), read_bed, (void **)rows, n, "list beds", err);
}
