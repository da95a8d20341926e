/*
 * farm_int.h - internal to the farm module (farm.c, farm_gcheck.c,
 * farm_files.c, farm_prepend.c, farm_resume.c), not a contract for anyone else: nothing outside
 * src/farm/farm*.c includes it; farm.h is the module's contract.
 *
 * What the parts share: the farm itself (struct farm), finding a printer
 * by name, the printer as the scheduler sees it, the event streams' wake,
 * and the start of a job (farm_gcheck.c judges its file on the io thread
 * before the driver has it; farm.c's scheduling pass calls it).
 *
 * Thread: as farm.h (the loop thread).
 */
#ifndef SF_FARM_FARM_INT_H
#define SF_FARM_FARM_INT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "farm.h"

/* After a store failure that may pass (busy, unreachable): the next scheduling pass. */
#define FARM_RETRY_MS 2000
/* After a claim that met its job's row held (another host's claim of it, a reason's write):
   the next pass in FARM_BUSY_RETRY_MS plus as much again at most, at random. */
#define FARM_BUSY_RETRY_MS 100

struct prep;      /* farm.c: a prepare task */
struct noreslice; /* farm.c: a re-slice that failed */
struct startlook; /* farm_gcheck.c: a start whose G-code is looked up */
/* A job not prepared again before until_ms (clock_mono_ms): farm_files.c. */
struct farm_cool {
    int64_t job_id;
    int64_t until_ms;
};
struct farm_ask;   /* farm_ask.c: a claim or take of the scheduling pass on its way */
struct resume_ask; /* farm_resume.c: a resume whose hold is on its way */
struct farm_spare; /* farm_spare.c: the other hosts' printers this host may prepare for */
struct store_printer_prep;
/* A queued job that fits only other hosts' printers is prepared here once it waited this long
   since its last change (farm_spare.c says why), */
#define FARM_SPARE_WAIT_MS 1000
/* for their settings as read again when older than this. */
#define FARM_SPARE_READ_MS 2000

struct farm {
    struct loop *l;            /* the loop */
    struct store *s;           /* the job store: reads, and writes the farm acts on */
    struct storeq *q;          /* its queue on a thread of its own: writes nothing waits for */
    struct pool *pool;         /* prepare workers */
    struct pool *io;           /* one thread for resume reads and G-code checks: not queued
                                  behind slicing */
    struct pool *files;        /* one thread for starts' G-code lookups (a fetch from a shared
                                  store's database: seconds): not queued behind either */
    struct farm_hooks hooks;   /* drivers, prepare, notify */
    char profiles_dir[512];    /* slicing profiles (farmcfg profiles_dir) */
    struct printer **printers; /* n_printers, config order */
    size_t n_printers;
    double gram_s;         /* farmcfg gram_seconds and material_first: the search's */
    bool material_first;   /* policy for the parts prepared from now on */
    uint64_t kick;         /* pending run() timer, 0 if none */
    uint64_t progress;     /* progress timer */
    uint64_t retry;        /* after a passing store failure: timer for the next pass, 0 if none */
    struct prep *posted;   /* prepare tasks whose PREPARE is on its way to the store */
    bool reading;          /* a scheduling pass's read of the live jobs is on its way */
    bool reread;           /* kicked meanwhile: another pass once it is back */
    bool stopping;         /* farm_free: what drivers report while closing goes unheard */
    int preparing;         /* prepare tasks in flight */
    struct prep *reslices; /* re-slices in flight (their jobs stay ready), linked by next */
    struct noreslice *no;  /* re-slices that failed: not tried again until a reload */
    size_t n_no, cap_no;
    struct startlook *looking;    /* starts whose G-code is being looked up (farm_gcheck.c) */
    struct farm_cool *cool;       /* jobs whose files could not be had in passing: not prepared */
    size_t n_cool, cap_cool;      /* again before until_ms (farm.c cool) */
    struct farmcfg_printer *seed; /* farm.ini's printers as last given (farm_seed), n_seed */
    size_t n_seed;
    struct farm_host *host;     /* one of several hosts on a shared store (farm_host.h), or NULL */
    struct farm_remote *remote; /* actions on other hosts' printers (farm_remote.h), or NULL */
    struct farm_view *view;     /* the other hosts' printers, and ours for them (farm_view.h) */
    struct farm_ask *asks;      /* claims and takes on the store thread (farm_ask.c) */
    struct farm_spare *spare;   /* other hosts' printers to prepare for (farm_spare.c), or NULL */
    /* resumes whose hold is on the store thread (farm_resume.c), linked by next */
    struct resume_ask *resuming;
};

/* Write job id's DEFER or PREPARE_FAILED (its preparation ended without a G-code) through the
   store thread, posted again while the store fails with nothing applied, so the job never
   stays preparing (farm_prepend.c). */
void farm_prep_end(struct farm *f, int64_t id, enum job_event ev, const struct job_event_args *a);

/* Wake the event streams (the notify hook), if any. */
void farm_notify(struct farm *f);

/* The printer named name, or NULL (removed printers too, until freed). */
struct printer *farm_find(const struct farm *f, const char *name);
/* A printer for cfg; old (NULL: none) the one it replaces, whose bed it keeps. */
struct printer *farm_printer_new(struct farm *f, const struct farmcfg_printer *cfg,
                                 const struct printer *old);
/* Append a printer for cfg to f's list. */
int farm_add_printer(struct farm *f, const struct farmcfg_printer *cfg, struct sf_err *err);

/* The printer as the scheduler sees it; its strings live in p (farm_spare.c). */
void farm_printer_view(const struct printer *p, struct sched_printer *out);
/* A printer's config as the scheduler sees it (idle); its strings live in c. */
void farm_cfg_view(const struct farmcfg_printer *c, struct sched_printer *out);

/*
 * farm_spare.c, one of several hosts with other live hosts: queued job j (sj[i] of the n in
 * the pass), which fits none of this host's printers, is claimed to prepare here for another
 * live host's printer it fits once it waited FARM_SPARE_WAIT_MS (else a pass then); the
 * caller checked the pool has a free place.  The other hosts' printers are read on the
 * store thread when needed (the answer kicks the farm).
 */
void farm_spare_claim(struct farm *f, const struct sched_job *sj, size_t n, size_t i,
                      const struct job_row *j);
/* What preparing for printer c needs, to publish for the other hosts (store_host_publish). */
void farm_spare_publish(const struct farmcfg_printer *c, struct store_printer_prep *out);
/* Free f's spare state (after the store thread delivered what was in flight). */
void farm_spare_free(struct farm *f);

/*
 * Start job j (ready) on printer p (idle): its G-code is looked up (on a
 * shared store, fetched) on the io thread, then p takes it (committed in
 * the store), and the driver gets it once the file passed p's G-code
 * policy on the io thread too (farm_gcheck.c).  Failures are logged; the next
 * scheduling pass tries again when nothing was committed.
 */
void farm_start(struct farm *f, const struct job_row *j, struct printer *p);
/* Is a start's G-code lookup in flight for job job_id (0: any) or printer (NULL: any)?  The
   scheduling pass starts neither again meanwhile. */
bool farm_start_looking(const struct farm *f, int64_t job_id, const char *printer);
/*
 * farm_files.c, on a prepare worker: the paths of a preparation's part
 * (part_sha) and of the optimized part it reuses (reuse_sha, "" if none)
 * into req, and where its G-code (and the optimized part, when not reused)
 * go, beside the stored files; looked up (on a shared store, fetched) on a
 * reader of the worker's own opened on s.  store_file_path's errors, and
 * the reader's (SF_EIO, SF_EUNREACH); req's out_path and mesh_in are then
 * "".
 */
int farm_prep_files(const struct store *s, struct prepare_req *req, const char *part_sha,
                    const char *reuse_sha, bool reslice, struct sf_err *err);
/* Job id's files could not be had in passing: it is not prepared again for FARM_RETRY_MS (a
   pass at every commit would write PREPARE and DEFER again and again meanwhile). */
void farm_cool(struct farm *f, int64_t id);
/* Is job id cooling (farm_cool)?  Drops the entries that are over. */
bool farm_cooling(struct farm *f, int64_t id);
/* Kick the farm again in FARM_RETRY_MS (a passing store error). */
void farm_retry_later(struct farm *f);
/* A claim met its job's row held: the holder commits in milliseconds, so the next pass runs
   in FARM_BUSY_RETRY_MS and a random as much again (hosts woken by one NOTIFY all reach for
   the first queued job; each waiting FARM_RETRY_MS, ten hosts claimed a third as fast). */
void farm_retry_soon(struct farm *f);
/*
 * farm.c: prepare job j for printer c (a printer's config): a ready job again for its key
 * (reslice; one of several hosts: taken under fence), else a queued one
 * (one of several hosts: claimed under fence, farm_ask_claim).  hand_over: c is another
 * host's printer (farm_ask_spare): the PREPARED gives the claim up with it
 * (store_job_prepared_release).  False when the store failed in passing (tried again later).
 */
bool farm_prepare(struct farm *f, const struct job_row *j, const struct farmcfg_printer *c,
                  bool reslice, int64_t fence, bool hand_over);

/*
 * farm_ask.c, one of several hosts: the scheduling pass's claims and takes
 * on the store thread; their answers on the loop act.  farm_ask_claim:
 * claim queued job jobs[i] (of the pass's n, sj their view, sp the
 * printers' in f's order, why their reasons), or if another host has it
 * one of the next the pass would prepare for printer best as well, then
 * prepare it for printers[best] (counted in f->preparing from now).  farm_ask_take: take ready job
 * j, then start it on p (reslice: prepare it again for p; counted in f->preparing from now); a
 * single host starts (or prepares) at once.  farm_ask_mark, in a pass: the jobs with a claim or
 * take on its way as the store will have them (queued -> preparing, ready -> printing), and the
 * printers (sp, f's order) a job is being taken for, busy.
 */
void farm_ask_claim(struct farm *f, const struct job_row *jobs, const struct sched_job *sj,
                    size_t n, size_t i, const struct sched_printer *sp, size_t best,
                    char (*why)[SCHED_REASON_MAX]);
/* As farm_ask_claim, to prepare j for another host's printer c (copied): farm_spare.c. */
void farm_ask_spare(struct farm *f, const struct job_row *j, const struct farmcfg_printer *c);
void farm_ask_take(struct farm *f, const struct job_row *j, struct printer *p, bool reslice);
void farm_ask_mark(const struct farm *f, struct job_row *jobs, size_t n, struct sched_printer *sp);

/*
 * Printer c's config into the farm (c->name's printer is added if new):
 * the same link, or a busy printer, takes it in place (a busy one keeps
 * its link until a later apply); an idle one with a new link (driver,
 * enabled, an option not live) is replaced and reconnects.  SF_ENOMEM.
 */
int farm_apply(struct farm *f, const struct farmcfg_printer *c, struct sf_err *err);
/* Free the printers marked removed that hold no job. */
void farm_sweep(struct farm *f);
/* Does the link differ between configs a and b (what farm_apply reconnects for)?  why: what. */
bool farm_link_change(const struct farmcfg_printer *a, const struct farmcfg_printer *b, char *why,
                      size_t n);

/* farm_printers.c: keep farm.ini's n printers p as the seed (copied).  SF_ENOMEM. */
int farm_seed(struct farm *f, const struct farmcfg_printer *p, size_t n, struct sf_err *err);
/*
 * The printers in force (farm.h, "Run-time printers"): the seed with the
 * store's rows over it, then the rows' own, into *out (free() it).  A
 * stored row that no longer parses is logged and left out (the seed's
 * printer of that name stands).  SF_EIO from the store, SF_ENOMEM.
 */
int farm_merged(struct farm *f, struct farmcfg_printer **out, size_t *n, struct sf_err *err);

#endif
