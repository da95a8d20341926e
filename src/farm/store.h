/*
 * store.h - the farm's durable memory: jobs, their files, printers, an
 * event log and print history, in one SQLite database (or a PostgreSQL
 * one: store_open_db) plus a content-addressed file directory under the
 * data dir.
 *
 *     DATA_DIR/slimfarm.db            SQLite, WAL, foreign keys, user_version
 *     DATA_DIR/files/ab/abcdef...     part and G-code files by SHA-256
 *
 * Every state change is one committed transaction that also appends to the
 * event log, so a daemon killed at any moment restarts with every job where
 * it was.  store_open() then runs crash recovery: jobs that were printing
 * (or paused) become interrupted, keeping their last acknowledged line, and
 * wait for an operator; jobs that were preparing go back to queued;
 * printers go offline until their drivers reconnect (a bed that holds a
 * part still does: store_printer_bed_get).
 *
 * Thread: one store per thread (the loop thread in the daemon); the
 * connection is not shared.  Workers hand results back to the loop, which
 * writes them; a worker that only reads may have a reader of its own
 * (store_open_reader).
 */
#ifndef SF_FARM_STORE_H
#define SF_FARM_STORE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../base/err.h"
#include "job.h"

struct store;

/* SHA-256 as lowercase hex plus NUL. */
#define STORE_SHA_HEX 65

/* What crash recovery did in store_open(). */
struct store_recovery {
    int interrupted; /* jobs printing/paused at the crash, now interrupted */
    int requeued;    /* jobs preparing at the crash, now queued */
};

/* A job as stored (plain data). */
struct job_row {
    int64_t id;                    /* > 0, assigned by store_job_add */
    struct job_opts opts;          /* as submitted; opts.priority may change later */
    enum job_state state;          /* current state */
    struct job_counts counts;      /* copies, copies_done, failures, max_retries */
    char file_sha[STORE_SHA_HEX];  /* the part file */
    char gcode_sha[STORE_SHA_HEX]; /* the sliced G-code; "" until prepared */
    double size_mm[3];             /* prepared part's bounding box x, y, z; 0 until prepared */
    double nozzle_mm;              /* nozzle the G-code was sliced for; 0 until prepared */
    int64_t gcode_lines;           /* its command lines (drv_job_scan); 0 if not known */
    char prep_key[192];            /* sched_key of the printers the G-code is for; "" if none */
    char mesh_sha[STORE_SHA_HEX];  /* the part as oriented and shaped, reused when it is
                                      prepared again for the same angle; "" if none */
    double mesh_angle_deg;         /* the overhang angle mesh_sha was optimized for */
    char printer[64];              /* printer of the current copy; "" when not on one */
    int64_t lines_acked;           /* last acknowledged line of the current copy */
    char reason[160];              /* why it waits or failed; "" if none */
    int64_t created_ms;            /* wall clock, ms since the epoch */
    int64_t updated_ms;            /* last change, same clock */
    double filament_g;             /* the G-code's filament estimate per copy; 0 if unknown */
    double support_g;              /* of which support; 0 if unknown */
    double support_saved_g;        /* support the optimization saved per copy, as estimated
                                      (prepare.h); 0 if none or not estimated */
    int64_t prepare_ms;            /* last preparation's wall time (orient .. slice); 0 if none */
    int64_t slice_ms;              /* of which slicing */
    int64_t ready_ms;              /* when it last became ready (wall clock); 0 if never */
    bool dev_measured;             /* mndr, andr are known: a slim or surface preparation */
    bool shape_changed;            /* the part prints reshaped (prepare.h) */
    double mndr, andr;             /* max / mean displacement of the part as it prints over
                                      its bounding-box diagonal (measure.h); 0 if not known */
    bool est_known;                /* est_s was kept with the G-code (schema 6); false for
                                      G-code stored before and jobs not prepared */
    double est_s;                  /* the G-code's print time estimate, s (gcjob_estimate_s);
                                      -1 when it states none */
    int64_t queue_pos;             /* its place among the waiting jobs of its priority, lower
                                      first (schema 9; store_job_move) */
};

/* Extra data some events carry (zero-initialise; unused fields ignored). */
struct job_event_args {
    const char *printer;   /* START: the printer it goes to (required) */
    const char *gcode_sha; /* PREPARED: stored G-code (required) */
    double size_mm[3];     /* PREPARED: part bounding box */
    double nozzle_mm;      /* PREPARED: nozzle it was sliced for */
    int64_t gcode_lines;   /* PREPARED: its command lines, as drv_job_scan counted them */
    const char *prep_key;  /* PREPARED: sched_key of the printers it is for; NULL or "":
                              none (the farm prepares it again before it prints) */
    const char *mesh_sha;  /* PREPARED: stored optimized part, NULL or "" to keep the one
                              recorded (a re-slice that reused it) */
    double mesh_angle_deg; /* PREPARED: the angle mesh_sha was optimized for */
    double filament_g;     /* PREPARED: the G-code's filament estimate, grams per copy */
    double support_g;      /* PREPARED: of which support */
    double saved_g;        /* PREPARED: support the optimization saved (prepare.h) */
    int64_t prepare_ms;    /* PREPARED: how long preparing took */
    int64_t slice_ms;      /* PREPARED: of which slicing */
    bool dev_measured;     /* PREPARED: mndr, andr are known (prepare.h); with neither this
                              nor mesh_sha (a re-slice of the saved part) the recorded
                              deviation stays */
    bool shape_changed;    /* PREPARED: the part prints reshaped */
    double mndr, andr;     /* PREPARED: its deviation (prepare.h) */
    bool est_known;        /* PREPARED: est_s is set (else the job has none kept) */
    double est_s;          /* PREPARED: the G-code's print time estimate (gcjob_estimate_s) */
    int64_t lines_acked;   /* PRINT_DONE/FAILED/PAUSE/CANCEL: where the printer got to;
                              RESUME of an interrupted job: line to resume from (0: stored) */
    double filament_mm;    /* PRINT_DONE/FAILED/CANCEL: filament used by this print */
    const char *reason;    /* PREPARE_FAILED/PRINT_FAILED/CANCEL: why, for operators */
    bool no_retry;         /* PRINT_FAILED: fail the job whatever retries it has left (an
                              operator's emergency stop stopped it) */
    const char *note;      /* PREPARED: NULL or what the preparation did other than the job
                              asked (a slimming that failed, prepare.h's shape_failed), for
                              operators: kept in the event's detail, not as the job's reason */
    int64_t fence;         /* any event, chiefly START and RESUME: the job's fencing token
                              its host holds (store_job_claim, store_job_attach); the event
                              is refused (SF_ESTALE) once another host took the job.  0:
                              not checked (one host) */
};

/* One row of print history. */
struct print_row {
    int64_t id;          /* > 0 */
    int64_t job_id;      /* the job */
    int copy;            /* 1-based copy number */
    char printer[64];    /* where it ran */
    char material[32];   /* material the job asked for ("" = printer's loaded one) */
    int64_t start_line;  /* first line streamed (> 0 when resumed after interrupt) */
    int64_t lines_acked; /* last acknowledged line */
    double filament_mm;  /* filament used */
    int64_t started_ms;  /* wall clock */
    int64_t ended_ms;    /* 0 while running */
    char outcome[16];    /* "" running, "done", "failed", "cancelled", "refused", "interrupted" */
    char gcode_sha[STORE_SHA_HEX]; /* the G-code it ran (schema 13; "" for an older print):
                                      the job's may change after (a reslice for another
                                      printer before its next copy) */
};

/* One entry of the event log. */
struct event_row {
    int64_t id;       /* increasing; SSE uses it as the event id */
    int64_t at_ms;    /* wall clock */
    int64_t job_id;   /* 0 if not about a job */
    char printer[64]; /* "" if not about a printer */
    char kind[24];    /* "job-start", "printer-state", ... */
    char detail[192]; /* human-readable */
};

/*
 * Open (creating if needed) the store in data_dir, lock it (an exclusive
 * flock on DATA_DIR/lock, held until store_close, so one process at a time
 * runs on a data dir), migrate the schema and run crash recovery (rec may
 * be NULL).  NULL with err set on failure (SF_EAGAIN when another process
 * holds the data dir, the message naming it and the holder's pid; SF_EIO
 * for the file system or SQLite, SF_EUNSUPP for a schema newer than this
 * program).  Free with store_close().
 */
struct store *store_open(const char *data_dir, struct store_recovery *rec, struct sf_err *err);
/*
 * As store_open, with the database at db: NULL or "" for SQLite in
 * DATA_DIR/slimfarm.db, or a PostgreSQL URL (postgresql://...; libpq's
 * form, e.g. postgresql:///farm?host=/run/postgresql).  The file directory
 * and the lock stay in data_dir either way.  One such store per PostgreSQL
 * database (SF_EAGAIN beside another, or beside hosts): crash recovery
 * takes every active job in the database for its own; several hosts share
 * one through store_open_host (store_host.h).  SF_EINVAL for a db that is
 * not such a URL.  Its PostgreSQL connection is the loop's: a lost one
 * reconnects without waiting (sqldb.h's SQLDB_NOWAIT), calls failing with
 * SF_EUNREACH meanwhile.
 */
struct store *store_open_db(const char *data_dir, const char *db, struct store_recovery *rec,
                            struct sf_err *err);
void store_close(struct store *s);

/*
 * Create or migrate the store at target, a PostgreSQL URL or a data dir
 * (its SQLite database, under the data dir's lock), and close it: no crash
 * recovery.  *from (may be NULL): the schema version found (0: new).
 * Errors as store_open's.
 */
int store_init(const char *target, int *from, struct sf_err *err);

/* The schema version this program writes. */
int store_schema_version(void);

/*
 * Files.  A writer streams a file into the store: it hashes as it writes a
 * temporary file, and commit moves it to its content address (a file that
 * is already there is kept) and records it.  store_file_put() does all
 * three for bytes in memory.  The writer is freed by commit or abort.
 *
 * On PostgreSQL the database holds every file's bytes, which all hosts
 * share, and the data dir is this host's cache of them: recording a file
 * sends it first, chunk by chunk, unless the database has it already
 * (SF_EINVAL over SF_STORE_BLOB_MAX, SF_EIO for the database or bytes that
 * no longer hash to sha, and then nothing is recorded), and
 * store_file_path fetches a file the cache lacks.  Both block on the
 * network for the file's size (about 1-2 s per 100 MiB, README).
 */
struct store_file;
struct store_file *store_file_begin(struct store *s, struct sf_err *err);
int store_file_write(struct store_file *f, const void *data, size_t len, struct sf_err *err);
int store_file_commit(struct store_file *f, char sha[STORE_SHA_HEX], struct sf_err *err);
void store_file_abort(struct store_file *f);
/* The path the writer writes to, to check the file before it is committed. */
const char *store_file_tmp_path(const struct store_file *f);
int store_file_put(struct store *s, const void *data, size_t len, char sha[STORE_SHA_HEX],
                   struct sf_err *err);
/*
 * A file made beside the store (path on the data dir's file system), taken
 * in two halves so the heavy one can leave the store's thread: adopt hashes
 * it, fsyncs it and renames it to its content address, touching only the
 * file system (any thread, while the store's thread works); record then
 * enters it in the database (the store's thread).  A crash between the two
 * leaves an unreferenced file, which the next adopt of the same bytes
 * replaces.  Adopting moves no bytes; streaming a 112 MB job through a
 * writer held the daemon's loop ~0.5 s (bench_jobstart).  On PostgreSQL
 * adopt also sends the file to the database, on a connection of its own
 * (errors as record's), so record finds it there and sends nothing.
 */
int store_file_adopt(const struct store *s, const char *path, char sha[STORE_SHA_HEX],
                     int64_t *size, struct sf_err *err);
int store_file_record(struct store *s, const char *sha, int64_t size, struct sf_err *err);
/*
 * Path of a stored file into path; SF_ENOTFOUND if unknown, SF_EINVAL if sha is not hex.
 * On PostgreSQL a file this host's cache lacks is fetched first, SHA-256 checked before it
 * is cached: SF_ENOTFOUND when the database lacks its bytes (only the host that stored it
 * has them), SF_EIO for a missing or damaged chunk or the file system; nothing is cached.
 */
int store_file_path(struct store *s, const char *sha, char *path, size_t cap, struct sf_err *err);
/* Whether sha is in the files table: 1 it is, 0 it is not, or the database's error (SF_EBUSY,
   SF_EUNREACH, SF_EIO: err says so), which is no answer: never taken for "not stored".  Tells
   store_file_path's two SF_ENOTFOUND apart: gone (0), or only not fetchable here (1). */
int store_file_known(struct store *s, const char *sha, struct sf_err *err);

/* Add a queued job for a stored part file; o is validated (SF_EINVAL).  *id is the new job's,
   set before the COMMIT: on SF_EINDOUBT it names the job a read-back may find committed. */
int store_job_add(struct store *s, const struct job_opts *o, const char *file_sha, int64_t *id,
                  struct sf_err *err);
/*
 * Add a job whose stored file sha is G-code to print as is (gcjob.h): it
 * is ready at once, its G-code is the file itself.  g gives what a
 * preparation would: prep_key (a gcjob_key, required), nozzle_mm,
 * gcode_lines (drv_job_scan's count), filament_g, support_g, est_known
 * and est_s.  o is
 * validated as store_job_add's (its method is stored as "gcode").
 */
int store_job_add_gcode(struct store *s, const struct job_opts *o, const char *sha,
                        const struct job_event_args *g, int64_t *id, struct sf_err *err);
/* SF_ENOTFOUND if no such job. */
int store_job_get(struct store *s, int64_t id, struct job_row *out, struct sf_err *err);
/*
 * Every job, oldest first, into *rows (free() it); *n its count.  It reads
 * all history: for a check or a tool, never for the daemon's loop (the
 * scheduler reads store_job_live, the API store_job_page).
 */
int store_job_list(struct store *s, struct job_row **rows, size_t *n, struct sf_err *err);
/*
 * The live jobs (every state but done, failed and cancelled), oldest first,
 * into *rows (free() it): what the scheduler works from.  Read through the
 * partial index jobs_live (schema 7), so its cost follows the live jobs, not
 * the history: 10,000 finished jobs add nothing.
 */
int store_job_live(struct store *s, struct job_row **rows, size_t *n, struct sf_err *err);
/*
 * The job interrupted on printer (its part may still be on the bed), the
 * most recently changed if there are several, into *out: SF_ENOTFOUND if
 * none.  An indexed lookup (jobs_state), not a scan.
 */
int store_job_interrupted(struct store *s, const char *printer, struct job_row *out,
                          struct sf_err *err);

#define STORE_PAGE_MAX 500 /* jobs in one page: a page's JSON stays well under a MiB */

/* Which jobs a page holds (zero-initialise: every job, oldest first). */
struct store_job_filter {
    unsigned states;     /* bit 1u << state for each state wanted; 0: every state */
    const char *printer; /* NULL or "": any; else jobs on that printer now or with a print
                            on it (prints_printer index) */
    int64_t since_ms;    /* > 0: updated_ms >= since_ms */
    int64_t until_ms;    /* > 0: updated_ms < until_ms */
    bool newest_first;   /* order by id descending */
    int64_t after_id;    /* > 0: only ids after it in that order (the cursor) */
    const char *name;    /* NULL or "": any; else jobs whose name holds it (ASCII case aside) */
};
/*
 * Up to limit (1 .. STORE_PAGE_MAX) jobs that pass f, in id order (f's
 * direction), into *rows (free() it).  *more (may be NULL) tells whether
 * more pass after the last one.  Ids are never reused and a new job gets a
 * higher id, so walking pages by after_id = the last id returns every job
 * exactly once while jobs are added (new ones at the end of an oldest-first
 * walk).  SF_EINVAL for a bad limit.
 */
int store_job_page(struct store *s, const struct store_job_filter *f, size_t limit,
                   struct job_row **rows, size_t *n, bool *more, struct sf_err *err);
/*
 * Apply ev to job id (job.h rules) in one transaction: the job row, print
 * history and the event log change together.  *to (may be NULL) receives
 * the new state.  SF_EINVAL if ev is not legal now (message from job_next),
 * SF_ENOTFOUND for no such job.
 */
int store_job_event(struct store *s, int64_t id, enum job_event ev, const struct job_event_args *a,
                    enum job_state *to, struct sf_err *err);
/* Record how far the printing copy got (called on a timer, not per line). */
int store_job_progress(struct store *s, int64_t id, int64_t lines_acked, struct sf_err *err);
/* One printing job's progress for store_jobs_progress(). */
struct store_progress {
    int64_t job_id;      /* in */
    int64_t lines_acked; /* in */
    bool saved;          /* out: written (false: the job is no longer printing or paused, or
                            its fence is stale) */
    int64_t fence;       /* in: the fencing token the writer holds the job by (store_host.h);
                            a stale one writes nothing.  0: not checked (one host) */
};
/*
 * Record the progress of many jobs in one transaction: with synchronous=FULL
 * every commit is an fsync, and the daemon's progress timer must not stall
 * the loop with one per printer.  Jobs no longer printing are skipped.
 * Returns how many were saved, or an error (then none was).
 */
int store_jobs_progress(struct store *s, struct store_progress *p, size_t n, struct sf_err *err);
/*
 * One job's progress from a host that holds it by fencing token fence
 * (store_host.h; > 0): SF_ESTALE, nothing written, when another host has
 * claimed, attached or reaped the job since; SF_ENOTFOUND when it is not
 * printing or paused.  Asynchronous commit, as store_jobs_progress.
 */
int store_job_progress_fenced(struct store *s, int64_t id, int64_t lines_acked, int64_t fence,
                              struct sf_err *err);
int store_job_set_priority(struct store *s, int64_t id, int priority, struct sf_err *err);
/*
 * Move waiting job id one place in the queue (by -1: up, +1: down): it
 * trades places with the waiting job next to it in the scheduler's order
 * (priority, higher first, then queue_pos, lower first).  Next to a job of
 * another priority, it takes that priority and lands just past it.  Logs
 * "job-move".  SF_EINVAL: by is not -1 or 1; SF_ENOTFOUND: no such job;
 * SF_EAGAIN: the job is not waiting (queued, preparing, ready) or is
 * already first (last).
 */
int store_job_move(struct store *s, int64_t id, int by, struct sf_err *err);
/* Set why a job waits (scheduler); writes only when it changed and the job still waits
   (queued, preparing, ready): a late write never replaces a cancelled or started job's reason. */
int store_job_set_reason(struct store *s, int64_t id, const char *reason, struct sf_err *err);

/* Record a printer's state (creating the row on first sight) and log the change. */
int store_printer_set(struct store *s, const char *name, enum printer_state st, struct sf_err *err);
/* SF_ENOTFOUND if never recorded. */
int store_printer_get(struct store *s, const char *name, enum printer_state *st,
                      struct sf_err *err);

/*
 * Whether printer name's bed holds a part (a finished or cancelled print
 * waiting for an operator): recorded before the job's own change, kept
 * through crash recovery and restarts, cleared by "cleared".  A printer
 * never recorded has a clear bed.
 */
int store_printer_bed_set(struct store *s, const char *name, bool full, struct sf_err *err);
int store_printer_bed_get(struct store *s, const char *name, bool *full, struct sf_err *err);

/*
 * Log what the farm did to printer name on its own (kind "printer-heat":
 * heaters turned off; "printer-command": a manual command and who sent
 * it; "printer-estop": an emergency stop), detail for operators.
 */
int store_printer_note(struct store *s, const char *name, const char *kind, const char *detail,
                       struct sf_err *err);

/* Print history of one job, oldest first, into *rows (free() it). */
int store_prints(struct store *s, int64_t job_id, struct print_row **rows, size_t *n,
                 struct sf_err *err);
/* Where a job's newest print ran. */
struct store_job_printer {
    int64_t job_id;
    char printer[64];
};
/*
 * For each of the n_ids jobs ids that has printed, where its newest print
 * ran, by job id, into *rows (free() it): one statement for a page of jobs,
 * reading those jobs' prints alone (an id range would read every job
 * between a sparse page's first and last).
 */
int store_last_printers(struct store *s, const int64_t *ids, size_t n_ids,
                        struct store_job_printer **rows, size_t *n, struct sf_err *err);

/* What a printer's bed holds, as the store knows it (plain data). */
struct store_bed {
    char printer[64];            /* the printer's name */
    bool bed_full;               /* a part waits to be taken off */
    int64_t interrupted_job;     /* a job left interrupted there (its part on the bed), 0 none */
    struct print_row last;       /* its newest print while a part is on its bed or it is
                                    in error or awaiting clear; last.id 0: none (or not read) */
    char job_name[JOB_NAME_MAX]; /* last's job: its name, */
    int copies;                  /* its copies */
    int64_t gcode_lines;         /* and its G-code's command lines */
};
/*
 * Every printer the store has seen, by name, with what its bed holds, into
 * *rows (free() it): one statement for the farm.
 */
int store_beds(struct store *s, struct store_bed **rows, size_t *n, struct sf_err *err);
/* Up to max events with id > after_id, oldest first, into *rows (free() it). */
int store_events(struct store *s, int64_t after_id, size_t max, struct event_row **rows, size_t *n,
                 struct sf_err *err);

/* Id of the newest event (0 if none): where a live event stream starts. */
int64_t store_event_last(struct store *s);

/*
 * Aggregates for the metrics, counted by SQLite rather than by loading
 * every row.  store_job_counts: jobs by state.  store_print_tally: ended
 * prints grouped by printer and outcome, in the order each pair first
 * occurred, with the sum of their jobs' estimates.
 */
int store_job_counts(struct store *s, uint64_t by_state[JOB_STATE_COUNT], struct sf_err *err);
struct print_tally {
    char printer[64];
    char outcome[16];  /* as print_row, never "" */
    uint64_t n;        /* prints */
    double filament_g; /* sum of their jobs' filament estimate per copy */
    double saved_g;    /* sum of their jobs' support saved per copy */
};
int store_print_tally(struct store *s, struct print_tally **rows, size_t *n, struct sf_err *err);

/*
 * Per printer, its prints over the last n_days UTC days up to now_ms
 * (store_stats.c): ended prints by outcome, seconds printing (a running
 * print up to now; a print across midnight split between its days), and
 * of those the seconds on each day, oldest first.  Printers with a print
 * in the window only, by name.  Reads every print that overlaps the
 * window: the API's reader thread, never the loop.
 */
#define STORE_STATS_DAYS_MAX 90 /* a quarter: a plot's width, not an archive */
struct store_printer_stats {
    char printer[64];
    uint64_t done, failed, cancelled, other; /* prints ended in the window, by outcome */
    double print_s;                          /* seconds printing within the window */
    double day_s[STORE_STATS_DAYS_MAX];      /* of which on each day (n_days used) */
};
int store_print_stats(struct store *s, int64_t now_ms, int n_days,
                      struct store_printer_stats **rows, size_t *n, struct sf_err *err);
/* Start (ms, UTC midnight) of the first day of an n_days window ending at now_ms. */
int64_t store_stats_since_ms(int64_t now_ms, int n_days);

/* A duration histogram over the store (seconds). */
enum store_hist {
    STORE_HIST_PREPARE, /* each job's last preparation (prepare_ms > 0) */
    STORE_HIST_SLICE,   /* its slicing part (slice_ms > 0) */
    STORE_HIST_PRINT,   /* prints done, start to end */
    STORE_HIST_WAIT,    /* ended prints' wait from ready to start (wait_ms > 0) */
};
#define STORE_HIST_BOUNDS_MAX 16
struct store_hist_out {
    uint64_t le[STORE_HIST_BOUNDS_MAX]; /* observations <= bounds[i] (cumulative) */
    uint64_t count;
    double sum_s;
};
/* Fill out for n (<= STORE_HIST_BOUNDS_MAX, else SF_EINVAL) ascending bounds in seconds. */
int store_hist(struct store *s, enum store_hist which, const double *bounds_s, size_t n,
               struct store_hist_out *out, struct sf_err *err);

/*
 * A second, read-only connection to s's database, for one other thread
 * (the API's reader): SQLite's WAL lets it read while s writes, so a
 * client's read never waits for the loop and the loop never waits for it.
 * It takes no lock, migrates nothing and recovers nothing (s did); only
 * the read functions may be called on it (a write fails: SQLITE_READONLY).
 * Use it on one thread at a time.  It may be opened on any thread while s
 * works (it reads only what s's open fixed: its data dir, target and host
 * flag), as the farm's workers do for a file lookup that may fetch a blob
 * (farm.c prep_files, farm_gcheck.c).  NULL with err set (SF_EIO,
 * SF_EUNREACH).  Free with store_close().
 */
struct store *store_open_reader(const struct store *s, struct sf_err *err);
/*
 * As store_open_reader, but the connection may write: for the store's own
 * thread (storeq.h), whose writes leave the loop.  Two writers on one
 * SQLite file take turns (its busy timeout); s keeps the data dir's lock,
 * the migrations and the recovery.  A host name joined on it
 * (store_host_join: a host's beat thread) is locked again after a
 * reconnect, as on s.
 */
struct store *store_open_writer(const struct store *s, struct sf_err *err);

/*
 * Database failures keep sqldb.h's codes in err: SF_EBUSY (busy) and
 * SF_EUNREACH (the connection is lost or not back yet), both with nothing
 * applied; SF_EINDOUBT (the connection was lost while the write committed:
 * it may have been applied); SF_EIO for what a retry cannot change.
 * store_commit_outcome: after a write on s failed with SF_EINDOUBT, whether
 * it committed: 1 yes, 0 no (run it again), < 0 still unknown (err set).
 */
int store_commit_outcome(struct store *s, struct sf_err *err);

/* A printer the API manages (store_printer_cfg.c; farm.h's run-time printers), plain data. */
#define STORE_PRINTER_CFG_MAX 4096 /* its section body: every option at its longest fits */
struct store_printer_cfg {
    int64_t id;                      /* order of the printers farm.ini does not name */
    char name[64];                   /* the printer */
    bool has_cfg;                    /* cfg is its section (else farm.ini's is in force) */
    char cfg[STORE_PRINTER_CFG_MAX]; /* "key: value" lines, as a [printer NAME] body */
    bool disabled;                   /* an operator disabled it, */
    char reason[128];                /* saying why */
    bool removed;                    /* farm.ini's printer of this name is removed */
};
/* Every row, by id, into *rows (free() it). */
int store_printer_cfg_list(struct store *s, struct store_printer_cfg **rows, size_t *n,
                           struct sf_err *err);
/* Write r (by r->name; r->id is ignored), logged as event "printer-config" with detail. */
int store_printer_cfg_put(struct store *s, const struct store_printer_cfg *r, const char *detail,
                          struct sf_err *err);
/* Drop printer name's row (none: SF_OK), logged as event "printer-config" with detail. */
int store_printer_cfg_drop(struct store *s, const char *name, const char *detail,
                           struct sf_err *err);

/*
 * Check the database: SQLite's integrity and foreign-key checks plus the
 * store's own invariants (states are known, a job on a printer names it and
 * has one open print, no open print for a job that is not on a printer).
 * SF_EBUG with the first violation.
 */
int store_check(struct store *s, struct sf_err *err);

#endif
