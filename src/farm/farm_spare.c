/*
 * farm_spare.c - one of several hosts with spare cores prepares for another
 * host's printer (issue 32: "any host with spare cores may prepare any
 * queued job"), and the printer's view as the scheduler sees it.
 *
 * The rule, kept simple: after the scheduling pass planned for this host's
 * own printers, a queued job that fits none of them (no host holds a queued
 * job) and fits a printer another live host owns is claimed here once it
 * has waited FARM_SPARE_WAIT_MS since its last change, while this host's
 * pool has a free place.  Why the wait: the printer's own host is woken by
 * the same NOTIFY and claims, within milliseconds, a job it has room for;
 * one still queued a second later waits for that host's pool (or for a
 * host that cannot prepare it at all), so this host takes nothing the
 * owner would have prepared sooner, and needs to know nothing of the
 * other hosts' pools.  A pass that finds such a job too young runs again
 * when it is not (a timer: nothing else would wake this host then).
 *
 * The job is prepared for that printer's settings as its owner published
 * them (store_host_publish, at each own of the beat; read here on the
 * farm's store thread, store_host_printers_prep, again when older than
 * FARM_SPARE_READ_MS); once prepared, its PREPARED and the release of this
 * host's claim are one transaction (store_job_prepared_release): the job
 * is ready and no host's, and the printer's owner takes it as it takes any
 * ready job no host holds (store_job_take; one statement, never two hosts)
 * and starts it: no host starts anything on a printer it does not own.
 * Why not hand it to the owner by name: the take already is the one way a
 * ready job reaches a printer, and a job no host holds also goes to any
 * host whose printer has the same key if the owner died meanwhile.  A host
 * that dies while preparing such a job is reaped as before: the job is
 * queued again.
 *
 * Thread: the loop thread (the read on the farm's store thread).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../base/clock.h"
#include "../base/log.h"
#include "../base/mem.h"
#include "farm_host.h"
#include "farm_int.h"
#include "printer.h"
#include "sched.h"
#include "store_host.h"
#include "storeq.h"

struct farm_spare {
    struct store_printer_prep *printers; /* the other live hosts' printers, as last read */
    struct farmcfg_printer *cfgs;        /* each as what preparing for it needs */
    struct sched_printer *views;         /* and as the scheduler sees it (strings in cfgs) */
    size_t n;
    int64_t read_at;   /* clock_mono_ms when that read came back; 0: none yet */
    int64_t db_offset; /* the database's clock less this host's wall clock, at that read */
    bool reading;      /* a read is on the store thread */
    uint64_t timer;    /* a pass when the next waiting job may be prepared here, 0 if none */
    int64_t timer_at;
};

/* A read of the other hosts' printers on the store thread: what it needs, what it found. */
struct spare_read {
    struct farm *f;
    char host[STORE_HOST_NAME_MAX];
    struct store_printer_prep *rows;
    size_t n;
    int64_t db_offset; /* store_clock_ms - clock_wall_ms on the store thread */
};

void
farm_cfg_view(const struct farmcfg_printer *c, struct sched_printer *out)
{
    *out = (struct sched_printer){ .name = c->name,
                                   .state = PRINTER_IDLE,
                                   .enabled = c->enabled,
                                   .material = c->material,
                                   .nozzle_mm = c->nozzle_mm,
                                   .group = c->group,
                                   .profile = c->profile,
                                   .overhang_deg = c->overhang_deg,
                                   .gcode_models = c->gcode_models };
    memcpy(out->bed_mm, c->bed_mm, sizeof(out->bed_mm));
}

void
farm_printer_view(const struct printer *p, struct sched_printer *out)
{
    farm_cfg_view(printer_cfg(p), out);
    enum printer_state st = printer_state(p);
    /* Idle here but not yet in its driver's eyes (its report is on the way):
       a start now would be refused and fail the print. */
    if (st == PRINTER_IDLE && !printer_connected(p))
        st = PRINTER_OFFLINE;
    out->state = st;
    out->enabled = out->enabled && !printer_removed(p);
}

void
farm_spare_publish(const struct farmcfg_printer *c, struct store_printer_prep *out)
{
    memset(out, 0, sizeof(*out));
    snprintf(out->name, sizeof(out->name), "%s", c->name);
    snprintf(out->profile, sizeof(out->profile), "%s", c->profile);
    snprintf(out->material, sizeof(out->material), "%s", c->material);
    out->nozzle_mm = c->nozzle_mm;
    memcpy(out->bed_mm, c->bed_mm, sizeof(out->bed_mm));
    out->overhang_deg = c->overhang_deg;
    snprintf(out->group, sizeof(out->group), "%s", c->group);
    snprintf(out->gcode_models, sizeof(out->gcode_models), "%s", c->gcode_models);
    out->attended = c->attended;
    snprintf(out->allow_gcode, sizeof(out->allow_gcode), "%s", c->allow_gcode);
    out->enabled = c->enabled;
}

/* What preparing for published printer p needs, as a printer's config. */
static void
spare_cfg(const struct store_printer_prep *p, struct farmcfg_printer *c)
{
    farmcfg_printer_init(c);
    snprintf(c->name, sizeof(c->name), "%s", p->name);
    snprintf(c->profile, sizeof(c->profile), "%s", p->profile);
    snprintf(c->material, sizeof(c->material), "%s", p->material);
    c->nozzle_mm = p->nozzle_mm;
    memcpy(c->bed_mm, p->bed_mm, sizeof(c->bed_mm));
    c->overhang_deg = p->overhang_deg;
    snprintf(c->group, sizeof(c->group), "%s", p->group);
    snprintf(c->gcode_models, sizeof(c->gcode_models), "%s", p->gcode_models);
    c->attended = p->attended;
    snprintf(c->allow_gcode, sizeof(c->allow_gcode), "%s", p->allow_gcode);
    c->enabled = p->enabled;
}

/* Is published printer p fit to prepare for, as farmcfg would take it (its profile and material
   name files under profiles_dir)?  If not, why in why. */
static bool
spare_ok(const struct store_printer_prep *p, char *why, size_t size)
{
    const char *bad = NULL;
    if (!farmcfg_ident_ok(p->profile))
        bad = "profile";
    else if (!farmcfg_ident_ok(p->material))
        bad = "material";
    else if (p->group[0] && !farmcfg_ident_ok(p->group))
        bad = "group";
    else if (!isfinite(p->nozzle_mm) || p->nozzle_mm <= 0)
        bad = "nozzle_mm";
    else if (!isfinite(p->overhang_deg) || p->overhang_deg <= 0 || p->overhang_deg >= 90)
        bad = "overhang_deg";
    for (int i = 0; !bad && i < 3; i++)
        if (!isfinite(p->bed_mm[i]) || p->bed_mm[i] <= 0)
            bad = "bed_size";
    if (bad)
        snprintf(why, size, "host %s's printer %s: bad %s", p->host, p->name, bad);
    return !bad;
}

static int
read_call(struct store *s, void *arg, struct sf_err *err)
{
    struct spare_read *r = arg;
    free(r->rows); /* a retry's */
    r->rows = NULL;
    r->n = 0;
    r->db_offset = store_clock_ms(s) - clock_wall_ms();
    return store_host_printers_prep(s, r->host, clock_wall_ms(), &r->rows, &r->n, err);
}

static void
on_read(void *ud, const struct storeq_result *res)
{
    struct spare_read *r = ud;
    struct farm *f = r->f;
    struct farm_spare *sp = f->spare;
    sp->reading = false;
    struct farmcfg_printer *c = r->n ? mem_calloc(r->n, sizeof(*c)) : NULL;
    struct sched_printer *v = r->n ? mem_array(r->n, sizeof(*v)) : NULL;
    if (res->rc || (r->n && (!c || !v))) {
        log_warn("farm", "the other hosts' printers: %s",
                 res->rc ? res->err->msg : "out of memory");
        free(r->rows);
        free(c);
        free(v);
    } else {
        free(sp->printers);
        free(sp->cfgs);
        free(sp->views);
        size_t n = 0, skipped = 0;
        char why[256];
        for (size_t k = 0; k < r->n; k++) {
            if (!spare_ok(&r->rows[k], why, sizeof(why))) { /* never prepared for */
                if (!skipped++)
                    log_warn("farm", "the other hosts' printers: %s: skipped", why);
                continue;
            }
            r->rows[n] = r->rows[k];
            spare_cfg(&r->rows[n], &c[n]);
            farm_cfg_view(&c[n], &v[n]);
            n++;
        }
        if (skipped > 1)
            log_warn("farm", "the other hosts' printers: %zu more skipped", skipped - 1);
        sp->printers = r->rows;
        sp->cfgs = c;
        sp->views = v;
        sp->n = n;
        sp->db_offset = r->db_offset;
    }
    sp->read_at = clock_mono_ms(); /* a failure too: read again in FARM_SPARE_READ_MS */
    free(r);
    if (!f->stopping)
        farm_kick(f);
}

/* Read the other hosts' printers again if the last read is old (none on its way). */
static void
refresh(struct farm *f)
{
    struct farm_spare *sp = f->spare;
    if (sp->reading || (sp->read_at && clock_mono_ms() - sp->read_at < FARM_SPARE_READ_MS))
        return;
    struct spare_read *r = mem_calloc(1, sizeof(*r));
    if (!r)
        return;
    r->f = f;
    snprintf(r->host, sizeof(r->host), "%s", farm_host_name(f));
    if (storeq_read(f->q, read_call, r, on_read, r)) {
        free(r);
        return;
    }
    sp->reading = true;
}

static void
on_timer(struct loop *l, void *ud)
{
    (void)l;
    struct farm *f = ud;
    f->spare->timer = 0;
    farm_kick(f);
}

/* A pass in ms (the earliest asked for wins). */
static void
pass_in(struct farm *f, int64_t ms)
{
    struct farm_spare *sp = f->spare;
    int64_t at = clock_mono_ms() + ms;
    if (sp->timer && sp->timer_at <= at)
        return;
    if (sp->timer)
        loop_timer_cancel(f->l, sp->timer);
    sp->timer = loop_timer_add(f->l, ms, on_timer, f);
    sp->timer_at = at;
}

void
farm_spare_claim(struct farm *f, const struct sched_job *sj, size_t n, size_t i,
                 const struct job_row *j)
{
    if (!farm_host_on(f) || farm_host_alone(f) || j->state != JOB_QUEUED || farm_cooling(f, j->id))
        return;
    if (!f->spare && !(f->spare = mem_calloc(1, sizeof(*f->spare))))
        return;
    struct farm_spare *sp = f->spare;
    refresh(f);
    if (!sp->n)
        return;
    size_t best = sched_prepare_for(sj, n, i, sp->views, sp->n);
    /* on the database's clock, as the claims and release_tx stamp updated_ms */
    int64_t waited = clock_wall_ms() + sp->db_offset - j->updated_ms;
    if (best == sp->n)
        return;
    if (waited < 0)
        waited = 0;
    if (waited < FARM_SPARE_WAIT_MS) { /* its owner's, if it has room meanwhile */
        pass_in(f, FARM_SPARE_WAIT_MS - waited);
        return;
    }
    log_info("farm", "job %lld: claiming it to prepare here for host %s's printer %s (spare cores)",
             (long long)j->id, sp->printers[best].host, sp->printers[best].name);
    farm_ask_spare(f, j, &sp->cfgs[best]);
}

void
farm_spare_free(struct farm *f)
{
    if (!f->spare)
        return;
    if (f->spare->timer)
        loop_timer_cancel(f->l, f->spare->timer);
    free(f->spare->printers);
    free(f->spare->cfgs);
    free(f->spare->views);
    free(f->spare);
    f->spare = NULL;
}
