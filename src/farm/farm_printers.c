/*
 * farm_printers.c - printers managed at run time (farm.h "Run-time
 * printers"): what the store's printer_cfgs rows (store.h) mean over
 * farm.ini's printers, and the operator's add, edit, disable, enable and
 * remove.
 *
 * Design: farm.ini seeds, the store overrides.  The farm keeps farm.ini's
 * printers as last given (the seed); the printers in force are computed
 * from the seed and the rows whenever either changes (start, SIGHUP, an
 * API call), and each change goes through the one path a reload takes
 * (farm_apply, farm_sweep in farm.c), so a printer the API adds is built,
 * connected, replaced and freed exactly as a farm.ini printer.  Every
 * change is committed to the store first (the farm's rule), then applied.
 *
 * Thread: the loop thread.
 */
#include "farm.h"
#include "farm_int.h"

#include <stdio.h>
#include <string.h>

#include "../base/log.h"
#include "../base/mem.h"

int
farm_seed(struct farm *f, const struct farmcfg_printer *p, size_t n, struct sf_err *err)
{
    struct farmcfg_printer *copy = n ? mem_array(n, sizeof(*copy)) : NULL;
    if (n && !copy)
        return sf_err_set(err, SF_ENOMEM, "farm: out of memory");
    if (n)
        memcpy(copy, p, n * sizeof(*copy));
    free(f->seed);
    f->seed = copy;
    f->n_seed = n;
    return SF_OK;
}

static const struct farmcfg_printer *
seed_of(const struct farm *f, const char *name)
{
    for (size_t i = 0; i < f->n_seed; i++)
        if (strcmp(f->seed[i].name, name) == 0)
            return &f->seed[i];
    return NULL;
}

static const struct store_printer_cfg *
row_of(const struct store_printer_cfg *rows, size_t n, const char *name)
{
    for (size_t i = 0; i < n; i++)
        if (strcmp(rows[i].name, name) == 0)
            return &rows[i];
    return NULL;
}

/*
 * The printer row r and seed make (either may be NULL), into *out; false
 * when there is none (removed, or a row that does not parse and no seed).
 * disable: apply the row's disable.
 */
static bool
effective(const struct farmcfg_printer *seed, const struct store_printer_cfg *r, bool disable,
          struct farmcfg_printer *out)
{
    if (r && r->removed)
        return false;
    bool have = false;
    if (r && r->has_cfg) {
        struct sf_err e;
        have = farmcfg_printer_parse(out, r->name, r->cfg, strlen(r->cfg), &e) == SF_OK;
        if (!have)
            log_printer(LOG_ERROR, r->name, "stored config: %s; %s", e.msg,
                        seed ? "farm.ini's section is used" : "the printer is left out");
    }
    if (!have && seed) {
        *out = *seed;
        have = true;
    }
    if (have && disable && r && r->disabled) {
        out->enabled = false;
        snprintf(out->disabled, sizeof(out->disabled), "%s", r->reason[0] ? r->reason : "-");
    }
    return have;
}

int
farm_merged(struct farm *f, struct farmcfg_printer **out, size_t *n, struct sf_err *err)
{
    struct store_printer_cfg *rows;
    size_t n_rows;
    *out = NULL;
    *n = 0;
    int rc = store_printer_cfg_list(f->s, &rows, &n_rows, err);
    if (rc)
        return rc;
    size_t cap = f->n_seed + n_rows;
    struct farmcfg_printer *list = cap ? mem_array(cap, sizeof(*list)) : NULL;
    if (cap && !list) {
        free(rows);
        return sf_err_set(err, SF_ENOMEM, "farm: out of memory");
    }
    size_t k = 0;
    for (size_t i = 0; i < f->n_seed; i++)
        k += effective(&f->seed[i], row_of(rows, n_rows, f->seed[i].name), true, &list[k]);
    for (size_t i = 0; i < n_rows; i++)
        if (!seed_of(f, rows[i].name))
            k += effective(NULL, &rows[i], true, &list[k]);
    free(rows);
    *out = list;
    *n = k;
    return SF_OK;
}

/* Printer name's row into *r (a fresh one, has nothing, when none) and its seed. */
static int
load(struct farm *f, const char *name, struct store_printer_cfg *r,
     const struct farmcfg_printer **seed, struct sf_err *err)
{
    struct store_printer_cfg *rows;
    size_t n;
    int rc = store_printer_cfg_list(f->s, &rows, &n, err);
    if (rc)
        return rc;
    const struct store_printer_cfg *mine = row_of(rows, n, name);
    if (mine)
        *r = *mine;
    else
        *r = (struct store_printer_cfg){ 0 };
    snprintf(r->name, sizeof(r->name), "%s", name);
    free(rows);
    *seed = seed_of(f, name);
    return SF_OK;
}

/* A printer an operator acts on: the printer in force, its row and its seed. */
struct target {
    struct printer *p;                  /* not being removed */
    struct store_printer_cfg r;         /* its row (a fresh one when it has none) */
    const struct farmcfg_printer *seed; /* farm.ini's printer of its name, or NULL */
};

/*
 * Printer name as a target into *t: SF_ENOTFOUND with err set, SF_EIO.
 * busy non-NULL: SF_EAGAIN while it holds a job, err saying so and then busy.
 */
static int
open_printer(struct farm *f, const char *name, struct target *t, const char *busy,
             struct sf_err *err)
{
    t->p = farm_find(f, name);
    if (!t->p || printer_removed(t->p))
        return sf_err_set(err, SF_ENOTFOUND, "no printer '%.64s'", name);
    if (busy && printer_job(t->p))
        return sf_err_set(err, SF_EAGAIN, "printer '%.64s' is printing job %lld%s", name,
                          (long long)printer_job(t->p), busy);
    if (busy && printer_hot_idle(t->p))
        return sf_err_set(err, SF_EAGAIN,
                          "printer '%.64s' is idle with its heaters on (held for a print to "
                          "resume, or set by hand): turn them off first (M104 S0, M140 S0) or "
                          "wait for hold_heat_min to turn them off",
                          name);
    return load(f, name, &t->r, &t->seed, err);
}

/* Commit row r (detail for the event log), then apply what it and the seed make. */
static int
commit(struct farm *f, const struct store_printer_cfg *r, const struct farmcfg_printer *seed,
       const char *detail, struct sf_err *err)
{
    int rc = store_printer_cfg_put(f->s, r, detail, err);
    struct farmcfg_printer c;
    if (rc == SF_OK && effective(seed, r, true, &c))
        rc = farm_apply(f, &c, err);
    log_printer(rc ? LOG_ERROR : LOG_INFO, r->name, "%s%s%s", detail, rc ? ": " : "",
                rc && err ? err->msg : "");
    farm_notify(f);
    farm_kick(f);
    return rc;
}

/* text as a stored section body: within the store's cap, and what the file's rules take. */
static int
check_text(const char *name, const char *text, struct farmcfg_printer *c, struct sf_err *err)
{
    size_t len = strlen(text);
    if (len >= STORE_PRINTER_CFG_MAX)
        return sf_err_set(err, SF_EINVAL, "printer '%.64s': its options are longer than %d bytes",
                          name, STORE_PRINTER_CFG_MAX - 1);
    return farmcfg_printer_parse(c, name, text, len, err);
}

int
farm_printer_add(struct farm *f, const char *name, const char *text, struct sf_err *err)
{
    struct farmcfg_printer c;
    struct store_printer_cfg r;
    const struct farmcfg_printer *seed;
    int rc = check_text(name, text, &c, err);
    if (rc)
        return rc;
    if (farm_find(f, name))
        return sf_err_set(err, SF_EAGAIN, "printer '%.64s' exists", name);
    if (f->n_printers >= FARMCFG_PRINTERS_MAX)
        return sf_err_set(err, SF_EINVAL, "the farm has %d printers, the most it takes",
                          FARMCFG_PRINTERS_MAX);
    seed = seed_of(f, name);
    /* A new printer: nothing of a removed one of this name carries over. */
    r = (struct store_printer_cfg){ .has_cfg = true };
    snprintf(r.name, sizeof(r.name), "%s", name);
    snprintf(r.cfg, sizeof(r.cfg), "%s", text);
    return commit(f, &r, seed, "added", err);
}

int
farm_printer_edit(struct farm *f, const char *name, const char *text, struct sf_err *err)
{
    struct farmcfg_printer c;
    struct target t;
    int rc;
    if ((rc = open_printer(f, name, &t, NULL, err)) || (rc = check_text(name, text, &c, err)))
        return rc;
    t.r.has_cfg = true;
    snprintf(t.r.cfg, sizeof(t.r.cfg), "%s", text);
    effective(NULL, &t.r, true, &c);
    char why[200];
    if (printer_job(t.p) && farm_link_change(printer_cfg(t.p), &c, why, sizeof(why)))
        return sf_err_set(err, SF_EAGAIN,
                          "printer '%.64s' is printing job %lld: its connection cannot change "
                          "while it prints (%s)",
                          name, (long long)printer_job(t.p), why);
    if (printer_hot_idle(t.p) && farm_link_change(printer_cfg(t.p), &c, why, sizeof(why)))
        return sf_err_set(err, SF_EAGAIN,
                          "printer '%.64s' is idle with its heaters on: its connection cannot "
                          "change until they are off (%s)",
                          name, why);
    return commit(f, &t.r, t.seed, "edited", err);
}

int
farm_printer_disable(struct farm *f, const char *name, const char *reason, struct sf_err *err)
{
    struct target t;
    /* Refused rather than deferred: a disable that lands later, when the print ends, is a
       change nobody sees happen; the operator waits for the print or cancels it. */
    int rc = open_printer(f, name, &t,
                          ": disable it once the print ends, or cancel the print first", err);
    if (rc)
        return rc;
    if (!reason[0] || strlen(reason) >= sizeof(t.r.reason))
        return sf_err_set(err, SF_EINVAL, "field 'reason': say why, in 1..%zu bytes",
                          sizeof(t.r.reason) - 1);
    t.r.disabled = true;
    snprintf(t.r.reason, sizeof(t.r.reason), "%s", reason);
    char detail[160];
    snprintf(detail, sizeof(detail), "disabled: %s", reason);
    return commit(f, &t.r, t.seed, detail, err);
}

int
farm_printer_enable(struct farm *f, const char *name, struct sf_err *err)
{
    struct target t;
    int rc = open_printer(f, name, &t, NULL, err);
    if (rc)
        return rc;
    t.r.disabled = false;
    t.r.reason[0] = '\0';
    return commit(f, &t.r, t.seed, "enabled", err);
}

/* Does printer name's bed hold a part or an interrupted job (the store's word)?  SF_EAGAIN. */
static int
bed_busy(struct farm *f, const char *name, struct sf_err *err)
{
    struct store_bed *beds = NULL;
    size_t n = 0;
    int rc = store_beds(f->s, &beds, &n, err);
    for (size_t i = 0; rc == SF_OK && i < n; i++) {
        if (strcmp(beds[i].printer, name) != 0)
            continue;
        if (beds[i].interrupted_job)
            rc = sf_err_set(err, SF_EAGAIN,
                            "printer '%.64s' holds interrupted job %lld: resume, restart or "
                            "cancel it first",
                            name, (long long)beds[i].interrupted_job);
        else if (beds[i].bed_full)
            rc = sf_err_set(err, SF_EAGAIN,
                            "printer '%.64s' has a part on its bed: take it off and press Bed "
                            "cleared first",
                            name);
    }
    free(beds);
    return rc;
}

int
farm_printer_remove(struct farm *f, const char *name, struct sf_err *err)
{
    struct target t;
    int rc = open_printer(f, name, &t, "", err);
    if (rc)
        return rc;
    if ((rc = bed_busy(f, name, err)))
        return rc;
    /* farm.ini's printer needs a row saying it is gone; the API's own needs none. */
    t.r = (struct store_printer_cfg){ .removed = true };
    snprintf(t.r.name, sizeof(t.r.name), "%s", name);
    rc = t.seed ? store_printer_cfg_put(f->s, &t.r, "removed", err)
                : store_printer_cfg_drop(f->s, name, "removed", err);
    if (rc)
        return rc;
    log_printer(LOG_INFO, name, "removed");
    printer_set_removed(t.p, true);
    farm_sweep(f);
    farm_notify(f);
    farm_kick(f);
    return SF_OK;
}

int
farm_printer_base(struct farm *f, const char *name, struct farmcfg_printer *out, bool *stored,
                  struct sf_err *err)
{
    struct target t;
    int rc = open_printer(f, name, &t, NULL, err);
    if (rc)
        return rc;
    if (!effective(t.seed, &t.r, false, out))
        return sf_err_set(err, SF_ENOTFOUND, "no printer '%.64s'", name);
    *stored = t.r.has_cfg;
    return SF_OK;
}
